"""The start of a run: the initial state with its consistent acceleration, and the BDF2 history.

**The initial state.** The paper takes u_1^1, v_1^1 as data; here the run starts from
u(0) = g, u'(0) = h with the consistent acceleration and multiplier of (2.7a) at t = 0
(:func:`consistent_acceleration`): a = G_ddot(0) on Gamma_D and
rho M_II a_I = (F(0) - D(h_c) - K g)_I - rho M_IC G_ddot(0), lambda from the Gamma_D rows, with
h_c = h with its Gamma_D values replaced by G_dot(0). The regularized form splits the initial
data by the lifting (x = g - B^- G(0), y = h_c - B^- G_dot(0), b = a - B^- G_ddot(0), each zero on
Gamma_D); Euler then has y^0 = h (regularized: y^0 = h - B^- G_dot^0 with zero trace), i.e.
u^{-1} = g - tau h.

**The BDF2 start** (:func:`with_prehistory`). BDF2 needs two past values of u and of v. A first
Euler step would keep order 2 at T, but in the original form the boundary velocity of that step
is a difference quotient of G, off by O(tau), the acceleration there a second difference
quotient of that error, O(1), and the largest multiplier error over the steps does not converge
at all (0.17 at step 2 for every tau from 2.5e-3 to 3.1e-4: ``python benchmarks/eld.py --part
start``). Here BDF2 starts as if it had run before t = 0 on the Taylor polynomial of the
solution,

    P(s) = g + s h_c + s^2/2 a_0 + s^3/6 S^T G_3,    s <= 0,

with a_0 the consistent initial acceleration and G_3 = (G_ddot(tau_1) - G_ddot(0)) / tau_1 on
Gamma_D: the history is u^{-1} = P(-tau_1) and the velocities v^0, v^{-1} = the BDF2 quotients
of P at 0 and -tau_1 (fictitious previous step tau_0 = tau_1). On Gamma_D the original form's u
is data, so v and a there are pure difference quotients of G; with this start the sequence of
their errors is smooth from the first step and a^j|Gamma_D = G_ddot(t_j) + O(tau^2) at every
step (with an exact velocity history it would be O(tau) at steps 1 and 2). On the free dofs the
equation itself fixes a^j, and O(tau^3) (u) and O(tau^2) (v) history errors keep order 2. The
regularized form uses the same history, split by the lifting (x^{-k} = u^{-k} -
B^-(u^{-k}|Gamma_D)). Tested: order 2 for u, u' and lambda at T and as the maximum over all
steps, both forms. ``BDF2(start='taylor2')`` drops the cubic term (for studies only).

**The error scale** (:func:`data_scale`): the floor of the adaptive controller's scale S_j is
the larger of the initial energy norm and the energy norms (rho|B^- G_dot|_M^2 +
|B^- G|_K^2)^{1/2} of the lifted data at 65 times in [0, T] (1 if all vanish), so that a run
starting at rest does not resolve exponentially small signals relatively (a tanh ramp's tail).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import scipy.sparse.linalg as spla

from ..errors import RunFailed, fail
from ..stepping.evolve import single_threaded_blas
from .state import ELDState, EnergyLedger


def _dot(a, b) -> float:
    return float(a @ b)


def consistent_acceleration(
    system, t: float, u: np.ndarray, v: np.ndarray, G_ddot: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(a, lambda) from (2.7a) at time t for given u, v: a = G_ddot on Gamma_D and
    rho M_II a_I = (F(t) - D(v) - K u)_I - rho M_IC G_ddot (CG with the diagonal of M, a
    mass matrix is well conditioned), lambda from the Gamma_D rows.

    Parameters
    ----------
    system : ELDSystem
        The problem and its operators on the mesh.
    t : float
    u, v : ndarray
        Displacement and velocity (dof vectors).
    G_ddot : ndarray
        The boundary acceleration on the constrained dofs.

    Returns
    -------
    (ndarray, ndarray)
        The acceleration (a dof vector) and the multiplier (on the constrained dofs).
    """
    p = system.problem
    c = p.constraint
    rho = system.rho
    I = system.I
    n = p.space.ndofs
    rhs = p.load(t) - system.D.apply(v) - p.K @ u
    a = np.zeros(n)
    a[c.dofs] = G_ddot
    r = (rhs - rho * (p.M @ a))[I] / rho
    diag = p.M.diagonal()[I]

    def mv(w):
        full = np.zeros(n)
        full[I] = w
        return (p.M @ full)[I]

    op = spla.LinearOperator((I.size, I.size), matvec=mv, dtype=float)
    prec = spla.LinearOperator((I.size, I.size), matvec=lambda w: w / diag, dtype=float)
    aI, info = spla.cg(op, r, rtol=1e-13, atol=0.0, maxiter=1000, M=prec)
    a[I] = aI
    lam = c.multiplier_from_residual((rhs - rho * (p.M @ a))[c.dofs])
    return a, lam


