"""``rothe`` command lines as tasks of :mod:`rothe.parallel`: what sweeps, compares and studies
hand to an executor (in this process or on Dask workers).
"""

from __future__ import annotations

import json
import signal
from pathlib import Path

from ..errors import RunFailed, RunInterrupted
from ..parallel.tasks import Task, TaskFailed
from ..stepping import interrupt
from .main import build_parser, execute, parse_command


def run_command(argv: list[str], out: str | None = None) -> dict | None:
    """Parse and execute one ``rothe`` command line; return the summary.json it wrote (or None).

    Exceptions propagate (classified by :func:`execute_task`); a run that fails midway still
    hands back the summary it wrote (status ``failed``). A run stopped by a stop signal (its
    session wrote its checkpoint and results so far and returned 128 + signal) raises
    :class:`~rothe.errors.RunInterrupted`: the signal was meant for the whole sweep, whose
    executor stops instead of starting the next run. Only a summary this run wrote counts:
    ``out/summary.json``, or ``out/incomplete/summary.json`` where a run that does not complete
    leaves the completed result of an earlier run in place (:mod:`rothe.cli.session`).
    """

    args = parse_command(build_parser(), list(argv))
    paths = (
        [Path(out) / "summary.json", Path(out) / "incomplete" / "summary.json"]
        if out is not None
        else []
    )

    def stamps():
        return [p.stat().st_mtime_ns if p.is_file() else None for p in paths]

    before = stamps()

    def summary():
        for path, old, new in zip(paths, before, stamps(), strict=True):
            if new is not None and new != old:  # written by this run
                return json.loads(path.read_text())
        return None

    try:
        code = execute(args)
    except RunFailed as exc:
        raise TaskFailed(str(exc), value=summary()) from exc
    if code - 128 in interrupt.SIGNALS:  # SIGINT, SIGTERM, SIGHUP, SIGQUIT
        raise RunInterrupted(f"interrupted by {signal.Signals(code - 128).name}", signum=code - 128)
    if code != 0:
        raise TaskFailed(f"exit status {code}", value=summary())
    done = summary()
    if done is None and getattr(args, "resume", None) is not None and paths:
        # resumed a run that had already completed: nothing ran, its summary is its result
        try:
            earlier = json.loads(paths[0].read_text())
        except (OSError, ValueError):
            earlier = None
        if isinstance(earlier, dict) and earlier.get("status") == "completed":
            done = earlier
    return done


def cli_task(key: str, argv: list[str], out: str | None = None, cost: float = 1.0) -> Task:
    """A task running ``rothe <argv>``; ``out`` is the run's output folder (its summary.json
    is the task's value)."""
    return Task(key, run_command, {"argv": [str(a) for a in argv], "out": out}, cost)
