"""A RIS run: the scheme of Alg. 3.2 from (0, 0, z0) until t reaches T, on the one evolve loop.

:func:`run_ris` runs one step control (:class:`~rothe.stepping.controllers.Uniform`,
:class:`~rothe.stepping.controllers.Adaptive` = Alg. 3.2, :class:`~rothe.ris.controllers.Order2`,
:class:`~rothe.ris.controllers.Regime`) and returns a :class:`RISResult`; :func:`run_nested`
runs Alg. 6.2 (:class:`~rothe.ris.controllers.Nested`: one run per tolerance, each never
stepping over a grid point of the runs before it) and returns one result per tolerance.

Why ``run_nested`` is its own driver and not ``run_ris(problem, Nested(...))``: Alg. 6.2 is a
sequence of runs, not a rule for the next step of one run -- run n's controller is built from
the grids of runs 1 ... n-1, and a checkpoint holds the finished runs beside the one under way.
A single ``run_ris`` call therefore always returns one result, and ``run_ris`` refuses a
``Nested`` in one line that points to ``run_nested``.

Both drive :func:`rothe.stepping.evolve.evolve` with a :class:`~rothe.ris.stepper.RISStepper`
and write checkpoints through :class:`~rothe.io.checkpoint.RunCheckpointing`. How a run ended
is its *landing record* (:func:`landing_record`): on T within 1e-10 max(1, T), or at S.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..errors import RunFailed, RunInterrupted, described, fail
from ..fem.adapt import SpaceAdaptivity
from ..io.checkpoint import RunCheckpointing, run_arguments
from ..io.mesh_series import MeshSeries
from ..io.trajectory import RunStatistics, Trajectory
from ..stepping.controllers import Adaptive
from ..stepping.evolve import evolve
from .controllers import (
    AdaptiveController,
    Nested,
    Order2,
    Regime,
    build_controller,
    step_range,
)
from .inner import InnerOptions, RISCode
from .problem import RISProblem
from .stepper import RISState, RISStepper

#: the step control of :func:`run_ris` when none is given: Alg. 3.2 at tol 1e-4, first step 0.1
DEFAULT_CONTROL = Adaptive(tol=1e-4, tau=0.1)


@dataclass
class RISResult:
    """What a RIS run returns.

    Parameters
    ----------
    trajectory : Trajectory
        Every accepted step: point series ``s``, ``t``, ``z`` (nodal values through
        ``problem.full_state``), ``energy``; step series ``tau``, ``I1``, ``I2``, ``I1_err``,
        ``I2_err``, ``lam``, ``kkt``, ``kkt_tol``, ``descent``, ``step_norm``,
        ``newton_iterations`` (and ``mesh_id``, ``n_dofs``, ``transfer_energy``, ``z_mesh_id``
        with ``adapt``); ``meta`` (the control, ``landing``, the linear solver, ...);
        ``stats``; ``meshes`` with ``adapt``.
    state : RISState
        The final state (s_K, t_K, z_K on the unknowns of the final mesh, K).
    control : object
        The step-control object the run used (for run n of :func:`run_nested`, the
        :class:`~rothe.stepping.controllers.Adaptive` of its tolerance).
    landing : dict
        How the run ended (:func:`landing_record`).
    """

    trajectory: Trajectory
    state: RISState
    control: object
    landing: dict

    @property
    def statistics(self) -> RunStatistics:
        """Steps, inner solves, Newton iterations, factorizations, seconds per phase, ..."""
        return self.trajectory.stats

    @property
    def meshes(self) -> MeshSeries | None:
        """The series of meshes of a run with ``adapt`` (None on a fixed mesh)."""
        return self.trajectory.meshes


def initial_trajectory(
    problem: RISProblem, meta: dict | None = None, adaptivity=None
) -> Trajectory:
    """The trajectory with the initial state. With ``adaptivity`` (the stepper's
    :class:`~rothe.ris.adapt.RISAdaptivity`) z is a ragged series, every state records its mesh
    id and dofs, and the meshes are kept."""
    traj = Trajectory(meta=meta)
    traj.append(
        s=0.0,
        t=0.0,
        z=problem.full_state(problem.z0),
        z_step=0,
        energy=problem.energy(0.0, problem.z0),
    )
    if adaptivity is not None:
        _with_meshes(traj, adaptivity)
        traj.append(z_mesh_id=0, mesh_id=0, n_dofs=problem.n)
    return traj


def _with_meshes(traj: Trajectory, adaptivity) -> None:
    traj.set_ragged("z")
    traj.meshes = adaptivity.series


def stored_states(traj: Trajectory):
    """(s, t, z) of the states whose z was kept (all of them unless keep_every > 1)."""
    z = traj["z"]
    idx = traj["z_step"] if "z_step" in traj else np.arange(len(z))
    return traj["s"][idx], traj["t"][idx], z


def landing_record(stepper: RISStepper, state: RISState) -> dict:
    """How the run ended: on T within ``t_tol`` = 1e-10 max(1, T) (``landed``), or at S.

    ``t_final_minus_T`` is the signed miss; ``landed`` is False only if the landing iteration
    (at most ``max_landing_retries`` shortened attempts of the last step) did not reach the
    tolerance, in which case the last accepted step is the attempt closest to T.
    """
    T = stepper.problem.T
    ended_by_S = stepper.S is not None and state.t < T - stepper.t_tol
    return {
        "ended_by": "S" if ended_by_S else "T",
        "T": T,
        "t_final": float(state.t),
        "t_final_minus_T": float(state.t - T),
        "tolerance": stepper.t_tol,
        "landed": bool(ended_by_S or abs(state.t - T) <= stepper.t_tol),
    }


def _keep_last_z(stepper: RISStepper, traj: Trajectory, state: RISState) -> None:
    """With keep_every > 1: make sure z of the last state is kept (once)."""
    steps = traj.entries("z_step")
    if not steps or int(steps[-1]) != state.k:
        traj.append(z=stepper.problem.full_state(state.z), z_step=state.k)
        if stepper.adaptivity is not None:
            traj.append(z_mesh_id=stepper.adaptivity.mesh_id)


def _failure_hint(code) -> str | None:
    """The likely cause behind a result code (:attr:`RISCode.hint`), None for other values."""
    try:
        return RISCode(code).hint
    except ValueError:
        return None


def _evolve(
    stepper: RISStepper,
    controller,
    traj: Trajectory,
    state: RISState,
    *,
    tau_min,
    progress,
    checkpointer,
) -> RISState:
    """The evolve loop, then the run's records in ``traj.meta`` (also when it stops)."""
    try:
        state = evolve(
            stepper,
            controller,
            state,
            traj,
            tau_min=tau_min,
            progress=progress,
            checkpointer=checkpointer,
        )
    except RunInterrupted as exc:
        if exc.state is not None:
            _keep_last_z(stepper, traj, exc.state)
        raise
    except RunFailed as exc:
        hint = _failure_hint(exc.where.get("code"))
        if hint and exc.args and "stagnation_window" not in exc.where:
            exc.args = (f"{exc.args[0]}; {hint}",) + exc.args[1:]
        raise
    finally:
        traj.meta["linear_solver"] = stepper.solver.linear.kind_used
        adaptivity = stepper.adaptivity
        if adaptivity is not None:
            traj.meta.update(adaptivity.meta())  # space_adaptations, transfer_failures, ...
    _keep_last_z(stepper, traj, state)
    traj.meta["landing"] = landing_record(stepper, state)
    return state


