"""One step of Alg. 3.2 (RISStepper): stagnation is detected and named, data that turns bad
midway, the result codes of an attempt, the adapt step that never changes the accepted
state in place, and a stop signal between the inner solver's iterations that abandons the step
(issue 21: begin_attempt / abandon, the resumed run bit for bit)."""

from __future__ import annotations

import copy
import signal

import numpy as np
import pytest

from rothe import RunFailed, run_ris
from rothe.errors import RunInterrupted
from rothe.fem.adapt import SpaceAdaptivity
from rothe.fem.mesh import unit_square
from rothe.io.checkpoint import CheckpointOptions, load_checkpoint
from rothe.ris import examples
from rothe.ris.examples import d2g_7_2, dg_7_2, example_front, g_7_2
from rothe.ris.fem_problem import FERISProblem
from rothe.ris.inner import BallStepSolver, RISCode
from rothe.ris.stepper import RISState, RISStepper, StagnationMonitor
from rothe.stepping.controllers import Adaptive, Uniform

from ..conftest import assert_same_trajectory
from .conftest import DIRECT, readme_problem, ris_1d_problem

# -- a wrong dF: stagnation is detected and named (spun to the 10^6-attempt cap before) ----------


def wrong_for_positive_z(z):
    """dF of Example 7.1, doubled where z > 0: the derivative check's test points near z0 = -2
    do not see it."""
    g = examples.dp(z)
    return 2 * g if float(z[0]) > 0.0 else g


@pytest.mark.parametrize("check", [True, False])
def test_wrong_dF_stops_with_a_message_naming_the_cause(check):
    problem = ris_1d_problem(dF=wrong_for_positive_z, check_derivatives=check)
    with pytest.raises(
        RunFailed,
        match=r"^no progress: 200 step attempts advanced s by .* at "
        r"t = 2\.0.* dF or d2F probably does not belong to F",
    ) as e:
        run_ris(problem, Adaptive(1e-4, tau=0.1))
    traj = e.value.trajectory
    assert traj is not None and 2.0 <= traj["t"][-1] < 2.1  # the steps before the jump are kept
    assert e.value.where["failed_solves"] > 50


def test_stagnation_monitor_state_round_trip():
    """Checkpoint protocol: the monitor's state is plain data and restores exactly."""
    stepper = RISStepper(ris_1d_problem())
    state = RISState(s=0.0, t=0.0, z=np.array([-2.0]))
    for tau in (0.1, 0.05, 0.3):
        result = stepper.step(state, tau)
        state = result.state
    data = copy.deepcopy(stepper.monitor.checkpoint_state())
    assert data["attempts"] == 3 and data["s_start"] == 0.0
    fresh = StagnationMonitor()
    fresh.restore_state(data)
    assert fresh.checkpoint_state() == stepper.monitor.checkpoint_state()


# -- data that turns bad midway: a failed run that keeps its steps ---------------------------------


def test_nan_load_midway_keeps_the_trajectory():
    problem = FERISProblem(
        unit_square(4),
        g_7_2,
        dg_7_2,
        d2g_7_2,
        load=lambda t: np.nan if 0.5 < t < 0.52 else -200.0 * t**3,
    )
    with pytest.raises(
        RunFailed,
        match=r"^load\(t=0\.5\d*\): got nan, must be finite \(no NaN "
        r"or inf\) \(at step \d+, s = ",
    ) as e:
        run_ris(problem, Adaptive(1e-4, tau=0.1))
    traj = e.value.trajectory
    assert len(traj) == e.value.where["step"] - 1 and traj["t"][-1] <= 0.5


def test_load_undefined_beyond_T_only_shortens_the_last_step():
    """An attempt that overshoots T into times where the load is not defined is a failed
    attempt, not a failed run."""

    def load(t):
        if t > 1.0 + 1e-9:
            raise ValueError("no data after T")
        return np.full(3, 3.0 * t)

    traj = run_ris(readme_problem(load=load), Uniform(0.07)).trajectory
    assert abs(traj["t"][-1] - 1.0) <= 1e-10


def test_an_attempt_beyond_T_without_data_is_a_failed_attempt_with_its_code():
    """The load raises beyond T: the attempt that overshoots is not converged, its code is
    RISCode.DATA_BEYOND_T (the string value stays "data_beyond_T"), and the state is kept."""

    def load(t):
        if t > 1.0 + 1e-9:
            raise ValueError("no data after T")
        return np.full(3, 3.0 * t)

    problem = readme_problem(load=load)
    traj = run_ris(problem, Uniform(0.07)).trajectory
    k = int(np.searchsorted(traj["t"], 0.9))  # slipping at t = 0.91
    state = RISState(s=float(traj["s"][k]), t=float(traj["t"][k]), z=traj["z"][k].copy(), k=k)
    stepper = RISStepper(problem)
    result = stepper.step(state, 0.5)
    assert not result.converged and result.code is RISCode.DATA_BEYOND_T
    assert result.code == "data_beyond_T" and not result.code.successful
    assert result.state.z is state.z and result.state.k == k + 1
    assert result.state.s == state.s + 0.5
    ok = stepper.step(state, 0.02)
    assert ok.converged and ok.code is RISCode.CONVERGED and ok.code.successful


