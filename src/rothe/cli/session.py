"""One ``rothe run`` command as a session: output directory, checkpoint, signals, results.

What a user sees in ``--out DIR`` (default ``rothe-out/<example>``):

- ``DIR/checkpoint/``: the run's checkpoint, written when the run starts, every
  ``--checkpoint-every`` seconds (default 60) and when it stops for any reason;
  ``rothe resume DIR`` continues from it (or ``rothe run ... --resume DIR``). Once a run has
  completed and its results are committed, the checkpoint is removed: it would only duplicate
  ``trajectory.npz`` (22 MB for ris-2d, hundreds of MB for adaptive runs; a sweep keeps one per
  run). ``--keep-checkpoint`` keeps it. A failed or interrupted run, or one whose results could
  not be written, always keeps it.
- ``DIR/summary.json``, ``DIR/trajectory.npz``, figures, ParaView files: the result, committed
  together when the run ends (:mod:`rothe.io.outputs`), whatever its status: ``completed``,
  ``failed`` (exit 1) or ``interrupted`` (SIGINT: exit 130, SIGTERM: exit 143; the trajectory
  so far, ``where`` it stopped and how to resume).
- An earlier result is never destroyed by a run that does not complete: if DIR holds the
  completed result of an earlier run, a failed or interrupted run writes its partial result to
  ``DIR/incomplete/`` and leaves the earlier one in place; the run that then completes (e.g.
  after ``rothe resume DIR``) replaces it and removes ``incomplete/``.
- A new run is refused if DIR holds the checkpoint of an unfinished (interrupted or killed)
  run -- resume it, or pass ``--discard-checkpoint`` to start over -- and if another rothe
  process is running in DIR. ``--out`` is checked for writability before the first step.
- A command without the run options (``--checkpoint-every``, ``--resume``,
  ``--discard-checkpoint``) goes through the same sequence; its interrupted run writes its
  results so far and names no ``rothe resume``.
"""

from __future__ import annotations

import contextlib
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

from ..errors import RunFailed, RunInterrupted, check_positive, fail
from ..io.atomic import check_writable, remove_stale_temporaries, temporary_name
from ..io.checkpoint import (
    CHECKPOINT_SUBDIR,
    MAIN,
    CheckpointError,
    CheckpointOptions,
    DirectoryLock,
    changed_keys,
    load_checkpoint,
    normalized,
)
from ..io.outputs import OutputSet, read_summary
from ..stepping import interrupt
from .common import float_option, out_path, progress_of, write_summary

#: options that change where and how results are shown, never the results themselves
PRESENTATION = (
    "out",
    "no_plots",
    "quiet",
    "resume",
    "checkpoint_every",
    "progress_every",
    "discard_checkpoint",
    "keep_checkpoint",
)
#: argparse bookkeeping
_INTERNAL = ("_command", "_options", "_argv", "_given", "verb", "name")
#: options stripped from the recorded command line (``rothe resume`` supplies them)
_STRIP_WITH_VALUE = ("--out", "--resume")
_STRIP_FLAGS = ("--discard-checkpoint",)
INCOMPLETE = "incomplete"
#: --checkpoint-every's default, and the interval of a command without the run options
DEFAULT_CHECKPOINT_EVERY = 60.0


def add_run_options(parser) -> None:
    """``--checkpoint-every``, ``--resume`` and ``--discard-checkpoint`` of the run commands."""
    float_option(
        parser,
        "--checkpoint-every",
        default=DEFAULT_CHECKPOINT_EVERY,
        metavar="SECONDS",
        help="write a checkpoint to OUT/checkpoint every SECONDS of wall time "
        "(default 60; also at the start, when stopped, and at the end)",
    )
    parser.add_argument(
        "--resume",
        default=None,
        metavar="DIR",
        help="continue the run whose checkpoint is in DIR (the same command "
        "line; see also 'rothe resume DIR')",
    )
    parser.add_argument(
        "--discard-checkpoint",
        action="store_true",
        help="start over even if OUT holds the checkpoint of an unfinished run (it is replaced)",
    )
    parser.add_argument(
        "--keep-checkpoint",
        action="store_true",
        help="keep OUT/checkpoint after the run completed (by default it is "
        "removed once the results are written: it duplicates "
        "trajectory.npz)",
    )


