"""Coupled runs on the shared evolve loop: :func:`run_coupled` (issue 19, phase 2).

A coupled run steps an elastic body tied to components (and controllers) by couplings
B u = G(t, q) (:class:`~rothe.eld.coupling.CoupledProblem`) with the bordered step of
:mod:`rothe.eld.coupled_step` (``docs/coupling.md``, Sec. 4): per step one back-substitution
with the body's step matrix A_II (one factorization per effective step size tau/alpha_0, the
border X = A_II^-1 (A Phi)_I with it) and an (r + s) dense solve; Newton on the border unknowns
for nonlinear components, a failure of which is a rejected step, never an accepted one.

The driver is the one every run uses (:func:`rothe.stepping.evolve.evolve`): the stepper
(:class:`CoupledStepper`) does one step and never decides acceptance; the controller comes
from the same step-control objects as :func:`~rothe.eld.run.run_eld`:
:class:`~rothe.stepping.controllers.Uniform` (T/tau equal steps) and
:class:`~rothe.stepping.controllers.Adaptive` (the error-norm controller of
:func:`rothe.eld.controllers.adaptive_controller`, order 1 or 2).

**Local error estimate** (adaptive steps). The trapezoidal residuals of the step on the whole
system -- the body's r_u = u^j - u^{j-1} - tau/2 (v^j + v^{j-1}), r_v = v^j - v^{j-1} -
tau/2 (a^j + a^{j-1}) and the components' r_q, r_p from q, p, pdot -- in the energy norm of the
coupled system, relative to the largest energy norm so far:

    local_error = c(omega) (r_u.K r_u + rho r_v.M r_v + r_q.K_q r_q + r_p.M_q r_p)^{1/2} / S_j

(c(omega) the scheme's factor, :meth:`~rothe.eld.scheme.Scheme.estimate_factor`; K_q the
linear components' stiffness; S_j >= ``error_scale``). The controllers' states z have no
energy: their trapezoidal residual r_z = z^j - z^{j-1} - tau/2 (zdot^j + zdot^{j-1}) is measured
in the Euclidean norm relative to their own scale, and the step's estimate is the larger of the
two (issue 19, item 2; docs/coupling.md, Sec. 11):

    local_error = max(above, c(omega) |r_z| / Z_j),
    Z_j = max(error_scale, max_{i <= j} max(|z^i|, theta |B_c y^i|)),  theta = 1/max(|A_c|_2, 1/T)

(A_c, B_c the controllers' state matrices, y the sensors' readings). The maximum and not a sum:
the two parts have different units (energy^{1/2} and z's), each is made relative to its own
scale, and the step must meet tol in both -- the mixed norm of ODE codes (a weighted max over
groups of unknowns). The floor theta |B_c y| is the z the sensors drive the controllers to on
their own time scale (y for a filter z' = (y - z)/T_f; T |B_c y| for an integrator): without it
a controller starting at z = 0 from a body at rest is a pure power law z ~ t^k at the start,
whose residual relative to |z| does not fall with tau there (self-similar) -- the steps fell
to 1e-10 on eld-control with --kd (measured, docs/coupling.md). Without controllers' states
the estimate is the energy part alone, bit for bit as before.

**Why a function of its own** and not ``run_eld(CoupledProblem)``: the same keywords
(``scheme=``, ``form=``, ``control=``) mean the same objects, but a coupled run has a different
state (q, p, z next to the fields), a different result (the components' trajectories and the
whole-system ledger), and today no ``data=`` (the prescribed part's data are taken at the
step's points); ``run_eld`` accepting a CoupledProblem would have to refuse half its keywords
for one kind of problem.

**Checkpoints** (``checkpoint=``, ``resume=``: the words and files of ``run_eld``,
:mod:`rothe.io.checkpoint`): :meth:`CoupledStepper.checkpoint_state` holds the state (the
body's u, v, a, lambda, the components' q, p, pdot, the controllers' z, the scheme's history
per BDF level with its products, the whole-system ledger), the key of the stored factorization
and the step algebra's counters, and with space adaptivity the mesh hierarchy and the series of
meshes; the controller its step-size state; the checkpoint the trajectory so far. A resumed
run refactors from the key (not counted) and continues bit for bit; SIGINT / SIGTERM stop it
with the trajectory so far and a checkpoint. :func:`run_coupled_many` runs several systems
with one checkpoint (the commands that compare two runs). When the coupled
step moves into :class:`~rothe.eld.stepper.ELDStepper` (docs/coupling.md, Sec. 12), this
function becomes run_eld's branch with the same signature.
"""

from __future__ import annotations

import inspect
import math
from dataclasses import asdict, dataclass, field, replace

import numpy as np
import scipy.sparse as sp

from ..errors import RunFailed, described, fail
from ..fem.adapt import free_transfer
from ..fem.adapt.cycle import energy_or_fail, finite_or_fail
from ..io.checkpoint import (
    CheckpointError,
    RunCheckpointing,
    digest,
    restored_vector,
    run_arguments,
)
from ..io.trajectory import Trajectory
from ..stepping.controllers import Adaptive, Uniform
from ..stepping.evolve import evolve
from ..timing import PhaseTimes
from .adapt import check_adapt
from .constraint import NodalLifting
from .controllers import checkpoint_where, step_controller
from .coupled_adapt import CoupledAdaptivity, CoupledMesh, check_coupled_adapt
from .coupled_step import SPARSE_COORDINATES, CoupledStepSystem
from .coupling import CoupledProblem
from .data import Points
from .form import DEFAULT_FORM, Original, as_form
from .scheme import BDF2, DEFAULT_SCHEME, as_scheme
from .state import ELDCode
from .stepper import GridLoop, StepGrid

#: the history a step needs (two states for BDF2)
_HISTORY = ("x", "y", "q", "p", "z", "gk", "gdk", "u", "v")
#: the vectors of a state (besides its history) a checkpoint stores
_STATE_VECTORS = ("u", "v", "a", "lam", "q", "p", "pdot", "z", "zdot")
#: the checkpoint format of :meth:`CoupledStepper.checkpoint_state`
CHECKPOINT_FORMAT = "rothe-coupled-state-1"
#: the products kept with that history (rho M v, K u, K v, rho M a; M_q p, K_q q): the ledger
#: and the estimate take differences of them instead of products of differences
_PRODUCTS = ("Mv", "Ku", "Kv", "Ma", "Mp", "Kq")


@dataclass
class CoupledState:
    """The state after step j: fields u, v, a, lam of the body, q, p, pdot of the components,
    z of the controllers, the scheme's history (``hist``: lists of the last states of x = u -
    L(S u), y, q, p, z, g_k, g'_k, u, v), the whole-system ledger and the error scale."""

    t: float
    j: int
    tau_prev: float | None
    u: np.ndarray
    v: np.ndarray
    a: np.ndarray
    lam: np.ndarray
    q: np.ndarray
    p: np.ndarray
    pdot: np.ndarray
    z: np.ndarray
    zdot: np.ndarray
    hist: dict
    ledger: dict
    energy_start: float
    energy_norm_max: float = 0.0
    z_norm_max: float = 0.0  # max over states of max(||z||, theta ||B_c y||): z's error scale
    energies: tuple | None = None  # (body, components) at this state, once computed
    lam_norm: float | None = None  # ||lam||_{L2(Gamma)}, once computed
    mesh_id: int = 0  # the body's mesh (space adaptivity)

    @property
    def fields(self) -> dict:
        """The body's u, v, a by name (what the space indicator of the adapt step reads)."""
        return {"u": self.u, "v": self.v, "a": self.a}

    @property
    def s(self) -> float:
        """The evolve loop's position: t."""
        return self.t


