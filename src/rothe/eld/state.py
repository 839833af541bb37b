"""The state of an elastodynamics run after a step, its energy ledger, and the step's result.

**The state** (:class:`ELDState`) holds every history vector on the mesh in one dict ``fields``
of named dof vectors of V_h (interleaved like the space):

    x, x_1     the scheme's unknown at t_j, t_{j-1} (u_1 regularized, u original)
    y, y_1     its velocity delta x at t_j, t_{j-1}
    b          its acceleration delta y at t_j
    u, u_1     displacement at t_j, t_{j-1};   v, v_1  velocity;   a  acceleration at t_j

(at j = 0 the ``_1`` entries are absent; BDF2 builds them at its first step), a dict
``boundary`` of vectors on the constrained dofs (Q_h: ``lam``, and with differenced data the
data history ``G``, ``G_1``, ``G_dot``, ``G_dot_1``), and a dict ``products`` of cached M and K
times fields (:data:`PRODUCTS`: ``Mx`` = M x, ... ; every one is a matrix times one field, so
it can be recomputed). **Mesh transfer** (space adaptivity) goes through :meth:`ELDState.mapped`
(every field through a linear operator P_new<-old, every boundary vector through an optional
operator, products dropped) and :meth:`rothe.eld.system.ELDSystem.adopt` of the system on the new
mesh (recomputes the products and the energy, books the energy change as ``transfer`` in the
ledger, and keeps every other history term). Nothing else carries state.

**Energy identity** (:class:`EnergyLedger`; closes to round-off for every scheme, form and step
sequence). Test the full equation rho M a + D v + K u + B^T lambda - F = R (R: the algebraic
residual of the step's solve, zero up to solver tolerance) with tau_j v^j. With
E = 1/2 rho v.M v + 1/2 u.K u, Delta z^j = z^j - z^{j-1} and the identity, valid for any three
vectors,

    <W tau delta z, z^j> = 1/2|z^j|_W^2 - 1/2|z^{j-1}|_W^2 + 1/2|Delta z^j|_W^2
                           + <W z^j, (alpha_0 - 1) Delta z^j - alpha_2 Delta z^{j-1}>,

one gets exactly

    E^j - E^{j-1} = tau F.v - tau lambda.(B v) - tau D(v).v + tau R.v - N^j - X^j,
    N^j = sum over (z, W) in ((v, rho M), (u, K)) of 1/2|Delta z^j|_W^2
          + <W z^j, (alpha_0 - 1) Delta z^j - alpha_2 Delta z^{j-1}>     (numerical dissipation)
    X^j = rho tau M(a^j - delta v^j).v^j + tau K u^j.(v^j - delta u^j)     (data/start mismatch)

(all of u, v, a the full fields; BDF2: from the first step on, v^0 in these formulas is the
start history's velocity V0, and X^1 also holds E^0 - E(u^0, V0) = O(tau^2)). Euler:
N^j = 1/2 rho|Delta v|_M^2 + 1/2|Delta u|_K^2 >= 0. BDF2: N^j is not sign-definite step by
step; in G-stability form (mu_j = alpha_0 - 1, nu = 1/4)

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
(tau R.v), ``transfer`` (energy changes by mesh transfers), and ``balance_residual``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..stepping.results import ResultCode

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


@dataclass
class EnergyLedger:
    """Cumulative terms of the discrete energy identity (module docstring).

    Attributes
    ----------
    kinetic, elastic : float
        1/2 rho v.M v and 1/2 u.K u at t_j.
    initial : float
        E^0.
    work : float
        Work of the loads, sum tau F.v.
    work_reaction : float
        Work of the support on the prescribed motion, -sum tau lambda.B v.
    dissipated : float
        Physical dissipation, sum tau D(v).v.
    numerical : float
        Numerical dissipation, sum N^j.
    mismatch : float
        Data/start mismatch, sum X^j.
    residual_work : float
        sum tau R.v (solver residual).
    transfer : float
        Energy changes by mesh transfers.
    numerical_G, step_change : float
        sum N_G^j and sum S^j of the G-stability split (BDF2).
    boundary_C, boundary_C0 : float
        C^j and C^0.
    g_zd_kin, g_sq_kin, g_zd_el, g_sq_el, g_mu : float
        The pieces of C^j kept for the next step.
    """

    kinetic: float = 0.0
    elastic: float = 0.0
    initial: float = 0.0
    work: float = 0.0  # loads F
    work_reaction: float = 0.0  # support on the prescribed boundary motion: -tau lambda.B v
    dissipated: float = 0.0  # physical: tau D(v).v
    numerical: float = 0.0  # N^j
    mismatch: float = 0.0  # X^j
    residual_work: float = 0.0  # tau R.v (solver residual)
    transfer: float = 0.0  # energy changes by mesh transfers (ELDSystem.adopt)
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
        """E = kinetic + elastic."""
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

    def record(self) -> dict:
        """The trajectory's point series of the energy identity at this state."""
        return dict(
            kinetic=self.kinetic,
            elastic=self.elastic,
            energy=self.energy,
            work=self.work,
            work_reaction=self.work_reaction,
            dissipated=self.dissipated,
            numerical_dissipation=self.numerical,
            numerical_dissipation_G=self.numerical_G,
            step_change=self.step_change,
            data_mismatch=self.mismatch,
            residual_work=self.residual_work,
            transfer=self.transfer,
            balance_residual=self.residual,
        )


