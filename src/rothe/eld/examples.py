"""Examples: a manufactured solution on the unit square, and a 3D cantilever moved at one end.

Manufactured solution (:func:`mms_problem`). On (0,1)^2 in plane strain,

    u(x, t) = sin(pi t + pi/6) P(x) + (1 - cos(pi t)) R(x),
    P = (x + x y + y^2/2,  x^2/2 - x y + y),   R = (x^2 - y^2/2 + y,  x y + x/2 + y^2),

so u(0) = P/2, u'(0) = (pi sqrt(3)/2) P. Dirichlet data G = u on the Dirichlet parts (default
``left``: one straight part, so that the exact multiplier -sigma n is continuous along it and
lies in the P2 trace space), traction on the other parts, and the body force that makes u exact
for the chosen damping:

    f = rho u'' - div sigma(u + b u') + (a u'  |  -d0 u' + d_nl N(u'))      (Rayleigh | nonlinear),
    traction on Gamma_N:  sigma(u + b u') n,   multiplier on Gamma_D:  lambda = -sigma(u + b u') n,

(the stiffness-proportional part b K of the damping is a Kelvin-Voigt stress b sigma(u'), hence
its appearance in the traction and the multiplier). u is quadratic in x, so P2 elements represent
it exactly: with ``degree=2`` the semi-discrete solution is u itself (the nonlinear damping is
integrated with the same rule in the scheme and in F) and every error measured is the error of
the time discretization. With P1 an O(h^2) spatial error adds to it.

Fast ramp (:func:`ramp_problem`): the unit square (P2 by default), its left side moved
sideways by G(t) = (0, A S(t)) with the smoothed step S(t) = (1 + tanh((t - t_ramp)/w))/2
(10 % to 90 % in 2.2 w; w = 0.005, t_ramp = 0.5), free elsewhere, no body force, Rayleigh damping
b K (b = 0.01) that damps the mesh's highest modes. A time-localized event for step control.

Cantilever (:func:`beam_problem`). The box [0, L] x [0, 1] x [0, 1] (E = 1000, nu = 0.3,
rho = 1), the end x = 0 held and moved: G(t) = (0, 0, A (1 - cos(2 pi t / t_move)) / 2) for
t <= t_move, then 0; the end x = L and the sides free. The multiplier on x = 0 is the reaction.
"""

from __future__ import annotations

import math
import warnings
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import (
    RotheInputError,
    check_choice,
    check_int,
    check_nonnegative,
    check_positive,
    check_real,
    described,
    fail,
)
from ..fem import mesh as meshes
from .components import LinearComponent, MassSpringDamper, den_hartog, rigid_motion_matrix
from .control import LinearController, PointSensor, locate
from .coupled_step import closed_loop_roots, coupled_modes, modal_rows
from .coupling import CoupledProblem, Translation, UserCoupling
from .damping import Damping, NonlinearDamping, RayleighDamping
from .frequencies import (
    Attachment,
    bar_frequencies,
    beam_frequencies,
    controlled_bar_roots,
    first_mode_decay_rate,
    sliced_bar_frequencies,
)
from .materials import Material, PiecewiseMaterial
from .problem import CellwiseLoad, DirichletData, ELDProblem

# quadratic polynomials c0 + cx x + cy y + cxx x^2 + cxy x y + cyy y^2, per component
_P = np.array([[0.0, 1.0, 0.0, 0.0, 1.0, 0.5], [0.0, 0.0, 1.0, 0.5, -1.0, 0.0]])
_R = np.array([[0.0, 0.0, 1.0, 1.0, 0.0, -0.5], [0.0, 0.5, 0.0, 0.0, 1.0, 1.0]])


def _quad_value(c, x):
    X, Y = x[0], x[1]
    return np.stack(
        [a[0] + a[1] * X + a[2] * Y + a[3] * X * X + a[4] * X * Y + a[5] * Y * Y for a in c]
    )


def _quad_grad(c, x):
    """(2, 2, ...): [comp, k] = d_k u_comp."""
    X, Y = x[0], x[1]
    out = np.empty((2, 2) + X.shape)
    for comp in range(2):
        a = c[comp]
        out[comp, 0] = a[1] + 2 * a[3] * X + a[4] * Y
        out[comp, 1] = a[2] + a[4] * X + 2 * a[5] * Y
    return out


def _div_sigma_const(c, lam, mu):
    """div sigma(w) = mu Lap w + (lam + mu) grad div w, constant for quadratic w; (2,) for
    scalar lam, mu, (2,) + their shape for arrays (per-cell constants)."""
    shape = (2,) + (1,) * np.ndim(mu)
    lap = np.array([2 * c[0, 3] + 2 * c[0, 5], 2 * c[1, 3] + 2 * c[1, 5]]).reshape(shape)
    grad_div = np.array([2 * c[0, 3] + c[1, 4], c[0, 4] + 2 * c[1, 5]]).reshape(shape)
    return mu * lap + (lam + mu) * grad_div


class ManufacturedSolution:
    """u = alpha(t) P + beta(t) R, alpha = sin(pi t + pi/6), beta = 1 - cos(pi t) (module doc).

    With a :class:`PiecewiseMaterial` the data are those of each cell's material: the body
    force with the cell's rho_c, lam_c, mu_c (:meth:`cellwise_body_force`), tractions and
    multipliers with the constants of the cell next to each boundary facet
    (:meth:`cellwise_traction`, :meth:`multiplier_on`), and the jump of the traction across the
    facets between two materials (:meth:`interface_load`), so that u stays the exact solution.

    Parameters
    ----------
    material : Material or PiecewiseMaterial
    damping : Damping
        The damping the body force is made for.
    """

    def __init__(self, material: Material | PiecewiseMaterial, damping: Damping):
        self.material = material
        self.damping = damping
        self.b = getattr(damping, "b", 0.0)
        self.piecewise = isinstance(material, PiecewiseMaterial)

    @staticmethod
    def _time(t):
        pi = math.pi
        s, c = math.sin(pi * t), math.cos(pi * t)
        s6, c6 = math.sin(pi * t + pi / 6), math.cos(pi * t + pi / 6)
        # (alpha, beta), their first and second derivatives
        return (s6, 1 - c), (pi * c6, pi * s), (-pi * pi * s6, pi * pi * c)

    def _coeffs(self, t, order):
        a, b = self._time(t)[order]
        return a * _P + b * _R

    def u(self, t, x):
        """u(t, x) (x of shape (2, ...))."""
        return _quad_value(self._coeffs(t, 0), x)

    def u_dot(self, t, x):
        """The velocity u'(t, x)."""
        return _quad_value(self._coeffs(t, 1), x)

    def u_ddot(self, t, x):
        """The acceleration u''(t, x)."""
        return _quad_value(self._coeffs(t, 2), x)

    def grad_u(self, t, x):
        """grad u(t, x), shape (2, 2, ...)."""
        return _quad_grad(self._coeffs(t, 0), x)

    def grad_u_dot(self, t, x):
        """grad u'(t, x), shape (2, 2, ...)."""
        return _quad_grad(self._coeffs(t, 1), x)

    def stress(self, t, x, lam=None, mu=None):
        """sigma(u + b u') at x: (2, 2, ...); ``lam``, ``mu`` (default: the material's) may be
        arrays broadcasting against x[0] (per facet or cell constants)."""
        if lam is None:
            lam, mu = self.material.lam_eff, self.material.mu
        g = self.grad_u(t, x) + self.b * self.grad_u_dot(t, x)
        eps = 0.5 * (g + g.transpose((1, 0) + tuple(range(2, g.ndim))))
        tr = eps[0, 0] + eps[1, 1]
        sig = 2 * mu * eps  # lam_eff: lam (plane strain), 2 lam mu/(lam + 2 mu) (plane stress)
        sig[0, 0] += lam * tr
        sig[1, 1] += lam * tr
        return sig

    def traction(self, t, x, n, lam=None, mu=None):
        """sigma(u + b u') n."""
        return np.einsum("ij...,j...->i...", self.stress(t, x, lam, mu), n)

    def multiplier(self, t, x, n):
        """lambda = -sigma(u + b u') n on Gamma_D (paper's sign: ... + B* lambda = F)."""
        return -self.traction(t, x, n)

    def body_force(self, t, x):
        """f = rho u'' - div sigma(u + b u') + the damping's mass and pointwise parts: the body
        force that makes u exact (one material; several: :meth:`cellwise_body_force`)."""
        if self.piecewise:
            raise fail(
                "body_force",
                described("a call without the mesh"),
                "must be cellwise_body_force() for several materials (each cell's material)",
            )
        m = self.material
        return self._body_force(t, x, m.rho, m.lam_eff, m.mu, 1.0)

    def _body_force(self, t, x, rho, lam, mu, weight):
        """rho u'' - div sigma(u + b u') + the damping force density, the constants scalars or
        (nc, 1); ``weight`` = rho/rho_ref multiplies the mass-proportional damping (it acts
        through the mass of density rho/rho_ref, :mod:`rothe.eld.materials`)."""
        w_coeffs = self._coeffs(t, 0) + self.b * self._coeffs(t, 1)
        div = _div_sigma_const(w_coeffs, lam, mu)  # (2,) or (2, nc, 1): constant per cell
        div = np.reshape(div, np.shape(div) + (1,) * (x.ndim - np.ndim(div)))
        v = self.u_dot(t, x)
        f = rho * self.u_ddot(t, x) - div
        if isinstance(self.damping, RayleighDamping):
            f = f + self.damping.a * weight * v
        elif isinstance(self.damping, NonlinearDamping):
            f = f + self.damping.force_density(v) + self.damping.d0 * (1.0 - weight) * v
        return f

    # -- several materials: per-cell and per-facet constants ----------------------------------
    def _material_constants(self):
        """lam_eff, mu, rho, rho/rho_ref per material index (PiecewiseMaterial.names)."""
        mats = [self.material.materials[name] for name in self.material.names]
        rho = np.array([m.rho for m in mats])
        return (
            np.array([m.lam_eff for m in mats]),
            np.array([m.mu for m in mats]),
            rho,
            rho / self.material.rho,
        )

    def cellwise_body_force(self):
        """The body force as a :class:`~rothe.eld.problem.CellwiseLoad` f(t, x, k), k (ne, 1)
        each cell's material index, on whatever mesh the problem is on (space adaptivity); one
        material: :meth:`body_force`."""
        if not self.piecewise:
            return self.body_force
        lam, mu, rho, weight = self._material_constants()

        def body_force(t, x, k):
            return self._body_force(t, x, rho[k], lam[k], mu[k], weight[k])

        return CellwiseLoad(body_force)

    def cellwise_traction(self):
        """sigma(u + b u') n as a :class:`~rothe.eld.problem.CellwiseLoad` g(t, x, n, k), k
        (nf, 1) the material of the cell next to each facet; one material:
        :meth:`traction`."""
        if not self.piecewise:
            return self.traction
        lam, mu, _, _ = self._material_constants()
        return CellwiseLoad(lambda t, x, n, k: self.traction(t, x, n, lam[k], mu[k]))

    def multiplier_on(self, mesh, facets):
        """lambda(t, x, n) = -sigma(u + b u') n on the Dirichlet ``facets`` of ``mesh`` (sorted,
        the order of their facet quadrature), with the constants of the cell next to each;
        one material: :meth:`multiplier`."""
        if not self.piecewise:
            return self.multiplier
        lam, mu, _, _ = self._material_constants()
        cell = np.asarray(mesh.f2t)[0, np.asarray(facets, dtype=np.int64)]
        k = self.material.on_mesh(mesh).names[cell][:, None]
        return lambda t, x, n: -self.traction(t, x, n, lam[k], mu[k])

    def interface_load(self, t, x, n, k0, k1):
        """(sigma_0(u + b u') - sigma_1(u + b u')) n_0 on the facets between two materials
        (k0, k1 (nf, 1): the materials of the two sides, n the outward normal of side 0): what
        sum_K int_K sigma_K : eps(phi) leaves on the interfaces of the exact u."""
        lam, mu, _, _ = self._material_constants()
        return self.traction(t, x, n, lam[k0] - lam[k1], mu[k0] - mu[k1])


