"""Independent runs on 1 and 2 worker processes: wall time of a compare and a study.

    python benchmarks/sweep.py               # compare ris-2d --n 40 and study eld-perturbation
    python benchmarks/sweep.py --quick       # compare ris-2d --n 10, smaller study: a try-out
    python benchmarks/sweep.py --only study  # one of them

Each command runs in its own process, exactly as a user types it (``--workers 1``: one run after
another in that process; ``--workers 2``: a local Dask cluster of 2 worker processes), so the wall
time includes the imports, the start-up of the cluster and the workers' imports. Printed per
command: wall time per worker count, speed-up (wall 1 / wall 2), and what bounds it:

* load balance: with the runs' own times t_i (measured in the 1-worker run), no schedule on 2
  workers beats max(sum t_i / 2, max t_i); ``ideal`` is sum t_i / that bound (2.0 when the longest
  run is at most half the total). For the study, whose summary has no per-run times, the t_i are
  modelled by the number of steps (1/tau per run, 1 + #targets runs per (tau, form) task);
* contention: ``inflation`` = sum of the runs' own times with 2 workers / with 1 worker (> 1
  when two runs at once slow each other: memory bandwidth, shared caches, a busy machine);
* start-up: the wall time not spent in runs;
* the machine: ``CPU s`` is the CPU time of the command and its worker processes, ``cores`` =
  CPU s / wall s the number of cores it actually got. On a quiet 2-core machine 2 workers get
  about 2; on a shared one much less, and then no worker count helps.

The machine may be shared: compare ratios measured in the same run, and re-run on a quiet
machine for numbers to quote.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run(argv: list[str], out: Path) -> tuple[float, float, dict]:
    """Wall time, CPU time (the command and every process it started: the workers are its
    children, reaped before it exits) and summary.json of one command."""
    cmd = [
        sys.executable,
        "-m",
        "rothe.cli.main",
        *argv,
        "--out",
        str(out),
        "--no-plots",
        "--quiet",
    ]
    c0, t0 = cpu_children(), time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall, cpu = time.perf_counter() - t0, cpu_children() - c0
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} exited {proc.returncode}:\n{proc.stderr}")
    return wall, cpu, json.loads((out / "summary.json").read_text())


def compare_bench(n: int, workers, base: Path) -> list[dict]:
    rows = []
    for w in workers:
        wall, cpu, summary = run(
            ["compare", "ris-2d", "--n", str(n), "--workers", str(w)], base / f"compare-w{w}"
        )
        times = [r["wall_time_s"] for r in summary["rows"]]
        rows.append(
            {
                "command": f"compare ris-2d --n {n}",
                "workers": w,
                "wall": wall,
                "cpu": cpu,
                "runs": len(times),
                "sum_runs": sum(times),
                "max_run": max(times),
            }
        )
    return rows


def study_bench(taus: list[float], workers, base: Path) -> list[dict]:
    rows = []
    for w in workers:
        argv = ["study", "eld-perturbation", "--workers", str(w)]
        if taus != DEFAULT_TAUS:
            argv += ["--taus", ",".join(f"{t:g}" for t in taus)]
        wall, cpu, summary = run(argv, base / f"study-w{w}")
        # one task per (tau, form): the unperturbed run and one run per perturbed datum
        targets = len(summary.get("targets", ("G", "F")))
        model = [(1 + targets) / tau for tau in taus for _form in (0, 1)]
        rows.append(
            {
                "command": "study eld-perturbation"
                + (
                    ""
                    if taus == DEFAULT_TAUS
                    else " (--taus " + ",".join(f"{t:g}" for t in taus) + ")"
                ),
                "workers": w,
                "wall": wall,
                "cpu": cpu,
                "runs": len(model),
                "sum_runs": None,
                "max_run": None,
                "study_seconds": summary["seconds"],
                "model": model,
            }
        )
    return rows


DEFAULT_TAUS = [0.1, 0.05, 0.02, 0.01, 0.005, 0.002, 0.001]


def print_table(rows: list[dict]) -> None:
    head = (
        f"{'command':<40} {'workers':>7} {'wall s':>8} {'speed-up':>8} {'ideal':>6} "
        f"{'CPU s':>8} {'cores':>5} {'runs':>5} {'sum runs s':>10} {'longest s':>9} "
        f"{'inflation':>9} {'start-up s':>10}"
    )
    print(head)
    print("-" * len(head))
    by_cmd: dict[str, dict[int, dict]] = {}
    for r in rows:
        by_cmd.setdefault(r["command"], {})[r["workers"]] = r
    for cmd, per in by_cmd.items():
        one = per.get(1)
        for w, r in sorted(per.items()):
            speed = one["wall"] / r["wall"] if one else float("nan")
            if r.get("model"):
                t = r["model"]
                ideal = sum(t) / max(sum(t) / w, max(t))
                sum_runs = longest = inflation = None
                # the study times its whole loop; the rest is start-up
                startup = r["wall"] - r["study_seconds"]
            else:
                sum_runs, longest = r["sum_runs"], r["max_run"]
                base_sum = one["sum_runs"] if one else sum_runs
                base_max = one["max_run"] if one else longest
                ideal = base_sum / max(base_sum / w, base_max)
                inflation = sum_runs / base_sum
                startup = None
            cells = [
                f"{cmd:<40}",
                f"{w:>7d}",
                f"{r['wall']:>8.1f}",
                f"{speed:>8.2f}",
                f"{ideal:>6.2f}",
                f"{r['cpu']:>8.1f}",
                f"{r['cpu'] / r['wall']:>5.2f}",
                f"{r['runs']:>5d}",
                f"{sum_runs:>10.1f}" if sum_runs is not None else f"{'':>10}",
                f"{longest:>9.1f}" if longest is not None else f"{'':>9}",
                f"{inflation:>9.2f}" if inflation is not None else f"{'':>9}",
                f"{startup:>10.1f}" if startup is not None else f"{'':>10}",
            ]
            print(" ".join(cells))
    print(
        "\nspeed-up = wall(1 worker) / wall; ideal = best possible on that many workers given "
        "the runs' own times (load balance);\nCPU s = CPU time of the command and its worker "
        "processes; cores = CPU s / wall s (the cores it actually got: about the worker count "
        "on a quiet machine);\ninflation = sum of run times / that with 1 worker (contention "
        "between simultaneous runs); start-up = wall - time in the study loop"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small versions to try it out")
    parser.add_argument("--only", choices=("compare", "study"), default=None)
    parser.add_argument("--workers", default="1,2", help="worker counts (default 1,2)")
    parser.add_argument("--out", default=None, help="folder of the runs (default: a temp dir)")
    args = parser.parse_args()
    workers = [int(w) for w in args.workers.split(",")]
    base = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="rothe-bench-sweep-"))
    rows = []
    if args.only in (None, "compare"):
        rows += compare_bench(10 if args.quick else 40, workers, base)
    if args.only in (None, "study"):
        rows += study_bench([0.1, 0.05, 0.02, 0.01] if args.quick else DEFAULT_TAUS, workers, base)
    print_table(rows)
    print(f"outputs: {base}")


if __name__ == "__main__":
    main()
