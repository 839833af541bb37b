"""The problem (rothe.eld.problem): on meshes from meshio (objects and files) with named parts,
and its fingerprint (what a checkpoint must match)."""

import meshio
import numpy as np
import pytest

from rothe.eld import DirichletData, ELDProblem, Material, RayleighDamping, mms_problem, run_eld
from rothe.errors import RotheInputError
from rothe.fem import mesh as meshes
from rothe.io.checkpoint import problem_fingerprint
from rothe.stepping.controllers import Uniform

POINTS = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 0.5, 0], [1, 0.5, 0]], float)
TRIANGLES = np.array([[0, 1, 5], [0, 5, 4], [4, 5, 3], [4, 3, 2]])
LINES = np.array([[0, 4], [4, 2]])  # the edge x = 0


def test_meshio_object_with_cell_sets_gives_named_parts():
    m = meshio.Mesh(
        POINTS,
        [("triangle", TRIANGLES), ("line", LINES)],
        cell_sets={"clamp": [np.array([], dtype=int), np.array([0, 1])]},
    )
    mesh = meshes.from_meshio(m)
    facets = mesh.facets[:, np.asarray(mesh.boundaries["clamp"])]
    assert np.allclose(mesh.p[0, facets], 0.0)


def test_gmsh_file_with_physical_groups_runs_an_eld_problem(tmp_path):
    m = meshio.Mesh(
        POINTS,
        [("triangle", TRIANGLES), ("line", LINES)],
        cell_data={
            "gmsh:physical": [np.full(4, 1), np.full(2, 2)],
            "gmsh:geometrical": [np.full(4, 1), np.full(2, 2)],
        },
        field_data={"domain": np.array([1, 2]), "clamp": np.array([2, 1])},
    )
    path = tmp_path / "square.msh"
    m.write(path, file_format="gmsh22", binary=False)
    mesh = meshes.load_mesh(path)
    assert list(mesh.boundaries) == ["clamp"]

    def lift(t, x):
        return np.stack([0 * x[0], 0.01 * t + 0 * x[0]])

    zero = lambda t, x: 0 * x  # noqa: E731
    problem = ELDProblem(
        mesh,
        Material(1.0, 1.0, 1.0),
        degree=2,
        dirichlet={
            "clamp": DirichletData(lift, lambda t, x: np.stack([0 * x[0], 0.01 + 0 * x[0]]), zero)
        },
        T=0.1,
    )
    traj = run_eld(problem, control=Uniform(0.05)).trajectory
    assert traj["reaction_clamp"].shape == (2, 2)
    with pytest.raises(RotheInputError, match="dirichlet: got 'left', must be one of clamp"):
        ELDProblem(mesh, Material(1.0, 1.0, 1.0), dirichlet={"left": lambda t, x: 0 * x})


def test_missing_mesh_file_is_a_one_line_error(tmp_path):
    with pytest.raises(RotheInputError, match=r"^mesh: got '.*nope.msh', no such file$"):
        meshes.load_mesh(tmp_path / "nope.msh")


def test_the_fingerprint_names_what_differs_and_is_what_checkpoints_compare():
    problem, _ = mms_problem(2, 1)
    fp = problem.fingerprint()
    assert problem_fingerprint(problem) == fp
    assert set(fp) == {
        "class",
        "ndofs",
        "T",
        "M",
        "K",
        "B",
        "initial",
        "load",
        "G",
        "damping",
        "description",
    }
    assert fp["class"] == "ELDProblem" and fp["ndofs"] == problem.space.ndofs and fp["T"] == 1.0
    assert mms_problem(2, 1)[0].fingerprint() == fp  # a pure function of the problem
    other = mms_problem(2, 1, damping=RayleighDamping(0.1, 0.01))[0].fingerprint()
    assert {k for k in fp if fp[k] != other[k]} == {"load", "damping", "description"}
    assert mms_problem(3, 1)[0].fingerprint()["M"] != fp["M"]


def test_element_cache_keeps_the_element_matrices_and_refuses_other_values():
    """ELDProblem(element_cache=True) keeps the element matrices of K (incremental rebuilds of
    space adaptivity) and builds the same K; anything but a bool or a pair is one line."""
    mesh = meshes.unit_square(3, named=True)
    zero = lambda t, x: np.zeros_like(x)  # noqa: E731
    kw = dict(degree=2, dirichlet={"left": DirichletData(zero, zero, zero)})
    material = Material(lam=1.0, mu=1.0, rho=1.0, dim=2)
    plain = ELDProblem(mesh, material, **kw)
    kept = ELDProblem(mesh, material, element_cache=True, **kw)
    assert plain.space.element_stiffness is None
    assert kept.space.element_stiffness.shape == (mesh.t.shape[1], 6, 2, 6, 2)
    assert np.array_equal(plain.K.data, kept.K.data)
    with pytest.raises(RotheInputError, match=r"^element_cache: got .*list.*must be True, False"):
        ELDProblem(mesh, material, element_cache=[1], **kw)
