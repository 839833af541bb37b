"""Space adaptivity for RIS: adaptive vs uniform meshes on the moving phase front (ris-front).

    python benchmarks/space_adaptivity_ris.py [--quick]

(to be joined into ``benchmarks/space_adaptivity.py --family ris``: :func:`run_ris_family`).

Problem: :func:`rothe.ris.examples.example_front` (a phase front sweeping the unit square,
c = 0.1), all runs with the same uniform step tau in s, so that the runs differ only in space.
Runs, all in this process:

* a reference on a fine uniform grid (the finest mesh of the run);
* uniform grids N x N;
* adaptive meshes from a coarse grid (``SpaceAdaptivity``, several ``space_tol``).

Error: e = max over t in {0.25, 0.5, 0.75} of || z_h(t) - z_ref(t) ||, the L2 norm with the lumped
mass of the reference mesh (the V-norm of the scheme) after evaluating z_h (P1 on its own mesh)
at the reference vertices, z(t) being the last accepted state with t_k <= t. Work: unknowns
summed over the accepted steps (each step solves on its own mesh). The adaptive meshes start
from a coarse grid and refine at most to the reference's cell size. Then per adaptive run the
summed dofs of a uniform run with the same error (log-log interpolation over the uniform rows)
and the ratio; the last line is that ratio for the most accurate adaptive run.
"""

from __future__ import annotations

import argparse
import resource
import time

import matplotlib.tri as mtri
import numpy as np

from rothe.fem.adapt import SpaceAdaptivity
from rothe.ris.examples import example_front
from rothe.ris.inner import InnerOptions
from rothe.ris.run import run_ris
from rothe.ris.summary import nodal_volumes
from rothe.stepping.controllers import Uniform

TIMES = (0.25, 0.5, 0.75)
DIRECT = InnerOptions(linear_solver="direct")


def _states_at(traj, times):
    """(z, mesh) of the last accepted state with t_k <= t, for each t."""
    t = np.asarray(traj["t"])
    z_all = traj["z"]
    out = []
    for tt in times:
        i = int(np.searchsorted(t, tt, side="right") - 1)
        if traj.meshes is not None:
            points, cells = traj.meshes.mesh(traj["z_mesh_id"][i])
        else:
            points, cells = traj.meta["_points"], traj.meta["_cells"]
        out.append((np.asarray(z_all[i]), points, cells))
    return out


def _error(run_states, ref_states, ref_points, ref_mass):
    errs = []
    for (z, points, cells), (zr, _, _) in zip(run_states, ref_states, strict=True):
        interp = mtri.LinearTriInterpolator(
            mtri.Triangulation(points[:, 0], points[:, 1], cells), z
        )
        zh = np.asarray(interp(ref_points[:, 0], ref_points[:, 1]).filled(np.nan))
        errs.append(float(np.sqrt(np.sum(ref_mass * (zh - zr) ** 2))))
    return max(errs)


def _run(n, tau, adapt=None):
    problem = example_front(n)
    t0 = time.perf_counter()
    traj = run_ris(problem, Uniform(tau), inner=DIRECT, adapt=adapt).trajectory
    seconds = time.perf_counter() - t0
    # the process's peak RSS so far (runs go from small to large, so mostly this run's)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    if adapt is None:
        traj.meta["_points"], traj.meta["_cells"] = problem.mesh.p.T, problem.mesh.t.T
        dofs = np.full(len(traj), problem.n)
    else:
        dofs = np.asarray(traj["n_dofs"])[1:]
    return traj, {
        "steps": len(traj),
        "dofs_max": int(dofs.max()),
        "dofs_summed": int(dofs.sum()),
        "seconds": seconds,
        "peak_mb": peak,
    }


def _uniform_work_at(rows, err):
    """Summed dofs of a uniform run with error ``err`` (log-log interpolation/extrapolation
    through the two uniform rows whose errors bracket it, else the nearest two)."""
    u = sorted((r for r in rows if r["mesh"] == "uniform"), key=lambda r: r["error"])
    e = np.log([r["error"] for r in u])
    w = np.log([r["dofs_summed"] for r in u])
    j = int(np.clip(np.searchsorted(e, np.log(err)), 1, len(u) - 1))
    slope = (w[j] - w[j - 1]) / (e[j] - e[j - 1])
    return float(np.exp(w[j - 1] + slope * (np.log(err) - e[j - 1])))