def result_arguments(args) -> dict:
    """The parsed options that can change the results (everything but presentation)."""
    skip = set(PRESENTATION) | set(_INTERNAL)
    return normalized({k: v for k, v in sorted(vars(args).items()) if k not in skip})


def strip_argv(argv: list[str]) -> list[str]:
    """The command line without --out/--resume/--discard-checkpoint (``rothe resume`` adds
    its own)."""
    out, i = [], 0
    while i < len(argv):
        tok = argv[i]
        name = tok.split("=", 1)[0]
        if name in _STRIP_WITH_VALUE:
            i += 1 if "=" in tok else 2
            continue
        if tok in _STRIP_FLAGS:
            i += 1
            continue
        out.append(tok)
        i += 1
    return out


def _option(key: str) -> str:
    return "--" + key.replace("_", "-")


def _fmt(value) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, list):
        return ",".join(_fmt(v) for v in value)
    return "(not given)" if value is None else str(value)


@dataclass
class Outcome:
    """How a run ended: ``status`` completed | failed | interrupted, with its result/error."""

    status: str
    result: object = None
    error: BaseException | None = None


class RunSession:
    """Output directory, checkpoint and signal handling of one run command."""

    def __init__(self, args, name: str, argv: list[str] | None = None):
        self.args = args
        self.name = name
        self.command = f"{args.verb} {args.name}"
        self.out = out_path(args, name)
        self.resume = None
        if getattr(args, "resume", None) is not None:
            given = Path(args.resume)
            if args.out is not None and _resolved(self.out) != _resolved(_run_dir(given)):
                raise fail(
                    "--out",
                    str(self.out),
                    f"must be the resumed directory {_run_dir(given)} (or omitted)",
                )
            self.resume = self._load_resumable(given)
            self.out = _run_dir(given)
        self._made_out = not self.out.exists()  # removed again if the run writes nothing
        check_writable(self.out, "--out")
        self.checkpoint_dir = self.out / CHECKPOINT_SUBDIR
        self._lock = DirectoryLock(self.checkpoint_dir)
        self._lock.acquire()
        try:
            remove_stale_temporaries(self.out)
            if self.resume is None:
                self._refuse_unfinished()
        except BaseException:
            self._lock.release()
            raise
        if argv is None:
            argv = getattr(args, "_argv", None)
        argv = list(sys.argv[1:] if argv is None else argv)
        self.checkpoint = CheckpointOptions(
            self.checkpoint_dir,
            every_seconds=check_positive(
                "--checkpoint-every", getattr(args, "checkpoint_every", DEFAULT_CHECKPOINT_EVERY)
            ),
            record={
                "command": self.command,
                "argv": strip_argv(argv),
                "args": result_arguments(args),
            },
        )
        self.progress = progress_of(args)
        self._guard = interrupt.interruptible(hard_second=True)

    # -- checks before the first step -----------------------------------------------------------
    def _load_resumable(self, given: Path):
        try:
            ckpt = load_checkpoint(given)
        except CheckpointError as exc:
            raise CheckpointError(f"--resume {exc}") from None
        ckpt.require_resumable()
        rec = ckpt.record
        if rec.get("command") != self.command:
            raise CheckpointError(
                f"--resume {given}: the checkpoint is of 'rothe "
                f"{rec.get('command')}', not 'rothe {self.command}'"
            )
        old, new = rec.get("args", {}), result_arguments(self.args)
        diff = [
            f"{_option(k)} {_fmt(new.get(k))} (checkpoint: {_fmt(old.get(k))})"
            for k in changed_keys(old, new)
        ]
        if diff:
            raise CheckpointError(
                f"--resume {given}: the command line differs from the "
                f"checkpoint's: {'; '.join(diff)}"
            )
        return ckpt

    def _refuse_unfinished(self) -> None:
        if not (self.checkpoint_dir / MAIN).is_file():
            return
        try:
            ckpt = load_checkpoint(self.checkpoint_dir, check_version=False, header_only=True)
        except CheckpointError:
            return  # unreadable: nothing that could be resumed is lost by replacing it
        discard = getattr(self.args, "discard_checkpoint", False)
        if ckpt.status in ("running", "interrupted") and not discard:
            raise fail(
                "--out",
                str(self.out),
                f"holds the checkpoint of an unfinished run ({ckpt.status}, "
                f"{ckpt.describe_where()}): continue it with 'rothe resume {self.out}' "
                "or start over with --discard-checkpoint",
            )

    # -- running --------------------------------------------------------------------------------
    def __enter__(self):
        self._guard.__enter__()
        return self

    def __exit__(self, *exc):
        self._guard.__exit__(*exc)
        self._lock.release()
        if self._made_out:  # e.g. input refused by the run: leave no empty --out behind
            with contextlib.suppress(OSError):
                self.out.rmdir()
        return False

    @property
    def keeps_checkpoint(self) -> bool:
        return bool(getattr(self.args, "keep_checkpoint", False))

    def run(self, fn) -> Outcome:
        """``fn(checkpoint=..., resume=..., progress=...)`` -> result; catches the stops."""
        try:
            return Outcome(
                "completed",
                fn(checkpoint=self.checkpoint, resume=self.resume, progress=self.progress),
            )
        except RunFailed as exc:
            return Outcome("failed", exc.trajectory, exc)
        except RunInterrupted as exc:
            return Outcome("interrupted", exc.trajectory, exc)

    @property
    def already_completed(self) -> bool:
        """Resuming a run whose results were already committed: nothing to do."""
        if self.resume is None or self.resume.status != "completed":
            return False
        s = read_summary(self.out) or {}
        return s.get("run_id") == self.resume.run_id and s.get("status") == "completed"

    def results_dir(self, status: str) -> Path:
        """Where this run's result goes (see the module docstring)."""
        if status == "completed":
            return self.out
        earlier = read_summary(self.out) or {}
        if earlier.get("status") == "completed" and earlier.get("run_id") != self.run_id:
            return self.out / INCOMPLETE
        return self.out

    @property
    def run_id(self) -> str | None:
        try:
            return load_checkpoint(
                self.checkpoint_dir, check_version=False, header_only=True
            ).run_id
        except CheckpointError:
            return None

    def outputs(self, status: str) -> OutputSet:
        """The set of output files of this run, committed together into :meth:`results_dir`."""
        return OutputSet(self.results_dir(status))

    def annotate(self, summary: dict, outcome: Outcome) -> dict:
        """status, where it stopped, checkpoint and resume hints, sessions and wall time."""
        try:
            ckpt = load_checkpoint(self.checkpoint_dir, check_version=False, header_only=True)
        except CheckpointError:
            ckpt = None
        summary["status"] = outcome.status
        # the command line, so that a completed run is recognized without its checkpoint
        # (rothe resume, rothe sweep --continue)
        summary["command"] = self.checkpoint.record["command"]
        summary["argv"] = self.checkpoint.record["argv"]
        if ckpt is not None:
            summary["run_id"] = ckpt.run_id
            summary["sessions"] = ckpt.sessions
            kept = outcome.status != "completed" or self.keeps_checkpoint
            # None: removed when the run completed (the key stays: tables keep their columns)
            summary["checkpoint"] = str(self.checkpoint_dir) if kept else None
            if ckpt.sessions > 1:
                summary["wall_time_note"] = (
                    f"wall_time_s sums {ckpt.sessions} sessions (the run was resumed)"
                )
        exc = outcome.error
        if isinstance(exc, RunInterrupted):
            summary["signal"] = interrupt.signal_name(exc.signum)
            summary["where"] = exc.where
            if ckpt is not None:  # (a run without checkpoints cannot be resumed)
                summary["resume"] = f"rothe resume {self.out}"
        elif isinstance(exc, RunFailed):
            summary["failure"] = str(exc)
            summary["where"] = exc.where
        return summary

    def finish(self, outcome: Outcome, results: Path) -> int:
        """After the results are committed: clean up, tell the user, return the exit status."""
        if outcome.status == "completed":
            inc = self.out / INCOMPLETE
            if inc.is_dir():
                shutil.rmtree(inc, ignore_errors=True)
            if not self.keeps_checkpoint:  # the results are committed: it only duplicates them
                _remove_checkpoint(self.checkpoint_dir)
            return 0
        exc = outcome.error
        if isinstance(exc, RunInterrupted):
            where = (
                ""
                if results == self.out
                else (f" (the earlier completed run stays in {self.out}/)")
            )
            resume = (
                f"; continue with: rothe resume {self.out}"
                if (self.checkpoint_dir / MAIN).is_file()
                else " (this run writes no checkpoint: run it again)"
            )
            print(f"rothe: {exc}; results so far in {results}/{where}{resume}", file=sys.stderr)
            return exc.exit_status
        raise exc


