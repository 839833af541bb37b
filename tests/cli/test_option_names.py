"""Every command-line refusal names the option, not the library's parameter (issue 17 item 4).

The library validates once, where a value enters, and names the API parameter; the command line
renames it to the option it came from through argparse's own table of the command
(rothe.cli.main.option_table), so no check is repeated only to name an option.
"""

from __future__ import annotations

import argparse

import pytest

from rothe.cli.main import main, option_table
from rothe.errors import RotheInputError, fail


@pytest.mark.parametrize(
    "argv, line",
    [
        (
            ["run", "eld-mms", "--tau", "0.03"],
            "rothe: error: --tau: got 0.03, must divide T = 1 into equal steps (T/tau = 33.3333)",
        ),
        (["run", "eld-beam", "--degree", "3"], "rothe: error: --degree: got 3, must be 1 or 2"),
        (
            ["run", "ris-2d", "--n", "4", "--dirichlet", "inlet"],
            "rothe: error: --dirichlet: got 'inlet', must be one of bottom, left, right, top "
            "(sides of "
            "the bounding box; the mesh has no named parts)",
        ),
        (["run", "ris-1d", "--tau", "0"], "rothe: error: --tau: got 0, must be > 0"),
    ],
)
def test_refusals_name_the_option(argv, line, tmp_path, capsys):
    code = main(argv + ["--quiet", "--no-plots", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == [line]


def test_option_table_reads_argparse_and_the_commands_aliases():
    parser = argparse.ArgumentParser()
    parser.add_argument("--space-tol", type=float)
    parser.add_argument("--tau", dest="step")
    parser.add_argument("--n", "-n")

    class Command:
        parameter_options = {"adapt": "--adapt-space"}

    table = option_table(parser, Command())
    assert table == {
        "space_tol": "--space-tol",
        "step": "--tau",
        "tau": "--tau",
        "n": "--n",
        "adapt": "--adapt-space",
    }


def test_renamed_keeps_the_rest_of_the_line_and_only_renames_its_own_parameter():
    exc = fail("space_tol", -1.0, "must be > 0")
    assert exc.parameter == "space_tol"
    assert str(exc.renamed("--space-tol")) == "--space-tol: got -1, must be > 0"
    plain = RotheInputError("load(t=0.5): got nan, must be finite")
    assert plain.renamed("--tau") is plain  # names no parameter: unchanged
