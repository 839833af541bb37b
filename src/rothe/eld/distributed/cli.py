"""``mpiexec -n N rothe run eld-beam --backend petsc ...``: the serial command on N processes.

Every process parses the same command line, builds the same mesh and its own part of the
problem (:class:`DistributedELDProblem`; no process assembles the whole problem) and steps.
Rank 0 alone owns the session (output directory, lock, checkpoint) and writes every file: the
kept states and the XDMF steps are **gathered** to it (serial numbering), so ``trajectory.npz``,
``summary.json`` and the two XDMF series are the serial run's files. The cost of gathering is
one message of 8 bytes per dof and field to rank 0 per written step (u and v for XDMF; u, v, a
per kept state), and rank 0 holds the serial mesh, its P1/P2 space for the stresses, and every
kept state (as a serial run does): at 10^7 dofs 80 MB per field and step, about 1 s on a
10 GB/s network, and a serial stress evaluation on rank 0 per written step (docs/scaling.md).

Every refusal happens on every process at the same point (the same input gives the same
check everywhere) or is decided on rank 0 and broadcast, so that no process is left waiting:
one line ``rothe: error: ...`` and exit status 2 from every process (mpiexec prints it once per
process).
"""

from __future__ import annotations

import shutil
import sys

from ...errors import RotheInputError, RunFailed, RunInterrupted
from ...fem.petsc_env import require_petsc
from ...stepping import interrupt

#: options of ``rothe run eld-beam`` this backend refuses, with what they are
_REFUSED = (("adapt_space", "--adapt-space (space adaptivity is not distributed)"),)


class OutputView:
    """What the serial output writers read from a problem (``space``, ``material``,
    ``constraint``, ``u0``, ``v0``, ``T``), built on rank 0 from the whole mesh without
    assembling M or K."""

    def __init__(self, mesh, problem):
        from ...fem.elasticity import VectorSpace
        from ..constraint import DirichletConstraint

        self.space = VectorSpace(mesh, problem.degree)
        self.material = problem.material
        self.constraint = DirichletConstraint(
            self.space, tuple(problem.local.dirichlet), "dirichlet"
        )
        self.T = problem.T
        part = problem.partition
        self.u0 = part.gather_serial(problem.u0)
        self.v0 = part.gather_serial(problem.v0)


def check_backend_options(args) -> None:
    """One line for an option the backend lacks (the same on every process)."""
    for key, what in _REFUSED:
        if getattr(args, key, None):
            raise RotheInputError(
                f"--backend petsc: got {what.split(' ')[0]}, not supported "
                f"with --backend petsc: {what.split('(', 1)[1].rstrip(')')}"
            )


def _broadcast_error(comm, fn):
    """fn() on rank 0; an input error there is raised on every process."""
    result, error = None, None
    if comm.rank == 0:
        try:
            result = fn()
        except RotheInputError as exc:
            error = str(exc)
    error = comm.bcast(error, root=0)
    if error is not None:
        raise RotheInputError(error)
    return result