def test_the_adapt_step_never_changes_the_accepted_state_in_place():
    """Issue 17: after an accepted step the adapt step returns a new state on the new mesh;
    the accepted state (and its z) are untouched, bit for bit."""
    problem = example_front(4, T=0.3)
    stepper = RISStepper(problem, DIRECT, adapt=SpaceAdaptivity(space_tol=0.5, max_dofs=300))
    state = RISState(s=0.0, t=0.0, z=problem.z0.copy())
    changed = 0
    for _ in range(12):
        result = stepper.step(state, 0.05)
        assert result.converged
        accepted = result.state
        z_before = accepted.z.copy()
        fields = (accepted.s, accepted.t, accepted.k)
        new = stepper.adapt(accepted, result)
        assert np.array_equal(accepted.z, z_before) and accepted.z.shape == z_before.shape
        assert (accepted.s, accepted.t, accepted.k) == fields
        if new is not accepted:
            changed += 1
            assert new.z is not accepted.z and new.z.shape == (stepper.problem.n,)
            assert (new.s, new.t, new.k) == fields
            assert result.problem is not stepper.problem  # the step stays on its own mesh
            assert result.state.z.shape == (result.problem.n,)
        else:
            assert stepper.problem is result.problem
        state = new
    assert changed >= 2


# -- a stop signal between the inner solver's iterations (issue 21, item 3) -------------------


def _interrupted_at_iterations(make_run, signal_at_call, ckpt, calls, sig=signal.SIGINT):
    """Run, stopped by ``sig`` sent at the given iterations of the inner solver (counted per
    session) and resumed each time; every stop abandons the step under way. Returns the last,
    uninterrupted session's trajectory."""
    resume = None
    for k in calls:
        signal_at_call(BallStepSolver, "step", k, sig)
        with pytest.raises(RunInterrupted) as info:
            make_run(checkpoint=CheckpointOptions(ckpt, every_seconds=0.01), resume=resume)
        exc = info.value
        assert exc.exit_status == 128 + sig and exc.where["abandoned_step"] is True
        assert str(exc).endswith("; the step under way was abandoned)")
        traj = exc.trajectory
        accepted = exc.where["accepted_steps"]
        # the abandoned attempt is nowhere: not recorded, not counted
        assert accepted == traj.stats.accepted_steps == len(traj["tau"])
        assert traj.stats.inner_solves == traj.stats.accepted_steps + traj.stats.rejected_steps
        saved = load_checkpoint(ckpt)
        assert saved.status == "interrupted" and saved.where["abandoned_step"] is True
        assert saved.state["stepper"]["k"] == accepted  # the last accepted state
        # the stored factorization's counters as at that state (abandon put them back)
        linear = saved.state["stepper"]["linear"]["stats"]
        assert linear["factorizations"] == traj.stats.linear_factorizations
        assert linear["solves"] == traj.stats.linear_solves
        resume = ckpt
    signal_at_call(BallStepSolver, "step", 10**9)
    return make_run(resume=ckpt)


def test_a_signal_between_inner_iterations_abandons_the_step_and_resumes_bit_for_bit(
    tmp_path, signal_at_call
):
    p = examples.example_7_2(6, T=0.3)

    def make_run(**kw):
        return run_ris(p, Adaptive(1e-4, tau=0.1), inner=DIRECT, **kw).trajectory

    counter = signal_at_call(BallStepSolver, "step", 10**9)
    full = make_run()
    n = counter[0]  # inner iterations of the whole run
    assert n > 100
    resumed = _interrupted_at_iterations(
        make_run, signal_at_call, tmp_path / "c", (n // 5, n // 4, n // 3)
    )
    assert_same_trajectory(full, resumed)
    assert full.meta["linear_solver"] == resumed.meta["linear_solver"]


def test_abandon_puts_back_the_factorization_the_monitor_and_the_last_tau():
    """What an attempt changes in the stepper, put back by abandon (references, no copies)."""
    p = examples.example_7_2(6, T=0.3)
    state = RISState(s=0.0, t=0.0, z=p.z0.copy())
    probe = RISStepper(p, DIRECT)
    while probe.solver.linear.stats.factorizations == 0:  # up to a step that moves z
        before, state = state, probe.step(state, 0.05).state
    stepper = RISStepper(p, DIRECT)
    stepper.begin_attempt(before)
    saved = (stepper.solver.linear.snapshot(), stepper.monitor.checkpoint_state())
    stepper.step(before, 0.05)
    lin = stepper.solver.linear
    assert lin.stats.factorizations > 0 and lin._prec is not None
    assert stepper.monitor.attempts == 1 and stepper._last_tau == 0.05
    stepper.abandon(before)
    assert lin._prec is None and lin.stats == saved[0]["stats"]
    assert stepper.monitor.checkpoint_state() == saved[1] and stepper._last_tau == 0.0