@dataclass
class CoupledStepResult:
    """One step attempt: the new state (None if it failed), the step, the estimate, the
    balance of the ledger and the residuals; ``errors`` for the controller."""

    state: CoupledState | None
    tau: float
    estimate: float = math.nan
    balance: float = 0.0
    residual_body: float = 0.0
    residual_components: float = 0.0
    constraint: float = 0.0
    reactions: dict = field(default_factory=dict)
    counters: dict = field(default_factory=dict)
    converged: bool = True
    code: ELDCode = ELDCode.OK
    message: str = ""
    where: dict = field(default_factory=dict)
    refinements: int = 0  # of the step's own mesh, each followed by a solve (space adaptivity)
    bisections: int = 0
    dofs: int = 0  # the body's unknowns of every solve of the step summed
    mesh: object = None  # the CoupledMesh the state was computed on (space adaptivity)

    @property
    def errors(self) -> dict:
        return {"local_error": self.estimate}


@dataclass
class CoupledResult:
    """What :func:`run_coupled` returns.

    Parameters
    ----------
    trajectory : Trajectory
        Point series (t = 0 included): ``t, q, p, z`` (the components' coordinates, velocities
        and the controllers' states, one row per state), ``lam_norm``, ``reaction_<part>``
        (the resultant of lambda on every constrained part), ``energy, energy_body,
        energy_components, work, work_components, work_controllers, work_prescribed,
        dissipated, numerical_dissipation, data_mismatch, residual_work, balance`` (the ledger
        of docs/coupling.md Sec. 5; ``balance`` its mismatch, round-off), ``residual_body,
        residual_components``, ``constraint`` (max |S u - G(t) - Gamma q| / max(1, max |u|):
        the coupling B u = G(t, q) at every accepted state), and with ``watch`` ``watch_u,
        watch_v``; step series ``tau, local_error``; ``stats`` and ``meta``.
    state : CoupledState
        The final state (fields u, v, a, lam of the body).
    stepper : CoupledStepper
    controller : object
    """

    trajectory: Trajectory
    state: CoupledState
    stepper: CoupledStepper
    controller: object

    @property
    def statistics(self):
        return self.trajectory.stats

    @property
    def meshes(self):
        """The series of meshes and the log of adaptations of a space-adaptive run
        (:class:`rothe.eld.adapt.ELDMeshes`), None on a fixed mesh."""
        ad = self.stepper.adaptivity
        return None if ad is None else ad.meshes

    def mesh_arrays(self) -> dict:
        """What ``trajectory.npz`` stores of the meshes of a space-adaptive run (every mesh
        once, ``state_mesh_id`` the mesh of every state: MeshSeries.npz_arrays); {} on a fixed
        mesh."""
        if self.meshes is None:
            return {}
        return self.meshes.series.npz_arrays(np.asarray(self.trajectory["mesh_id"]))


def _taylor(x0, v0, a0, h):
    return x0 - h * v0 + 0.5 * h * h * a0, v0 - h * a0


