"""``rothe sweep`` and the executor: bit-identical runs on a Dask cluster, failures reported in
the table, lost workers retried once, in-process without Dask, bad input refused before any run.

One 2-worker local cluster is shared by the cluster tests (module-scoped fixture); the CLI uses
it through ``--scheduler``.
"""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import time

import numpy as np
import pytest

from rothe.cli.main import main
from rothe.io.trajectory import is_timing_array
from rothe.parallel import Executor, Task
from rothe.parallel import executor as executor_module

from ..conftest import run_cli

NEEDS_DASK = 'the cluster tests need dask: pip install "rothe[dask]"'
#: summary fields that measure time or memory or name the run (its folder, its checkpoint, its
#: session id, its command line as spelled: a sweep writes --n=3 where a person wrote --n 3), not
#: the computation
UNTIMED = {"wall_time_s", "peak_memory_mb", "setup_time_s", "checkpoint", "run_id", "argv"}


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def assert_npz_equal(a, b):
    with np.load(a) as fa, np.load(b) as fb:
        keys = [k for k in fa.files if not is_timing_array(k)]
        assert sorted(keys) == sorted(k for k in fb.files if not is_timing_array(k))
        for k in keys:
            assert np.array_equal(fa[k], fb[k]), k


def computed(summary: dict) -> dict:
    return {k: v for k, v in summary.items() if k not in UNTIMED}


@pytest.fixture(scope="module")
def cluster():
    pytest.importorskip("distributed", reason=NEEDS_DASK)
    with executor_module.local_cluster(2) as cl:  # the cluster of --workers 2
        yield cl


# -- bit for bit ---------------------------------------------------------------------------------


def test_cluster_sweep_equals_serial_runs_bit_for_bit(tmp_path, capsys, cluster):
    out = tmp_path / "sweep"
    code, stdout, err = run_cli(
        capsys,
        "sweep",
        "run",
        "ris-2d",
        "--param",
        "n=3,4",
        "--param",
        "control=adaptive,order2",
        "--tol",
        "3e-2",
        "--tau",
        "0.1",
        "--no-plots",
        "--scheduler",
        cluster.scheduler_address,
        "--out",
        out,
        "--plot",
        "n,sum_residual",
    )
    assert code == 0, err
    rows = read_csv(out / "sweep.csv")
    names = [
        "n=3_control=adaptive",
        "n=3_control=order2",
        "n=4_control=adaptive",
        "n=4_control=order2",
    ]
    assert [r["run"] for r in rows] == names
    assert (out / "sweep_sum_residual_vs_n.png").stat().st_size > 1000
    # both worker processes ran runs (progress lines in a log name the worker)
    assert len(set(re.findall(r" s, (tcp://[\d.]+:\d+)\]", err))) == 2, err
    for name in names:
        n, control = name.split("_")
        serial = tmp_path / f"serial-{name}"
        assert (
            main(
                [
                    "run",
                    "ris-2d",
                    f"--{n}",
                    f"--{control}",
                    "--tol",
                    "3e-2",
                    "--tau",
                    "0.1",
                    "--no-plots",
                    "--quiet",
                    "--out",
                    str(serial),
                ]
            )
            == 0
        )
        assert_npz_equal(out / name / "trajectory.npz", serial / "trajectory.npz")
        assert computed(json.loads((out / name / "summary.json").read_text())) == computed(
            json.loads((serial / "summary.json").read_text())
        )


def test_study_on_cluster_equals_in_process(tmp_path, capsys, cluster):
    argv = [
        "study",
        "eld-perturbation",
        "--taus",
        "0.1,0.05",
        "--n",
        "2",
        "--targets",
        "G,F",
        "--damping",
        "rayleigh",
        "--no-plots",
        "--quiet",
    ]
    assert main(argv + ["--workers", "1", "--out", str(tmp_path / "serial")]) == 0
    assert (
        main(argv + ["--scheduler", cluster.scheduler_address, "--out", str(tmp_path / "dask")])
        == 0
    )
    serial = json.loads((tmp_path / "serial" / "summary.json").read_text())
    dask = json.loads((tmp_path / "dask" / "summary.json").read_text())
    for s in (serial, dask):
        s.pop("seconds"), s.pop("peak_memory_mb")
    assert serial == dask and len(serial["G"]["amp_original"]) == 2
    assert (tmp_path / "dask" / "table.txt").read_text() == (
        tmp_path / "serial" / "table.txt"
    ).read_text()


