"""The inner problem of one RIS step: a ball-constrained, L1-regularized, non-convex minimization.

Step 3 of Alg. 3.2 asks for z_k with

    0 in d(R + I_tau)(z_k - z_{k-1}) + D_z I(t_{k-1}, z_k)                     (3.1)
    I(t_{k-1}, z_k) + R(z_k - z_{k-1}) <= I(t_{k-1}, z_{k-1})                  (3.2)

i.e. a stationary point of J(d) = I(t_{k-1}, z_{k-1} + d) + R(d) on the ball ||d||_V <= tau that
does not increase J. Lemma 4.1 writes (3.1) with a multiplier lambda >= 0:

    g_i + r_i sgn(d_i) + lambda m_i d_i = 0      where d_i != 0,
    |g_i| <= r_i                                 where d_i  = 0,            g = D_z I(t_{k-1}, z)
    lambda (||d||_V - tau) = 0,   ||d||_V <= tau,   lambda >= 0.             (4.1)-(4.4)

Design: the ball is handled *directly*;
we never search over lambda with penalized problems (lambda -> z(lambda) jumps exactly where the
viscous jumps happen). Each iteration

1. predicts the active set (moving nodes and their signs) from a diagonal Newton step on the
   normal map: node i moves iff |y_i| > r_i / D_i with y = d - (g + lambda M d) / D,
   D_i = H_ii + lambda m_i (so a node at rest moves iff |g_i| > r_i);
2. solves the semismooth Newton system on that active set -- off the sphere a plain Newton step,
   on the sphere the bordered system for (d, lambda) *together* with the linearized constraint
   ||d||_V = tau (two solves with one matrix, no lambda search);
3. keeps the iterate feasible (orthant projection onto the predicted signs, radial retraction
   onto the ball) and globalizes with a line search on J, which therefore never increases;
4. falls back to a forward-backward step with the proximal map of R + I_tau in the m-weighted
   inner product -- soft-thresholding followed by radial scaling onto the ball -- whenever the
   Newton candidate does not decrease J (non-convex F, indefinite Hessian) or sends a node that
   starts moving from rest back against its predicted sign where the shifted Hessian has no
   positive curvature along the nodes sent back (Newton aiming at a saddle of the active-set
   problem: projected, that node would never move). Repeated failures
   shift the Hessian by nu*M (Levenberg style), which the solver relaxes again after successes.

The multiplier is read off the converged point: on the sphere, lambda is the least-squares
solution of the stationarity equations over the moving nodes (exact at a KKT point), clamped at 0.

The solver has the init / step / terminate shape: :meth:`BallStepSolver.init` builds the state
at d = 0 (z = z_{k-1}), :meth:`step` does one iteration, :meth:`terminate` returns a result code.
Nothing raises inside the loop: failures become codes and the step is then rejected upstream.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..fem.linear import ReusableSolver, SingularSystem
from ..stepping import interrupt
from ..stepping.results import ResultCode
from .problem import RISProblem

_EPS = np.finfo(float).eps

#: what the three failures of an inner solve most likely mean (one text for the two that say
#: the solver cannot reach stationarity)
_NOT_STATIONARY = (
    "the inner solver cannot reach stationarity: dF or d2F probably does not "
    "belong to F (check_derivatives=True compares them with finite differences)"
)


class RISCode(ResultCode):
    """Result code of one RIS step attempt: the inner solve's outcome (or why there was none).

    The value is the short code stored in trajectories, ``where`` dicts and summaries (a member
    compares equal to it: ``code == "stalled"``); ``message`` says what it means, for the three
    failures of the inner solve the likely cause that a run stopped by them reports
    (:attr:`hint`). A failed solve is never accepted (every controller rejects it).
    """

    RUNNING = "running", "the inner solve is under way"
    CONVERGED = "converged", "the KKT residual of (4.1)-(4.4) fell below the tolerance"
    MAX_ITERATIONS = "max_iterations", _NOT_STATIONARY
    STALLED = "stalled", _NOT_STATIONARY
    NONFINITE = "nonfinite", "F, dF, d2F or the load gave a non-finite value (overflow or NaN)"
    DATA_BEYOND_T = (
        "data_beyond_T",
        (
            "the load cannot be evaluated beyond T, where the attempt "
            "overshot: the step is shortened to land on T"
        ),
    )

    @property
    def successful(self) -> bool:
        """True for :attr:`CONVERGED`."""
        return self is RISCode.CONVERGED

    @property
    def hint(self) -> str | None:
        """The likely cause to report when a run stops after such failures (the message of the
        three failures of the inner solve; None for the other codes)."""
        failures = (RISCode.MAX_ITERATIONS, RISCode.STALLED, RISCode.NONFINITE)
        return self.message if self in failures else None


@dataclass
class InnerOptions:
    """Convergence criteria and limits of the inner solver.

    The stationarity residual (see :func:`kkt_residual`) must fall below
    ``atol + rtol * scale`` with scale = ||r||_{V^-1} + ||D_z I(t, z_{k-1})||_{V^-1}, or below
    the round-off floor of evaluating the gradient, whichever is larger.

    Parameters
    ----------
    atol, rtol : float
        Absolute and relative tolerance of the stationarity residual.
    max_iter : int
        Most Newton iterations of one step.
    max_fb_backtracks : int
        Most backtracking trials (on the constant c) of one forward-backward step.
    linear_solver : {'auto', 'direct', 'amg'}
        The solver of the Newton systems (:class:`~rothe.fem.linear.ReusableSolver`).
    amg_threshold : int, optional
        Unknowns above which ``'auto'`` uses AMG (None: by the fill of A,
        :func:`amg_threshold_for`).
    """

    atol: float = 1e-10
    rtol: float = 1e-10
    max_iter: int = 100
    max_fb_backtracks: int = 60
    linear_solver: str = "auto"
    amg_threshold: int | None = None  # None: by the fill of A, see amg_threshold_for


def amg_threshold_for(problem: RISProblem, options: InnerOptions) -> int:
    """Unknowns above which ``auto`` uses AMG instead of sparse LU.

    Measured on Example 7.2 (benchmarks/ris_2d.py, LU reused across iterations and steps): at
    408k and 998k unknowns in 2D, LU and AMG cost about the same per step (jump: 1.4 vs 2.1 and
    1.3 vs 1.5 LU(A) per accepted step; slip: 1.6 vs 1.0), while at 159k a jump step took 16 s with
    LU and 48 s with AMG. LU fill grows like n log n for 2D-like stencils (<= 10 nonzeros per row:
    2.7 GB peak at 10^6 unknowns) but like n^(4/3) in 3D, so: 400k unknowns for sparse 2D-like
    matrices, 50k otherwise.
    """
    if options.amg_threshold is not None:
        return int(options.amg_threshold)
    A = problem.A
    per_row = A.nnz / max(problem.n, 1) if sp.issparse(A) else problem.n
    return 400_000 if per_row <= 10 else 50_000


@dataclass
class InnerState:
    """The iterate of one inner solve: d = z - z_{k-1}, z, A z, D_z I, J, the multiplier, the
    KKT residual and tolerance, the counters, the Hessian shift nu and the result code."""

    t: float
    zprev: np.ndarray
    tau: float
    d: np.ndarray
    z: np.ndarray
    Az: np.ndarray
    g: np.ndarray
    J: float
    J0: float
    lam: float = 0.0
    kkt: float = np.inf
    tol: float = 0.0
    scale: float = 1.0
    iteration: int = 0
    newton_steps: int = 0
    fb_steps: int = 0
    nu: float = 0.0
    c_fb: float = 1.0
    code: RISCode = RISCode.RUNNING
    hint: np.ndarray | None = None  # a candidate increment (e.g. the previous step's), tried once
    last_alpha: float = 0.0  # damping factor of the last accepted line-search step


@dataclass
class InnerResult:
    """What :meth:`BallStepSolver.solve` returns: z_k, d = z_k - z_{k-1}, the multiplier,
    the result code, the counters and D_z I(t_{k-1}, z_k)."""

    z: np.ndarray
    d: np.ndarray
    lam: float
    converged: bool
    code: RISCode
    iterations: int
    newton_steps: int
    fb_steps: int
    kkt_residual: float
    tolerance: float
    J_start: float
    J_final: float
    gradient: np.ndarray  # D_z I(t_{k-1}, z_k), reused by the residual estimators


def stationarity_defect(problem: RISProblem, d, g, lam) -> np.ndarray:
    """Componentwise defect w of (4.4) with multiplier lam (a vector of nodal functionals)."""
    moving = d != 0.0
    w = np.where(moving, g + problem.r * np.sign(d) + lam * problem.m * d, 0.0)
    rest = ~moving
    w[rest] = np.sign(g[rest]) * np.maximum(np.abs(g[rest]) - problem.r[rest], 0.0)
    return w


def multiplier_on_sphere(problem: RISProblem, d, g) -> float:
    """Least-squares lambda >= 0 for g + r sgn(d) + lambda M d = 0 over the moving nodes.

    Minimizes sum_i (g_i + r_i sgn d_i + lambda m_i d_i)^2 / m_i, i.e. the V^-1 norm of the
    defect: lambda = -sum_i (g_i + r_i sgn d_i) d_i / ||d||_V^2.
    """
    nd2 = float(problem.m @ (d * d))
    if nd2 == 0.0:
        return 0.0
    lam = -float(((g + problem.r * np.sign(d)) * d).sum()) / nd2
    return max(lam, 0.0)


def kkt_residual(problem: RISProblem, d, g, lam, tau) -> float:
    """||w||_{V^-1} + lam * (tau - ||d||_V)_+ : stationarity (4.4) plus complementarity (4.1)."""
    w = stationarity_defect(problem, d, g, lam)
    return problem.norm_Vinv(w) + lam * max(tau - problem.norm_V(d), 0.0)


class _NewtonMatrix:
    """K = S (H + shift*M) S + diag(D_I) on a fixed sparsity pattern, refilled by numpy.

    S = diag(chi) masks the active (moving) nodes; inactive rows and columns are replaced by a
    positive diagonal so the system keeps its size (a preconditioner built for one active set
    stays usable for a neighbouring one). H = A + F''(z) with a diagonal F'' (nodal F) or a
    sparse one (the cell rule of a FERISProblem): both are filled into a fixed CSR pattern by
    numpy, the sparse F'' through the positions of its entries in the union pattern of A and
    F'', computed once per pattern (the cell rule's pattern is fixed per mesh). Assembling
    S (A + F'') S with sparse products instead cost the cell rule 17 of its 70 s on Example
    7.2's 40 x 40 grid (profile in docs/ris_fem.md).
    """

    def __init__(self, problem: RISProblem):
        self.p = problem
        A = problem.A
        if problem.sparse:
            A = sp.csr_matrix(A)
            # make sure every diagonal entry is structurally present
            A = (A + sp.diags(np.zeros(problem.n))).tocsr()
            A.sort_indices()
            self.A = A
            self.rows = np.repeat(np.arange(problem.n), np.diff(A.indptr))
            self.cols = A.indices
            diag_mask = self.rows == self.cols
            self.diag_pos = np.flatnonzero(diag_mask)
            assert np.array_equal(self.rows[self.diag_pos], np.arange(problem.n))
        else:
            self.A = np.asarray(A)

    def build(self, chi: np.ndarray, hess_F, shift: float, inactive_diag: np.ndarray):
        """The Newton matrix on the active set ``chi`` (inactive rows: ``inactive_diag``)."""
        p = self.p
        chif = chi.astype(float)
        general = sp.issparse(hess_F) or np.ndim(hess_F) == 2
        if p.sparse and general:
            H = sp.csr_matrix(hess_F)
            rows, cols, diag_pos, a_data, h_pos, pattern = self._union(H)
            data = a_data + np.bincount(h_pos, weights=H.data, minlength=a_data.size)
            dvals = data[diag_pos] + shift * p.m
            data *= chif[rows] * chif[cols]
            data[diag_pos] = chif * dvals + (1 - chif) * inactive_diag
            # own index arrays: a solver may compact K in place (eliminate_zeros)
            return sp.csr_matrix(
                (data, pattern.indices.copy(), pattern.indptr.copy()), shape=pattern.shape
            )
        if p.sparse:
            K = sp.csr_matrix(
                (self.A.data * (chif[self.rows] * chif[self.cols]), self.A.indices, self.A.indptr),
                shape=self.A.shape,
            )
            dvals = self.A.data[self.diag_pos] + hess_F + shift * p.m
            K.data[self.diag_pos] = chif * dvals + (1 - chif) * inactive_diag
            return K
        H = np.array(self.A, dtype=float)
        if general:
            H = H + (hess_F.toarray() if sp.issparse(hess_F) else np.asarray(hess_F))
        else:
            H[np.diag_indices_from(H)] += hess_F
        K = H * np.outer(chif, chif)
        K[np.diag_indices_from(K)] = chif * (np.diag(H) + shift * p.m) + (1 - chif) * inactive_diag
        return K

    def _union(self, H: sp.csr_matrix):
        """The union pattern of A and ``H`` (cached per pattern of H): its row and column of
        every entry, the positions of the diagonal, A's values scattered into it and the
        positions of H's entries in it."""
        cached = getattr(self, "_union_cache", None)
        if (
            cached is not None
            and np.array_equal(cached[0], H.indptr)
            and np.array_equal(cached[1], H.indices)
        ):
            return cached[2]
        n = self.p.n
        A = self.A
        h_rows = np.repeat(np.arange(n), np.diff(H.indptr))
        U = (
            sp.csr_matrix((np.ones(A.nnz), A.indices, A.indptr), shape=A.shape)
            + sp.csr_matrix((np.ones(H.nnz), (h_rows, H.indices)), shape=A.shape)
        ).tocsr()
        U.sum_duplicates()
        U.sort_indices()
        rows = np.repeat(np.arange(n), np.diff(U.indptr))
        cols = U.indices.astype(np.int64)
        keys = rows * n + cols  # sorted: U is canonical
        a_pos = np.searchsorted(keys, self.rows * n + self.cols)
        h_pos = np.searchsorted(keys, h_rows * n + H.indices)
        a_data = np.zeros(U.nnz)
        a_data[a_pos] = A.data
        diag_pos = np.searchsorted(keys, np.arange(n) * (n + 1))
        entry = (rows, cols, diag_pos, a_data, h_pos, U)
        self._union_cache = (H.indptr.copy(), H.indices.copy(), entry)
        return entry


class BallStepSolver:
    """Damped semismooth Newton for one step (3.1)+(3.2); see the module docstring.

    Parameters
    ----------
    problem : RISProblem
    options : InnerOptions, optional
        Tolerances and limits (default ``InnerOptions()``).
    """

    def __init__(self, problem: RISProblem, options: InnerOptions | None = None):
        self.p = problem
        self.o = options or InnerOptions()
        # a stop signal may abandon the step during a factorization (stepping.interrupt.splu)
        self.linear = ReusableSolver(
            self.o.linear_solver,
            amg_threshold=amg_threshold_for(problem, self.o),
            splu=interrupt.splu,
        )
        self._K = _NewtonMatrix(problem)
        self._hess_cache = None  # (z, F''(z)) of the last iterate asked for
        A = problem.A
        self._absA = abs(A) if problem.sparse else np.abs(A)
        # Lipschitz-type scale of grad(phi) in the m-metric (Gershgorin): start of the FB step
        rowsum = np.asarray(abs(A).sum(axis=1)).ravel()
        self._c_scale = float(np.max(rowsum / problem.m))

    # -- evaluations ---------------------------------------------------------------------------
    def _evaluate(self, t, zprev, d):
        z = zprev + d
        Az = self.p.A @ z
        Fz = self.p.F(z)
        ell = self.p.load(t)
        g = Az + self.p.dF(z) - ell
        J = 0.5 * float(z @ Az) + Fz - float(ell @ z) + self.p.dissipation(d)
        return z, Az, g, J

    def _hessian(self, z):
        """F''(z), kept for the last z: an iteration asks for it up to three times at one iterate
        (the saddle test of the ray to the sphere, the Newton step, the convexifying shift), and
        the cell rule's sparse F'' costs an assembly each time."""
        cached = self._hess_cache
        if cached is not None and np.array_equal(cached[0], z):
            return cached[1]
        h = self.p.d2F(z)
        self._hess_cache = (np.array(z, copy=True), h)
        return h

    def _hess_diag(self, z, hess_F):
        if sp.issparse(hess_F) or np.ndim(hess_F) == 2:
            return self.p.A_diag + np.asarray(
                hess_F.diagonal() if sp.issparse(hess_F) else np.diag(hess_F)
            )
        return self.p.A_diag + hess_F

    def _convexifying_shift(self, z) -> float:
        """max(0, -min_i F''_ii / m_i) (for a general F'' from its diagonal: the consistent
        quadrature of a FERISProblem, whose F'' is mass-like)."""
        h = self._hessian(z)
        if sp.issparse(h) or np.ndim(h) == 2:
            h = np.asarray(h.diagonal() if sp.issparse(h) else np.diag(h))
        return float(max(0.0, np.max(-h / self.p.m)))

    def _apply_H(self, hess_F, v):
        out = self.p.A @ v
        if sp.issparse(hess_F) or np.ndim(hess_F) == 2:
            return out + np.asarray(hess_F @ v).ravel()
        return out + hess_F * v

    # -- init / step / terminate --------------------------------------------------------------
    def init(self, t: float, zprev: np.ndarray, tau: float, hint=None, start=None) -> InnerState:
        """State at d = 0 (z = z_{k-1}). ``hint``: an increment tried as the first candidate.

        The iteration always starts at z_{k-1} (it must: from there descent finds the stationary
        point "nearest" the previous state). A hint -- typically the previous accepted step scaled
        to the new tau -- is only a line-search candidate of the first iteration, taken if it
        lowers J; in a viscous jump it replaces a useless Newton step with the indefinite Hessian
        at the start of the step by a point on the sphere with a good multiplier.

        ``start``: an increment to start from instead of 0 (scaled into the ball), for a solve
        that must find the stationary point nearest a given point rather than the one nearest
        z_{k-1}: the relaxation of a transferred state (:mod:`rothe.ris.adapt`). J never
        increases from J(start) then.
        """
        d = np.zeros_like(zprev)
        if start is not None:
            d = np.array(start, dtype=float)
            nd0 = self.p.norm_V(d)
            if nd0 > tau:
                d *= tau / nd0
        z, Az, g, J = self._evaluate(t, zprev, d)
        p = self.p
        scale = p.norm_Vinv(p.r) + p.norm_Vinv(g)
        # round-off floor of evaluating g (sum of absolute contributions), in the V^-1 norm
        floor_terms = (self._absA @ np.abs(z)) + np.abs(p.dF(z)) + np.abs(p.load(t)) + np.abs(g)
        floor = 64 * _EPS * p.norm_Vinv(floor_terms)
        tol = max(self.o.atol + self.o.rtol * scale, floor)
        st = InnerState(
            t=t, zprev=zprev, tau=tau, d=d, z=z, Az=Az, g=g, J=J, J0=J, tol=tol, scale=scale
        )
        # forward-backward backtracking starts from a long step (small c): it reaches the sphere
        # at once when the ball is active, and halves the step from there otherwise
        st.c_fb = max(1e-4 * self._c_scale, 1e-12)
        if start is not None:
            self._set_multiplier(st)
        else:
            st.kkt = kkt_residual(p, d, g, 0.0, tau)
        if hint is not None and np.any(hint):
            h = np.asarray(hint, dtype=float).copy()
            nh = p.norm_V(h)
            if nh > tau:
                h *= tau / nh
            st.hint = h
        return st

    def terminate(self, st: InnerState) -> tuple[bool, RISCode]:
        """(done, code): converged, out of iterations, or a failure set by :meth:`step`."""
        if st.code is not RISCode.RUNNING:
            return True, st.code
        if st.kkt <= st.tol:
            st.code = RISCode.CONVERGED
            return True, st.code
        if st.iteration >= self.o.max_iter:
            st.code = RISCode.MAX_ITERATIONS
            return True, st.code
        return False, st.code

    def step(self, st: InnerState) -> InnerState:
        """One iteration: Newton candidate with line search on J, else a forward-backward step."""
        p = self.p
        st.iteration += 1
        if st.hint is not None:
            hint, st.hint = st.hint, None
            sphere = p.norm_V(hint) >= st.tau * (1 - 1e-12)
            if self._line_search(st, hint, None, sphere=sphere, full_only=True):
                return st
        nd = p.norm_V(st.d)
        if 0.0 < nd < st.tau * (1 - 1e-12) and self._ray_to_sphere(st, nd):
            return st
        on_sphere = nd >= st.tau * (1 - 1e-12) and st.lam > 0
        kkt_before = st.kkt
        accepted = self._newton_step(st, on_sphere)
        if accepted:
            st.newton_steps += 1
            if st.last_alpha == 1.0 and st.kkt <= 0.5 * kkt_before:
                st.nu = 0.0  # the true Hessian works here: quadratic convergence from now on
            else:
                st.nu *= 0.5
        else:
            # shift the Hessian by nu*M: at least the amount that makes A + F'' + nu*M >= A >= 0
            st.nu = min(
                max(2 * st.nu, self._convexifying_shift(st.z), 1e-3 * self._c_scale),
                1e6 * self._c_scale,
            )
            if not self._fb_step(st):
                st.code = RISCode.STALLED
                return st
            st.fb_steps += 1
        if not (np.isfinite(st.J) and np.all(np.isfinite(st.d))):
            st.code = RISCode.NONFINITE
        return st

    def _ray_to_sphere(self, st: InnerState, nd: float) -> bool:
        """Leave a saddle at once: from an iterate d inside the ball with negative curvature
        d.H d < 0 along it, try d tau / ||d||_V (a line-search candidate, taken if it lowers J).

        With negative curvature and a descending linear part, J decreases along the whole ray
        from 0 through d, so its minimum in the ball lies on the sphere. The case: the first step
        of a viscous jump started just past the end of sticking, where the excess of |D_z I| over
        r is tiny and the iterates escape z_{k-1} by a factor 3-6 in ||d|| per iteration (7 of
        the 10 iterations of such a step on 160 x 160). In slip the curvature along d is positive
        and nothing is tried.
        """
        hess_F = self._hessian(st.z)
        if float(st.d @ self._apply_H(hess_F, st.d)) >= 0.0:
            return False
        cand = st.d * (st.tau / nd)
        return self._line_search(st, cand, None, sphere=True, full_only=True)

    def solve(self, t: float, zprev: np.ndarray, tau: float, hint=None, start=None) -> InnerResult:
        """The step (3.1)-(3.2) from ``zprev`` at time ``t`` on the ball of radius ``tau``
        (``hint``: a candidate increment tried once, e.g. the previous step's; ``start``: the
        first iterate, e.g. a transferred state to relax).

        After every iteration (one Newton system: a factorization or Krylov solves, and its
        line search) a stop signal abandons the attempt of the evolve loop
        (:func:`rothe.stepping.interrupt.check`; nothing happens outside one)."""
        st = self.init(t, zprev, tau, hint, start)
        while True:
            done, code = self.terminate(st)
            if done:
                break
            self.step(st)
            interrupt.check()
        return self._result(st)

    # -- pieces -------------------------------------------------------------------------------
    def _set_multiplier(self, st: InnerState) -> None:
        p = self.p
        if p.norm_V(st.d) >= st.tau * (1 - 1e-10):
            st.lam = multiplier_on_sphere(p, st.d, st.g)
        else:
            st.lam = 0.0
        st.kkt = kkt_residual(p, st.d, st.g, st.lam, st.tau)

    def _accept(self, st: InnerState, d, z, Az, g, J) -> None:
        st.d, st.z, st.Az, st.g, st.J = d, z, Az, g, J
        self._set_multiplier(st)

    def _newton_step(self, st: InnerState, on_sphere: bool) -> bool:
        p = self.p
        d, g, lam, tau = st.d, st.g, (st.lam if on_sphere else 0.0), st.tau
        hess_F = self._hessian(st.z)
        hdiag = self._hess_diag(st.z, hess_F)
        # 1. active-set prediction by a diagonal Newton step on the normal map
        # D_i must be a meaningful positive scale: where the curvature along coordinate i is
        # negative, a clamped near-zero D_i turns a 1e-7 stationarity defect into an active-set
        # flip of a moving node at every iteration (a stall found by hypothesis, seed 374)
        Dg = np.maximum(hdiag + lam * p.m, 1e-2 * self._c_scale * p.m)
        y = d - (g + lam * p.m * d) / Dg
        active = np.abs(y) > p.r / Dg
        if not np.any(active):
            # every node at rest: the step is d = 0 (sticking) when that is stationary
            if np.any(d != 0):
                cand = np.zeros_like(d)
                return self._line_search(st, cand, None)
            return False
        sigma = np.sign(y) * active
        inactive = ~active
        # 2. Newton system on the active set (inactive nodes are sent to zero: delta_I = -d_I)
        shift = lam + st.nu
        inactive_diag = np.where(Dg > 0, Dg, 1.0)
        dI = np.where(inactive, d, 0.0)
        HdI = self._apply_H(hess_F, dI) if np.any(dI) else np.zeros_like(d)
        G = g + p.r * sigma + lam * p.m * d
        b = np.where(active, -G + HdI, -inactive_diag * d)
        try:
            if on_sphere:
                w = np.where(active, p.m * d, 0.0)
                pvec, qvec = self._solve_newton(
                    active, hess_F, shift, inactive_diag, [b, w], self._lin_rtol(st)
                )
                nd = p.norm_V(d)
                wq = float(w @ qvec)
                if not np.isfinite(wq) or abs(wq) <= 1e-14 * max(
                    float(w @ w) / max(Dg.max(), 1e-300), 1e-300
                ):
                    return False
                mI = float((p.m * dI * dI).sum())
                dlam = (float(w @ pvec) - mI - nd * (tau - nd)) / wq
                delta = pvec - dlam * qvec
                lam_new = lam + dlam
            else:
                (delta,) = self._solve_newton(
                    active, hess_F, shift, inactive_diag, [b], self._lin_rtol(st)
                )
                lam_new = 0.0
        except SingularSystem:
            return False
        if not np.all(np.isfinite(delta)):
            return False
        delta[inactive] = -d[inactive]
        # 3. feasibility: orthant of the predicted signs, then the ball
        trial = d + delta
        wrong = np.sign(trial) != sigma
        sent_back = wrong & active & (d == 0.0)
        if np.any(sent_back) and not self._positive_curvature(
            hess_F, hdiag, shift, sent_back, delta
        ):
            # a node the prediction sets moving from rest (|g_i| > r_i: moving it along sigma_i
            # lowers J) is sent back against sigma_i, and the shifted Hessian has no positive
            # curvature along those nodes: Newton aims at a saddle. Projected, that node stays
            # at rest for good and the others creep (random_problem(57242, 3), found by
            # hypothesis: 100 iterations, J falling by 1e-5 each, KKT residual constant).
            # Refuse the candidate, so that the shift nu M grows and the forward-backward step
            # moves the node. With positive curvature the sign flip is the ordinary semismooth
            # case (the coupling overruled the diagonal prediction): the orthant projection and
            # the next prediction settle it, and refusing there cost the 640 x 640 slip phase
            # 3x its Newton iterations in forward-backward steps.
            return False
        trial[wrong] = 0.0
        nt = p.norm_V(trial)
        retracted = False
        if on_sphere and lam_new > 0 and nt > 0:
            trial *= tau / nt
            sphere = True
        else:
            sphere = False
            if nt > tau:
                trial *= tau / nt
                sphere = retracted = True
        if self._line_search(st, trial, hess_F, sphere=sphere):
            return True
        # a Newton point outside the ball, retracted onto the sphere, from an iterate inside
        # it: the shorter trials retracted onto the sphere too are all the same point when
        # d = 0, while the minimizer may lie inside the ball (a wrong first active-set
        # prediction; convex_problem(1882, 4), tau = 1.25, found by hypothesis: a
        # forward-backward step). Then the chord from d to the retracted point, inside the
        # ball, before giving up; tried only where the sphere's trials failed, so every step
        # that succeeded before is unchanged
        if retracted and p.norm_V(d) < tau * (1 - 1e-12):
            return self._line_search(st, trial, hess_F, sphere=False)
        return False

    def _positive_curvature(self, hess_F, hdiag, shift, nodes, delta) -> bool:
        """Whether H + shift*M (H = A + F''(z)) curves upwards along the given nodes.

        Both K_ii = H_ii + shift m_i > 0 at each node and v.(H + shift M) v > 0 for v = delta
        restricted to the nodes (one product with H, paid only when a node is sent back).
        """
        m = self.p.m
        if np.any(hdiag[nodes] + shift * m[nodes] <= 0.0):
            return False
        v = np.where(nodes, delta, 0.0)
        curvature = float(v @ self._apply_H(hess_F, v)) + shift * float((m * v * v).sum())
        return bool(np.isfinite(curvature) and curvature > 0.0)

    def _solve_newton(self, active, hess_F, shift, inactive_diag, rhs, rtol):
        """Solve the active-set Newton system K x = b for each b in ``rhs`` (full-length vectors).

        K = S (A + F'' + shift M) S + diag(inactive_diag) (I - S), S = diag(active).

        Direct path (and dense problems): K at full size, so the LU of one active set stays a
        good preconditioner for neighbouring ones (GMRES absorbs the low-rank difference).
        AMG path: the system reduced to the active set, K_AA = A_AA + diag(c) with
        c = F''_A + shift m_A; the hierarchy is built from the SPD surrogate A_AA + diag(c_+)
        (A_AA is a principal submatrix of the SPD A), CG runs when K_AA is that surrogate
        (c >= 0, e.g. in slip) and GMRES when K_AA is indefinite (e.g. at a viscous jump);
        the hierarchy is reused until the active set changes or the iterations grow.
        """
        p = self.p
        general = sp.issparse(hess_F) or np.ndim(hess_F) == 2
        kind = self.linear.resolve_kind(p.n) if p.sparse else "dense"
        if kind != "amg" or general:
            K = self._K.build(active, hess_F, shift, inactive_diag)
            return self.linear.solve(K, rhs, rtol=rtol)
        idx = np.flatnonzero(active)
        A_AA = self._reduced_A(active, idx)
        c = hess_F[idx] + shift * p.m[idx]
        K_AA = (A_AA + sp.diags(c)).tocsr()
        spd = bool(c.min() >= 0)
        surrogate = K_AA if spd else (A_AA + sp.diags(np.maximum(c, 0.0))).tocsr()
        sols = self.linear.solve(
            K_AA, [b[idx] for b in rhs], rtol=rtol, key=active, surrogate=surrogate, spd=spd
        )
        out = []
        for b, x_A in zip(rhs, sols, strict=True):
            x = b / inactive_diag  # inactive rows: diag(inactive_diag) x_I = b_I
            x[idx] = x_A
            out.append(x)
        return out

    def _reduced_A(self, active, idx):
        cached = getattr(self, "_A_reduced", None)
        if cached is not None and np.array_equal(cached[0], active):
            return cached[1]
        A_AA = sp.csr_matrix(self.p.A)[idx][:, idx].tocsr()
        self._A_reduced = (active.copy(), A_AA)
        return A_AA

    def _line_search(
        self, st: InnerState, cand, hess_F, sphere: bool = False, full_only: bool = False
    ) -> bool:
        """Line search along d -> cand (retracting onto the sphere when it is active)."""
        p = self.p
        d = st.d
        noise = 1e-13 * (abs(st.J) + abs(st.J0) + 1.0)
        step = cand - d

        def predicted_decrease(trial):
            # decrease of the model J(d) + g.s + s.H s / 2 + R(d + s) - R(d) at s = trial - d
            s = trial - d
            quad = float(s @ self._apply_H(hess_F, s)) if hess_F is not None else 0.0
            return -(float(st.g @ s) + 0.5 * quad + p.dissipation(trial) - p.dissipation(d))

        for alpha in (1.0,) if full_only else (1.0, 0.5, 0.25):
            trial = d + alpha * step if alpha < 1 else cand
            if sphere and alpha < 1:
                nt = p.norm_V(trial)
                if nt > 0:
                    trial = trial * (st.tau / nt)
            z, Az, g, J = self._evaluate(st.t, st.zprev, trial)
            if not np.isfinite(J):
                continue
            # a real predicted decrease is required: a step that only "decreases" J by
            # round-off (e.g. a Newton step cancelled by the orthant projection) is a stall.
            # It is the model's decrease at *this* trial: a projected or retracted Newton point
            # can overshoot (the model rises again towards it) along a descent direction, and
            # the full step's prediction refused the shorter trials that decrease J (two convex
            # problems took forward-backward steps so, found by hypothesis)
            pred = predicted_decrease(trial)
            if pred > noise and J < st.J and J <= st.J - 1e-4 * pred:
                self._accept(st, trial, z, Az, g, J)
                st.last_alpha = alpha
                return True
            if abs(J - st.J) <= noise:
                # J is flat to round-off (near convergence): accept if stationarity improves
                on = p.norm_V(trial) >= st.tau * (1 - 1e-10)
                lam = multiplier_on_sphere(p, trial, g) if on else 0.0
                if kkt_residual(p, trial, g, lam, st.tau) < 0.5 * st.kkt:
                    self._accept(st, trial, z, Az, g, J)
                    st.last_alpha = alpha
                    return True
        return False

    def _fb_step(self, st: InnerState) -> bool:
        """Forward-backward step d+ = prox(d - g/(c m)) with backtracking on c.

        prox of R + I_tau in the (c m)-weighted inner product: soft-threshold with r/(c m), then
        scale radially onto the ball. Sufficient decrease J(d+) <= J(d) - 1e-4 c ||d+ - d||_m^2.
        """
        p = self.p
        c = max(st.c_fb / 2, 1e-12)
        for _ in range(self.o.max_fb_backtracks):
            y = st.d - st.g / (c * p.m)
            s = np.sign(y) * np.maximum(np.abs(y) - p.r / (c * p.m), 0.0)
            ns = p.norm_V(s)
            if ns > st.tau:
                s *= st.tau / ns
            step = s - st.d
            ms = float(p.m @ (step * step))
            if ms == 0.0:
                return False
            z, Az, g, J = self._evaluate(st.t, st.zprev, s)
            if np.isfinite(J) and J <= st.J - 1e-4 * c * ms:
                st.c_fb = c
                self._accept(st, s, z, Az, g, J)
                return True
            c *= 2.0
        return False

    def _lin_rtol(self, st: InnerState) -> float:
        """Forcing term of the inexact Newton method (Eisenstat-Walker type).

        eta = min(1e-2, kkt/scale) gives superlinear convergence; it is never looser than needed
        for the last step to land below the tolerance (eta * kkt <= tol / 10).
        """
        eta = min(1e-2, st.kkt / st.scale)
        eta = max(eta, 0.1 * st.tol / max(st.kkt, 1e-300))
        return float(np.clip(eta, 1e-12, 1e-2))

    def _result(self, st: InnerState) -> InnerResult:
        converged = st.code is RISCode.CONVERGED
        return InnerResult(
            z=st.z,
            d=st.d,
            lam=st.lam,
            converged=converged,
            code=st.code,
            iterations=st.iteration,
            newton_steps=st.newton_steps,
            fb_steps=st.fb_steps,
            kkt_residual=st.kkt,
            tolerance=st.tol,
            J_start=st.J0,
            J_final=st.J,
            gradient=st.g,
        )
