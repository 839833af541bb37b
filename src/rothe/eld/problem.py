"""An elastodynamics problem as the operator DAE (2.7): data, operators and validation.

    rho u'' + D u' + K u + B* lambda = F   in V*,      B u = G   in Q*,      u(0) = g, u'(0) = h.

:class:`ELDProblem` collects the mesh, the material, the damping, the Dirichlet data G(t) on named
boundary parts (enforced weakly through the trace B and a multiplier, see
:mod:`rothe.eld.constraint`), the Neumann tractions on other named parts, the body force and the
initial data. It assembles M (density 1), K and the damping operator once, and evaluates the
data at a given time:

- ``load(t)``: F(t) = int f(t) . phi dx + sum_parts int_P g_P(t) . phi ds  (a dof vector);
- ``G(t)``, ``G_dot(t)``, ``G_ddot(t)``: the nodal values of G and its derivatives on the
  constrained dofs (B u = G means S u = G(t) there).

Callables and their shapes (x holds points with the coordinate axis first):

- Dirichlet ``G(t, x)`` with x (d, k) returns (d, k) (a (d,) constant broadcasts);
  pass a :class:`DirichletData` to give G_dot and G_ddot as well. Without them the library
  differentiates G by central differences and states the estimated accuracy (``derivative_info``
  and a warning).
- traction ``g(t, x, n)`` with points x and outward unit normals n, both (d, nf, nq);
- body force ``f(t, x)`` with x (d, ne, nq);
- interface load ``h(t, x, n, k0, k1)`` (several materials) on the interior facets whose two
  cells have different materials: x and n (d, nf, nq), n the unit normal pointing out of side 0
  (the cell ``mesh.f2t[0]``), k0, k1 (nf, 1) the materials of the two sides as indices into
  ``PiecewiseMaterial.names``; F gets sum_facets int_F h . phi ds (e.g. the jump of the traction
  (sigma_0 - sigma_1) n_0 that a manufactured solution leaves there);
- ``u0``, ``v0``: callables x -> (d, k), dof vectors, or None (zero).

Several materials: a body force or traction wrapped in :class:`CellwiseLoad` is called with the
material index k of the cells as well, ``f(t, x, k)`` with k (ne, 1) per cell and
``g(t, x, n, k)`` with k (nf, 1) of the cell next to each facet (indices into
``PiecewiseMaterial.names``, as k0, k1 of the interface load). The problem takes k from its own
mesh, so such data go to another mesh (:meth:`ELDProblem.on_mesh`, space adaptivity) where a
closure over one mesh's cells could not.

Loads are integrated by quadrature of degree ``load_quadrature`` (default 2p, p the element
degree: exact for loads of degree p against the basis) over the cells (body force) and the
facets of the traction parts.
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import RotheInputError, check_int, check_positive, described, fail
from ..fem.elasticity import VectorSpace
from ..io.checkpoint import digest
from .constraint import DirichletConstraint
from .damping import Damping, NoDamping
from .materials import Material, PiecewiseMaterial

#: relative tolerance of the consistency G(0) = u0 on Gamma_D (Remark 2.2)
CONSISTENCY_TOL = 1e-8


class _CellQuadrature:
    """Cell quadrature of a chosen degree for the body force (when it differs from 2p)."""

    def __init__(self, space, intorder: int):
        # scikit-fem is imported where a basis is built (the start-up time of the command line)
        from skfem import Basis

        basis = Basis(space.mesh, space.element, intorder=intorder)
        self.values = np.stack([np.asarray(b[0]) for b in basis.basis])  # (nbf, ne, nq)
        self.dx = np.asarray(basis.dx)
        self.x = np.asarray(basis.global_coordinates())
        self.element_dofs = np.asarray(basis.element_dofs)
        self.n_scalar = space.n_scalar
        self.dim = space.dim

    def load(self, f: np.ndarray) -> np.ndarray:
        """int f . phi dx for f (d, ne, nq) at this rule's points."""
        local = np.einsum("ieq,eq,ceq->cie", self.values, self.dx, f)
        out = np.empty((self.n_scalar, self.dim))
        flat = self.element_dofs.ravel()
        for c in range(self.dim):
            out[:, c] = np.bincount(flat, weights=local[c].ravel(), minlength=self.n_scalar)
        return out.ravel()


