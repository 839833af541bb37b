"""Adaptive meshes by bisection: conformity, parts, coarsening back, history, checkpoint."""

from __future__ import annotations

import copy

import meshio
import numpy as np
import pytest
from scipy.spatial import Delaunay
from skfem import Basis, ElementTetP2, ElementTriP2, MeshHex, MeshQuad, MeshTet, MeshTri

from rothe.errors import RotheInputError
from rothe.fem import mesh as meshes
from rothe.fem.adapt import AdaptiveMesh, check_adaptable
from rothe.fem.mesh import load_mesh, unit_cube, unit_square
from rothe.fem.topology import (
    barycentric,
    barycentric_gradients,
    facet_structures,
    lagrange_dofs,
)


def delaunay_mesh(dim: int, n: int, seed: int):
    """An irregular mesh of the unit square/cube: Delaunay of random points and the corners."""
    rng = np.random.default_rng(seed)
    pts = np.vstack(
        [rng.random((n, dim)), np.array(np.meshgrid(*[[0.0, 1.0]] * dim)).reshape(dim, -1).T]
    )
    t = Delaunay(pts).simplices.T
    cls = MeshTri if dim == 2 else MeshTet
    _, vol = barycentric_gradients(pts.T, t)
    return cls(pts.T.copy(), t[:, vol > 1e-6].copy())


def centroids(am):
    return am.points[am.cells].mean(axis=1)


def refine_near(am, x, radius):
    return am.refine(np.linalg.norm(centroids(am) - x, axis=1) < radius)


def check_parts_on_sides(am):
    """Every facet of a named side lies on that side; the parts cover the whole boundary."""
    m = am.mesh
    sides = {
        "left": (0, 0.0),
        "right": (0, 1.0),
        "bottom": (1, 0.0),
        "top": (1, 1.0),
        "front": (2, 0.0),
        "back": (2, 1.0),
    }
    covered = np.zeros(m.facets.shape[1], dtype=bool)
    for part, idx in m.boundaries.items():
        axis, level = sides[part]
        assert np.allclose(m.p[axis, m.facets[:, idx]], level)
        covered[idx] = True
    assert np.array_equal(np.flatnonzero(covered), np.sort(m.boundary_facets()))


MESHES = {
    "square": lambda: meshes.unit_square(3, named=True),
    "box": lambda: meshes.box(2, 2, 2),
    "delaunay2": lambda: delaunay_mesh(2, 40, 0),
    "delaunay3": lambda: delaunay_mesh(3, 40, 1),
}


@pytest.mark.parametrize("name", sorted(MESHES))
def test_refinement_is_conforming_nested_and_counts_dofs(name):
    m0 = MESHES[name]()
    am = AdaptiveMesh(m0)
    vol0 = barycentric_gradients(m0.p, m0.t)[1].sum()
    rng = np.random.default_rng(7)
    for _ in range(5):
        before = am.n_cells
        change = am.refine(rng.random(am.n_cells) < 0.3)
        assert am.n_cells > before and change.changed
        assert am.is_conforming()
        m = am.mesh
        assert np.isclose(barycentric_gradients(m.p, m.t)[1].sum(), vol0, rtol=1e-12)
        n_edges = (m.facets if am.dim == 2 else m.edges).shape[1]
        assert am.ndofs(1) == m.p.shape[1]
        assert am.ndofs(2, components=am.dim) == am.dim * (m.p.shape[1] + n_edges)
        # every new cell lies in the old cell it came from
        assert np.all(change.old_count == 1)
        lam = barycentric(
            m.p[:, m.t].mean(axis=1), change.old_points.T, change.old_cells.T, change.old_start
        )
        assert lam.min() > 0
    if name in ("square", "box"):
        check_parts_on_sides(am)


def test_scikit_fem_structures_match():
    """Facets, t2f injected into the mesh and the P2 dof numbering equal scikit-fem's own."""
    for m0, element in (
        (meshes.unit_square(2, named=True), ElementTriP2),
        (meshes.box(1, 1, 1), ElementTetP2),
    ):
        am = AdaptiveMesh(m0)
        am.refine(np.arange(0, am.n_cells, 2))
        m = am.mesh
        fresh = type(m)(m.p, m.t)
        assert np.array_equal(fresh.facets, m.facets)
        assert np.array_equal(fresh.t2f, m.t2f)
        f, t2f = facet_structures(m.t, m.p.shape[1])
        assert np.array_equal(f, fresh.facets) and np.array_equal(t2f, fresh.t2f)
        basis = Basis(fresh, element())
        edofs, n = lagrange_dofs(m.t, m.p.shape[1], 2)
        assert n == basis.N and np.array_equal(edofs, basis.element_dofs)
        # the numbering handed to the mesh by a P2 transfer is scikit-fem's
        change = am.refine(np.arange(0, am.n_cells, 3))
        m = am.mesh
        change.transfer(2)
        assert np.array_equal(
            Basis(m, element()).element_dofs, Basis(type(m)(m.p, m.t), element()).element_dofs
        )


