"""The evolve loop shared by every step controller (and every stepper): every phase in one place.

    while not stepper.finished(state):
        (stop here if a stop signal arrived: checkpoint, then RunInterrupted)
        tau, s_end = controller.propose(s)          # propose: the controller
        result = stepper.step(state, tau, s_end)    # step: the stepper does one step, decides
                                                    #   nothing (shortened while it overshoots
                                                    #   the end: stepper.overshoot); a stop
                                                    #   signal may abandon it (interrupt.check)
        decision = controller.decide(result)        # accept or reject: the controller
        if decision.accept:
            state = stepper.adapt(result.state, result)   # adapt: a new mesh, or the same state
                                                    #   (a stop signal may abandon the attempt
                                                    #   up to here, the adapt step included)
            stepper.record(trajectory, result, state)     # record the accepted step
        else: retry with decision.next_tau
        (write a checkpoint when one is due, or SIGUSR1 asked for one)   # checkpoint

A stepper provides ``step(state, tau, s_end) -> result`` (with ``converged``, ``code``, ``tau``,
``errors``, ``state`` and solver counters), ``adapt(state, result) -> state`` (the state to go on
from: the accepted one, or a new state on an adapted mesh; never the accepted state changed in
place), ``record(trajectory, result, state)`` (the accepted step ``result`` and the state after
the adapt step), ``finished(state)``, ``limit(state, tau)`` (e.g. to stop at a given S),
``overshoot(state, attempts)`` (a shorter tau that lands on the end time, or None, given the
attempts of this step so far) with ``pick_landing(state, attempts)`` (the attempt to hand to the
controller), ``where(state, result)``, ``progress_fields(state)``, optionally
``begin_attempt(state)`` (called before each attempt: the point to return to) with
``abandon(state)`` (undo what an abandoned attempt changed in the stepper, see *Signals*),
``progress_position(state) -> (label, value, total)`` and ``times`` (a
:class:`~rothe.timing.PhaseTimes` of the phases inside its step and adapt step: estimate,
mark, refine, transfer, rebuild, factor, solve), added to ``trajectory.stats.seconds`` with the
loop's own phases (step, adapt, record, checkpoint).
For checkpoints, ``checkpoint_state(state) -> dict`` and ``restore_state(data) -> state`` (the
controller: ``checkpoint_state() -> dict``, ``restore_state(data)``); see
:mod:`rothe.io.checkpoint` and docs/robustness.md.

If a rejection would push the step below ``tau_min``, the loop raises :class:`RunFailed` naming
the step, s, t, tau and the residuals; the trajectory so far is attached to the exception.

Signals (:mod:`rothe.stepping.interrupt`): between two steps the loop checks whether a stop
signal (SIGINT, SIGTERM, SIGHUP, SIGQUIT) arrived; if so it writes a checkpoint (when it has a
checkpointer) and raises :class:`~rothe.errors.RunInterrupted` with the trajectory so far.
Inside an attempt -- the step, its landing retries, the decision and, after an acceptance, the
adapt step (RIS relaxes the transferred state there by the step's own solver) -- a stepper that
calls :func:`rothe.stepping.interrupt.check` between its iterations lets the signal take effect
at once: the attempt raises :class:`~rothe.stepping.interrupt.StepAbandoned`, the loop drops it
(never accepted or recorded, its counts taken back, the controller's state put back as it was
before the attempt), calls ``stepper.abandon(state)`` when the stepper has it, and stops as
above with the last accepted state. A stepper that never calls ``check`` finishes its step
first. SIGUSR1 asks for a checkpoint: written at the next step boundary, the run goes on.
"""

from __future__ import annotations

import time
from contextlib import nullcontext

from ..errors import RunFailed, RunInterrupted, check_int, check_positive
from ..io.trajectory import Trajectory
from ..timing import PhaseTimes
from . import interrupt
from .progress import Progress, as_progress_options

_BLAS_CONTROLLER = []  # the one threadpoolctl controller of the process (found libraries)


