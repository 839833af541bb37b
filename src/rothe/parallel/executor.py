"""Where independent runs execute: in this process, or on a Dask cluster.

:class:`Executor` maps a list of :class:`~rothe.parallel.tasks.Task` to their
:class:`~rothe.parallel.tasks.TaskResult`, in the order of the tasks, whatever order they finish:

- ``Executor(workers=1)``: one after another in this process (Dask is not imported);
- ``Executor(workers=N)``: a ``distributed.LocalCluster`` of N worker *processes* with one thread
  each (the runs are GIL-bound Python with single-threaded BLAS), started for the map (or for the
  ``with`` block) and closed afterwards;
- ``Executor(scheduler=ADDRESS)`` (or a ``distributed.Client``, or a cluster object such as
  dask-jobqueue's ``SLURMCluster``): an existing cluster; the executor only connects.

Failure semantics: a run that fails is a result with its status, never an exception here (see
:func:`~rothe.parallel.tasks.execute_task`). A task whose worker dies (killed, out of memory) is
re-run once on another worker: the local cluster's scheduler allows one worker death per task
(``allowed_failures=1``); a second death makes the result ``lost``. Tasks are also submitted with
Dask ``retries=1``, which covers exceptions raised outside the run itself (e.g. unpickling on the
worker); a run's own failure is deterministic and not retried. Expensive tasks (``Task.cost``)
are started first.

Progress: on a terminal a bar of runs done / total; otherwise (logs, CI) one line per finished
run (and, in-process, one per started run), so a log says which run of how many is going.

Signals: during a map (in the main thread) SIGINT, SIGTERM, SIGHUP and SIGQUIT stop it with
:class:`~rothe.errors.RunInterrupted` instead of killing the process (the default for SIGTERM),
so that the cluster is closed and the caller can keep what finished (:attr:`Executor.finished`,
:attr:`Executor.started`). A run under way in this process handles the signal itself (its
session writes a checkpoint and its results so far, then the map stops); runs on Dask workers are
cancelled and keep their last checkpoint. A second signal ends the process at once.
"""

from __future__ import annotations

import importlib.util
import logging
import os
import re
import signal
import sys
import threading
import time
import uuid

from ..errors import RotheInputError, RunInterrupted, check_int, fail, integer_allowed
from ..stepping import interrupt
from .tasks import Task, TaskResult, execute_task

#: seconds to wait for an existing scheduler (``--scheduler``) before giving up
CONNECT_TIMEOUT_S = 5.0
#: seconds a local cluster may have no worker at all before the waiting runs are lost
LOCAL_NO_WORKER_TIMEOUT_S = 120.0
INSTALL_HINT = 'pip install "rothe[dask]"'


def dask_available() -> bool:
    """Whether dask.distributed can be imported (without importing it)."""
    if "distributed" in sys.modules:  # None there: the import is blocked
        return sys.modules["distributed"] is not None
    try:
        return importlib.util.find_spec("distributed") is not None
    except (ImportError, ValueError):
        return False


