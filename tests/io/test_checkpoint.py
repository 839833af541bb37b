"""Checkpoint and resume from Python: run_ris, run_nested, run_eld; the file format; refusals.
Issue 21: meshes written once (O(K) in total), a checkpoint changed after it was written refused
in one line when it is read, a state that does not fit the stepper refused in one line, an
uncreatable checkpoint directory naming the parameter, and no ``.lock`` left behind by a run that
wrote no checkpoint."""

from __future__ import annotations

import json
import os
import signal

import numpy as np
import pytest

from rothe import Adaptive, Nested, run_nested, run_ris
from rothe.errors import RotheInputError, RunFailed, RunInterrupted
from rothe.io.checkpoint import (
    MAIN,
    Checkpointer,
    CheckpointError,
    CheckpointOptions,
    DirectoryLock,
    RunCheckpointing,
    frozen,
    is_frozen,
    load_checkpoint,
    restored_vector,
)
from rothe.io.mesh_series import MeshSeries
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
    assert header["format"] == "rothe-checkpoint" and header["format_version"] == 2
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
    lock = DirectoryLock(tmp_path)
    lock.acquire()
    try:  # the same process may take it again (the CLI holds it around the run)
        run_ris(example_7_1(), Adaptive(1e-3), checkpoint=tmp_path)
    finally:
        lock.release()
    assert load_checkpoint(tmp_path).status == "completed"


# -- issue 21: growing states, edited files, states that do not fit, locks ----------------------


class GrowingMeshes:
    """A stepper whose state holds a series that gains one mesh of ``n`` vertices per step
    (what an adaptive run's stepper returns from checkpoint_state), and a vector x."""

    def __init__(self, n: int = 2000):
        self.n = n
        self.series = MeshSeries()

    def add_mesh(self, k: int) -> None:
        rng = np.random.default_rng(k)
        points = rng.random((self.n, 2))
        cells = np.arange(3 * self.n, dtype=np.int64).reshape(-1, 3) % self.n
        self.series.add(k, points, cells)

    def checkpoint_state(self, x) -> dict:
        return {"x": x, "series": self.series.checkpoint_state()}

    def restore_state(self, data) -> np.ndarray:
        self.series = MeshSeries.restore_state(data["series"])
        return restored_vector(data, "x", 3)


def _checkpointer(path, restored=None):
    return Checkpointer(
        CheckpointOptions(path), api="test", arguments={}, fingerprint={}, restored=restored
    )


def _sizes(path):
    return {p.name: p.stat().st_size for p in path.iterdir() if p.name != ".lock"}


def test_each_mesh_of_a_growing_series_is_written_once(tmp_path):
    """K checkpoints of a series of K meshes: every mesh is in exactly one arrays file and
    checkpoint.npz only gains a reference per mesh (under 200 bytes of JSON), so the mesh bytes
    written are O(K) (they were O(K^2): every checkpoint rewrote every mesh)."""
    stepper = GrowingMeshes()
    cp = _checkpointer(tmp_path)
    mesh_bytes = stepper.n * (2 * 8 + 3 * 8)
    written = 0
    main_sizes = []
    for k in range(12):
        stepper.add_mesh(k)
        before = _sizes(tmp_path)
        cp.save(stepper, None, np.arange(3.0))
        after = _sizes(tmp_path)
        new = {n: s for n, s in after.items() if n.startswith("arrays-") and n not in before}
        assert len(new) == 1  # the one new mesh, nothing else
        written += sum(new.values())
        main_sizes.append(after[MAIN])
    assert written < 12 * (mesh_bytes + 2000)
    growth = np.diff(main_sizes)
    assert growth.max() < 200 and main_sizes[-1] < mesh_bytes / 10
    cp.close()
    ckpt = load_checkpoint(tmp_path)
    series = MeshSeries.restore_state(ckpt.state["stepper"]["series"])
    assert series.ids == list(range(12))
    for k in range(12):
        assert np.array_equal(series.mesh(k)[0], stepper.series.mesh(k)[0])