def single_threaded_blas():
    """Limit BLAS to one thread while stepping.

    The steppers are dominated by level-1 operations (dots, norms) on vectors of 1e3-1e6
    entries and by sparse solves that do not use BLAS threads. Threaded OpenBLAS level-1 calls
    spin-wait for their workers: on 2 busy cores a 25k-entry dot took 650 us instead of 8 us
    and a whole 160x160 run was 3.3x slower. ``threadpoolctl`` sets the limit even when numpy was
    imported first (environment variables would be too late then). Its controller (the scan of
    the loaded libraries, 2-4 ms) is made once per process: the factorization of every mesh of
    a space-adaptive run enters this context.
    """
    if not _BLAS_CONTROLLER:
        try:
            # heavy: imported when first needed (start-up time of the command line)
            from threadpoolctl import ThreadpoolController
        except ImportError:  # pragma: no cover - a declared dependency
            return nullcontext()
        _BLAS_CONTROLLER.append(ThreadpoolController())
    return _BLAS_CONTROLLER[0].limit(limits=1, user_api="blas")


def evolve(
    stepper,
    controller,
    state,
    trajectory: Trajectory,
    *,
    tau_min: float = 1e-12,
    max_attempts: int = 1_000_000,
    max_landing_retries: int = 6,
    max_steps: int | None = None,
    progress=False,
    checkpointer=None,
):
    """Run from ``state`` until ``stepper.finished`` (or ``max_steps`` accepted steps in this
    call); returns the final state.

    Accepted steps are recorded into ``trajectory`` (``stepper.record``); statistics are
    accumulated in ``trajectory.stats`` (the wall time adds to what is there, so a resumed run
    sums its sessions). BLAS runs single-threaded meanwhile (:func:`single_threaded_blas`).
    ``progress``: bool or :class:`~rothe.stepping.progress.ProgressOptions`.
    ``checkpointer``: a :class:`~rothe.io.checkpoint.Checkpointer` (with ``trajectory``
    registered) to which a checkpoint is written when one is due, and when the run stops
    (interrupted or failed). Raises :class:`RunFailed` or :class:`RunInterrupted`, both carrying
    the trajectory so far.

    Parameters
    ----------
    stepper
        The family's stepper (``step``, ``record``, ``adapt``, ``finished``, ...).
    controller
        A step controller (``propose``, ``decide``).
    state
        The state to start from (recorded already).
    trajectory : Trajectory
    tau_min : float
        The run fails (:class:`RunFailed`) when a step below it is proposed.
    max_attempts : int
        Most step attempts in this call.
    max_landing_retries : int
        Most shorter retries of a step that overshoots the end.
    max_steps : int, optional
        Stop after this many accepted steps in this call (None: at the end).
    progress : bool or ProgressOptions
    checkpointer : Checkpointer, optional

    Returns
    -------
    state
        The final state.
    """
    tau_min = check_positive("tau_min", tau_min)
    if max_steps is not None:
        max_steps = check_int("max_steps", max_steps, minimum=1)
    with single_threaded_blas(), interrupt.interruptible():
        loop = _Loop(stepper, controller, trajectory, checkpointer, as_progress_options(progress))
        try:
            return loop.run(state, tau_min, max_attempts, max_landing_retries, max_steps)
        except RunFailed as exc:  # a stepper's own failure: still hand back what was computed
            if exc.trajectory is None:
                exc.trajectory = trajectory
            loop.checkpoint("failed", where={**exc.where, "failure": str(exc)}, quiet=True)
            raise
        finally:
            loop.close()


