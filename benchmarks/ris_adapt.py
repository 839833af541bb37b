"""RIS on changing meshes without artefacts (issue 18, item 0): the table of the docs.

    python benchmarks/ris_adapt.py [--controls uniform,adaptive,nested,order2,regime]
                                   [--n3 12] [--control3 C] [--front-controls C,...]
                                   [--quadrature lumped|consistent] [--fixed] [--timeout S]
                                   [--out DIR]

Runs the command line as a user would, one run after the other (each in its own process, timed
from outside), every run with its command's defaults:

* ``rothe run ris-2d --control X --adapt-space`` for X in ``--controls`` (with ``--fixed`` also
  without ``--adapt-space``: the fixed mesh's number of viscous jumps);
* ``rothe run ris-3d --n N3 --adapt-space`` (``--control C`` with ``--control3``) and
  ``rothe run ris-front --adapt-space``, with ``--front-controls`` also ``rothe run ris-front
  --control C --adapt-space`` for each C (the residual controls, issue 18 item 0);
* ``--quadrature Q`` is passed to every run (default: the command's, ``consistent`` with
  ``--adapt-space`` since issue 18's transfer item; ``lumped`` gives the table before it).

Per run, from its summary.json: whether it reached T (``landing``), the viscous jumps
(:func:`rothe.ris.summary.viscous_jumps`), the energy the mesh changes moved against the
path's own dissipation sum_k R(z_k - z_{k-1}): sum_k |transfer_energy_k| (interpolation onto
the new mesh), sum_k relax_energy_k (the relaxation of the transferred state at fixed t,
:mod:`rothe.ris.adapt`; never a step of the path) and their sum (what the mesh changes left in
the state), the most times a vertex was removed again after its refinement
(``max_recoarsened``), the mesh changes (``space_adaptations``), relaxations refused, the accepted
(rejected) steps, the wall and CPU seconds of the process and the 1-minute load average when it
ended. Targets (issue 18, item 0): every run reaches T; ris-2d has as many
viscous jumps as on the fixed mesh (one, at t ~ 0.172); the transfer energy is a small fraction
of the dissipation; ris-front --adapt-space with its defaults under 120 s.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def rothe(argv: list[str], out: Path, timeout: float) -> tuple[dict, float]:
    """Run ``rothe <argv> --out out --no-plots``; (summary.json, wall seconds), the process's
    CPU seconds in the summary as ``cpu_s`` (the steadier number on a shared machine). After
    ``timeout`` seconds the run is stopped with SIGTERM (it writes its checkpoint, no summary):
    then {"stopped": "t = ..."} from its last progress line."""
    env = dict(os.environ, PYTHONPATH=str(SRC) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cmd = [sys.executable, "-m", "rothe.cli.main", *argv, "--out", str(out), "--no-plots"]
    t0, c0 = time.perf_counter(), _children_cpu()
    proc = subprocess.Popen(
        cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    try:
        text, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGTERM)
        text, _ = proc.communicate()
    wall, cpu = time.perf_counter() - t0, _children_cpu() - c0
    path = out / "summary.json"
    if not path.exists():
        lines = [ln for ln in text.splitlines() if ln.startswith("rothe:")] or text.splitlines()
        last = lines[-1] if lines else "?"
        return {"failed": f"stopped after {wall:.0f} s: {last}", "cpu_s": cpu}, wall
    return dict(json.loads(path.read_text()), cpu_s=cpu), wall


def row(label: str, summary: dict, wall: float, fixed: dict | None) -> dict:
    """The table's row of one adaptive run (``fixed``: the same run on the fixed mesh)."""
    if "failed" in summary:
        return {"run": label, "failed": summary["failed"], "wall": wall, "cpu": summary["cpu_s"]}
    landing = summary.get("landing") or {}
    diss = summary.get("dissipation_sum") or float("nan")
    return {
        "run": label,
        "reached_T": bool(landing.get("landed")) and landing.get("ended_by") == "T",
        "t_final": summary.get("t_final"),
        "jumps": summary.get("n_viscous_jumps"),
        "jumps_fixed": None if fixed is None else fixed.get("n_viscous_jumps"),
        "jump_t": [round(j["t"], 5) for j in summary.get("viscous_jumps", [])][:3],
        "dissipation": diss,
        "transfer_frac": summary.get("transfer_energy_abs_sum", float("nan")) / diss,
        "relax_frac": summary.get("relax_energy_sum", float("nan")) / diss,
        "net_frac": (
            summary.get("transfer_energy_sum", float("nan"))
            + summary.get("relax_energy_sum", float("nan"))
        )
        / diss,
        "max_recoarsened": summary.get("max_recoarsened"),
        "mesh_changes": summary.get("space_adaptations"),
        "relax_refused": summary.get("relax_refused"),
        "steps": summary.get("accepted_steps"),
        "rejected": summary.get("rejected_steps"),
        "dofs_max": summary.get("n_dofs_max"),
        "wall": wall,
        "cpu": summary.get("cpu_s"),
    }