def test_a_resumed_checkpointer_adopts_the_meshes_already_written(tmp_path):
    stepper = GrowingMeshes(200)
    cp = _checkpointer(tmp_path)
    for k in range(3):
        stepper.add_mesh(k)
        cp.save(stepper, None, np.arange(3.0))
    cp.close()
    files = set(_sizes(tmp_path))
    restored = load_checkpoint(tmp_path)
    again = GrowingMeshes(200)
    x = again.restore_state(restored.state["stepper"])
    assert all(is_frozen(again.series.mesh(k)[0]) for k in range(3))
    cp = _checkpointer(tmp_path, restored=restored)
    cp.save(again, None, x)
    assert {n for n in _sizes(tmp_path) if n.startswith("arrays-")} == {
        n for n in files if n.startswith("arrays-")
    }  # nothing rewritten
    again.add_mesh(3)
    cp.save(again, None, x)
    cp.close()
    assert len([n for n in _sizes(tmp_path) if n.startswith("arrays-")]) == 4
    assert MeshSeries.restore_state(load_checkpoint(tmp_path).state["stepper"]["series"]).ids == [
        0,
        1,
        2,
        3,
    ]


def test_frozen_is_a_read_only_owned_copy_and_idempotent():
    a = np.arange(4.0)
    f = frozen(a)
    assert is_frozen(f) and f is not a and frozen(f) is f
    a[0] = 7.0
    assert f[0] == 0.0
    assert not is_frozen(f[1:])  # a view does not own its data


def _edit(path, change):
    """Rewrite checkpoint.npz with ``change(header, arrays)`` applied (as an editor would)."""
    with np.load(path / MAIN, allow_pickle=False) as f:
        data = {k: f[k] for k in f.files}
    header = json.loads(data.pop("__checkpoint__").tobytes().decode())
    change(header, data)
    np.savez(
        path / MAIN, __checkpoint__=np.frombuffer(json.dumps(header).encode(), np.uint8), **data
    )


def _x_ref(header):
    return header["state"]["stepper"]["x"]["__array__"]


EDITS = {
    "no state": (lambda h, a: h.pop("state"), "(no 'state' entry)"),
    "no stepper state": (lambda h, a: h["state"].pop("stepper"), "(its state has no 'stepper')"),
    "state not a dict": (
        lambda h, a: h.update(state=[1, 2]),
        "('state' is a list, must be a dict)",
    ),
    "status unknown": (
        lambda h, a: h.update(status="paused"),
        "(status 'paused' is not one of running, interrupted, failed, completed)",
    ),
    "array missing": (
        lambda h, a: a.pop(_x_ref(h)),
        "(its state refers to an array 'a0' that is not stored)",
    ),
    "vector shorter": (
        lambda h, a: a.update({_x_ref(h): a[_x_ref(h)][:-1]}),
        "(its state differs from what rothe wrote: edited or damaged after it was written)",
    ),
    "vector replaced by a string": (
        lambda h, a: h["state"]["stepper"].update(x="hello"),
        "(its state differs from what rothe wrote: edited or damaged after it was written)",
    ),
    "stepper state null": (
        lambda h, a: h["state"].update(stepper=None),
        "(its state differs from what rothe wrote: edited or damaged after it was written)",
    ),
}


@pytest.mark.parametrize("edit", list(EDITS))
def test_a_checkpoint_changed_after_it_was_written_is_refused_when_read(tmp_path, edit):
    """Was a KeyError ('state') or, on resume, a matmul dimension mismatch in the first step."""
    stepper = GrowingMeshes(50)
    stepper.add_mesh(0)
    cp = _checkpointer(tmp_path)
    cp.save(stepper, None, np.arange(3.0))
    cp.close()
    change, message = EDITS[edit]
    _edit(tmp_path, change)
    with pytest.raises(CheckpointError) as info:
        load_checkpoint(tmp_path)
    assert str(info.value) == f"{tmp_path / MAIN}: not a readable checkpoint {message}"


def test_an_edited_mesh_file_is_refused_too(tmp_path):
    stepper = GrowingMeshes(50)
    stepper.add_mesh(0)
    cp = _checkpointer(tmp_path)
    cp.save(stepper, None, np.arange(3.0))
    cp.close()
    (arrays,) = [p for p in tmp_path.iterdir() if p.name.startswith("arrays-")]
    with np.load(arrays) as f:
        data = {k: f[k] for k in f.files}
    data["f0"] = data["f0"] * 2.0
    np.savez(arrays, **data)
    with pytest.raises(CheckpointError, match="its state differs from what rothe wrote"):
        load_checkpoint(tmp_path)
    arrays.unlink()
    with pytest.raises(
        CheckpointError,
        match=r"arrays-000001\.npz: an array file of the "
        r"checkpoint is missing or damaged",
    ):
        load_checkpoint(tmp_path)


