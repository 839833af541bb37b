"""Implicit Euler (3.4) for the elastodynamic operator DAE, in the original and regularized forms.

With D u^j = (u^j - u^{j-1})/tau and D^2 u^j = (u^j - 2 u^{j-1} + u^{j-2})/tau^2 (t_j = j tau):

``original`` -- the index-3 saddle-point system (2.7) discretized directly: per step
    rho M D^2 u^j + D(D u^j) + K u^j + B^T lambda^j = F^j,      B u^j = G^j,
    one (nonlinear if D is) saddle-point system for (u^j, lambda^j).

``regularized`` -- the index-1 form (2.8) discretized as (3.4): per step
    u_2^j = B^- G^j,  v_2^j = B^- G_dot^j,  w_2^j = B^- G_ddot^j        (3.4b)
    u_1^j in V_B = ker B from (3.4a) tested with V_B:
      rho M (D^2 u_1^j + w_2^j) + D(D u_1^j + v_2^j) + K (u_1^j + u_2^j) = F^j   on V_B,
    lambda^j from (3.4a) tested with V^c (:meth:`DirichletConstraint.multiplier_from_residual`);
    u^j = u_1^j + u_2^j, velocity v^j = D u_1^j + v_2^j, acceleration a^j = D^2 u_1^j + w_2^j.
    B^- is a fixed right inverse of B (:mod:`rothe.eld.constraint`; default: nodal lifting).

Start-up (the paper takes u_1^1, v_1^1 as given data): u^0 = g, u^{-1} = g - tau h, so that
D u^0 = h, and the steps j = 1, ..., n = T/tau follow. In the regularized form u_1^0 =
g - B^- G^0 and v_1^0 = h - B^- G_dot^0 (with their Gamma_D values set to zero: h need not match
G_dot(0), Remark 2.2), u_1^{-1} = u_1^0 - tau v_1^0. Unique solvability needs tau < rho/d0
(Lemma 3.2); it is checked before the first step, together with B g = G(0) (Remark 2.2).

Linear damping: the step matrix (rho/tau^2) M + C/tau + K (on ker B, or bordered by B) is factored
once and every step is back-substitutions. Nonlinear damping: Newton's method with backtracking,
its systems solved by Krylov iterations preconditioned with a stored factorization
(:mod:`rothe.eld.solvers`). A Newton solve that fails stops the run with :class:`RunFailed`
(the step is never accepted).

Energy bookkeeping (the discrete energy identity of the scheme). Testing the full equation
rho M a + D v + K u + B^T lambda = F with tau v^j and using 2 (a - b) a = a^2 - b^2 + (a - b)^2:

    E^j - E^{j-1} = tau F.v  - tau lambda.(B v)  - tau D(v).v  - N^j  - X^j,
    E = 1/2 rho v.M v + 1/2 u.K u,
    N^j = 1/2 rho |v^j - v^{j-1}|_M^2 + 1/2 |u^j - u^{j-1}|_K^2 >= 0   (numerical dissipation),
    X^j = rho tau M(a^j - D v^j).v^j + tau K u^j.(v^j - D u^j)           (data mismatch),

i.e. work of the loads, work of the support (reaction) on the prescribed boundary motion, physical
dissipation, numerical dissipation of implicit Euler, and a term that vanishes when G_dot, G_ddot
are the difference quotients of G (always in the original form; O(tau) per unit time in the
regularized form with exact derivatives). The trajectory holds these sums and the residual of
the balance, which closes to solver tolerance.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..control.controllers import UniformController
from ..errors import RunFailed, check_choice, check_positive, fail
from ..io.checkpoint import RunCheckpointing, run_arguments
from ..io.trajectory import Trajectory
from ..stepping.evolve import evolve
from .constraint import LIFTINGS, make_lifting
from .data import DATA_MODES, DataNoise, StepData
from .problem import ELDProblem
from .solvers import ReferenceSolver, SolveFailed, resolve_kind

FORMS = ("regularized", "original")


@dataclass
class NewtonOptions:
    """Newton's method for nonlinear damping: stop when the (estimated) error of the iterate is
    below ``tol`` times the size of the unknown, at most ``max_iter`` iterations. The Newton
    corrections are solved to the relative residual ``krylov_rtol`` (inexact Newton: the
    iteration then contracts by about that factor, and the stopping test still asks for
    ``tol``)."""

    tol: float = 1e-10
    max_iter: int = 25
    krylov_rtol: float = 1e-4

    def __post_init__(self):
        self.tol = check_positive("newton tol", self.tol)
        self.krylov_rtol = check_positive("newton krylov_rtol", self.krylov_rtol)
        if int(self.max_iter) < 1:
            raise fail("newton max_iter", self.max_iter, "must be >= 1")


@dataclass
class EnergyLedger:
    """Cumulative terms of the discrete energy identity (see the module docstring)."""

    kinetic: float = 0.0
    elastic: float = 0.0
    initial: float = 0.0
    work: float = 0.0  # loads F
    work_reaction: float = 0.0  # support on the prescribed boundary motion: -tau lambda.B v
    dissipated: float = 0.0  # physical: tau D(v).v
    numerical: float = 0.0  # implicit Euler: N^j
    mismatch: float = 0.0  # X^j

    @property
    def energy(self) -> float:
        return self.kinetic + self.elastic

    @property
    def residual(self) -> float:
        """E^j - E^0 - (work + work_reaction - dissipated - numerical - mismatch)."""
        return self.energy - self.initial - (self.work + self.work_reaction - self.dissipated
                                             - self.numerical - self.mismatch)


@dataclass
class ELDState:
    s: float  # the evolve loop's curve parameter: here the time
    t: float
    j: int
    x: np.ndarray  # the scheme's unknown at t_j: u_1^j (regularized) or u^j (original)
    x_prev: np.ndarray  # ... at t_{j-1}
    u: np.ndarray  # u^j
    v: np.ndarray  # v^j (the scheme's velocity)
    Ku: np.ndarray
    Mv: np.ndarray
    lam: np.ndarray | None
    ledger: EnergyLedger
    # M x, K x of the scheme's unknown at t_j and t_{j-1}: every other product of a step is a
    # combination of these and of thin products with the lifted boundary data, so a step with
    # linear damping needs two sparse products besides the back-substitution
    Mx: np.ndarray | None = None
    Kx: np.ndarray | None = None
    Mx_prev: np.ndarray | None = None
    Kx_prev: np.ndarray | None = None


@dataclass
class ELDStepResult:
    state: ELDState
    tau: float
    lam: np.ndarray
    reactions: dict
    newton_iterations: int
    du: np.ndarray | None = None  # (u^j - u^{j-1})/tau, = v^j in the original form
    counters: dict = field(default_factory=dict)
    converged: bool = True
    code: str = "ok"

    @property
    def errors(self) -> dict:
        return {}


@dataclass
class _Kinematics:
    """The fields of one step and the products the energy identity and lambda need."""

    x: np.ndarray
    Mx: np.ndarray
    Kx: np.ndarray
    u: np.ndarray | None = None
    v: np.ndarray | None = None
    Ku: np.ndarray | None = None
    Mv: np.ndarray | None = None
    Ma: np.ndarray | None = None
    Dv: np.ndarray | None = None
    lam: np.ndarray | None = None


class ELDStepper:
    """One Euler step of (3.4) in either form; the evolve loop (fixed step) drives it.

    Parameters
    ----------
    problem : ELDProblem
    form : 'regularized' | 'original'
    tau : step size; T / tau must be an integer
    data : 'points' | 'means' | 'differenced'  (:mod:`rothe.eld.data`)
    lifting : 'nodal' | 'harmonic'  (the right inverse B^-, regularized form)
    solver : 'auto' | 'direct' | 'amg'
    noise : DataNoise, optional perturbation of the data of every step (Sec. 4.3)
    store_fields : keep u, v, lambda of every step in the trajectory
    observer : callable(state, result) after every accepted step (e.g. to write XDMF)
    linear_rtol : relative residual of iterative linear solves
    """

    def __init__(self, problem: ELDProblem, form: str, tau: float, *, data: str = "points",
                 lifting: str = "nodal", solver: str = "auto", newton: NewtonOptions | None = None,
                 noise: DataNoise | None = None, store_fields: bool = True, observer=None,
                 linear_rtol: float = 1e-10):
        self.problem = problem
        self.form = check_choice("form", form, FORMS)
        self.tau = tau = check_positive("tau", tau)
        bound = problem.step_bound()
        if not tau < bound:
            raise fail("tau", tau, f"must be < rho/d0 = {bound:g} (Lemma 3.2: unique solvability "
                       "of the Euler steps)")
        ratio = problem.T / tau
        self.n_steps = int(round(ratio))
        if self.n_steps < 1 or abs(ratio - self.n_steps) > 1e-9 * max(1.0, ratio):
            raise fail("tau", tau, f"must divide T = {problem.T:g} into equal steps "
                       f"(T/tau = {ratio:.6g})")
        self.data_mode = check_choice("data", data, DATA_MODES)
        self.lifting_kind = check_choice("lifting", lifting, LIFTINGS)
        self.newton = newton or NewtonOptions()
        self.store_fields = bool(store_fields)
        self.observer = observer
        problem.check_initial_consistency()
        self.data = StepData(problem, tau, data, noise)

        p = problem
        c = p.constraint
        self.rho = p.material.rho
        self.D = p.damping_op
        self.I = c.free
        n = p.space.ndofs
        # A = (rho/tau^2) M + C/tau + K with C = a_M M + a_K K (+ E), without forming C
        D = self.D
        A = ((self.rho / tau**2 + D.mass_coef / tau) * p.M
             + (1.0 + D.stiffness_coef / tau) * p.K).tocsr()
        if D.matrix is not None:
            A = (A + (1.0 / tau) * D.matrix).tocsr()
        if self.form == "regularized":
            self.kind = resolve_kind(solver, self.I.size, p.space.dim)
            rbm = p.space.rigid_body_modes()[self.I] if self.kind == "amg" else None
            self.solver = ReferenceSolver(self.kind, spd=True, near_nullspace=rbm, rtol=linear_rtol)
            self.A_II = A[self.I][:, self.I].tocsr()
            del A  # at a million unknowns every matrix of this size costs 0.6 GB
            if self.D.is_linear:
                self.solver.factor(self.A_II)
            self.lifting = make_lifting(self.lifting_kind, c, p.K)
            if self.lifting_kind == "nodal":
                # B^- g = S^T g: products with lifted data only touch the columns of Gamma_D
                self._M_C = p.M[:, c.dofs].tocsr()
                self._K_C = p.K[:, c.dofs].tocsr()
        else:
            self.kind = resolve_kind(solver, n + c.m, p.space.dim)
            if self.kind == "amg":
                raise fail("solver", solver if solver != "auto" else "auto (amg at this size)",
                           "the original form's saddle-point system is solved by sparse LU only; "
                           "use the regularized form for AMG")
            self.solver = ReferenceSolver("direct", spd=False, rtol=linear_rtol)
            self.A = A
            self._kkt_lin = self._kkt(A)
            if self.D.is_linear:
                self.solver.factor(self._kkt_lin)
            self.lifting = None
        self.initial_factorizations = self.solver.stats.factorizations
        self._last_newton = 0

    def _kkt(self, A) -> sp.csr_matrix:
        B = self.problem.constraint.B
        return sp.bmat([[A, B.T], [B, None]], format="csr")

    # -- initial state --------------------------------------------------------------------------
    def initial_state(self) -> ELDState:
        p, tau = self.problem, self.tau
        c = p.constraint
        G0, G_dot0 = self.data.initial()
        if self.form == "regularized":
            u2, v2 = self.lifting.lift_many([G0, G_dot0])
            x = p.u0 - u2
            x[c.dofs] = 0.0
            v1 = p.v0 - v2
            v1[c.dofs] = 0.0
            x_prev = x - tau * v1
            u, v = x + u2, v1 + v2
        else:
            x = p.u0.copy()
            x_prev = p.u0 - tau * p.v0
            u, v = x, p.v0.copy()
        Ku, Mv = p.K @ u, p.M @ v
        e0 = 0.5 * self.rho * float(v @ Mv) + 0.5 * float(u @ Ku)
        ledger = EnergyLedger(kinetic=0.5 * self.rho * float(v @ Mv), elastic=0.5 * float(u @ Ku),
                              initial=e0)
        return ELDState(s=0.0, t=0.0, j=0, x=x, x_prev=x_prev, u=u, v=v, Ku=Ku, Mv=Mv, lam=None,
                        ledger=ledger, Mx=p.M @ x, Kx=p.K @ x, Mx_prev=p.M @ x_prev,
                        Kx_prev=p.K @ x_prev)

    def record_initial(self, traj: Trajectory, state: ELDState) -> None:
        L = state.ledger
        rec = dict(t=0.0, kinetic=L.kinetic, elastic=L.elastic, energy=L.energy, work=0.0,
                   work_reaction=0.0, dissipated=0.0, numerical_dissipation=0.0,
                   data_mismatch=0.0, balance_residual=0.0)
        if self.store_fields:
            rec.update(u=state.u.copy(), v=state.v.copy(), du=state.v.copy())
        traj.append(**rec)

    # -- evolve-loop interface ------------------------------------------------------------------
    def finished(self, state: ELDState) -> bool:
        return state.j >= self.n_steps

    def limit(self, state: ELDState, tau: float) -> float:
        return tau

    def overshoot(self, state, attempts):
        return None  # t_n = n tau = T exactly: equal steps never overshoot

    def pick_landing(self, state, attempts):
        return attempts[-1]

    def where(self, state: ELDState, result=None) -> dict:
        info = {"step": state.j + 1, "s": state.t, "t": state.t, "tau": self.tau,
                "form": self.form}
        if result is not None:
            info["newton_iterations"] = result.newton_iterations
        return info

    def progress_fields(self, state: ELDState) -> dict:
        return {"t": f"{state.t:.4g}", "newton": self._last_newton}

    def step(self, state: ELDState, tau: float, s_end=None) -> ELDStepResult:
        if not math.isclose(tau, self.tau, rel_tol=1e-12):
            raise RunFailed(f"the Euler scheme (3.4) takes equal steps tau = {self.tau:g}; the "
                            f"controller asked for {tau:g}", where=self.where(state))
        j = state.j + 1
        st = self.solver.stats
        before = (st.factorizations, st.backsolves, st.krylov_iterations, st.solves)
        vals = self.data.at(j)
        try:
            if self.form == "regularized":
                k, its = self._step_regularized(state, vals)
            else:
                k, its = self._step_original(state, vals)
        except SolveFailed as exc:
            raise RunFailed(f"linear solve failed at step {j} (t = {j * tau:.6g}): {exc}",
                            where=self.where(state)) from exc
        self._last_newton = its
        p = self.problem
        c = p.constraint
        x, u, v, Ku, Mv, Ma, Dv = k.x, k.u, k.v, k.Ku, k.Mv, k.Ma, k.Dv
        if k.lam is None:
            # (3.4a) tested with V^c: the residual on the constrained rows is B^T lambda
            C = c.dofs
            r_C = vals.F[C] - self.rho * Ma[C] - Dv[C] - Ku[C]
            lam = c.multiplier_from_residual(r_C)
        else:
            lam = k.lam
        # energy identity (module docstring)
        L = state.ledger
        dv, du = v - state.v, u - state.u
        dMv, dKu = Mv - state.Mv, Ku - state.Ku
        Bv = c.boundary_mass @ v[c.dofs]
        ledger = replace(
            L,
            kinetic=0.5 * self.rho * float(v @ Mv),
            elastic=0.5 * float(u @ Ku),
            work=L.work + tau * float(vals.F @ v),
            work_reaction=L.work_reaction - tau * float(lam @ Bv),
            dissipated=L.dissipated + tau * float(Dv @ v),
            numerical=L.numerical + 0.5 * self.rho * float(dv @ dMv) + 0.5 * float(du @ dKu),
            mismatch=L.mismatch + self.rho * tau * float((Ma - dMv / tau) @ v)
            + tau * float(Ku @ (v - du / tau)),
        )
        new = ELDState(s=j * tau, t=j * tau, j=j, x=x, x_prev=state.x, u=u, v=v, Ku=Ku, Mv=Mv,
                       lam=lam, ledger=ledger, Mx=k.Mx, Kx=k.Kx, Mx_prev=state.Mx,
                       Kx_prev=state.Kx)
        counters = {
            "newton_iterations": its,
            "linear_factorizations": st.factorizations - before[0],
            "linear_solves": st.backsolves - before[1],
            "krylov_iterations": st.krylov_iterations - before[2],
        }
        return ELDStepResult(state=new, tau=tau, lam=lam, reactions=c.reactions(lam),
                             newton_iterations=its, du=du / tau, counters=counters)

    # -- the two forms --------------------------------------------------------------------------
    def _lifted(self, gs):
        """[(B^- g, M B^- g, K B^- g) for g in gs], by thin column products (nodal lifting)."""
        if self.lifting_kind == "nodal":
            return [(self.lifting(g), self._M_C @ g, self._K_C @ g) for g in gs]
        p = self.problem
        return [(w, p.M @ w, p.K @ w) for w in self.lifting.lift_many(list(gs))]

    def _kinematics(self, state: ELDState, x, Mx, Kx, lifted, with_nonlinear: bool = True):
        """u, v, a and their products from x = u_1^j (or u^j) and the lifted data.

        u = x + u2, v = (x - x^{j-1})/tau + v2, a = (x - 2 x^{j-1} + x^{j-2})/tau^2 + w2.
        """
        tau = self.tau
        p1 = state.x
        (u2, _, Ku2), (v2, Mv2, Kv2), (_, Mw2, _) = lifted
        k = _Kinematics(x=x, Mx=Mx, Kx=Kx)
        k.u = x + u2 if u2 is not None else x
        k.v = (x - p1) / tau + (v2 if v2 is not None else 0.0)
        k.Mv = (Mx - state.Mx) / tau + Mv2
        k.Ma = (Mx - 2.0 * state.Mx + state.Mx_prev) / tau**2 + Mw2
        k.Ku = Kx + Ku2
        Kv = (Kx - state.Kx) / tau + Kv2
        D = self.D
        Dv = D.mass_coef * k.Mv + D.stiffness_coef * Kv
        if D.matrix is not None:
            Dv = Dv + D.matrix @ k.v
        if with_nonlinear and not D.is_linear:
            Dv = Dv + D.nonlinear_apply(k.v)
        k.Dv = Dv
        return k

    def _step_regularized(self, state: ELDState, vals):
        p, tau, rho = self.problem, self.tau, self.rho
        I = self.I
        n = p.space.ndofs
        lifted = self._lifted((vals.G, vals.G_dot, vals.G_ddot))
        (u2, _, Ku2), (v2, Mv2, Kv2), (w2, Mw2, _) = lifted
        D = self.D
        guess = (2.0 * state.x - state.x_prev)[I]
        if D.is_linear:
            # [(rho/tau^2) M + C/tau + K] x = F + rho M (2 x^{j-1} - x^{j-2})/tau^2 - rho M w2
            #                                   + C (x^{j-1}/tau - v2) - K u2      on V_B
            rhs = (vals.F + rho * (2.0 * state.Mx - state.Mx_prev) / tau**2 - rho * Mw2
                   + D.mass_coef * (state.Mx / tau - Mv2)
                   + D.stiffness_coef * (state.Kx / tau - Kv2) - Ku2)
            if D.matrix is not None:
                rhs = rhs + D.matrix @ (state.x / tau - v2)
            xI = self.solver.solve_reference(rhs[I], x0=guess)
            x = np.zeros(n)
            x[I] = xI
            return self._kinematics(state, x, p.M @ x, p.K @ x, lifted), 0

        cache = {}

        def residual(xI):
            x = np.zeros(n)
            x[I] = xI
            k = self._kinematics(state, x, p.M @ x, p.K @ x, lifted)
            cache["k"] = k
            R = rho * k.Ma + k.Dv + k.Ku - vals.F
            return R[I], k.v

        def jacobian(v):
            # matrix-free J_II w = A_II w + (N'(v) E w)_I / tau; assembled only when the
            # stored preconditioner must be rebuilt
            action = D.nonlinear_jacobian_action(v)

            def matvec(w):
                full = np.zeros(n)
                full[I] = w
                return self.A_II @ w + action(full)[I] / tau

            op = spla.LinearOperator((I.size, I.size), matvec=matvec, dtype=float)

            def assemble():
                return (self.A_II + (1.0 / tau) * D.nonlinear_jacobian(v)[I][:, I]).tocsr()

            return op, assemble

        _, its = self._newton(residual, jacobian, guess, state.x[I], state)
        return cache["k"], its

    def _step_original(self, state: ELDState, vals):
        p, tau, rho = self.problem, self.tau, self.rho
        c = p.constraint
        n = p.space.ndofs
        zero = (None, 0.0, 0.0)
        lifted = [zero, zero, zero]
        g_rhs = c.boundary_mass @ vals.G
        D = self.D
        if D.is_linear:
            rhs_u = (vals.F + rho * (2.0 * state.Mx - state.Mx_prev) / tau**2
                     + D.mass_coef * state.Mx / tau + D.stiffness_coef * state.Kx / tau)
            if D.matrix is not None:
                rhs_u = rhs_u + D.matrix @ (state.x / tau)
            z = self.solver.solve_reference(np.concatenate([rhs_u, g_rhs]))
            u = z[:n]
            k = self._kinematics(state, u, p.M @ u, p.K @ u, lifted)
            k.lam = z[n:]
            return k, 0

        B = c.B
        lam0 = state.lam if state.lam is not None else np.zeros(c.m)
        cache = {}

        def residual(z):
            u, lam = z[:n], z[n:]
            k = self._kinematics(state, u, p.M @ u, p.K @ u, lifted)
            k.lam = lam
            cache["k"] = k
            R_u = rho * k.Ma + k.Dv + k.Ku + B.T @ lam - vals.F
            return np.concatenate([R_u, B @ u - g_rhs]), k.v

        def jacobian(v):
            action = D.nonlinear_jacobian_action(v)
            m = c.m

            def matvec(z):
                u, lam = z[:n], z[n:]
                return np.concatenate([self.A @ u + action(u) / tau + B.T @ lam, B @ u])

            op = spla.LinearOperator((n + m, n + m), matvec=matvec, dtype=float)

            def assemble():
                return self._kkt(self.A + (1.0 / tau) * D.nonlinear_jacobian(v))

            return op, assemble

        z0 = np.concatenate([2.0 * state.x - state.x_prev, lam0])
        _, its = self._newton(residual, jacobian, z0, np.concatenate([state.x, lam0]), state)
        return cache["k"], its

    def _newton(self, residual, jacobian, z0, z_prev, state):
        """Newton's method with backtracking on |R|; returns (z, iterations) or raises RunFailed.

        Stops when the estimated error of the iterate, |dz| theta / (1 - theta) with the
        contraction theta = |dz_k| / |dz_{k-1}| (or |dz| itself in the first iteration), is below
        tol * max(|z|, |z - z_prev|).
        """
        opts = self.newton
        z = z0.copy()
        R, v = residual(z)
        rnorm = np.linalg.norm(R)
        prev_step = None
        for it in range(1, opts.max_iter + 1):
            if rnorm == 0.0:
                return z, it - 1
            J, assemble = jacobian(v)
            dz = self.solver.solve(J, -R, assemble=assemble, rtol=opts.krylov_rtol)
            alpha = 1.0
            while True:
                z_new = z + alpha * dz
                R_new, v_new = residual(z_new)
                r_new = np.linalg.norm(R_new)
                if r_new <= (1.0 - 1e-4 * alpha) * rnorm or alpha < 1.0 / 64:
                    break
                alpha *= 0.5
            step = alpha * np.linalg.norm(dz)
            z, R, v, rnorm = z_new, R_new, v_new, r_new
            scale = max(np.linalg.norm(z), np.linalg.norm(z - z_prev), 1e-300)
            if prev_step is not None and prev_step > 0 and alpha == 1.0:
                theta = step / prev_step
                estimate = step * theta / (1.0 - theta) if theta < 1.0 else math.inf
            else:
                estimate = step
            if estimate <= opts.tol * scale or step == 0.0:
                return z, it
            prev_step = step
        where = self.where(state)
        where.update(newton_iterations=opts.max_iter, residual=float(rnorm))
        raise RunFailed(
            f"Newton's method did not converge in {opts.max_iter} iterations at step "
            f"{state.j + 1} (t = {(state.j + 1) * self.tau:.6g}, tau = {self.tau:g}, "
            f"|R| = {rnorm:.3g}); the step is not accepted", where=where)

    # -- recording ------------------------------------------------------------------------------
    def record(self, traj: Trajectory, result: ELDStepResult) -> None:
        st = result.state
        L = st.ledger
        rec = dict(
            t=st.t, kinetic=L.kinetic, elastic=L.elastic, energy=L.energy, work=L.work,
            work_reaction=L.work_reaction, dissipated=L.dissipated,
            numerical_dissipation=L.numerical, data_mismatch=L.mismatch,
            balance_residual=L.residual, tau=result.tau,
            lam_norm=self.problem.constraint.l2_norm(result.lam),
            newton_iterations=result.newton_iterations,
        )
        for part, force in result.reactions.items():
            rec[f"reaction_{part}"] = force
        if self.store_fields:
            rec.update(u=st.u, v=st.v, du=result.du, lam=result.lam)
        traj.append(**rec)
        if self.observer is not None:
            self.observer(st, result)

    # -- checkpoint protocol (rothe.io.checkpoint); kept apart from the scheme on purpose ------
    _STATE_ARRAYS = ("x", "x_prev", "u", "v", "Ku", "Mv", "lam", "Mx", "Kx", "Mx_prev", "Kx_prev")
    _DATA_HISTORY = ("_j", "_prev_G", "_prev_G_dot", "_prev_G_exact", "_prev_G_dot_exact")

    def checkpoint_state(self, state: ELDState) -> dict:
        """The state of step j with the scheme's history (x^{j-1} and the products kept with
        it), the energy ledger, the step data's history (difference quotients of G), the Newton
        counter shown in the progress, and the linear solver (with its reference matrix when it
        was refactored since the stepper was built)."""
        refactored = self.solver.stats.factorizations != self.initial_factorizations
        return {
            "stepper": "eld", "form": self.form, "tau": self.tau,
            "s": float(state.s), "t": float(state.t), "j": int(state.j),
            "arrays": {name: getattr(state, name) for name in self._STATE_ARRAYS},
            "ledger": asdict(state.ledger),
            "data": {name: getattr(self.data, name) for name in self._DATA_HISTORY},
            "last_newton": int(self._last_newton),
            "solver": self.solver.checkpoint_state(reference=refactored),
        }

    def restore_state(self, data: dict) -> ELDState:
        if data.get("stepper") != "eld" or data["form"] != self.form or data["tau"] != self.tau:
            raise ValueError("restore_state: the state of another stepper (form, tau)")
        arrays = {k: None if v is None else np.array(v) for k, v in data["arrays"].items()}
        for name, value in data["data"].items():
            setattr(self.data, name, value if np.isscalar(value) else np.array(value))
        self._last_newton = int(data["last_newton"])
        self.solver.restore_state(data["solver"])
        return ELDState(s=float(data["s"]), t=float(data["t"]), j=int(data["j"]),
                        ledger=EnergyLedger(**data["ledger"]), **arrays)


def run_eld(problem: ELDProblem, form: str = "regularized", tau: float = 0.01, *,
            data: str = "points", lifting: str = "nodal", solver: str = "auto",
            newton: NewtonOptions | None = None, noise: DataNoise | None = None,
            store_fields: bool = True, observer=None, progress=False,
            linear_rtol: float = 1e-10, meta: dict | None = None, checkpoint=None,
            resume=None) -> Trajectory:
    """Run the Euler scheme (3.4) from t = 0 to T with n = T/tau equal steps.

    Runs on the shared evolve loop with a fixed-step controller. Returns a
    :class:`~rothe.io.trajectory.Trajectory`: point series (n + 1 entries, t = 0 included)
    ``t, kinetic, elastic, energy, work, work_reaction, dissipated, numerical_dissipation,
    data_mismatch, balance_residual`` (and with ``store_fields`` ``u``, the scheme's velocity
    ``v`` and the difference quotient ``du`` = (u^j - u^{j-1})/tau, which differ in the
    regularized form by v_2^j - D u_2^j; ``du`` at t = 0 is h); step series (n entries)
    ``tau, lam_norm, reaction_<part>, newton_iterations`` (and ``lam``).
    Raises :class:`RunFailed` (with ``.trajectory``) if a step cannot be solved.
    ``checkpoint`` / ``resume``: as for :func:`rothe.stepping.ris.run_ris` (a resumed run
    continues bit for bit; an ``observer`` that keeps state, such as an output writer, is
    passed as a checkpoint attachment so that it is restored too).
    """
    stepper = ELDStepper(problem, form, tau, data=data, lifting=lifting, solver=solver,
                         newton=newton, noise=noise, store_fields=store_fields, observer=observer,
                         linear_rtol=linear_rtol)
    info = {"example": problem.name, "form": form, "tau": tau, "n_steps": stepper.n_steps,
            "data": data, "lifting": lifting if form == "regularized" else None,
            "solver": stepper.kind, "control": "uniform", "step_bound": problem.step_bound(),
            "problem": problem.describe()}
    if noise is not None:
        info["noise"] = {"delta": noise.delta, "target": noise.target, "seed": noise.seed}
    info.update(meta or {})
    controller = UniformController(tau)
    arguments = run_arguments(
        form=form, tau=tau, data=data, lifting=lifting, solver=solver,
        newton=asdict(stepper.newton), noise=None if noise is None else asdict(noise),
        store_fields=store_fields, linear_rtol=linear_rtol)
    with RunCheckpointing("run_eld", problem, arguments, checkpoint, resume) as rc:
        cp, restored = rc.checkpointer, rc.restored
        if restored is not None:
            traj = restored.trajectory(0)
            traj.meta.update(info)
            traj.meta["sessions"] = restored.sessions + 1
            state = stepper.restore_state(restored.state["stepper"])
            controller.restore_state(restored.state["controller"])
        else:
            traj = Trajectory(meta=info)
            state = stepper.initial_state()
            stepper.record_initial(traj, state)
            traj.stats.linear_factorizations += stepper.initial_factorizations
        if cp is not None:
            cp.register(traj)
            if restored is None:
                cp.save_or_warn(stepper, controller, state, where=_eld_where(traj, state))
        try:
            final = evolve(stepper, controller, state, traj, tau_min=tau, progress=progress,
                           checkpointer=cp)
        except RunFailed as exc:
            exc.trajectory = traj
            _finish_meta(traj, stepper)
            raise
        finally:
            _finish_meta(traj, stepper)
        if cp is not None:
            cp.save_or_warn(stepper, controller, final, status="completed",
                    where=_eld_where(traj, final))
    traj.final_state = final  # not saved to .npz: the last state and the stepper, for callers
    traj.stepper = stepper
    return traj


def _eld_where(traj: Trajectory, state: ELDState) -> dict:
    return {"accepted_steps": traj.stats.accepted_steps, "s": float(state.t),
            "t": float(state.t), "j": int(state.j)}


def _finish_meta(traj: Trajectory, stepper: ELDStepper) -> None:
    s = stepper.solver.stats
    traj.meta["linear_solver"] = {
        "kind": stepper.kind, "factorizations": s.factorizations, "backsolves": s.backsolves,
        "krylov_iterations": s.krylov_iterations, "setup_seconds": s.setup_seconds,
    }