class CellwiseLoad:
    """A body force f(t, x, k) or traction g(t, x, n, k) that needs the material index k of
    its cells (module docstring): :class:`ELDProblem` passes k of its own mesh.

    Parameters
    ----------
    f : callable
        (t, x, k) for a body force, (t, x, n, k) for a traction.
    """

    def __init__(self, f):
        if not callable(f):
            raise fail("f", type(f).__name__, "must be a callable (t, x, k) or (t, x, n, k)")
        self.f = f

    def __call__(self, *args):
        return self.f(*args)


@dataclass
class DirichletData:
    """G(t, x) on one boundary part, with its time derivatives if known.

    Parameters
    ----------
    G : callable(t, x) -> values
        The prescribed displacement on the part.
    G_dot, G_ddot : callable(t, x) -> values, optional
        Its first and second time derivatives (None: central differences of G, see
        :class:`ELDProblem`).
    """

    G: object
    G_dot: object = None
    G_ddot: object = None

    def __post_init__(self):
        for name in ("G", "G_dot", "G_ddot"):
            f = getattr(self, name)
            if f is not None and not callable(f):
                raise fail(name, type(f).__name__, "must be a callable (t, x) -> values")
        if self.G is None:
            raise fail("G", None, "must be a callable (t, x) -> values")


def _eps_step(order: int, scale: float) -> float:
    """Step for central differences of order 1 or 2 balancing truncation and round-off."""
    eps = np.finfo(float).eps
    return (eps ** (1.0 / 3.0) if order == 1 else eps**0.25) * scale


