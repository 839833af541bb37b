"""Cost of mesh adaptation (rothe.fem.adapt) against a P1 stiffness assembly and factorization.

    python benchmarks/adapt_mesh.py            # 2D 10^5 and 10^6 cells, 3D ~10^5 cells
    python benchmarks/adapt_mesh.py --quick    # 2D 10^5 and 3D 3*10^4 cells

A ring-shaped front moves across the unit square/cube (scikit-fem Kuhn/tensor meshes with named
sides). Every step coarsens the cells behind the front and refines the cells on it (two extra
generations at most), exactly what a stepper does after an accepted step. Per step (median of
the measured steps) the table reports:

* ``adapt``: ``AdaptiveMesh.adapt`` (coarsening + bisection + conformity closure + compaction);
* ``mesh``: the scikit-fem mesh with its named boundaries (facets computed by rothe);
* ``T P1``, ``T P2``, ``T P2vec``: the transfer matrices (scalar P1 and P2, which numbers the
  edges of the new mesh; vector P2, interleaved, up to 5*10^5 cells: at 2*10^6 cells its 8.6
  million rows would take the process over 3 GB);
* ``K P1``: ``rothe.fem.scalar.stiffness`` on the adapted mesh; ``LU``: splu (MMD_AT_PLUS_A) of
  its interior block; the ratio ``adapt / (K + LU)`` is the target ("well under 1"). The LU is
  skipped ("-") above 3*10^5 unknowns in 2D (at 10^6 it alone needs more than the 3 GB a
  process may use here; PERFORMANCE-NOTES: 1.7 GB and 11 s) and 2*10^4 in 3D (minutes each).

Setup (``AdaptiveMesh(mesh)`` on the initial mesh) is reported once. Times are wall seconds on
a shared machine: compare the ratios, measured in the same run.
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np
import scipy.sparse.linalg as spla


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def timed(f, *args, **kwargs):
    t0 = time.perf_counter()
    out = f(*args, **kwargs)
    return out, time.perf_counter() - t0


def front_masks(am, radius, width, max_level):
    c = am.points[am.cells].mean(axis=1)
    r = np.linalg.norm(c - 0.5, axis=1)
    on = np.abs(r - radius) < width
    return on & (am.levels < max_level), np.abs(r - radius) > 2 * width


def run(label: str, mesh, steps: int, max_level: int) -> dict:
    from rothe.fem.adapt import AdaptiveMesh
    from rothe.fem.scalar import boundary_nodes, stiffness

    am, t_setup = timed(AdaptiveMesh, mesh)
    d = am.dim
    n0 = am.n_cells
    # bring the front to its refined state first (not timed)
    for _ in range(max_level):
        refine, _ = front_masks(am, 0.25, 0.04, max_level)
        am.adapt(refine=refine)
    rows = []
    for k in range(steps):
        refine, coarsen = front_masks(am, 0.25 + 0.03 * (k + 1), 0.04, max_level)
        change, t_adapt = timed(am.adapt, refine=refine, coarsen=coarsen)
        m, t_mesh = timed(lambda: am.mesh)
        _, t_p1 = timed(change.transfer, 1)
        _, t_p2s = timed(change.transfer, 2)
        t_p2 = float("nan")
        if am.n_cells <= 500_000:
            _, t_p2 = timed(change.transfer, 2, d)
        K, t_k = timed(stiffness, m)
        t_lu = float("nan")
        free = np.setdiff1d(np.arange(m.p.shape[1]), boundary_nodes(m))
        if free.size <= (300_000 if d == 2 else 20_000):
            A = K[free][:, free].tocsc()
            _, t_lu = timed(spla.splu, A, permc_spec="MMD_AT_PLUS_A")
            del A, _
        rows.append(
            (
                am.n_cells,
                change.bisections,
                change.merges,
                t_adapt,
                t_mesh,
                t_p1,
                t_p2s,
                t_p2,
                t_k,
                t_lu,
            )
        )
    arr = np.array(rows, dtype=float)
    med = np.median(arr, axis=0)
    return {
        "label": label,
        "initial": n0,
        "cells": int(med[0]),
        "bisections": int(med[1]),
        "merges": int(med[2]),
        "setup": t_setup,
        "adapt": med[3],
        "mesh": med[4],
        "p1": med[5],
        "p2s": med[6],
        "p2": med[7],
        "K": med[8],
        "LU": med[9],
        "peak": peak_mb(),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small meshes only")
    ap.add_argument("--steps", type=int, default=5, help="measured front steps per mesh")
    args = ap.parse_args()
    from rothe.fem import mesh as meshes

    cases = [("2D 1e5", lambda: meshes.unit_square(224, named=True), 3)]
    if args.quick:
        cases.append(("3D 3e4", lambda: meshes.box(17, 17, 17), 3))
    else:
        cases.append(("2D 1e6", lambda: meshes.unit_square(708, named=True), 3))
        cases.append(("3D 1e5", lambda: meshes.box(26, 26, 26), 3))
    head = (
        f"{'mesh':<7} {'cells0':>8} {'cells':>8} {'bisect':>7} {'merge':>7} {'setup':>7} "
        f"{'adapt':>7} {'mesh':>7} {'T P1':>7} {'T P2':>7} {'T P2vec':>8} {'K P1':>7} "
        f"{'LU':>7} "
        f"{'adapt/K':>8} {'adapt/(K+LU)':>12} {'peak MB':>8}"
    )
    print(head)
    print("-" * len(head))
    for label, build, levels in cases:
        r = run(label, build(), args.steps, levels)
        have_lu = np.isfinite(r["LU"])
        lu = f"{r['LU']:.3f}" if have_lu else "-"
        ratio = f"{r['adapt'] / (r['K'] + r['LU']):.3f}" if have_lu else "-"
        p2v = f"{r['p2']:.3f}" if np.isfinite(r["p2"]) else "-"
        print(
            f"{r['label']:<7} {r['initial']:>8} {r['cells']:>8} {r['bisections']:>7} "
            f"{r['merges']:>7} {r['setup']:>7.3f} {r['adapt']:>7.3f} {r['mesh']:>7.3f} "
            f"{r['p1']:>7.3f} {r['p2s']:>7.3f} {p2v:>8} {r['K']:>7.3f} {lu:>7} "
            f"{r['adapt'] / r['K']:>8.2f} {ratio:>12} {r['peak']:>8.0f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
