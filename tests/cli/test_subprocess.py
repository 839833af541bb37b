"""Real processes: kill -9 at random instants, signals from outside, a second Ctrl-C, a full
disk (a file-size limit everywhere; a small tmpfs where we may mount one), a read-only --out."""

from __future__ import annotations

import contextlib
import json
import os
import random
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from rothe import Adaptive, run_ris
from rothe.io.checkpoint import MAIN, CheckpointError, load_checkpoint
from rothe.ris.examples import example_7_2
from rothe.ris.inner import InnerOptions

ROTHE = [sys.executable, "-m", "rothe.cli.main"]


def _files(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in d.iterdir() if p.is_file()}


def _readable(d: Path) -> None:
    """Every result file in d is complete: npz/json parse, the checkpoint loads."""
    for p in d.iterdir():
        if p.suffix == ".npz":
            with np.load(p, allow_pickle=False) as f:
                for k in f.files:
                    f[k]
        elif p.suffix == ".json":
            json.loads(p.read_text())
    if (d / "checkpoint" / MAIN).exists():
        load_checkpoint(d)


def test_kill_9_at_random_instants_then_resume_is_bit_identical(tmp_path):
    """Three SIGKILLs at random instants (fixed seed), each followed by `rothe resume`; the final
    trajectory equals the uninterrupted run's (computed here through the Python API)."""
    t0 = time.perf_counter()
    ref = run_ris(
        example_7_2(6), Adaptive(1e-3, tau=0.1), inner=InnerOptions(linear_solver="auto")
    ).trajectory
    duration = time.perf_counter() - t0 + 1.5  # + interpreter start and imports
    # A kill that lands after the last step (the measured duration is only an estimate on a
    # loaded machine) interrupts nothing that resume must redo; such kills do not count, and
    # the attempt is repeated with earlier kill instants until one lands inside the run.
    rng = random.Random(20261123)
    for attempt in range(4):
        out = tmp_path / f"run{attempt}"
        run = ROTHE + [
            "run",
            "ris-2d",
            "--n",
            "6",
            "--tol",
            "1e-3",
            "--out",
            str(out),
            "--quiet",
            "--no-plots",
            "--checkpoint-every",
            "0.05",
        ]
        resume = ROTHE + ["resume", str(out), "--quiet"]
        proc = subprocess.Popen(run, cwd=tmp_path)
        kills, inside, log, finished = 0, 0, [], False
        try:
            while kills < 3:
                delay = rng.uniform(0.3, 0.9) * duration * 0.5**attempt
                try:
                    proc.wait(timeout=delay)
                    break  # finished before the kill
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
                    kills += 1
                where, status = "no checkpoint yet", None
                with contextlib.suppress(CheckpointError):
                    ck = load_checkpoint(out)
                    where, status = ck.describe_where(), ck.status
                if status is None and _completed(out):
                    # killed after the summary was committed and the checkpoint removed: the
                    # run had finished (a fresh run would start its sessions anew)
                    log.append(f"kill after {delay:.2f} s: after the run completed")
                    finished = True
                    break
                inside += status not in (None, "completed")  # resume redoes steps
                log.append(f"kill after {delay:.2f} s: {where} ({status})")
                proc = subprocess.Popen(
                    resume if (out / "checkpoint" / MAIN).exists() else run, cwd=tmp_path
                )
            if not finished:
                assert proc.wait(timeout=300) == 0, log
        finally:
            if proc.poll() is None:
                proc.kill()
        if inside:
            break
    assert inside >= 1, log
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "completed" and s["sessions"] >= 2, log
    with np.load(out / "trajectory.npz") as f:
        for key in ref.keys():
            assert np.array_equal(ref[key], f[key]), (key, log)
        for key, value in ref.stats.untimed().items():
            assert f[f"stats_{key}"].item() == value, (key, log)
    assert not [p for p in out.iterdir() if p.name.startswith(".rothe-tmp")]


def _completed(out) -> bool:
    """Whether ``out`` holds the summary of a completed run."""
    path = out / "summary.json"
    return path.exists() and json.loads(path.read_text()).get("status") == "completed"


def _wait_for_line(proc, prefix: str, timeout: float = 120.0) -> str:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = proc.stderr.readline()
        if line.startswith(prefix):
            return line
        if not line and proc.poll() is not None:
            break
    raise AssertionError(f"no line starting with {prefix!r}")


