"""Linear solvers for the Newton systems, with reuse of factorizations and AMG hierarchies.

A Newton system K x = b changes a little from one iteration to the next (the diagonal of F''
moves, the multiplier changes, a few nodes enter or leave the active set). Re-factorizing every
time is wasteful: a back-substitution is 7-25x cheaper than a factorization and an AMG solve
(measured on 2D grids). So a :class:`ReusableSolver` keeps a *preconditioner* built from a reference
matrix K_ref and solves the *current* K by preconditioned GMRES. When K == K_ref the preconditioner
is exact (LU) and GMRES stops after one iteration; when K has drifted, a few more iterations
absorb the difference; when it has drifted too far (too many iterations), the preconditioner is
rebuilt from the current K. The caller decides nothing about reuse.

Preconditioners: ``direct`` = scipy ``splu`` with ``MMD_AT_PLUS_A`` ordering (the symmetric
ordering halves fill versus COLAMD); ``amg`` = pyamg smoothed aggregation; ``auto`` picks direct
up to ``amg_threshold`` unknowns (LU is faster there for a changing matrix) and AMG above.
Dense matrices (small R^n problems) are solved by LAPACK directly.

Reproducibility. The stored preconditioner changes the results at round-off level (GMRES stops
at a tolerance, so which LU it is preconditioned with shows in the last bits), so it is part of
a run's state: :meth:`ReusableSolver.checkpoint_state` saves the matrix it was built from and
:meth:`~ReusableSolver.restore_state` rebuilds it (SuperLU is deterministic: the same matrix gives
the same factors). pyamg's smoothed-aggregation setup estimates spectral radii from a *random*
start vector drawn from numpy's global generator, so two identical runs used to differ by up to
3.5e-13; every AMG setup here runs under :func:`reproducible_random` (a fixed seed, the caller's
global random state restored afterwards), which makes AMG runs repeatable bit for bit too.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import check_choice

LINEAR_SOLVERS = ("auto", "direct", "amg")


@dataclass
class LinearStats:
    """Counters of a :class:`ReusableSolver`: preconditioner builds (LU factorizations or AMG
    setups), right-hand sides solved, Krylov iterations, failures.
    """

    factorizations: int = 0  # preconditioner builds (LU factorizations or AMG setups)
    solves: int = 0  # right-hand sides solved
    krylov_iterations: int = 0
    failures: int = 0

    def as_dict(self) -> dict:
        """The counters as a dict."""
        return dict(self.__dict__)


@contextlib.contextmanager
def reproducible_random(seed: int = 0):
    """Run a block with numpy's *global* generator seeded, then restore the caller's state.

    For library code that draws from ``np.random`` without a seed argument (pyamg's spectral
    radius estimates), so that its results are the same in every run.
    """
    saved = np.random.get_state()
    np.random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(saved)


def sparse_state(M) -> dict:
    """A sparse matrix as a checkpoint dict (its compressed arrays exactly as they are)."""
    M = M if M.format in ("csr", "csc") else sp.csr_matrix(M)
    return {
        "format": M.format,
        "shape": [int(x) for x in M.shape],
        "data": M.data,
        "indices": M.indices,
        "indptr": M.indptr,
    }


def sparse_from_state(data: dict):
    """The CSC or CSR matrix of :func:`sparse_state`'s dict."""
    cls = sp.csc_matrix if data["format"] == "csc" else sp.csr_matrix
    return cls(
        (np.asarray(data["data"]), np.asarray(data["indices"]), np.asarray(data["indptr"])),
        shape=tuple(data["shape"]),
    )


def v_cycle(ml, b: np.ndarray) -> np.ndarray:
    """One V-cycle of the pyamg hierarchy ``ml`` from the zero start: x ~ A^{-1} b.

    The cycle of pyamg's ``MultilevelSolver`` (pre-smoothing, the residual restricted, the
    coarse correction, post-smoothing; the coarsest level by ``ml.coarse_solver``), without
    the two fine-level residual norms its ``aspreconditioner`` computes around every
    application (``solve(b, maxiter=1)``: ||b - A 0|| before and ||b - A x|| after): the same
    arithmetic, hence the same bits, with 7 products with the fine matrix per CG iteration
    instead of 9 under Chebyshev(3) smoothing. The ELD solves (``rothe.eld.solvers``) pair it
    with scipy's CG, which unlike pyamg's does not recompute r = b - A x every eighth
    iteration: their iterates are pyamg's to round-off (1e-15 relative) for 0.65-0.75x the
    seconds (P1 beam, 107k dofs, docs/scaling.md)."""
    levels = ml.levels
    x = np.zeros_like(b)
    # descend: smooth, restrict the residual; the right-hand sides and iterates kept per level
    stack = []
    for k in range(len(levels) - 1):
        level = levels[k]
        level.presmoother(level.A, x, b)
        stack.append((level, x, b))
        b = level.R @ (b - level.A @ x)
        x = np.zeros_like(b)
    x = ml.coarse_solver(levels[-1].A, b)
    for level, xf, bf in reversed(stack):
        xf += level.P @ x
        level.postsmoother(level.A, xf, bf)
        x = xf
    return x


