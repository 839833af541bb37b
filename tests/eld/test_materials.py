"""Materials: plane stress, several materials in one body (per-cell assembly, regions from gmsh
subdomains), and their refusals."""

import meshio
import numpy as np
import pytest
import scipy.sparse.linalg as spla
from skfem import MeshTri

from rothe.eld import DirichletData, ELDProblem, Material, StressEvaluator
from rothe.eld.materials import PiecewiseMaterial, material_from, materials_from
from rothe.errors import RotheInputError
from rothe.fem import mesh as meshes
from rothe.fem.elasticity import VectorSpace
from rothe.fem.mesh import tag_box_faces


def _zero(t, x):
    return 0 * x


#: a held part: G = 0 with its derivatives given (no differenced-derivative warnings)
HELD = DirichletData(_zero, _zero, _zero)


def _bar(nx=8, ny=2, length=2.0, height=0.25):
    return tag_box_faces(
        MeshTri.init_tensor(np.linspace(0, length, nx + 1), np.linspace(0, height, ny + 1))
    )


def _halves(mesh, at=1.0):
    """Subdomains 'a' (centroid x < at) and 'b'."""
    c = mesh.p[:, mesh.t].mean(axis=1)
    return mesh.with_subdomains({"a": np.flatnonzero(c[0] < at), "b": np.flatnonzero(c[0] >= at)})


@pytest.mark.parametrize("degree", [1, 2])
def test_all_regions_with_one_material_assemble_the_single_material_matrices(degree):
    mesh = _halves(_bar())
    steel = Material.from_young(E=200.0, nu=0.3, rho=7.8, dim=2)
    one = ELDProblem(mesh, steel, degree=degree, dirichlet={"left": HELD})
    two = ELDProblem(
        mesh,
        PiecewiseMaterial({"steel": steel}, regions={"a": "steel", "b": "steel"}),
        degree=degree,
        dirichlet={"left": HELD},
    )
    assert abs(one.K - two.K).max() <= 1e-13 * abs(one.K).max()
    assert abs(one.M - two.M).max() == 0.0
    assert two.material.rho == 7.8
    assert one.describe()["lam"] == steel.lam and "plane" not in one.describe()


def test_two_material_bar_static_displacement_is_the_analytic_one():
    """nu = 0: uniaxial stress P, u_x = P x/E1 on [0, 1], P/E1 + P (x - 1)/E2 on [1, 2]:
    piecewise linear, so P1 is exact when x = 1 is a mesh line."""
    mesh = _halves(_bar(nx=8, ny=2))
    E1, E2, P = 100.0, 25.0, 0.3
    mats = PiecewiseMaterial(
        {
            "stiff": Material.from_young(E1, 0.0, 1.0, dim=2),
            "soft": Material.from_young(E2, 0.0, 2.0, dim=2),
        },
        regions={"a": "stiff", "b": "soft"},
    )
    problem = ELDProblem(
        mesh,
        mats,
        degree=1,
        dirichlet={"left": HELD},
        traction={"right": lambda t, x, n: np.stack([P + 0 * x[0], 0 * x[0]])},
    )
    c = problem.constraint
    K = problem.K.tocsr()
    u = np.zeros(problem.space.ndofs)
    u[c.free] = spla.spsolve(K[c.free][:, c.free].tocsc(), problem.load(0.0)[c.free])
    x = problem.space.doflocs[0]
    exact = np.where(x <= 1.0, P * x / E1, P / E1 + P * (x - 1.0) / E2)
    U = u.reshape(-1, 2)
    assert np.abs(U[:, 0] - exact).max() < 1e-12
    assert np.abs(U[:, 1]).max() < 1e-12
    # the mass is the actual density's: rho_ref M integrates rho over the body (0.25 x (1 + 2))
    ones = np.tile([1.0, 0.0], problem.space.n_scalar)
    assert problem.material.rho * ones @ (problem.M @ ones) == pytest.approx(0.25 * 3.0, 1e-13)


@pytest.mark.parametrize("plane", ["strain", "stress"])
def test_plane_models_give_their_energy_for_a_uniform_strain(plane):
    E, nu = 10.0, 0.3
    m = Material.from_young(E, nu, rho=1.0, dim=2, plane=plane)
    V = VectorSpace(meshes.unit_square(3), 1)
    eps = np.array([[0.02, 0.005], [0.005, -0.01]])
    u = np.ascontiguousarray((eps @ V.doflocs).T).ravel()
    K = V.stiffness(m.lam_eff, m.mu)
    if plane == "stress":  # sigma = E/(1 - nu^2) [(1 - nu) eps + nu tr(eps) I]
        sig = E / (1 - nu**2) * ((1 - nu) * eps + nu * np.trace(eps) * np.eye(2))
    else:  # sigma = E/((1 + nu)(1 - 2 nu)) [(1 - 2 nu) eps + nu tr(eps) I]
        sig = E / ((1 + nu) * (1 - 2 * nu)) * ((1 - 2 * nu) * eps + nu * np.trace(eps) * np.eye(2))
    assert u @ (K @ u) == pytest.approx(np.sum(sig * eps), rel=1e-12)  # area 1
    s = StressEvaluator(V, m).stress(u)
    assert np.allclose(s[:, :2, :2], sig, rtol=1e-12, atol=0)
    expected_zz = 0.0 if plane == "stress" else m.lam * np.trace(eps)
    assert np.allclose(s[:, 2, 2], expected_zz, atol=1e-14)


