"""Vectorized evaluation of P1/P2 fields on cells and facets, for residual error indicators.

:class:`SimplexEvaluator` holds, for one triangle/tetrahedron mesh and degree, what every
residual indicator needs: barycentric gradients and volumes of the cells, cell diameters h_K,
the element dofs (scikit-fem numbering), quadrature on the cells and on the facets, and the
facet topology (which cells meet at each interior facet, which facets are on the boundary).
Everything is one numpy pass over all cells or facets: no loop over cells or facets.

Geometry used by the indicators: on a cell K with barycentric coordinates lambda_j,
|F_j| = d |K| |grad lambda_j| for the face F_j opposite vertex j, and the outward unit normal of
K on F_j is n = -grad lambda_j / |grad lambda_j|.

Weights (Verfuerth's robust weights for -div(s grad u) + kappa u): for a cell or facet S,

    alpha_S = min(h_S / sqrt(s), 1 / sqrt(kappa))      (= h_S / sqrt(s) when kappa = 0),

and the indicator of a cell collects alpha_K^2 ||R_K||^2_K, half of s^{-1/2} alpha_F ||J_F||^2_F
for each interior face and s^{-1/2} alpha_F ||J_F||^2_F for each face on the Neumann boundary.
With kappa = 0 this is the classical (h_K ||R_K||, h_F^{1/2} ||J_F||) estimator divided by
sqrt(s), so that it estimates the energy norm (s ||grad e||^2 + kappa ||e||^2)^{1/2} directly.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..errors import fail
from .topology import (
    FacetTopology,
    barycentric_gradients,
    cell_diameters,
    lagrange_dofs,
    lagrange_gradients,
    lagrange_values,
)


def _rule(dim_ref: int, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric points (dim_ref + 1, nq) and weights summing to 1 on a reference simplex."""
    from skfem.quadrature import get_quadrature  # heavy: imported when first needed (start-up time)
    from skfem.refdom import (  # heavy: imported when first needed (start-up time)
        RefLine,
        RefTet,
        RefTri,
    )

    if dim_ref == 0:
        return np.ones((1, 1)), np.ones(1)
    ref = {1: RefLine, 2: RefTri, 3: RefTet}[dim_ref]
    X, W = get_quadrature(ref, max(order, 1))
    lam = np.vstack([1.0 - X.sum(axis=0, keepdims=True), X])
    return lam, W / W.sum()


@dataclass
class CellIndicators:
    """Error indicators per cell and their parts (all arrays (n_cells,)).

    ``eta`` = sqrt(cell + jump + boundary); ``cell``, ``jump`` and ``boundary`` are the squared
    contributions of the cell residual, of the interior facet jumps (half of each facet to
    each side) and of the Neumann facets; ``estimate`` = sqrt(sum eta^2).
    """

    eta: np.ndarray
    cell: np.ndarray
    jump: np.ndarray
    boundary: np.ndarray

    @property
    def estimate(self) -> float:
        return float(np.sqrt(np.sum(self.eta**2)))

    def describe(self) -> dict:
        """The estimate, the cell, jump and boundary parts ((sum of squares)^(1/2) each) and the
        largest eta_K.
        """
        return {
            "estimate": self.estimate,
            "cell": float(np.sqrt(self.cell.sum())),
            "jump": float(np.sqrt(self.jump.sum())),
            "boundary": float(np.sqrt(self.boundary.sum())),
            "max_eta": float(self.eta.max(initial=0.0)),
        }


#: cells per chunk of :meth:`SimplexEvaluator.vertex_gradients`
VERTEX_CHUNK = 1024


