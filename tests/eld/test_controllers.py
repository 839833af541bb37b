"""Adaptive time steps (rothe.eld.controllers): the error-norm controller, adaptive runs."""

import math
from dataclasses import dataclass, field

import numpy as np
import pytest

from rothe.eld import (
    BDF2,
    Differenced,
    ImplicitEuler,
    NonlinearDamping,
    Regularized,
    mms_errors,
    mms_problem,
    ramp_problem,
    run_eld,
)
from rothe.eld.scheme import BDF2_RATIO_CAP, BOUND_SAFETY
from rothe.errors import RotheInputError
from rothe.stepping.controllers import Adaptive, ErrorNormController


@dataclass
class _Result:
    tau: float
    error: float
    converged: bool = True
    code: str = "ok"
    errors: dict = field(default_factory=dict)

    def __post_init__(self):
        self.errors = {"local_error": self.error}


def test_error_norm_controller_rejects_accepts_and_limits_the_next_step():
    bound_calls = []

    def bound(tau_last):
        bound_calls.append(tau_last)
        return 0.3 if tau_last is None else 0.35

    c = ErrorNormController(1e-3, 0.1, order=2, max_ratio=1.8, step_bound=bound, tau_max=1.0)
    assert c.propose(0.0) == (0.1, None)
    # too large an error: reject, shrink by safety * (tol/err)^(1/3) but not below fac_min
    d = c.decide(_Result(0.1, 8e-3))
    assert not d.accept and d.next_tau == pytest.approx(0.1 * 0.9 * 0.5)
    d = c.decide(_Result(d.next_tau, 1e-1))
    assert not d.accept and d.next_tau == pytest.approx(0.045 * 0.2)  # fac_min
    # accepted right after a rejection: no growth even with a tiny error
    d = c.decide(_Result(0.009, 1e-9))
    assert d.accept and d.next_tau == pytest.approx(0.009)
    # then growth, limited by fac_max = 2 and by max_ratio = 1.8 times the last accepted step
    d = c.decide(_Result(0.009, 1e-9))
    assert d.accept and d.next_tau == pytest.approx(1.8 * 0.009)
    # the step bound of the last accepted step caps the proposal
    tau = d.next_tau
    for _ in range(20):
        d = c.decide(_Result(tau, 1e-9))
        tau = d.next_tau
    assert tau == pytest.approx(0.35) and bound_calls[-1] == pytest.approx(0.35)
    # a failed inner solve is a rejection, whatever the error
    d = c.decide(_Result(tau, 0.0, converged=False, code="newton"))
    assert not d.accept and d.next_tau == pytest.approx(0.25 * 0.35)
    # round trip of its state
    saved = c.checkpoint_state()
    other = ErrorNormController(1e-3, 0.1, order=2, max_ratio=1.8, step_bound=bound)
    other.restore_state(saved)
    assert other.checkpoint_state() == saved
    with pytest.raises(RotheInputError, match=r"^tol: got 0, must be > 0"):
        ErrorNormController(0.0, 0.1, order=2)


@pytest.fixture(scope="module")
def ramp_run():
    problem = ramp_problem(2, 2)
    return problem, run_eld(problem, scheme=BDF2(), control=Adaptive(1e-4, tau=0.01)).trajectory


def test_adaptive_bdf2_refines_at_the_ramp_and_keeps_its_limits(ramp_run):
    problem, traj = ramp_run
    t, tau = traj["t"][1:], traj["tau"]
    assert traj["t"][-1] == 1.0
    assert traj.stats.rejected_steps >= 1
    near = tau[np.abs(t - 0.5) < 0.01]
    far = tau[(t < 0.3) | (t > 0.8)]
    assert near.max() < far.min() / 5
    # every accepted step met the tolerance, the ratio cap and the solvability bound
    assert traj["local_error"].max() <= 1e-4
    ratios = tau[1:] / tau[:-1]
    assert ratios.max() <= BDF2_RATIO_CAP * (1 + 1e-12)
    scale = np.abs(traj["energy"]).max() + np.abs(traj["work_reaction"]).max()
    assert np.abs(traj["balance_residual"]).max() <= 1e-12 * scale
    assert traj.meta["ratio_cap"] == BDF2_RATIO_CAP and traj.meta["tol"] == 1e-4


def test_adaptive_steps_never_exceed_the_solvability_bound():
    problem, _ = mms_problem(2, 1, damping=NonlinearDamping(d0=2.0), T=4.0)  # rho/d0 = 0.5
    for scheme in (ImplicitEuler(), BDF2()):
        traj = run_eld(problem, scheme=scheme, control=Adaptive(0.5, tau=0.1)).trajectory
        tau = traj["tau"]
        prev = [None] + list(tau[:-1])
        eff = [t / scheme.coefficients(t, p)[0] for t, p in zip(tau, prev, strict=True)]
        assert max(eff) <= BOUND_SAFETY * 0.5 * (1 + 1e-12)
        assert max(eff) > 0.8 * BOUND_SAFETY * 0.5  # the bound, not the error, limited it


def test_adaptive_error_follows_the_tolerance():
    problem, exact = mms_problem(2, 2)
    errs, steps = [], []
    for tol in (1e-3, 1e-5):
        result = run_eld(
            problem, scheme=BDF2(), control=Adaptive(tol, tau=0.01), store_fields=False
        )
        errs.append(mms_errors(exact, result)["error_u_l2"])
        steps.append(result.statistics.accepted_steps)
    # local error ~ tau^3 ~ tol: 100x smaller tol, about 100^(1/3) = 4.6x more steps
    assert 3.0 <= steps[1] / steps[0] <= 7.0
    assert errs[1] < errs[0] / 10


def test_adaptive_defaults():
    """Adaptive(tol): the first step 0.01, steps in [1e-10 T, T]."""
    problem, _ = mms_problem(2, 1)
    traj = run_eld(problem, control=Adaptive(1e-2)).trajectory
    assert traj.meta["tau"] == 0.01 and traj["tau"][0] == 0.01
    assert traj.meta["tau_min"] == 1e-10 and traj.meta["tau_max"] == 1.0
    assert math.isfinite(BDF2_RATIO_CAP)


@pytest.mark.parametrize("scheme", [ImplicitEuler(), BDF2()], ids=["euler", "bdf2"])
def test_differenced_data_step_control_does_not_depend_on_the_lifting(scheme):
    """With differenced data both liftings give the same u, v, a (to the Newton tolerance), so
    the adaptive runs must take about the same steps (the error scale S_j, taken from the lifted
    data's energy, differs with the lifting by a few per cent). The estimate on the harmonic
    lifting's unknowns used to see the data quotients' jump after a step cut and drove tau below
    tau_min on this run (mms n=3, BDF2, tol 1e-4)."""
    problem, _ = mms_problem(3, 2)
    runs = {
        lifting: run_eld(
            problem,
            form=Regularized(lifting),
            scheme=scheme,
            control=Adaptive(1e-4, tau=0.02),
            data=Differenced(),
        ).trajectory
        for lifting in ("nodal", "harmonic")
    }
    nodal, harmonic = runs["nodal"], runs["harmonic"]
    n_nodal, n_harmonic = nodal.stats.accepted_steps, harmonic.stats.accepted_steps
    assert abs(n_harmonic - n_nodal) <= 0.1 * n_nodal
    assert harmonic.stats.rejected_steps <= nodal.stats.rejected_steps + 2
    assert np.max(harmonic["local_error"]) < 1e-4
    scale = np.abs(nodal["u"]).max()
    assert np.abs(harmonic["u"][-1] - nodal["u"][-1]).max() <= 1e-3 * scale
