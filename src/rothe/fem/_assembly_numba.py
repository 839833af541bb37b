"""Compiled element loops for :mod:`rothe.fem.elasticity` (optional: numba, extra ``fast``).

The same element matrices as the numpy path (affine Jacobian by cofactors, reference gradients,
the same quadrature), summed into the same block array, one cell after the other; the numpy path
sums each chunk by bincount, so the two agree to round-off (tested), not bit for bit. Without
numba, ``AVAILABLE`` is False and nothing here is called.
"""

from __future__ import annotations

import numpy as np

try:  # pragma: no cover - depends on the environment
    import numba

    AVAILABLE = True
except ImportError:  # pragma: no cover
    numba = None
    AVAILABLE = False


def _jit(f):
    if numba is None:  # pragma: no cover
        return f
    return numba.njit(cache=True, nogil=True)(f)


@_jit
def _geometry(p, t, c, inv):
    """Fill inv (d, d) with J^{-1} of cell c (inv[k, a]); return |det J|."""
    d = p.shape[0]
    if d == 2:
        e00 = p[0, t[1, c]] - p[0, t[0, c]]
        e01 = p[1, t[1, c]] - p[1, t[0, c]]
        e10 = p[0, t[2, c]] - p[0, t[0, c]]
        e11 = p[1, t[2, c]] - p[1, t[0, c]]
        det = e00 * e11 - e01 * e10
        inv[0, 0] = e11 / det
        inv[0, 1] = -e10 / det
        inv[1, 0] = -e01 / det
        inv[1, 1] = e00 / det
        return abs(det)
    x0 = p[0, t[0, c]]
    y0 = p[1, t[0, c]]
    z0 = p[2, t[0, c]]
    ax, ay, az = p[0, t[1, c]] - x0, p[1, t[1, c]] - y0, p[2, t[1, c]] - z0
    bx, by, bz = p[0, t[2, c]] - x0, p[1, t[2, c]] - y0, p[2, t[2, c]] - z0
    cx, cy, cz = p[0, t[3, c]] - x0, p[1, t[3, c]] - y0, p[2, t[3, c]] - z0
    # rows of J^{-1}: (b x c, c x a, a x b) / det, J = [a b c]
    r0x, r0y, r0z = by * cz - bz * cy, bz * cx - bx * cz, bx * cy - by * cx
    r1x, r1y, r1z = cy * az - cz * ay, cz * ax - cx * az, cx * ay - cy * ax
    r2x, r2y, r2z = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    det = ax * r0x + ay * r0y + az * r0z
    inv[0, 0], inv[0, 1], inv[0, 2] = r0x / det, r0y / det, r0z / det
    inv[1, 0], inv[1, 1], inv[1, 2] = r1x / det, r1y / det, r1z / det
    inv[2, 0], inv[2, 1], inv[2, 2] = r2x / det, r2y / det, r2z / det
    return abs(det)


@_jit
def _cell_positions(ed, c, diag, upper, lower, pair_ids, pi, pj, pos):
    nbf = ed.shape[0]
    for i in range(nbf):
        pos[i, i] = diag[ed[i, c]]
    for k in range(pi.size):
        i = pi[k]
        j = pj[k]
        u = pair_ids[c, k]
        if ed[i, c] < ed[j, c]:
            pos[i, j] = upper[u]
            pos[j, i] = lower[u]
        else:
            pos[i, j] = lower[u]
            pos[j, i] = upper[u]


@_jit
def _stiffness(
    p, t, ed, diag, upper, lower, pair_ids, pi, pj, order, dref, wref, lam_c, mu_c, blocks
):
    d = p.shape[0]
    nbf = ed.shape[0]
    nq = wref.size
    inv = np.empty((d, d))
    G = np.empty((nq, nbf, d))
    pos = np.empty((nbf, nbf), dtype=np.int64)
    loc = np.empty((d, d))
    for o in range(order.size):
        c = order[o]
        det = _geometry(p, t, c, inv)
        lam = lam_c[c]
        mu = mu_c[c]
        for q in range(nq):
            for i in range(nbf):
                for a in range(d):
                    s = 0.0
                    for k in range(d):
                        s += dref[q, i, k] * inv[k, a]
                    G[q, i, a] = s
        _cell_positions(ed, c, diag, upper, lower, pair_ids, pi, pj, pos)
        # block (j, i) is the transpose of block (i, j): compute i <= j only
        for i in range(nbf):
            for j in range(i, nbf):
                for a in range(d):
                    for b in range(d):
                        loc[a, b] = 0.0
                for q in range(nq):
                    w = det * wref[q]
                    dot = 0.0
                    for k in range(d):
                        dot += G[q, i, k] * G[q, j, k]
                    for a in range(d):
                        for b in range(d):
                            v = lam * G[q, i, a] * G[q, j, b] + mu * G[q, i, b] * G[q, j, a]
                            if a == b:
                                v += mu * dot
                            loc[a, b] += w * v
                r = pos[i, j]
                for a in range(d):
                    for b in range(d):
                        blocks[r, a, b] += loc[a, b]
                if j != i:
                    r = pos[j, i]
                    for a in range(d):
                        for b in range(d):
                            blocks[r, b, a] += loc[a, b]


