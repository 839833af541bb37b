"""Options and output conventions shared by every command.

Every ``run``/``compare``/``study`` takes ``--out DIR``, ``--no-plots``, ``--quiet`` and
``--progress-every SECONDS``; results go to ``rothe-out/<name>/`` by default: ``summary.json``,
``trajectory.npz`` and PNG figures (plus ParaView files where there is a mesh). Every file is
written atomically (:mod:`rothe.io.atomic`); the ``run`` commands commit their files together
(:mod:`rothe.cli.session`, :mod:`rothe.io.outputs`).
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import sys
from pathlib import Path

import numpy as np

from ..errors import RotheInputError, check_int, check_positive, fail, got, integer_allowed
from ..io.atomic import TMP_PREFIX, atomic_write_text, check_writable
from ..parallel.executor import INSTALL_HINT, Executor, check_workers, dask_available
from ..stepping.progress import ProgressOptions


def add_output_options(parser, name: str) -> None:
    """--out (default rothe-out/<name>), --no-plots, --quiet and --progress-every."""
    parser.add_argument("--out", default=None, help=f"output directory (default rothe-out/{name})")
    parser.add_argument("--no-plots", action="store_true", help="do not draw figures")
    parser.add_argument("--quiet", action="store_true", help="no progress bar and no summary")
    float_option(
        parser,
        "--progress-every",
        default=30.0,
        metavar="SECONDS",
        help="when stderr is not a terminal (a log): one progress line every "
        "SECONDS (default 30); on a terminal a progress bar",
    )


def out_path(args, name: str) -> Path:
    """``--out``, or ``rothe-out/<name>`` when it is not given; an empty or blank ``--out ''``
    is refused (it wrote into the default folder without a word)."""
    out = getattr(args, "out", None)
    if out is None:
        return Path("rothe-out") / name
    if not str(out).strip():
        raise fail("--out", out, f"must name a directory (omit --out for rothe-out/{name})")
    return Path(out)


def output_dir(args, name: str) -> Path:
    """The output directory, created and checked for writability (errors name --out)."""
    return check_writable(out_path(args, name), "--out")


def progress_of(args) -> ProgressOptions:
    """The progress options of a command (``--quiet``, ``--progress-every``)."""
    every = getattr(args, "progress_every", 30.0)
    return ProgressOptions(
        enabled=not args.quiet, every_seconds=check_positive("--progress-every", every)
    )


def parse_float(name: str):
    """argparse type for a float; errors name the option."""

    def conv(text):
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(got(text, "must be a number")) from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(got(text, "must be finite"))
        return value

    return conv


def float_option(parser, name: str, **kwargs) -> None:
    """Add the option ``name`` taking one finite number (:func:`parse_float`) to ``parser``.

    Parameters
    ----------
    parser : argparse.ArgumentParser or argument group
    name : str
        The option, e.g. ``"--tau"``.
    **kwargs
        The other arguments of ``add_argument`` (``default``, ``help``, ``metavar``, ...).
    """
    parser.add_argument(name, type=parse_float(name), **kwargs)


def parse_int(name: str, minimum: int | None = None):
    """argparse type for an integer whose errors say what is allowed (argparse's own says only
    ``invalid int value: 'auto'``); the range itself is checked where the value is used, so
    an integer out of range keeps that check's message."""

    def conv(text):
        try:
            return int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(got(text, integer_allowed(minimum))) from None

    return conv


def parse_float_list(name: str):
    """argparse type for ``1e-3,1e-4``: every item a finite number, none empty (``--tols ''``
    must not silently mean "the defaults")."""

    def conv(text):
        items = text.split(",")
        try:
            values = [float(x) for x in items]
        except ValueError:
            values = None
        if values is None or not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(
                got(text, "must be a comma-separated list of finite numbers")
            )
        return values

    return conv


def given(args, option: str) -> bool:
    """True if ``option`` (e.g. ``'--tol'``) was written on the command line (recorded by
    :func:`rothe.cli.main.main` as ``args._given``), as opposed to taking its default."""
    return option in getattr(args, "_given", ())


