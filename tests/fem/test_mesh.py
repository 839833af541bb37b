"""Meshes: builders, symmetry of the union-jack grid, file import (gmsh 2.2/4.1, vtu), bad files."""

from __future__ import annotations

import meshio
import numpy as np
import pytest
from skfem import MeshTri

from rothe.errors import RotheInputError
from rothe.fem.mesh import (
    box,
    cell_volumes,
    check_mesh,
    load_mesh,
    part_frame,
    tag_box_faces,
    unit_cube,
    unit_square,
)
from rothe.fem.scalar import boundary_nodes


def _left_rest(mid):
    return np.where(np.isclose(mid[0], 0.0), "left", "rest")


def _permutation(p, fmap, n):
    """Node permutation P with p[:, P] = fmap(p) on an n x n grid of the unit square."""
    key = lambda q: np.round(q[0] * n).astype(int) * (n + 1) + np.round(q[1] * n).astype(int)  # noqa: E731
    k0, k1 = key(p), key(fmap(p))
    order = np.argsort(k0)
    return order[np.searchsorted(k0[order], k1)]


def test_unit_square_and_cube_sizes():
    m = unit_square(40)
    assert m.p.shape == (2, 1681) and m.t.shape == (3, 3200)
    assert np.isclose(cell_volumes(m).sum(), 1.0)
    c = unit_cube(3)
    assert c.p.shape == (3, 64) and c.t.shape == (4, 162)
    assert np.isclose(cell_volumes(c).sum(), 1.0)
    # the sides of the box by scikit-fem's default names, computed on demand
    sides = {
        name: boundary_nodes(c, name)
        for name in ("left", "right", "bottom", "top", "front", "back")
    }
    assert all(v.size == 16 for v in sides.values())
    assert np.allclose(c.p[2, sides["back"]], 1.0) and np.allclose(c.p[1, sides["bottom"]], 0.0)


@pytest.mark.parametrize("n", [0, -3])
def test_grid_needs_n_at_least_1(n):
    with pytest.raises(RotheInputError, match=rf"^n: got {n}, must be an integer >= 1$"):
        unit_square(n)
    with pytest.raises(RotheInputError, match=r"^n: got .*, must be an integer >= 1$"):
        unit_cube(n)
    assert unit_square(1).t.shape == (3, 2) and unit_cube(1).t.shape == (4, 6)


def test_unknown_pattern():
    with pytest.raises(RotheInputError, match="pattern: got 'zigzag', must be one of"):
        unit_square(4, "zigzag")


@pytest.mark.parametrize("n", [2, 4, 6])
def test_unionjack_is_invariant_under_all_reflections(n):
    m = unit_square(n, "unionjack")
    cells = {tuple(c) for c in np.sort(m.t, axis=0).T}
    for fmap in (
        lambda q: np.array([1 - q[0], q[1]]),
        lambda q: np.array([q[0], 1 - q[1]]),
        lambda q: np.array([q[1], q[0]]),
        lambda q: np.array([1 - q[1], 1 - q[0]]),
    ):
        P = _permutation(m.p, fmap, n)
        assert np.allclose(m.p[:, P], fmap(m.p))
        assert {tuple(c) for c in np.sort(P[m.t], axis=0).T} == cells


def test_tensor_grid_symmetric_under_diagonal_only():
    n = 4
    m = unit_square(n)
    cells = {tuple(c) for c in np.sort(m.t, axis=0).T}
    swap = _permutation(m.p, lambda q: np.array([q[1], q[0]]), n)
    flip = _permutation(m.p, lambda q: np.array([1 - q[0], q[1]]), n)
    assert {tuple(c) for c in np.sort(swap[m.t], axis=0).T} == cells
    assert {tuple(c) for c in np.sort(flip[m.t], axis=0).T} != cells


@pytest.mark.parametrize("writer", ["write_msh41", "write_msh22"])
def test_gmsh_2d_with_physical_groups(tmp_path, gmsh_text, writer):
    ref = unit_square(4)
    path = getattr(gmsh_text, writer)(tmp_path / "square.msh", ref, _left_rest)
    m = load_mesh(path)
    assert m.p.shape == ref.p.shape and m.t.shape == ref.t.shape
    assert set(m.boundaries) == {"left", "rest"}
    left = boundary_nodes(m, ["left"])
    assert np.allclose(m.p[0, left], 0.0) and left.size == 5
    both = boundary_nodes(m, ["left", "rest"])
    assert np.array_equal(both, boundary_nodes(m))


@pytest.mark.parametrize("writer", ["write_msh41", "write_msh22"])
def test_gmsh_3d_with_physical_groups(tmp_path, gmsh_text, writer):
    ref = unit_cube(3)
    path = getattr(gmsh_text, writer)(
        tmp_path / "cube.msh", ref, lambda mid: np.where(np.isclose(mid[2], 0), "floor", "walls")
    )
    m = load_mesh(path)
    assert m.p.shape == (3, 64) and m.t.shape == (4, 162)
    floor = boundary_nodes(m, "floor")
    assert floor.size == 16 and np.allclose(m.p[2, floor], 0.0)


def test_file_with_only_lines(tmp_path):
    path = tmp_path / "lines.vtu"
    meshio.write(path, meshio.Mesh(np.array([[0.0, 0, 0], [1, 0, 0]]), [("line", [[0, 1]])]))
    with pytest.raises(RotheInputError, match=r"has no triangle cells \(found: line\)"):
        load_mesh(path, dim=2)


