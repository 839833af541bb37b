"""One coupled step as a bordered linear system, and a small reference integrator (issue 19).

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

The original form (2.7) with the same couplings is this system with the nodal lifting and the
data differenced, g'_k = delta g_k, g''_k = delta g'_k (the boundary velocity and
acceleration of the original form are the scheme's quotients of S u = g): the two forms differ
only where data enter separately -- prescribed G', G'' and the noise of Theorem 4.5.

:class:`CoupledStepSystem` is the algebra of one step (what phase 2 wires into the stepper);
:func:`run_coupled_reference` is a plain uniform-step loop over it for small problems (tests,
the derivation's checks: energy ledger, orders, frequencies, noise), not the production
stepper (no adaptivity, checkpoints or outputs).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import RunFailed, check_positive, fail
from ..stepping.evolve import single_threaded_blas
from .constraint import HarmonicLifting, NodalLifting
from .coupling import CoupledProblem

SCHEMES = ("euler", "bdf2")
FORMS = ("regularized", "original")


def step_alphas(scheme: str, tau: float, tau_prev: float | None) -> tuple[float, float, float]:
    """(alpha_0, alpha_1, alpha_2): Euler (1, -1, 0); BDF2 with omega = tau/tau_prev
    ((1 + 2 omega)/(1 + omega), -(1 + omega), omega^2/(1 + omega)) (= 3/2, -2, 1/2)."""
    if scheme == "euler":
        return 1.0, -1.0, 0.0
    w = 1.0 if tau_prev is None else tau / tau_prev
    return (1 + 2 * w) / (1 + w), -(1 + w), w * w / (1 + w)


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
        self.Gamma = system.gamma().toarray()
        self.Phi = system.lifted_modes(self.lifting)  # (n, r)
        self.r = system.size
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
        self._key = None

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

    def factor(
        self, cm: float, cc: float, ck: float, wu: float, wv: float, kappa_z: float | None
    ) -> None:
        """Factor A_II of A = cm rho M + cc C + ck K and build the border: X = A_II^{-1}
        (A Phi)_I (r back-substitutions), W = wu Y_u + wv Y_v - Y_lam M_G^{-1} L^T A, V, the
        part of the Schur complement that does not depend on the components' Jacobian.
        ``kappa_z``: controller states are unknowns with delta z = kappa_z z + c_z (None:
        they are known, e.g. for the consistent initial acceleration)."""
        key = (cm, cc, ck, wu, wv, kappa_z)
        if key == self._key:
            return
        I = self.I
        A = self.matrix(cm, cc, ck)
        self.A = A
        self._lu = spla.splu(sp.csc_matrix(A[I][:, I]), permc_spec="MMD_AT_PLUS_A")
        self.stats["factorizations"] += 1
        APhi = A @ self.Phi  # (n, r)
        PhiA = (A.T @ self.Phi).T  # Phi^T A (r, n)
        self.X = self._lu.solve(APhi[I]) if self.r else np.zeros((I.size, 0))
        self.stats["back_substitutions"] += self.r
        # sensor rows: W (k, n) = wu Y_u + wv Y_v - (A^T L Z)^T
        W = (wu * self.Y_u + wv * self.Y_v).toarray()
        if self.k_in:
            W = W - (A.T @ self._LZ).T
        self.W = W
        r, s = self.r, self.s if kappa_z is not None else 0
        EDW = self.E @ (self.Dc @ W) if self.k_in else np.zeros((r, A.shape[0]))
        V = np.zeros((r + s, I.size))
        V[:r] = (PhiA - EDW)[:, I]
        if s:
            V[r:] = -(self.Bc @ W)[:, I]
        self.V = V
        C = np.zeros((r + s, r + s))
        C[:r, :r] = PhiA @ self.Phi - EDW @ self.Phi
        if s:
            C[:r, r:] = -self.E @ self.Cc
            C[r:, :r] = -self.Bc @ (W @ self.Phi)
            C[r:, r:] = kappa_z * np.eye(s) - self.Ac
        # Schur complement without the components' block: C - V [X, 0]
        C[:, :r] -= V @ self.X
        self.S0 = C
        self._with_z = kappa_z is not None
        self._key = key

    def back_substitute(self, rhs_I: np.ndarray) -> np.ndarray:
        """K_II^{-1} rhs_I with the stored factorization (counted in the stats)."""
        self.stats["back_substitutions"] += 1
        return self._lu.solve(rhs_I)

    def solve(self, rhs_I, rhs_q, rhs_z, component_matrix, residual=None):
        """(x_I, q, z) of the bordered system (module docstring) for the right sides
        ``rhs_I`` (-r_k,I), ``rhs_q``, ``rhs_z`` and the components' block
        ``component_matrix`` (kappa^2 M_q + kappa C_q + K_q, or the Jacobian of a nonlinear
        component). With ``residual`` (a callable (x_I, q, z) -> the component rows' residual,
        for nonlinear components) Newton on (q, z) with that Jacobian."""
        x0 = self.back_substitute(rhs_I)
        r = self.r
        S = self.S0.copy()
        S[:r, :r] += component_matrix
        rhs = np.concatenate([rhs_q, rhs_z if self._with_z else np.zeros(0)]) - self.V @ x0
        self.stats["schur_solves"] += 1
        xi = np.linalg.solve(S, rhs) if S.size else np.zeros(0)
        if residual is not None:
            for _ in range(30):
                q, z = xi[:r], xi[r:]
                x_I = x0 - self.X @ q
                res, J = residual(x_I, q, z)
                if not np.all(np.isfinite(res)):
                    raise RunFailed("component Newton: non-finite residual")
                if np.linalg.norm(res) <= 1e-12 * max(1.0, np.linalg.norm(rhs)):
                    break
                S = self.S0.copy()
                S[:r, :r] += J
                xi = xi - np.linalg.solve(S, res)
                self.stats["newton_iterations"] += 1
            else:
                raise RunFailed("component Newton did not converge in 30 iterations")
        q, z = xi[:r], xi[r:]
        return x0 - self.X @ q, q, z


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
    T[:, I.size :] = kern.Phi
    Kq = np.zeros((r, r))
    for cmp in system.components:
        if not cmp.is_linear:
            raise fail("components", cmp.name, "must be linear for natural modes")
        sl = system.slice(cmp)
        Kq[sl, sl] = cmp.stiffness
    KT = T.T @ (kern.K @ T)
    KT[I.size :, I.size :] += Kq
    MT = T.T @ (kern.rho * (kern.M @ T))
    MT[I.size :, I.size :] += kern.Mq
    w2, V = sla.eigh(0.5 * (KT + KT.T), 0.5 * (MT + MT.T), subset_by_index=[0, count - 1])
    return np.sqrt(np.maximum(w2, 0.0)), T @ V, V[I.size :]


def _taylor(x0, v0, a0, h):
    """(x(-h), v(-h)) of the quadratic Taylor polynomial."""
    return x0 - h * v0 + 0.5 * h * h * a0, v0 - h * a0


def run_coupled_reference(
    system: CoupledProblem,
    tau: float,
    T: float | None = None,
    *,
    scheme: str = "euler",
    form: str = "regularized",
    lifting: str = "nodal",
    noise=None,
    watch=None,
) -> dict:
    """Uniform steps of the coupled scheme (see :func:`_run`), with BLAS on one thread as in
    the evolve loop (threaded level-1 BLAS spin-waits on busy cores)."""
    with single_threaded_blas():
        return _run(
            system, tau, T, scheme=scheme, form=form, lifting=lifting, noise=noise, watch=watch
        )


def _run(
    system: CoupledProblem,
    tau: float,
    T: float | None = None,
    *,
    scheme: str = "euler",
    form: str = "regularized",
    lifting: str = "nodal",
    noise=None,
    watch=None,
) -> dict:
    """Uniform steps of the coupled scheme (module docstring) from t = 0 to T.

    Parameters
    ----------
    system : CoupledProblem (linear body damping, linear couplings; components may be
        nonlinear, solved by Newton on the border unknowns)
    tau : step; T : end time (default the body's T), a multiple of tau
    scheme : 'euler' | 'bdf2' (BDF2 starts from a Taylor history with the consistent initial
        accelerations)
    form : 'regularized' (g', g'' of the known data evaluated: prescribed G_dot, G_ddot) or
        'original' (nodal lifting, the known data differenced: the original form (2.7))
    noise : callable j -> (theta, xi, vartheta), each (r,) or None: perturbations of the
        coordinates that enter the coupling data at step j = 1..n (the component's outputs
        seen by the body; the initial state is exact). Regularized form:
        g = ... + Gamma (q + theta), g' = ... + Gamma (p + xi), g'' = ... + Gamma (pdot +
        vartheta); original form: only theta (its quotients enter through the differenced
        data).
    watch : sparse (k, n) rows, recorded on u at every step (``watch_u``) and on v
        (``watch_v``)

    Returns
    -------
    dict of arrays over the states j = 0..n: t, q, p, z, lam_norm, energy (body + components),
    the ledger terms and ``balance`` (their mismatch, round-off), watch_u/watch_v; the final
    fields u, v, a, lam; ``stats`` (factorizations, back-substitutions, ...).
    """
    if scheme not in SCHEMES:
        raise fail("scheme", scheme, "must be one of " + ", ".join(SCHEMES))
    if form not in FORMS:
        raise fail("form", form, "must be one of " + ", ".join(FORMS))
    tau = check_positive("tau", tau)
    body = system.body
    T = body.T if T is None else check_positive("T", T)
    n_steps = int(round(T / tau))
    if not math.isclose(n_steps * tau, T, rel_tol=1e-9):
        raise fail("tau", tau, f"must divide T = {T:g} into equal steps")
    if form == "original" and lifting != "nodal":
        raise fail("lifting", lifting, "must be nodal in the original form")
    kern = CoupledStepSystem(system, lifting)
    c = kern.constraint
    I, n, r, s = kern.I, body.space.ndofs, kern.r, kern.s
    rho, M, K, D = kern.rho, kern.M, kern.K, kern.D
    Gam, Phi, Mq = kern.Gamma, kern.Phi, kern.Mq
    comps_linear = all(cmp.is_linear for cmp in system.components)
    ctrls = system.controllers

    Cmat = D.linear  # small problems: C assembled once
    BT = c.B.T.tocsr()
    rhoM = (rho * M).tocsr()

    def C_apply(v):
        return Cmat @ v

    def comp_force(t, q, p):
        return system.force(t, q, p)

    def noise_at(j):
        if noise is None:
            return np.zeros(r), np.zeros(r), np.zeros(r)
        th, xi, vt = noise(j)
        return (
            np.zeros(r) if th is None else np.asarray(th, float),
            np.zeros(r) if xi is None or form == "original" else np.asarray(xi, float),
            np.zeros(r) if vt is None or form == "original" else np.asarray(vt, float),
        )

    # -- initial state: consistent u0, v0 trace, accelerations (the index-1 system) -----------
    q0, p0 = system.q0, system.p0
    z0 = np.concatenate([k.z0 for k in ctrls]) if ctrls else np.zeros(0)
    gk0 = body.G(0.0)  # (noise from the first step on: the initial state is exact)
    gdk0 = body.G_dot(0.0)
    gddk0 = body.G_ddot(0.0)
    system.check_initial_consistency()
    u0 = body.u0.copy()
    u0[c.dofs] = gk0 + Gam @ q0
    v0 = body.v0.copy()
    v0[c.dofs] = gdk0 + Gam @ p0
    F0 = body.load(0.0)
    # accelerations: X = a_1 + Phi pdot, r = rho M X + r_k; W only through lambda
    kern.factor(1.0, 0.0, 0.0, 0.0, 0.0, None)
    r_k = rho * (M @ kern.lift(gddk0)) + C_apply(v0) + K @ u0 - F0
    y_k = kern.Y_u @ u0 + kern.Y_v @ v0 - kern._LZ.T @ r_k if kern.k_in else np.zeros(0)
    w_k = kern.Cc @ z0 + kern.Dc @ y_k if kern.o else np.zeros(0)
    rhs_q = system.load(0.0) - comp_force(0.0, q0, p0) - Phi.T @ r_k + kern.E @ w_k
    a1_I, pdot0, _ = kern.solve(-r_k[I], rhs_q, np.zeros(0), Mq)
    a0 = np.zeros(n)
    a0[I] = a1_I
    a0 = a0 + kern.lift(gddk0) + Phi @ pdot0
    res0 = rho * (M @ a0) + C_apply(v0) + K @ u0 - F0
    lam0 = kern.multiplier(res0)
    ys0 = kern.Y_u @ u0 + kern.Y_v @ v0 + kern.Y_lam @ lam0 if kern.k_in else np.zeros(0)
    zdot0 = kern.Ac @ z0 + kern.Bc @ ys0 if s else np.zeros(0)

    def split(u_, v_, q_, p_):
        """Free parts x = u - L(S u), y = v - L(S v) and the known data g_k = S u - Gamma q,
        g'_k = S v - Gamma p."""
        gu, gv = u_[c.dofs], v_[c.dofs]
        x_ = u_ - kern.lift(gu)
        y_ = v_ - kern.lift(gv)
        x_[c.dofs] = 0.0
        y_[c.dofs] = 0.0
        return x_, y_, gu - Gam @ q_, gv - Gam @ p_

    x_0, y_0, gk_0, gdk_0 = split(u0, v0, q0, p0)
    hist = {
        "x": [x_0],
        "y": [y_0],
        "q": [q0],
        "p": [p0],
        "z": [z0],
        "gk": [gk_0],
        "gdk": [gdk_0],
        "u": [u0],
        "v": [v0],
    }
    if scheme == "bdf2":
        um, vm = _taylor(u0, v0, a0, tau)
        qm, pm = _taylor(q0, p0, pdot0, tau)
        zm = z0 - tau * zdot0
        xm, ym, gkm, gdkm = split(um, vm, qm, pm)
        for key, val in (
            ("x", xm),
            ("y", ym),
            ("q", qm),
            ("p", pm),
            ("z", zm),
            ("gk", gkm),
            ("gdk", gdkm),
            ("u", um),
            ("v", vm),
        ):
            hist[key].insert(0, val)

    Mqs = system.mass()
    Kq_lin = np.zeros((r, r))
    Cq_lin = np.zeros((r, r))
    for cmp in system.components:
        if cmp.is_linear:
            sl = system.slice(cmp)
            Kq_lin[sl, sl], Cq_lin[sl, sl] = cmp.stiffness, cmp.damping

    def energies(u_, v_, q_, p_):
        """Body energy; components: kinetic + the potential of the linear ones (the work of
        a nonlinear component's force is booked whole in ``dissipated``)."""
        kin, _ = system.component_energy(q_, p_)
        return 0.5 * rho * v_ @ (M @ v_) + 0.5 * u_ @ (K @ u_), kin + 0.5 * q_ @ (Kq_lin @ q_)

    Eb, Ec = energies(u0, v0, q0, p0)
    out = {
        k: []
        for k in (
            "t",
            "q",
            "p",
            "z",
            "lam_norm",
            "energy",
            "energy_body",
            "energy_components",
            "work",
            "work_components",
            "work_controllers",
            "work_prescribed",
            "dissipated",
            "numerical_dissipation",
            "data_mismatch",
            "residual_work",
            "balance",
            "watch_u",
            "watch_v",
            "residual_body",
            "residual_components",
        )
    }
    ledger = dict.fromkeys(
        (
            "work",
            "work_components",
            "work_controllers",
            "work_prescribed",
            "dissipated",
            "numerical_dissipation",
            "data_mismatch",
            "residual_work",
        ),
        0.0,
    )
    reactions = {part: [] for part in c.parts}

    def record(t, u_, v_, q_, p_, z_, lam_, Eb_, Ec_, balance):
        out["t"].append(t)
        out["q"].append(q_.copy())
        out["p"].append(p_.copy())
        out["z"].append(z_.copy())
        out["lam_norm"].append(c.l2_norm(lam_))
        out["energy_body"].append(Eb_)
        out["energy_components"].append(Ec_)
        out["energy"].append(Eb_ + Ec_)
        for key, val in ledger.items():
            out[key].append(val)
        out["balance"].append(balance)
        if watch is not None:
            out["watch_u"].append(watch @ u_)
            out["watch_v"].append(watch @ v_)
        for part, R in c.reactions(lam_).items():
            reactions[part].append(R)

    record(0.0, u0, v0, q0, p0, z0, lam0, Eb, Ec, 0.0)
    out["residual_body"].append(0.0)
    out["residual_components"].append(0.0)
    E_start = Eb + Ec
    tau_prev = None
    u, v, a, lam = u0, v0, a0, lam0
    for j in range(1, n_steps + 1):
        t = j * tau
        al0, al1, al2 = step_alphas(scheme, tau, tau_prev if scheme == "bdf2" else None)
        if scheme == "bdf2" and j == 1:
            al0, al1, al2 = step_alphas("bdf2", tau, tau)
        kap = al0 / tau

        def hpart(key, al1=al1, al2=al2):
            h = hist[key]
            out_ = al1 * h[-1]
            if al2 != 0.0:
                out_ = out_ + al2 * h[-2]
            return out_ / tau

        c_x, c_y = hpart("x"), hpart("y")
        c_q, c_p, c_z = hpart("q"), hpart("p"), (hpart("z") if s else np.zeros(0))
        th, xi, vt = noise_at(j)
        gk = body.G(t) + Gam @ th
        if form == "regularized":
            gdk = body.G_dot(t) + Gam @ xi
            gddk = body.G_ddot(t) + Gam @ vt
        else:  # the original form: the known data differenced with the scheme's quotients
            gdk = kap * gk + hpart("gk")
            gddk = kap * gdk + hpart("gdk")
        u_k = kern.lift(gk)
        v_k = c_x + kern.lift(gdk) + Phi @ c_q
        a_k = kap * c_x + c_y + kern.lift(gddk) + Phi @ (kap * c_q + c_p)
        F = body.load(t)
        r_k = rhoM @ a_k + C_apply(v_k) + K @ u_k - F
        kern.factor(kap * kap, kap, 1.0, 1.0, kap, kap)
        y_k = (kern.Y_u @ u_k + kern.Y_v @ v_k - kern._LZ.T @ r_k) if kern.k_in else np.zeros(0)
        pd_k = kap * c_q + c_p  # pdot = kappa^2 q + pd_k
        f_ext = system.load(t)
        w_k = kern.Dc @ y_k if kern.o else np.zeros(0)
        if comps_linear:
            rhs_q = f_ext - Mqs @ pd_k - Cq_lin @ c_q - Phi.T @ r_k + kern.E @ w_k
            Jq = kap * kap * Mqs + kap * Cq_lin + Kq_lin
            x_I, q, z = kern.solve(-r_k[I], rhs_q, kern.Bc @ y_k - c_z if s else np.zeros(0), Jq)
        else:

            def residual(
                x_I, q_, z_, t=t, pd_k=pd_k, r_k=r_k, y_k=y_k, f_ext=f_ext, c_q=c_q, kap=kap
            ):
                p_ = kap * q_ + c_q
                pdot_ = kap * kap * q_ + pd_k
                X = np.zeros(n)
                X[I] = x_I
                X = X + Phi @ q_
                r_full = kern.A @ X + r_k
                ys = kern.W @ X + y_k if kern.k_in else np.zeros(0)
                w = kern.Cc @ z_ + kern.Dc @ ys if kern.o else np.zeros(0)
                res = Mqs @ pdot_ + comp_force(t, q_, p_) + Phi.T @ r_full - f_ext - kern.E @ w
                fq, fp = system.force_jacobians(t, q_, p_)
                return res, kap * kap * Mqs + kap * fp + fq

            x_I, q, z = kern.solve(
                -r_k[I],
                f_ext - Mqs @ pd_k - Phi.T @ r_k + kern.E @ w_k,
                kern.Bc @ y_k - c_z if s else np.zeros(0),
                kap * kap * Mqs,
                residual=residual,
            )
        x = np.zeros(n)
        x[I] = x_I
        y = kap * x + c_x
        b = kap * y + c_y
        p = kap * q + c_q
        pdot = kap * p + c_p
        u = x + kern.lift(gk + Gam @ q)
        v = y + kern.lift(gdk + Gam @ p)
        a = b + kern.lift(gddk + Gam @ pdot)
        res = rhoM @ a + C_apply(v) + K @ u - F
        lam = kern.multiplier(res)
        R = res + BT @ lam  # algebraic residual of the body rows (solver tolerance)
        ys = kern.Y_u @ u + kern.Y_v @ v + kern.Y_lam @ lam if kern.k_in else np.zeros(0)
        w = kern.Cc @ z + kern.Dc @ ys if kern.o else np.zeros(0)
        Rq = Mqs @ pdot + comp_force(t, q, p) - Gam.T @ (c.boundary_mass @ lam) - f_ext - kern.E @ w

        # -- ledger (docs/coupling.md, Sec. 5) ----------------------------------------------------
        def quot(key, now, al0=al0, al1=al1, al2=al2):
            h = hist[key]
            val = al0 * now + al1 * h[-1]
            return (val + al2 * h[-2]) / tau if al2 != 0.0 else val / tau

        def N(key, now, W, al0=al0, al2=al2):
            h = hist[key]
            dz = now - h[-1]
            out_ = 0.5 * dz @ (W @ dz)
            dprev = h[-1] - h[-2] if al2 != 0.0 else 0.0 * dz
            return out_ + now @ (W @ ((al0 - 1.0) * dz - al2 * dprev))

        num = N("v", v, rhoM) + N("u", u, K) + N("p", p, Mqs) + N("q", q, Kq_lin)
        mism = tau * (rhoM @ (a - quot("v", v))) @ v + tau * (K @ u) @ (v - quot("u", u))
        # the components' quotients are exact (p = delta q, pdot = delta p), no mismatch
        ledger["work"] += tau * F @ v
        ledger["work_components"] += tau * f_ext @ p
        ledger["work_controllers"] += tau * p @ (kern.E @ w) if kern.o else 0.0
        diss = tau * C_apply(v) @ v + tau * p @ (Cq_lin @ p)
        if not comps_linear:  # the whole work of the nonlinear components' forces
            diss += tau * p @ (comp_force(t, q, p) - Kq_lin @ q - Cq_lin @ p)
        ledger["dissipated"] += diss
        ledger["work_prescribed"] += -tau * lam @ (c.boundary_mass @ gdk)
        ledger["numerical_dissipation"] += num
        ledger["data_mismatch"] += mism
        ledger["residual_work"] += tau * R @ v + tau * Rq @ p
        Eb, Ec = energies(u, v, q, p)
        out["residual_body"].append(
            float(np.abs(R).max() / max(1.0, np.abs(F).max(), np.abs(K @ u).max()))
        )
        out["residual_components"].append(float(np.abs(Rq).max(initial=0.0)))
        balance = (Eb + Ec - E_start) - (
            ledger["work"]
            + ledger["work_components"]
            + ledger["work_controllers"]
            + ledger["work_prescribed"]
            - ledger["dissipated"]
            + ledger["residual_work"]
            - ledger["numerical_dissipation"]
            - ledger["data_mismatch"]
        )
        record(t, u, v, q, p, z, lam, Eb, Ec, balance)
        x_now, y_now, gk_now, gdk_now = x, y, gk, gdk
        for key, val in (
            ("x", x_now),
            ("y", y_now),
            ("q", q),
            ("p", p),
            ("z", z),
            ("gk", gk_now),
            ("gdk", gdk_now),
            ("u", u),
            ("v", v),
        ):
            hist[key].append(val)
            if len(hist[key]) > 3:
                hist[key].pop(0)
        tau_prev = tau
    result = {k: np.asarray(val) for k, val in out.items()}
    for part, vals in reactions.items():
        result[f"reaction_{part}"] = np.asarray(vals)
    result.update(u=u, v=v, a=a, lam=lam, stats=dict(kern.stats), n_steps=n_steps)
    return result
