"""Couplings: boundary parts of an elastic body tied to components, B u = G(t, q) (issue 19).

A coupling ties a named boundary part P of the body to a component with coordinates q
(:mod:`rothe.eld.components`): every point x of P moves by G(t, q, x). With the trace B of
:mod:`rothe.eld.constraint` (B = M_G S, S u the values on the constrained dofs) the
constraint is imposed through its nodal values, S_P u = g_P(t, q) = G(t, q, x_P), and the
coupled system reads (``docs/coupling.md``, (C.1))

    rho M u'' + D(u') + K u + B^T lambda = F                        (C.1a)
    M_q q'' + f(t, q, q') - g_q^T M_G lambda = f_ext(t) + E w        (C.1b)
    B u = M_G g(t, q)                                                (C.1c)

**Sign (action = reaction).** The generalized force of the multiplier on the component is
+g_q^T M_G lambda = +(dG/dq)^T lambda (it appears as -(dG/dq)^T lambda on the left of (C.1b),
where the body has +B^T lambda). For any (du, dq) that keeps the constraint,
B du = M_G g_q dq, the virtual work of the two is lambda . (B du - M_G g_q dq) = 0, and the
power of the constraint forces is -lambda . M_G g_t (only explicit time dependence works).
For a rigid body the generalized force is the resultant force and moment (about x_ref) of the
traction lambda, i.e. minus the reaction the rigid body exerts on the body (tested).

Derivatives a step needs (regularized form, B u2 = G, B v2 = G', B w2 = G''):

    g'  = g_t + g_q q',
    g'' = g_tt + 2 g_tq q' + g_qq[q', q'] + g_q q''

(:meth:`Coupling.derivatives`); the ready-made couplings are linear in q and independent of t,
so g' = g_q q' and g'' = g_q q'' (no curvature terms), and a coupled step stays linear.

Ready-made couplings:

- :class:`Translation`: the part moves rigidly with (some of) the component's coordinates,
  G(q, x) = D q_sel (e.g. a point mass, the carrier of a tuned mass damper, a support moved by
  one actuator along a direction);
- :class:`RigidMotion`: the part moves with a :class:`~rothe.eld.components.RigidBody`,
  G(q, x) = a + theta x (x - x_ref);
- :class:`UserCoupling`: G, dG/dq and optionally the curvature and time derivatives as
  callables; the derivatives are compared with finite differences when built.

:class:`CoupledProblem` binds an :class:`~rothe.eld.problem.ELDProblem` (its prescribed
Dirichlet data, tractions, loads) to components and couplings (and controllers,
:mod:`rothe.eld.control`), validates them (a part that does not exist, a part that also
carries traction or prescribed data, a part sharing nodes with another constrained part, a
coupling to a component that is not in the system, initial data that violate the constraint),
and evaluates the data of the constraint on all constrained dofs: g, g', g'' and the coupling
matrix Gamma = g_q (constrained dofs x all coordinates).
"""

from __future__ import annotations

import json
import warnings
from abc import ABC, abstractmethod

import numpy as np
import scipy.sparse as sp

from ..errors import RotheInputError, check_int, described, fail
from ..io.checkpoint import digest
from .components import Component, RigidBody, check_jacobian, rigid_motion_matrix
from .constraint import NodalLifting
from .problem import DirichletData, ELDProblem

#: relative tolerance of the consistency of u0 with G(0, q0) on coupled parts (Remark 2.2)
CONSISTENCY_TOL = 1e-8