def execute_beam(command, args) -> int:
    """The body of ``rothe run eld-beam`` with ``--backend petsc`` (module docstring)."""
    MPI, _ = require_petsc("--backend petsc")
    from ...cli.common import peak_memory_mb
    from ...cli.eld_commands import (
        BEAM_SIDEWAYS_NOTE,
        _already_completed,
        _beam_reactions,
        _print_run,
        _write_run,
        energy_summary,
        run_summary,
    )
    from ...cli.session import RunSession
    from ...fem import mesh as meshes
    from ..examples import beam_problem
    from ..output import EldXdmfWriter
    from .problem import DistributedELDProblem
    from .run import run_eld_petsc

    comm = MPI.COMM_WORLD
    root = comm.rank == 0
    check_backend_options(args)
    form, tau, scheme, control, tol, n, every, keep, damping = command.validate(args)
    # the beam's data from beam_problem on one cell across (material, damping, G, T: nothing
    # there depends on n), the mesh as beam_problem builds it
    kwargs = dict(
        length=args.length,
        E=args.E,
        nu=args.nu,
        rho=args.rho,
        damping=damping,
        amplitude=args.amplitude,
        t_move=args.t_move,
        T=args.T,
        degree=args.degree,
    )
    data = beam_problem(1, **kwargs)._data
    mesh = meshes.box(max(1, int(round(args.length * n))), n, n, args.length, 1.0, 1.0)
    problem = DistributedELDProblem(mesh, data, comm)
    view = OutputView(mesh, problem) if root else None
    del mesh  # the whole mesh with its facets and edges: rank 0's OutputView keeps what it needs
    if not root:
        problem.partition.gather_serial(problem.u0)  # the collective gathers of OutputView
        problem.partition.gather_serial(problem.v0)
    ndofs = problem.ndofs
    label = f"eld-beam, {scheme}, {form}, tau={tau:g}, {ndofs} dofs, {comm.size} processes"
    session = _broadcast_error(comm, lambda: RunSession(args, command.name))
    guard = session if root else interrupt.interruptible(hard_second=True)
    summary, e, code, results, completed, pending = None, None, 0, None, False, None
    with guard:
        done = comm.bcast(_already_completed(session) if root else None, root=0)
        if done:
            return 0
        writer = None
        if root:
            stream = session.checkpoint_dir / "stream"
            if session.resume is None:
                shutil.rmtree(stream, ignore_errors=True)
            writer = EldXdmfWriter(stream, view, name="beam")
            if session.resume is None:
                writer.write(0.0, view.u0, view.v0, None)
            session.checkpoint.attachments = {"xdmf": writer}
        part = problem.partition

        def observer(state, result):
            if state.j % every == 0 or state.t >= problem.T * (1.0 - 1e-12):
                u, v = part.gather_serial(state.u), part.gather_serial(state.v)
                if writer is not None:
                    writer.write(state.t, u, v, result.lam)

        def run(checkpoint=None, resume=None, progress=False):
            return run_eld_petsc(
                problem,
                form,
                tau,
                scheme=scheme,
                control=control,
                tol=tol,
                solver=args.solver,
                keep_every=keep,
                observer=observer,
                linear_rtol=1e-8,
                checkpoint=checkpoint,
                resume=resume,
                progress=progress,
            )

        if root:
            outcome = session.run(run)
        else:
            from ...cli.session import Outcome

            try:
                outcome = Outcome("completed", run())
            except RunFailed as exc:
                outcome = Outcome("failed", exc.trajectory, exc)
            except RunInterrupted as exc:
                outcome = Outcome("interrupted", exc.trajectory, exc)
        peaks = comm.gather(peak_memory_mb(), root=0)
        if root:
            results = session.results_dir(outcome.status)
            traj = outcome.result
            completed = outcome.status == "completed"
            if traj is not None:
                with session.outputs(outcome.status) as stage:
                    writer.export(stage)
                    summary = run_summary(traj, command.name)
                    summary.update(
                        n=n,
                        degree=args.degree,
                        length=args.length,
                        E=args.E,
                        nu=args.nu,
                        amplitude=args.amplitude,
                        t_move=args.t_move,
                        backend="petsc",
                        processes=comm.size,
                        peak_memory_mb=max(peaks),
                        peak_memory_mb_per_process=peaks,
                        seconds_per_step=traj.stats.wall_time_s / max(traj.stats.accepted_steps, 1),
                        xdmf=[p.name for p in writer.paths],
                        xdmf_steps=writer.steps_written,
                    )
                    if traj.stats.accepted_steps:
                        summary.update(_beam_reactions(traj))
                        e = energy_summary(traj)
                        put_in = e["work_support"] + e["work_loads"]
                        summary["numerical_dissipation_fraction"] = (
                            e["dissipated_numerical"] / put_in if put_in > 0 else None
                        )
                    session.annotate(summary, outcome)
                    _write_run(
                        args,
                        stage,
                        command.name,
                        traj,
                        summary,
                        label,
                        view,
                        xdmf=False,
                        plots=completed,
                    )
            try:
                code = session.finish(outcome, results)
            except RunFailed as exc:  # raised after the others know the exit status
                pending, code = exc, 1
            if completed:
                writer.discard()
        elif outcome.status == "failed":
            code = 1
        elif outcome.status == "interrupted":
            code = outcome.error.exit_status
    code = comm.bcast(code, root=0)
    if pending is not None:
        raise pending
    if root and completed:
        _print_run(
            args,
            results,
            command.name,
            summary,
            (
                "example",
                "form",
                "scheme",
                "tau",
                "accepted_steps",
                "ndofs",
                "processes",
                "linear_solver",
                "krylov_iterations",
                "seconds_per_step",
                "peak_memory_mb",
                "reaction_left_final",
                "reaction_left_max_abs",
                "wall_time_s",
            ),
        )
        if (
            not args.quiet
            and e is not None
            and max(summary["reaction_sideways_over_z"]) > BEAM_SIDEWAYS_NOTE
        ):
            print(
                "note: coarse mesh for the reactions (sideways reactions above "
                f"{100 * BEAM_SIDEWAYS_NOTE:.0f} % of R_z); use --degree 2 or a larger --n"
            )
    sys.stdout.flush()
    return code