def run_sequence(args, name: str, run, write, *, prepare=None, completed=None, session=None):
    """The one run sequence of every ``rothe run`` command: run (or resume) -> stage -> write
    -> annotate -> summary last -> finish.

    ``run(checkpoint=, resume=, progress=)`` runs the problem (:meth:`RunSession.run`);
    ``write(stage, outcome) -> summary | None`` writes the result into the staging directory
    (also of a failed or interrupted run with a trajectory), returning the summary, which is
    annotated (:meth:`RunSession.annotate`) and written last; ``prepare(session)`` runs first
    inside the session (e.g. opens a stream writer); ``completed()`` after a completed run's
    results are committed; ``session``: the :class:`RunSession` the caller built (rank 0 of
    ``eld-beam --backend petsc``, which tells the other processes whether it could), by default
    ``RunSession(args, name)``. Returns ``(exit status, outcome, results directory, summary)``;
    ``outcome`` is None when a resumed run had already completed (nothing is done).
    """
    if session is None:
        session = RunSession(args, name)
    summary = None
    with session:
        if session.already_completed:
            print(
                f"rothe: {session.out}: the run already completed; its results are there",
                file=sys.stderr,
            )
            return 0, None, session.out, None
        if prepare is not None:
            prepare(session)
        outcome = session.run(run)
        results = session.results_dir(outcome.status)
        if outcome.status == "completed" or outcome.result is not None:
            with session.outputs(outcome.status) as stage:
                summary = write(stage, outcome)
                if summary is not None:
                    session.annotate(summary, outcome)
                    write_summary(stage, summary)
        code = session.finish(outcome, results)
        if outcome.status == "completed" and completed is not None:
            completed()
    return code, outcome, results, summary


def _remove_checkpoint(directory: Path) -> None:
    """Remove a checkpoint directory at once for a reader: renamed to a hidden temporary name
    (atomic), then deleted; a kill in between leaves the temporary, which the next run in OUT
    removes (:func:`~rothe.io.atomic.remove_stale_temporaries`), never a checkpoint whose
    segments are half gone."""
    if not directory.is_dir():
        return
    doomed = temporary_name(directory)
    try:
        directory.rename(doomed)
    except OSError:
        doomed = directory
    shutil.rmtree(doomed, ignore_errors=True)


def _run_dir(path: Path) -> Path:
    """The run's output directory for a path given to --resume / rothe resume."""
    path = Path(path)
    if path.name == CHECKPOINT_SUBDIR and (path / MAIN).exists():
        return path.parent
    return path


def _resolved(path: Path) -> Path:
    with contextlib.suppress(OSError):
        return path.resolve()
    return path