class CoupledStepper(GridLoop):
    """One step of the coupled scheme at a time for the evolve loop (module docstring).

    Parameters
    ----------
    system : CoupledProblem
        Body with linear damping, linear couplings; components may be nonlinear.
    scheme : ImplicitEuler or BDF2
        BDF2 (``start='taylor'``) starts from the Taylor history with the consistent initial
        accelerations of the body and the components.
    form : Regularized or Original
        Regularized: the known data's g', g'' evaluated (G_dot, G_ddot of the prescribed
        parts); Original: nodal lifting, the known data differenced with the scheme's
        quotients (2.7).
    T : float
        End time.
    control : Uniform or Adaptive
        The steps (:class:`rothe.eld.stepper.StepGrid`, without a solvability bound: the
        coupled step takes linear damping, whose step matrix rho kappa^2 M + kappa C + K is
        positive definite on ker B for C >= 0).
    watch : sparse (k, n) matrix, optional
        Rows recorded on u and v at every state (``watch_u``, ``watch_v``).
    error_scale : float
        The floor of the estimate's scale S_j (default 1e-12).
    fields : bool
        Record the body's u, v and lambda at every state (series ``u``, ``v``, ``lam``: the
        fields of glued bodies, :mod:`rothe.eld.bodies`) and the components' accelerations
        (``pdot``). With ``adapt`` the body's fields live on changing meshes: every accepted
        state is kept on the mesh it was computed on, as run_eld keeps its states
        (:meth:`rothe.eld.adapt.ELDMeshes.keep`: u, v, a, lambda and the cell stresses in the
        result's ``meshes.kept``, the series ``kept_step``, ``kept_t``, ``kept_mesh_id``).
    adapt : SpaceAdaptivity, optional
        Adapt the body's mesh after accepted steps (:mod:`rothe.eld.coupled_adapt`:
        :meth:`adapt`, :meth:`transferred`); the stepper is bound to one mesh at a time
        (:meth:`_bind`).
    noise : callable j -> (theta, xi, vartheta), optional
        Perturbations, each (r,) or None, of the coordinates that enter the coupling data at
        step j = 1, 2, ... (the components' outputs the body sees; the initial state is exact;
        Theorem 4.5 with couplings): regularized form g = G + Gamma (q + theta), g' = G_dot +
        Gamma (p + xi), g'' = G_ddot + Gamma (pdot + vartheta); original form only theta (its
        quotients enter through the differenced data).
    """

    def __init__(
        self,
        system,
        scheme,
        form,
        T,
        control,
        *,
        watch=None,
        error_scale=1e-12,
        noise=None,
        fields=False,
        adapt=None,
    ):
        if noise is not None and not callable(noise):
            raise fail(
                "noise", type(noise).__name__, "must be a callable j -> (theta, xi, vartheta)"
            )
        if isinstance(scheme, BDF2) and scheme.start != "taylor":
            raise fail("scheme", f"BDF2(start={scheme.start!r})", "must start 'taylor' here")
        self.system = system
        self.scheme = scheme
        self.form = form
        self.T = float(T)
        self.watch = watch
        self.fields = bool(fields)
        self.error_scale = float(error_scale)
        self.noise = noise
        #: the lifting of the step system ('nodal' in the original form)
        self.lifting = "nodal" if isinstance(form, Original) else form.lifting
        self._original = isinstance(form, Original)
        kern = CoupledStepSystem(system, self.lifting)
        self._start = CoupledMesh(system, kern)  # the initial mesh's (a resumed run rebuilds)
        self._bind(system, kern)
        self.r, self.s_ctrl = kern.r, kern.s
        #: theta = 1 / max(||A_c||_2, 1/T): the controllers' time scale; theta ||B_c y|| is the z
        #: the sensors' reading drives them to (the z floor of the estimate, module docstring)
        self._z_time = 1.0 / max(float(np.linalg.norm(kern.Ac, 2)), 1.0 / self.T) if kern.s else 0.0
        self.comps_linear = all(cmp.is_linear for cmp in system.components)
        self.Mq = system.mass()
        r = self.r
        Ks, Cs = [], []
        for cmp in system.components:
            lin = cmp.is_linear
            Ks.append(cmp.stiffness if lin else sp.csr_matrix((cmp.size, cmp.size)))
            Cs.append(cmp.damping if lin else sp.csr_matrix((cmp.size, cmp.size)))
        if r >= SPARSE_COORDINATES:  # glued bodies: the components' matrices are FE matrices
            self.Mq = sp.csr_matrix(self.Mq)
            self.Kq = sp.block_diag(Ks, format="csr")
            self.Cq = sp.block_diag(Cs, format="csr")
        else:
            self.Kq = np.zeros((r, r))
            self.Cq = np.zeros((r, r))
            for cmp, K_, C_ in zip(system.components, Ks, Cs, strict=True):
                sl = system.slice(cmp)
                self.Kq[sl, sl] = K_.toarray() if sp.issparse(K_) else K_
                self.Cq[sl, sl] = C_.toarray() if sp.issparse(C_) else C_
        self.order = scheme.order
        self.max_ratio = scheme.ratio_cap
        self.grid = StepGrid(control, scheme, self.T, math.inf)
        self.tau, self.steps, self.n_steps = self.grid.tau, self.grid.steps, self.grid.n_steps
        self.times = PhaseTimes()
        self._last_newton = 0
        self._Jq = (None, None)  # (kappa, kappa^2 M_q + kappa C_q + K_q)
        #: space adaptivity of the body (rothe.eld.coupled_adapt), None on a fixed mesh
        self.adaptivity = None if adapt is None else CoupledAdaptivity(self, adapt)
        self._adapted: float | None = None  # eta of the last adapt step (None: none)
        #: (state, mesh hierarchy, CoupledMesh) before a step's own refinements: a rejected
        #: step goes back to its start state's mesh (:meth:`_back_to_mesh_of`)
        self._base = None

    def _bind(self, system, kern) -> None:
        """Bind the stepper to the body's mesh: the system on it, its step algebra and what the
        step takes from them (docs/coupling.md, Speed) -- everything that lives on the mesh
        (space adaptivity binds the new mesh's, :meth:`transferred`)."""
        self.system, self.kern = system, kern
        # one object per mesh: the indicators' memo knows the mesh by it (ELDAdaptivity)
        self._current = CoupledMesh(system, kern)
        body = self.body = system.body
        self.c = kern.constraint
        self.n = body.space.ndofs
        self.rhoM = (kern.rho * kern.M).tocsr()
        self.BT = self.c.B.T.tocsr()
        self.C = body.damping_op.linear
        self._nodal = isinstance(kern.lifting, NodalLifting)
        self._damped = self.C is not None and sp.csr_matrix(self.C).count_nonzero() > 0
        self._PhiT = kern.Phi.T.tocsr() if sp.issparse(kern.Phi) else kern.Phi.T
        G = system.gamma()
        self._GamT = G.T.tocsr() if kern.many else G.T.toarray()

    def _mesh(self):
        """The current mesh's system and step algebra (the adapt cycle's "problem")."""
        return self._current

    # -- helpers ---------------------------------------------------------------------------------
    def _noise_at(self, j: int):
        """(theta, xi, vartheta) of step j: zeros without noise; xi, vartheta zero in the
        original form."""
        r = self.r
        if self.noise is None:
            return np.zeros(r), np.zeros(r), np.zeros(r)
        th, xi, vt = self.noise(j)
        original = isinstance(self.form, Original)
        return (
            np.zeros(r) if th is None else np.asarray(th, float),
            np.zeros(r) if xi is None or original else np.asarray(xi, float),
            np.zeros(r) if vt is None or original else np.asarray(vt, float),
        )

    def _split(self, u_, v_, q_, p_):
        kern, c = self.kern, self.c
        gu, gv = u_[c.dofs], v_[c.dofs]
        x_ = u_ - kern.lift(gu)
        y_ = v_ - kern.lift(gv)
        x_[c.dofs] = 0.0
        y_[c.dofs] = 0.0
        return x_, y_, gu - kern.Gamma @ q_, gv - kern.Gamma @ p_

    def _energies(self, u_, v_, q_, p_, Ku=None, Mv=None):
        """(body, components) energies; ``Ku``, ``Mv``: K u_, rho M v_ if the caller has them."""
        kin, _ = self.system.component_energy(q_, p_)
        Ku = self.kern.K @ u_ if Ku is None else Ku
        Mv = self.rhoM @ v_ if Mv is None else Mv
        return (0.5 * v_ @ Mv + 0.5 * u_ @ Ku, kin + 0.5 * q_ @ (self.Kq @ q_))

    def _products(self, u_, v_, a_, q_, p_) -> dict:
        """rho M v, K u, K v, rho M a, M_q p, K_q q of one state (:data:`_PRODUCTS`)."""
        K = self.kern.K
        return {
            "Mv": self.rhoM @ v_,
            "Ku": K @ u_,
            "Kv": K @ v_,
            "Ma": self.rhoM @ a_,
            "Mp": self.Mq @ p_,
            "Kq": self.Kq @ q_,
        }

    def _norm(self, u_, v_, q_, p_):
        Eb, Ec = self._energies(u_, v_, q_, p_)
        return math.sqrt(max(2.0 * (Eb + Ec), 0.0))

    # -- the initial state -----------------------------------------------------------------------
    def initial_state(self) -> CoupledState:
        """Consistent u0, v0 traces and accelerations (the index-1 system at t = 0)."""
        system, kern, body, c = self.system, self.kern, self.body, self.c
        I, n = kern.I, self.n
        ctrls = system.controllers
        q0, p0 = system.q0.copy(), system.p0.copy()
        z0 = np.concatenate([k.z0 for k in ctrls]) if ctrls else np.zeros(0)
        system.check_initial_consistency()
        gk0, gdk0, gddk0 = body.G(0.0), body.G_dot(0.0), body.G_ddot(0.0)
        u0 = body.u0.copy()
        u0[c.dofs] = gk0 + kern.Gamma @ q0
        v0 = body.v0.copy()
        v0[c.dofs] = gdk0 + kern.Gamma @ p0
        F0 = body.load(0.0)
        kern.factor(1.0, 0.0, 0.0, 0.0, 0.0, None)
        r_k = kern.rho * (kern.M @ kern.lift(gddk0)) + self.C @ v0 + kern.K @ u0 - F0
        y_k = kern.Y_u @ u0 + kern.Y_v @ v0 - kern._LZ.T @ r_k if kern.k_in else np.zeros(0)
        w_k = kern.Cc @ z0 + kern.Dc @ y_k if kern.o else np.zeros(0)
        rhs_q = (
            system.load(0.0)
            - system.force(0.0, q0, p0)
            - kern.Phi.T @ r_k
            + (kern.E @ w_k if kern.o else 0.0)
        )
        a1_I, pdot0, _ = kern.solve(-r_k[I], rhs_q, np.zeros(0), self.Mq)
        a0 = np.zeros(n)
        a0[I] = a1_I
        a0 = a0 + kern.lift(gddk0) + kern.Phi @ pdot0
        lam0 = kern.multiplier(self.rhoM @ a0 + self.C @ v0 + kern.K @ u0 - F0)
        ys0 = kern.Y_u @ u0 + kern.Y_v @ v0 + kern.Y_lam @ lam0 if kern.k_in else np.zeros(0)
        zdot0 = kern.Ac @ z0 + kern.Bc @ ys0 if self.s_ctrl else np.zeros(0)
        x0, y0, g0, gd0 = self._split(u0, v0, q0, p0)
        hist = {
            "x": [x0],
            "y": [y0],
            "q": [q0],
            "p": [p0],
            "z": [z0],
            "gk": [g0],
            "gdk": [gd0],
            "u": [u0],
            "v": [v0],
        }
        for key, val in self._products(u0, v0, a0, q0, p0).items():
            hist[key] = [val]
        Eb, Ec = self._energies(u0, v0, q0, p0)
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
        if self.adaptivity is not None:  # the body's energy change on every new mesh
            ledger["transfer"] = 0.0
        return CoupledState(
            t=0.0,
            j=0,
            tau_prev=None,
            u=u0,
            v=v0,
            a=a0,
            lam=lam0,
            q=q0,
            p=p0,
            pdot=pdot0,
            z=z0,
            zdot=zdot0,
            hist=hist,
            ledger=ledger,
            energy_start=Eb + Ec,
            energy_norm_max=self._norm(u0, v0, q0, p0),
            z_norm_max=self._z_size(z0, ys0) if self.s_ctrl else 0.0,
        )

    def _z_size(self, z, ys) -> float:
        """max(||z||, theta ||B_c y||): the controllers' size at a state (module docstring)."""
        return max(
            float(np.linalg.norm(z)), self._z_time * float(np.linalg.norm(self.kern.Bc @ ys))
        )

    def _history(self, state: CoupledState, tau: float) -> dict:
        """The history of this step: BDF2's first step prepends the Taylor states at -tau."""
        if not (isinstance(self.scheme, BDF2) and state.j == 0):
            return state.hist  # (read only: the step builds a new history)
        hist = {k: list(v) for k, v in state.hist.items()}
        um, vm = _taylor(state.u, state.v, state.a, tau)
        qm, pm = _taylor(state.q, state.p, state.pdot, tau)
        zm = state.z - tau * state.zdot
        xm, ym, gkm, gdkm = self._split(um, vm, qm, pm)
        for key, val in zip(_HISTORY, (xm, ym, qm, pm, zm, gkm, gdkm, um, vm), strict=True):
            hist[key].insert(0, val)
        # (the Taylor history's acceleration at -tau is a0: it is quadratic)
        for key, val in self._products(um, vm, state.a, qm, pm).items():
            hist[key].insert(0, val)
        return hist

    # -- the step --------------------------------------------------------------------------------
    def step(self, state: CoupledState, tau: float, s_end=None) -> CoupledStepResult:
        """One step from ``state`` with step ``tau`` (never decides acceptance). With space
        adaptivity the in-step refinement rounds of run_eld
        (:meth:`rothe.eld.adapt.ELDAdaptivity.refine_in_step`): while the step's estimate on
        its mesh exceeds space_tol (first step; 1.3 space_tol after), the body's mesh is
        refined and the step solved again from ``state`` transferred to it (q, p, z
        unchanged; the body's energy change booked as ``transfer``, :meth:`transferred`). The
        result is the last solve's, its counters those of every solve; ``refinements``,
        ``bisections`` and ``dofs`` count the rounds. A step rejected by the controller goes
        back to its start state's mesh. Never abandoned by a stop signal (the step is short):
        a stop takes effect at the next step boundary."""
        if self.adaptivity is None:
            return self._attempt(state, tau)
        self._back_to_mesh_of(state)
        original = state
        first = self._attempt(state, tau)
        counters = [first.counters]

        def remember():
            base = self._base
            if base is None or base[0] is not original:
                base = (
                    original,
                    self.adaptivity.adaptation.amesh.checkpoint_state(),
                    self._current,
                )
            return base

        def adopt(out, base):  # (the transfer bound the stepper to out's mesh)
            self._base = base
            return out.problem

        def attempt(state):
            result = self._attempt(state, tau)
            counters.append(result.counters)
            return result

        done = self.adaptivity.refine_in_step(
            self._current,
            state,
            first,
            tau,
            self.T,
            attempt=attempt,
            remember=remember,
            adopt=adopt,
            failed=lambda: None,  # (a failed transfer left the stepper on its mesh)
            ndofs=lambda current: current.system.body.space.ndofs,
        )
        result = done.result
        result.refinements, result.bisections, result.dofs = (
            done.refinements,
            done.bisections,
            done.dofs,
        )
        result.counters = {key: sum(c.get(key, 0) for c in counters) for key in counters[-1]}
        result.mesh = self._current
        return result

    def _back_to_mesh_of(self, state: CoupledState) -> None:
        """A step retried (rejected by the time controller, or checkpointed after that) from a
        state whose mesh was refined during the rejected attempt: back to that state's mesh
        and its system (kept alive in ``_base``: the coupled rebuild releases nothing)."""
        base = self._base
        if base is not None and base[0] is state and state.mesh_id != self.adaptivity.mesh_id:
            self.adaptivity.adaptation.restore_state({"amesh": base[1]})
            self._bind(base[2].system, base[2].kern)

    def _attempt(self, state: CoupledState, tau: float) -> CoupledStepResult:
        """One solve of the step from ``state`` on the current mesh."""
        before = dict(self.kern.stats)
        try:
            with self.times.phase("solve"):
                new, info = self._step(state, tau)
        except (RunFailed, np.linalg.LinAlgError, FloatingPointError) as exc:
            return CoupledStepResult(
                None,
                tau,
                converged=False,
                code=ELDCode.NEWTON if isinstance(exc, RunFailed) else ELDCode.LINEAR_SOLVE,
                message=f"coupled step at t = {state.t + tau:.6g} failed: {exc}",
                where=self.where(state, None),
                counters=self._counters(before),
            )
        # (one reduction: a NaN or an infinity anywhere makes the sum non-finite)
        finite = math.isfinite(
            sum(float(a.sum()) for a in (new.u, new.v, new.q, new.p, new.z, new.lam))
        )
        if not finite:
            return CoupledStepResult(
                None,
                tau,
                converged=False,
                code=ELDCode.NON_FINITE,
                message=f"coupled step at t = {state.t + tau:.6g}: the state is not finite",
                where=self.where(state, None),
                counters=self._counters(before),
            )
        self._last_newton = self.kern.stats["newton_iterations"] - before["newton_iterations"]
        return CoupledStepResult(new, tau, counters=self._counters(before), **info)

    def _counters(self, before: dict) -> dict:
        st = self.kern.stats
        return {
            "newton_iterations": st["newton_iterations"] - before["newton_iterations"],
            "linear_factorizations": st["factorizations"] - before["factorizations"],
            "linear_solves": st["back_substitutions"] - before["back_substitutions"],
        }

    def _step(self, state: CoupledState, tau: float):
        system, kern, body, c = self.system, self.kern, self.body, self.c
        I, n, s = kern.I, self.n, self.s_ctrl
        Gam, Phi, PhiT, Mq, Kq, Cq = kern.Gamma, kern.Phi, self._PhiT, self.Mq, self.Kq, self.Cq
        rhoM, K, Cmat = self.rhoM, kern.K, self.C
        hist = self._history(state, tau)
        if isinstance(self.scheme, BDF2):
            al0, al1, al2 = self.scheme.coefficients(tau, tau if state.j == 0 else state.tau_prev)
        else:
            al0, al1, al2 = self.scheme.coefficients(tau)
        kap = al0 / tau
        t = self.grid.time_after(state, tau)
        b1, b2 = al1 / tau, al2 / tau

        def hpart(key):
            h = hist[key]
            return b1 * h[-1] + b2 * h[-2] if al2 != 0.0 else b1 * h[-1]

        c_x, c_y = hpart("x"), hpart("y")
        c_q, c_p = hpart("q"), hpart("p")
        c_z = hpart("z") if s else np.zeros(0)
        # the known part of the data: prescribed parts (the coupled parts' zero placeholders
        # are not evaluated) and the noise
        if self._original:  # the known data differenced with the quotients
            (gk,) = system.known_data(t, derivatives=False)
        else:
            gk, gdk, gddk = system.known_data(t)
        if self.noise is not None:
            th, xi, vt = self._noise_at(state.j + 1)
            gk = gk + Gam @ th
            if not self._original:
                gdk, gddk = gdk + Gam @ xi, gddk + Gam @ vt
        if self._original:
            gdk = kap * gk + hpart("gk")
            gddk = kap * gdk + hpart("gdk")
        # u_k = L g_k, v_k = c_x + L g'_k + Phi c_q, a_k = kappa c_x + c_y + L g''_k +
        # Phi (kappa c_q + c_p) (S.1); the lifting is linear: L (g + Gamma q) = L g + Phi q
        v_k = c_x + Phi @ c_q
        a_k = kap * c_x + c_y + Phi @ (kap * c_q + c_p)
        if self._nodal:  # L g = S^T g
            u_k = np.zeros(n)
            u_k[c.dofs] = gk
            v_k[c.dofs] += gdk
            a_k[c.dofs] += gddk
        else:  # one back-substitution for the three
            u_k, Lgd, Lgdd = kern.lifting.lift_many([gk, gdk, gddk])
            v_k += Lgd
            a_k += Lgdd
        F = body.load(t)
        r_k = rhoM @ a_k + K @ u_k - F
        if self._damped:
            r_k += Cmat @ v_k
        coefficients = (kap * kap, kap, 1.0, 1.0, kap, kap)
        if kern.needs_factor(*coefficients):
            with self.times.phase("factor"):
                kern.factor(*coefficients)
        y_k = (kern.Y_u @ u_k + kern.Y_v @ v_k - kern._LZ.T @ r_k) if kern.k_in else np.zeros(0)
        pd_k = kap * c_q + c_p
        f_ext = system.load(t)
        w_k = kern.Dc @ y_k if kern.o else np.zeros(0)
        rhs_z = kern.Bc @ y_k - c_z if s else np.zeros(0)
        rhs_q = f_ext - Mq @ pd_k - PhiT @ r_k
        if kern.o:
            rhs_q += kern.E @ w_k
        if self.comps_linear:
            if self._Jq[0] != kap:  # kappa^2 M_q + kappa C_q + K_q: one object per step size
                self._Jq = (kap, kap * kap * Mq + kap * Cq + Kq)
            x_I, q, z = kern.solve(-r_k[I], rhs_q - Cq @ c_q, rhs_z, self._Jq[1])
        else:
            if kern.X is None:
                kern._border()  # W (sensor rows) for the residual

            def residual(x_I, q_, z_):
                p_ = kap * q_ + c_q
                pdot_ = kap * kap * q_ + pd_k
                X = np.zeros(n)
                X[I] = x_I
                X = X + Phi @ q_
                r_full = kern.A @ X + r_k
                ys = kern.W @ X + y_k if kern.k_in else np.zeros(0)
                w = kern.Cc @ z_ + kern.Dc @ ys if kern.o else np.zeros(0)
                res = Mq @ pdot_ + system.force(t, q_, p_) + PhiT @ r_full - f_ext
                if kern.o:
                    res = res - kern.E @ w
                fq, fp = system.force_jacobians(t, q_, p_)
                return res, np.asarray(kap * kap * Mq + kap * fp + fq)

            x_I, q, z = kern.solve(-r_k[I], rhs_q, rhs_z, kap * kap * Mq, residual=residual)
        x = np.zeros(n)
        x[I] = x_I
        y = kap * x + c_x
        p = kap * q + c_q
        pdot = kap * p + c_p
        # X = x + Phi q: u = X + u_k, v = kappa X + v_k, a = kappa^2 X + a_k (S.1)
        X = x + Phi @ q
        u = X + u_k
        v = kap * X + v_k
        a = (kap * kap) * X + a_k
        # (each product once: the ledger, the energies, the estimate and the residual reuse them,
        # and the next steps take them from the history)
        now = {
            "Mv": rhoM @ v,
            "Ku": K @ u,
            "Kv": K @ v,
            "Ma": rhoM @ a,
            "Mp": Mq @ p,
            "Kq": Kq @ q,
        }
        Ku, Ma, Mv, Mp, Kqq = now["Ku"], now["Ma"], now["Mv"], now["Mp"], now["Kq"]
        Cv = Cmat @ v if self._damped else None
        res = Ma + Ku - F
        if Cv is not None:
            res += Cv
        lam = kern.multiplier(res)
        R = res + self.BT @ lam
        MGlam = c.boundary_mass @ lam
        ys = kern.Y_u @ u + kern.Y_v @ v + kern.Y_lam @ lam if kern.k_in else np.zeros(0)
        w = kern.Cc @ z + kern.Dc @ ys if kern.o else np.zeros(0)
        zdot = kern.Ac @ z + kern.Bc @ ys if s else np.zeros(0)
        Ew = kern.E @ w if kern.o else None
        Cqp = Cq @ p
        force = Kqq + Cqp if self.comps_linear else system.force(t, q, p)
        Rq = Mq @ pdot + force - self._GamT @ MGlam - f_ext
        if Ew is not None:
            Rq -= Ew

        # -- ledger (docs/coupling.md, Sec. 5) ----------------------------------------------------
        def quot(key, now):
            h = hist[key]
            val = al0 * now + al1 * h[-1]
            return (val + al2 * h[-2]) / tau if al2 != 0.0 else val / tau

        def N(key, z_now, product):
            """N(z, W) = 1/2 |dz|_W^2 + z . W ((alpha_0 - 1) dz - alpha_2 dz_prev) (Sec. 5),
            W dz from the history's ``product``."""
            h, Wh = hist[key], hist[product]
            dz = z_now - h[-1]
            Wdz = now[product] - Wh[-1]
            out = 0.5 * (dz @ Wdz)
            if al2 != 0.0:
                out += z_now @ ((al0 - 1.0) * Wdz - al2 * (Wh[-1] - Wh[-2]))
            elif al0 != 1.0:
                out += (al0 - 1.0) * (z_now @ Wdz)
            return out

        L = dict(state.ledger)
        L["numerical_dissipation"] += (
            N("v", v, "Mv") + N("u", u, "Ku") + N("p", p, "Mp") + N("q", q, "Kq")
        )
        # rho M (a - delta v), delta v the scheme's quotient of v: from the products
        L["data_mismatch"] += tau * (Ma - quot("Mv", Mv)) @ v + tau * Ku @ (v - quot("u", u))
        L["work"] += tau * F @ v
        L["work_components"] += tau * f_ext @ p
        if Ew is not None:
            L["work_controllers"] += tau * p @ Ew
        diss = tau * (p @ Cqp)
        if Cv is not None:
            diss += tau * (Cv @ v)
        if not self.comps_linear:
            diss += tau * p @ (force - Kqq - Cqp)
        L["dissipated"] += diss
        L["work_prescribed"] += -tau * (MGlam @ gdk)
        L["residual_work"] += tau * R @ v + tau * Rq @ p
        Eb = 0.5 * (v @ Mv) + 0.5 * (u @ Ku)
        Ec = 0.5 * (p @ Mp) + 0.5 * (q @ Kqq)
        balance = (Eb + Ec - state.energy_start) - (
            L["work"]
            + L["work_components"]
            + L["work_controllers"]
            + L["work_prescribed"]
            - L["dissipated"]
            + L["residual_work"]
            - L["numerical_dissipation"]
            - L["data_mismatch"]
            + L.get("transfer", 0.0)
        )
        # -- local error estimate (module docstring) ---------------------------------------------
        ht = 0.5 * tau
        ru = u - state.u - ht * (v + state.v)
        rv = v - state.v - ht * (a + state.a)
        rq = q - state.q - ht * (p + state.p)
        rp = p - state.p - ht * (pdot + state.pdot)
        omega = 1.0 if state.tau_prev is None else tau / state.tau_prev
        norm_new = math.sqrt(max(2.0 * (Eb + Ec), 0.0))  # (self._norm without the products)
        scale = max(self.error_scale, state.energy_norm_max, norm_new)
        # K ru and rho M rv: the same differences of the products
        Kru = Ku - hist["Ku"][-1] - ht * (now["Kv"] + hist["Kv"][-1])
        Mrv = Mv - hist["Mv"][-1] - ht * (Ma + hist["Ma"][-1])
        factor = self.scheme.estimate_factor(omega)
        est = (
            factor
            * math.sqrt(max(ru @ Kru + rv @ Mrv + rq @ (Kq @ rq) + rp @ (Mq @ rp), 0))
            / scale
        )
        z_norm_max = state.z_norm_max
        if s:  # the controllers' z: their own residual and scale, the larger estimate counts
            rz = z - state.z - ht * (zdot + state.zdot)
            z_norm_max = max(z_norm_max, self._z_size(z, ys))
            est = max(est, factor * float(np.linalg.norm(rz)) / max(self.error_scale, z_norm_max))
        new_hist = {
            key: [hist[key][-1], val]
            for key, val in zip(_HISTORY, (x, y, q, p, z, gk, gdk, u, v), strict=True)
        }
        for key in _PRODUCTS:
            new_hist[key] = [hist[key][-1], now[key]]
        new = CoupledState(
            t=t,
            j=state.j + 1,
            tau_prev=tau,
            u=u,
            v=v,
            a=a,
            lam=lam,
            q=q,
            p=p,
            pdot=pdot,
            z=z,
            zdot=zdot,
            hist=new_hist,
            ledger=L,
            energy_start=state.energy_start,
            energy_norm_max=max(state.energy_norm_max, norm_new),
            z_norm_max=z_norm_max,
            energies=(Eb, Ec),
            lam_norm=math.sqrt(max(float(lam @ MGlam), 0.0)),
            mesh_id=state.mesh_id,
        )
        info = {
            "estimate": est,
            "balance": float(balance),
            "residual_body": float(np.abs(R).max() / max(1.0, np.abs(F).max(), np.abs(Ku).max())),
            "residual_components": float(np.abs(Rq).max(initial=0.0)),
            "constraint": float(
                np.abs(u[c.dofs] - gk - Gam @ q).max(initial=0.0)
                / max(1.0, np.abs(u).max(initial=0.0))
            ),
            "reactions": c.reactions(lam),
        }
        return new, info

    # -- space adaptivity (rothe.eld.coupled_adapt) ---------------------------------------------
    def transferred(self, state: CoupledState, T, current, new) -> CoupledState:
        """``state`` on the mesh of ``new`` (a :class:`~rothe.eld.coupled_adapt.CoupledMesh`)
        through the dof transfer ``T`` (new x old), the stepper bound to it
        (:mod:`rothe.eld.coupled_adapt`, step 4): u, v, a and the history's u, v mapped, the
        trace of t_j re-evaluated from the data and q, p, pdot (u|Gamma = g_k(t_j) + Gamma q,
        v|Gamma = g'_k(t_j) + Gamma p, a|Gamma = g''_k(t_j) + Gamma pdot; in the original form
        too: its differenced boundary velocity restarts there as at t = 0), x, y, g_k, g'_k
        split off by the new lifting, the
        products recomputed, lambda by the trace transfer; q, p, pdot, z unchanged. The
        body's energy change is added to the ledger's ``transfer``. On failure the stepper
        stays bound to ``current``."""
        old_c = self.c
        E_old = (
            state.energies[0]
            if state.energies
            else self._energies(state.u, state.v, state.q, state.p)[0]
        )
        self._bind(new.system, new.kern)
        try:
            return self._transferred(state, T, old_c, E_old)
        except BaseException:
            self._bind(current.system, current.kern)
            raise

    def _transferred(self, state, T, old_c, E_old) -> CoupledState:
        c, Gam = self.c, self.kern.Gamma
        u, v, a = (finite_or_fail(name, T @ getattr(state, name)) for name in "uva")
        # the trace of t_j from the data and q, p, pdot, in both forms: the original form's
        # boundary velocity restarts from G_dot(t_j) as at t = 0 (initial_state) instead of
        # keeping the quotient of the previous step, whose lag tau_{j-1} G''/2 (Euler) the
        # next step turns into an acceleration ~ tau_{j-1}/tau after the controller cuts tau
        # on the new mesh: an estimate that no tau brings below tol (docs/coupling.md, Sec. 14)
        gk, gdk, gddk = self.system.known_data(state.t)
        u[c.dofs] = gk + Gam @ state.q
        v[c.dofs] = gdk + Gam @ state.p
        a[c.dofs] = gddk + Gam @ state.pdot
        old = state.hist
        levels = len(old["u"])
        hist = {key: [] for key in list(_HISTORY) + list(_PRODUCTS)}
        for i in range(levels):
            if i == levels - 1:  # the current state: the data of t_j on the new boundary
                ui, vi, ai = u, v, a
            else:  # t_{j-1}: its transferred trace (its acceleration enters no product used)
                ui, vi = T @ old["u"][i], T @ old["v"][i]
                ai = np.zeros_like(ui)
            qi, pi, zi = old["q"][i], old["p"][i], old["z"][i]
            xi, yi, gki, gdki = self._split(ui, vi, qi, pi)
            for key, val in zip(_HISTORY, (xi, yi, qi, pi, zi, gki, gdki, ui, vi), strict=True):
                hist[key].append(val)
            for key, val in self._products(ui, vi, ai, qi, pi).items():
                hist[key].append(val)
        Eb = 0.5 * (v @ hist["Mv"][-1]) + 0.5 * (u @ hist["Ku"][-1])
        Ec = state.energies[1] if state.energies else self._energies(u, v, state.q, state.p)[1]
        energy_or_fail(Eb + Ec)
        ledger = dict(state.ledger)
        ledger["transfer"] = ledger.get("transfer", 0.0) + (Eb - E_old)
        lam = free_transfer(T, old_c.dofs, c.dofs) @ state.lam
        return replace(
            state,
            u=u,
            v=v,
            a=a,
            lam=lam,
            hist=hist,
            ledger=ledger,
            energies=(Eb, Ec),
            lam_norm=None,
            energy_norm_max=max(state.energy_norm_max, math.sqrt(max(2.0 * (Eb + Ec), 0.0))),
        )

    # -- evolve-loop interface -------------------------------------------------------------------
    def adapt(self, state: CoupledState, result: CoupledStepResult) -> CoupledState:
        """The adapt step after the accepted ``result`` (:mod:`rothe.eld.coupled_adapt`): with
        space adaptivity, when due and the run goes on, the state on a new mesh (a new state;
        the accepted one is never changed); otherwise ``state`` itself. The same cycle and
        bookkeeping as :meth:`rothe.eld.stepper.ELDStepper.adapt`; a failed adaptation stops
        the run with RunFailed, the accepted step standing on its own mesh."""
        self._adapted = None
        ad = self.adaptivity
        if ad is None:
            return state
        self._base = None  # accepted: the state's mesh is the current one (a failed adapt too)
        out, estimate = ad.after_step(
            self._mesh(),
            state,
            result,
            self.T,
            finished=self.finished(state),
            where=lambda: self.where(state),
            ndofs=lambda out: self.n,
            transfer=lambda new: new.ledger["transfer"] - state.ledger["transfer"],
        )
        if out is not None and out.changed:
            state = out.state
        self._adapted = estimate
        return state

    def where(self, state: CoupledState, result=None) -> dict:
        """Step number, time, tau (NaN without a result), form and scheme, for messages."""
        return {
            "step": state.j + 1,
            "s": state.t,
            "t": state.t,
            "tau": result.tau if result is not None else math.nan,
            "form": self.form.name,
            "scheme": self.scheme.name,
        }

    def progress_fields(self, state: CoupledState) -> dict:
        """The time and the last Newton count, for the progress line."""
        return {"t": f"{state.t:.4g}", "newton": self._last_newton}

    # -- records ---------------------------------------------------------------------------------
    def record_state(
        self, traj: Trajectory, state: CoupledState, reactions, balance, rb, rc, constraint=0.0
    ):
        """Append the state, energies, residuals, reactions and constraint error to ``traj``."""
        Eb, Ec = state.energies or self._energies(state.u, state.v, state.q, state.p)
        values = {
            "t": state.t,
            "q": state.q.copy(),
            "p": state.p.copy(),
            "z": state.z.copy(),
            "lam_norm": self.c.l2_norm(state.lam) if state.lam_norm is None else state.lam_norm,
            "energy_body": Eb,
            "energy_components": Ec,
            "energy": Eb + Ec,
            "balance": balance,
            "residual_body": rb,
            "residual_components": rc,
            "constraint": constraint,
            **state.ledger,
            **{f"reaction_{part}": R for part, R in reactions.items()},
        }
        if self.watch is not None:
            values["watch_u"] = self.watch @ state.u
            values["watch_v"] = self.watch @ state.v
        if self.fields:
            values["pdot"] = state.pdot.copy()
            if self.adaptivity is None:  # (adaptive: kept on their meshes, record())
                values.update(u=state.u.copy(), v=state.v.copy(), lam=state.lam.copy())
        if self.adaptivity is not None:  # the mesh the state was computed on
            values.update(mesh_id=int(state.mesh_id), ndofs=int(state.u.size))
        traj.append(**values)

    def record_initial(self, traj: Trajectory, state: CoupledState) -> None:
        """Record the initial state with its reactions and relative error |u_C - G(0)|."""
        c = self.c
        g0 = self.body.G(0.0) + self.kern.Gamma @ state.q
        constraint = np.abs(state.u[c.dofs] - g0).max(initial=0.0)
        constraint /= max(1.0, np.abs(state.u).max(initial=0.0))
        self.record_state(traj, state, c.reactions(state.lam), 0.0, 0.0, 0.0, float(constraint))
        if self.fields and self.adaptivity is not None:
            self.adaptivity.meshes.keep(traj, state, self._current)

    def record(self, traj: Trajectory, result: CoupledStepResult, state: CoupledState) -> None:
        """Record an accepted step's state with the result's reactions, balance and residuals."""
        self.record_state(
            traj,
            state,
            result.reactions,
            result.balance,
            result.residual_body,
            result.residual_components,
            result.constraint,
        )
        traj.append(tau=result.tau, local_error=result.estimate)
        if self.fields and self.adaptivity is not None:
            # the accepted state on the mesh it was computed on (the state recorded above is
            # the one after the adapt step, on the next mesh)
            self.adaptivity.meshes.keep(traj, result.state, result.mesh)
        if self.adaptivity is not None:  # eta of the adapt step after it (NaN: none)
            traj.append(
                space_estimate=math.nan if self._adapted is None else self._adapted,
                # the step's own refinements (summed as run_eld's: meshes_summary)
                step_dofs=int(result.dofs),
                step_refinements=int(result.refinements),
                step_bisections=int(result.bisections),
            )

    # -- checkpoints -----------------------------------------------------------------------------
    def checkpoint_state(self, state: CoupledState) -> dict:
        """Everything that influences the rest of the run, as arrays and plain values
        (:mod:`rothe.io.checkpoint`): the state -- the body's u, v, a, lambda, the components'
        q, p, pdot, the controllers' z, zdot, the scheme's history (x, y, q, p, z, g_k, g'_k,
        u, v and their products per level), the whole-system ledger, the energies the next
        record reads --, the key of the stored factorization with the step algebra's
        counters, the Newton count of the progress line, and with space adaptivity the mesh
        hierarchy, the series of meshes and the log (:class:`CoupledAdaptivity`)."""
        if self.adaptivity is not None:
            self._back_to_mesh_of(state)  # e.g. stopped after a rejected, refined attempt
        return {
            "format": CHECKPOINT_FORMAT,
            "scheme": self.scheme.name,
            "form": self.form.name,
            "lifting": self.lifting,
            "t": float(state.t),
            "j": int(state.j),
            "tau_prev": state.tau_prev,
            **{key: getattr(state, key).copy() for key in _STATE_VECTORS},
            "hist": {key: [w.copy() for w in levels] for key, levels in state.hist.items()},
            "ledger": {key: float(v) for key, v in state.ledger.items()},
            "energy_start": float(state.energy_start),
            "energy_norm_max": float(state.energy_norm_max),
            "z_norm_max": float(state.z_norm_max),
            "energies": None if state.energies is None else [float(e) for e in state.energies],
            "lam_norm": None if state.lam_norm is None else float(state.lam_norm),
            "mesh_id": int(state.mesh_id),
            "kern": self.kern.checkpoint_state(),
            "last_newton": int(self._last_newton),
            "adapt": None if self.adaptivity is None else self.adaptivity.checkpoint_state(),
        }

    def restore_state(self, data: dict) -> CoupledState:
        """The state of :meth:`checkpoint_state`. With space adaptivity the mesh is restored and
        the system rebuilt on it (:meth:`CoupledAdaptivity.rebuild` from the initial mesh's);
        the stored factorization is made again from its key (not counted). A state of another
        scheme, form, lifting or kind of mesh, or whose vectors do not fit this system, is
        refused in one line (:class:`~rothe.io.checkpoint.CheckpointError`)."""
        if not isinstance(data, dict) or data.get("format") != CHECKPOINT_FORMAT:
            got = data.get("format") if isinstance(data, dict) else type(data).__name__
            raise CheckpointError(
                f"checkpoint state stepper: format {got!r}, must be {CHECKPOINT_FORMAT!r} "
                "(the checkpoint is of another run)"
            )
        for key, mine in (
            ("scheme", self.scheme.name),
            ("form", self.form.name),
            ("lifting", self.lifting),
        ):
            if data.get(key) != mine:
                raise CheckpointError(
                    f"checkpoint state stepper: {key} {data.get(key)!r}, this run has {mine!r}"
                )
        if (data.get("adapt") is None) != (self.adaptivity is None):
            kind = "a fixed-mesh" if data.get("adapt") is None else "a space-adaptive"
            raise CheckpointError(
                f"checkpoint state stepper: {kind} run's state, this run "
                + ("adapts its mesh" if self.adaptivity is not None else "keeps its mesh")
            )
        if self.adaptivity is not None:
            self.adaptivity.restore_state(data["adapt"])
            if int(data["mesh_id"]) != 0:
                new = self.adaptivity.rebuild(self._start, self.adaptivity.adaptation.mesh)
                self._bind(new.system, new.kern)
        sizes = {"u": self.n, "lam": self.c.m, "q": self.r, "z": self.s_ctrl}
        sizes.update(v=self.n, a=self.n, p=self.r, pdot=self.r, zdot=self.s_ctrl)
        vectors = {key: restored_vector(data, key, sizes[key]) for key in _STATE_VECTORS}
        component_matrix = None
        key = data["kern"].get("key")
        stepped = key is not None and key[2] == 1.0  # a step's (kappa^2, kappa, 1, 1, ...)
        if stepped and self.comps_linear:
            # the components' block of the last step, as _step makes it
            kap = float(key[1])
            self._Jq = (kap, kap * kap * self.Mq + kap * self.Cq + self.Kq)
            component_matrix = self._Jq[1]
        self.kern.restore_state(
            data["kern"], component_matrix, border=stepped and not self.comps_linear
        )
        self._last_newton = int(data.get("last_newton", 0))
        energies = data.get("energies")
        tp, lam_norm = data["tau_prev"], data.get("lam_norm")
        return CoupledState(
            t=float(data["t"]),
            j=int(data["j"]),
            tau_prev=None if tp is None else float(tp),
            **vectors,
            hist={
                key: [np.array(w, dtype=float) for w in levels]
                for key, levels in data["hist"].items()
            },
            ledger={key: float(v) for key, v in data["ledger"].items()},
            energy_start=float(data["energy_start"]),
            energy_norm_max=float(data["energy_norm_max"]),
            # (a checkpoint from before z entered the norm: ||z|| now, 0 without controllers)
            z_norm_max=float(data.get("z_norm_max", np.linalg.norm(vectors["z"]))),
            energies=None if energies is None else tuple(float(e) for e in energies),
            lam_norm=None if lam_norm is None else float(lam_norm),
            mesh_id=int(data.get("mesh_id", 0)),
        )


