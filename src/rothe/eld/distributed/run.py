"""``run_eld(..., backend='petsc')``: the serial driver's contract on many processes.

Every process runs the same evolve loop (:func:`rothe.stepping.evolve.evolve`) on its part of
the state; every decision the loop takes (accept, reject, next step, stop) depends only on
global quantities (error estimates and energies are allreduced), so the processes agree.
What is gathered, and where:

- the trajectory: every process records the scalar series (identical everywhere); the kept
  fields ``u, v, a`` are gathered to **rank 0** in the serial numbering (``lam`` is replicated);
  rank 0's trajectory is the serial one, the others hold the scalars only;
- checkpoints: written by rank 0 alone, the state gathered to it in the serial numbering (the
  same file as a serial run's, plus ``processes``); ``due`` is rank 0's clock, broadcast; a
  resume scatters the state back and is refused on another number of processes (the
  partition, and with it GAMG's aggregates and every sum's order, depend on it: bit for bit
  holds on the same number only);
- SIGINT/SIGTERM on any process: the loop's signal test is preceded by an allreduce of the
  flags (:meth:`PetscELDStepper.finished`), so all processes stop after the same step, write
  the checkpoint together and raise :class:`~rothe.errors.RunInterrupted` with the trajectory.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from ...errors import RotheInputError, RunFailed
from ...io.checkpoint import RunCheckpointing, load_checkpoint
from ...io.trajectory import RunStatistics, Trajectory
from ...stepping.controllers import Adaptive
from ...stepping.evolve import evolve
from ..controllers import checkpoint_where, describe_run
from ..data import DEFAULT_DATA, DataMode
from ..form import DEFAULT_FORM, Form
from ..scheme import DEFAULT_SCHEME, Scheme
from ..state import ELDState
from ..stepper import DEFAULT_CONTROL
from .problem import DistributedELDProblem
from .stepper import PetscELDStepper


class _Frozen:
    """A stepper stand-in that hands the real checkpointer an already gathered state."""

    def __init__(self, data):
        self.data = data

    def checkpoint_state(self, state):
        return self.data


class DistributedCheckpointer:
    """The evolve loop's checkpointer on every process; rank 0 owns the real one."""

    def __init__(self, comm, real):
        self.comm = comm
        self.real = real  # a rothe.io.checkpoint.Checkpointer on rank 0, None elsewhere

    @property
    def sequence(self) -> int:
        return self.comm.bcast(self.real.sequence if self.real is not None else None, root=0)

    def due(self) -> bool:
        """Whether a checkpoint is due, decided on rank 0 and broadcast."""
        return bool(self.comm.bcast(self.real.due() if self.real is not None else None, root=0))

    def save_or_warn(
        self, stepper, controller, state, *, status: str = "running", where: dict | None = None
    ):
        """Gather the state and save it on rank 0; the path (or None), broadcast. Collective."""
        data = stepper.checkpoint_state(state)  # collective gather
        path = None
        if self.real is not None:
            path = self.real.save_or_warn(
                _Frozen(data), controller, state, status=status, where=where
            )
        return self.comm.bcast(None if path is None else str(path), root=0)


def _check_resume_processes(resume, comm) -> None:
    """One line if the checkpoint was written by another number of processes. Rank 0's
    ``resume`` decides (the command line passes it there only)."""
    if not comm.bcast(resume is not None if comm.rank == 0 else None, root=0):
        return
    msg = None
    if comm.rank == 0:
        try:
            ck = resume if hasattr(resume, "header") else load_checkpoint(resume, header_only=True)
            args = ck.header.get("arguments", {})
            got = args.get("processes")
            if args.get("backend") != "petsc":
                msg = "resume: the checkpoint is of a serial run: resume it without --backend petsc"
            elif got != comm.size:
                msg = (
                    f"resume: the checkpoint was written by {got} processes, this run has "
                    f"{comm.size}: resume with mpiexec -n {got} (the partition fixes the "
                    "order of every sum)"
                )
        except RotheInputError as exc:
            msg = str(exc)
    msg = comm.bcast(msg, root=0)
    if msg:
        raise RotheInputError(msg)


@dataclass
class DistributedRun:
    """What :func:`run_eld_petsc` returns (:func:`rothe.eld.run_eld` makes it an
    :class:`~rothe.eld.run.ELDResult`): the trajectory (complete on rank 0, the scalar series
    elsewhere), the final state (the owned parts), the stepper, the controller and the
    problem."""

    trajectory: Trajectory
    state: ELDState
    stepper: PetscELDStepper
    controller: object
    problem: DistributedELDProblem


