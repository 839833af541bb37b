"""`rothe run|compare ris-1d`: outputs, summary fields, bad input = one line and exit status 2."""

import json
import subprocess
import sys

import numpy as np
import pytest

from rothe.cli.main import main

SUMMARY_FIELDS = {
    "example",
    "control",
    "tol",
    "accepted_steps",
    "rejected_steps",
    "inner_solves",
    "newton_iterations",
    "t_final",
    "s_final",
    "max_residual",
    "sum_residual",
    "wall_time_s",
    "error_l2",
    "error_linf",
}


def test_run_ris_1d_writes_results_and_figures(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", "ris-1d", "--out", str(out), "--quiet"]) == 0
    assert capsys.readouterr().out == ""  # --quiet
    summary = json.loads((out / "summary.json").read_text())
    assert SUMMARY_FIELDS <= set(summary)
    assert summary["control"] == "adaptive" and summary["tol"] == 1e-4
    assert summary["t_final"] == pytest.approx(5.0)
    assert summary["error_linf"] <= 2e-2
    with np.load(out / "trajectory.npz") as f:
        K = f["tau"].size
        assert f["s"].shape == (K + 1,) and f["t"].shape == (K + 1,) and f["z"].shape == (K + 1, 1)
        for key in ("I1", "I2", "lam"):
            assert f[key].shape == (K,)
        assert K == summary["accepted_steps"]
        assert np.isclose(f["s"][-1], summary["s_final"])
    assert (out / "fig1_path.png").stat().st_size > 1000
    assert (out / "fig2_steps.png").stat().st_size > 1000


def test_run_ris_1d_says_why_it_rejects_one_attempt_per_acceptance(tmp_path, capsys):
    """Issue 21: 682 accepted and 682 rejected steps with no word why; the summary line of
    rejected_steps now names Alg. 3.2's double/reject cycle (docs/ris.md)."""
    assert main(["run", "ris-1d", "--out", str(tmp_path / "run"), "--no-plots"]) == 0
    stdout = capsys.readouterr().out
    (line,) = [ln for ln in stdout.splitlines() if ln.split()[:1] == ["rejected_steps"]]
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["rejected_steps"] == summary["accepted_steps"] == 682
    assert line.split()[1] == "682" and "(1.00 per accepted step: Alg. 3.2's double/" in line
    assert "rejects up to one attempt per acceptance" in line
    # other controls reject few and need no remark
    regime = ["run", "ris-1d", "--control", "regime", "--no-plots", "--out", str(tmp_path / "r")]
    assert main(regime) == 0
    assert "per accepted step" not in capsys.readouterr().out


@pytest.mark.parametrize(
    "control, extra",
    [
        ("uniform", ["--tau", "0.05"]),
        ("order2", []),
        ("regime", []),
        ("nested", ["--tols", "1e-2,1e-3"]),
    ],
)
def test_run_ris_1d_other_controls(tmp_path, control, extra):
    out = tmp_path / control
    assert (
        main(
            [
                "run",
                "ris-1d",
                "--control",
                control,
                *extra,
                "--out",
                str(out),
                "--quiet",
                "--no-plots",
            ]
        )
        == 0
    )
    summary = json.loads((out / "summary.json").read_text())
    assert summary["control"] == control
    if control == "nested":
        assert len(summary["runs"]) == 2 and (out / "nested_1.npz").exists()
    assert not list(out.glob("*.png"))


@pytest.mark.parametrize(
    "args, message",
    [
        (["--tol", "0"], "rothe: error: --tol: got 0, must be > 0"),
        (["--tol", "-1e-3"], "rothe: error: --tol: got -0.001, must be > 0"),
        (["--tau", "0"], "rothe: error: --tau: got 0, must be > 0"),
        (["--tau", "-2"], "rothe: error: --tau: got -2, must be > 0"),
        (
            ["--control", "nested", "--tols", "1e-3,1e-3"],
            "rothe: error: --tols: got '0.001,0.001', must be strictly decreasing",
        ),
        (
            ["--control", "fast"],
            "rothe: error: --control: got 'fast', must be one of adaptive, uniform, nested, "
            "order2, regime",
        ),
        (
            ["--tau", "0.1", "--tau-min", "0.5"],
            "rothe: error: --tau-min: got 0.5, must be <= --tau (= 0.1)",
        ),
        (["--tol", "abc"], "rothe: error: argument --tol: got 'abc', must be a number"),
    ],
)
def test_bad_input_is_one_line_and_status_2(tmp_path, capsys, args, message):
    code = main(["run", "ris-1d", *args, "--out", str(tmp_path), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.strip() == message
    assert "Traceback" not in err


def test_unknown_example(capsys):
    assert main(["run", "ris-7d"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("rothe: error: run: got 'ris-7d', must be one of ")
    assert "ris-1d" in err and len(err.splitlines()) == 1


def test_failed_run_keeps_trajectory_and_exits_1(tmp_path, capsys):
    out = tmp_path / "fail"
    code = main(
        ["run", "ris-1d", "--tol", "1e-9", "--tau-min", "1e-3", "--out", str(out), "--quiet"]
    )
    err = capsys.readouterr().err
    assert code == 1 and len(err.strip().splitlines()) == 1
    assert "step size fell below tau_min" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and summary["where"]["step"] >= 1
    with np.load(out / "trajectory.npz") as f:
        assert f["tau"].size == summary["accepted_steps"]


def test_console_script_entry_point(tmp_path):
    """The installed command: a separate process, the real exit status and stderr."""
    proc = subprocess.run(
        [sys.executable, "-m", "rothe.cli.main", "run", "ris-1d", "--tau", "-1"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip() == "rothe: error: --tau: got -1, must be > 0"


def test_compare_ris_1d_table_and_figure(tmp_path, capsys):
    out = tmp_path / "cmp"
    assert (
        main(
            [
                "compare",
                "ris-1d",
                "--tols",
                "1e-3,1e-4",
                "--taus",
                "0.1,0.05,0.02",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "solves/uniform@Linf" in printed and printed.count("uniform") >= 3
    assert (out / "fig3_error_vs_steps.png").exists()
    rows = json.loads((out / "summary.json").read_text())["rows"]
    assert {r["control"] for r in rows} == {"adaptive", "order2", "regime", "uniform"}
