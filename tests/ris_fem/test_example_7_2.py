"""Example 7.2 at test size: the paper's headline, the step-wise guarantees, symmetry, branches,
and every controller on the FE problem.

Headline (Sec. 7.2, Fig. 5): the adaptive scheme reaches the global residual sum_k(I1+I2) of the
uniform scheme with about half its steps. On a 16 x 16 grid (289 nodes) we fit the uniform
scheme's accepted steps against its global residual over four step sizes (tau = 0.005 ...
0.000625) and require the adaptive runs at tol = 1e-3 and 1e-4 to need at most 0.6 times the
uniform steps for their own global residual (measured: about 0.57 for both).

The ``regime`` controller (issue 12) is held to the equidistribution bound measured from the
uniform runs of the same module: (sum_k sqrt(I_k))^2 / (N sum_k I_k) over the finest uniform run
is the smallest fraction of uniform's steps any step sequence can need at equal global residual
while I ~ C(s) tau^2 (0.516 on this grid; see rothe.cli.ris_fem_commands.equidistribution_bound).
"""

from __future__ import annotations

import numpy as np
import pytest

from rothe.cli.ris_fem_commands import equidistribution_bound, uniform_work_interpolant
from rothe.fem.scalar import lumped_mass
from rothe.ris.fem_problem import describe_branch, example_7_2, example_7_2_3d, viscous_jumps
from rothe.ris.stepper import run_nested, run_ris

UNIFORM_TAUS = (0.005, 0.0025, 0.00125, 0.000625)


@pytest.fixture(scope="module")
def grid16():
    return example_7_2(16)


@pytest.fixture(scope="module")
def adaptive16_runs(grid16):
    return {tol: run_ris(grid16, "adaptive", tol=tol, tau=0.1) for tol in (1e-3, 1e-4)}


@pytest.fixture(scope="module")
def adaptive16(adaptive16_runs):
    return adaptive16_runs[1e-4]


@pytest.fixture(scope="module")
def uniform16(grid16):
    return [run_ris(grid16, "uniform", tol=None, tau=tau) for tau in UNIFORM_TAUS]


def check_every_step(problem, traj):
    """KKT residual, (3.2), Lemma 4.12, the ball, complementarity of lambda, t monotone."""
    kkt, kkt_tol = traj["kkt"], traj["kkt_tol"]
    assert np.all(kkt <= kkt_tol), f"KKT residual above tolerance: {np.nonzero(kkt > kkt_tol)[0]}"
    energy = traj["energy"]
    scale = 1e-12 * max(1.0, float(np.max(np.abs(energy))))
    assert np.all(traj["descent"] >= -scale), "(3.2) violated"
    I1, I2 = traj["I1"], traj["I2"]
    assert np.all(I1 >= -1e-14)
    # Lemma 4.12: I2 >= 0 up to the quadrature error (embedded-rule estimate) and round-off
    assert np.all(I2 >= -(traj["I2_err"] + 1e-12)), f"min I2 = {I2.min():.3g}"
    m_all = lumped_mass(problem.mesh)
    Z, tau, lam, t = traj["z"], traj["tau"], traj["lam"], traj["t"]
    nd = np.sqrt(np.sum(m_all * np.diff(Z, axis=0) ** 2, axis=1))
    # ||z_k - z_{k-1}||_V <= tau_k up to round-off of the difference of two O(1) states
    roundoff = 1e-14 * max(1.0, float(np.max(np.abs(Z))))
    assert np.all(nd <= tau * (1 + 1e-10) + roundoff)
    on_sphere = lam > 0  # complementarity (4.3): lambda > 0 only on the sphere
    assert np.all(np.abs(nd[on_sphere] - tau[on_sphere]) <= 1e-8 * tau[on_sphere] + roundoff)
    assert np.all(np.diff(t) >= 0) and abs(t[-1] - problem.T) <= 1e-9
    assert np.all(Z[:, problem.fixed] == 0)


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
    tr = run_ris(p, "adaptive", tol=1e-4, tau=0.1)
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
    neg = run_ris(example_7_2(8), "uniform", tol=None, tau=0.02)
    pos_problem = example_7_2(8, amplitude=200.0)
    pos = run_ris(pos_problem, "uniform", tol=None, tau=0.02)
    assert len(neg) == len(pos)
    assert np.max(np.abs(neg["z"] + pos["z"])) < 1e-9
    b = describe_branch(pos_problem, pos)
    assert b["z_min"] == 0.0 and b["z_max"] > 1.3 and b["branch"].startswith("z >= 0")


def test_z0_in_the_other_well_switches_later():
    """z0 = 1 (the other well) with the load pushing down: the state sticks near +1 and jumps to
    the negative well only when the load is strong enough (t ~ 0.63 on the 8 x 8 grid)."""
    p = example_7_2(8, z0=1.0)
    tr = run_ris(p, "uniform", tol=None, tau=0.02)
    check_every_step(p, tr)
    jumps = viscous_jumps(tr)
    assert jumps[0]["t"] == 0.0  # z0 = 1 up to the boundary is not stationary: it relaxes first
    assert any(0.55 < j["t"] < 0.7 for j in jumps[1:])
    k = np.searchsorted(tr["t"], 0.5)
    assert tr["z"][k].max() > 0.9  # still in the positive well at t = 0.5
    assert describe_branch(p, tr)["z_max"] <= 0.0  # ends in the negative well


@pytest.fixture(scope="module")
def nested8():
    return run_nested(example_7_2(8), [1e-3, 1e-4], tau=0.1)


def test_order2_and_nested_on_the_fe_problem(nested8):
    p = example_7_2(8)
    tr = run_ris(p, "order2", tol=1e-4, tau=0.1)
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
    tr = run_ris(p, "adaptive", tol=1e-3, tau=0.1)
    check_every_step(p, tr)
    jumps = viscous_jumps(tr)
    assert len(jumps) == 1 and 0.16 < jumps[0]["t"] < 0.19
    assert tr["z"][-1].min() < -1.3


# -- the regime controller (issue 12) -------------------------------------------------------------


@pytest.fixture(scope="module")
def regime16(grid16):
    return run_ris(grid16, "regime", tol=1e-4, tau=0.1)


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
    tr = run_ris(p, "regime", tol=1e-3, tau=0.1)
    check_every_step(p, tr)
    assert np.all(tr["I1"] < 1e-3) and np.all(tr["I2"] < 1e-3)
    assert len(viscous_jumps(tr)) == 1 and tr["z"][-1].min() < -1.3