def run_coupled(system: CoupledProblem, **options) -> CoupledResult:
    """Run a coupled system from t = 0 to T on the evolve loop (module docstring).

    Parameters
    ----------
    system : CoupledProblem
        The body, its couplings, components and controllers.
    scheme : ImplicitEuler or BDF2
    form : Regularized or Original
    control : Uniform or Adaptive
        Uniform(tau): T/tau equal steps (tau must divide T); Adaptive(tol, tau=None,
        tau_min=None, tau_max=None): the local error estimate below tol, first step ``tau``
        (default T/100), steps in [tau_min (default 1e-10 T), tau_max (default T)].
    T : float, optional
        End time (default the body's T).
    watch : sparse (k, n) matrix, optional
        Rows of u and v recorded at every state (``watch_u``, ``watch_v``).
    error_scale : float
        The floor of the error estimate's scale.
    noise : callable j -> (theta, xi, vartheta), optional
        Perturbations of the coordinates that enter the coupling data (:class:`CoupledStepper`;
        not with checkpoints: a callable cannot be compared on resume).
    fields : bool
        Record u, v, lambda of the body at every state (series ``u``, ``v``, ``lam``).
    adapt : SpaceAdaptivity, optional
        Adapt the body's mesh between accepted steps (:mod:`rothe.eld.coupled_adapt`): the
        trajectory gets the point series ``mesh_id``, ``ndofs``, the step series
        ``space_estimate``, ``step_refinements``, ``step_bisections``, ``step_dofs`` (a step
        whose own estimate is too large is solved again on its refined mesh, as in run_eld)
        and the ledger term ``transfer``; the result's ``meshes``
        (:class:`rothe.eld.adapt.ELDMeshes`) every mesh once and the log of adaptations; with
        ``fields`` every accepted state's fields on its own mesh (:class:`CoupledStepper`). Not
        with ``watch`` or ``noise`` (they live on one mesh).
    progress : bool or ProgressOptions
    checkpoint, resume : optional
        As for :func:`~rothe.eld.run.run_eld`: a directory or
        :class:`~rothe.io.checkpoint.CheckpointOptions` to write checkpoints to (at the start,
        every 60 s, when stopped, at the end), and one written by ``run_coupled`` with the same
        arguments and system to continue from. A resumed run returns the trajectory of the
        uninterrupted run bit for bit (its statistics too, but the wall time, which sums the
        sessions); SIGINT / SIGTERM raise :class:`~rothe.errors.RunInterrupted` with the
        trajectory so far and a checkpoint.

    Returns
    -------
    CoupledResult
    """
    # (the keywords are run_coupled_many's: its signature, _run_coupled_signature; a keyword
    # it does not take, or results=, is a TypeError as for any function)
    run_coupled.__signature__.bind(system, **options)
    (result,) = run_coupled_many({"run": system}, **options).values()
    return result


