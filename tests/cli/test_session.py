"""The run commands as sessions (in-process): signals, resume, refusals, what --out holds; a
completed run removes its checkpoint unless ``--keep-checkpoint``, an interrupted one keeps it, a
refused input leaves no ``--out`` and no ``.lock``, ``--continue`` and ``rothe resume``
recognize a completed run without its checkpoint, a signal inside a step abandons it (issue
21)."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from rothe.cli.main import main
from rothe.cli.session import _remove_checkpoint
from rothe.io.checkpoint import MAIN, load_checkpoint
from rothe.ris.inner import BallStepSolver
from rothe.ris.stepper import RISStepper

from ..conftest import assert_same_trajectory, run_cli

RIS2D = ["run", "ris-2d", "--n", "4", "--tol", "1e-3", "--no-plots", "--quiet"]
RIS1D = ["run", "ris-1d", "--tol", "1e-3", "--no-plots", "--quiet"]
RIS2D_REGIME = RIS2D + ["--control", "regime"]  # 489 attempts


def _run(argv, capsys):
    return run_cli(capsys, *argv)


def _code_err(capsys, *argv):
    """``rothe *argv`` in this process: (exit status, stderr)."""
    code, _, err = run_cli(capsys, *argv)
    return code, err


def _summary(d):
    return json.loads((d / "summary.json").read_text())


def _lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.strip()]


@pytest.mark.parametrize(
    "cmd, sig, status",
    [(RIS2D, signal.SIGINT, 130), (RIS1D, signal.SIGTERM, 143), (RIS2D_REGIME, signal.SIGINT, 130)],
    ids=["INT", "TERM", "INT-regime"],
)
def test_signal_writes_results_so_far_and_a_checkpoint_then_resume_is_bit_identical(
    tmp_path, capsys, signal_at_attempt, cmd, sig, status
):
    ref = tmp_path / "ref"
    assert _run(cmd + ["--out", ref], capsys)[0] == 0
    out = tmp_path / "run"
    signal_at_attempt(RISStepper, 200 if cmd[1] == "ris-2d" else 60, sig)
    code, _, err = _run(cmd + ["--out", out], capsys)
    assert code == status
    (line,) = _lines(err)
    assert line.startswith(f"rothe: interrupted by {signal.Signals(sig).name} after ")
    assert line.endswith(f"continue with: rothe resume {out}")
    s = _summary(out)
    assert s["status"] == "interrupted" and s["signal"] == signal.Signals(sig).name
    assert s["where"]["accepted_steps"] == s["accepted_steps"] > 0
    assert s["resume"] == f"rothe resume {out}" and s["t_final"] < s["where"]["t"] + 1e-12
    with np.load(out / "trajectory.npz") as f:
        assert f["tau"].size == s["accepted_steps"]
    assert load_checkpoint(out).status == "interrupted"
    assert sorted(s["files"]) == sorted(p.name for p in out.iterdir() if p.is_file())
    signal_at_attempt(RISStepper, 10**9)
    code, _, err = _run(["resume", out, "--quiet"], capsys)
    assert code == 0 and err == ""
    s = _summary(out)
    assert s["status"] == "completed" and s["sessions"] == 2 and "wall_time_note" in s
    with np.load(ref / "trajectory.npz") as a, np.load(out / "trajectory.npz") as b:
        assert_same_trajectory(a, b)
    # resuming a completed run does nothing
    code, _, err = _run(["resume", out], capsys)
    assert code == 0 and "already completed" in err


def test_a_signal_inside_a_step_abandons_it_exit_130_and_resume_is_bit_identical(
    tmp_path, capsys, signal_at_call
):
    """Issue 21: SIGINT between two iterations of the inner solver stops the run at once; the
    step under way is abandoned (not in the trajectory), the checkpoint holds the previous
    accepted state, exit status 130; ``rothe resume`` then gives the uninterrupted run."""
    ref = tmp_path / "ref"
    assert _run(RIS2D + ["--out", ref], capsys)[0] == 0
    out = tmp_path / "run"
    signal_at_call(BallStepSolver, "step", 60)
    code, _, err = _run(RIS2D + ["--out", out], capsys)
    assert code == 130
    (line,) = _lines(err)
    assert "; the step under way was abandoned)" in line, line
    s = _summary(out)
    assert s["status"] == "interrupted" and s["where"]["abandoned_step"] is True
    ckpt = load_checkpoint(out)
    assert ckpt.status == "interrupted" and ckpt.where["abandoned_step"] is True
    assert ckpt.state["stepper"]["k"] == s["accepted_steps"] == s["where"]["accepted_steps"] > 0
    with np.load(out / "trajectory.npz") as f:
        assert f["tau"].size == s["accepted_steps"]
    signal_at_call(BallStepSolver, "step", 10**9)
    assert _run(["resume", out, "--quiet"], capsys)[0] == 0
    with np.load(ref / "trajectory.npz") as a, np.load(out / "trajectory.npz") as b:
        assert_same_trajectory(a, b)


def test_resume_refusals_are_one_line_with_exit_status_2(tmp_path, capsys):
    d = tmp_path / "run"

    def snapshot():
        return {p.relative_to(d): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}

    def refused(argv, match):
        before = snapshot() if d.exists() else None
        code, out, err = _run(argv, capsys)
        assert code == 2, err
        (line,) = _lines(err)
        assert line.startswith("rothe: error: ") and __import__("re").search(match, line), line
        # a refused resume writes nothing: the earlier result and its checkpoint are untouched
        if before is not None:
            assert snapshot() == before

    refused(["resume", tmp_path / "missing"], r"missing: no such directory")
    (tmp_path / "empty").mkdir()
    refused(["resume", tmp_path / "empty"], r"empty: no checkpoint here")
    assert list((tmp_path / "empty").iterdir()) == []
    assert (
        _run(
            [
                "run",
                "ris-1d",
                "--tol",
                "1e-3",
                "--out",
                d,
                "--quiet",
                "--no-plots",
                "--keep-checkpoint",
            ],
            capsys,
        )[0]
        == 0
    )
    assert {"summary.json", "trajectory.npz"} <= {p.name for p in d.iterdir()}
    refused(
        ["run", "ris-1d", "--tol", "1e-5", "--resume", d],
        r"--resume .*run: the command line differs from the checkpoint's: --tol 1e-05 "
        r"\(checkpoint: 0\.001\)",
    )
    refused(
        ["run", "ris-2d", "--resume", d],
        r"the checkpoint is of 'rothe run ris-1d', not "
        r"'rothe run ris-2d'",
    )
    refused(
        ["run", "ris-1d", "--tol", "1e-3", "--resume", d, "--out", tmp_path / "x"],
        r"--out: got .*x', must be the resumed directory",
    )
    assert not (tmp_path / "x").exists()
    ckpt = d / "checkpoint" / MAIN
    with np.load(ckpt, allow_pickle=False) as f:
        data = {k: f[k] for k in f.files}
    header = json.loads(data["__checkpoint__"].tobytes().decode())
    header["rothe_version"] = "0.0.1"
    data["__checkpoint__"] = np.frombuffer(json.dumps(header).encode(), np.uint8)
    np.savez(ckpt, **data)
    refused(
        ["resume", d],
        r"written by rothe 0\.0\.1, this is rothe \S+; resume it with "
        r"rothe 0\.0\.1 or start over",
    )
    raw = ckpt.read_bytes()
    ckpt.write_bytes(raw[:100])
    refused(["resume", d], r"checkpoint\.npz: not a readable checkpoint \(truncated or damaged")


def test_stopped_before_the_first_accepted_step(tmp_path, capsys, monkeypatch):
    """A signal during set-up (e.g. Ctrl-C during the first, long step of a big run, whose
    attempt is then rejected): a summary with 0 steps, a checkpoint, resumable."""
    original = RISStepper.finished
    sent = []

    def finished(self, state):
        if not sent:
            sent.append(os.kill(os.getpid(), signal.SIGINT))
        return original(self, state)

    monkeypatch.setattr(RISStepper, "finished", finished)
    d = tmp_path / "run"
    assert _run(RIS2D + ["--out", d], capsys)[0] == 130
    s = _summary(d)
    assert s["status"] == "interrupted" and s["accepted_steps"] == 0 and s["max_residual"] == 0
    monkeypatch.setattr(RISStepper, "finished", original)
    assert _run(["resume", d, "--quiet"], capsys)[0] == 0
    assert _summary(d)["status"] == "completed"


def test_resume_refuses_a_checkpoint_written_from_python(tmp_path, capsys):
    from rothe import Adaptive, run_ris
    from rothe.ris.examples import example_7_1

    run_ris(example_7_1(), Adaptive(1e-2), checkpoint=tmp_path / "c")
    code, _, err = _run(["resume", tmp_path / "c"], capsys)
    assert code == 2 and "written by run_ris() from Python, not by a rothe command" in err


def test_resume_refuses_a_changed_mesh_file(tmp_path, capsys, signal_at_attempt):
    """The problem's fingerprint: the same command line on an edited mesh file is refused."""
    import meshio

    from rothe.fem.mesh import unit_square

    m = unit_square(4)
    path = tmp_path / "square.vtu"
    meshio.write(path, meshio.Mesh(m.p.T, [("triangle", m.t.T)]))
    d = tmp_path / "run"
    argv = ["run", "ris-2d", "--mesh", path, "--tol", "1e-3", "--out", d, "--quiet", "--no-plots"]
    signal_at_attempt(RISStepper, 20)
    assert _run(argv, capsys)[0] == 130
    signal_at_attempt(RISStepper, 10**9)
    p = m.p.copy()
    p[:, 12] += 0.01  # move an interior node
    meshio.write(path, meshio.Mesh(p.T, [("triangle", m.t.T)]))
    code, _, err = _run(["resume", d], capsys)
    assert code == 2
    assert "the problem differs from the checkpoint's (in: A, F, load, mesh, weights)" in err