def mms_problem(
    n: int = 8,
    degree: int = 2,
    *,
    damping: Damping | None = None,
    rho: float = 1.0,
    lam: float = 2.0,
    mu: float = 1.0,
    T: float = 1.0,
    dirichlet=("left",),
    start: str = "exact",
    load_quadrature: int | None = None,
    material: Material | None = None,
    mesh=None,
) -> tuple[ELDProblem, ManufacturedSolution]:
    """The manufactured-solution problem on the unit square with n x n cells (module docstring).

    ``mesh``: any 2D body instead (u is defined everywhere): the exact data on the
    ``dirichlet`` parts, its traction on every other named part; every boundary facet must be
    in a named part (an unnamed one would be traction-free, not the manufactured solution's).

    Default damping: NonlinearDamping(b=0.01, d0=0.5, d_nl=1, v_ref=1). ``start='rest'`` starts
    from u0 = v0 = 0 instead of the exact initial data, which is inconsistent with G(0) != 0
    (Remark 2.2) and is refused before the first step.

    Parameters
    ----------
    n : int
        Cells per side.
    degree : int
        1 or 2.
    damping : Damping, optional
    rho, lam, mu : float
        Density and Lamé constants.
    T : float
        The end time.
    dirichlet : sequence of str
        The Dirichlet parts (traction on the others).
    start : {'exact', 'rest'}
    load_quadrature : int, optional
        The degree of the quadrature of body force and tractions (default 2 * degree).
    material : Material or PiecewiseMaterial, optional
        Instead of rho, lam, mu: a 2D material, also in plane stress (the body force, traction
        and multiplier are then those of the plane-stress law, sigma = lam* tr(eps) I + 2 mu eps
        with lam* = 2 lam mu/(lam + 2 mu)). Several materials on regions of ``mesh``: each
        cell's body force f = rho_c u'' - div sigma_c(u + b u') + damping with its constants,
        tractions and multipliers with those of the cell next to the facet, and on the facets
        between two materials the load (sigma_0 - sigma_1)(u + b u') n_0 (ELDProblem's
        ``interface_load``): sum_K int_K sigma_K(u) : eps(v) = int f v + int_{Gamma_N} t v +
        sum_{interfaces} int (sigma_0 - sigma_1) n_0 . v, so u stays exact. The body force and
        tractions are :class:`~rothe.eld.problem.CellwiseLoad` s (each cell's material index
        from the problem's mesh): a space-adaptive run takes them to its refined meshes.

    Returns
    -------
    (ELDProblem, ManufacturedSolution)
    """
    start = check_choice("start", start, ("exact", "rest"))
    if material is None:
        material = Material(rho=rho, lam=lam, mu=mu, dim=2)
    damping = damping if damping is not None else NonlinearDamping(b=0.01, d0=0.5, d_nl=1.0)
    exact = ManufacturedSolution(material, damping)
    if mesh is None:
        mesh = meshes.unit_square(n, named=True)
    else:
        _check_mms_mesh(mesh)
    dirichlet = (dirichlet,) if isinstance(dirichlet, str) else tuple(dirichlet)
    data = DirichletData(exact.u, exact.u_dot, exact.u_ddot)
    names = sorted((mesh.boundaries or {}).keys())
    # an unknown Dirichlet name is reported by ELDProblem (one line, naming the known parts);
    # several materials: loads that take each cell's material index from the problem's mesh,
    # so that they go to the refined meshes of a space-adaptive run
    traction = {p: exact.cellwise_traction() for p in names if p not in dirichlet}
    problem = ELDProblem(
        mesh,
        material,
        degree=degree,
        damping=damping,
        dirichlet={p: data for p in dirichlet},
        traction=traction,
        body_force=exact.cellwise_body_force(),
        interface_load=exact.interface_load if exact.piecewise else None,
        u0=(lambda x: exact.u(0.0, x)) if start == "exact" else None,
        v0=(lambda x: exact.u_dot(0.0, x)) if start == "exact" else None,
        T=T,
        name="eld-mms",
        load_quadrature=load_quadrature,
    )
    return problem, exact


def _check_mms_mesh(mesh) -> None:
    """A mesh for :func:`mms_problem`: 2D (the manufactured solution is plane), every boundary
    facet in a named part; one line naming ``mesh`` otherwise."""
    meshes.check_mesh_dim(mesh, 2, "triangles: the manufactured solution is plane")
    named = [np.asarray(f) for f in (mesh.boundaries or {}).values()]
    outside = np.setdiff1d(
        np.asarray(mesh.boundary_facets()), np.concatenate(named) if named else []
    )
    if outside.size:
        x = np.asarray(mesh.p)[:, np.asarray(mesh.facets)[:, outside[0]]].mean(axis=1)
        raise fail(
            "mesh",
            described(
                f"{outside.size} boundary facets in no named part (the first at "
                f"({x[0]:.4g}, {x[1]:.4g}))"
            ),
            "must put every boundary facet in a physical group (the exact data or traction "
            "goes on each part)",
        )


def mms_errors(exact: ManufacturedSolution, result) -> dict:
    """Errors at T of u and v (L2, H1) and of lambda (L2(Gamma_D)) of a run of the
    manufactured problem; with kept fields (on a fixed mesh) also the maxima over the kept
    states t > 0 (``error_u_l2_max``, ``error_v_l2_max``, ``error_lam_l2_max``).

    Parameters
    ----------
    exact : ManufacturedSolution
    result : ELDResult
        What :func:`rothe.eld.run_eld` returned (its final state on its final mesh).

    Returns
    -------
    dict
    """
    problem = result.problem
    traj = result.trajectory
    space = problem.space
    T = float(traj["t"][-1])
    state = result.state
    u = state.u if state is not None else traj["u"][-1]
    v = state.v if state is not None else traj["v"][-1]
    lam = state.lam if state is not None else traj["lam"][-1]
    eu = space.error_norms(u, lambda x: exact.u(T, x), lambda x: exact.grad_u(T, x))
    ev = space.error_norms(v, lambda x: exact.u_dot(T, x), lambda x: exact.grad_u_dot(T, x))
    lam_quad = multiplier_quadrature(problem)
    # -sigma n with the constants of the cell next to each Dirichlet facet (several materials)
    multiplier = exact.multiplier_on(
        space.mesh, space.facets(problem.constraint.parts, "dirichlet")
    )
    out = {
        "error_u_l2": eu["l2"],
        "error_u_h1": eu["h1"],
        "error_v_l2": ev["l2"],
        "error_v_h1": ev["h1"],
        "error_lam_l2": lam_quad.error(lam, lambda x, n: multiplier(T, x, n)),
        "lam_norm": "L2(Gamma_D)",
    }
    if "kept_t" in traj and "u" in traj:
        ts = traj["kept_t"]
        us, vs, lams = traj["u"], traj["v"], traj["lam"]
        ks = range(1, len(ts))
        out["error_u_l2_max"] = max(
            space.error_norms(us[k], lambda x, t=ts[k]: exact.u(t, x))["l2"] for k in ks
        )
        out["error_v_l2_max"] = max(
            space.error_norms(vs[k], lambda x, t=ts[k]: exact.u_dot(t, x))["l2"] for k in ks
        )
        out["error_lam_l2_max"] = max(
            lam_quad.error(lams[k], lambda x, n, t=ts[k]: multiplier(t, x, n)) for k in ks
        )
    return out


