"""Issue 10, items 4 and 5: what a new user and the fuzzer found on the command line.

Every bad input is one line ``rothe: error: ...`` naming the option, exit status 2; a run that
fails is one line and exit status 1 with the results so far on disk.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from rothe import __version__
from rothe.cli.registry import commands, load_all
from rothe.cli.ris_commands import CONTROLS

from ..conftest import run_cli


def one_line_error(capsys, *argv, status=2) -> str:
    code, _, err = run_cli(capsys, *argv)
    assert code == status, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    return err.strip()


# -- argparse: no abbreviations, --version, bare `rothe` -----------------------------------------


@pytest.mark.parametrize(
    "argv, line",
    [
        # read as --no-plots 8 before
        (["run", "ris-1d", "--n", "8"], "rothe: error: unrecognized arguments: --n 8"),
        # read as --tols 1e-3 before
        (
            ["compare", "ris-1d", "--tol", "1e-3"],
            "rothe: error: unrecognized arguments: --tol 1e-3",
        ),
        (
            ["run", "ris-1d", "--contr", "uniform"],
            "rothe: error: unrecognized arguments: --contr uniform",
        ),
    ],
)
def test_options_are_never_abbreviated(tmp_path, capsys, argv, line):
    assert one_line_error(capsys, *argv, "--out", str(tmp_path)) == line


def test_version(capsys):
    code, out, err = run_cli(capsys, "--version")
    assert code == 0 and out.strip() == f"rothe {__version__}" and err == ""


def test_bare_rothe_prints_usage_and_every_command(capsys):
    code, out, err = run_cli(capsys)
    assert code == 2 and out == ""
    assert err.startswith("usage: rothe ")
    load_all()
    for verb in ("run", "compare", "study"):
        for name in commands(verb):
            assert f"rothe {verb} {name} " in err


# -- options a control ignores are refused -------------------------------------------------------


@pytest.mark.parametrize(
    "argv, line",
    [
        (
            ["--control", "nested", "--tol", "1e-6"],
            "rothe: error: --tol: got 1e-06, is not used by --control nested (it reads --tols); "
            "--tol is for --control adaptive or order2 or regime",
        ),
        (
            ["--control", "uniform", "--tol", "1e-9"],
            "rothe: error: --tol: got 1e-09, is not used by --control uniform (no tolerance: "
            "its step "
            "is --tau); --tol is for --control adaptive or order2 or regime",
        ),
        (
            ["--control", "order2", "--tols", "1e-3,1e-4"],
            "rothe: error: --tols: got 0.001,0.0001, is not used by --control order2 (it "
            "reads --tol); "
            "--tols is for --control nested",
        ),
        (
            ["--control", "nested", "--tols", ""],  # silently ran the defaults before
            "rothe: error: argument --tols: got '', must be a comma-separated list of finite "
            "numbers",
        ),
        (
            ["--control", "nested", "--tols", "1e-3,,1e-4"],
            "rothe: error: argument --tols: got '1e-3,,1e-4', must be a comma-separated list "
            "of finite "
            "numbers",
        ),
    ],
)
def test_options_the_control_ignores_are_refused(tmp_path, capsys, argv, line):
    assert one_line_error(capsys, "run", "ris-1d", *argv, "--out", str(tmp_path)) == line


def test_every_control_says_which_options_it_reads():
    """A new controller (e.g. of another branch) must declare them in CONTROL_OPTIONS."""
    from rothe.cli.ris_commands import CONTROL_OPTIONS

    assert set(CONTROLS) <= set(CONTROL_OPTIONS)


def test_nested_prints_its_tolerances_not_a_default_tol(tmp_path, capsys):
    code, out, err = run_cli(
        capsys,
        "run",
        "ris-1d",
        "--control",
        "nested",
        "--tols",
        "1e-2,1e-3",
        "--no-plots",
        "--out",
        str(tmp_path),
    )
    assert code == 0, err
    assert "tols               [0.01, 0.001]" in out


# -- values that used to surface as tracebacks or as someone else's parameter --------------------


@pytest.mark.parametrize(
    "argv, line",
    [
        (
            ["run", "ris-1d", "--keep-every", "2"],  # cannot reshape array, after the whole run
            "rothe: error: --keep-every: got 2, must be 1 for ris-1d (one unknown; the errors "
            "against "
            "(7.1) need every state)",
        ),
        (
            ["run", "ris-1d", "--tau", "1e300"],
            "rothe: error: --tau: got 1e+300, must be <= T (= 5), the end time of the run",
        ),
        (
            ["run", "ris-2d", "--n", "4", "--tau", "1e300"],  # load(t=1.25e+299): got -inf before
            "rothe: error: --tau: got 1e+300, must be <= T (= 1), the end time of the run",
        ),
        (
            ["run", "ris-1d", "--tau-min", "1e-320"],
            "rothe: error: --tau-min: got 9.99989e-321, must be >= 5e-14 (1e-14 max(1, T): a "
            "smaller "
            "step vanishes in the round-off of s)",
        ),
        (
            ["compare", "ris-1d", "--tols", "-0.1,0.1"],  # "expected one argument" before
            "rothe: error: --tols: got -0.1, must be > 0",
        ),
        (
            ["compare", "ris-1d", "--taus", "1e-320,0.1"],  # complained about tau_min before
            "rothe: error: --taus: got 9.99989e-321, must be >= 1e-12 (the smallest step "
            "tau_min of "
            "the runs)",
        ),
        (
            ["run", "ris-2d", "--n", "4", "--z0", "1e300"],  # "F(z0): got inf" before
            "rothe: error: --z0: got 1e+300, gives non-finite data (F(z0): got inf, must be "
            "finite (no "
            "NaN or inf))",
        ),
        (
            ["run", "ris-2d", "--n", "4", "--amplitude", "1e300"],  # KeyError: 'I1' before
            "rothe: error: --amplitude: got 1e+300, gives non-finite data (load(t=1): got a "
            "vector of "
            "norm inf, must have a finite V^-1 norm (sum l_i^2 / m_i overflows))",
        ),
        (["run", "ris-2d", "--mesh", ""], "rothe: error: --mesh: got '', must name a mesh file"),
        (
            ["run", "ris-2d", "--n", "4", "--duplicate-nodes", "merge"],
            "rothe: error: --duplicate-nodes: got 'merge', is only used with --mesh (the built-in "
            "grids have no duplicate nodes)",
        ),
        (
            ["run", "ris-2d", "--n", "4", "--xdmf-time", "x"],
            "rothe: error: --xdmf-time: got 'x', must be one of s, t",
        ),
    ],
)
def test_bad_values_name_the_option(tmp_path, capsys, argv, line):
    assert one_line_error(capsys, *argv, "--out", str(tmp_path / "o")) == line
    assert not (tmp_path / "o" / "summary.json").exists()


@pytest.mark.parametrize(
    "argv",
    [
        ["run", "ris-2d"],
        ["run", "ris-3d"],
        ["compare", "ris-2d"],
        ["run", "eld-mms"],
        ["run", "eld-beam"],
        ["study", "eld-convergence"],
        ["study", "eld-perturbation"],
    ],
)
def test_huge_grid_is_refused_before_allocating(tmp_path, capsys, argv):
    """--n 100000 died in numpy's _ArrayMemoryError; now an estimate against the memory."""
    line = one_line_error(capsys, *argv, "--n", "100000", "--out", str(tmp_path))
    assert line.startswith("rothe: error: --n: got 100000, needs about ")
    assert "estimated), more than the " in line and line.endswith(" of memory available")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs os.mkfifo (POSIX)")