class SimplexEvaluator:
    """Geometry, dofs, quadrature and facet topology of a P1/P2 mesh (see the module doc)."""

    def __init__(
        self, mesh, degree: int = 1, cell_order: int | None = None, facet_order: int | None = None
    ):
        self.mesh = mesh
        self.p = np.asarray(mesh.p, dtype=float)
        self.t = np.asarray(mesh.t, dtype=np.int64)
        self.dim = self.p.shape[0]
        self.degree = int(degree)
        self.glam, self.vol = barycentric_gradients(self.p, self.t)
        self.h = cell_diameters(self.p, self.t)
        self.edofs, self.ndofs = lagrange_dofs(self.t, self.p.shape[1], self.degree)
        self.cell_lam, self.cell_w = _rule(self.dim, cell_order or 2 * self.degree + 2)
        self.facet_lam, self.facet_w = _rule(self.dim - 1, facet_order or 2 * self.degree)

    @cached_property
    def topology(self) -> FacetTopology:
        """The facet topology (:class:`FacetTopology`) of the evaluator's mesh."""
        return FacetTopology(self.p, self.t)

    # -- cells ----------------------------------------------------------------------------------
    @cached_property
    def cell_points(self) -> np.ndarray:
        """Quadrature points (d, nc, nq) of the cell rule."""
        return self.cell_points_of(slice(None))

    def cell_points_of(self, cells) -> np.ndarray:
        """Quadrature points (d, n, nq) of the cell rule on ``cells`` (indices or a slice)."""
        X = self.p[:, self.t[:, cells]]  # (d, d+1, n)
        return np.einsum("dkc,kq->dcq", X, self.cell_lam)

    @property
    def cell_dx(self) -> np.ndarray:
        """Weights (nc, nq) (|K| included)."""
        return self.vol[:, None] * self.cell_w[None, :]

    def values(self, U: np.ndarray, cells=slice(None)) -> np.ndarray:
        """Field values at the cell points: U (ndofs,) -> (nc, nq); (ndofs, m) -> (m, nc, nq);
        only on ``cells`` (indices or a slice) if given."""
        phi = lagrange_values(self.cell_lam, self.degree)  # (nloc, nq)
        U = np.asarray(U, dtype=float)
        if U.ndim == 1:
            return np.einsum("kc,kq->cq", U[self.edofs[:, cells]], phi)
        return np.einsum("kcm,kq->mcq", U[self.edofs[:, cells]], phi)

    def gradients(self, U: np.ndarray) -> np.ndarray:
        """grad u at the cell points: (ndofs,) -> (d, nc, nq); (ndofs, m) -> (m, d, nc, nq)."""
        nc = self.t.shape[1]
        lam = np.broadcast_to(self.cell_lam[:, None, :], (self.dim + 1, nc, len(self.cell_w)))
        dphi = lagrange_gradients(lam, self.glam, self.degree)  # (nloc, d, nc, nq)
        U = np.asarray(U, dtype=float)
        if U.ndim == 1:
            return np.einsum("kc,kdcq->dcq", U[self.edofs], dphi)
        return np.einsum("kcm,kdcq->mdcq", U[self.edofs], dphi)

    def hessians(self, U: np.ndarray, gv: np.ndarray | None = None) -> np.ndarray:
        """Cellwise constant Hessians of P2 fields: (ndofs,) -> (d, d, nc); (ndofs, m) -> (m, ...).

        grad u is affine on K, so H (x_k - x_0) = grad u(x_k) - grad u(x_0) for the edges from
        vertex 0: H = [grad u(x_k) - grad u(x_0)]_k E^{-1}, E = [x_1 - x_0, ...]. Zero for P1.
        ``gv``: U's :meth:`vertex_gradients` if the caller has them already.
        """
        U = np.asarray(U, dtype=float)
        d, nc = self.dim, self.t.shape[1]
        shape = (d, d, nc) if U.ndim == 1 else (U.shape[1], d, d, nc)
        if self.degree == 1:
            return np.zeros(shape)
        g = self.vertex_gradients(U) if gv is None else gv  # (m, d, nc, vertex)
        dg = g[..., 1:] - g[..., :1]  # (m, d_grad, nc, k)
        # E^{-1} = rows grad lambda_1..d: (E^{-1})_{k,j} = d_j lambda_{k+1}
        Einv = self.glam[1:]  # (k, j, nc)
        H = np.einsum("mick,kjc->mijc", dg, Einv)
        H = 0.5 * (H + H.transpose(0, 2, 1, 3))
        return H[0] if U.ndim == 1 else H

    def vertex_gradients(self, U: np.ndarray) -> np.ndarray:
        """grad u at the d+1 vertices of every cell: (ndofs,) or (ndofs, m) -> (m, d, nc, d+1).

        grad u of a P1/P2 field is affine on each cell, so these values give it everywhere in
        the cell: grad u(x) = sum_v lambda_v(x) grad u(x_v) (:meth:`gradients_from_vertices`)."""
        U = np.asarray(U, dtype=float)
        d, nc = self.dim, self.t.shape[1]
        eye = np.eye(d + 1)
        Um = U[:, None] if U.ndim == 1 else U
        out = np.empty((Um.shape[1], d, nc, d + 1))
        # in chunks of VERTEX_CHUNK cells: the basis gradients (nloc, d, n, d+1) and the
        # contraction's copies of them, 14 MB at 6k P2 tetrahedra in one piece, were the peak of
        # the estimate phase of an adaptive 3D run (each cell's values are its own)
        for k0 in range(0, nc, VERTEX_CHUNK):
            c = slice(k0, min(k0 + VERTEX_CHUNK, nc))
            n = c.stop - c.start
            lam = np.broadcast_to(eye[:, None, :], (d + 1, n, d + 1))  # vertex k: lambda = e_k
            dphi = lagrange_gradients(lam, self.glam[:, :, c], self.degree)  # (nloc, d, n, d+1)
            # optimize: a BLAS contraction, 2-3x faster than the plain loop at 4k P2 cells
            out[:, :, c] = np.einsum("kcm,kdcv->mdcv", Um[self.edofs[:, c]], dphi, optimize=True)
        return out

    @staticmethod
    def gradients_from_vertices(gv: np.ndarray, cells: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """grad u at barycentric points lam (d+1, n, nq) of cells (n,) from its vertex values
        ``gv`` (m, d, nc, d+1) (:meth:`vertex_gradients`): sum_v lam_v grad u(x_v), exact for
        P1/P2 (the gradient is affine); (m, d, n, nq). The same values as :meth:`gradients_at`
        with d+1 terms per point instead of the n_local basis gradients."""
        return np.einsum("mdnv,vnq->mdnq", gv[:, :, cells], lam, optimize=True)

    # -- facets ---------------------------------------------------------------------------------
    def facet_geometry(self, cells: np.ndarray, local: np.ndarray):
        """(measure (nf,), outward unit normal (d, nf), diameter (nf,)) of the faces opposite
        local vertex ``local`` of ``cells``."""
        g = self.glam[local, :, cells].T  # (d, nf)
        norm = np.sqrt(np.sum(g * g, axis=0))
        measure = self.dim * self.vol[cells] * norm
        normal = -g / norm
        # facet diameter: longest edge among the facet's vertices
        verts = np.array([[k for k in range(self.dim + 1) if k != j] for j in range(self.dim + 1)])[
            local
        ]  # (nf, d)
        pts = self.p[:, np.take_along_axis(self.t[:, cells].T, verts, axis=1)]  # (d, nf, d)
        h2 = np.zeros(len(cells))
        for a in range(self.dim):
            for b in range(a + 1, self.dim):
                e = pts[:, :, a] - pts[:, :, b]
                h2 = np.maximum(h2, np.sum(e * e, axis=0))
        diam = np.sqrt(h2) if self.dim > 1 else np.ones(len(cells))
        return measure, normal, diam

    def facet_lambda(
        self, cells: np.ndarray, local: np.ndarray, facet_vertices: np.ndarray
    ) -> np.ndarray:
        """Barycentric coordinates (d+1, nf, nq) in ``cells`` of the facet quadrature points.

        The facet rule's coordinates refer to the facet vertices in the order of
        ``facet_vertices`` (d, nf), so both cells at an interior facet get the same points.
        """
        tc = self.t[:, cells]  # (d+1, nf)
        match = tc[:, None, :] == facet_vertices[None, :, :]  # (d+1 cell, d facet, nf)
        lam = np.einsum("kjf,jq->kfq", match.astype(float), self.facet_lam)
        return lam

    def facet_points(self, facet_vertices: np.ndarray) -> np.ndarray:
        """Points (d, nf, nq) of the facet rule on the facets with vertices (d, nf)."""
        X = self.p[:, facet_vertices]  # (d, d facet verts, nf)
        return np.einsum("djf,jq->dfq", X, self.facet_lam)

    def gradients_at(self, U: np.ndarray, cells: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """grad u at barycentric points lam (d+1, n, nq) of cells (n,): (m, d, n, nq)."""
        dphi = lagrange_gradients(lam, self.glam[:, :, cells], self.degree)  # (nloc,d,n,nq)
        U = np.asarray(U, dtype=float)
        Um = U[:, None] if U.ndim == 1 else U
        return np.einsum("knm,kdnq->mdnq", Um[self.edofs[:, cells]], dphi)

    def values_at(self, U: np.ndarray, cells: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """u at barycentric points lam (d+1, n, nq) of cells (n,): (m, n, nq)."""
        phi = lagrange_values(lam, self.degree)  # (nloc, n, nq)
        U = np.asarray(U, dtype=float)
        Um = U[:, None] if U.ndim == 1 else U
        return np.einsum("knm,knq->mnq", Um[self.edofs[:, cells]], phi)

    def boundary_part_mask(self, parts) -> np.ndarray:
        """Mask over ``topology.boundary`` of the facets in the named parts (mesh.boundaries)."""
        known = self.mesh.boundaries or {}
        sel = np.zeros(self.topology.facets.shape[1], dtype=bool)
        for part in parts:
            if part not in known:
                names = ", ".join(sorted(known)) or "(the mesh has no named parts)"
                raise fail("parts", part, f"must be one of {names}")
            sel[np.asarray(known[part], dtype=np.int64)] = True
        return sel[self.topology.boundary]


def robust_weight(h: np.ndarray, stiffness, reaction) -> np.ndarray:
    """alpha = min(h / sqrt(s), 1 / sqrt(kappa)) (h / sqrt(s) where kappa = 0), elementwise:
    s and kappa numbers or arrays like h (per cell or facet: a body of several materials)."""
    a = h / np.sqrt(stiffness)
    if np.ndim(reaction) == 0:
        return np.minimum(a, 1.0 / np.sqrt(reaction)) if reaction > 0 else a
    with np.errstate(divide="ignore"):
        return np.minimum(a, np.where(reaction > 0, 1.0 / np.sqrt(reaction), np.inf))


def assemble_indicators(
    ev: SimplexEvaluator,
    cell_sq: np.ndarray,
    inner_sq: np.ndarray,
    inner_cells: np.ndarray,
    bnd_sq: np.ndarray,
    bnd_cells: np.ndarray,
) -> CellIndicators:
    """Sum the squared parts per cell: interior facet terms half to each side."""
    nc = ev.t.shape[1]
    jump = 0.5 * (
        np.bincount(inner_cells[0], weights=inner_sq, minlength=nc)
        + np.bincount(inner_cells[1], weights=inner_sq, minlength=nc)
    )
    boundary = np.bincount(bnd_cells, weights=bnd_sq, minlength=nc)
    eta = np.sqrt(cell_sq + jump + boundary)
    return CellIndicators(eta=eta, cell=cell_sq, jump=jump, boundary=boundary)
