"""Checkpoint and resume of coupled runs (run_coupled / run_bodies / run_coupled_many with
``checkpoint=`` / ``resume=``): interrupted by SIGINT or SIGTERM and resumed, each equal to the
uninterrupted run bit for bit (fixed mesh with adaptive steps and controllers, an adaptive
mesh, glued bodies, a sequence of two runs); what a stop leaves; resumes that are refused."""

from __future__ import annotations

import signal

import numpy as np
import pytest

from rothe.eld import BDF2, ImplicitEuler, Original
from rothe.eld.bodies import run_bodies
from rothe.eld.coupled_run import CoupledStepper, run_coupled, run_coupled_many
from rothe.errors import RotheInputError
from rothe.fem.adapt import SpaceAdaptivity
from rothe.io.checkpoint import CheckpointError, load_checkpoint
from rothe.stepping.controllers import Adaptive, Uniform

from ..conftest import interrupted_thrice
from .test_bodies import SOFT, STIFF, two_bodies
from .test_coupled_step import _shaken_tip

pytestmark = pytest.mark.filterwarnings("ignore:G_d")


def _tip(**kw):
    return _shaken_tip(degree=1, nx=6, controllers=True, T=0.1, **kw)


def assert_same(a, b):
    """Every series equal (np.array_equal; NaN where the other has NaN: the space estimate
    of a step after which no adaptation was due) and every statistic but the wall times."""
    assert set(a.keys()) == set(b.keys())
    bad = [k for k in a.keys() if not np.array_equal(a[k], b[k], equal_nan=True)]
    assert not bad, f"differ: {bad}"
    assert a.stats.untimed() == b.stats.untimed()


def interrupted(make_run, signal_at_attempt, ckpt, attempts, sig=signal.SIGINT, runs=None):
    """:func:`tests.conftest.interrupted_thrice` for the coupled stepper."""
    return interrupted_thrice(
        make_run, CoupledStepper, signal_at_attempt, ckpt, sig, attempts, runs=runs
    )


def test_fixed_mesh_adaptive_bdf2_with_controllers_resumes_bit_for_bit(tmp_path, signal_at_attempt):
    """Adaptive BDF2 with rejections (the controller's state), two controllers (z), the
    mass-spring (q, p, pdot) and the shaken support; stopped thrice."""
    options = dict(scheme=BDF2(), control=Adaptive(3e-3, tau=0.01))
    full = run_coupled(_tip(), **options)
    assert full.trajectory.stats.rejected_steps > 0 and full.state.z.size > 0

    def make_run(**kw):
        return run_coupled(_tip(), **options, **kw)

    res = interrupted(make_run, signal_at_attempt, tmp_path / "c", attempts=(3, 6, 5))
    assert_same(full.trajectory, res.trajectory)
    assert res.trajectory.meta["sessions"] == 4
    for key in ("u", "v", "a", "lam", "q", "p", "pdot", "z", "zdot"):
        assert np.array_equal(getattr(full.state, key), getattr(res.state, key)), key
    assert full.state.ledger == res.state.ledger
    assert load_checkpoint(tmp_path / "c").status == "completed"


def test_adaptive_mesh_resumes_bit_for_bit(tmp_path, signal_at_attempt):
    """The body's mesh changes after every step: the checkpoint holds the mesh hierarchy and
    the series; the resumed run rebuilds the system on the restored mesh (SIGTERM)."""
    options = dict(
        scheme=BDF2(),
        form=Original(),
        control=Uniform(0.01),
        adapt=SpaceAdaptivity(space_tol=1e-3, adapt_every=1, max_dofs=3000),
    )
    full = run_coupled(_tip(), **options)
    assert len(set(full.trajectory["mesh_id"].tolist())) >= 3
    assert full.trajectory["step_refinements"].sum() > 0  # with the in-step rounds

    def make_run(**kw):
        return run_coupled(_tip(), **options, **kw)

    res = interrupted(
        make_run, signal_at_attempt, tmp_path / "c", attempts=(4, 3), sig=signal.SIGTERM
    )
    assert_same(full.trajectory, res.trajectory)
    assert res.state.mesh_id == full.state.mesh_id and np.array_equal(res.state.u, full.state.u)
    assert res.meshes.adaptations == full.meshes.adaptations
    a, b = full.mesh_arrays(), res.mesh_arrays()
    assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def test_stopped_after_a_step_rejected_on_its_refined_mesh_resumes_bit_for_bit(
    tmp_path, signal_at_attempt, monkeypatch
):
    """In-step refinement rounds with adaptive steps: the stop comes after an attempt whose
    mesh was refined in its rounds and that the controller rejected -- the checkpoint is of
    the state before it, on that state's mesh (the stepper goes back to it), and the resumed
    run goes on as the uninterrupted one (the in-step estimates of adapt_every = 2 included)."""
    options = dict(
        scheme=BDF2(),
        form=Original(),
        control=Adaptive(1e-2, tau=0.01),
        adapt=SpaceAdaptivity(space_tol=3e-4, adapt_every=2, max_dofs=3000),
    )
    attempts = []  # (start state, refinements) of every attempt of the uninterrupted run
    step = CoupledStepper.step

    def counted(self, state, tau, s_end=None):
        result = step(self, state, tau, s_end)
        attempts.append((state, result.refinements))
        return result

    with monkeypatch.context() as m:
        m.setattr(CoupledStepper, "step", counted)
        full = run_coupled(_tip(), **options)
    # the attempts refined in their rounds and then rejected (the next one from the same state)
    rejected = [
        k + 1
        for k in range(len(attempts) - 1)
        if attempts[k][1] > 0 and attempts[k + 1][0] is attempts[k][0]
    ]
    assert len(rejected) >= 2 and full.trajectory["step_refinements"].sum() > 0

    def make_run(**kw):
        return run_coupled(_tip(), **options, **kw)

    # (the signal arrives before the k-th attempt, the stop after it; the second session
    # counts from its resumed state, whose next attempt is the rejected one's retry)
    res = interrupted(
        make_run,
        signal_at_attempt,
        tmp_path / "c",
        attempts=(rejected[0], rejected[1] - rejected[0]),
    )
    assert_same(full.trajectory, res.trajectory)
    assert res.state.mesh_id == full.state.mesh_id and np.array_equal(res.state.u, full.state.u)
    assert res.meshes.adaptations == full.meshes.adaptations


