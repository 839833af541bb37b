"""Interfaces between bodies: matching nodes and mortar projections (known answers: the patch
test, the permutation on matching meshes, row sums), glued bodies equal one body, refusals."""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial import cKDTree
from skfem import MeshTet, MeshTri

from rothe.eld.interface import Interface
from rothe.eld.materials import Material, PiecewiseMaterial
from rothe.errors import RotheInputError
from rothe.fem.elasticity import VectorSpace
from rothe.fem.mesh import tag_box_faces


def _square(x0, x1, nx, ny):
    return tag_box_faces(
        MeshTri.init_tensor(np.linspace(x0, x1, nx + 1), np.linspace(0, 1, ny + 1))
    )


def _cube(x0, x1, n, m):
    return tag_box_faces(
        MeshTet.init_tensor(
            np.linspace(x0, x1, n + 1), np.linspace(0, 1, m + 1), np.linspace(0, 1, m + 1)
        )
    )


@pytest.mark.parametrize("dim,degree", [(2, 1), (2, 2), (3, 1), (3, 2)])
def test_matching_meshes_pair_their_nodes_and_the_mortar_projection_is_that_permutation(
    dim, degree
):
    mesh = _square if dim == 2 else _cube
    a = VectorSpace(mesh(0, 1, 2, 3), degree)
    b = VectorSpace(mesh(1, 2, 3, 3), degree)
    matching = Interface(a, "right", b, "left")
    mortar = Interface(a, "right", b, "left", method="mortar")
    assert matching.method == "matching" and mortar.method == "mortar"
    xa = a.doflocs[:, matching.dofs1]
    xb = b.doflocs[:, matching.dofs2]
    assert np.abs(matching.Pi @ xb.T - xa.T).max() < 1e-14  # the partner is the same point
    assert abs(matching.Pi - mortar.Pi).max() < 1e-13
    assert abs(mortar.M12 - mortar.D @ matching.Pi).max() < 1e-14


