"""ris-front on a fixed grid: what each step control costs and how far its path is from a fine one.

    python benchmarks/ris_front_tol.py [--n 16] [--runs ref,uniform0.02,order2-1e-3,...]
                                       [--ref-tau 5e-4] [--out DIR]

Runs :func:`rothe.ris.examples.example_front` (n x n, the command's data: z = 0 on the
right side, the vertex rule of ``rothe run ris-front`` without ``--adapt-space``) one after
another in this process, each control from the table ``RUNS``; ``ref`` is the uniform step
``--ref-tau`` (5e-4), the fine path the others are compared with. Per run: reached T,
accepted (rejected) steps, Newton iterations, viscous jumps
(:func:`rothe.ris.summary.viscous_jumps`), wall and CPU seconds, and the relative V-norm
distance of z(t) from the reference's at t = 0.25, 0.5, 0.75, 1 (z(t) = the last state with
t_k <= t). ``ref`` first: its states are kept in ``--out`` (default a tmp dir) for the runs
after it. Issue 18, item 0: should ris-front's residual controls default to
``--tol 1e-3``?
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from rothe.ris.controllers import Order2, Regime  # noqa: E402
from rothe.ris.examples import example_front  # noqa: E402
from rothe.ris.run import run_ris  # noqa: E402
from rothe.ris.summary import viscous_jumps  # noqa: E402
from rothe.stepping.controllers import Adaptive, Uniform  # noqa: E402

TIMES = (0.25, 0.5, 0.75, 1.0)
RUNS = {
    "ref": Uniform(5e-4),
    "uniform0.02": Uniform(0.02),
    "order2-1e-3": Order2(1e-3, tau=0.02),
    "order2-1e-4": Order2(1e-4, tau=0.02),
    "regime-1e-3": Regime(1e-3, tau=0.02),
    "regime-1e-4": Regime(1e-4, tau=0.02),
    "adaptive-1e-3": Adaptive(1e-3, tau=0.02),
    "adaptive-1e-4": Adaptive(1e-4, tau=0.02),
}


def states_at(traj, times=TIMES) -> np.ndarray:
    """z(t) at the times: the last stored state with t_k <= t (nodal values)."""
    t = np.asarray(traj["t"])
    z = traj["z"]
    return np.array(
        [np.asarray(z[int(np.searchsorted(t, ts + 1e-12, "right")) - 1]) for ts in times]
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=16)
    ap.add_argument("--runs", default=",".join(RUNS))
    ap.add_argument("--out", default=None)
    ap.add_argument("--ref-tau", type=float, default=5e-4, help="the reference's uniform step")
    args = ap.parse_args(argv)
    RUNS["ref"] = Uniform(args.ref_tau)
    out = Path(args.out or tempfile.mkdtemp(prefix="ris_front_tol_"))
    out.mkdir(parents=True, exist_ok=True)
    print(
        "| run | reached T | accepted (rejected) | Newton | viscous jumps | wall s (CPU s) | "
        + " | ".join(f"rel. dist. z({ts:g})" for ts in TIMES)
        + " |"
    )
    print("|---" * (6 + len(TIMES)) + "|")
    for name in args.runs.split(","):
        p = example_front(args.n, dirichlet=("right",))
        w0, c0 = time.perf_counter(), time.process_time()
        r = run_ris(p, RUNS[name])
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        zs = states_at(r.trajectory)
        np.save(out / f"{args.n}_{name}.npy", zs)
        ref_path = out / f"{args.n}_ref.npy"
        dists = ["—"] * len(TIMES)
        if ref_path.exists() and name != "ref":
            ref = np.load(ref_path)
            m = p.m_all  # the lumped mass of all nodes: the V-norm of nodal values

            def norm(v, m=m):
                return float(np.sqrt(m @ (v * v)))

            dists = [f"{norm(a - b) / norm(b):.3g}" for a, b in zip(zs, ref, strict=True)]
        st = r.statistics
        reached = (
            "yes" if abs(r.state.t - p.T) <= 1e-10 * max(1.0, p.T) else f"no ({r.state.t:.4g})"
        )
        print(
            f"| {name} | {reached} | {st.accepted_steps} ({st.rejected_steps}) | "
            f"{st.newton_iterations} | {len(viscous_jumps(r.trajectory))} | "
            f"{wall:.1f} ({cpu:.1f}) | " + " | ".join(dists) + " |",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
