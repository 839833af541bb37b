"""Where the N-process PETSc set-up's peak memory goes: GAMG's Galerkin products level by level.

Builds the P1 beam of ``benchmarks/eld_mpi.py`` (n cells across, 4n x n x n) on the processes
of mpiexec, sets up the PETSc stepper (CG + GAMG, ``--amg-products``) and prints, largest
process, resident / peak MB before and after the preconditioner's set-up (the peak reset to
the resident size right before it, Linux's ``/proc/self/clear_refs``: the set-up's own peak),
the hierarchy, and then each level's product P^T A P formed again by each of PETSc's
algorithms (``-matptap_via``): its seconds and its transient (peak minus resident before).
``--without-km`` destroys M and K (and their Gamma_D blocks) before the set-up: the set-up's
peak if they were not resident (a bound for keeping them elsewhere; the steps cannot run).
docs/scaling.md, "Peak memory per process with the default settings (eighth session)":

    mpiexec -n 2 python benchmarks/gamg_products.py --n 32
    mpiexec -n 2 python benchmarks/gamg_products.py --n 44 --algorithms none --without-km
"""

from __future__ import annotations

import argparse
import time

import skfem  # noqa: F401
from mpi4py import MPI  # noqa: F401 - before petsc4py (the wheel's order)


def memory_mb() -> tuple[float, float]:
    """(resident, peak) MB of this process (VmRSS, VmHWM)."""
    with open("/proc/self/status") as f:
        d = {ln.split(":")[0]: int(ln.split()[1]) / 1024 for ln in f if ln.startswith("Vm")}
    return d["VmRSS"], d["VmHWM"]


def reset_peak() -> None:
    """VmHWM := VmRSS (Linux >= 4.0)."""
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=32)
    ap.add_argument("--amg-products", default="fast")
    ap.add_argument("--algorithms", default="nonscalable,scalable,allatonce,allatonce_merged")
    ap.add_argument("--without-km", action="store_true")
    args = ap.parse_args(argv)
    from petsc4py import PETSc

    from rothe.eld.damping import RayleighDamping
    from rothe.eld.distributed import stepper as petsc_stepper
    from rothe.eld.distributed.problem import DistributedELDProblem
    from rothe.eld.examples import beam_problem
    from rothe.fem import mesh as meshes
    from rothe.stepping.controllers import Uniform

    comm = MPI.COMM_WORLD

    def largest(values):
        return [comm.allreduce(v, op=MPI.MAX) for v in values]

    def say(text):
        if comm.rank == 0:
            print(text, flush=True)

    def mark(name):
        rss, peak = largest(memory_mb())
        say(f"{name:<34} resident {rss:6.0f} MB, peak {peak:6.0f} MB")

    n = args.n
    mesh = meshes.box(4 * n, n, n, 4.0, 1.0, 1.0)
    data = beam_problem(1, damping=RayleighDamping(0.0, 0.002), T=0.02).definition
    problem = DistributedELDProblem(mesh, data, comm)
    del mesh
    mark("problem (M, K)")
    set_up = petsc_stepper.PetscELDStepper._setup_pc_timed

    def measured_set_up(stepper):
        if args.without_km:
            for mat in (problem.K, problem.M, stepper._M_C, stepper._K_C):
                mat.destroy()
        mark("before the set-up")
        reset_peak()
        set_up(stepper)
        mark("after the set-up (its own peak)")

    petsc_stepper.PetscELDStepper._setup_pc_timed = measured_set_up
    stepper = petsc_stepper.PetscELDStepper(
        problem,
        control=Uniform(0.01),
        solver="amg",
        store_fields=False,
        linear_rtol=1e-8,
        amg_products=args.amg_products,
    )
    pc = stepper._ksp.getPC()
    levels = pc.getMGLevels()
    operators = [pc.getMGSmoother(k).getOperators()[0] for k in range(levels)]
    total = PETSc.Mat.InfoType.GLOBAL_SUM
    rows = [a.getSize()[0] for a in operators]
    nnz = [int(a.getInfo(total)["nz_used"]) for a in operators]
    p_nnz = [int(pc.getMGInterpolation(k).getInfo(total)["nz_used"]) for k in range(1, levels)]
    say(
        f"levels {levels}: rows {rows}, nonzeros {nnz}, interpolations' nonzeros {p_nnz}; "
        f"set-up {stepper.stats.setup_seconds:.1f} s"
    )
    options = PETSc.Options()
    algorithms = [a for a in args.algorithms.split(",") if a and a != "none"]
    for k in range(levels - 1, 0, -1):
        A, P = operators[k], pc.getMGInterpolation(k)
        for algorithm in algorithms:
            options["matptap_via"] = algorithm
            rss0 = largest(memory_mb())[0]
            reset_peak()
            comm.Barrier()
            t0 = time.perf_counter()
            C = A.ptap(P)
            comm.Barrier()
            seconds = time.perf_counter() - t0
            peak = largest(memory_mb())[1]
            C.destroy()
            options.delValue("matptap_via")
            say(
                f"level {k} -> {k - 1} {algorithm:<17} {seconds:7.2f} s, "
                f"transient {peak - rss0:5.0f} MB"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