class MultiplierQuadrature:
    """Evaluates multipliers (values on the constrained dofs) at Gamma_D quadrature points."""

    def __init__(self, problem: ELDProblem):
        self.problem = problem
        c = problem.constraint
        self.q = problem.space.facet_quadrature(
            c.parts, intorder=2 * problem.space.degree + 2, name="dirichlet"
        )

    def values(self, lam: np.ndarray) -> np.ndarray:
        """The multiplier (values on the constrained dofs) at the quadrature points, (d, nf, nq)."""
        c = self.problem.constraint
        space = self.problem.space
        full = np.zeros((space.n_scalar, space.dim))
        full[c.scalar_dofs] = np.asarray(lam).reshape(-1, space.dim)
        return np.stack(
            [np.einsum("ifq,if->fq", self.q.values, full[self.q.dofs, k]) for k in range(space.dim)]
        )

    def error(self, lam: np.ndarray, exact) -> float:
        """||lambda_h - lambda||_{L2(Gamma_D)} against ``exact(x, n)`` (points and normals)."""
        diff = self.values(lam) - exact(self.q.x, self.q.normals)
        return float(np.sqrt(np.sum(np.sum(diff**2, axis=0) * self.q.dx)))


def multiplier_quadrature(problem: ELDProblem) -> MultiplierQuadrature:
    """The :class:`MultiplierQuadrature` of ``problem``'s Dirichlet parts."""
    return MultiplierQuadrature(problem)


# -- the fast ramp -----------------------------------------------------------------------------


class _DirichletMotion(ABC):
    """G, G_dot, G_ddot of a boundary motion from one ``_field(t, x, order)`` (order 0, 1, 2)."""

    @abstractmethod
    def _field(self, t, x, order):
        """The motion's value (order 0) or its first / second time derivative at (t, x)."""

    def G(self, t, x):
        return self._field(t, x, 0)

    def G_dot(self, t, x):
        return self._field(t, x, 1)

    def G_ddot(self, t, x):
        return self._field(t, x, 2)


class SmoothStep(_DirichletMotion):
    """G(t) = (0, A (1 + tanh((t - t0)/w))/2) with its first and second derivatives (2D)."""

    def __init__(self, amplitude: float = 0.1, t0: float = 0.5, width: float = 0.005):
        self.A = float(amplitude)
        self.t0 = float(t0)
        self.w = check_positive("width", width)

    def _s(self, t, order):
        z = math.tanh((t - self.t0) / self.w)
        if order == 0:
            return self.A * (1.0 + z) / 2.0
        sech2 = 1.0 - z * z
        if order == 1:
            return self.A * sech2 / (2.0 * self.w)
        return -self.A * sech2 * z / self.w**2

    def _field(self, t, x, order):
        out = np.zeros((2,) + x.shape[1:])
        out[1] = self._s(t, order)
        return out


def ramp_problem(
    n: int = 4,
    degree: int = 2,
    *,
    amplitude: float = 0.1,
    t_ramp: float = 0.5,
    width: float = 0.005,
    b: float = 0.01,
    rho: float = 1.0,
    lam: float = 2.0,
    mu: float = 1.0,
    T: float = 1.0,
) -> ELDProblem:
    """The unit square with its left side moved by a fast smoothed step (module docstring).

    Parameters
    ----------
    amplitude, t_ramp, width : float
        A, t_ramp and w of G(t) (module docstring).
    b : float
        The Rayleigh damping b K.
    n, degree, rho, lam, mu, T
        As in :func:`mms_problem`.

    Returns
    -------
    ELDProblem
    """
    material = Material(rho=rho, lam=lam, mu=mu, dim=2)
    step = SmoothStep(amplitude, t_ramp, width)
    mesh = meshes.unit_square(n, named=True)
    g0 = step.G(0.0, np.zeros((2, 1)))[:, 0]
    return ELDProblem(
        mesh,
        material,
        degree=degree,
        damping=RayleighDamping(0.0, b),
        dirichlet={"left": DirichletData(step.G, step.G_dot, step.G_ddot)},
        u0=lambda x: np.broadcast_to(g0[:, None], x.shape).copy(),
        T=T,
        name="eld-ramp",
    )


# -- the cantilever ----------------------------------------------------------------------------


class EndMotion(_DirichletMotion):
    """G(t) = (0, 0, A (1 - cos(2 pi t / t_move)) / 2) for t <= t_move, else 0 (H^2 in time)."""

    def __init__(self, amplitude: float = 0.1, t_move: float = 0.5):
        self.A = float(amplitude)
        self.t_move = check_positive("t_move", t_move)

    def _z(self, t, order):
        if t > self.t_move:
            return 0.0
        w = 2 * math.pi / self.t_move
        if order == 0:
            return self.A * (1 - math.cos(w * t)) / 2
        if order == 1:
            return self.A * w * math.sin(w * t) / 2
        return self.A * w * w * math.cos(w * t) / 2

    def _field(self, t, x, order):
        out = np.zeros((3,) + x.shape[1:])
        out[2] = self._z(t, order)
        return out


#: why a mesh of :func:`beam_problem` and :func:`pulse_3d_problem` must be 3D (their refusal)
BEAM_MESH = "tetrahedra: the held end moves along z"
PULSE_3D_MESH = "tetrahedra; the 2D pulse is eld-pulse"


def beam_problem(
    n: int = 4,
    *,
    length: float = 4.0,
    E: float = 1000.0,
    nu: float = 0.3,
    rho: float = 1.0,
    damping: Damping | None = None,
    amplitude: float = 0.1,
    t_move: float = 0.5,
    T: float = 2.0,
    degree: int = 1,
    material: Material | PiecewiseMaterial | None = None,
    mesh=None,
    dirichlet=("left",),
) -> ELDProblem:
    """The cantilever: n cells across the unit cross-section, round(length * n) along it; the
    ``dirichlet`` parts (default ``left``, x = 0) held and moved along z by G(t).

    Parameters
    ----------
    n : int
        Cells across the cross-section.
    length : float
        L.
    E, nu, rho : float
        Young's modulus, Poisson's ratio, density.
    damping : Damping, optional
        None: no damping (:class:`~rothe.eld.damping.NoDamping`).
    amplitude, t_move : float
        A and t_move of the end motion G(t) (module docstring).
    T : float
        The end time.
    degree : int
        1 or 2.
    material : Material or PiecewiseMaterial, optional
        A 3D material instead of E, nu, rho (materials by region with a ``mesh``).
    mesh : skfem.MeshTet, optional
        Any 3D body with named boundary parts (e.g. gmsh physical groups,
        :func:`rothe.fem.mesh.load_mesh`) instead of the box; ``n`` and ``length`` unused.
    dirichlet : str or tuple of str
        The held and moved parts (an unknown name: one line listing the mesh's parts).

    Returns
    -------
    ELDProblem
    """
    if material is None:
        material = Material.from_young(E, nu, rho, dim=3)
    if mesh is None:
        nx = max(1, int(round(length * n)))
        mesh = meshes.box(nx, n, n, length, 1.0, 1.0)
    else:
        meshes.check_mesh_dim(mesh, 3, BEAM_MESH)
    motion = EndMotion(amplitude, t_move)
    held = DirichletData(motion.G, motion.G_dot, motion.G_ddot)
    parts = (dirichlet,) if isinstance(dirichlet, str) else tuple(dirichlet)
    return ELDProblem(
        mesh,
        material,
        degree=degree,
        damping=damping,
        dirichlet={part: held for part in parts},
        T=T,
        name="eld-beam",
    )


# -- the pulse (space adaptivity) --------------------------------------------------------------


class BoundaryPulse(_DirichletMotion):
    """G(t, x) = A s(t) w(x) e: a short push along the unit vector e, localized around the
    point c of a boundary part.

    s(t) = sin^4(pi t / t_pulse) for t <= t_pulse, 0 after (C^2: s, s', s'' vanish at 0 and at
    t_pulse, so u0 = v0 = 0 are consistent and G_ddot is continuous); w(x) =
    exp(-sum_k ((x_k - c_k)/width)^2). On the left side of the rectangle (c = (0, 1/2),
    e = (1, 0), the defaults) w = exp(-((y - 1/2)/width)^2).

    Parameters
    ----------
    amplitude, t_pulse, width : float
        A, t_pulse and the width of w.
    center : (d,) array
        c (default (0, 1/2)).
    direction : (d,) array
        e, normalized here (default (1, 0); :func:`rothe.fem.mesh.part_frame` gives a part's
        mean inward normal).
    """

    def __init__(
        self,
        amplitude: float = 0.01,
        t_pulse: float = 0.1,
        center=(0.0, 0.5),
        width: float = 0.1,
        direction=(1.0, 0.0),
    ):
        self.A = float(amplitude)
        self.t_pulse = check_positive("t_pulse", t_pulse)
        self.center = np.asarray(center, dtype=float).reshape(-1)
        self.width = check_positive("width", width)
        e = np.asarray(direction, dtype=float).reshape(-1)
        if e.shape != self.center.shape or not np.linalg.norm(e) > 0:
            raise fail(
                "direction", tuple(e.tolist()), f"must be a non-zero {self.center.size}-vector"
            )
        self.direction = e / np.linalg.norm(e)

    def _s(self, t, order):
        if t <= 0.0 or t >= self.t_pulse:
            return 0.0
        k = math.pi / self.t_pulse
        s, c = math.sin(k * t), math.cos(k * t)
        if order == 0:
            return s**4
        if order == 1:
            return 4.0 * k * s**3 * c
        return k * k * (12.0 * s * s * c * c - 4.0 * s**4)

    def _field(self, t, x, order):
        out = np.zeros(x.shape)
        r2 = 0.0
        for k, ck in enumerate(self.center):
            r2 = r2 + ((x[k] - ck) / self.width) ** 2
        g = self.A * self._s(t, order) * np.exp(-r2)
        for k, ek in enumerate(self.direction):
            if ek != 0.0:  # (the zero components stay +0)
                out[k] = g if ek == 1.0 else g * ek
        return out


def rectangle(nx: int, ny: int, length: float = 2.0, height: float = 1.0):
    """[0, length] x [0, height] with nx x ny cells of two triangles, named faces."""
    # scikit-fem is imported where a mesh is built (the start-up time of the command line)
    from skfem import MeshTri

    return meshes.tag_box_faces(
        MeshTri.init_tensor(np.linspace(0.0, length, nx + 1), np.linspace(0.0, height, ny + 1))
    )


