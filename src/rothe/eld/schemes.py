"""Implicit Euler (3.4) and variable-step BDF2 for the elastodynamic operator DAE, both forms.

Schemes (``scheme=``). Steps tau_j = t_j - t_{j-1} may vary (``control='adaptive'`` or a given
sequence ``steps=``). Both schemes apply one difference operator twice, to the displacement and
to the velocity (for BDF2 this is BDF2 on the first-order system (u, v)):

    delta_j z := (alpha_0 z^j + alpha_1 z^{j-1} + alpha_2 z^{j-2}) / tau_j,
    euler:  (alpha_0, alpha_1, alpha_2) = (1, -1, 0),
    bdf2:   omega = tau_j / tau_{j-1},  alpha_0 = (1 + 2 omega)/(1 + omega),
            alpha_1 = -(1 + omega),  alpha_2 = omega^2 / (1 + omega)           (= 3/2, -2, 1/2)

(:func:`step_coefficients`). With equal steps, Euler is the paper's D u^j and D^2 u^j (3.4).
Variable-step BDF2 is zero-stable only for ratios omega < 1 + sqrt(2) (Grigorieff 1983): a given
step sequence beyond that is refused, and the adaptive controller never proposes more than
:data:`BDF2_RATIO_CAP` = 1.8 (below also Becker's (2 + sqrt 13)/3 = 1.87 of the variable-step
BDF2 energy estimates).

Forms (``form=``); in both, the step is the stationary problem for the scheme's unknown x^j:

``original`` -- (2.7) discretized directly: x = u, with y^j = delta_j u (velocity) and
    a^j = delta_j y (acceleration),
        rho M a^j + D(y^j) + K u^j + B^T lambda^j = F^j,      B u^j = G^j,
    one (nonlinear if D is) saddle-point system for (u^j, lambda^j).

``regularized`` -- the index-1 form (2.8), with the structure of Sec. 3:
        u_2^j = B^- G^j,  v_2^j = B^- G_dot^j,  w_2^j = B^- G_ddot^j           (3.4b)
    (the lifting: the data at t_j, whatever the steps), x = u_1^j in V_B = ker B with
    y^j = delta_j u_1 and b^j = delta_j y from
        rho M (b^j + w_2^j) + D(y^j + v_2^j) + K (u_1^j + u_2^j) = F^j   tested with V_B,
    and lambda^j from the same equation tested with V^c
    (:meth:`DirichletConstraint.multiplier_from_residual`). u = u_1 + u_2, v = y + v_2 (the
    velocity the damping sees), a = b + w_2. B^- is a fixed right inverse of B
    (:mod:`rothe.eld.constraint`; default: nodal lifting).

Since y^j = (alpha_0 x^j + h_x)/tau_j and b^j = (alpha_0 y^j + h_y)/tau_j with history terms h,
the step operator in x is, with the effective step tau_eff = tau_j / alpha_0,

    A(tau_eff) x = (rho/tau_eff^2) M x + D((x + ...)/tau_eff) + K x,
    for linear damping C:  rho alpha_0^2/tau_j^2 M + alpha_0/tau_j C + K.

**Solvability (Lemma 3.2 for these schemes).** On V_B, <A u - A w, u - w> >= (d1/tau_eff + k1)
||u - w||^2 + (rho/tau_eff^2 - d0/tau_eff) |u - w|^2 by (2.4), (2.5): every step is uniquely
solvable if tau_j / alpha_0 < rho/d0, i.e. tau_j < rho/d0 (Euler) and, for BDF2,
tau_j (1 + omega_j)/(1 + 2 omega_j) < rho/d0: tau_j < 1.5 rho/d0 with equal steps, and in
general tau_j < [2c - tau_{j-1} + sqrt(tau_{j-1}^2 + 4 c^2)] / 2 with c = rho/d0 (the left side
increases with tau_j; :func:`max_step_for`). No bound if d0 = 0. Uniform steps and given
sequences are checked before the first step; the adaptive controller keeps tau_j/alpha_0 below
0.95 rho/d0.

**Start.** The paper takes u_1^1, v_1^1 as data; here the run starts from u(0) = g, u'(0) = h.
Euler: u^{-1} = g - tau h, i.e. y^0 = h (regularized: y^0 = h - B^- G_dot^0 with zero trace).
BDF2 needs two past values of u and of v. A first Euler step would keep order 2 at T, but in
the original form the boundary velocity of that step is a difference quotient of G, off by
O(tau), the acceleration there a second difference quotient of that error, O(1), and the
largest multiplier error over the steps does not converge at all (0.17 at step 2 for every tau
from 2.5e-3 to 3.1e-4: ``python benchmarks/eld.py --part start``). Here BDF2 starts as if it
had run before t = 0 on the Taylor polynomial of the solution,

    P(s) = g + s h_c + s^2/2 a_0 + s^3/6 S^T G_3,    s <= 0,

with h_c = h with its Gamma_D values replaced by G_dot(0), a_0 the consistent initial
acceleration (rho M a_0 = F(0) - D(h_c) - K g on the free dofs, a_0 = G_ddot(0) on Gamma_D) and
G_3 = (G_ddot(tau_1) - G_ddot(0)) / tau_1 on Gamma_D: the history is u^{-1} = P(-tau_1) and the
velocities v^0, v^{-1} = the BDF2 quotients of P at 0 and -tau_1 (fictitious previous step
tau_0 = tau_1). On Gamma_D the original form's u is data, so v and a there are pure difference
quotients of G; with this start the sequence of their errors is smooth from the first step and
a^j|Gamma_D = G_ddot(t_j) + O(tau^2) at every step (with an exact velocity history it would be
O(tau) at steps 1 and 2). On the free dofs the equation itself fixes a^j, and O(tau^3) (u) and
O(tau^2) (v) history errors keep order 2. The regularized form uses the same history, split by
the lifting (x^{-k} = u^{-k} - B^-(u^{-k}|Gamma_D)). Tested: order 2 for u, u' and lambda at T
and as the maximum over all steps, both forms.

**Local error estimate** (``result.errors['local_error']``, for ``control='adaptive'``). The
trapezoidal residuals of the step, r_x = x^j - x^{j-1} - tau/2 (y^j + y^{j-1}) and
r_y = y^j - y^{j-1} - tau/2 (b^j + b^{j-1}), are O(tau^3) and, for smooth solutions,
c(omega) r estimates the local error of BDF2: its local error is -tau^3 (1 + omega)^2 /
(6 omega (1 + 2 omega)) u''' and r = -tau^3 u''' (1/12 + (1 + omega)^2/(6 omega (1 + 2 omega))),
so c(omega) = 2 (1 + omega)^2 / (omega (1 + 2 omega) + 2 (1 + omega)^2) (= 8/11 for equal steps).
For Euler r_x = tau/2 (y^j - y^{j-1}) = tau^2/2 u'' is the local error itself (c = 1). The
estimate is measured in the energy norm relative to the largest energy norm seen so far,

    local_error = c(omega) (r_x.K r_x + rho r_y.M r_y)^{1/2} / S_j,
    S_j = max(error_scale, max_{k<=j} (u^k.K u^k + rho v^k.M v^k)^{1/2})

(x, y, b are the scheme's unknowns: u_1, its velocity and acceleration in the regularized form;
u, v, a in the original form; with differenced data and the harmonic lifting u, v, a with their
Gamma_D values set to zero, since the lifted difference quotients of G jump after a step cut by
an amount no smaller step removes). The floor ``error_scale`` keeps a run that starts at rest from
resolving exponentially small signals relatively (a tanh ramp's tail); by default it is the larger
of the initial energy norm and the energy norms (rho|B^- G_dot|_M^2 + |B^- G|_K^2)^{1/2} of the
lifted data at 65 times in [0, T] (1 if all vanish). It needs only the current and the previous
step, so it is exact for variable steps and after rejections.

**Energy identity** (closes to round-off for every scheme, form and step sequence). Test the
full equation rho M a + D v + K u + B^T lambda - F = R (R: the algebraic residual of the step's
solve, zero up to solver tolerance) with tau_j v^j. With E = 1/2 rho v.M v + 1/2 u.K u,
Delta z^j = z^j - z^{j-1} and the identity, valid for any three vectors,

    <W tau delta z, z^j> = 1/2|z^j|_W^2 - 1/2|z^{j-1}|_W^2 + 1/2|Delta z^j|_W^2
                           + <W z^j, (alpha_0 - 1) Delta z^j - alpha_2 Delta z^{j-1}>,

one gets exactly

    E^j - E^{j-1} = tau F.v - tau lambda.(B v) - tau D(v).v + tau R.v - N^j - X^j,
    N^j = sum over (z, W) in ((v, rho M), (u, K)) of 1/2|Delta z^j|_W^2
          + <W z^j, (alpha_0 - 1) Delta z^j - alpha_2 Delta z^{j-1}>     (numerical dissipation)
    X^j = rho tau M(a^j - delta v^j).v^j + tau K u^j.(v^j - delta u^j)     (data/start mismatch)

(BDF2: from the first step on, v^0 in these formulas is the start history's velocity V0, and
X^1 also holds E^0 - E(u^0, V0) = O(tau^2)).

(all of u, v, a the full fields). Euler: N^j = 1/2 rho|Delta v|_M^2 + 1/2|Delta u|_K^2 >= 0.
BDF2: N^j is not sign-definite step by step; in G-stability form (mu_j = alpha_0 - 1, nu = 1/4)

    N^j = C^j - C^{j-1} + N_G^j + S^j,   C^j = mu_j <W z^j, Delta z^j> + nu |Delta z^j|_W^2,
    N_G^j = 1/4 |Delta z^j|_W^2 + 1/4 |Delta z^{j-1}|_W^2 - alpha_2 <W Delta z^j, Delta z^{j-1}>,
    S^j = (mu_{j-1} - alpha_2) <W z^{j-1}, Delta z^{j-1}>         (summed over (v, rho M), (u, K)),

so for equal steps (alpha_2 = 1/2, S = 0) N_G^j = 1/4|Delta^2 z^j|_W^2 >= 0 and the energy lost
numerically is sum N_G plus the boundary term C^n - C^0 (C is the G-norm energy minus E;
O(tau) and cancelling to O(tau^2) in free vibration). N_G >= 0 also while the steps shrink
(omega <= 1); S is the energy booked to step changes. X vanishes in the original form after the
first step and, in the regularized form, when G_dot, G_ddot are the scheme's difference
quotients of G. The trajectory holds the running sums ``work`` (loads), ``work_reaction`` (the
support on the prescribed motion), ``dissipated`` (physical), ``numerical_dissipation`` (N),
``numerical_dissipation_G`` (N_G), ``step_change`` (S), ``data_mismatch`` (X), ``residual_work``
(tau R.v), ``transfer`` (energy changes by mesh transfers, see below), and ``balance_residual``.

**The state** (:class:`ELDState`) holds every history vector on the mesh in one dict
``fields`` of named dof vectors of V_h (interleaved like the space):

    x, x_1     the scheme's unknown at t_j, t_{j-1} (u_1 regularized, u original)
    y, y_1     its velocity delta x at t_j, t_{j-1}
    b          its acceleration delta y at t_j
    u, u_1     displacement at t_j, t_{j-1};   v, v_1  velocity;   a  acceleration at t_j

(at j = 0 the ``_1`` entries are absent; BDF2 builds them at its first step), a dict
``boundary`` of vectors on the constrained dofs (Q_h: ``lam``, and in ``differenced`` mode the
data history ``G``, ``G_1``, ``G_dot``, ``G_dot_1``), and a dict ``products`` of cached M and K
times fields (:data:`PRODUCTS`: ``Mx`` = M x, ... ; every one is a matrix times one field, so
it can be recomputed). **Mesh transfer** (space adaptivity) goes through
:meth:`ELDState.mapped` (every field through a linear operator P_new<-old, every boundary vector
through an optional operator, products dropped) and :meth:`ELDStepper.adopt` of the stepper built
on the new mesh (recomputes the products and the energy, books the energy change as
``transfer`` in the ledger, and keeps every other history term). Nothing else carries state.

**Checkpoints.** :meth:`ELDStepper.checkpoint_state` returns a dict of arrays and plain values
(the state with its products, the ledger, the error scale, the solver's counters and the key of
the stored factorization: the effective step and, for nonlinear damping, the velocity of the
Jacobian it factors); :meth:`ELDStepper.restore_state` rebuilds the state and refactors from
that key, so a resumed run continues bit for bit (single-threaded BLAS). :func:`run_eld` and
:func:`prepare_eld_run` take ``checkpoint=`` / ``resume=`` (:mod:`rothe.io.checkpoint`).

Linear algebra: with linear damping and constant tau_eff the step matrix is factored once and
every step is one back-substitution plus two sparse products (M x, K x; every other product is
a combination of cached ones and thin products with the lifted data). When tau_eff changes,
the system is solved by Krylov iterations preconditioned with the stored factorization, which is
rebuilt from the current matrix when they stall (below REFACTOR_BELOW unknowns with the direct
solver: a new LU for every new tau_eff). Nonlinear damping: Newton's method with
backtracking, corrections by Krylov iterations preconditioned the same way
(:mod:`rothe.eld.solvers`). A step whose solve fails, or whose state or data is not finite, is
never accepted.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import (
    RotheInputError,
    RunFailed,
    check_choice,
    check_int,
    check_positive,
    described,
    fail,
)
from ..io.checkpoint import RunCheckpointing, run_arguments
from ..io.trajectory import Trajectory
from ..stepping.controllers import FixedStepController
from ..stepping.evolve import evolve, single_threaded_blas
from .constraint import LIFTINGS, make_lifting
from .controllers import adaptive_controller
from .data import DATA_MODES, DataNoise, StepData
from .problem import ELDProblem
from .solvers import ConstrainedSolver, ReferenceSolver, SolveFailed, SolverStats, resolve_kind

FORMS = ("regularized", "original")
SCHEMES = ("euler", "bdf2")
CONTROLS = ("uniform", "adaptive")
#: BDF2 starts: the Taylor history of the module docstring (default), the same without the
#: cubic Gamma_D term, and one implicit Euler step (the last two only to show why not)
STARTS = ("taylor", "taylor2", "euler")
#: variable-step BDF2 is zero-stable for step ratios below 1 + sqrt(2)
BDF2_ZERO_STABILITY = 1.0 + math.sqrt(2.0)
#: the adaptive controller's largest step ratio for BDF2 (well below the zero-stability limit)
BDF2_RATIO_CAP = 1.8
#: the adaptive controller stays below this fraction of the solvability bound
BOUND_SAFETY = 0.95
#: below this many unknowns a new tau_eff gets its own LU (cheaper than ~10 preconditioned
#: Krylov iterations with the stored one; PERFORMANCE-NOTES: factor / solve ~ 26 at 25k in 2D)
REFACTOR_BELOW = 20_000
#: cached products: name -> (matrix, field)
PRODUCTS = {
    "Mx": ("M", "x"),
    "Kx": ("K", "x"),
    "Mx_1": ("M", "x_1"),
    "Kx_1": ("K", "x_1"),
    "My": ("M", "y"),
    "Ky": ("K", "y"),
    "My_1": ("M", "y_1"),
    "Ky_1": ("K", "y_1"),
    "Mb": ("M", "b"),
    "Ku": ("K", "u"),
    "Mv": ("M", "v"),
}


def step_coefficients(
    scheme: str, tau: float, tau_prev: float | None = None
) -> tuple[float, float, float]:
    """(alpha_0, alpha_1, alpha_2) of delta_j z = (alpha_0 z^j + alpha_1 z^{j-1} + alpha_2
    z^{j-2}) / tau_j (module docstring); BDF2 with omega = tau / tau_prev (1 if None)."""
    if scheme == "euler":
        return 1.0, -1.0, 0.0
    w = 1.0 if tau_prev is None else tau / tau_prev
    return (1.0 + 2.0 * w) / (1.0 + w), -(1.0 + w), w * w / (1.0 + w)


def max_step_for(scheme: str, bound: float, tau_prev: float | None) -> float:
    """The supremum of the steps tau with tau / alpha_0(tau / tau_prev) < bound (= rho/d0).

    Euler: bound. BDF2: 1.5 bound for the first step (fictitious tau_0 = tau_1) and otherwise
    the positive root of tau (tau_prev + tau) = bound (tau_prev + 2 tau)."""
    if not math.isfinite(bound):
        return math.inf
    if scheme == "euler":
        return bound
    if tau_prev is None:
        return 1.5 * bound
    c, tp = bound, tau_prev
    return 0.5 * (2.0 * c - tp + math.sqrt(tp * tp + 4.0 * c * c))


def estimate_factor(scheme: str, omega: float) -> float:
    """c(omega): local error of the step = c(omega) times its trapezoidal residual."""
    if scheme == "euler":
        return 1.0
    w = omega
    return 2.0 * (1.0 + w) ** 2 / (w * (1.0 + 2.0 * w) + 2.0 * (1.0 + w) ** 2)


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
    """Cumulative terms of the discrete energy identity (module docstring)."""

    kinetic: float = 0.0
    elastic: float = 0.0
    initial: float = 0.0
    work: float = 0.0  # loads F
    work_reaction: float = 0.0  # support on the prescribed boundary motion: -tau lambda.B v
    dissipated: float = 0.0  # physical: tau D(v).v
    numerical: float = 0.0  # N^j
    mismatch: float = 0.0  # X^j
    residual_work: float = 0.0  # tau R.v (solver residual)
    transfer: float = 0.0  # energy changes by mesh transfers (ELDStepper.adopt)
    numerical_G: float = 0.0  # N_G^j (G-stability part of N)
    step_change: float = 0.0  # S^j
    boundary_C: float = 0.0  # C^j (current)
    boundary_C0: float = 0.0  # C^0
    # pieces of C^j kept for the next step: <W z, Delta z> and |Delta z|_W^2, (v, rho M), (u, K)
    g_zd_kin: float = 0.0
    g_sq_kin: float = 0.0
    g_zd_el: float = 0.0
    g_sq_el: float = 0.0
    g_mu: float = 0.0

    @property
    def energy(self) -> float:
        return self.kinetic + self.elastic

    @property
    def residual(self) -> float:
        """E^j - E^0 - (work + work_reaction - dissipated + residual_work - numerical - mismatch
        + transfer)."""
        return (
            self.energy
            - self.initial
            - (
                self.work
                + self.work_reaction
                - self.dissipated
                + self.residual_work
                - self.numerical
                - self.mismatch
                + self.transfer
            )
        )


@dataclass
class ELDState:
    """The state after step j (module docstring: fields, boundary, products)."""

    t: float
    j: int
    tau_prev: float | None  # the step that ended at t (None at j = 0)
    fields: dict
    boundary: dict
    products: dict
    ledger: EnergyLedger
    energy_norm_max: float = 0.0  # S_j: scale of the error estimate (module docstring)
    mesh_id: int = 0  # the mesh the fields live on (space adaptivity, rothe.eld.adapt)

    @property
    def s(self) -> float:  # the evolve loop's curve parameter: here the time
        return self.t

    @property
    def u(self) -> np.ndarray:
        return self.fields["u"]

    @property
    def v(self) -> np.ndarray:
        return self.fields["v"]

    @property
    def lam(self) -> np.ndarray | None:
        return self.boundary.get("lam")

    def mapped(self, op, boundary_op=None) -> ELDState:
        """The state with every field mapped through the linear operator ``op`` (a matrix or a
        callable, new dofs x old dofs), every boundary vector through ``boundary_op`` (dropped if
        None), and no cached products (:meth:`ELDStepper.adopt` recomputes them)."""
        apply = op if callable(op) else (lambda w: op @ w)
        fields = {k: np.asarray(apply(w), dtype=float) for k, w in self.fields.items()}
        if boundary_op is None:
            boundary = {}
        else:
            bapply = boundary_op if callable(boundary_op) else (lambda w: boundary_op @ w)
            boundary = {k: np.asarray(bapply(w), dtype=float) for k, w in self.boundary.items()}
        return replace(self, fields=fields, boundary=boundary, products={})


@dataclass
class ELDStepResult:
    state: ELDState | None
    tau: float
    lam: np.ndarray | None = None
    reactions: dict = field(default_factory=dict)
    newton_iterations: int = 0
    estimate: float = math.nan
    counters: dict = field(default_factory=dict)
    converged: bool = True
    code: str = "ok"
    message: str = ""
    where: dict = field(default_factory=dict)

    @property
    def errors(self) -> dict:
        return {"local_error": self.estimate}


class _NewtonFailed(Exception):
    def __init__(self, iterations: int, rnorm: float):
        super().__init__(f"{iterations} iterations, |R| = {rnorm:.3g}")
        self.iterations = iterations
        self.rnorm = rnorm


def _dot(a, b) -> float:
    return float(a @ b)


class ELDStepper:
    """One step of Euler or BDF2 in either form (module docstring); the evolve loop drives it.

    Parameters
    ----------
    problem : ELDProblem
    form : 'regularized' | 'original'
    tau : the step (uniform control: T / tau must be an integer) or the first step (adaptive)
    scheme : 'euler' | 'bdf2'
    control : 'uniform' | 'adaptive'
    steps : a given step sequence tau_1, ..., tau_n summing to T (instead of tau)
    data : 'points' | 'means' (Euler only) | 'differenced'  (:mod:`rothe.eld.data`)
    lifting : 'nodal' | 'harmonic'  (the right inverse B^-, regularized form)
    solver : 'auto' | 'direct' | 'amg'
    noise : DataNoise, optional perturbation of the data of every step (Sec. 4.3)
    store_fields, keep_every : keep u, v, a, lambda of every k-th state (and the last)
    observer : callable(state, result) after every accepted step (e.g. to write XDMF)
    linear_rtol : relative residual of iterative linear solves
    start : BDF2 start, 'taylor' (default; module docstring), or for studies of the start
        'taylor2' (no cubic Gamma_D term: O(tau) multiplier error at steps 1 and 3 in the
        original form) and 'euler' (one implicit Euler step: O(1) multiplier error at step 2)
    """

    def __init__(
        self,
        problem: ELDProblem,
        form: str,
        tau: float,
        *,
        scheme: str = "euler",
        control: str = "uniform",
        steps=None,
        data: str = "points",
        lifting: str = "nodal",
        solver: str = "auto",
        newton: NewtonOptions | None = None,
        noise: DataNoise | None = None,
        store_fields: bool = True,
        keep_every: int = 1,
        observer=None,
        linear_rtol: float = 1e-10,
        start: str = "taylor",
        error_scale: float | None = None,
    ):
        self.problem = p = problem
        self.form = check_choice("form", form, FORMS)
        self.scheme = check_choice("scheme", scheme, SCHEMES)
        self.start = check_choice("start", start, STARTS)
        self.control = check_choice("control", control, CONTROLS)
        self.data_mode = check_choice("data", data, DATA_MODES)
        if self.scheme == "bdf2" and self.data_mode == "means":
            raise fail(
                "data",
                "means",
                "with scheme bdf2 must be points or differenced (step "
                "means are first-order data: they sit O(tau) away from t_j)",
            )
        self.lifting_kind = check_choice("lifting", lifting, LIFTINGS)
        self.newton = newton or NewtonOptions()
        self.store_fields = bool(store_fields)
        self.keep_every = check_int("keep_every", keep_every, minimum=1)
        self.observer = observer
        self.T = p.T
        self.bound = p.step_bound()
        self.order = 1 if self.scheme == "euler" else 2
        self.max_ratio = math.inf if self.scheme == "euler" else BDF2_RATIO_CAP
        self._setup_grid(tau, steps)
        p.check_initial_consistency()
        self.data = StepData(p, self.data_mode, noise)

        c = p.constraint
        self.rho = p.material.rho
        self.D = p.damping_op
        self.I = c.free
        # the first step's effective step: the stored factorization's matrix
        a0 = 1.0 if self.scheme == "euler" else 1.5
        te0 = self.tau / a0
        self._A_te = te0
        self._A_stored = None
        self._ref: dict | None = None  # what the solver's stored factorization was built from
        # with linear damping and no user matrix, A(te) restricted to the free nodes is
        # gathered from the blocks of K and the scalar mass (VectorSpace.restricted_combination):
        # A itself and its row and column slices (0.6 GB each at a million unknowns) are
        # never formed
        self._free_nodes = free_nodes = np.setdiff1d(np.arange(p.space.n_scalar), c.scalar_dofs)
        self._lean = self.D.matrix is None
        if self.form == "regularized":
            self.kind = resolve_kind(solver, self.I.size, p.space.dim)
            rbm = p.space.rigid_body_modes(free_nodes) if self.kind == "amg" else None
            self.solver = ReferenceSolver(self.kind, spd=True, near_nullspace=rbm, rtol=linear_rtol)
            self.lifting = make_lifting(self.lifting_kind, c, p.K)
            if self.lifting_kind == "nodal":
                # B^- g = S^T g: products with lifted data only touch the columns of Gamma_D
                self._M_C = p.space.symmetric_columns(p.M, c.scalar_dofs)
                self._K_C = p.space.symmetric_columns(p.K, c.scalar_dofs)
        else:
            # the bordered system is solved by condensing the constraint (ConstrainedSolver):
            # the size of A_II, and LU or AMG of A_II both apply
            self.kind = resolve_kind(solver, self.I.size, p.space.dim)
            rbm = p.space.rigid_body_modes(free_nodes) if self.kind == "amg" else None
            self.solver = ConstrainedSolver(c, self.kind, near_nullspace=rbm, rtol=linear_rtol)
            self.lifting = None
        # A(tau_eff) of the first step, restricted to ker B (regularized) or full (original);
        # at a million unknowns every matrix of this size costs 0.6 GB: keep only this one (the
        # lean original form keeps none: its products with A(te) go through M and K)
        if self._lean and self.form == "original":
            self._A_te = None
        else:
            self._A_stored = self._operator_matrix(te0)
        if self.D.is_linear:
            self._factor(te0, None)
        self.initial_factorizations = self.solver.stats.factorizations
        self._last_newton = 0
        self.error_scale = (
            None if error_scale is None else check_positive("error_scale", error_scale)
        )

    # -- set-up ---------------------------------------------------------------------------------
    def _setup_grid(self, tau, steps) -> None:
        T = self.T
        self.steps = None
        self.tau_uniform = None
        if steps is not None:
            if self.control != "uniform":
                raise fail(
                    "steps", described("a step sequence"), "is a fixed grid: use control='uniform'"
                )
            self.steps = self._check_steps(steps)
            self.tau = float(self.steps[0])
            self.n_steps = int(self.steps.size)
            times = np.cumsum(self.steps)
            times[-1] = T
            self._times = np.concatenate([[0.0], times])
            return
        self.tau = tau = check_positive("tau", tau)
        if self.control == "uniform":
            self._check_uniform_bound(tau)
            ratio = T / tau
            n = round(ratio) if math.isfinite(ratio) and ratio < 2**62 else -1
            if n < 1 or abs(ratio - n) > 1e-9 * max(1.0, ratio):
                raise fail(
                    "tau", tau, f"must divide T = {T:g} into equal steps (T/tau = {ratio:.6g})"
                )
            self.n_steps = int(n)
            self.tau_uniform = tau
        else:
            if tau > T:
                raise fail("tau", tau, f"(the first step) must be <= T = {T:g}")
            self.n_steps = None
            self._check_uniform_bound(tau)  # the first step

    def _check_uniform_bound(self, tau: float) -> None:
        bound = self.bound
        if self.scheme == "euler":
            if not tau < bound:
                raise fail(
                    "tau",
                    tau,
                    f"must be < rho/d0 = {bound:g} (Lemma 3.2: unique "
                    "solvability of the Euler steps)",
                )
        elif not tau / 1.5 < bound:
            raise fail(
                "tau",
                tau,
                f"must be < 1.5 rho/d0 = {1.5 * bound:g} (Lemma 3.2 for BDF2: "
                "tau_j/alpha_j < rho/d0 with alpha_j = (1 + 2 omega)/(1 + omega) = 1.5 "
                "for equal steps)",
            )

    def _check_steps(self, steps) -> np.ndarray:
        try:
            arr = np.asarray(steps, dtype=float).ravel()
        except (TypeError, ValueError):
            raise fail(
                "steps", described(type(steps).__name__), "must be a sequence of step sizes"
            ) from None
        if arr.size == 0:
            raise fail("steps", described("[]"), "must hold at least one step size")
        bad = np.flatnonzero(~(np.isfinite(arr) & (arr > 0)))
        if bad.size:
            k = int(bad[0])
            raise fail(
                "steps", described(f"tau_{k + 1} = {arr[k]:g}"), "must be positive and finite"
            )
        total = float(arr.sum())
        if abs(total - self.T) > 1e-10 * self.T:
            raise fail(
                "steps", described(f"steps summing to {total:.12g}"), f"must sum to T = {self.T:g}"
            )
        tau_prev = None
        for k, tau in enumerate(arr):
            if self.scheme == "bdf2" and tau_prev is not None:
                ratio = tau / tau_prev
                if not ratio < BDF2_ZERO_STABILITY:
                    raise fail(
                        "steps",
                        described(f"tau_{k + 1}/tau_{k} = {ratio:.6g}"),
                        f"must be < 1 + sqrt(2) = {BDF2_ZERO_STABILITY:.6g} (zero-stability "
                        "of variable-step BDF2)",
                    )
            a0 = step_coefficients(self.scheme, tau, tau_prev)[0]
            if not tau / a0 < self.bound:
                raise fail(
                    "steps",
                    described(f"tau_{k + 1} = {tau:g}"),
                    f"must satisfy tau_j/alpha_j < rho/d0 = {self.bound:g} (alpha_j = "
                    f"{a0:.6g}; Lemma 3.2)",
                )
            tau_prev = tau
        return arr

    @property
    def system_size(self) -> int:
        """Unknowns of the step's linear systems: free dofs (regularized) or dofs + multiplier."""
        c = self.problem.constraint
        return self.I.size if self.form == "regularized" else self.problem.space.ndofs + c.m

    @property
    def A_II(self):
        """The stored step matrix A(tau_eff) on the free dofs (regularized form)."""
        return self._A_stored if self.form == "regularized" else None

    def max_step(self, tau_prev: float | None) -> float:
        """The controller's limit for the step after ``tau_prev``: the step whose effective
        step tau/alpha_0 is BOUND_SAFETY times the solvability bound (:func:`max_step_for`)."""
        return max_step_for(self.scheme, BOUND_SAFETY * self.bound, tau_prev)

    # -- matrices and solves --------------------------------------------------------------------
    def _step_matrix(self, te: float) -> sp.csr_matrix:
        """A(te) = (rho/te^2) M + C/te + K with C = a_M M + a_K K (+ E), without forming C."""
        p, D = self.problem, self.D
        A = (
            (self.rho / te**2 + D.mass_coef / te) * p.M + (1.0 + D.stiffness_coef / te) * p.K
        ).tocsr()
        if D.matrix is not None:
            A = (A + (1.0 / te) * D.matrix).tocsr()
        return A

    def _coefficients(self, te: float) -> tuple[float, float]:
        """(c_mass, c_stiff) of A(te) = c_mass M + c_stiff K (+ E/te)."""
        D = self.D
        return self.rho / te**2 + D.mass_coef / te, 1.0 + D.stiffness_coef / te

    def _restricted(self, te: float):
        """A(te) on the free nodes, a BlockMatrix gathered from K and the scalar mass."""
        c_mass, c_stiff = self._coefficients(te)
        p = self.problem
        return p.space.restricted_combination(p.K, c_stiff, c_mass, self._free_nodes)

    def _operator_matrix(self, te: float):
        if self._lean and self.form == "regularized":
            return self._restricted(te)
        A = self._step_matrix(te)
        if self.form == "regularized":
            return A[self.I][:, self.I].tocsr()
        return A

    def _apply_A(self, w: np.ndarray, te: float) -> np.ndarray:
        """A(te) w on the form's unknowns (free dofs, or all dofs in the original form)."""
        if te == self._A_te:
            return self._A_stored @ w
        p, D = self.problem, self.D
        if self.form == "regularized":
            full = np.zeros(p.space.ndofs)
            full[self.I] = w
        else:
            full = w
        out = (self.rho / te**2 + D.mass_coef / te) * (p.M @ full) + (
            1.0 + D.stiffness_coef / te
        ) * (p.K @ full)
        if D.matrix is not None:
            out = out + (D.matrix @ full) / te
        return out[self.I] if self.form == "regularized" else out

    def _kkt(self, A) -> sp.csr_matrix:
        B = self.problem.constraint.B
        return sp.bmat([[A, B.T], [B, None]], format="csr")

    def _pattern_parts(self):
        """The system's sparsity pattern with the values of M, K, E (and B) on it, so that A(te)
        for a new te is one linear combination of value arrays (variable steps)."""
        if getattr(self, "_parts", None) is None:
            p, D = self.problem, self.D
            n = p.space.ndofs
            E = sp.csr_matrix(D.matrix) if D.matrix is not None else sp.csr_matrix((n, n))
            zero_nn = sp.csr_matrix((n, n))
            if self.form == "regularized":

                def system(X, Bpart=None):
                    return sp.csr_matrix(X)[self.I][:, self.I]
            else:
                B = p.constraint.B
                zero_B = sp.csr_matrix(B.shape)

                def system(X, Bpart=None):
                    return self._kkt_blocks(X, zero_B if Bpart is None else Bpart)

            P = sp.csr_matrix(system(p.M + p.K + E, None if self.form == "regularized" else B))
            P.sum_duplicates()
            P.sort_indices()
            ncol = P.shape[1]
            keys = (
                np.repeat(np.arange(P.shape[0], dtype=np.int64), np.diff(P.indptr)) * ncol
                + P.indices
            )

            def on_pattern(X):
                X = sp.csr_matrix(X)
                X.sum_duplicates()
                xk = (
                    np.repeat(np.arange(X.shape[0], dtype=np.int64), np.diff(X.indptr)) * ncol
                    + X.indices
                )
                out = np.zeros(keys.size)
                out[np.searchsorted(keys, xk)] = X.data
                return out

            parts = {
                "M": on_pattern(system(p.M)),
                "K": on_pattern(system(p.K)),
                "E": on_pattern(system(E)),
                "B": None if self.form == "regularized" else on_pattern(system(zero_nn, B)),
            }
            self._parts = (P.indices.copy(), P.indptr.copy(), P.shape, parts)
        return self._parts

    @staticmethod
    def _kkt_blocks(A, B):
        m = B.shape[0]
        return sp.bmat([[A, B.T], [B, sp.csr_matrix((m, m))]], format="csr")

    def _system_matrix(self, te: float, v: np.ndarray | None) -> sp.csr_matrix:
        """The matrix a factorization is built from: A(te) (+ N'(v)/te), restricted or bordered.
        A function of (te, v) alone, so that a checkpoint can name it (variable steps with
        linear damping: by value arrays on a fixed pattern, :meth:`_pattern_parts`)."""
        variable_steps = self.n_steps is None or self.steps is not None
        if v is None and self._lean and self.form == "regularized":
            return self._restricted(te)
        if v is None and variable_steps:
            indices, indptr, shape, parts = self._pattern_parts()
            D = self.D
            data = (
                (self.rho / te**2 + D.mass_coef / te) * parts["M"]
                + (1.0 + D.stiffness_coef / te) * parts["K"]
                + (1.0 / te) * parts["E"]
            )
            if parts["B"] is not None:
                data = data + parts["B"]
            return sp.csr_matrix((data, indices.copy(), indptr.copy()), shape=shape)
        A = self._step_matrix(te)
        if v is not None:
            A = (A + (1.0 / te) * self.D.nonlinear_jacobian(v)).tocsr()
        if self.form == "regularized":
            return A[self.I][:, self.I].tocsr()
        return self._kkt(A)

    def _factor(self, te: float, v: np.ndarray | None) -> None:
        if v is None and self._lean and self.form == "regularized" and te == self._A_te:
            # the stored step matrix itself: no second copy for the solver; the AMG setup is
            # the peak of a large run, so first free what only assemblies need
            if self.kind == "amg":
                self.problem.space.release_assembly_caches()
            self.solver.factor(self._A_stored)
        elif v is None and self._lean and self.form == "original":
            # A_II and the thin blocks of A on the constrained dofs, for the condensed solve
            # (A is symmetric: its rows on the constrained dofs are the transposed columns)
            p = self.problem
            c = p.constraint
            c_mass, c_stiff = self._coefficients(te)
            A_C = (
                c_mass * p.space.symmetric_columns(p.M, c.scalar_dofs)
                + c_stiff * p.space.symmetric_columns(p.K, c.scalar_dofs)
            ).tocsr()
            A_IC = A_C[self.I]
            A_II = self._restricted(te)
            if self.kind == "amg":
                p.space.release_assembly_caches()
            self.solver.factor_parts(A_II, A_IC, A_IC.T, A_C[c.dofs])
            del A_II
        else:
            self.solver.factor(self._system_matrix(te, v))
        self._ref = {"tau_eff": float(te), "v": None if v is None else v.copy()}

    def _assembler(self, te: float, v: np.ndarray | None):
        def assemble():
            self._ref = {"tau_eff": float(te), "v": None if v is None else v.copy()}
            return self._system_matrix(te, v)

        return assemble

    def _solve_linear(self, rhs: np.ndarray, te: float, guess=None) -> np.ndarray:
        """A(te) z = rhs (bordered in the original form) for linear damping."""
        ref = self._ref
        if ref is not None and ref["v"] is None and ref["tau_eff"] == te:
            return self.solver.solve_reference(rhs, x0=guess)
        n = rhs.size
        if self.kind == "direct" and n <= REFACTOR_BELOW:
            self._factor(te, None)
            return self.solver.solve_reference(rhs, x0=guess)
        if self.form == "regularized":
            op = spla.LinearOperator((n, n), matvec=lambda w: self._apply_A(w, te), dtype=float)
        else:
            B = self.problem.constraint.B
            nu = self.problem.space.ndofs

            def matvec(z):
                return np.concatenate([self._apply_A(z[:nu], te) + B.T @ z[nu:], B @ z[:nu]])

            op = spla.LinearOperator((n, n), matvec=matvec, dtype=float)
        return self.solver.solve(op, rhs, assemble=self._assembler(te, None))

    # -- initial state --------------------------------------------------------------------------
    def _lift(self, g: np.ndarray) -> np.ndarray:
        return self.lifting(g)

    def _split(self, w: np.ndarray) -> np.ndarray:
        """The kernel part w - B^-(w|Gamma_D) (exactly zero on Gamma_D)."""
        c = self.problem.constraint
        out = w - self._lift(w[c.dofs])
        out[c.dofs] = 0.0
        return out

    def consistent_acceleration(
        self, t: float, u: np.ndarray, v: np.ndarray, G_ddot: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(a, lambda) from (2.7a) at time t for given u, v: a = G_ddot on Gamma_D and
        rho M_II a_I = (F(t) - D(v) - K u)_I - rho M_IC G_ddot (CG with the diagonal of M, a
        mass matrix is well conditioned), lambda from the Gamma_D rows."""
        p = self.problem
        c = p.constraint
        I = self.I
        n = p.space.ndofs
        rhs = p.load(t) - self.D.apply(v) - p.K @ u
        a = np.zeros(n)
        a[c.dofs] = G_ddot
        r = (rhs - self.rho * (p.M @ a))[I] / self.rho
        diag = p.M.diagonal()[I]

        def mv(w):
            full = np.zeros(n)
            full[I] = w
            return (p.M @ full)[I]

        op = spla.LinearOperator((I.size, I.size), matvec=mv, dtype=float)
        prec = spla.LinearOperator((I.size, I.size), matvec=lambda w: w / diag, dtype=float)
        aI, info = spla.cg(op, r, rtol=1e-13, atol=0.0, maxiter=1000, M=prec)
        a[I] = aI
        lam = c.multiplier_from_residual((rhs - self.rho * (p.M @ a))[c.dofs])
        return a, lam

    def initial_state(self) -> ELDState:
        """The state at t = 0 (raises RunFailed if the consistent acceleration or multiplier
        at t = 0 is not finite, e.g. after an overflow)."""
        # BLAS level-1 calls outside the evolve loop: single-threaded as inside it
        # (rothe.stepping.evolve.single_threaded_blas; threaded dots spin on busy cores)
        with single_threaded_blas(), np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return self._initial_state()

    def _initial_state(self) -> ELDState:
        p = self.problem
        c = p.constraint
        G0, Gd0 = self.data.initial()
        vc = p.v0.copy()
        vc[c.dofs] = Gd0
        Gdd0 = p.G_ddot(0.0)
        for name, value in (("load(0)", p.load(0.0)), ("G_dot(0)", Gd0), ("G_ddot(0)", Gdd0)):
            if not np.all(np.isfinite(value)):
                raise fail(name, "non-finite values", "must be finite (the initial data)")
        a0, lam0 = self.consistent_acceleration(0.0, p.u0, vc, Gdd0)
        if not (np.all(np.isfinite(a0)) and np.all(np.isfinite(lam0))):
            raise RunFailed(
                "non-finite initial state: the consistent acceleration or multiplier "
                "at t = 0 has NaN or inf entries (overflow?)",
                where={"step": 0, "s": 0.0, "t": 0.0, "form": self.form, "scheme": self.scheme},
            )
        if self.form == "regularized":
            u2, v2, w2 = self.lifting.lift_many([G0, Gd0, Gdd0])
            x = p.u0 - u2
            x[c.dofs] = 0.0
            y = vc - v2
            y[c.dofs] = 0.0
            b = a0 - w2
            b[c.dofs] = 0.0
            u, v = x + u2, y + v2
        else:
            x, y, b = p.u0.copy(), p.v0.copy(), a0.copy()
            u, v = x, p.v0.copy()
        fields = {"x": x, "y": y, "b": b, "u": u, "v": v, "a": a0}
        boundary = {"lam": lam0}
        if self.data_mode == "differenced":
            boundary.update(G=G0, G_dot=Gd0)
        state = ELDState(
            t=0.0,
            j=0,
            tau_prev=None,
            fields=fields,
            boundary=boundary,
            products={},
            ledger=EnergyLedger(),
        )
        self._fill_products(state)
        Ku, Mv = state.products["Ku"], state.products["Mv"]
        kin, el = 0.5 * self.rho * _dot(v, Mv), 0.5 * _dot(u, Ku)
        state.ledger = EnergyLedger(kinetic=kin, elastic=el, initial=kin + el)
        norm0 = math.sqrt(max(2.0 * (kin + el), 0.0))
        if self.error_scale is None and self.control == "adaptive":
            self.error_scale = max(norm0, self._data_scale()) or 1.0
        state.energy_norm_max = max(norm0, self.error_scale or 0.0)
        return state

    def _data_scale(self) -> float:
        """max over 65 times in [0, T] of (rho|B^- G_dot|_M^2 + |B^- G|_K^2)^{1/2} (the lifting
        of the regularized form; the nodal one in the original form)."""
        p = self.problem
        c = p.constraint
        best = 0.0
        for t in np.linspace(0.0, self.T, 65):
            g, gd = p.G(t), p.G_dot(t)
            if not (np.all(np.isfinite(g)) and np.all(np.isfinite(gd))):
                continue
            if self.lifting is not None:
                u2, v2 = self.lifting.lift_many([g, gd])
            else:
                u2, v2 = c.embed(g), c.embed(gd)
            best = max(best, self.rho * _dot(v2, p.M @ v2) + _dot(u2, p.K @ u2))
        return math.sqrt(best)

    def _fill_products(self, state: ELDState, names=None) -> None:
        p = self.problem
        mats = {"M": p.M, "K": p.K}
        for name, (mat, fname) in PRODUCTS.items():
            if names is not None and name not in names:
                continue
            if fname in state.fields and name not in state.products:
                state.products[name] = mats[mat] @ state.fields[fname]

    def adopt(self, state: ELDState) -> ELDState:
        """Take over a state mapped from another mesh (:meth:`ELDState.mapped`): recompute the
        cached products with this stepper's M and K, the energy and the G-form pieces of the
        ledger; the energy change is booked as ``transfer``. (The mesh change itself, and the
        stepper for the new mesh, belong to the space-adaptivity layer.)"""
        state = replace(
            state, products={}, fields=dict(state.fields), boundary=dict(state.boundary)
        )
        self._fill_products(state)
        p = self.problem
        f, pr = state.fields, state.products
        L = state.ledger
        kin, el = 0.5 * self.rho * _dot(f["v"], pr["Mv"]), 0.5 * _dot(f["u"], pr["Ku"])
        new = replace(L, kinetic=kin, elastic=el, transfer=L.transfer + (kin + el) - L.energy)
        if "u_1" in f:
            dv, du = f["v"] - f["v_1"], f["u"] - f["u_1"]
            Mdv, Kdu = pr["Mv"] - p.M @ f["v_1"], pr["Ku"] - p.K @ f["u_1"]
            new.g_zd_kin = self.rho * _dot(pr["Mv"], dv)
            new.g_sq_kin = self.rho * _dot(Mdv, dv)
            new.g_zd_el = _dot(pr["Ku"], du)
            new.g_sq_el = _dot(Kdu, du)
        state.ledger = new
        return state

    def record_initial(self, traj: Trajectory, state: ELDState) -> None:
        L = state.ledger
        rec = dict(
            t=0.0,
            kinetic=L.kinetic,
            elastic=L.elastic,
            energy=L.energy,
            work=0.0,
            work_reaction=0.0,
            dissipated=0.0,
            numerical_dissipation=0.0,
            numerical_dissipation_G=0.0,
            step_change=0.0,
            data_mismatch=0.0,
            residual_work=0.0,
            transfer=0.0,
            balance_residual=0.0,
        )
        traj.append(**rec)
        if self.store_fields:
            self._keep(traj, state)

    def _keep(self, traj: Trajectory, state: ELDState) -> None:
        traj.append(
            kept_step=state.j,
            kept_t=state.t,
            u=state.u.copy(),
            v=state.v.copy(),
            a=state.fields["a"].copy(),
            lam=state.lam.copy(),
        )

    # -- evolve-loop interface ------------------------------------------------------------------
    def finished(self, state: ELDState) -> bool:
        if self.n_steps is not None:
            return state.j >= self.n_steps
        return state.t >= self.T

    def limit(self, state: ELDState, tau: float) -> float:
        """Adaptive control: land on T (the last two steps split the rest evenly instead of
        leaving a sliver)."""
        if self.n_steps is not None:
            return tau
        rest = self.T - state.t
        if tau >= rest * (1.0 - 1e-12):
            return rest
        if tau < rest < 2.0 * tau:
            return 0.5 * rest
        return tau

    def overshoot(self, state, attempts):
        return None  # the grid (or limit) lands on T exactly

    def pick_landing(self, state, attempts):
        return attempts[-1]

    def where(self, state: ELDState, result=None) -> dict:
        info = {
            "step": state.j + 1,
            "s": state.t,
            "t": state.t,
            "tau": result.tau if result is not None else self.tau,
            "form": self.form,
            "scheme": self.scheme,
        }
        if result is not None:
            info["newton_iterations"] = result.newton_iterations
        return info

    def progress_fields(self, state: ELDState) -> dict:
        return {"t": f"{state.t:.4g}", "newton": self._last_newton}

    def _time_after(self, state: ELDState, tau: float) -> float:
        j = state.j + 1
        if self.tau_uniform is not None:
            return j * self.tau_uniform
        if self.steps is not None:
            return float(self._times[j])
        t = state.t + tau
        if abs(t - self.T) <= 4.0 * np.finfo(float).eps * max(1.0, self.T):
            t = self.T
        return t

    def _failed(self, state, tau, code, message, its=0, counters=None) -> ELDStepResult:
        where = self.where(state)
        where.update(tau=tau, newton_iterations=its)
        return ELDStepResult(
            state=None,
            tau=tau,
            newton_iterations=its,
            converged=False,
            code=code,
            message=message,
            where=where,
            counters=counters or {},
        )

    def step(self, state: ELDState, tau: float, s_end=None) -> ELDStepResult:
        # overflow and NaN are detected in the result (a failed step), not reported as warnings
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            return self._step(state, tau)

    def _step(self, state: ELDState, tau: float) -> ELDStepResult:
        j = state.j + 1
        t_new = self._time_after(state, tau)
        scheme = self.scheme
        if scheme == "bdf2" and state.j == 0:
            if self.start == "euler":
                scheme = "euler"
            else:
                state = self._with_prehistory(state, tau)
        coeffs = step_coefficients(scheme, tau, state.tau_prev)
        a0 = coeffs[0]
        if self.scheme == "bdf2" and state.j > 0 and not tau / state.tau_prev < BDF2_ZERO_STABILITY:
            raise RunFailed(
                f"step {j}: tau/tau_prev = {tau / state.tau_prev:.6g} is beyond the "
                f"zero-stability limit 1 + sqrt(2) of variable-step BDF2",
                where=self.where(state),
            )
        if not tau / a0 < self.bound:
            raise RunFailed(
                f"step {j}: tau = {tau:g} violates tau/alpha_0 < rho/d0 = "
                f"{self.bound:g} (Lemma 3.2)",
                where=self.where(state),
            )
        hist = None
        if self.data_mode == "differenced":
            hist = {k: state.boundary[k] for k in ("G", "G_dot")}
            if coeffs[2]:
                hist.update(G_1=state.boundary["G_1"], G_dot_1=state.boundary["G_dot_1"])
        vals = self.data.at(j, state.t, t_new, coeffs, hist)
        bad = vals.first_nonfinite()
        if bad is not None:
            what = {
                "F": "the load F (body force, tractions)",
                "G": "the Dirichlet data G",
                "G_dot": "G_dot",
                "G_ddot": "G_ddot",
            }[bad]
            raise RunFailed(
                f"non-finite data at step {j} (t = {t_new:.6g}): {what} has NaN or inf entries",
                where=self.where(state),
            )
        st = self.solver.stats
        before = (st.factorizations, st.backsolves, st.krylov_iterations, st.solves)

        def counters():
            return {
                "newton_iterations": its,
                "linear_factorizations": st.factorizations - before[0],
                "linear_solves": st.backsolves - before[1],
                "krylov_iterations": st.krylov_iterations - before[2],
            }

        its = 0
        try:
            if self.form == "regularized":
                k, its = self._step_regularized(state, vals, coeffs, tau)
            else:
                k, its = self._step_original(state, vals, coeffs, tau)
        except SolveFailed as exc:
            return self._failed(
                state,
                tau,
                "linear-solve",
                f"linear solve failed at step {j} "
                f"(t = {t_new:.6g}, tau = {tau:g}): {exc}; the step is not "
                "accepted",
                its,
                counters(),
            )
        except _NewtonFailed as exc:
            its = exc.iterations
            return self._failed(
                state,
                tau,
                "newton",
                f"Newton's method did not converge in {exc.iterations} "
                f"iterations at step {j} (t = {t_new:.6g}, tau = {tau:g}, |R| = {exc.rnorm:.3g}); "
                "the step is not accepted",
                its,
                counters(),
            )
        self._last_newton = its
        new, result_extra = self._complete(state, k, vals, coeffs, tau, t_new, scheme)
        if new is None:
            return self._failed(
                state,
                tau,
                "non-finite",
                f"non-finite state at step {j} (t = "
                f"{t_new:.6g}, tau = {tau:g}): {result_extra} has NaN or inf "
                "entries; the step is not accepted",
                its,
                counters(),
            )
        c = self.problem.constraint
        return ELDStepResult(
            state=new,
            tau=tau,
            lam=new.lam,
            reactions=c.reactions(new.lam),
            newton_iterations=its,
            estimate=result_extra,
            counters=counters(),
        )

    # -- BDF2 start -----------------------------------------------------------------------------
    def _with_prehistory(self, state: ELDState, tau: float) -> ELDState:
        """The j = 0 state with the BDF2 history u^{-1}, v^0, v^{-1} from the Taylor polynomial P
        (module docstring), for a first step tau (fictitious tau_0 = tau)."""
        p = self.problem
        c = p.constraint
        f = state.fields
        u0, a0 = f["u"], f["a"]
        vc = f["v"].copy()
        vc[c.dofs] = self.data.initial()[1]
        G3 = np.zeros(p.space.ndofs)
        if self.start == "taylor":
            G3[c.dofs] = (p.G_ddot(tau) - p.G_ddot(0.0)) / tau

        def P(s):
            return u0 + s * vc + (0.5 * s * s) * a0 + (s**3 / 6.0) * G3

        U1, U2, U3 = P(-tau), P(-2.0 * tau), P(-3.0 * tau)
        V0 = (1.5 * u0 - 2.0 * U1 + 0.5 * U2) / tau
        V1 = (1.5 * U1 - 2.0 * U2 + 0.5 * U3) / tau
        fields = dict(f)
        if self.form == "regularized":
            fields.update(x_1=self._split(U1), y=self._split(V0), y_1=self._split(V1))
        else:
            fields.update(x_1=U1, y=V0, y_1=V1)
        # the ledger follows the history too: v^0 = V0 (O(tau^2) from the initial velocity) with
        # u^{-1} = U1, v^{-1} = V1; the energy difference of V0 and v^0 is booked in X^1
        fields.update(v=V0, u_1=U1, v_1=V1)
        boundary = dict(state.boundary)
        if self.data_mode == "differenced":
            boundary.update(G_1=U1[c.dofs], G_dot=V0[c.dofs], G_dot_1=V1[c.dofs])
        products = {k: w for k, w in state.products.items() if k not in ("My", "Ky", "Mv")}
        new = replace(state, tau_prev=tau, fields=fields, boundary=boundary, products=products)
        self._fill_products(new)
        pr = new.products
        L = new.ledger
        kin = 0.5 * self.rho * _dot(V0, pr["Mv"])
        # C^0 with mu_0 = 1/2 (the fictitious equal history)
        dv, du = V0 - V1, u0 - U1
        L = replace(
            L,
            kinetic=kin,
            mismatch=L.mismatch - (kin - L.kinetic),
            g_zd_kin=self.rho * _dot(pr["Mv"], dv),
            g_sq_kin=self.rho * _dot(pr["Mv"] - p.M @ V1, dv),
            g_zd_el=_dot(pr["Ku"], du),
            g_sq_el=_dot(pr["Ku"] - p.K @ U1, du),
            g_mu=0.5,
        )
        C0 = 0.5 * (L.g_zd_kin + L.g_zd_el) + 0.25 * (L.g_sq_kin + L.g_sq_el)
        new.ledger = replace(L, boundary_C=C0, boundary_C0=C0)
        return new

    # -- the two forms --------------------------------------------------------------------------
    def _lifted(self, vals):
        """[(B^- g, M B^- g, K B^- g) for g in (G, G_dot, G_ddot)] (thin products for nodal)."""
        gs = (vals.G, vals.G_dot, vals.G_ddot)
        if self.lifting_kind == "nodal":
            return [(self.lifting(g), self._M_C @ g, self._K_C @ g) for g in gs]
        p = self.problem
        return [(w, p.M @ w, p.K @ w) for w in self.lifting.lift_many(list(gs))]

    @staticmethod
    def _history(state: ELDState, coeffs):
        """h_x = alpha_1 x^{j-1} + alpha_2 x^{j-2} and h_y, with their M and K products."""
        _, a1, a2 = coeffs
        f, pr = state.fields, state.products
        h = {
            "x": a1 * f["x"],
            "Mx": a1 * pr["Mx"],
            "Kx": a1 * pr["Kx"],
            "y": a1 * f["y"],
            "My": a1 * pr["My"],
            "Ky": a1 * pr["Ky"],
        }
        if a2:
            for key, name in (("x", "x_1"), ("y", "y_1")):
                h[key] = h[key] + a2 * f[name]
            for key in ("Mx", "Kx", "My", "Ky"):
                h[key] = h[key] + a2 * pr[key + "_1"]
        return h

    def _kinematics(self, h, coeffs, tau, x, Mx, Kx, lifted, with_nonlinear=True) -> dict:
        """y, b, u, v, a and their products from x and the lifted data (module docstring)."""
        a0 = coeffs[0]
        (u2, _, Ku2), (v2, Mv2, Kv2), (w2, Mw2, _) = lifted
        k = {"x": x, "Mx": Mx, "Kx": Kx}
        k["y"] = (a0 * x + h["x"]) / tau
        k["My"] = (a0 * Mx + h["Mx"]) / tau
        k["Ky"] = (a0 * Kx + h["Kx"]) / tau
        k["b"] = (a0 * k["y"] + h["y"]) / tau
        k["Mb"] = (a0 * k["My"] + h["My"]) / tau
        if u2 is None:
            k["u"], k["Ku"], k["v"], k["Mv"], k["a"], k["Ma"] = (
                x,
                Kx,
                k["y"],
                k["My"],
                k["b"],
                k["Mb"],
            )
            Kv = k["Ky"]
        else:
            k["u"], k["Ku"] = x + u2, Kx + Ku2
            k["v"], k["Mv"] = k["y"] + v2, k["My"] + Mv2
            k["a"], k["Ma"] = k["b"] + w2, k["Mb"] + Mw2
            Kv = k["Ky"] + Kv2
        D = self.D
        Dv = D.mass_coef * k["Mv"] + D.stiffness_coef * Kv
        if D.matrix is not None:
            Dv = Dv + D.matrix @ k["v"]
        if with_nonlinear and not D.is_linear:
            Dv = Dv + D.nonlinear_apply(k["v"])
        k["Dv"] = Dv
        return k

    def _guess(self, state: ELDState, tau: float) -> np.ndarray:
        f = state.fields
        if "x_1" not in f or state.tau_prev is None:
            return f["x"]
        return f["x"] + (tau / state.tau_prev) * (f["x"] - f["x_1"])

    def _step_regularized(self, state: ELDState, vals, coeffs, tau):
        p, rho = self.problem, self.rho
        I = self.I
        n = p.space.ndofs
        a0 = coeffs[0]
        te = tau / a0
        lifted = self._lifted(vals)
        (u2, _, Ku2), (v2, Mv2, Kv2), (w2, Mw2, _) = lifted
        h = self._history(state, coeffs)
        D = self.D
        guess = self._guess(state, tau)[I]
        if D.is_linear:
            # A(te) x = F - rho M (alpha_0 h_x/tau^2 + h_y/tau + w2) - C (h_x/tau + v2) - K u2
            rhs = (
                vals.F
                - rho * (a0 * h["Mx"] / tau**2 + h["My"] / tau + Mw2)
                - D.mass_coef * (h["Mx"] / tau + Mv2)
                - D.stiffness_coef * (h["Kx"] / tau + Kv2)
                - Ku2
            )
            if D.matrix is not None:
                rhs = rhs - D.matrix @ (h["x"] / tau + v2)
            xI = self._solve_linear(rhs[I], te, guess)
            x = np.zeros(n)
            x[I] = xI
            return self._kinematics(h, coeffs, tau, x, p.M @ x, p.K @ x, lifted), 0

        cache = {}

        def residual(xI):
            x = np.zeros(n)
            x[I] = xI
            k = self._kinematics(h, coeffs, tau, x, p.M @ x, p.K @ x, lifted)
            cache["k"] = k
            R = rho * k["Ma"] + k["Dv"] + k["Ku"] - vals.F
            return R[I], k["v"]

        def jacobian(v):
            # matrix-free J_II w = A_II(te) w + (N'(v) E w)_I / te; assembled only when the
            # stored preconditioner must be rebuilt
            action = D.nonlinear_jacobian_action(v)

            def matvec(w):
                full = np.zeros(n)
                full[I] = w
                return self._apply_A(w, te) + action(full)[I] / te

            op = spla.LinearOperator((I.size, I.size), matvec=matvec, dtype=float)
            return op, self._assembler(te, v)

        _, its = self._newton(residual, jacobian, guess, state.fields["x"][I])
        return cache["k"], its

    def _step_original(self, state: ELDState, vals, coeffs, tau):
        p, rho = self.problem, self.rho
        c = p.constraint
        n = p.space.ndofs
        a0 = coeffs[0]
        te = tau / a0
        zero = (None, 0.0, 0.0)
        lifted = [zero, zero, zero]
        g_rhs = c.boundary_mass @ vals.G
        h = self._history(state, coeffs)
        D = self.D
        if D.is_linear:
            rhs_u = (
                vals.F
                - rho * (a0 * h["Mx"] / tau**2 + h["My"] / tau)
                - D.mass_coef * h["Mx"] / tau
                - D.stiffness_coef * h["Kx"] / tau
            )
            if D.matrix is not None:
                rhs_u = rhs_u - D.matrix @ (h["x"] / tau)
            z = self._solve_linear(np.concatenate([rhs_u, g_rhs]), te)
            u = z[:n]
            k = self._kinematics(h, coeffs, tau, u, p.M @ u, p.K @ u, lifted)
            k["lam"] = z[n:]
            return k, 0

        B = c.B
        lam0 = state.lam if state.lam is not None else np.zeros(c.m)
        cache = {}

        def residual(z):
            u, lam = z[:n], z[n:]
            k = self._kinematics(h, coeffs, tau, u, p.M @ u, p.K @ u, lifted)
            k["lam"] = lam
            cache["k"] = k
            R_u = rho * k["Ma"] + k["Dv"] + k["Ku"] + B.T @ lam - vals.F
            return np.concatenate([R_u, B @ u - g_rhs]), k["v"]

        def jacobian(v):
            action = D.nonlinear_jacobian_action(v)
            m = c.m

            def matvec(z):
                u, lam = z[:n], z[n:]
                return np.concatenate([self._apply_A(u, te) + action(u) / te + B.T @ lam, B @ u])

            op = spla.LinearOperator((n + m, n + m), matvec=matvec, dtype=float)
            return op, self._assembler(te, v)

        x = state.fields["x"]
        z0 = np.concatenate([self._guess(state, tau), lam0])
        _, its = self._newton(residual, jacobian, z0, np.concatenate([x, lam0]))
        return cache["k"], its

    def _newton(self, residual, jacobian, z0, z_prev):
        """Newton's method with backtracking on |R|; returns (z, iterations) or raises
        _NewtonFailed.

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
            if not math.isfinite(rnorm):
                raise _NewtonFailed(it - 1, rnorm)
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
        raise _NewtonFailed(opts.max_iter, float(rnorm))

    # -- the new state: multiplier, ledger, estimate ---------------------------------------------
    def _complete(
        self, state: ELDState, k: dict, vals, coeffs, tau: float, t_new: float, scheme: str
    ):
        """The state after the step, or (None, name) if a field is not finite."""
        p = self.problem
        c = p.constraint
        rho = self.rho
        a0, _, a2 = coeffs
        C = c.dofs
        if "lam" in k:
            lam = k["lam"]
        else:
            # (3.4a) tested with V^c: the residual on the constrained rows is B^T lambda
            lam = c.multiplier_from_residual(vals.F[C] - rho * k["Ma"][C] - k["Dv"][C] - k["Ku"][C])
        for name, w in (("u", k["u"]), ("v", k["v"]), ("a", k["a"]), ("lambda", lam)):
            if not np.all(np.isfinite(w)):
                return None, name
        f, pr = state.fields, state.products
        u, v, Ku, Mv, Ma, Dv = k["u"], k["v"], k["Ku"], k["Mv"], k["Ma"], k["Dv"]
        L = state.ledger
        # numerical dissipation N^j and its G-form pieces (module docstring)
        du, dv = u - f["u"], v - f["v"]
        dKu, dMv = Ku - pr["Ku"], Mv - pr["Mv"]
        sq_kin, sq_el = rho * _dot(dMv, dv), _dot(dKu, du)
        zd_kin, zd_el = rho * _dot(Mv, dv), _dot(Ku, du)
        N = 0.5 * (sq_kin + sq_el) + (a0 - 1.0) * (zd_kin + zd_el)
        tdu, tdv = a0 * du, a0 * dv  # tau delta z = alpha_0 Delta z^j - alpha_2 Delta z^{j-1}
        cross = 0.0
        if a2:
            du1, dv1 = f["u"] - f["u_1"], f["v"] - f["v_1"]
            N -= a2 * (rho * _dot(Mv, dv1) + _dot(Ku, du1))
            tdu, tdv = tdu - a2 * du1, tdv - a2 * dv1
            cross = rho * _dot(dMv, dv1) + _dot(dKu, du1)
        nu = 0.0 if scheme == "euler" else 0.25
        mu = a0 - 1.0
        N_G = (0.5 - nu) * (sq_kin + sq_el) + nu * (L.g_sq_kin + L.g_sq_el) - a2 * cross
        S = (L.g_mu - a2) * (L.g_zd_kin + L.g_zd_el)
        C_new = mu * (zd_kin + zd_el) + nu * (sq_kin + sq_el)
        # data/start mismatch X and the work of the algebraic residual R
        X = rho * (tau * _dot(Ma, v) - _dot(Mv, tdv)) + (tau * _dot(Ku, v) - _dot(Ku, tdu))
        R = rho * Ma + Dv + Ku - vals.F
        R[C] += c.boundary_mass @ lam
        Bv = c.boundary_mass @ v[C]
        kin, el = 0.5 * rho * _dot(v, Mv), 0.5 * _dot(u, Ku)
        if not math.isfinite(kin + el):
            return None, "the energy E = 1/2 rho v.M v + 1/2 u.K u"
        ledger = replace(
            L,
            kinetic=kin,
            elastic=el,
            work=L.work + tau * _dot(vals.F, v),
            work_reaction=L.work_reaction - tau * _dot(lam, Bv),
            dissipated=L.dissipated + tau * _dot(Dv, v),
            numerical=L.numerical + N,
            mismatch=L.mismatch + X,
            residual_work=L.residual_work + tau * _dot(R, v),
            numerical_G=L.numerical_G + N_G,
            step_change=L.step_change + S,
            boundary_C=C_new,
            g_zd_kin=zd_kin,
            g_sq_kin=sq_kin,
            g_zd_el=zd_el,
            g_sq_el=sq_el,
            g_mu=mu,
        )
        # local error estimate (trapezoidal residuals, module docstring)
        Kr = k["Kx"] - pr["Kx"] - 0.5 * tau * (k["Ky"] + pr["Ky"])
        rx = k["x"] - f["x"] - 0.5 * tau * (k["y"] + f["y"])
        Mr = k["My"] - pr["My"] - 0.5 * tau * (k["Mb"] + pr["Mb"])
        ry = k["y"] - f["y"] - 0.5 * tau * (k["b"] + f["b"])
        if (
            self.form == "regularized"
            and self.lifting_kind == "harmonic"
            and self.data_mode == "differenced"
        ):
            # With differenced data G_dot^j is a difference quotient of G, not integrated by the
            # step: after a step cut (omega -> 0) it jumps by the previous quotient's O(tau_prev^2)
            # error, and the harmonic lifting spreads that jump over the interior, where no
            # smaller step can remove it (the run failed below tau_min). Both liftings give the
            # same u, v, a with differenced data, so the estimate is taken from them on the free
            # dofs: the nodal lifting's estimate, which contains the solution's error only.
            C = self.problem.constraint.dofs
            rx = u - f["u"] - 0.5 * tau * (v + f["v"])
            ry = v - f["v"] - 0.5 * tau * (k["a"] + f["a"])
            rx[C] = 0.0
            ry[C] = 0.0
            Kr = self.problem.K @ rx
            Mr = self.problem.M @ ry
        omega = 1.0 if state.tau_prev is None else tau / state.tau_prev
        norm_new = math.sqrt(max(2.0 * (kin + el), 0.0))
        scale = max(state.energy_norm_max, norm_new, 1e-300)
        est = (
            estimate_factor(scheme, omega)
            * math.sqrt(max(_dot(rx, Kr) + rho * _dot(ry, Mr), 0.0))
            / scale
        )
        fields = {
            "x": k["x"],
            "x_1": f["x"],
            "y": k["y"],
            "y_1": f["y"],
            "b": k["b"],
            "u": u,
            "u_1": f["u"],
            "v": v,
            "v_1": f["v"],
            "a": k["a"],
        }
        products = {
            "Mx": k["Mx"],
            "Kx": k["Kx"],
            "Mx_1": pr["Mx"],
            "Kx_1": pr["Kx"],
            "My": k["My"],
            "Ky": k["Ky"],
            "My_1": pr["My"],
            "Ky_1": pr["Ky"],
            "Mb": k["Mb"],
            "Ku": Ku,
            "Mv": Mv,
        }
        boundary = {"lam": lam}
        if self.data_mode == "differenced":
            b = state.boundary
            boundary.update(G=vals.G, G_1=b["G"], G_dot=vals.G_dot, G_dot_1=b["G_dot"])
        new = ELDState(
            t=t_new,
            j=state.j + 1,
            tau_prev=tau,
            fields=fields,
            boundary=boundary,
            products=products,
            ledger=ledger,
            energy_norm_max=max(state.energy_norm_max, norm_new),
            mesh_id=state.mesh_id,
        )
        return new, est

    def adapt(self, state: ELDState, result: ELDStepResult) -> ELDState:
        """The adapt step of the evolve loop: a fixed mesh, so the accepted state itself."""
        return state

    # -- recording ------------------------------------------------------------------------------
    def record(self, traj: Trajectory, result: ELDStepResult, state=None) -> None:
        st = result.state
        L = st.ledger
        rec = dict(
            t=st.t,
            kinetic=L.kinetic,
            elastic=L.elastic,
            energy=L.energy,
            work=L.work,
            work_reaction=L.work_reaction,
            dissipated=L.dissipated,
            numerical_dissipation=L.numerical,
            numerical_dissipation_G=L.numerical_G,
            step_change=L.step_change,
            data_mismatch=L.mismatch,
            residual_work=L.residual_work,
            transfer=L.transfer,
            balance_residual=L.residual,
            tau=result.tau,
            local_error=result.estimate,
            lam_norm=self.problem.constraint.l2_norm(result.lam),
            newton_iterations=result.newton_iterations,
        )
        for part, force in result.reactions.items():
            rec[f"reaction_{part}"] = force
        traj.append(**rec)
        if self.store_fields and (st.j % self.keep_every == 0 or self.finished(st)):
            self._keep(traj, st)
        if self.observer is not None:
            self.observer(st, result)

    # -- checkpoints ----------------------------------------------------------------------------
    def checkpoint_state(self, state: ELDState) -> dict:
        """Everything that influences the rest of the run, as arrays and plain values: the state
        (fields, boundary vectors with the data history of ``differenced`` mode, products,
        ledger, error scale), the key of the stored factorization, the solver's counters (the
        run's ``linear_solver`` statistics continue from them) and the Newton count the
        progress line shows. The step data itself keeps no state (:mod:`rothe.eld.data`)."""
        ref = self._ref
        return {
            "format": "rothe-eld-state-1",
            "scheme": self.scheme,
            "form": self.form,
            "t": float(state.t),
            "j": int(state.j),
            "tau_prev": state.tau_prev,
            "fields": {k: w.copy() for k, w in state.fields.items()},
            "boundary": {k: w.copy() for k, w in state.boundary.items()},
            "products": {k: w.copy() for k, w in state.products.items()},
            "ledger": {k: float(v) for k, v in asdict(state.ledger).items()},
            "energy_norm_max": float(state.energy_norm_max),
            "mesh_id": int(state.mesh_id),
            "error_scale": None if self.error_scale is None else float(self.error_scale),
            "solver_reference": None
            if ref is None
            else {"tau_eff": ref["tau_eff"], "v": None if ref["v"] is None else ref["v"].copy()},
            "solver_stats": asdict(self.solver.stats),
            "last_newton": int(self._last_newton),
        }

    def restore_state(self, data: dict) -> ELDState:
        """The state of :meth:`checkpoint_state`; refactors the stored matrix it names and
        continues the solver's counters from the checkpoint's (the refactorization is not
        counted: the uninterrupted run did not do it)."""
        if data.get("format") != "rothe-eld-state-1":
            raise RotheInputError(
                f"checkpoint: got format {data.get('format')!r}, must be 'rothe-eld-state-1'"
            )
        for key in ("scheme", "form"):
            if data[key] != getattr(self, key):
                raise RotheInputError(
                    f"checkpoint: got {key} {data[key]!r}, this run has {getattr(self, key)!r}"
                )
        ref = data["solver_reference"]
        if ref is not None:
            same = (
                self._ref is not None
                and self._ref["tau_eff"] == ref["tau_eff"]
                and (
                    (self._ref["v"] is None and ref["v"] is None)
                    or (
                        self._ref["v"] is not None
                        and ref["v"] is not None
                        and np.array_equal(self._ref["v"], ref["v"])
                    )
                )
            )
            if not same:
                self._factor(
                    ref["tau_eff"], None if ref["v"] is None else np.asarray(ref["v"], dtype=float)
                )
        if data.get("solver_stats") is not None:
            self.solver.stats = SolverStats(**data["solver_stats"])
        if data.get("error_scale") is not None:
            self.error_scale = float(data["error_scale"])
        self._last_newton = int(data.get("last_newton", 0))
        tp = data["tau_prev"]
        return ELDState(
            t=float(data["t"]),
            j=int(data["j"]),
            tau_prev=None if tp is None else float(tp),
            fields={k: np.asarray(w, dtype=float).copy() for k, w in data["fields"].items()},
            boundary={k: np.asarray(w, dtype=float).copy() for k, w in data["boundary"].items()},
            products={k: np.asarray(w, dtype=float).copy() for k, w in data["products"].items()},
            ledger=EnergyLedger(**data["ledger"]),
            energy_norm_max=float(data["energy_norm_max"]),
            mesh_id=int(data.get("mesh_id", 0)),
        )


@dataclass
class ELDRun:
    """A prepared run: the stepper, its controller, the trajectory with the initial state
    recorded (or the trajectory and state restored from a checkpoint), the state to continue
    from and the evolve loop's tau_min (:func:`prepare_eld_run`).

    ``checkpointing`` (a :class:`~rothe.io.checkpoint.RunCheckpointing`, or None) holds the
    lock on the checkpoint directory from :func:`prepare_eld_run` until :meth:`evolve` ends or
    :meth:`close` is called."""

    stepper: ELDStepper
    controller: object
    trajectory: Trajectory
    state: ELDState
    tau_min: float
    checkpointing: RunCheckpointing | None = None

    @property
    def checkpointer(self):
        return None if self.checkpointing is None else self.checkpointing.checkpointer

    @property
    def resumed(self) -> bool:
        return self.checkpointing is not None and self.checkpointing.resuming

    def evolve(self, progress=False) -> ELDState:
        """Run to the end on the shared evolve loop; returns the final state.

        With a checkpointer: a checkpoint of the initial state (a new run), checkpoints when
        due and when the run stops (interrupted, failed), and one with status ``completed`` at
        the end. Raises :class:`RunFailed` / :class:`~rothe.errors.RunInterrupted` with the
        trajectory so far."""
        cp = self.checkpointer
        try:
            if cp is not None and not self.resumed and cp.sequence == 0:
                cp.save_or_warn(
                    self.stepper,
                    self.controller,
                    self.state,
                    where=_eld_where(self.trajectory, self.state),
                )
            try:
                final = evolve(
                    self.stepper,
                    self.controller,
                    self.state,
                    self.trajectory,
                    tau_min=self.tau_min,
                    progress=progress,
                    checkpointer=cp,
                )
            except RunFailed as exc:
                exc.trajectory = self.trajectory
                raise
            finally:
                _finish_meta(self.trajectory, self.stepper)
            self.state = final
            if cp is not None:
                cp.save_or_warn(
                    self.stepper,
                    self.controller,
                    final,
                    status="completed",
                    where=_eld_where(self.trajectory, final),
                )
        finally:
            self.close()
        return final

    def close(self) -> None:
        """Release the checkpoint directory (done by :meth:`evolve`)."""
        if self.checkpointing is not None:
            self.checkpointing.close()


def prepare_eld_run(
    problem: ELDProblem,
    form: str = "regularized",
    tau: float = 0.01,
    *,
    scheme: str = "euler",
    control: str = "uniform",
    tol: float | None = None,
    steps=None,
    data: str = "points",
    lifting: str = "nodal",
    solver: str = "auto",
    newton: NewtonOptions | None = None,
    noise: DataNoise | None = None,
    store_fields: bool = True,
    keep_every: int = 1,
    observer=None,
    linear_rtol: float = 1e-10,
    tau_min: float | None = None,
    tau_max: float | None = None,
    start: str = "taylor",
    error_scale: float | None = None,
    meta: dict | None = None,
    checkpoint=None,
    resume=None,
    space=None,
) -> ELDRun:
    """Validate the options, build stepper and controller, record the initial state
    (the arguments of :func:`run_eld`); with ``resume``, restore stepper, controller,
    trajectory and state from the checkpoint instead."""
    control = check_choice("control", control, CONTROLS)
    if control == "adaptive":
        if tol is None:
            raise fail("tol", None, "must be given (> 0) with control='adaptive'")
        tol = check_positive("tol", tol)
    elif tol is not None:
        raise fail("tol", tol, "is used by control='adaptive' only (this run has uniform steps)")
    stepper_kwargs = dict(
        form=form,
        tau=tau,
        scheme=scheme,
        control=control,
        steps=steps,
        data=data,
        lifting=lifting,
        solver=solver,
        newton=newton,
        noise=noise,
        store_fields=store_fields,
        keep_every=keep_every,
        observer=observer,
        linear_rtol=linear_rtol,
        start=start,
        error_scale=error_scale,
    )
    if space is None:
        stepper = ELDStepper(problem, **stepper_kwargs)
    else:
        from .adapt import SpaceAdaptiveStepper, check_space_options

        space = check_space_options(space, data=data, noise=noise, form=form)
        stepper = SpaceAdaptiveStepper(problem, space, stepper_kwargs)
    info = {
        "example": problem.name,
        "form": form,
        "scheme": scheme,
        "control": control,
        "tau": stepper.tau,
        "n_steps": stepper.n_steps,
        "data": data,
        "lifting": lifting if form == "regularized" else None,
        "solver": stepper.kind,
        "step_bound": problem.step_bound(),
        "keep_every": stepper.keep_every,
        "start": start if scheme == "bdf2" else None,
        "problem": problem.describe(),
    }
    if steps is not None:
        info["control"] = "given steps"
    if noise is not None:
        info["noise"] = noise.describe()
    if space is not None:
        info["space"] = space.describe()
    if control == "adaptive":
        tau_min = 1e-10 * problem.T if tau_min is None else check_positive("tau_min", tau_min)
        tau_max = problem.T if tau_max is None else check_positive("tau_max", tau_max)
        if tau_max < stepper.tau:
            raise fail("tau_max", tau_max, f"must be >= the first step tau = {stepper.tau:g}")
        if tau_min > stepper.tau:
            raise fail("tau_min", tau_min, f"must be <= the first step tau = {stepper.tau:g}")
        controller = adaptive_controller(
            stepper, tol, stepper.tau, tau_min=tau_min, tau_max=tau_max
        )
        info.update(
            tol=tol,
            tau_min=tau_min,
            tau_max=tau_max,
            ratio_cap=stepper.max_ratio if math.isfinite(stepper.max_ratio) else None,
        )
        loop_tau_min = tau_min
    else:
        if stepper.steps is not None:
            controller = FixedStepController(stepper.steps)
        else:
            controller = FixedStepController.uniform(stepper.tau, stepper.n_steps)
        loop_tau_min = 1e-300  # a fixed grid never shrinks a step; a failed step stops the run
    info.update(meta or {})
    # what a checkpoint must match to be resumed (the stepper's values after validation)
    arguments = run_arguments(
        form=form,
        scheme=scheme,
        control=control,
        tol=tol,
        tau=stepper.tau,
        steps=stepper.steps,
        data=data,
        lifting=lifting,
        solver=solver,
        newton=asdict(stepper.newton),
        noise=None if noise is None else noise.describe(),
        store_fields=store_fields,
        keep_every=stepper.keep_every,
        linear_rtol=linear_rtol,
        tau_min=tau_min,
        tau_max=tau_max,
        start=start,
        error_scale=error_scale,
        **({} if space is None else {"space": space.describe()}),
    )
    rc = RunCheckpointing("run_eld", problem, arguments, checkpoint, resume)
    try:
        restored = rc.restored
        if restored is not None:
            traj = restored.trajectory(0)
            traj.meta.update(info)
            traj.meta["sessions"] = restored.sessions + 1
            state = stepper.restore_state(restored.state["stepper"])
            controller.restore_state(restored.state["controller"])
            if control == "adaptive":
                traj.meta["error_scale"] = stepper.error_scale
        else:
            traj = Trajectory(meta=info)
            try:
                state = stepper.initial_state()
            except RunFailed as exc:
                exc.trajectory = traj
                _finish_meta(traj, stepper)
                raise
            if control == "adaptive":
                traj.meta["error_scale"] = stepper.error_scale
            stepper.record_initial(traj, state)
            traj.stats.linear_factorizations += stepper.initial_factorizations
        if space is not None:
            traj.space = stepper  # the meshes and the kept fields (ragged across meshes)
        if rc.checkpointer is not None:
            rc.checkpointer.register(traj)
    except BaseException:
        rc.close()
        raise
    return ELDRun(stepper, controller, traj, state, loop_tau_min, rc)


def run_eld(
    problem: ELDProblem,
    form: str = "regularized",
    tau: float = 0.01,
    *,
    scheme: str = "euler",
    control: str = "uniform",
    tol: float | None = None,
    steps=None,
    data: str = "points",
    lifting: str = "nodal",
    solver: str = "auto",
    newton: NewtonOptions | None = None,
    noise: DataNoise | None = None,
    store_fields: bool = True,
    keep_every: int = 1,
    observer=None,
    progress=False,
    linear_rtol: float = 1e-10,
    tau_min: float | None = None,
    tau_max: float | None = None,
    start: str = "taylor",
    error_scale: float | None = None,
    meta: dict | None = None,
    checkpoint=None,
    resume=None,
    space=None,
) -> Trajectory:
    """Run Euler (3.4) or BDF2 from t = 0 to T (module docstring).

    ``control='uniform'``: n = T/tau equal steps (or the given ``steps``); ``'adaptive'``: tau is
    the first step, the local error estimate is kept below ``tol`` (relative to the energy-norm
    scale S_j, floor ``error_scale``) with steps in [tau_min, tau_max] (defaults 1e-10 T and T).

    Runs on the shared evolve loop. Returns a :class:`~rothe.io.trajectory.Trajectory`:
    point series (one entry per state, t = 0 included) ``t, kinetic, elastic, energy, work,
    work_reaction, dissipated, numerical_dissipation, numerical_dissipation_G, step_change,
    data_mismatch, residual_work, transfer, balance_residual``; step series (one per step)
    ``tau, local_error, lam_norm, reaction_<part>, newton_iterations``; with ``store_fields``
    the kept states (every ``keep_every``-th, t = 0 and the last) ``kept_step, kept_t`` and
    ``u, v, a`` (interleaved dof vectors of ``problem.space``) and ``lam`` (values on the
    constrained dofs ``problem.constraint.dofs``; ``lam[0]`` and ``a[0]`` are the consistent
    multiplier and acceleration at t = 0). ``traj.final_state``, ``traj.stepper`` and
    ``traj.controller`` are attached (not saved). Raises :class:`RunFailed` (with
    ``.trajectory``) if a step cannot be solved or its state or data is not finite.

    ``checkpoint`` / ``resume``: as for :func:`rothe.ris.stepper.run_ris` (a directory or
    :class:`~rothe.io.checkpoint.CheckpointOptions`; a checkpoint written by ``run_eld`` with
    the same arguments and problem). A resumed run, with any scheme and control, returns the
    trajectory of the uninterrupted run bit for bit (statistics too, but the wall time, which
    sums the sessions). An ``observer`` that keeps state, such as an output writer, is passed
    as a checkpoint attachment so that it is restored too. SIGINT / SIGTERM raise
    :class:`~rothe.errors.RunInterrupted` with the trajectory so far (and a checkpoint).

    ``space``: a :class:`rothe.fem.adapt.SpaceAdaptivity` adapts the mesh after every
    ``adapt_every``-th accepted step (:mod:`rothe.eld.adapt`; data ``'points'``, no noise);
    None (default) keeps the mesh. The trajectory then also has the point series ``mesh_id``,
    ``ndofs``, ``cells``, the step series ``space_estimate``, ``kept_mesh_id`` with the kept
    states, and ``traj.space`` (the :class:`~rothe.eld.adapt.SpaceAdaptiveStepper`: the meshes
    in ``.series``, the kept fields in ``.kept``, the log in ``.adaptations``); ``u, v, a, lam``
    are not series of the trajectory then (they live on different meshes).
    """
    run = prepare_eld_run(
        problem,
        form,
        tau,
        scheme=scheme,
        control=control,
        tol=tol,
        steps=steps,
        data=data,
        lifting=lifting,
        solver=solver,
        newton=newton,
        noise=noise,
        store_fields=store_fields,
        keep_every=keep_every,
        observer=observer,
        linear_rtol=linear_rtol,
        tau_min=tau_min,
        tau_max=tau_max,
        start=start,
        error_scale=error_scale,
        meta=meta,
        checkpoint=checkpoint,
        resume=resume,
        space=space,
    )
    final = run.evolve(progress=progress)
    traj = run.trajectory
    traj.final_state = final  # not saved to .npz: the last state and the stepper, for callers
    traj.stepper = run.stepper
    traj.controller = run.controller
    return traj


def _eld_where(traj: Trajectory, state: ELDState) -> dict:
    return {
        "accepted_steps": traj.stats.accepted_steps,
        "s": float(state.t),
        "t": float(state.t),
        "j": int(state.j),
    }


def _finish_meta(traj: Trajectory, stepper: ELDStepper) -> None:
    s = stepper.solver.stats
    traj.meta["linear_solver"] = {
        "kind": stepper.kind,
        "factorizations": s.factorizations,
        "backsolves": s.backsolves,
        "krylov_iterations": s.krylov_iterations,
        "setup_seconds": s.setup_seconds,
    }
