"""Linear solvers for the Euler steps: one factorization (or AMG setup) reused for the whole run.

Every step of the scheme solves a system with the same matrix when the damping is linear,
A = (rho/tau^2) M + C/tau + K (restricted to ker B in the regularized form, bordered by B in the
original one), so it is factored once and each step is a back-substitution (measured with
``python benchmarks/eld_peers.py``, 3D P1 beam, 56,355 dofs: SuperLU factorization 38 s, a step
0.24-0.30 s; ``python benchmarks/eld.py --part steps``: a linear step costs 1.0-2.2
back-substitutions, see docs/eld.md). With nonlinear damping the Newton
matrices J = A + N'(v)/tau stay close to A: they are solved by a Krylov method preconditioned with
the stored factorization of a reference matrix, which is rebuilt from the current J only when the
Krylov method needs more than ``max_krylov`` iterations.

Kinds:
- ``direct``: scipy ``splu`` with the symmetric ``MMD_AT_PLUS_A`` ordering; Krylov = CG for SPD
  matrices, GMRES for the saddle-point matrices of the original form;
- ``amg``: pyamg smoothed aggregation with the rigid-body modes as near-null space (the
  aggregation must reproduce the kernel of the elasticity operator on the coarse levels: Vanek,
  Mandel & Brezina, Computing 56 (1996) 179-196), CG accelerated. SPD matrices only. The
  hierarchy is built for the symmetrically Jacobi-scaled matrix D^{-1/2} A D^{-1/2}
  (:func:`jacobi_scaled`): pyamg's Chebyshev smoother is a polynomial in the matrix itself,
  tuned to its largest eigenvalue, so on a graded mesh, whose diagonal spans the cell volumes
  (a step matrix (rho/tau^2) M + K of an adaptive 3D P2 mesh: diagonal from 0.19 to 21), it
  smooths only the dofs of the largest diagonal entries: CG needed 72 V-cycles for rtol
  1e-10 on such a 13 626-dof matrix, 12 with the scaling (11 either way on the uniform
  n = 16 mesh, whose diagonal spans 0.10-0.86; docs/adaptivity.md).
- ``jacobi`` (chosen by 'auto' only, on the 3D meshes of a space-adaptive run whose CFL number
  is moderate, :func:`resolve_kind`): CG preconditioned by the diagonal, no setup beyond the
  diagonal and no hierarchy. The step matrix (rho/tau_eff^2) M + K scaled by its diagonal has
  a condition number bounded by the CFL number c_p tau_eff / h_min (mass-dominated), not by
  the number of unknowns, so the iterations stay bounded under refinement
  (docs/adaptivity.md: 43 per solve on average, at most 57, on the eld3d pulse).
"""

from __future__ import annotations

import time
from contextlib import nullcontext
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import fail
from ..fem.linear import reproducible_random, v_cycle
from ..stepping import interrupt
from ..stepping.evolve import single_threaded_blas
from ..timing import PhaseTimes

SOLVERS = ("auto", "direct", "amg")

#: pyamg smoothed aggregation settings (see the module docstring for why)
AMG_DEFAULTS = dict(
    max_coarse=500,
    coarse_solver="splu",
    improve_candidates=None,
    smooth=("jacobi", {"omega": 4.0 / 3.0, "weighting": "block"}),
    presmoother=("chebyshev", {"degree": 3}),
    postsmoother=("chebyshev", {"degree": 3}),
)

#: the AMG of a short-lived mesh (a space-adaptive run's, ``ELDSystem(short_lived=True)``):
#: plain aggregation, no prolongator smoothing. Its setup is a tenth of the smoothed one's (the
#: Jacobi smoothing of the tentative prolongator and its spectral radius estimate), and on the
#: mass-dominated step matrices of such runs CG needs as many V-cycles: on a 13 626-dof
#: matrix of the eld3d pulse (scaled, rtol 1e-10) setup 0.026 s and 12 cycles in 0.35 s,
#: against 0.30 s and 11 cycles in 0.46 s (docs/adaptivity.md).
SHORT_LIVED_AMG = {"smooth": None}


#: 'auto' takes CG with the Jacobi preconditioner (kind ``jacobi``) on a short-lived 3D mesh
#: above the LU limit when its CFL number c_p tau_eff / h_min (:func:`resolve_kind`) is at most
#: this; AMG above
JACOBI_CFL = 2.0
#: the iterations of a Jacobi-CG solve before it gives up (:class:`SolveFailed`)
JACOBI_MAXITER = 1000