@pytest.mark.parametrize("name", ["square", "box", "delaunay2", "delaunay3"])
def test_coarsening_returns_exactly_to_the_initial_mesh(name):
    m0 = MESHES[name]()
    am = AdaptiveMesh(m0)
    rng = np.random.default_rng(3)
    for _ in range(6):
        refine_near(am, rng.random(am.dim), 0.3)
    assert am.levels.max() >= 4
    calls = 0
    while True:
        change = am.coarsen(np.ones(am.n_cells, dtype=bool))
        assert am.is_conforming()
        calls += 1
        if not change.changed:
            break
        assert change.merges > 0 and np.all(change.old_count >= 1)
    assert calls <= 80
    assert np.array_equal(am.cells, m0.t.T) and np.array_equal(am.points, m0.p.T)
    assert am.mesh_id == 6 + calls - 1
    if name in ("square", "box"):
        assert {k: np.sort(v).tolist() for k, v in am.mesh.boundaries.items()} == {
            k: np.sort(v).tolist() for k, v in m0.boundaries.items()
        }


def test_cycle_of_refinement_edges_is_refined_and_coarsened():
    """An irregular tetrahedral mesh whose longest-edge labelling has a cycle of refinement
    edges around a vertex: the closure breaks it (AMP's rule) and coarsening still returns."""
    m0 = delaunay_mesh(3, 60, 1)
    am = AdaptiveMesh(m0)
    rng = np.random.default_rng(1)
    rng.random((60, 3))  # the state used to draw the points above
    for _ in range(12):
        refine_near(am, rng.random(3), 0.25)
        assert am.is_conforming()
    assert am._stats["cycle_breaks"] >= 1
    while am.coarsen(np.ones(am.n_cells, dtype=bool)).changed:
        pass
    assert np.array_equal(am.cells, m0.t.T)


def test_a_front_that_passes_leaves_the_initial_mesh():
    """Refine at a point moving across the square, coarsen everything else every step."""
    m0 = meshes.unit_square(4, named=True)
    am = AdaptiveMesh(m0)
    sizes = []
    for x in np.linspace(-0.2, 1.2, 29):
        near = np.linalg.norm(centroids(am) - [x, 0.5], axis=1) < 0.15
        am.adapt(refine=near & (am.levels < 6), coarsen=~near)
        assert am.is_conforming()
        sizes.append(am.n_cells)
    assert max(sizes) > 4 * m0.t.shape[1]
    for _ in range(8):
        am.coarsen(np.ones(am.n_cells, dtype=bool))
    assert np.array_equal(am.cells, m0.t.T)


def test_three_bisections_of_a_kuhn_tetrahedron_give_eight_similar_children():
    """3D rule = Maubach's bisection on Kuhn simplices (tags 3, 2, 1): after three generations
    all eight children are similar to the parent with ratio 1/2."""
    p = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [1, 1, 1]], dtype=float)
    am = AdaptiveMesh(MeshTet(p.T.copy(), np.array([[0, 1, 2, 3]]).T))

    def lengths(P):
        return np.sort([np.linalg.norm(P[a] - P[b]) for a in range(4) for b in range(a + 1, 4)])

    am.uniform(3)
    assert am.n_cells == 8
    for cell in am.cells:
        assert np.allclose(lengths(am.points[cell]), lengths(p) / 2)


def test_shape_regularity_of_repeated_local_refinement():
    for dim in (2, 3):
        m0 = delaunay_mesh(dim, 25, 11)
        am = AdaptiveMesh(m0)
        q0 = am.shape_quality().min()
        for _ in range(10 if dim == 2 else 7):
            refine_near(am, np.full(dim, 0.37), 0.2)
        assert am.levels.max() >= 7
        assert am.shape_quality().min() > 0.15 * q0


def test_checkpoint_round_trip_is_bit_identical():
    for m0 in (meshes.unit_square(3, named=True), delaunay_mesh(3, 20, 2)):
        am = AdaptiveMesh(m0)
        rng = np.random.default_rng(5)
        for _ in range(3):
            am.adapt(refine=rng.random(am.n_cells) < 0.3, coarsen=rng.random(am.n_cells) < 0.3)
        data = copy.deepcopy(am.checkpoint_state())
        twin = AdaptiveMesh.restore_state(data)
        for a, b in ((am, twin),):
            assert np.array_equal(a.cells, b.cells) and np.array_equal(a.points, b.points)
            assert a.mesh_id == b.mesh_id and np.array_equal(a.levels, b.levels)
        for _ in range(3):
            r, c = rng.random(am.n_cells) < 0.3, rng.random(am.n_cells) < 0.3
            ca, cb = am.adapt(refine=r, coarsen=c), twin.adapt(refine=r, coarsen=c)
            assert np.array_equal(am.cells, twin.cells)
            assert np.array_equal(am.points, twin.points)
            assert np.array_equal(ca.old_start, cb.old_start)
            assert (ca.transfer(2) != cb.transfer(2)).nnz == 0
        if am.mesh.boundaries:
            for k, v in am.mesh.boundaries.items():
                assert np.array_equal(v, twin.mesh.boundaries[k])