def test_mesh_naming_a_fifo_is_refused_instead_of_blocking(tmp_path, capsys):
    fifo = tmp_path / "mesh.msh"
    os.mkfifo(fifo)
    assert one_line_error(
        capsys, "run", "ris-2d", "--mesh", str(fifo), "--out", str(tmp_path / "o")
    ) == (
        f"rothe: error: --mesh: got '{fifo}', is not a regular file (a FIFO, socket or device), "
        "must be a mesh file"
    )


# -- runs that fail keep what they computed --------------------------------------------------------


def test_failure_at_the_first_step_writes_a_summary(tmp_path, capsys):
    """KeyError: 'I1' before, and no summary."""
    out = tmp_path / "o"
    line = one_line_error(
        capsys,
        "run",
        "ris-2d",
        "--n",
        "4",
        "--tau",
        "0.5",
        "--tau-min",
        "0.5",
        "--tol",
        "1e-6",
        "--no-plots",
        "--out",
        str(out),
        status=1,
    )
    assert line.startswith("rothe: run failed: step size fell below tau_min = 0.5 at step 1 ")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and summary["accepted_steps"] == 0
    assert summary["max_residual"] == 0.0 and summary["n_viscous_jumps"] == 0
    assert (out / "trajectory.npz").exists() and (out / "solution.xdmf").exists()


