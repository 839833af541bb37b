"""One mesh on many processes: rothe's PETSc backend against serial rothe and FEniCSx 0.11.

The P1 beam of ``rothe run eld-beam`` (E = 1000, nu = 0.3, rho = 1, Rayleigh b = 0.002, G(t) on
x = 0), implicit Euler, tau = 0.01, ``--steps`` steps, CG to 1e-8, every tool its own process,
the tools alternating inside each repeat (docs/scaling.md, "Measured"):

- ``rothe serial``: the default install, without petsc4py (pyamg smoothed aggregation + CG;
  ``--backend serial``; the child of ``benchmarks/eld_peers.py``);
- ``rothe petsc N=k``: ``mpiexec -n k`` with ``run_eld(..., backend='petsc')`` (PETSc CG + GAMG
  with the rigid-body near-nullspace, regularized form); N = 1 is also what ``rothe run
  eld-beam`` takes by default on one process where petsc4py is installed (``--backend auto``);
- ``rothe petsc N=k lean`` (``--lean``, default N = 2): the same with ``amg_products='lean'``
  (GAMG's all-at-once Galerkin product on its finest level: less memory, slower set-up);
- ``dolfinx N=k``: FEniCSx 0.11 (``../shared/anchors/eld_beam_dolfinx011.py``, strong
  Dirichlet, CG + GAMG) on the identical mesh, ``mpiexec -n k``.

Phases: assembly (problem and matrices), setup (AMG hierarchy), time per step after the first
(the first carries pyamg's coarse pseudo-inverse), CG iterations per step, total, peak resident
memory per process (the largest over the processes). Needs petsc4py (the PyPI wheel
``dolfinx-solver-real``, which also brings dolfinx); run it with that environment's python:

    /path/to/venv-mpi/bin/python benchmarks/eld_mpi.py --n 44 --repeats 2
    /path/to/venv-mpi/bin/python benchmarks/eld_mpi.py --quick      # n = 12, one repeat
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
TAU = 0.01


def petsc_child(n: int, steps: int, rtol: float, amg_products: str = "fast") -> None:
    """One run of the PETSc backend on the processes of mpiexec; rank 0 prints one JSON line."""
    import skfem  # noqa: F401
    from mpi4py import MPI  # noqa: F401 - before petsc4py (the wheel's order)

    from rothe.cli.common import peak_memory_mb
    from rothe.eld.distributed.problem import DistributedELDProblem
    from rothe.eld.distributed.stepper import PetscELDStepper
    from rothe.eld.examples import beam_problem
    from rothe.fem import mesh as meshes
    from rothe.io.trajectory import Trajectory
    from rothe.stepping.controllers import FixedStepController, Uniform
    from rothe.stepping.evolve import evolve

    comm = MPI.COMM_WORLD
    memory = {}

    def mark(phase):
        """Resident and peak memory (largest over the processes) after a phase, in MB."""
        with open("/proc/self/status") as f:
            rss = next(int(ln.split()[1]) for ln in f if ln.startswith("VmRSS")) / 1024.0
        peak = peak_memory_mb()
        memory[phase] = {
            "rss": round(comm.allreduce(rss, op=MPI.MAX)),
            "peak": round(comm.allreduce(peak, op=MPI.MAX)),
        }

    def clock():
        comm.Barrier()
        return time.perf_counter()

    out = {"tool": "rothe-petsc", "n": n, "processes": comm.size}
    t0 = clock()
    mesh = meshes.box(4 * n, n, n, 4.0, 1.0, 1.0)
    out["mesh_s"] = clock() - t0
    mark("mesh")
    t0 = clock()
    from rothe.eld.damping import RayleighDamping

    data = beam_problem(1, damping=RayleighDamping(0.0, 0.002), T=steps * TAU).definition
    problem = DistributedELDProblem(mesh, data, comm)
    del mesh  # as the command line does: only the partition's submesh stays
    out["ndofs"] = problem.ndofs
    t_problem = clock() - t0
    mark("problem (partition, submesh assembly, PETSc M, K)")
    stamps = []

    def observer(state, result):
        if result is None:  # the initial state (recorded with lambda(0)): not a step
            return
        stamps.append((time.perf_counter(), result.counters.get("krylov_iterations", 0)))

    t0 = clock()
    stepper = PetscELDStepper(
        problem,
        control=Uniform(TAU),
        solver="amg",
        store_fields=False,
        observer=observer,
        linear_rtol=rtol,
        amg_products=amg_products,
    )
    t_stepper = clock() - t0
    mark("stepper (A, GAMG setup)")
    out["setup_s"] = comm.allreduce(stepper.stats.setup_seconds, op=MPI.MAX)
    out["assembly_s"] = t_problem + t_stepper - out["setup_s"]
    traj = Trajectory()
    t0 = clock()
    state = stepper.initial_state()
    stepper.record_initial(traj, state)
    evolve(
        stepper,
        FixedStepController.uniform(stepper.tau, stepper.n_steps),
        state,
        traj,
        tau_min=1e-300,
    )
    t_end = clock()
    mark("time steps")
    times = [s for s, _ in stamps]
    out["first_step_s"] = times[0] - t0
    out["per_step_after_first_s"] = (times[-1] - times[0]) / max(len(times) - 1, 1)
    out["steps_s"] = t_end - t0
    out["krylov_its_per_step"] = sum(c for _, c in stamps) / len(stamps)
    out["krylov_s_per_step"] = comm.allreduce(stepper.krylov_seconds, op=MPI.MAX) / len(stamps)
    out["memory_mb"] = memory
    out["total_s"] = out["mesh_s"] + t_problem + t_stepper + out["steps_s"]
    out["reaction_final"] = np.asarray(traj["reaction_left"][-1]).tolist()
    peaks = comm.gather(peak_memory_mb(), root=0)
    if comm.rank == 0:
        out["peak_mb_max"] = max(peaks)
        out["peak_mb_sum"] = sum(peaks)
        print(json.dumps(out), flush=True)


def export_mesh(work: Path, n: int) -> Path:
    """meshes/beam_nN.npz in the format of ../shared/anchors/export_beam_mesh.py."""
    from rothe.fem import mesh as meshes

    path = work / "meshes" / f"beam_n{n}.npz"
    if path.is_file():
        return path
    m = meshes.box(4 * n, n, n, 4.0, 1.0, 1.0)
    bfac = m.boundary_facets()
    left = m.boundaries["left"]
    other = np.setdiff1d(bfac, left)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(
        path,
        points=m.p.T.copy(),
        tets=m.t.T.astype(np.int64).copy(),
        left_tris=m.facets[:, left].T.astype(np.int64).copy(),
        other_tris=m.facets[:, other].T.astype(np.int64).copy(),
        n=n,
        nx=4 * n,
        L=4.0,
    )
    return path


def run(cmd: list[str], cwd: Path) -> dict:
    env = dict(
        os.environ,
        PYTHONPATH=str(REPO / "src") + os.pathsep + os.environ.get("PYTHONPATH", ""),
        OMP_NUM_THREADS="1",
        OPENBLAS_NUM_THREADS="1",
    )
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr[-3000:]}")
    return json.loads([ln for ln in proc.stdout.splitlines() if ln.startswith("{")][-1])


def normalize(tool: str, row: dict, wall: float) -> dict:
    """The columns of the table from each tool's JSON line."""
    if tool == "rothe serial":
        peak = max(v["peak"] for v in row["memory_mb"].values())
    elif tool.startswith("dolfinx"):
        peak = row.get("peak_rss_mb_max") or row.get("peak_rss_mb_self")
    else:
        peak = row["peak_mb_max"]
    return {
        "assembly_s": row["assembly_s"],
        "setup_s": row["setup_s"],
        "step_s": row["per_step_after_first_s"],
        "first_step_s": row["first_step_s"],
        "its": row["krylov_its_per_step"],
        "total_s": row["total_s"],
        "peak_mb": peak,
        "wall_s": wall,
        "reaction_z": row["reaction_final"][2],
        "ndofs": row["ndofs"],
        "krylov_s": row.get("krylov_s_per_step", float("nan")),
        "memory_mb": row.get("memory_mb"),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=44, help="cells across (44: 1,075,275 dofs)")
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="n = 12, one repeat")
    ap.add_argument("--processes", default="1,2", help="process counts of the parallel tools")
    ap.add_argument("--no-dolfinx", action="store_true")
    ap.add_argument("--out", default=str(REPO / "rothe-out" / "eld_mpi"))
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--rtol", type=float, default=1e-8)
    ap.add_argument(
        "--lean",
        default="2",
        help="process counts of an extra rothe petsc row with --amg-products lean ('' none)",
    )
    ap.add_argument("--amg-products", default="fast", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        petsc_child(args.n, args.steps, args.rtol, args.amg_products)
        return 0
    if args.quick:
        args.n, args.repeats = 12, 1
    work = Path(args.out)
    work.mkdir(parents=True, exist_ok=True)
    py = sys.executable
    mpiexec = str(Path(py).parent / "mpiexec")
    peer = Path(os.environ.get("ROTHE_PEER_ANCHORS", REPO.parent / "shared" / "anchors"))
    if not (peer / "eld_beam_dolfinx011.py").is_file():
        peer = Path("/work/shared/anchors")
    procs = [int(k) for k in args.processes.split(",")]
    lean = [int(k) for k in args.lean.split(",") if k]
    tools = [
        (
            "rothe serial",
            [
                py,
                str(HERE / "eld_peers.py"),
                "--child",
                "--n",
                str(args.n),
                "--degree",
                "1",
                "--form",
                "regularized",
                "--solver",
                "amg",
                "--steps",
                str(args.steps),
                "--data",
                "points",
                "--rtol",
                str(args.rtol),
                "--tau",
                str(TAU),
            ],
        )
    ]
    have_dolfinx = (
        not args.no_dolfinx
        and subprocess.run(
            [py, "-c", "import dolfinx_solver, dolfinx"], capture_output=True
        ).returncode
        == 0
    )
    if have_dolfinx:
        export_mesh(work, args.n)
    for k in procs:
        child = [mpiexec, "-n", str(k), py, str(Path(__file__)), "--child", "--n", str(args.n)]
        child += ["--steps", str(args.steps), "--rtol", str(args.rtol)]
        tools.append((f"rothe petsc N={k}", child))
        if k in lean:
            tools.append((f"rothe petsc N={k} lean", child + ["--amg-products", "lean"]))
        if have_dolfinx:
            tools.append(
                (
                    f"dolfinx 0.11 N={k}",
                    [
                        mpiexec,
                        "-n",
                        str(k),
                        py,
                        str(peer / "eld_beam_dolfinx011.py"),
                        "--n",
                        str(args.n),
                        "--mode",
                        "gamg",
                        "--tau",
                        str(TAU),
                        "--steps",
                        str(args.steps),
                        "--rtol",
                        str(args.rtol),
                    ],
                )
            )
    rows: dict[str, list[dict]] = {name: [] for name, _ in tools}
    log = work / "runs.jsonl"
    for rep in range(args.repeats):
        for name, cmd in tools:
            load = os.getloadavg()[0]
            t0 = time.perf_counter()
            row = run(cmd, work)
            r = normalize(name, row, time.perf_counter() - t0)
            r["load"] = load
            rows[name].append(r)
            with open(log, "a") as f:
                f.write(json.dumps({"tool": name, "repeat": rep, **r}) + "\n")
            print(
                f"[{rep}] {name}: {r['step_s']:.2f} s/step, its {r['its']:.1f}, "
                f"peak {r['peak_mb']:.0f} MB, load {load:.2f}",
                file=sys.stderr,
                flush=True,
            )
    best = {
        name: {
            k: (
                max(v[k] for v in rs)
                if k == "peak_mb"
                else rs[-1][k]
                if k == "memory_mb"
                else min(v[k] for v in rs)
            )
            for k in rs[0]
        }
        for name, rs in rows.items()
    }
    ndofs = best["rothe serial"]["ndofs"]
    print(
        f"P1 beam n = {args.n}, {ndofs:,} dofs, {args.steps} Euler steps, tau = {TAU}, "
        f"{args.repeats} repeats (min of times, max of peaks); loads "
        + ", ".join(f"{r['load']:.2f}" for rs in rows.values() for r in rs)
    )
    hdr = (
        f"{'tool':<22}{'assembly s':>11}{'setup s':>9}{'s/step':>8}{'1st s':>7}{'its':>6}"
        f"{'total s':>9}{'peak MB/proc':>13}{'R_z(T)':>13}"
    )
    print(hdr + f"{'CG s/step':>10}")
    print("-" * (len(hdr) + 10))
    for name, b in best.items():
        print(
            f"{name:<22}{b['assembly_s']:>11.1f}{b['setup_s']:>9.1f}{b['step_s']:>8.2f}"
            f"{b['first_step_s']:>7.1f}{b['its']:>6.1f}{b['total_s']:>9.1f}"
            f"{b['peak_mb']:>13.0f}{b['reaction_z']:>13.7g}{b['krylov_s']:>10.2f}"
        )
    for name, b in best.items():
        if b.get("memory_mb"):
            print(
                f"memory of {name} after each phase (MB, largest process: resident / peak): "
                + "; ".join(f"{k} {v['rss']}/{v['peak']}" for k, v in b["memory_mb"].items())
            )
    s = best["rothe serial"]

    def ratio(a, b, key):
        if a in best and b in best:
            print(f"  {a} / {b}, {key}: {best[a][key] / best[b][key]:.3f}")

    print(
        "ratios (targets: serial <= 0.9 x dolfinx serial; N=2 step <= 0.65 x serial rothe, "
        "peak/proc <= 0.6 x serial rothe, step <= 1.0 x dolfinx N=2):"
    )
    ratio("rothe serial", "dolfinx 0.11 N=1", "step_s")
    # the default where petsc4py is installed (--backend auto on one process)
    ratio("rothe petsc N=1", "dolfinx 0.11 N=1", "step_s")
    ratio("rothe petsc N=2", "rothe petsc N=1", "peak_mb")
    ratio("rothe petsc N=2", "rothe serial", "step_s")
    ratio("rothe petsc N=2", "rothe serial", "peak_mb")
    ratio("rothe petsc N=2 lean", "rothe serial", "peak_mb")
    ratio("rothe petsc N=2 lean", "rothe serial", "step_s")
    ratio("rothe petsc N=2 lean", "rothe petsc N=2", "setup_s")
    ratio("rothe petsc N=2", "dolfinx 0.11 N=2", "step_s")
    ratio("rothe petsc N=2", "rothe petsc N=1", "step_s")
    if "rothe petsc N=1" in best:
        rel = abs(best["rothe petsc N=1"]["reaction_z"] - s["reaction_z"]) / abs(s["reaction_z"])
        print(f"  reaction R_z(T): petsc N=1 against serial rothe, relative {rel:.2e}")
    (work / "table.json").write_text(json.dumps({"best": best, "runs": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