def test_sigint_from_outside_then_a_second_one_exits_at_once(tmp_path):
    """In a log (stderr a pipe) the progress lines appear; the first SIGINT finishes the step and
    writes results; a second one right after ends the process at once. Whatever is on disk then
    is complete (atomic writes): every npz and json parses, the checkpoint loads."""
    out = tmp_path / "run"
    proc = subprocess.Popen(
        ROTHE
        + [
            "run",
            "ris-2d",
            "--n",
            "12",
            "--tol",
            "1e-5",
            "--out",
            str(out),
            "--no-plots",
            "--progress-every",
            "0.2",
        ],
        cwd=tmp_path,
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
    )
    try:
        line = _wait_for_line(proc, "rothe: step ")
        assert " t = " in line and "elapsed" in line and "\r" not in line
        proc.send_signal(signal.SIGINT)
        time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        t_second = time.monotonic()
        code = proc.wait(timeout=60)
        assert time.monotonic() - t_second < 10
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.stderr.close()
    # killed by the second SIGINT (-2), or the first one had already finished writing (130)
    assert code in (-signal.SIGINT, 130)
    _readable(out)
    assert load_checkpoint(out).status in ("running", "interrupted")


def test_sigterm_from_outside(tmp_path):
    out = tmp_path / "run"
    proc = subprocess.Popen(
        ROTHE
        + [
            "run",
            "ris-2d",
            "--n",
            "12",
            "--tol",
            "1e-5",
            "--out",
            str(out),
            "--no-plots",
            "--progress-every",
            "0.2",
        ],
        cwd=tmp_path,
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
    )
    try:
        _wait_for_line(proc, "rothe: step ")
        proc.send_signal(signal.SIGTERM)
        err = proc.stderr.read()
        code = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.stderr.close()
    assert code == 143, err
    assert "rothe: interrupted by SIGTERM after " in err
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "interrupted" and s["signal"] == "SIGTERM"
    assert load_checkpoint(out).status == "interrupted"
    _readable(out)


def _limit_file_size(limit: int):
    def apply():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails (EFBIG)

    return apply


def test_a_write_that_fails_midway_keeps_the_earlier_files_and_is_one_line(tmp_path):
    """A file-size limit makes every large write fail like a full disk does (EFBIG instead of
    ENOSPC), wherever it happens: npz, HDF5, checkpoint segments."""
    out = tmp_path / "run"
    small = ROTHE + [
        "run",
        "ris-2d",
        "--n",
        "3",
        "--tol",
        "1e-3",
        "--out",
        str(out),
        "--quiet",
        "--no-plots",
    ]
    subprocess.run(small, cwd=tmp_path, check=True)
    before = _files(out)
    big = ROTHE + [
        "run",
        "ris-2d",
        "--n",
        "8",
        "--tol",
        "1e-3",
        "--out",
        str(out),
        "--quiet",
        "--no-plots",
        "--checkpoint-every",
        "0.5",
    ]
    proc = subprocess.run(
        big,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
        preexec_fn=_limit_file_size(200_000),
    )
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr and len(lines) <= 2, proc.stderr
    assert lines[-1].startswith(f"rothe: error: cannot write {out}/")
    assert lines[-1].endswith(": File too large (files written before are unchanged)")
    assert _files(out) == before
    assert not [p for p in out.iterdir() if p.name.startswith(".rothe-tmp")]


@contextlib.contextmanager
def _tmpfs(path: Path, size: str):
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a tmpfs needs root")
    path.mkdir()
    r = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True
    )
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.decode().strip()}")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], capture_output=True)


def test_full_tmpfs_and_read_only_out(tmp_path):
    """The fuzzer's case: --out on a tiny tmpfs. No crash (h5py used to segfault here), one
    line naming the file, the earlier result intact; then read-only: refused before step 1."""
    with _tmpfs(tmp_path / "mnt", "1m") as mnt:
        out = mnt / "run"
        small = ROTHE + [
            "run",
            "ris-2d",
            "--n",
            "3",
            "--tol",
            "1e-3",
            "--out",
            str(out),
            "--quiet",
            "--no-plots",
        ]
        subprocess.run(small, cwd=tmp_path, check=True)
        before = _files(out)
        big = ROTHE + [
            "run",
            "ris-2d",
            "--n",
            "10",
            "--tol",
            "1e-3",
            "--out",
            str(out),
            "--quiet",
            "--no-plots",
        ]
        proc = subprocess.run(big, cwd=tmp_path, capture_output=True, text=True, timeout=600)
        assert proc.returncode == 1, proc.stderr
        assert "Traceback" not in proc.stderr and "Exception ignored" not in proc.stderr
        last = proc.stderr.strip().splitlines()[-1]
        assert last.startswith(f"rothe: error: cannot write {out}/")
        assert "No space left on device" in last
        assert _files(out) == before
        subprocess.run(["mount", "-o", "remount,ro", str(mnt)], check=True)
        t0 = time.perf_counter()
        proc = subprocess.run(
            ROTHE + ["run", "ris-2d", "--n", "40", "--out", str(mnt / "new"), "--quiet"],
            cwd=tmp_path,
            capture_output=True,
            text=True,
        )
        assert proc.returncode == 2
        assert proc.stderr.strip() == (
            f"rothe: error: --out: got '{mnt / 'new'}', cannot create or write files in this "
            "directory ([Errno 30] Read-only file system)"
        )
        assert time.perf_counter() - t0 < 30  # refused before the ~minute-long run
