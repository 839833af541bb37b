"""Options and output conventions shared by every command.

Every ``run``/``compare``/``study`` takes ``--out DIR``, ``--no-plots`` and ``--quiet``; results go
to ``rothe-out/<name>/`` by default: ``summary.json``, ``trajectory.npz`` and PNG figures (plus
ParaView files where there is a mesh).
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import sys
from pathlib import Path

import numpy as np

from ..errors import fail


def add_output_options(parser, name: str) -> None:
    parser.add_argument("--out", default=None, help=f"output directory (default rothe-out/{name})")
    parser.add_argument("--no-plots", action="store_true", help="do not draw figures")
    parser.add_argument("--quiet", action="store_true", help="no progress bar and no summary")


def output_dir(args, name: str) -> Path:
    out = Path(args.out) if args.out else Path("rothe-out") / name
    if out.exists() and not out.is_dir():
        raise fail("--out", str(out), "must be a directory (a file of that name exists)")
    out.mkdir(parents=True, exist_ok=True)
    return out


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
    def conv(text):
        try:
            return [float(x) for x in text.split(",") if x.strip()]
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"got {text!r}, must be a comma-separated list of numbers"
            ) from None

    return conv


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
    path = Path(out) / "summary.json"
    path.write_text(json.dumps(_jsonable(summary), indent=2) + "\n")
    return path


def print_summary(summary: dict, keys) -> None:
    width = max(len(k) for k in keys)
    for k in keys:
        if k in summary:
            v = summary[k]
            if isinstance(v, float):
                v = f"{v:.6g}"
            print(f"  {k:<{width}}  {v}")