@pytest.mark.parametrize("suffix", [".vtu", ".xdmf"])
def test_vtu_xdmf_2d_points_with_z_column_and_unused_nodes(tmp_path, monkeypatch, suffix):
    monkeypatch.chdir(tmp_path)  # meshio's XDMF writer puts its .h5 into the cwd
    ref = unit_square(3)
    pts = np.c_[ref.p.T, np.zeros(ref.p.shape[1])]
    pts = np.vstack([pts, [[5.0, 5.0, 0.0]]])  # a node no cell uses (a gmsh geometry point)
    path = tmp_path / f"square{suffix}"
    meshio.write(path, meshio.Mesh(pts, [("triangle", ref.t.T)]))
    m = load_mesh(path)
    assert m.p.shape == (2, 16)
    assert np.isclose(cell_volumes(m).sum(), 1.0)


def test_missing_unreadable_and_wrong_meshes(tmp_path):
    with pytest.raises(RotheInputError, match=r"^mesh: got '.*nope.msh', no such file$"):
        load_mesh(tmp_path / "nope.msh")
    bad = tmp_path / "bad.msh"
    bad.write_text("this is not a mesh\n")
    with pytest.raises(
        RotheInputError, match=r"^mesh: got '.*bad.msh', is not a mesh meshio can read"
    ):
        load_mesh(bad)
    unknown = tmp_path / "mesh.xyz123"
    unknown.write_text("1 2 3\n")
    with pytest.raises(RotheInputError, match="is not a mesh meshio can read"):
        load_mesh(unknown)
    with pytest.raises(RotheInputError, match="is a directory"):
        load_mesh(tmp_path)
    # a curved surface mesh is not a planar 2D mesh
    surf = tmp_path / "surface.vtu"
    meshio.write(
        surf,
        meshio.Mesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 1]]), [("triangle", [[0, 1, 2]])]),
    )
    with pytest.raises(RotheInputError, match="not flat in 2D"):
        load_mesh(surf)
    # a tetrahedral file asked for as 2D without triangles
    tet = tmp_path / "tet.vtu"
    c = unit_cube(2)
    meshio.write(tet, meshio.Mesh(c.p.T, [("tetra", c.t.T)]))
    with pytest.raises(RotheInputError, match=r"has no triangle cells \(found: tetra\)"):
        load_mesh(tet, dim=2)
    assert load_mesh(tet).p.shape == (3, 27)


def test_degenerate_cell_is_rejected(tmp_path):
    path = tmp_path / "flat.vtu"
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]])
    meshio.write(path, meshio.Mesh(pts, [("triangle", [[0, 1, 2], [0, 1, 3]])]))
    with pytest.raises(RotheInputError, match=r"degenerate cell \(index 1, volume 0\)"):
        load_mesh(path)


def test_check_mesh_rejects_bad_indices():
    from skfem import MeshTri

    m = MeshTri(np.array([[0.0, 1, 0], [0, 0, 1]]), np.array([[0], [1], [2]]))
    check_mesh(m)
    m.t[2, 0] = 7
    with pytest.raises(RotheInputError, match=r"cell node index 7"):
        check_mesh(m)


@pytest.mark.parametrize(
    "value, message",
    [
        (np.nan, "has a non-finite node coordinate (nan), coordinates must be finite"),
        (np.inf, "has a non-finite node coordinate (inf), coordinates must be finite"),
        (
            1e200,
            "has node coordinates up to 1e+200 in magnitude, must be at most 1e+100 (squared "
            "lengths and volumes would overflow; rescale the mesh)",
        ),
    ],
)
def test_non_finite_or_huge_coordinates_are_refused_before_the_kd_tree(tmp_path, value, message):
    """A NaN, an inf or coordinates x1e200 made scipy's cKDTree raise inside coincident_nodes
    (a traceback, issue 21); now one line naming the file."""
    ref = unit_square(3)
    pts = np.c_[ref.p.T, np.zeros(ref.p.shape[1])]
    if value == 1e200:
        pts = pts * value
    else:
        pts[4, 0] = value
    path = tmp_path / "m.vtu"
    meshio.write(path, meshio.Mesh(pts, [("triangle", ref.t.T)]))
    with pytest.raises(RotheInputError) as info:
        load_mesh(path)
    assert str(info.value) == f"mesh: got '{path}', {message}"
    assert info.value.parameter == "mesh"


def test_coincident_nodes_of_large_finite_coordinates():
    """The k-d tree works on coordinates scaled to the unit box: 1e200 finds the same pairs."""
    from rothe.fem.mesh import coincident_nodes

    p = np.array([[0.0, 1.0, 1.0, 0.5], [0.0, 0.0, 1.0, 0.5]])
    p = np.c_[p, p[:, 1]]  # node 4 repeats node 1
    for scale in (1.0, 1e200, 1e-200):
        assert coincident_nodes(p * scale).tolist() == [[1, 4]]


def test_part_frame_is_the_exact_midpoint_and_inward_normal_of_a_straight_side():
    rect = tag_box_faces(MeshTri.init_tensor(np.linspace(0, 2, 9), np.linspace(0, 1, 5)))
    c, n = part_frame(rect, "left")
    assert c.tolist() == [0.0, 0.5] and n.tolist() == [1.0, 0.0]  # to the bit
    c, n = part_frame(rect, "top")
    assert c.tolist() == [1.0, 1.0] and n.tolist() == [0.0, -1.0]
    c, n = part_frame(box(2, 2, 2, 3.0, 1.0, 1.0), "right")
    assert np.allclose(c, [3.0, 0.5, 0.5]) and np.allclose(n, [-1.0, 0.0, 0.0])
    with pytest.raises(RotheInputError, match=r"^dirichlet: got 'inlet', must be one of bottom"):
        part_frame(rect, "inlet", "dirichlet")
    # the whole boundary of the square: its normals cancel
    whole = rect.with_boundaries({"all": rect.boundary_facets()})
    with pytest.raises(RotheInputError, match=r"^part: got 'all', has no mean normal"):
        part_frame(whole, "all")