def pulse_problem(
    n: int = 4,
    degree: int = 2,
    *,
    length: float = 2.0,
    amplitude: float = 0.01,
    t_pulse: float = 0.1,
    width: float = 0.1,
    b: float = 0.001,
    rho: float = 1.0,
    lam: float = 2.0,
    mu: float = 1.0,
    T: float = 0.8,
    mesh=None,
    material: Material | PiecewiseMaterial | None = None,
    dirichlet=("left",),
    name: str = "eld-pulse",
) -> ELDProblem:
    """The pulse (:class:`BoundaryPulse`): the rectangle [0, length] x [0, 1] with round(length
    n) x n cells, the left side held and pushed by G around y = 1/2, the other sides free, at
    rest at t = 0; Rayleigh damping b K (b = 0.001, it damps the mesh's highest modes). With
    lam = 2, mu = rho = 1 the pressure wave (speed sqrt((lam + 2 mu)/rho) = 2) crosses the
    length 2 in t = 1, the shear wave (speed 1) follows; a front of width ~ 2 t_pulse = 0.2.

    Any body (2D or 3D): ``mesh`` with named boundary parts (e.g. gmsh physical groups,
    :func:`rothe.fem.mesh.load_mesh`) instead of n, length; the first of the ``dirichlet``
    parts is pushed along its mean inward normal around the centre of its bounding box
    (:func:`rothe.fem.mesh.part_frame`), the others are held (G = 0). ``material``: a
    Material (also plane stress) or a PiecewiseMaterial on the mesh's regions instead of rho,
    lam, mu.

    Parameters
    ----------
    n, degree : int
        Cells across the height of the rectangle; 1 or 2.
    length, amplitude, t_pulse, width, b, rho, lam, mu, T : float
    mesh : skfem mesh, optional
    material : Material or PiecewiseMaterial, optional
    dirichlet : sequence of str
        The held parts, the pushed one first (default ``("left",)``).
    name : str
        The problem's name (:func:`pulse_3d_problem`: ``"eld-pulse-3d"``).

    Returns
    -------
    ELDProblem
    """
    dirichlet = tuple(dirichlet)
    if not dirichlet:
        raise fail("dirichlet", dirichlet, "must name at least one boundary part")
    if mesh is None:
        if material is None:
            material = Material(rho=rho, lam=lam, mu=mu, dim=2)
        pulse = BoundaryPulse(amplitude, t_pulse, (0.0, 0.5), width, (1.0, 0.0))
        n = int(n)
        mesh = rectangle(max(1, round(length * n)), n, length, 1.0)
    else:
        dim = meshes.mesh_dim(mesh)
        if material is None:
            material = Material(rho=rho, lam=lam, mu=mu, dim=dim)
        center, normal = meshes.part_frame(mesh, dirichlet[0], "dirichlet")
        pulse = BoundaryPulse(amplitude, t_pulse, center, width, normal)

    def held(t, x):
        return np.zeros_like(x)

    data = {p: DirichletData(held, held, held) for p in dirichlet[1:]}
    data[dirichlet[0]] = DirichletData(pulse.G, pulse.G_dot, pulse.G_ddot)
    return ELDProblem(
        mesh,
        material,
        degree=degree,
        damping=RayleighDamping(0.0, b),
        dirichlet=data,
        T=T,
        name=name,
    )


def block(nx: int, ny: int, nz: int, length: float = 1.0, width: float = 1.0, height: float = 1.0):
    """[0, length] x [0, width] x [0, height] with nx x ny x nz cubes of six tetrahedra each
    (scikit-fem's ``MeshTet.init_tensor``), the faces named left/right (x), bottom/top (y),
    front/back (z)."""
    # scikit-fem is imported where a mesh is built (the start-up time of the command line)
    from skfem import MeshTet

    return meshes.tag_box_faces(
        MeshTet.init_tensor(
            np.linspace(0.0, length, nx + 1),
            np.linspace(0.0, width, ny + 1),
            np.linspace(0.0, height, nz + 1),
        )
    )


def pulse_3d_problem(
    n: int = 2,
    degree: int = 2,
    *,
    length: float = 1.0,
    amplitude: float = 0.01,
    t_pulse: float = 0.1,
    width: float = 0.15,
    b: float = 0.001,
    rho: float = 1.0,
    lam: float = 2.0,
    mu: float = 1.0,
    T: float = 0.5,
    material: Material | PiecewiseMaterial | None = None,
    mesh=None,
    dirichlet=("left",),
) -> ELDProblem:
    """The pulse in 3D: the block [0, length] x [0, 1] x [0, 1] (:func:`block`, round(length n)
    x n x n cubes of six tetrahedra), its face x = 0 (``left``) held and pushed along x by
    :class:`BoundaryPulse` around its centre (0, 1/2, 1/2),

        G(t, x) = A s(t) exp(-((y - 1/2)^2 + (z - 1/2)^2) / width^2) e_x,

    s(t) = sin^4(pi t / t_pulse) on [0, t_pulse]; the other faces free, at rest at t = 0,
    Rayleigh damping b K. With lam = 2, mu = rho = 1 a pressure front (speed 2) leaves the
    pushed spot as a half sphere of thickness ~ 2 t_pulse = 0.2, the shear front (speed 1)
    follows; the pressure front reaches x = 1 at t = 0.5 (the default T) and the sides
    y, z = 0, 1 at t = 0.25, from where reflections follow it. The localized push on part of
    the face makes the fronts thin shells: the adaptive mesh refines on them and coarsens
    behind.

    P2 by default, P1 allowed. Why P2: a P2 tetrahedral space has about 8 times the dofs of P1
    on the same mesh (vertices + edges, ~7 edges per vertex) and its matrix rows about twice
    the nonzeros, so a P2 dof costs more to assemble, factor and solve; but the energy error
    of a smooth wave falls as h^2 against P1's h, and at the errors of interest (a few per
    cent) P2 needs far fewer dofs for the same error (the 2D pulse: P2 reaches P1's error with
    fewer dofs by a factor that grows as the error falls; in 3D the factor is cubed, h^-3).
    It also makes a reference one uniform refinement finer 4 times more accurate in the energy
    norm (8 times in L2), which the 3D benchmark needs (benchmarks/space_adaptivity.py
    ``--family eld3d``); with P1 the reference would have to be 4 times finer, 64 times the
    cells.

    Parameters
    ----------
    n, degree : int
        Cubes across the block's cross-section; 1 or 2.
    length, amplitude, t_pulse, width, b, rho, lam, mu, T : float
    material : Material, optional
        Instead of rho, lam, mu (dim 3).
    mesh : skfem.MeshTet, optional
        A refinement of the block with its named faces instead of n, length (the nested
        meshes of the benchmark, :class:`rothe.fem.adapt.AdaptiveMesh` ``.uniform``), or any
        3D body with named parts (a gmsh file): the first ``dirichlet`` part pushed along its
        mean inward normal around the centre of its bounding box
        (:func:`rothe.fem.mesh.part_frame`: on the block's ``left`` exactly e_x at
        (0, 1/2, 1/2)), the others held (:func:`pulse_problem`).
    dirichlet : sequence of str
        The held parts, the pushed one first (default ``("left",)``).

    Returns
    -------
    ELDProblem
    """
    if mesh is None:
        n = check_int("n", n, minimum=1)
        length = check_positive("length", length)
        mesh = block(max(1, round(length * n)), n, n, length)
    else:
        meshes.check_mesh_dim(mesh, 3, PULSE_3D_MESH)
    if material is None:
        material = Material(rho=rho, lam=lam, mu=mu, dim=3)
    return pulse_problem(
        degree=degree,
        amplitude=amplitude,
        t_pulse=t_pulse,
        width=width,
        b=b,
        T=T,
        mesh=mesh,
        material=material,
        dirichlet=dirichlet,
        name="eld-pulse-3d",
    )


# -- the bar with a mass-spring at its tip (issue 19) -------------------------------------------


@dataclass
class TipMassExample:
    """The bar of :func:`tip_mass_problem`: the coupled system, started in its first axial mode,
    and the frequencies the run is compared with.

    Attributes
    ----------
    system : CoupledProblem
        The body clamped on its clamped parts (``left``), the mass-spring tied to the tip part
        (``right``) by a translation.
    analytic : ndarray
        The first three axial angular frequencies of the 1D bar (length, cross-section
        ``area``) with the mass-spring at its end (the transcendental equation:
        :func:`rothe.eld.frequencies.bar_frequencies`); for a body of several materials whose
        materials fill slices along x, those of the sliced bar
        (:func:`rothe.eld.frequencies.sliced_bar_frequencies`, :func:`axial_slices`); NaN for
        other bodies of several materials (the reason in ``prediction``).
    discrete : ndarray
        The first three axial frequencies of the semi-discrete coupled system
        (:func:`rothe.eld.coupled_step.coupled_modes`; axial: the tip moves along x).
    length, area : float
        The bar's length and cross-section behind ``analytic`` (of a mesh: its extent in x
        and its volume / length, a prismatic bar along x).
    """

    system: CoupledProblem
    analytic: np.ndarray
    discrete: np.ndarray
    length: float = math.nan
    area: float = math.nan
    #: the projection on the excited modes (:func:`~rothe.eld.coupled_step.modal_rows`):
    #: c = projection_u u + projection_q q, one row per mode of ``modes``
    projection_u: np.ndarray | None = None
    projection_q: np.ndarray | None = None
    #: how ``analytic`` was found: ``"bar"`` (one material), ``"sliced bar"`` (slices of
    #: several materials along x: ``slices``) or ``"n/a: <why>"`` (``analytic`` NaN)
    prediction: str = "bar"
    #: the slices behind a sliced bar's ``analytic``, from the clamped end to the tip: per
    #: slice its interval [a, b] in x, material name, axial modulus and density
    slices: list | None = None

    @property
    def modes(self) -> int:
        """K, the axial modes the run starts in."""
        return 0 if self.projection_u is None else self.projection_u.shape[0]

    @property
    def watch(self):
        """projection_u as the ``watch`` rows of :func:`~rothe.eld.coupled_run.run_coupled`:
        the run records R_u u at every state (``watch_u``) without keeping the fields."""
        return sp.csr_matrix(self.projection_u)

    def modal_coordinates(self, trajectory) -> np.ndarray:
        """(states, K): c_k(t_j) = (R_u u_j)_k + (R_q q_j)_k of a run with ``watch`` (its
        ``watch_u``) or with ``fields`` (its ``u``)."""
        q = np.asarray(trajectory["q"])
        if "watch_u" in trajectory.keys():
            return np.asarray(trajectory["watch_u"]) + q @ self.projection_q.T
        return np.asarray(trajectory["u"]) @ self.projection_u.T + q @ self.projection_q.T


