"""Checkpoint and resume from Python: run_ris, run_nested, run_eld; the file format; refusals."""

from __future__ import annotations

import json
import signal

import numpy as np
import pytest

from rothe import Adaptive, Nested, run_nested, run_ris
from rothe.errors import RunFailed, RunInterrupted
from rothe.io.checkpoint import (
    MAIN,
    CheckpointError,
    CheckpointOptions,
    load_checkpoint,
)
from rothe.ris.examples import example_7_1, example_7_2
from rothe.ris.inner import InnerOptions
from rothe.ris.stepper import RISStepper

from ..conftest import assert_same_trajectory, interrupted_thrice

DIRECT = InnerOptions(linear_solver="direct")


def test_run_ris_interrupted_and_resumed_equals_the_uninterrupted_run(tmp_path, signal_at_attempt):
    p = example_7_2(6, T=0.3)

    def make_run(**kw):
        return run_ris(p, Adaptive(1e-4, tau=0.1), inner=DIRECT, **kw).trajectory

    full = make_run()
    resumed = interrupted_thrice(make_run, RISStepper, signal_at_attempt, tmp_path / "c")
    assert_same_trajectory(full, resumed)
    assert resumed.meta["sessions"] == 4
    ckpt = load_checkpoint(tmp_path / "c")
    assert ckpt.status == "completed" and ckpt.sessions == 4
    # the wall time sums the sessions: at least what the checkpoint before the last had
    assert resumed.stats.wall_time_s >= ckpt.header["trajectories"][0]["stats"]["wall_time_s"]


def test_amg_runs_repeat_and_resume_bit_for_bit(tmp_path, signal_at_attempt):
    """pyamg's setup draws random vectors; under a fixed seed two runs (whatever numpy's global
    random state) and an interrupted + resumed run agree bit for bit."""
    p = example_7_2(24, T=0.2)  # 529 unknowns: more than one AMG level
    amg = InnerOptions(linear_solver="amg")

    def make_run(**kw):
        return run_ris(p, Adaptive(1e-3, tau=0.1), inner=amg, **kw).trajectory

    np.random.seed(1)
    a = make_run()
    assert a.meta["linear_solver"] == "pyamg-sa"
    np.random.seed(2)
    b = make_run()
    assert_same_trajectory(a, b)
    signal_at_attempt(RISStepper, 20)
    with pytest.raises(RunInterrupted):
        make_run(checkpoint=tmp_path / "c")
    signal_at_attempt(RISStepper, 10**9)
    assert_same_trajectory(a, make_run(resume=tmp_path / "c"))


def test_run_nested_resumes_inside_the_second_run(tmp_path, signal_at_attempt):
    p = example_7_1()

    def make_run(**kw):
        return [r.trajectory for r in run_nested(p, Nested([1e-2, 1e-3], tau=0.1), **kw)]

    full = make_run()
    n_first = full[0].stats.accepted_steps + full[0].stats.rejected_steps
    signal_at_attempt(RISStepper, n_first + 20)  # 20 attempts into the second run
    with pytest.raises(RunInterrupted):
        make_run(checkpoint=tmp_path / "c")
    assert load_checkpoint(tmp_path / "c").state["run"]["nested_index"] == 1
    signal_at_attempt(RISStepper, 10**9)
    resumed = make_run(resume=tmp_path / "c")
    assert len(resumed) == 2
    for a, b in zip(full, resumed, strict=True):
        assert_same_trajectory(a, b)


def test_run_eld_sigterm_and_resume(tmp_path, signal_at_attempt):
    from rothe.eld import ELDStepper, make_damping, mms_problem, run_eld
    from rothe.stepping.controllers import Uniform

    p, _ = mms_problem(3, 2, damping=make_damping("nonlinear", b=0.01, d0=0.5))

    def make_run(**kw):
        return run_eld(p, control=Uniform(0.01), **kw).trajectory

    full = make_run()
    resumed = interrupted_thrice(
        make_run,
        ELDStepper,
        signal_at_attempt,
        tmp_path / "c",
        sig=signal.SIGTERM,
        attempts=(1, 30, 40),
    )
    assert_same_trajectory(full, resumed)
    for key in ("factorizations", "backsolves", "krylov_iterations"):
        assert full.meta["linear_solver"][key] == resumed.meta["linear_solver"][key]


def test_checkpoint_file_format_needs_no_pickle_and_segments_are_incremental(tmp_path):
    p = example_7_1()
    traj = run_ris(p, Adaptive(1e-2), checkpoint=CheckpointOptions(tmp_path, 1e-9)).trajectory
    with np.load(tmp_path / MAIN, allow_pickle=False) as f:
        header = json.loads(f["__checkpoint__"].tobytes().decode())
    assert header["format"] == "rothe-checkpoint" and header["format_version"] == 1
    assert header["api"] == "run_ris" and header["arguments"]["tol"] == 1e-2
    assert header["status"] == "completed"
    assert {"A", "z0", "load", "F"} <= set(header["fingerprint"])
    assert header["libraries"]["numpy"] == np.__version__
    segments = header["trajectories"][0]["segments"]
    assert len(segments) > 10  # one per checkpoint (one after every step here)
    # every entry is written once: the segment counts add up to the series lengths
    total = sum(s["counts"]["s"] for s in segments)
    assert total == len(traj["s"])
    files = {x.name for x in tmp_path.iterdir()}
    assert files == {MAIN, ".lock"} | {s["file"] for s in segments}