@pytest.mark.parametrize("dim,degree", [(2, 1), (2, 2), (3, 1), (3, 2)])
def test_mortar_projection_passes_the_patch_test(dim, degree):
    """Non-matching sides: Pi reproduces the fields both trace spaces contain (degree p), and
    the rows of M_12 sum to those of D (their total: the interface's measure, 1)."""
    if dim == 2:
        a, b = VectorSpace(_square(0, 1, 2, 3), degree), VectorSpace(_square(1, 2, 3, 5), degree)
    else:
        a, b = VectorSpace(_cube(0, 1, 2, 2), degree), VectorSpace(_cube(1, 2, 2, 3), degree)
    itf = Interface(a, "right", b, "left")
    assert itf.method == "mortar"
    x1, x2 = a.doflocs[:, itf.dofs1], b.doflocs[:, itf.dofs2]
    fields = [lambda x: 1.0 + 0 * x[1], lambda x: 1 + 2 * x[1] - 3 * x[-1]]
    if degree == 2:
        fields.append(lambda x: x[1] ** 2 - 2 * x[1] * x[-1] + 0.5 * x[-1] ** 2)
    for f in fields:
        assert np.abs(itf.Pi @ f(x2) - f(x1)).max() < 1e-12
    assert np.allclose(
        np.asarray(itf.M12.sum(axis=1)).ravel(), np.asarray(itf.D.sum(axis=1)).ravel(), atol=1e-14
    )
    assert itf.M12.sum() == pytest.approx(1.0, abs=1e-13)
    # a field of higher degree is only projected (P1: the L2 projection of y^2 differs)
    if degree == 1:
        assert np.abs(itf.Pi @ x2[1] ** 2 - x1[1] ** 2).max() > 1e-3
    # the vector form acts per component on interleaved dofs
    u2 = np.ascontiguousarray(
        np.stack(
            [f(b.doflocs) for f in fields[:2]] * (dim // 2)
            + ([fields[0](b.doflocs)] if dim == 3 else [])
        ).T
    ).ravel()
    proj = itf.project(u2).reshape(-1, dim)
    assert np.allclose(proj[:, 1], fields[1](x1), atol=1e-12)


@pytest.mark.parametrize("dim,degree", [(2, 2), (3, 1), (3, 2)])
def test_the_sparse_mortar_projection_equals_the_dense_one(dim, degree, monkeypatch):
    """Pi = D^{-1} M_12 built by blocks of columns (no dense k1 x k2) equals the dense
    formula it replaced (the full solve, entries below 1e-14 of the largest dropped) to
    round-off, with the same entries kept; several blocks (block = 7 columns) and one; the
    patch test holds for the result."""
    import scipy.sparse.linalg as spla

    from rothe.eld import interface

    if dim == 2:
        a, b = VectorSpace(_square(0, 1, 2, 13), degree), VectorSpace(_square(1, 2, 3, 17), degree)
    else:
        a, b = VectorSpace(_cube(0, 1, 2, 4), degree), VectorSpace(_cube(1, 2, 2, 5), degree)
    itf = Interface(a, "right", b, "left")
    assert itf.method == "mortar" and sp.issparse(itf.Pi)
    dense = spla.splu(sp.csc_matrix(itf.D)).solve(itf.M12.toarray())
    dense[np.abs(dense) < 1e-14 * np.abs(dense).max()] = 0.0
    k1, k2 = dense.shape
    assert k2 > 14  # several blocks of 7
    for block in (7, 10_000):
        Pi = interface.mortar_projection(itf.D, itf.M12, block=block)
        assert Pi.shape == (k1, k2) and isinstance(Pi, sp.csr_matrix)
        assert np.abs(Pi.toarray() - dense).max() <= 1e-15 * np.abs(dense).max()
        assert Pi.nnz == np.count_nonzero(dense)
        assert np.array_equal(Pi.toarray() != 0, dense != 0)
    # the interface builds it without a dense k1 x k2: its largest dense array is k1 x block
    shapes = []
    original = interface.mortar_projection

    def spy(D, M12, block=interface.PI_BLOCK):
        real = spla.splu

        def splu(A, *args, **kw):
            lu = real(A, *args, **kw)

            class Spy:
                def solve(self, rhs):
                    shapes.append(rhs.shape)
                    return lu.solve(rhs)

            return Spy()

        monkeypatch.setattr(interface.spla, "splu", splu)
        try:
            return original(D, M12, block=5)
        finally:
            monkeypatch.setattr(interface.spla, "splu", real)

    monkeypatch.setattr(interface, "mortar_projection", spy)
    again = Interface(a, "right", b, "left")
    assert shapes and max(c for _, c in shapes) == 5 and len(shapes) == -(-k2 // 5)
    assert np.abs((again.Pi - itf.Pi).toarray()).max() <= 1e-15
    x1, x2 = a.doflocs[:, itf.dofs1], b.doflocs[:, itf.dofs2]
    assert np.abs(again.Pi @ (1 + 2 * x2[1]) - (1 + 2 * x1[1])).max() < 1e-12


@pytest.mark.parametrize("degree", [1, 2])
def test_glued_bodies_of_two_materials_equal_one_body_with_two_materials(degree):
    """Matching meshes: T^T blkdiag(K_1, K_2) T is the stiffness of the union mesh with the
    two materials on its two halves (and the same for the mass)."""
    soft, stiff = Material(1.0, 1.0, 1.0), Material(3.0, 2.0, 5.0)
    a, b = VectorSpace(_square(0, 1, 2, 2), degree), VectorSpace(_square(1, 2, 3, 2), degree)
    itf = Interface(a, "right", b, "left")
    K = itf.glue(a.stiffness(soft.lam, soft.mu), b.stiffness(stiff.lam, stiff.mu))
    M = itf.glue(soft.rho * a.mass(), stiff.rho * b.mass())
    union_mesh = tag_box_faces(
        MeshTri.init_tensor(
            np.r_[np.linspace(0, 1, 3), np.linspace(1, 2, 4)[1:]], np.linspace(0, 1, 3)
        )
    )
    cx = union_mesh.p[0, union_mesh.t].mean(axis=0)
    union_mesh = union_mesh.with_subdomains(
        {"a": np.flatnonzero(cx < 1), "b": np.flatnonzero(cx > 1)}
    )
    u = VectorSpace(union_mesh, degree)
    cells = PiecewiseMaterial(
        {"soft": soft, "stiff": stiff}, regions={"a": "soft", "b": "stiff"}
    ).on_mesh(union_mesh)
    Ku = u.stiffness(cells.lam, cells.mu)
    Mu = u.mass(cells.rho)
    # the glued unknowns: body 1 off the interface, then all of body 2, located by coordinates
    x_glued = np.hstack([a.doflocs[:, itf.free1[::2] // 2], b.doflocs])
    k = cKDTree(x_glued.T).query(u.doflocs.T)[1]
    P = sp.csr_matrix(
        (np.ones(u.ndofs), (np.arange(u.ndofs), (2 * k[:, None] + np.arange(2)).ravel())),
        shape=(u.ndofs, K.shape[0]),
    )
    assert abs(P @ K @ P.T - Ku).max() < 1e-12 * abs(Ku).max()
    assert abs(P @ M @ P.T - Mu).max() < 1e-14


def test_bad_interfaces_are_one_line_each():
    a = VectorSpace(_square(0, 1, 2, 3), 1)
    apart = VectorSpace(_square(1.5, 2.5, 2, 3), 1)
    shifted = VectorSpace(_square(1, 2, 3, 5), 1)
    half = VectorSpace(
        tag_box_faces(MeshTri.init_tensor(np.linspace(1, 2, 3), np.linspace(0, 0.5, 3))), 1
    )
    cases = [
        (
            lambda: Interface(a, "right", apart, "left"),
            r"^interface: got parts 'right' \(body 1\) and 'left' \(body 2\) that do not touch: "
            r"0 % of 'right' lies on 'left' \(nearest distance 0\.5, tolerance 3\.33e-09\), must "
            r"cover it$",
        ),
        (
            lambda: Interface(a, "right", half, "left"),
            r"^interface: got parts 'right' \(body 1\) and 'left' \(body 2\) that do not touch: "
            r"50 % of 'right' lies on 'left'",
        ),
        (
            lambda: Interface(a, "right", shifted, "left", method="matching"),
            r"^interface: got parts 'right' and 'left' whose nodes do not pair up within 2e-09 "
            r"\(2 of 4 nodes of 'right' have no partner\), must be matching meshes",
        ),
        (
            lambda: Interface(a, "rigth", shifted, "left"),
            r"^interface\.part1: got 'rigth', must be one of bottom, left, right, top",
        ),
        (
            lambda: Interface(a, "right", VectorSpace(_cube(1, 2, 1, 1), 1), "left"),
            r"^interface\.space2: got a 3D body, must have the dimension of body 1 \(2D\)$",
        ),
        (
            lambda: Interface(a, "right", shifted, "left", method="nitsche"),
            r"^interface\.method: got 'nitsche', must be one of auto, matching, mortar$",
        ),
    ]
    for make, message in cases:
        with pytest.raises(RotheInputError, match=message) as info:
            make()
        assert "\n" not in str(info.value)
