"""The executor's worker count (issue 21): at most the cores this process may use, refused in
one line before any cluster starts (--workers 1000 started 1000 processes and failed after
106 s with a "Nanny failed to start" traceback); capped to the number of runs of a sweep."""

from __future__ import annotations

import pytest

from rothe.errors import RotheInputError
from rothe.parallel import Executor
from rothe.parallel import executor as executor_module


def test_more_workers_than_cores_are_refused(monkeypatch):
    monkeypatch.setattr(executor_module, "cpu_count", lambda: 4)
    assert Executor(4, progress=False).workers == 4
    with pytest.raises(RotheInputError) as info:
        Executor(1000, progress=False)
    # the API names its parameters (the command line renames them: tests/cli/test_bad_input.py)
    assert str(info.value).startswith(
        "workers: got 1000, must be at most 4 (the cores this process may use;"
    )
    assert str(info.value).endswith("; scheduler runs on a larger cluster)")
    assert info.value.parameter == "workers" and info.value.mentions == ("scheduler",)
    monkeypatch.setenv("ROTHE_WORKERS", "9")
    with pytest.raises(RotheInputError, match=r"^ROTHE_WORKERS: got 9, must be at most 4 "):
        executor_module.default_workers()
    monkeypatch.setenv("ROTHE_WORKERS", "x")
    with pytest.raises(RotheInputError, match=r"^ROTHE_WORKERS: got 'x', must be an integer"):
        executor_module.default_workers()


def test_an_existing_cluster_has_its_own_workers():
    ex = Executor(scheduler="tcp://127.0.0.1:9", progress=False)  # nothing connects yet
    assert ex.workers == 1 and not ex.in_process


def test_a_sweep_starts_no_more_local_workers_than_runs(tmp_path, monkeypatch):
    from rothe.cli import sweep

    monkeypatch.setattr(executor_module, "cpu_count", lambda: 8)
    ex = Executor(8, progress=False)
    monkeypatch.setattr(
        Executor,
        "map",
        lambda self, tasks: [
            executor_module.TaskResult(t.key, "completed", "", value={}) for t in tasks
        ],
    )
    monkeypatch.setattr(Executor, "_connect", lambda self: None)
    sweep.run_sweep("ris-1d", ["tol=1e-2,1e-3"], ["--no-plots"], out=tmp_path / "s", executor=ex)
    assert ex.workers == 2