def initial_state(system, where: dict) -> ELDState:
    """The state at t = 0 (module docstring) with its products and ledger; its
    ``energy_norm_max`` is the initial energy norm.

    Raises :class:`~rothe.errors.RunFailed` (with ``where``) if the consistent acceleration or
    multiplier at t = 0 is not finite (e.g. after an overflow), and a one-line error if the
    initial data are not finite."""
    # BLAS level-1 calls outside the evolve loop: single-threaded as inside it
    # (rothe.stepping.evolve.single_threaded_blas; threaded dots spin on busy cores)
    with single_threaded_blas(), np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        return _initial_state(system, where)


def _initial_state(system, where: dict) -> ELDState:
    p = system.problem
    c = p.constraint
    G0, Gd0 = system.data.initial()
    vc = p.v0.copy()
    vc[c.dofs] = Gd0
    Gdd0 = p.G_ddot(0.0)
    for name, value in (("load(0)", p.load(0.0)), ("G_dot(0)", Gd0), ("G_ddot(0)", Gdd0)):
        if not np.all(np.isfinite(value)):
            raise fail(name, "non-finite values", "must be finite (the initial data)")
    a0, lam0 = consistent_acceleration(system, 0.0, p.u0, vc, Gdd0)
    if not (np.all(np.isfinite(a0)) and np.all(np.isfinite(lam0))):
        raise RunFailed(
            "non-finite initial state: the consistent acceleration or multiplier "
            "at t = 0 has NaN or inf entries (overflow?)",
            where=where,
        )
    if system.lifting is not None:  # regularized: split by the lifting
        u2, v2, w2 = system.lifting.lift_many([G0, Gd0, Gdd0])
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
    boundary.update(system.data.mode.initial_history(G0, Gd0))
    state = ELDState(
        t=0.0,
        j=0,
        tau_prev=None,
        fields=fields,
        boundary=boundary,
        products={},
        ledger=EnergyLedger(),
    )
    system.fill_products(state)
    Ku, Mv = state.products["Ku"], state.products["Mv"]
    kin, el = 0.5 * system.rho * _dot(v, Mv), 0.5 * _dot(u, Ku)
    state.ledger = EnergyLedger(kinetic=kin, elastic=el, initial=kin + el)
    state.energy_norm_max = math.sqrt(max(2.0 * (kin + el), 0.0))
    return state


def data_scale(system, T: float) -> float:
    """max over 65 times in [0, T] of (rho|B^- G_dot|_M^2 + |B^- G|_K^2)^{1/2} (the lifting
    of the regularized form; the nodal one in the original form)."""
    p = system.problem
    c = p.constraint
    best = 0.0
    for t in np.linspace(0.0, T, 65):
        g, gd = p.G(t), p.G_dot(t)
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(gd))):
            continue
        if system.lifting is not None:
            u2, v2 = system.lifting.lift_many([g, gd])
        else:
            u2, v2 = c.embed(g), c.embed(gd)
        best = max(best, system.rho * _dot(v2, p.M @ v2) + _dot(u2, p.K @ u2))
    return math.sqrt(best)