def test_new_run_refused_over_an_unfinished_checkpoint(tmp_path, capsys, signal_at_attempt):
    d = tmp_path / "run"
    signal_at_attempt(RISStepper, 5)
    assert _run(["run", "ris-1d", "--out", d, "--quiet", "--no-plots"], capsys)[0] == 130
    signal_at_attempt(RISStepper, 10**9)
    code, _, err = _run(["run", "ris-1d", "--tol", "1e-3", "--out", d, "--quiet"], capsys)
    assert code == 2
    assert (
        f"--out: got '{d}', holds the checkpoint of an unfinished run (interrupted, "
        "accepted_steps = "
    ) in err
    assert f"continue it with 'rothe resume {d}' or start over with --discard-checkpoint" in err
    code, _, _ = _run(
        [
            "run",
            "ris-1d",
            "--tol",
            "1e-3",
            "--out",
            d,
            "--quiet",
            "--no-plots",
            "--discard-checkpoint",
        ],
        capsys,
    )
    assert code == 0 and _summary(d)["tol"] == 1e-3


def test_a_run_that_does_not_complete_never_replaces_a_completed_result(
    tmp_path, capsys, signal_at_attempt
):
    d = tmp_path / "run"
    argv = ["run", "ris-2d", "--n", "4", "--tol", "1e-3", "--out", d, "--quiet"]
    assert _run(argv, capsys)[0] == 0
    first = {p.name: p.read_bytes() for p in d.iterdir() if p.is_file()}
    assert "fig1_path.png" in first
    # fails at step 18: the earlier result stays, the failed one goes to incomplete/
    code, _, err = _run(argv + ["--tau-min", "1e-2"], capsys)
    assert code == 1 and "run failed: step size fell below tau_min" in err
    assert {p.name: p.read_bytes() for p in d.iterdir() if p.is_file()} == first
    assert _summary(d / "incomplete")["status"] == "failed"
    # interrupted: the same
    signal_at_attempt(RISStepper, 30)
    code, _, err = _run(argv + ["--tol", "2e-3", "--no-plots"], capsys)
    assert code == 130 and f"(the earlier completed run stays in {d}/)" in err
    assert {p.name: p.read_bytes() for p in d.iterdir() if p.is_file()} == first
    assert _summary(d / "incomplete")["status"] == "interrupted"
    # completed after resume: replaces it, removes the earlier figures (not of this run) and
    # incomplete/
    signal_at_attempt(RISStepper, 10**9)
    assert _run(["resume", d, "--quiet"], capsys)[0] == 0
    s = _summary(d)
    assert s["status"] == "completed" and s["tol"] == 2e-3
    assert not (d / "incomplete").exists() and not (d / "fig1_path.png").exists()
    assert sorted(s["files"]) == sorted(p.name for p in d.iterdir() if p.is_file())


