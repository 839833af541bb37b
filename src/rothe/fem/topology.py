"""Combinatorics and geometry of simplex meshes, vectorized: facets, edges, P2 dofs, barycentrics.

Conventions (those of scikit-fem 12, so that arrays built here can be handed to its meshes):

* cells ``t`` have shape (d + 1, n_cells) (scikit-fem) or (n_cells, d + 1) (the forest of
  :mod:`rothe.fem.adapt.bisection`); functions here say which.
* the *face opposite local vertex j* of a cell is the facet spanned by its other d vertices;
* entities (edges, facets) are numbered by the lexicographic order of their sorted vertex
  tuples -- exactly scikit-fem's ``Mesh.build_entities`` (``np.unique(..., axis=1)``), so
  ``facets``, ``t2f``, ``edges``, ``t2e`` computed here equal scikit-fem's own, computed
  3-10x faster by sorting packed int64 keys instead of ``np.unique`` over columns;
* local facets of a cell in scikit-fem order: triangle [[0,1],[1,2],[0,2]], tetrahedron
  [[0,1,2],[0,1,3],[0,2,3],[1,2,3]]; local edges of a tetrahedron [[0,1],[1,2],[0,2],[0,3],
  [1,3],[2,3]] (``RefTri.facets``, ``RefTet.facets``, ``RefTet.edges``);
* P2 Lagrange dofs: vertex dofs first (dof = vertex index), then one dof per edge
  (triangles: per facet) numbered V + entity index, local order vertices then edges in the
  order above (scikit-fem's ``ElementTriP2`` / ``ElementTetP2``).
"""

from __future__ import annotations

import numpy as np

from .mesh import barycentric_gradients

#: local facets (as vertex lists) of a cell in scikit-fem order
SKFEM_FACETS = {
    2: np.array([[0, 1], [1, 2], [0, 2]]),
    3: np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]),
}
#: local edges of a cell in scikit-fem order (for triangles the edges are the facets; a segment
#: is its own edge: the P2 basis of a facet of a triangle, rothe.eld.interface.facet_basis)
SKFEM_EDGES = {
    1: np.array([[0, 1]]),
    2: SKFEM_FACETS[2],
    3: np.array([[0, 1], [1, 2], [0, 2], [0, 3], [1, 3], [2, 3]]),
}


def opposite_faces(d: int) -> np.ndarray:
    """(d + 1, d) local vertex lists: row j is the face opposite local vertex j."""
    return np.array([[k for k in range(d + 1) if k != j] for j in range(d + 1)])


def pack_rows(rows: np.ndarray, n: int) -> np.ndarray | None:
    """One int64 key per row of sorted non-negative ints < n, ordered lexicographically.

    Returns None when n^k does not fit in 63 bits (callers then fall back to lexsort).
    """
    k = rows.shape[1]
    if float(max(n, 2)) ** k >= 2.0**62:
        return None
    rows = rows.astype(np.int64, copy=False)
    key = rows[:, 0].copy()
    for c in range(1, k):
        key *= n
        key += rows[:, c]
    return key


