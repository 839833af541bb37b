"""Trajectory contents: every series per step, z of every k-th state, npz round trip."""

import numpy as np
import pytest

from rothe import Trajectory, run_ris
from rothe.ris.examples import example_7_1
from rothe.ris.stepper import stored_states


def test_keep_every_keeps_every_kth_and_the_last_state(tmp_path):
    full = run_ris(example_7_1(), "order2", tol=1e-3, tau=0.1)
    thin = run_ris(example_7_1(), "order2", tol=1e-3, tau=0.1, keep_every=7)
    K = len(full)
    assert len(thin) == K and np.array_equal(thin["s"], full["s"])
    steps = thin["z_step"]
    assert steps[0] == 0 and steps[-1] == K and np.all(steps[1:-1] % 7 == 0)
    assert np.array_equal(thin["z"], full["z"][steps])
    s, t, z = stored_states(thin)
    assert np.array_equal(s, full["s"][steps]) and z.shape == (len(steps), 1)
    assert thin.meta["linear_solver"] == "lapack"
    loaded = Trajectory.load_npz(thin.save_npz(tmp_path / "thin.npz"))
    assert np.array_equal(loaded["z_step"], steps)
    assert loaded.stats.accepted_steps == K


def test_keep_every_must_be_positive():
    with pytest.raises(ValueError, match="keep_every: got 0, must be an integer >= 1"):
        run_ris(example_7_1(), "adaptive", tol=1e-3, tau=0.1, keep_every=0)
