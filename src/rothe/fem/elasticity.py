"""Vector P1/P2 finite elements for linear isotropic elasticity (plane strain in 2D, and 3D).

:class:`VectorSpace` is the space V_h = [S_h]^d of continuous piecewise linear (P1) or quadratic
(P2) vector fields on a scikit-fem simplex mesh (``MeshTri`` / ``MeshTet``). Its degrees of
freedom are *interleaved*: component c of scalar dof k is vector dof ``d*k + c``, so that every
d x d block of a matrix couples two scalar dofs. That is the block layout of a BSR matrix, and
it is how every matrix here is built: one scalar sparsity pattern computed once, plus a
(nnz, d, d) array of block values filled by a vectorized scatter.

Matrices (all with the paper's conventions, Altmann 2015, Sec. 2.2):

- stiffness (2.3):  <K u, v> = int sigma(u) : eps(v) dx,  sigma(u) = lam tr(eps(u)) I + 2 mu eps(u),
  assembled as  K^{ab}_{ij} = int lam d_a phi_i d_b phi_j + mu d_b phi_i d_a phi_j
  + mu delta_ab grad phi_i . grad phi_j  (block (a, b) couples component a of dof i with
  component b of dof j), with the quadrature that is exact for affine simplices
  (one point for P1, degree 2 for P2);
- mass:  <M u, v> = int u . v dx, the scalar mass (exact: |det J| times the reference mass)
  times the d x d identity, stored with its d nonzeros per block only;
- block-coefficient mass  int (C(x) u) . v dx for a d x d field C given at quadrature points
  (the Jacobian of a pointwise nonlinear damping);
- :meth:`VectorSpace.restricted_combination`: a M + b K restricted to a set of nodes (the step
  matrix of the Euler scheme on the free dofs) as a BSR matrix, gathered from K without forming
  a M + b K.

How the assembly stays lean at a million unknowns (measured in benchmarks/eld_peers.py):

- the sparsity pattern is built from the *pairs* of local dofs (i < j) of every cell: one stable
  sort of their keys, then the rows are put together from the unique pairs (lower part,
  diagonal, upper part) by counting -- no ``np.unique`` over all (i, j, cell) entries, int32
  indices;
- the map (cell, i, j) -> position in the pattern is not stored: it is rebuilt per chunk of cells
  from the pair numbers (ne x nbf(nbf-1)/2 int32);
- element matrices are computed from the vertex coordinates (affine Jacobians, reference
  gradients) chunk by chunk, so no (d nbf)^2 x ncells array ever exists; one quadrature point for
  P1 strains (they are constant);
- the scatter into the pattern is a bincount per block component over the chunk's range of
  positions, or, if numba is installed (extra ``fast``), one compiled loop over the cells
  (:mod:`rothe.fem._assembly_numba`; same sums in a different order: equal to round-off).

Loads are applied through quadrature: body force f(x) and boundary tractions g(x) are
evaluated at quadrature points by numpy and integrated against the basis in one pass, so a
time-dependent load costs one vectorized evaluation per step and no generic assembly.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from ..errors import check_int, check_positive, check_real, described, fail
from .mesh import check_simplex_mesh, with_fast_edges, with_fast_facets

#: element-matrix entries (floats) per chunk of cells in the numpy assembly (1 MB, at least
#: 256 cells: 1.8 MB for P2 tetrahedra; the chunk's index and scatter temporaries are several
#: times that: the stiffness assembly is the peak of an adaptive 3D run's rebuild, 2**22
#: +36 MB over 2**19, 2**19 +10 MB over 2**17 on the eld3d pulse at the same CPU time,
#: docs/adaptivity.md)
CHUNK_ENTRIES = 2**17
#: the compiled loops are used from this much work on (d^2 nbf^2 nq per cell, summed): below,
#: importing numba and loading its cached kernels (about a second) costs more than the numpy
#: assembly saves (3D: from about 120k P1 or 5k P2 tetrahedra)
NUMBA_MIN_WORK = 2**24


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
    from skfem import (  # heavy: imported when first needed (start-up time)
        ElementTetP1,
        ElementTetP2,
        ElementTriP1,
        ElementTriP2,
    )

    return {(2, 1): ElementTriP1, (2, 2): ElementTriP2, (3, 1): ElementTetP1, (3, 2): ElementTetP2}[
        (dim, degree)
    ]()


def _compiled():
    """:mod:`rothe.fem._assembly_numba`, imported when first needed: importing numba (and
    llvmlite) adds about 35 MB of resident memory and a few tenths of a second to every process
    (measured: ``import rothe.eld`` 140 MB with it, 83 MB without), and below the thresholds
    (:data:`NUMBA_MIN_WORK`, :data:`NUMBA_MIN_MATVEC`) nothing of it is called: e.g. the meshes
    of a space-adaptive 3D run up to ~15k P2 dofs."""
    from . import _assembly_numba  # heavy: numba, imported when first needed (memory)

    return _assembly_numba


def use_numba(work: int | None = None) -> bool:
    """True if the compiled kernels are used for an assembly of this much ``work``
    (:data:`NUMBA_MIN_WORK`; None: whatever the size): numba importable and ROTHE_NO_NUMBA
    unset or 0. ROTHE_NUMBA=1 uses them at any size (tests, benchmarks)."""
    if os.environ.get("ROTHE_NO_NUMBA", "0") not in ("", "0"):
        return False
    forced = os.environ.get("ROTHE_NUMBA", "0") not in ("", "0")
    if work is not None and work < NUMBA_MIN_WORK and not forced:
        return False

    return _compiled().AVAILABLE


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


# -- reference element and affine geometry -------------------------------------------------------


@dataclass(frozen=True)
class _Reference:
    """Quadrature and basis of the reference simplex for one (dim, degree)."""

    nbf: int
    grad_weights: np.ndarray  # (nq,) weights of the rule exact for grad . grad (degree 2p - 2)
    grads: np.ndarray  # (nq, nbf, d) reference gradients at its points
    mass: np.ndarray  # (nbf, nbf) reference mass int phi_i phi_j (exact, degree 2p)


_REFERENCES: dict = {}


def _reference(element, dim: int, degree: int) -> _Reference:
    key = (dim, degree)
    if key not in _REFERENCES:
        # heavy: imported when first needed (start-up time of the command line)
        from skfem.quadrature import get_quadrature

        nbf = element.doflocs.shape[0]
        X, W = get_quadrature(element.refdom, max(1, 2 * (degree - 1)))
        grads = np.stack([element.lbasis(X, i)[1] for i in range(nbf)])  # (nbf, d, nq)
        Xm, Wm = get_quadrature(element.refdom, 2 * degree)
        vals = np.stack([element.lbasis(Xm, i)[0] for i in range(nbf)])  # (nbf, nq)
        _REFERENCES[key] = _Reference(
            nbf=nbf,
            grad_weights=np.asarray(W, dtype=float),
            grads=np.ascontiguousarray(grads.transpose(2, 0, 1)),
            mass=np.einsum("iq,jq,q->ij", vals, vals, Wm),
        )
        m = _REFERENCES[key].mass
        m[...] = 0.5 * (m + m.T)  # exactly symmetric
    return _REFERENCES[key]


def affine_geometry(p: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse Jacobians and |det J| of the affine maps of the simplices t ((d+1, C) vertices).

    J = [x_1 - x_0, ..., x_d - x_0]; returns invJ (d, d, C) with invJ[k, a, c] = (J^{-1})_{ka}
    of cell c (so that grad phi = J^{-T} grad_ref phi, component a = sum_k invJ[k, a] d_k
    phi_ref) and |det J| (C,). Cofactor formulas; the cell axis last so that every operation
    runs over long contiguous arrays.
    """
    d = p.shape[0]
    x0 = p[:, t[0]]
    E = [p[:, t[k + 1]] - x0 for k in range(d)]  # columns of J, each (d, C)
    inv = np.empty((d, d, t.shape[1]))
    if d == 2:
        det = E[0][0] * E[1][1] - E[0][1] * E[1][0]
        inv[0, 0] = E[1][1] / det
        inv[0, 1] = -E[1][0] / det
        inv[1, 0] = -E[0][1] / det
        inv[1, 1] = E[0][0] / det
    else:
        # rows of J^{-1}: (e2 x e3, e3 x e1, e1 x e2) / det
        rows = (
            np.cross(E[1], E[2], axis=0),
            np.cross(E[2], E[0], axis=0),
            np.cross(E[0], E[1], axis=0),
        )
        det = np.einsum("ac,ac->c", E[0], rows[0])
        for k in range(3):
            np.divide(rows[k], det, out=inv[k])
    return inv, np.abs(det)


