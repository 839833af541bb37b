"""I1 (3.3), I2 (3.4): quadrature, Lemma 5.3 (order tau^2 in R^n), Lemma 4.12 (I2 >= 0)."""

import numpy as np
import pytest

from rothe import RISProblem, run_ris
from rothe.ris.examples import example_7_1
from rothe.ris.residuals import simpson_weights, step_residuals
from rothe.ris.stepper import RISState, RISStepper
from rothe.stepping.controllers import Adaptive, Uniform


@pytest.mark.parametrize("n", [2, 4, 8, 16])
def test_simpson_is_exact_for_cubics(n):
    x = np.linspace(0, 1, n + 1)
    w = simpson_weights(n)
    for k in range(4):
        assert w @ x**k == pytest.approx(1 / (k + 1), rel=1e-14)


def test_simpson_rejects_odd_subintervals():
    with pytest.raises(ValueError, match="must be even"):
        simpson_weights(5)


def test_residual_of_a_sticking_step_is_tau_squared_over_two():
    """From the equilibrium (t, z) = (3, 7) of Ex. 7.1 the step sticks (d = 0) and
    dist(-DI(t^, 7)) = t^ - 3, so I1 = int_0^tau s ds = tau^2 / 2 exactly, I2 = 0."""
    problem = example_7_1()
    stepper = RISStepper(problem)
    for tau in (0.4, 0.1, 0.025):
        r = stepper.step(RISState(s=0.0, t=3.0, z=np.array([7.0])), tau)
        assert r.converged and r.state.z[0] == 7.0
        assert r.I1 == pytest.approx(tau**2 / 2, rel=1e-12)
        assert r.I2 == 0.0


def smooth_problem(n=4):
    A = 2 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
    return RISProblem(
        A,
        F=lambda z: float(np.sum(np.cos(z))),
        dF=lambda z: -np.sin(z),
        d2F=lambda z: -np.cos(z),
        load=lambda t: 2.0 * t * np.arange(1, n + 1),
        dissipation_weights=0.3,
        metric_weights=np.linspace(0.5, 1.5, n),
        z0=np.zeros(n),
        T=2.0,
    )


def test_lemma_5_3_residuals_are_order_tau_squared():
    """In R^n, I1 + I2 <= C tau^2 (Lemma 5.3): from a slipping state the residual of one step
    decays at least like tau^2 (fitted slope >= 1.9) and I/tau^2 does not grow as tau -> 0."""
    problem = smooth_problem()
    traj = run_ris(problem, Uniform(1e-2)).trajectory  # to t = T = 2, slipping
    assert np.any(traj["z"][-1] != traj["z"][-2]) and traj["lam"][-1] == 0
    state = RISState(s=0.0, t=float(traj["t"][-2]), z=traj["z"][-2].copy())
    stepper = RISStepper(problem)
    taus = np.array([4e-2, 2e-2, 1e-2, 5e-3])
    res = np.array([stepper.step(state, tau).errors for tau in taus], dtype=object)
    total = np.array([r["I1"] + r["I2"] for r in res])
    assert np.all(total > 0)
    slope = np.polyfit(np.log(taus), np.log(total), 1)[0]
    assert slope >= 1.9
    C = total / taus**2
    assert np.all(C[1:] <= C[:-1] * 1.05)


@pytest.mark.parametrize("seed", range(4))
def test_lemma_4_12_on_random_nonconvex_runs(seed):
    """Every accepted step: I1 >= 0 and I2 >= -(Simpson error estimate) - kkt * ||d||_V.

    Lemma 4.12 assumes exact stationarity; a KKT defect w of the inner solve shifts the discrete
    energy identity by <w, d> <= ||w||_{V^-1} ||d||_V, so that is the solver's share of the bound.
    """
    rng = np.random.default_rng(seed)
    n = 5
    B = rng.standard_normal((n, n))
    a = rng.uniform(1, 3, n)
    b = 4 * rng.standard_normal(n)
    problem = RISProblem(
        B @ B.T / n + 0.5 * np.eye(n),
        F=lambda z: float(a @ (1 - z**2) ** 2),
        dF=lambda z: -4 * a * z * (1 - z**2),
        d2F=lambda z: a * (12 * z**2 - 4),
        load=lambda t: b * t,
        dissipation_weights=rng.uniform(0.2, 1, n),
        metric_weights=rng.uniform(0.5, 1.5, n),
        z0=-np.ones(n),
        T=1.0,
    )
    traj = run_ris(problem, Adaptive(1e-5, tau=0.05)).trajectory
    assert len(traj) > 10
    assert np.all(traj["I1"] >= 0)
    assert np.all(traj["I2"] >= -traj["I2_err"] - traj["kkt"] * traj["step_norm"] - 1e-15)
    assert np.all(traj["descent"] >= -1e-12)


def test_residuals_use_the_gradient_at_the_inner_solution():
    """step_residuals with gbar = DI(t_{k-1}, z_k): a jump step of Ex. 7.1 has I1 = I2 = 0."""
    problem = example_7_1()
    z_prev, z_new = np.array([-1.0]), np.array([-0.5])
    gbar = problem.gradient(2.0, z_new)
    r = step_residuals(problem, 2.0, z_prev, 2.0, z_new, gbar)
    assert r.I1 == 0.0
    assert r.I2 == pytest.approx(0.0, abs=1e-14)
