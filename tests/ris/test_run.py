"""The run driver: run_ris and run_nested take step-control objects and return RISResult;
trajectory contents (every series per step, z of every k-th state, npz round trip); the landing
on T; the likely cause of a stop after failed inner solves."""

import numpy as np
import pytest

from rothe import RunFailed, Trajectory, run_nested, run_ris
from rothe.errors import RotheInputError
from rothe.ris.controllers import Nested, Order2, Regime
from rothe.ris.examples import example_7_1
from rothe.ris.inner import InnerOptions, RISCode
from rothe.ris.run import RISResult, stored_states
from rothe.ris.stepper import RISState
from rothe.stepping.controllers import Adaptive, Uniform

from .conftest import readme_problem


def test_keep_every_keeps_every_kth_and_the_last_state(tmp_path):
    full = run_ris(example_7_1(), Order2(1e-3, tau=0.1)).trajectory
    thin = run_ris(example_7_1(), Order2(1e-3, tau=0.1), keep_every=7).trajectory
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
        run_ris(example_7_1(), Adaptive(1e-3, tau=0.1), keep_every=0)


def test_run_ris_returns_the_trajectory_the_final_state_and_the_statistics():
    result = run_ris(example_7_1(), Regime(1e-3, tau=0.2))
    assert isinstance(result, RISResult) and isinstance(result.state, RISState)
    traj = result.trajectory
    assert result.statistics is traj.stats and result.statistics.accepted_steps == len(traj)
    assert result.state.k == len(traj) and result.state.s == traj["s"][-1]
    assert result.state.t == traj["t"][-1] and np.array_equal(result.state.z, traj["z"][-1])
    assert result.control == Regime(1e-3, tau=0.2) and result.meshes is None
    assert traj.meta["control"] == "regime" and traj.meta["tol"] == 1e-3
    assert traj.meta["tau0"] == 0.2
    assert not hasattr(traj, "final_state") and not hasattr(traj, "controller")
    # the default: Alg. 3.2 at tol 1e-4 with first step 0.1
    default = run_ris(example_7_1())
    assert default.control == Adaptive(1e-4, tau=0.1)
    same = run_ris(example_7_1(), Adaptive(1e-4)).trajectory
    assert np.array_equal(default.trajectory["s"], same["s"])
    assert default.trajectory.meta["tau0"] == 0.1
    # uniform steps carry no tolerance
    assert run_ris(example_7_1(), Uniform(0.5)).trajectory.meta["tol"] is None


@pytest.mark.parametrize(
    "control, match",
    [
        (
            "adaptive",
            r"^control: got 'adaptive', must be a step-control object: Uniform\(tau\), "
            r"Adaptive\(tol\) \(rothe.stepping.controllers\), Order2\(tol\) or "
            r"Regime\(tol\) \(rothe.ris.controllers\)$",
        ),
        (1e-4, r"^control: got a float, must be a step-control object"),
        (
            Nested([1e-2, 1e-3]),
            r"^control: got a Nested, must be a step-control object: .*; "
            r"run_nested runs a Nested sequence of tolerances$",
        ),
    ],
)
def test_run_ris_refuses_what_is_not_the_control_of_one_run(control, match):
    with pytest.raises(RotheInputError, match=match) as info:
        run_ris(example_7_1(), control)
    assert info.value.parameter == "control"


@pytest.mark.parametrize(
    "control, match",
    [
        (
            [1e-2, 1e-3],
            r"^control: got a list, must be Nested\(tols\) \(rothe.ris.controllers\); "
            r"the control of a single run goes to run_ris$",
        ),
        (Adaptive(1e-3), r"^control: got a Adaptive, must be Nested\(tols\)"),
    ],
)
def test_run_nested_refuses_what_is_not_a_nested_control(control, match):
    with pytest.raises(RotheInputError, match=match):
        run_nested(example_7_1(), control)


def test_run_nested_returns_one_result_per_tolerance():
    results = run_nested(example_7_1(), Nested([1e-2, 1e-3], tau=0.2))
    assert [r.control for r in results] == [Adaptive(1e-2, tau=0.2), Adaptive(1e-3, tau=0.2)]
    for i, r in enumerate(results):
        traj = r.trajectory
        assert traj.meta["nested_index"] == i and traj.meta["tol"] == r.control.tol
        assert traj.meta["control"] == ("adaptive" if i == 0 else "nested")
        assert r.state.k == len(traj) and r.landing["landed"]
    assert len(results[1].trajectory) > len(results[0].trajectory)


def test_a_stop_after_failed_inner_solves_names_the_likely_cause():
    """No iteration allowed: sticking steps converge at once (d = 0 is stationary), the first
    step of the jump at t = 2 cannot; the stop below tau_min says what the code means."""
    with pytest.raises(
        RunFailed,
        match=r"^step size fell below tau_min = 0\.03 at step \d+ .*"
        r"inner solve failed \(max_iterations\)\); the inner "
        r"solver cannot reach stationarity: dF or d2F probably "
        r"does not belong to F",
    ) as info:
        run_ris(example_7_1(), Uniform(0.1, tau_min=0.03), inner=InnerOptions(max_iter=0))
    assert info.value.where["code"] == "max_iterations"
    assert info.value.where["code"] is RISCode.MAX_ITERATIONS
    assert 2.0 <= info.value.trajectory["t"][-1] <= 2.1 + 1e-12


# -- the run ends on T (it ended at t = 1.0001418 for T = 1) --------------------------------------


@pytest.mark.parametrize(
    "control",
    [
        Adaptive(1e-5, tau=0.05),  # the README's call
        Order2(1e-5, tau=0.05),
        Uniform(0.013),
    ],
)
def test_readme_example_ends_on_T(control):
    result = run_ris(readme_problem(), control)
    traj = result.trajectory
    assert result.landing == traj.meta["landing"] and result.state.t == traj["t"][-1]
    assert abs(traj["t"][-1] - 1.0) <= 1e-10
    assert traj["t"][-2] < 1.0
    landing = traj.meta["landing"]
    assert landing["landed"] and landing["ended_by"] == "T"
    assert landing["t_final_minus_T"] == traj["t"][-1] - 1.0
    if isinstance(control, Adaptive):
        # t(tau) = t_{k-1} + max(tau - d*, 0) near the end of a slip: one slope-one Newton step
        # from the overshooting attempt lands (regula falsi from tau = 0 took six and missed by
        # 1.4e-4)
        assert traj.stats.landing_retries == 1