def _where(traj: Trajectory, state: RISState) -> dict:
    st = traj.stats
    return {
        "accepted_steps": st.accepted_steps,
        "rejected_steps": st.rejected_steps,
        "s": float(state.s),
        "t": float(state.t),
    }


def _control_arguments(control, name: str) -> dict:
    """What identifies a run's step control in its checkpoint: name, tol, step range, knobs."""
    tau, tau_min, tau_max = step_range(control)
    out = {
        "control": name,
        "tol": getattr(control, "tol", None),
        "tau": tau,
        "tau_min": tau_min,
        "tau_max": tau_max,
    }
    if isinstance(control, Order2):
        out["safety"] = control.safety
    if isinstance(control, Regime):
        out.update(theta=control.theta, grow=control.grow)
    return out


def _run_info(problem: RISProblem, name: str, tol, tau: float, adapt) -> dict:
    """``traj.meta`` of a run: the example, the control, its tolerance and first step."""
    info = {"example": problem.name, "control": name, "tol": tol, "tau0": tau}
    if adapt is not None:  # under the key trajectories have always had (results unchanged)
        info["space"] = adapt.describe()
    return info


def _start(
    problem: RISProblem,
    stepper: RISStepper,
    controller,
    info: dict,
    restored,
    index: int,
    checkpointer,
):
    """The trajectory and the state of run ``index``: restored from the checkpoint or new."""
    if restored is not None:
        traj = restored.trajectory(index)
        traj.meta.update(info)
        traj.meta["sessions"] = restored.sessions + 1
        state = stepper.restore_state(restored.state["stepper"])
        if stepper.adaptivity is not None:
            _with_meshes(traj, stepper.adaptivity)
        controller.restore_state(restored.state["controller"])
        if checkpointer is not None:
            checkpointer.register(traj)
        return traj, state
    traj = initial_trajectory(problem, info, stepper.adaptivity)
    state = RISState(s=0.0, t=0.0, z=problem.z0.copy())
    if checkpointer is not None:
        checkpointer.register(traj)
        checkpointer.save_or_warn(stepper, controller, state, where=_where(traj, state))
    return traj, state