@dataclass
class ELDState:
    """The state after step j (module docstring: fields, boundary, products).

    Parameters
    ----------
    t : float
        The time t_j.
    j : int
        The number of steps.
    tau_prev : float or None
        The step that ended at t (None at j = 0).
    fields, boundary, products : dict
        The dof vectors, the vectors on the constrained dofs and the cached M, K products (module
        docstring).
    ledger : EnergyLedger
    energy_norm_max : float
        S_j, the scale of the error estimate (:mod:`rothe.eld.stepper`).
    mesh_id : int
        The mesh the fields live on (space adaptivity).
    """

    t: float
    j: int
    tau_prev: float | None  # the step that ended at t (None at j = 0)
    fields: dict
    boundary: dict
    products: dict
    ledger: EnergyLedger
    energy_norm_max: float = 0.0  # S_j: scale of the error estimate (rothe.eld.stepper)
    mesh_id: int = 0  # the mesh the fields live on (space adaptivity, rothe.eld.adapt)

    @property
    def s(self) -> float:
        """The evolve loop's curve parameter: here the time."""
        return self.t

    @property
    def u(self) -> np.ndarray:
        """The displacement u^j."""
        return self.fields["u"]

    @property
    def v(self) -> np.ndarray:
        """The velocity v^j."""
        return self.fields["v"]

    @property
    def lam(self) -> np.ndarray | None:
        """The multiplier lambda^j on the constrained dofs (None once dropped by a transfer)."""
        return self.boundary.get("lam")

    def mapped(self, op, boundary_op=None) -> ELDState:
        """The state with every field mapped through the linear operator ``op`` (a matrix or a
        callable, new dofs x old dofs), every boundary vector through ``boundary_op`` (dropped if
        None), and no cached products (:meth:`rothe.eld.system.ELDSystem.adopt` recomputes
        them)."""
        apply = op if callable(op) else (lambda w: op @ w)
        fields = {k: np.asarray(apply(w), dtype=float) for k, w in self.fields.items()}
        if boundary_op is None:
            boundary = {}
        else:
            bapply = boundary_op if callable(boundary_op) else (lambda w: boundary_op @ w)
            boundary = {k: np.asarray(bapply(w), dtype=float) for k, w in self.boundary.items()}
        return replace(self, fields=fields, boundary=boundary, products={})


class ELDCode(ResultCode):
    """How a step ended; the value is what trajectories and summaries hold."""

    OK = "ok", "the step's solve converged"
    LINEAR_SOLVE = "linear-solve", "linear solve failed"
    NEWTON = "newton", "Newton's method did not converge"
    NON_FINITE = "non-finite", "non-finite state"


@dataclass
class ELDStepResult:
    """One step attempt (:meth:`rothe.eld.stepper.ELDStepper.step`).

    ``state`` is the state after the step (None if it failed), ``system`` the linear system
    (and with it the mesh and the problem) the step was computed on, ``estimate`` the local
    error estimate, ``refinements`` how often the step's own mesh was refined and the step
    solved again (space adaptivity) and ``bisections`` the bisections those refinements made,
    ``code`` an :class:`ELDCode` and ``message`` the one-line
    account of a failure.

    Parameters
    ----------
    state : ELDState or None
    tau : float
        The step tried.
    lam : ndarray, optional
        The multiplier lambda^j.
    reactions : dict
        The reaction of every Dirichlet part.
    newton_iterations : int
    estimate : float
    counters : dict
        The linear solver's counters of the step.
    converged : bool
    code : ELDCode
    message : str
    where : dict
        Where a failure happened (step, t, tau).
    system : ELDSystem, optional
    refinements : int
    bisections : int
    """

    state: ELDState | None
    tau: float
    lam: np.ndarray | None = None
    reactions: dict = field(default_factory=dict)
    newton_iterations: int = 0
    estimate: float = math.nan
    counters: dict = field(default_factory=dict)
    converged: bool = True
    code: ELDCode = ELDCode.OK
    message: str = ""
    where: dict = field(default_factory=dict)
    system: object = field(default=None, repr=False)
    refinements: int = 0
    bisections: int = 0

    @property
    def errors(self) -> dict:
        """The error measures the step controller reads: ``local_error``."""
        return {"local_error": self.estimate}