# -- failures ------------------------------------------------------------------------------------


def test_failing_run_is_reported_and_the_others_complete(tmp_path, capsys, cluster):
    out = tmp_path / "sweep"
    code, stdout, err = run_cli(
        capsys,
        "sweep",
        "run",
        "ris-1d",
        "--param",
        "tau-min=1e-12,0.05",
        "--tol",
        "1e-3",
        "--no-plots",
        "--scheduler",
        cluster.scheduler_address,
        "--out",
        out,
    )
    assert code == 1
    rows = {r["run"]: r for r in read_csv(out / "sweep.csv")}
    ok, bad = rows["tau-min=1e-12"], rows["tau-min=0.05"]
    assert ok["status"] == "completed" and ok["message"] == ""
    assert bad["status"] == "failed"
    assert bad["message"].startswith("step size fell below tau_min = 0.05")
    # the failed run's own summary (what it computed before it stopped) is in its row
    failed_summary = json.loads((out / "tau-min=0.05" / "summary.json").read_text())
    assert int(bad["accepted_steps"]) == failed_summary["accepted_steps"] >= 1
    assert "failed" in stdout and "1 of 2 runs completed" in stdout


def test_lost_worker_is_retried_once(tmp_path, cluster):
    """The worker running a run is killed (SIGKILL): the run is re-run on a live worker and its
    result is the serial one; a run that kills its worker at every attempt is reported lost."""
    import threading

    from distributed import Client

    from rothe.cli.tasks import cli_task

    out = tmp_path / "killed"
    argv = ["run", "ris-1d", "--tol", "1e-3", "--no-plots", "--quiet"]
    with Client(cluster) as client:
        # a cluster without workers (its nannies gave up) fails the test instead of hanging it
        ex = Executor(scheduler=client, progress=False, no_worker_timeout=60)
        killed = []

        def kill_worker_running_it():
            deadline = time.monotonic() + 60
            while not killed and time.monotonic() < deadline:
                for addr, keys in client.processing().items():
                    if any("killed" in str(k) for k in keys):
                        pid = client.run(os.getpid, workers=[addr])[addr]
                        os.kill(pid, signal.SIGKILL)
                        killed.append(pid)
                time.sleep(0.02)

        killer = threading.Thread(target=kill_worker_running_it, daemon=True)
        killer.start()
        first = ex.map([cli_task("killed", argv + ["--out", str(out)], out=str(out))])[0]
        killer.join()
        # functions the workers can import (not this test module): os.abort kills the worker
        second = ex.map([Task("kills always", os.abort, {}), Task("fine", dict, {"x": 4})])
    assert len(killed) == 1
    assert first.status == "completed" and first.value["accepted_steps"] > 0
    assert main(argv + ["--out", str(tmp_path / "serial")]) == 0
    assert_npz_equal(out / "trajectory.npz", tmp_path / "serial" / "trajectory.npz")
    assert second[0].status == "lost" and "died twice" in second[0].message
    assert second[1].status == "completed" and second[1].value == {"x": 4}


def test_runs_on_a_cluster_without_workers_are_lost_after_the_timeout():
    distributed = pytest.importorskip("distributed", reason=NEEDS_DASK)
    with executor_module.local_cluster(0) as empty, distributed.Client(empty) as client:
        t0 = time.perf_counter()
        res = Executor(scheduler=client, progress=False, no_worker_timeout=1.0).map(
            [Task("a", dict, {"x": 1}), Task("b", dict, {"x": 2})]
        )
    assert [r.status for r in res] == ["lost", "lost"] and time.perf_counter() - t0 < 30
    assert res[0].message == (
        "no worker left on the cluster for 1 s (the worker processes died and were not restarted)"
    )


