"""The lean elasticity assembly (rothe.fem.elasticity) against scikit-fem, and its parts:
sparsity pattern, chunked numpy scatter vs numba loops, step-matrix gather, mesh entities."""

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st
from skfem import (
    Basis,
    BilinearForm,
    ElementVector,
    FacetBasis,
    MeshTet,
    MeshTri,
    asm,
)
from skfem.models.elasticity import linear_elasticity

from rothe.fem import elasticity as el
from rothe.fem import mesh as meshes
from rothe.fem._assembly_numba import AVAILABLE as NUMBA

CASES = [(2, 1), (2, 2), (3, 1), (3, 2)]


def _mesh(dim, perm_seed=None, jiggle=0.0):
    """A small box mesh; optionally with permuted vertex numbers and moved interior vertices
    (so that cells are unsorted and not congruent)."""
    if dim == 2:
        mesh = MeshTri.init_tensor(np.linspace(0, 1, 4), np.linspace(0, 1.5, 5))
    else:
        mesh = MeshTet.init_tensor(np.linspace(0, 1, 4), np.linspace(0, 1, 3), np.linspace(0, 2, 4))
    p, t = mesh.p.copy(), mesh.t.copy()
    rng = np.random.default_rng(perm_seed)
    if jiggle:
        inner = np.all((p > 1e-12) & (p < p.max(axis=1, keepdims=True) - 1e-12), axis=0)
        p[:, inner] += jiggle * rng.uniform(-1, 1, (p.shape[0], int(inner.sum())))
    if perm_seed is not None:
        perm = rng.permutation(p.shape[1])
        inverse = np.empty_like(perm)
        inverse[perm] = np.arange(perm.size)
        p, t = p[:, perm], inverse[t]
        t = t[rng.permutation(t.shape[0])]  # local vertex order scrambled too
    cls = MeshTri if dim == 2 else MeshTet
    mesh = cls(p, t)
    return meshes.tag_box_faces(mesh)


def _skfem_matrices(mesh, dim, degree, lam, mu):
    basis = Basis(mesh, ElementVector(el._scalar_element(dim, degree)), intorder=2 * degree)

    @BilinearForm
    def vector_mass(u, v, w):
        return sum(u[i] * v[i] for i in range(dim))

    return asm(linear_elasticity(lam, mu), basis), asm(vector_mass, basis)


@pytest.fixture(params=["numpy", "numba"])
def kernels(request, monkeypatch):
    """Run a test with the numpy path and (if installed) the compiled loops at any size."""
    if request.param == "numba":
        if not NUMBA:
            pytest.skip("numba not installed (extra 'fast')")
        monkeypatch.setenv("ROTHE_NUMBA", "1")
        monkeypatch.delenv("ROTHE_NO_NUMBA", raising=False)
    else:
        monkeypatch.setenv("ROTHE_NO_NUMBA", "1")
    return request.param


@pytest.mark.parametrize("dim,degree", CASES)
def test_stiffness_and_mass_equal_scikit_fem_on_unsorted_distorted_meshes(dim, degree, kernels):
    mesh = _mesh(dim, perm_seed=3, jiggle=0.08)
    V = el.VectorSpace(mesh, degree)
    assert V.compiled_assembly == (kernels == "numba")
    K_ref, M_ref = _skfem_matrices(mesh, dim, degree, 2.5, 1.25)
    K = V.stiffness(2.5, 1.25)
    Kb = V.stiffness(2.5, 1.25, format="bsr")
    M = V.mass()
    scale = abs(K_ref).max()
    assert abs(K - K_ref).max() < 1e-13 * scale
    assert abs(Kb - K_ref).max() < 1e-13 * scale
    assert abs(M - M_ref).max() < 1e-13 * abs(M_ref).max()
    # the mass stores its d nonzeros per block only; K every entry of every block
    assert M.nnz == dim * V.nnz_scalar and K.nnz == dim * dim * V.nnz_scalar
    np.testing.assert_allclose(V.doflocs, Basis(mesh, V.element).doflocs, atol=1e-15)