# -- sparsity pattern ----------------------------------------------------------------------------


class ScalarPattern:
    """CSR pattern of the scalar dofs coupled through a cell, and where cells' entries go.

    Built from the pairs i < j of local dofs of every cell: their keys min * n + max are sorted
    once (stable argsort, int64), equal keys numbered; the unique pairs (a < b) then give, per
    row r, the lower entries (b = r, sorted by a), the diagonal and the upper entries (a = r,
    sorted by b) by counting. Stored: ``indptr``, ``indices`` (int32 when they fit), the
    positions ``diag`` (n,), ``upper``/``lower`` (E,) of each unique pair's two entries and the
    pair number of each (cell, local pair) ``pair_ids`` (ne, nbf(nbf-1)/2, int32).
    """

    def __init__(self, element_dofs: np.ndarray, n: int):
        ed = np.asarray(element_dofs)
        nbf, ne = ed.shape
        self.n, self.nbf, self.ne = n, nbf, ne
        self.pairs = [(i, j) for i in range(nbf) for j in range(i + 1, nbf)]
        self.pi = np.array([i for i, _ in self.pairs], dtype=np.intp)
        self.pj = np.array([j for _, j in self.pairs], dtype=np.intp)
        edT = ed.T  # (ne, nbf), a view
        a = edT[:, self.pi]
        b = edT[:, self.pj]
        if np.any(a == b):
            raise fail("mesh", "a cell with a repeated dof", "must have distinct dofs per cell")
        keys = np.minimum(a, b).astype(np.int64)
        keys *= n
        keys += np.maximum(a, b)
        del a, b
        keys = keys.ravel()
        perm = np.argsort(keys, kind="stable")
        skeys = keys[perm]
        del keys
        first = np.empty(skeys.size, dtype=bool)
        if skeys.size:
            first[0] = True
            np.not_equal(skeys[1:], skeys[:-1], out=first[1:])
        ids = np.cumsum(first, dtype=np.int64)
        ids -= 1
        pair_ids = np.empty(skeys.size, dtype=np.int32)
        pair_ids[perm] = ids
        del perm, ids
        ukeys = skeys[first]
        del skeys, first
        self.pair_ids = pair_ids.reshape(ne, len(self.pairs))
        ua = (ukeys // n).astype(np.int64)
        ub = (ukeys - ua * n).astype(np.int64)
        del ukeys
        E = ua.size
        n_upper = np.bincount(ua, minlength=n)
        n_lower = np.bincount(ub, minlength=n)
        nnz = 2 * E + n
        idx_dtype = np.int32 if nnz < 2**31 - 1 else np.int64
        indptr = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(n_lower + 1 + n_upper, out=indptr[1:])
        diag = indptr[:-1] + n_lower
        # upper entry (a, b): after the diagonal of row a, in the order of b (pairs are sorted)
        start_up = np.zeros(n, dtype=np.int64)
        np.cumsum(n_upper[:-1], out=start_up[1:])
        upper = diag[ua] + 1 + (np.arange(E, dtype=np.int64) - start_up[ua])
        # lower entry (b, a): row b, in the order of a (stable sort by b keeps a ascending)
        order = np.argsort(ub, kind="stable")
        start_lo = np.zeros(n, dtype=np.int64)
        np.cumsum(n_lower[:-1], out=start_lo[1:])
        lower = np.empty(E, dtype=np.int64)
        lower[order] = indptr[ub[order]] + (np.arange(E, dtype=np.int64) - start_lo[ub[order]])
        del order
        indices = np.empty(nnz, dtype=idx_dtype)
        indices[diag] = np.arange(n)
        indices[upper] = ub
        indices[lower] = ua
        self.indptr = indptr.astype(idx_dtype)
        self.indices = indices
        self.nnz = nnz
        self.diag = diag.astype(idx_dtype)
        self.upper = upper.astype(idx_dtype)
        self.lower = lower.astype(idx_dtype)
        # cells in the order of their smallest dof: a run of consecutive cells then writes to a
        # narrow band of rows (scikit-fem's init_tensor numbers the six tetrahedra of a cube in
        # six sweeps over the whole mesh), which keeps the scatter in cache
        self.cell_order = np.argsort(ed.min(axis=0), kind="stable").astype(
            np.int32 if ne < 2**31 - 1 else np.int64
        )

    def cell_map(self, ed_chunk: np.ndarray, pair_chunk: np.ndarray) -> np.ndarray:
        """Positions (C, nbf, nbf) in the pattern of the entries (dof_i, dof_j) of C cells.

        ``ed_chunk`` (nbf, C) are the cells' dofs, ``pair_chunk`` (C, npairs) their pair ids.
        """
        nbf = self.nbf
        C = ed_chunk.shape[1]
        out = np.empty((C, nbf, nbf), dtype=np.int64)
        for i in range(nbf):
            out[:, i, i] = self.diag[ed_chunk[i]]
        up = self.upper[pair_chunk]
        lo = self.lower[pair_chunk]
        ascending = ed_chunk[self.pi].T < ed_chunk[self.pj].T  # (C, npairs)
        out[:, self.pi, self.pj] = np.where(ascending, up, lo)
        out[:, self.pj, self.pi] = np.where(ascending, lo, up)
        return out

    def chunks(self, cells_per_chunk: int):
        """Cell index arrays of consecutive runs of :attr:`cell_order`."""
        for c0 in range(0, self.ne, cells_per_chunk):
            yield self.cell_order[c0 : c0 + cells_per_chunk]

    def rows(self) -> np.ndarray:
        """Row index of every entry (nnz,)."""
        return np.repeat(np.arange(self.n, dtype=self.indices.dtype), np.diff(self.indptr))


#: products with a BlockMatrix use the compiled kernel (if numba is there) from this many
#: stored entries on (below, scipy's few milliseconds do not pay for loading numba)
NUMBA_MIN_MATVEC = 2**22


class BlockMatrix(sp.bsr_matrix):
    """A BSR matrix (d x d blocks) that can also be indexed like a CSR matrix.

    Sums and transposes are scipy's BSR operations; the matrix takes 30 % less memory than CSR
    (one column index per block). Products with a vector use, when numba is installed and the
    matrix is large (:data:`NUMBA_MIN_MATVEC` entries), a compiled kernel with the 2 x 2 / 3 x 3
    block product written out: the same sums in the same order as scipy's ``bsr_matvec``, hence
    the same bits (tested), 1.5-2x faster (it is the AMG cycle's main cost: the CG and the
    fine-level smoother multiply with A_II). Indexing (``K[rows][:, cols]``), which scipy's BSR
    does not support, goes through a CSR copy: convenient for small problems and tests; at scale
    use :meth:`VectorSpace.symmetric_columns` and :meth:`VectorSpace.restricted_combination`.
    """

    def __getitem__(self, key):
        return self.tocsr()[key]

    def _matmul_vector(self, other):
        if (
            self.blocksize in ((2, 2), (3, 3))
            and self.dtype == np.float64
            and (self.nnz >= NUMBA_MIN_MATVEC or _numba_forced())
            and getattr(other, "dtype", None) == np.float64
            and other.ndim == 1
            and use_numba()
        ):
            return _compiled().bsr_matvec(
                self.indptr, self.indices, self.data, np.ascontiguousarray(other)
            )
        return super()._matmul_vector(other)


def _numba_forced() -> bool:
    return os.environ.get("ROTHE_NUMBA", "0") not in ("", "0")


def _scatter_chunk(
    out: np.ndarray, positions: np.ndarray, local: np.ndarray, premultiplied: bool = False
) -> None:
    """out[positions] += local, summing repeated positions (one bincount over their range).

    ``out`` is (nnz,) or (nnz, k) (k values per position, e.g. the d x d entries of a block,
    flattened); ``positions`` has the shape of ``local`` (then ``premultiplied``: they index
    out.ravel()) or of ``local`` without its last axis of length k.
    """
    k = 1 if out.ndim == 1 else out.shape[1]
    flat = out.reshape(-1) if out.ndim > 1 else out
    if not premultiplied and k > 1:
        positions = (positions * k)[..., None] + np.arange(k)
    lo = int(positions.min())
    hi = int(positions.max()) + 1
    if k > 1:
        lo, hi = lo - lo % k, hi + (-hi) % k
    sums = np.bincount((positions - lo).ravel(), weights=local.ravel(), minlength=hi - lo)
    flat[lo:hi] += sums


class VectorSpace:
    """Vector P1/P2 Lagrange space on a triangle (2D) or tetrahedron (3D) mesh.

    Parameters
    ----------
    mesh : skfem.MeshTri | skfem.MeshTet
        Named boundary parts live in ``mesh.boundaries`` (facet index arrays).
    degree : 1 | 2

    Construction is cheap (the dof numbering; for P2 scikit-fem's, which needs the mesh edges in
    3D); the sparsity pattern is built on the first matrix asked for, the scikit-fem bases
    (:attr:`grad_basis`, :attr:`quad_basis`) only when quadrature-point fields are asked for.
    """

    def __init__(self, mesh, degree: int = 1):
        self.dim = check_simplex_mesh(mesh)
        self.degree = check_int("degree", degree)
        if self.degree not in (1, 2):
            raise fail("degree", degree, "must be 1 or 2")
        self.mesh = mesh
        self.element = _scalar_element(self.dim, self.degree)
        self._ref = _reference(self.element, self.dim, self.degree)
        if self.degree == 1:
            # P1: scalar dof k is vertex k (scikit-fem numbers it so too)
            self._dofs = None
            self.element_dofs = np.asarray(mesh.t)
            self.n_scalar = int(mesh.p.shape[1])
        else:
            from skfem.assembly import Dofs  # heavy: imported when first needed (start-up time)

            # scikit-fem numbers the P2 dofs by the mesh edges (3D) or facets (2D); build them
            # by one sort of int64 keys instead of its np.unique over rows
            if self.dim == 3:
                with_fast_edges(mesh)
            else:
                with_fast_facets(mesh)
            self._dofs = Dofs(mesh, self.element)
            self.element_dofs = np.asarray(self._dofs.element_dofs)
            self.n_scalar = int(self._dofs.N)
        self.ndofs = self.dim * self.n_scalar
        #: the element matrices of K kept by its last assembly (``stiffness(..., keep=True)``)
        self.element_stiffness = None

    # -- dofs -----------------------------------------------------------------------------------
    @cached_property
    def doflocs(self) -> np.ndarray:
        """Coordinates (d, n_scalar) of the scalar dofs (vertices; P2: also edge midpoints)."""
        p = np.asarray(self.mesh.p)
        if self.degree == 1:
            return p
        t = np.asarray(self.mesh.t)
        x0 = p[:, t[0]]
        E = np.stack([p[:, t[k + 1]] - x0 for k in range(self.dim)], axis=1)  # (d, d, ne)
        out = np.empty((self.dim, self.n_scalar))
        for i, xi in enumerate(np.asarray(self.element.doflocs)):
            out[:, self.element_dofs[i]] = x0 + np.einsum("akc,k->ac", E, xi)
        return out

    # -- sparsity pattern -----------------------------------------------------------------------
    @cached_property
    def pattern(self) -> ScalarPattern:
        """The scalar CSR pattern (built on first use, see :class:`ScalarPattern`)."""
        return ScalarPattern(self.element_dofs, self.n_scalar)

    @property
    def pattern_indptr(self) -> np.ndarray:
        return self.pattern.indptr

    @property
    def pattern_cols(self) -> np.ndarray:
        return self.pattern.indices

    @property
    def nnz_scalar(self) -> int:
        return self.pattern.nnz

    def scalar_matrix(self, values: np.ndarray) -> sp.csr_matrix:
        """The scalar n x n CSR matrix with ``values`` on the scalar sparsity pattern."""
        n = self.n_scalar
        return sp.csr_matrix((values, self.pattern_cols, self.pattern_indptr), shape=(n, n))

    def block_matrix(self, blocks: np.ndarray, format: str = "csr"):
        """The vector matrix from block values (nnz_scalar, d, d) on the scalar pattern.

        ``format='bsr'`` returns a :class:`BlockMatrix` on the scalar pattern (no copy of
        ``blocks``); 'csr' converts it (every entry of every block is stored, zeros included).
        """
        d, n = self.dim, self.n_scalar
        bsr = BlockMatrix(
            (blocks, self.pattern_cols, self.pattern_indptr), shape=(d * n, d * n), blocksize=(d, d)
        )
        if format == "bsr":
            return bsr
        if format != "csr":
            raise fail("format", format, "must be csr or bsr")
        return bsr.tocsr()

    def _chunks(self, entries_per_cell: int):
        """Index arrays of runs of cells (in the pattern's cell order) with about
        CHUNK_ENTRIES element-matrix entries each."""
        return self.pattern.chunks(max(256, CHUNK_ENTRIES // max(entries_per_cell, 1)))

    def _chunk_map(self, cells) -> np.ndarray:
        pat = self.pattern
        return pat.cell_map(self.element_dofs[:, cells], pat.pair_ids[cells])

    def _geometry(self, cells):
        t = np.asarray(self.mesh.t)[:, cells]
        return affine_geometry(np.asarray(self.mesh.p), t)

    def release_assembly_caches(self) -> None:
        """Drop what only further assemblies need: the pattern's map from cells to entries
        (cell pair numbers, positions, cell order) and the cached scalar mass values (about
        120 MB at a million P1 unknowns). The matrices already built keep the pattern's index
        arrays they share; a later assembly rebuilds the rest (one sort)."""
        self.__dict__.pop("pattern", None)
        self.__dict__.pop("scalar_mass_values", None)

    @property
    def compiled_assembly(self) -> bool:
        """Whether the matrices of this space are assembled by the numba loops (see
        :func:`use_numba`; the work is d^2 nbf^2 nq per cell)."""
        ref = self._ref
        work = self.dim**2 * ref.nbf**2 * ref.grad_weights.size * self.element_dofs.shape[1]
        return use_numba(work)

    # -- quadrature (scikit-fem bases, for fields, loads and errors) -----------------------------
    @cached_property
    def grad_basis(self):
        """scikit-fem Basis with the rule of degree 2(p - 1) (at least one point); created on
        first use (the matrices here do not need it)."""
        from skfem import Basis  # heavy: imported when first needed (start-up time)

        return Basis(self.mesh, self.element, intorder=max(1, 2 * (self.degree - 1)))

    @cached_property
    def quad_basis(self):
        """Basis with the quadrature exact for products of two basis functions (degree 2p).

        Used for loads, errors and nonlinear (pointwise) damping; created on first use because
        at a million unknowns in 3D it costs about a gigabyte.
        """
        from skfem import Basis  # heavy: imported when first needed (start-up time)

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
        """|K| of every cell (|det J| / d!)."""
        t = np.asarray(self.mesh.t)
        return affine_geometry(np.asarray(self.mesh.p), t)[1] / math.factorial(self.dim)

    # -- matrices -------------------------------------------------------------------------------
    def cell_coefficient(self, name: str, value) -> float | np.ndarray:
        """A material coefficient as a float (constant) or a finite array (n_cells,) (one value
        per cell, e.g. from subdomain tags: :class:`rothe.eld.materials.PiecewiseMaterial`)."""
        arr = np.asarray(value, dtype=float)
        if arr.ndim == 0:
            return check_real(name, float(arr))
        ne = self.element_dofs.shape[1]
        if arr.shape != (ne,):
            raise fail(
                name,
                described(f"an array of shape {arr.shape}"),
                f"must be a number or one value per cell, shape ({ne},)",
            )
        if not np.all(np.isfinite(arr)):
            raise fail(name, described("non-finite values"), "must be finite")
        return arr

    def stiffness_blocks(self, lam, mu, *, reuse=None, keep: bool = False) -> np.ndarray:
        """Block values (nnz_scalar, d, d) of K of (2.3) on the scalar pattern.

        ``lam``, ``mu``: constants, or arrays (n_cells,) of per-cell Lamé constants (several
        materials in one body; the element matrix of cell c is lam_c S_lam + mu_c S_mu, so
        the assembly stays one vectorized pass over chunks of cells).

        Incremental assembly (space adaptivity, :mod:`rothe.eld.adapt`): ``keep`` stores the
        element matrices K_c[i, a, j, b] in :attr:`element_stiffness` (n_cells, nbf, d, nbf,
        d); ``reuse`` = (matrices, source) takes them for the cells with ``source[c] >= 0``
        from ``matrices[source[c]]`` (another mesh's :attr:`element_stiffness`, the cells
        that did not change: same vertices in the same order, so the same element matrix)
        instead of computing them. The scatter is the same in both cases (same chunks, same
        order), so the result equals a full assembly bit for bit. The compiled loops (large
        meshes, :func:`use_numba`) neither keep nor reuse."""
        lam = self.cell_coefficient("lam", lam)
        mu = self.cell_coefficient("mu", mu)
        d, ref = self.dim, self._ref
        pat = self.pattern
        blocks = np.zeros((pat.nnz, d, d))
        self.element_stiffness = None
        if self.compiled_assembly:
            ne = self.element_dofs.shape[1]
            _compiled().stiffness_blocks(
                np.asarray(self.mesh.p),
                np.asarray(self.mesh.t),
                np.asarray(self.element_dofs),
                pat,
                ref.grads,
                ref.grad_weights,
                np.broadcast_to(lam, (ne,)),
                np.broadcast_to(mu, (ne,)),
                blocks,
            )
            return blocks
        cellwise = isinstance(lam, np.ndarray) or isinstance(mu, np.ndarray)
        nbf = ref.nbf
        ne = self.element_dofs.shape[1]
        flat = blocks.reshape(-1)
        ab = np.arange(d)[:, None, None] * d + np.arange(d)[None, None, :]  # a d + b, (d, 1, d)
        kept = np.empty((ne, nbf, d, nbf, d)) if keep else None
        if reuse is not None:
            old, source = reuse
            source = np.asarray(source, dtype=np.int64)
            if source.shape != (ne,) or old.shape[1:] != (nbf, d, nbf, d):
                raise fail(
                    "reuse",
                    described(f"element matrices {old.shape} for {source.shape} cells"),
                    f"must give ({ne},) sources of ({nbf}, {d}, {nbf}, {d}) matrices",
                )
        for cells in self._chunks(d * d * nbf * nbf):
            if reuse is not None:
                src = source[cells]
                fresh = src < 0
                local = np.empty((cells.size, nbf, d, nbf, d))
                local[~fresh] = old[src[~fresh]]
                if fresh.any():
                    local[fresh] = self._element_stiffness(cells[fresh], lam, mu, cellwise)
            else:
                local = self._element_stiffness(cells, lam, mu, cellwise)
            if kept is not None:
                kept[cells] = local
            # entry (i, a, j, b) of cell c goes to block (a, b) of position (c, i, j)
            index = (self._chunk_map(cells) * (d * d))[:, :, None, :, None] + ab
            _scatter_chunk(flat, index, local)
        self.element_stiffness = kept
        return blocks

    def _element_stiffness(self, cells, lam, mu, cellwise: bool) -> np.ndarray:
        """Element matrices (C, nbf, d, nbf, d) of K of the cells ``cells``:
        K_c[i, a, j, b] = lam_c S[i, a, j, b] + mu_c (S[i, b, j, a] + delta_ab sum_e S[i, e, j,
        e]) with S[i, a, j, b] = int_c d_a phi_i d_b phi_j (the bilinear form of (2.3))."""
        d, ref = self.dim, self._ref
        nbf = ref.nbf
        inv, det = self._geometry(cells)
        C = det.size
        # G[c, q, i d + a] = sum_k dref[q, i, k] invJ[k, a, c]: gradients at the points
        G = np.einsum("qik,kac->cqia", ref.grads, inv).reshape(C, -1, nbf * d)
        # the weights split evenly (w > 0) keep S, hence K, exactly symmetric
        G *= np.sqrt(det[:, None] * ref.grad_weights)[:, :, None]
        # S[c, i, a, j, b] = int d_a phi_i d_b phi_j (one small matmul per cell)
        S = np.matmul(G.transpose(0, 2, 1), G).reshape(C, nbf, d, nbf, d)
        del G
        if cellwise:
            ne = self.element_dofs.shape[1]
            lam_c = np.broadcast_to(lam, (ne,))[cells].reshape(-1, 1, 1, 1, 1)
            mu_c = np.broadcast_to(mu, (ne,))[cells]
            local = lam_c * S
            local += mu_c.reshape(-1, 1, 1, 1, 1) * S.transpose(0, 1, 4, 3, 2)
            trace = mu_c.reshape(-1, 1, 1) * np.einsum("ciaja->cij", S)
        else:
            local = lam * S
            local += mu * S.transpose(0, 1, 4, 3, 2)
            trace = mu * np.einsum("ciaja->cij", S)
        del S
        for a in range(d):
            local[:, :, a, :, a] += trace
        return local

    def stiffness(self, lam, mu, format: str = "csr", *, reuse=None, keep: bool = False):
        """K of (2.3) for Lamé constants lam, mu (constants or per-cell arrays); CSR or BSR.
        ``reuse``, ``keep``: element matrices of unchanged cells taken from another mesh /
        kept for the next one (:meth:`stiffness_blocks`)."""
        return self.block_matrix(
            self.stiffness_blocks(lam, mu, reuse=reuse, keep=keep), format=format
        )

    @cached_property
    def scalar_mass_values(self) -> np.ndarray:
        """Values of the scalar mass int phi_i phi_j on the scalar pattern (exact)."""
        return self.weighted_scalar_mass_values(None)

    def weighted_scalar_mass_values(self, weight) -> np.ndarray:
        """Values of int w phi_i phi_j on the scalar pattern for a per-cell weight w (n_cells,)
        (None: w = 1), exact on affine cells (|det J| w_c times the reference mass)."""
        ref = self._ref
        if weight is not None:
            weight = np.broadcast_to(
                self.cell_coefficient("density", weight), (self.element_dofs.shape[1],)
            )
        out = np.zeros(self.nnz_scalar)
        if self.compiled_assembly:
            _compiled().scalar_mass(
                np.asarray(self.mesh.p),
                np.asarray(self.mesh.t),
                np.asarray(self.element_dofs),
                self.pattern,
                ref.mass,
                out,
                weight,
            )
            return out
        for cells in self._chunks(ref.nbf * ref.nbf):
            _, det = self._geometry(cells)
            if weight is not None:
                det = det * weight[cells]
            _scatter_chunk(out, self._chunk_map(cells), det[:, None, None] * ref.mass[None])
        return out

    def scalar_mass(self) -> sp.csr_matrix:
        """The scalar mass matrix int phi_i phi_j (CSR, exact)."""
        return self.scalar_matrix(self.scalar_mass_values)

    def kron_identity(self, values: np.ndarray) -> sp.csr_matrix:
        """The vector matrix S (x) I_d of scalar values S on the pattern, d nonzeros per block.

        Vector row d r + a holds the entries d c + a of the scalar row r (CSR built directly,
        no explicit zeros: a third of the memory of a full block matrix in 3D).
        """
        d, n = self.dim, self.n_scalar
        pat = self.pattern
        indptr = pat.indptr.astype(np.int64)
        lengths = np.diff(indptr)
        big = d * pat.nnz >= 2**31 - 1
        idx_dtype = np.int64 if big else np.int32
        vptr = np.empty(d * n + 1, dtype=np.int64)
        vptr[:-1] = (d * indptr[:-1, None] + np.arange(d)[None, :] * lengths[:, None]).ravel()
        vptr[-1] = d * pat.nnz
        rows = pat.rows().astype(np.int64)
        within = np.arange(pat.nnz, dtype=np.int64) - indptr[rows]
        base = d * indptr[rows] + within
        del within
        data = np.empty(d * pat.nnz)
        indices = np.empty(d * pat.nnz, dtype=idx_dtype)
        cols = pat.indices.astype(idx_dtype) * d
        for a in range(d):
            pos = base + a * lengths[rows]
            data[pos] = values
            indices[pos] = cols + a
        return sp.csr_matrix((data, indices, vptr.astype(idx_dtype)), shape=(d * n, d * n))

    def mass(self, density=None) -> sp.csr_matrix:
        """Vector mass M = (scalar mass) x I_d (d nonzeros per block): density 1, or the
        weighted mass int density u . v dx for a per-cell ``density`` (n_cells,)."""
        if density is None:
            return self.kron_identity(self.scalar_mass_values)
        return self.kron_identity(self.weighted_scalar_mass_values(density))

    def coefficient_mass(self, C: np.ndarray) -> sp.csr_matrix:
        """Matrix of  int (C(x) u) . v dx  for a d x d field C given at the quadrature points.

        C has shape (d, d, ne, nq) (degree-2p rule, :attr:`quad_points`).
        """
        d = self.dim
        N = self._quad_values  # (nbf, ne, nq)
        w = self.quad_dx
        blocks = np.zeros((self.nnz_scalar, d, d))
        nbf = N.shape[0]
        for cells in self._chunks(d * d * nbf * nbf):
            positions = self._chunk_map(cells)
            Nc = N[:, cells]
            for a in range(d):
                for b in range(d):
                    local = np.einsum("ieq,jeq,eq->eij", Nc, Nc, w[cells] * C[a, b][cells])
                    _scatter_chunk(blocks[:, a, b], positions, local)
        return self.block_matrix(blocks)

    def restricted_combination(
        self, K, stiffness_coef: float, mass_coef: float, nodes=None, mass_values=None
    ) -> sp.bsr_matrix:
        """(mass_coef M + stiffness_coef K) on the vector dofs of the scalar dofs ``nodes``.

        M is this space's mass, of density 1 or with the scalar ``mass_values`` on the pattern
        (:meth:`weighted_scalar_mass_values` of a per-cell density), and K a matrix from
        :meth:`stiffness` (CSR or BSR):
        its blocks are gathered directly from K's arrays on the entries whose row and column
        are both kept, so neither the sum nor a row/column slice of K is ever formed. Returns
        a BSR matrix with d x d blocks on the kept nodes in increasing order (the layout of
        the interleaved free dofs; pyamg aggregates its block rows as nodes). A K of another
        layout falls back to sparse arithmetic.
        """
        d, n = self.dim, self.n_scalar
        pat = self.pattern
        keep = np.ones(n, dtype=bool) if nodes is None else np.zeros(n, dtype=bool)
        if nodes is not None:
            keep[np.asarray(nodes, dtype=np.int64)] = True
        layout = self._stiffness_layout(K)
        if layout is None:
            scalar = self.scalar_mass_values if mass_values is None else mass_values
            A = (mass_coef * self.kron_identity(scalar) + stiffness_coef * sp.csr_matrix(K)).tocsr()
            dofs = self.vector_dofs(np.flatnonzero(keep))
            return A[dofs][:, dofs].tobsr(blocksize=(d, d))
        new_index = np.cumsum(keep) - 1
        rows = pat.rows()
        entries = np.flatnonzero(keep[rows] & keep[pat.indices])
        rows = rows[entries].astype(np.int64)
        m = int(keep.sum())
        indptr = np.zeros(m + 1, dtype=np.int64)
        np.cumsum(np.bincount(new_index[rows], minlength=m), out=indptr[1:])
        idx_dtype = np.int32 if entries.size < 2**31 - 1 else np.int64
        indices = new_index[pat.indices[entries]].astype(idx_dtype)
        data = np.empty((entries.size, d, d))
        if layout == "bsr":
            np.multiply(stiffness_coef, K.data[entries], out=data)
        else:
            # CSR from the blocks: row d r + a holds blocks[s:e, a, :] of scalar row r = [s, e)
            ptr = pat.indptr.astype(np.int64)
            base = d * (d - 1) * ptr[rows] + d * entries
            stride = d * (ptr[rows + 1] - ptr[rows])
            del rows
            for a in range(d):
                for b in range(d):
                    np.multiply(stiffness_coef, K.data[base + a * stride + b], out=data[:, a, b])
        values = self.scalar_mass_values if mass_values is None else mass_values
        mass = mass_coef * values[entries]
        for a in range(d):
            data[:, a, a] += mass
        return BlockMatrix(
            (data, indices, indptr.astype(idx_dtype)), shape=(d * m, d * m), blocksize=(d, d)
        )

    def symmetric_columns(self, A, nodes) -> sp.csr_matrix:
        """A[:, dofs] for a symmetric A (this space's CSR or BSR matrices), dofs = the vector
        dofs of the scalar dofs ``nodes``: taken as the transpose of the rows, which CSR and BSR
        store contiguously (a column slice of a CSR matrix reads all of it; BSR has none)."""
        nodes = np.asarray(nodes, dtype=np.int64)
        d = self.dim
        if sp.issparse(A) and A.format == "bsr" and A.blocksize == (d, d):
            ptr = A.indptr.astype(np.int64)
            starts, ends = ptr[nodes], ptr[nodes + 1]
            counts = ends - starts
            take = np.repeat(starts - np.concatenate([[0], np.cumsum(counts)[:-1]]), counts)
            take += np.arange(int(counts.sum()))
            indptr = np.concatenate([[0], np.cumsum(counts)])
            rows = sp.bsr_matrix(
                (A.data[take], A.indices[take], indptr),
                shape=(d * nodes.size, A.shape[1]),
                blocksize=(d, d),
            )
            return rows.tocsr().T.tocsr()
        return sp.csr_matrix(A)[self.vector_dofs(nodes)].T.tocsr()

    def _stiffness_layout(self, K):
        """'bsr' or 'csr' if K has the layout :meth:`stiffness` produces, else None."""
        d, N = self.dim, self.ndofs
        pat = self.pattern
        if K.shape != (N, N):
            return None
        if sp.issparse(K) and K.format == "bsr":
            if (
                K.blocksize == (d, d)
                and K.indptr.size == pat.indptr.size
                and np.array_equal(K.indptr, pat.indptr)
                and np.array_equal(K.indices, pat.indices)
            ):
                return "bsr"
            return None
        if not (sp.issparse(K) and K.format == "csr") or K.nnz != d * d * pat.nnz:
            return None
        ptr = pat.indptr.astype(np.int64)
        lengths = np.diff(ptr)
        expected = (d * d * ptr[:-1, None] + d * np.arange(d)[None, :] * lengths[:, None]).ravel()
        if not np.array_equal(K.indptr[:-1], expected):
            return None
        # spot check of the column layout on the diagonal blocks
        diag = pat.diag.astype(np.int64)
        rows = np.arange(self.n_scalar)
        base = d * (d - 1) * ptr[rows] + d * diag
        stride = d * lengths
        for a in range(d):
            if not np.array_equal(K.indices[base + a * stride], d * rows):
                return None
        return "csr"

    # -- fields at quadrature points ------------------------------------------------------------
    def values_at_quad(self, u: np.ndarray) -> np.ndarray:
        """u_h at the quadrature points: shape (d, ne, nq)."""
        U = np.asarray(u).reshape(self.n_scalar, self.dim)
        N = self._quad_values
        return np.stack(
            [np.einsum("ieq,ie->eq", N, U[self.element_dofs, c]) for c in range(self.dim)]
        )

    def gradients_at_quad(self, u: np.ndarray) -> np.ndarray:
        """grad u_h at the quadrature points: shape (d, d, ne, nq), [c, k] = d_k u_c."""
        U = np.asarray(u).reshape(self.n_scalar, self.dim)
        G = self._quad_grads
        return np.stack(
            [np.einsum("ikeq,ie->keq", G, U[self.element_dofs, c]) for c in range(self.dim)]
        )

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
        """The names of the mesh's boundary parts, sorted."""
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
        return np.unique(np.asarray(self._dofs.get_facet_dofs(facets).all(), dtype=np.int64))

    def vector_dofs(self, scalar_dofs: np.ndarray) -> np.ndarray:
        """Interleaved vector dofs of a set of scalar dofs (node-major: k0x, k0y, k1x, ...)."""
        s = np.asarray(scalar_dofs, dtype=np.int64)
        return (self.dim * s[:, None] + np.arange(self.dim)[None, :]).ravel()

    def facet_quadrature(
        self, parts, intorder: int | None = None, name: str = "parts"
    ) -> FacetQuadrature:
        """A :class:`FacetQuadrature` on the named boundary parts (degree ``intorder``, default 2p;
        ``name`` is the parameter an unknown part's error names).

        Made once per (parts, intorder) on this space and shared (read only): scikit-fem's
        FacetBasis maps every cell of the mesh first (5 ms at 4k P2 dofs), and the boundary mass,
        the constraint and the data indicator of a space-adaptive run ask for the same one.
        """
        facets = self.facets(parts, name)
        intorder = 2 * self.degree if intorder is None else int(intorder)
        key = (tuple(parts), intorder)
        cache = self.__dict__.setdefault("_facet_quadratures", {})
        if key not in cache:
            cache[key] = self.facet_quadrature_on(facets, intorder)
        return cache[key]

    def facet_quadrature_on(self, facets, intorder: int | None = None) -> FacetQuadrature:
        """A :class:`FacetQuadrature` on the given ``facets`` (degree ``intorder``, default 2p),
        boundary or interior ones, each seen from its side 0 (``mesh.f2t[0]``, whose outward
        normal it has); not cached (:meth:`facet_quadrature` caches the named parts')."""
        from skfem import FacetBasis  # heavy: imported when first needed (start-up time)

        intorder = 2 * self.degree if intorder is None else int(intorder)
        fb = FacetBasis(self.mesh, self.element, facets=facets, intorder=intorder)
        return FacetQuadrature(
            values=np.stack([np.asarray(b[0]) for b in fb.basis]),
            dofs=np.asarray(fb.element_dofs),
            dx=np.asarray(fb.dx),
            x=np.asarray(fb.global_coordinates()),
            normals=np.asarray(fb.normals),
        )

    def boundary_scalar_mass(self, parts, name: str = "parts") -> sp.csr_matrix:
        """Scalar boundary mass int_Gamma phi_i phi_j ds over the named parts (n_scalar square).

        P1: |F| (1 + delta_ij) / (d (d + 1)) on every facet F (exact, from the facets' vertices;
        scikit-fem's FacetBasis would first build the affine maps of all cells, 0.4 GB at two
        million tetrahedra). P2: facet quadrature of degree 4.
        """
        n = self.n_scalar
        if self.degree == 1:
            facets = self.facets(parts, name)
            dofs = np.asarray(self.mesh.facets)[:, facets]  # (d, nf) vertices
            x = np.asarray(self.mesh.p)[:, dofs]  # (d, d, nf)
            if self.dim == 2:
                size = np.linalg.norm(x[:, 1] - x[:, 0], axis=0)
            else:
                size = 0.5 * np.linalg.norm(
                    np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], axis=0), axis=0
                )
            d = self.dim
            ref = (np.ones((d, d)) + np.eye(d)) / (d * (d + 1))
            local = ref[:, :, None] * size[None, None, :]
        else:
            q = self.facet_quadrature(parts, name=name)
            dofs = q.dofs
            local = np.einsum("ifq,jfq,fq->ijf", q.values, q.values, q.dx)
        rows = np.broadcast_to(dofs[:, None, :], local.shape).ravel()
        cols = np.broadcast_to(dofs[None, :, :], local.shape).ravel()
        return sp.coo_matrix((local.ravel(), (rows, cols)), shape=(n, n)).tocsr()

    # -- misc -----------------------------------------------------------------------------------
    def rigid_body_modes(self, nodes=None) -> np.ndarray:
        """Columns spanning the rigid motions (kernel of K): (ndofs, 3) in 2D, (ndofs, 6) in 3D.

        With ``nodes`` (scalar dofs, increasing), only the rows of their vector dofs.
        """
        d = self.dim
        x = self.doflocs if nodes is None else self.doflocs[:, np.asarray(nodes)]
        n = x.shape[1]
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
