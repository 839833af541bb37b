"""The form objects (rothe.eld.form): Regularized(lifting=...) and Original()."""

import pytest

from rothe.eld import Original, Regularized, mms_problem, run_eld
from rothe.errors import RotheInputError


def test_forms_name_themselves_and_their_lifting():
    assert Regularized().lifting == "nodal" and Regularized("harmonic").lifting == "harmonic"
    assert Regularized().describe() == {"form": "regularized", "lifting": "nodal"}
    assert Original().describe() == {"form": "original", "lifting": None}
    assert Regularized() == Regularized("nodal") != Regularized("harmonic")


def test_form_objects_refuse_bad_input_in_one_line_naming_the_parameter():
    with pytest.raises(
        RotheInputError,
        match=r"^lifting: got 'smooth', must be one of nodal, "
        r"harmonic$",
    ) as info:
        Regularized(lifting="smooth")
    assert info.value.parameter == "lifting"
    problem, _ = mms_problem(2, 1)
    with pytest.raises(
        RotheInputError,
        match=r"^form: got 'index3', must be Regularized\("
        r"lifting=\.\.\.\) or Original\(\)",
    ) as info:
        run_eld(problem, form="index3")
    assert info.value.parameter == "form" and len(str(info.value).splitlines()) == 1
    with pytest.raises(AttributeError):  # frozen: validated once, in the constructor
        Regularized().lifting = "smooth"