def test_max_dofs_cap_refines_the_largest_indicators_first():
    m0 = meshes.unit_square(4, named=True)
    am = AdaptiveMesh(m0)
    c = centroids(am)
    eta = np.exp(-10 * np.linalg.norm(c - [0.2, 0.3], axis=1))
    dofs0 = am.ndofs(2, 2)
    cap = dofs0 + 60
    change = am.adapt(
        refine=np.ones(am.n_cells, dtype=bool), max_dofs=cap, degree=2, components=2, priority=eta
    )
    assert dofs0 < am.ndofs(2, 2) <= cap
    # the cell with the largest indicator was refined, the one with the smallest was not
    refined_old = np.unique(change.old_start[am.levels > 0])
    assert np.argmax(eta) in refined_old and np.argmin(eta) not in refined_old
    # a cap that is already reached refines nothing
    same = am.adapt(
        refine=np.ones(am.n_cells, dtype=bool), max_dofs=am.ndofs(2, 2), degree=2, components=2
    )
    assert not same.changed


def test_max_level_and_subdomains():
    m0 = meshes.unit_square(2, named=True)
    left_cells = np.flatnonzero(m0.p[0, m0.t].mean(axis=0) < 0.5)
    from dataclasses import replace

    m0 = replace(m0, _subdomains={"west": left_cells})
    am = AdaptiveMesh(m0)
    for _ in range(5):
        am.adapt(refine=np.ones(am.n_cells, dtype=bool), max_level=3)
    assert am.levels.max() == 3 and am.levels.min() == 3
    m = am.mesh
    west = m.subdomains["west"]
    cx = m.p[0, m.t].mean(axis=0)
    assert np.all(cx[west] < 0.5) and np.all(np.delete(cx, west) > 0.5)


@pytest.mark.parametrize("dim", [2, 3])
def test_gmsh_mesh_keeps_its_named_parts(tmp_path, gmsh_text, dim):
    base = delaunay_mesh(dim, 30 if dim == 2 else 20, 4)

    def classify(mid):
        return np.where(np.isclose(mid[0], 0.0), "inlet", "wall")

    path = tmp_path / "domain.msh"
    gmsh_text.write_msh41(path, base, classify)
    m0 = load_mesh(path)
    am = AdaptiveMesh(m0)
    for _ in range(4):
        refine_near(am, np.array([0.0] + [0.5] * (dim - 1)), 0.3)
    assert am.is_conforming()
    m = am.mesh
    inlet = m.facets[:, m.boundaries["inlet"]]
    assert np.allclose(m.p[0, inlet], 0.0)
    # the inlet facets tile the face x = 0 (length 1 / area 1)
    P = m.p[:, inlet]  # (d, d, nf)
    if dim == 2:
        size = np.linalg.norm(P[:, 1] - P[:, 0], axis=0)
    else:
        size = 0.5 * np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0], axis=0), axis=0)
    assert np.isclose(size.sum(), 1.0)
    assert len(m.boundaries["inlet"]) > len(m0.boundaries["inlet"])
    bnd = np.sort(np.concatenate([m.boundaries["inlet"], m.boundaries["wall"]]))
    assert np.array_equal(bnd, np.sort(m.boundary_facets()))


def test_adaptation_refuses_meshes_it_cannot_bisect():
    with pytest.raises(RotheInputError, match=r"^mesh: got a mesh of quadrilaterals"):
        AdaptiveMesh(MeshQuad())
    with pytest.raises(RotheInputError, match=r"^mesh: got a mesh of hexahedra"):
        check_adaptable(MeshHex())
    mixed = meshio.Mesh(
        np.array([[0, 0], [1, 0], [1, 1], [0, 1], [2, 0], [2, 1.0]]),
        [("triangle", np.array([[0, 1, 2], [0, 2, 3]])), ("quad", np.array([[1, 4, 5, 2]]))],
    )
    with pytest.raises(RotheInputError, match=r"^mesh: got a mixed mesh \(triangle, quad\)"):
        check_adaptable(mixed)
    assert check_adaptable(unit_cube(2)) is not None
    am = AdaptiveMesh(unit_square(2))
    with pytest.raises(RotheInputError, match=r"refine: got a boolean mask of shape \(3,\)"):
        am.refine(np.ones(3, dtype=bool))
    with pytest.raises(RotheInputError, match=r"coarsen: got cell index 99, must be in \[0, 7\]"):
        am.coarsen([99])


def test_nothing_marked_changes_nothing():
    am = AdaptiveMesh(meshes.box(1, 1, 1))
    mesh = am.mesh
    change = am.adapt(refine=np.zeros(am.n_cells, dtype=bool), coarsen=[])
    assert not change.changed and am.mesh_id == 0 and am.mesh is mesh
    T = change.transfer(2, 3)
    assert (T != np.eye(T.shape[0])).sum() == 0
