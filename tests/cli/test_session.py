"""The run session (rothe.cli.session), issue 21: a completed run removes its checkpoint unless
``--keep-checkpoint``; an interrupted one keeps it; a refused input leaves no ``--out`` and no
``.lock``; ``--continue`` and ``rothe resume`` recognize a completed run without its checkpoint."""

from __future__ import annotations

import json
import os
import signal

import pytest

from rothe.cli.main import main
from rothe.io.checkpoint import MAIN, load_checkpoint
from rothe.ris.stepper import RISStepper

RIS1D = ["run", "ris-1d", "--tol", "1e-3", "--no-plots", "--quiet"]


@pytest.fixture
def signal_at_attempt(monkeypatch):
    """``signal_at_attempt(cls, k, sig)``: the k-th ``step`` call from now first sends ``sig``
    to this process (as a Ctrl-C or a kill would arrive during that step)."""

    def install(cls, k, sig=signal.SIGINT):
        original = cls.__dict__.get("_issue21_step", cls.step)
        monkeypatch.setattr(cls, "_issue21_step", original, raising=False)
        calls = [0]

        def step(self, state, tau, s_end=None):
            calls[0] += 1
            if calls[0] == k:
                os.kill(os.getpid(), sig)
            return original(self, state, tau, s_end)

        monkeypatch.setattr(cls, "step", step)

    return install


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err


def _summary(d):
    return json.loads((d / "summary.json").read_text())


def test_a_completed_run_removes_its_checkpoint_and_says_how_to_keep_it(tmp_path, capsys):
    out = tmp_path / "run"
    assert _run(capsys, *RIS1D, "--out", out) == (0, "")
    assert sorted(p.name for p in out.iterdir()) == ["summary.json", "trajectory.npz"]
    s = _summary(out)
    assert s["status"] == "completed" and s["checkpoint"] is None
    assert s["command"] == "run ris-1d" and s["argv"] == RIS1D
    # resuming it does nothing, without a checkpoint too
    code, err = _run(capsys, "resume", out)
    assert (
        code == 0
        and err.strip() == f"rothe: {out}: the run already completed; its results are there"
    )


def test_keep_checkpoint_keeps_it_and_does_not_change_the_results(tmp_path, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    assert _run(capsys, *RIS1D, "--out", a)[0] == 0
    assert _run(capsys, *RIS1D, "--keep-checkpoint", "--out", b)[0] == 0
    assert load_checkpoint(b).status == "completed"
    assert _summary(b)["checkpoint"] == str(b / "checkpoint")
    assert (a / "trajectory.npz").read_bytes() != b""  # both wrote results
    sa, sb = _summary(a), _summary(b)
    for key in ("accepted_steps", "rejected_steps", "sum_residual", "energy_final"):
        assert sa[key] == sb[key]


def test_an_interrupted_run_keeps_its_checkpoint(tmp_path, capsys, signal_at_attempt):
    out = tmp_path / "run"
    signal_at_attempt(RISStepper, 40, signal.SIGTERM)
    assert _run(capsys, *RIS1D, "--out", out)[0] == 143
    assert load_checkpoint(out).status == "interrupted"
    assert _summary(out)["checkpoint"] == str(out / "checkpoint")
    signal_at_attempt(RISStepper, 10**9)
    assert _run(capsys, "resume", out, "--quiet") == (0, "")
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
    code, err = _run(capsys, *argv, "--out", out, "--quiet", "--no-plots")
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
    assert _run(capsys, *argv)[0] == 0
    assert not list(out.glob("*/checkpoint"))
    stamps = {p: p.stat().st_mtime_ns for p in out.glob("*/summary.json")}
    (out / "tol=1e-3" / "summary.json").unlink()  # as if this run had never finished
    assert _run(capsys, *argv, "--continue")[0] == 0
    assert (out / "tol=1e-2" / "summary.json").stat().st_mtime_ns == stamps[
        out / "tol=1e-2" / "summary.json"
    ]  # not run again
    rows = {r["run"]: r for r in json.loads((out / "sweep.json").read_text())["rows"]}
    assert [rows[k]["status"] for k in ("tol=1e-2", "tol=1e-3")] == ["completed"] * 2
    assert "argv" not in rows["tol=1e-2"] and rows["tol=1e-2"]["accepted_steps"] > 0
    # another command line in the same folder is not mistaken for the completed run
    assert _run(capsys, *argv[:-2], "--tau", "0.05", "--out", out, "--continue")[0] == 0
    assert (out / "tol=1e-2" / "summary.json").stat().st_mtime_ns != stamps[
        out / "tol=1e-2" / "summary.json"
    ]


def test_checkpoint_file_is_gone_but_a_removed_checkpoint_is_never_half_removed(tmp_path):
    """The removal renames the directory to a hidden temporary first."""
    from rothe.cli.session import _remove_checkpoint

    d = tmp_path / "checkpoint"
    d.mkdir()
    (d / MAIN).write_bytes(b"x")
    (d / "traj0-000001.npz").write_bytes(b"y")
    _remove_checkpoint(d)
    assert list(tmp_path.iterdir()) == []
