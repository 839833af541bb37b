"""Example 7.1: adaptive (Alg. 3.2), order2, regime and uniform -- work against error, and speed.

    python benchmarks/ris_1d.py

Prints one row per run: control, tol or tau, accepted, rejected, inner solves, L2 and L-infinity
errors against (7.1), wall time, and the ratio of inner solves to what uniform needs for the same
L-infinity error. Uniform's work at a given error comes from a least-squares fit of
log(solves) against log(Linf) over the uniform runs of the same invocation (uniform's error is
~sqrt(2) tau: the lag at the start of the jump), so every ratio is measured in one run.

Then the measure of issue 12, the global residual sum_k(I1+I2): accepted steps and inner solves
divided by uniform's at the same global residual, interpolated log-log between the two uniform
runs that bracket it, and the equidistribution bound of the finest uniform run (the least
fraction of uniform's steps any step sequence can need while I ~ C(s) tau^2; here slip, where
all the residual is, is 6/16 of the arc length: 0.375).

Targets (foundation issue): adaptive <= 1/2 and order2 <= 1/4 of uniform's inner solves at equal
L-infinity error; a whole adaptive run at tol 1e-5 in under 1 s.
"""

from __future__ import annotations

import time

import numpy as np

from rothe import run_ris
from rothe.cli.ris_commands import control_object, format_table
from rothe.ris.examples import errors_against_exact, example_7_1
from rothe.ris.summary import (
    compare_rows,
    equidistribution_bound,
    ris_summary,
    uniform_work_at_error,
)

CONTROLS = ("adaptive", "order2", "regime")
TOLS = (1e-3, 1e-4, 1e-5, 1e-6)
TAUS = (0.1, 0.05, 0.02, 0.01, 0.005, 0.002, 0.001, 0.0005)


def one(problem, control, tol=None, tau=0.1) -> dict:
    traj = run_ris(problem, control_object(control, tol=tol, tau=tau)).trajectory
    row = ris_summary(traj, "ris-1d", errors_against_exact(traj["s"], traj["t"], traj["z"]))
    row["tau0"] = tau
    if control == "uniform":
        row["equidistribution_bound"] = equidistribution_bound(traj["I1"] + traj["I2"])
    return row


def fitted_ratio(rows, control, work_uniform, key, err):
    r = [x for x in rows if x["control"] == control]
    b, a = np.polyfit(np.log([x["error_linf"] for x in r]), np.log([x[key] for x in r]), 1)
    return float(np.exp(a + b * np.log(err))) / work_uniform(err)


def main() -> None:
    problem = example_7_1()
    rows = [one(problem, c, tol=tol) for c in CONTROLS for tol in TOLS]
    rows += [one(problem, "uniform", tau=tau) for tau in TAUS]
    work = uniform_work_at_error(rows)
    print("Example 7.1 (T = 5, z0 = -2), first step tau0 = 0.1 for the step controllers\n")
    print(format_table(rows, work))

    print("\nOn the fitted error-vs-work curves (log work against log Linf, tol 1e-3..1e-6):")
    head = f"{'Linf':>8} {'adaptive solves':>16} {'adaptive accepted':>18}"
    head += "".join(f" {c + ' solves':>14}" for c in CONTROLS[1:])
    print(head)
    for err in (1e-2, 3e-3, 1e-3):
        line = (
            f"{err:>8.0e} {fitted_ratio(rows, 'adaptive', work, 'inner_solves', err):>16.2f} "
            f"{fitted_ratio(rows, 'adaptive', work, 'accepted_steps', err):>18.2f}"
        )
        line += "".join(
            f" {fitted_ratio(rows, c, work, 'inner_solves', err):>14.2f}" for c in CONTROLS[1:]
        )
        print(line)

    print(
        "\nAt equal global residual sum_k(I1+I2) (interpolated between the bracketing uniform "
        "runs; '-': outside their range):"
    )
    print(
        f"{'control':<9} {'tol':>7} {'global res':>10} {'steps/uniform':>13} {'solves/uniform':>14}"
    )
    for r in compare_rows(rows):
        if r["control"] == "uniform":
            continue

        def fmt(x, width):
            return f"{x:>{width}.3f}" if x is not None else f"{'-':>{width}}"

        print(
            f"{r['control']:<9} {r['tol']:>7.0e} {r['global_residual']:>10.3e} "
            f"{fmt(r['ratio_steps'], 13)} {fmt(r['ratio_solves'], 14)}"
        )
    finest = min((r for r in rows if r["control"] == "uniform"), key=lambda r: r["tau0"])
    print(
        f"equidistribution bound (uniform tau = {finest['tau0']:g}): "
        f"{finest['equidistribution_bound']:.3f} of uniform's steps"
    )

    print("\nDependence on where tau0 * 2^j (Alg. 3.2) or the first steps fall; tau0 sweep:")
    print(
        f"{'control':<9} {'tol':>7} {'tau0':>6} {'accepted':>8} {'rejected':>8} {'Linf':>9} "
        f"{'solves/uniform@Linf':>20}"
    )
    for control in ("adaptive", "regime"):
        for tol in (1e-4, 1e-5):
            for tau0 in (0.1, 0.125, 0.15):
                r = one(problem, control, tol=tol, tau=tau0)
                print(
                    f"{control:<9} {tol:>7.0e} {tau0:>6} {r['accepted_steps']:>8} "
                    f"{r['rejected_steps']:>8} {r['error_linf']:>9.2e} "
                    f"{r['inner_solves'] / work(r['error_linf']):>20.2f}"
                )

    for control in ("adaptive", "regime"):
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            run_ris(problem, control_object(control, tol=1e-5, tau=0.1))
            times.append(time.perf_counter() - t0)
        print(f"\nwhole {control} run at tol 1e-5: {min(times):.3f} s (min of 3; target < 1 s)")


if __name__ == "__main__":
    main()