def tip_mass_problem(
    n: int = 2,
    degree: int = 2,
    *,
    length: float = 1.0,
    height: float = 0.25,
    E: float = 100.0,
    nu: float = 0.0,
    rho: float = 1.0,
    mass: float = 0.25,
    spring: float = 0.0,
    damper: float = 0.0,
    amplitude: float = 0.01,
    T: float = 2.0,
    material: Material | PiecewiseMaterial | None = None,
    mesh=None,
    clamp=("left",),
    tip: str = "right",
    damping: Damping | None = None,
    modes: int = 1,
) -> TipMassExample:
    """A plane-stress strip [0, length] x [0, height] (n cells across, round(n length/height)
    along) clamped on ``left``, carrying on ``right`` a mass ``mass`` on a spring ``spring``
    and a damper ``damper`` to the ground (:class:`~rothe.eld.components.MassSpringDamper`,
    all axes), tied by B u = q on ``right`` (:class:`~rothe.eld.coupling.Translation`).

    With nu = 0 the axial motion is that of the 1D bar, whose angular frequencies solve the
    end condition E A beta cos(beta L) = (k - w^2 m) sin(beta L), beta = w sqrt(rho/E),
    A = height (per unit thickness); the run starts in the first axial mode of the discrete
    coupled system, scaled so that the tip moves by ``amplitude``, at rest.

    ``material``: a Material instead of E, nu, rho (plane stress by default in 2D); the
    analytic frequencies then take the axial modulus, E in plane stress and 3D and
    E/(1 - nu^2) in plane strain (sigma_yy = 0 across the free sides), with E, nu of
    :attr:`~rothe.eld.materials.Material.young`; or a PiecewiseMaterial: when its materials
    fill slices along x (:func:`axial_slices`) the analytic frequencies are the sliced bar's
    (:func:`~rothe.eld.frequencies.sliced_bar_frequencies`, each slice's axial modulus as
    above, the mass-spring at the tip), otherwise NaN (the reason in ``prediction``).
    ``mesh``: any body (2D or 3D, named parts) instead of the strip, clamped on the parts
    ``clamp``, the mass-spring on the part ``tip``; "axial" is along x, and the analytic
    frequencies are those of a prismatic bar along x (length: the extent in x, area:
    volume / length). ``damping``: the body's damping (default none); the start mode and the
    frequencies are those of the undamped system.

    ``modes``: K, the run starts in the sum of the first K axial modes phi_k of the discrete
    coupled system (body and tip coordinate), each scaled so that its tip moves by
    ``amplitude`` with the sign of the first mode's tip (K = 1: the first mode alone, as
    before, bit for bit); the example's ``projection_u``, ``projection_q`` give their modal
    coordinates c_k = phi_k^T M x (:func:`~rothe.eld.coupled_step.modal_rows`), the
    frequencies of the run's c_k (:func:`~rothe.eld.frequencies.modal_frequencies`) are the
    measured ones. ``analytic`` and ``discrete`` hold max(3, K) frequencies.
    """
    modes = check_int("modes", modes, minimum=1)
    mass = check_positive("mass", mass)
    spring = check_nonnegative("spring", spring)
    damper = check_nonnegative("damper", damper)
    amplitude = check_positive("amplitude", amplitude)
    if degree not in (1, 2):
        raise fail("degree", degree, "must be 1 or 2")
    if mesh is None:
        n = check_int("n", n, minimum=1)
        length = check_positive("length", length)
        height = check_positive("height", height)
        nx = max(1, int(round(n * length / height)))
        mesh = rectangle(nx, n, length, height)
        area, refine = height, "n"
    else:
        p = np.asarray(mesh.p)
        length = float(np.ptp(p[0]))
        area = float(meshes.cell_volumes(mesh).sum()) / length
        refine = "mesh"
    dim = meshes.mesh_dim(mesh)
    if material is None:
        material = Material.from_young(
            E, nu, rho, dim=dim, plane="stress" if dim == 2 else "strain"
        )
        modulus = E
    elif isinstance(material, PiecewiseMaterial):
        modulus = math.nan
    else:
        modulus, rho = axial_modulus(material, dim), material.rho
    clamp = (clamp,) if isinstance(clamp, str) else tuple(clamp)

    def held(t, x):
        return 0.0 * x

    def build(u0=None, q0=None):
        mover = MassSpringDamper(mass, spring, damper, dim=dim, q0=q0, name="tip")
        body = ELDProblem(
            mesh,
            material,
            degree=degree,
            dirichlet={part: held for part in clamp},
            damping=damping,
            u0=u0,
            T=T,
            name="tip-mass",
        )
        return CoupledProblem(body, [mover], [Translation(tip, mover)])

    with warnings.catch_warnings():  # G = 0: its derivatives by differences are exact
        warnings.filterwarnings("ignore", message="G_d")
        w, U, Q = coupled_modes(build(), 16)
        axial = np.flatnonzero(np.abs(Q[0]) > 10 * np.abs(Q[1:]).max(axis=0))
        if axial.size < 3:
            raise fail(
                refine,
                n if refine == "n" else described("the mesh"),
                "gives fewer than 3 axial modes among the first 16: refine",
            )
        if modes > axial.size:
            raise fail(
                "modes",
                modes,
                f"must be at most {axial.size} (the axial modes among the first 16 of the "
                "discrete system)",
            )
        excited = axial[:modes]
        k = int(excited[0])
        scale = amplitude / abs(Q[0, k])
        u0, q0 = U[:, k] * scale, Q[:, k] * scale
        for i in excited[1:]:  # the higher modes' tips move with the first's, by amplitude
            scale_i = amplitude / Q[0, i] * np.sign(Q[0, k])
            u0, q0 = u0 + U[:, i] * scale_i, q0 + Q[:, i] * scale_i
        system = build(u0, q0)
        R_u, R_q = modal_rows(system, U[:, excited], Q[:, excited])
    count = max(3, modes)
    attachment = Attachment.mass_spring(mass, spring)
    prediction, slices = "bar", None
    if not math.isnan(modulus):
        analytic = bar_frequencies(length, modulus, rho, area=area, right=attachment, count=count)
    else:
        slices = axial_slices(mesh, material, tip)
        if isinstance(slices, str):
            prediction, slices = slices, None
            analytic = np.full(count, math.nan)
        else:
            prediction = "sliced bar"
            analytic = sliced_bar_frequencies(
                [s["x"][1] - s["x"][0] for s in slices],
                [s["modulus"] for s in slices],
                [s["rho"] for s in slices],
                area=area,
                right=attachment,
                count=count,
            )
    return TipMassExample(
        system, analytic, w[axial[:count]], length, area, R_u, R_q, prediction, slices
    )


#: why a body of several materials has no analytic frequencies (its ``prediction``)
NOT_SLICES = "n/a: the materials do not fill slices along x (the sliced bar needs them)"


def axial_modulus(material: Material, dim: int) -> float:
    """The modulus of a bar's axial motion in ``material``: E in plane stress and 3D (free
    sides: sigma_yy = sigma_zz = 0), E/(1 - nu^2) in plane strain (eps_zz = 0, sigma_yy = 0)."""
    E, nu = material.young
    return E if material.plane == "stress" or dim == 3 else E / (1.0 - nu * nu)


def axial_slices(mesh, material: PiecewiseMaterial, tip: str = "right", rtol: float = 1e-9):
    """The slices along x of a body of several materials, from the clamped end to the tip, or
    the reason there are none (:data:`NOT_SLICES` with what failed).

    Each material's cells are grouped into intervals of x: the cells' [min x, max x] of their
    nodes, sorted, merged where they overlap or touch (one material may fill several slices).
    The body is sliced when these intervals, all materials together, tile [x_min, x_max]
    (a_0 = x_min, b_{i} = a_{i+1}, b_last = x_max, to ``rtol`` L) and each fills the whole
    cross-section: its cells' volume is (b_i - a_i) A, A = volume / L, to ``rtol`` of the
    body's volume. A core in a shell along the length, or layers along y, overlap in x and are
    refused. The order is reversed when the ``tip`` part lies at x_min (the bar's x = 0 is the
    clamped end). Returns a list of dicts: ``x`` [a, b], ``material`` (name), ``modulus``
    (:func:`axial_modulus`), ``rho``; or the reason (a string)."""
    p, t = np.asarray(mesh.p), np.asarray(mesh.t)
    dim = meshes.mesh_dim(mesh)
    names = material.on_mesh(mesh).names
    x = p[0, t]  # (nodes of a cell, cells)
    lo, hi = x.min(axis=0), x.max(axis=0)
    volume = meshes.cell_volumes(mesh)
    x0, x1 = float(p[0].min()), float(p[0].max())
    L, total = x1 - x0, float(volume.sum())
    tol = rtol * L
    a, b, v, owner = [], [], [], []
    for k in np.unique(names):  # (a loop over the materials, not the cells)
        cells = np.flatnonzero(names == k)
        cells = cells[np.argsort(lo[cells], kind="stable")]
        start_x, reach = lo[cells], np.maximum.accumulate(hi[cells])
        starts = np.flatnonzero(np.r_[True, start_x[1:] > reach[:-1] + tol])
        ends = np.r_[starts[1:] - 1, cells.size - 1]
        a.append(start_x[starts])
        b.append(reach[ends])
        v.append(np.add.reduceat(volume[cells], starts))
        owner.append(np.full(starts.size, k))
    a, b, v, owner = (np.concatenate(z) for z in (a, b, v, owner))
    order = np.argsort(a, kind="stable")
    a, b, v, owner = a[order], b[order], v[order], owner[order]
    if abs(a[0] - x0) > tol or abs(b[-1] - x1) > tol or np.any(np.abs(a[1:] - b[:-1]) > tol):
        return f"{NOT_SLICES}: their intervals of x overlap or leave gaps"
    if np.any(np.abs(v - (b - a) * total / L) > rtol * total):
        return f"{NOT_SLICES}: a slice does not fill the cross-section"
    tip_x = meshes.part_centroid(mesh, tip, "tip")[0][0]
    slices = []
    for ai, bi, k in zip(a, b, owner, strict=True):
        name = material.names[k]
        m = material.materials[name]
        slices.append(
            {
                "x": [float(ai), float(bi)],
                "material": name,
                "modulus": axial_modulus(m, dim),
                "rho": float(m.rho),
            }
        )
    return slices[::-1] if tip_x - x0 < x1 - tip_x else slices