def run_coupled_many(
    systems: dict,
    *,
    scheme=DEFAULT_SCHEME,
    form=DEFAULT_FORM,
    control=None,
    T: float | None = None,
    watch=None,
    error_scale: float = 1e-12,
    noise=None,
    fields: bool = False,
    adapt=None,
    progress=False,
    checkpoint=None,
    resume=None,
    results: dict | None = None,
) -> dict:
    """Run several coupled systems one after the other with the same options (those of
    :func:`run_coupled`), with one checkpoint for all: the commands that compare two runs
    (``rothe run eld-tmd``: with and without the absorber; ``eld-control``: with and without
    the feedback) checkpoint and resume as one run. The checkpoint holds the finished runs
    (their trajectories, final states and controllers) and the state of the one under way;
    a resumed sequence restores the finished runs and continues the one under way bit for bit.

    Parameters
    ----------
    systems : dict label -> CoupledProblem
        The runs in order (``run_coupled``'s is ``{'run': system}``).
    results : dict, optional
        Filled with label -> :class:`CoupledResult` as the runs finish (restored ones first),
        so that a caller has the finished runs when a later one stops (RunInterrupted,
        RunFailed carry the trajectory of the run under way).

    Returns
    -------
    dict label -> CoupledResult
    """
    if not isinstance(systems, dict) or not systems:
        raise fail("systems", described(repr(systems)[:60]), "must be a dict label -> system")
    for system in systems.values():
        if not isinstance(system, CoupledProblem):
            raise fail("system", type(system).__name__, "must be a rothe.eld.CoupledProblem")
    scheme = as_scheme(scheme)
    form = as_form(form)
    if T is not None:
        T = float(T)
        if not (math.isfinite(T) and T > 0):
            raise fail("T", T, "must be positive and finite")
    if not isinstance(control, (Uniform, Adaptive)):
        raise fail(
            "control",
            type(control).__name__,
            "must be Uniform(tau) or Adaptive(tol) (rothe.stepping.controllers)",
        )
    if adapt is not None:
        check_adapt(adapt, data=Points(), noise=None)
        check_coupled_adapt(adapt, watch=watch, noise=noise)
    if noise is not None and (checkpoint is not None or resume is not None):
        raise fail(
            "noise",
            described("a callable"),
            "is not supported with checkpoint or resume (a callable cannot be compared on "
            "resume): run the perturbation study without checkpoints",
        )
    options = dict(watch=watch, error_scale=error_scale, noise=noise, fields=fields, adapt=adapt)
    ends = {label: system.body.T if T is None else T for label, system in systems.items()}
    arguments = run_arguments(
        runs=list(systems),
        scheme=scheme.describe(),
        form=form.describe(),
        control={"type": type(control).__name__, **asdict(control)},
        T=[ends[label] for label in systems],
        watch=None if watch is None else digest(watch),
        error_scale=error_scale,
        fields=bool(fields),
        **({} if adapt is None else {"adapt": adapt.describe()}),
    )
    done = {} if results is None else results
    labels = list(systems)
    with RunCheckpointing("run_coupled", _Systems(systems), arguments, checkpoint, resume) as rc:
        cp, restored = rc.checkpointer, rc.restored
        start, finished = 0, []
        if restored is not None:
            context = restored.state["run"] or {}
            start = int(context.get("index", 0))
            finished = list(context.get("finished", []))
            for i in range(start):
                label = labels[i]
                run = _CoupledRun(systems[label], scheme, form, control, ends[label], options)
                state = run.stepper.restore_state(finished[i]["stepper"])
                run.controller.restore_state(finished[i]["controller"])
                traj = restored.trajectory(i)
                if cp is not None:
                    cp.register(traj)
                done[label] = CoupledResult(traj, state, run.stepper, run.controller)
        for i in range(start, len(labels)):
            label = labels[i]
            run = _CoupledRun(systems[label], scheme, form, control, ends[label], options)
            if cp is not None:
                cp.context = {"index": i, "finished": finished}
            if restored is not None and i == start:
                traj = restored.trajectory(i)
                traj.meta.update(run.info)
                traj.meta["sessions"] = restored.sessions + 1
                state = rc.restore(run.stepper, run.controller)
            else:
                traj = Trajectory(meta=run.info)
                state = run.stepper.initial_state()
                run.stepper.record_initial(traj, state)
            if cp is not None:
                cp.register(traj)
                if not (restored is not None and i == start):
                    cp.save_or_warn(
                        run.stepper, run.controller, state, where=checkpoint_where(traj, state)
                    )
            state = evolve(
                run.stepper,
                run.controller,
                state,
                traj,
                tau_min=run.tau_min,
                progress=progress,
                checkpointer=cp,
            )
            done[label] = CoupledResult(traj, state, run.stepper, run.controller)
            if cp is not None:
                finished = finished + [
                    {
                        "stepper": run.stepper.checkpoint_state(state),
                        "controller": run.controller.checkpoint_state(),
                    }
                ]
        if cp is not None:
            cp.context = {"index": len(labels), "finished": finished}
            last = done[labels[-1]]
            cp.save_or_warn(status="completed", where=checkpoint_where(last.trajectory, last.state))
    return {label: done[label] for label in labels}