def test_out_is_checked_before_the_first_step(tmp_path, capsys):
    code, _, err = _run(["run", "ris-1d", "--out", "/proc/x", "--quiet"], capsys)
    assert code == 2
    assert err.strip() == (
        "rothe: error: --out: got '/proc/x', cannot create or write files "
        "in this directory ([Errno 2] No such file or directory)"
    )
    (tmp_path / "f").write_text("x")
    code, _, err = _run(["run", "ris-1d", "--out", tmp_path / "f", "--quiet"], capsys)
    assert code == 2 and "must be a directory (a file of that name exists)" in err
    if os.geteuid() != 0:  # root writes anywhere: the tmpfs test in test_cli_subprocess covers it
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        code, _, err = _run(["run", "ris-1d", "--out", ro / "x", "--quiet"], capsys)
        assert code == 2 and "--out: got" in err and "Permission denied" in err


def test_a_full_disk_at_the_end_keeps_the_earlier_files_and_is_one_line(
    tmp_path, capsys, monkeypatch
):
    d = tmp_path / "run"
    argv = ["run", "ris-1d", "--tol", "1e-3", "--out", d, "--quiet", "--no-plots"]
    assert _run(argv, capsys)[0] == 0
    first = {p.name: p.read_bytes() for p in d.iterdir() if p.is_file()}
    real = np.savez_compressed

    def full_disk(file, *args, **kwargs):
        if str(file).endswith("trajectory.npz"):
            with open(file, "wb") as f:
                f.write(b"PK\x03\x04 partial")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(file, *args, **kwargs)

    monkeypatch.setattr(np, "savez_compressed", full_disk)
    code, _, err = _run(argv[:3] + ["2e-3"] + argv[4:], capsys)
    assert code == 1
    assert _lines(err) == [
        f"rothe: error: cannot write {d}/trajectory.npz: No space left on "
        "device (files written before are unchanged)"
    ]
    assert {p.name: p.read_bytes() for p in d.iterdir() if p.is_file()} == first
    assert not [p for p in d.iterdir() if p.name.startswith(".rothe-tmp")]


