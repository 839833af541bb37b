"""MeshSeries: meshes stored once, npz and checkpoint round trips, VTU/PVD output read back."""

import copy

import numpy as np
import pytest

from rothe.fem.adapt import AdaptiveMesh
from rothe.io.mesh_series import MeshSeries, read_pvd, write_vtu_series
from rothe.plotting.adapt import plot_dofs, plot_mesh_snapshots


def _adapted_meshes():
    """Three meshes of one refinement history: initial, refined near a corner, coarsened back."""
    import skfem

    amesh = AdaptiveMesh(skfem.MeshTri.init_symmetric().refined(2))
    out = [(amesh.mesh_id, amesh.points.copy(), amesh.cells.copy())]
    centers = amesh.points[amesh.cells].mean(axis=1)
    amesh.refine(np.linalg.norm(centers, axis=1) < 0.3)
    out.append((amesh.mesh_id, amesh.points.copy(), amesh.cells.copy()))
    amesh.coarsen(np.ones(len(amesh.cells), dtype=bool), rounds=3)
    out.append((amesh.mesh_id, amesh.points.copy(), amesh.cells.copy()))
    return out


def test_each_mesh_stored_once_and_npz_round_trip(tmp_path):
    meshes = _adapted_meshes()
    assert len({len(p) for _, p, _ in meshes}) >= 2  # the refinement changed the mesh
    series = MeshSeries()
    state_ids = []
    for mesh_id, p, c in meshes:
        for _ in range(3):  # three states per mesh: registered each time, stored once
            series.add(mesh_id, p, c)
            state_ids.append(mesh_id)
    assert series.ids == [m for m, _, _ in meshes]
    arrays = series.npz_arrays(state_ids)
    np.savez(tmp_path / "t.npz", **arrays)
    with np.load(tmp_path / "t.npz") as data:
        back, back_ids = MeshSeries.from_npz(data)
    assert np.array_equal(back_ids, state_ids)
    for mesh_id, p, c in meshes:
        bp, bc = back.mesh(mesh_id)
        assert np.array_equal(bp, p) and np.array_equal(bc, c)
    assert np.array_equal(series.n_vertices(state_ids), [len(series.mesh(i)[0]) for i in state_ids])


def test_checkpoint_round_trip_is_exact():
    series = MeshSeries()
    for mesh_id, p, c in _adapted_meshes():
        series.add(mesh_id, p, c)
    back = MeshSeries.restore_state(copy.deepcopy(series.checkpoint_state()))
    assert back.ids == series.ids
    for k in series.ids:
        assert all(np.array_equal(a, b) for a, b in zip(back.mesh(k), series.mesh(k), strict=True))


def test_added_arrays_are_copies():
    import skfem

    m = skfem.MeshTri.init_symmetric()
    p, c = m.p.T.copy(), m.t.T.copy()
    series = MeshSeries()
    series.add(0, p, c)
    p[:] = 7.0
    assert not np.any(series.mesh(0)[0] == 7.0)


def test_bad_input_names_the_problem():
    series = MeshSeries()
    with pytest.raises(ValueError, match="mesh_id must be >= 0"):
        series.add(-1, np.zeros((3, 2)), [[0, 1, 2]])
    with pytest.raises(ValueError, match="cells refer to vertices outside 0..2"):
        series.add(0, np.zeros((3, 2)), [[0, 1, 3]])
    series.add(0, np.zeros((3, 2)), [[0, 1, 2]])
    with pytest.raises(ValueError, match=r"meshes not in the series: \[4\]"):
        series.npz_arrays([0, 4])
    with pytest.raises(KeyError, match="mesh id 5 is not in the series"):
        series.mesh(5)
    with pytest.raises(ValueError, match="no mesh series"):
        MeshSeries.from_npz({"t": np.zeros(2)})


def test_vtu_series_reads_back_with_meshio(tmp_path):
    import meshio

    meshes = _adapted_meshes()
    series = MeshSeries()
    state_ids, times, data = [], [], []
    for i, (mesh_id, p, c) in enumerate(meshes):
        series.add(mesh_id, p, c)
        state_ids.append(mesh_id)
        times.append(0.5 * i)
        data.append({"z": p[:, 0] + 2 * p[:, 1], "u": p.copy()})
    pvd = write_vtu_series(tmp_path, "solution", series, state_ids, times, data)
    t_back, files = read_pvd(pvd)
    assert np.array_equal(t_back, times)
    for (_, p, c), f in zip(meshes, files, strict=True):
        m = meshio.read(f)
        assert np.array_equal(m.points[:, :2], p) and np.all(m.points[:, 2] == 0)
        assert np.array_equal(m.cells_dict["triangle"], c)
        assert np.allclose(m.point_data["z"], p[:, 0] + 2 * p[:, 1])
        assert m.point_data["u"].shape == (len(p), 3)  # 2D vectors padded for ParaView
    with pytest.raises(ValueError, match="field 'z' has 3 values"):
        write_vtu_series(tmp_path, "bad", series, [0], [0.0], [{"z": np.zeros(3)}])
    with pytest.raises(ValueError, match="one entry per state"):
        write_vtu_series(tmp_path, "bad", series, [0, 0], [0.0], [{}])


def test_figures_are_written(tmp_path):
    import skfem

    meshes = _adapted_meshes()
    series = MeshSeries()
    for mesh_id, p, c in meshes:
        series.add(mesh_id, p, c)
    ids = [m for m, _, _ in meshes]
    plot_dofs(tmp_path / "dofs.png", [0, 1, 2], series.n_vertices(ids), s=[0, 1.5, 3])
    values = [series.mesh(i)[0][:, 0] for i in ids]
    plot_mesh_snapshots(tmp_path / "snap.png", series, ids, [0, 1, 2], values, [0, 1, 2])
    tet = skfem.MeshTet.init_tensor(*(np.linspace(0, 1, 3),) * 3)
    s3 = MeshSeries()
    s3.add(0, tet.p.T, tet.t.T)
    plot_mesh_snapshots(tmp_path / "snap3.png", s3, [0], [0.0], [tet.p[2]], [0])
    assert all((tmp_path / f).stat().st_size > 1000 for f in ("dofs.png", "snap.png", "snap3.png"))
