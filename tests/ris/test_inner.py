"""The inner step (3.1)+(3.2) on random non-convex problems; Lemma 4.1 checked independently;
the result codes (RISCode) carry their messages and keep their string values."""

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import example, given, settings
from hypothesis import strategies as st

from rothe import BallStepSolver, InnerOptions, RISProblem
from rothe.ris.inner import RISCode
from rothe.stepping.results import ResultCode


def random_problem(seed, n, sparse=False, coupled_F=False):
    rng = np.random.default_rng(seed)
    B = rng.standard_normal((n, n))
    A = B @ B.T / n + 0.3 * np.eye(n)
    a = rng.uniform(0.5, 4.0, n)  # double-well depths: F is non-convex
    C = 0.5 * rng.standard_normal((n, n)) / n
    C = C + C.T
    if coupled_F:
        F = lambda z: float(a @ (1 - z**2) ** 2 + 0.5 * z @ C @ z)  # noqa: E731
        dF = lambda z: -4 * a * z * (1 - z**2) + C @ z  # noqa: E731
        d2F = lambda z: np.diag(a * (12 * z**2 - 4)) + C  # noqa: E731
    else:
        F = lambda z: float(a @ (1 - z**2) ** 2)  # noqa: E731
        dF = lambda z: -4 * a * z * (1 - z**2)  # noqa: E731
        d2F = lambda z: a * (12 * z**2 - 4)  # noqa: E731
    return with_random_data(rng, sp.csr_matrix(A) if sparse else A, F, dF, d2F), rng


def with_random_data(rng, A, F, dF, d2F):
    """The RIS problem of A and F with a random affine load, weights and start (n = len(A))."""
    n = A.shape[0]
    b0, b1 = rng.standard_normal(n), 3 * rng.standard_normal(n)
    return RISProblem(
        A,
        F,
        dF,
        d2F,
        load=lambda t: b0 + b1 * t,
        dissipation_weights=rng.uniform(0.1, 2.0, n),
        metric_weights=rng.uniform(0.2, 2.0, n),
        z0=rng.uniform(-1.5, 1.5, n),
        T=1.0,
    )


def independent_kkt(problem, t, zprev, res, tau):
    """Residuals of (4.1)-(4.4) computed from scratch (not with the solver's helpers)."""
    d = res.z - zprev
    g = problem.A @ res.z + problem.dF(res.z) - problem.load(t)
    r, m, lam = problem.r, problem.m, res.lam
    moving = d != 0
    w = np.where(moving, g + r * np.sign(d) + lam * m * d, np.maximum(np.abs(g) - r, 0))
    stat = np.sqrt(np.sum(w**2 / m))
    nd = np.sqrt(m @ d**2)
    dist = np.sqrt(np.sum(np.maximum(np.abs(g) - r, 0) ** 2 / m))
    return stat, nd, dist, g, d


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 10**6),
    n=st.integers(1, 9),
    tau=st.floats(1e-3, 3.0),
    t=st.floats(0.0, 1.0),
    sparse=st.booleans(),
    coupled=st.booleans(),
)
# a node set moving from rest on which the active-set Hessian is indefinite: Newton aimed back at
# the saddle, the orthant projection kept the node at rest, and 100 iterations crept
# (max_iterations before the fix)
@example(seed=57242, n=3, tau=1.0, t=0.75, sparse=True, coupled=True)
def test_every_step_satisfies_lemma_4_1(seed, n, tau, t, sparse, coupled):
    problem, rng = random_problem(seed, n, sparse, coupled)
    zprev = rng.uniform(-1.5, 1.5, n)
    solver = BallStepSolver(problem, InnerOptions(atol=1e-10, rtol=1e-10))
    res = solver.solve(t, zprev, tau)
    assert res.converged, res.code
    stat, nd, dist, g, d = independent_kkt(problem, t, zprev, res, tau)
    assert stat <= 1e-8
    assert res.lam >= 0.0
    assert nd <= tau * (1 + 1e-12)
    if nd < tau * (1 - 1e-9):
        assert res.lam == 0.0  # (4.1): an interior step has no multiplier
    # (4.2): tau * dist(-DI) = lam ||d||^2 and (4.3): R(d) + tau dist = <-DI, d>
    scale = 1.0 + abs(g @ d) + tau * dist
    assert abs(tau * dist - res.lam * nd**2) <= 1e-7 * scale
    assert abs(problem.dissipation(d) + tau * dist + g @ d) <= 1e-7 * scale
    # (3.2): the step never increases I(t, .) + R(. - zprev)
    J = problem.energy(t, res.z) + problem.dissipation(d)
    assert J <= problem.energy(t, zprev) + 1e-12 * (1 + abs(J))


