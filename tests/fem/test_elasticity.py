"""Vector P1/P2 elasticity assembly (rothe.fem.elasticity) against scikit-fem and exact data."""

import numpy as np
import pytest
import scipy.sparse.linalg as spla
from skfem import Basis, BilinearForm, ElementVector, MeshQuad, MeshTet, MeshTri, asm
from skfem.models.elasticity import linear_elasticity

from rothe.errors import RotheInputError
from rothe.fem import mesh as meshes
from rothe.fem.elasticity import VectorSpace, lame_from_young


def _mesh(dim, n=3):
    return meshes.unit_square(n, named=True) if dim == 2 else meshes.box(n, n, n)


@pytest.mark.parametrize("dim,degree", [(2, 1), (2, 2), (3, 1), (3, 2)])
def test_stiffness_and_mass_match_scikit_fem(dim, degree):
    mesh = _mesh(dim, 2)
    V = VectorSpace(mesh, degree)
    basis = Basis(mesh, ElementVector(V.element), intorder=2 * degree)

    @BilinearForm
    def vector_mass(u, v, w):
        return sum(u[i] * v[i] for i in range(dim))

    # scikit-fem's vector element interleaves the components like VectorSpace
    assert abs(V.stiffness(2.0, 1.5) - asm(linear_elasticity(2.0, 1.5), basis)).max() < 1e-12
    assert abs(V.mass() - asm(vector_mass, basis)).max() < 1e-14


@pytest.mark.parametrize("dim,degree", [(2, 1), (2, 2), (3, 1)])
def test_rigid_motions_are_the_kernel_and_mass_measures_the_domain(dim, degree):
    V = VectorSpace(_mesh(dim), degree)
    K, M = V.stiffness(3.0, 0.7), V.mass()
    R = V.rigid_body_modes()
    assert np.abs(K @ R).max() < 1e-12
    assert abs(K - K.T).max() < 1e-13
    one_x = np.zeros(V.ndofs)
    one_x[0::dim] = 1.0
    assert one_x @ (M @ one_x) == pytest.approx(1.0, rel=1e-12)  # |unit square| or |unit cube|


def _static_error(n, degree):
    """Solve -div sigma(u) = f, u = exact on the boundary, for u = (sin(pi x) sin(pi y), x y^2)."""
    lam, mu = 2.0, 1.0
    pi = np.pi

    def exact(x):
        return np.stack([np.sin(pi * x[0]) * np.sin(pi * x[1]), x[0] * x[1] ** 2])

    def grad(x):
        X, Y = x[0], x[1]
        return np.stack(
            [
                np.stack(
                    [pi * np.cos(pi * X) * np.sin(pi * Y), pi * np.sin(pi * X) * np.cos(pi * Y)]
                ),
                np.stack([Y**2, 2 * X * Y]),
            ]
        )

    def force(x):
        X, Y = x[0], x[1]
        s = np.sin(pi * X) * np.sin(pi * Y)
        c = np.cos(pi * X) * np.cos(pi * Y)
        # -div sigma = -mu lap u - (lam + mu) grad div u, div u = pi cos(pi x) sin(pi y) + 2 x y
        lap = np.stack([-2 * pi**2 * s, 2 * X])
        grad_div = np.stack([-(pi**2) * s + 2 * Y, pi**2 * c + 2 * X])
        return -mu * lap - (lam + mu) * grad_div

    V = VectorSpace(meshes.unit_square(n, named=True), degree)
    K = V.stiffness(lam, mu)
    F = V.load_from_quad(force(V.quad_points))
    fixed = V.vector_dofs(V.scalar_dofs_on(("left", "right", "bottom", "top")))
    free = np.setdiff1d(np.arange(V.ndofs), fixed)
    u = V.interpolate(exact)
    u[free] = spla.spsolve(K[free][:, free].tocsc(), F[free] - K[free][:, fixed] @ u[fixed])
    return V.error_norms(u, exact, grad)


@pytest.mark.parametrize("degree,order", [(1, 2.0), (2, 3.0)])
def test_static_convergence_orders(degree, order):
    errs = [_static_error(n, degree) for n in (4, 8, 16)]
    l2 = [e["l2"] for e in errs]
    h1 = [e["h1_semi"] for e in errs]
    rate_l2 = np.polyfit(np.log([4, 8, 16]), np.log(l2), 1)[0]
    rate_h1 = np.polyfit(np.log([4, 8, 16]), np.log(h1), 1)[0]
    assert -rate_l2 > order - 0.25
    assert -rate_h1 > order - 1 - 0.25


def test_constant_traction_integrates_to_the_force():
    V = VectorSpace(meshes.unit_square(5, named=True), 2)
    q = V.facet_quadrature(("right",))
    g = np.broadcast_to(np.array([3.0, -2.0])[:, None, None], q.x.shape)
    load = q.integrate_against_basis(g, V.n_scalar)
    assert load.sum(axis=0) == pytest.approx([3.0, -2.0], rel=1e-12)
    assert np.allclose(q.normals[0], 1.0) and np.allclose(q.normals[1], 0.0)


def test_boundary_dofs_of_p2_include_edge_midpoints():
    V = VectorSpace(meshes.unit_square(4, named=True), 2)
    dofs = V.scalar_dofs_on(("left",))
    assert dofs.size == 9  # 5 vertices and 4 edge midpoints on x = 0
    assert np.allclose(V.doflocs[0, dofs], 0.0)


def test_bad_inputs_are_one_line_errors():
    V = VectorSpace(meshes.unit_square(2, named=True), 1)
    with pytest.raises(
        RotheInputError, match=r"^parts: got 'lft', must be one of bottom, left, right, top"
    ):
        V.scalar_dofs_on(("lft",))
    with pytest.raises(RotheInputError, match="degree: got 3, must be 1 or 2"):
        VectorSpace(meshes.unit_square(2, named=True), 3)
    with pytest.raises(
        RotheInputError, match="mesh: got 'MeshQuad1', must be a scikit-fem MeshTri or MeshTet"
    ):
        VectorSpace(MeshQuad(), 1)
    with pytest.raises(RotheInputError, match="nu: got 0.5, must satisfy -1 < nu < 0.5"):
        lame_from_young(1000.0, 0.5)
    lam, mu = lame_from_young(1000.0, 0.3)
    assert mu == pytest.approx(1000 / 2.6) and lam == pytest.approx(1000 * 0.3 / (1.3 * 0.4))


def test_box_mesh_has_six_named_faces():
    mesh = meshes.box(4, 2, 3, length=2.0)
    assert sorted(mesh.boundaries) == ["back", "bottom", "front", "left", "right", "top"]
    assert isinstance(mesh, MeshTet)
    # each face of the box: 2 triangles per square
    assert len(mesh.boundaries["left"]) == 2 * 2 * 3
    assert len(mesh.boundaries["right"]) == 2 * 2 * 3
    assert isinstance(meshes.unit_square(2, named=True), MeshTri)
