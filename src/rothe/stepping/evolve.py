"""The evolve loop shared by every step controller (and every stepper).

    while not stepper.finished(state):
        tau, s_end = controller.propose(s)         # the controller proposes
        result = stepper.step(state, tau, s_end)   # the stepper does one step, decides nothing
        (shorten the step if it overshoots the end: stepper.overshoot)
        decision = controller.decide(result)       # the controller accepts or rejects
        accept -> state = result.state, record; reject -> retry with decision.next_tau

A stepper provides ``step(state, tau, s_end) -> result`` (with ``converged``, ``code``, ``tau``,
``errors``, ``state`` and solver counters), ``finished(state)``, ``limit(state, tau)`` (e.g. to
stop at a given S), ``overshoot(state, attempts)`` (a shorter tau that lands on the end time, or
None, given the attempts of this step so far) with ``pick_landing(state, attempts)`` (the attempt to
hand to the controller), ``record(trajectory, result)`` and ``progress_fields(state)``.

If a rejection would push the step below ``tau_min``, the loop raises :class:`RunFailed` naming
the step, s, t, tau and the residuals; the trajectory so far is attached to the exception.
"""

from __future__ import annotations

import sys
import time
from contextlib import nullcontext

from ..errors import RunFailed, check_positive
from ..io.trajectory import Trajectory


def _progress_bar(enabled: bool):
    if not enabled:
        return None
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover - tqdm is a dependency
        return None
    # delay: runs shorter than about a second never show a bar; disable=None: no bar when
    # stderr is not a terminal (logs, CI), where carriage returns only clutter the file
    return tqdm(
        total=None,
        file=sys.stderr,
        delay=1.0,
        unit="step",
        leave=False,
        dynamic_ncols=True,
        disable=None,
    )


def single_threaded_blas():
    """Limit BLAS to one thread while stepping.

    The steppers are dominated by level-1 operations (dots, norms) on vectors of 1e3-1e6
    entries and by sparse solves that do not use BLAS threads. Threaded OpenBLAS level-1 calls
    spin-wait for their workers: on 2 busy cores a 25k-entry dot took 650 us instead of 8 us
    and a whole 160x160 run was 3.3x slower. ``threadpoolctl`` sets the limit even when numpy was
    imported first (environment variables would be too late then).
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - a declared dependency
        return nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


def evolve(
    stepper,
    controller,
    state,
    trajectory: Trajectory,
    *,
    tau_min: float = 1e-12,
    max_attempts: int = 1_000_000,
    max_landing_retries: int = 6,
    progress: bool = False,
):
    """Run from ``state`` until ``stepper.finished``; returns the final state.

    Accepted steps are recorded into ``trajectory`` (``stepper.record``); statistics are
    accumulated in ``trajectory.stats``. BLAS runs single-threaded meanwhile
    (:func:`single_threaded_blas`).
    """
    with single_threaded_blas():
        try:
            return _evolve(stepper, controller, state, trajectory, tau_min=tau_min,
                           max_attempts=max_attempts, max_landing_retries=max_landing_retries,
                           progress=progress)
        except RunFailed as exc:  # a stepper's own failure: still hand back what was computed
            if exc.trajectory is None:
                exc.trajectory = trajectory
            raise


def _evolve(stepper, controller, state, trajectory, *, tau_min, max_attempts,
            max_landing_retries, progress):
    tau_min = check_positive("tau_min", tau_min)
    stats = trajectory.stats
    bar = _progress_bar(progress)
    t_start = time.perf_counter()
    attempts = 0
    try:
        while not stepper.finished(state):
            attempts += 1
            if attempts > max_attempts:
                raise RunFailed(
                    f"stopped after {max_attempts} step attempts without reaching the end",
                    where=stepper.where(state, None),
                    trajectory=trajectory,
                )
            tau, s_end = controller.propose(state.s)
            tau_lim = stepper.limit(state, tau)
            if tau_lim < tau:
                tau, s_end = tau_lim, None
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
            decision = controller.decide(result)
            if decision.accept:
                state = result.state
                stepper.record(trajectory, result)
                stats.accepted_steps += 1
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
            if bar is not None:
                bar.update(1)
                fields = stepper.progress_fields(state)
                fields.update(acc=stats.accepted_steps, rej=stats.rejected_steps)
                bar.set_postfix(fields, refresh=False)
    finally:
        stats.wall_time_s += time.perf_counter() - t_start
        if bar is not None:
            bar.close()
    return state


def _count(stats, result) -> None:
    stats.inner_solves += 1
    for key in (
        "newton_iterations",
        "fb_steps",
        "linear_factorizations",
        "linear_solves",
        "krylov_iterations",
    ):
        setattr(stats, key, getattr(stats, key) + int(result.counters.get(key, 0)))