def cpu_count() -> int:
    """The CPUs this process may run on (its affinity; ``os.cpu_count()`` where there is none)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - macOS, Windows
        return os.cpu_count() or 1


def check_workers(name: str, workers) -> int:
    """A local cluster's worker count: an integer from 1 to the cores this process may use.

    Every worker is a process running one single-threaded run, so workers beyond the cores only
    share them (each run slower, the total no faster) and multiply the memory; --workers 1000
    started 1000 processes and failed after 106 s with a "Nanny failed to start" traceback. A
    larger cluster is reached with ``scheduler`` instead (the message mentions it: the command
    line names it ``--scheduler``)."""
    n = check_int(name, workers, minimum=1)
    cores = cpu_count()
    if n > cores:
        raise RotheInputError(
            f"{name}: got {n}, must be at most {cores} (the cores this process may use; a "
            "worker runs one single-threaded run, more workers than cores only share them; "
            "scheduler runs on a larger cluster)",
            name,
            mentions=("scheduler",),
        )
    return n


def default_workers() -> int:
    """``ROTHE_WORKERS`` if set, else the number of cores when Dask is installed, else 1."""
    env = os.environ.get("ROTHE_WORKERS")
    if env:
        try:
            n = int(env)
        except ValueError:
            raise fail("ROTHE_WORKERS", env, integer_allowed(1)) from None
        return check_workers("ROTHE_WORKERS", n)
    return cpu_count() if dask_available() else 1


def _import_distributed(what: str):
    try:
        import distributed  # heavy: imported when first needed (start-up time)
    except ImportError:
        raise RotheInputError(f"{what} needs dask.distributed: {INSTALL_HINT}") from None
    return distributed


def local_cluster(n_workers: int, **kwargs):
    """The ``distributed.LocalCluster`` of ``--workers N``: N worker processes with one thread
    each, no dashboard, and one retry for a task whose worker dies (``allowed_failures=1``).

    The workers' statistical profiler is off: it only feeds the dashboard, and sampling the
    run's stack every 10 ms cost about 1.5 % of a core per worker."""
    distributed = _import_distributed(f"workers={n_workers}")
    import dask  # heavy: imported when first needed (start-up time)

    # Dask's own log lines (a worker's heartbeat that meets the closing scheduler, a task marked
    # failed after its workers died) only repeat what the results report, with tracebacks
    options = dict(
        n_workers=n_workers,
        threads_per_worker=1,
        processes=True,
        dashboard_address=None,
        silence_logs=logging.CRITICAL,
        # no dashboard; the scheduler's HTTP endpoints (health, metrics) on a free
        # port instead of 8787, which another cluster on the machine may hold
        scheduler_kwargs={"allowed_failures": 1, "dashboard": False, "dashboard_address": ":0"},
    )
    options.update(kwargs)
    # the nannies copy the configuration when they are made (and pass it to restarted workers)
    with dask.config.set({"distributed.worker.profile.enabled": False}):
        return distributed.LocalCluster(**options)


class _Progress:
    """Runs done / total: a tqdm bar on a terminal, else one plain line per event."""

    def __init__(self, total: int, title: str, enabled: bool, where: str):
        self.total, self.title, self.done = total, title, 0
        self.enabled = enabled and total > 0
        self.bar = None
        if not self.enabled:
            return
        if sys.stderr.isatty():
            from tqdm import tqdm  # heavy: imported when first needed (start-up time)

            self.bar = tqdm(
                total=total, desc=title, unit="run", file=sys.stderr, dynamic_ncols=True, leave=True
            )
        else:
            self._line(f"{total} run{'s' if total != 1 else ''}, {where}")

    def _line(self, text: str) -> None:
        print(f"{self.title}: {text}", file=sys.stderr, flush=True)

    def started(self, index: int, task: Task) -> None:
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.set_postfix_str(task.key, refresh=True)
        else:
            self._line(f"run {index + 1}/{self.total} started: {task.key}")

    def finished(self, result: TaskResult) -> None:
        self.done += 1
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix_str(f"{result.key}: {result.status}", refresh=True)
            return
        where = "" if result.worker == "in-process" else f", {result.worker}"
        text = f"{self.done}/{self.total} done: {result.key}: {result.status}"
        if result.message:
            text += f" ({result.message[:200]})"
        self._line(f"{text} [{result.seconds:.1f} s{where}]")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


class _StopOnSignals:
    """For one map, in the main thread: SIGINT/SIGTERM raise RunInterrupted where the map is
    (waiting for the cluster, or between two in-process runs); a second signal gets the system
    default (ends the process) while the map cleans up. A run's own session installs its own
    handlers while it runs and restores these afterwards."""

    def __enter__(self):
        self.previous = {}
        if threading.current_thread() is threading.main_thread():
            for sig in interrupt.SIGNALS:
                self.previous[sig] = signal.getsignal(sig)
                signal.signal(sig, self._handler)
        return self

    @staticmethod
    def _handler(signum, frame):  # noqa: ARG004 - signal API
        for sig in interrupt.SIGNALS:
            # a hang-up often comes twice (kernel and shell): never escalate on it
            hup = sig == getattr(signal, "SIGHUP", None)
            signal.signal(sig, signal.SIG_IGN if hup else signal.SIG_DFL)
        raise RunInterrupted(f"interrupted by {interrupt.signal_name(signum)}", signum=signum)

    def __exit__(self, *exc):
        for sig, prev in self.previous.items():
            signal.signal(sig, prev if prev is not None else signal.SIG_DFL)
        return False


