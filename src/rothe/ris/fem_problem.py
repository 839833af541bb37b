"""Rate-independent systems in H^1_0 discretized by P1 finite elements (Example 1.4, Sec. 7.2).

Andreia & Meyer (2022), Example 1.4 with Z = H^1_0(Omega) (or H^1 with zero values on named
boundary parts), V = L2, X = L1:

    I(t, z) = 1/2 int c |grad z|^2 + int g(z) - <l(t), z>,     R(v) = kappa ||v||_{L1},
    ||v||_V = ||v||_{L2}.

Discretization (P1 on triangles / tetrahedra, nodal basis phi_i, lumped mass m_i = int phi_i):

* unknowns: the nodal values z_i at the *free* nodes (every node not on the Dirichlet boundary),
  z_i = 0 on the Dirichlet nodes; :meth:`FERISProblem.full_state` returns all nodal values in the
  order of ``mesh.p`` with those zeros;
* A = stiffness of c(-Laplace) restricted to the free nodes (exact for P1, c piecewise constant);
* F(z) = sum_i m_i g(z_i) over *all* nodes (the Dirichlet nodes contribute the constant
  g(0) sum m_i there, so that F is the lumped approximation of int_Omega g(z_h) itself);
  F'(z)_i = m_i g'(z_i) and F''(z) = diag(m_i g''(z_i)) at the free nodes;
* R(v) = sum_i kappa m_i |v_i| (r_i = kappa m_i) and ||v||_V^2 = sum_i m_i v_i^2;
* <l(t), phi_i> the nodal functionals of the load, restricted to the free nodes.

Which quadrature F uses, and why
    Nodal (vertex, "lumped") quadrature: int_K g(z_h) ~ |K|/(d+1) sum_{vertices} g(z_j),
    i.e. F(z) = sum_i m_i g(z_i). Reasons: (1) it is the same lumping the paper uses for the L1
    norm ([9, Sec. 4]) and the metric V uses, so F', R and the metric all act node by
    node and the generalized Newton matrix of a step is A + diag(m g''(z)) + diag(...) with the
    sparsity of A -- a consistent quadrature would make F'' a full mass-like matrix per
    iteration; (2) F, F' and F'' cost O(n) vector operations and no assembly (under 10 ms at
    10^6 nodes versus 3-5 s for a quadrature-point assembly, measured); (3) it is
    accurate enough: the vertex rule is exact for affine integrands and O(h^2) for smooth ones,
    the same order as the P1 L2 error, so the discrete energy converges at order 2 (tested in
    tests/fem/test_convergence.py); (4) it keeps the discrete problem a RIS in R^n with diagonal
    data, for which dist (2.4) has a closed form and the KKT system of Lemma 4.1
    decouples except through A.

    ``quadrature="consistent"``: F(z) = int g(z_h) by a cell rule of degree 4
    (:class:`_CellQuadrature`; a load density by the same rule). It costs the non-diagonal F''
    (Example 7.2 on 40 x 40: 59 s against 21 s, one jump at t = 0.1719 with both, dissipation
    +0.1 %) and buys an energy that does not change when the mesh is refined: under the vertex
    rule a new midpoint v of the edge (a, b) changes F by m_v (g(z_v) - (g(z_a) + g(z_b))/2)
    although z_h is the same function (issue 18; docs/ris_fem.md, *An energy-neutral transfer*).

Load
    ``load(t)`` returns either a number c -- the constant density, <l(t), phi_i> = c m_i (exact,
    since m_i = int phi_i) -- or a vector of nodal functionals over all nodes (values at the
    Dirichlet nodes are ignored). Example 7.2: <l(t), z> = -200 t^3 int z, i.e. c = -200 t^3.

Sign conventions are those of :class:`rothe.ris.problem.RISProblem`: D_z I = A z + F'(z) - l(t).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..errors import (
    DataError,
    RotheInputError,
    check_finite_array,
    check_positive,
    check_real,
    described,
    fail,
)
from ..fem.mesh import bad, cell_volumes, check_mesh, describe, mesh_dim
from ..fem.scalar import boundary_nodes, lumped_mass, split_dofs, stiffness
from ..fem.simplex import _rule
from ..io.checkpoint import digest
from .problem import RISProblem

#: the quadratures of int g(z_h) (and of a load density): ``lumped`` (vertex rule) or
#: ``consistent`` (a cell rule of degree CELL_ORDER, :class:`_CellQuadrature`)
QUADRATURES = ("lumped", "consistent")

#: the degree of the consistent cell rule: exact for the quartic double well on P1
CELL_ORDER = 4

#: points where g', g'' are compared with finite differences of g and g' (irrational-ish, so
#: that kinks of a piecewise g at round numbers are not hit)
DERIVATIVE_CHECK_POINTS = np.array(
    [-2.31, -1.13, -0.617, -0.0931, 0.0, 0.0713, 0.389, 0.94, 1.27, 2.58]
)

ScalarFn = Callable[[np.ndarray], np.ndarray]


def _vectorized(label: str, fn: ScalarFn, x: np.ndarray) -> np.ndarray:
    try:
        y = np.asarray(fn(x), dtype=float)
    except Exception as exc:  # the user's function: any failure is bad input
        raise bad(
            label,
            f"an error on a numpy array ({type(exc).__name__}: {exc})",
            "must be a vectorized function of a numpy array",
        ) from None
    if y.shape != x.shape:
        if y.ndim == 0:
            y = np.full(x.shape, float(y))
        else:
            raise bad(
                label,
                f"an array of shape {y.shape} for input shape {x.shape}",
                "must return one value per entry",
            )
    return y


def check_pointwise_derivatives(
    g: ScalarFn, dg: ScalarFn, d2g: ScalarFn, points=DERIVATIVE_CHECK_POINTS
) -> None:
    """Compare dg with central differences of g and d2g with those of dg at a few points.

    A derivative passes at a point if it matches the difference quotient to a relative 1e-5 for
    either of two step sizes (1e-4 and 1e-6 times max(1, |z|)): the larger step absorbs
    round-off, the smaller the curvature of smooth functions. Raises a one-line
    RotheInputError naming the derivative, the point and both values.
    """
    z = np.asarray(points, dtype=float)
    gz = _vectorized("g", g, z)
    d1 = _vectorized("dg", dg, z)
    d2 = _vectorized("d2g", d2g, z)
    for label, values in (("g", gz), ("dg", d1), ("d2g", d2)):
        if not np.all(np.isfinite(values)):
            z_bad = z[~np.isfinite(values)][0]
            raise bad(label, f"a non-finite value at z = {z_bad:g}", "must be finite")
    for label, exact, base, of in (("dg", d1, g, "g"), ("d2g", d2, dg, "dg")):
        best = np.full(z.shape, np.inf)
        fd_keep = np.zeros_like(z)
        for rel in (1e-4, 1e-6):
            h = rel * np.maximum(1.0, np.abs(z))
            fd = (_vectorized(of, base, z + h) - _vectorized(of, base, z - h)) / (2 * h)
            err = np.abs(fd - exact) / np.maximum(1.0, np.maximum(np.abs(fd), np.abs(exact)))
            better = err < best
            best = np.where(better, err, best)
            fd_keep = np.where(better, fd, fd_keep)
        wrong = np.nonzero(best > 1e-5)[0]
        if wrong.size:
            i = wrong[0]
            raise RotheInputError(
                f"{label}: got {exact[i]:.6g} at z = {z[i]:g}, must match finite differences "
                f"of {of} ({fd_keep[i]:.6g}); check the derivative you supplied"
            )


class FERISProblem(RISProblem):
    """A P1 finite-element RIS on a scikit-fem triangle or tetrahedron mesh.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
        P1 simplex mesh (see :mod:`rothe.fem.mesh` for builders and file import).
    g, dg, d2g : vectorized callables R -> R
        The energy density of F(z) = int g(z) and its first two derivatives (checked against
        finite differences at a few points when the problem is built).
    load : callable
        t -> number (a constant load density c(t): <l, phi_i> = c(t) m_i) or (n_nodes,) array
        of nodal functionals <l(t), phi_i>. Checked to be finite at 9 times in [0, T].
    kappa : float > 0
        R(v) = kappa ||v||_{L1} with lumped mass.
    coefficient : number, per-cell array or callable c(x) > 0
        A = stiffness of c (-Laplace).
    z0 : number, callable z0(x) or array
        Initial state: a number (the value at every free node), nodal values over all nodes
        (must vanish on the Dirichlet nodes) or over the free nodes only.
    T : float
        Final time.
    dirichlet : None or list of str
        None: homogeneous Dirichlet on the whole boundary; otherwise the names of the boundary
        parts (``mesh.boundaries``) where z = 0; the rest of the boundary is natural (Neumann).
    load_rate : callable, optional
        t -> dl/dt in the same form as ``load``.
    load_density : callable, optional
        (t, x) -> load density at the points x (shape (d, n_points)) instead of ``load``
        (``load=None``): <l(t), phi_i> = m_i l(t, x_i) (lumped, exact for affine densities
        times constants). A density is what lets a problem move to another mesh
        (:meth:`on_mesh`, space adaptivity); ``load_density_rate`` likewise for dl/dt.
    name : str
        The problem's name in ``trajectory.meta['example']``.

    The examples of Sec. 7 are built by :mod:`rothe.ris.examples`.
    """

    def __init__(
        self,
        mesh,
        g: ScalarFn,
        dg: ScalarFn,
        d2g: ScalarFn,
        load: Callable[[float], object],
        *,
        kappa: float = 1.0,
        coefficient=1.0,
        z0=0.0,
        T: float = 1.0,
        dirichlet=None,
        load_rate: Callable[[float], object] | None = None,
        name: str = "ris-fem",
        load_density: Callable[[float, np.ndarray], object] | None = None,
        load_density_rate: Callable[[float, np.ndarray], object] | None = None,
        quadrature: str = "lumped",
    ):
        if quadrature not in QUADRATURES:
            raise bad("quadrature", repr(quadrature), f"must be one of {', '.join(QUADRATURES)}")
        self.quadrature = quadrature
        # what on_mesh needs to build the same problem on another mesh
        self._spec = dict(
            g=g,
            dg=dg,
            d2g=d2g,
            load=load,
            kappa=kappa,
            coefficient=coefficient,
            T=T,
            dirichlet=dirichlet,
            load_rate=load_rate,
            name=name,
            load_density=load_density,
            load_density_rate=load_density_rate,
            quadrature=quadrature,
        )
        self.coefficient = coefficient
        self.mesh = check_mesh(mesh)
        self.dim = mesh_dim(mesh)
        T = check_positive("T", T)
        self.kappa = check_positive("kappa", kappa)
        n_nodes = mesh.p.shape[1]
        fixed = boundary_nodes(mesh, dirichlet)
        if fixed.size == 0:
            where = "the mesh boundary" if dirichlet is None else f"boundary parts {dirichlet}"
            raise bad(
                "mesh",
                f"a mesh with no nodes on {where} ({describe(mesh)})",
                "homogeneous Dirichlet data needs at least one boundary node",
            )
        free, fixed = split_dofs(n_nodes, fixed)
        if free.size == 0:
            raise bad(
                "mesh",
                f"a mesh whose {n_nodes} nodes all lie on the Dirichlet boundary",
                "needs at least one interior node (refine the mesh)",
            )
        self.free, self.fixed = free, fixed
        self.n_nodes = n_nodes
        self.dirichlet = dirichlet
        _check_every_component_held(mesh, fixed, dirichlet)

        check_pointwise_derivatives(g, dg, d2g)
        self.g, self.dg, self.d2g = g, dg, d2g

        m_all = lumped_mass(mesh)
        self.m_all = m_all
        self._cells = None if quadrature == "lumped" else _CellQuadrature(mesh, free)
        if load_density is not None:
            if load is not None:
                raise bad(
                    "load",
                    "a load together with load_density",
                    "give one of them (load=None with a density)",
                )
            load = _nodal_from_density(load_density, mesh, m_all, "load_density", self._cells)
            if load_density_rate is not None:
                load_rate = _nodal_from_density(
                    load_density_rate, mesh, m_all, "load_density_rate", self._cells
                )
        elif load is None:
            raise bad(
                "load",
                "None",
                "must be a callable t -> density or nodal functionals (or give load_density)",
            )
        m = m_all[free]
        K = stiffness(mesh, coefficient)
        A = sp.csr_matrix(K[free][:, free])
        A.sort_indices()
        self._F_fixed = float(np.sum(m_all[fixed]) * _vectorized("g", g, np.zeros(1))[0])

        self._user_load = load
        self._user_load_rate = load_rate
        for t_check in np.linspace(0.0, T, 9):
            self._load_vector(load, t_check, "load")

        z0_free = self._initial_state(z0)

        super().__init__(
            A=A,
            F=self._F,
            dF=self._dF,
            d2F=self._d2F,
            load=lambda t: self._load_vector(self._user_load, t, "load"),
            dissipation_weights=self.kappa * m,
            metric_weights=m,
            z0=z0_free,
            T=T,
            load_rate=(
                None
                if load_rate is None
                else (lambda t: self._load_vector(self._user_load_rate, t, "load_rate"))
            ),
            name=name,
            # F' and F'' are exact sums of the pointwise g', g'' checked above
            check_derivatives=False,
            # A is the stiffness of c > 0 on the free nodes: positive definite exactly when every
            # connected part of the mesh has a Dirichlet node (checked above, in O(n))
            check_coercivity=False,
        )

    # -- another mesh (space adaptivity) ------------------------------------------------------
    def check_movable(self) -> None:
        """Refuse data tied to this mesh: nodal-functional loads and per-cell coefficients.

        A problem moves to another mesh (:meth:`on_mesh`) only with data defined on the domain:
        a load density (a number per t, or ``load_density``), a number or a callable c(x). The
        one-line error names ``adapt``, the parameter of :func:`rothe.ris.run.run_ris` that
        asks for meshes that change.
        """
        spec = self._spec
        if spec["load_density"] is None:
            val = np.asarray(spec["load"](0.0), dtype=float)
            if val.ndim != 0:
                raise fail(
                    "adapt",
                    described("a load given as nodal functionals of one mesh"),
                    "needs a load density (a number per t, or load_density(t, x)) so "
                    "that the load can be evaluated on every adapted mesh",
                )
        c = spec["coefficient"]
        if not callable(c) and np.ndim(c) != 0:
            raise fail(
                "adapt",
                described("a coefficient given per cell of one mesh"),
                "needs a number or a callable c(x)",
            )

    def on_mesh(self, mesh) -> FERISProblem:
        """The same problem (g, load, kappa, c, T, Dirichlet parts, name) on ``mesh``, z0 = 0.

        Used after every change of an adaptive mesh; :meth:`check_movable` says whether the
        data allow it. The caller sets the state (the transferred z_k) itself.
        """
        self.check_movable()
        return FERISProblem(mesh, z0=0.0, **self._spec)

    # -- data ----------------------------------------------------------------------------------
    def _load_vector(self, fn, t: float, label: str) -> np.ndarray:
        """Nodal functionals at the free nodes. Failures are :class:`DataError`: bad input when
        the problem is built, a failed run that keeps its trajectory when found midway."""
        name = f"{label}(t={t:g})"
        try:
            val = fn(t)
        except Exception as exc:
            raise DataError(
                f"{name}: got an error ({type(exc).__name__}: {exc}), must evaluate for t in [0, T]"
            ) from None
        try:
            val = np.asarray(val, dtype=float)
        except (TypeError, ValueError):
            raise DataError(
                f"{name}: got a {type(val).__name__}, must be a number (density) or "
                f"one nodal functional per node ({self.n_nodes})"
            ) from None
        if val.ndim == 0:
            _finite_data(name, val)
            return float(val) * self.m_all[self.free]
        if val.shape != (self.n_nodes,):
            raise DataError(
                f"{name}: got an array of shape {val.shape}, must be a number "
                f"(density) or one nodal functional per node ({self.n_nodes})"
            )
        _finite_data(name, val[self.free])
        return val[self.free]

    def _initial_state(self, z0) -> np.ndarray:
        n_free = self.free.size
        if callable(z0):
            z = np.asarray(z0(self.mesh.p), dtype=float)
            if z.ndim == 0:
                z = np.full(self.n_nodes, float(z))
            z = z.copy()
            z[self.fixed] = 0.0  # the interpolant of a function in H^1_0 vanishes there anyway
        else:
            z = np.asarray(z0, dtype=float)
            if z.ndim == 0:
                check_real("z0", float(z))
                return np.full(n_free, float(z))
        if z.shape == (n_free,) and n_free != self.n_nodes:
            return check_finite_array("z0", z).copy()
        if z.shape != (self.n_nodes,):
            raise bad(
                "z0",
                f"an array of shape {z.shape}",
                f"must be a number, a callable, or values at all {self.n_nodes} nodes "
                f"or at the {n_free} free nodes",
            )
        check_finite_array("z0", z)
        on_bnd = np.abs(z[self.fixed]).max()
        if on_bnd > 0:
            raise bad(
                "z0",
                f"values up to {on_bnd:g} on Dirichlet nodes",
                "must vanish there (homogeneous Dirichlet data)",
            )
        return z[self.free].copy()

    # -- F by nodal quadrature ----------------------------------------------------------------
    def _F(self, z: np.ndarray) -> float:
        if self._cells is not None:
            return self._cells.F(self.g, z)
        return float(self.m @ self.g(z)) + self._F_fixed

    def _dF(self, z: np.ndarray) -> np.ndarray:
        if self._cells is not None:
            return self._cells.dF(self.dg, z)
        return self.m * self.dg(z)

    def _d2F(self, z: np.ndarray):
        if self._cells is not None:
            return self._cells.d2F(self.d2g, z)
        return self.m * self.d2g(z)

    def fingerprint(self) -> dict:
        """:meth:`RISProblem.fingerprint` and a hash of the mesh (nodes and cells)."""
        fp = super().fingerprint()
        fp["mesh"] = digest(self.nodes, self.cells)
        return fp

    # -- output -------------------------------------------------------------------------------
    def full_state(self, z: np.ndarray) -> np.ndarray:
        """Nodal values at all mesh nodes (order of ``mesh.p``), zero on the Dirichlet nodes."""
        out = np.zeros(self.n_nodes)
        out[self.free] = z
        return out

    def integral(self, z: np.ndarray) -> float:
        """int_Omega z_h by the lumped mass (exact for P1)."""
        return float(self.m @ z)

    @property
    def nodes(self) -> np.ndarray:
        """The mesh nodes, one row per node (n_nodes, d)."""
        return self.mesh.p.T.copy()

    @property
    def cells(self) -> np.ndarray:
        """The mesh cells, one row of node indices per cell."""
        return self.mesh.t.T.copy()


def _nodal_from_density(density, mesh, m_all: np.ndarray, label: str, cells=None):
    """t -> nodal functionals m_i l(t, x_i) of a density l(t, x) (lumped), or with ``cells`` (a
    :class:`_CellQuadrature`) int l(t) phi_i by its cell rule."""
    if cells is not None:
        return cells.nodal_from_density(density, label)
    x = np.asarray(mesh.p, dtype=float)

    def nodal(t):
        return _density_values(density, t, x, label) * m_all

    return nodal


def _density_values(density, t: float, points: np.ndarray, label: str) -> np.ndarray:
    """l(t, x) at the points (d, n) as an array (n,) (a number: the same at every point), or
    DataError naming ``label`` for an array of another shape."""
    val = np.asarray(density(t, points), dtype=float)
    if val.ndim == 0:
        return np.full(points.shape[1], float(val))
    if val.shape != (points.shape[1],):
        raise DataError(
            f"{label}(t={t:g}): got an array of shape {val.shape}, must be one "
            f"value per point ({points.shape[1]})"
        )
    return val


class _CellQuadrature:
    """int g(z_h), its derivatives and int l phi_i by a cell rule of degree :data:`CELL_ORDER`
    (``quadrature="consistent"``), vectorized over cells.

    With lam_q, w_q the rule's barycentric points and weights (sum w_q = 1) and z_{K,q} =
    sum_j lam_{jq} z_{K_j}:

        F(z) = sum_K |K| sum_q w_q g(z_{K,q}),
        F'(z)_i = sum_{K ni i} |K| sum_q w_q g'(z_{K,q}) lam_{iq},
        F''(z)_ij = sum_{K ni i, j} |K| sum_q w_q g''(z_{K,q}) lam_{iq} lam_{jq},

    exact for a polynomial g of degree <= CELL_ORDER (the double well of Example 7.2 is
    quartic). Why (issue 18): the integral of g(z_h) depends on the function z_h only, so a
    refinement that interpolates z_h (P1 nested) does not change F, where the vertex rule
    changes it by m_v (g(z_v) - (g(z_a) + g(z_b))/2) at every new midpoint v (48 m_v across a
    double-well interface). F'' has the sparsity of A; its entries are summed into a pattern
    fixed once per mesh (the free-free entries of the cells' local matrices).
    """

    def __init__(self, mesh, free: np.ndarray):
        t = np.asarray(mesh.t)
        d1 = t.shape[0]
        self.t = t
        self.n_nodes = mesh.p.shape[1]
        self.free = free
        self.lam, w = _rule(d1 - 1, CELL_ORDER)  # (d+1, nq), (nq,)
        self.wvol = w[:, None] * cell_volumes(mesh)[None, :]  # (nq, nc)
        p = np.asarray(mesh.p, dtype=float)
        # quadrature points (d, nq, nc)
        self.x = np.einsum("jq,djc->dqc", self.lam, p[:, t])
        # the cells' vertices as free-node numbers, the Dirichlet nodes as the extra slot nf
        # of a zero-padded z: z_{K,q} = lam^T z[lt] and F' a bincount over lt, no full-length
        # state per evaluation (measured faster than einsum, and than a CSR gather matrix)
        nf = free.size
        local = np.full(self.n_nodes, nf, dtype=np.int64)
        local[free] = np.arange(nf)
        self._lt = local[t]  # (d+1, nc)
        self._lt_flat = self._lt.ravel()
        self._lamT = np.ascontiguousarray(self.lam.T)  # (nq, d+1)
        # F'': lam_iq lam_jq for every (i, j) (rows i (d+1) + j), and the free-free entries of
        # the cells' local matrices summed into a CSR pattern by one sparse product
        nc = t.shape[1]
        self._LL = np.einsum("iq,jq->ijq", self.lam, self.lam).reshape(d1 * d1, -1)
        rows = np.broadcast_to(self._lt[:, None, :], (d1, d1, nc)).ravel()
        cols = np.broadcast_to(self._lt[None, :, :], (d1, d1, nc)).ravel()
        keep = np.flatnonzero((rows < nf) & (cols < nf))
        keys, inv = np.unique(rows[keep] * nf + cols[keep], return_inverse=True)
        self._assemble = sp.csr_matrix(
            (np.ones(keep.size), (inv, keep)), shape=(keys.size, d1 * d1 * nc)
        )
        self._indices = keys % nf
        self._indptr = np.concatenate([[0], np.cumsum(np.bincount(keys // nf, minlength=nf))])
        self._nf = nf

    def _at_points(self, z):
        """z_{K,q} (nq, nc) from the values ``z`` at the free nodes (0 at Dirichlet nodes)."""
        return self._lamT @ np.append(z, 0.0)[self._lt]

    def F(self, g, z) -> float:
        return float(np.sum(self.wvol * g(self._at_points(z))))

    def dF(self, dg, z) -> np.ndarray:
        local = self.lam @ (self.wvol * dg(self._at_points(z)))  # (d+1, nc)
        out = np.bincount(self._lt_flat, weights=local.ravel(), minlength=self._nf + 1)
        return out[: self._nf]

    def d2F(self, d2g, z) -> sp.csr_matrix:
        h = self.wvol * d2g(self._at_points(z))  # (nq, nc)
        data = self._assemble @ (self._LL @ h).ravel()
        return sp.csr_matrix(
            (data, self._indices.copy(), self._indptr.copy()), shape=(self._nf, self._nf)
        )

    def nodal_from_density(self, density, label: str):
        """t -> int l(t, x) phi_i(x) dx by the cell rule, for all nodes."""
        d, nq, nc = self.x.shape
        pts = self.x.reshape(d, nq * nc)

        def nodal(t):
            val = _density_values(density, t, pts, label)
            local = self.lam @ (self.wvol * val.reshape(nq, nc))
            return np.bincount(self.t.ravel(), weights=local.ravel(), minlength=self.n_nodes)

        return nodal


def _finite_data(name: str, values) -> None:
    values = np.asarray(values, dtype=float)
    if not np.all(np.isfinite(values)):
        bad_value = float(values[~np.isfinite(values)].ravel()[0])
        raise DataError(f"{name}: got {bad_value}, must be finite (no NaN or inf)")


def _check_every_component_held(mesh, fixed: np.ndarray, dirichlet) -> None:
    """Every connected part of the mesh must contain a Dirichlet node.

    The stiffness of c > 0 restricted to the free nodes is then positive definite (its null
    space on the whole mesh is the functions constant on each connected part, and those vanish
    where a part holds a zero Dirichlet value): the coercivity of A that the scheme needs
    (Andreia & Meyer 2022, Sec. 1.3). A part with only natural boundary conditions gives a
    singular A and an energy with a flat direction (z + c on that part). O(n) with
    scipy.sparse.csgraph.
    """
    t = np.asarray(mesh.t)
    n = mesh.p.shape[1]
    # a star per cell (vertex 0 to the others) connects exactly what the cell connects
    rows = np.tile(t[0], t.shape[0] - 1)
    cols = t[1:].ravel()
    graph = sp.csr_matrix((np.ones(rows.size, dtype=np.int8), (rows, cols)), shape=(n, n))
    count, label = connected_components(graph, directed=False)
    if count == 1:
        return
    held = np.zeros(count, dtype=bool)
    held[label[fixed]] = True
    if not held.all():
        free_parts = int(np.count_nonzero(~held))
        where = "the boundary" if dirichlet is None else f"boundary parts {dirichlet}"
        raise bad(
            "mesh",
            f"a mesh of {count} disconnected parts, {free_parts} of them without "
            f"a node on {where} ({describe(mesh)})",
            "every part needs a Dirichlet node (else A is singular: the energy is flat "
            "along z + const on that part)",
        )
