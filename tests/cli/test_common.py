"""``rothe.cli.common``: the argparse types say what the library's checks say."""

from __future__ import annotations

import argparse

import pytest

from rothe.cli.common import parse_float_list, parse_int
from rothe.errors import RotheInputError, check_int


@pytest.mark.parametrize(
    "text, minimum", [("auto", 1), ("1.5", 0), ("1e5", 1), ("", None), ("x", 3)]
)
def test_parse_int_refuses_in_the_words_of_check_int(text, minimum):
    """One source of "must be an integer >= k" (``errors.integer_allowed``): the command line's
    type (argparse puts ``argument --k:`` before it) and the library's check give one line."""
    with pytest.raises(argparse.ArgumentTypeError) as typed:
        parse_int("--k", minimum)(text)
    allowed = "must be an integer" + ("" if minimum is None else f" >= {minimum}")
    assert str(typed.value) == f"got {text!r}, {allowed}"
    if text not in ("1e5",):  # an integral float: check_int takes it, parse_int does not
        with pytest.raises(RotheInputError) as checked:
            check_int("--k", text, minimum)
        assert str(checked.value) == f"--k: {typed.value}"


def test_parse_int_leaves_the_range_to_the_check_where_the_value_is_used():
    assert parse_int("--k", 1)("0") == 0
    with pytest.raises(RotheInputError, match=r"^--k: got 0, must be an integer >= 1$"):
        check_int("--k", 0, 1)


def test_parse_float_list_refuses_an_empty_item():
    with pytest.raises(argparse.ArgumentTypeError) as typed:
        parse_float_list("--tols")("1e-3,")
    assert str(typed.value) == "got '1e-3,', must be a comma-separated list of finite numbers"
