"""Example 7.1: adaptive (Alg. 3.2), order2 and uniform -- work against error, and speed.

    python benchmarks/ris_1d.py

Prints one row per run: control, tol or tau, accepted, rejected, inner solves, L2 and L-infinity
errors against (7.1), wall time, and the ratio of inner solves to what uniform needs for the same
L-infinity error. Uniform's work at a given error comes from a least-squares fit of
log(solves) against log(Linf) over the uniform runs of the same invocation (uniform's error is
~sqrt(2) tau: the lag at the start of the jump), so every ratio is measured in one run.

Targets (foundation issue): adaptive <= 1/2 and order2 <= 1/4 of uniform's inner solves at equal
L-infinity error; a whole adaptive run at tol 1e-5 in under 1 s.
"""

from __future__ import annotations

import time

import numpy as np

from rothe import run_ris
from rothe.cli.ris_commands import format_table, ris_summary, uniform_work_at_error
from rothe.problems.ris_1d import errors_against_exact, example_7_1

TOLS = (1e-3, 1e-4, 1e-5, 1e-6)
TAUS = (0.1, 0.05, 0.02, 0.01, 0.005, 0.002, 0.001)


def one(problem, control, tol=None, tau=0.1) -> dict:
    traj = run_ris(problem, control, tol=tol, tau=tau)
    row = ris_summary(traj, "ris-1d", errors_against_exact(traj["s"], traj["t"], traj["z"]))
    row["tau0"] = tau
    return row


def fitted_ratio(rows, control, work_uniform, key, err):
    r = [x for x in rows if x["control"] == control]
    b, a = np.polyfit(np.log([x["error_linf"] for x in r]), np.log([x[key] for x in r]), 1)
    return float(np.exp(a + b * np.log(err))) / work_uniform(err)


def main() -> None:
    problem = example_7_1()
    rows = [one(problem, c, tol=tol) for c in ("adaptive", "order2") for tol in TOLS]
    rows += [one(problem, "uniform", tau=tau) for tau in TAUS]
    work = uniform_work_at_error(rows)
    print("Example 7.1 (T = 5, z0 = -2), first step tau0 = 0.1 for adaptive/order2\n")
    print(format_table(rows, work))

    print("\nOn the fitted error-vs-work curves (log work against log Linf, tol 1e-3..1e-6):")
    print(f"{'Linf':>8} {'adaptive solves':>16} {'adaptive accepted':>18} {'order2 solves':>14}")
    for err in (1e-2, 3e-3, 1e-3):
        adaptive_solves = fitted_ratio(rows, "adaptive", work, "inner_solves", err)
        print(f"{err:>8.0e} {adaptive_solves:>16.2f} "
              f"{fitted_ratio(rows, 'adaptive', work, 'accepted_steps', err):>18.2f} "
              f"{fitted_ratio(rows, 'order2', work, 'inner_solves', err):>14.2f}")

    print("\nAlg. 3.2 depends on where tau0 * 2^j falls (its double/reject cycle); tau0 sweep:")
    print(f"{'tol':>7} {'tau0':>6} {'accepted':>8} {'rejected':>8} {'Linf':>9} "
          f"{'solves/uniform':>15}")
    for tol in (1e-4, 1e-5):
        for tau0 in (0.1, 0.125, 0.15):
            r = one(problem, "adaptive", tol=tol, tau=tau0)
            print(f"{tol:>7.0e} {tau0:>6} {r['accepted_steps']:>8} {r['rejected_steps']:>8} "
                  f"{r['error_linf']:>9.2e} {r['inner_solves'] / work(r['error_linf']):>15.2f}")

    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        run_ris(problem, "adaptive", tol=1e-5, tau=0.1)
        times.append(time.perf_counter() - t0)
    print(f"\nwhole adaptive run at tol 1e-5: {min(times):.3f} s (min of 3; target < 1 s)")


if __name__ == "__main__":
    main()
