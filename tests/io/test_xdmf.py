"""XDMF + HDF5 time series: readable by meshio, HDF5 next to the XML, round trip exact."""

from __future__ import annotations

import os

import numpy as np
import pytest

from rothe.fem.mesh import unit_cube, unit_square
from rothe.io.xdmf import XdmfSeriesWriter, read_series, write_series


@pytest.mark.parametrize("mesh", [unit_square(3), unit_cube(2)], ids=["tri", "tet"])
def test_round_trip(tmp_path, mesh, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the .h5 must land beside the .xdmf, not in the cwd
    rng = np.random.default_rng(0)
    Z = rng.standard_normal((5, mesh.p.shape[1]))
    s = np.array([0.0, 0.1, 0.25, 0.5, 1.0])
    path = write_series(
        tmp_path / "out" / "sol.xdmf", mesh.p.T, mesh.t.T, s, {"z": Z}, {"t": s / 2}
    )
    assert sorted(os.listdir(tmp_path / "out")) == ["sol.h5", "sol.xdmf"]
    assert not (tmp_path / "sol.h5").exists()
    points, cells, times, data = read_series(path)
    assert np.array_equal(points, mesh.p.T) and np.array_equal(cells, mesh.t.T)
    assert np.array_equal(times, s) and np.array_equal(data["z"], Z)
    text = path.read_text()
    assert text.count('<Information Name="t"') == 5
    assert ("Triangle" if mesh.p.shape[0] == 2 else "Tetrahedron") in text


def test_streaming_writer_is_atomic_and_checks_shapes(tmp_path):
    m = unit_square(2)
    with XdmfSeriesWriter(tmp_path / "a.xdmf", m.p.T, m.t.T) as w:
        w.write_step(0.0, {"z": np.zeros(9)})
        w.write_step(0.5, {"z": np.ones(9), "u": np.ones((9, 2))})
        # nothing visible under the final names before close (a kill now leaves no pair)
        assert not (tmp_path / "a.xdmf").exists() and not (tmp_path / "a.h5").exists()
        with pytest.raises(ValueError, match=r"z: got shape \(4,\), must be \(9,\)"):
            w.write_step(1.0, {"z": np.ones(4)})
    _, _, times, data = read_series(tmp_path / "a.xdmf")
    assert times.tolist() == [0.0, 0.5] and data["u"].shape == (1, 9, 3)
    assert sorted(os.listdir(tmp_path)) == ["a.h5", "a.xdmf"]  # no temporary left
    # an error while writing leaves the earlier pair untouched and no temporary file
    before = (tmp_path / "a.h5").read_bytes()
    with pytest.raises(RuntimeError), XdmfSeriesWriter(tmp_path / "a.xdmf", m.p.T, m.t.T) as w:
        w.write_step(0.0, {"z": np.full(9, 7.0)})
        raise RuntimeError("the run failed")
    assert (tmp_path / "a.h5").read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["a.h5", "a.xdmf"]
    with pytest.raises(ValueError, match="cells: got shape"):
        XdmfSeriesWriter(tmp_path / "b.xdmf", m.p.T, np.zeros((3, 5), int))