def run_ris(
    problem: RISProblem,
    control=DEFAULT_CONTROL,
    *,
    adapt: SpaceAdaptivity | None = None,
    S: float | None = None,
    inner: InnerOptions | None = None,
    simpson_subintervals: int = 8,
    keep_every: int = 1,
    progress=False,
    meta: dict | None = None,
    checkpoint=None,
    resume=None,
) -> RISResult:
    """Run the scheme of Alg. 3.2 from (0, 0, z0) until t reaches T (or s reaches S).

    Parameters
    ----------
    problem : RISProblem
        The system (1.5) in R^n, or a :class:`~rothe.ris.fem_problem.FERISProblem`.
    control : step-control object
        :class:`~rothe.stepping.controllers.Uniform` (tau[, tau_min]): fixed steps, a failed
        solve retried with half the step; :class:`~rothe.stepping.controllers.Adaptive`
        (tol, tau, tau_min, tau_max): Alg. 3.2; :class:`~rothe.ris.controllers.Order2`,
        :class:`~rothe.ris.controllers.Regime` (beyond the paper; docs/ris.md). The first step
        defaults to 0.1, tau_min to 1e-12. (Alg. 6.2, :class:`~rothe.ris.controllers.Nested`,
        is :func:`run_nested`.)
    adapt : SpaceAdaptivity, optional
        Adapt the P1 mesh of a FERISProblem after every ``adapt_every``-th accepted step
        (:mod:`rothe.ris.adapt`); None keeps the problem's mesh (the run is then exactly the
        fixed-mesh one). With it, ``trajectory["z"]`` is a list (one array per stored state, on
        its mesh), ``z_mesh_id`` / ``mesh_id`` / ``n_dofs`` say which mesh each state lives on,
        ``transfer_energy`` per step the energy change by the transfer, and
        ``trajectory.meshes`` keeps every distinct mesh once.
    S : float, optional
        Stop at s = S instead of t = T.
    inner : InnerOptions, optional
        Tolerances, limits and the linear solver of the inner solver.
    simpson_subintervals : int
        Composite Simpson subintervals for I1, I2 (even, default 8).
    keep_every : int
        Keep z of every k-th accepted state and of the last one (the other series are kept for
        every step; ``z_step`` says which steps z holds, :func:`stored_states`).
    progress : bool or ProgressOptions
        A progress line on stderr (:class:`~rothe.stepping.progress.ProgressOptions`).
    meta : dict, optional
        Added to ``trajectory.meta``.
    checkpoint : path or CheckpointOptions, optional
        Write checkpoints (:class:`~rothe.io.checkpoint.CheckpointOptions`: interval, default
        60 s) at the start, every interval, when the run stops and at the end.
    resume : path, optional
        A checkpoint written by ``run_ris`` with the same arguments and problem (else
        :class:`~rothe.io.checkpoint.CheckpointError`): the run continues from it and returns
        what the uninterrupted run would have, bit for bit (the statistics too, except the
        wall time, which sums the sessions).

    Returns
    -------
    RISResult
        The trajectory, the final state, the control and the landing record;
        ``trajectory.meta['linear_solver']`` records the linear solver that ran.

    Raises
    ------
    RunFailed
        When the step would fall below tau_min, the run makes no progress or the data cannot
        be evaluated (``.trajectory``: the steps so far).
    RunInterrupted
        When SIGINT or SIGTERM arrives (``.trajectory``, ``.checkpoint``).
    """
    controller = build_controller(control)
    tau, tau_min, _ = step_range(control)
    stepper = RISStepper(
        problem, inner, simpson_subintervals, S=S, keep_every=keep_every, adapt=adapt
    )
    info = _run_info(problem, controller.name, getattr(control, "tol", None), tau, adapt)
    info.update(meta or {})
    extra = {} if adapt is None else {"adapt": adapt.describe()}
    arguments = run_arguments(
        **_control_arguments(control, controller.name),
        S=S,
        inner=asdict(inner or InnerOptions()),
        simpson_subintervals=simpson_subintervals,
        keep_every=keep_every,
        **extra,
    )
    with RunCheckpointing("run_ris", problem, arguments, checkpoint, resume) as rc:
        cp = rc.checkpointer
        traj, state = _start(problem, stepper, controller, info, rc.restored, 0, cp)
        state = _evolve(
            stepper, controller, traj, state, tau_min=tau_min, progress=progress, checkpointer=cp
        )
        if cp is not None:
            cp.save_or_warn(
                stepper, controller, state, status="completed", where=_where(traj, state)
            )
    return RISResult(traj, state, control, traj.meta["landing"])