def peak_memory_mb() -> float:
    """Peak resident memory of this process in MB: Linux's VmHWM (the high-water mark of this
    process's own address space), else ``ru_maxrss`` (KiB on Linux, bytes on macOS). Not
    ``ru_maxrss`` on Linux: it survives execve, so a spawned process (a sweep's Dask worker, a
    benchmark's child) starts from its parent's resident size at the fork (measured: a child of
    a parent holding 480 MB reported 486 MB with ru_maxrss, 28 MB with VmHWM)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / 1024.0 if sys.platform != "darwin" else rss / 2**20


def _jsonable(value):
    """``value`` with numpy scalars and arrays as Python numbers and lists, and every
    non-finite float -- also a numpy one, also inside an array -- as None: ``summary.json``
    stays strict JSON (json.dumps would write NaN, which JSON parsers refuse)."""
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return _jsonable(value.item())
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_summary(out: Path, summary: dict) -> Path:
    """Write ``out/summary.json`` atomically. In a run's staging directory (see
    :mod:`rothe.io.outputs`) the summary also lists the files of the result (``files``)."""

    out = Path(out)
    if out.name.startswith(TMP_PREFIX):
        names = sorted(p.name for p in out.iterdir() if p.is_file() and not p.name.startswith("."))
        summary = dict(summary, files=sorted(set(names) | {"summary.json"}))
    path = out / "summary.json"
    atomic_write_text(path, json.dumps(_jsonable(summary), indent=2) + "\n")
    return path


def write_table(out: Path, text: str, name: str = "table.txt") -> Path:
    """Write a table (text) atomically."""

    return atomic_write_text(Path(out) / name, text)


def print_summary(summary: dict, keys, notes: dict | None = None) -> None:
    """Print the fields ``keys`` of ``summary`` that it has, one per line (floats with 6 digits);
    ``notes`` (key -> text) adds a remark after the value of a key, e.g. what a count means."""
    width = max(len(k) for k in keys)
    notes = notes or {}
    for k in keys:
        if k in summary:
            v = summary[k]
            if isinstance(v, float):
                v = f"{v:.6g}"
            note = f"  ({notes[k]})" if k in notes else ""
            print(f"  {k:<{width}}  {v}{note}")


def dofs_keys(keys, summary: dict, dofs: str, initial: str, largest: str) -> tuple:
    """``keys`` with the initial and the largest dofs of an adaptive run around the key
    ``dofs`` (the final ones), when the summary has them (``--adapt-space``)."""
    keys = tuple(k for k in keys if k not in (initial, largest))
    if initial not in summary or dofs not in keys:
        return keys
    i = keys.index(dofs)
    return keys[:i] + (initial, dofs, largest) + keys[i + 1 :]


# -- parallel runs: --workers, --scheduler ---------------------------------------------------


def add_parallel_options(parser) -> None:
    """``--workers N`` and ``--scheduler ADDRESS`` for commands that run independent runs."""
    parser.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="run the independent runs on a local Dask cluster of N worker processes "
        "(default: the number of cores if Dask is installed, else 1; 1 = one after another "
        "in this process, no Dask; env ROTHE_WORKERS sets the default)",
    )
    parser.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="address of an existing Dask scheduler (e.g. tcp://host:8786) to run on instead",
    )


def executor_from_args(args, title: str) -> Executor:
    """The executor of ``--workers``/``--scheduler``; bad values are one-line input errors."""
    workers = args.workers
    if workers is not None:
        workers = check_int("--workers", workers, minimum=1)
        if args.scheduler is None:  # a local cluster: at most one worker per core
            workers = check_workers("--workers", workers)
    if args.scheduler is not None:
        if workers is not None:
            raise fail(
                "--workers",
                workers,
                "cannot be combined with --scheduler (the cluster has its own workers)",
            )
        if not args.scheduler.strip():
            raise fail(
                "--scheduler", args.scheduler, "must be a scheduler address (e.g. tcp://host:8786)"
            )
    if workers is not None and workers > 1 and not dask_available():
        raise RotheInputError(
            f"--workers {workers} needs dask.distributed: {INSTALL_HINT} (or --workers 1)"
        )
    if args.scheduler is not None and not dask_available():
        raise RotheInputError(f"--scheduler needs dask.distributed: {INSTALL_HINT}")
    return Executor(
        workers, args.scheduler, progress=not getattr(args, "quiet", False), title=title
    )