def number_rows(rows: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Unique ids of the rows (each row sorted): (unique_rows (m, k), ids (len(rows),)).

    Ids follow the lexicographic order of the rows (scikit-fem's entity numbering).
    """
    key = pack_rows(rows, n)
    if key is not None:
        ukey, first, inv = np.unique(key, return_index=True, return_inverse=True)
        return rows[first], inv.ravel()
    order = np.lexsort(rows.T[::-1])
    srt = rows[order]
    new = np.ones(len(srt), dtype=bool)
    new[1:] = np.any(srt[1:] != srt[:-1], axis=1)
    ids_sorted = np.cumsum(new) - 1
    ids = np.empty(len(rows), dtype=np.int64)
    ids[order] = ids_sorted
    return srt[new], ids


def entities(t: np.ndarray, local: np.ndarray, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Entities spanned by the local vertex lists ``local`` of every cell of t (d+1, nc).

    Returns (entities (k, m) sorted vertex tuples, t2e (len(local), nc)), as scikit-fem's
    ``build_entities``.
    """
    nc = t.shape[1]
    rows = np.sort(np.concatenate([t[loc] for loc in local], axis=1).T, axis=1)
    uniq, ids = number_rows(rows, n_points)
    return np.ascontiguousarray(uniq.T), ids.reshape(len(local), nc)


def facet_structures(t: np.ndarray, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """scikit-fem's (``facets``, ``t2f``) of a triangle/tetrahedron mesh with cells t (d+1, nc)."""
    d = t.shape[0] - 1
    return entities(t, SKFEM_FACETS[d], n_points)


def edge_structures(t: np.ndarray, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """scikit-fem's (``edges``, ``t2e``) of a tetrahedron mesh (for triangles: the facets)."""
    d = t.shape[0] - 1
    return entities(t, SKFEM_EDGES[d], n_points)


def lagrange_dofs(
    t: np.ndarray, n_points: int, degree: int, t2e: np.ndarray | None = None
) -> tuple[np.ndarray, int]:
    """(element_dofs (n_local, nc), n_dofs) of scalar P1/P2 in scikit-fem's numbering."""
    if degree == 1:
        return np.asarray(t, dtype=np.int64), int(n_points)
    if t2e is None:
        _, t2e = edge_structures(t, n_points)
    n_edges = int(t2e.max()) + 1 if t2e.size else 0
    return np.vstack([np.asarray(t, dtype=np.int64), n_points + t2e]), int(n_points + n_edges)


def local_nodes(d: int, degree: int) -> np.ndarray:
    """Barycentric coordinates (n_local, d + 1) of the local Lagrange nodes (scikit-fem order)."""
    eye = np.eye(d + 1)
    if degree == 1:
        return eye
    mids = np.array([(eye[a] + eye[b]) / 2 for a, b in SKFEM_EDGES[d]])
    return np.vstack([eye, mids])


def lagrange_values(lam: np.ndarray, degree: int) -> np.ndarray:
    """Values of the local P1/P2 basis at points with barycentric coordinates lam (d+1, ...).

    P1: lam_i. P2: vertex i: lam_i (2 lam_i - 1); edge (a, b): 4 lam_a lam_b (scikit-fem order).
    Returns (n_local, ...).
    """
    if degree == 1:
        return lam
    d = lam.shape[0] - 1
    vert = lam * (2.0 * lam - 1.0)
    edge = np.stack([4.0 * lam[a] * lam[b] for a, b in SKFEM_EDGES[d]])
    return np.concatenate([vert, edge], axis=0)


def lagrange_gradients(lam: np.ndarray, glam: np.ndarray, degree: int) -> np.ndarray:
    """Gradients of the local P1/P2 basis: (n_local, d, ...).

    ``lam`` (d+1, n, ...) barycentric coordinates at the points, ``glam`` (d+1, d, n) the
    (cellwise constant) gradients of the barycentric coordinates; trailing point axes of lam
    broadcast against glam's cell axis.
    """
    extra = lam.ndim - 2
    g = glam.reshape(glam.shape + (1,) * extra)  # (d+1, d, n, 1...)
    if degree == 1:
        return np.broadcast_to(g, glam.shape[:2] + lam.shape[1:])
    d = lam.shape[0] - 1
    vert = (4.0 * lam - 1.0)[:, None] * g
    edge = np.stack([4.0 * (lam[a][None] * g[b] + lam[b][None] * g[a]) for a, b in SKFEM_EDGES[d]])
    return np.concatenate([vert, edge], axis=0)


def barycentric(
    points: np.ndarray,
    p: np.ndarray,
    t: np.ndarray,
    cells: np.ndarray,
    glam: np.ndarray | None = None,
) -> np.ndarray:
    """Barycentric coordinates (d+1, k) of points (d, k) in cells[i] (indices into t)."""
    if glam is None:
        glam, _ = barycentric_gradients(p, t[:, cells])
        G = glam
    else:
        G = glam[:, :, cells]
    x0 = p[:, t[0, cells]]
    diff = points - x0
    lam = np.einsum("jdk,dk->jk", G[1:], diff)
    return np.vstack([1.0 - lam.sum(axis=0, keepdims=True), lam])


def snap_dyadic(lam: np.ndarray, bits: int = 30, tol: float = 1e-9) -> np.ndarray:
    """Round barycentric coordinates to the nearest multiple of 2^-bits when within tol * 2^-bits.

    Points created by bisection (vertices and edge midpoints of descendants) have dyadic
    barycentric coordinates in every ancestor; rounding removes the round-off of the solve so
    that transfer weights are exactly 0, 1, 1/2, 3/8, ... and unchanged cells map by identity.
    """
    scale = float(2**bits)
    r = np.round(lam * scale)
    close = np.abs(lam * scale - r) <= tol * scale
    return np.where(close, r / scale, lam)


def cell_diameters(p: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Longest edge h_K of every cell: p (d, n), t (d+1, nc)."""
    k = t.shape[0]
    h2 = np.zeros(t.shape[1])
    for a in range(k):
        for b in range(a + 1, k):
            e = p[:, t[a]] - p[:, t[b]]
            h2 = np.maximum(h2, np.sum(e * e, axis=0))
    return np.sqrt(h2)


class FacetTopology:
    """Interior and boundary facets of a simplex mesh with the cells on either side.

    Built from the faces opposite each local vertex (scikit-fem's ``facets`` numbering).
    Attributes (f = facet index into ``facets``):

    ``facets`` (d, nf) sorted vertex tuples; ``cell_facets`` (d+1, nc): facet opposite local
    vertex j of each cell; ``interior`` (ni,) facet ids with two cells, ``inner_cells`` (2, ni)
    and ``inner_local`` (2, ni) the cells and the local vertex opposite the facet in each;
    ``boundary`` (nb,) facet ids with one cell, ``boundary_cells`` (nb,), ``boundary_local``
    (nb,).
    """

    def __init__(self, p: np.ndarray, t: np.ndarray):
        d = p.shape[0]
        nc = t.shape[1]
        faces = opposite_faces(d)
        self.facets, self.cell_facets = entities(t, faces, p.shape[1])
        nf = self.facets.shape[1]
        flat = self.cell_facets.ravel()  # index j * nc + c
        order = np.argsort(flat, kind="stable")
        counts = np.bincount(flat, minlength=nf)
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        cell_of = order % nc
        local_of = order // nc
        inner = np.flatnonzero(counts == 2)
        self.interior = inner
        self.inner_cells = np.vstack([cell_of[first[inner]], cell_of[first[inner] + 1]])
        self.inner_local = np.vstack([local_of[first[inner]], local_of[first[inner] + 1]])
        bnd = np.flatnonzero(counts == 1)
        self.boundary = bnd
        self.boundary_cells = cell_of[first[bnd]]
        self.boundary_local = local_of[first[bnd]]
        if np.any(counts > 2):
            raise ValueError(
                "mesh: a facet is shared by more than two cells (not a manifold simplicial mesh)"
            )