HEADER = (
    "| run | reached T | viscous jumps (fixed mesh) | dissipation | Σ abs(transfer E) / diss. | "
    "Σ relax E / diss. | Σ (transfer + relax) E / diss. | max re-coarsened | "
    "mesh changes (relax refused) | steps (rejected) | max dofs | "
    "wall s (CPU s) | load |"
)


def format_row(r: dict) -> str:
    if "failed" in r:
        blank = " |" * 10
        return (
            f"| {r['run']} | no: {r['failed']} |{blank} {r['wall']:.1f} ({r['cpu']:.1f}) | "
            f"{r['load']:.1f} |"
        )
    fixed = "" if r["jumps_fixed"] is None else f" ({r['jumps_fixed']})"
    reached = "yes" if r["reached_T"] else f"no (t = {r['t_final']:.5g})"
    return (
        f"| {r['run']} | {reached} | {r['jumps']}{fixed} at t = "
        f"{', '.join(f'{t:g}' for t in r['jump_t']) or '-'} | {r['dissipation']:.4g} | "
        f"{r['transfer_frac']:.2g} | {r['relax_frac']:.3g} | {r['net_frac']:.3g} | "
        f"{r['max_recoarsened']} | "
        f"{r['mesh_changes']} ({r['relax_refused']}) | {r['steps']} ({r['rejected']}) | "
        f"{r['dofs_max']} | {r['wall']:.1f} ({r['cpu']:.1f}) | {r['load']:.1f} |"
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--controls", default="uniform,adaptive,nested,order2,regime")
    ap.add_argument("--n3", type=int, default=12, help="--n of the ris-3d run (its default 12)")
    ap.add_argument("--control3", default=None, help="--control of the ris-3d run")
    ap.add_argument(
        "--front-controls", default="", help="ris-front runs with these --control values too"
    )
    ap.add_argument("--quadrature", default=None, help="--quadrature of every run")
    ap.add_argument(
        "--only", default=None, help="comma-separated subset: ris-2d, ris-front, ris-3d"
    )
    ap.add_argument("--fixed", action="store_true", help="also run ris-2d/3d on the fixed mesh")
    ap.add_argument(
        "--timeout", type=float, default=900.0, help="stop a run after this many seconds"
    )
    ap.add_argument("--out", default=None, help="keep the runs' outputs here (default: a tmp dir)")
    args = ap.parse_args(argv)
    base = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="ris_adapt_"))
    only = set(args.only.split(",")) if args.only else {"ris-2d", "ris-front", "ris-3d"}
    runs = []
    if "ris-2d" in only:
        for control in args.controls.split(","):
            cmd = ["run", "ris-2d", "--control", control]
            runs.append((f"ris-2d --control {control}", cmd, args.fixed))
    if "ris-front" in only:
        runs.append(("ris-front", ["run", "ris-front"], False))
        for control in filter(None, args.front_controls.split(",")):
            cmd = ["run", "ris-front", "--control", control]
            runs.append((f"ris-front --control {control}", cmd, False))
    if "ris-3d" in only:
        cmd = ["run", "ris-3d", "--n", str(args.n3)]
        label = f"ris-3d --n {args.n3}"
        if args.control3:
            cmd += ["--control", args.control3]
            label += f" --control {args.control3}"
        runs.append((label, cmd, args.fixed))
    extra = [] if args.quadrature is None else ["--quadrature", args.quadrature]
    runs = [(label + " ".join([""] + extra), cmd + extra, f) for label, cmd, f in runs]
    rows = []
    for i, (label, cmd, with_fixed) in enumerate(runs):
        fixed = None
        if with_fixed:
            fixed, _ = rothe(cmd, base / f"{i}-fixed", args.timeout)
        summary, wall = rothe([*cmd, "--adapt-space"], base / f"{i}-adapt", args.timeout)
        r = row(f"`{label} --adapt-space`", summary, wall, fixed)
        r["load"] = os.getloadavg()[0]  # the 1-minute load average when the run ended
        rows.append(r)
        print(format_row(r), file=sys.stderr, flush=True)
    print(HEADER)
    print("|" + "---|" * HEADER.count(" | ") + "---|")
    for r in rows:
        print(format_row(r))
    front = next((r for r in rows if r["run"].startswith("`ris-front ")), None)
    ok_T = all(r.get("reached_T") for r in rows)
    ok_jumps = all(r.get("jumps") == 1 for r in rows if "ris-2d" in r["run"])
    print(f"every run reached T: {ok_T}")
    print(
        f"ris-2d: one viscous jump (the fixed 40 x 40 grid's count) in every run: {ok_jumps}"
        + ("" if ok_T else " (on the part of the path the stopped runs reached)")
    )
    if front is not None:
        print(
            f"ris-front --adapt-space: {front['wall']:.1f} s wall, "
            f"{front.get('cpu', float('nan')):.1f} s CPU (target < 120 s)"
        )
    print(f"outputs in {base}")
    (base / "ris_adapt.json").write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