def _checkpoint(tmp_path, **kw):
    d = tmp_path / "c"
    run_ris(example_7_1(), Adaptive(1e-3), checkpoint=d, **kw)
    return d


def test_resume_refuses_another_problem_other_arguments_and_another_api(tmp_path):
    d = _checkpoint(tmp_path)
    with pytest.raises(
        CheckpointError,
        match=r"the problem differs from the checkpoint's "
        r"\(in: T, load\)",
    ):
        run_ris(example_7_1(T=4.0), Adaptive(1e-3), resume=d)
    with pytest.raises(
        CheckpointError,
        match=r"the arguments differ from the checkpoint's: "
        r"tol = 0\.0001 \(checkpoint: 0\.001\)",
    ):
        run_ris(example_7_1(), Adaptive(1e-4), resume=d)
    with pytest.raises(CheckpointError, match="the checkpoint is of run_ris, not run_nested"):
        run_nested(example_7_1(), Nested([1e-2, 1e-3]), resume=d)
    with pytest.raises(CheckpointError, match="differs.*in: A"):
        run_ris(example_7_2(4), Adaptive(1e-3), resume=d)


def _rewrite_header(d, **changes):
    with np.load(d / MAIN, allow_pickle=False) as f:
        data = {k: f[k] for k in f.files}
    header = json.loads(data["__checkpoint__"].tobytes().decode())
    header.update(changes)
    data["__checkpoint__"] = np.frombuffer(json.dumps(header).encode(), np.uint8)
    np.savez(d / MAIN, **data)


def test_other_library_versions_are_a_warning(tmp_path):
    from rothe.io.checkpoint import CheckpointWarning

    d = _checkpoint(tmp_path)
    _rewrite_header(d, libraries={"numpy": "1.0.0"})
    with pytest.warns(CheckpointWarning, match=r"numpy 1\.0\.0 -> .*may differ .* last bits"):
        run_ris(example_7_1(), Adaptive(1e-3), resume=d)


def test_resume_refuses_missing_truncated_foreign_and_other_version(tmp_path):
    p = example_7_1()
    with pytest.raises(CheckpointError, match=r"nowhere: no such directory"):
        run_ris(p, Adaptive(1e-3), resume=tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(CheckpointError, match=r"empty: no checkpoint here"):
        run_ris(p, Adaptive(1e-3), resume=tmp_path / "empty")
    d = _checkpoint(tmp_path)
    _rewrite_header(d, rothe_version="0.0.1")
    with pytest.raises(CheckpointError, match=r"written by rothe 0\.0\.1, this is rothe "):
        run_ris(p, Adaptive(1e-3), resume=d)
    _rewrite_header(d, format="something-else")
    with pytest.raises(CheckpointError, match="not a rothe checkpoint"):
        load_checkpoint(d)
    raw = (d / MAIN).read_bytes()
    (d / MAIN).write_bytes(raw[: len(raw) // 2])
    with pytest.raises(CheckpointError, match=r"not a readable checkpoint \(truncated or damaged"):
        run_ris(p, Adaptive(1e-3), resume=d)
    np.savez(d / MAIN, x=np.zeros(3))
    with pytest.raises(CheckpointError, match="not a rothe checkpoint"):
        load_checkpoint(d)


def test_a_failed_run_leaves_a_failed_checkpoint_that_is_not_resumed(tmp_path):
    p = example_7_2(4)
    d = tmp_path / "c"
    with pytest.raises(RunFailed) as info:
        run_ris(p, Adaptive(1e-9, tau=0.5, tau_min=0.2), checkpoint=d)
    assert info.value.trajectory is not None
    ckpt = load_checkpoint(d)
    assert ckpt.status == "failed" and "tau_min" in ckpt.where["failure"]
    with pytest.raises(CheckpointError, match="the run failed .*resuming it would repeat"):
        run_ris(p, Adaptive(1e-9, tau=0.5, tau_min=0.2), resume=d)


def test_one_writer_per_checkpoint_directory(tmp_path):
    from rothe.io.checkpoint import DirectoryLock

    lock = DirectoryLock(tmp_path)
    lock.acquire()
    try:  # the same process may take it again (the CLI holds it around the run)
        run_ris(example_7_1(), Adaptive(1e-3), checkpoint=tmp_path)
    finally:
        lock.release()
    assert load_checkpoint(tmp_path).status == "completed"