@_jit
def _mass(p, t, ed, diag, upper, lower, pair_ids, pi, pj, order, mref, weight_c, out):
    d = p.shape[0]
    nbf = ed.shape[0]
    inv = np.empty((d, d))
    pos = np.empty((nbf, nbf), dtype=np.int64)
    for o in range(order.size):
        c = order[o]
        det = _geometry(p, t, c, inv) * weight_c[c]
        _cell_positions(ed, c, diag, upper, lower, pair_ids, pi, pj, pos)
        for i in range(nbf):
            for j in range(nbf):
                out[pos[i, j]] += det * mref[i, j]


def _pattern_args(pattern):
    return (
        pattern.diag,
        pattern.upper,
        pattern.lower,
        pattern.pair_ids,
        pattern.pi.astype(np.int64),
        pattern.pj.astype(np.int64),
        pattern.cell_order,
    )


def stiffness_blocks(p, t, ed, pattern, dref, wref, lam, mu, blocks) -> None:
    """blocks += K's element blocks (see VectorSpace.stiffness_blocks); ``lam``, ``mu`` are
    per-cell arrays (n_cells,) (a constant is passed as a constant array: the same products,
    hence the same bits)."""
    _stiffness(
        np.ascontiguousarray(p, dtype=float),
        np.ascontiguousarray(t),
        np.ascontiguousarray(ed),
        *_pattern_args(pattern),
        np.ascontiguousarray(dref, dtype=float),
        np.ascontiguousarray(wref, dtype=float),
        np.ascontiguousarray(lam, dtype=float),
        np.ascontiguousarray(mu, dtype=float),
        blocks,
    )


def scalar_mass(p, t, ed, pattern, mref, out, weight=None) -> None:
    """out += the scalar mass |det J| w_c mref of every cell c (w = 1 without ``weight``:
    |det J| * 1.0 is |det J| exactly)."""
    ne = np.asarray(t).shape[1]
    w = np.ones(ne) if weight is None else np.ascontiguousarray(weight, dtype=float)
    _mass(
        np.ascontiguousarray(p, dtype=float),
        np.ascontiguousarray(t),
        np.ascontiguousarray(ed),
        *_pattern_args(pattern),
        np.ascontiguousarray(mref, dtype=float),
        w,
        out,
    )


# -- BSR products (bit for bit scipy's bsr_matvec: the same sums in the same order) -------------


@_jit
def _bsr_matvec_3(indptr, indices, data, x, y):
    for i in range(indptr.size - 1):
        y0 = y[3 * i]
        y1 = y[3 * i + 1]
        y2 = y[3 * i + 2]
        for jj in range(indptr[i], indptr[i + 1]):
            j = 3 * indices[jj]
            x0 = x[j]
            x1 = x[j + 1]
            x2 = x[j + 2]
            y0 = ((y0 + data[jj, 0, 0] * x0) + data[jj, 0, 1] * x1) + data[jj, 0, 2] * x2
            y1 = ((y1 + data[jj, 1, 0] * x0) + data[jj, 1, 1] * x1) + data[jj, 1, 2] * x2
            y2 = ((y2 + data[jj, 2, 0] * x0) + data[jj, 2, 1] * x1) + data[jj, 2, 2] * x2
        y[3 * i] = y0
        y[3 * i + 1] = y1
        y[3 * i + 2] = y2


@_jit
def _bsr_matvec_2(indptr, indices, data, x, y):
    for i in range(indptr.size - 1):
        y0 = y[2 * i]
        y1 = y[2 * i + 1]
        for jj in range(indptr[i], indptr[i + 1]):
            j = 2 * indices[jj]
            x0 = x[j]
            x1 = x[j + 1]
            y0 = (y0 + data[jj, 0, 0] * x0) + data[jj, 0, 1] * x1
            y1 = (y1 + data[jj, 1, 0] * x0) + data[jj, 1, 1] * x1
        y[2 * i] = y0
        y[2 * i + 1] = y1


def bsr_matvec(indptr, indices, data, x) -> np.ndarray:
    """y = A x for a BSR matrix with 2 x 2 or 3 x 3 blocks given by its arrays (float64).

    (A loop over general R x C blocks was slower than scipy's for pyamg's 6 x 6 coarse levels:
    those stay with scipy.)"""
    R = data.shape[1]
    y = np.zeros(R * (indptr.size - 1))
    if R == 3:
        _bsr_matvec_3(indptr, indices, data, x, y)
    else:
        _bsr_matvec_2(indptr, indices, data, x, y)
    return y