def test_piecewise_stresses_use_each_cells_constants():
    mesh = _halves(_bar())
    mats = PiecewiseMaterial(
        {"x": Material(1.0, 1.0, 1.0), "y": Material(1.0, 3.0, 2.0)}, regions={"a": "x", "b": "y"}
    )
    V = VectorSpace(mesh, 1)
    u = np.ascontiguousarray((0.01 * V.doflocs).T).ravel()  # eps = 0.01 I, tr = 0.02
    s = StressEvaluator(V, mats).stress(u)
    a = mesh.subdomains["a"]
    b = mesh.subdomains["b"]
    assert np.allclose(s[a, 0, 0], 1.0 * 0.02 + 2 * 1.0 * 0.01)
    assert np.allclose(s[b, 0, 0], 3.0 * 0.02 + 2 * 2.0 * 0.01)


def test_regions_by_predicate_of_the_centroids():
    mesh = _bar()
    mats = PiecewiseMaterial(
        {"x": Material(1.0, 1.0, 1.0), "y": Material(4.0, 1.0, 1.0)},
        regions={lambda c: c[0] < 1.0: "x", lambda c: c[0] >= 1.0: "y"},
    )
    cells = mats.on_mesh(mesh)
    assert set(np.unique(cells.rho)) == {1.0, 4.0}
    assert cells.density_weight.max() == 1.0 and mats.rho == 4.0


def test_gmsh_cell_physical_groups_are_subdomains_and_material_regions(tmp_path):
    points = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0]], float)
    tris = np.array([[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]])
    lines = np.array([[0, 3]])
    m = meshio.Mesh(
        points,
        [("triangle", tris), ("line", lines)],
        cell_data={
            "gmsh:physical": [np.array([1, 1, 2, 2]), np.array([3])],
            "gmsh:geometrical": [np.array([1, 1, 2, 2]), np.array([3])],
        },
        field_data={"core": np.array([1, 2]), "shell": np.array([2, 2]), "clamp": np.array([3, 1])},
    )
    path = tmp_path / "two.msh"
    m.write(path, file_format="gmsh22", binary=False)
    mesh = meshes.load_mesh(path)
    assert sorted(mesh.subdomains) == ["core", "shell"] and list(mesh.boundaries) == ["clamp"]
    cx = mesh.p[0, mesh.t].mean(axis=0)
    assert np.all(cx[mesh.subdomains["core"]] < 1) and np.all(cx[mesh.subdomains["shell"]] > 1)
    mats = PiecewiseMaterial({"core": Material(1.0, 1.0, 1.0), "shell": Material(2.0, 1.0, 5.0)})
    problem = ELDProblem(mesh, mats, dirichlet={"clamp": HELD})
    assert np.array_equal(problem.cell_material.mu[mesh.subdomains["shell"]], [5.0, 5.0])
    # a file whose volume cells carry no tag: no subdomains, a material by region is refused
    plain = meshio.Mesh(points, [("triangle", tris)])
    plain.write(tmp_path / "plain.msh", file_format="gmsh22", binary=False)
    # (no regions given: each material's name is its region, so the refusal names the
    # materials; it named the regions, which were not given)
    no_subdomains = (
        r"^materials: got 'core', must be one of the mesh's subdomains: \(the mesh has no "
        r"subdomains\) \(a material without a region fills the cell group of its name\)$"
    )
    with pytest.raises(RotheInputError, match=no_subdomains):
        mats.on_mesh(meshes.load_mesh(tmp_path / "plain.msh"))