@pytest.mark.parametrize(
    "value, message",
    [
        (
            np.arange(2.0),
            "checkpoint state stepper.x: 2 entries, this problem has 3 (the checkpoint "
            "is of another problem, or damaged)",
        ),
        (
            np.zeros((3, 2)),
            "checkpoint state stepper.x: an array of shape (3, 2) and dtype float64, "
            "must be a vector of real numbers",
        ),
        ("hello", "checkpoint state stepper.x: a str, must be a vector of real numbers"),
        (None, "checkpoint state stepper.x: a NoneType, must be a vector of real numbers"),
    ],
)
def test_restored_vector_names_the_entry_that_does_not_fit(value, message):
    with pytest.raises(CheckpointError) as info:
        restored_vector({"x": value}, "x", 3)
    assert str(info.value) == message
    with pytest.raises(CheckpointError, match=r"^checkpoint state stepper\.x: missing"):
        restored_vector({}, "x", 3)
    assert np.array_equal(restored_vector({"x": np.arange(3)}, "x", 3), [0.0, 1.0, 2.0])


class _Problem:
    T = 1.0

    def fingerprint(self):
        return {"n": 3}


class _Stepper:
    def checkpoint_state(self, x):
        return {"x": x}

    def restore_state(self, data):
        return data["x"] @ np.ones(3)  # what a stepper does with a vector of the wrong length


def test_run_checkpointing_restore_turns_a_state_that_does_not_fit_into_one_line(tmp_path):
    rc = RunCheckpointing("test", _Problem(), {}, checkpoint=tmp_path)
    rc.checkpointer.save(_Stepper(), None, np.arange(4.0))
    rc.close()
    rc = RunCheckpointing("test", _Problem(), {}, resume=tmp_path)
    with pytest.raises(CheckpointError) as info:
        rc.restore(_Stepper())
    rc.close()
    assert str(info.value).startswith(
        f"{tmp_path}: the checkpoint's state does not fit this run (ValueError: matmul: "
    )


@pytest.mark.parametrize("where", ["checkpoint", "resume"])
def test_an_uncreatable_checkpoint_directory_names_the_parameter(tmp_path, where):
    """run_eld(..., checkpoint='/proc/ckpt') raised a raw FileNotFoundError from mkdir."""
    if where == "checkpoint":
        with pytest.raises(RotheInputError) as info:
            RunCheckpointing("test", _Problem(), {}, checkpoint="/proc/ckpt")
        assert str(info.value) == (
            "checkpoint: got '/proc/ckpt', cannot create or write files "
            "in this directory ([Errno 2] No such file or directory)"
        )
        assert info.value.parameter == "checkpoint"
        return
    rc = RunCheckpointing("test", _Problem(), {}, checkpoint=tmp_path)
    rc.checkpointer.save(_Stepper(), None, np.arange(3.0))
    rc.close()
    os.chmod(tmp_path, 0o555)
    try:
        if os.access(tmp_path, os.W_OK):
            pytest.skip("running as a user who can write a read-only directory (root)")
        with pytest.raises(RotheInputError, match=r"^resume: got '.*', cannot create or write "):
            RunCheckpointing("test", _Problem(), {}, resume=tmp_path)
    finally:
        os.chmod(tmp_path, 0o755)


def test_the_eld_driver_names_the_checkpoint_parameter():
    from rothe.eld import mms_problem, run_eld
    from rothe.stepping.controllers import Uniform

    problem, _ = mms_problem(2)
    with pytest.raises(RotheInputError, match=r"^checkpoint: got '/proc/ckpt', cannot create"):
        run_eld(problem, control=Uniform(0.1), checkpoint="/proc/ckpt")


def test_a_lock_released_with_no_checkpoint_written_leaves_nothing(tmp_path):
    """A refused ELD input after the command line took the lock left OUT/checkpoint/.lock."""
    d = tmp_path / "checkpoint"
    with DirectoryLock(d), DirectoryLock(d):  # re-entrant: the session's and the run's
        assert (d / ".lock").is_file()
    assert not d.exists()
    with DirectoryLock(d):
        (d / MAIN).write_bytes(b"x")
    assert sorted(p.name for p in d.iterdir()) == [".lock", MAIN]  # a checkpoint stays locked
