"""The examples of Sec. 7: Example 7.1 against its exact BV solution (7.1), and Example 7.2 at
test size -- the paper's headline, the step-wise guarantees, symmetry, branches, and every
controller on the FE problem -- with its 3D analogue.

Headline of Example 7.2 (Sec. 7.2, Fig. 5): the adaptive scheme reaches the global residual
sum_k(I1+I2) of the uniform scheme with about half its steps. On a 16 x 16 grid (289 nodes) we
fit the uniform scheme's accepted steps against its global residual over four step sizes
(tau = 0.005 ... 0.000625) and require the adaptive runs at tol = 1e-3 and 1e-4 to need at most
0.6 times the uniform steps for their own global residual (measured: about 0.57 for both).

The ``regime`` controller (issue 12) is held to the equidistribution bound measured from the
uniform runs of the same module: (sum_k sqrt(I_k))^2 / (N sum_k I_k) over the finest uniform run
is the smallest fraction of uniform's steps any step sequence can need at equal global residual
while I ~ C(s) tau^2 (0.516 on this grid; see rothe.ris.summary.equidistribution_bound).
"""

import math

import numpy as np
import pytest

from rothe import run_ris
from rothe.cli.ris_commands import control_object
from rothe.errors import RotheInputError
from rothe.fem.mesh import unit_cube, unit_square
from rothe.ris.controllers import Nested, Order2, Regime
from rothe.ris.examples import (
    errors_against_exact,
    exact_solution,
    example_7_1,
    example_7_2,
    example_7_2_3d,
    example_front,
)
from rothe.ris.run import run_nested
from rothe.ris.summary import (
    describe_branch,
    equidistribution_bound,
    uniform_work_at_error,
    uniform_work_interpolant,
    viscous_jumps,
)
from rothe.stepping.controllers import Adaptive, Uniform

from .conftest import check_every_step


@pytest.fixture(scope="module")
def problem():
    return example_7_1()


def run(problem, control, tol=None, tau=0.1):
    traj = run_ris(problem, control_object(control, tol=tol, tau=tau)).trajectory
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


# -- Example 7.2 and its 3D analogue ---------------------------------------------------------------


def test_3d_problem_and_dimension_checks():
    p = example_7_2_3d(3)
    assert p.dim == 3 and p.n_nodes == 64 and p.n == 8
    assert math.isclose(p.energy(0.0, p.z0), 48.0, rel_tol=1e-14)
    with pytest.raises(
        RotheInputError,
        match=r"^mesh: got a 3D mesh \(64 nodes, 162 tetrahedra\), "
        r"must be 2D \(triangles\) for ris-2d$",
    ):
        example_7_2(mesh=unit_cube(3))
    with pytest.raises(RotheInputError, match=r"must be 3D \(tetrahedra\) for ris-3d$"):
        example_7_2_3d(mesh=unit_square(3))


@pytest.mark.parametrize("n", [1, 0, -3])
def test_grid_smaller_than_2(n):
    """A grid of one cell per side has no interior node: refused by every built-in RIS grid."""
    for example in (example_7_2, example_7_2_3d, example_front):
        with pytest.raises(RotheInputError, match=rf"^n: got {n}, must be an integer >= 2$"):
            example(n)


UNIFORM_TAUS = (0.005, 0.0025, 0.00125, 0.000625)


@pytest.fixture(scope="module")
def grid16():
    return example_7_2(16)


@pytest.fixture(scope="module")
def adaptive16_runs(grid16):
    return {tol: run_ris(grid16, Adaptive(tol, tau=0.1)).trajectory for tol in (1e-3, 1e-4)}


@pytest.fixture(scope="module")
def adaptive16(adaptive16_runs):
    return adaptive16_runs[1e-4]


@pytest.fixture(scope="module")
def uniform16(grid16):
    return [run_ris(grid16, Uniform(tau)).trajectory for tau in UNIFORM_TAUS]


def test_every_accepted_step_adaptive(grid16, adaptive16_runs):
    for traj in adaptive16_runs.values():
        check_every_step(grid16, traj)


def test_every_accepted_step_uniform(grid16, uniform16):
    for traj in uniform16:
        check_every_step(grid16, traj)