def run_eld_petsc(
    problem,
    *,
    scheme: Scheme = DEFAULT_SCHEME,
    form: Form = DEFAULT_FORM,
    control=DEFAULT_CONTROL,
    data: DataMode = DEFAULT_DATA,
    solver: str = "auto",
    newton=None,
    noise=None,
    store_fields: bool = True,
    keep_every: int = 1,
    observer=None,
    progress=False,
    linear_rtol: float = 1e-10,
    error_scale: float | None = None,
    meta: dict | None = None,
    checkpoint=None,
    resume=None,
    comm=None,
    amg_products: str = "fast",
) -> DistributedRun:
    """:func:`rothe.eld.run_eld` on the processes of ``comm`` (module docstring); the
    parameters are run_eld's (no ``adapt``: space adaptivity is not distributed) and
    ``amg_products`` (:class:`PetscELDStepper`: ``'fast'`` or ``'lean'``, how GAMG forms its
    coarse operators; recorded, and a resumed run must use the same).

    Parameters
    ----------
    problem : ELDProblem or DistributedELDProblem
        A serial problem is copied to the processes (every process built it: for small
        problems and tests); large bodies are built as a :class:`DistributedELDProblem`.
    comm : mpi4py communicator, optional
        Default ``MPI.COMM_WORLD`` (a DistributedELDProblem brings its own).

    Returns
    -------
    DistributedRun
    """
    if not isinstance(problem, DistributedELDProblem):
        problem = DistributedELDProblem.from_problem(problem, comm)
    comm = problem.comm
    _check_resume_processes(resume, comm)
    stepper = PetscELDStepper(
        problem,
        scheme=scheme,
        form=form,
        control=control,
        data=data,
        solver=solver,
        newton=newton,
        noise=noise,
        store_fields=store_fields,
        keep_every=keep_every,
        observer=observer,
        linear_rtol=linear_rtol,
        error_scale=error_scale,
        amg_products=amg_products,
    )
    info, arguments, controller, loop_tau_min = describe_run(
        problem,
        stepper,
        solver_kind=stepper.kind,
        solver=solver,
        noise=None,
        adapt=None,
        store_fields=store_fields,
        linear_rtol=linear_rtol,
        error_scale=error_scale,
        meta=meta,
        backend={
            "backend": "petsc",
            "processes": int(comm.size),
            "amg_products": stepper.amg_products,
        },
    )
    adaptive = isinstance(stepper.control, Adaptive)
    root = comm.rank == 0
    rc = None
    error = None
    if root:
        try:
            rc = RunCheckpointing("run_eld", problem, arguments, checkpoint, resume)
        except RotheInputError as exc:
            error = exc
    error = comm.bcast(error, root=0)
    if error is not None:
        raise error
    try:
        restored = rc.restored if rc is not None else None
        resuming = comm.bcast(restored is not None, root=0)
        if resuming:
            if root:
                traj = restored.trajectory(0)
                traj.meta.update(info)
                traj.meta["sessions"] = restored.sessions + 1
                payload = (restored.state["controller"], asdict(traj.stats))
            else:
                traj, payload = Trajectory(meta=info), None
            ctrl_state, stats = comm.bcast(payload, root=0)
            if not root:
                traj.stats = RunStatistics(**stats)
            state = stepper.restore_state(restored.state["stepper"] if root else None)
            controller.restore_state(ctrl_state)
        else:
            traj = Trajectory(meta=info)
            state = stepper.initial_state()
            stepper.record_initial(traj, state)
            traj.stats.linear_factorizations += stepper.initial_factorizations
        if adaptive:
            traj.meta["error_scale"] = stepper.error_scale
        cp = None
        if comm.bcast(rc is not None and rc.checkpointer is not None, root=0):
            real = rc.checkpointer if root else None
            if root:
                real.register(traj)
            cp = DistributedCheckpointer(comm, real)
            if not resuming:
                cp.save_or_warn(
                    stepper,
                    controller,
                    state,
                    where={"accepted_steps": 0, "s": 0.0, "t": 0.0, "j": 0},
                )
        try:
            final = evolve(
                stepper,
                controller,
                state,
                traj,
                tau_min=loop_tau_min,
                progress=progress if root else False,
                checkpointer=cp,
            )
        except RunFailed as exc:
            exc.trajectory = traj
            raise
        finally:
            _finish_meta(traj, stepper)
        if cp is not None:
            cp.save_or_warn(
                stepper,
                controller,
                final,
                status="completed",
                where=checkpoint_where(traj, final),
            )
    finally:
        if rc is not None:
            rc.close()
    return DistributedRun(traj, final, stepper, controller, problem)


def _finish_meta(traj: Trajectory, stepper: PetscELDStepper) -> None:
    s = stepper.stats
    traj.meta["linear_solver"] = {
        "kind": stepper.kind,
        "engine": "PETSc CG + " + ("GAMG" if stepper.kind == "amg" else "MUMPS LU"),
        "factorizations": s.factorizations,
        "backsolves": s.backsolves,
        "krylov_iterations": s.krylov_iterations,
        "setup_seconds": s.setup_seconds,
    }