def test_nan_load_midway_is_a_failed_run_that_keeps_its_trajectory(tmp_path, capsys, monkeypatch):
    """FERISProblem raised an input error (exit 2) and discarded the steps computed so far."""
    import numpy as np

    from rothe.fem.mesh import unit_square
    from rothe.ris import examples
    from rothe.ris.fem_problem import FERISProblem

    def factory(n, mesh, **kw):
        # NaN on (0.5, 0.52): between the nine times the problem checks when it is built
        return FERISProblem(
            unit_square(n),
            examples.g_7_2,
            examples.dg_7_2,
            examples.d2g_7_2,
            load=lambda t: np.nan if 0.5 < t < 0.52 else -200.0 * t**3,
            name="ris-2d",
        )

    monkeypatch.setattr(examples, "example_7_2", factory)
    out = tmp_path / "o"
    line = one_line_error(
        capsys, "run", "ris-2d", "--n", "4", "--no-plots", "--out", str(out), status=1
    )
    assert line.startswith("rothe: run failed: load(t=0.5")
    assert "got nan, must be finite (no NaN or inf) (at step " in line
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and summary["accepted_steps"] > 10
    assert 0.4 < summary["t_final"] <= 0.5
    with np.load(out / "trajectory.npz") as f:
        assert f["tau"].size == summary["accepted_steps"]


# -- the run ends on T, and says so ------------------------------------------------------------


def test_order2_run_ends_on_T(tmp_path, capsys):
    """It ended at t = 5.00016 for T = 5."""
    out = tmp_path / "o"
    code, stdout, err = run_cli(
        capsys, "run", "ris-1d", "--control", "order2", "--no-plots", "--out", str(out)
    )
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert abs(summary["t_final"] - 5.0) <= 1e-10 * 5
    landing = summary["landing"]
    assert landing["landed"] is True and landing["ended_by"] == "T"
    assert landing["tolerance"] == pytest.approx(5e-10)
    assert landing["t_final_minus_T"] == pytest.approx(summary["t_final"] - 5.0, abs=1e-15)


# -- output to a closed pipe ------------------------------------------------------------


def test_closed_stdout_pipe_is_not_a_traceback(tmp_path):
    """``rothe run ris-1d --control uniform | head -3`` ended in a BrokenPipeError traceback."""
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "rothe.cli.main",
            "run",
            "ris-1d",
            "--control",
            "uniform",
            "--no-plots",
            "--out",
            str(tmp_path / "o"),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        cwd=tmp_path,
    )
    proc.stdout.close()  # the reader goes away before anything is printed
    err = proc.stderr.read().decode()
    proc.stderr.close()
    assert proc.wait(timeout=120) == 141  # 128 + SIGPIPE, as for a program killed by it
    assert err == ""
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["status"] == "completed"
