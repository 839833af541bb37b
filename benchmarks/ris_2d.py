"""Example 7.2 at paper size and far beyond: work, residuals, cost per step, memory.

    python benchmarks/ris_2d.py              # everything (about half an hour on 2 cores)
    python benchmarks/ris_2d.py --quick      # a smaller version (N = 80, 160) to try it out

Part 1, paper size (40 x 40 cells, 1681 nodes): adaptive at tol 1e-4, 1e-5, 1e-6 and uniform at
several tau: steps, rejected, inner solves, Newton iterations, wall time, local residual
max_k(I1+I2) and global residual sum_k(I1+I2).

Part 2, scale: on N x N grids (N = 160, 640, 1000; 1000 is 10^6 nodes), each N in its own
process so that its peak memory is its own. Two representative phases, 10 accepted steps each
with the adaptive controller (tol 1e-5):

* jump: from z = 0 at t = 0.17 (exact on every mesh: z = 0 sticks until t ~ 0.1725), i.e. the
  end of sticking and the first steps of the viscous jump (ball active, indefinite Hessian);
* slip: from the 40 x 40 solution at t ~ 0.5, interpolated to the fine grid (the Rothe view
  allows the mesh to change between steps), i.e. rate-independent slip (ball inactive). The
  coarse interpolant has kinks along the coarse edges, so the first fine steps relax a state far
  from equilibrium: 5 accepted warm-up steps are timed and reported separately ("after mesh
  change"), then the 10 measured steps follow.

Every cost is divided by the time of one sparse LU factorization + solve of the stiffness
matrix A on the same mesh, measured in the same process (splu, MMD_AT_PLUS_A). Targets: at most 5
on the 640 x 640 grid; 10^6 nodes in under 4 GB; cost per step growing no faster than about
N^2 log N^2.
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import subprocess
import sys
import time

import numpy as np


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


# -- part 1 -------------------------------------------------------------------------------------
def paper_size(quick: bool) -> None:
    from rothe import run_ris
    from rothe.problems.ris_fem import example_7_2

    problem = example_7_2(40)
    print("Part 1: Example 7.2 on the 40 x 40 grid (1681 nodes), tau0 = 0.01 for adaptive\n")
    head = (
        f"{'control':<9} {'tol/tau':>8} {'steps':>6} {'rejected':>8} {'solves':>7} "
        f"{'Newton':>7} {'seconds':>8} {'local res':>10} {'global res':>10} "
        f"{'t_final':>7} {'E_final':>9}"
    )
    print(head)
    print("-" * len(head))
    runs = [("adaptive", tol, 0.01) for tol in ((1e-4, 1e-5) if quick else (1e-4, 1e-5, 1e-6))]
    runs += [
        ("uniform", None, tau) for tau in ((1e-2, 5e-3) if quick else (1e-2, 5e-3, 2e-3, 1e-3))
    ]
    for control, tol, tau in runs:
        traj = run_ris(problem, control, tol=tol, tau=tau)
        st = traj.stats
        res = traj["I1"] + traj["I2"]
        par = tol if control != "uniform" else tau
        print(
            f"{control:<9} {par:>8.0e} {st.accepted_steps:>6} {st.rejected_steps:>8} "
            f"{st.inner_solves:>7} {st.newton_iterations:>7} {st.wall_time_s:>8.2f} "
            f"{res.max():>10.3e} {res.sum():>10.3e} {traj['t'][-1]:>7.4f} "
            f"{traj['energy'][-1]:>9.3f}"
        )


# -- part 2 (one process per N) -------------------------------------------------------------------
class _Limited:
    """Stop the evolve loop after a number of accepted steps."""

    def __init__(self, stepper, steps):
        self._stepper, self._stop = stepper, steps

    def __getattr__(self, name):
        return getattr(self._stepper, name)

    def finished(self, state):
        return state.k >= self._stop or self._stepper.finished(state)


def _slip_state(n_fine: int):
    """The 40 x 40 adaptive solution at t ~ 0.5, interpolated to the n_fine x n_fine grid.

    P1 interpolation on the coarse triangles (matplotlib's trapezoid-map locator: O(n log n)
    and no dense point-by-cell matrix, unlike a generic probe).
    """
    from matplotlib.tri import LinearTriInterpolator, Triangulation

    from rothe import run_ris
    from rothe.problems.ris_fem import example_7_2

    coarse = example_7_2(40)
    traj = run_ris(coarse, "adaptive", tol=1e-4, tau=0.01)
    k = int(np.searchsorted(traj["t"], 0.5))
    tri = Triangulation(coarse.mesh.p[0], coarse.mesh.p[1], coarse.mesh.t.T)
    interp = LinearTriInterpolator(tri, traj["z"][k])
    fine = example_7_2(n_fine)
    z_fine = np.asarray(interp(fine.mesh.p[0], fine.mesh.p[1]).filled(0.0))[fine.free]
    return float(traj["s"][k]), float(traj["t"][k]), z_fine, float(traj["tau"][k])


def measure(n: int, solver: str, phase: str, steps: int) -> dict:
    import scipy.sparse.linalg as spla

    from rothe.control.controllers import AdaptiveController
    from rothe.io.trajectory import Trajectory
    from rothe.nonlinear.ris_inner import InnerOptions
    from rothe.problems.ris_fem import example_7_2
    from rothe.stepping.evolve import evolve, single_threaded_blas
    from rothe.stepping.ris import RISState, RISStepper

    t0 = time.perf_counter()
    problem = example_7_2(n)
    t_build = time.perf_counter() - t0
    with single_threaded_blas():
        best = math.inf
        for _ in range(2):
            t0 = time.perf_counter()
            lu = spla.splu(problem.A.tocsc(), permc_spec="MMD_AT_PLUS_A")
            lu.solve(np.ones(problem.n))
            best = min(best, time.perf_counter() - t0)
            del lu
    t_lu = best
    if phase == "jump":
        state = RISState(s=0.0, t=0.17, z=problem.z0.copy())
        tau0 = 0.004
    else:
        s0, t_start, z, tau0 = _slip_state(n)
        state = RISState(s=s0, t=t_start, z=z)
    stepper = RISStepper(problem, InnerOptions(linear_solver=solver))
    traj = Trajectory()
    controller = AdaptiveController(1e-5, tau0)
    warm = {"warmup_s": 0.0, "warmup_accepted": 0, "warmup_rejected": 0}
    if phase == "slip":
        t0 = time.perf_counter()
        state = evolve(_Limited(stepper, state.k + 5), controller, state, traj)
        warm = {
            "warmup_s": time.perf_counter() - t0,
            "warmup_accepted": traj.stats.accepted_steps,
            "warmup_rejected": traj.stats.rejected_steps,
        }
        traj = Trajectory()
    # the first accepted step alone, then nine more
    t0 = time.perf_counter()
    state = evolve(_Limited(stepper, state.k + 1), controller, state, traj)
    t_first = time.perf_counter() - t0
    t0 = time.perf_counter()
    evolve(_Limited(stepper, state.k + steps - 1), controller, state, traj)
    t_rest = time.perf_counter() - t0
    st = traj.stats
    per_step = (t_first + t_rest) / st.accepted_steps
    return {
        "N": n,
        "nodes": problem.n_nodes,
        "unknowns": problem.n,
        "solver": solver,
        "phase": phase,
        "build_s": t_build,
        "lu_s": t_lu,
        "first_step_s": t_first,
        "per_step_s": per_step,
        "ratio": per_step / t_lu,
        "accepted": st.accepted_steps,
        "rejected": st.rejected_steps,
        "newton": st.newton_iterations,
        "factorizations": st.linear_factorizations,
        "krylov": st.krylov_iterations,
        "peak_mb": peak_mb(),
        "linear_solver": stepper.solver.linear.kind_used,
        **warm,
    }


def scale(quick: bool) -> None:
    sizes = (80, 160) if quick else (160, 640, 1000)
    print(
        "\nPart 2: cost per accepted step on N x N grids (adaptive, tol 1e-5; "
        "ratio = seconds per accepted step / one LU factorization + solve of A)\n"
    )
    head = (
        f"{'N':>5} {'unknowns':>9} {'phase':>5} {'solver':>6} {'LU(A) s':>8} {'1st step s':>10} "
        f"{'s/step':>7} {'ratio':>6} {'acc':>4} {'rej':>4} {'Newton':>6} {'fact':>5} "
        f"{'Krylov':>6} {'peak MB':>8}"
    )
    print(head)
    print("-" * len(head))
    rows = []
    for n in sizes:
        for phase in ("jump", "slip"):
            for solver in ("direct", "amg"):
                out = subprocess.run(
                    [sys.executable, __file__, "--one", str(n), solver, phase],
                    capture_output=True,
                    text=True,
                    check=True,
                )
                r = json.loads(out.stdout.strip().splitlines()[-1])
                rows.append(r)
                print(
                    f"{r['N']:>5} {r['unknowns']:>9} {phase:>5} {solver:>6} {r['lu_s']:>8.3f} "
                    f"{r['first_step_s']:>10.2f} {r['per_step_s']:>7.2f} {r['ratio']:>6.2f} "
                    f"{r['accepted']:>4} {r['rejected']:>4} {r['newton']:>6} "
                    f"{r['factorizations']:>5} {r['krylov']:>6} {r['peak_mb']:>8.0f}",
                    flush=True,
                )
                if phase == "slip":
                    print(
                        f"{'':>16} after mesh change: {r['warmup_accepted']} steps "
                        f"({r['warmup_rejected']} rejected) in {r['warmup_s']:.2f} s = "
                        f"{r['warmup_s'] / r['warmup_accepted'] / r['lu_s']:.2f} LU(A) per step",
                        flush=True,
                    )
    print(
        "\nGrowth of the cost per accepted step against N^2 log N^2 (relative to the smallest N):"
    )
    base = sizes[0]
    for phase in ("jump", "slip"):
        for solver in ("direct", "amg"):
            rs = [r for r in rows if r["phase"] == phase and r["solver"] == solver]
            r0 = rs[0]
            parts = []
            for r in rs:
                model = (r["N"] ** 2 * math.log(r["N"] ** 2)) / (base**2 * math.log(base**2))
                parts.append(
                    f"N={r['N']}: {r['per_step_s'] / r0['per_step_s']:.1f}x "
                    f"(N^2 log N^2: {model:.1f}x)"
                )
            print(f"  {phase:<5} {solver:<6} " + ", ".join(parts))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--one", nargs=3, metavar=("N", "SOLVER", "PHASE"), help=argparse.SUPPRESS)
    parser.add_argument("--part", choices=("1", "2", "all"), default="all")
    args = parser.parse_args()
    if args.one:
        n, solver, phase = int(args.one[0]), args.one[1], args.one[2]
        print(json.dumps(measure(n, solver, phase, steps=10)))
        return
    if args.part in ("1", "all"):
        paper_size(args.quick)
    if args.part in ("2", "all"):
        scale(args.quick)


if __name__ == "__main__":
    main()