def test_sticking_step_costs_no_linear_solve():
    """If |D_z I(t, z_prev)| <= r componentwise, z_prev itself is the answer (d = 0)."""
    problem, rng = random_problem(3, 5)
    zprev = problem.z0.copy()
    g = problem.gradient(0.0, zprev)
    problem.r[:] = np.abs(g) + 0.1
    solver = BallStepSolver(problem)
    res = solver.solve(0.0, zprev, 0.5)
    assert res.converged and res.iterations == 0
    assert np.array_equal(res.z, zprev) and res.lam == 0.0
    assert solver.linear.stats.factorizations == 0


def test_viscous_jump_lands_on_sphere_with_positive_multiplier():
    """Ex. 7.1 at t = 2.2, z = -2: no stable state nearby, so the step is a jump of length tau."""
    from rothe.ris.examples import example_7_1

    problem = example_7_1()
    solver = BallStepSolver(problem)
    for tau in (1e-3, 0.1, 1.0, 3.0):
        res = solver.solve(2.2, np.array([-2.0]), tau)
        assert res.converged
        assert res.d[0] == pytest.approx(tau, rel=1e-12)
        # stationarity on the sphere: -DI(2.2, z) - 1 = lam * d  with DI = z - 3.2 + p'(z)
        z = res.z[0]
        grad = z - 3.2 + problem.dF(res.z)[0]
        assert res.lam == pytest.approx((-grad - 1.0) / tau, rel=1e-9)
        assert res.lam > 0


def test_first_jump_step_just_past_the_end_of_sticking_leaves_the_saddle_at_once():
    """Example 7.2 at t = 0.171 (the onset of the jump is t* = 200^(-1/3) = 0.170998): the excess
    of |D_z I| over r is ~1e-5 of r, so the iterates escape z = 0 slowly; once their direction
    has negative curvature the ray to the sphere is taken (8 iterations and 7 factorizations
    without it on 32 x 32, 22 and 18 on 320 x 320)."""
    from rothe.ris.examples import example_7_2

    p = example_7_2(32)
    solver = BallStepSolver(p, InnerOptions(linear_solver="direct"))
    res = solver.solve(0.171, p.z0.copy(), 0.004)
    assert res.converged and res.kkt_residual <= res.tolerance
    assert p.norm_V(res.d) == pytest.approx(0.004, rel=1e-10) and res.lam > 100  # the jump
    assert res.J_final < res.J_start  # (3.2)
    assert res.iterations <= 6 and solver.linear.stats.factorizations <= 4


def convex_problem(seed, n):
    """A strictly convex quadratic I with a strongly coupled A (random, not diagonally dominant)."""
    rng = np.random.default_rng(seed)
    B = rng.standard_normal((n, n))
    A = B @ B.T / n + 0.05 * np.eye(n)
    a = rng.uniform(0.1, 1.0, n)
    return with_random_data(
        rng, A, lambda z: float(0.5 * a @ z**2), lambda z: a * z, lambda z: a.copy()
    ), rng


