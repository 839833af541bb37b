"""The in-process mode needs no Dask (its import blocked here), the sweep table, progress lines
in a log, and what :func:`rothe.parallel.execute_task` guarantees every run.

In a module of its own: blocking the import of dask must not meet a live cluster (the cluster
tests of test_sweep.py share one for their module).
"""

from __future__ import annotations

import csv
import json
import sys

import numpy as np
import pytest

from rothe.cli.main import main
from rothe.io.trajectory import is_timing_array
from rothe.parallel import Executor, Task, execute_task
from rothe.parallel import executor as executor_module

from ..conftest import run_cli

SUMMARY_FIELDS = {
    "accepted_steps",
    "rejected_steps",
    "inner_solves",
    "newton_iterations",
    "t_final",
    "s_final",
    "max_residual",
    "sum_residual",
    "energy_final",
}


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def returns(x):
    return x


def fails(x):
    raise ValueError(f"bad\n{x}")  # the message of a result is one line


@pytest.fixture
def no_dask(monkeypatch):
    """Importing dask or distributed fails (as when the extra is not installed)."""
    for name in list(sys.modules):
        if name.split(".")[0] in ("dask", "distributed"):
            monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "dask", None)
    monkeypatch.setitem(sys.modules, "distributed", None)
    monkeypatch.delenv("ROTHE_WORKERS", raising=False)


def test_workers_1_needs_no_dask_and_writes_the_table(tmp_path, capsys, no_dask):
    out = tmp_path / "sweep"
    code, stdout, err = run_cli(
        capsys,
        "sweep",
        "run",
        "ris-1d",
        "--param",
        "tol=1e-2,1e-3",
        "--param",
        "control=adaptive,order2",
        "--no-plots",
        "--workers",
        "1",
        "--out",
        out,
        "--plot",
        "tol,error_linf",
    )
    assert code == 0, err
    rows = read_csv(out / "sweep.csv")
    assert len(rows) == 4 and {r["status"] for r in rows} == {"completed"}
    doc = json.loads((out / "sweep.json").read_text())
    assert doc["executor"] == "in-process" and doc["params"]["tol"] == ["1e-2", "1e-3"]
    for row, jrow in zip(rows, doc["rows"], strict=True):
        summary = json.loads((out / row["run"] / "summary.json").read_text())
        assert SUMMARY_FIELDS <= set(row)
        for key in SUMMARY_FIELDS | {"error_linf"}:  # the row holds the run's summary.json
            assert float(row[key]) == summary[key] == jrow[key], key
        assert jrow["tol"] == summary["tol"] and jrow["control"] == summary["control"]
        assert not list((out / row["run"]).glob("*.png"))  # --no-plots went to every run
    assert (out / "sweep_error_linf_vs_tol.png").exists()
    # progress in a log (stderr is not a terminal): which run of how many
    assert "run 1/4 started: tol=1e-2_control=adaptive" in err and "4/4 done" in err
    assert "dask" not in str(sys.modules.get("distributed"))


def test_default_without_dask_is_in_process(no_dask, monkeypatch):
    assert executor_module.default_workers() == 1 and Executor().in_process
    monkeypatch.setenv("ROTHE_WORKERS", "3")
    monkeypatch.setattr(executor_module, "cpu_count", lambda: 4)  # at most the cores (issue 21)
    assert executor_module.default_workers() == 3


def test_workers_2_without_dask_says_how_to_install(tmp_path, capsys, no_dask):
    for argv in (
        ["sweep", "run", "ris-1d", "--param", "tol=1e-2"],
        ["compare", "ris-1d", "--tols", "1e-2", "--taus", "0.1,0.05"],
        ["study", "eld-convergence", "--n", "2", "--halvings", "1"],
    ):
        code, _, err = run_cli(capsys, *argv, "--workers", "2", "--out", tmp_path / "x")
        assert code == 2
        assert err.strip() == (
            "rothe: error: --workers 2 needs dask.distributed: "
            'pip install "rothe[dask]" (or --workers 1)'
        )
    assert not (tmp_path / "x").exists()


def test_executor_returns_results_in_task_order_and_keeps_going():
    tasks = [
        Task("a", returns, {"x": 1}, cost=1),
        Task("b", fails, {"x": 2}, cost=5),
        Task("c", returns, {"x": 3}, cost=9),
    ]
    res = Executor(1, progress=False).map(tasks)
    assert [r.key for r in res] == ["a", "b", "c"] and [r.value for r in res] == [1, None, 3]
    assert res[1].status == "error" and res[1].message == "ValueError: bad 2"
    assert "Traceback" in res[1].detail
    with pytest.raises(ValueError, match="'a' appears twice"):
        Executor(1).map([Task("a", returns, {"x": 1}), Task("a", returns, {"x": 2})])


def test_task_environment_isolates_blas_threads_and_global_rng():
    np.random.seed(123)
    before = np.random.get_state()[1].copy()
    draws = [execute_task(Task(str(i), draw, {})).value for i in range(2)]
    assert draws[0] == draws[1]  # same start state for every task, whatever ran before
    assert np.array_equal(np.random.get_state()[1], before)  # the caller's state is restored
    threads_before = blas_threads()
    threads = execute_task(Task("t", blas_threads, {})).value
    assert threads and all(n == 1 for n in threads)
    assert blas_threads() == threads_before


def draw():
    return float(np.random.rand())


def blas_threads():
    from threadpoolctl import threadpool_info

    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]


