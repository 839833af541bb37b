"""The scheme objects (rothe.eld.scheme): coefficients, the solvability bound, the estimate
factor, validation in the constructor."""

import math

import pytest

from rothe.eld import BDF2, ImplicitEuler, mms_problem, run_eld
from rothe.eld.scheme import BDF2_RATIO_CAP, BDF2_ZERO_STABILITY, STARTS, as_scheme
from rothe.errors import RotheInputError


def test_coefficients_and_solvability_bound():
    euler, bdf2 = ImplicitEuler(), BDF2()
    assert euler.coefficients(0.1, 0.05) == (1.0, -1.0, 0.0)
    a0, a1, a2 = bdf2.coefficients(0.2, 0.1)  # omega = 2
    assert (a0, a1, a2) == pytest.approx((5 / 3, -3.0, 4 / 3))
    # delta is exact for quadratics with variable steps: z = t^2 at t = 0, 0.1, 0.3
    assert (a0 * 0.09 + a1 * 0.01 + a2 * 0.0) / 0.2 == pytest.approx(0.6)
    c = 0.7  # rho/d0
    assert euler.max_step(c, 0.3) == c
    assert bdf2.max_step(c, None) == pytest.approx(1.5 * c)
    for tp in (0.01, 0.3, 1.0, 10.0):
        tau = bdf2.max_step(c, tp)
        assert tau / bdf2.coefficients(tau, tp)[0] == pytest.approx(c, rel=1e-12)
        below = 0.999 * tau
        assert below / bdf2.coefficients(below, tp)[0] < c
    assert bdf2.max_step(math.inf, 0.3) == math.inf


def test_equal_steps_and_the_estimate_factor():
    """alpha_0 for equal steps (the first matrix, the indicator's reaction), c(1) = 8/11."""
    bdf2 = BDF2()
    assert bdf2.coefficients(0.1, None) == (1.5, -2.0, 0.5)
    assert bdf2.alpha0 == bdf2.coefficients(0.1, 0.1)[0] == 1.5
    assert ImplicitEuler().alpha0 == ImplicitEuler().coefficients(0.1, 0.1)[0] == 1.0
    assert bdf2.estimate_factor(1.0) == pytest.approx(8 / 11)
    assert ImplicitEuler().estimate_factor(0.3) == 1.0
    assert (ImplicitEuler().order, bdf2.order) == (1, 2)
    assert ImplicitEuler().ratio_cap == math.inf and bdf2.ratio_cap == BDF2_RATIO_CAP
    assert bdf2.zero_stability == BDF2_ZERO_STABILITY == 1 + math.sqrt(2)


def test_the_bdf2_start_chooses_the_first_step():
    assert BDF2().prehistory and BDF2("taylor2").prehistory
    assert BDF2().first_step() == BDF2()
    assert not BDF2("euler").prehistory and BDF2("euler").first_step() == ImplicitEuler()
    assert not ImplicitEuler().prehistory and ImplicitEuler().first_step() == ImplicitEuler()
    assert BDF2("taylor2").describe() == {"scheme": "bdf2", "start": "taylor2"}
    assert ImplicitEuler().describe() == {"scheme": "euler", "start": None}


def test_scheme_objects_refuse_bad_input_in_one_line_naming_the_parameter():
    with pytest.raises(
        RotheInputError, match=r"^start: got 'taylor3', must be one of " + ", ".join(STARTS) + "$"
    ) as info:
        BDF2(start="taylor3")
    assert info.value.parameter == "start"
    problem, _ = mms_problem(2, 1)
    with pytest.raises(
        RotheInputError,
        match=r"^scheme: got 'bdf3', must be ImplicitEuler\(\) "
        r"or BDF2\(start=\.\.\.\)",
    ) as info:
        run_eld(problem, scheme="bdf3")
    assert info.value.parameter == "scheme" and len(str(info.value).splitlines()) == 1
    with pytest.raises(RotheInputError, match=r"^scheme: got <class"):
        as_scheme(BDF2)  # the class, not an object
    with pytest.raises(AttributeError):  # frozen: validated once, in the constructor
        BDF2().start = "euler"