def test_bad_material_input_is_one_line_each():
    mesh = _halves(_bar())
    one = Material(1.0, 1.0, 1.0)
    cases = [
        (
            lambda: PiecewiseMaterial({"x": one}, regions={"a": "x"}).on_mesh(mesh),
            r"^materials: got 16 of 32 cells in no region with a material \(the first at "
            r"\(1\.083, 0\.08333\)\), every cell must be in one of the regions a$",
        ),
        (
            lambda: PiecewiseMaterial({"x": one}, regions={"c": "x"}).on_mesh(mesh),
            r"^regions: got 'c', must be one of the mesh's subdomains: a, b$",
        ),
        (
            lambda: PiecewiseMaterial({"x": one}, regions={"a": "y"}),
            r"^regions: got 'a' -> 'y', must map each region to one of the materials: x$",
        ),
        (
            lambda: PiecewiseMaterial(
                {"x": one, "y": Material(1.0, 1.0, 2.0)},
                regions={"a": "x", lambda c: c[0] < 2: "y"},
            ).on_mesh(mesh),
            r"^regions: got '<lambda>', must not overlap a region of another material: 16 cells",
        ),
        (
            lambda: PiecewiseMaterial({"x": one, "y": Material(1.0, 1.0, 1.0, dim=3)}),
            r"^materials\['y'\]: got dim 3, plane 'strain', must match the other materials",
        ),
        (lambda: PiecewiseMaterial({}), r"^materials: got \{\}, must map at least one name"),
        (
            lambda: Material(1.0, -0.7, 1.0, plane="stress"),
            r"^lam: got -0\.7, must be > -2 mu / 3 = -0\.666667 for plane stress",
        ),
        (
            lambda: Material(1.0, 1.0, 1.0, dim=3, plane="stress"),
            r"^plane: got 'stress', must be 'strain' \(the default\) in 3D",
        ),
        (
            lambda: Material(1.0, 1.0, 1.0, plane="shell"),
            r"^plane: got 'shell', must be one of strain, stress$",
        ),
        (
            lambda: VectorSpace(mesh, 1).stiffness(np.ones(3), 1.0),
            r"^lam: got an array of shape \(3,\), must be a number or one value per cell, "
            r"shape \(32,\)$",
        ),
    ]
    for make, message in cases:
        with pytest.raises(RotheInputError, match=message) as info:
            make()
        assert "\n" not in str(info.value)
    # plane stress admits what plane strain refuses and vice versa (-mu < lam <= -2 mu / 3)
    Material(1.0, -0.6, 1.0, plane="stress")
    Material(1.0, -0.9, 1.0, plane="strain")


def test_material_from_either_pair_and_a_pair_completed_from_the_default():
    lam, mu = 0.3 * 200 / (1.3 * 0.4), 200 / 2.6
    by_young = material_from(rho=7.8, E=200.0, nu=0.3, dim=3)
    assert by_young == Material.from_young(200.0, 0.3, 7.8, dim=3)
    by_lame = material_from(rho=7.8, lam=lam, mu=mu, dim=3)
    assert by_lame.lam == lam and by_lame.mu == mu
    assert by_lame.young == pytest.approx((200.0, 0.3), rel=1e-14)
    # nothing given: the default, built as the default's pair (bit for bit)
    assert material_from(rho=1.0, default={"lam": 2.0, "mu": 1.0}) == Material(1.0, 2.0, 1.0)
    # E alone on a default given as (lam, mu) = (2, 1): nu of that default, 1/3
    m = material_from(rho=1.0, E=8.0, default={"lam": 2.0, "mu": 1.0}, plane="stress")
    assert m.young == pytest.approx((8.0, 1 / 3), rel=1e-14) and m.plane == "stress"
    # mu alone on a default (E, nu) = (100, 0): lam of that default, 0
    m = material_from(rho=1.0, mu=10.0, default={"E": 100.0, "nu": 0.0})
    assert (m.lam, m.mu) == (0.0, 10.0)


def test_material_from_refuses_mixed_pairs_naming_both():
    with pytest.raises(RotheInputError) as info:
        material_from(rho=1.0, E=210.0, mu=80.0)
    exc = info.value
    assert str(exc) == "E: got 210, must not be combined with mu: give E, nu or lam, mu"
    assert exc.parameter == "E" and "mu" in exc.mentions
    table = {"E": "--E", "nu": "--nu", "lam": "--lam", "mu": "--mu"}
    assert str(exc.renamed("--E", table)) == (
        "--E: got 210, must not be combined with --mu: give --E, --nu or --lam, --mu"
    )
    with pytest.raises(RotheInputError, match=r"^nu: got 0.2, must not be combined with lam"):
        material_from(rho=1.0, nu=0.2, lam=1.0)
    with pytest.raises(RotheInputError, match=r"^nu: got 0.5, must satisfy -1 < nu < 0.5"):
        material_from(rho=1.0, E=1.0, nu=0.5)
    with pytest.raises(RotheInputError, match=r"^E: got None, must be given with nu"):
        material_from(rho=1.0)


def test_materials_from_constants_by_name():
    mats = materials_from(
        {"steel": {"E": 200.0, "nu": 0.3, "rho": 7.8}, "rubber": {"lam": 1.0, "mu": 0.1}},
        regions={"a": "steel", "b": "rubber"},
        rho=1.1,
    )
    assert mats.materials["steel"] == Material.from_young(200.0, 0.3, 7.8, dim=2)
    assert mats.materials["rubber"] == Material(1.1, 1.0, 0.1) and mats.rho == 7.8
    cases = [
        ({"s": {"E": -1.0, "nu": 0.3}}, r"^materials: got 's' with E: got -1, must be > 0$"),
        ({"s": {"E": 1.0, "mu": 0.3}}, r"^materials: got 's' with E: got 1, must not be combined"),
        ({"s": {"G": 1.0}}, r"^materials: got 's' with 'G', must give E, nu or lam, mu, and rho$"),
        ({"s": {"rho": 1.0}}, r"^materials: got 's' with E: got None, must be given with nu"),
        ({}, r"^materials: got \{\}, must map at least one name"),
    ]
    for constants, message in cases:
        with pytest.raises(RotheInputError, match=message):
            materials_from(constants, rho=1.0)