# -- the cantilever on a shaken support, with and without a tuned mass damper (issue 19) --------


class PlateAbsorber(LinearComponent):
    """A rigid end plate (small rotations: translation a, rotation theta about its centre x_c;
    mass m_p, inertia J_p) carrying an absorber mass m_a on a spring k and a damper c along the
    axis ``axis``. 2D: coordinates q = (a_x, a_y, theta, s), with s the absorber's
    displacement,

        M = diag(m_p, m_p, J_p, m_a),   f = k (a_y - s) (e_ay - e_s) + c (p_ay - p_s) (e_ay - e_s);

    3D (a centre of 3 coordinates): q = (a_x, a_y, a_z, theta_x, theta_y, theta_z, s),
    M = diag(m_p I, J_p I, m_a) (J_p isotropic about the centre), the same spring and damper
    between a_axis and s.

    Without an absorber (``absorber_mass=0``) only (a, theta): the plate alone, a
    :class:`~rothe.eld.components.RigidBody`'s coordinates. Tie it to a part with
    :func:`plate_coupling`.

    Parameters
    ----------
    plate_mass, plate_inertia : float
        m_p > 0, J_p > 0 about the centre.
    center : (2,) or (3,) array
        x_c, the reference point of the rotation; its size is the dimension.
    absorber_mass, stiffness, damping : float
        m_a >= 0 (0: no absorber), k, c >= 0.
    name : str
    axis : int
        The absorber's direction: 1 (y, default: the formulas above), 0 (x: a_x - s) or, in
        3D, 2 (z).
    """

    def __init__(
        self,
        plate_mass: float,
        plate_inertia: float,
        center,
        *,
        absorber_mass: float = 0.0,
        stiffness: float = 0.0,
        damping: float = 0.0,
        name: str = "plate",
        axis: int = 1,
    ):
        mp = check_positive("plate_mass", plate_mass)
        Jp = check_positive("plate_inertia", plate_inertia)
        ma = check_nonnegative("absorber_mass", absorber_mass)
        k = check_nonnegative("stiffness", stiffness)
        c = check_nonnegative("damping", damping)
        center = np.asarray(center, dtype=float).ravel()
        if center.size not in (2, 3):
            raise fail("center", described(f"{center.tolist()}"), "must be a point in 2D or 3D")
        self.center = center
        self.dim = d = center.size
        if d == 2:
            names, rigid = ("a_x", "a_y", "theta"), [mp, mp, Jp]
        else:
            names = ("a_x", "a_y", "a_z", "theta_x", "theta_y", "theta_z")
            rigid = [mp] * 3 + [Jp] * 3
        if ma == 0.0:
            super().__init__(np.array(rigid), coordinates=names, name=name)
            return
        if axis not in range(d):
            raise fail("axis", axis, "must be 0 (x) or 1 (y)" + (" or 2 (z)" if d == 3 else ""))
        e = np.zeros(len(names) + 1)
        e[axis], e[-1] = 1.0, -1.0  # a_y - s (a_x - s along x, a_z - s along z)
        super().__init__(
            np.array(rigid + [ma]),
            k * np.outer(e, e),
            c * np.outer(e, e),
            coordinates=(*names, "absorber_" + "xyz"[axis]),
            name=name,
        )


def plate_coupling(part: str, plate: PlateAbsorber) -> UserCoupling:
    """B u = G(q) on ``part``: the part moves with the plate, G(q, x) = a + theta x (x - x_c)
    (linearized rigid motion, 2D: theta e_z x (x - x_c);
    :func:`~rothe.eld.components.rigid_motion_matrix`); the absorber coordinate does not enter
    G. A linear, time-independent coupling."""
    rigid = 3 if plate.dim == 2 else 6

    def G_q(t, q, x):
        R = rigid_motion_matrix(plate.dim, x, plate.center)  # (d, k, 3 or 6)
        out = np.zeros(R.shape[:2] + (plate.size,))
        out[:, :, :rigid] = R
        return out

    def G(t, q, x):
        return np.einsum("dkm,m->dk", G_q(t, q, x), q)

    return UserCoupling(part, plate, G, G_q, linear=True)


@dataclass
class TMDExample:
    """The cantilever of :func:`tmd_problem`, with and without the absorber.

    Attributes
    ----------
    with_tmd, without_tmd : CoupledProblem
        Base, strip and end plate; with_tmd adds the absorber on the plate.
    frequency : float
        w_1, the first bending frequency of the system without the absorber (discrete modes).
    modal_mass : float
        m_1 of that mode with the plate's deflection a_y scaled to 1.
    stiffness, damping : float
        The absorber's k, c (Den Hartog: :func:`~rothe.eld.components.den_hartog`).
    forcing : float
        The angular frequency of the force on the base.
    beam_frequency : float
        w_1 of the Euler-Bernoulli cantilever of the strip (clamped, no plate, no base), for
        comparison; NaN for a body of several materials (``prediction`` says why).
    length, height : float
        The strip's L and H (of a mesh: its extent in x and area / L).
    clamped_frequency : float
        w_c, the lowest frequency of the discrete body clamped at its base (no plate, no
        support), which sizes the support's springs.
    prediction : str or None
        Why ``beam_frequency`` is NaN (:data:`SEVERAL_MATERIALS`), None where it is defined.
    direction : int
        The axis the support is pushed along and the absorber swings along (the plate's
        deflection a_direction; :func:`tmd_problem`'s ``direction`` or its default).
    """

    with_tmd: CoupledProblem
    without_tmd: CoupledProblem
    frequency: float
    modal_mass: float
    stiffness: float
    damping: float
    forcing: float
    beam_frequency: float
    length: float = math.nan
    height: float = math.nan
    clamped_frequency: float = math.nan
    prediction: str | None = None
    direction: int = 1


#: why the predictions of eld-tmd and eld-control that need one E and rho are NaN (null in
#: summary.json) for a body of several materials
SEVERAL_MATERIALS = "n/a: several materials (the formula is a uniform strip's, of one E and rho)"


def _strip(n, degree, length, height, material, young, mesh=None, base="left", tip="right", axis=0):
    """The body of the coupled examples: the checked ``n``, ``length``, ``height``, the
    material (default E = ``young``, nu = 0, rho = 1, plane stress; plane strain in 3D), the
    axial modulus of the strip (:func:`axial_modulus`: E in plane stress and 3D, E/(1 - nu^2)
    in plane strain; NaN for a PiecewiseMaterial: no one modulus), the mesh, round(n L/H) x n
    cells on [0, L] x [0, H], and the centroid and size of the ``tip`` part (the right side:
    (L, H/2) and H).

    ``mesh``: a 2D or 3D body with the named parts ``base`` and ``tip`` instead of the strip;
    it is taken as a bar along ``axis``: L its extent along it, H = volume / L (2D: the strip's
    own L, H to round-off; 3D: the cross-section's area A), the tip's centroid and measure
    (length in 2D, area in 3D) from its facets (:func:`rothe.fem.mesh.part_centroid`).
    ``axis`` 1 (y) or 2 (z, a 3D mesh) needs a mesh; the built-in strip lies along x only."""
    if axis not in (0, 1, 2):
        raise fail("axis", axis, "must be 0 (x), 1 (y) or 2 (z)")
    if axis > 0 and mesh is None:
        raise fail("axis", "xyz"[axis], "needs a mesh (the built-in strip lies along x)")
    if degree not in (1, 2):
        raise fail("degree", degree, "must be 1 or 2")
    strip = mesh is None
    if strip:
        n = check_int("n", n, minimum=1)
        length = check_positive("length", length)
        height = check_positive("height", height)
        mesh = rectangle(max(1, int(round(n * length / height))), n, length, height)
    elif axis >= meshes.mesh_dim(mesh):
        raise fail(
            "axis",
            "xyz"[axis],
            f"needs a 3D mesh (got a 2D mesh: {meshes.describe(mesh)})",
        )
    meshes.part_centroid(mesh, base, "base")  # (the base must be a part: one line if not)
    if tip == base:
        raise fail("tip", tip, "must not be the base's part (the base and the tip are two ends)")
    if strip and tip == "right":  # (exact, as before the parts could be named)
        center, tip_size = np.array([length, height / 2]), height
    else:
        center, tip_size = meshes.part_centroid(mesh, tip, "tip")
    if not strip:
        length = float(np.ptp(np.asarray(mesh.p)[axis]))
        height = float(meshes.cell_volumes(mesh).sum()) / length
    dim = meshes.mesh_dim(mesh)
    if material is None:
        plane = "stress" if dim == 2 else "strain"
        material = Material.from_young(young, 0.0, 1.0, dim=dim, plane=plane)
    if isinstance(material, PiecewiseMaterial):
        modulus = math.nan
    else:
        modulus = axial_modulus(material, dim)
    return n, length, height, material, modulus, mesh, center, tip_size


#: why eld-tmd's Euler-Bernoulli comparison is NaN (null in summary.json) on a 3D body
BEAM_THEORY_2D = (
    "n/a: a 3D body (the Euler-Bernoulli comparison is the plane strip's, E H^3/12; the "
    "discrete w_1 and w_c hold in 3D)"
)


