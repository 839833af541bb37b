"""ELD ParaView output (rothe.eld.output), issue 21: the body and the multiplier series share
one time axis (beam_multiplier.xdmf had 40 frames from t = 0.05, beam.xdmf 41 from t = 0)."""

from __future__ import annotations

import meshio
import numpy as np

from rothe.eld import beam_problem
from rothe.eld.output import EldXdmfWriter


def _times(path):
    with meshio.xdmf.TimeSeriesReader(str(path)) as reader:
        reader.read_points_cells()
        frames = [reader.read_data(k) for k in range(reader.num_steps)]
    return [t for t, _, _ in frames], [pd for _, pd, _ in frames]


def test_body_and_multiplier_series_have_the_same_times(tmp_path):
    problem = beam_problem(1, T=0.1)
    writer = EldXdmfWriter(tmp_path / "work", problem, name="beam")
    m = problem.constraint.dofs.size
    writer.write(0.0, problem.u0, problem.v0, None)  # as the command line does before the run
    for k, t in enumerate((0.05, 0.1), start=1):
        writer.write(t, problem.u0, problem.v0, np.full(m, float(k)))
    body, bnd = writer.export(tmp_path)
    t_body, _ = _times(tmp_path / body.name)
    t_bnd, data = _times(tmp_path / bnd.name)
    assert t_body == t_bnd == [0.0, 0.05, 0.1]
    assert np.all(np.isnan(data[0]["lambda"]))  # not given at t = 0: NaN, not left out
    assert np.all(data[1]["lambda"][:, : problem.space.dim] == 1.0)
    assert np.array_equal(data[2]["reaction_density"], -data[2]["lambda"])