def run_nested(
    problem: RISProblem,
    control: Nested,
    *,
    adapt: SpaceAdaptivity | None = None,
    inner: InnerOptions | None = None,
    simpson_subintervals: int = 8,
    keep_every: int = 1,
    progress=False,
    checkpoint=None,
    resume=None,
) -> list[RISResult]:
    """Alg. 6.2: runs for tol_1 > tol_2 > ...; run n never steps over a grid point of runs < n.

    Run 1 is Alg. 3.2 at tol_1; run n lands exactly on every grid point of the runs before it
    (6.1), so the s-grids nest (Assumption 6.1(3), which Theorem 6.4 needs).

    Parameters
    ----------
    problem : RISProblem
        As for :func:`run_ris`.
    control : Nested
        The tolerances and the step range (:class:`~rothe.ris.controllers.Nested`).
    adapt : SpaceAdaptivity, optional
        As for :func:`run_ris`: every run adapts its own mesh hierarchy from the problem's mesh.
    inner, simpson_subintervals, keep_every, progress
        As for :func:`run_ris`.
    checkpoint, resume
        As for :func:`run_ris`; a checkpoint holds the finished runs and the state of the one
        under way.

    Returns
    -------
    list of RISResult
        One per tolerance, in the order of ``control.tols``; ``meta['nested_index']`` numbers
        them.
    """
    if not isinstance(control, Nested):
        what = repr(control) if isinstance(control, str) else f"a {type(control).__name__}"
        raise fail(
            "control",
            described(what),
            "must be Nested(tols) (rothe.ris.controllers); "
            "the control of a single run goes to run_ris",
        )
    tols = list(control.tols)
    tau, tau_min, tau_max = step_range(control)
    extra = {} if adapt is None else {"adapt": adapt.describe()}
    arguments = run_arguments(
        tols=tols,
        tau=tau,
        tau_min=tau_min,
        tau_max=tau_max,
        inner=asdict(inner or InnerOptions()),
        simpson_subintervals=simpson_subintervals,
        keep_every=keep_every,
        **extra,
    )
    with RunCheckpointing("run_nested", problem, arguments, checkpoint, resume) as rc:
        cp, restored = rc.checkpointer, rc.restored
        results: list[RISResult] = []
        start = 0
        if restored is not None:
            start = int(restored.state["run"]["nested_index"])
            results = _restored_runs(restored, start, control, adapt, cp)
        grid = np.empty(0)
        for r in results:
            grid = np.union1d(grid, r.trajectory["s"][1:])
        for i in range(start, len(tols)):
            tol = tols[i]
            controller = AdaptiveController(
                tol, tau, tau_min, tau_max, grid=grid if i > 0 else None
            )
            stepper = RISStepper(
                problem, inner, simpson_subintervals, keep_every=keep_every, adapt=adapt
            )
            info = _run_info(problem, controller.name, tol, tau, adapt)
            info["nested_index"] = i
            if cp is not None:
                cp.context = _nested_context(i, results, adapt)
            traj, state = _start(
                problem, stepper, controller, info, restored if i == start else None, i, cp
            )
            try:
                state = _evolve(
                    stepper,
                    controller,
                    traj,
                    state,
                    tau_min=tau_min,
                    progress=progress,
                    checkpointer=cp,
                )
            except RunFailed as exc:
                exc.where["nested_tol"] = tol
                raise
            run_control = Adaptive(
                tol, tau=control.tau, tau_min=control.tau_min, tau_max=control.tau_max
            )
            results.append(RISResult(traj, state, run_control, traj.meta["landing"]))
            grid = np.union1d(grid, traj["s"][1:])
        if cp is not None:
            cp.context = _nested_context(len(tols), results, adapt)
            last = results[-1].trajectory
            cp.save_or_warn(
                status="completed",
                where={
                    "accepted_steps": last.stats.accepted_steps,
                    "s": float(last["s"][-1]),
                    "t": float(last["t"][-1]),
                },
            )
    return results