@pytest.mark.parametrize("dim,degree", CASES)
def test_numba_loops_equal_the_numpy_chunks_to_round_off(dim, degree, monkeypatch):
    if not NUMBA:
        pytest.skip("numba not installed (extra 'fast')")
    mesh = _mesh(dim, perm_seed=5, jiggle=0.05)
    monkeypatch.setenv("ROTHE_NO_NUMBA", "1")
    V = el.VectorSpace(mesh, degree)
    K0, m0 = V.stiffness_blocks(3.0, 0.7), V.scalar_mass_values
    monkeypatch.setattr(el, "CHUNK_ENTRIES", 64)  # many chunks of a few cells
    V_small = el.VectorSpace(mesh, degree)
    K_small = V_small.stiffness_blocks(3.0, 0.7)
    monkeypatch.delenv("ROTHE_NO_NUMBA")
    monkeypatch.setenv("ROTHE_NUMBA", "1")
    V1 = el.VectorSpace(mesh, degree)
    K1, m1 = V1.stiffness_blocks(3.0, 0.7), V1.scalar_mass_values
    assert np.abs(K1 - K0).max() <= 1e-14 * np.abs(K0).max()
    assert np.abs(K_small - K0).max() <= 1e-14 * np.abs(K0).max()
    assert np.abs(m1 - m0).max() <= 1e-14 * np.abs(m0).max()


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**16), dim=st.sampled_from([2, 3]), degree=st.sampled_from([1, 2]))
def test_pattern_is_the_scalar_coupling_of_the_cells(seed, dim, degree):
    mesh = _mesh(dim, perm_seed=seed)
    V = el.VectorSpace(mesh, degree)
    pat = V.pattern
    ed = V.element_dofs
    nbf, ne = ed.shape
    rows_ref = np.broadcast_to(ed[:, None, :], (nbf, nbf, ne)).ravel()
    cols_ref = np.broadcast_to(ed[None, :, :], (nbf, nbf, ne)).ravel()
    # every pair of dofs that share a cell, no other (counts of the pairs: never zero)
    ref = sp.coo_matrix(
        (np.ones(rows_ref.size), (rows_ref, cols_ref)), shape=(V.n_scalar, V.n_scalar)
    ).tocsr()
    ref.sort_indices()
    assert np.array_equal(pat.indptr, ref.indptr) and np.array_equal(pat.indices, ref.indices)
    assert pat.indices.dtype == np.int32
    assert np.array_equal(pat.indices[pat.diag], np.arange(V.n_scalar))
    rows = pat.rows()
    # the two entries of every unique pair are (a, b) with a < b and (b, a)
    assert np.all(rows[pat.upper] < pat.indices[pat.upper])
    assert np.array_equal(rows[pat.upper], pat.indices[pat.lower])
    assert np.array_equal(pat.indices[pat.upper], rows[pat.lower])
    # the map of every cell entry points at the position of (dof_i, dof_j)
    positions = V._chunk_map(np.arange(ed.shape[1]))
    assert np.array_equal(rows[positions], np.broadcast_to(ed.T[:, :, None], positions.shape))
    assert np.array_equal(
        pat.indices[positions], np.broadcast_to(ed.T[:, None, :], positions.shape)
    )


