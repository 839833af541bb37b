"""BDF2 (variable steps) in both forms: orders, the start, the energy ledger, the bounds."""

import math

import numpy as np
import pytest

from rothe.eld import (
    DirichletData,
    ELDProblem,
    Material,
    NonlinearDamping,
    mms_errors,
    mms_problem,
    run_eld,
    step_coefficients,
)
from rothe.eld.examples import multiplier_quadrature
from rothe.eld.schemes import BDF2_ZERO_STABILITY, max_step_for
from rothe.eld.studies import fitted_rate
from rothe.errors import RotheInputError
from rothe.fem import mesh as meshes

TAUS = (0.1, 0.05, 0.025, 0.0125)


@pytest.fixture(scope="module")
def mms():
    return mms_problem(2, 2)


@pytest.mark.parametrize("form", ["regularized", "original"])
def test_second_order_for_u_v_and_lambda_at_T_and_over_all_steps(mms, form):
    problem, exact = mms  # P2 represents the solution exactly: all error is temporal
    errs = [mms_errors(problem, exact, run_eld(problem, form, tau, scheme="bdf2")) for tau in TAUS]
    for key in (
        "error_u_l2",
        "error_v_l2",
        "error_lam_l2",
        "error_u_l2_max",
        "error_v_l2_max",
        "error_lam_l2_max",
    ):
        rate = fitted_rate(TAUS, [e[key] for e in errs])
        assert rate >= 1.8, (key, rate)
    assert errs[-1]["error_u_l2"] < 5e-3


def _sequence(n, T=1.0):
    """Alternating ratios about 1.6 and 1/1.6 on a smooth variation (largest ratio 1.75)."""
    k = np.arange(n)
    w = (1.0 + 0.6 * (k % 2)) * (1.0 + 0.5 * np.sin(2 * np.pi * (k + 0.5) / n))
    return T * w / w.sum()


@pytest.mark.parametrize("form", ["regularized", "original"])
def test_variable_steps_keep_order_two(mms, form):
    problem, exact = mms
    rows = []
    for n in (10, 20, 40, 80):
        steps = _sequence(n)
        assert (steps[1:] / steps[:-1]).max() > 1.5
        traj = run_eld(problem, form, 0.1, scheme="bdf2", steps=steps)
        assert np.allclose(traj["tau"], steps, rtol=0, atol=1e-15)
        assert traj["t"][-1] == 1.0
        rows.append((steps.max(), mms_errors(problem, exact, traj)))
    h = [r[0] for r in rows]
    for key in ("error_u_l2", "error_v_l2", "error_lam_l2", "error_u_l2_max"):
        assert fitted_rate(h, [r[1][key] for r in rows]) >= 1.8, key


def _max_lambda_errors(problem, exact, taus, start):
    q = multiplier_quadrature(problem)
    out = []
    for tau in taus:
        traj = run_eld(problem, "original", tau, scheme="bdf2", start=start)
        ts, lams = traj["kept_t"], traj["lam"]
        out.append(
            max(
                q.error(lams[k], lambda x, n, t=ts[k]: exact.multiplier(t, x, n))
                for k in range(1, len(ts))
            )
        )
    return out


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


def test_coefficients_and_solvability_bound():
    assert step_coefficients("euler", 0.1, 0.05) == (1.0, -1.0, 0.0)
    a0, a1, a2 = step_coefficients("bdf2", 0.2, 0.1)  # omega = 2
    assert (a0, a1, a2) == pytest.approx((5 / 3, -3.0, 4 / 3))
    # delta is exact for quadratics with variable steps: z = t^2 at t = 0, 0.1, 0.3
    assert (a0 * 0.09 + a1 * 0.01 + a2 * 0.0) / 0.2 == pytest.approx(0.6)
    c = 0.7  # rho/d0
    assert max_step_for("euler", c, 0.3) == c
    assert max_step_for("bdf2", c, None) == pytest.approx(1.5 * c)
    for tp in (0.01, 0.3, 1.0, 10.0):
        tau = max_step_for("bdf2", c, tp)
        assert tau / step_coefficients("bdf2", tau, tp)[0] == pytest.approx(c, rel=1e-12)
        below = 0.999 * tau
        assert below / step_coefficients("bdf2", below, tp)[0] < c


def test_bdf2_step_bound_is_checked_before_any_step():
    problem, _ = mms_problem(2, 1, damping=NonlinearDamping(d0=2.0))  # rho/d0 = 0.5
    with pytest.raises(
        RotheInputError,
        match=r"^tau: got 0.8, must be < 1.5 rho/d0 = 0.75 "
        r"\(Lemma 3.2 for BDF2",
    ):
        run_eld(problem, "regularized", 0.8, scheme="bdf2")
    # 0.5 is refused by Euler but solvable for BDF2 (tau/alpha = 1/3 < 1/2)
    assert len(run_eld(problem, "original", 0.5, scheme="bdf2")["t"]) == 3
    with pytest.raises(
        RotheInputError,
        match=r"^steps: got tau_1 = 0.8, must satisfy "
        r"tau_j/alpha_j < rho/d0 = 0.5 \(alpha_j = 1.5",
    ):
        run_eld(problem, "regularized", 0.1, scheme="bdf2", steps=[0.8, 0.2])


