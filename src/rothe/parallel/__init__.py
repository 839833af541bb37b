"""Independent runs in this process or on Dask: tasks, the executor, and parameter sweeps.

- :mod:`rothe.parallel.tasks`: :class:`Task` (a picklable run: a module-level function and its
  arguments, or the argv of a ``rothe run`` command), :class:`TaskResult` and
  :func:`execute_task` (what happens around a run wherever it executes);
- :mod:`rothe.parallel.executor`: :class:`Executor` (in-process, a local Dask cluster of worker
  processes, or an existing Dask scheduler);
- the command line's ``--workers``/``--scheduler`` options are in :mod:`rothe.cli.common`, its
  sweeps (``rothe sweep run <example> --param NAME=V1,V2,...``) and its runs
  as tasks are in :mod:`rothe.cli.sweep` and :mod:`rothe.cli.tasks`.

Dask (``pip install "rothe[dask]"``) is imported only when a cluster is used. See
``docs/scaling.md``.
"""

from .executor import (
    Executor,
    dask_available,
    default_workers,
    run_tasks,
)
from .tasks import Task, TaskFailed, TaskResult, execute_task, task_environment

__all__ = [
    "Executor",
    "Task",
    "TaskFailed",
    "TaskResult",
    "dask_available",
    "default_workers",
    "execute_task",
    "run_tasks",
    "task_environment",
]