def _bending_mode_3d(w, Q, offset: int, axis: int, across: int, refine) -> tuple[float, float]:
    """(w_1, m_1) of the first bending mode along ``across`` of a 3D coupled system from its
    mass-normalized modes (w, Q of :func:`~rothe.eld.coupled_step.coupled_modes`; the plate's
    a at ``offset``): the modes are grouped by frequency (within 1e-3: a square section's
    bending modes in its two transverse axes are one eigenvalue, split in the solver's basis
    at will), and in each group the combination psi = sum_k c_k phi_k, |c| = 1, with the
    largest a_across, c = Q[a_across, group] / |.|; the first group whose psi has
    |a_across| > 10 |a_axis| and > 10 |a_other| is bending along ``across``, with
    w_1^2 = sum_k c_k^2 w_k^2 (the Rayleigh quotient) and m_1 = 1 / |Q[a_across, group]|^2
    (psi's a_across scaled to 1)."""
    other = 3 - axis - across
    start = 0
    while start < w.size:
        group = np.flatnonzero(np.abs(w - w[start]) <= 1e-3 * w[start])
        group = group[group >= start]
        a = Q[offset + across, group]
        size = float(np.sqrt(a @ a))
        if size > 0:
            c = a / size
            psi = Q[:, group] @ c
            side = max(abs(psi[offset + axis]), abs(psi[offset + other]))
            if abs(psi[offset + across]) > 10 * side:
                return float(np.sqrt(c**2 @ w[group] ** 2)), 1.0 / size**2
        start = int(group[-1]) + 1
    raise fail(*refine, "gives no bending mode among the first 8: refine")


def _body_mass(mesh, material) -> float:
    """The body's mass sum_c rho_c |c| (the density of each cell's material)."""
    if isinstance(material, PiecewiseMaterial):
        rho = material.on_mesh(mesh).rho
    else:
        rho = material.rho
    return float((meshes.cell_volumes(mesh) * rho).sum())


def _clamped_frequency(mesh, material, degree: int, part: str) -> float:
    """w_c, the lowest natural frequency of the discrete body clamped on ``part`` (nothing
    else attached): K x = w^2 rho_ref M x on the free dofs, for any material (a
    PiecewiseMaterial's per-cell constants and densities are in K and M). Shift-invert Lanczos
    about 0 (K is positive definite with the clamp), started from the vector of ones so every
    run gets the same value. For the slender strip it is the first bending mode, the discrete
    counterpart of the Euler-Bernoulli w_EB (10.085 against 10.15 for eld-tmd's default)."""

    def held(t, x):
        return 0.0 * x

    with warnings.catch_warnings():  # G = 0: its derivatives by differences are exact
        warnings.filterwarnings("ignore", message="G_d")
        body = ELDProblem(mesh, material, degree=degree, dirichlet={part: held}, name="clamped")
    free = body.constraint.free
    K = body.K.tocsr()[free][:, free].tocsc()
    M = (body.material.rho * body.M).tocsr()[free][:, free].tocsc()
    w2 = spla.eigsh(
        K, k=1, M=M, sigma=0.0, which="LM", v0=np.ones(free.size), return_eigenvectors=False
    )
    return float(np.sqrt(w2[0]))


def tmd_problem(
    n: int = 2,
    degree: int = 2,
    *,
    length: float = 1.0,
    height: float = 0.1,
    material: Material | PiecewiseMaterial | None = None,
    mass_ratio: float = 0.05,
    force: float = 0.01,
    forcing_ratio: float = 1.0,
    b: float = 0.0,
    T: float = 12.0,
    mesh=None,
    base: str = "left",
    tip: str = "right",
    axis: int = 0,
    direction: int | None = None,
) -> TMDExample:
    """A plane-stress strip [0, length] x [0, height] (n cells across, round(n length/height)
    along; default material E = 10^4, nu = 0, rho = 1) whose ``left`` end is tied to a support
    (:class:`~rothe.eld.components.MassSpringDamper`, mass m_b = the strip's mass, springs
    k_b = (m_b + strip) (4 w_c)^2 in x and y: a stiff support, w_c the lowest frequency of the
    discrete strip clamped at that end, :func:`_clamped_frequency`, defined for any material;
    until issue 19's materials it was the Euler-Bernoulli w_EB, 0.6 % above w_c for the default
    strip) pushed by f(t) = force sin(W t) e_y, and whose ``right`` end is a rigid plate (mass
    0.05 of the strip's, inertia m_p height^2/12; :class:`PlateAbsorber`). The strip's mass is
    sum_c rho_c |c| (any material).
    The system starts at rest; Rayleigh damping b K on the strip.

    ``with_tmd`` carries on the plate an absorber of mass ``mass_ratio`` m_1 tuned by Den
    Hartog to the first bending mode (w_1, m_1 of the system without it: the discrete coupled
    modes); W = ``forcing_ratio`` w_1 (default: at that resonance).

    Parameters
    ----------
    n, degree : int
    length, height : float
    material : Material or PiecewiseMaterial, optional
        A 2D material (default E = 10^4, nu = 0, rho = 1, plane stress), or several on the
        mesh's regions: the support, the plate and the absorber are sized by the body as
        built (its mass, w_c, the discrete modes), so only ``beam_frequency``, a comparison,
        is NaN then.
    mass_ratio, force, forcing_ratio, b, T : float
    mesh : skfem.MeshTri or skfem.MeshTet, optional
        A 2D or 3D body along ``axis`` with the named parts ``base`` (tied to the support) and
        ``tip`` (the plate, centred at the part's centroid, J_p by the part's length; in 3D
        J_p = m_p |tip| / 12 about every axis, the square plate's about its sides) instead of
        the strip (:func:`_strip`: L its extent along the axis, H = volume / L; a gmsh mesh of
        the strip with these parts gives the strip's run to round-off). In 3D the first bending
        mode along ``direction`` is taken in the span of the modes within 1e-3 of its
        frequency (a square section's two bending modes are one eigenvalue): the combination
        with the largest a_direction, its w_1^2 the Rayleigh quotient; ``beam_frequency`` is
        NaN (``prediction``: :data:`BEAM_THEORY_2D`).
    base, tip : str
        The boundary parts (default ``left``, ``right``: the strip's).
    axis : int
        The body's long axis, 0 (x, default), 1 (y, a mesh only) or 2 (z, a 3D mesh).
    direction : int, optional
        The transverse axis the support is pushed along and the absorber swings along: in 2D
        the other axis (the default), in 3D any but ``axis`` (default the next one,
        (axis + 1) mod 3).

    Returns
    -------
    TMDExample
    """
    refine = ("n", n) if mesh is None else ("mesh", described("the mesh"))
    n, length, height, material, modulus, mesh, center, tip_size = _strip(
        n, degree, length, height, material, 1e4, mesh, base, tip, axis
    )
    dim = meshes.mesh_dim(mesh)
    if direction is None:
        direction = 1 - axis if dim == 2 else (axis + 1) % 3
    if direction not in range(dim) or direction == axis:
        raise fail(
            "direction",
            direction,
            f"must be an axis 0..{dim - 1} of the {dim}D body other than axis {axis} (the "
            "absorber swings across the body)",
        )
    across = direction
    mu = check_positive("mass_ratio", mass_ratio)
    force = check_real("force", force)
    ratio = check_positive("forcing_ratio", forcing_ratio)
    b = check_nonnegative("b", b)
    strip = _body_mass(mesh, material)
    several = isinstance(material, PiecewiseMaterial)
    w_eb = (
        math.nan
        if several or dim == 3
        else beam_frequencies(length, modulus * height**3 / 12, material.rho * height, count=1)[0]
    )
    w_c = _clamped_frequency(mesh, material, degree, base)
    base_mass = strip
    base_k = (base_mass + strip) * (4.0 * w_c) ** 2
    plate_mass = 0.05 * strip
    # (3D: tip_size is the plate's area, h^2 of a square plate of side h)
    plate_J = plate_mass * (tip_size**2 if dim == 2 else tip_size) / 12
    damping = RayleighDamping(0.0, b) if b > 0 else None

    def build(absorber=None, forcing=0.0):
        def push(t):
            f = np.zeros(dim)
            f[across] = force * math.sin(forcing * t)
            return f

        support = MassSpringDamper(base_mass, base_k, dim=dim, load=push, name="base")
        k, c = (0.0, 0.0) if absorber is None else absorber[1:]
        plate = PlateAbsorber(
            plate_mass,
            plate_J,
            center,
            absorber_mass=0.0 if absorber is None else absorber[0],
            stiffness=k,
            damping=c,
            name="tip",
            axis=across,
        )
        return CoupledProblem.from_body(
            mesh,
            material,
            degree=degree,
            damping=damping,
            components=[support, plate],
            couplings=[Translation(base, support), plate_coupling(tip, plate)],
            T=T,
            name="eld-tmd",
        )

    with warnings.catch_warnings():  # G = 0 on no prescribed part: nothing is differenced
        warnings.filterwarnings("ignore", message="G_d")
        bare = build()
        w, _, Q = coupled_modes(bare, 8)
        ay = bare.offsets["tip"] + across  # (the deflection across the body, a_y along x)
        ax = bare.offsets["tip"] + axis
        if dim == 2:
            bending = np.flatnonzero(np.abs(Q[ay]) > 10 * np.abs(Q[ax]))
            if bending.size == 0:
                raise fail(*refine, "gives no bending mode among the first 8: refine")
            k1 = int(bending[0])
            w1 = float(w[k1])
            m1 = 1.0 / float(Q[ay, k1]) ** 2  # (mass-normalized modes: the deflection a_y = 1)
        else:
            w1, m1 = _bending_mode_3d(w, Q, bare.offsets["tip"], axis, across, refine)
        k_a, c_a = den_hartog(m1, w1, mu)
        forcing = ratio * w1
        return TMDExample(
            with_tmd=build((mu * m1, k_a, c_a), forcing),
            without_tmd=build(None, forcing),
            frequency=w1,
            modal_mass=m1,
            stiffness=k_a,
            damping=c_a,
            forcing=forcing,
            beam_frequency=float(w_eb),
            length=length,
            height=height,
            clamped_frequency=w_c,
            prediction=SEVERAL_MATERIALS if several else (BEAM_THEORY_2D if dim == 3 else None),
            direction=across,
        )