@settings(max_examples=80, deadline=None)
@given(
    seed=st.integers(0, 10**6), n=st.integers(2, 9), tau=st.floats(1e-2, 3.0), t=st.floats(0.0, 1.0)
)
# the Newton candidate overshoots along a descent direction (272169: the Newton point outside the
# ball, retracted radially onto the sphere; 68455: a node sent back and projected to rest), so the
# model rises from d to it: the line search gated every shorter trial by the full step's negative
# predicted decrease, refused them although they lower J, and a forward-backward step was taken
@example(seed=272169, n=2, tau=2.0, t=0.5)
@example(seed=68455, n=2, tau=2.0044676301485684, t=0.7078257571931234)
# 1882: from d = 0 the Newton point lies outside the ball and its retraction onto the sphere
# raises J, while the minimizer lies inside: every shorter trial retracted onto the sphere was
# that same point, so a forward-backward step was taken; the chord inside the ball is tried now
@example(seed=1882, n=4, tau=1.25, t=0.0)
def test_convex_step_needs_no_forward_backward_step(seed, n, tau, t):
    # With a positive definite Hessian a node that Newton sends back against its predicted sign
    # is the ordinary semismooth case (the coupling overruled the diagonal prediction), not a
    # saddle: the candidate must be projected and kept. Refusing it (as before the curvature
    # check) sent 176 of 400 such problems into forward-backward steps, and the 640 x 640 slip
    # phase of Example 7.2 into 3x its Newton iterations.
    problem, _ = convex_problem(seed, n)
    res = BallStepSolver(problem).solve(t, problem.z0, tau)
    assert res.converged, res.code
    assert res.fb_steps == 0
    stat, nd, _, _, _ = independent_kkt(problem, t, problem.z0, res, tau)
    assert nd <= tau * (1 + 1e-12)
    assert stat <= 1e-6 * (1 + np.abs(problem.load(t)).max())


def test_curvature_check_tells_a_saddle_from_a_minimum():
    problem, _ = random_problem(3, 2)
    solver = BallStepSolver(problem)
    nodes = np.array([True, False])
    delta = np.array([0.7, -0.2])
    H = problem.A + np.diag(np.zeros(2))
    up = np.zeros(2)
    down = np.array([-(H[0, 0] + 1.0), 0.0])  # F''_00 pushes the curvature at node 0 below zero
    hdiag_up, hdiag_down = np.diag(H) + up, np.diag(H) + down
    assert solver._positive_curvature(up, hdiag_up, 0.0, nodes, delta)
    assert not solver._positive_curvature(down, hdiag_down, 0.0, nodes, delta)
    # a shift nu M large enough makes it a minimum again
    assert solver._positive_curvature(down, hdiag_down, 10.0 / problem.m.min(), nodes, delta)


def test_result_codes_keep_their_strings_and_carry_their_messages():
    """The codes stored in trajectories, where-dicts and summaries are the strings they were;
    the likely cause of a stop is the member's message (FAILURE_HINTS before)."""
    import json

    assert issubclass(RISCode, ResultCode)
    values = {"running", "converged", "max_iterations", "stalled", "nonfinite", "data_beyond_T"}
    assert {c.value for c in RISCode} == values
    for code in RISCode:
        assert code == code.value and str(code) == code.value and f"{code}" == code.value
        assert RISCode(code.value) is code and code.message
        assert json.loads(json.dumps({"code": code})) == {"code": code.value}
    assert RISCode.CONVERGED.successful and not RISCode.STALLED.successful
    cause = "dF or d2F probably does not belong to F"
    assert cause in RISCode.STALLED.hint and cause in RISCode.MAX_ITERATIONS.hint
    assert "non-finite value" in RISCode.NONFINITE.hint
    assert RISCode.CONVERGED.hint is None and RISCode.DATA_BEYOND_T.hint is None
    assert RISCode.RUNNING.hint is None


