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

from ..errors import check_positive
from ..stepping.progress import ProgressOptions


def add_output_options(parser, name: str) -> None:
    parser.add_argument("--out", default=None, help=f"output directory (default rothe-out/{name})")
    parser.add_argument("--no-plots", action="store_true", help="do not draw figures")
    parser.add_argument("--quiet", action="store_true", help="no progress bar and no summary")
    parser.add_argument(
        "--progress-every",
        type=parse_float("--progress-every"),
        default=30.0,
        metavar="SECONDS",
        help="when stderr is not a terminal (a log): one progress line every "
        "SECONDS (default 30); on a terminal a progress bar",
    )


def output_dir(args, name: str) -> Path:
    """The output directory, created and checked for writability (errors name --out)."""
    from ..io.atomic import check_writable

    out = Path(args.out) if args.out else Path("rothe-out") / name
    return check_writable(out, "--out")


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
            raise argparse.ArgumentTypeError(f"got {text!r}, must be a number") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"got {text!r}, must be finite")
        return value

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
                f"got {text!r}, must be a comma-separated list of finite numbers"
            )
        return values

    return conv


def given(args, option: str) -> bool:
    """True if ``option`` (e.g. ``'--tol'``) was written on the command line (recorded by
    :func:`rothe.cli.main.main` as ``args._given``), as opposed to taking its default."""
    return option in getattr(args, "_given", ())


def fit_default_cap(args, space, initial: int) -> None:
    """--adapt-space without --max-dofs: the command's default cap, or twice the initial mesh's
    dofs (nodes, for RIS) when that is more. A --max-dofs the user gave is checked against the
    initial mesh where the run starts instead."""
    if space is not None and args.max_dofs is None and space.max_dofs is not None:
        space.max_dofs = max(space.max_dofs, 2 * int(initial))


def peak_memory_mb() -> float:
    """Peak resident memory of this process in MB (ru_maxrss is KiB on Linux, bytes on macOS)."""
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / 1024.0 if sys.platform != "darwin" else rss / 2**20


def _jsonable(value):
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_summary(out: Path, summary: dict) -> Path:
    """Write ``out/summary.json`` atomically. In a run's staging directory (see
    :mod:`rothe.io.outputs`) the summary also lists the files of the result (``files``)."""
    from ..io.atomic import TMP_PREFIX, atomic_write_text

    out = Path(out)
    if out.name.startswith(TMP_PREFIX):
        names = sorted(p.name for p in out.iterdir() if p.is_file() and not p.name.startswith("."))
        summary = dict(summary, files=sorted(set(names) | {"summary.json"}))
    path = out / "summary.json"
    atomic_write_text(path, json.dumps(_jsonable(summary), indent=2) + "\n")
    return path


def write_table(out: Path, text: str, name: str = "table.txt") -> Path:
    """Write a table (text) atomically."""
    from ..io.atomic import atomic_write_text

    return atomic_write_text(Path(out) / name, text)


def print_summary(summary: dict, keys) -> None:
    width = max(len(k) for k in keys)
    for k in keys:
        if k in summary:
            v = summary[k]
            if isinstance(v, float):
                v = f"{v:.6g}"
            print(f"  {k:<{width}}  {v}")
