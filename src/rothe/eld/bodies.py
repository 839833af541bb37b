"""Several elastic bodies glued along interfaces, stepped in time (issue 19, Sec. 2.2.3).

Each body has its own mesh, material (Lamé constants, density; per-cell materials too) and
element degree. A *base* body carries the prescribed Dirichlet data, tractions and loads of an
:class:`~rothe.eld.problem.ELDProblem`; every *attached* body k is glued to a boundary part
P_k of the base along its own part Q_k by :class:`~rothe.eld.interface.Interface`:

    B_1 u_1 - B_k u_k = 0 on Gamma_k,   i.e.  S_{P_k} u_1 = Pi_k S_{Q_k} u_k

(matching nodes: Pi_k a permutation; non-matching: the mortar projection onto the base's
trace space). The glued system is the multiplier form (C.1) of :mod:`rothe.eld.coupling`
with the attached body in the role of the *component* (the Interface's docstring): its
coordinates are its free dofs, q_k = u_k off its clamped parts,

    M_q = rho_k M_k,  K_q = K_k,  C_q = C_k (restricted to the free dofs),  f_ext = F_k(t),
    G(q_k) = Pi_k S_{Q_k} E_k q_k   (linear, no explicit t, no curvature),

so the multiplier lambda_k on Gamma_k (a traction density in the base's trace space) acts on
the base by +B_1^T lambda_k and on body k by -(Pi_k S_{Q_k} E_k)^T M_G lambda_k: action =
reaction (the resultants are -int lambda_k ds and +int lambda_k ds because Pi_k reproduces
constants; tested to round-off). The glue does no work (G has no explicit t: the power of the
constraint forces -lambda . M_G g_t vanishes), so the whole-system ledger of
:func:`~rothe.eld.coupled_run.run_coupled` -- base energy + every attached body's energy
(the components' kinetic 1/2 p.M_q p and potential 1/2 q.K_q q) against the work of the loads
of all bodies, damping and the scheme's numerical dissipation -- closes to round-off.

**Stepped by the coupled stepper, solved monolithically**: the glued step is the bordered
step of :mod:`rothe.eld.coupled_step` -- implicit Euler and BDF2, both forms (regularized:
B v_2 = G' = Pi S p, B w_2 = G'' = Pi S pdot expressed by the attached body's velocities and
accelerations; original), uniform and adaptive steps with the attached bodies' energies in the
error norm, the multiplier, the ledger, the constraint residual at every accepted step -- with
no new stepper. With many coordinates (an attached body's free dofs) and no controllers its
linear system is factored as ONE sparse matrix T^T blkdiag(A_1, J_k) T (the substitution
u_1 = P_I^T x_I + Phi q of the glue; J_k = kappa^2 rho_k M_k + kappa C_k + K_k), which with
the nodal lifting and matching meshes is the union mesh's step matrix (the rows of body 1's
interface nodes added to their partners'): one sparse LU per step size, one back-substitution
per step, the multiplier from the base's residual afterwards. That is why glued bodies with
matching meshes equal one body (tested) and why a glued step costs about the union body's
(docs/coupling.md, "Several bodies").

Attached bodies take no prescribed data other than clamped parts (u = 0: their dofs are left
out of q) and keep their meshes (their dofs are q; the base may adapt its mesh,
``run_bodies(..., fields=False, adapt=SpaceAdaptivity(...))``: the glue is rebuilt on every
mesh, :meth:`Glue.on_mesh`, :mod:`rothe.eld.coupled_adapt`).

**Chains** (and trees): body k may be glued to an attached body j < k instead of the base
(``(Body, part_j, body_part, j)``). Such a glue carries no multiplier: body j's dofs on the
interface are slaved to body k's trace (u_j|P = Pi S_Q u_k, body j side 1 as the base is) and
body k's coordinates join body j's component -- the substitution of
:meth:`Interface.substitution`, made inside :class:`ElasticComponent` (``children``): the
component of a body glued to the base is then the glued subtree, its M_q, K_q, C_q, f_ext the
glued ones (with matching meshes the union mesh's on the glued space). A chain base - 1 - 2
with matching meshes equals the union mesh run; a non-matching chain interface is glued by
the mortar Pi (tested against the same bodies glued as a star around body 1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ..errors import RotheInputError, described, fail
from ..fem.elasticity import VectorSpace
from ..fem.mesh import tag_box_faces
from .components import Component
from .coupled_run import CoupledResult, run_coupled
from .coupling import CoupledProblem, Coupling
from .interface import Interface
from .materials import PiecewiseMaterial
from .problem import DirichletData, ELDProblem


def _zero(t, x):
    return np.zeros_like(x)


_CLAMP = DirichletData(_zero, _zero, _zero)


@dataclass
class Body:
    """One elastic body of a glued system: the keywords of an
    :class:`~rothe.eld.problem.ELDProblem` without T.

    Parameters
    ----------
    mesh : skfem mesh with named boundary parts
    material : Material or PiecewiseMaterial
    degree : 1 or 2
    dirichlet : dict part -> G, optional
        Prescribed data (the base only).
    clamped : sequence of parts held at u = 0
    traction : dict part -> g(t, x, n), optional
    body_force : callable (t, x), optional
    damping : Damping, optional (linear: the coupled step's condition)
    u0, v0 : initial data (callables x -> (d, k), dof vectors, or None)
    name : str
    """

    mesh: object
    material: object
    degree: int = 1
    dirichlet: dict | None = None
    clamped: tuple = ()
    traction: dict | None = None
    body_force: object = None
    damping: object = None
    u0: object = None
    v0: object = None
    name: str = "body"


class ElasticComponent(Component):
    """An attached body as a linear component (module docstring): coordinates q = its free
    dofs (off the clamped parts), M_q = rho M, K_q = K, C_q = C restricted to them, load F(t).

    Built from an assembled ELDProblem (``problem``: its dirichlet parts are the clamped ones
    and the interface part, both only to fix the free dofs; ``clamped`` the former).

    **Chains** (``children``: pairs (Interface, ElasticComponent) of bodies glued to this one
    along this body's part ``interface.part1``): the children are eliminated by substitution,
    as the glue of :meth:`Interface.substitution` does. This body's dofs on a child's
    interface are slaved to the child's trace, u|P = Pi S_Q u_child (the same orientation as
    the base's glue: this body is side 1); the coordinates are this body's free dofs off those
    interfaces, then each child's coordinates. Every body b of the subtree has its map
    u_b = E_b q (:attr:`maps`) and the component's matrices are the glued ones,

        M_q = sum_b E_b^T rho_b M_b E_b,  K_q = sum_b E_b^T K_b E_b,  C_q likewise,
        f_ext(t) = sum_b E_b^T F_b(t),

    so a chain of bodies is one linear component of the base (with matching meshes: the union
    mesh's matrices on the glued space). Without children E_b is the selection of the free
    dofs and this is the component above, entry for entry."""

    is_linear = True

    def __init__(self, problem: ELDProblem, clamped, name: str, children=()):
        space = problem.space
        self.problem = problem
        self.name = str(name)
        held = (
            space.vector_dofs(space.scalar_dofs_on(tuple(clamped), f"{name}.clamped"))
            if clamped
            else np.zeros(0, dtype=np.int64)
        )
        self.free = np.setdiff1d(np.arange(space.ndofs), held)
        children = list(children)
        slaved = [space.vector_dofs(itf.dofs1) for itf, _ in children]
        for (itf, child), rows in zip(children, slaved, strict=True):
            clash = np.intersect1d(rows, held).size
            if clash:
                raise fail(
                    f"{child.name}.interface",
                    itf.part1,
                    f"shares {clash // space.dim} node(s) with a clamped part of {name!r}; "
                    "a glued part must not touch a clamped one",
                )
        every = np.concatenate(slaved) if slaved else np.zeros(0, dtype=np.int64)
        if np.unique(every).size != every.size:
            raise fail(
                f"{name}.interfaces",
                [itf.part1 for itf, _ in children],
                "must not share nodes: a node is glued to one body",
            )
        own = np.setdiff1d(self.free, every)
        sizes = [own.size] + [child.size for _, child in children]
        self.size = int(sum(sizes))
        starts = np.concatenate([[0], np.cumsum(sizes)])
        m = self.size
        # E: q -> u (n, m): the own coordinates, and each child's trace on its interface
        E = sp.csr_matrix((np.ones(own.size), (own, np.arange(own.size))), shape=(space.ndofs, m))
        #: (name, problem, E_b) of every body of the subtree, this one first
        self.maps = []
        for (itf, child), rows, start in zip(children, slaved, starts[1:-1], strict=True):
            place = sp.csr_matrix(
                (np.ones(child.size), (np.arange(child.size), start + np.arange(child.size))),
                shape=(child.size, m),
            )
            S2 = itf.space2.vector_dofs(itf.dofs2)
            trace = (itf.vector(itf.Pi) @ child.E[S2] @ place).tocoo()  # (rows, m)
            E = E + sp.csr_matrix((trace.data, (rows[trace.row], trace.col)), shape=E.shape)
            self.maps += [(b, prob, (Eb @ place).tocsr()) for b, prob, Eb in child.maps]
        self.E = E.tocsr()
        self.E.eliminate_zeros()
        self.maps.insert(0, (self.name, problem, self.E))
        self.children = children
        mass = stiffness = damping = None
        for _, prob, Eb in self.maps:
            if not prob.damping_op.is_linear:
                raise fail(
                    f"{prob.name}.damping",
                    prob.damping.describe().get("type", "nonlinear"),
                    "must be linear (an attached body is a linear component)",
                )
            rho = float(prob.material.rho)
            Mb = (Eb.T @ (rho * sp.csr_matrix(prob.M)) @ Eb).tocsr()
            Kb = (Eb.T @ sp.csr_matrix(prob.K) @ Eb).tocsr()
            mass = Mb if mass is None else mass + Mb
            stiffness = Kb if stiffness is None else stiffness + Kb
            C = prob.damping_op.linear
            if C is not None:
                Cb = (Eb.T @ sp.csr_matrix(C) @ Eb).tocsr()
                damping = Cb if damping is None else damping + Cb
        # sparse (FE matrices on the free dofs): the coupled step factors the glued system as
        # one sparse matrix (coupled_step.CoupledStepSystem.solve)
        self.mass, self.stiffness = mass.tocsr(), stiffness.tocsr()
        self._C = None if damping is None else damping.tocsr()
        self.damping = sp.csr_matrix(self.mass.shape) if self._C is None else self._C
        self.q0 = np.concatenate([problem.u0[own]] + [child.q0 for _, child in children])
        self.p0 = np.concatenate([problem.v0[own]] + [child.p0 for _, child in children])
        for (itf, child), rows in zip(children, slaved, strict=True):
            for label, given, q in (("u0", problem.u0, self.q0), ("v0", problem.v0, self.p0)):
                gap = np.abs(given[rows] - self.E[rows] @ q).max(initial=0.0)
                if gap > 1e-10 * max(1.0, np.abs(given).max(initial=0.0)):
                    raise fail(
                        f"{name}.{label}",
                        described(f"values off by {gap:.3g} on {itf.part1!r}"),
                        f"must equal those of the glued body {child.name!r} there",
                    )
        self.coordinates = tuple(f"u{k}" for k in own) + tuple(
            f"{child.name}.{c}" for _, child in children for c in child.coordinates
        )

    def force(self, t, q, p):
        """K_q q + C_q p."""
        return self.stiffness @ q + (0.0 if self._C is None else self._C @ p)

    def jacobians(self, t, q, p):
        """(K_q, C_q)."""
        return self.stiffness, self.damping

    def load(self, t):
        """The bodies' F(t) (tractions, body force) on the coordinates: sum_b E_b^T F_b(t)
        (without children: F(t) on the free dofs)."""
        out = np.zeros(self.size)
        for _, prob, Eb in self.maps:
            out += Eb.T @ prob.load(t)
        return out

    def potential(self, q):
        """1/2 q . K_q q."""
        return 0.5 * float(q @ (self.stiffness @ q))

    def kinetic_energy(self, p):
        """1/2 p . M_q p."""
        return 0.5 * float(p @ (self.mass @ p))

    def field(self, q: np.ndarray) -> np.ndarray:
        """The body's dof vector u = E q (zero on the clamped parts); q may be (..., m)."""
        q = np.asarray(q)
        return (self.E @ q.T).T if q.ndim > 1 else self.E @ q

    def describe(self) -> dict:
        return {"type": "ElasticBody", "name": self.name, "size": int(self.size)}


class Glue(Coupling):
    """B u = G(q) on the base's part of an interface: G(q, x) = Pi S_Q E q (module
    docstring), linear and constant in t; x must be the interface's side-1 points in the
    order of ``interface.dofs1`` (checked).

    Attributes
    ----------
    J : scipy.sparse.csr_matrix (d k1, m)
        dG/dq = Pi S_Q E on interleaved rows (d j + i: component i at side-1 point j), as
        sparse as Pi (matching: one entry per row): nothing of size d k1 x m is built dense, so
        the attached body's unknowns are not capped by it (``docs/coupling.md``, Sec. 13).
    """

    is_linear = True

    def __init__(self, interface: Interface, component: ElasticComponent):
        super().__init__(interface.part1, component)
        self.interface = interface
        self.dim = interface.space1.dim
        S2 = interface.space2.vector_dofs(interface.dofs2)
        self.J = (interface.vector(interface.Pi) @ component.E[S2]).tocsr()
        self.J.eliminate_zeros()
        self._x1 = interface.space1.doflocs[:, interface.dofs1]

    def _check(self, x):
        if x.shape != self._x1.shape or not np.allclose(x, self._x1, rtol=0, atol=1e-12):
            raise RotheInputError(
                f"interface: the points of {self.part!r} are not the interface's side-1 "
                "points (internal ordering)",
                "interface",
            )

    def _point_rows(self, x) -> np.ndarray | None:
        """The interleaved rows of J for the points x: None for all (checked), else the rows
        of the nearest side-1 points (a subset: the system's dimension check)."""
        if x.shape[1] == self._x1.shape[1]:
            self._check(x)
            return None
        k = cKDTree(self._x1.T).query(np.asarray(x, float).T)[1]
        return (self.dim * k[:, None] + np.arange(self.dim)).ravel()

    def _at(self, x, vec) -> np.ndarray:
        """(J q) at the points x as (d, k)."""
        rows = self._point_rows(x)
        J = self.J if rows is None else self.J[rows]
        return (J @ vec).reshape(-1, self.dim).T

    def values(self, t, q, x):
        """Pi S_Q E q at the part's points, (d, k1): one sparse product."""
        return self._at(x, q)

    def derivatives(self, t, q, p, pdot, x):
        """(G, G', G'') = (J q, J p, J pdot) at the points x, each (d, k): G is linear in q
        with no explicit t (no curvature), and the products are sparse."""
        return self._at(x, q), self._at(x, p), self._at(x, pdot)

    def jacobian_matrix(self, t, q, x):
        """The constant sparse J (d k, m) (rows of the points x if a subset)."""
        rows = self._point_rows(x)
        return self.J if rows is None else self.J[rows]

    def jacobian(self, t, q, x):
        """The constant dG/dq as the protocol's dense (d, k, m): for a few points only (the
        system's dimension check); the system assembles Gamma from :meth:`jacobian_matrix`."""
        J = self.jacobian_matrix(t, q, x).toarray()
        return J.reshape(-1, self.dim, J.shape[1]).transpose(1, 0, 2)

    def on_mesh(self, mesh, degree: int) -> Glue:
        """The glue for the base body on another mesh (space adaptivity of the base): the
        interface rebuilt between the new base mesh and the same attached body. Matching nodes
        stay matching while the base's interface facets are not refined; once they are, the
        base's trace space is finer than the attached body's and the interface is glued by the
        mortar projection (exact there: the attached trace lies in the finer space, so Pi is
        its interpolation), unless ``method='matching'`` was asked for -- then ``auto``."""
        itf = self.interface
        method = "mortar" if itf.requested == "mortar" else "auto"
        new = Interface(
            VectorSpace(mesh, degree),
            itf.part1,
            itf.space2,
            itf.part2,
            method=method,
            tol=itf.tol,
            name=itf.name,
        )
        new.requested = itf.requested
        return Glue(new, self.component)

    def describe(self) -> dict:
        return {
            "type": "Glue",
            "part": self.part,
            "component": self.component.name,
            **self.interface.describe(),
        }


class GluedBodies:
    """A base body with bodies glued to it, or glued to each other in chains (module
    docstring).

    Parameters
    ----------
    base : Body
        Prescribed data (``dirichlet``, ``clamped``), tractions, body force, damping of the
        body that holds the others (body 0).
    attached : sequence of (Body, part_j, body_part) or (Body, part_j, body_part, j)
        Body k (the k-th item, k = 1, 2, ...) glued along its ``body_part`` to body j's part
        ``part_j``: j = 0 (the base; the default of a triple) or an attached body j < k (a
        chain: base - 1 - 2 - ..., or any tree). An attached body takes ``clamped`` parts
        (u = 0) but no other prescribed data. Bodies glued to the base are the system's
        components, each with the bodies glued to it eliminated by substitution
        (:class:`ElasticComponent`'s ``children``); only the base's interfaces carry a
        multiplier.
    method : 'auto' | 'matching' | 'mortar'
        Of every :class:`~rothe.eld.interface.Interface`.
    T : float
        End time.

    Attributes
    ----------
    system : CoupledProblem
        The base with the bodies glued to it as components (:func:`run_bodies` runs it).
    interfaces : list of Interface
        The base's interfaces (with a multiplier), in the order of ``components``.
    components : list of ElasticComponent
        The bodies glued to the base (with their chains).
    chains : list of Interface
        The interfaces between attached bodies (eliminated: no multiplier).
    """

    def __init__(self, base: Body, attached, *, method: str = "auto", T: float = 1.0):
        if not isinstance(base, Body):
            raise fail("base", type(base).__name__, "must be a rothe.eld.bodies.Body")
        attached = list(attached)
        if not attached:
            raise fail("attached", [], "must glue at least one body to the base")
        self.base_body = base
        self.T = float(T)
        parts = [set((base.mesh.boundaries or {}).keys())]
        bodies, names, seen = [base], {base.name}, {}
        links, problems = [], []  # per attached body: (j, part on j, own part); its problem
        glued_parts = [set() for _ in range(len(attached) + 1)]  # parts glued, per body
        for k, item in enumerate(attached):
            label = f"attached[{k}]"
            if not (isinstance(item, tuple | list) and len(item) in (3, 4)):
                raise fail(
                    label,
                    described(repr(item)[:60]),
                    "must be (Body, part_j, body_part) or (Body, part_j, body_part, j)",
                )
            body, part1, part2 = item[:3]
            j = 0 if len(item) == 3 else item[3]
            if not isinstance(j, int | np.integer) or isinstance(j, bool) or not 0 <= j <= k:
                raise fail(
                    f"{label}[3]",
                    j,
                    f"must be the number of a body before it: 0 (the base) to {k}",
                )
            j = int(j)
            if not isinstance(body, Body):
                raise fail(f"{label}[0]", type(body).__name__, "must be a rothe.eld.bodies.Body")
            if body.dirichlet:
                raise fail(
                    f"{label}.dirichlet",
                    sorted(body.dirichlet)[0],
                    "must be empty: an attached body takes clamped parts (u = 0) only",
                )
            if body.name in names:
                raise fail(f"{label}.name", body.name, "must be unique among the bodies")
            names.add(body.name)
            where = "base_part" if j == 0 else "part_j"
            if part1 not in parts[j]:
                allowed = ", ".join(sorted(parts[j])) or "(the mesh has no named parts)"
                raise fail(f"{label}.{where}", part1, f"must be one of {allowed}")
            if (j, part1) in seen:
                raise fail(f"{label}.{where}", part1, f"is already glued ({seen[(j, part1)]})")
            if j and (
                part1 in (bodies[j].traction or {})
                or part1 in bodies[j].clamped
                or part1 in glued_parts[j]
            ):
                raise fail(
                    f"{label}.part_j",
                    part1,
                    f"is loaded, clamped or glued on {bodies[j].name!r}; a part is one of them",
                )
            seen[(j, part1)] = label
            glued_parts[j].add(part1)
            parts2 = set((body.mesh.boundaries or {}).keys())
            if part2 not in parts2:
                allowed = ", ".join(sorted(parts2)) or "(the mesh has no named parts)"
                raise fail(f"{label}.body_part", part2, f"must be one of {allowed}")
            if part2 in (body.traction or {}):
                raise fail(
                    f"{label}.traction",
                    part2,
                    "is the glued part; a part is either glued or loaded",
                )
            for p in body.clamped:
                if p not in parts2 or p == part2:
                    raise fail(
                        f"{label}.clamped",
                        p,
                        "must be a boundary part of the body other than the glued one: "
                        + ", ".join(sorted(parts2 - {part2})),
                    )
            glued_parts[k + 1].add(part2)
            # the body assembled (its dirichlet: the clamped parts and, to fix nothing but the
            # free dofs, the glued part; its loads and initial data as given)
            problems.append(
                ELDProblem(
                    body.mesh,
                    body.material,
                    degree=body.degree,
                    damping=body.damping,
                    dirichlet={**{p: _CLAMP for p in body.clamped}, part2: _CLAMP},
                    traction=body.traction,
                    body_force=body.body_force,
                    u0=body.u0,
                    v0=body.v0,
                    T=self.T,
                    name=body.name,
                )
            )
            bodies.append(body)
            parts.append(parts2)
            links.append((j, part1, part2))
        # the components bottom-up: every body with the bodies glued to it (its children)
        base_space = VectorSpace(base.mesh, base.degree)
        spaces = [base_space] + [prob.space for prob in problems]
        built: dict = {}
        self.chains = []
        sides = []  # (interface, the body of side 1, the body of side 2): body numbers
        for k in range(len(attached), 0, -1):
            children = []
            for c in range(k + 1, len(attached) + 1):  # in the order given
                j, part1, part2 = links[c - 1]
                if j == k:
                    itf = Interface(
                        spaces[k],
                        part1,
                        spaces[c],
                        part2,
                        method=method,
                        name=f"attached[{c - 1}].interface",
                    )
                    children.append((itf, built.pop(c)))
                    self.chains.insert(0, itf)
                    sides.insert(0, (itf, k, c))
            body = bodies[k]
            built[k] = ElasticComponent(problems[k - 1], body.clamped, body.name, children)
        comps, glues, itfs = [], [], []
        for k in range(1, len(attached) + 1):
            j, part1, part2 = links[k - 1]
            if j:
                continue
            comp = built.pop(k)
            itf = Interface(
                base_space,
                part1,
                problems[k - 1].space,
                part2,
                method=method,
                name=f"attached[{k - 1}].interface",
            )
            comps.append(comp)
            itfs.append(itf)
            glues.append(Glue(itf, comp))
            sides.append((itf, 0, k))
        dirichlet = {**{p: _CLAMP for p in base.clamped}, **dict(base.dirichlet or {})}
        self.system = CoupledProblem.from_body(
            base.mesh,
            base.material,
            components=comps,
            couplings=glues,
            dirichlet=dirichlet,
            degree=base.degree,
            damping=base.damping,
            traction=base.traction,
            body_force=base.body_force,
            u0=base.u0,
            v0=base.v0,
            T=self.T,
            name=base.name,
        )
        self.components, self.interfaces, self.glues = comps, itfs, glues
        for glue in glues:  # the side-1 points in the interface's order
            glue._check(self.system._points[glue.part])
        # every attached body in the order given: (its component, its map u_b = E_b q_c)
        where = {name: (comp, prob, Eb) for comp in comps for name, prob, Eb in comp.maps}
        self._attached = [where[b.name] for b in bodies[1:]]
        self._sides = sides

    @property
    def base(self) -> ELDProblem:
        """The base body's problem (its constraint covers the glued parts)."""
        return self.system.body

    def bodies(self) -> list:
        """(name, space) of every body, the base first, then the attached ones as given."""
        return [(self.base.name, self.base.space)] + [
            (prob.name, prob.space) for _, prob, _ in self._attached
        ]

    def problems(self) -> list:
        """The problem of every body (the base's with its constraint), in :meth:`bodies`'s
        order."""
        return [self.base] + [prob for _, prob, _ in self._attached]

    def fields(self, u: np.ndarray, q: np.ndarray) -> list:
        """The dof vectors of all bodies, the base first, from the base's u and the stacked
        coordinates q (one state: (n,), (r,); or series (k, n), (k, r)): u_b = E_b q_c of the
        component c that holds body b."""
        out = [np.asarray(u)]
        for comp, _, Eb in self._attached:
            qc = np.asarray(q)[..., self.system.slice(comp)]
            out.append((Eb @ qc.T).T if qc.ndim > 1 else Eb @ qc)
        return out

    def interface_tractions(self, t, q, p, pdot) -> list:
        """Every attached body's traction on its constrained parts -- the part glued to the
        body before it (the base, or in a chain an attached body) and its clamped parts -- at
        the states ``t`` (k,), ``q``, ``p``, ``pdot`` (k, r), from the body's residual: with
        u_b = E_b q, v_b = E_b p, a_b = E_b pdot (its map, :meth:`fields`),

            f_b = rho_b M_b a_b + C_b v_b + K_b u_b - F_b(t),   lambda_b = -M_{G,b}^{-1} f_b|_C

        (C: the body's constrained dofs, M_{G,b} its boundary mass there; f_b vanishes on its
        other free dofs up to the step's residual). f_b is the nodal force the neighbour or
        the clamp exerts on body b: on a body glued to the base the multiplier's
        (Pi S)^T M_G lambda (:meth:`interface_forces`) to solver tolerance; on a chain
        interface, which has no multiplier (its glue is substituted), the consistent reaction
        of the substitution (the slaved side's residual pushed onto the body's dofs); on a
        clamped part the clamp's reaction. lambda_b is the multiplier the body's constrained
        parts would carry as Dirichlet boundaries (the base's convention: the force on the
        body is -B^T lambda, the traction exerted on it -lambda). Returns per attached body
        (in :meth:`bodies`'s order) a (k, m_b) array on its problem's constrained dofs."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        q, p, pdot = (np.atleast_2d(np.asarray(w, dtype=float)) for w in (q, p, pdot))
        out = []
        for comp, prob, Eb in self._attached:
            sl = self.system.slice(comp)
            u, v, a = (Eb @ w[:, sl].T for w in (q, p, pdot))  # (n_b, k)
            f = float(prob.material.rho) * (prob.M @ a) + prob.K @ u
            C = prob.damping_op.linear
            if C is not None:
                f += C @ v
            f -= np.column_stack([prob.load(ti) for ti in t])  # (per state: not per cell)
            c = prob.constraint
            out.append(-c.multiplier_from_residual(f[c.dofs]).T)
        return out

    def multiplier(self, lam: np.ndarray, k: int = 0) -> np.ndarray:
        """lambda on interface k (its side-1 nodes, interleaved), from the base's lambda."""
        c = self.system.constraint
        d = self.base.space.dim
        pos = c.part_positions[self.interfaces[k].part1]
        return np.asarray(lam)[..., (d * pos[:, None] + np.arange(d)).ravel()]

    def interface_forces(self, lam: np.ndarray, k: int = 0):
        """The nodal forces of interface k's multiplier on the two bodies: (on the base, -B^T
        lambda, (n_1,); on body k, +(Pi S E)^T M_G lambda as a dof vector of body k,
        (n_k,)). Their resultants sum to zero (action = reaction)."""
        c = self.system.constraint
        only = self._only(lam, k)
        f1 = -(c.B.T @ only)
        # (Pi S_Q)^T M_G lambda on body k's interface dofs (zero where it is clamped): the
        # generalized force Gamma^T M_G lambda before the component's map E, which for a
        # chain mixes in the bodies glued to body k
        itf, comp = self.interfaces[k], self.components[k]
        local = (c.boundary_mass @ only)[self.system._rows[itf.part1].T.ravel()]
        f2 = np.zeros(comp.problem.space.ndofs)
        f2[itf.space2.vector_dofs(itf.dofs2)] = itf.vector(itf.Pi).T @ local
        held = np.setdiff1d(np.arange(f2.size), comp.free)
        f2[held] = 0.0
        return f1, f2

    def _only(self, lam, k):
        keep = np.zeros_like(np.asarray(lam, float))
        c = self.system.constraint
        d = self.base.space.dim
        pos = c.part_positions[self.interfaces[k].part1]
        rows = (d * pos[:, None] + np.arange(d)).ravel()
        keep[rows] = np.asarray(lam)[rows]
        return keep

    def interface_residual(self, u: np.ndarray, q: np.ndarray) -> float:
        """max |S_1 u_j - Pi S_2 u_k| over every interface (the base's and the chains') of
        one state, relative to max(1, max |u|): zero up to round-off on the chains (their
        glue is substituted), the coupling's residual on the base's."""
        us = self.fields(u, q)
        worst = 0.0
        for itf, j, k in self._sides:
            side1 = us[j].reshape(-1, itf.space1.dim)[itf.dofs1].ravel()
            worst = max(worst, float(np.abs(side1 - itf.project(us[k])).max(initial=0.0)))
        return worst / max(1.0, max(float(np.abs(w).max(initial=0.0)) for w in us))

    def describe(self) -> dict:
        """Bodies (name, unknowns, degree, material) and interfaces, for summaries."""
        return {
            "bodies": [
                {
                    "name": name,
                    "ndofs": int(space.ndofs),
                    "degree": int(space.degree),
                }
                for name, space in self.bodies()
            ],
            "interfaces": [itf.describe() for itf in self.interfaces],
            "chains": [itf.describe() for itf in self.chains],
        }


def run_bodies(glued: GluedBodies, *, fields: bool = True, **options) -> CoupledResult:
    """Run glued bodies (:class:`GluedBodies`) from 0 to T: :func:`run_coupled` on its
    system, the keywords of which (scheme, form, control, T, watch, error_scale, adapt,
    progress, checkpoint, resume) ``options`` passes on. With ``fields`` the base's u, v and
    lambda are recorded at every state (series ``u``, ``v``, ``lam``; the attached bodies'
    are their coordinates ``q``, ``p``: :meth:`GluedBodies.fields`).

    Trajectory series besides run_coupled's: ``reaction_<base_part>`` is the resultant the
    attached body exerts on the base through that interface (-int lambda ds), ``constraint``
    the interface residual max|S u_1 - Pi S u_k| / max(1, max|u_1|) at every accepted state,
    ``balance`` the whole-system ledger's mismatch."""
    if not isinstance(glued, GluedBodies):
        raise fail("glued", type(glued).__name__, "must be a rothe.eld.bodies.GluedBodies")
    options.setdefault("T", glued.T)
    return run_coupled(glued.system, fields=fields, **options)


def _along(extent: float, height: float, n: int) -> int:
    """Cells along a strip of this extent with n across (round(n extent / H), at least 1)."""
    return max(1, round(n * extent / height))


def strip_pair_dofs(length, height, split, n1, n2, degree1, degree2) -> tuple[int, int]:
    """The unknowns of the two bodies of :func:`strip_pair` (2D vector P1 or P2: 2 (k n_x + 1)
    (k n_y + 1)), counted without building the meshes (the command's memory check)."""
    return tuple(
        2 * (k * _along(extent, height, n) + 1) * (k * n + 1)
        for extent, n, k in ((split, n1, degree1), (length - split, n2, degree2))
    )


def strip_pair(length: float, height: float, split: float, n1: int, n2: int):
    """Two triangulated strips [0, split] x [0, H] and [split, L] x [0, H] with n1 and n2
    cells across (round(n_k len_k / H) along, at least 1) and the parts left, right, bottom,
    top: the bodies of ``rothe run eld-two-bodies`` (n1 = n2: matching interface nodes)."""
    # scikit-fem is imported where a mesh is built (the start-up time of the command line)
    from skfem import MeshTri

    def strip(x0, x1, n):
        nx = _along(x1 - x0, height, n)
        return tag_box_faces(
            MeshTri.init_tensor(np.linspace(x0, x1, nx + 1), np.linspace(0, height, n + 1))
        )

    return strip(0.0, split, n1), strip(split, length, n2)


def strip_union(
    length, height, split, n, degree, material1, material2, *, traction, T, clamp="left"
) -> ELDProblem:
    """The single body on the union of :func:`strip_pair` (n cells across both): the same
    cells, ``material1`` left of ``split`` and ``material2`` right of it (per-cell materials,
    :class:`~rothe.eld.materials.PiecewiseMaterial`; one Material if they are equal), the
    part ``clamp`` held at u = 0 and ``traction`` (part -> g) -- the reference a glued run
    with matching meshes equals (``rothe run eld-two-bodies --compare-union``)."""
    # scikit-fem is imported where a mesh is built (the start-up time of the command line)
    from skfem import MeshTri

    nx1, nx2 = _along(split, height, n), _along(length - split, height, n)
    xs = np.r_[np.linspace(0.0, split, nx1 + 1), np.linspace(split, length, nx2 + 1)[1:]]
    mesh = tag_box_faces(MeshTri.init_tensor(xs, np.linspace(0, height, n + 1)))
    material = material1
    if material1 != material2:
        cx = mesh.p[0, mesh.t].mean(axis=0)
        mesh = mesh.with_subdomains(
            {"body1": np.flatnonzero(cx < split), "body2": np.flatnonzero(cx > split)}
        )
        material = PiecewiseMaterial(
            {"material1": material1, "material2": material2},
            regions={"body1": "material1", "body2": "material2"},
        )
    return ELDProblem(
        mesh,
        material,
        degree=degree,
        dirichlet={clamp: _CLAMP},
        traction=traction,
        T=T,
        name="union",
    )