def test_progress_lines_in_a_log(tmp_path, capsys):
    code = main(
        [
            "run",
            "ris-2d",
            "--n",
            "4",
            "--tol",
            "1e-3",
            "--out",
            str(tmp_path / "r"),
            "--no-plots",
            "--progress-every",
            "0.01",
        ]
    )
    err = capsys.readouterr().err
    assert code == 0
    lines = [x for x in err.splitlines() if x.startswith("rothe: step ")]
    assert lines, err
    import re

    pattern = (
        r"^rothe: step \d+ \(accepted \d+, rejected \d+\)  s = [\d.e+-]+  "
        r"t = [\d.e+-]+/1 \([\d.]+%\)  tau = [\d.e+-]+  elapsed \d+:\d\d:\d\d"
    )
    assert all(re.match(pattern, x) for x in lines), lines[0]
    assert "\r" not in err
    assert err.splitlines()[-1].startswith("rothe: finished at step ")


def test_a_second_process_cannot_write_into_the_same_out(tmp_path, capsys):
    d = tmp_path / "run"
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from rothe.io.checkpoint import DirectoryLock;"
            f"DirectoryLock({str(d / 'checkpoint')!r}).acquire(); print('locked', flush=True);"
            "time.sleep(60)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        code, _, err = _run(["run", "ris-1d", "--out", d, "--quiet"], capsys)
        assert code == 2
        assert f"in use by another running rothe process (pid {holder.pid})" in err
    finally:
        holder.kill()
        holder.wait()


