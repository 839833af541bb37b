"""The command line and the signals of issue 21, in child processes: a dropped SSH session
(the controlling terminal hangs up: SIGHUP) stops a run like SIGTERM -- results so far, a
checkpoint, exit status 129 -- although the terminal it was writing to is gone; SIGQUIT stops
with 131; SIGUSR1 writes a checkpoint and the run completes; SIGINT during a long factorization
ends the process at once."""

from __future__ import annotations

import fcntl
import json
import os
import pty
import signal
import subprocess
import sys
import termios
import time
from pathlib import Path

import pytest

import rothe
from rothe.io.checkpoint import MAIN, load_checkpoint

RUN = [
    sys.executable,
    "-m",
    "rothe.cli.main",
    "run",
    "ris-2d",
    "--n",
    "24",
    "--control",
    "regime",
    "--tol",
    "1e-5",
    "--no-plots",
    "--checkpoint-every",
    "0.5",
    "--progress-every",
    "0.2",
]


def _wait_for_progress(out: Path, proc, accepted: int = 20, timeout: float = 120.0) -> None:
    """Until a checkpoint records ``accepted`` steps (the run is well under way)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end and proc.poll() is None:
        try:
            if load_checkpoint(out, header_only=True).where.get("accepted_steps", 0) >= accepted:
                return
        except Exception:  # noqa: BLE001 - not written yet, or being replaced
            pass
        time.sleep(0.1)
    raise AssertionError(f"no progress (exit {proc.poll()})")


def _terminal_session():
    """preexec_fn: a new session whose controlling terminal is the child's stdin (a pty), as
    a login shell's job in an SSH session has."""
    os.setsid()
    fcntl.ioctl(0, termios.TIOCSCTTY, 0)


def test_a_dropped_terminal_stops_the_run_like_sigterm(tmp_path):
    out = tmp_path / "run"
    master, slave = pty.openpty()
    proc = subprocess.Popen(
        RUN + ["--out", str(out)],
        stdin=slave,
        stdout=slave,
        stderr=slave,
        preexec_fn=_terminal_session,
        cwd=tmp_path,
    )
    os.close(slave)
    try:
        _wait_for_progress(out, proc)
        os.close(master)  # the SSH connection drops: the kernel hangs the terminal up
        master = None
        assert proc.wait(timeout=120) == 129
    finally:
        if master is not None:
            os.close(master)
        if proc.poll() is None:
            proc.kill()
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "interrupted" and s["signal"] == "SIGHUP"
    assert s["where"]["accepted_steps"] == s["accepted_steps"] > 0
    ckpt = load_checkpoint(out)
    assert ckpt.status == "interrupted" and ckpt.where["signal"] == "SIGHUP"
    done = subprocess.run(
        [sys.executable, "-m", "rothe.cli.main", "resume", str(out), "--quiet"],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr
    assert json.loads((out / "summary.json").read_text())["sessions"] == 2


@pytest.mark.parametrize("sig, status", [(signal.SIGQUIT, 131), (signal.SIGHUP, 129)])
def test_quit_and_hangup_of_a_logged_run(tmp_path, sig, status):
    out = tmp_path / "run"
    with open(tmp_path / "log", "w") as log:
        proc = subprocess.Popen(RUN + ["--out", str(out)], stdout=log, stderr=log, cwd=tmp_path)
        try:
            _wait_for_progress(out, proc)
            proc.send_signal(sig)
            assert proc.wait(timeout=120) == status
        finally:
            if proc.poll() is None:
                proc.kill()
    name = signal.Signals(sig).name
    lines = (tmp_path / "log").read_text().splitlines()
    assert lines[-1].startswith(f"rothe: interrupted by {name} after ")  # the log is kept
    assert lines[-1].endswith(f"continue with: rothe resume {out}")
    assert json.loads((out / "summary.json").read_text())["signal"] == name


def test_sigusr1_writes_a_checkpoint_and_the_run_completes(tmp_path):
    out = tmp_path / "run"
    argv = [
        sys.executable,
        "-m",
        "rothe.cli.main",
        "run",
        "ris-2d",
        "--n",
        "16",
        "--control",
        "regime",
        "--tol",
        "1e-4",
        "--no-plots",
        "--checkpoint-every",
        "1000",
    ]
    with open(tmp_path / "log", "w") as log:
        proc = subprocess.Popen(
            argv + ["--out", str(out), "--keep-checkpoint"], stdout=log, stderr=log, cwd=tmp_path
        )
        try:
            end = time.monotonic() + 120
            while not (out / "checkpoint" / MAIN).exists() and time.monotonic() < end:
                time.sleep(0.1)  # the checkpoint written at the start
            time.sleep(0.5)
            first = load_checkpoint(out, header_only=True).sequence
            proc.send_signal(signal.SIGUSR1)
            assert proc.wait(timeout=600) == 0
        finally:
            if proc.poll() is None:
                proc.kill()
    text = (tmp_path / "log").read_text()
    assert "rothe: SIGUSR1: checkpoint written to " in text and "the run goes on" in text
    ckpt = load_checkpoint(out, header_only=True)
    assert ckpt.status == "completed" and ckpt.sequence == first + 2  # SIGUSR1, end


SLOW_FACTORIZATION = """
import os, signal, sys, time
import scipy.sparse.linalg as spla
from rothe.cli.main import main
real, calls = spla.splu, [0]
def splu(*args, **kwargs):  # the third factorization takes 60 s (and releases the GIL)
    calls[0] += 1
    if calls[0] == 3:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(60)
    return real(*args, **kwargs)
spla.splu = splu
sys.exit(main(sys.argv[1:]))
"""


def test_a_signal_during_a_long_factorization_ends_the_process_at_once(tmp_path):
    """Issue 21: SIGINT while a step's sparse LU runs (25 s at 17k dofs of ris-3d) abandons the
    step at once (the factorization runs in a worker thread, rothe.stepping.interrupt.call); the
    process writes its results and ends with 130 without waiting for the factorization, and
    without the interpreter's failing finalization around the still running worker."""
    out = tmp_path / "run"
    argv = ["run", "ris-2d", "--n", "6", "--tol", "1e-3", "--linear-solver", "direct"]
    t0 = time.monotonic()
    src = str(Path(rothe.__file__).resolve().parents[1])  # this tree, whatever the cwd
    proc = subprocess.run(
        [sys.executable, "-c", SLOW_FACTORIZATION, *argv, "--no-plots", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
        env=dict(os.environ, PYTHONPATH=src),
    )
    seconds = time.monotonic() - t0
    assert proc.returncode == 130, proc.stderr
    assert seconds < 45 and "Exception ignored" not in proc.stderr, proc.stderr
    (line,) = [ln for ln in proc.stderr.splitlines() if ln.startswith("rothe: interrupted")]
    assert "; the step under way was abandoned)" in line
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "interrupted" and s["where"]["abandoned_step"] is True
    assert load_checkpoint(out).status == "interrupted"
