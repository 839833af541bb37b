"""Seconds from a stop signal to the end of the process, on runs whose single steps take seconds
(issue 21, item 3: a Ctrl-C used to wait for the end of the step, up to 157 s).

Each case runs as a separate ``rothe`` process with plain progress lines every 0.1 s on stderr,
so that the end of every loop iteration (step, decision, adapt step) shows as a new step number.
Once an iteration took at least the case's seconds (``--min-step`` for all), the signal is sent
``--at`` (a fraction) of that duration into the next one, and the seconds until the loop stopped
and until the process exited are measured::

    PYTHONPATH=src python benchmarks/interrupt_latency.py [--only TEXT] [--src DIR]
        [--min-step SECONDS] [--at FRACTION] [--signal INT|TERM] [--repeat N] [--max-wait S]

Prints one line per measurement: the case, the seconds of the iteration before the signal, the
seconds from the signal until the loop stopped (the progress line's ``stopped at`` line) and
until the process exited (after writing the results and the checkpoint), the exit status, the
step attempt and dofs where it stopped, and whether the run abandoned the step under way
(``where.abandoned_step`` in summary.json). ``--src`` runs another source tree (e.g.
the ``src`` of an older commit, for the numbers before the change). Run it alone on the
machine: the numbers are wall-clock seconds.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

RIS_3D = ["run", "ris-3d", "--n", "2", "--adapt-space"]
#: (name, argv, seconds of a long iteration): coarse runs whose later steps take seconds each
#: (ris-3d: ~20 s to the first 3 s iteration, ~40 s to the first 10 s one; ris-front: ~20 min)
CASES = [
    ("ris-3d --n 2 --adapt-space", RIS_3D, 3.0),
    ("ris-3d --n 2 --adapt-space", RIS_3D, 10.0),
    ("ris-front --adapt-space", ["run", "ris-front", "--adapt-space"], 3.0),
    (
        "eld-beam --adapt-space (40k)",
        ["run", "eld-beam", "--adapt-space", "--space-tol", "1e-3", "--max-dofs", "40000"],
        3.0,
    ),
]

STEP = re.compile(r"^rothe: step (\d+) ")


def measure(argv, src: Path, min_step: float, at: float, sig: int, max_wait: float) -> dict:
    """Run ``rothe *argv`` until an iteration took ``min_step`` seconds, signal ``at`` of that
    into the next one, and time the exit."""
    out = Path(tempfile.mkdtemp(prefix="rothe-latency-"))
    env = dict(os.environ, PYTHONPATH=str(src))
    cmd = [sys.executable, "-m", "rothe.cli.main", *argv, "--out", str(out / "run")]
    cmd += ["--no-plots", "--progress-every", "0.1"]
    proc = subprocess.Popen(
        cmd,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    changes: list[tuple[float, int]] = []  # (instant, step number) where the number changed
    tail: list[str] = []
    stopped: list[float] = []  # when the loop stopped (the progress line's last line)

    def read():
        for line in proc.stderr:
            tail[:] = (tail + [line.rstrip()])[-3:]
            if line.startswith("rothe: stopped at step"):
                stopped.append(time.monotonic())
            m = STEP.match(line)
            if m and (not changes or int(m.group(1)) != changes[-1][1]):
                changes.append((time.monotonic(), int(m.group(1))))

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    start = time.monotonic()
    sent = None
    step_seconds = None
    try:
        while proc.poll() is None and time.monotonic() - start < max_wait:
            time.sleep(0.02)
            if len(changes) < 2:
                continue
            (t1, _), (t2, n2) = changes[-2], changes[-1]
            if t2 - t1 >= min_step and time.monotonic() - t2 >= at * (t2 - t1):
                step_seconds, at_step = t2 - t1, n2 + 1
                sent = time.monotonic()
                os.kill(proc.pid, sig)
                break
        if sent is None:
            proc.kill()
            proc.wait()
            return {"error": f"no iteration of {min_step:g} s within {max_wait:g} s"}
        status = proc.wait()
        latency = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        reader.join(timeout=5)
    summary = {}
    path = out / "run" / "summary.json"
    if path.exists():
        summary = json.loads(path.read_text())
    shutil.rmtree(out, ignore_errors=True)
    where = summary.get("where", {})
    return {
        "step_seconds": step_seconds,
        "latency": latency,
        "to_stop": stopped[0] - sent if stopped else float("nan"),
        "status": status,
        "attempt": at_step,
        "abandoned": bool(where.get("abandoned_step", False)),
        "accepted": where.get("accepted_steps"),
        "dofs": where.get("dofs"),
        "run_seconds": sent - start,
        "tail": tail[-1] if tail else "",
    }


def main(argv=None) -> int:
    """Measure every case (or those whose name contains ``--only``) and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="", help="cases whose name contains this text")
    ap.add_argument("--src", default=str(ROOT / "src"), help="source tree to run")
    ap.add_argument(
        "--min-step", type=float, default=None, help="seconds of a long iteration (all cases)"
    )
    ap.add_argument("--at", type=float, default=0.5, help="signal this share into the next one")
    ap.add_argument("--signal", default="INT", choices=("INT", "TERM"))
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--max-wait", type=float, default=1200.0, help="seconds to find a long step")
    args = ap.parse_args(argv)
    sig = getattr(signal, "SIG" + args.signal)
    print(f"source: {args.src}; SIG{args.signal} at {args.at:g} of the next iteration")
    print(
        f"{'case':30s} {'step s':>7s} {'signal->stop s':>14s} {'signal->exit s':>14s} "
        f"{'exit':>5s} {'attempt':>7s} {'dofs':>6s} {'abandoned':>9s}"
    )
    for name, case, min_step in CASES:
        if args.only not in name:
            continue
        min_step = args.min_step if args.min_step is not None else min_step
        for _ in range(args.repeat):
            r = measure(case, Path(args.src), min_step, args.at, sig, args.max_wait)
            if "error" in r:
                print(f"{name:30s} {r['error']}")
                continue
            print(
                f"{name:30s} {r['step_seconds']:7.1f} {r['to_stop']:14.1f} {r['latency']:14.1f} "
                f"{r['status']:5d} {r['attempt']:7d} {str(r['dofs']):>6s} "
                f"{str(r['abandoned']):>9s}",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
