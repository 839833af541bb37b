"""Scalar P1 finite elements on simplices: stiffness, mass, lumped mass, Dirichlet selection.

All assembly is vectorized over cells with numpy element kernels (no Python loop over cells or
nodes). On a simplex K with vertices x_0..x_d and barycentric coordinates lambda_j,

    grad lambda_j = const on K,  (grad lambda_1, ..., grad lambda_d) = B^{-T},  B = [x_1-x_0, ...],
    grad lambda_0 = -(grad lambda_1 + ... + grad lambda_d),

so the element stiffness of a(u, v) = int c grad u . grad v with c constant on K is
c_K |K| G G^T (G the (d+1) x d matrix of the gradients), the element mass is
|K| (1 + delta_ij) / ((d + 1)(d + 2)) and the lumped (row-sum) mass is |K| / (d + 1) at each
vertex. The lumped mass m_i therefore equals int phi_i exactly (the row sum of the consistent
mass matrix), which is what makes ``m_i * c`` the exact nodal functional of a constant load c.

A coefficient ``c`` may be a positive number, an array of one value per cell, or a callable
``c(x)`` evaluated at the cell barycentres x (shape (d, n_cells)): piecewise constant in all
cases, which keeps the stiffness exact for P1.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..errors import fail
from .mesh import (
    BOX_PARTS,
    bad,
    barycentric_gradients,
    boundary_facets,
    box_part_nodes,
    cell_volumes,
)


def cell_coefficient(mesh, coefficient, name: str = "coefficient") -> np.ndarray:
    """Per-cell values of a piecewise constant coefficient (see module docstring)."""
    nc = mesh.t.shape[1]
    if callable(coefficient):
        centroids = mesh.p[:, mesh.t].mean(axis=1)
        c = np.asarray(coefficient(centroids), dtype=float)
        c = np.broadcast_to(c, (nc,)) if c.ndim == 0 else c
    else:
        c = np.asarray(coefficient, dtype=float)
        if c.ndim == 0:
            c = np.full(nc, float(c))
    if c.shape != (nc,):
        raise bad(
            name,
            f"an array of shape {c.shape}",
            f"must be a number, a callable or one value per cell ({nc})",
        )
    ok = np.isfinite(c) & (c > 0)
    if not np.all(ok):
        raise fail(name, float(c[~ok][0]), "must be finite and > 0 in every cell")
    return np.asarray(c, dtype=float)


def _assemble(mesh, local: np.ndarray) -> sp.csr_matrix:
    """Sum element matrices, laid out (d+1, d+1, n_cells), into a CSR matrix."""
    t = mesh.t
    k, nc = t.shape
    rows = np.broadcast_to(t[:, None, :], (k, k, nc)).ravel()
    cols = np.broadcast_to(t[None, :, :], (k, k, nc)).ravel()
    n = mesh.p.shape[1]
    A = sp.coo_matrix((local.ravel(), (rows, cols)), shape=(n, n)).tocsr()
    A.sum_duplicates()
    A.sort_indices()
    return A


def stiffness(mesh, coefficient=1.0) -> sp.csr_matrix:
    """K_ij = int c grad phi_j . grad phi_i over all nodes (no boundary condition applied)."""
    c = cell_coefficient(mesh, coefficient)
    G, vol = barycentric_gradients(mesh.p, mesh.t)
    cv = c * vol
    k = G.shape[0]
    local = np.empty((k, k, G.shape[2]))
    for i in range(k):  # (d+1)^2 / 2 vector operations over all cells, not a loop over cells
        for j in range(i, k):
            local[i, j] = cv * np.sum(G[i] * G[j], axis=0)
            local[j, i] = local[i, j]
    return _assemble(mesh, local)


def mass(mesh) -> sp.csr_matrix:
    """Consistent mass M_ij = int phi_i phi_j."""
    d = mesh.p.shape[0]
    vol = cell_volumes(mesh)
    ref = (np.ones((d + 1, d + 1)) + np.eye(d + 1)) / ((d + 1) * (d + 2))
    return _assemble(mesh, ref[:, :, None] * vol[None, None, :])


def lumped_mass(mesh) -> np.ndarray:
    """m_i = int phi_i = sum over cells at node i of |K| / (d + 1) (row sums of :func:`mass`)."""
    d = mesh.p.shape[0]
    vol = cell_volumes(mesh)
    n = mesh.p.shape[1]
    # mesh.t.ravel() lists t[0, :], t[1, :], ...: every vertex slot of every cell once
    return np.bincount(mesh.t.ravel(), weights=np.tile(vol / (d + 1), d + 1), minlength=n)


def boundary_nodes(mesh, parts=None) -> np.ndarray:
    """Sorted node indices on the whole boundary (``parts=None``) or on named boundary parts.

    Named parts are scikit-fem boundaries (``mesh.boundaries``: facet indices), e.g. from gmsh
    physical groups (:func:`rothe.fem.mesh.load_mesh`) or ``mesh.with_boundaries(...)``. A mesh
    without named parts offers the sides of its bounding box under scikit-fem's default names
    (``left``, ``right``, ``bottom``, ``top``, ``front``, ``back``; see
    :func:`rothe.fem.mesh.box_part_nodes`).
    """
    if parts is None:
        return np.unique(boundary_facets(mesh)).astype(np.int64)
    if isinstance(parts, str):
        parts = [parts]
    parts = list(parts)
    if not parts:
        raise bad("dirichlet", "an empty list", "name at least one boundary part")
    known = dict(mesh.boundaries or {})
    if known:
        for part in parts:
            if part not in known:
                raise fail("dirichlet", part, f"must be one of {', '.join(sorted(known))}")
        f = np.concatenate([np.asarray(known[part], dtype=np.int64) for part in parts])
        return np.unique(mesh.facets[:, f]).astype(np.int64)
    box = [name for name, (axis, _) in BOX_PARTS.items() if axis < mesh.p.shape[0]]
    for part in parts:
        if part not in box:
            raise fail(
                "dirichlet",
                part,
                f"must be one of {', '.join(sorted(box))} (sides of "
                "the bounding box; the mesh has no named parts)",
            )
    facets = boundary_facets(mesh)
    return np.unique(np.concatenate([box_part_nodes(mesh, part, facets) for part in parts]))


def split_dofs(n_nodes: int, fixed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(free, fixed) node index arrays: the complement of ``fixed`` and ``fixed`` itself."""
    mask = np.ones(n_nodes, dtype=bool)
    mask[fixed] = False
    return np.nonzero(mask)[0], np.asarray(fixed, dtype=np.int64)


def nodal_values(mesh, f) -> np.ndarray:
    """Nodal values of f: a number, an (n_nodes,) array, or a callable f(x), x of shape (d, n)."""
    n = mesh.p.shape[1]
    if callable(f):
        v = np.asarray(f(mesh.p), dtype=float)
    else:
        v = np.asarray(f, dtype=float)
    return np.broadcast_to(v, (n,)).astype(float) if v.ndim == 0 else v
