"""Example 7.1 of Andreia & Meyer (2022) against its exact BV solution (7.1)."""

import numpy as np
import pytest

from rothe import run_ris
from rothe.cli.ris_commands import uniform_work_at_error
from rothe.ris.examples import errors_against_exact, exact_solution, example_7_1


@pytest.fixture(scope="module")
def problem():
    return example_7_1()


def run(problem, control, tol=None, tau=0.1):
    traj = run_ris(problem, control, tol=tol, tau=tau)
    row = errors_against_exact(traj["s"], traj["t"], traj["z"])
    row.update(
        control=control,
        tol=tol,
        tau0=tau,
        inner_solves=traj.stats.inner_solves,
        accepted_steps=traj.stats.accepted_steps,
    )
    return traj, row


@pytest.fixture(scope="module")
def uniform_rows(problem):
    return [run(problem, "uniform", tau=tau)[1] for tau in (0.1, 0.05, 0.02, 0.01, 0.005, 0.002)]


def test_exact_solution_is_a_bv_solution(problem):
    """(7.1) satisfies t' + |z'| = 1, (2.3b) and the energy balance (2.5) for the energy of SPEC."""
    s = np.linspace(0, 16, 16001)
    t, z = exact_solution(s)
    dt, dz = np.gradient(t, s), np.gradient(z, s)
    interior = np.all(np.abs(s[:, None] - [2.0, 10.0]) > 1e-2, axis=1)
    assert np.allclose((dt + np.abs(dz))[interior], 1.0)
    dist = np.array(
        [problem.dist(problem.gradient(ti, np.array([zi]))) for ti, zi in zip(t, z, strict=True)]
    )
    assert np.max((dt * dist)[interior]) < 1e-12  # (2.3b)
    # (2.5): I(t(s), z(s)) + int R(z') + |z'| dist = I(0, z0) + int d_t I t'
    energy = np.array([problem.energy(ti, np.array([zi])) for ti, zi in zip(t, z, strict=False)])
    dtI = -z  # d/dt I(t, z) = -z for the load (t + 1) z
    integrand = np.abs(dz) + np.abs(dz) * dist - dtI * dt
    lhs = energy + np.concatenate(
        [[0], np.cumsum(0.5 * (integrand[1:] + integrand[:-1]) * np.diff(s))]
    )
    assert np.max(np.abs(lhs - energy[0])) < 1e-3


def test_adaptive_tol_1e4_is_within_2e2_of_exact(problem):
    traj, row = run(problem, "adaptive", tol=1e-4)
    assert row["error_linf"] <= 2e-2
    assert traj["t"][-1] == pytest.approx(5.0, abs=1e-9)
    assert traj["z"][-1, 0] == pytest.approx(9.0, abs=2e-2)


def test_error_falls_as_tol_falls(problem):
    errs = [run(problem, "adaptive", tol=tol)[1] for tol in (1e-3, 1e-4, 1e-5)]
    linf = [e["error_linf"] for e in errs]
    l2 = [e["error_l2"] for e in errs]
    assert linf[0] > linf[1] > linf[2]
    assert l2[0] > l2[1] > l2[2]


def test_uniform_converges_with_order_one(uniform_rows):
    tau = np.array([r["tau0"] for r in uniform_rows])
    l2 = np.array([r["error_l2"] for r in uniform_rows])
    slope = np.polyfit(np.log(tau), np.log(l2), 1)[0]
    assert slope >= 0.9
    assert l2[-1] < 1e-2


HEADLINE_TOLS = (1e-3, 1e-4, 1e-5, 1e-6)