class Executor:
    """Runs tasks in-process (``workers=1``) or on Dask (``workers > 1`` or ``scheduler``)."""

    def __init__(
        self,
        workers: int | None = None,
        scheduler=None,
        *,
        progress: bool = True,
        title: str = "rothe",
        no_worker_timeout: float | None = None,
    ):
        if workers is None:
            workers = 1 if scheduler is not None else default_workers()
        self.workers = (
            check_int("workers", workers, minimum=1)
            if scheduler is not None
            else check_workers("workers", workers)
        )
        self.scheduler = scheduler
        self.progress = progress
        self.title = title
        # with no worker at all for this long, the runs still waiting are reported lost; by
        # default only on the local cluster (whose workers cannot come back once their nannies
        # gave up); an existing cluster may be waiting for its jobs to start
        if no_worker_timeout is None and scheduler is None:
            no_worker_timeout = LOCAL_NO_WORKER_TIMEOUT_S
        self.no_worker_timeout = no_worker_timeout
        self._client = None
        self._owned: list = []  # client and cluster this executor started (closed by it)
        self._depth = 0
        #: of the last map, also when it was interrupted: the result of every task that
        #: finished (None for the others), in task order, and the indices of the tasks started
        self.finished: list[TaskResult | None] = []
        self.started: set[int] = set()

    @property
    def in_process(self) -> bool:
        return self.scheduler is None and self.workers == 1

    def describe(self) -> str:
        """In-process, a local Dask cluster of n workers, or the scheduler's address (for the
        summary of a sweep).
        """
        if self.in_process:
            return "in-process"
        if self.scheduler is None:
            return f"local Dask cluster of {self.workers} worker processes"
        addr = getattr(self.scheduler, "scheduler_address", self.scheduler)
        if not isinstance(addr, str):
            addr = getattr(getattr(self.scheduler, "scheduler", None), "address", "a Dask client")
        return f"Dask scheduler {addr}"

    # -- cluster lifetime ----------------------------------------------------------------------
    def __enter__(self):
        # re-entrant: a function handed an executor that its caller already entered may enter
        # it again; only the outermost exit closes what was started
        self._depth += 1
        if not self.in_process:
            try:
                self._connect()
            except BaseException:
                self._depth -= 1
                raise
        return self

    def __exit__(self, *exc):
        self._depth -= 1
        if self._depth == 0:
            self.close()

    def close(self) -> None:
        """Close the Dask client and cluster this executor started (not one it was given)."""
        while self._owned:
            obj = self._owned.pop()
            try:
                obj.close()
            except Exception:  # pragma: no cover - closing is best effort
                pass
        self._client = None

    def _connect(self):
        if self._client is not None:
            return self._client
        distributed = _import_distributed(
            "scheduler" if self.scheduler is not None else f"workers={self.workers}"
        )
        if self.scheduler is None:
            cluster = local_cluster(self.workers)
            self._owned.append(cluster)
            self._client = distributed.Client(cluster)
            self._owned.append(self._client)
        elif isinstance(self.scheduler, distributed.Client):
            self._client = self.scheduler
        else:
            target = self.scheduler
            if isinstance(target, str) and not target.strip():
                raise fail(
                    "scheduler", target, "must be a scheduler address (e.g. tcp://host:8786)"
                )
            try:
                self._client = distributed.Client(target, timeout=f"{CONNECT_TIMEOUT_S:g}s")
            except (OSError, ValueError, TypeError) as exc:
                raise fail(
                    "scheduler",
                    str(target),
                    f"cannot connect within {CONNECT_TIMEOUT_S:g} s ({' '.join(str(exc).split())})",
                ) from None
            self._owned.append(self._client)
        return self._client

    # -- mapping -------------------------------------------------------------------------------
    def map(self, tasks: list[Task]) -> list[TaskResult]:
        """Run every task; results in the order of ``tasks``."""
        tasks = list(tasks)
        keys = [t.key for t in tasks]
        if len(set(keys)) != len(keys):
            dup = next(k for k in keys if keys.count(k) > 1)
            raise ValueError(f"task keys must be unique, {dup!r} appears twice")
        self.finished = [None] * len(tasks)
        self.started = set()
        with _StopOnSignals():
            if self.in_process:
                return self._map_in_process(tasks)
            started_here = self._client is None
            try:
                client = self._connect()
                return self._map_dask(client, tasks)
            finally:
                if started_here:
                    self.close()

    def _map_in_process(self, tasks):
        progress = _Progress(len(tasks), self.title, self.progress, "in-process")
        results = self.finished
        try:
            for i, task in enumerate(tasks):
                progress.started(i, task)
                self.started.add(i)
                results[i] = execute_task(task)
                progress.finished(results[i])
        finally:
            progress.close()
        return results

    def _map_dask(self, client, tasks):
        """Submit in order of decreasing cost, at most one task per worker thread at a time.

        Holding the rest back on this side (instead of handing all to the scheduler) keeps
        the longest-first order exact and never queues a run behind another on a worker, where
        a worker's death would count against it too (the scheduler counts every task assigned
        to a dead worker); a slot that frees up is refilled at once, and workers that join
        later (a SLURM job that starts) are used within a second.
        """
        import distributed  # heavy: imported when first needed (start-up time)

        progress = _Progress(len(tasks), self.title, self.progress, self.describe())
        token = uuid.uuid4().hex[:8]
        pending = sorted(range(len(tasks)), key=lambda i: -float(tasks[i].cost))  # stable
        pending.reverse()  # pop() takes the most expensive
        running: dict = {}  # future -> task index
        results = self.finished
        started: dict[int, float] = {}
        no_workers_since = None
        try:
            while pending or running:
                threads = sum(client.nthreads().values())
                if threads == 0 and self.no_worker_timeout is not None:
                    now = time.perf_counter()
                    no_workers_since = no_workers_since or now
                    if now - no_workers_since > self.no_worker_timeout:
                        self._give_up(client, tasks, pending, running, results, progress)
                        break
                else:
                    no_workers_since = None
                threads = max(threads, 1)
                while pending and len(running) < threads:
                    i = pending.pop()
                    key = f"rothe-{_safe_key(tasks[i].key)}-{token}-{i}"
                    fut = client.submit(execute_task, tasks[i], key=key, retries=1, pure=False)
                    running[fut] = i
                    started[i] = time.perf_counter()
                    self.started.add(i)
                try:
                    done, _ = distributed.wait(
                        list(running), timeout=1.0, return_when="FIRST_COMPLETED"
                    )
                except TimeoutError:  # nothing finished within 1 s: look for new workers
                    continue
                for fut in done:
                    i = running.pop(fut)
                    results[i] = self._result(fut, tasks[i], time.perf_counter() - started[i])
                    progress.finished(results[i])
        except BaseException:
            client.cancel(list(running))
            raise
        finally:
            progress.close()
        return results

    def _give_up(self, client, tasks, pending, running, results, progress) -> None:
        """No worker for ``no_worker_timeout`` seconds: every run not finished is lost."""
        message = (
            f"no worker left on the cluster for {self.no_worker_timeout:g} s "
            "(the worker processes died and were not restarted)"
        )
        client.cancel(list(running))
        for i in list(running.values()) + pending:
            results[i] = TaskResult(tasks[i].key, "lost", message, worker="")
            progress.finished(results[i])
        running.clear()
        pending.clear()

    @staticmethod
    def _result(fut, task: Task, seconds: float) -> TaskResult:
        import distributed  # heavy: imported when first needed (start-up time)

        try:
            return fut.result()
        except distributed.KilledWorker as exc:
            return TaskResult(
                task.key,
                "lost",
                "its worker died twice while running it (killed, "
                f"e.g. out of memory): {' '.join(str(exc).split())}",
                seconds=seconds,
                worker="",
            )
        except Exception as exc:  # e.g. the task could not be unpickled on the worker
            return TaskResult(
                task.key, "error", f"{type(exc).__name__}: {exc}", seconds=seconds, worker=""
            )
        finally:
            # forget it on the cluster now: a finished run held there would be run again if
            # its worker died later (the scheduler recomputes lost results that are wanted)
            fut.release()


def _safe_key(key: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.=+-]+", "_", key)[:80]


def run_tasks(
    tasks, *, workers: int | None = 1, scheduler=None, progress: bool = False, title: str = "rothe"
) -> list[TaskResult]:
    """Shorthand for ``Executor(workers, scheduler, progress=..., title=...).map(tasks)``."""
    return Executor(workers, scheduler, progress=progress, title=title).map(tasks)


__all__ = [
    "CONNECT_TIMEOUT_S",
    "LOCAL_NO_WORKER_TIMEOUT_S",
    "Executor",
    "dask_available",
    "default_workers",
    "local_cluster",
    "run_tasks",
]