@pytest.mark.parametrize("tol", [1e-3, 1e-4])
def test_headline_adaptive_needs_at_most_0_6_of_the_uniform_steps(tol, adaptive16_runs, uniform16):
    res = [float(np.sum(tr["I1"] + tr["I2"])) for tr in uniform16]
    steps = [len(tr) for tr in uniform16]
    slope, icpt = np.polyfit(np.log(res), np.log(steps), 1)
    # the uniform scheme is first order: global residual ~ C / steps
    assert -1.1 < slope < -0.9, slope
    adaptive = adaptive16_runs[tol]
    res_a = float(np.sum(adaptive["I1"] + adaptive["I2"]))
    assert res[-1] < res_a < res[0]  # interpolation, not extrapolation
    uniform_steps = np.exp(icpt + slope * np.log(res_a))
    ratio = len(adaptive) / uniform_steps
    assert ratio <= 0.6, f"adaptive {len(adaptive)} steps vs uniform {uniform_steps:.0f}"
    # the local residual max_k(I1 + I2) of the adaptive run is below 2 tol (I1, I2 < tol each)
    assert np.max(adaptive["I1"] + adaptive["I2"]) < 2 * tol


def test_large_steps_while_sticking_and_jumping(adaptive16):
    """Fig. 4: larger steps in sticking and in the viscous jump than in rate-independent slip."""
    tr = adaptive16
    jumps = viscous_jumps(tr)
    assert len(jumps) == 1 and 0.16 < jumps[0]["t"] < 0.18  # 200 t^3 = 1 at t = 0.171
    s_mid = tr["s"][1:]
    tau = tr["tau"]
    in_jump = (s_mid > jumps[0]["s_start"]) & (s_mid <= jumps[0]["s_end"])
    in_slip = s_mid > jumps[0]["s_end"] + 0.05
    assert np.median(tau[in_jump]) > 4 * np.median(tau[in_slip])
    assert tau[0] == 0.1 and np.all(np.diff(tr["z"][:2], axis=0) == 0)  # first step sticks


def _reflection(mesh, fmap):
    p = mesh.p
    n = int(round(1 / np.min(np.diff(np.unique(p[0])))))
    key = lambda q: np.round(q[0] * n).astype(int) * (n + 1) + np.round(q[1] * n).astype(int)  # noqa: E731
    k0, k1 = key(p), key(fmap(p))
    order = np.argsort(k0)
    perm = order[np.searchsorted(k0[order], k1)]
    invariant = {tuple(c) for c in np.sort(perm[mesh.t], axis=0).T} == {
        tuple(c) for c in np.sort(mesh.t, axis=0).T
    }
    return perm, invariant


def test_symmetry_on_the_tensor_grid(grid16, adaptive16):
    """The 16 x 16 grid is symmetric under (x, y) -> (y, x) and (x, y) -> (1-x, 1-y); so is z."""
    for fmap in (lambda q: np.array([q[1], q[0]]), lambda q: np.array([1 - q[0], 1 - q[1]])):
        perm, invariant = _reflection(grid16.mesh, fmap)
        assert invariant
        Z = adaptive16["z"]
        assert np.max(np.abs(Z - Z[:, perm])) < 1e-9


def test_symmetry_on_the_union_jack_grid():
    """Union-jack grid: invariant under all reflections of the square; z must be as well."""
    p = example_7_2(8, pattern="unionjack")
    tr = run_ris(p, Adaptive(1e-4, tau=0.1)).trajectory
    check_every_step(p, tr)
    for fmap in (
        lambda q: np.array([1 - q[0], q[1]]),
        lambda q: np.array([q[0], 1 - q[1]]),
        lambda q: np.array([q[1], q[0]]),
    ):
        perm, invariant = _reflection(p.mesh, fmap)
        assert invariant
        assert np.max(np.abs(tr["z"] - tr["z"][:, perm])) < 1e-9


def test_load_sign_mirrors_the_branch():
    """g is even: amplitude +200 gives exactly -z of the run with -200 (same steps)."""
    neg = run_ris(example_7_2(8), Uniform(0.02)).trajectory
    pos_problem = example_7_2(8, amplitude=200.0)
    pos = run_ris(pos_problem, Uniform(0.02)).trajectory
    assert len(neg) == len(pos)
    assert np.max(np.abs(neg["z"] + pos["z"])) < 1e-9
    b = describe_branch(pos_problem, pos)
    assert b["z_min"] == 0.0 and b["z_max"] > 1.3 and b["branch"].startswith("z >= 0")


def test_z0_in_the_other_well_switches_later():
    """z0 = 1 (the other well) with the load pushing down: the state sticks near +1 and jumps to
    the negative well only when the load is strong enough (t ~ 0.63 on the 8 x 8 grid)."""
    p = example_7_2(8, z0=1.0)
    tr = run_ris(p, Uniform(0.02)).trajectory
    check_every_step(p, tr)
    jumps = viscous_jumps(tr)
    assert jumps[0]["t"] == 0.0  # z0 = 1 up to the boundary is not stationary: it relaxes first
    assert any(0.55 < j["t"] < 0.7 for j in jumps[1:])
    k = np.searchsorted(tr["t"], 0.5)
    assert tr["z"][k].max() > 0.9  # still in the positive well at t = 0.5
    assert describe_branch(p, tr)["z_max"] <= 0.0  # ends in the negative well


