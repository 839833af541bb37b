"""The FE RIS problem: structure (interior unknowns, full state, lumped weights), derivatives of
F by nodal quadrature, every bad input named in the issue with its one-line message, and the
data that can (or cannot) move to another mesh."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from skfem import MeshTri

from rothe.errors import RotheInputError
from rothe.fem.adapt import SpaceAdaptivity
from rothe.fem.mesh import load_mesh, unit_square
from rothe.fem.scalar import lumped_mass, stiffness
from rothe.ris.examples import d2g_7_2, dg_7_2, example_7_2, example_front, g_7_2
from rothe.ris.fem_problem import FERISProblem, check_pointwise_derivatives


@pytest.fixture(scope="module")
def p8():
    return example_7_2(8)


def test_structure_of_example_7_2(p8):
    p = p8
    mesh = p.mesh
    assert p.n_nodes == 81 and p.n == 49 and p.free.size + p.fixed.size == 81
    on_edge = (mesh.p[:, p.fixed] == 0) | (mesh.p[:, p.fixed] == 1)
    assert np.all(on_edge.any(axis=0))
    m = lumped_mass(mesh)
    assert np.allclose(p.m, m[p.free]) and np.allclose(p.r, p.kappa * m[p.free])
    K = stiffness(mesh)
    assert abs(p.A - K[p.free][:, p.free]).max() == 0
    # full_state: all nodes in mesh order, zero on the boundary
    z = np.arange(1.0, p.n + 1)
    full = p.full_state(z)
    assert full.shape == (81,) and np.all(full[p.fixed] == 0) and np.array_equal(full[p.free], z)
    # load: -200 t^3 int phi_i = -200 t^3 m_i exactly
    assert np.allclose(p.load(0.5), -200 * 0.125 * p.m)
    assert np.allclose(p.load_rate(0.5), -600 * 0.25 * p.m)
    # F over all nodes: 48 * area at z = 0, and the integral of g by the vertex rule
    assert math.isclose(p.F(np.zeros(p.n)), 48.0, rel_tol=1e-14)
    assert math.isclose(p.energy(0.0, p.z0), 48.0, rel_tol=1e-14)


@settings(max_examples=40, deadline=None)
@given(arrays(np.float64, 49, elements=st.floats(-2, 2)), st.floats(0, 1))
def test_F_and_gradient_are_the_lumped_integrals(z, t):
    p = example_7_2(8)
    full = p.full_state(z)
    m_all = lumped_mass(p.mesh)
    assert math.isclose(p.F(z), float(m_all @ g_7_2(full)), rel_tol=1e-12, abs_tol=1e-12)
    assert np.allclose(p.dF(z), p.m * dg_7_2(z), rtol=1e-14, atol=0)
    assert np.allclose(p.d2F(z), p.m * d2g_7_2(z), rtol=1e-14, atol=0)
    # directional derivative of the energy by central differences
    v = np.sin(np.arange(p.n))
    h = 1e-6
    fd = (p.energy(t, z + h * v) - p.energy(t, z - h * v)) / (2 * h)
    assert math.isclose(p.gradient(t, z) @ v, fd, rel_tol=1e-6, abs_tol=1e-6)
    # dist: closed form with lumped weights (SPEC section 1)
    eta = p.gradient(t, z)
    closed_form = float(np.sum(np.maximum(np.abs(eta) - p.m, 0) ** 2 / p.m))
    assert math.isclose(p.dist(eta) ** 2, closed_form, rel_tol=1e-12, abs_tol=1e-300)


def test_named_dirichlet_parts_and_z0_forms():
    mesh = unit_square(4)
    p = example_7_2(mesh=mesh, dirichlet=["left"])
    assert p.fixed.size == 5 and np.allclose(mesh.p[0, p.fixed], 0) and p.n == 20
    # z0 as a callable, as nodal values (zero on the boundary) and as free values
    q = example_7_2(4, z0=lambda x: np.sin(np.pi * x[0]) * np.sin(np.pi * x[1]))
    full = q.full_state(q.z0)
    assert full.max() > 0.9 and np.all(full[q.fixed] == 0)
    assert np.array_equal(example_7_2(4, z0=full).z0, q.z0)
    assert np.array_equal(example_7_2(4, z0=q.z0).z0, q.z0)
    assert np.all(example_7_2(4, z0=-0.5).z0 == -0.5)


# -- bad inputs ----------------------------------------------------------------------------------


def test_wrong_first_derivative():
    with pytest.raises(
        RotheInputError,
        match=r"^dg: got .* at z = -2.31, must match finite differences of g "
        r"\(.*\); check the derivative you supplied$",
    ):
        FERISProblem(
            unit_square(4),
            g_7_2,
            lambda z: 192 * z * (1 - z * z),
            d2g_7_2,
            load=lambda t: -200 * t**3,
        )


def test_wrong_second_derivative():
    with pytest.raises(
        RotheInputError,
        match=r"^d2g: got 2881\.59 at z = -2\.31, must match "
        r"finite differences of dg \(2877\.59\)",
    ):
        # g = 48 (1 - z^2)^2 - 2 z^2 with the derivative right but g'' of the plain double well
        FERISProblem(
            unit_square(4),
            lambda z: g_7_2(z) - 2 * z * z,
            lambda z: dg_7_2(z) - 4 * z,
            d2g_7_2,
            load=lambda t: -200 * t**3,
        )


def test_correct_piecewise_g_passes_and_nonvectorized_g_fails():
    # |z|^3 has a continuous g'' with a kink at 0; the check points avoid round numbers
    check_pointwise_derivatives(
        lambda z: np.abs(z) ** 3, lambda z: 3 * z * np.abs(z), lambda z: 6 * np.abs(z)
    )
    with pytest.raises(RotheInputError, match=r"^g: got an error on a numpy array \(TypeError"):
        FERISProblem(unit_square(4), lambda z: math.exp(z), np.exp, np.exp, load=lambda t: 0.0)
    with pytest.raises(RotheInputError, match=r"^dg: got a non-finite value at z = -2.31"):
        check_pointwise_derivatives(np.exp, lambda z: np.where(z < -2, np.nan, np.exp(z)), np.exp)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_load_nan_or_inf(bad):
    with pytest.raises(
        RotheInputError,
        match=r"^load\(t=0\.625\): got (nan|inf|-inf), must be "
        r"finite \(no NaN or inf\)$",
    ):
        example_load = lambda t: bad if t > 0.6 else -200 * t**3  # noqa: E731
        FERISProblem(unit_square(4), g_7_2, dg_7_2, d2g_7_2, load=example_load)
    vec = np.zeros(25)
    vec[12] = bad  # an interior node
    with pytest.raises(RotheInputError, match=r"^load\(t=0\): got .*, must be finite"):
        FERISProblem(unit_square(4), g_7_2, dg_7_2, d2g_7_2, load=lambda t: vec)


def test_load_of_wrong_shape_or_raising():
    with pytest.raises(
        RotheInputError,
        match=r"^load\(t=0\): got an array of shape \(3,\), "
        r"must be a number \(density\) or one nodal "
        r"functional per node \(25\)$",
    ):
        FERISProblem(unit_square(4), g_7_2, dg_7_2, d2g_7_2, load=lambda t: np.ones(3))
    with pytest.raises(RotheInputError, match=r"^load\(t=0\): got an error \(KeyError"):
        FERISProblem(unit_square(4), g_7_2, dg_7_2, d2g_7_2, load=lambda t: {}[t])


def test_mesh_without_boundary_or_interior_nodes(tmp_path, gmsh_text):
    # a physical group that names no facet of the mesh: no Dirichlet nodes
    path = gmsh_text.write_msh22(
        tmp_path / "sq.msh",
        unit_square(4),
        lambda mid: np.where(np.isclose(mid[0], 0), "left", "rest"),
    )
    text = (
        path.read_text()
        .replace('"rest"', '"rest"\n1 9 "hole"')
        .replace("$PhysicalNames\n3", "$PhysicalNames\n4")
    )
    path.write_text(text)
    mesh = load_mesh(path)
    with pytest.raises(RotheInputError, match=r"^dirichlet: got 'hole', must be one of left, rest"):
        example_7_2(mesh=mesh, dirichlet=["hole"])
    mesh = MeshTri(
        mesh.p,
        mesh.t,
        _boundaries={"left": mesh.boundaries["left"], "hole": np.empty(0, dtype=np.int64)},
    )
    with pytest.raises(
        RotheInputError,
        match=r"^mesh: got a mesh with no nodes on boundary parts "
        r"\['hole'\] \(25 nodes, 32 triangles\), homogeneous "
        r"Dirichlet data needs at least one boundary node$",
    ):
        example_7_2(mesh=mesh, dirichlet=["hole"])
    # every node on the boundary: nothing to compute
    with pytest.raises(
        RotheInputError,
        match=r"^mesh: got a mesh whose 4 nodes all lie on the "
        r"Dirichlet boundary, needs at least one interior",
    ):
        example_7_2(mesh=MeshTri())


def test_z0_nonzero_on_the_boundary_and_bad_shapes():
    full = np.ones(25)
    with pytest.raises(
        RotheInputError,
        match=r"^z0: got values up to 1 on Dirichlet nodes, must "
        r"vanish there \(homogeneous Dirichlet data\)$",
    ):
        example_7_2(4, z0=full)
    with pytest.raises(RotheInputError, match=r"^z0: got an array of shape \(7,\)"):
        example_7_2(4, z0=np.zeros(7))
    with pytest.raises(RotheInputError, match=r"^z0: got nan, must be finite"):
        example_7_2(4, z0=math.nan)


def test_kappa_and_T_must_be_positive():
    with pytest.raises(RotheInputError, match=r"^kappa: got 0, must be > 0$"):
        example_7_2(4, kappa=0)
    with pytest.raises(RotheInputError, match=r"^T: got -1, must be > 0$"):
        example_7_2(4, T=-1)


def test_fe_problem_needs_a_dirichlet_node_on_every_part_of_the_mesh():
    """The stiffness on the free nodes is singular on a part of the mesh without Dirichlet
    nodes; FE problems check it by connected components instead of a factorization."""
    a = unit_square(3)
    b = MeshTri(a.p + np.array([[3.0], [0.0]]), a.t)  # a second square, apart from the first
    two = MeshTri(np.hstack([a.p, b.p]), np.hstack([a.t, b.t + a.p.shape[1]]))
    left = lambda x: x[0] < 1e-9  # noqa: E731
    two = two.with_boundaries({"left": left})
    with pytest.raises(
        RotheInputError,
        match=r"^mesh: got a mesh of 2 disconnected parts, 1 of "
        r"them without a node on boundary parts \['left'\]",
    ):
        FERISProblem(two, g_7_2, dg_7_2, d2g_7_2, load=lambda t: -200 * t**3, dirichlet=["left"])
    FERISProblem(two, g_7_2, dg_7_2, d2g_7_2, load=lambda t: -200 * t**3)  # both held


def test_only_data_defined_on_the_domain_moves_to_another_mesh():
    """check_movable names the API parameter, adapt (the command line renames it): a load of
    nodal functionals or a per-cell coefficient belongs to one mesh."""
    p = example_7_2(4)
    p.check_movable()
    q = p.on_mesh(unit_square(5))
    assert q.n_nodes == 36 and np.allclose(q.load(0.5), -200 * 0.125 * q.m)
    nodal = FERISProblem(p.mesh, g_7_2, dg_7_2, d2g_7_2, load=lambda t: -200 * t**3 * p.m_all)
    with pytest.raises(
        RotheInputError,
        match=r"^adapt: got a load given as nodal functionals "
        r"of one mesh, needs a load density",
    ) as info:
        nodal.check_movable()
    assert info.value.parameter == "adapt"
    cells = FERISProblem(
        p.mesh, g_7_2, dg_7_2, d2g_7_2, load=lambda t: -1.0, coefficient=np.ones(p.mesh.t.shape[1])
    )
    with pytest.raises(
        RotheInputError,
        match=r"^adapt: got a coefficient given per cell of one "
        r"mesh, needs a number or a callable c\(x\)$",
    ):
        cells.on_mesh(unit_square(5))
    front = example_front(4)
    front.check_movable()
    from rothe.ris.adapt import RISAdaptivity

    assert RISAdaptivity(front, SpaceAdaptivity(space_tol=1.0)).mesh_id == 0


def test_the_consistent_quadrature_integrates_the_double_well_exactly_with_its_derivatives():
    """quadrature="consistent": F(z) = int g(z_h) exactly for the quartic g of (7.2) (checked
    against a 4x finer grid's integral of the same P1 function, which the rule also integrates
    exactly), F' and F'' (a sparse matrix) match central differences."""
    p = example_7_2(6, quadrature="consistent")
    rng = np.random.default_rng(7)
    z = rng.uniform(-1.3, 1.3, p.n)
    from rothe.fem.adapt import AdaptiveMesh, free_transfer

    amesh = AdaptiveMesh(p.mesh)
    change = amesh.refine(np.ones(amesh.n_cells, dtype=bool))
    q = p.on_mesh(amesh.mesh)
    zq = free_transfer(change.transfer(1), p.free, q.free) @ z
    assert q.F(zq) == pytest.approx(p.F(z), rel=1e-13)
    lumped = example_7_2(6)
    assert abs(lumped.F(z) - p.F(z)) > 1.0  # the vertex rule is another energy
    v = rng.standard_normal(p.n)
    h = 1e-6
    fd = (p.F(z + h * v) - p.F(z - h * v)) / (2 * h)
    assert p.dF(z) @ v == pytest.approx(fd, rel=1e-7)
    H = p.d2F(z)
    assert H.shape == (p.n, p.n) and H.nnz == p.A.nnz
    fd2 = (p.dF(z + h * v) - p.dF(z - h * v)) / (2 * h)
    assert np.allclose(H @ v, fd2, rtol=1e-6, atol=1e-6 * np.abs(fd2).max())
    assert abs(H - H.T).max() <= 1e-12 * abs(H).max()


def test_the_consistent_quadrature_of_a_load_density_and_bad_input():
    """<l(t), z_h> = int l z_h by the cell rule: exact for l = x^2 y^2 against the affine
    z_h = 1 - x (zero on the Dirichlet side x = 1): 1/36; the lumped m_i l(x_i) z_i is off by
    O(h^2). An unknown quadrature is refused in one line."""

    def problem(quadrature):
        return FERISProblem(
            unit_square(4),
            g_7_2,
            dg_7_2,
            d2g_7_2,
            None,
            load_density=lambda t, x: x[0] ** 2 * x[1] ** 2,
            dirichlet=["right"],
            quadrature=quadrature,
        )

    p, lumped = problem("consistent"), problem("lumped")
    z = 1.0 - p.nodes[p.free, 0]
    assert p.load(0.0) @ z == pytest.approx(1.0 / 36.0, rel=1e-13)
    assert abs(lumped.load(0.0) @ z - 1.0 / 36.0) > 5e-4  # measured 9.2e-4
    with pytest.raises(RotheInputError, match=r"^quadrature: got 'gauss', must be one of lumped"):
        example_7_2(4, quadrature="gauss")
