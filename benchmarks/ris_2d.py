"""Example 7.2 at paper size and far beyond: work, residuals, cost per step and per solve, 3D.

    python benchmarks/ris_2d.py              # everything (about an hour on 2 quiet cores)
    python benchmarks/ris_2d.py --quick      # a smaller version (N = 16; N = 80, 160) to try it out
    python benchmarks/ris_2d.py --part 1     # or 2, 3d; --sizes 160,640 and --control for part 2

Part 1, paper size (40 x 40 cells, 1681 nodes): the table of ``rothe compare ris-2d`` --
adaptive (Alg. 3.2), order2 and regime at tol 1e-4, 1e-5, 1e-6 and uniform at tau = 0.01/2^k,
k = 0..8: steps, rejected, inner solves, Newton iterations, local residual max_k(I1+I2), global
residual sum_k(I1+I2), seconds, and the work ratios to uniform at the same global residual
(interpolated log-log between the bracketing uniform runs), with the equidistribution bound
(the least fraction of uniform's steps any step sequence can need while I ~ C(s) tau^2). Then
where the inner solves go: accepted / rejected attempts by regime of the attempt (sticking,
viscous jump, slip, the first step of a new regime = switch, and the attempts of a step shortened
to land on T), and the share of Newton iterations spent in rejected attempts.
Target (issue 12): regime <= 1/4 of uniform's solves and <= 1/3 of its steps at equal global
residual, every accepted step with I1, I2 < tol.

Part 2, scale: on N x N grids (N = 160, 640, 1000; 1000 is 10^6 nodes), each N in its own
process so that its peak memory is its own. Two representative phases, 10 accepted steps each
with one controller (``--control``, default regime; tol 1e-5):

* jump: from z = 0 at t = 0.17 (exact on every mesh: z = 0 sticks until t ~ 0.1725), i.e. the
  end of sticking and the first steps of the viscous jump (ball active, indefinite Hessian);
* slip: from the 40 x 40 solution at t ~ 0.5, interpolated to the fine grid (the Rothe view
  allows the mesh to change between steps). The coarse interpolant has kinks along the coarse
  edges, so it is far from equilibrium on the fine grid: 5 accepted warm-up steps are timed and
  reported separately ("after mesh change"), then the 10 measured steps follow. These 15 steps
  are still the fine grid's relaxation of that state, a viscous motion with the ball active
  (t stays at 0.50005 while s advances), not rate-independent slip with the ball inactive: what
  they measure is the cost of steps after a mesh change, on the many-nodes-moving active set
  that slip has too. Reaching true slip on the fine grid needs hundreds of relaxation steps.

Every cost is divided by the time of one sparse LU factorization + solve of the stiffness
matrix A on the same mesh, measured in the same process (splu, MMD_AT_PLUS_A): per accepted
step (target <= 5 at 640 x 640) and per inner solve (target <= 2 at 640 x 640, issue 12);
10^6 nodes in under 4 GB; cost per step growing no faster than about N^2 log N^2.

Part 3D: the energy of Example 7.2 on the unit cube (P1 tetrahedra, 8^3 cubes, 343 unknowns):
the part 1 table for tol 1e-4, 1e-5 and uniform tau = 0.01/2^k, k = 0..6.
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


# -- parts 1 and 3D ------------------------------------------------------------------------------
CATEGORIES = ("stick", "jump", "slip", "switch", "landing")


class _Attempts:
    """Wraps the stepper and the controller of one run and files every attempt in a category.

    An attempt belongs to its regime (rothe.ris.controllers.step_regime), or to ``switch``
    when its regime differs from that of the last accepted step, or to ``landing`` when it is
    one of the attempts of a step shortened to land on T; a failed solve counts in its regime.
    """

    def __init__(self, stepper, controller):
        self.stepper, self.controller = stepper, controller
        self.pending = []
        self.counts = {c: [0, 0] for c in CATEGORIES}  # accepted, rejected
        self.newton = [0, 0]  # Newton iterations of accepted / of rejected attempts
        self._last = None

    def step(self, state, tau, s_end=None):
        result = self.stepper.step(state, tau, s_end)
        self.pending.append(result)
        return result

    def decide(self, result):
        from rothe.ris.controllers import step_regime

        decision = self.controller.decide(result)
        group, self.pending = self.pending, []
        for r in group:
            accepted = decision.accept and r is result
            regime = step_regime(r)
            if len(group) > 1:
                category = "landing"
            elif self._last is not None and regime != self._last:
                category = "switch"
            else:
                category = regime
            self.counts[category][0 if accepted else 1] += 1
            self.newton[0 if accepted else 1] += int(r.counters.get("newton_iterations", 0))
        if decision.accept:
            self._last = step_regime(result)
        return decision


class _Proxy:
    """Forward everything to ``inner`` except the given overrides."""

    def __init__(self, inner, **overrides):
        self._inner = inner
        self.__dict__.update(overrides)

    def __getattr__(self, name):
        return getattr(self._inner, name)


def run_logged(problem, control, tol, tau, example):
    """One run as rothe.ris.run.run_ris does it, with every attempt filed (_Attempts)."""
    from rothe.cli.ris_commands import control_object
    from rothe.ris.controllers import build_controller
    from rothe.ris.run import initial_trajectory
    from rothe.ris.stepper import RISState, RISStepper
    from rothe.ris.summary import describe_branch, equidistribution_bound, ris_summary
    from rothe.stepping.evolve import evolve

    controller = build_controller(control_object(control, tol=tol, tau=tau))
    stepper = RISStepper(problem)
    log = _Attempts(stepper, controller)
    traj = initial_trajectory(problem, {"control": controller.name, "tol": tol, "tau0": tau})
    evolve(
        _Proxy(stepper, step=log.step),
        _Proxy(controller, decide=log.decide),
        RISState(0.0, 0.0, problem.z0.copy()),
        traj,
    )
    row = ris_summary(traj, example, describe_branch(problem, traj))
    row.update(tau0=tau, status="completed", n_nodes=problem.n_nodes)
    if control == "uniform":
        row["equidistribution_bound"] = equidistribution_bound(traj["I1"] + traj["I2"])
    return row, log


def work_table(problem, example, controls, tols, taus, tau0=0.1) -> None:
    from rothe.cli.ris_fem_commands import format_table

    runs = [(c, tol, tau0) for c in controls for tol in tols]
    runs += [("uniform", None, tau) for tau in taus]
    rows, logs = [], []
    for control, tol, tau in runs:
        row, log = run_logged(problem, control, tol, tau, example)
        rows.append(row)
        logs.append(log)
    print(format_table(rows))
    print("\nWhere the inner solves go: accepted/rejected attempts by category (see the docstring)")
    head = (
        f"{'control':<9} {'tol/tau':>8} "
        + " ".join(f"{c:>13}" for c in CATEGORIES)
        + f" {'solves':>7} {'Newton in rejected':>18}"
    )
    print(head)
    print("-" * len(head))
    for row, log in zip(rows, logs, strict=True):
        par = row["tau0"] if row["control"] == "uniform" else row["tol"]
        cells = " ".join(f"{log.counts[c][0]:>7}/{log.counts[c][1]:<5}" for c in CATEGORIES)
        newton = sum(log.newton)
        share = log.newton[1] / newton if newton else 0.0
        print(f"{row['control']:<9} {par:>8.3g} {cells} {row['inner_solves']:>7} {share:>17.1%}")


def paper_size(quick: bool) -> None:
    from rothe.cli.ris_fem_commands import COMPARE_CONTROLS, COMPARE_TAUS
    from rothe.ris.examples import example_7_2

    n = 16 if quick else 40
    problem = example_7_2(n)
    print(
        f"Part 1: Example 7.2 on the {n} x {n} grid ({problem.n_nodes} nodes), first step 0.1 "
        "for the step controllers\n"
    )
    tols = (1e-4, 1e-5) if quick else (1e-4, 1e-5, 1e-6)
    taus = COMPARE_TAUS[:8] if quick else COMPARE_TAUS
    work_table(problem, "ris-2d", COMPARE_CONTROLS, tols, taus)


def cube(quick: bool) -> None:
    from rothe.cli.ris_fem_commands import COMPARE_CONTROLS
    from rothe.ris.examples import example_7_2_3d

    n = 4 if quick else 8
    problem = example_7_2_3d(n)
    print(
        f"\nPart 3D: the energy of Example 7.2 on the unit cube, {n}^3 cubes "
        f"({problem.n} unknowns), first step 0.1 for the step controllers\n"
    )
    taus = tuple(0.01 / 2**k for k in range(5 if quick else 7))
    work_table(problem, "ris-3d", COMPARE_CONTROLS, (1e-4,) if quick else (1e-4, 1e-5), taus)


# -- part 2 (one process per N) -------------------------------------------------------------------
def _slip_state(n_fine: int):
    """The 40 x 40 adaptive solution at t ~ 0.5, interpolated to the n_fine x n_fine grid.

    P1 interpolation on the coarse triangles (matplotlib's trapezoid-map locator: O(n log n)
    and no dense point-by-cell matrix, unlike a generic probe).
    """
    from matplotlib.tri import LinearTriInterpolator, Triangulation

    from rothe import Adaptive, run_ris
    from rothe.ris.examples import example_7_2

    coarse = example_7_2(40)
    traj = run_ris(coarse, Adaptive(1e-4, tau=0.01)).trajectory
    k = int(np.searchsorted(traj["t"], 0.5))
    tri = Triangulation(coarse.mesh.p[0], coarse.mesh.p[1], coarse.mesh.t.T)
    interp = LinearTriInterpolator(tri, traj["z"][k])
    fine = example_7_2(n_fine)
    z_fine = np.asarray(interp(fine.mesh.p[0], fine.mesh.p[1]).filled(0.0))[fine.free]
    return float(traj["s"][k]), float(traj["t"][k]), z_fine, float(traj["tau"][k])


def measure(n: int, solver: str, phase: str, steps: int, control: str = "regime") -> dict:
    import scipy.sparse.linalg as spla

    from rothe.cli.ris_commands import control_object
    from rothe.io.trajectory import Trajectory
    from rothe.ris.controllers import build_controller
    from rothe.ris.examples import example_7_2
    from rothe.ris.inner import InnerOptions
    from rothe.ris.stepper import RISState, RISStepper
    from rothe.stepping.evolve import evolve, single_threaded_blas

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
    controller = build_controller(control_object(control, tol=1e-5, tau=tau0))
    warm = {"warmup_s": 0.0, "warmup_accepted": 0, "warmup_rejected": 0}
    if phase == "slip":
        t0 = time.perf_counter()
        state = evolve(stepper, controller, state, traj, max_steps=5)
        warm = {
            "warmup_s": time.perf_counter() - t0,
            "warmup_accepted": traj.stats.accepted_steps,
            "warmup_rejected": traj.stats.rejected_steps,
        }
        traj = Trajectory()
    # the first accepted step alone, then nine more
    t0 = time.perf_counter()
    state = evolve(stepper, controller, state, traj, max_steps=1)
    t_first = time.perf_counter() - t0
    t0 = time.perf_counter()
    evolve(stepper, controller, state, traj, max_steps=steps - 1)
    t_rest = time.perf_counter() - t0
    st = traj.stats
    per_step = (t_first + t_rest) / st.accepted_steps
    per_solve = (t_first + t_rest) / st.inner_solves
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
        "control": control,
        "solves": st.inner_solves,
        "per_solve_s": per_solve,
        "ratio_solve": per_solve / t_lu,
        "accepted": st.accepted_steps,
        "rejected": st.rejected_steps,
        "newton": st.newton_iterations,
        "factorizations": st.linear_factorizations,
        "krylov": st.krylov_iterations,
        "peak_mb": peak_mb(),
        "linear_solver": stepper.solver.linear.kind_used,
        **warm,
    }


def scale(quick: bool, sizes=None, control: str = "regime") -> None:
    sizes = tuple(sizes) if sizes else ((80, 160) if quick else (160, 640, 1000))
    print(
        f"\nPart 2: cost per accepted step and per inner solve on N x N grids ({control}, "
        "tol 1e-5; LU = seconds / one LU factorization + solve of A)\n"
    )
    head = (
        f"{'N':>5} {'unknowns':>9} {'phase':>5} {'solver':>6} {'LU(A) s':>8} {'1st step s':>10} "
        f"{'s/step':>7} {'LU/step':>7} {'solves':>6} {'s/solve':>7} {'LU/solve':>8} {'acc':>4} "
        f"{'rej':>4} {'Newton':>6} {'fact':>5} {'Krylov':>6} {'peak MB':>8}"
    )
    print(head)
    print("-" * len(head))
    rows = []
    for n in sizes:
        for phase in ("jump", "slip"):
            for solver in ("direct", "amg"):
                out = subprocess.run(
                    [sys.executable, __file__, "--one", str(n), solver, phase, control],
                    capture_output=True,
                    text=True,
                    check=True,
                )
                r = json.loads(out.stdout.strip().splitlines()[-1])
                rows.append(r)
                print(
                    f"{r['N']:>5} {r['unknowns']:>9} {phase:>5} {solver:>6} {r['lu_s']:>8.3f} "
                    f"{r['first_step_s']:>10.2f} {r['per_step_s']:>7.2f} {r['ratio']:>7.2f} "
                    f"{r['solves']:>6} {r['per_solve_s']:>7.2f} {r['ratio_solve']:>8.2f} "
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
    parser.add_argument(
        "--one", nargs=4, metavar=("N", "SOLVER", "PHASE", "CONTROL"), help=argparse.SUPPRESS
    )
    parser.add_argument("--part", choices=("1", "2", "3d", "all"), default="all")
    parser.add_argument("--sizes", default=None, help="grids N of part 2, e.g. 160,640")
    parser.add_argument(
        "--control", default="regime", help="step controller of part 2 (default regime)"
    )
    args = parser.parse_args()
    if args.one:
        n, solver, phase, control = int(args.one[0]), args.one[1], args.one[2], args.one[3]
        print(json.dumps(measure(n, solver, phase, steps=10, control=control)))
        return
    if args.part in ("1", "all"):
        paper_size(args.quick)
    if args.part in ("2", "all"):
        sizes = [int(x) for x in args.sizes.split(",")] if args.sizes else None
        scale(args.quick, sizes, args.control)
    if args.part in ("3d", "all"):
        cube(args.quick)


if __name__ == "__main__":
    main()