def test_eld_beam_interrupted_leaves_consistent_xdmf_and_resumes_bit_for_bit(
    tmp_path, capsys, signal_at_attempt
):
    """The fuzzer's case (eld-beam + SIGINT left 76 MB of HDF5 without an XDMF index or a
    summary): the XDMF index, its HDF5 file and the summary agree, and the resumed series is
    the uninterrupted one, dataset by dataset."""
    import h5py
    import meshio

    from rothe.eld import ELDStepper

    argv = [
        "run",
        "eld-beam",
        "--n",
        "1",
        "--T",
        "1",
        "--tau",
        "0.01",
        "--save-every",
        "2",
        "--no-plots",
        "--quiet",
        "--checkpoint-every",
        "0.01",
    ]
    ref = tmp_path / "ref"
    assert _run(argv + ["--out", ref], capsys)[0] == 0
    out = tmp_path / "run"
    signal_at_attempt(ELDStepper, 37)
    assert _run(argv + ["--out", out], capsys)[0] == 130
    s = _summary(out)
    assert s["status"] == "interrupted" and s["accepted_steps"] == 37  # the step under way
    assert s["xdmf_steps"] == 19  # t = 0 and every second step up to 36
    for name, steps in (("beam", 19), ("beam_multiplier", 19)):  # one time axis (issue 21)
        with meshio.xdmf.TimeSeriesReader(str(out / f"{name}.xdmf")) as reader:
            reader.read_points_cells()
            assert reader.num_steps == steps
            t, _, _ = reader.read_data(steps - 1)
        assert t == pytest.approx(0.36)
    signal_at_attempt(ELDStepper, 10**9)
    assert _run(["resume", out, "--quiet"], capsys)[0] == 0
    assert not list((out / "checkpoint" / "stream").glob("*.h5"))  # merged, then removed
    for name in ("beam.h5", "beam_multiplier.h5"):
        with h5py.File(ref / name) as a, h5py.File(out / name) as b:
            keys = []
            a.visit(lambda k, keys=keys: keys.append(k))
            datasets = [k for k in keys if isinstance(a[k], h5py.Dataset)]
            assert len(datasets) > 50
            for k in datasets:
                x, y = a[k][()], b[k][()]
                # every frame holds numbers: lambda(0) at t = 0, not NaN (issue 21)
                assert x.dtype.kind != "f" or np.all(np.isfinite(x)), (name, k)
                assert np.array_equal(x, y), (name, k)
    assert (ref / "beam.xdmf").read_text() == (out / "beam.xdmf").read_text()
    with np.load(ref / "trajectory.npz") as a, np.load(out / "trajectory.npz") as b:
        assert_same_trajectory(a, b)


# -- issue 21: the checkpoint of a completed run ------------------------------------------------


def test_a_completed_run_removes_its_checkpoint_and_says_how_to_keep_it(tmp_path, capsys):
    out = tmp_path / "run"
    assert _code_err(capsys, *RIS1D, "--out", out) == (0, "")
    assert sorted(p.name for p in out.iterdir()) == ["summary.json", "trajectory.npz"]
    s = _summary(out)
    assert s["status"] == "completed" and s["checkpoint"] is None
    assert s["command"] == "run ris-1d" and s["argv"] == RIS1D
    # resuming it does nothing, without a checkpoint too
    code, err = _code_err(capsys, "resume", out)
    assert (
        code == 0
        and err.strip() == f"rothe: {out}: the run already completed; its results are there"
    )


