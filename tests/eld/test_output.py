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


# -- issue 21: the body and the multiplier series share one time axis ------------------------------
# (beam_multiplier.xdmf had 40 frames from t = 0.05 while beam.xdmf had 41 from t = 0; then a NaN
# frame at t = 0; now the frame at t = 0 holds the consistent multiplier lambda(0))


def _frames(path):
    with meshio.xdmf.TimeSeriesReader(str(path)) as reader:
        reader.read_points_cells()
        frames = [reader.read_data(k) for k in range(reader.num_steps)]
    return [t for t, _, _ in frames], [pd for _, pd, _ in frames]


def test_the_multiplier_series_starts_at_t0_with_the_consistent_lambda(tmp_path):
    from rothe.eld import beam_problem
    from rothe.eld.output import EldXdmfWriter

    problem = beam_problem(1, T=0.1)
    writer = EldXdmfWriter(tmp_path / "work", problem, name="beam")
    seen = []

    def observer(state, result):  # as the command line's eld-beam writer
        seen.append(None if result is None else result.tau)
        writer.write(state.t, state.u, state.v, state.lam)

    result = run_eld(problem, control=Uniform(0.05), observer=observer)
    assert seen == [None, 0.05, 0.05]  # the initial state first, then each accepted step
    body, bnd = writer.export(tmp_path)
    t_body, _ = _frames(tmp_path / body.name)
    t_bnd, data = _frames(tmp_path / bnd.name)
    assert t_body == t_bnd == [0.0, 0.05, 0.1]
    dim = problem.space.dim
    lam = result.trajectory["lam"]  # the kept multipliers, lambda(0) first
    for k in range(3):
        want = np.asarray(lam[k]).reshape(-1, dim)[writer._lam_rows]
        assert np.all(np.isfinite(data[k]["lambda"]))
        assert np.array_equal(data[k]["lambda"][:, :dim], want), k
        assert np.array_equal(data[k]["reaction_density"], -data[k]["lambda"])
    # lambda(0) = the Gamma_D rows of (2.7a) at t = 0: the end starts to move (G_ddot(0) != 0)
    assert np.abs(data[0]["lambda"]).max() > 0


def test_a_frame_without_a_multiplier_is_refused(tmp_path):
    from rothe.eld import beam_problem
    from rothe.eld.output import EldXdmfWriter

    problem = beam_problem(1, T=0.1)
    writer = EldXdmfWriter(tmp_path / "work", problem, name="beam")
    with pytest.raises(ValueError, match=r"^lam: got None, must be the multiplier at t = 0$"):
        writer.write(0.0, problem.u0, problem.v0, None)
    assert writer.steps_written == 0