def test_a_solve_that_runs_out_of_iterations_says_so():
    problem, rng = random_problem(11, 6)
    res = BallStepSolver(problem, InnerOptions(max_iter=1)).solve(0.5, problem.z0, 1.0)
    assert not res.converged and res.code is RISCode.MAX_ITERATIONS
    res = BallStepSolver(problem).solve(0.5, problem.z0, 1.0)
    assert res.converged and res.code is RISCode.CONVERGED


def _newton_matrix_by_sparse_products(problem, chi, hess_F, shift, inactive_diag):
    """The reference K = S (A + F'') S + diag(chi shift m + (1 - chi) inactive_diag) by sparse
    algebra: what _NewtonMatrix.build computed for a sparse F'' before its fixed pattern."""
    chif = chi.astype(float)
    S = sp.diags(chif)
    K = S @ (sp.csr_matrix(problem.A) + sp.csr_matrix(hess_F)) @ S
    return (K + sp.diags(chif * shift * problem.m + (1 - chif) * inactive_diag)).tocsr()


def test_newton_matrix_of_a_sparse_second_derivative_equals_the_sparse_products():
    """The cell rule's F'' filled into the union pattern of A and F'' (cached per pattern) gives
    the same K as S (A + F'') S + diag(...) by sparse products, for several active sets, for two
    iterates with one pattern, and after a F'' with another pattern (the cache is refreshed)."""
    from rothe.ris.examples import example_7_2
    from rothe.ris.inner import _NewtonMatrix

    p = example_7_2(8, quadrature="consistent")
    rng = np.random.default_rng(3)
    K = _NewtonMatrix(p)
    other = sp.random(p.n, p.n, density=0.05, random_state=4, format="csr")
    for hess in (p.d2F(rng.uniform(-1.3, 1.3, p.n)), p.d2F(rng.uniform(-1.3, 1.3, p.n)), other):
        for fraction in (1.0, 0.5, 0.0):
            chi = rng.random(p.n) < fraction
            diag = rng.uniform(1.0, 2.0, p.n)
            got = K.build(chi, hess, 0.7, diag)
            want = _newton_matrix_by_sparse_products(p, chi, hess, 0.7, diag)
            assert abs(got - want).max() <= 1e-13 * abs(want).max()


def test_cell_rule_step_equals_the_step_with_the_sparse_product_newton_matrix(monkeypatch):
    """Example 7.2 with the cell rule, the jump step at t = 0.18 and a slip step after it: the
    solver with the fixed-pattern Newton matrix returns the same z, multiplier and iteration
    count as with K by sparse products (the path before), both KKT-exact."""
    from rothe.ris.examples import example_7_2
    from rothe.ris.inner import _NewtonMatrix

    p = example_7_2(12, quadrature="consistent")
    fast = BallStepSolver(p, InnerOptions(linear_solver="direct"))
    jump = fast.solve(0.18, p.z0.copy(), 0.02)
    slip = fast.solve(0.3, jump.z, 0.02)
    monkeypatch.setattr(
        _NewtonMatrix,
        "build",
        lambda self, chi, hess, shift, diag: _newton_matrix_by_sparse_products(
            self.p, chi, hess, shift, diag
        ),
    )
    ref = BallStepSolver(p, InnerOptions(linear_solver="direct"))
    ref_jump = ref.solve(0.18, p.z0.copy(), 0.02)
    ref_slip = ref.solve(0.3, ref_jump.z, 0.02)
    assert jump.lam > 0 and p.norm_V(jump.d) == pytest.approx(0.02, rel=1e-10)  # a jump
    for got, want in ((jump, ref_jump), (slip, ref_slip)):
        assert got.converged and want.converged and got.kkt_residual <= got.tolerance
        assert np.abs(got.z - want.z).max() <= 1e-9 * np.abs(want.z).max()
        assert got.lam == pytest.approx(want.lam, rel=1e-8, abs=1e-10)
        assert got.iterations == want.iterations