#: the attributes of a ReusableSolver that a solve may change (besides its counters)
_SNAPSHOT = ("_prec", "_prec_shape", "_key", "_fresh_its", "kind_used", "_ref", "_ref_kind")


class SingularSystem(RuntimeError):
    """The Newton matrix could not be factorized or the Krylov solver did not converge."""


class ReusableSolver:
    """Solve K x = b for a sequence of slowly changing K, reusing one preconditioner.

    Parameters
    ----------
    method : 'auto' | 'direct' | 'amg'
    amg_threshold : int
        Above this many unknowns, 'auto' uses AMG.
    max_krylov : int
        Direct: GMRES restart length; more iterations than this mean the stored LU is stale.
        AMG: a solve needing more than ``max(max_krylov, 3 x the iterations right after a
        rebuild)`` iterations triggers a rebuild from the current matrix.
    splu : callable, optional
        The sparse LU factorization (default scipy's ``splu``); the RIS inner solver passes
        :func:`rothe.stepping.interrupt.splu`, so that a stop signal abandons a step during a
        long factorization (this layer knows no signals).

    ``solve(K, rhs, key=..., surrogate=..., spd=...)``: a ``key`` (e.g. the active set) that
    differs from the stored one forces a rebuild; ``surrogate`` is the matrix the preconditioner
    is built from if not K itself (AMG needs an SPD matrix even when K is indefinite); ``spd``
    says K itself is SPD, so AMG runs preconditioned CG instead of GMRES.
    """

    def __init__(
        self, method: str = "auto", amg_threshold: int = 150_000, max_krylov: int = 12, splu=None
    ):
        self.method = check_choice("linear_solver", method, LINEAR_SOLVERS)
        self._splu = splu if splu is not None else spla.splu
        self.amg_threshold = int(amg_threshold)
        self.max_krylov = int(max_krylov)
        self.stats = LinearStats()
        self._prec = None  # callable b -> approx K_ref^{-1} b
        self._prec_shape = None
        self._key = None
        self._fresh_its: int | None = None  # Krylov iterations of the first solve after a build
        self.kind_used: str | None = None
        self._ref = None  # the matrix the preconditioner was built from (for checkpoints)
        self._ref_kind: str | None = None

    def reset(self) -> None:
        """Forget the stored preconditioner (e.g. when the mesh changes)."""
        self._prec = None
        self._prec_shape = None
        self._key = None
        self._ref = None
        self._ref_kind = None

    def resolve_kind(self, n: int) -> str:
        """``'direct'`` or ``'amg'`` for ``n`` unknowns: the method, or for ``'auto'`` direct up
        to ``amg_threshold`` unknowns.
        """
        if self.method != "auto":
            return self.method
        return "direct" if n <= self.amg_threshold else "amg"

    # -- building ------------------------------------------------------------------------------
    def _build(self, K, kind: str) -> None:
        self.stats.factorizations += 1
        self._fresh_its = None
        try:
            if kind == "direct":
                Kc = sp.csc_matrix(K)
            else:
                Kc = sp.csr_matrix(K)
                Kc.eliminate_zeros()
            self._factor(Kc, kind)
        except RuntimeError as exc:  # splu: "Factor is exactly singular"
            self._prec = None
            self._ref = None
            self.stats.failures += 1
            raise SingularSystem(str(exc)) from exc
        self._prec_shape = K.shape

    def _factor(self, Kc, kind: str) -> None:
        """Build the preconditioner from ``Kc`` (CSC for LU, CSR for AMG) and remember ``Kc``."""
        if kind == "direct":
            lu = self._splu(Kc, permc_spec="MMD_AT_PLUS_A")
            self._prec = lu.solve
            self.kind_used = "splu"
        else:
            import pyamg  # heavy: imported when first needed (start-up time)

            with reproducible_random():
                ml = pyamg.smoothed_aggregation_solver(Kc, max_coarse=500)
            self._prec = lambda b: v_cycle(ml, b)
            self.kind_used = "pyamg-sa"
        self._ref, self._ref_kind = Kc, kind

    # -- checkpoint protocol -------------------------------------------------------------------
    def checkpoint_state(self) -> dict:
        """What decides future results: the matrix the stored preconditioner was built from (it
        is rebuilt from it, bit for bit), the active-set key, the iteration baseline of the
        rebuild rule, and the counters."""
        ref = None
        if self._prec is not None and self._ref is not None:
            ref = {
                "kind": self._ref_kind,
                "matrix": sparse_state(self._ref),
                "shape": [int(x) for x in self._prec_shape],
            }
        return {
            "stats": self.stats.as_dict(),
            "kind_used": self.kind_used,
            "key": None if self._key is None else np.asarray(self._key),
            "fresh_its": self._fresh_its,
            "reference": ref,
        }

    def restore_state(self, data: dict) -> None:
        """Restore from :meth:`checkpoint_state`: the preconditioner rebuilt from its matrix, the
        key, the iteration baseline and the counters.
        """
        self.reset()
        ref = data["reference"]
        if ref is not None:
            self._factor(sparse_from_state(ref["matrix"]), ref["kind"])
            self._prec_shape = tuple(ref["shape"])
        self._key = None if data["key"] is None else np.array(data["key"], copy=True)
        self._fresh_its = None if data["fresh_its"] is None else int(data["fresh_its"])
        self.kind_used = data["kind_used"]
        self.stats = LinearStats(**data["stats"])

    # -- undoing an abandoned attempt ------------------------------------------------------------
    def snapshot(self) -> dict:
        """What solves change: the stored preconditioner (by reference: a rebuild replaces it,
        nothing changes it in place), its key, the iteration baseline and a copy of the
        counters. :meth:`rollback` puts it back, e.g. when a step is abandoned."""
        state = {name: getattr(self, name) for name in _SNAPSHOT}
        state["stats"] = LinearStats(**self.stats.as_dict())
        return state

    def rollback(self, state: dict) -> None:
        """Put back what :meth:`snapshot` returned."""
        for name in _SNAPSHOT:
            setattr(self, name, state[name])
        self.stats = LinearStats(**state["stats"].as_dict())

    # -- solving -------------------------------------------------------------------------------
    def solve(
        self,
        K,
        rhs: list[np.ndarray],
        rtol: float = 1e-10,
        *,
        key=None,
        surrogate=None,
        spd: bool = False,
    ) -> list[np.ndarray]:
        """Solve K x = b for each b in ``rhs`` to relative residual ``rtol``."""
        if not sp.issparse(K):
            return self._dense(K, rhs)
        K = sp.csr_matrix(K)
        kind = self.resolve_kind(K.shape[0])
        stale = (
            self._prec is None
            or self._prec_shape != K.shape
            or (key is not None and (self._key is None or not np.array_equal(key, self._key)))
        )
        if stale:
            self._build(K if surrogate is None else surrogate, kind)
            self._key = None if key is None else np.array(key, copy=True)
        out = []
        for b in rhs:
            x = self._krylov(K, b, rtol, kind, spd)
            if x is None:  # the stored preconditioner is stale: rebuild and retry once
                self._build(K if surrogate is None else surrogate, kind)
                self._key = None if key is None else np.array(key, copy=True)
                x = self._krylov(K, b, rtol, kind, spd, fresh=True)
                if x is None:
                    self.stats.failures += 1
                    raise SingularSystem(
                        "the Krylov solver did not converge with a fresh preconditioner"
                    )
            out.append(x)
        return out

    def _dense(self, K, rhs):
        self.stats.factorizations += 1
        self.stats.solves += len(rhs)
        self.kind_used = "lapack"
        try:
            lu = sla.lu_factor(np.asarray(K), check_finite=True)
        except (ValueError, np.linalg.LinAlgError) as exc:
            self.stats.failures += 1
            raise SingularSystem(str(exc)) from exc
        if np.any(np.abs(np.diag(lu[0])) <= 1e-14 * max(1.0, np.max(np.abs(K)))):
            self.stats.failures += 1
            raise SingularSystem("singular dense matrix")
        return [sla.lu_solve(lu, b) for b in rhs]

    def _krylov(self, K, b, rtol, kind, spd, fresh=False):
        self.stats.solves += 1
        bnorm = np.linalg.norm(b)
        if bnorm == 0.0:
            return np.zeros_like(b)
        if kind == "direct":
            x = self._prec(b)
            if not np.all(np.isfinite(x)):
                return None
            self.stats.krylov_iterations += 1
            if np.linalg.norm(b - K @ x) <= rtol * bnorm:
                return x
            x0, restart, maxiter, limit = x, self.max_krylov, 1, self.max_krylov
        else:
            x0, restart, maxiter = None, 60, 4
            limit = (
                10**9
                if fresh or self._fresh_its is None
                else max(self.max_krylov, 3 * self._fresh_its)
            )
        M = spla.LinearOperator(K.shape, matvec=self._prec, dtype=float)
        its = [0]

        def count(_):
            its[0] += 1

        if kind == "amg" and spd:
            x, info = spla.cg(
                K, b, x0=x0, rtol=rtol, atol=0.0, maxiter=restart * maxiter, M=M, callback=count
            )
        else:
            x, info = spla.gmres(
                K,
                b,
                x0=x0,
                rtol=rtol,
                atol=0.0,
                restart=restart,
                maxiter=maxiter,
                M=M,
                callback=count,
                callback_type="pr_norm",
            )
        self.stats.krylov_iterations += its[0]
        if info != 0 or not np.all(np.isfinite(x)) or its[0] > limit:
            return None
        if np.linalg.norm(b - K @ x) > max(rtol, 1e-14) * bnorm * 10:
            return None
        if kind == "amg" and self._fresh_its is None:
            self._fresh_its = its[0]
        return x
