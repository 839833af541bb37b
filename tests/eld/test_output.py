"""The outputs of a run (rothe.eld.output): trajectory.npz with the mesh, XDMF with stresses,
figures."""

import json

import meshio
import numpy as np
import pytest

from rothe.eld import BDF2, StressEvaluator, mms_problem, run_eld, von_mises, write_eld_result
from rothe.stepping.controllers import Uniform


def test_write_eld_result_for_a_users_run(tmp_path):
    problem, _ = mms_problem(2, 2)
    result = run_eld(problem, control=Uniform(0.1), scheme=BDF2(), keep_every=3)
    traj = result.trajectory
    paths = write_eld_result(result, tmp_path, name="mine")
    data = np.load(paths["npz"])
    kept = data["kept_step"]
    assert list(kept) == [0, 3, 6, 9, 10]  # every 3rd, t = 0 and the last
    assert data["u"].shape == (5, problem.space.ndofs)
    assert data["lam"].shape == (5, problem.constraint.m)
    assert np.array_equal(data["lam_dofs"], problem.constraint.dofs)
    assert data["nodes"].shape == (problem.space.mesh.p.shape[1], 2)
    meta = json.loads(str(data["meta"]))
    assert meta["scheme"] == "bdf2" and meta["keep_every"] == 3
    ev = StressEvaluator(problem.space, problem.material)
    with meshio.xdmf.TimeSeriesReader(str(tmp_path / "mine.xdmf")) as reader:
        reader.read_points_cells()
        assert reader.num_steps == 5
        t, point_data, cell_data = reader.read_data(4)
    assert t == pytest.approx(1.0)
    assert np.allclose(cell_data["stress"][0], ev.stress(traj["u"][-1]).reshape(-1, 9))
    assert np.allclose(cell_data["von_mises"][0], von_mises(ev.stress(traj["u"][-1])))
    assert point_data["stress_nodal"].shape == (problem.space.mesh.p.shape[1], 9)
    for name in ("fig_energy.png", "fig_reaction.png", "mine_multiplier.xdmf"):
        assert (tmp_path / name).is_file()
    # without stored fields there is nothing to write to XDMF: one line
    bare = run_eld(problem, control=Uniform(0.5), store_fields=False)
    with pytest.raises(ValueError, match=r"^result: got a run without stored fields, must come"):
        write_eld_result(bare, tmp_path / "bare", figures=False)