@pytest.fixture(scope="module")
def headline(problem, uniform_rows):
    """Error-versus-work curves as in the paper's Fig. 3: log(work) fitted against log(Linf)."""
    work_uniform = uniform_work_at_error(uniform_rows)
    curves = {}
    for control in ("adaptive", "order2"):
        rows = [run(problem, control, tol=tol)[1] for tol in HEADLINE_TOLS]
        err = np.log([r["error_linf"] for r in rows])
        fits = {}
        for key in ("inner_solves", "accepted_steps"):
            b, a = np.polyfit(err, np.log([r[key] for r in rows]), 1)
            fits[key] = lambda e, a=a, b=b: float(np.exp(a + b * np.log(e)))
        curves[control] = (rows, fits)
    return work_uniform, curves


ERRORS = (1e-2, 3e-3, 1e-3)


def test_headline_adaptive_iterations_about_a_quarter(headline):
    """The paper's Fig. 3 claim: about a quarter of uniform's iterations (accepted steps)."""
    work_uniform, curves = headline
    _, fits = curves["adaptive"]
    ratios = [fits["accepted_steps"](e) / work_uniform(e) for e in ERRORS]
    assert max(ratios) <= 0.4
    assert min(ratios) >= 0.15  # a quarter, not a different regime altogether


def test_headline_order2_inner_solves_at_most_half(headline):
    """Counting every inner solve (accepted + rejected), order2 needs at most half of uniform's,
    pointwise at every tolerance and on the fitted curve."""
    work_uniform, curves = headline
    rows, fits = curves["order2"]
    for r in rows:
        assert r["inner_solves"] <= 0.5 * work_uniform(r["error_linf"])
    for e in ERRORS:
        assert fits["inner_solves"](e) <= 0.3 * work_uniform(e)


@pytest.mark.xfail(
    strict=True,
    reason=(
        "Alg. 3.2 as published needs 0.50-0.58 of uniform's inner solves on the fitted curve "
        "(pointwise up to 1.07 at tol=1e-4): when I(tau) falls in [tol/4, tol/2) it doubles tau, "
        "2 tau is rejected, tau is halved and accepted again, so in slip rejections equal "
        "acceptances. The order2 controller meets the bound."
    ),
)
def test_headline_adaptive_inner_solves_at_most_half(headline):
    """The issue's version of the headline for Alg. 3.2: accepted + rejected <= 1/2 of uniform."""
    work_uniform, curves = headline
    _, fits = curves["adaptive"]
    for e in ERRORS:
        assert fits["inner_solves"](e) <= 0.5 * work_uniform(e)


def test_every_accepted_step_satisfies_kkt_and_lemma_4_12(problem):
    traj, _ = run(problem, "adaptive", tol=1e-5)
    assert np.all(traj["kkt"] <= traj["kkt_tol"])
    assert np.all(traj["kkt"] <= 1e-8)
    assert np.all(traj["lam"] >= 0)
    assert np.all(traj["I1"] >= 0)
    # Lemma 4.12 up to the quadrature error and the inner solver's share kkt * ||d||_V
    assert np.all(traj["I2"] >= -traj["I2_err"] - traj["kkt"] * traj["step_norm"] - 1e-15)
    assert np.all(traj["descent"] >= -1e-12)  # (3.2)
    s, t, tau = traj["s"], traj["t"], traj["tau"]
    assert np.allclose(np.diff(s), tau)
    dz = np.abs(np.diff(traj["z"][:, 0]))
    assert np.all(dz <= tau * (1 + 1e-12))
    assert np.allclose(np.diff(t), tau - dz, atol=1e-12)  # Step 4 time update


def test_adaptive_takes_large_steps_while_sticking_and_jumping(problem):
    """Fig. 2: steps double during sticking (I1 = I2 = 0) and in the 1-D viscous jump."""
    traj, _ = run(problem, "adaptive", tol=1e-5)
    s, tau = traj["s"][1:], traj["tau"]
    slip = tau[(s > 10.5) & (s < 15.5)]
    jump = tau[(s > 2.5) & (s < 9.5)]
    assert jump.max() >= 8 * slip.max()
    assert np.sum((s > 2.5) & (s < 9.5)) < 20
