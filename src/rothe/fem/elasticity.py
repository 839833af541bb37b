"""Vector P1/P2 finite elements for linear isotropic elasticity (plane strain in 2D, and 3D).

:class:`VectorSpace` is the space V_h = [S_h]^d of continuous piecewise linear (P1) or quadratic
(P2) vector fields on a scikit-fem simplex mesh (``MeshTri`` / ``MeshTet``). Its degrees of
freedom are *interleaved*: component c of scalar dof k is vector dof ``d*k + c``, so that every
d x d block of a matrix couples two scalar dofs. That is the block layout of a BSR matrix, and
it is how every matrix here is built: one scalar sparsity pattern (the pattern of the scalar
mass matrix) computed once, plus a (nnz, d, d) array of block values refilled by numpy.

Matrices (all with the paper's conventions, Altmann 2015, Sec. 2.2):

- stiffness (2.3):  <K u, v> = int sigma(u) : eps(v) dx,  sigma(u) = lam tr(eps(u)) I + 2 mu eps(u),
  assembled as  K^{ab}_{ij} = int lam d_a phi_i d_b phi_j + mu d_b phi_i d_a phi_j
  + mu delta_ab grad phi_i . grad phi_j  (block (a, b) couples component a of dof i with
  component b of dof j), with the quadrature that is exact for affine simplices
  (one point for P1, degree 2 for P2);
- mass:  <M u, v> = int u . v dx, the scalar mass (exact quadrature, closed form for P1)
  times the d x d identity;
- block-coefficient mass  int (C(x) u) . v dx for a d x d field C given at quadrature points
  (the Jacobian of a pointwise nonlinear damping).

Loads are applied through quadrature: body force f(x) and boundary tractions g(x) are
evaluated at quadrature points by numpy and integrated against the basis in one pass, so a
time-dependent load costs one vectorized evaluation per step and no generic assembly.

The hand-written element kernels follow PERFORMANCE-NOTES: vector mass by the scalar mass and a
block identity (not by a vector form), one-point stiffness for P1, no Python loop over elements.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from ..errors import check_int, check_positive, check_real, fail


def lame_from_young(E: float, nu: float) -> tuple[float, float]:
    """Lamé constants (lam, mu) from Young's modulus E > 0 and Poisson ratio -1 < nu < 1/2.

    mu = E / (2 (1 + nu)),  lam = E nu / ((1 + nu)(1 - 2 nu))  (3D and plane strain).
    """
    E = check_positive("E", E)
    nu = check_real("nu", nu)
    if not -1.0 < nu < 0.5:
        raise fail("nu", nu, "must satisfy -1 < nu < 0.5")
    return E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))


def _scalar_element(dim: int, degree: int):
    from skfem import ElementTetP1, ElementTetP2, ElementTriP1, ElementTriP2

    return {(2, 1): ElementTriP1, (2, 2): ElementTriP2,
            (3, 1): ElementTetP1, (3, 2): ElementTetP2}[(dim, degree)]()


def check_simplex_mesh(mesh, name: str = "mesh") -> int:
    """Spatial dimension of a scikit-fem triangle/tetrahedron mesh (else a one-line error)."""
    from skfem import MeshTet, MeshTri

    if isinstance(mesh, MeshTri):
        return 2
    if isinstance(mesh, MeshTet):
        return 3
    raise fail(name, type(mesh).__name__,
               "must be a scikit-fem MeshTri or MeshTet (P1/P2 simplices)")


@dataclass
class FacetQuadrature:
    """Quadrature on a set of boundary facets: points, weights and basis values.

    ``values`` (nbf, nf, nq) are the scalar basis functions of the adjacent cell evaluated at
    the facet quadrature points, ``dofs`` (nbf, nf) their scalar dof indices, ``dx`` (nf, nq)
    the weights (facet measure included), ``x`` (d, nf, nq) the points, ``normals`` (d, nf, nq)
    the outward unit normals.
    """

    values: np.ndarray
    dofs: np.ndarray
    dx: np.ndarray
    x: np.ndarray
    normals: np.ndarray

    def integrate_against_basis(self, g: np.ndarray, n_scalar: int) -> np.ndarray:
        """The vector sum_q dx g_c(x_q) phi_k(x_q) for each component c: shape (n_scalar, d)."""
        d = g.shape[0]
        local = np.einsum("ifq,fq,cfq->cif", self.values, self.dx, g)
        out = np.empty((n_scalar, d))
        flat = self.dofs.ravel()
        for c in range(d):
            out[:, c] = np.bincount(flat, weights=local[c].ravel(), minlength=n_scalar)
        return out


class VectorSpace:
    """Vector P1/P2 Lagrange space on a triangle (2D) or tetrahedron (3D) mesh.

    Parameters
    ----------
    mesh : skfem.MeshTri | skfem.MeshTet
        Named boundary parts live in ``mesh.boundaries`` (facet index arrays).
    degree : 1 | 2
    """

    def __init__(self, mesh, degree: int = 1):
        from skfem import Basis

        self.dim = check_simplex_mesh(mesh)
        self.degree = check_int("degree", degree)
        if self.degree not in (1, 2):
            raise fail("degree", degree, "must be 1 or 2")
        self.mesh = mesh
        self.element = _scalar_element(self.dim, self.degree)
        # gradients of P1 are constant, of P2 linear: grad.grad is integrated exactly by a rule of
        # degree 2(p - 1) (at least one point)
        self.grad_basis = Basis(mesh, self.element, intorder=max(1, 2 * (self.degree - 1)))
        self.n_scalar = int(self.grad_basis.N)
        self.ndofs = self.dim * self.n_scalar
        self.element_dofs = np.asarray(self.grad_basis.element_dofs)
        self.doflocs = np.asarray(self.grad_basis.doflocs)
        self._build_pattern()

    # -- sparsity pattern -----------------------------------------------------------------------
    def _build_pattern(self) -> None:
        """Scalar CSR pattern and the map (i, j, e) -> position of entry (dof_i, dof_j) in it.

        One sort of the keys row * n + col of all element entries (np.unique with the inverse);
        at two million tetrahedra this takes about 7 s and 1.3 GB transient, far below the
        memory of the AMG hierarchy that follows.
        """
        edofs = self.element_dofs.astype(np.int64)
        nbf, ne = edofs.shape
        n = self.n_scalar
        key = (edofs[:, None, :] * n + edofs[None, :, :]).ravel()
        unique, inverse = np.unique(key, return_inverse=True)
        del key
        big = unique.size > 2**31 - 1
        self._map = inverse.astype(np.int64 if big else np.int32)
        del inverse
        self.pattern_rows = (unique // n).astype(np.int32)
        self.pattern_cols = (unique % n).astype(np.int32)
        self.pattern_indptr = np.concatenate(
            [[0], np.cumsum(np.bincount(self.pattern_rows, minlength=n))]
        ).astype(np.int64 if big else np.int32)
        self.nnz_scalar = int(unique.size)

    def _scatter(self, local: np.ndarray) -> np.ndarray:
        """Sum element contributions local (nbf, nbf, ne) into the scalar pattern's values."""
        return np.bincount(self._map, weights=local.ravel(), minlength=self.nnz_scalar)

    def scalar_matrix(self, values: np.ndarray) -> sp.csr_matrix:
        n = self.n_scalar
        return sp.csr_matrix((values, self.pattern_cols, self.pattern_indptr), shape=(n, n))

    def block_matrix(self, blocks: np.ndarray) -> sp.csr_matrix:
        """The vector matrix from block values (nnz_scalar, d, d) on the scalar pattern."""
        d, n = self.dim, self.n_scalar
        bsr = sp.bsr_matrix((blocks, self.pattern_cols, self.pattern_indptr),
                            shape=(d * n, d * n), blocksize=(d, d))
        return bsr.tocsr()

    # -- quadrature -----------------------------------------------------------------------------
    @cached_property
    def quad_basis(self):
        """Basis with the quadrature exact for products of two basis functions (degree 2p).

        Used for the mass, loads, errors and nonlinear (pointwise) damping; created on first
        use because at a million unknowns in 3D it costs about a gigabyte.
        """
        from skfem import Basis

        return Basis(self.mesh, self.element, intorder=2 * self.degree)

    @cached_property
    def _quad_values(self) -> np.ndarray:
        return np.stack([np.asarray(b[0]) for b in self.quad_basis.basis])  # (nbf, ne, nq)

    @cached_property
    def _quad_grads(self) -> np.ndarray:
        return np.stack([b[0].grad for b in self.quad_basis.basis])  # (nbf, d, ne, nq)

    @property
    def quad_dx(self) -> np.ndarray:
        return np.asarray(self.quad_basis.dx)  # (ne, nq)

    @cached_property
    def quad_points(self) -> np.ndarray:
        """Quadrature points (d, ne, nq) of the degree-2p rule."""
        return np.asarray(self.quad_basis.global_coordinates())

    @cached_property
    def cell_volumes(self) -> np.ndarray:
        return np.asarray(self.grad_basis.dx).sum(axis=1)

    # -- matrices -------------------------------------------------------------------------------
    def stiffness(self, lam: float, mu: float) -> sp.csr_matrix:
        """K of (2.3) for Lamé constants lam, mu (constant over the mesh)."""
        d = self.dim
        G = np.stack([b[0].grad for b in self.grad_basis.basis])  # (nbf, d, ne, nq)
        G = G * np.sqrt(np.asarray(self.grad_basis.dx))[None, None]  # dx > 0: split it evenly
        trace = np.einsum("iceq,jceq->ije", G, G)
        blocks = np.empty((self.nnz_scalar, d, d))
        for a in range(d):
            for b in range(d):
                P = np.einsum("ieq,jeq->ije", G[:, a], G[:, b])  # int d_a phi_i d_b phi_j
                local = lam * P + mu * P.transpose(1, 0, 2)
                if a == b:
                    local += mu * trace
                blocks[:, a, b] = self._scatter(local)
        return self.block_matrix(blocks)

    @cached_property
    def scalar_mass_values(self) -> np.ndarray:
        """Values of the scalar mass int phi_i phi_j on the scalar pattern (exact)."""
        if self.degree == 1:
            # closed form for P1 simplices: |T| (1 + delta_ij) / ((d + 1)(d + 2))
            nbf = self.dim + 1
            ref = (np.ones((nbf, nbf)) + np.eye(nbf)) / ((self.dim + 1) * (self.dim + 2))
            local = ref[:, :, None] * self.cell_volumes[None, None, :]
        else:
            N = self._quad_values
            local = np.einsum("ieq,jeq,eq->ije", N, N, self.quad_dx)
        return self._scatter(local)

    def scalar_mass(self) -> sp.csr_matrix:
        return self.scalar_matrix(self.scalar_mass_values)

    def mass(self) -> sp.csr_matrix:
        """Vector mass M = (scalar mass) x I_d, density 1."""
        d = self.dim
        blocks = self.scalar_mass_values[:, None, None] * np.eye(d)[None]
        return self.block_matrix(blocks)

    def coefficient_mass(self, C: np.ndarray) -> sp.csr_matrix:
        """Matrix of  int (C(x) u) . v dx  for a d x d field C given at the quadrature points.

        C has shape (d, d, ne, nq) (degree-2p rule, :attr:`quad_points`).
        """
        d = self.dim
        N = self._quad_values
        w = self.quad_dx
        blocks = np.empty((self.nnz_scalar, d, d))
        for a in range(d):
            for b in range(d):
                blocks[:, a, b] = self._scatter(np.einsum("ieq,jeq,eq->ije", N, N, w * C[a, b]))
        return self.block_matrix(blocks)

    # -- fields at quadrature points ------------------------------------------------------------
    def values_at_quad(self, u: np.ndarray) -> np.ndarray:
        """u_h at the quadrature points: shape (d, ne, nq)."""
        U = np.asarray(u).reshape(self.n_scalar, self.dim)
        N = self._quad_values
        return np.stack([np.einsum("ieq,ie->eq", N, U[self.element_dofs, c])
                         for c in range(self.dim)])

    def gradients_at_quad(self, u: np.ndarray) -> np.ndarray:
        """grad u_h at the quadrature points: shape (d, d, ne, nq), [c, k] = d_k u_c."""
        U = np.asarray(u).reshape(self.n_scalar, self.dim)
        G = self._quad_grads
        return np.stack([np.einsum("ikeq,ie->keq", G, U[self.element_dofs, c])
                         for c in range(self.dim)])

    def load_from_quad(self, f: np.ndarray) -> np.ndarray:
        """The load vector int f . phi dx for f given at the quadrature points (d, ne, nq)."""
        N = self._quad_values
        local = np.einsum("ieq,eq,ceq->cie", N, self.quad_dx, f)
        out = np.empty((self.n_scalar, self.dim))
        flat = self.element_dofs.ravel()
        for c in range(self.dim):
            out[:, c] = np.bincount(flat, weights=local[c].ravel(), minlength=self.n_scalar)
        return out.ravel()

    def integrate(self, values: np.ndarray) -> float:
        """int over the domain of a scalar field given at the quadrature points (ne, nq)."""
        return float(np.sum(values * self.quad_dx))

    # -- boundary -------------------------------------------------------------------------------
    def part_names(self) -> list[str]:
        return sorted((self.mesh.boundaries or {}).keys())

    def facets(self, parts, name: str = "parts") -> np.ndarray:
        """Facet indices of the named boundary parts (one-line error for an unknown name)."""
        known = self.mesh.boundaries or {}
        out = []
        for part in parts:
            if part not in known:
                allowed = ", ".join(sorted(known)) if known else "(the mesh has no named parts)"
                raise fail(name, part, f"must be one of {allowed} (boundary parts of the mesh)")
            out.append(np.asarray(known[part], dtype=np.int64))
        return np.unique(np.concatenate(out)) if out else np.zeros(0, dtype=np.int64)

    def scalar_dofs_on(self, parts, name: str = "parts") -> np.ndarray:
        """Sorted scalar dofs on the closure of the named parts (vertices and, for P2, edges)."""
        facets = self.facets(parts, name)
        if facets.size == 0:
            return np.zeros(0, dtype=np.int64)
        if self.degree == 1:
            # P1: the dofs are the facets' vertices (scikit-fem's get_dofs would first build the
            # edge structures of the whole mesh, seconds at a million unknowns)
            return np.unique(self.mesh.facets[:, facets]).astype(np.int64)
        return np.unique(np.asarray(self.grad_basis.get_dofs(facets).all(), dtype=np.int64))

    def vector_dofs(self, scalar_dofs: np.ndarray) -> np.ndarray:
        """Interleaved vector dofs of a set of scalar dofs (node-major: k0x, k0y, k1x, ...)."""
        s = np.asarray(scalar_dofs, dtype=np.int64)
        return (self.dim * s[:, None] + np.arange(self.dim)[None, :]).ravel()

    def facet_quadrature(self, parts, intorder: int | None = None,
                         name: str = "parts") -> FacetQuadrature:
        from skfem import FacetBasis

        facets = self.facets(parts, name)
        fb = FacetBasis(self.mesh, self.element, facets=facets,
                        intorder=2 * self.degree if intorder is None else intorder)
        return FacetQuadrature(
            values=np.stack([np.asarray(b[0]) for b in fb.basis]),
            dofs=np.asarray(fb.element_dofs),
            dx=np.asarray(fb.dx),
            x=np.asarray(fb.global_coordinates()),
            normals=np.asarray(fb.normals),
        )

    def boundary_scalar_mass(self, parts, name: str = "parts") -> sp.csr_matrix:
        """Scalar boundary mass int_Gamma phi_i phi_j ds over the named parts (n_scalar square)."""
        q = self.facet_quadrature(parts, name=name)
        nbf, nf = q.dofs.shape
        local = np.einsum("ifq,jfq,fq->ijf", q.values, q.values, q.dx)
        rows = np.broadcast_to(q.dofs[:, None, :], local.shape).ravel()
        cols = np.broadcast_to(q.dofs[None, :, :], local.shape).ravel()
        n = self.n_scalar
        return sp.coo_matrix((local.ravel(), (rows, cols)), shape=(n, n)).tocsr()

    # -- misc -----------------------------------------------------------------------------------
    def rigid_body_modes(self) -> np.ndarray:
        """Columns spanning the rigid motions (kernel of K): (ndofs, 3) in 2D, (ndofs, 6) in 3D."""
        d, n = self.dim, self.n_scalar
        x = self.doflocs
        if d == 2:
            modes = np.zeros((n, d, 3))
            modes[:, 0, 0] = 1.0
            modes[:, 1, 1] = 1.0
            modes[:, 0, 2], modes[:, 1, 2] = -x[1], x[0]
        else:
            modes = np.zeros((n, d, 6))
            for c in range(3):
                modes[:, c, c] = 1.0
            # rotations about the x, y and z axes: omega x r
            modes[:, 1, 3], modes[:, 2, 3] = -x[2], x[1]
            modes[:, 0, 4], modes[:, 2, 4] = x[2], -x[0]
            modes[:, 0, 5], modes[:, 1, 5] = -x[1], x[0]
        return modes.reshape(d * n, -1)

    def interpolate(self, field) -> np.ndarray:
        """Nodal interpolant of a vector field: ``field(x)`` with x (d, npts) returns (d, npts)."""
        vals = np.asarray(field(self.doflocs), dtype=float)
        vals = np.broadcast_to(vals, (self.dim, self.n_scalar)) if vals.ndim == 1 else vals
        return np.ascontiguousarray(vals.T).ravel()

    def vertex_values(self, u: np.ndarray) -> np.ndarray:
        """Values at the mesh vertices (npoints, d); scikit-fem numbers vertex dofs first."""
        return np.asarray(u).reshape(self.n_scalar, self.dim)[: self.mesh.p.shape[1]]

    def error_norms(self, u: np.ndarray, exact, grad_exact=None) -> dict:
        """L2 and H1-seminorm errors of u_h against exact(x) (d, ...) and grad_exact(x) (d, d, ...).

        Integrated with the degree-2p rule at the quadrature points.
        """
        x = self.quad_points
        diff = self.values_at_quad(u) - np.asarray(exact(x))
        out = {"l2": float(np.sqrt(self.integrate(np.sum(diff**2, axis=0))))}
        if grad_exact is not None:
            gdiff = self.gradients_at_quad(u) - np.asarray(grad_exact(x))
            out["h1_semi"] = float(np.sqrt(self.integrate(np.sum(gdiff**2, axis=(0, 1)))))
            out["h1"] = float(np.hypot(out["l2"], out["h1_semi"]))
        return out