def test_compare_keeps_the_rows_that_worked(tmp_path, capsys, no_dask):
    """Issue 10: ``compare ris-1d --tols 1e-320,0.1`` exited 1 and wrote nothing."""
    out = tmp_path / "cmp"
    code, stdout, err = run_cli(
        capsys,
        "compare",
        "ris-1d",
        "--tols",
        "1e-320,0.1",
        "--taus",
        "0.1,0.05",
        "--workers",
        "1",
        "--no-plots",
        "--out",
        out,
    )
    assert code == 1
    rows = json.loads((out / "summary.json").read_text())["rows"]
    assert [(r["control"], r["status"].split(":")[0]) for r in rows] == [
        ("adaptive", "failed"),
        ("adaptive", "completed"),
        ("order2", "failed"),
        ("order2", "completed"),
        ("regime", "failed"),
        ("regime", "completed"),
        ("uniform", "completed"),
        ("uniform", "completed"),
    ]
    assert rows[0]["status"].startswith("failed: step size fell below tau_min")
    assert rows[0]["accepted_steps"] >= 1  # what the failed run computed is in its row
    table = (out / "table.txt").read_text()
    assert table.count("failed: step size fell below") == 3  # adaptive, order2, regime
    assert "run 8/8 started: uniform tau=0.05" in err and "8/8 done" in err


def test_sigterm_stops_the_sweep_keeps_the_table_and_continue_resumes_it(
    tmp_path, capsys, no_dask, monkeypatch
):
    """SIGTERM while the second of three runs steps: that run writes its checkpoint and results
    so far, the sweep starts no further run, writes the table of what it has and exits 143;
    ``--continue`` then keeps the completed run, finishes the interrupted one exactly like an
    uninterrupted run, and runs the one that had not started."""
    import os
    import signal

    from rothe.stepping import interrupt

    entered = []
    real_enter = interrupt.interruptible.__enter__

    def enter_and_signal(self):
        guard = real_enter(self)
        if self.hard_second:  # the session of a run command, around the whole run
            entered.append(1)
            if len(entered) == 2:
                os.kill(os.getpid(), signal.SIGTERM)  # only sets the guard's flag
        return guard

    monkeypatch.setattr(interrupt.interruptible, "__enter__", enter_and_signal)
    out = tmp_path / "sweep"
    # --keep-checkpoint: the completed runs keep theirs, so that the last --continue below
    # meets a checkpoint made with other options (without it a completed run is recognized by
    # its summary and run anew with the new options: tests/cli/test_session.py)
    code, stdout, err = run_cli(
        capsys,
        "sweep",
        "run",
        "ris-1d",
        "--param",
        "tol=1e-2,1e-3,1e-4",
        "--no-plots",
        "--workers",
        "1",
        "--out",
        out,
        "--keep-checkpoint",
    )
    assert code == 143 and len(entered) == 2
    assert (
        err.strip()
        .splitlines()[-1]
        .startswith("rothe: sweep interrupted by SIGTERM: 1 of 3 runs completed; table so far in ")
    )
    assert err.strip().endswith("the same command with --continue continues the sweep")
    rows = read_csv(out / "sweep.csv")
    assert [r["status"] for r in rows] == ["completed", "interrupted", "pending"]
    assert rows[1]["message"] == (
        f"stopped by SIGTERM; continue it with: rothe resume {out / 'tol=1e-3'}"
    )
    assert rows[1]["accepted_steps"] != ""  # the interrupted run's summary so far
    assert rows[2]["message"] == "not started (sweep stopped by SIGTERM)"
    assert json.loads((out / "sweep.json").read_text())["interrupted"] == "SIGTERM"
    assert not (out / "tol=1e-4").exists()
    assert signal.getsignal(signal.SIGTERM) in (signal.SIG_DFL, None)  # handlers restored
    monkeypatch.setattr(interrupt.interruptible, "__enter__", real_enter)
    first = (out / "tol=1e-2" / "summary.json").stat().st_mtime_ns
    # --continue: the completed run is kept, the interrupted one resumes, the third runs
    code, stdout, err = run_cli(
        capsys,
        "sweep",
        "run",
        "ris-1d",
        "--param",
        "tol=1e-2,1e-3,1e-4",
        "--no-plots",
        "--workers",
        "1",
        "--out",
        out,
        "--continue",
        "--keep-checkpoint",
    )
    assert code == 0, err
    rows = read_csv(out / "sweep.csv")
    assert [r["status"] for r in rows] == ["completed"] * 3
    assert [r["sessions"] for r in rows] == ["1", "2", "1"]
    assert (out / "tol=1e-2" / "summary.json").stat().st_mtime_ns == first  # not run again
    assert (
        main(
            [
                "run",
                "ris-1d",
                "--tol",
                "1e-3",
                "--no-plots",
                "--quiet",
                "--out",
                str(tmp_path / "serial"),
            ]
        )
        == 0
    )
    with (
        np.load(out / "tol=1e-3" / "trajectory.npz") as a,
        np.load(tmp_path / "serial" / "trajectory.npz") as b,
    ):
        for k in a.files:
            if k != "meta" and not is_timing_array(k):  # meta counts the sessions
                assert np.array_equal(a[k], b[k]), k
    # a run whose checkpoint was made with other options is refused, the others still run
    code, stdout, err = run_cli(
        capsys,
        "sweep",
        "run",
        "ris-1d",
        "--param",
        "tol=1e-2,1e-5",
        "--no-plots",
        "--workers",
        "1",
        "--out",
        out,
        "--continue",
        "--simpson",
        "4",
        "--keep-checkpoint",
    )
    rows = read_csv(out / "sweep.csv")
    assert code == 1 and [r["status"] for r in rows] == ["error", "completed"]
    assert (
        "the command line differs from the checkpoint's: --simpson 4 (checkpoint: 8)"
        in (rows[0]["message"])
    )
