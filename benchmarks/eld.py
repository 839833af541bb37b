"""Elastodynamics (Altmann 2015, scheme (3.4)): cost per step against one back-substitution,
Newton iterations with nonlinear damping, and the 3D cantilever at more than a million unknowns.

    python benchmarks/eld.py                 # all parts (the 1.07M-dof beam takes ~3 minutes)
    python benchmarks/eld.py --part steps    # 2D/3D per-step costs only
    python benchmarks/eld.py --part beam --beam-n 44 --beam-steps 5

Part "steps": the manufactured solution (P2 on an n x n square) and a small cantilever (P1, LU),
linear Rayleigh damping and the nonlinear damping D v = b K v - d0 M v + d_nl N(v), both forms.
Per run: steps, factorizations, back-substitutions per step, Newton iterations per step, seconds
per step, the median time of one back-substitution with the *same* factorization (measured in
the same run, after it), and their ratio. Targets (issue 5): linear damping one factorization
for the whole run and time per step <= 3 back-substitutions; nonlinear damping <= 4 Newton
iterations per step on average.

Part "beam": the 3D cantilever (E = 1000, nu = 0.3, rho = 1, held end moved by G(t)) with
n cells across and 4n along (n = 44: 1,075,275 unknowns), regularized form, Rayleigh damping,
pyamg smoothed aggregation with the rigid-body modes as near-null space and CG to 1e-8.
Runs in a subprocess so that its peak memory (ru_maxrss) is its own. Target: under 8 GB.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

from rothe.eld import NonlinearDamping, RayleighDamping, beam_problem, mms_problem, run_eld


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def step_row(label, problem, form, tau):
    traj = run_eld(problem, form, tau, store_fields=False)
    stepper = traj.stepper
    n = stepper.A_II.shape[0] if form == "regularized" else stepper._kkt_lin.shape[0]
    backsolve = stepper.solver.time_backsolve(n, repeats=30)
    st = traj.stats
    steps = st.accepted_steps
    per_step = st.wall_time_s / steps
    info = traj.meta["linear_solver"]
    return {
        "case": label, "form": form, "unknowns": n, "steps": steps,
        "factorizations": info["factorizations"],
        "backsolves_per_step": info["backsolves"] / steps,
        "newton_per_step": st.newton_iterations / steps,
        "seconds_per_step": per_step, "backsolve_seconds": backsolve,
        "ratio": per_step / backsolve,
    }


def part_steps(n2d: int, n3d: int, tau: float) -> list[dict]:
    rows = []
    rayleigh_2d, nonlinear_2d = RayleighDamping(0.1, 0.01), NonlinearDamping(0.01, 0.5, 1.0)
    rayleigh_3d, nonlinear_3d = RayleighDamping(0.0, 0.002), NonlinearDamping(0.002, 0.5, 1.0)
    cases = [
        (f"2D P2 n={n2d}, Rayleigh", lambda: mms_problem(n2d, 2, damping=rayleigh_2d)[0]),
        (f"2D P2 n={n2d}, nonlinear", lambda: mms_problem(n2d, 2, damping=nonlinear_2d)[0]),
        (f"3D P1 beam n={n3d}, Rayleigh", lambda: beam_problem(n3d, damping=rayleigh_3d, T=1.0)),
        (f"3D P1 beam n={n3d}, nonlinear", lambda: beam_problem(n3d, damping=nonlinear_3d, T=1.0)),
    ]
    for label, build in cases:
        problem = build()
        for form in ("regularized", "original"):
            rows.append(step_row(label, problem, form, tau))
            print_rows(rows[-1:], header=len(rows) == 1)
    return rows


def print_rows(rows, header=True):
    if header:
        head = (f"{'case':<30} {'form':<12} {'unknowns':>9} {'steps':>6} {'factor.':>7} "
                f"{'backsolves/step':>15} {'newton/step':>11} {'s/step':>9} {'s/backsolve':>11} "
                f"{'ratio':>6}")
        print(head)
        print("-" * len(head))
    for r in rows:
        print(f"{r['case']:<30} {r['form']:<12} {r['unknowns']:>9d} {r['steps']:>6d} "
              f"{r['factorizations']:>7d} {r['backsolves_per_step']:>15.2f} "
              f"{r['newton_per_step']:>11.2f} {r['seconds_per_step']:>9.2e} "
              f"{r['backsolve_seconds']:>11.2e} {r['ratio']:>6.2f}", flush=True)


def beam_child(n: int, steps: int) -> dict:
    """One beam run; returns the measurements (called in a subprocess)."""
    tau = 0.01
    t0 = time.perf_counter()
    problem = beam_problem(n, damping=RayleighDamping(0.0, 0.002), T=steps * tau)
    t_assembly = time.perf_counter() - t0
    t0 = time.perf_counter()
    traj = run_eld(problem, "regularized", tau, solver="amg", store_fields=False,
                   linear_rtol=1e-8)
    t_total = time.perf_counter() - t0
    info = traj.meta["linear_solver"]
    st = traj.stats
    return {
        "n": n, "unknowns": problem.space.ndofs, "free_unknowns": int(traj.stepper.I.size),
        "tetrahedra": int(problem.space.mesh.t.shape[1]), "steps": st.accepted_steps,
        "assembly_seconds": t_assembly, "amg_setup_seconds": info["setup_seconds"],
        "run_seconds": t_total, "seconds_per_step": st.wall_time_s / st.accepted_steps,
        "cg_iterations_per_step": info["krylov_iterations"] / st.accepted_steps,
        "peak_memory_mb": peak_mb(),
        "balance_residual_max": float(abs(traj["balance_residual"]).max()),
        "reaction_left_final": traj["reaction_left"][-1].tolist(),
    }


def part_beam(n: int, steps: int) -> dict:
    cmd = [sys.executable, __file__, "--beam-child", str(n), str(steps)]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    row = json.loads(out.strip().splitlines()[-1])
    head = (f"{'unknowns':>10} {'tets':>9} {'steps':>5} {'assembly s':>10} {'AMG setup s':>11} "
            f"{'s/step':>8} {'CG its/step':>11} {'peak MB':>8}")
    print(head)
    print("-" * len(head))
    print(f"{row['unknowns']:>10d} {row['tetrahedra']:>9d} {row['steps']:>5d} "
          f"{row['assembly_seconds']:>10.1f} {row['amg_setup_seconds']:>11.1f} "
          f"{row['seconds_per_step']:>8.2f} {row['cg_iterations_per_step']:>11.1f} "
          f"{row['peak_memory_mb']:>8.0f}")
    print(f"energy balance residual max {row['balance_residual_max']:.2e}; reaction at the held "
          f"end at t = {steps * 0.01:g}: {row['reaction_left_final']}")
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", default="all", choices=("all", "steps", "beam"))
    parser.add_argument("--n2d", type=int, default=64, help="2D cells per side (default 64)")
    parser.add_argument("--n3d", type=int, default=8, help="beam cells across for LU (default 8)")
    parser.add_argument("--tau", type=float, default=0.01)
    parser.add_argument("--beam-n", type=int, default=44, help="beam cells across (default 44)")
    parser.add_argument("--beam-steps", type=int, default=5)
    parser.add_argument("--beam-child", nargs=2, type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.beam_child:
        print(json.dumps(beam_child(*args.beam_child)))
        return 0
    if args.part in ("all", "steps"):
        print("Per-step cost against one back-substitution with the same factorization")
        part_steps(args.n2d, args.n3d, args.tau)
        print()
    if args.part in ("all", "beam"):
        print("3D cantilever, regularized form, pyamg SA + rigid-body modes, CG to 1e-8")
        part_beam(args.beam_n, args.beam_steps)
    return 0


if __name__ == "__main__":
    sys.exit(main())