def run_ris_family(quick: bool) -> float:
    """Run the RIS part, print the table; returns the work ratio of the most accurate adaptive
    run (summed dofs, adaptive / uniform at equal error)."""
    # same tau for every run; the adaptive meshes start from the n0 x n0 grid and refine at
    # most to the reference's cell size (max_level bisections: h_ref = h0 / 2^(level/2))
    if quick:
        tau, n_ref, uniform_n, n0 = 0.05, 48, (6, 12, 24, 36), 6
        tols = (4.0, 1.0)
    else:
        tau, n_ref, uniform_n, n0 = 0.05, 64, (8, 16, 32, 48), 8
        tols = (4.0, 2.0, 1.0)
    max_level = 2 * int(round(np.log2(n_ref / n0)))
    wall0 = time.perf_counter()
    ref, ref_info = _run(n_ref, tau)
    print(f"  reference N={n_ref}: {ref_info}", flush=True)
    ref_states = _states_at(ref, TIMES)
    ref_points = ref_states[0][1]
    ref_mass = nodal_volumes(ref_points, ref_states[0][2])
    rows = []
    for n in uniform_n:
        traj, info = _run(n, tau)
        info.update(
            mesh="uniform",
            param=f"N={n}",
            error=_error(_states_at(traj, TIMES), ref_states, ref_points, ref_mass),
        )
        rows.append(info)
        print(f"  uniform N={n}: {info}", flush=True)
    for tol in tols:
        adapt = SpaceAdaptivity(
            space_tol=tol,
            refine_fraction=0.5,
            coarsen_fraction=0.05,
            max_dofs=(n_ref + 1) ** 2,
            max_level=max_level,
        )
        traj, info = _run(n0, tau, adapt)
        info.update(
            mesh="adaptive",
            param=f"tol={tol:g}",
            error=_error(_states_at(traj, TIMES), ref_states, ref_points, ref_mass),
            adaptations=traj.meta["space_adaptations"],
        )
        rows.append(info)
        print(f"  adaptive tol={tol:g}: {info}", flush=True)
    for r in rows:
        if r["mesh"] == "adaptive":
            r["uniform_at_error"] = _uniform_work_at(rows, r["error"])
            r["ratio"] = r["dofs_summed"] / r["uniform_at_error"]
            errs = [u["error"] for u in rows if u["mesh"] == "uniform"]
            r["extrapolated"] = not min(errs) <= r["error"] <= max(errs)
    print(
        f"RIS front (example_front, c = 0.1), uniform tau = {tau:g} in s for every run; "
        f"reference: uniform {n_ref}x{n_ref} grid ({(n_ref + 1) ** 2} nodes, "
        f"{ref_info['steps']} steps, {ref_info['seconds']:.1f} s)"
    )
    print(
        "error: max over t in {0.25, 0.5, 0.75} of the lumped L2 norm of z_h(t) - z_ref(t) on "
        "the reference mesh; work: unknowns summed over the accepted steps"
    )
    head = (
        f"{'mesh':<9} {'param':<9} {'steps':>6} {'dofs max':>9} {'dofs summed':>12} "
        f"{'error':>10} {'seconds':>8} {'RSS MB':>8} {'unif. dofs@err':>14} {'ratio':>6}"
    )
    print(head)
    print("-" * len(head))
    for r in rows:
        extra = f" {r['uniform_at_error']:>14.4g} {r['ratio']:>6.3f}" if "ratio" in r else ""
        if r.get("extrapolated"):
            extra += "  (extrapolated: error outside the uniform rows)"
        print(
            f"{r['mesh']:<9} {r['param']:<9} {r['steps']:>6d} {r['dofs_max']:>9d} "
            f"{r['dofs_summed']:>12d} {r['error']:>10.4g} {r['seconds']:>8.1f} "
            f"{r['peak_mb']:>8.1f}{extra}"
        )
    best = min((r for r in rows if r["mesh"] == "adaptive"), key=lambda r: r["error"])
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(
        f"total {time.perf_counter() - wall0:.1f} s, peak RSS {rss:.0f} MB (RSS MB: the "
        "process's peak after each run; the reference ran first)"
    )
    print(f"work ratio adaptive/uniform at equal error: {best['ratio']:.3f}")
    return best["ratio"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="coarse sizes (under 3 minutes)")
    args = parser.parse_args()
    run_ris_family(args.quick)


if __name__ == "__main__":
    main()
