"""The controllers' z in the adaptive error norm of coupled runs (issue 19, item 2): steps and
errors of adaptive runs of eld-control with a filtered derivative (one controller state z)
against a fine uniform reference (docs/coupling.md, Sec. 11, *The controllers' z in the norm*)::

    PYTHONPATH=src python benchmarks/coupled_z_norm.py [--kd 0.05] [--filter-time 0.02] [--T 1]
        [--tols 1e-3,1e-4] [--ref-tau 1e-4]

Per tol: accepted and rejected steps, seconds, the errors of z and q (the base's coordinate)
against uniform BDF2 with --ref-tau, max over the accepted states (the reference interpolated
linearly), relative to the reference's max; the smallest step. Run it with PYTHONPATH of the
tree before and after the change to compare.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings

import numpy as np

from rothe.eld.coupled_run import run_coupled
from rothe.eld.examples import control_problem
from rothe.stepping.controllers import Adaptive, Uniform


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kd", type=float, default=0.05)
    ap.add_argument("--filter-time", type=float, default=0.02)
    ap.add_argument("--T", type=float, default=1.0)
    ap.add_argument("--tols", default="1e-3,1e-4")
    ap.add_argument("--ref-tau", type=float, default=1e-4)
    args = ap.parse_args()
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="G_d")  # no prescribed part: nothing differenced
        system = control_problem(kd=args.kd, filter_time=args.filter_time, T=args.T).controlled
        ref = run_coupled(system, control=Uniform(args.ref_tau), T=args.T).trajectory
        t_ref, z_ref, q_ref = ref["t"], ref["z"][:, 0], ref["q"][:, 0]
        for tol in (float(x) for x in args.tols.split(",")):
            start = time.perf_counter()
            res = run_coupled(system, control=Adaptive(tol, tau=0.005), T=args.T)
            seconds = time.perf_counter() - start
            tr = res.trajectory
            t, z, q = tr["t"], tr["z"][:, 0], tr["q"][:, 0]
            z_error = np.abs(z - np.interp(t, t_ref, z_ref)).max() / np.abs(z_ref).max()
            q_error = np.abs(q - np.interp(t, t_ref, q_ref)).max() / np.abs(q_ref).max()
            row = dict(
                tol=tol,
                accepted=int(tr.stats.accepted_steps),
                rejected=int(tr.stats.rejected_steps),
                seconds=round(seconds, 2),
                z_error=float(z_error),
                q_error=float(q_error),
                tau_min=float(np.diff(t).min()),
            )
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
