"""One independent run as a picklable task, and what happens around it wherever it executes.

A :class:`Task` names a module-level function and its keyword arguments (both pickled by
reference/value, so a Dask worker on another machine can run it; the command line wraps the argv
of a ``rothe run`` command in one: :func:`rothe.cli.tasks.cli_task`). :func:`execute_task` runs
a task and never raises for a failure of the run: it returns a :class:`TaskResult` with a status,

- ``completed``: the function returned;
- ``failed``: the run stopped midway (:class:`~rothe.errors.RunFailed`, or :class:`TaskFailed`
  raised by the function with what it computed so far);
- ``error``: bad input found only when the run started (:class:`~rothe.errors.RotheInputError`)
  or an unexpected exception (type, message and traceback kept);
- ``lost`` is set by the executor when the worker running the task died twice;
- ``interrupted`` / ``pending``: set by a sweep stopped by SIGINT/SIGTERM for the runs under
  way / not started (:func:`rothe.cli.sweep.interrupted_results`).

Bit-identical results wherever a task runs: :func:`task_environment` gives every task the same
process state, whatever ran before it in that process: BLAS and OpenMP limited to one thread
(threaded reductions sum in another order), and numpy's legacy global RNG and Python's ``random``
seeded to 0 for the task and restored afterwards (pyamg draws its spectral-radius start vectors
from ``np.random.rand``, so an AMG run otherwise depends on what the process drew before).
"""

from __future__ import annotations

import random
import sys
import time
import traceback
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import RotheInputError, RunFailed

STATUSES = ("completed", "failed", "error", "lost", "interrupted", "pending")


@dataclass
class Task:
    """A picklable description of one run.

    ``fn`` must be a module-level function (pickled by reference: importable on the workers),
    called as ``fn(**kwargs)``; its return value travels back to the caller, so keep it small
    (a summary row, not a trajectory). ``key`` names the run in progress lines and tables and must
    be unique within one map. ``cost`` is a relative estimate of the run time: the executor
    starts expensive tasks first (longest processing time first balances unequal runs).
    """

    key: str
    fn: Callable[..., Any]
    kwargs: dict = field(default_factory=dict)
    cost: float = 1.0


@dataclass
class TaskResult:
    """What a task produced: status (one of :data:`STATUSES`), a one-line message, the value."""

    key: str
    status: str
    message: str = ""
    value: Any = None
    seconds: float = 0.0
    worker: str = "in-process"
    detail: str = ""  # the traceback of an unexpected exception

    @property
    def completed(self) -> bool:
        return self.status == "completed"


class TaskFailed(Exception):
    """Raised by a task function for a run that stopped but produced something worth keeping."""

    def __init__(self, message: str, value=None, status: str = "failed"):
        super().__init__(message)
        self.value = value
        self.status = status


@contextmanager
def task_environment(seed: int = 0):
    """Single-threaded BLAS/OpenMP and seeded global RNGs for one task; restored afterwards."""
    from threadpoolctl import threadpool_limits  # heavy: imported when first needed (start-up time)

    np_state = np.random.get_state()
    py_state = random.getstate()
    np.random.seed(seed)
    random.seed(seed)
    try:
        with threadpool_limits(limits=1):
            yield
    finally:
        np.random.set_state(np_state)
        random.setstate(py_state)


def _worker_name() -> str:
    # only when Dask is already loaded: the in-process mode must not import it
    distributed = sys.modules.get("distributed")
    if distributed is None:
        return "in-process"
    try:
        return str(distributed.get_worker().address)
    except ValueError:  # not inside a worker
        return "in-process"


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def execute_task(task: Task) -> TaskResult:
    """Run ``task`` in this process (the same function in-process and on a Dask worker)."""
    t0 = time.perf_counter()
    value, detail = None, ""
    with task_environment():
        try:
            value = task.fn(**task.kwargs)
            status, message = "completed", ""
        except TaskFailed as exc:
            status, message, value = exc.status, str(exc), exc.value
        except RunFailed as exc:
            status, message = "failed", str(exc)
        except RotheInputError as exc:
            status, message = "error", str(exc)
        except Exception as exc:  # any other defect of one run must not stop the others
            status, message = "error", f"{type(exc).__name__}: {exc}"
            detail = traceback.format_exc()
    return TaskResult(
        task.key,
        status,
        _one_line(message),
        value,
        time.perf_counter() - t0,
        _worker_name(),
        detail,
    )


__all__ = ["STATUSES", "Task", "TaskFailed", "TaskResult", "execute_task", "task_environment"]