# -- the bar whose clamped end is moved by feedback on the tip velocity (issue 19) --------------


@dataclass
class ControlExample:
    """The bar of :func:`control_problem`, with and without the feedback, started in its first
    mode, and the predicted decay rates.

    Attributes
    ----------
    controlled, uncontrolled : CoupledProblem
    roots : ndarray
        s = -alpha + i w of the first two modes of the controlled bar (with the Kelvin-Voigt
        damping b): :func:`rothe.eld.frequencies.controlled_bar_roots` (its Newton from the
        undamped frequency is not reliable for the third with the default b: at w_3 ~ 48 the
        material damping b w^2/2 ~ 6 is no perturbation).
    roots_uncontrolled : ndarray
        The same without the feedback.
    roots_undamped : ndarray
        The controlled bar without material damping: the feedback's own effect per mode
        (Re s > 0: a mode destabilized by the non-collocated feedback, the spillover).
    modal_rate : float
        The first mode's decay rate to first order in the gain:
        :func:`rothe.eld.frequencies.first_mode_decay_rate` plus the uncontrolled rate.
    frequency : float
        w_1 of the discrete uncontrolled system (the mode the runs start in).
    length, height : float
        The strip's L and H (of a mesh: its extent in x and area / L).
    prediction : str or None
        Why ``roots``, ``roots_uncontrolled``, ``roots_undamped`` and ``modal_rate`` are NaN
        (:data:`SEVERAL_MATERIALS`: they are the uniform bar's), None where they are defined.
    roots_discrete, roots_discrete_uncontrolled : ndarray
        The roots of the first two axial modes of the semi-discrete closed loop, with and
        without the feedback (:func:`rothe.eld.coupled_step.closed_loop_roots`: the
        eigenvalues of the body on the constraint, the base and the controller's state near
        i w_k of the discrete uncontrolled modes): defined for any material and mesh; the rate
        a run measures as tau -> 0. NaN for a second axial mode not among the first 8.
    """

    controlled: CoupledProblem
    uncontrolled: CoupledProblem
    roots: np.ndarray
    roots_uncontrolled: np.ndarray
    roots_undamped: np.ndarray
    modal_rate: float
    frequency: float
    length: float = math.nan
    height: float = math.nan
    prediction: str | None = None
    roots_discrete: np.ndarray = field(default_factory=lambda: np.full(2, complex(math.nan)))
    roots_discrete_uncontrolled: np.ndarray = field(
        default_factory=lambda: np.full(2, complex(math.nan))
    )


def control_problem(
    n: int = 2,
    degree: int = 2,
    *,
    length: float = 1.0,
    height: float = 0.25,
    material: Material | PiecewiseMaterial | None = None,
    base_mass: float = 1.0,
    base_stiffness: float = 50.0,
    gain: float = 1.0,
    kd: float = 0.0,
    filter_time: float = 0.02,
    b: float = 0.005,
    amplitude: float = 0.01,
    T: float = 6.0,
    mesh=None,
    base: str = "left",
    tip: str = "right",
    axis: int = 0,
) -> ControlExample:
    """A plane-stress strip [0, length] x [0, height] (default E = 100, nu = 0, rho = 1: the
    axial motion is the 1D bar's) whose ``left`` end is held by a base (mass ``base_mass``,
    spring ``base_stiffness`` along x, 10^4 across) pushed along x by a PD law on the tip's
    axial velocity v_L at (length, height/2) (:meth:`rothe.eld.control.LinearController.pd`):

        f = -(k_p v_L + k_d v_L'),  v_L' filtered by (1 + T_f s)^-1,
        i.e. f = -H(s) u_L with H(s) = s (k_p + k_d s/(1 + T_f s));

    the tip is free, Rayleigh damping b K on the strip (Kelvin-Voigt: the modulus E (1 + b s)).
    Both runs start at rest in the first axial mode of the discrete uncontrolled system, the
    base displaced by ``amplitude``. The feedback damps that mode at the rate -Re s_1 of the
    characteristic equation (``roots``); modes whose base and tip move in antiphase are pushed
    the other way (``roots_undamped``), held by b.

    Parameters
    ----------
    n, degree : int
    length, height : float
    material : Material or PiecewiseMaterial, optional
        Several materials on the mesh's regions: the runs, the discrete frequency and the
        discrete closed loop's roots (``roots_discrete``) as for one, the uniform bar's
        predicted roots and rates NaN, ``prediction`` says why.
    base_mass, base_stiffness, gain, kd, filter_time, b, amplitude, T : float
        m_b, k_b, k_p, k_d, T_f (used with k_d > 0), b, the initial amplitude and T.
    mesh : skfem.MeshTri or skfem.MeshTet, optional
        A 2D or 3D body along ``axis`` with the named parts ``base`` (held by the base) and
        ``tip`` (the sensor at its centroid) instead of the strip (:func:`_strip`: L its
        extent along the axis, H = volume / L in the predicted roots: in 3D the section's
        area A, the 1D bar's roots with the axial modulus E).
    base, tip : str
        The boundary parts (default ``left``, ``right``: the strip's).
    axis : int
        The bar's axis, 0 (x, default), 1 (y, a mesh only) or 2 (z, a 3D mesh): the base's
        spring k_b, the push and the fed-back velocity along it (10^4 across, every other
        axis).

    Returns
    -------
    ControlExample
    """
    refine = ("n", n) if mesh is None else ("mesh", described("the mesh"))
    n, length, height, material, modulus, mesh, center, _ = _strip(
        n, degree, length, height, material, 100.0, mesh, base, tip, axis
    )
    try:  # the sensor of v_L sits at the tip part's centroid
        locate(mesh, center)
    except RotheInputError:
        where = ", ".join(f"{v:.4g}" for v in center)
        raise fail(
            "tip",
            tip,
            f"has its centroid ({where}) outside the body, where the sensor of v_L would sit; "
            "must be a part whose centroid lies in the body (e.g. a straight end)",
        ) from None
    mb = check_positive("base_mass", base_mass)
    kb = check_nonnegative("base_stiffness", base_stiffness)
    dim = meshes.mesh_dim(mesh)
    springs = [1e4] * dim  # (k_b along the bar, stiff across)
    springs[axis] = kb
    kp = check_real("gain", gain)
    kd = check_nonnegative("kd", kd)
    b = check_nonnegative("b", b)
    amplitude = check_positive("amplitude", amplitude)
    rho = material.rho
    damping = RayleighDamping(0.0, b) if b > 0 else None
    Tf = check_positive("filter_time", filter_time) if kd > 0 else None

    def build(feedback: bool, q0=None, u0=None):
        support = MassSpringDamper(mb, springs, dim=dim, q0=q0, name="base")
        sensor = PointSensor(center, "velocity", axes=[axis])
        along = np.eye(dim)[:, [axis]].tolist()  # (the push e_axis: a column)
        ctrls = []
        if feedback:
            ctrls = [LinearController.pd(kp, kd, sensor, support, filter_time=Tf, directions=along)]
        return CoupledProblem.from_body(
            mesh,
            material,
            degree=degree,
            damping=damping,
            components=[support],
            couplings=[Translation(base, support)],
            controllers=ctrls,
            u0=u0,
            T=T,
            name="eld-control",
        )

    with warnings.catch_warnings():  # no prescribed part: nothing is differenced
        warnings.filterwarnings("ignore", message="G_d")
        w, U, Q = coupled_modes(build(False), 8)
        across = np.delete(np.abs(Q[:dim]), axis, axis=0).max(axis=0)  # (the base's q)
        axial = np.flatnonzero(np.abs(Q[axis]) > 10 * across)
        if axial.size == 0:
            raise fail(*refine, "gives no axial mode among the first 8: refine")
        k = int(axial[0])
        scale = amplitude / abs(Q[axis, k])
        q0, u0 = Q[:, k] * scale, U[:, k] * scale
        controlled, uncontrolled = build(True, q0, u0), build(False, q0, u0)
        # the discrete closed loop's roots continuing the first two axial modes: any material
        follow = axial[:2]
        discrete = np.full(2, complex(math.nan, math.nan))
        discrete_free = discrete.copy()
        discrete[: follow.size] = closed_loop_roots(
            controlled, w[follow], U[:, follow], Q[:, follow]
        )
        discrete_free[: follow.size] = closed_loop_roots(
            uncontrolled, w[follow], U[:, follow], Q[:, follow]
        )

    def H(s):
        return s * (kp + (kd * s / (1.0 + Tf * s) if kd > 0 else 0.0))

    if isinstance(material, PiecewiseMaterial):  # (no one E and rho: no uniform bar)
        unknown = np.full(2, complex(math.nan, math.nan))
        return ControlExample(
            controlled,
            uncontrolled,
            unknown,
            unknown.copy(),
            unknown.copy(),
            math.nan,
            float(w[k]),
            length,
            height,
            prediction=SEVERAL_MATERIALS,
            roots_discrete=discrete,
            roots_discrete_uncontrolled=discrete_free,
        )
    bar = dict(area=height, base_mass=mb, base_stiffness=kb)
    roots = controlled_bar_roots(length, modulus, rho, H=H, kelvin_voigt=b, count=2, **bar)
    free = controlled_bar_roots(length, modulus, rho, kelvin_voigt=b, count=2, **bar)
    undamped = controlled_bar_roots(length, modulus, rho, H=H, count=2, **bar)
    modal = first_mode_decay_rate(length, modulus, rho, H=H, **bar) - free[0].real
    return ControlExample(
        controlled,
        uncontrolled,
        roots,
        free,
        undamped,
        modal,
        float(w[k]),
        length,
        height,
        roots_discrete=discrete,
        roots_discrete_uncontrolled=discrete_free,
    )