@pytest.mark.parametrize("dim,degree", CASES)
def test_restricted_combination_is_the_sliced_sum(dim, degree):
    mesh = _mesh(dim, perm_seed=1)
    V = el.VectorSpace(mesh, degree)
    K, M = V.stiffness(2.0, 1.0), V.mass()
    nodes = np.flatnonzero(V.doflocs[0] > 0.2)
    dofs = V.vector_dofs(nodes)
    expected = (1e3 * M + 1.2 * K)[dofs][:, dofs]
    for matrix in (K, V.stiffness(2.0, 1.0, format="bsr"), K.tocsc()):
        A = V.restricted_combination(matrix, 1.2, 1e3, nodes)
        assert A.format == "bsr" and A.blocksize == (dim, dim)
        assert abs(A - expected).max() < 1e-12 * abs(expected).max()
    assert V._stiffness_layout(K) == "csr"
    assert V._stiffness_layout(K.tocsc()) is None
    Kz = K.copy()
    Kz.eliminate_zeros()
    if Kz.nnz != K.nnz:  # a CSR of another layout falls back to sparse arithmetic
        assert V._stiffness_layout(Kz) is None
        assert abs(V.restricted_combination(Kz, 1.2, 1e3, nodes) - expected).max() < 1e-9


def test_symmetric_columns_and_block_matrix_indexing():
    V = el.VectorSpace(_mesh(3, perm_seed=2), 1)
    K = V.stiffness(1.0, 1.0, format="bsr")
    assert isinstance(K, el.BlockMatrix)
    Kc, M = K.tocsr(), V.mass()
    nodes = np.array([0, 4, 9])
    dofs = V.vector_dofs(nodes)
    assert abs(V.symmetric_columns(K, nodes) - Kc[:, dofs]).max() == 0
    assert abs(V.symmetric_columns(M, nodes) - M[:, dofs]).max() == 0
    assert abs(K[dofs][:, dofs] - Kc[dofs][:, dofs]).max() == 0
    x = np.random.default_rng(0).standard_normal(V.ndofs)
    np.testing.assert_allclose(K @ x, Kc @ x, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("dim,degree", CASES)
def test_boundary_mass_equals_facet_quadrature(dim, degree):
    mesh = _mesh(dim, perm_seed=4, jiggle=0.05)
    V = el.VectorSpace(mesh, degree)
    Mb = V.boundary_scalar_mass(("left", "top"))
    fb = FacetBasis(mesh, V.element, facets=V.facets(("left", "top")), intorder=2 * degree)

    @BilinearForm
    def mass(u, v, w):
        return u * v

    assert abs(Mb - asm(mass, fb)).max() < 1e-15


@pytest.mark.parametrize("dim", [2, 3])
def test_mesh_entities_equal_scikit_fems(dim):
    mesh = _mesh(dim, perm_seed=7)
    for indices in (mesh.elem.refdom.facets, getattr(mesh.elem.refdom, "edges", None)):
        ours = meshes.build_entities(mesh.t, indices, mesh.p.shape[1])
        theirs = mesh.build_entities(mesh.t, indices)
        for a, b in zip(ours, theirs, strict=True):
            assert (a is None and b is None) or (np.array_equal(a, b) and a.dtype == b.dtype)
    fresh = (MeshTri if dim == 2 else MeshTet)(mesh.p, mesh.t)
    tagged = meshes.tag_box_faces(fresh)
    assert np.array_equal(
        np.sort(np.concatenate(list(tagged.boundaries.values()))),
        (MeshTri if dim == 2 else MeshTet)(mesh.p, mesh.t).boundary_facets(),
    )


def test_space_construction_is_cheap_and_lazy():
    V = el.VectorSpace(meshes.box(2, 2, 2), 1)
    # no pattern, no scikit-fem basis until a matrix or a quadrature field is asked for
    assert "pattern" not in V.__dict__ and "grad_basis" not in V.__dict__
    V.mass()
    assert "pattern" in V.__dict__ and "quad_basis" not in V.__dict__
    assert sp.issparse(V.scalar_mass())


@pytest.mark.parametrize("dim", [2, 3])
def test_block_matrix_product_is_scipys_bit_for_bit(dim, monkeypatch):
    V = el.VectorSpace(_mesh(dim, perm_seed=6, jiggle=0.05), 2)
    K = V.stiffness(1.7, 0.9, format="bsr")
    x = np.random.default_rng(1).standard_normal(V.ndofs)
    reference = sp.bsr_matrix(K) @ x
    monkeypatch.setenv("ROTHE_NO_NUMBA", "1")
    assert np.array_equal(K @ x, reference)
    if NUMBA:
        monkeypatch.delenv("ROTHE_NO_NUMBA")
        monkeypatch.setenv("ROTHE_NUMBA", "1")  # the compiled product at any size
        assert np.array_equal(K @ x, reference)
        A = V.restricted_combination(K, 1.1, 30.0, np.arange(1, V.n_scalar, 2))
        assert isinstance(A, el.BlockMatrix)
        y = np.random.default_rng(2).standard_normal(A.shape[0])
        assert np.array_equal(A @ y, sp.bsr_matrix(A) @ y)


def test_numba_is_imported_only_when_a_kernel_is_used():
    """Importing numba costs ~35 MB of resident memory in every process: below the thresholds
    (a small 3D P2 assembly and its products) it is not imported at all."""
    import os
    import subprocess
    import sys

    code = (
        "import sys\n"
        "import numpy as np\n"
        "from skfem import MeshTet\n"
        "from rothe.fem import elasticity as el\n"
        "space = el.VectorSpace(MeshTet.init_tensor(*[np.linspace(0, 1, 4)] * 3), 2)\n"
        "K = space.stiffness(1.0, 1.0, format='bsr')\n"
        "K @ np.ones(K.shape[0])\n"
        "print('numba' in sys.modules)\n"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROTHE_")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"


# -- incremental assembly: element matrices of unchanged cells reused -----------------------------


@pytest.mark.parametrize("dim, degree", [(2, 2), (3, 1), (3, 2)])
def test_incremental_stiffness_equals_the_full_assembly_bit_for_bit(dim, degree):
    """After a refinement, a coarsening and both at once, K assembled with the element matrices
    of the unchanged cells taken from the previous mesh equals the full assembly exactly (same
    chunks, same scatter); most cells of the coarsening are reused (the test sees reuse)."""
    from rothe.eld.examples import block, rectangle
    from rothe.fem.adapt import AdaptiveMesh

    amesh = AdaptiveMesh(rectangle(4, 2) if dim == 2 else block(2, 2, 2))
    amesh.uniform(4)  # below NUMBA_MIN_WORK: the compiled loops neither keep nor reuse
    old = el.VectorSpace(amesh.mesh, degree)
    old.stiffness_blocks(2.0, 1.5, keep=True)
    rng = np.random.default_rng(3)
    for what in ("refine", "coarsen", "both"):
        n = amesh.n_cells
        change = amesh.adapt(
            refine=rng.random(n) < 0.2 if what != "coarsen" else None,
            coarsen=rng.random(n) < 0.6 if what != "refine" else None,
        )
        assert change.changed
        source = np.where(change.unchanged, change.old_start, -1)
        assert 0 < np.count_nonzero(source >= 0) < n
        new = el.VectorSpace(amesh.mesh, degree)
        full = new.stiffness_blocks(2.0, 1.5)
        assert new.element_stiffness is None
        inc = new.stiffness_blocks(2.0, 1.5, reuse=(old.element_stiffness, source), keep=True)
        assert np.array_equal(full, inc), what
        # the kept matrices are the cells' own: an unchanged cell has its old one
        kept = new.element_stiffness
        assert np.array_equal(kept[source >= 0], old.element_stiffness[source[source >= 0]])
        old = new


def test_incremental_stiffness_refuses_matrices_of_another_element():
    from rothe.fem.adapt import AdaptiveMesh

    amesh = AdaptiveMesh(_mesh(2))
    p1 = el.VectorSpace(amesh.mesh, 1)
    p1.stiffness_blocks(1.0, 1.0, keep=True)
    p2 = el.VectorSpace(amesh.mesh, 2)
    source = np.arange(amesh.n_cells)
    with pytest.raises(Exception, match=r"^reuse: got .*must give"):
        p2.stiffness_blocks(1.0, 1.0, reuse=(p1.element_stiffness, source))
