"""Running an elastodynamics problem from t = 0 to T: :func:`run_eld` and :func:`prepare_eld_run`.

A run is the stepper (:class:`rothe.eld.stepper.ELDStepper`: the scheme, the form, the data, the
linear system, the adapt step), the controller built from the step-control object
(:mod:`rothe.eld.controllers`), the trajectory, and the shared evolve loop
(:func:`rothe.stepping.evolve.evolve`). What a caller chooses are objects, validated in their
constructors: the scheme (:class:`~rothe.eld.scheme.ImplicitEuler`,
:class:`~rothe.eld.scheme.BDF2`), the form (:class:`~rothe.eld.form.Regularized`,
:class:`~rothe.eld.form.Original`), the steps (:class:`~rothe.stepping.controllers.Uniform`,
:class:`~rothe.stepping.controllers.Given`, :class:`~rothe.stepping.controllers.Adaptive`), the
data (:class:`~rothe.eld.data.Points`, :class:`~rothe.eld.data.Means`,
:class:`~rothe.eld.data.Differenced`) and the space adaptivity
(:class:`~rothe.fem.adapt.SpaceAdaptivity`). :func:`run_eld` returns an :class:`ELDResult`.

**Checkpoints** (:mod:`rothe.io.checkpoint`): ``checkpoint=`` writes them (at the start, every
60 s, when stopped, at the end), ``resume=`` continues a run with the same problem and arguments
bit for bit; SIGINT / SIGTERM raise :class:`~rothe.errors.RunInterrupted` with the trajectory so
far (and a checkpoint).
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass

from ..errors import RunFailed, check_choice, described, fail
from ..io.checkpoint import RunCheckpointing
from ..io.trajectory import Trajectory
from ..stepping.controllers import Adaptive
from ..stepping.evolve import evolve
from .adapt import ELDMeshes
from .controllers import checkpoint_where, describe_run
from .data import DEFAULT_DATA, DataMode, DataNoise
from .form import DEFAULT_FORM, Form
from .problem import ELDProblem
from .scheme import DEFAULT_SCHEME, Scheme
from .state import ELDState
from .stepper import DEFAULT_CONTROL, ELDStepper, NewtonOptions

#: where :func:`run_eld` runs: this process, or one mesh on the processes of mpiexec with PETSc
#: (:mod:`rothe.eld.distributed`, docs/scaling.md)
BACKENDS = ("serial", "petsc")


@dataclass
class ELDResult:
    """What :func:`run_eld` returns.

    Parameters
    ----------
    trajectory : Trajectory
        Point series (one entry per state, t = 0 included) ``t, kinetic, elastic, energy, work,
        work_reaction, dissipated, numerical_dissipation, numerical_dissipation_G, step_change,
        data_mismatch, residual_work, transfer, balance_residual``; step series (one per step)
        ``tau, local_error, lam_norm, reaction_<part>, newton_iterations``; with
        ``store_fields`` the kept states (every ``keep_every``-th, t = 0 and the last)
        ``kept_step, kept_t`` and, on a fixed mesh, ``u, v, a`` (interleaved dof vectors of
        ``problem.space``) and ``lam`` (values on the constrained dofs
        ``problem.constraint.dofs``; ``lam[0]`` and ``a[0]`` are the consistent multiplier and
        acceleration at t = 0); ``stats`` and ``meta``. With space adaptivity also ``mesh_id``,
        ``ndofs``, ``cells`` (per state), ``space_estimate``, ``step_dofs``,
        ``step_refinements``, ``step_bisections`` (per step) and ``kept_mesh_id``; the kept
        fields are in ``meshes.kept`` then.
    state : ELDState or None
        The final state (None if the run failed before its first state).
    stepper : ELDStepper or None
    controller : object or None
        The step controller (its state: ``checkpoint_state()``).
    problem : ELDProblem
        The problem on the final mesh (the run's problem on a fixed mesh).
    meshes : ELDMeshes or None
        Space adaptivity: the series of meshes, the kept fields on them and the log of
        adaptations (:class:`rothe.eld.adapt.ELDMeshes`); None on a fixed mesh.
    """

    trajectory: Trajectory
    state: ELDState | None
    stepper: ELDStepper | None
    controller: object
    problem: ELDProblem
    meshes: ELDMeshes | None = None

    @property
    def statistics(self):
        """The run's statistics (``trajectory.stats``: steps, solves, seconds per phase)."""
        return self.trajectory.stats


@dataclass
class ELDRun:
    """A prepared run: the stepper, its controller, the trajectory with the initial state
    recorded (or the trajectory and state restored from a checkpoint), the state to continue
    from and the evolve loop's tau_min (:func:`prepare_eld_run`).

    ``checkpointing`` (a :class:`~rothe.io.checkpoint.RunCheckpointing`, or None) holds the
    lock on the checkpoint directory from :func:`prepare_eld_run` until :meth:`evolve` ends or
    :meth:`close` is called.

    Parameters
    ----------
    stepper : ELDStepper
    controller
        The step controller.
    trajectory : Trajectory
    state : ELDState
        The state to continue from.
    tau_min : float
        The evolve loop's smallest step.
    checkpointing : RunCheckpointing, optional
    """

    stepper: ELDStepper
    controller: object
    trajectory: Trajectory
    state: ELDState
    tau_min: float
    checkpointing: RunCheckpointing | None = None

    @property
    def checkpointer(self):
        """The checkpointer (None without checkpoints)."""
        return None if self.checkpointing is None else self.checkpointing.checkpointer

    @property
    def resumed(self) -> bool:
        """Whether the run continues from a checkpoint."""
        return self.checkpointing is not None and self.checkpointing.resuming

    def result(self) -> ELDResult:
        """The result so far: the trajectory, the current state, the stepper, the controller,
        the problem on the current mesh and the series of meshes."""
        return ELDResult(
            self.trajectory,
            self.state,
            self.stepper,
            self.controller,
            self.stepper.problem,
            self.stepper.meshes,
        )

    def evolve(self, progress=False) -> ELDResult:
        """Run to the end on the shared evolve loop.

        With a checkpointer: a checkpoint of the initial state (a new run), checkpoints when
        due and when the run stops (interrupted, failed), and one with status ``completed`` at
        the end. Raises :class:`RunFailed` / :class:`~rothe.errors.RunInterrupted` with the
        trajectory so far.

        Returns
        -------
        ELDResult
        """
        cp = self.checkpointer
        try:
            if cp is not None and not self.resumed and cp.sequence == 0:
                cp.save_or_warn(
                    self.stepper,
                    self.controller,
                    self.state,
                    where=checkpoint_where(self.trajectory, self.state),
                )
            try:
                final = evolve(
                    self.stepper,
                    self.controller,
                    self.state,
                    self.trajectory,
                    tau_min=self.tau_min,
                    progress=progress,
                    checkpointer=cp,
                )
            except RunFailed as exc:
                exc.trajectory = self.trajectory
                raise
            finally:
                _finish_meta(self.trajectory, self.stepper)
            self.state = final
            if cp is not None:
                cp.save_or_warn(
                    self.stepper,
                    self.controller,
                    final,
                    status="completed",
                    where=checkpoint_where(self.trajectory, final),
                )
        finally:
            self.close()
        return self.result()

    def close(self) -> None:
        """Release the checkpoint directory (done by :meth:`evolve`)."""
        if self.checkpointing is not None:
            self.checkpointing.close()


def prepare_eld_run(
    problem: ELDProblem,
    *,
    scheme: Scheme = DEFAULT_SCHEME,
    form: Form = DEFAULT_FORM,
    control=DEFAULT_CONTROL,
    data: DataMode = DEFAULT_DATA,
    adapt=None,
    solver: str = "auto",
    newton: NewtonOptions | None = None,
    noise: DataNoise | None = None,
    store_fields: bool = True,
    keep_every: int = 1,
    observer=None,
    linear_rtol: float = 1e-10,
    error_scale: float | None = None,
    meta: dict | None = None,
    checkpoint=None,
    resume=None,
) -> ELDRun:
    """Validate the options, build stepper and controller, record the initial state (the
    arguments of :func:`run_eld`); with ``resume``, restore stepper, controller, trajectory and
    state from the checkpoint instead.

    Parameters
    ----------
    problem : ELDProblem
    scheme, form, control, data, adapt, solver, newton, noise
        As in :func:`run_eld`.
    store_fields, keep_every, observer, linear_rtol, error_scale, meta, checkpoint, resume
        As in :func:`run_eld`.

    Returns
    -------
    ELDRun
        Run it with :meth:`ELDRun.evolve`.
    """
    stepper = ELDStepper(
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
        adapt=adapt,
    )
    described_run = describe_run(
        problem,
        stepper,
        solver_kind=stepper.system.kind,
        solver=solver,
        noise=noise,
        adapt=adapt,
        store_fields=store_fields,
        linear_rtol=linear_rtol,
        error_scale=error_scale,
        meta=meta,
    )
    info, arguments, controller, loop_tau_min = described_run
    adaptive = isinstance(stepper.control, Adaptive)
    rc = RunCheckpointing("run_eld", problem, arguments, checkpoint, resume)
    try:
        restored = rc.restored
        if restored is not None:
            traj = restored.trajectory(0)
            traj.meta.update(info)
            traj.meta["sessions"] = restored.sessions + 1
            state = stepper.restore_state(restored.state["stepper"])
            controller.restore_state(restored.state["controller"])
            if adaptive:
                traj.meta["error_scale"] = stepper.error_scale
        else:
            traj = Trajectory(meta=info)
            try:
                state = stepper.initial_state()
            except RunFailed as exc:
                exc.trajectory = traj
                _finish_meta(traj, stepper)
                raise
            if adaptive:
                traj.meta["error_scale"] = stepper.error_scale
            stepper.record_initial(traj, state)
            traj.stats.linear_factorizations += stepper.initial_factorizations
        if rc.checkpointer is not None:
            rc.checkpointer.register(traj)
    except BaseException:
        rc.close()
        raise
    return ELDRun(stepper, controller, traj, state, loop_tau_min, rc)


def run_eld(
    problem: ELDProblem, *, progress=False, backend: str = "serial", **options
) -> ELDResult:
    """Run implicit Euler (3.4) or BDF2 from t = 0 to T on the shared evolve loop.

    Parameters
    ----------
    problem : ELDProblem
    scheme : ImplicitEuler or BDF2, default ImplicitEuler()
        The time scheme (:mod:`rothe.eld.scheme`; ``BDF2(start='taylor')``).
    form : Regularized or Original, default Regularized(lifting='nodal')
        The form of the DAE (:mod:`rothe.eld.form`).
    control : Uniform, Given or Adaptive, default Uniform(0.01)
        ``Uniform(tau)``: n = T/tau equal steps (tau must divide T); ``Given(steps)``: a
        sequence summing to T; ``Adaptive(tol, tau=..., tau_min=..., tau_max=...)``: the local
        error estimate (relative to the energy-norm scale S_j, floor ``error_scale``) kept below
        tol, first step ``tau`` (default 0.01), steps in [tau_min, tau_max] (defaults 1e-10 T
        and T). Uniform steps and given sequences are checked against Lemma 3.2 before the first
        step.
    data : Points, Means or Differenced, default Points()
        How F, G, G_dot, G_ddot enter a step (:mod:`rothe.eld.data`).
    adapt : SpaceAdaptivity, optional
        Adapt the mesh after every ``adapt_every``-th accepted step (:mod:`rothe.eld.adapt`;
        data ``Points()``, no noise); None (default) keeps the mesh.
    solver : {'auto', 'direct', 'amg'}
        The linear solver (:mod:`rothe.eld.solvers`).
    newton : NewtonOptions, optional
    noise : DataNoise, optional
        Perturbation of the data of every step (Theorem 4.5).
    store_fields : bool
        Keep u, v, a, lambda of every ``keep_every``-th state, t = 0 and the last.
    keep_every : int
    observer : callable(state, result), optional
        Called with the initial state (``result`` None; its ``lam`` is the consistent
        multiplier lambda(0) of :mod:`rothe.eld.start`) and after every accepted step (e.g. an
        output writer; one that keeps state is passed as a checkpoint attachment so that it is
        restored too, and a resumed run does not call it for the initial state again).
    progress : bool or ProgressOptions
    linear_rtol : float
        Relative residual of iterative linear solves.
    error_scale : float, optional
        Floor of the adaptive controller's scale (default :func:`rothe.eld.start.data_scale`).
    meta : dict, optional
        Added to the trajectory's meta data.
    checkpoint, resume : optional
        A directory or :class:`~rothe.io.checkpoint.CheckpointOptions`; a checkpoint written by
        ``run_eld`` with the same arguments and problem. A resumed run returns the trajectory of
        the uninterrupted run bit for bit (statistics too, but the wall time, which sums the
        sessions).
    backend : {'serial', 'petsc'}
        ``'petsc'``: the mesh partitioned over the processes of ``mpiexec`` (every process
        calls run_eld), PETSc's CG with GAMG or MUMPS (:mod:`rothe.eld.distributed`; needs
        mpi4py and petsc4py; no ``adapt``, data ``Points()``, no noise, the nodal lifting).
        ``problem`` may then be a :class:`~rothe.eld.distributed.DistributedELDProblem`. The
        answer is the serial one to the solver tolerance; the fields of the trajectory are
        complete on rank 0, the state holds each process's owned dofs.
    amg_products : {'fast', 'lean'}
        Backend ``'petsc'`` only: how GAMG forms its coarse operators P^T A P
        (:data:`rothe.eld.solvers.AMG_PRODUCTS`). ``'fast'`` (default): PETSc's two-step
        product; ``'lean'``: the all-at-once product, which never stores A P — about 0.75x the
        peak memory per process on two processes, for a set-up 5-7x slower (docs/scaling.md;
        on one process both are PETSc's sequential product).

    Returns
    -------
    ELDResult
        The trajectory, the final state, the stepper, the controller, the problem on the final
        mesh and (space adaptivity) the series of meshes.

    Raises :class:`RunFailed` (with ``.trajectory``) if a step cannot be solved or its state or
    data is not finite, :class:`~rothe.errors.RunInterrupted` on SIGINT / SIGTERM, and
    :class:`~rothe.errors.RotheInputError` (one line naming the parameter) for bad input.
    """
    if check_choice("backend", backend, BACKENDS) == "petsc":
        if options.pop("adapt", None) is not None:
            raise fail(
                "adapt",
                described("a SpaceAdaptivity"),
                "is not supported with backend 'petsc' (space adaptivity is not distributed): "
                "run it serially",
            )
        # PETSc and MPI (optional, heavy) are imported only for this backend
        from .distributed.run import run_eld_petsc

        done = run_eld_petsc(problem, progress=progress, **options)
        return ELDResult(done.trajectory, done.state, done.stepper, done.controller, done.problem)
    if "amg_products" in options:
        raise fail(
            "amg_products",
            options["amg_products"],
            "is an option of backend 'petsc' (PETSc's GAMG); the serial backend's AMG is pyamg",
        )
    return prepare_eld_run(problem, **options).evolve(progress=progress)


def _finish_meta(traj: Trajectory, stepper: ELDStepper) -> None:
    system = stepper.system
    s = system.solver.stats
    traj.meta["linear_solver"] = {
        "kind": system.kind,
        "factorizations": s.factorizations,
        "backsolves": s.backsolves,
        "krylov_iterations": s.krylov_iterations,
        "setup_seconds": s.setup_seconds,
    }


# help(run_eld) and inspect show every keyword: those of prepare_eld_run, progress and backend
def _run_eld_signature() -> inspect.Signature:
    prepare = inspect.signature(prepare_eld_run)
    names = list(prepare.parameters)
    params = list(prepare.parameters.values())
    progress = inspect.Parameter("progress", inspect.Parameter.KEYWORD_ONLY, default=False)
    params.insert(names.index("observer") + 1, progress)
    backend = inspect.Parameter(
        "backend", inspect.Parameter.KEYWORD_ONLY, default="serial", annotation="str"
    )
    params.append(backend)
    params.append(
        inspect.Parameter(
            "amg_products", inspect.Parameter.KEYWORD_ONLY, default="fast", annotation="str"
        )
    )
    return prepare.replace(parameters=params, return_annotation="ELDResult")


run_eld.__signature__ = _run_eld_signature()
