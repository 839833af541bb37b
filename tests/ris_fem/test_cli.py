"""``rothe run ris-2d|ris-3d`` and ``rothe compare ris-2d``: outputs, bad input, failed runs."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from rothe.cli.main import main
from rothe.fem.mesh import unit_cube, unit_square
from rothe.io.trajectory import Trajectory
from rothe.io.xdmf import read_series


def run_cli(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_run_ris_2d_outputs(tmp_path, capsys):
    out = tmp_path / "r"
    code, stdout, err = run_cli(
        capsys, "run", "ris-2d", "--n", "6", "--tol", "1e-3", "--out", str(out)
    )
    assert code == 0, err
    assert "branch" in stdout and "linear_solver" in stdout
    files = {p.name for p in out.iterdir()}
    assert {
        "summary.json",
        "trajectory.npz",
        "solution.xdmf",
        "solution.h5",
        "fig4_steps.png",
        "fig_snapshots.png",
        "fig1_path.png",
    } <= files
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_nodes"] == 49 and summary["n_unknowns"] == 25
    assert summary["linear_solver"] == "splu" and summary["peak_memory_mb"] > 10
    # the run lands on T = 1 within the landing tolerance 1e-10 max(1, T) (rothe.ris.stepper)
    assert summary["status"] == "completed" and summary["landing"]["landed"]
    assert abs(summary["t_final"] - 1.0) <= 1e-10
    assert summary["z_max"] == 0.0 and summary["z_min"] < -1.3
    assert summary["n_viscous_jumps"] == 1 and summary["branch"].startswith("z <= 0")
    assert summary["max_kkt_residual"] < 1e-6 and summary["newton_iterations"] > 0
    with np.load(out / "trajectory.npz") as f:
        nodes, cells, Z = f["nodes"], f["cells"], f["z"]
    mesh = unit_square(6)
    assert np.array_equal(nodes, mesh.p.T) and np.array_equal(cells, mesh.t.T)
    assert Z.shape == (summary["accepted_steps"] + 1, 49)
    boundary = mesh.boundary_nodes()
    assert np.all(Z[:, boundary] == 0) and np.isclose(Z[-1].min(), summary["z_min"])
    traj = Trajectory.load_npz(out / "trajectory.npz")
    points, _, times, data = read_series(out / "solution.xdmf")
    assert np.array_equal(points, nodes) and np.array_equal(times, traj["s"])
    assert np.array_equal(data["z"], Z)


@pytest.mark.parametrize("method", ["auto", "direct", "amg"])
def test_reported_linear_solver_is_the_one_that_ran(method):
    """summary.json names the solver from the size rule; it must match what the solver used."""
    from rothe.cli.ris_fem_commands import linear_solver_used
    from rothe.ris.fem_problem import example_7_2
    from rothe.ris.inner import InnerOptions
    from rothe.ris.stepper import RISState, RISStepper

    p = example_7_2(6)
    stepper = RISStepper(p, InnerOptions(linear_solver=method))
    state = RISState(0.0, 0.0, p.z0.copy())
    for _ in range(4):  # sticking, then the viscous jump: Newton systems are solved
        state = stepper.step(state, 0.1).state
    assert stepper.solver.linear.kind_used is not None
    assert linear_solver_used(Trajectory(), p, method) == stepper.solver.linear.kind_used


def test_run_ris_2d_from_gmsh_with_named_dirichlet_part(tmp_path, capsys, gmsh_text):
    msh = gmsh_text.write_msh41(
        tmp_path / "sq.msh",
        unit_square(6),
        lambda mid: np.where(np.isclose(mid[0], 0), "left", "rest"),
    )
    out = tmp_path / "g"
    code, _, err = run_cli(
        capsys,
        "run",
        "ris-2d",
        "--mesh",
        str(msh),
        "--dirichlet",
        "left",
        "--control",
        "uniform",
        "--tau",
        "0.05",
        "--no-plots",
        "--quiet",
        "--out",
        str(out),
    )
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["mesh"] == str(msh) and summary["n_unknowns"] == 42
    with np.load(out / "trajectory.npz") as f:
        Z, nodes = f["z"], f["nodes"]
    left = np.isclose(nodes[:, 0], 0)
    assert np.all(Z[:, left] == 0) and np.all(Z[-1, ~left] < 0)  # Neumann elsewhere


def test_run_ris_3d(tmp_path, capsys):
    out = tmp_path / "c"
    code, _, err = run_cli(
        capsys, "run", "ris-3d", "--n", "3", "--tol", "1e-3", "--quiet", "--out", str(out)
    )
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_nodes"] == 64 and summary["example"] == "ris-3d"
    points, cells, _, data = read_series(out / "solution.xdmf")
    assert points.shape == (64, 3) and cells.shape[1] == 4
    assert (out / "fig_snapshots.png").exists()


def test_amplitude_sign_and_z0_are_options(tmp_path, capsys):
    out = tmp_path / "p"
    code, _, err = run_cli(
        capsys,
        "run",
        "ris-2d",
        "--n",
        "4",
        "--amplitude",
        "200",
        "--control",
        "uniform",
        "--tau",
        "0.05",
        "--no-plots",
        "--quiet",
        "--out",
        str(out),
    )
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["z_min"] == 0.0 and summary["z_max"] > 1.2 and summary["amplitude"] == 200.0


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--n", "1"], r"--n: got 1, must be an integer >= 2"),
        (["--n", "x"], r"argument --n: invalid int value: 'x'"),
        (["--mesh", "NOFILE.msh"], r"--mesh: got 'NOFILE.msh', no such file"),
        (["--mesh", "GARBAGE"], r"--mesh: got '.*garbage.msh', is not a mesh meshio can read"),
        (["--mesh", "TETS"], r"--mesh: got '.*tets.vtu', has no triangle cells \(found: tetra\)"),
        (["--mesh", "GARBAGE", "--n", "8"], r"--n: got 8, cannot be combined with --mesh"),
        (
            ["--dirichlet", "inlet"],
            r"--dirichlet: got 'inlet', must be one of bottom, left, right, top",
        ),
        (
            ["--linear-solver", "cholesky"],
            r"--linear-solver: got 'cholesky', must be one of auto, "
            r"direct, amg",
        ),
        (["--tol", "-1"], r"--tol: got -1, must be > 0"),
        (["--amplitude", "nan"], r"argument --amplitude: got 'nan', must be finite"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, argv, message):
    import meshio

    (tmp_path / "garbage.msh").write_text("not a mesh\n")
    c = unit_cube(2)
    meshio.write(tmp_path / "tets.vtu", meshio.Mesh(c.p.T, [("tetra", c.t.T)]))
    subst = {
        "NOFILE.msh": "NOFILE.msh",
        "GARBAGE": str(tmp_path / "garbage.msh"),
        "TETS": str(tmp_path / "tets.vtu"),
    }
    argv = [subst.get(a, a) for a in argv]
    code, stdout, err = run_cli(
        capsys, "run", "ris-2d", *argv, "--out", str(tmp_path / "o"), "--quiet"
    )
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    import re

    assert re.match(r"^rothe: error: " + message, lines[0]), lines[0]
    assert stdout == ""


def test_exit_status_2_from_the_real_command(tmp_path):
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "rothe.cli.main",
            "run",
            "ris-2d",
            "--mesh",
            str(tmp_path / "missing.msh"),
        ],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"rothe: error: --mesh: got '{tmp_path / 'missing.msh'}', no such file"
    ]


def test_failed_run_keeps_the_trajectory(tmp_path, capsys):
    out = tmp_path / "f"
    code, _, err = run_cli(
        capsys,
        "run",
        "ris-2d",
        "--n",
        "4",
        "--tau-min",
        "0.05",
        "--no-plots",
        "--quiet",
        "--out",
        str(out),
    )
    assert code == 1
    assert err.strip().startswith("rothe: run failed: step size fell below tau_min = 0.05")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and summary["accepted_steps"] >= 1
    with np.load(out / "trajectory.npz") as f:
        assert f["z"].shape == (summary["accepted_steps"] + 1, 25)
        assert f["nodes"].shape == (25, 2)
    assert read_series(out / "solution.xdmf")[3]["z"].shape[0] == summary["accepted_steps"] + 1


def test_compare_ris_2d_table_figure_and_compare_json(tmp_path, capsys):
    out = tmp_path / "cmp"
    # the uniform residuals (2.1 ... 0.52) bracket tol = 1e-2 (0.75), not 3e-3 (0.41)
    code, stdout, err = run_cli(
        capsys,
        "compare",
        "ris-2d",
        "--n",
        "4",
        "--tols",
        "1e-2,3e-3",
        "--taus",
        "0.02,0.01,0.005",
        "--controls",
        "adaptive,regime",
        "--out",
        str(out),
    )
    assert code == 0, err
    table = (out / "table.txt").read_text()
    assert table.strip() == stdout.split("wrote")[0].strip()
    rows = json.loads((out / "summary.json").read_text())["rows"]
    assert [r["control"] for r in rows] == ["adaptive"] * 2 + ["regime"] * 2 + ["uniform"] * 3
    assert all(r["status"] == "completed" for r in rows)
    assert "solves/u" in table and "equidistribution bound" in table
    assert (out / "fig5_residuals.png").exists()
    # the uniform scheme's global residual halves with the step
    u = [r["sum_residual"] for r in rows[4:]]
    assert 1.7 < u[0] / u[1] < 2.3 and 1.7 < u[1] / u[2] < 2.3
    cmp = json.loads((out / "compare.json").read_text())
    keys = [
        "control",
        "tol",
        "tau",
        "accepted",
        "rejected",
        "solves",
        "newton",
        "seconds",
        "local_residual",
        "global_residual",
        "ratio_steps",
        "ratio_solves",
        "ratio_seconds",
    ]
    assert all(list(r) == keys for r in cmp["rows"])
    for r, s in zip(cmp["rows"], rows, strict=True):
        assert (r["control"], r["accepted"], r["solves"]) == (
            s["control"],
            s["accepted_steps"],
            s["inner_solves"],
        )
        assert r["global_residual"] == s["sum_residual"]
        assert r["local_residual"] == s["max_residual"]
    uniform = [r for r in cmp["rows"] if r["control"] == "uniform"]
    assert all(
        r["tol"] is None
        and r["ratio_steps"] is None
        and r["ratio_solves"] is None
        and r["ratio_seconds"] is None
        for r in uniform
    )
    # the ratios: log-log interpolation between the bracketing uniform runs, by hand
    g = np.log([r["global_residual"] for r in uniform])[::-1]
    for r in cmp["rows"][:4]:
        x = np.log(r["global_residual"])
        if not g[0] <= x <= g[-1]:
            assert r["ratio_steps"] is None and r["ratio_solves"] is None
            continue
        for work, ratio in (
            ("accepted", "ratio_steps"),
            ("solves", "ratio_solves"),
            ("seconds", "ratio_seconds"),
        ):
            w = np.log([u[work] for u in uniform])[::-1]
            i = int(np.searchsorted(g, x).clip(1, len(g) - 1))
            expected = np.exp(w[i - 1] + (w[i] - w[i - 1]) * (x - g[i - 1]) / (g[i] - g[i - 1]))
            assert r[ratio] == pytest.approx(r[work] / expected, rel=1e-12)
    assert [r["ratio_solves"] is not None for r in cmp["rows"][:4]] == [True, False] * 2
    bound = cmp["equidistribution_bound"]
    assert bound["tau"] == 0.005 and 0.3 < bound["ratio_steps"] < 1.0


def test_compare_rows_null_outside_the_uniform_range():
    from rothe.cli.ris_fem_commands import compare_rows

    def row(control, G, acc, tau0=0.1, tol=1e-4):
        return {
            "control": control,
            "tol": tol,
            "tau0": tau0,
            "accepted_steps": acc,
            "rejected_steps": 0,
            "inner_solves": acc,
            "newton_iterations": 2 * acc,
            "wall_time_s": 0.01 * acc,
            "max_residual": G / acc,
            "sum_residual": G,
            "status": "completed",
        }

    rows = [
        row("regime", 0.5, 10),
        row("regime", 0.05, 50),
        row("regime", 2.0, 5),
        row("uniform", 1.0, 100, tau0=0.01, tol=None),
        row("uniform", 0.1, 1000, tau0=0.001, tol=None),
    ]
    out = compare_rows(rows)
    # G = 0.5 between 1.0 (100 steps) and 0.1 (1000): log-log gives 100 * 2 = 200 steps
    assert out[0]["ratio_steps"] == pytest.approx(10 / 200)
    assert out[0]["ratio_seconds"] == pytest.approx(0.1 / 2.0)
    assert out[1]["ratio_steps"] is None and out[2]["ratio_solves"] is None  # outside the range
    assert out[3]["ratio_steps"] is None and out[3]["tol"] is None and out[3]["tau"] == 0.01
    # a run that produced nothing (a lost task): its status only, nulls in compare.json
    lost = {"control": "regime", "tol": 1e-5, "tau0": 0.1, "status": "lost: worker died"}
    out = compare_rows(rows + [lost])
    assert list(out[-1]) == list(out[0]) and out[-1]["solves"] is None
    assert out[-1]["ratio_solves"] is None and out[0]["ratio_steps"] == pytest.approx(10 / 200)


def test_compare_bad_input(tmp_path, capsys):
    code, _, err = run_cli(capsys, "compare", "ris-2d", "--taus", "0.1", "--out", str(tmp_path))
    assert code == 2 and err.strip() == (
        "rothe: error: --taus: got '0.1', needs at least two step sizes"
    )
    code, _, err = run_cli(
        capsys, "compare", "ris-2d", "--controls", "nested", "--out", str(tmp_path)
    )
    assert code == 2 and err.strip() == (
        "rothe: error: --controls: got 'nested', must be one of adaptive, order2, regime"
    )
