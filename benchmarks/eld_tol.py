"""What the ``tol`` of adaptive ELD steps buys: the achieved error against tol on ``eld-mms``,
whose exact solution is known (issue 21, item 7).

``Adaptive(tol)`` bounds the *local* error estimate of every accepted step (``local_error``,
:mod:`rothe.eld.stepper`): the error one step adds, in the energy norm
(u.K u + rho v.M v)^(1/2), relative to the largest energy norm of the run so far (at least
``error_scale``). It is no bound on the error at T: the errors of the steps add up (and are
damped or not by the problem). This script measures, for Euler and BDF2 and several tol, the
error of the run against the exact solution in that same relative energy norm -- at T and the
largest over the steps -- next to the sum of the local estimates. P2 elements represent the
manufactured solution exactly, so every error measured is the error of the time steps::

    PYTHONPATH=src python benchmarks/eld_tol.py [--n 4] [--tols 1e-2,1e-3,1e-4,1e-5,1e-6]
        [--schemes euler,bdf2] [--damping nonlinear|rayleigh] [--markdown]

Columns: accepted and rejected steps; the largest local estimate / tol (<= 1 by construction);
the error at T / tol; the largest error over the steps / tol; the sum of the local estimates /
tol; the error at T itself; seconds.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

from rothe.eld import BDF2, ImplicitEuler, make_damping, mms_problem, run_eld
from rothe.stepping.controllers import Adaptive

SCHEMES = {"euler": ImplicitEuler, "bdf2": BDF2}


def measure(n: int, scheme: str, tol: float, damping: str) -> dict:
    """One adaptive run of the manufactured problem and its errors (module docstring)."""
    problem, exact = mms_problem(n, 2, damping=make_damping(damping, b=0.01, d0=0.5))
    t0 = time.perf_counter()
    result = run_eld(problem, scheme=SCHEMES[scheme](), control=Adaptive(tol, tau=0.01))
    seconds = time.perf_counter() - t0
    traj = result.trajectory
    space, K, M = problem.space, problem.K, problem.M
    rho = problem.material.rho
    # the estimator's scale at the end: the largest energy norm, at least error_scale
    norms = np.sqrt(np.maximum(2.0 * np.asarray(traj["energy"]), 0.0))
    scale = max(float(traj.meta["error_scale"]), float(norms.max()))
    errors = []
    for t, u, v in zip(traj["kept_t"], traj["u"], traj["v"], strict=True):
        eu = u - space.interpolate(lambda x, t=t: exact.u(t, x))
        ev = v - space.interpolate(lambda x, t=t: exact.u_dot(t, x))
        errors.append(math.sqrt(float(eu @ (K @ eu)) + rho * float(ev @ (M @ ev))) / scale)
    local = np.asarray(traj["local_error"])
    return {
        "scheme": scheme,
        "tol": tol,
        "accepted": traj.stats.accepted_steps,
        "rejected": traj.stats.rejected_steps,
        "local_max": float(local.max()) / tol,
        "at_T": errors[-1] / tol,
        "max": max(errors) / tol,
        "local_sum": float(local.sum()) / tol,
        "error_T": errors[-1],
        "seconds": seconds,
    }


def main(argv=None) -> int:
    """Print the table (plain or markdown)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=4, help="cells per side (P2; default 4)")
    ap.add_argument("--tols", default="1e-2,1e-3,1e-4,1e-5,1e-6")
    ap.add_argument("--schemes", default="euler,bdf2")
    ap.add_argument("--damping", default="nonlinear", choices=("nonlinear", "rayleigh"))
    ap.add_argument("--markdown", action="store_true")
    args = ap.parse_args(argv)
    tols = [float(x) for x in args.tols.split(",")]
    head = (
        "scheme",
        "tol",
        "accepted",
        "rejected",
        "max local est./tol",
        "error at T/tol",
        "max error/tol",
        "sum local est./tol",
        "error at T",
        "seconds",
    )
    if args.markdown:
        print("| " + " | ".join(head) + " |")
        print("|" + "---|" * len(head))
    else:
        print(
            f"{'scheme':6s} {'tol':>7s} {'acc':>5s} {'rej':>4s} {'loc/tol':>8s} {'T/tol':>8s} "
            f"{'max/tol':>8s} {'sum/tol':>8s} {'error T':>10s} {'s':>6s}"
        )
    for scheme in args.schemes.split(","):
        for tol in tols:
            r = measure(args.n, scheme, tol, args.damping)
            cells = (
                r["scheme"],
                f"{tol:.0e}",
                str(r["accepted"]),
                str(r["rejected"]),
                f"{r['local_max']:.2f}",
                f"{r['at_T']:.2f}",
                f"{r['max']:.2f}",
                f"{r['local_sum']:.1f}",
                f"{r['error_T']:.2e}",
                f"{r['seconds']:.1f}",
            )
            if args.markdown:
                print("| " + " | ".join(cells) + " |", flush=True)
            else:
                print(
                    f"{cells[0]:6s} {cells[1]:>7s} {cells[2]:>5s} {cells[3]:>4s} {cells[4]:>8s} "
                    f"{cells[5]:>8s} {cells[6]:>8s} {cells[7]:>8s} {cells[8]:>10s} "
                    f"{cells[9]:>6s}",
                    flush=True,
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
