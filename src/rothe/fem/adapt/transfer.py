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
from ..topology import (
    barycentric,
    edge_structures,
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
        The vector matrix is ``kron(T_scalar, I)`` (:func:`interleave`).

    Returns a CSR matrix of shape (components * n_new, components * n_old). If the change
    changed nothing it is the identity.
    """
    _check(degree, components)
    p_old = change.old_points.T
    t_old = change.old_cells.T
    p_new = change.new_points.T
    t_new = change.new_cells.T
    d = p_old.shape[0]
    edofs_old, n_old = _dofs(change.old_cache, t_old, p_old.shape[1], degree)
    if not change.changed:
        return sp.identity(components * n_old, format="csr")
    edofs_new, n_new = _dofs(change.new_cache, t_new, p_new.shape[1], degree)

    start = change.old_start
    count = change.old_count
    # cells that did not change (the same vertices in the same order): their nodes map one to
    # one, which is most of the mesh in a typical adaptation
    unchanged = change.unchanged

    # nodes of unchanged cells take the value of the same node of the old cell
    nloc = edofs_new.shape[0]
    U = np.flatnonzero(unchanged)
    old_of_new = np.full(n_new, -1, dtype=np.int64)
    old_of_new[edofs_new[:, U].ravel()] = edofs_old[:, start[U]].ravel()
    rows_id = np.flatnonzero(old_of_new >= 0)
    cols_id = old_of_new[rows_id]
    # every other node: one representative (cell, local node) among the changed cells
    todo = np.flatnonzero(old_of_new < 0)
    changed = np.flatnonzero(~unchanged)
    rep_cell = np.empty(n_new, dtype=np.int64)
    rep_loc = np.empty(n_new, dtype=np.int64)
    rep_cell[edofs_new[:, changed].ravel()] = np.tile(changed, nloc)
    rep_loc[edofs_new[:, changed].ravel()] = np.repeat(np.arange(nloc), len(changed))
    rep_cell, rep_loc = rep_cell[todo], rep_loc[todo]

    bary = local_nodes(d, degree)  # (nloc, d+1)
    x = _node_points(p_new, t_new, bary, rep_cell, rep_loc)
    st, ct = start[rep_cell], count[rep_cell]
    n_todo = len(todo)
    if np.all(ct == 1):
        cell = st
        lam = barycentric(x, p_old, t_old, cell)
    else:
        rows = np.repeat(np.arange(n_todo), ct)
        offs = np.arange(len(rows)) - np.repeat(np.cumsum(ct) - ct, ct)
        cand = np.repeat(st, ct) + offs
        lam_all = barycentric(x[:, rows], p_old, t_old, cand)
        score = lam_all.min(axis=0)
        best = np.maximum.reduceat(score, np.cumsum(ct) - ct) if n_todo else score
        # the first candidate (in old cell order) reaching the best score of its node: the
        # containing cell (min lambda >= 0); on a shared face any of them gives equal weights
        idx = np.flatnonzero(score >= np.repeat(best, ct))[::-1]
        pick = np.empty(n_todo, dtype=np.int64)
        pick[rows[idx]] = idx
        cell = cand[pick]
        lam = lam_all[:, pick]
    lam = snap_dyadic(lam)
    vals = lagrange_values(lam, degree)  # (nloc_old, n_todo)
    cols = edofs_old[:, cell]
    keep = vals != 0.0
    # CSR directly (no COO sort): one entry in the identity rows, the nonzero weights in the rest
    cnt = np.zeros(n_new, dtype=np.int64)
    cnt[rows_id] = 1
    cnt[todo] = keep.sum(axis=0)
    indptr = np.concatenate([[0], np.cumsum(cnt)])
    indices = np.empty(indptr[-1], dtype=np.int64)
    data = np.empty(indptr[-1])
    indices[indptr[rows_id]] = cols_id
    data[indptr[rows_id]] = 1.0
    pos = indptr[todo][None, :] + np.cumsum(keep, axis=0) - 1
    indices[pos[keep]] = cols[keep]
    data[pos[keep]] = vals[keep]
    T = sp.csr_matrix((data, indices, indptr), shape=(n_new, n_old))
    T.sort_indices()
    return T if components == 1 else interleave(T, components)


def interleave(T: sp.csr_matrix, m: int) -> sp.csr_matrix:
    """kron(T, I_m) for a CSR matrix, built directly: row m*j + k holds T's row j with the
    columns m*i + k (component k of scalar dof i; interleaved vector dofs).

    Entry e of scalar row j (offset o = e - indptr[j], row length c_j) goes to position
    m * indptr[j] + k * c_j + o of the vector matrix: one pass, no sort.
    """
    T = sp.csr_matrix(T)
    n_rows, n_cols = T.shape
    indptr = T.indptr.astype(np.int64)
    cnt = np.diff(indptr)
    row = np.repeat(np.arange(n_rows), cnt)
    e = np.arange(indptr[-1])
    base = (m - 1) * indptr[row] + e  # m * indptr[j] + o
    indices = np.empty(m * indptr[-1], dtype=np.int64)
    data = np.empty(m * indptr[-1])
    for k in range(m):  # the m components, not a loop over dofs
        pos = base + k * cnt[row]
        indices[pos] = T.indices * m + k
        data[pos] = T.data
    indptr_v = np.concatenate([[0], np.cumsum(np.repeat(cnt, m))])
    return sp.csr_matrix((data, indices, indptr_v), shape=(m * n_rows, m * n_cols))


def _dofs(cache: dict, t: np.ndarray, n_points: int, degree: int):
    """Element dofs of P``degree`` on (t, n_points), kept in the mesh's cache.

    The edge numbering is shared with :attr:`AdaptiveMesh.mesh` (triangles: its facets; it is
    handed to the scikit-fem mesh, so a P2 basis built on it does not number the edges again).
    """
    key = ("lagrange_dofs", degree)
    if key not in cache:
        t2e = None
        if degree == 2:
            t2e = edge_numbering(cache, t, n_points)[1]
        cache[key] = lagrange_dofs(t, n_points, degree, t2e=t2e)
    return cache[key]


def edge_numbering(cache: dict, t: np.ndarray, n_points: int):
    """(edges, t2e) of the mesh (scikit-fem's numbering), computed once per mesh version."""
    if "edges" not in cache:
        cache["edges"] = edge_structures(t, n_points)
        mesh = cache.get("mesh")
        if mesh is not None and t.shape[0] == 4 and not hasattr(mesh, "_t2e"):
            mesh._edges = cache["edges"][0].astype(np.int32)
            mesh._t2e = cache["edges"][1].astype(np.int32)
    return cache["edges"]


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
    free P1 nodes of :class:`~rothe.ris.fem_problem.FERISProblem`), ``z_new = Tf @ z_old``
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
