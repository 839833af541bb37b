"""``mpiexec -n N rothe run eld-beam --backend petsc ...``: the serial command on N processes.

Every process parses the same command line, builds the same mesh and its own part of the
problem (:class:`~rothe.eld.distributed.problem.DistributedELDProblem`; no process assembles
the whole problem) and steps (``run_eld(..., backend="petsc")``). Rank 0 alone owns the session
(output directory, lock, checkpoint) and writes every file: the kept states and the XDMF steps
are **gathered** to it (serial numbering), so ``trajectory.npz``, ``summary.json`` and the two
XDMF series are the serial run's files. The cost of gathering is one message of 8 bytes per dof
and field to rank 0 per written step (u and v for XDMF; u, v, a per kept state), and rank 0
holds the serial mesh, its P1/P2 space for the stresses, and every kept state (as a serial run
does): at 10^7 dofs 80 MB per field and step, about 1 s on a 10 GB/s network, and a serial
stress evaluation on rank 0 per written step (docs/scaling.md).

Every refusal happens on every process at the same point (the same input gives the same
check everywhere) or is decided on rank 0 and broadcast, so that no process is left waiting:
one line ``rothe: error: ...`` and exit status 2 from every process (mpiexec prints it once per
process).
"""

from __future__ import annotations

import sys

from ..eld.constraint import DirichletConstraint
from ..eld.distributed.problem import DistributedELDProblem
from ..eld.output import EldXdmfWriter
from ..eld.run import ELDResult, run_eld
from ..errors import RotheInputError, RunFailed, RunInterrupted
from ..fem import mesh as meshes
from ..fem.elasticity import VectorSpace
from ..fem.petsc_env import require_petsc
from ..stepping import interrupt
from .common import peak_memory_mb
from .session import RunSession, run_sequence


class OutputView:
    """What the serial output writers read from a problem (``space``, ``material``,
    ``constraint``, ``u0``, ``v0``, ``T``), built on rank 0 from the whole mesh without
    assembling M or K."""

    def __init__(self, mesh, problem):
        self.space = VectorSpace(mesh, problem.degree)
        self.material = problem.material
        self.constraint = DirichletConstraint(
            self.space, tuple(problem.local.dirichlet), "dirichlet"
        )
        self.T = problem.T
        part = problem.partition
        self.u0 = part.gather_serial(problem.u0)
        self.v0 = part.gather_serial(problem.v0)


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
    """The body of ``rothe run eld-beam`` with ``--backend petsc`` (module docstring);
    ``command`` is the :class:`~rothe.cli.eld_commands.RunEldBeam` that parsed ``args`` (its
    validation, write step, summary fields and printout are the serial command's); rank 0 runs
    the one run sequence (:func:`~rothe.cli.session.run_sequence`) in the session it built."""
    MPI, _ = require_petsc("--backend petsc")
    comm = MPI.COMM_WORLD
    root = comm.rank == 0
    objects, n, every, keep, damping, _, material, _ = command.validate(args)
    products = args.amg_products or "fast"  # validated above; fast: PETSc's default products
    # the beam's data from beam_problem on one cell across (material, damping, G, T: nothing
    # there depends on n), the mesh as beam_problem builds it
    definition = command.beam(args, 1, damping, material).definition
    mesh = meshes.box(max(1, int(round(args.length * n))), n, n, args.length, 1.0, 1.0)
    problem = DistributedELDProblem(mesh, definition, comm)
    view = OutputView(mesh, problem) if root else None
    del mesh  # the whole mesh with its facets and edges: rank 0's OutputView keeps what it needs
    if not root:
        problem.partition.gather_serial(problem.u0)  # the collective gathers of OutputView
        problem.partition.gather_serial(problem.v0)
    label = (
        f"eld-beam, {objects['scheme'].name}, {objects['form'].name}, tau={args.tau:g}, "
        f"{problem.ndofs} dofs, {comm.size} processes"
    )
    part = problem.partition
    # rank 0 builds the session (output directory, lock, checkpoint) and runs the one run
    # sequence (cli/session.run_sequence) in it; the others step alongside
    session = _broadcast_error(comm, lambda: RunSession(args, command.name))
    done = comm.bcast(session.already_completed if root else None, root=0)
    writers = []  # rank 0's XDMF writer, once the session is open
    peaks = []  # every process's peak memory (MB), gathered to rank 0 after its run

    def prepare(session):
        writer = EldXdmfWriter(command.stream_dir(session), view, name="beam")
        session.checkpoint.attachments = {"xdmf": writer}
        writers.append(writer)

    def observer(state, result):
        # collective (every process gathers); result None: the initial state with lambda(0),
        # so that both series start at t = 0 (not called again on resume)
        if result is None or command.frame_due(state, every, problem.T):
            u, v = part.gather_serial(state.u), part.gather_serial(state.v)
            if writers:
                lam = state.lam if result is None else result.lam
                writers[0].write(state.t, u, v, lam)

    def run(checkpoint=None, resume=None, progress=False):
        try:
            return run_eld(
                problem,
                **objects,
                solver=args.solver,
                keep_every=keep,
                observer=observer,
                linear_rtol=1e-8,
                checkpoint=checkpoint,
                resume=resume,
                progress=progress,
                backend="petsc",
                amg_products=products,
            )
        finally:  # a collective: every process, however its run ended
            peaks.append(comm.gather(peak_memory_mb(), root=0))

    def summarize(summary, result, completed):
        command.summarize(args, summary, result.trajectory, material)
        summary.update(
            backend="petsc",
            processes=comm.size,
            amg_products=products,
            peak_memory_mb=max(peaks[0]),
            peak_memory_mb_per_process=peaks[0],
        )

    def write(stage, outcome):
        completed = outcome.status == "completed"
        traj = outcome.result.trajectory if completed else outcome.result
        # the outputs read the serial mesh and numbering: rank 0's view of the problem
        result = ELDResult(traj, None, None, None, view)
        return command.write_result(args, stage, result, completed, writers[0], summarize, label)

    outcome, pending = None, None
    # one guard on every process from the first step to the broadcast of the exit status (rank
    # 0's session guard, inside it, is then a no-op): a signal after the last step, while rank
    # 0 writes the results, leaves the finished run as a serial run does, instead of killing
    # the other processes with SIGTERM's default action
    with interrupt.interruptible(hard_second=True):
        if root:
            try:
                code, outcome, results, summary = run_sequence(
                    args,
                    command.name,
                    run,
                    write,
                    prepare=prepare,
                    completed=lambda: writers[0].discard(),
                    session=session,
                )
            except RunFailed as exc:  # raised by session.finish: after the others know the status
                pending, code = exc, 1
        elif done:
            code = 0
        else:
            try:
                run()
                code = 0
            except RunFailed:
                code = 1
            except RunInterrupted as exc:
                code = exc.exit_status
        code = comm.bcast(code, root=0)
    if pending is not None:
        raise pending
    if outcome is not None and outcome.status == "completed":
        command.print_result(args, results, summary)
    sys.stdout.flush()
    return code