class _CoupledRun:
    """One run of :func:`run_coupled_many`: the stepper, its controller, the trajectory's meta
    data and the evolve loop's tau_min."""

    def __init__(self, system, scheme, form, control, T, options):
        if isinstance(control, Adaptive) and control.tau is None:
            control = replace(control, tau=T / 100)  # the first step: 1/100 of the run
        self.stepper = CoupledStepper(system, scheme, form, T, control, **options)
        info = {}
        self.controller, _, self.tau_min = step_controller(self.stepper, control, T, info)
        adapt = options["adapt"]
        self.info = {
            "kind": "eld-coupled",
            **form.describe(),
            **scheme.describe(),
            "T": T,
            "components": [cmp.name for cmp in system.components],
            "parts": list(self.stepper.c.parts),
            **info,
            **({} if adapt is None else {"adapt": adapt.describe()}),
        }


class _Systems:
    """The systems of :func:`run_coupled_many` as the one problem a checkpoint fingerprints:
    every system's :meth:`CoupledProblem.fingerprint` under its label."""

    def __init__(self, systems: dict):
        self.systems = systems

    def fingerprint(self) -> dict:
        return {
            f"{label}.{key}": value
            for label, system in self.systems.items()
            for key, value in system.fingerprint().items()
        }


# help(run_coupled) and inspect show every keyword: run_coupled_many's (one list, not two)
def _run_coupled_signature() -> inspect.Signature:
    many = inspect.signature(run_coupled_many)
    system = inspect.Parameter(
        "system", inspect.Parameter.POSITIONAL_OR_KEYWORD, annotation="CoupledProblem"
    )
    keywords = [p for name, p in many.parameters.items() if name not in ("systems", "results")]
    return many.replace(parameters=[system, *keywords], return_annotation="CoupledResult")


run_coupled.__signature__ = _run_coupled_signature()
