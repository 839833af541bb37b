"""Efficiency of the ELD and RIS residual indicators, and adaptive vs uniform refinement.

    python benchmarks/adapt_efficiency.py            # up to ~10^5 dofs in 2D, ~2*10^4 in 3D
    python benchmarks/adapt_efficiency.py --quick    # up to ~10^4 / ~3*10^3 dofs

The stationary model problems of :mod:`rothe.eld.efficiency` and :mod:`rothe.ris.efficiency`
(a Rothe step of each
family with a manufactured exact solution, a fixed reaction coefficient):

* ELD: -div sigma(u) + kappa u = f, lam = 2, mu = 1, kappa = 1, u = u* on ``left``, tractions
  elsewhere; u* = a phi with phi a smooth bump or a steep tanh front on a circle;
* RIS: the step (3.1) of Example 7.2's energy from z_{k-1} = 0 with lambda_k = 250.

Part 1 prints, for uniform (every edge halved per level) and adaptive (Doerfler, theta = 0.5,
one bisection per marked cell) meshes, the dofs, the estimate eta, the exact energy-norm error
and the efficiency eta/|||e|||, and one summary line per case with the band over all meshes and
over the meshes with >= 1000 dofs. Part 2 prints the dofs that adaptive and uniform refinement
need to reach the error of the finest uniform mesh (front of width 0.02; log-log interpolation)
and their ratio.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from rothe.eld.efficiency import elasticity_study
from rothe.fem.adapt.efficiency import dofs_for_error
from rothe.ris.efficiency import ris_study


def table(title: str, rows: list[dict]) -> None:
    print(f"  {title}")
    print(f"  {'dofs':>8} {'cells':>8} {'estimate':>10} {'error':>10} {'eta/err':>8}")
    for r in rows:
        print(
            f"  {r['dofs']:>8} {r['cells']:>8} {r['estimate']:>10.3e} {r['error']:>10.3e} "
            f"{r['efficiency']:>8.2f}"
        )


def band(rows: list[dict], min_dofs: int = 0) -> str:
    eff = [r["efficiency"] for r in rows if r["dofs"] >= min_dofs]
    return f"[{min(eff):.2f}, {max(eff):.2f}]" if eff else "-"


def part1(quick: bool) -> None:
    big2, big3 = (12_000, 3_000) if quick else (120_000, 20_000)
    cases = [
        ("ELD P1 2D bump", lambda ad: elasticity_study(2, 1, "bump", adaptive=ad, max_dofs=big2)),
        ("ELD P1 2D front", lambda ad: elasticity_study(2, 1, "front", adaptive=ad, max_dofs=big2)),
        ("ELD P2 2D bump", lambda ad: elasticity_study(2, 2, "bump", adaptive=ad, max_dofs=big2)),
        ("ELD P2 2D front", lambda ad: elasticity_study(2, 2, "front", adaptive=ad, max_dofs=big2)),
        (
            "ELD P1 3D bump",
            lambda ad: elasticity_study(3, 1, "bump", adaptive=ad, n0=1, max_dofs=big3),
        ),
        (
            "ELD P2 3D bump",
            lambda ad: elasticity_study(3, 2, "bump", adaptive=ad, n0=1, max_dofs=big3),
        ),
        ("RIS P1 2D front", lambda ad: ris_study(2, "front", adaptive=ad, max_dofs=big2 // 2)),
        ("RIS P1 3D front", lambda ad: ris_study(3, "front", adaptive=ad, n0=2, max_dofs=big3)),
    ]
    print("Part 1: efficiency eta / |||u - u_h||| (energy norm)\n")
    summary = []
    for name, study in cases:
        print(name)
        out = {}
        for adaptive in (False, True):
            t0 = time.perf_counter()
            rows = study(adaptive)
            label = "adaptive" if adaptive else "uniform"
            table(f"{label} ({time.perf_counter() - t0:.1f} s)", rows)
            out[label] = rows
        allrows = out["uniform"] + out["adaptive"]
        summary.append((name, band(allrows), band(allrows, 1000)))
        print()
    print(f"{'case':<18} {'band (all meshes)':>18} {'band (>= 1000 dofs)':>20}")
    for name, b_all, b_fine in summary:
        print(f"{name:<18} {b_all:>18} {b_fine:>20}")
    print()


def part2(quick: bool) -> None:
    big = 9_000 if quick else 140_000
    print("Part 2: dofs to reach the error of the finest uniform mesh (front width 0.02)\n")
    head = (
        f"{'case':<16} {'target error':>12} {'uniform dofs':>13} {'adaptive dofs':>14} {'ratio':>7}"
    )
    print(head)
    print("-" * len(head))
    for name, study in (
        (
            "ELD P1 2D",
            lambda ad: elasticity_study(2, 1, "front", width=0.02, adaptive=ad, max_dofs=big),
        ),
        (
            "ELD P2 2D",
            lambda ad: elasticity_study(2, 2, "front", width=0.02, adaptive=ad, max_dofs=big),
        ),
        ("RIS P1 2D", lambda ad: ris_study(2, "front", width=0.02, adaptive=ad, max_dofs=big // 2)),
    ):
        uniform = study(False)
        adaptive = study(True)
        target = uniform[-1]["error"]
        nu = dofs_for_error(uniform, target)
        na = dofs_for_error(adaptive, target)
        print(f"{name:<16} {target:>12.3e} {nu:>13.0f} {na:>14.0f} {na / nu:>7.3f}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smaller meshes")
    args = ap.parse_args()
    np.seterr(all="ignore")
    part1(args.quick)
    part2(args.quick)


if __name__ == "__main__":
    main()
