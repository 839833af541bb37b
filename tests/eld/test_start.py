"""The start of a run (rothe.eld.start): the consistent initial acceleration and multiplier, and
the BDF2 history that keeps the multiplier second order at every step."""

import numpy as np
import pytest

from rothe.eld import (
    BDF2,
    ELDStepper,
    Original,
    RayleighDamping,
    mms_errors,
    mms_problem,
    run_eld,
)
from rothe.eld.start import consistent_acceleration, data_scale, with_prehistory
from rothe.eld.studies import fitted_rate
from rothe.errors import RotheInputError
from rothe.stepping.controllers import Adaptive, Uniform


def _max_lambda_errors(problem, exact, taus, start):
    """The largest multiplier error over all steps (mms_errors' ``error_lam_l2_max``)."""
    return [
        mms_errors(
            exact, run_eld(problem, form=Original(), control=Uniform(tau), scheme=BDF2(start=start))
        )["error_lam_l2_max"]
        for tau in taus
    ]


def test_the_start_keeps_the_multiplier_second_order_at_every_step():
    """SPEC 7's trap, over a short horizon where the start dominates the largest error.

    Original form, where B u = G makes v and a on Gamma_D pure difference quotients of G: the
    Taylor start with the cubic Gamma_D term keeps every step's multiplier error O(tau^2); without
    it the errors of steps 1 and 3 are O(tau); one Euler step first leaves an O(1) error."""
    problem, exact = mms_problem(2, 2, T=0.05)
    taus = (0.0025, 0.00125, 0.000625)
    taylor = _max_lambda_errors(problem, exact, taus, "taylor")
    assert fitted_rate(taus, taylor) >= 1.8
    taylor2 = _max_lambda_errors(problem, exact, taus, "taylor2")
    assert 0.8 <= fitted_rate(taus, taylor2) <= 1.2
    euler = _max_lambda_errors(problem, exact, taus[:2], "euler")
    assert euler[1] > 0.9 * euler[0] > 100 * taylor[0]


def test_initial_state_is_consistent_and_the_history_follows_the_taylor_polynomial():
    # Rayleigh damping: the body force is quadratic, so the space holds the exact acceleration
    problem, exact = mms_problem(2, 2, damping=RayleighDamping(0.1, 0.01))
    stepper = ELDStepper(problem, scheme=BDF2(), control=Uniform(0.01))
    state = stepper.initial_state()
    system = stepper.system
    # the consistent acceleration of the exact initial data is the exact one (P2: exact space)
    a = exact.u_ddot(0.0, problem.space.doflocs)
    assert np.abs(state.fields["a"] - np.asarray(a).T.ravel()).max() <= 1e-8
    a2, lam = consistent_acceleration(system, 0.0, state.u, state.v, problem.G_ddot(0.0))
    assert np.array_equal(a2, state.fields["a"]) and np.array_equal(lam, state.lam)
    assert state.ledger.energy == state.ledger.initial > 0 and state.j == 0
    # the BDF2 history: u^{-1} = P(-tau) is u(-tau) up to O(tau^3) (the Taylor polynomial)
    errors = []
    for tau in (0.02, 0.01):
        new = with_prehistory(stepper, state, tau)
        u_prev = np.asarray(exact.u(-tau, problem.space.doflocs)).T.ravel()
        errors.append(np.abs(new.fields["u_1"] - u_prev).max())
    assert 0 < errors[1] < 2e-5 and 6.0 <= errors[0] / errors[1] <= 10.0
    assert new.tau_prev == tau and "x_1" in new.fields and "x_1" not in state.fields
    assert new.ledger.boundary_C0 == new.ledger.boundary_C != 0.0


def test_error_scale_and_inconsistent_initial_data():
    problem, _ = mms_problem(2, 1)
    stepper = ELDStepper(problem, control=Adaptive(1e-3, tau=0.01))
    state = stepper.initial_state()
    norm0 = np.sqrt(2.0 * state.ledger.energy)
    assert stepper.error_scale == pytest.approx(max(norm0, data_scale(stepper.system, 1.0)))
    assert state.energy_norm_max == stepper.error_scale
    with pytest.raises(
        RotheInputError,
        match=r"^u0: got max\|u0 - G\(0\)\| = 0.5 on the "
        "Dirichlet parts left, must equal G\\(0\\)",
    ):
        run_eld(mms_problem(2, 1, start="rest")[0], control=Uniform(0.1))
