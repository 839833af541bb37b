"""Transfer of P1/P2 (vector) fields between the meshes before and after an adaptation.

The transfer is **nodal interpolation** of the old finite element function at the Lagrange
nodes of the new mesh, assembled once as a sparse matrix T (n_new_dofs x n_old_dofs), so that
a stepper maps any number of history vectors by sparse products (``T @ U`` with the vectors
as columns):

    (T u)_j = u_h(x_j) = sum_i u_i phi_i^old(x_j),   x_j the j-th Lagrange node of the new mesh.

* **Refinement**: the new cells lie inside old cells, and P1/P2 on the old mesh is a subspace of
  P1/P2 on the new one (nested meshes), so the interpolant *is* the old function: the transfer
  is exact (tested to round-off with random fields and random marked sets). Each row has the
  d+1 (P1) or (d+1)(d+2)/2 (P2) basis values of the old cell containing x_j.
* **Coarsening**: every node of a coarser cell is a node of the finer mesh (a vertex, or the
  midpoint of an edge that was either bisected -- then it is a vertex -- or kept -- then it is
  a P2 edge node). So on coarsening the interpolation is an *injection*: each row has a single
  1, the new dofs take the old values at the same points.

Why interpolation and not the L2 projection on coarsening: (1) it keeps the values on the
boundary exactly -- the constraint S u = G of the ELD scheme (B u = G, Sec. 2.2.3) holds after
transfer on the new Dirichlet nodes with no correction, and for RIS the Dirichlet nodes stay
zero; (2) it is local (no solve with the coarse mass matrix) and exact on refinement; (3) on the
parts of the mesh that do not change it is the identity, bit for bit. What it does not keep:
integrals (mass, momentum, int z) and energies. The kinetic and elastic energy of an
interpolated field differ from the old ones (on coarsening usually less, because unresolved
oscillations are cut, but they can increase); the ELD ledger must book
E(T u) - E(u) as a transfer term, and the RIS descent test (3.2) must compare energies on the
new mesh after transfer (SPEC Sec. 7).

Weights are computed from barycentric coordinates of the nodes in the old cells, rounded to
dyadic numbers when within 1e-9 * 2^-30 of one (nodes created by bisection have dyadic
coordinates in every ancestor), so unchanged cells map by exact identities.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ...errors import fail
from .topology import (
    barycentric,
    barycentric_gradients,
    lagrange_dofs,
    lagrange_values,
    local_nodes,
    snap_dyadic,
)


def _check(degree, components):
    if degree not in (1, 2):
        raise fail("degree", degree, "must be 1 or 2")
    if components not in (1, 2, 3):
        raise fail("components", components, "must be 1 (scalar), 2 or 3 (vector)")


def transfer_matrix(change, degree: int = 1, components: int = 1) -> sp.csr_matrix:
    """Sparse T with (T u_old) the nodal interpolant of u_old on the new mesh.

    Parameters
    ----------
    change : :class:`~rothe.fem.adapt.bisection.MeshChange`
    degree : 1 | 2
        P1 or P2 Lagrange elements (scikit-fem's dof numbering: vertices, then edges).
    components : 1, 2 or 3
        1 for scalar fields; d for vector fields with *interleaved* dofs (component c of
        scalar dof k is ``components * k + c``, as :class:`rothe.fem.elasticity.VectorSpace`).
        The vector matrix is ``kron(T_scalar, I)``.

    Returns a CSR matrix of shape (components * n_new, components * n_old). If the change
    changed nothing it is the identity.
    """
    _check(degree, components)
    p_old = change.old_points.T
    t_old = change.old_cells.T
    p_new = change.new_points.T
    t_new = change.new_cells.T
    d = p_old.shape[0]
    edofs_old, n_old = lagrange_dofs(t_old, p_old.shape[1], degree)
    if not change.changed:
        return sp.identity(components * n_old, format="csr")
    edofs_new, n_new = lagrange_dofs(t_new, p_new.shape[1], degree)

    # one representative (cell, local node) per new dof
    nloc, nc = edofs_new.shape
    rep_cell = np.empty(n_new, dtype=np.int64)
    rep_loc = np.empty(n_new, dtype=np.int64)
    rep_cell[edofs_new.ravel()] = np.tile(np.arange(nc), nloc)
    rep_loc[edofs_new.ravel()] = np.repeat(np.arange(nloc), nc)
    bary = local_nodes(d, degree)  # (nloc, d+1)
    x = _node_points(p_new, t_new, bary, rep_cell, rep_loc)

    start = change.old_start[rep_cell]
    count = change.old_count[rep_cell]
    glam, _ = barycentric_gradients(p_old, t_old)
    if np.all(count == 1):
        cell = start
        lam = barycentric(x, p_old, t_old, cell, glam)
    else:
        rows = np.repeat(np.arange(n_new), count)
        offs = np.arange(len(rows)) - np.repeat(np.cumsum(count) - count, count)
        cand = np.repeat(start, count) + offs
        lam_all = barycentric(x[:, rows], p_old, t_old, cand, glam)
        score = lam_all.min(axis=0)
        seg = np.cumsum(count) - count
        best = np.maximum.reduceat(score, seg)
        # the first candidate (in old cell order) reaching the best score of its node: the
        # containing cell (min lambda >= 0); on a shared face any of them gives equal weights
        idx = np.flatnonzero(score >= np.repeat(best, count))[::-1]
        pick = np.empty(n_new, dtype=np.int64)
        pick[rows[idx]] = idx
        cell = cand[pick]
        lam = lam_all[:, pick]
    lam = snap_dyadic(lam)
    vals = lagrange_values(lam, degree)  # (nloc_old, n_new)
    cols = edofs_old[:, cell]  # (nloc_old, n_new)
    rows = np.broadcast_to(np.arange(n_new), vals.shape)
    keep = vals != 0.0
    T = sp.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(n_new, n_old))
    T.sum_duplicates()
    T.sort_indices()
    if components > 1:
        T = sp.kron(T, sp.identity(components, format="csr"), format="csr")
    return T


def _node_points(p, t, bary, rep_cell, rep_loc):
    """Coordinates (d, n) of the Lagrange nodes from their cells' vertices."""
    d = p.shape[0]
    w = bary[rep_loc]  # (n, d+1)
    x = np.zeros((d, len(rep_cell)))
    for k in range(d + 1):
        wk = w[:, k]
        nz = wk != 0.0
        x[:, nz] += wk[nz] * p[:, t[k, rep_cell[nz]]]
    return x


def free_transfer(T: sp.spmatrix, old_free: np.ndarray, new_free: np.ndarray) -> sp.csr_matrix:
    """The transfer restricted to free dofs: rows ``new_free``, columns ``old_free``.

    For a state stored on the free dofs only with zeros on the Dirichlet dofs (RIS: z on the
    free P1 nodes of :class:`~rothe.problems.ris_fem.FERISProblem`), ``z_new = Tf @ z_old``
    equals ``(T @ full(z_old))[new_free]`` because the dropped columns multiply zeros.
    """
    T = sp.csr_matrix(T)
    return sp.csr_matrix(T[np.asarray(new_free)][:, np.asarray(old_free)])


def transfer_vectors(T: sp.spmatrix, *vectors: np.ndarray) -> list[np.ndarray]:
    """Map several dof vectors with one sparse product (columns stacked)."""
    if not vectors:
        return []
    U = np.column_stack([np.asarray(v, dtype=float) for v in vectors])
    V = T @ U
    return [np.ascontiguousarray(V[:, k]) for k in range(V.shape[1])]