def test_keep_checkpoint_keeps_it_and_does_not_change_the_results(tmp_path, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    assert _code_err(capsys, *RIS1D, "--out", a)[0] == 0
    assert _code_err(capsys, *RIS1D, "--keep-checkpoint", "--out", b)[0] == 0
    assert load_checkpoint(b).status == "completed"
    assert _summary(b)["checkpoint"] == str(b / "checkpoint")
    assert (a / "trajectory.npz").read_bytes() != b""  # both wrote results
    sa, sb = _summary(a), _summary(b)
    for key in ("accepted_steps", "rejected_steps", "sum_residual", "energy_final"):
        assert sa[key] == sb[key]


def test_an_interrupted_run_keeps_its_checkpoint(tmp_path, capsys, signal_at_attempt):
    out = tmp_path / "run"
    signal_at_attempt(RISStepper, 40, signal.SIGTERM)
    assert _code_err(capsys, *RIS1D, "--out", out)[0] == 143
    assert load_checkpoint(out).status == "interrupted"
    assert _summary(out)["checkpoint"] == str(out / "checkpoint")
    signal_at_attempt(RISStepper, 10**9)
    assert _code_err(capsys, "resume", out, "--quiet") == (0, "")
    assert not (out / "checkpoint").exists() and _summary(out)["sessions"] == 2


@pytest.mark.parametrize(
    "argv",
    [
        ["run", "eld-mms", "--tau", "0.3"],
        ["run", "eld-mms", "--tau", "1e300"],
    ],
)
def test_input_refused_after_the_session_started_leaves_nothing(tmp_path, capsys, argv):
    """The ELD run checks tau against T and rho/d0 after the session took OUT/checkpoint/.lock:
    that left OUT/checkpoint/.lock behind."""
    out = tmp_path / "run"
    code, err = _code_err(capsys, *argv, "--out", out, "--quiet", "--no-plots")
    assert code == 2 and err.startswith("rothe: error: --tau: got ")
    assert not out.exists()


def test_sweep_continue_keeps_completed_runs_without_their_checkpoints(tmp_path, capsys):
    out = tmp_path / "sweep"
    argv = [
        "sweep",
        "run",
        "ris-1d",
        "--param",
        "tol=1e-2,1e-3",
        "--no-plots",
        "--workers",
        "1",
        "--quiet",
        "--out",
        out,
    ]
    assert _code_err(capsys, *argv)[0] == 0
    assert not list(out.glob("*/checkpoint"))
    stamps = {p: p.stat().st_mtime_ns for p in out.glob("*/summary.json")}
    (out / "tol=1e-3" / "summary.json").unlink()  # as if this run had never finished
    assert _code_err(capsys, *argv, "--continue")[0] == 0
    assert (out / "tol=1e-2" / "summary.json").stat().st_mtime_ns == stamps[
        out / "tol=1e-2" / "summary.json"
    ]  # not run again
    rows = {r["run"]: r for r in json.loads((out / "sweep.json").read_text())["rows"]}
    assert [rows[k]["status"] for k in ("tol=1e-2", "tol=1e-3")] == ["completed"] * 2
    assert "argv" not in rows["tol=1e-2"] and rows["tol=1e-2"]["accepted_steps"] > 0
    # another command line in the same folder is not mistaken for the completed run
    assert _code_err(capsys, *argv[:-2], "--tau", "0.05", "--out", out, "--continue")[0] == 0
    assert (out / "tol=1e-2" / "summary.json").stat().st_mtime_ns != stamps[
        out / "tol=1e-2" / "summary.json"
    ]


def test_checkpoint_file_is_gone_but_a_removed_checkpoint_is_never_half_removed(tmp_path):
    """The removal renames the directory to a hidden temporary first."""
    d = tmp_path / "checkpoint"
    d.mkdir()
    (d / MAIN).write_bytes(b"x")
    (d / "traj0-000001.npz").write_bytes(b"y")
    _remove_checkpoint(d)
    assert list(tmp_path.iterdir()) == []