@pytest.fixture(scope="module")
def nested8():
    return [r.trajectory for r in run_nested(example_7_2(8), Nested([1e-3, 1e-4], tau=0.1))]


def test_order2_and_nested_on_the_fe_problem(nested8):
    p = example_7_2(8)
    tr = run_ris(p, Order2(1e-4, tau=0.1)).trajectory
    check_every_step(p, tr)
    runs = nested8
    for r in runs:
        check_every_step(p, r)
    coarse, fine = runs[0]["s"], runs[1]["s"]
    # Alg. 6.2: the grid of the second run contains every grid point of the first
    assert np.all(np.min(np.abs(coarse[:, None] - fine[None, :]), axis=1) <= 1e-12)


def test_nested_takes_no_round_off_sized_steps(nested8):
    """A step that would end within round-off of an earlier grid point lands on it exactly."""
    assert np.min(nested8[1]["tau"]) > 1e-12


def test_3d_analogue():
    p = example_7_2_3d(4)
    tr = run_ris(p, Adaptive(1e-3, tau=0.1)).trajectory
    check_every_step(p, tr)
    jumps = viscous_jumps(tr)
    assert len(jumps) == 1 and 0.16 < jumps[0]["t"] < 0.19
    assert tr["z"][-1].min() < -1.3


# -- the regime controller (issue 12) -------------------------------------------------------------


@pytest.fixture(scope="module")
def regime16(grid16):
    return run_ris(grid16, Regime(1e-4, tau=0.1)).trajectory


def test_every_accepted_step_regime(grid16, regime16):
    """Alg. 3.2's acceptance (I1 < tol and I2 < tol), KKT, (3.2), Lemma 4.12 at every step."""
    check_every_step(grid16, regime16)
    assert np.all(regime16["I1"] < 1e-4) and np.all(regime16["I2"] < 1e-4)
    jumps = viscous_jumps(regime16)
    assert len(jumps) == 1 and 0.16 < jumps[0]["t"] < 0.19


def _regime_ratio_and_bound(regime16, uniform16):
    def row(traj):
        return {
            "control": traj.meta["control"],
            "status": "completed",
            "sum_residual": float(np.sum(traj["I1"] + traj["I2"])),
            "inner_solves": traj.stats.inner_solves,
        }

    solves_at = uniform_work_interpolant([row(t) for t in uniform16], "inner_solves")
    base = solves_at(row(regime16)["sum_residual"])
    assert base is not None, "the uniform runs must bracket the regime run's global residual"
    finest = min(uniform16, key=lambda t: t["tau"][0])
    return regime16.stats.inner_solves / base, equidistribution_bound(finest["I1"] + finest["I2"])


def test_regime_solves_near_the_equidistribution_bound(regime16, uniform16):
    """Inner solves (accepted + rejected + landing) at equal global residual, against uniform:
    within 10 % of the bound no step sequence can beat (measured 0.548 vs 0.516 at tol 1e-4)."""
    ratio, bound = _regime_ratio_and_bound(regime16, uniform16)
    assert 0.45 < bound < 0.6
    assert ratio <= 1.1 * bound, f"regime: {ratio:.3f} of uniform's solves, bound {bound:.3f}"
    assert regime16.stats.rejected_steps <= 0.02 * regime16.stats.accepted_steps


@pytest.mark.xfail(
    strict=True,
    reason=(
        "issue 12's coarse guard (<= 0.4 of uniform's solves at equal global residual) is below "
        "what any step sequence can reach on Example 7.2: sticking and the viscous jump are 45 % "
        "of the arc length but carry ~0 of the residual, slip carries all of it with I ~ C(s) "
        "tau^2, so by Cauchy-Schwarz N >= (sum sqrt(I_k))^2 / G, i.e. >= 0.516 of uniform's "
        "steps on this grid (0.520 at 40 x 40); regime needs 0.548"
    ),
)
def test_issue_12_guard_regime_solves_at_most_0_4_of_uniform(regime16, uniform16):
    ratio, _ = _regime_ratio_and_bound(regime16, uniform16)
    assert ratio <= 0.4


def test_regime_on_the_3d_analogue():
    p = example_7_2_3d(4)
    tr = run_ris(p, Regime(1e-3, tau=0.1)).trajectory
    check_every_step(p, tr)
    assert np.all(tr["I1"] < 1e-3) and np.all(tr["I2"] < 1e-3)
    assert len(viscous_jumps(tr)) == 1 and tr["z"][-1].min() < -1.3