def with_prehistory(stepper, state: ELDState, tau: float) -> ELDState:
    """The j = 0 state with the BDF2 history u^{-1}, v^0, v^{-1} from the Taylor polynomial P
    (module docstring), for a first step tau (fictitious tau_0 = tau).

    The one copy for both backends: ``stepper`` (:class:`rothe.eld.stepper.StepperBase`, the
    serial or the PETSc one) supplies the linear algebra -- ``_start_data(tau, cubic)`` (the
    Gamma_D values of G_dot(0) and of G_3 = (G_ddot(tau) - G_ddot(0))/tau), ``_split`` (the
    scheme's unknown of a field), ``_fill_products``, ``_mult``, ``_dots`` -- and ``problem``,
    ``C``, ``rho``, ``scheme`` (its ``start`` says whether P has the cubic Gamma_D term:
    ``'taylor'``) and ``data_mode``.

    Parameters
    ----------
    stepper : StepperBase
    state : ELDState
        The initial state (not changed).
    tau : float
        The first step.

    Returns
    -------
    ELDState
    """
    p = stepper.problem
    C = stepper.C
    f = state.fields
    u0, a0 = f["u"], f["a"]
    cubic = stepper.scheme.start == "taylor"
    gd0, g3 = stepper._start_data(tau, cubic)
    vc = f["v"].copy()
    vc[C] = gd0
    G3 = np.zeros(vc.size)
    if cubic:
        G3[C] = g3

    def P(s):
        return u0 + s * vc + (0.5 * s * s) * a0 + (s**3 / 6.0) * G3

    U1, U2, U3 = P(-tau), P(-2.0 * tau), P(-3.0 * tau)
    V0 = (1.5 * u0 - 2.0 * U1 + 0.5 * U2) / tau
    V1 = (1.5 * U1 - 2.0 * U2 + 0.5 * U3) / tau
    fields = dict(f)
    split = stepper._split
    fields.update(x_1=split(U1), y=split(V0), y_1=split(V1))
    # the ledger follows the history too: v^0 = V0 (O(tau^2) from the initial velocity) with
    # u^{-1} = U1, v^{-1} = V1; the energy difference of V0 and v^0 is booked in X^1
    fields.update(v=V0, u_1=U1, v_1=V1)
    boundary = dict(state.boundary)
    boundary.update(stepper.data_mode.start_history(U1, V0, V1, C))
    products = {k: w for k, w in state.products.items() if k not in ("My", "Ky", "Mv")}
    new = replace(state, tau_prev=tau, fields=fields, boundary=boundary, products=products)
    stepper._fill_products(new)
    pr = new.products
    L = new.ledger
    rho = stepper.rho
    # C^0 with mu_0 = 1/2 (the fictitious equal history)
    dv, du = V0 - V1, u0 - U1
    v0M, zdk, sqk, zde, sqe = stepper._dots(
        [
            (V0, pr["Mv"]),
            (pr["Mv"], dv),
            (pr["Mv"] - stepper._mult(p.M, V1), dv),
            (pr["Ku"], du),
            (pr["Ku"] - stepper._mult(p.K, U1), du),
        ]
    )
    kin = 0.5 * rho * v0M
    L = replace(
        L,
        kinetic=kin,
        mismatch=L.mismatch - (kin - L.kinetic),
        g_zd_kin=rho * zdk,
        g_sq_kin=rho * sqk,
        g_zd_el=zde,
        g_sq_el=sqe,
        g_mu=0.5,
    )
    C0 = 0.5 * (L.g_zd_kin + L.g_zd_el) + 0.25 * (L.g_sq_kin + L.g_sq_el)
    new.ledger = replace(L, boundary_C=C0, boundary_C0=C0)
    return new
