"""One coupled step as a bordered linear system (issue 19).

The equations are those of ``docs/coupling.md`` (Sec. 4); in short, with the scheme's
difference operator delta z = (alpha_0 z^j + alpha_1 z^{j-1} + alpha_2 z^{j-2})/tau,
kappa = alpha_0/tau and the history part c_z = (alpha_1 z^{j-1} + alpha_2 z^{j-2})/tau of any
variable z (so that delta z = kappa z^j + c_z):

- body (regularized form): x = u_1 in ker B, y = delta x, b = delta y; component: q,
  p = delta q, pdot = delta p; controllers: z with delta z = A_c z + B_c y_s;
- data: g = g_k + Gamma q, g' = g'_k + Gamma p, g'' = g''_k + Gamma pdot (linear couplings;
  g_k, g'_k, g''_k the known part: prescribed data, noise);
- u = x + L g, v = y + L g', a = b + L g'' (L = B^-, the lifting), hence with
  X = x + Phi q, Phi = L Gamma:
      u = X + u_k,  v = kappa X + v_k,  a = kappa^2 X + a_k,
      r := rho M a + C v + K u - F = A X + r_k,   A = rho kappa^2 M + kappa C + K;
- the rows of ker B (the free dofs I):                      (A X + r_k)_I = 0
- the component, lambda eliminated (M_G lambda = -L^T r):
      M_q pdot + f(q, p) + Phi^T r - f_ext - E w = 0,
- the controllers: delta z = A_c z + B_c y_s, w = C_c z + D_c y_s, y_s = W X + y_k with
  W = Y_u + kappa Y_v - Y_lam M_G^{-1} L^T A.

Unknowns (x_I, xi), xi = (q, z): the body's step matrix A_II -- the same matrix a step with
prescribed data factors -- bordered by r + s rows and columns:

    [ A_II                      (A Phi)_I          0        ] [x_I]   [-r_k,I               ]
    [ (Phi^T A - E D_c W)_.I    S_qq              -E C_c    ] [ q ] = [f_q + E D_c y_k      ]
    [ -B_c W_.I                 -B_c W Phi   kappa I - A_c  ] [ z ]   [B_c y_k - c_z        ]

with S_qq = kappa^2 M_q + kappa C_q + K_q + Phi^T A Phi - E D_c W Phi. Solved by the Schur
complement on xi: per factorization of A_II (per effective step size) the r columns
X = A_II^{-1} (A Phi)_I (r back-substitutions); per step ONE back-substitution
x_0 = -A_II^{-1} r_k,I, an (r + s) dense solve, and x_I = x_0 - X q. A nonlinear component
(or controller) is solved by Newton on xi alone (x_I stays the affine function x_0 - X q):
no further back-substitution.

With many coordinates (r >= :data:`SPARSE_COORDINATES`: glued bodies, whose attached body's
free dofs are the coordinates) and no controllers the Schur complement would be dense r x r;
the bordered matrix is then factored as one sparse matrix instead, T^T blkdiag(A, J_q) T with
T = [[P_I^T, Phi], [0, I]] (the substitution u = P_I^T x_I + Phi q): one sparse LU per step
size and one back-substitution per step (:meth:`CoupledStepSystem.solve`).

The original form (2.7) with the same couplings is this system with the nodal lifting and the
data differenced, g'_k = delta g_k, g''_k = delta g'_k (the boundary velocity and
acceleration of the original form are the scheme's quotients of S u = g): the two forms differ
only where data enter separately -- prescribed G', G'' and the noise of Theorem 4.5.

:class:`CoupledStepSystem` is the algebra of one step; the stepper that drives it on the
evolve loop is :class:`rothe.eld.coupled_run.CoupledStepper` (:func:`rothe.eld.run_coupled`).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import RunFailed, fail
from .constraint import HarmonicLifting, NodalLifting
from .coupling import CoupledProblem

#: from this many coordinates on (glued bodies) the border's matrices are kept sparse; below,
#: dense (a few coordinates: dense products cost less than sparse ones per step)
SPARSE_COORDINATES = 64


def _dense(A):
    """A dense copy of a sparse matrix (the components' block of glued bodies), else A."""
    return A.toarray() if sp.issparse(A) else A


def _same(A, B) -> bool:
    """Equal matrices (dense or sparse alike)."""
    if sp.issparse(A) != sp.issparse(B) or A.shape != B.shape:
        return False
    return (A != B).nnz == 0 if sp.issparse(A) else np.array_equal(A, B)


class CoupledStepSystem:
    """The bordered system of one coupled step on one mesh (module docstring).

    Parameters
    ----------
    system : CoupledProblem
        Body with linear damping; linear couplings (the border Phi = L Gamma is constant).
    lifting : 'nodal' | 'harmonic'

    ``stats``: factorizations, back_substitutions, schur_solves, newton_iterations.
    """

    def __init__(self, system: CoupledProblem, lifting: str = "nodal"):
        if not isinstance(system, CoupledProblem):
            raise fail("system", type(system).__name__, "must be a rothe.eld.CoupledProblem")
        body = system.body
        if not body.damping_op.is_linear:
            raise fail(
                "damping",
                body.damping.describe().get("type", "nonlinear"),
                "must be linear for the coupled step (nonlinear body damping: the body's "
                "Newton refactors A_II, and X with it)",
            )
        if not all(cp.is_linear for cp in system.couplings):
            raise fail(
                "couplings",
                "a nonlinear coupling",
                "must be linear here (G affine in q: the border Phi = L Gamma constant)",
            )
        self.system = system
        self.body = body
        c = self.constraint = system.constraint
        self.rho = float(body.material.rho)
        self.M = sp.csr_matrix(body.M)
        self.K = sp.csr_matrix(body.K)
        self.D = body.damping_op
        self.I = c.free
        if lifting == "nodal":
            self.lifting = NodalLifting(c)
        elif lifting == "harmonic":
            self.lifting = HarmonicLifting(c, self.K)
        else:
            raise fail("lifting", lifting, "must be one of nodal, harmonic")
        self.r = system.size
        #: many coordinates (glued bodies: an attached body's free dofs): Gamma, Phi sparse and
        #: the step solved monolithically (:meth:`solve`) when there are no controllers
        self.many = self.r >= SPARSE_COORDINATES
        Gamma = system.gamma()
        # Phi = L Gamma, sparse (n, r): no dense n x r copy for glued bodies
        self.Phi_sparse = system.lifted_modes(self.lifting)
        self.Gamma = Gamma.tocsr() if self.many else Gamma.toarray()
        #: Phi as the step's products take it (sparse for glued bodies, else dense)
        self.Phi = self.Phi_sparse if self.many else self.Phi_sparse.toarray()
        self.Mq = system.mass()
        n, m = body.space.ndofs, c.m
        ctrls = system.controllers
        self.s = sum(k.size for k in ctrls)
        self.k_in = sum(k.n_inputs for k in ctrls)
        self.o = sum(k.outputs for k in ctrls)
        self.Y_u = sp.vstack([k.Y_u for k in ctrls] or [sp.csr_matrix((0, n))], format="csr")
        self.Y_v = sp.vstack([k.Y_v for k in ctrls] or [sp.csr_matrix((0, n))], format="csr")
        self.Y_lam = sp.vstack([k.Y_lam for k in ctrls] or [sp.csr_matrix((0, m))], format="csr")
        self.Ac = sla.block_diag(*[k.A for k in ctrls]) if self.s else np.zeros((0, 0))
        self.Bc = np.zeros((self.s, self.k_in))
        self.Cc = np.zeros((self.o, self.s))
        self.Dc = np.zeros((self.o, self.k_in))
        self.E = np.zeros((self.r, self.o))
        si = ki = oi = 0
        for k in ctrls:
            A, B, C, D = k.jacobians(0.0, k.z0, np.zeros(k.n_inputs))
            self.Bc[si : si + k.size, ki : ki + k.n_inputs] = B
            self.Cc[oi : oi + k.outputs, si : si + k.size] = C
            self.Dc[oi : oi + k.outputs, ki : ki + k.n_inputs] = D
            self.E[system.slice(k.component), oi : oi + k.outputs] = k.E
            si, ki, oi = si + k.size, ki + k.n_inputs, oi + k.outputs
        # M_G^{-1} Y_lam^T lifted: the multiplier rows of the sensors as body vectors
        if self.k_in:
            Z = (
                np.column_stack(
                    [c.multiplier_from_residual(col) for col in self.Y_lam.T.toarray().T]
                )
                if self.Y_lam.nnz
                else np.zeros((m, self.k_in))
            )
            self._LZ = (
                np.column_stack(self.lifting.lift_many([Z[:, j] for j in range(self.k_in)]))
                if self.Y_lam.nnz
                else np.zeros((n, self.k_in))
            )
        else:
            self._LZ = np.zeros((n, 0))
        self.stats = {
            "factorizations": 0,
            "back_substitutions": 0,
            "schur_solves": 0,
            "newton_iterations": 0,
        }
        #: the bordered system solved as one sparse matrix (:meth:`solve`): many coordinates,
        #: no controllers
        self.monolithic = self.many and self.s == 0
        self._key = None
        self._schur = None  # (LU of S, its component block) of the last linear solve
        self._mono = None  # (sparse LU of the whole bordered matrix, its component block)
        self.X = None  # the border columns A_II^{-1} (A Phi)_I, built when the Schur path runs

    # -- the lifting and its transpose -----------------------------------------------------------
    def lift(self, g: np.ndarray) -> np.ndarray:
        """The lifting L g of boundary values g."""
        return self.lifting(g)

    def lift_transpose(self, r: np.ndarray) -> np.ndarray:
        """L^T r: nodal r_C; harmonic r_C - K_CI K_II^{-1} r_I (K symmetric)."""
        c = self.constraint
        if isinstance(self.lifting, NodalLifting):
            return r[c.dofs]
        lu, K_IC = self.lifting._lu, self.lifting._K_IC
        return r[c.dofs] - K_IC.T @ lu.solve(r[c.free])

    def multiplier(self, r: np.ndarray) -> np.ndarray:
        """lambda = -M_G^{-1} L^T r (the equation tested with V^c, r = rho M a + C v + K u - F)."""
        return -self.constraint.multiplier_from_residual(self.lift_transpose(r))

    # -- factorization ---------------------------------------------------------------------------
    def matrix(self, cm: float, cc: float, ck: float) -> sp.csr_matrix:
        """cm rho M + cc C + ck K, C = mass_coef M + stiffness_coef K (+ matrix)."""
        D = self.D
        A = (cm * self.rho + cc * D.mass_coef) * self.M + (ck + cc * D.stiffness_coef) * self.K
        if D.matrix is not None:
            A = A + cc * D.matrix
        return sp.csr_matrix(A)

    def needs_factor(
        self, cm: float, cc: float, ck: float, wu: float, wv: float, kappa_z: float | None
    ) -> bool:
        """Whether :meth:`factor` with these coefficients would factor anew (they differ from
        the stored factorization's); the stepper asks so as not to time an empty phase."""
        return (cm, cc, ck, wu, wv, kappa_z) != self._key

    def factor(
        self, cm: float, cc: float, ck: float, wu: float, wv: float, kappa_z: float | None
    ) -> None:
        """Factor A_II of A = cm rho M + cc C + ck K and build the border: X = A_II^{-1}
        (A Phi)_I (r back-substitutions), W = wu Y_u + wv Y_v - Y_lam M_G^{-1} L^T A, V, the
        part of the Schur complement that does not depend on the components' Jacobian.
        ``kappa_z``: controller states are unknowns with delta z = kappa_z z + c_z (None:
        they are known, e.g. for the consistent initial acceleration)."""
        if not self.needs_factor(cm, cc, ck, wu, wv, kappa_z):
            return
        key = (cm, cc, ck, wu, wv, kappa_z)
        I = self.I
        A = self.matrix(cm, cc, ck)
        self.A = A
        self._A_II = sp.csc_matrix(A[I][:, I])
        self._key = key
        self._with_z = kappa_z is not None
        self._kappa_z = kappa_z
        self._wu, self._wv = wu, wv
        self._schur = self._mono = None
        self.X = self._lu = None
        if self.monolithic:
            # the whole bordered matrix is factored with the components' block (solve): A_II
            # alone is never needed
            return
        self._lu = spla.splu(self._A_II, permc_spec="MMD_AT_PLUS_A")
        self.stats["factorizations"] += 1
        self._border()

    # -- checkpoints -----------------------------------------------------------------------------
    def checkpoint_state(self) -> dict:
        """The key of the stored factorization (its coefficients) and the counters: what a
        resumed run needs to go on as the uninterrupted one (:meth:`restore_state`)."""
        return {
            "key": None if self._key is None else list(self._key),
            "stats": {k: int(v) for k, v in self.stats.items()},
        }

    def restore_state(self, data: dict, component_matrix=None, border: bool = False) -> None:
        """Factor the matrix the key of :meth:`checkpoint_state` names -- on the monolithic
        path the bordered matrix with ``component_matrix`` (the components' block of the last
        step, linear components) or, with ``border`` (nonlinear ones after a step), A_II and
        the border -- then continue the counters from the checkpoint's: the refactorization is
        not counted, the uninterrupted run did not do it. The same matrices factored by the
        same SuperLU give the same factors, so the next steps are the uninterrupted run's bit
        for bit."""
        key = data.get("key")
        if key is not None:
            self.factor(*key)
            if self.monolithic and component_matrix is not None:
                self._monolithic(component_matrix)
            elif self.monolithic and border:
                self._border()
        self.stats = {k: int(v) for k, v in data["stats"].items()}

    def _border(self) -> None:
        """X = A_II^{-1} (A Phi)_I (back-substitutions for the non-zero border columns only),
        the sensor rows W, V and the Schur complement S0 = C - V [X, 0] without the
        components' block: the part of the Schur path that depends on the step size only."""
        I, A = self.I, self.A
        if self._lu is None:
            self._lu = spla.splu(self._A_II, permc_spec="MMD_AT_PLUS_A")
            self.stats["factorizations"] += 1
        wu, wv, kappa_z = self._wu, self._wv, self._kappa_z
        # Phi is sparse (rows on the coupled dofs) and, for glued bodies (r in the thousands),
        # most of its columns are zero: sparse products, back-substitutions for the others only
        APhi = (A @ self.Phi_sparse).tocsc()  # (n, r)
        PhiA = (A.T @ self.Phi_sparse).T.tocsr()  # Phi^T A (r, n)
        X = np.zeros((I.size, self.r))
        cols = np.flatnonzero(np.diff(APhi.indptr))
        if cols.size:
            X[:, cols] = self._lu.solve(APhi[I][:, cols].toarray())
        self._cols, self._X_cols = cols, X[:, cols]  # x_I = x_0 - X q on them only
        self.stats["back_substitutions"] += cols.size
        # sensor rows: W (k, n) = wu Y_u + wv Y_v - (A^T L Z)^T
        W = (wu * self.Y_u + wv * self.Y_v).toarray()
        if self.k_in:
            W = W - (A.T @ self._LZ).T
        self.W = W
        r, s = self.r, self.s if kappa_z is not None else 0
        EDW = self.E @ (self.Dc @ W) if self.k_in else None
        top = PhiA[:, I] if EDW is None else sp.csr_matrix(PhiA[:, I].toarray() - EDW[:, I])
        blocks = [top] + ([sp.csr_matrix(-(self.Bc @ W)[:, I])] if s else [])
        V = sp.vstack(blocks, format="csr") if blocks[0].shape[0] or s else top.tocsr()
        self.V = V = V if r + s >= SPARSE_COORDINATES else V.toarray()
        Phi = _dense(self.Phi)
        C = np.zeros((r + s, r + s))
        C[:r, :r] = _dense(PhiA @ Phi)
        if EDW is not None:
            C[:r, :r] -= EDW @ Phi
        if s:
            C[:r, r:] = -self.E @ self.Cc
            C[r:, :r] = -self.Bc @ (W @ Phi)
            C[r:, r:] = kappa_z * np.eye(s) - self.Ac
        # Schur complement without the components' block: C - V [X, 0]
        C[:, :r] -= V @ X
        self.S0 = C
        self.X = X

    def back_substitute(self, rhs_I: np.ndarray) -> np.ndarray:
        """K_II^{-1} rhs_I with the stored factorization (counted in the stats)."""
        self.stats["back_substitutions"] += 1
        return self._lu.solve(rhs_I)

    def _monolithic(self, component_matrix):
        """The sparse LU of the whole bordered matrix (no controllers)

            [ A_II            (A Phi)_I                        ]
            [ (Phi^T A)_.I    Phi^T A Phi + component_matrix   ]

        i.e. T^T blkdiag(A, component_matrix) T with T = [[P_I^T, Phi], [0, I]]: the
        substitution u = P_I^T x_I + Phi q of the constraint into the body and the component.
        For glued bodies with the nodal lifting it is the union body's step matrix (the rows of
        the base's interface dofs added to their partners'), as sparse as it: one factorization
        per step size and component block, one back-substitution per step."""
        cached = self._mono
        if cached is not None and (
            cached[1] is component_matrix or _same(cached[1], component_matrix)
        ):
            return cached[0]
        I, A, Phi = self.I, self.A, self.Phi_sparse
        APhi = (A @ Phi).tocsr()
        PhiA = (Phi.T @ A).tocsr()
        Sqq = (PhiA @ Phi + sp.csr_matrix(component_matrix)).tocsr()
        big = sp.bmat([[self._A_II, APhi[I]], [PhiA[:, I], Sqq]], format="csc")
        lu = spla.splu(big, permc_spec="MMD_AT_PLUS_A")
        self.stats["factorizations"] += 1
        self._mono = (lu, component_matrix)
        return lu

    def solve(self, rhs_I, rhs_q, rhs_z, component_matrix, residual=None):
        """(x_I, q, z) of the bordered system (module docstring) for the right sides
        ``rhs_I`` (-r_k,I), ``rhs_q``, ``rhs_z`` and the components' block
        ``component_matrix`` (kappa^2 M_q + kappa C_q + K_q, or the Jacobian of a nonlinear
        component). With ``residual`` (a callable (x_I, q, z) -> the component rows' residual,
        for nonlinear components) Newton on (q, z) with that Jacobian.

        Linear components, many coordinates, no controllers (glued bodies): the bordered
        matrix factored as one sparse matrix (:meth:`_monolithic`). Otherwise the Schur
        complement on (q, z): one back-substitution and an (r + s) dense solve per step."""
        r = self.r
        if residual is None and self.monolithic:
            lu = self._monolithic(component_matrix)
            self.stats["back_substitutions"] += 1
            self.stats["schur_solves"] += 1
            sol = lu.solve(np.concatenate([rhs_I, rhs_q]))
            return sol[: self.I.size], sol[self.I.size :], np.zeros(0)
        if self.X is None:
            self._border()
        x0 = self.back_substitute(rhs_I)
        rhs = np.concatenate([rhs_q, rhs_z if self._with_z else np.zeros(0)]) - self.V @ x0
        self.stats["schur_solves"] += 1
        if residual is None and rhs.size:
            # linear components: S is constant per factorization and component block, so its
            # LU is kept (O((r + s)^2) per step)
            cached = self._schur
            if cached is None or not (
                cached[1] is component_matrix or _same(cached[1], component_matrix)
            ):
                S = self.S0.copy()
                S[:r, :r] += _dense(component_matrix)
                cached = self._schur = (sla.lu_factor(S, check_finite=False), component_matrix)
            xi = sla.lu_solve(cached[0], rhs, check_finite=False)
        else:
            S = self.S0.copy()
            S[:r, :r] += _dense(component_matrix)
            xi = np.linalg.solve(S, rhs) if S.size else np.zeros(0)
        if residual is not None:
            for _ in range(30):
                q, z = xi[:r], xi[r:]
                x_I = x0 - self._X_cols @ q[self._cols]
                res, J = residual(x_I, q, z)
                if not np.all(np.isfinite(res)):
                    raise RunFailed("component Newton: non-finite residual")
                if np.linalg.norm(res) <= 1e-12 * max(1.0, np.linalg.norm(rhs)):
                    break
                S = self.S0.copy()
                S[:r, :r] += _dense(J)
                xi = xi - np.linalg.solve(S, res)
                self.stats["newton_iterations"] += 1
            else:
                raise RunFailed("component Newton did not converge in 30 iterations")
        q, z = xi[:r], xi[r:]
        return x0 - self._X_cols @ q[self._cols], q, z


def coupled_modes(system: CoupledProblem, count: int = 6, lifting: str = "nodal"):
    """The undamped natural modes of the coupled system (no controllers): the generalized
    eigenproblem of K and M restricted to the constraint, u = P^T x_I + Phi q,

        T^T blkdiag(K, K_q) T  v = w^2  T^T blkdiag(rho M, M_q) T  v,   T = [P^T, Phi],

    solved densely (small problems: tests, the examples' reference frequencies and initial
    data). Returns (w (count,), u modes (n, count), q modes (r, count)), w ascending."""
    kern = CoupledStepSystem(system, lifting)
    n, I, r = system.body.space.ndofs, kern.I, kern.r
    T = np.zeros((n, I.size + r))
    T[I, np.arange(I.size)] = 1.0
    T[:, I.size :] = _dense(kern.Phi)
    Kq = np.zeros((r, r))
    for cmp in system.components:
        if not cmp.is_linear:
            raise fail("components", cmp.name, "must be linear for natural modes")
        sl = system.slice(cmp)
        Kq[sl, sl] = _dense(cmp.stiffness)
    KT = T.T @ (kern.K @ T)
    KT[I.size :, I.size :] += Kq
    MT = T.T @ (kern.rho * (kern.M @ T))
    MT[I.size :, I.size :] += _dense(kern.Mq)
    w2, V = sla.eigh(0.5 * (KT + KT.T), 0.5 * (MT + MT.T), subset_by_index=[0, count - 1])
    return np.sqrt(np.maximum(w2, 0.0)), T @ V, V[I.size :]


def modal_rows(system: CoupledProblem, U: np.ndarray, Q: np.ndarray, lifting: str = "nodal"):
    """The rows that project a state (u, q) of the coupled system on its modes (U, Q of
    :func:`coupled_modes`, M-orthonormal): the modal coordinates

        c_k = phi_k^T blkdiag(rho M, M_q) (u, q) = (rho M U_k)^T u + (M_q Q_k)^T q,

    i.e. c = R_u u + R_q q. For a state on the constraint (u = P^T x_I + Phi q, the coupled
    parts moving with q and G = 0) c_k = V_k^T M_T x, the k-th generalized coordinate; a linear
    scheme steps every c_k on its own. Returns (R_u (count, n), R_q (count, r))."""
    kern = CoupledStepSystem(system, lifting)
    R_u = (kern.rho * (kern.M @ U)).T
    R_q = (_dense(kern.Mq) @ Q).T
    return np.ascontiguousarray(R_u), np.ascontiguousarray(R_q)


def closed_loop_matrices(system: CoupledProblem):
    """The semi-discrete closed loop (body on the constraint, components, controllers) as a
    first-order linear system B x' = A x, x = (v, v', z), v = (x_I, q) the generalized
    coordinates of :func:`coupled_modes` (u = P^T x_I + Phi q, nodal lifting):

        M_T v'' + C_T v' + K_T v = E_T w,   w = C_c z + D_c y,   z' = A_c z + B_c y,
        y = Y_u u + Y_v u' + Y_lam lambda = Y_q v + Y_p v' + Y_a v'',

    with M_T = T^T rho M T + blkdiag(0, M_q), C_T, K_T likewise (the body's damping C, the
    components' df/dp, df/dq at rest), E_T = [0; E] (the actuated coordinates) and
    lambda = -M_G^-1 L^T (rho M a + C v + K u) (docs/coupling.md, (C.1)-(C.3) and Sec. 4's
    W = Y_u + kappa Y_v - Y_lam M_G^-1 L^T A with the scheme's kappa -> d/dt), hence
    Y_q = (Y_u - Z^T K) T, Y_p = (Y_v - Z^T C) T, Y_a = -Z^T rho M T, Z = L M_G^-1 Y_lam^T:

        B = [[I, 0, 0], [0, M_T - E_T D_c Y_a, 0], [0, -B_c Y_a, I]],
        A = [[0, I, 0], [-(K_T - E_T D_c Y_q), -(C_T - E_T D_c Y_p), E_T C_c],
             [B_c Y_q, B_c Y_p, A_c]].

    The feedback makes A non-symmetric; nonlinear components and controllers are linearized
    at rest (their Jacobians at t = 0, q = p = 0, z = z_0, y = 0). Returns (A, B) sparse
    (2N + s square, N = |I| + r) and the reduced mass M_T (N x N, sparse, without the
    feedback's term: the norm in which :func:`closed_loop_roots` compares modes)."""
    kern = CoupledStepSystem(system, "nodal")
    n, I, r, s = system.body.space.ndofs, kern.I, kern.r, kern.s
    N = I.size + r
    P_T = sp.csr_matrix((np.ones(I.size), (I, np.arange(I.size))), shape=(n, I.size))
    T = sp.hstack([P_T, sp.csr_matrix(kern.Phi_sparse)], format="csr")
    rhoM, C, K = kern.matrix(1.0, 0.0, 0.0), kern.matrix(0.0, 1.0, 0.0), kern.matrix(0.0, 0.0, 1.0)
    Kq, Cq = np.zeros((r, r)), np.zeros((r, r))
    for cmp in system.components:
        sl = system.slice(cmp)
        dq, dp = cmp.jacobians(0.0, np.zeros(cmp.size), np.zeros(cmp.size))
        Kq[sl, sl], Cq[sl, sl] = _dense(dq), _dense(dp)

    def reduced(A, Aq):
        return (T.T @ A @ T + sp.block_diag([sp.csr_matrix((I.size, I.size)), Aq])).tocsr()

    MT, CT, KT = reduced(rhoM, kern.Mq), reduced(C, Cq), reduced(K, Kq)
    mass = MT
    zero = sp.csr_matrix((N, N))
    if kern.k_in:
        # all sparse: the feedback's terms are of rank k (sensors) on the actuated rows q
        ET = sp.csr_matrix(np.vstack([np.zeros((I.size, kern.o)), kern.E]))  # (N, o)
        Z = sp.csr_matrix(kern._LZ)  # (n, k): L M_G^-1 Y_lam^T, zero without reaction sensors
        Z.eliminate_zeros()
        Yq = ((kern.Y_u - Z.T @ K) @ T).tocsr()
        Yp = ((kern.Y_v - Z.T @ C) @ T).tocsr()
        Ya = (-(Z.T @ rhoM @ T)).tocsr()
        ED = ET @ sp.csr_matrix(kern.Dc)
        MT, KT, CT = MT - ED @ Ya, KT - ED @ Yq, CT - ED @ Yp
        Bc = sp.csr_matrix(kern.Bc)
        Bz, Az = Bc @ Ya, sp.csr_matrix(kern.Ac)
        top_z, rows_z = ET @ sp.csr_matrix(kern.Cc), [Bc @ Yq, Bc @ Yp, Az]
    else:
        Bz = sp.csr_matrix((0, N))
        top_z, rows_z = sp.csr_matrix((N, 0)), [np.zeros((0, N)), np.zeros((0, N)), None]
    eye_N, eye_s = sp.identity(N, format="csr"), sp.identity(s, format="csr")
    B = sp.bmat([[eye_N, None, None], [None, MT, None], [None, -Bz, eye_s]], format="csc")
    A = sp.bmat(
        [
            [zero, eye_N, sp.csr_matrix((N, s))],
            [-sp.csr_matrix(KT), -sp.csr_matrix(CT), top_z],
            [sp.csr_matrix(rows_z[0]), sp.csr_matrix(rows_z[1]), rows_z[2]],
        ],
        format="csc",
    )
    return A, B, mass


def closed_loop_roots(system: CoupledProblem, frequencies, U, Q, count: int = 6) -> np.ndarray:
    """The eigenvalues s = -sigma + i omega of the semi-discrete closed loop
    (:func:`closed_loop_matrices`, A x = s B x) that continue the given undamped modes
    (w_k, U_k, Q_k of :func:`coupled_modes`, typically of the system without controllers):
    for each k the ``count`` eigenvalues nearest i w_k (shift-invert, one complex sparse LU of
    A - s_0 B per mode, s_0 = i w_k (1 + 1e-4) so that an undamped root is not the shift), of
    which the one whose eigenvector's displacement part v has the largest M_T-overlap
    |phi_k^T M_T v| / (|phi_k|_M |v|_M) with phi_k = (U_k on the free dofs, Q_k). sigma_k is
    the mode's decay rate predicted by the discrete body (no time discretization): a run's
    measured rate tends to it as tau -> 0 (docs/coupling.md, Sec. 11). Returns the roots
    (len(frequencies),), complex, Im s > 0."""
    A, B, MT = closed_loop_matrices(system)
    I, N = system.constraint.free, MT.shape[0]
    size = A.shape[0]
    roots = np.empty(len(frequencies), dtype=complex)
    for j, w in enumerate(np.asarray(frequencies, dtype=float)):
        phi = np.concatenate([U[I, j], Q[:, j]])
        shift = 1j * w * (1 + 1e-4) if w > 0 else 1e-4
        lu = spla.splu(sp.csc_matrix(A - shift * B, dtype=complex))
        op = spla.LinearOperator(
            (size, size), matvec=lambda x, lu=lu: lu.solve(B @ x), dtype=complex
        )
        # a fixed start vector: ARPACK's own is random, which made the roots differ in the
        # 14th digit between two runs of one command (summary.json not reproducible)
        rng = np.random.default_rng(j)
        start = rng.standard_normal(size) + 1j * rng.standard_normal(size)
        mu, vecs = spla.eigs(op, k=min(count, size - 2), which="LM", v0=start)  # (k < size - 1)
        vals = shift + 1.0 / mu
        v = vecs[:N]
        Mphi = MT @ phi
        overlap = np.abs(Mphi @ v) / np.sqrt(
            (phi @ Mphi) * np.einsum("ij,ij->j", v.conj(), MT @ v).real
        )
        overlap[vals.imag < 0] = -1.0
        best = int(np.argmax(overlap - 1e-9 * np.abs(vals - shift)))
        roots[j] = vals[best]
    return roots