def test_step_sequences_are_checked():
    problem, _ = mms_problem(2, 1)
    limit = f"{BDF2_ZERO_STABILITY:.6g}"
    with pytest.raises(
        RotheInputError,
        match=rf"^steps: got tau_3/tau_2 = 2.5, must be < 1 \+ "
        rf"sqrt\(2\) = {limit} \(zero-stability",
    ):
        run_eld(problem, "regularized", 0.1, scheme="bdf2", steps=[0.1, 0.1, 0.25, 0.55])
    # Euler has no ratio limit
    assert len(run_eld(problem, "regularized", 0.1, steps=[0.1, 0.1, 0.25, 0.55])["t"]) == 5
    with pytest.raises(RotheInputError, match=r"^steps: got steps summing to 0.9, must sum to T"):
        run_eld(problem, "regularized", 0.1, steps=[0.5, 0.4])
    with pytest.raises(RotheInputError, match=r"^steps: got tau_2 = -0.1, must be positive"):
        run_eld(problem, "regularized", 0.1, steps=[1.1, -0.1])


def _free_vibration(n=4):
    mesh = meshes.unit_square(n, named=True)
    material = Material(rho=1.0, lam=2.0, mu=1.0, dim=2)

    def zero(t, x):
        return np.zeros_like(x)

    return ELDProblem(
        mesh,
        material,
        degree=1,
        dirichlet={"left": DirichletData(zero, zero, zero)},
        u0=lambda x: np.stack([0.1 * x[0] ** 2, 0.2 * x[0] * x[1]]),
        v0=lambda x: np.stack([x[0] * x[1], -x[0]]),
        T=1.0,
    )


def test_energy_ledger_closes_to_round_off_for_bdf2_uniform_given_and_adaptive_steps():
    problem, _ = mms_problem(3, 2)  # nonlinear damping, loads, moving support
    runs = [run_eld(problem, form, 0.02, scheme="bdf2") for form in ("regularized", "original")]
    runs.append(run_eld(problem, "regularized", 0.1, scheme="bdf2", steps=_sequence(30)))
    runs.append(run_eld(problem, "original", 0.01, scheme="bdf2", control="adaptive", tol=1e-3))
    for traj in runs:
        scale = (
            np.abs(traj["energy"]).max()
            + np.abs(traj["work"]).max()
            + np.abs(traj["work_reaction"]).max()
        )
        assert np.abs(traj["balance_residual"]).max() <= 1e-12 * scale
        # N = N_G + S + C^n - C^0 at every state, with C^0 the start's boundary term
        N, NG, S = (
            traj[k] for k in ("numerical_dissipation", "numerical_dissipation_G", "step_change")
        )
        C = N - NG - S
        assert np.abs(C).max() < 0.5 * scale  # a boundary term, not accumulating
        # Newton to 1e-10: the algebraic residual's work is small but booked
        assert np.abs(traj["residual_work"]).max() <= 1e-6 * scale


def test_bdf2_G_dissipation_is_nonnegative_with_equal_steps_and_far_below_euler():
    problem = _free_vibration()
    euler = run_eld(problem, "regularized", 0.01)
    bdf2 = run_eld(problem, "regularized", 0.01, scheme="bdf2")
    E0 = bdf2["energy"][0]
    assert np.abs(bdf2["balance_residual"]).max() <= 1e-12 * E0
    assert np.diff(bdf2["numerical_dissipation_G"]).min() >= -1e-14 * E0
    assert np.abs(bdf2["step_change"]).max() <= 1e-14 * E0
    # no loads, no damping, fixed support: all energy change is numerical
    assert E0 - bdf2["energy"][-1] == pytest.approx(bdf2["numerical_dissipation"][-1], rel=1e-9)
    lost_euler = 1 - euler["energy"][-1] / E0
    lost_bdf2 = 1 - bdf2["energy"][-1] / E0
    assert lost_euler > 0.15 and 0 < lost_bdf2 < lost_euler / 10


def test_absurd_tau_is_one_line():
    problem, _ = mms_problem(2, 1)
    with pytest.raises(
        RotheInputError,
        match=r"^tau: got 9.99989e-321, must divide T = 1 into "
        r"equal steps \(T/tau = inf\)",
    ):
        run_eld(problem, "regularized", 1e-320)
    assert math.isinf(1.0 / 1e-320)
    with pytest.raises(RotheInputError, match=r"^tau: got 1e\+300, must be < rho/d0"):
        run_eld(problem, "regularized", 1e300)