class Coupling(ABC):
    """B u = G(t, q) on the boundary part ``part``: the part's points x move by G(t, q, x).

    Subclasses define :meth:`values` and :meth:`jacobian` (and, if not linear and
    time-independent, :meth:`second_derivatives`). Arrays: points x (d, k); G (d, k);
    dG/dq (d, k, m) with m = component.size.
    """

    part: str
    component: Component

    def __init__(self, part: str, component: Component):
        if not isinstance(part, str) or not part:
            raise fail("part", part, "must name a boundary part of the mesh")
        if not isinstance(component, Component):
            raise fail(
                "component",
                type(component).__name__,
                "must be a rothe.eld component (PointMass, RigidBody, ...)",
            )
        self.part = part
        self.component = component

    #: True if G(t, q, x) = G_0(x) + (dG/dq)(x) q with dG/dq constant and no explicit t
    is_linear: bool = True

    @abstractmethod
    def values(self, t: float, q: np.ndarray, x: np.ndarray) -> np.ndarray:
        """G(t, q, x), shape (d, k)."""

    @abstractmethod
    def jacobian(self, t: float, q: np.ndarray, x: np.ndarray) -> np.ndarray:
        """dG/dq at (t, q, x), shape (d, k, m)."""

    def jacobian_matrix(self, t: float, q: np.ndarray, x: np.ndarray) -> sp.csr_matrix:
        """dG/dq at (t, q, x) as a sparse (d k, m) matrix, the rows point by point (row d j + i:
        component i at point j): what :meth:`CoupledProblem.gamma` assembles. By default the
        non-zeros of :meth:`jacobian`; a coupling whose dense (d, k, m) would be large (a glued
        body: m its unknowns) builds it sparse."""
        J = np.asarray(self.jacobian(t, q, x))
        d, k, m = J.shape
        return sp.csr_matrix(J.transpose(1, 0, 2).reshape(d * k, m))

    def second_derivatives(
        self, t: float, q: np.ndarray, p: np.ndarray, x: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(G_t, G_tt + 2 G_tq p + G_qq[p, p], nothing else) -- the terms of G' and G'' that
        are not g_q q' and g_q q'': (G_t, curvature), each (d, k). Zero for linear couplings."""
        z = np.zeros((x.shape[0], x.shape[1]))
        return z, z.copy(), z.copy()

    def derivatives(self, t, q, p, pdot, x):
        """(G, G', G'') at the points x, each (d, k) (module docstring):
        G' = G_t + G_q p, G'' = curvature + G_q pdot."""
        J = self.jacobian(t, q, x)
        G_t, curv, _ = self.second_derivatives(t, q, p, x)
        return (
            self.values(t, q, x),
            G_t + np.einsum("dkm,m->dk", J, p),
            curv + np.einsum("dkm,m->dk", J, pdot),
        )

    def on_mesh(self, mesh, degree: int) -> Coupling:
        """The coupling for the body on another mesh (space adaptivity,
        :meth:`CoupledProblem.on_mesh`): itself -- G(t, q, x) is evaluated at the new part's
        points; a coupling that holds mesh operators (the glue of two bodies) rebuilds them."""
        return self

    def describe(self) -> dict:
        """Type, part and component name, for summaries."""
        return {"type": type(self).__name__, "part": self.part, "component": self.component.name}


class Translation(Coupling):
    """The part moves rigidly with coordinates of the component: G(q, x) = D q_sel.

    Parameters
    ----------
    part : str
    component : Component
    coordinates : indices of q that move the part (default: the first d)
    directions : (d, len(coordinates)) matrix D (default: the identity, coordinate k moves
        the part along axis k); e.g. one actuator coordinate moving the part in y:
        ``coordinates=[0], directions=[[0], [1]]``
    """

    def __init__(self, part: str, component: Component, coordinates=None, directions=None):
        super().__init__(part, component)
        self._coords = (
            None
            if coordinates is None
            else [check_int("coordinates", c) for c in np.atleast_1d(coordinates)]
        )
        if self._coords is not None:
            for c in self._coords:
                if not 0 <= c < component.size:
                    raise fail(
                        "coordinates",
                        c,
                        f"must be an index of the component's {component.size} coordinates",
                    )
        self._directions = None if directions is None else np.asarray(directions, dtype=float)

    def _matrix(self, d: int) -> np.ndarray:
        """(d, m): G = P q."""
        m = self.component.size
        coords = list(range(d)) if self._coords is None else self._coords
        if self._coords is None and m < d:
            raise fail(
                "coordinates", None, f"must be given: the component has {m} < d = {d} coordinates"
            )
        D = np.eye(d) if self._directions is None else self._directions
        if D.shape != (d, len(coords)):
            raise fail(
                "directions",
                described(f"an array of shape {D.shape}"),
                f"must have shape ({d}, {len(coords)})",
            )
        P = np.zeros((d, m))
        P[:, coords] = D
        return P

    def values(self, t, q, x):
        """G(q, x) = D q_sel at every point x (the coupling protocol)."""
        return np.broadcast_to((self._matrix(x.shape[0]) @ q)[:, None], x.shape).copy()

    def jacobian(self, t, q, x):
        """The constant dG/dq, the selection D at every point (the coupling protocol)."""
        P = self._matrix(x.shape[0])
        return np.broadcast_to(P[:, None, :], (x.shape[0], x.shape[1], P.shape[1])).copy()


class RigidMotion(Coupling):
    """The part moves with a :class:`~rothe.eld.components.RigidBody` (linearized):
    G(q, x) = a + theta x (x - x_ref), q = (a, theta), x_ref the body's reference point."""

    def __init__(self, part: str, body: RigidBody):
        if not isinstance(body, RigidBody):
            raise fail("body", type(body).__name__, "must be a rothe.eld.RigidBody")
        super().__init__(part, body)

    def values(self, t, q, x):
        """G(q, x) = (dG/dq) q, the linearized rigid motion (the coupling protocol)."""
        return np.einsum("dkm,m->dk", self.jacobian(t, q, x), q)

    def jacobian(self, t, q, x):
        """The rigid-motion matrix at x about the body's reference point (the coupling protocol)."""
        body = self.component
        if x.shape[0] != body.dim:
            raise fail(
                "body",
                described(f"a {body.dim}D rigid body"),
                f"must have the mesh's dimension {x.shape[0]}",
            )
        return rigid_motion_matrix(body.dim, x, body.reference)


class UserCoupling(Coupling):
    """G(t, q, x) given by callables.

    Parameters
    ----------
    part, component
    G : callable (t, q, x) -> (d, k)
    G_q : callable (t, q, x) -> (d, k, m)
    G_t : callable (t, q, x) -> (d, k), optional (explicit time dependence)
    curvature : callable (t, q, p, x) -> (d, k), optional: G_tt + 2 G_tq p + G_qq[p, p]
    linear : declare G affine in q, G_q constant, no explicit t (the step stays linear)

    G_q is compared with finite differences of G in q (and G_t with those in t) at t = 0,
    q = q0 of the component and two random points, on the part's points, when the coupling is
    bound to a problem (:class:`CoupledProblem`); the curvature with finite differences of
    G_q along p.
    """

    def __init__(
        self,
        part: str,
        component: Component,
        G,
        G_q,
        *,
        G_t=None,
        curvature=None,
        linear: bool = False,
    ):
        super().__init__(part, component)
        for label, f in (("G", G), ("G_q", G_q), ("G_t", G_t), ("curvature", curvature)):
            if f is not None and not callable(f):
                raise fail(label, type(f).__name__, "must be a callable")
        if G is None or G_q is None:
            raise fail("G" if G is None else "G_q", None, "must be a callable (t, q, x)")
        self._G, self._Gq, self._Gt, self._curv = G, G_q, G_t, curvature
        self.is_linear = bool(linear)

    def values(self, t, q, x):
        """The user's G(t, q, x), as a float array (the coupling protocol)."""
        return np.asarray(self._G(float(t), q, x), dtype=float)

    def jacobian(self, t, q, x):
        """The user's dG/dq(t, q, x), as a float array (the coupling protocol)."""
        return np.asarray(self._Gq(float(t), q, x), dtype=float)

    def second_derivatives(self, t, q, p, x):
        """(G_t, curvature, zeros) from the user's callables, zero where not given."""
        z = np.zeros(x.shape)
        G_t = z if self._Gt is None else np.asarray(self._Gt(float(t), q, x), dtype=float)
        curv = z if self._curv is None else np.asarray(self._curv(float(t), q, p, x), dtype=float)
        return G_t, curv, z.copy()

    def check(self, x: np.ndarray) -> None:
        """Compare G_q, G_t and the curvature with finite differences at the points x."""
        comp = self.component
        q0 = comp.q0
        shape = (x.shape[0], x.shape[1])
        G0 = self.values(0.0, q0, x)
        if G0.shape != shape or not np.all(np.isfinite(G0)):
            raise fail(
                "G",
                described(f"values of shape {G0.shape}"),
                f"must return finite values of shape {shape} for points {x.shape}",
            )
        J0 = self.jacobian(0.0, q0, x)
        if J0.shape != shape + (comp.size,):
            raise fail(
                "G_q",
                described(f"an array of shape {J0.shape}"),
                f"must have shape {shape + (comp.size,)}",
            )
        check_jacobian(
            "G_q",
            lambda q: self.values(0.0, q, x).ravel(),
            lambda q: self.jacobian(0.0, q, x).reshape(-1, comp.size),
            q0,
            "G in q",
        )
        if self._Gt is not None:
            check_jacobian(
                "G_t",
                lambda t: self.values(t[0], q0, x).ravel(),
                lambda t: self._Gt(t[0], q0, x).reshape(-1, 1),
                np.zeros(1),
                "G in t",
            )
        if self._curv is not None and self._Gt is None:
            # curvature = G_qq[p, p]: the derivative of G_q p along p
            rng = np.random.default_rng(7)
            p = rng.standard_normal(comp.size)
            check_jacobian(
                "curvature",
                lambda s: np.einsum("dkm,m->dk", self.jacobian(0.0, q0 + s[0] * p, x), p).ravel(),
                lambda s: self._curv(0.0, q0 + s[0] * p, p, x).reshape(-1, 1),
                np.zeros(1),
                "G_q p along p",
            )


class _Placeholder(DirichletData):
    """Zero data for a coupled part inside the body problem's constraint (the coupling's
    values are added by :class:`CoupledProblem`)."""

    def __init__(self):
        def zero(t, x):
            return np.zeros_like(x)

        super().__init__(zero, zero, zero)


class CoupledProblem:
    """An elastic body coupled to components (and controllers): (C.1) of the module docstring.

    Parameters
    ----------
    problem : ELDProblem
        The body: mesh, material, damping, prescribed Dirichlet data (``dirichlet``, may be
        empty when couplings hold the body), tractions, body force, u0, v0, T.
    components : sequence of Component
    couplings : sequence of Coupling
    controllers : sequence of controllers (:mod:`rothe.eld.control`)

    Attributes
    ----------
    body : ELDProblem
        The body problem whose constraint covers the prescribed *and* the coupled parts (the
        coupled parts carry zero placeholder data there; :meth:`g` adds the couplings).
    constraint : DirichletConstraint
        ``body.constraint``: B = M_G S on all constrained dofs.
    size : int
        r, the number of component coordinates (all components, in the order given).
    offsets : dict component name -> first index of its coordinates in q.
    """

    def __init__(self, problem: ELDProblem, components, couplings, controllers=()):
        if not isinstance(problem, ELDProblem):
            raise fail("problem", type(problem).__name__, "must be a rothe.eld.ELDProblem")
        self._setup(
            problem.space.mesh, dict(problem._data), problem, components, couplings, controllers
        )

    @classmethod
    def from_body(
        cls, mesh, material, *, components, couplings, controllers=(), dirichlet=None, **body
    ) -> CoupledProblem:
        """Build the body and the system at once; unlike an ELDProblem the body may have no
        prescribed Dirichlet data (``dirichlet`` empty or None) when couplings hold it.
        ``body``: the other keyword arguments of :class:`~rothe.eld.problem.ELDProblem`."""
        allowed = {
            "degree",
            "damping",
            "traction",
            "body_force",
            "u0",
            "v0",
            "T",
            "name",
            "load_quadrature",
        }
        for key in body:
            if key not in allowed:
                raise fail(
                    key,
                    described("an unknown keyword"),
                    "must be one of " + ", ".join(sorted(allowed)),
                )
        data = dict(
            degree=1,
            damping=None,
            traction=None,
            body_force=None,
            u0=None,
            v0=None,
            T=1.0,
            name="eld",
            load_quadrature=None,
        )
        data.update(body, material=material, dirichlet=dict(dirichlet or {}))
        self = cls.__new__(cls)
        self._setup(mesh, data, None, components, couplings, controllers)
        return self

    def _setup(self, mesh, data, problem, components, couplings, controllers):
        # what on_mesh needs to build the same system on another mesh (space adaptivity): the
        # data before the coupled parts' placeholders are added, the problem they came from
        self._source = (dict(data, dirichlet=dict(data["dirichlet"])), problem)
        self.components = list(components)
        self.couplings = list(couplings)
        self.controllers = list(controllers)
        names = set()
        for k, c in enumerate(self.components):
            if not isinstance(c, Component):
                raise fail(f"components[{k}]", type(c).__name__, "must be a rothe.eld component")
            if c.name in names:
                raise fail(f"components[{k}].name", c.name, "must be unique in the system")
            names.add(c.name)
        self.offsets, off = {}, 0
        for c in self.components:
            self.offsets[c.name] = off
            off += c.size
        self.size = off
        known = set((mesh.boundaries or {}).keys())
        prescribed = dict(data["dirichlet"])
        traction = set(data["traction"] or {})
        seen = {}
        for k, cp in enumerate(self.couplings):
            label = f"couplings[{k}].part"
            if not isinstance(cp, Coupling):
                raise fail(f"couplings[{k}]", type(cp).__name__, "must be a rothe.eld Coupling")
            if cp.part not in known:
                allowed = ", ".join(sorted(known)) if known else "(the mesh has no named parts)"
                raise fail(label, cp.part, f"must be one of {allowed} (boundary parts of the mesh)")
            if cp.part in traction:
                raise fail(
                    label,
                    cp.part,
                    "also carries a traction; a coupled part is held by its component, not loaded",
                )
            if cp.part in prescribed:
                raise fail(
                    label,
                    cp.part,
                    "also carries prescribed Dirichlet data; a part is "
                    "either prescribed or coupled",
                )
            if cp.part in seen:
                raise fail(label, cp.part, f"is already coupled (couplings[{seen[cp.part]}])")
            seen[cp.part] = k
            if id(cp.component) not in {id(c) for c in self.components}:
                raise fail(
                    f"couplings[{k}].component",
                    cp.component.name,
                    "must be one of the system's components: "
                    + (", ".join(c.name for c in self.components) or "(none)"),
                )
        if not prescribed and not self.couplings:
            raise fail(
                "couplings",
                [],
                "must hold at least one part when the problem has no "
                "prescribed Dirichlet data (a free body: Sec. 2.2)",
            )
        data["dirichlet"] = {**prescribed, **{cp.part: _Placeholder() for cp in self.couplings}}
        if problem is not None and not self.couplings:
            self.body = problem
        else:
            self.body = _rebuild(mesh, problem, data)
        space = self.body.space
        # shared nodes between a coupled part and any other constrained part: the values there
        # would be set twice (by G(t, x) and by G(t, q), or by two components)
        dofs = {p: space.scalar_dofs_on((p,), "dirichlet") for p in data["dirichlet"]}
        for p, k in seen.items():
            for other, od in dofs.items():
                n = np.intersect1d(dofs[p], od).size if other != p else 0
                if n:
                    raise fail(
                        f"couplings[{k}].part",
                        p,
                        f"shares {n} node(s) with the constrained part {other!r}; "
                        "coupled parts must not touch other constrained parts",
                    )
        self.constraint = self.body.constraint
        c = self.constraint
        d = space.dim
        self._points, self._rows = {}, {}
        for cp in self.couplings:
            pos = c.part_positions[cp.part]
            self._points[cp.part] = space.doflocs[:, c.scalar_dofs[pos]]
            self._rows[cp.part] = d * pos[None, :] + np.arange(d)[:, None]  # (d, k)
            if isinstance(cp, UserCoupling):
                cp.check(self._points[cp.part])
            else:
                cp.jacobian(0.0, cp.component.q0, self._points[cp.part][:, :1])  # dims checked
        # the prescribed parts' data and points, for known_data (the coupled parts' placeholders
        # are zero: not evaluated)
        self._known = [
            (self.body.dirichlet[p], space.doflocs[:, c.scalar_dofs[pos]], pos)
            for p in prescribed
            for pos in (c.part_positions[p],)
        ]
        self._known_direct = all(
            dp.G_dot is not None and dp.G_ddot is not None for dp, _, _ in self._known
        )
        self._gamma_cache = None
        for k, ctrl in enumerate(self.controllers):
            ctrl.bind(self, f"controllers[{k}]")

    def on_mesh(self, mesh) -> CoupledProblem:
        """The same system (components, controllers, the body's material, damping, data, T) on
        another mesh of the body with the same named boundary parts (space adaptivity,
        :mod:`rothe.eld.coupled_adapt`): the body rebuilt (:meth:`ELDProblem.on_mesh`: initial
        data given as dof vectors are not carried over -- an adaptive run transfers its state
        instead), every coupling for the new mesh (:meth:`Coupling.on_mesh`), the controllers
        bound to the new body (their sensor rows). The components are the same objects: q does
        not live on the mesh."""
        data, problem = self._source
        data = dict(data)
        if problem is not None:
            problem = problem.on_mesh(mesh)
            data = dict(problem._data)
        else:
            for key in ("u0", "v0"):
                if data[key] is not None and not callable(data[key]):
                    data[key] = None
        couplings = [cp.on_mesh(mesh, data["degree"]) for cp in self.couplings]
        new = CoupledProblem.__new__(CoupledProblem)
        new._setup(mesh, data, problem, self.components, couplings, self.controllers)
        return new

    # -- coordinates ----------------------------------------------------------------------------
    def slice(self, component: Component) -> slice:
        """The slice of ``component``'s coordinates in the stacked vector."""
        o = self.offsets[component.name]
        return slice(o, o + component.size)

    @property
    def q0(self) -> np.ndarray:
        return np.concatenate([c.q0 for c in self.components]) if self.components else np.zeros(0)

    @property
    def p0(self) -> np.ndarray:
        return np.concatenate([c.p0 for c in self.components]) if self.components else np.zeros(0)

    @property
    def is_linear(self) -> bool:
        """Linear components, couplings and controllers: one bordered linear solve per step."""
        return (
            all(c.is_linear for c in self.components)
            and all(cp.is_linear for cp in self.couplings)
            and all(getattr(k, "is_linear", True) for k in self.controllers)
        )

    def mass(self):
        """blkdiag(M_q) over the components, (r, r): sparse if a component's mass is (glued
        bodies), else dense."""
        if any(sp.issparse(c.mass) for c in self.components):
            return sp.block_diag([c.mass for c in self.components], format="csr")
        M = np.zeros((self.size, self.size))
        for c in self.components:
            s = self.slice(c)
            M[s, s] = c.mass
        return M

    def force(self, t: float, q: np.ndarray, p: np.ndarray) -> np.ndarray:
        """f(t, q, p) of all components (r,)."""
        out = np.zeros(self.size)
        for c in self.components:
            s = self.slice(c)
            out[s] = c.force(t, q[s], p[s])
        return out

    def force_jacobians(self, t: float, q: np.ndarray, p: np.ndarray):
        """(df/dq, df/dp), each (r, r), block diagonal."""
        Fq, Fp = np.zeros((self.size, self.size)), np.zeros((self.size, self.size))
        for c in self.components:
            s = self.slice(c)
            Fq[s, s], Fp[s, s] = (
                J.toarray() if sp.issparse(J) else J for J in c.jacobians(t, q[s], p[s])
            )
        return Fq, Fp

    def load(self, t: float) -> np.ndarray:
        """f_ext(t) of all components (r,)."""
        out = np.zeros(self.size)
        for c in self.components:
            out[self.slice(c)] = c.load(t)
        return out

    # -- constraint data on all constrained dofs ------------------------------------------------
    def _coupled(self, which: str, t, q, p=None, pdot=None) -> np.ndarray:
        c = self.constraint
        out = np.zeros(c.m)
        for cp in self.couplings:
            s = self.slice(cp.component)
            x = self._points[cp.part]
            if which == "g":
                vals = cp.values(t, q[s], x)
            else:
                _, gd, gdd = cp.derivatives(t, q[s], p[s], pdot[s], x)
                vals = gd if which == "g_dot" else gdd
            out[self._rows[cp.part]] = vals
        return out

    def known_data(self, t: float, derivatives: bool = True) -> tuple:
        """(G(t), G_dot(t), G_ddot(t)) of the prescribed parts on all constrained dofs, zero on
        the coupled parts: the body's G, G_dot, G_ddot without evaluating the coupled parts'
        zero placeholders (the data of every step; the shapes were checked by the body's
        evaluation at t = 0). ``derivatives=False``: (G(t),)."""
        body = self.body
        if not self._known_direct:  # differenced derivatives: the body's own evaluation
            return (body.G(t), body.G_dot(t), body.G_ddot(t)) if derivatives else (body.G(t),)
        d, m = body.space.dim, self.constraint.m
        which = ("G", "G_dot", "G_ddot") if derivatives else ("G",)
        outs = [np.zeros((m // d, d)) for _ in which]
        t = float(t)
        for data, x, pos in self._known:
            for out, name in zip(outs, which, strict=True):
                out[pos] = np.asarray(getattr(data, name)(t, x), dtype=float).T
        return tuple(out.ravel() for out in outs)

    def g(self, t: float, q: np.ndarray) -> np.ndarray:
        """Nodal values of G on all constrained dofs: prescribed G(t, x) and coupled
        G(t, q, x) (m,)."""
        return self.body.G(t) + self._coupled("g", t, q)

    def g_dot(self, t: float, q: np.ndarray, p: np.ndarray) -> np.ndarray:
        """G' = G_t + G_q p (prescribed: the problem's G_dot)."""
        return self.body.G_dot(t) + self._coupled("g_dot", t, q, p, np.zeros_like(p))

    def g_ddot(self, t: float, q: np.ndarray, p: np.ndarray, pdot: np.ndarray) -> np.ndarray:
        """G'' = G_tt + 2 G_tq p + G_qq[p, p] + G_q pdot (prescribed: the problem's G_ddot)."""
        return self.body.G_ddot(t) + self._coupled("g_ddot", t, q, p, pdot)

    def gamma(self, t: float = 0.0, q: np.ndarray | None = None) -> sp.csr_matrix:
        """Gamma = dg/dq, (m, r) sparse: rows on the coupled dofs, assembled from every
        coupling's sparse :meth:`Coupling.jacobian_matrix` (no dense (d, k, m) for a glued body).
        Cached when every coupling is linear (then it does not depend on t, q)."""
        if self._gamma_cache is not None:
            return self._gamma_cache
        q = self.q0 if q is None else q
        rows, cols, vals = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)], [np.zeros(0)]
        for cp in self.couplings:
            s = self.slice(cp.component)
            J = cp.jacobian_matrix(t, q[s], self._points[cp.part]).tocoo()  # (d k, m_c)
            # local row d j + i -> the constrained row d pos_j + i (self._rows is (d, k))
            rows.append(self._rows[cp.part].T.ravel()[J.row])
            cols.append(J.col + s.start)
            vals.append(J.data)
        G = sp.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(self.constraint.m, self.size),
        )
        G.eliminate_zeros()
        if all(cp.is_linear for cp in self.couplings):
            self._gamma_cache = G
        return G

    def lifted_modes(self, lifting) -> sp.csr_matrix:
        """Phi = L Gamma (n, r) sparse: the body displacement of each unit coordinate through the
        right inverse L = B^- -- the step's border (``docs/coupling.md``). Nodal: Gamma's rows
        put on the constrained dofs (S^T Gamma); otherwise the lifting of Gamma's non-zero
        columns only (a glued body's coordinates off its interface move nothing of the base),
        so nothing n x r is built dense."""
        G = self.gamma()
        n, c = self.body.space.ndofs, self.constraint
        if isinstance(lifting, NodalLifting):
            G = G.tocoo()
            return sp.csr_matrix((G.data, (c.dofs[G.row], G.col)), shape=(n, self.size))
        G = G.tocsc()
        cols = np.flatnonzero(np.diff(G.indptr))
        if cols.size == 0:
            return sp.csr_matrix((n, self.size))
        lifted = np.column_stack(lifting.lift_many(list(G[:, cols].toarray().T)))  # (n, ncols)
        place = sp.csr_matrix(
            (np.ones(cols.size), (np.arange(cols.size), cols)), shape=(cols.size, self.size)
        )
        return (sp.csr_matrix(lifted) @ place).tocsr()

    # -- forces ---------------------------------------------------------------------------------
    def generalized_reaction(
        self, lam: np.ndarray, t: float = 0.0, q: np.ndarray | None = None
    ) -> np.ndarray:
        """Gamma^T M_G lambda (r,): the force of the multiplier *on* the components
        (+(dG/dq)^T lambda; it stands as -Gamma^T M_G lambda on the left of (C.1b))."""
        return self.gamma(t, q).T @ (self.constraint.boundary_mass @ np.asarray(lam))

    def body_reaction(self, lam: np.ndarray) -> np.ndarray:
        """B^T lambda (n,): the term on the left of (C.1a) (the force on the body is minus
        it)."""
        return self.constraint.B.T @ np.asarray(lam)

    # -- initial data ---------------------------------------------------------------------------
    def check_initial_consistency(self, tol: float = CONSISTENCY_TOL) -> float:
        """S u0 = g(0, q0) on every constrained part (Remark 2.2 with data that are unknowns);
        one-line error naming u0 and the part otherwise."""
        body, c = self.body, self.constraint
        g0 = self.g(0.0, self.q0)
        su0 = c.restrict(body.u0)
        scale = max(
            1.0, float(np.max(np.abs(g0), initial=0.0)), float(np.max(np.abs(body.u0), initial=0.0))
        )
        worst, where = 0.0, None
        for part in c.parts:
            rows = (
                self.body.space.dim * c.part_positions[part][:, None]
                + np.arange(self.body.space.dim)[None, :]
            ).ravel()
            err = float(np.max(np.abs(su0[rows] - g0[rows]), initial=0.0))
            if err > worst:
                worst, where = err, part
        if not worst <= tol * scale:
            raise RotheInputError(
                f"u0: got max|u0 - G(0, q0)| = {worst:.3g} on the part {where!r}, must equal "
                f"G(0, q0) there within {tol * scale:.3g} (consistent initial data, Remark 2.2)",
                "u0",
            )
        return worst

    def consistent_u0(self) -> np.ndarray:
        """u0 with its values on the constrained dofs replaced by g(0, q0)."""
        u = self.body.u0.copy()
        u[self.constraint.dofs] = self.g(0.0, self.q0)
        return u

    # -- energy ---------------------------------------------------------------------------------
    def component_energy(self, q: np.ndarray, p: np.ndarray) -> tuple[float, float | None]:
        """(kinetic, potential) of all components; potential None if a component has none."""
        kin, pot = 0.0, 0.0
        for c in self.components:
            s = self.slice(c)
            kin += c.kinetic_energy(p[s])
            v = c.potential(q[s])
            pot = None if (pot is None or v is None) else pot + v
        return kin, pot

    def fingerprint(self) -> dict:
        """Cheap hashes that identify the system (what a checkpoint of :func:`run_coupled` must
        match to be resumed, :mod:`rothe.io.checkpoint`): the body's own
        (:meth:`ELDProblem.fingerprint`) and, per entry so that a refusal says what differs,
        the components (M_q, the force at a fixed (t, q, p) -- a spring, a damper, a user's
        force --, the loads at 0, T/3, T, q0, p0), the couplings (Gamma at q0, the data g at
        T/3) and the controllers (their Jacobians at z0, z0, the sensor rows)."""
        T = float(self.body.T)
        r = self.size
        q = np.sin(np.arange(1, r + 1))
        p = np.cos(np.arange(1, r + 1))
        out = {f"body.{k}": v for k, v in self.body.fingerprint().items()}
        mass = self.mass()
        out["components"] = digest(
            mass if sp.issparse(mass) else np.asarray(mass),
            self.force(T / 3.0, q, p),
            *[self.load(t) for t in (0.0, T / 3.0, T)],
            self.q0,
            self.p0,
        )
        out["couplings"] = digest(self.gamma(), self.g(T / 3.0, q))
        parts = []
        for k in self.controllers:
            z0 = np.asarray(k.z0, float)
            parts += [z0, k.Y_u, k.Y_v, k.Y_lam]
            parts += [np.asarray(J, float) for J in k.jacobians(0.0, z0, np.ones(k.n_inputs))]
        out["controllers"] = digest(*parts) if parts else None
        out["system"] = digest(
            np.frombuffer(
                json.dumps(self.describe(), sort_keys=True, default=str).encode(), np.uint8
            )
        )
        return out

    def describe(self) -> dict:
        """Components, couplings, controllers and the number of coordinates, for summaries."""
        return {
            "components": [c.describe() for c in self.components],
            "couplings": [cp.describe() for cp in self.couplings],
            "controllers": [k.describe() for k in self.controllers],
            "coordinates": self.size,
        }


def _rebuild(mesh, problem: ELDProblem | None, data: dict) -> ELDProblem:
    """The body problem with the coupled parts added to its constraint (zero placeholder data).
    Rebuilt from an existing problem, its initial data are taken over as they are (dof vectors
    stay dof vectors)."""
    data = dict(data)
    if problem is None:
        return ELDProblem(mesh, **data)
    data["u0"], data["v0"] = None, None
    with warnings.catch_warnings():  # derivative notes were given for the original problem
        warnings.simplefilter("ignore")
        body = ELDProblem(mesh, **data)
    body.u0, body.v0 = problem.u0.copy(), problem.v0.copy()
    body._data = dict(problem._data, dirichlet=data["dirichlet"])
    return body