def test_glued_bodies_resume_bit_for_bit(tmp_path, signal_at_attempt):
    """Two glued bodies (the monolithic factorization of the bordered matrix is made again
    from the checkpoint's key): the fields of both bodies equal."""
    options = dict(scheme=BDF2(), control=Uniform(0.05))
    full = run_bodies(two_bodies(SOFT, STIFF, n=2, ny=(1, 1)), **options)

    def make_run(**kw):
        return run_bodies(two_bodies(SOFT, STIFF, n=2, ny=(1, 1)), **options, **kw)

    res = interrupted(make_run, signal_at_attempt, tmp_path / "c", attempts=(4,))
    assert_same(full.trajectory, res.trajectory)
    assert {"u", "v", "lam", "q"} <= set(res.trajectory.keys())


def test_a_sequence_of_two_runs_resumes_in_either_run(tmp_path, signal_at_attempt):
    """run_coupled_many (eld-tmd, eld-control): stopped in the first run and in the second;
    the finished run is restored from the checkpoint (trajectory, final state, meshes)."""
    options = dict(scheme=ImplicitEuler(), control=Uniform(0.01))

    def systems():
        return {"with": _tip(), "without": _shaken_tip(degree=1, nx=6, T=0.1)}

    full = run_coupled_many(systems(), **options)
    done = {}

    def make_run(**kw):
        done.clear()
        return run_coupled_many(systems(), **options, results=done, **kw)

    # 10 steps per run: the 4th attempt of the first session, then the 9th of the second
    # (the second run's 3rd step)
    res = interrupted(make_run, signal_at_attempt, tmp_path / "c", attempts=(4, 9), runs=(0, 1))
    assert list(res) == ["with", "without"] and list(done) == ["with", "without"]
    for label in res:
        assert_same(full[label].trajectory, res[label].trajectory)
        assert np.array_equal(full[label].state.q, res[label].state.q)
    ckpt = load_checkpoint(tmp_path / "c")
    assert ckpt.status == "completed" and ckpt.n_trajectories == 2


def test_resume_refuses_other_arguments_another_system_and_noise(tmp_path):
    d = tmp_path / "c"
    run_coupled(_tip(), scheme=BDF2(), control=Uniform(0.02), checkpoint=d)
    with pytest.raises(CheckpointError, match=r"the arguments differ from the checkpoint's: "):
        run_coupled(_tip(), scheme=ImplicitEuler(), control=Uniform(0.02), resume=d)
    with pytest.raises(CheckpointError, match=r"arguments differ.*control = "):
        run_coupled(_tip(), scheme=BDF2(), control=Uniform(0.01), resume=d)
    # another component (the tip's mass-spring without controllers): the system differs
    other = _shaken_tip(degree=1, nx=6, T=0.1)
    with pytest.raises(CheckpointError, match=r"the problem differs from the checkpoint's \(in: "):
        run_coupled(other, scheme=BDF2(), control=Uniform(0.02), resume=d)
    with pytest.raises(RotheInputError, match="^noise: got a callable, is not supported with"):
        run_coupled(
            _tip(),
            scheme=BDF2(),
            control=Uniform(0.02),
            noise=lambda j: (None, None, None),
            checkpoint=tmp_path / "n",
        )