class _Loop:
    def __init__(self, stepper, controller, trajectory, checkpointer, progress):
        self.stepper = stepper
        self.controller = controller
        self.trajectory = trajectory
        self.checkpointer = checkpointer
        self.progress_options = progress
        self.progress = None
        self.state = None
        self.times = PhaseTimes()  # the loop's own phases
        self._mark = time.perf_counter()

    def _clock(self) -> None:
        """Add the time since the last mark, and the phase seconds so far, to the statistics
        (so checkpoints carry them)."""
        now = time.perf_counter()
        stats = self.trajectory.stats
        stats.wall_time_s += now - self._mark
        self._mark = now
        seconds = PhaseTimes(stats.seconds)
        seconds.add(self.times.take())
        inner = getattr(self.stepper, "times", None)
        if inner is not None:
            seconds.add(inner.take())
        stats.seconds = dict(seconds)

    def where(self, state) -> dict:
        stats = self.trajectory.stats
        info = {"accepted_steps": stats.accepted_steps, "rejected_steps": stats.rejected_steps}
        info.update(self.stepper.where(state, None))
        return info

    def checkpoint(self, status: str, where: dict | None = None, quiet: bool = False):
        if self.checkpointer is None or self.state is None:
            return None
        self._clock()
        info = self.where(self.state)
        info.update(where or {})
        try:
            with self.times.phase("checkpoint"):
                return self.checkpointer.save_or_warn(
                    self.stepper, self.controller, self.state, status=status, where=info
                )
        except Exception:
            if quiet:  # the failure being reported matters more than its checkpoint
                return None
            raise

    def stop_if_signalled(self, state, abandoned: bool = False) -> None:
        signum = interrupt.requested()
        if signum is None:
            return
        name = interrupt.signal_name(signum)
        extra = {"signal": name}
        if abandoned:
            extra["abandoned_step"] = True
        where = self.where(state)
        where.update(extra)
        path = self.checkpoint("interrupted", where=extra)
        raise RunInterrupted(
            f"interrupted by {name} after {where['accepted_steps']} accepted steps "
            f"(s = {where.get('s', float('nan')):.6g}, t = {where.get('t', float('nan')):.6g}"
            + ("; the step under way was abandoned)" if abandoned else ")"),
            signum=signum,
            where=where,
            trajectory=self.trajectory,
            checkpoint=path,
            state=state,
        )

    def abandon(self, state, counts: dict, controller_state: dict | None) -> None:
        """A stop signal abandoned the attempt under way (StepAbandoned): forget it -- the
        statistics go back to ``counts`` and the controller to ``controller_state``, both taken
        before the attempt; the stepper undoes its own changes in ``abandon`` -- then stop with
        the last accepted ``state``."""
        stats = self.trajectory.stats
        for key, value in counts.items():
            setattr(stats, key, value)
        if controller_state is not None:
            self.controller.restore_state(controller_state)
        undo = getattr(self.stepper, "abandon", None)
        if undo is not None:
            undo(state)
        self.stop_if_signalled(state, abandoned=True)
        raise AssertionError("a step was abandoned without a stop signal")  # pragma: no cover

    def checkpoint_if_asked(self) -> None:
        """A checkpoint when one is due, or now if SIGUSR1 asked for one (the run goes on)."""
        asked = interrupt.checkpoint_requested()
        if self.checkpointer is None:
            if asked:
                self.progress.note(
                    "rothe: SIGUSR1: this run writes no checkpoint (none was asked for)"
                )
            return
        if asked or self.checkpointer.due():
            path = self.checkpoint("running")
            if asked:
                w = self.where(self.state)
                written = f"written to {path}" if path is not None else "NOT written"
                self.progress.note(
                    f"rothe: SIGUSR1: checkpoint {written} after {w['accepted_steps']} accepted "
                    f"steps (s = {w.get('s', float('nan')):.6g}, t = "
                    f"{w.get('t', float('nan')):.6g}); the run goes on"
                )

    def run(self, state, tau_min, max_attempts, max_landing_retries, max_steps):
        stepper, controller, trajectory = self.stepper, self.controller, self.trajectory
        stats = trajectory.stats
        times = self.times
        self.state = state
        self.progress = Progress(self.progress_options, stepper, state)
        attempts = stats.accepted_steps + stats.rejected_steps  # nonzero when resumed
        accepted_here = 0
        while not stepper.finished(state):
            if max_steps is not None and accepted_here >= max_steps:
                break
            self.stop_if_signalled(state)
            attempts += 1
            if attempts > max_attempts:
                raise RunFailed(
                    f"stopped after {max_attempts} step attempts without reaching the end",
                    where=stepper.where(state, None),
                    trajectory=trajectory,
                )
            # one attempt: propose, step (and its landing retries), decide and, when accepted,
            # the adapt step; a stop signal may abandon it anywhere in there (interrupt.check)
            counts = {key: getattr(stats, key) for key in _COUNTED}
            before = _controller_state(controller)
            begin = getattr(stepper, "begin_attempt", None)
            if begin is not None:
                begin(state)
            try:
                with interrupt.abandonable():
                    # propose
                    tau, s_end = controller.propose(state.s)
                    tau_lim = stepper.limit(state, tau)
                    if tau_lim < tau:
                        tau, s_end = tau_lim, None
                    # step (shortened while it overshoots the end)
                    with times.phase("step"):
                        result = stepper.step(state, tau, s_end)
                        _count(stats, result)
                        attempts_here = [result]
                        for _ in range(max_landing_retries):
                            shorter = stepper.overshoot(state, attempts_here)
                            if shorter is None:
                                break
                            stats.landing_retries += 1
                            attempts_here.append(stepper.step(state, shorter, None))
                            _count(stats, attempts_here[-1])
                        if len(attempts_here) > 1:
                            result = stepper.pick_landing(state, attempts_here)
                    # accept or reject
                    decision = controller.decide(result)
                    if decision.accept:
                        stats.accepted_steps += 1
                        # adapt: the state to go on from (a new mesh, or the accepted state)
                        try:
                            with times.phase("adapt"):
                                new_state = stepper.adapt(result.state, result)
                        except RunFailed:  # the accepted step stands, on its own mesh: keep it
                            self.state = result.state
                            stepper.record(trajectory, result, result.state)
                            raise
            except interrupt.StepAbandoned:
                self.abandon(state, counts, before)
            if decision.accept:
                accepted_here += 1
                state = self.state = new_state
                # record the accepted step (and what the adapt step did)
                with times.phase("record"):
                    stepper.record(trajectory, result, state)
            else:
                stats.rejected_steps += 1
                if decision.next_tau < tau_min:
                    where = stepper.where(state, result)
                    where["tau_next"] = decision.next_tau
                    raise RunFailed(
                        "step size fell below tau_min = "
                        f"{tau_min:g} at step {where.get('step')} (s = {where.get('s'):.6g}, "
                        f"t = {where.get('t'):.6g}, tau = {result.tau:.3g}; {decision.reason})",
                        where=where,
                        trajectory=trajectory,
                    )
            self.progress.update(state, stats)
            self.checkpoint_if_asked()
        return state

    def close(self) -> None:
        self._clock()
        if self.progress is not None:
            done = self.state is not None and self.stepper.finished(self.state)
            self.progress.close(
                self.state, self.trajectory.stats, "finished" if done else "stopped"
            )


#: the statistics an attempt adds to (put back when it is abandoned; _count adds the middle ones)
_COUNTED = (
    "inner_solves",
    "newton_iterations",
    "fb_steps",
    "linear_factorizations",
    "linear_solves",
    "krylov_iterations",
    "landing_retries",
    "accepted_steps",
)


def _controller_state(controller) -> dict | None:
    """The controller's state before an attempt (put back when the attempt is abandoned after
    the controller decided on it), or None for a controller without the checkpoint protocol."""
    save = getattr(controller, "checkpoint_state", None)
    if save is None or getattr(controller, "restore_state", None) is None:
        return None
    return save()


def _count(stats, result) -> None:
    stats.inner_solves += 1
    for key in _COUNTED[1:-2]:
        setattr(stats, key, getattr(stats, key) + int(result.counters.get(key, 0)))