#: how GAMG forms its coarse operators P^T A P (``amg_products``): ``fast`` is PETSc's default
#: two-step product, which stores A P on every process (on MPI the set-up's peak: about 1.3 KB
#: per owned dof above what the hierarchy keeps); ``lean`` PETSc's all-at-once product
#: (``-matptap_via allatonce``), which never forms A P: 0.76x the peak memory per process on
#: the 1.07 M-dof beam at N = 2, for a set-up 5-7x slower (docs/scaling.md, "--amg-products";
#: the all-at-once product on the finest level only: half that set-up, a peak 15-40 MB
#: higher, not taken: eighth session)
AMG_PRODUCTS = ("fast", "lean")


@dataclass
class SolverStats:
    """Counters of a linear solver: factorizations (LU or AMG setups; for Jacobi-CG the
    reference and its diagonal taken), backsolves (applications of the stored factorization,
    V-cycles or Jacobi-CG iterations), Krylov iterations, systems solved and setup seconds.
    """

    factorizations: int = 0  # LU factorizations, AMG setups or Jacobi references
    backsolves: int = 0  # applications of the stored factorization / V-cycles / CG iterations
    krylov_iterations: int = 0
    solves: int = 0  # systems solved
    setup_seconds: float = 0.0


def jacobi_scaled(A):
    """(D^{-1/2} A D^{-1/2}, D^{-1/2} as a vector) for a BSR or CSR matrix A with a positive
    diagonal D; a BSR matrix stays BSR of its own class (a
    :class:`~rothe.fem.elasticity.BlockMatrix` keeps its compiled product, the AMG cycle's main
    cost at scale) with the same blocks and pattern (the values d_i^{-1/2} a_ij d_j^{-1/2}
    block by block, vectorized)."""
    s = 1.0 / np.sqrt(A.diagonal())
    if A.format == "bsr":
        r, c = A.blocksize
        rows = np.repeat(np.arange(A.shape[0] // r), np.diff(A.indptr))
        data = A.data * s.reshape(-1, r)[rows][:, :, None] * s.reshape(-1, c)[A.indices][:, None, :]
        return type(A)((data, A.indices, A.indptr), shape=A.shape), s
    A = sp.csr_matrix(A)
    rows = np.repeat(np.arange(A.shape[0]), np.diff(A.indptr))
    data = A.data * s[rows] * s[A.indices]
    return sp.csr_matrix((data, A.indices, A.indptr), shape=A.shape), s


class SolveFailed(RuntimeError):
    """The Krylov method did not converge even with a fresh preconditioner."""


def scaled_cg(op, s: np.ndarray, b: np.ndarray, x0, rtol: float, maxiter: int, M=None):
    """(x, iterations) of scipy's CG on the scaled system S A S y = S b, x = S y (``op``
    applies S A S, ``s`` the diagonal of S = D^{-1/2}, ``M`` an optional preconditioner of
    S A S): it stops when ||S (b - A x)|| <= rtol ||S b||. (None, iterations) if it did not
    converge or x is not finite."""
    count = [0]

    def cb(_):
        count[0] += 1

    y0 = None if x0 is None else np.asarray(x0, dtype=float) / s
    y, info = spla.cg(op, s * b, x0=y0, rtol=rtol, atol=0.0, maxiter=maxiter, M=M, callback=cb)
    if info != 0 or not np.all(np.isfinite(y)):
        return None, count[0]
    return s * y, count[0]


def jacobi_cg(A, inv_diag: np.ndarray, b: np.ndarray, x0, rtol: float, maxiter: int):
    """(x, iterations) of CG for the SPD system A x = b preconditioned by the diagonal;
    (None, maxiter) if it did not converge.

    :func:`scaled_cg` with S = D^{-1/2} (the iterates of Jacobi-preconditioned CG), S A S
    applied as an operator (no scaled copy of A): it stops when
    ||D^{-1/2} r|| <= rtol ||D^{-1/2} b||, the AMG path's stopping rule."""
    s = np.sqrt(inv_diag)
    op = spla.LinearOperator(A.shape, matvec=lambda y: s * (A @ (s * y)), dtype=float)
    return scaled_cg(op, s, b, x0, rtol, maxiter)


#: 'auto' takes sparse LU up to this many unknowns, AMG above: 2D, 3D, and 3D meshes of a
#: space-adaptive run (``short_lived``)
LU_LIMITS = {2: 200_000, 3: 30_000, "3-short": 1_500}


def resolve_kind(
    kind: str, n: int, dim: int, short_lived: bool = False, cfl: float | None = None
) -> str:
    """'auto': sparse LU in 2D up to 200k unknowns and in 3D up to 30k, AMG above; in 3D on
    the meshes a space-adaptive run builds (``short_lived``) LU only up to 1.5k, above it
    Jacobi-CG (``jacobi``) when the mesh's CFL number ``cfl`` = c_p tau_eff / h_min is at most
    :data:`JACOBI_CFL`, else AMG.

    3D LU fill grows fast: ``python benchmarks/eld_peers.py`` measured SuperLU at 56,355 dofs
    (P1 beam, N = 16) at 38 s and 0.98 GB peak, while the AMG setup of the 1,075,275-dof beam
    took 18 s at 2.6 GB peak (docs/eld.md, "Linear algebra and scale"). A mesh of an adaptive
    run lives ``adapt_every`` steps, so its LU is not amortized: on the 3D P2 pulse
    (``benchmarks/space_adaptivity.py --family eld3d``) the LU of meshes up to 15k unknowns
    was 11.5 of the 15.3 s of a run and its fill the run's peak memory; with AMG from 5k on
    the run took 14.3 s, 353 instead of 536 MB (docs/adaptivity.md). Since such meshes get the
    Jacobi-scaled plain-aggregation AMG (:data:`SHORT_LIVED_AMG`, setup ~0.03 s at 13k) the
    LUs of the meshes between 1.5k and 5k (0.1-0.4 s each, a dozen per run) cost more than
    its solves: the limit went down to 1.5k (the tol 6e-3 run: CPU 8.3 -> 7.9 s, peak
    387 -> 348 MB, measured on loaded cores).
    """
    if kind not in SOLVERS:
        raise fail("solver", kind, "must be one of " + ", ".join(SOLVERS))
    if kind != "auto":
        return kind
    limit = LU_LIMITS[dim if dim == 2 or not short_lived else "3-short"]
    if n <= limit:
        return "direct"
    if dim == 3 and short_lived and cfl is not None and cfl <= JACOBI_CFL:
        return "jacobi"
    return "amg"


class ReferenceSolver:
    """Solve A x = b for matrices A close to a reference one, reusing its factorization.

    Parameters
    ----------
    kind : 'direct' | 'amg' | 'jacobi'
    spd : bool
        The matrices are symmetric positive definite (CG) or not (GMRES; direct only).
    near_nullspace : ndarray, optional
        For AMG: the rigid-body modes on the unknowns of the system.
    rtol : float
        Relative residual of Krylov solves (and of AMG solves with the reference matrix).
    max_krylov : int
        Rebuild the reference from the current matrix when a solve needs more iterations.
    times : PhaseTimes, optional
        Where the factorizations (and AMG setups) are timed, as phase ``factor``.
    symmetric_lu : bool
        Direct and SPD: SuperLU in its symmetric mode (diagonal pivots, the ordering of
        A + A^T): the same fill, 40 % less time per factorization (measured: 7.7k unknowns,
        P2 in 2D, 68 vs 111 ms), results equal to round-off but not bit for bit to the default
        mode. Space-adaptive runs use it (one factorization per mesh); fixed-mesh runs keep the
        default mode.
    """

    def __init__(
        self,
        kind: str = "direct",
        spd: bool = True,
        near_nullspace=None,
        rtol: float = 1e-10,
        max_krylov: int = 20,
        amg_options: dict | None = None,
        times: PhaseTimes | None = None,
        symmetric_lu: bool = False,
    ):
        if kind not in ("direct", "amg", "jacobi"):
            raise fail("solver", kind, "must be direct, amg or jacobi")
        if kind in ("amg", "jacobi") and not spd:
            raise fail(
                "solver",
                kind,
                "needs a symmetric positive definite system; the original "
                "form's saddle-point system is solved by sparse LU (use solver='direct')",
            )
        self.times = times
        self.kind = kind
        self.spd = spd
        self.symmetric_lu = bool(symmetric_lu) and spd
        self.near_nullspace = near_nullspace
        self.rtol = rtol
        self.max_krylov = max_krylov
        self.amg_options = dict(amg_options or {})
        self.stats = SolverStats()
        self._A = None
        self._prec = None
        self._ml = None
        self._scale = None  # D^{-1/2} of the AMG reference (jacobi_scaled)

    # -- reference ------------------------------------------------------------------------------
    def factor(self, A) -> None:
        """Factor (or set up AMG for) the reference matrix A (single-threaded BLAS: the dense
        coarse-level factorization took 1.1 s instead of 0.05 s with threads on 2 busy cores)."""
        timed = self.times.phase("factor") if self.times is not None else nullcontext()
        with single_threaded_blas(), timed:
            self._factor(A)

    def _factor(self, A) -> None:
        t0 = time.perf_counter()
        self.stats.factorizations += 1
        if self.kind == "direct":
            options = {"SymmetricMode": True} if self.symmetric_lu else {}
            # a stop signal may abandon the step during the factorization (interrupt.splu)
            lu = interrupt.splu(sp.csc_matrix(A), permc_spec="MMD_AT_PLUS_A", options=options)
            self._prec = lu.solve
            self._ml = None
        elif self.kind == "jacobi":
            # no setup: the inverse diagonal (the preconditioner) and A itself (by reference)
            if not (sp.issparse(A) and A.format in ("bsr", "csr")):
                A = sp.csr_matrix(A)
            inv = 1.0 / A.diagonal()
            self._scale = inv
            self._prec = lambda r: inv * r
            self._ml = None
        else:
            import pyamg  # heavy: imported when first needed (start-up time)

            # BSR (d x d blocks) is kept: pyamg then aggregates nodes, not single components
            if not (sp.issparse(A) and A.format in ("bsr", "csr")):
                A = sp.csr_matrix(A)
            # the hierarchy of D^{-1/2} A D^{-1/2} (module docstring); its near-null space is
            # D^{1/2} times A's
            As, scale = jacobi_scaled(A)
            B = None
            if self.near_nullspace is not None:
                B = np.asarray(self.near_nullspace) / scale[:, None]
            opts = dict(AMG_DEFAULTS)
            opts.update(self.amg_options)
            with reproducible_random():  # pyamg draws random start vectors: repeatable runs
                self._ml = pyamg.smoothed_aggregation_solver(As, B=B, **opts)
            # the coarse solver factors lazily on its first call: do it here, in the setup,
            # not in the first time step
            coarse = self._ml.levels[-1].A
            self._ml.coarse_solver(coarse, np.zeros(coarse.shape[0]))
            self._scale = scale
            ml = self._ml
            # the preconditioner of A itself: D^{-1/2} (V-cycle of the scaled matrix) D^{-1/2}
            self._prec = lambda r: scale * v_cycle(ml, scale * r)
        self._A = A
        self.stats.setup_seconds += time.perf_counter() - t0

    # -- undoing an abandoned step ------------------------------------------------------------
    def snapshot(self, stored: bool = True) -> dict:
        """What factorizations and solves change: the stored reference (by reference: a
        refactorization replaces it, nothing changes it in place) and a copy of the counters.
        :meth:`rollback` puts it back when a step is abandoned (:meth:`ELDStepper.abandon`).
        ``stored=False``: the counters only (the reference is not kept alive by the snapshot:
        a space-adaptive run releases the systems it leaves, :meth:`release`)."""
        return {
            "stored": (self._A, self._prec, self._ml, self._scale) if stored else None,
            "stats": replace(self.stats),
        }

    def rollback(self, state: dict) -> None:
        """Put back what :meth:`snapshot` returned (the stored reference only if it holds one)."""
        if state["stored"] is not None:
            self._A, self._prec, self._ml, self._scale = state["stored"]
        self.stats = replace(state["stats"])

    def release(self) -> None:
        """Drop the stored reference (matrix, factorization or AMG hierarchy); the counters
        stay. The solver cannot solve until it is factored again."""
        self._A = self._prec = self._ml = self._scale = None

    @property
    def factored(self) -> bool:
        """Whether a reference factorization (or AMG hierarchy) is stored."""
        return self._prec is not None

    def solve_reference(self, b: np.ndarray, x0=None) -> np.ndarray:
        """x = A_ref^{-1} b: one back-substitution (direct), AMG-CG or Jacobi-CG to rtol.

        AMG: CG on the scaled system D^{-1/2} A D^{-1/2} y = D^{-1/2} b, x = D^{-1/2} y, so the
        relative residual rtol is that of the D^{-1/2}-weighted residual,
        ||D^{-1/2} (b - A x)|| <= rtol ||D^{-1/2} b||; Jacobi-CG (:func:`jacobi_cg`) stops on
        the same residual (its iterates are those of CG on the scaled system)."""
        self.stats.solves += 1
        if self.kind == "direct":
            self.stats.backsolves += 1
            return self._prec(b)
        if self.kind == "jacobi":
            method, cap = "Jacobi-CG", JACOBI_MAXITER
            x, its = jacobi_cg(self._A, self._scale, b, x0, self.rtol, cap)
        else:  # the hierarchy's fine level is the scaled matrix itself
            method, cap = "AMG-CG", 500
            ml = self._ml
            shape = ml.levels[0].A.shape
            M = spla.LinearOperator(shape, matvec=lambda r: v_cycle(ml, r), dtype=float)
            x, its = scaled_cg(ml.levels[0].A, self._scale, b, x0, self.rtol, cap, M=M)
        self.stats.backsolves += its
        self.stats.krylov_iterations += its
        if x is None:
            raise SolveFailed(f"{method} did not reach rtol {self.rtol:g} in {cap} iterations")
        return x

    def time_backsolve(self, n: int, repeats: int = 20, seed: int = 0) -> float:
        """Median seconds of one application of the stored factorization (one back-substitution
        for LU, one V-cycle for AMG) to a random vector of length n; for benchmarks."""
        rng = np.random.default_rng(seed)
        times = []
        for _ in range(repeats):
            b = rng.standard_normal(n)
            t0 = time.perf_counter()
            self._prec(b)
            times.append(time.perf_counter() - t0)
        return float(np.median(times))

    # -- nearby matrices ------------------------------------------------------------------------
    def solve(self, A, b: np.ndarray, x0=None, assemble=None, rtol: float | None = None):
        """x = A^{-1} b by Krylov preconditioned with the reference (rebuilt if it went stale).

        A may be a matrix-free operator; ``assemble()`` then returns it as a sparse matrix for
        the (rare) rebuilds of the reference. ``rtol`` overrides the relative tolerance (inexact
        Newton corrections need less than the final accuracy).
        """
        if self._prec is None:
            self.factor(A if assemble is None else assemble())
        x = self._krylov(A, b, x0, rtol)
        if x is None:
            self.factor(A if assemble is None else assemble())
            x = self._krylov(A, b, x0, rtol)
            if x is None:
                raise SolveFailed("Krylov solve failed with a fresh preconditioner")
        return x

    def _krylov(self, A, b, x0, rtol=None):
        rtol = self.rtol if rtol is None else rtol
        self.stats.solves += 1
        bnorm = np.linalg.norm(b)
        if bnorm == 0.0:
            return np.zeros_like(b)
        n = A.shape[0]
        count = [0]

        def prec(r):
            count[0] += 1
            return self._prec(r)

        M = spla.LinearOperator((n, n), matvec=prec, dtype=float)
        its = [0]

        def cb(_):
            its[0] += 1

        if self.spd:
            # Jacobi preconditions a nearby matrix as well as the reference: its iterations
            # are those of the reference's solves, not a few
            maxiter = JACOBI_MAXITER if self.kind == "jacobi" else self.max_krylov
            x, info = spla.cg(A, b, x0=x0, rtol=rtol, atol=0.0, maxiter=maxiter, M=M, callback=cb)
        else:
            # scipy's GMRES stops its inner iterations on the preconditioned residual and checks
            # the true one at restarts: allow a few restarts before calling the reference stale
            x, info = spla.gmres(
                A,
                b,
                x0=x0,
                rtol=rtol,
                atol=0.0,
                restart=self.max_krylov,
                maxiter=3,
                M=M,
                callback=cb,
                callback_type="pr_norm",
            )
        self.stats.krylov_iterations += its[0]
        self.stats.backsolves += count[0]
        if info != 0 or not np.all(np.isfinite(x)):
            return None
        return x


class ConstrainedSolver(ReferenceSolver):
    """The bordered systems of the original form, solved by condensing the constraint.

    With B = M_G S (S selects the constrained dofs C, M_G the boundary mass, invertible) and
    I the free dofs, the system

        [A  B^T] [u  ]   [f]
        [B  0  ] [lam] = [g]

    is, exactly,  u_C = M_G^{-1} g,  A_II u_I = f_I - A_IC u_C,
    lam = M_G^{-1} (f_C - A_CI u_I - A_CC u_C)  (M_G symmetric): one solve with A_II, the
    matrix of the regularized form, plus two solves with the small boundary mass. This is what
    strong Dirichlet conditions do in a general FE code; it replaces the LU of the indefinite
    bordered matrix (no AMG possible) by the SPD solver of A_II (``direct`` or ``amg``), so both
    forms cost the same (``python benchmarks/eld_peers.py``, 56,355 dofs: SuperLU setup 39.9 s
    against 38.3 s for the regularized form, peak 983 MB for both). The answer is the KKT
    solution up to round-off (tested; the reactions equal the strong-Dirichlet peer's to 6e-12).

    ``factor`` accepts the bordered matrix (n + m square, from the Newton path) or A itself
    (n square); :meth:`factor_parts` takes A_II, A_IC, A_CI, A_CC directly (the lean path at
    scale). Krylov solves with nearby bordered matrices (nonlinear damping) run GMRES on them,
    preconditioned by the condensed solve with the stored reference.
    """

    def __init__(
        self,
        constraint,
        kind: str = "direct",
        near_nullspace=None,
        rtol: float = 1e-10,
        max_krylov: int = 20,
        amg_options: dict | None = None,
        times: PhaseTimes | None = None,
        symmetric_lu: bool = False,
    ):
        super().__init__("direct", spd=False, rtol=rtol, max_krylov=max_krylov)
        self.kind = kind
        self.constraint = constraint
        self.n = constraint.space.ndofs
        # the factorizations happen in the inner solver: it times them
        self.inner = ReferenceSolver(
            kind,
            spd=True,
            near_nullspace=near_nullspace,
            rtol=rtol,
            max_krylov=max_krylov,
            amg_options=amg_options,
            times=times,
            symmetric_lu=symmetric_lu,
        )
        self._parts = None

    def snapshot(self, stored: bool = True) -> dict:
        """The stored reference with the thin blocks and the inner solver's (see
        :meth:`ReferenceSolver.snapshot`)."""
        state = super().snapshot(stored)
        state.update(parts=self._parts if stored else None, inner=self.inner.snapshot(stored))
        return state

    def rollback(self, state: dict) -> None:
        """Put back what :meth:`snapshot` returned."""
        super().rollback(state)
        if state["stored"] is not None:
            self._parts = state["parts"]
        self.inner.rollback(state["inner"])

    def release(self) -> None:
        """Drop the stored reference, the thin blocks and the inner solver's."""
        super().release()
        self._parts = None
        self.inner.release()

    def factor(self, A) -> None:
        """Factor the reference from the bordered matrix or from A (n x n)."""
        n, c = self.n, self.constraint
        A = sp.csr_matrix(A)
        if A.shape == (n + c.m, n + c.m):
            A = A[:n][:, :n]
        elif A.shape != (n, n):
            raise ValueError(
                f"matrix of shape {A.shape}, expected {(n, n)} or {(n + c.m, n + c.m)}"
            )
        I, C = c.free, c.dofs
        A_I, A_C = A[I], A[C]
        self.factor_parts(A_I[:, I], A_I[:, C], A_C[:, I], A_C[:, C])

    def factor_parts(self, A_II, A_IC, A_CI, A_CC) -> None:
        """Factor A_II (LU or AMG) and keep the thin blocks of A on the constrained dofs."""
        before = self.inner.stats.setup_seconds
        self.inner.factor(A_II)
        self.stats.factorizations += 1
        self.stats.setup_seconds += self.inner.stats.setup_seconds - before
        self._parts = (sp.csr_matrix(A_IC), sp.csr_matrix(A_CI), sp.csr_matrix(A_CC))
        self._A = None
        self._prec = self._condensed
        self._ml = self.inner._ml

    def _condensed(self, rhs: np.ndarray, x0=None) -> np.ndarray:
        c, n = self.constraint, self.n
        I, C = c.free, c.dofs
        A_IC, A_CI, A_CC = self._parts
        f, g = rhs[:n], rhs[n:]
        u = np.empty(n)
        u_C = c.multiplier_from_residual(g)  # M_G^{-1} g
        u[C] = u_C
        u[I] = self.inner.solve_reference(f[I] - A_IC @ u_C, x0=x0)
        lam = c.multiplier_from_residual(f[C] - A_CI @ u[I] - A_CC @ u_C)
        return np.concatenate([u, lam])

    def solve_reference(self, b: np.ndarray, x0=None) -> np.ndarray:
        """[u; lam] of the reference bordered system (x0: a guess of u, or of [u; lam])."""
        inner = self.inner.stats
        before = (inner.backsolves, inner.krylov_iterations)
        guess = None
        if x0 is not None and self.inner.kind != "direct":
            guess = np.asarray(x0)[: self.n][self.constraint.free]
        z = self._condensed(b, x0=guess)
        self.stats.solves += 1
        self.stats.backsolves += inner.backsolves - before[0]
        self.stats.krylov_iterations += inner.krylov_iterations - before[1]
        return z