# -- bad input: one line, exit 2, nothing run ---------------------------------------------------


@pytest.mark.parametrize(
    "args, message",
    [
        (
            ["--param", "foo=1,2"],
            "--param: got 'foo', is not an option of 'rothe run ris-1d' (its options: ",
        ),
        (["--param", "tol="], "--param: got 'tol=', needs at least one value after tol="),
        (["--param", "tol=1e-3,"], "--param: got 'tol=1e-3,', has an empty value"),
        (["--param", "tol"], "--param: got 'tol', must be NAME=V1,V2,..."),
        (["--param", "tol=1e-3,-1"], "sweep run tol=-1: --tol: got -1, must be > 0"),
        (["--param", "simpson=4,3"], "sweep run simpson=3: --simpson: got 3, must be an even"),
        (["--param", "tau=0.1,x"], "sweep run tau=x: argument --tau: got 'x', must be a number"),
        (["--param", "out=a,b"], "--param: got 'out', cannot be swept"),
        (["--param", "tol=1e-3", "--tol", "1e-4"], "--tol: given both in --param and as an option"),
        (
            ["--param", "tol=1e-3", "--unknown"],
            "sweep run tol=1e-3: unrecognized arguments: --unknown",
        ),
        (["--param", "tol=1e-3", "--workers", "0"], "--workers: got 0, must be an integer >= 1"),
        (["--param", "tol=1e-3", "--plot", "tol"], "--plot: got 'tol', must name two columns X,Y"),
        ([], "--param: none given"),
        (
            ["--param", "tol=1e-3", "--workers", "2", "--scheduler", "tcp://127.0.0.1:9"],
            "--workers: got 2, cannot be combined with --scheduler",
        ),
        (
            ["--param", "tol=1e-3", "--scheduler", ""],
            "--scheduler: got '', must be a scheduler address",
        ),
        (["--param", "tol=1e-3,1e-3"], "--param: got 'tol=1e-3,1e-3', repeats a value"),
        (["--param", "tol=1e-3", "--param", "tol=1e-4"], "--param: got 'tol', is given twice"),
    ],
)
def test_bad_sweep_input_is_one_line_before_any_run(tmp_path, capsys, args, message):
    out = tmp_path / "sweep"
    code, stdout, err = run_cli(capsys, "sweep", "run", "ris-1d", *args, "--out", out)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("rothe: error: " + message), lines
    assert not out.exists()


def test_unreachable_scheduler_is_refused_quickly(tmp_path, capsys, monkeypatch):
    pytest.importorskip("distributed", reason=NEEDS_DASK)
    monkeypatch.setattr(executor_module, "CONNECT_TIMEOUT_S", 1.0)
    out = tmp_path / "sweep"
    t0 = time.perf_counter()
    code, _, err = run_cli(
        capsys,
        "sweep",
        "run",
        "ris-1d",
        "--param",
        "tol=1e-2",
        "--scheduler",
        "tcp://127.0.0.1:9",
        "--out",
        out,
    )
    assert code == 2 and time.perf_counter() - t0 < 10
    assert (
        err.startswith(
            "rothe: error: --scheduler: got 'tcp://127.0.0.1:9', cannot connect within 1 s"
        )
        and len(err.strip().splitlines()) == 1
    )
    assert not out.exists()
    code, _, err = run_cli(capsys, "compare", "ris-1d", "--workers", "0", "--out", out)
    assert code == 2 and err.strip() == "rothe: error: --workers: got 0, must be an integer >= 1"


def test_eld_sweep_refuses_a_bad_value_naming_the_run(tmp_path, capsys):
    code, _, err = run_cli(
        capsys, "sweep", "run", "eld-mms", "--param", "form=regularized,x", "--out", tmp_path / "s"
    )
    assert code == 2 and err.strip() == (
        "rothe: error: sweep run form=x: --form: got 'x', must be one of regularized, original"
    )
