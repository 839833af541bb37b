"""Linear solvers for the Newton systems, with reuse of factorizations and AMG hierarchies.

A Newton system K x = b changes a little from one iteration to the next (the diagonal of F''
moves, the multiplier changes, a few nodes enter or leave the active set). Re-factorizing every
time is wasteful: a back-substitution is 7-25x cheaper than a factorization and an AMG solve
(PERFORMANCE-NOTES). So a :class:`ReusableSolver` keeps a *preconditioner* built from a reference
matrix K_ref and solves the *current* K by preconditioned GMRES. When K == K_ref the preconditioner
is exact (LU) and GMRES stops after one iteration; when K has drifted, a few more iterations
absorb the difference; when it has drifted too far (too many iterations), the preconditioner is
rebuilt from the current K. The caller decides nothing about reuse.

Preconditioners: ``direct`` = scipy ``splu`` with ``MMD_AT_PLUS_A`` ordering (the symmetric
ordering halves fill versus COLAMD); ``amg`` = pyamg smoothed aggregation; ``auto`` picks direct
up to ``amg_threshold`` unknowns (LU is faster there for a changing matrix) and AMG above.
Dense matrices (small R^n problems) are solved by LAPACK directly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import check_choice

LINEAR_SOLVERS = ("auto", "direct", "amg")


@dataclass
class LinearStats:
    factorizations: int = 0  # preconditioner builds (LU factorizations or AMG setups)
    solves: int = 0  # right-hand sides solved
    krylov_iterations: int = 0
    failures: int = 0

    def as_dict(self) -> dict:
        return dict(self.__dict__)


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

    ``solve(K, rhs, key=..., surrogate=..., spd=...)``: a ``key`` (e.g. the active set) that
    differs from the stored one forces a rebuild; ``surrogate`` is the matrix the preconditioner
    is built from if not K itself (AMG needs an SPD matrix even when K is indefinite); ``spd``
    says K itself is SPD, so AMG runs preconditioned CG instead of GMRES.
    """

    def __init__(self, method: str = "auto", amg_threshold: int = 150_000, max_krylov: int = 12):
        self.method = check_choice("linear_solver", method, LINEAR_SOLVERS)
        self.amg_threshold = int(amg_threshold)
        self.max_krylov = int(max_krylov)
        self.stats = LinearStats()
        self._prec = None  # callable b -> approx K_ref^{-1} b
        self._prec_shape = None
        self._key = None
        self._fresh_its: int | None = None  # Krylov iterations of the first solve after a build
        self.kind_used: str | None = None

    def reset(self) -> None:
        """Forget the stored preconditioner (e.g. when the mesh changes)."""
        self._prec = None
        self._prec_shape = None
        self._key = None

    def resolve_kind(self, n: int) -> str:
        if self.method != "auto":
            return self.method
        return "direct" if n <= self.amg_threshold else "amg"

    # -- building ------------------------------------------------------------------------------
    def _build(self, K, kind: str) -> None:
        self.stats.factorizations += 1
        self._fresh_its = None
        try:
            if kind == "direct":
                lu = spla.splu(sp.csc_matrix(K), permc_spec="MMD_AT_PLUS_A")
                self._prec = lu.solve
                self.kind_used = "splu"
            else:
                import pyamg

                Kc = sp.csr_matrix(K)
                Kc.eliminate_zeros()
                ml = pyamg.smoothed_aggregation_solver(Kc, max_coarse=500)
                self._prec = ml.aspreconditioner(cycle="V")
                self.kind_used = "pyamg-sa"
        except RuntimeError as exc:  # splu: "Factor is exactly singular"
            self._prec = None
            self.stats.failures += 1
            raise SingularSystem(str(exc)) from exc
        self._prec_shape = K.shape

    # -- solving -------------------------------------------------------------------------------
    def solve(self, K, rhs: list[np.ndarray], rtol: float = 1e-10, *, key=None, surrogate=None,
              spd: bool = False) -> list[np.ndarray]:
        """Solve K x = b for each b in ``rhs`` to relative residual ``rtol``."""
        if not sp.issparse(K):
            return self._dense(K, rhs)
        K = sp.csr_matrix(K)
        kind = self.resolve_kind(K.shape[0])
        stale = (self._prec is None or self._prec_shape != K.shape
                 or (key is not None and (self._key is None or not np.array_equal(key, self._key))))
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
                    raise SingularSystem("the Krylov solver did not converge with a fresh "
                                         "preconditioner")
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
            limit = 10**9 if fresh or self._fresh_its is None else max(
                self.max_krylov, 3 * self._fresh_its)
        M = spla.LinearOperator(K.shape, matvec=self._prec, dtype=float)
        its = [0]

        def count(_):
            its[0] += 1

        if kind == "amg" and spd:
            x, info = spla.cg(K, b, x0=x0, rtol=rtol, atol=0.0, maxiter=restart * maxiter, M=M,
                              callback=count)
        else:
            x, info = spla.gmres(K, b, x0=x0, rtol=rtol, atol=0.0, restart=restart,
                                 maxiter=maxiter, M=M, callback=count, callback_type="pr_norm")
        self.stats.krylov_iterations += its[0]
        if info != 0 or not np.all(np.isfinite(x)) or its[0] > limit:
            return None
        if np.linalg.norm(b - K @ x) > max(rtol, 1e-14) * bnorm * 10:
            return None
        if kind == "amg" and self._fresh_its is None:
            self._fresh_its = its[0]
        return x