class ELDProblem:
    """Elastodynamics with Dirichlet data by multipliers (see the module docstring).

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        With named boundary parts (``rothe.fem.mesh``: ``unit_square(n, named=True)``, ``box``,
        ``tag_box_faces``, ``load_mesh``).
    material : Material or PiecewiseMaterial
        One material, or several on regions of the mesh (subdomains or centroid predicates).
    degree : {1, 2}
        Vector P1 or P2 elements.
    damping : Damping, optional
        Default: none.
    dirichlet : dict
        part -> callable G(t, x) or DirichletData. Where two parts share nodes, the part listed
        last sets their values.
    traction : dict, optional
        part -> callable g(t, x, n), or a :class:`CellwiseLoad` g(t, x, n, k).
    body_force : callable f(t, x), or a :class:`CellwiseLoad` f(t, x, k), optional
    interface_load : callable h(t, x, n, k0, k1), optional
        A load on the facets between two materials of a PiecewiseMaterial (module docstring).
    u0, v0 : callable, dof vector or None
        Initial displacement and velocity (None: zero); u0 must match G(0) on the Dirichlet
        parts (Remark 2.2, checked before the first step).
    T : float
        End time.
    name : str
        The problem's name in outputs.
    load_quadrature : int, optional
        Degree of the quadrature rule for body force and tractions (default 2p).
    element_cache : bool or tuple, optional
        Incremental rebuilds (space adaptivity, :meth:`on_mesh`): True keeps the element
        matrices of K (``space.element_stiffness``); (matrices, source) also takes those of the
        cells with ``source[c] >= 0`` from ``matrices[source[c]]`` (another mesh's, cells that
        did not change) instead of computing them (:meth:`VectorSpace.stiffness_blocks`: K is
        the same bit for bit).
    """

    def __init__(
        self,
        mesh,
        material: Material,
        *,
        degree: int = 1,
        damping: Damping | None = None,
        dirichlet: dict,
        traction: dict | None = None,
        body_force=None,
        interface_load=None,
        u0=None,
        v0=None,
        T: float = 1.0,
        name: str = "eld",
        load_quadrature: int | None = None,
        element_cache=False,
    ):
        self.name = name
        if not (
            isinstance(element_cache, bool)
            or (isinstance(element_cache, tuple) and len(element_cache) == 2)
        ):
            raise fail(
                "element_cache",
                described(type(element_cache).__name__),
                "must be True, False or (element matrices, source cells)",
            )
        # what on_mesh needs to build the same problem on another mesh (space adaptivity)
        self._data = dict(
            material=material,
            degree=degree,
            damping=damping,
            dirichlet=dirichlet,
            traction=traction,
            body_force=body_force,
            u0=u0,
            v0=v0,
            T=T,
            name=name,
            load_quadrature=load_quadrature,
        )
        if interface_load is not None:  # (only then: the definition of the others unchanged)
            self._data["interface_load"] = interface_load
        self.space = VectorSpace(mesh, degree)
        if not isinstance(material, Material | PiecewiseMaterial):
            raise fail(
                "material",
                type(material).__name__,
                "must be a rothe.eld.Material or PiecewiseMaterial",
            )
        if material.dim != self.space.dim:
            raise fail(
                "material.dim", material.dim, f"must equal the mesh dimension {self.space.dim}"
            )
        self.material = material
        self.damping = NoDamping() if damping is None else damping
        if not isinstance(self.damping, Damping):
            raise fail("damping", type(self.damping).__name__, "must be a rothe.eld damping object")
        self.T = check_positive("T", T)
        if not isinstance(dirichlet, dict) or not dirichlet:
            raise fail("dirichlet", dirichlet, "must map at least one boundary part to its data G")
        traction = dict(traction or {})
        both = sorted(set(dirichlet) & set(traction))
        if both:
            raise fail(
                "traction", both[0], "is also a Dirichlet part; a part is either held or loaded"
            )
        self.dirichlet = {
            p: g if isinstance(g, DirichletData) else DirichletData(g) for p, g in dirichlet.items()
        }
        self.constraint = DirichletConstraint(self.space, tuple(self.dirichlet), "dirichlet")
        default_q = 2 * self.space.degree
        if load_quadrature is None:
            load_quadrature = default_q
        self.load_quadrature = check_int("load_quadrature", load_quadrature, minimum=1)
        if self.load_quadrature > 19:
            raise fail("load_quadrature", load_quadrature, "must be an integer in 1..19")
        self._traction = {}
        for part, g in traction.items():
            if not callable(g):
                raise fail(f"traction[{part!r}]", type(g).__name__, "must be a callable (t, x, n)")
            self._traction[part] = (
                g,
                self.space.facet_quadrature(
                    (part,), intorder=self.load_quadrature, name="traction"
                ),
            )
        if body_force is not None and not callable(body_force):
            raise fail("body_force", type(body_force).__name__, "must be a callable (t, x)")
        self.body_force = body_force
        self._cell_quadrature = (
            None
            if self.load_quadrature == default_q
            else _CellQuadrature(self.space, self.load_quadrature)
        )

        sp_ = self.space
        # BSR with d x d blocks (rothe.fem.elasticity.BlockMatrix): 30 % less memory than CSR
        if isinstance(material, PiecewiseMaterial):
            # per-cell data; M is weighted by rho_c/rho_ref so that material.rho * M is the
            # mass of the actual density (rothe.eld.materials)
            self.cell_material = material.on_mesh(mesh)
            self.K = sp_.stiffness(self.cell_material.lam, self.cell_material.mu, format="bsr")
            self.M = sp_.mass(self.cell_material.density_weight)
        else:
            self.cell_material = None
            keep = element_cache is not False
            reuse = element_cache if isinstance(element_cache, tuple) else None
            if reuse is not None and reuse[0] is None:
                reuse = None  # the other mesh kept none (a problem built without the cache)
            self.K = sp_.stiffness(
                material.lam_eff, material.mu, format="bsr", reuse=reuse, keep=keep
            )
            self.M = sp_.mass()
        self._interface = None
        cellwise = [
            name
            for name, g in [("body_force", body_force)]
            + [(f"traction[{p!r}]", g) for p, g in traction.items()]
            if isinstance(g, CellwiseLoad)
        ]
        if cellwise and self.cell_material is None:
            raise fail(
                cellwise[0],
                described(f"a CellwiseLoad with one material ({type(material).__name__})"),
                "needs a PiecewiseMaterial (k indexes its materials)",
            )
        # the material index of each cell, and of the cell next to each traction facet (in
        # the order of the part's facet quadrature: VectorSpace.facets sorts them)
        self._cell_index = None if self.cell_material is None else self.cell_material.names[:, None]
        f2t0 = np.asarray(mesh.f2t)[0]
        self._traction_index = {
            p: self._cell_index[f2t0[sp_.facets((p,), "traction")]]
            for p, g in traction.items()
            if isinstance(g, CellwiseLoad)
        }
        if interface_load is not None:
            if not callable(interface_load):
                raise fail(
                    "interface_load",
                    type(interface_load).__name__,
                    "must be a callable (t, x, n, k0, k1)",
                )
            if self.cell_material is None:
                raise fail(
                    "interface_load",
                    described(f"a load with one material ({type(material).__name__})"),
                    "needs a PiecewiseMaterial (it acts between two materials)",
                )
            self._interface = (interface_load, *self._interface_quadrature())
        self.damping_op = self.damping.operator(sp_, self.M, self.K)
        self.u0 = self._initial(u0, "u0")
        self.v0 = self._initial(v0, "v0")
        self._part_points = {
            p: sp_.doflocs[:, sp_.scalar_dofs_on((p,), "dirichlet")] for p in self.dirichlet
        }
        self.derivative_info = self._derivative_info()

    def _interface_quadrature(self):
        """The facets between cells of different materials: their quadrature of degree
        ``load_quadrature`` seen from side 0 (``mesh.f2t[0]``, whose outward normal n_0 it
        has) and the materials (k0, k1) of the two sides, (nf, 1) each. None if there are none."""
        f2t = np.asarray(self.space.mesh.f2t)
        names = self.cell_material.names
        interior = np.flatnonzero(f2t[1] >= 0)
        k0, k1 = names[f2t[0, interior]], names[f2t[1, interior]]
        between = k0 != k1
        facets = interior[between]
        if facets.size == 0:
            return None, None, None
        q = self.space.facet_quadrature_on(facets, self.load_quadrature)
        return q, k0[between][:, None], k1[between][:, None]

    def release_operators(self) -> None:
        """Drop K, M and the damping operator (a space-adaptive run, on a problem it made
        itself and has left: :meth:`rothe.eld.system.ELDSystem.release`); the space, the
        constraint, the material and the data stay. Nothing that needs the matrices works
        afterwards; :meth:`on_mesh` on the same mesh builds them again."""
        self.K = self.M = self.damping_op = None

    @property
    def definition(self) -> dict:
        """The problem's definition without the mesh: the keyword arguments it was built with
        (material, degree, damping, dirichlet, traction, body_force, u0, v0, T, name,
        load_quadrature), so that ``ELDProblem(mesh, **problem.definition)`` builds it on
        another mesh or only on a part of it (:mod:`rothe.eld.distributed`). A copy."""
        return dict(self._data)

    def on_mesh(self, mesh, source=None, *, keep: bool = False) -> ELDProblem:
        """The same problem (material, damping, data, T) on another mesh with the same named
        boundary parts (space adaptivity: :mod:`rothe.eld.adapt`).

        ``keep``: its element matrices of K are kept for the next mesh (about 7 KB per P2
        tetrahedron); ``source`` (n_cells of ``mesh``,): per new cell the cell of this
        problem's mesh it equals (-1: a new cell, from :class:`rothe.fem.adapt.MeshChange`'s
        ``unchanged`` and ``old_start``): those cells' element matrices are taken from this
        problem's kept ones (an incremental rebuild, bit for bit the full one; without kept
        ones or ``source``: all computed).

        Initial data given as callables are interpolated on the new mesh; given as dof
        vectors they cannot be, and the new problem gets u0 = G(0) on Gamma_D and 0 elsewhere,
        v0 = 0 (consistent, Remark 2.2). An adaptive run never starts from them: its state is
        transferred from the previous mesh."""
        data = dict(self._data)
        arrays = [k for k in ("u0", "v0") if data[k] is not None and not callable(data[k])]
        for k in arrays:
            data[k] = None
        with warnings.catch_warnings():  # the derivative notes were given for the first mesh
            warnings.simplefilter("ignore")
            cache = keep if source is None else (self.space.element_stiffness, source)
            new = ELDProblem(mesh, **data, element_cache=cache)
        if "u0" in arrays:
            c = new.constraint
            new.u0 = c.embed(new.G(0.0))
        new._data = dict(self._data)
        return new

    # -- initial data ---------------------------------------------------------------------------
    def _initial(self, value, name: str) -> np.ndarray:
        n = self.space.ndofs
        if value is None:
            return np.zeros(n)
        if callable(value):
            return self.space.interpolate(value)
        arr = np.asarray(value, dtype=float)
        if arr.shape != (n,):
            raise fail(
                name, f"an array of shape {arr.shape}", f"must be a callable or shape ({n},)"
            )
        if not np.all(np.isfinite(arr)):
            raise fail(name, "non-finite values", "must be finite")
        return arr.copy()

    def check_initial_consistency(self, tol: float = CONSISTENCY_TOL) -> float:
        """Remark 2.2: B g = G(0). Raises a one-line error if max|S u0 - G(0)| exceeds
        tol * max(1, max|G(0)|, max|u0|); returns the mismatch."""
        g0 = self.G(0.0)
        su0 = self.constraint.restrict(self.u0)
        err = float(np.max(np.abs(su0 - g0))) if g0.size else 0.0
        scale = max(1.0, float(np.max(np.abs(g0), initial=0.0)), float(np.max(np.abs(self.u0))))
        if not err <= tol * scale:
            raise RotheInputError(
                f"u0: got max|u0 - G(0)| = {err:.3g} on the Dirichlet parts "
                f"{', '.join(self.constraint.parts)}, must equal G(0) there within "
                f"{tol * scale:.3g} (consistent initial data, Remark 2.2)"
            )
        return err

    # -- data -----------------------------------------------------------------------------------
    def _eval_dirichlet(self, which: str, t: float) -> np.ndarray:
        c = self.constraint
        d = self.space.dim
        out = np.zeros((c.scalar_dofs.size, d))
        for part, data in self.dirichlet.items():
            f = getattr(data, which)
            x = self._part_points[part]
            vals = np.asarray(f(float(t), x), dtype=float)
            if vals.shape == (d,):
                vals = np.broadcast_to(vals[:, None], (d, x.shape[1]))
            if vals.shape != (d, x.shape[1]):
                raise fail(
                    f"dirichlet[{part!r}].{which}",
                    f"values of shape {vals.shape}",
                    f"must return shape ({d}, k) for points x of shape ({d}, k)",
                )
            out[c.part_positions[part]] = vals.T
        return out.ravel()

    def G(self, t: float) -> np.ndarray:
        """G(t): the nodal values of the Dirichlet data on the constrained dofs."""
        return self._eval_dirichlet("G", t)

    def G_dot(self, t: float) -> np.ndarray:
        """G_dot(t) on the constrained dofs (given, or central differences of G)."""
        if all(d.G_dot is not None for d in self.dirichlet.values()):
            return self._eval_dirichlet("G_dot", t)
        h = _eps_step(1, max(1.0, self.T))
        return (self.G(t + h) - self.G(t - h)) / (2 * h)

    def G_ddot(self, t: float) -> np.ndarray:
        """G_ddot(t) on the constrained dofs (given, or central differences)."""
        if all(d.G_ddot is not None for d in self.dirichlet.values()):
            return self._eval_dirichlet("G_ddot", t)
        if all(d.G_dot is not None for d in self.dirichlet.values()):
            h = _eps_step(1, max(1.0, self.T))
            plus, minus = self._eval_dirichlet("G_dot", t + h), self._eval_dirichlet("G_dot", t - h)
            return (plus - minus) / (2 * h)
        h = _eps_step(2, max(1.0, self.T))
        return (self.G(t + h) - 2 * self.G(t) + self.G(t - h)) / (h * h)

    def _derivative_info(self) -> dict:
        """How G_dot and G_ddot are obtained, with an error estimate when differenced.

        The estimate compares the difference quotient with step h and 2h at five times in [0, T]
        (both are O(h^2), so the difference over 3 estimates the error of the h quotient).
        """
        info = {}
        have_dot = all(d.G_dot is not None for d in self.dirichlet.values())
        have_ddot = all(d.G_ddot is not None for d in self.dirichlet.values())
        times = np.linspace(0.0, self.T, 5)
        scale = max(1.0, self.T)
        for which, given in (("G_dot", have_dot), ("G_ddot", have_ddot)):
            if given:
                info[which] = {"method": "given"}
                continue
            from_dot = which == "G_ddot" and have_dot
            f = (lambda t: self._eval_dirichlet("G_dot", t)) if from_dot else self.G
            order = 1 if (which == "G_dot" or from_dot) else 2
            h = _eps_step(order, scale)
            err, size = 0.0, 0.0
            # scale of the derivative: its own size, or that of G over the time scale if larger
            # (so that a derivative that vanishes does not make the relative error meaningless)
            g_scale = max(float(np.max(np.abs(f(t)), initial=0.0)) for t in times)
            for t in times:
                if order == 1:
                    a = (f(t + h) - f(t - h)) / (2 * h)
                    b = (f(t + 2 * h) - f(t - 2 * h)) / (4 * h)
                else:
                    a = (f(t + h) - 2 * f(t) + f(t - h)) / h**2
                    b = (f(t + 2 * h) - 2 * f(t) + f(t - 2 * h)) / (4 * h**2)
                err = max(err, float(np.max(np.abs(a - b), initial=0.0)) / 3)
                size = max(size, float(np.max(np.abs(a), initial=0.0)))
            method = "central differences of " + ("G_dot" if from_dot else "G")
            size = max(size, g_scale / max(self.T, 1e-300) ** order)
            info[which] = {
                "method": method,
                "h": h,
                "estimated_error": err,
                "estimated_relative_error": err / size if size > 0 else 0.0,
            }
            warnings.warn(
                f"{which} not given: {method} with h = {h:.2g}; estimated max error "
                f"{err:.2g} (relative {info[which]['estimated_relative_error']:.2g}) at t in "
                f"[0, {self.T:g}]",
                stacklevel=3,
            )
        return info

    def load(self, t: float) -> np.ndarray:
        """F(t): body force and tractions as a dof vector."""
        sp_ = self.space
        F = np.zeros(sp_.ndofs)
        if self.body_force is not None:
            q = self._cell_quadrature
            x = sp_.quad_points if q is None else q.x
            k = (self._cell_index,) if isinstance(self.body_force, CellwiseLoad) else ()
            f = np.broadcast_to(np.asarray(self.body_force(float(t), x, *k), dtype=float), x.shape)
            F += sp_.load_from_quad(f) if q is None else q.load(f)
        for part, (g, q) in self._traction.items():
            k = (self._traction_index[part],) if part in self._traction_index else ()
            vals = np.asarray(g(float(t), q.x, q.normals, *k), dtype=float)
            vals = np.broadcast_to(vals, q.x.shape)
            F += q.integrate_against_basis(vals, sp_.n_scalar).ravel()
        if self._interface is not None and self._interface[1] is not None:
            h, q, k0, k1 = self._interface
            vals = np.broadcast_to(
                np.asarray(h(float(t), q.x, q.normals, k0, k1), dtype=float), q.x.shape
            )
            F += q.integrate_against_basis(vals, sp_.n_scalar).ravel()
        return F

    @property
    def has_loads(self) -> bool:
        """Whether there is a body force or a traction."""
        return self.body_force is not None or bool(self._traction) or self._interface is not None

    # -- description ----------------------------------------------------------------------------
    def describe(self) -> dict:
        """The problem as in a trajectory's meta data (mesh, material, damping, parts, T)."""
        m = self.material
        return {
            "name": self.name,
            "dim": self.space.dim,
            "degree": self.space.degree,
            "ndofs": self.space.ndofs,
            "constrained_dofs": self.constraint.m,
            "cells": int(self.space.mesh.t.shape[1]),
            **m.describe(),
            "damping": self.damping.describe(),
            "dirichlet_parts": list(self.constraint.parts),
            "traction_parts": list(self._traction),
            **({"interface_load": True} if self._interface is not None else {}),
            "T": self.T,
            "load_quadrature": self.load_quadrature,
            "derivatives_of_G": self.derivative_info,
        }

    def fingerprint(self) -> dict:
        """Cheap hashes that identify the problem (what a checkpoint must match to be resumed):
        the class, the dofs, T, the assembled M, K and B, the initial data, the load and G at
        t = 0, T/3, T, the damping force at a fixed velocity (a user's damping function is not
        described) and the description. Each entry is compared separately on resume, so the
        refusal can say what differs (:mod:`rothe.io.checkpoint`)."""
        T = float(self.T)
        times = (0.0, T / 3.0, T)
        c = self.constraint
        return {
            "class": type(self).__name__,
            "ndofs": int(self.space.ndofs),
            "T": T,
            "M": digest(self.M),
            "K": digest(self.K),
            "B": digest(c.B, c.dofs),
            "initial": digest(self.u0, self.v0),
            "load": digest(*[self.load(t) for t in times]),
            "G": digest(*[self.G(t) for t in times]),
            "damping": digest(self.damping_op.apply(np.sin(np.arange(self.space.ndofs)))),
            "description": digest(
                np.frombuffer(
                    json.dumps(self.describe(), sort_keys=True, default=str).encode(), np.uint8
                )
            ),
        }

    def step_bound(self) -> float:
        """Lemma 3.2: the steps are uniquely solvable for tau < rho/d0 (inf if d0 = 0)."""
        d0 = self.damping.constants.d0
        return math.inf if d0 == 0 else self.material.rho / d0
