"""Several elastic bodies glued along an interface: B_1 u_1 - B_2 u_2 = 0 (issue 19).

Body 1's boundary part P_1 and body 2's part P_2 cover the same interface Gamma (each body
has its own mesh, material and element degree). The multiplier space is the trace space of
body 1 on P_1 (the *non-mortar* side, as in the mortar method) and the constraint is

    int_Gamma (u_1 - u_2) . mu ds = 0   for all mu in Q_h(P_1),
    i.e.  D S_1 u_1 = M_12 S_2 u_2,    D_ij = int phi_i phi_j ds,   (M_12)_ik = int phi_i psi_k ds,

with phi the side-1 and psi the side-2 trace bases (scalar; the vector form is Kronecker with
I_d on interleaved dofs). Hence S_1 u_1 = Pi S_2 u_2 with Pi = D^{-1} M_12, the L2 projection
onto body 1's trace space: body 1's interface values are *data that are unknowns* given by
body 2's -- the coupling B u = G(t, q) of :mod:`rothe.eld.coupling` with body 2 in the role
of the component (G = Pi S_2 u_2, linear, no curvature), and the same sign: B_1^T lambda on
body 1, -(Pi S_2)^T M_G lambda on body 2 (action = reaction).

- **Matching meshes** (``method="matching"``): the interface nodes pair up geometrically
  (a k-d tree; tolerance ``tol`` relative to the smallest interface facet) and Pi is the
  permutation of the pairs; with matching meshes the mortar Pi is that permutation too
  (tested).
- **Non-matching meshes** (``method="mortar"``): M_12 integrated exactly on the intersections
  of the facets of the two sides (2D: overlapping segments; 3D: the polygons of two coplanar
  triangles, clipped by Sutherland-Hodgman, vectorized over all candidate pairs, fan-
  triangulated, degree-4 rule), so Pi reproduces every field both trace spaces contain (the
  patch test: constants and linear fields exactly) and rows of M_12 sum to those of D;
  Pi = D^{-1} M_12 solved by blocks of columns into a sparse matrix, no dense k1 x k2
  (:func:`mortar_projection`).
- ``method="auto"`` (default): matching if every node pairs up, else mortar.

Refused with one line: a part that does not exist, bodies of different dimensions, a side-1
part that does not lie on the side-2 part (the meshes do not touch: the share of P_1 covered
by P_2 is stated), nodes that do not pair up when ``matching`` is asked for.

:meth:`Interface.substitution` gives T with (u_1, u_2) = T (x_1, u_2) for x_1 the values of
u_1 off P_1: the glued space. T^T blkdiag(K_1, K_2) T is the stiffness of the glued bodies
(with matching meshes: the union mesh's stiffness, tested) -- the monolithic alternative to
the multiplier. Glued bodies in time (:mod:`rothe.eld.bodies`) take the multiplier route: the
coupled step of :mod:`rothe.eld.coupled_step` with body 2 as the component (why: its
docstring).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.spatial import cKDTree

from ..errors import RotheInputError, described, fail
from ..fem.elasticity import VectorSpace
from ..fem.topology import lagrange_values

METHODS = ("auto", "matching", "mortar")
#: node pairing and coplanarity tolerance, relative to the smallest interface facet size
DEFAULT_TOL = 1e-8

# Gauss-Legendre on [0, 1] (exact to degree 7) and a degree-4 rule on the reference triangle
_GL_X, _GL_W = np.polynomial.legendre.leggauss(4)
_GL_X, _GL_W = 0.5 * (_GL_X + 1.0), 0.5 * _GL_W
_a, _b, _c, _d = 0.445948490915965, 0.091576213509771, 0.111690794839005, 0.054975871827661
_TRI_X = np.array(
    [[_a, _a], [1 - 2 * _a, _a], [_a, 1 - 2 * _a], [_b, _b], [1 - 2 * _b, _b], [_b, 1 - 2 * _b]]
)
_TRI_W = np.array([_c, _c, _c, _d, _d, _d])  # weights sum to 1/2 (the reference area)


#: columns of M_12 solved at once by :func:`mortar_projection` (its dense work array is
#: k1 x PI_BLOCK: 2 MB for k1 = 1000)
PI_BLOCK = 256
#: entries of Pi below this, relative to its largest, are dropped: the tail of D^{-1}, which
#: decays exponentially away from the overlap of the supports (round-off, not the projection)
PI_DROP = 1e-14


def mortar_projection(D: sp.spmatrix, M12: sp.spmatrix, block: int = PI_BLOCK) -> sp.csr_matrix:
    """The mortar (L2) projection Pi = D^{-1} M_12 onto body 1's trace space as a sparse
    (k1, k2) matrix, with no dense k1 x k2 array: one sparse LU of the side-1 mass D, then the
    columns of the sparse mixed mass M_12 (built from the facet pairs' overlaps,
    :meth:`Interface._mixed_mass`) solved ``block`` at a time, each block's entries below
    :data:`PI_DROP` times the largest so far dropped before it is stored sparse; a last pass
    drops those below PI_DROP times the largest of all. Every entry the dense formula
    (``lu.solve(M12.toarray())`` with the same drop) keeps is kept and every one it drops is
    dropped (a running maximum is never above the final one): the two agree to round-off
    (tested). Memory k1 x block + the entries kept, instead of k1 x k2 (docs/coupling.md,
    Sec. 16: on a 2D interface Pi itself is dense, D^{-1} decays slowly; dual multipliers would
    make it sparse)."""
    lu = spla.splu(sp.csc_matrix(D))
    M = sp.csc_matrix(M12)
    k1, k2 = M.shape
    data, rows, counts, top = [], [], [np.zeros(1, np.int64)], 0.0
    for start in range(0, k2, block):  # blocks of columns, not nodes: k2 / block solves
        X = lu.solve(M[:, start : start + block].toarray())
        top = max(top, float(np.abs(X).max(initial=0.0)))
        keep = np.abs(X) >= PI_DROP * top
        # column by column (CSC): the kept rows of each column of the block, in order
        cols, r = np.nonzero(keep.T)
        data.append(X.T[cols, r])
        rows.append(r.astype(np.int32))
        counts.append(np.bincount(cols, minlength=X.shape[1]))
    Pi = sp.csc_matrix(
        (
            np.concatenate(data or [np.zeros(0)]),
            np.concatenate(rows or [np.zeros(0, np.int32)]),
            np.cumsum(np.concatenate(counts)),
        ),
        shape=(k1, k2),
    )
    Pi.data[np.abs(Pi.data) < PI_DROP * max(top, 1e-300)] = 0.0
    Pi.eliminate_zeros()
    return Pi.tocsr()


def facet_dofs(space: VectorSpace, facets: np.ndarray) -> np.ndarray:
    """Scalar dofs of boundary facets (nloc, nf): the facet's vertices (in ``mesh.facets``
    order), then for P2 its edge midpoints (2D: m01; 3D: m01, m12, m02), found by exact
    lookup of the midpoints among the dof locations."""
    verts = np.asarray(space.mesh.facets)[:, facets]  # (d, nf)
    if space.degree == 1:
        return verts
    p = np.asarray(space.mesh.p)
    pairs = [(0, 1)] if space.dim == 2 else [(0, 1), (1, 2), (0, 2)]
    tree = cKDTree(space.doflocs.T)
    mids = []
    for i, j in pairs:
        x = 0.5 * (p[:, verts[i]] + p[:, verts[j]])
        mids.append(tree.query(x.T)[1])
    return np.vstack([verts] + mids)


def facet_basis(dim: int, degree: int, bary: np.ndarray) -> np.ndarray:
    """Values of the facet's Lagrange basis (order of :func:`facet_dofs`) at barycentric
    coordinates ``bary`` (d, ...): shape (nloc, ...). The facet is a simplex of dimension
    dim - 1: its basis is the general one, :func:`rothe.fem.topology.lagrange_values`
    (P2: lam_i (2 lam_i - 1) at the vertices, 4 lam_a lam_b on the edges, scikit-fem order)."""
    assert bary.shape[0] == dim
    return lagrange_values(bary, degree)


def _clip(poly: np.ndarray, count: np.ndarray, f) -> tuple[np.ndarray, np.ndarray]:
    """Sutherland-Hodgman: clip polygons (P, V, 2) with ``count`` vertices each by the half
    plane f(x) >= 0 (f linear, vectorized over points (..., 2)). Returns padded polygons with
    at most one more vertex."""
    P, V, _ = poly.shape
    out = np.zeros((P, V + 1, 2))
    n_out = np.zeros(P, dtype=np.int64)
    rows = np.arange(P)
    for k in range(V):
        active = k < count
        cur = poly[:, k]
        nxt = poly[rows, np.where(k + 1 < count, k + 1, 0)]
        fc, fn = f(cur), f(nxt)
        inside_c, inside_n = fc >= 0, fn >= 0
        # keep the current vertex if inside
        keep = active & inside_c
        out[rows[keep], n_out[keep]] = cur[keep]
        n_out += keep
        # add the crossing point if the edge crosses the line
        cross = active & (inside_c != inside_n)
        with np.errstate(divide="ignore", invalid="ignore"):  # s only used where they cross
            s = fc / (fc - fn)
            x = cur + s[:, None] * (nxt - cur)
        out[rows[cross], n_out[cross]] = x[cross]
        n_out += cross
    return out, n_out


class Interface:
    """B_1 u_1 - B_2 u_2 = 0 between ``part1`` of body 1 and ``part2`` of body 2 (module
    docstring).

    Parameters
    ----------
    space1, space2 : VectorSpace (or problems with ``.space``)
    part1, part2 : boundary part names
    method : 'auto' | 'matching' | 'mortar'
    tol : pairing / coplanarity tolerance relative to the smallest interface facet

    Attributes
    ----------
    dofs1, dofs2 : scalar dofs of the two parts (sorted)
    D, M12 : sparse (k1, k1), (k1, k2) (mortar; for matching D = M12 permuted)
    Pi : (k1, k2) sparse: S_1 u_1 = Pi S_2 u_2 (per component)
    method : the method used ('matching' or 'mortar')
    """

    def __init__(
        self,
        space1,
        part1: str,
        space2,
        part2: str,
        *,
        method: str = "auto",
        tol: float = DEFAULT_TOL,
        name: str = "interface",
    ):
        space1 = getattr(space1, "space", space1)
        space2 = getattr(space2, "space", space2)
        if method not in METHODS:
            raise fail(f"{name}.method", method, "must be one of " + ", ".join(METHODS))
        if space1.dim != space2.dim:
            raise fail(
                f"{name}.space2",
                described(f"a {space2.dim}D body"),
                f"must have the dimension of body 1 ({space1.dim}D)",
            )
        self.space1, self.space2 = space1, space2
        self.part1, self.part2 = part1, part2
        self.name = name
        self.facets1 = space1.facets((part1,), f"{name}.part1")
        self.facets2 = space2.facets((part2,), f"{name}.part2")
        self.dofs1 = space1.scalar_dofs_on((part1,), f"{name}.part1")
        self.dofs2 = space2.scalar_dofs_on((part2,), f"{name}.part2")
        if self.facets1.size == 0 or self.facets2.size == 0:
            raise fail(
                f"{name}.part1" if self.facets1.size == 0 else f"{name}.part2",
                part1 if self.facets1.size == 0 else part2,
                "must have facets",
            )
        self.h = min(
            self._sizes(space1, self.facets1).min(), self._sizes(space2, self.facets2).min()
        )
        self.abs_tol = tol * self.h
        self.tol = tol
        #: the method asked for (``method`` becomes the one used)
        self.requested = method
        self.method = method
        pairing = self._pair()
        if method == "matching" and pairing is None:
            raise RotheInputError(
                f"{name}: got parts {part1!r} and {part2!r} whose nodes do not pair up within "
                f"{self.abs_tol:.3g} ({self._unpaired} of {self.dofs1.size} nodes of {part1!r} "
                "have no partner), must be matching meshes; method='mortar' glues "
                "non-matching ones",
                name,
            )
        self.D = self._side1_mass()
        if pairing is not None and method != "mortar":
            k1, k2 = self.dofs1.size, self.dofs2.size
            self.Pi = sp.csr_matrix((np.ones(k1), (np.arange(k1), pairing)), shape=(k1, k2))
            self.M12 = (self.D @ self.Pi).tocsr()
            self.method = "matching"
        else:
            self.M12, covered = self._mixed_mass()
            area = self._sizes(space1, self.facets1, measure=True).sum()
            if not abs(covered - area) <= 1e-9 * area:
                d = self._gap()
                raise RotheInputError(
                    f"{name}: got parts {part1!r} (body 1) and {part2!r} (body 2) that do not "
                    f"touch: {100 * covered / area:.3g} % of {part1!r} lies on {part2!r} "
                    f"(nearest distance {d:.3g}, tolerance {self.abs_tol:.3g}), must cover it",
                    name,
                )
            self.Pi = mortar_projection(self.D, self.M12)
            self.method = "mortar"

    # -- geometry ------------------------------------------------------------------------------
    @staticmethod
    def _sizes(space, facets, measure: bool = False) -> np.ndarray:
        p = np.asarray(space.mesh.p)
        v = np.asarray(space.mesh.facets)[:, facets]
        if space.dim == 2:
            return np.linalg.norm(p[:, v[1]] - p[:, v[0]], axis=0)
        e1, e2 = p[:, v[1]] - p[:, v[0]], p[:, v[2]] - p[:, v[0]]
        if measure:
            return 0.5 * np.linalg.norm(np.cross(e1, e2, axis=0), axis=0)
        return np.min(
            [
                np.linalg.norm(e1, axis=0),
                np.linalg.norm(e2, axis=0),
                np.linalg.norm(e2 - e1, axis=0),
            ],
            axis=0,
        )

    def _gap(self) -> float:
        x1 = self.space1.doflocs[:, self.dofs1].T
        x2 = self.space2.doflocs[:, self.dofs2].T
        return float(cKDTree(x2).query(x1)[0].min())

    def _pair(self):
        """Side-2 position of each side-1 node, or None if not all pair up one to one."""
        x1 = self.space1.doflocs[:, self.dofs1].T
        x2 = self.space2.doflocs[:, self.dofs2].T
        dist, k = cKDTree(x2).query(x1)
        ok = dist <= self.abs_tol
        self._unpaired = int((~ok).sum())
        if self._unpaired or np.unique(k).size != k.size or x1.shape[0] != x2.shape[0]:
            self._unpaired = (
                max(self._unpaired, 1) if x1.shape[0] != x2.shape[0] else self._unpaired
            )
            return None
        return k

    def _side1_mass(self) -> sp.csr_matrix:
        Ms = self.space1.boundary_scalar_mass((self.part1,), f"{self.name}.part1")
        return sp.csr_matrix(Ms[self.dofs1][:, self.dofs1])

    def _mixed_mass(self):
        """M_12 by exact integration on the facet intersections; returns (M_12, covered
        measure of P_1)."""
        s1, s2 = self.space1, self.space2
        d = s1.dim
        p1, p2 = np.asarray(s1.mesh.p), np.asarray(s2.mesh.p)
        v1 = np.asarray(s1.mesh.facets)[:, self.facets1]  # (d, n1)
        v2 = np.asarray(s2.mesh.facets)[:, self.facets2]
        X1 = p1[:, v1].transpose(2, 1, 0)  # (n1, d vertices, d coords)
        X2 = p2[:, v2].transpose(2, 1, 0)
        c1, c2 = X1.mean(axis=1), X2.mean(axis=1)
        r1 = np.linalg.norm(X1 - c1[:, None], axis=2).max()
        r2 = np.linalg.norm(X2 - c2[:, None], axis=2).max()
        lists = cKDTree(c1).query_ball_point(c2, r1 + r2 + self.abs_tol)
        i2 = np.repeat(np.arange(len(lists)), [len(lst) for lst in lists])
        i1 = (
            np.concatenate([np.asarray(lst, dtype=np.int64) for lst in lists])
            if len(i2)
            else np.zeros(0, dtype=np.int64)
        )
        loc1 = np.searchsorted(self.dofs1, facet_dofs(s1, self.facets1))
        loc2 = np.searchsorted(self.dofs2, facet_dofs(s2, self.facets2))
        A, B = X1[i1], X2[i2]  # (P, d, d)
        if d == 2:
            pts1, pts2, w = self._segments(A, B)
        else:
            pts1, pts2, w = self._triangles(A, B)
        # pts1, pts2: barycentric coordinates (P, nq, d) on the two facets; w (P, nq)
        phi = facet_basis(d, s1.degree, np.moveaxis(pts1, 2, 0))  # (n_loc1, P, nq)
        psi = facet_basis(d, s2.degree, np.moveaxis(pts2, 2, 0))
        local = np.einsum("ipq,kpq,pq->pik", phi, psi, w)
        rows = np.broadcast_to(loc1[:, i1].T[:, :, None], local.shape)
        cols = np.broadcast_to(loc2[:, i2].T[:, None, :], local.shape)
        M12 = sp.coo_matrix(
            (local.ravel(), (rows.ravel(), cols.ravel())), shape=(self.dofs1.size, self.dofs2.size)
        ).tocsr()
        return M12, float(w.sum())

    def _segments(self, A, B):
        """Overlaps of segments A (P, 2 vertices, 2) and B on A's line: Gauss points."""
        a0, e = A[:, 0], A[:, 1] - A[:, 0]
        length = np.linalg.norm(e, axis=1)
        t = e / length[:, None]
        n = np.stack([-t[:, 1], t[:, 0]], axis=1)
        sb = np.einsum("pvk,pk->pv", B - a0[:, None], t) / length[:, None]  # on A: [0, 1]
        off = np.abs(np.einsum("pvk,pk->pv", B - a0[:, None], n)).max(axis=1)
        lo = np.clip(sb.min(axis=1), 0.0, 1.0)
        hi = np.clip(sb.max(axis=1), 0.0, 1.0)
        ok = (off <= self.abs_tol) & (hi > lo)
        lo, hi = np.where(ok, lo, 0.0), np.where(ok, hi, 0.0)
        s = lo[:, None] + (hi - lo)[:, None] * _GL_X[None]  # (P, nq) on A
        w = (hi - lo)[:, None] * _GL_W[None] * length[:, None]
        x = a0[:, None] + s[..., None] * e[:, None]
        # barycentric on B: x = b0 + r (b1 - b0)
        eb = B[:, 1] - B[:, 0]
        r = np.einsum("pqk,pk->pq", x - B[:, None, 0], eb) / np.einsum("pk,pk->p", eb, eb)[:, None]
        return np.stack([1 - s, s], axis=2), np.stack([1 - r, r], axis=2), w

    def _triangles(self, A, B):
        """Intersections of coplanar triangles A, B (P, 3, 3): clipped polygons, fan
        triangulation, the degree-4 rule; barycentric coordinates on A and B."""
        P = A.shape[0]
        a0, e1, e2 = A[:, 0], A[:, 1] - A[:, 0], A[:, 2] - A[:, 0]
        nrm = np.cross(e1, e2)
        area2 = np.linalg.norm(nrm, axis=1)
        nh = nrm / area2[:, None]
        # dual basis in A's plane: g_i . e_j = delta_ij
        G = np.linalg.inv(np.stack([e1, e2, nh], axis=2))  # rows: g1, g2, n
        rel = B - a0[:, None]
        xi = np.einsum("pik,pvk->pvi", G, rel)  # (P, 3 vertices, 3): (xi, eta, normal offset)
        off = np.abs(xi[:, :, 2]).max(axis=1)
        poly, count = xi[:, :, :2].copy(), np.full(P, 3)
        poly = np.concatenate([poly, np.zeros((P, 3, 2))], axis=1)  # room for 3 more
        for f in (lambda x: x[..., 0], lambda x: x[..., 1], lambda x: 1 - x[..., 0] - x[..., 1]):
            poly, count = _clip(poly, count, f)
        ok = (off <= self.abs_tol) & (count >= 3)
        count = np.where(ok, count, 0)
        V = poly.shape[1]
        # fan triangles (v0, v_k, v_k+1), k = 1..V-2; empty ones get zero weight
        k = np.arange(1, V - 1)
        t0 = np.broadcast_to(poly[:, :1], (P, k.size, 2))
        t1, t2 = poly[:, k], poly[:, k + 1]
        valid = (k[None, :] + 1) < count[:, None]
        jac = (t1[..., 0] - t0[..., 0]) * (t2[..., 1] - t0[..., 1]) - (t1[..., 1] - t0[..., 1]) * (
            t2[..., 0] - t0[..., 0]
        )
        jac = np.where(valid, np.abs(jac), 0.0)  # (P, k) reference (A) Jacobians
        q = (
            t0[:, :, None]
            + _TRI_X[None, None, :, :1] * (t1 - t0)[:, :, None]
            + _TRI_X[None, None, :, 1:] * (t2 - t0)[:, :, None]
        )  # (P, k, 6, 2) on A
        w = jac[:, :, None] * _TRI_W[None, None] * area2[:, None, None]
        q = q.reshape(P, -1, 2)
        w = w.reshape(P, -1)
        bary_a = np.stack([1 - q[..., 0] - q[..., 1], q[..., 0], q[..., 1]], axis=2)
        x = a0[:, None] + q[..., :1] * e1[:, None] + q[..., 1:] * e2[:, None]
        b0, f1, f2 = B[:, 0], B[:, 1] - B[:, 0], B[:, 2] - B[:, 0]
        nb = np.cross(f1, f2)
        Gb = np.linalg.inv(np.stack([f1, f2, nb / np.linalg.norm(nb, axis=1)[:, None]], axis=2))
        rb = np.einsum("pik,pqk->pqi", Gb, x - b0[:, None])
        bary_b = np.stack([1 - rb[..., 0] - rb[..., 1], rb[..., 0], rb[..., 1]], axis=2)
        return bary_a, bary_b, w

    # -- operators -----------------------------------------------------------------------------
    def vector(self, S: sp.spmatrix) -> sp.csr_matrix:
        """The vector (interleaved) form S (x) I_d of a scalar interface matrix."""
        return sp.kron(S, sp.identity(self.space1.dim), format="csr")

    def project(self, u2: np.ndarray) -> np.ndarray:
        """Body 1's interface values Pi S_2 u_2 (d k1,) from body 2's field u_2."""
        d = self.space2.dim
        tr = np.asarray(u2).reshape(-1, d)[self.dofs2]
        return (self.Pi @ tr).ravel()

    def substitution(self) -> sp.csr_matrix:
        """T with (u_1, u_2) = T (x_1, u_2): x_1 the values of u_1 at the dofs off P_1 (the
        glued space; u_1 on P_1 = Pi S_2 u_2)."""
        s1, s2 = self.space1, self.space2
        d = s1.dim
        n1, n2 = s1.ndofs, s2.ndofs
        on = s1.vector_dofs(self.dofs1)
        off = np.setdiff1d(np.arange(n1), on)
        m = off.size
        eye1 = sp.csr_matrix((np.ones(m), (off, np.arange(m))), shape=(n1, m))
        S2 = sp.csr_matrix(
            (
                np.ones(d * self.dofs2.size),
                (np.arange(d * self.dofs2.size), s2.vector_dofs(self.dofs2)),
            ),
            shape=(d * self.dofs2.size, n2),
        )
        E1 = sp.csr_matrix((np.ones(on.size), (on, np.arange(on.size))), shape=(n1, on.size))
        top = sp.hstack([eye1, E1 @ self.vector(self.Pi) @ S2])
        bottom = sp.hstack([sp.csr_matrix((n2, m)), sp.identity(n2, format="csr")])
        self.free1 = off
        return sp.vstack([top, bottom], format="csr")

    def glue(self, A1, A2) -> sp.csr_matrix:
        """T^T blkdiag(A_1, A_2) T: a matrix of the glued bodies (stiffness, mass)."""
        T = self.substitution()
        return (T.T @ sp.block_diag([sp.csr_matrix(A1), sp.csr_matrix(A2)]) @ T).tocsr()

    def describe(self) -> dict:
        """The two parts, the method and the node counts, for summaries."""
        return {
            "part1": self.part1,
            "part2": self.part2,
            "method": self.method,
            "nodes1": int(self.dofs1.size),
            "nodes2": int(self.dofs2.size),
        }
