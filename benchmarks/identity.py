"""Outputs of a fixed set of runs, recorded before a refactoring and compared after it.

    python benchmarks/identity.py record DIR      # run every case, outputs into DIR/<case>/
    python benchmarks/identity.py compare A B     # every array of every trajectory.npz and
                                                  # every non-timing field of every summary.json

A refactoring that must not change results (issue 17) is checked by ``record`` on the commit
before it, ``record`` on the commit after it, and ``compare``: arrays must be bit-identical
(NaN equal to NaN), summaries equal except for fields that are wall-clock times, dates, paths or
the command line itself. ``--only NAME[,NAME]`` records a subset. ``CASES`` below lists the runs;
where an option's spelling changes on purpose, ``TRANSLATE`` maps the old argv to the new one
(applied by ``record --translated``) and the note says so.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

#: name -> argv after ``rothe`` (``{out}`` is the case's output directory)
CASES: dict[str, list[str]] = {
    "ris-1d-adaptive": ["run", "ris-1d", "--control", "adaptive", "--tol", "1e-4"],
    "ris-1d-regime": ["run", "ris-1d", "--control", "regime", "--tol", "1e-4"],
    "ris-1d-nested": ["run", "ris-1d", "--control", "nested", "--tols", "1e-2,1e-3"],
    "ris-2d-regime": ["run", "ris-2d", "--n", "16", "--control", "regime", "--tol", "1e-4"],
    "ris-2d-adaptive": ["run", "ris-2d", "--n", "8", "--control", "adaptive", "--tol", "1e-4"],
    "ris-front-adapt": [
        "run",
        "ris-front",
        "--adapt-space",
        "--n",
        "8",
        "--max-dofs",
        "400",
        "--tol",
        "1e-3",
    ],
    "ris-3d-adapt": [
        "run",
        "ris-3d",
        "--n",
        "3",
        "--adapt-space",
        "--max-dofs",
        "300",
        "--tol",
        "1e-3",
    ],
    "eld-mms-euler-adaptive": [
        "run",
        "eld-mms",
        "--scheme",
        "euler",
        "--control",
        "adaptive",
        "--tol",
        "1e-3",
        "--n",
        "4",
    ],
    "eld-mms-bdf2-adaptive": [
        "run",
        "eld-mms",
        "--scheme",
        "bdf2",
        "--control",
        "adaptive",
        "--tol",
        "1e-4",
        "--n",
        "4",
    ],
    "eld-mms-original": ["run", "eld-mms", "--form", "original", "--n", "4", "--tau", "0.05"],
    "eld-mms-adapt-space": [
        "run",
        "eld-mms",
        "--n",
        "4",
        "--degree",
        "1",
        "--tau",
        "0.05",
        "--adapt-space",
        "--space-tol",
        "0.05",
        "--max-dofs",
        "2000",
    ],
    "eld-pulse-coarse": [
        "run",
        "eld-pulse",
        "--n",
        "4",
        "--T",
        "0.2",
        "--tau",
        "0.01",
        "--max-dofs",
        "3000",
    ],
    "eld-beam": ["run", "eld-beam", "--n", "2", "--T", "0.2"],
    "eld-tip-mass": ["run", "eld-tip-mass", "--T", "0.5", "--tau", "0.01"],
    "sweep": ["sweep", "run", "ris-1d", "--param", "tol=1e-3,1e-4", "--param", "control=adaptive"],
}

#: cases killed by SIGINT after ``delay`` seconds and then resumed with ``rothe resume``
KILLED: dict[str, tuple[list[str], float]] = {
    "ris-2d-killed-resumed": (
        [
            "run",
            "ris-2d",
            "--n",
            "24",
            "--control",
            "regime",
            "--tol",
            "1e-5",
            "--checkpoint-every",
            "0.5",
        ],
        6.0,
    ),
}

#: old argv -> new argv for options whose meaning changed on purpose (see the module docstring)
TRANSLATE: dict[str, list[str]] = {}

#: summary.json keys that are timings, dates, paths or the command line: never compared
SKIP_KEYS = {
    "wall_time_s",
    "seconds",
    "time_s",
    "started",
    "finished",
    "date",
    "out",
    "command",
    "argv",
    "checkpoint",
    "resume",
    "elapsed_s",
    "wall_time",
    "timings",
    "sessions",
    "python",
    "platform",
    "version",
    "hostname",
    "peak_memory_mb",
    "phase_seconds",
    "rothe_version",
    "path",
    "paths",
    "files",
    "run_id",
    "executor",
}


def _rothe(argv: list[str], out: Path, **popen) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "rothe.cli.main", *argv]
    if argv[0] != "resume":
        cmd += ["--out", str(out)]
    if argv[0] == "run" or argv[0] == "resume":
        cmd += ["--quiet", "--no-plots"] if argv[0] == "run" else ["--quiet", "--no-plots"]
    env = dict(os.environ, PYTHONHASHSEED="0", OMP_NUM_THREADS="1")
    return subprocess.Popen(
        cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **popen
    )


def record(root: Path, only: set[str] | None, translated: bool) -> int:
    root.mkdir(parents=True, exist_ok=True)
    failures = 0
    for name, argv in CASES.items():
        if only and name not in only:
            continue
        if translated and name in TRANSLATE:
            argv = TRANSLATE[name]
        start = time.perf_counter()
        proc = _rothe(argv, root / name)
        text, _ = proc.communicate()
        print(
            f"{name:28s} exit {proc.returncode}  {time.perf_counter() - start:6.1f} s", flush=True
        )
        if proc.returncode != 0:
            failures += 1
            print(text[-2000:])
    for name, (argv, delay) in KILLED.items():
        if only and name not in only:
            continue
        start = time.perf_counter()
        proc = _rothe(argv, root / name)
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        text, _ = proc.communicate()
        killed = proc.returncode
        proc = _rothe(["resume", str(root / name)], root / name)
        text2, _ = proc.communicate()
        print(
            f"{name:28s} exit {killed} then {proc.returncode}  "
            f"{time.perf_counter() - start:6.1f} s",
            flush=True,
        )
        if killed != 130 or proc.returncode != 0:
            failures += 1
            print(text[-1000:], text2[-2000:])
    return 1 if failures else 0


def _npz_files(root: Path) -> dict[str, Path]:
    return {
        str(p.relative_to(root)): p
        for p in sorted(root.rglob("*.npz"))
        if "checkpoint" not in p.parts
    }


def _json_files(root: Path) -> dict[str, Path]:
    names = ("summary.json", "compare.json", "sweep.json")
    return {
        str(p.relative_to(root)): p
        for p in sorted(root.rglob("*.json"))
        if p.name in names and "checkpoint" not in p.parts
    }


def _diff_json(a, b, path: str, out: list[str]) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        for key in sorted(set(a) | set(b)):
            if key in SKIP_KEYS or "seconds" in key or key.endswith("_time_s"):
                continue
            if key not in a or key not in b:
                out.append(f"{path}.{key}: only in {'after' if key in b else 'before'}")
                continue
            _diff_json(a[key], b[key], f"{path}.{key}", out)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out.append(f"{path}: length {len(a)} != {len(b)}")
            return
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _diff_json(x, y, f"{path}[{i}]", out)
    elif a != b and not (a != a and b != b):  # NaN == NaN
        out.append(f"{path}: {a!r} != {b!r}")


def compare(before: Path, after: Path) -> int:
    problems: list[str] = []
    n_arrays = n_fields = 0
    npz_a, npz_b = _npz_files(before), _npz_files(after)
    for rel in sorted(set(npz_a) | set(npz_b)):
        if rel not in npz_a or rel not in npz_b:
            problems.append(f"{rel}: only {'after' if rel in npz_b else 'before'}")
            continue
        with (
            np.load(npz_a[rel], allow_pickle=False) as fa,
            np.load(npz_b[rel], allow_pickle=False) as fb,
        ):
            for key in sorted(set(fa.files) | set(fb.files)):
                if key in ("stats_wall_time_s",) or key.startswith("stats_seconds"):
                    continue  # wall-clock times
                if key not in fa.files or key not in fb.files:
                    problems.append(f"{rel}:{key}: only {'after' if key in fb.files else 'before'}")
                    continue
                x, y = fa[key], fb[key]
                n_arrays += 1
                if key == "meta":  # a JSON string: compared like a summary
                    diffs: list[str] = []
                    _diff_json(json.loads(str(x)), json.loads(str(y)), f"{rel}:meta", diffs)
                    problems.extend(diffs)
                    continue
                same = (
                    x.shape == y.shape
                    and x.dtype == y.dtype
                    and (np.array_equal(x, y, equal_nan=x.dtype.kind in "fc"))
                )
                if not same:
                    problems.append(
                        f"{rel}:{key}: arrays differ ({x.shape} {x.dtype} vs {y.shape} {y.dtype})"
                    )
    js_a, js_b = _json_files(before), _json_files(after)
    for rel in sorted(set(js_a) | set(js_b)):
        if rel not in js_a or rel not in js_b:
            problems.append(f"{rel}: only {'after' if rel in js_b else 'before'}")
            continue
        a, b = json.loads(js_a[rel].read_text()), json.loads(js_b[rel].read_text())
        diffs: list[str] = []
        _diff_json(a, b, rel, diffs)
        n_fields += _count_leaves(a)
        problems.extend(diffs)
    print(
        f"{len(npz_a)} trajectory files, {n_arrays} arrays; {len(js_a)} summaries, "
        f"{n_fields} fields"
    )
    if problems:
        print(f"{len(problems)} differences:")
        for p in problems:
            print("  " + p)
        return 1
    print("identical: every array bit for bit, every non-timing summary field equal")
    return 0


def _count_leaves(x) -> int:
    if isinstance(x, dict):
        return sum(_count_leaves(v) for k, v in x.items() if k not in SKIP_KEYS)
    if isinstance(x, list):
        return sum(_count_leaves(v) for v in x)
    return 1


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="verb", required=True)
    r = sub.add_parser("record")
    r.add_argument("dir", type=Path)
    r.add_argument("--only", default="")
    r.add_argument("--translated", action="store_true")
    c = sub.add_parser("compare")
    c.add_argument("before", type=Path)
    c.add_argument("after", type=Path)
    args = parser.parse_args(argv)
    if args.verb == "record":
        only = {s for s in args.only.split(",") if s} or None
        return record(args.dir, only, args.translated)
    return compare(args.before, args.after)


if __name__ == "__main__":
    sys.exit(main())
