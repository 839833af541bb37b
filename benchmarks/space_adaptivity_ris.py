"""Space adaptivity for RIS: adaptive vs uniform meshes on a front whose solution is unique.

    python benchmarks/space_adaptivity_ris.py [--quick] [--tols 0.02,0.01] [--band 0.05]
    python benchmarks/space_adaptivity.py --family ris [--quick]   (calls run_ris_family)

Problem: :func:`rothe.ris.examples.example_front_unique` (``rothe run ris-front-unique``): a
strictly convex energy (c = 1e-3, g = 5 z^2) under a load whose front (width 0.025) sweeps
from the corner (0, 0) to radius 0.9; its evolution is unique and at every time the obstacle
problem of :func:`~rothe.ris.examples.front_unique_state`. All runs use the same uniform step
tau in s (direct solver), so that they differ only in space. Runs, all in this process:

* uniform grids N x N (16 ... 192; the finest one takes at least 30 s in the full run);
* adaptive meshes from the coarsest grid (``SpaceAdaptivity``, several ``space_tol``), refined
  at most to the cell size of the 128 x 128 grid (64 x 64 with ``--quick``).

Error: a step k of the scheme solves (3.1) at the load time t_{k-1}, and on this problem its
z_k is the obstacle solution at t_{k-1} on its own mesh (whenever the ball constraint is
inactive, lambda_k = 0; the table's ``lam>0`` column counts the steps where it was not). So
e = max over the three steps whose load time t_{k-1} is nearest to 0.25, 0.5, 0.75 of
|| z_k - z_ref(t_{k-1}) ||, the L2 norm with the lumped mass of a reference grid twice as fine
as the finest uniform one (384 x 384, 192 x 192 with ``--quick``), z_k (P1 on its mesh)
evaluated at the reference vertices, z_ref the obstacle solution on the reference grid (no
time error enters: the runs' t_k differ). Work: unknowns summed over the accepted steps. Per
adaptive run the summed dofs and the seconds of a uniform run with the same error (log-log
interpolation over the two uniform rows around it) and the ratios; the last two lines are
those ratios for the adaptive run with the smallest error inside the range of the uniform
errors.
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np

from rothe.fem.adapt import SpaceAdaptivity
from rothe.ris.examples import (
    FRONT_UNIQUE_DEFAULTS,
    example_front_unique,
    front_unique_error,
)
from rothe.ris.inner import InnerOptions
from rothe.ris.run import run_ris
from rothe.stepping.controllers import Uniform

TIMES = (0.25, 0.5, 0.75)
DIRECT = InnerOptions(linear_solver="direct")
REACTION = FRONT_UNIQUE_DEFAULTS["reaction"]


def _error(reference, traj, problem):
    """max over the steps whose load time t_{k-1} is nearest to each of TIMES of
    || z_k - z(t_{k-1}) || on the reference grid (:func:`front_unique_error`)."""
    t = np.asarray(traj["t"])
    errs = []
    for tt in TIMES:
        k = int(np.argmin(np.abs(t[:-1] - tt))) + 1  # step k: load time t[k-1], state z[k]
        if traj.meshes is not None:
            points, cells = traj.meshes.mesh(traj["z_mesh_id"][k])
        else:
            points, cells = problem.mesh.p.T, problem.mesh.t.T
        errs.append(front_unique_error(reference, t[k - 1], traj["z"][k], points, cells, REACTION))
    return max(errs)


def _run(n, tau, adapt=None):
    problem = example_front_unique(n)
    t0 = time.perf_counter()
    result = run_ris(problem, Uniform(tau), inner=DIRECT, adapt=adapt)
    seconds = time.perf_counter() - t0
    traj = result.trajectory
    # the process's peak RSS so far (runs go from small to large, so mostly this run's)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    dofs = np.full(len(traj["lam"]), problem.n) if adapt is None else traj["n_dofs"]
    info = {
        "steps": len(traj["lam"]),
        "lam_pos": int(np.count_nonzero(np.asarray(traj["lam"]) > 0)),
        "dofs_max": int(np.max(dofs)),
        "dofs_summed": int(np.sum(dofs)),
        "seconds": seconds,
        "peak_mb": peak,
    }
    if adapt is not None:
        info["adaptations"] = traj.meta["space_adaptations"]
        info["phases"] = {
            k: round(float(v), 2) for k, v in result.statistics.seconds.items() if v > 0.05
        }
    return traj, problem, info


def _uniform_at(rows, err, key):
    """``key`` (summed dofs or seconds) of a uniform run with error ``err``: log-log
    interpolation through the two uniform rows whose errors bracket it (else the nearest two)."""
    u = sorted((r for r in rows if r["mesh"] == "uniform"), key=lambda r: r["error"])
    e = np.log([r["error"] for r in u])
    w = np.log([r[key] for r in u])
    j = int(np.clip(np.searchsorted(e, np.log(err)), 1, len(u) - 1))
    slope = (w[j] - w[j - 1]) / (e[j] - e[j - 1])
    return float(np.exp(w[j - 1] + slope * (np.log(err) - e[j - 1])))


#: the adaptive runs' marking: measured against adapting every step with a Doerfler fraction 0.5
#: and no band (docs/adaptivity.md): adapting every 4th step with a band of 0.08 (the front
#: moves about 0.05 in 4 steps) halves the seconds at the same error
BAND, EVERY, REFINE_FRACTION, COARSEN_FRACTION = 0.08, 4, 0.8, 0.02


def adaptivity(tol, n0, n_fine, band=BAND, every=EVERY, refine_fraction=REFINE_FRACTION):
    """The adaptive runs' options: refine at most to the finest uniform grid's cell size
    (2 bisections halve h)."""
    return SpaceAdaptivity(
        space_tol=tol,
        refine_fraction=refine_fraction,
        coarsen_fraction=min(COARSEN_FRACTION, 1.0 - refine_fraction),
        max_dofs=(n_fine + 1) ** 2,
        max_level=2 * int(round(np.log2(n_fine / n0))),
        refine_band=band,
        adapt_every=every,
    )


def run_ris_family(
    quick: bool,
    tols=None,
    band=BAND,
    every=EVERY,
    refine_fraction=REFINE_FRACTION,
) -> float:
    """Run the RIS part, print the table and the two ratio lines; returns the work ratio of the
    adaptive run with the smallest error inside the uniform range (summed dofs, adaptive /
    uniform at equal error)."""
    # the adaptive meshes refine at most to the n_cap x n_cap grid's h; the finest uniform grid
    # is finer than that, so that the adaptive errors fall inside the uniform range; the
    # reference grid is twice as fine as the finest uniform one (and nested with n_cap's)
    if quick:
        tau, uniform_n, n_cap = 0.02, (8, 16, 32, 64, 96), 64
        tols = (0.2, 0.1, 0.05) if tols is None else tols
    else:
        tau, uniform_n, n_cap = 0.02, (16, 32, 64, 128, 192), 128
        tols = (0.1, 0.05, 0.025, 0.0125) if tols is None else tols
    n0, n_fine = uniform_n[0], n_cap
    wall0 = time.perf_counter()
    n_ref = 2 * uniform_n[-1]
    ref = example_front_unique(n_ref)
    rows = []
    for n in uniform_n:
        traj, problem, info = _run(n, tau)
        info.update(mesh="uniform", param=f"N={n}", error=_error(ref, traj, problem))
        rows.append(info)
        print(f"  uniform N={n}: {info}", flush=True)
    for tol in tols:
        traj, problem, info = _run(
            n0, tau, adaptivity(tol, n0, n_fine, band, every, refine_fraction)
        )
        info.update(
            mesh="adaptive",
            param=f"tol={tol:g}",
            error=_error(ref, traj, problem),
        )
        rows.append(info)
        print(f"  adaptive tol={tol:g}: {info}", flush=True)
    errs = [u["error"] for u in rows if u["mesh"] == "uniform"]
    for r in rows:
        if r["mesh"] == "adaptive":
            r["dofs_ratio"] = r["dofs_summed"] / _uniform_at(rows, r["error"], "dofs_summed")
            r["seconds_ratio"] = r["seconds"] / _uniform_at(rows, r["error"], "seconds")
            r["inside"] = min(errs) <= r["error"] <= max(errs)
    print(
        f"RIS unique front (example_front_unique, ris-front-unique), uniform tau = {tau:g} in s "
        f"for every run; adaptive from {n0}x{n0}, h down to the {n_fine}x{n_fine} grid's; "
        f"reference: the obstacle solution on the {n_ref}x{n_ref} grid; adaptive: "
        f"adapt_every {every}, refine_band {band:g}, refine_fraction {refine_fraction:g}"
    )
    print(
        "error: max over the steps with load time nearest to 0.25, 0.5, 0.75 of the lumped L2 "
        "norm of z_k - z_ref(t_{k-1}); work: unknowns summed over the accepted steps; "
        "lam>0: steps with an active ball"
    )
    head = (
        f"{'mesh':<9} {'param':<11} {'steps':>6} {'lam>0':>5} {'dofs max':>9} "
        f"{'dofs summed':>12} {'error':>10} {'seconds':>8} {'RSS MB':>7} {'dofs ratio':>10} "
        f"{'s ratio':>8}"
    )
    print(head)
    print("-" * len(head))
    for r in rows:
        extra = f" {r['dofs_ratio']:>10.3f} {r['seconds_ratio']:>8.3f}" if "dofs_ratio" in r else ""
        if r["mesh"] == "adaptive" and not r["inside"]:
            extra += "  (extrapolated: error outside the uniform range)"
        print(
            f"{r['mesh']:<9} {r['param']:<11} {r['steps']:>6d} {r['lam_pos']:>5d} "
            f"{r['dofs_max']:>9d} {r['dofs_summed']:>12d} {r['error']:>10.4g} "
            f"{r['seconds']:>8.1f} {r['peak_mb']:>7.0f}{extra}"
        )
    for r in rows:
        if "phases" in r:
            print(f"  phases of adaptive {r['param']} (s): {r['phases']}")
    inside = [r for r in rows if r["mesh"] == "adaptive" and r["inside"]]
    best = min(inside or [r for r in rows if r["mesh"] == "adaptive"], key=lambda r: r["error"])
    print(f"total {time.perf_counter() - wall0:.1f} s; ratios of adaptive {best['param']}")
    print(f"ris: work ratio adaptive/uniform at equal error: {best['dofs_ratio']:.3f}")
    print(f"ris: seconds ratio adaptive/uniform at equal error: {best['seconds_ratio']:.3f}")
    return best["dofs_ratio"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="coarse sizes (about 2 minutes)")
    parser.add_argument(
        "--tols", default=None, help="comma-separated space_tol of the adaptive runs"
    )
    parser.add_argument("--band", type=float, default=BAND, help="refine_band (a length)")
    parser.add_argument("--every", type=int, default=EVERY, help="adapt_every")
    parser.add_argument(
        "--refine-fraction", type=float, default=REFINE_FRACTION, help="Doerfler fraction"
    )
    args = parser.parse_args()
    tols = None if args.tols is None else tuple(float(x) for x in args.tols.split(","))
    run_ris_family(
        args.quick,
        tols=tols,
        band=args.band,
        every=args.every,
        refine_fraction=args.refine_fraction,
    )


if __name__ == "__main__":
    main()