def _nested_context(index: int, results: list[RISResult], adapt) -> dict:
    """The driver's part of a nested checkpoint: the run under way, the final states of the
    finished runs and (with ``adapt``) their meshes."""
    context = {
        "nested_index": index,
        "states": [
            {"s": float(r.state.s), "t": float(r.state.t), "z": r.state.z, "k": int(r.state.k)}
            for r in results
        ],
    }
    if adapt is not None:
        context["series"] = [r.meshes.checkpoint_state() for r in results]
    return context


def _restored_runs(restored, count: int, control: Nested, adapt, checkpointer) -> list:
    """The first ``count`` runs of a nested sequence, finished before the checkpoint."""
    context = restored.state["run"]
    out = []
    for i in range(count):
        traj = restored.trajectory(i)
        if adapt is not None:  # the finished runs' meshes are in the checkpoint's context
            traj.meshes = MeshSeries.restore_state(context["series"][i])
        if checkpointer is not None:
            checkpointer.register(traj)
        data = context["states"][i]
        state = RISState(
            s=float(data["s"]),
            t=float(data["t"]),
            z=np.array(data["z"], dtype=float),
            k=int(data["k"]),
        )
        run_control = Adaptive(
            control.tols[i], tau=control.tau, tau_min=control.tau_min, tau_max=control.tau_max
        )
        out.append(RISResult(traj, state, run_control, traj.meta["landing"]))
    return out
