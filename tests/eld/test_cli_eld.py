"""The ELD commands: outputs, summary fields, and one-line errors with exit status 2."""

import json
from pathlib import Path

import meshio
import numpy as np
import pytest

from ..conftest import run_cli


def _run(argv, capsys):
    return run_cli(capsys, *argv)


def test_run_eld_mms_writes_summary_trajectory_and_figures(tmp_path, capsys):
    out = tmp_path / "mms"
    code, stdout, _ = _run(
        ["run", "eld-mms", "--tau", "0.05", "--n", "2", "--out", str(out)], capsys
    )
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    for key in (
        "error_u_l2",
        "error_u_h1",
        "error_v_l2",
        "error_v_h1",
        "error_lam_l2",
        "accepted_steps",
        "rejected_steps",
        "newton_iterations",
        "wall_time_s",
        "balance_residual_max",
        "reaction_left_final",
    ):
        assert key in summary, key
    assert summary["lam_norm"] == "L2(Gamma_D)"
    assert summary["accepted_steps"] == 20 and summary["status"] == "completed"
    assert summary["balance_residual_max"] < 1e-9
    assert (out / "fig_energy.png").is_file() and (out / "fig_reaction.png").is_file()
    data = np.load(out / "trajectory.npz")
    # kept states t = 0, ..., T (lam[0] the consistent initial multiplier) and the mesh
    assert data["lam"].shape[0] == 21 and data["t"].shape[0] == 21
    assert data["u"].shape == (21, data["doflocs"].shape[0] * 2)
    assert data["nodes"].shape == (9, 2) and data["cells"].shape == (8, 3)
    assert np.array_equal(data["kept_t"], data["t"])
    for name in ("mms.xdmf", "mms.h5", "mms_multiplier.xdmf"):
        assert (out / name).is_file(), name
    assert "energy balance of the scheme" in stdout and "numerical dissipation" in stdout


def test_quiet_prints_nothing(tmp_path, capsys):
    code, stdout, stderr = _run(
        [
            "run",
            "eld-mms",
            "--tau",
            "0.1",
            "--n",
            "2",
            "--quiet",
            "--no-plots",
            "--out",
            str(tmp_path),
        ],
        capsys,
    )
    assert code == 0 and stdout == "" and stderr == ""
    assert not (tmp_path / "fig_energy.png").exists()


@pytest.mark.parametrize(
    "args,message",
    [
        (
            ["--rho", "1", "--d0", "2", "--tau", "0.6"],
            "tau: got 0.6, must be < rho/d0 = 0.5 (Lemma 3.2",
        ),
        (["--rho", "-1"], "rho: got -1, must be > 0"),
        (["--mu", "-1"], "mu: got -1, must be > 0"),
        (["--lam", "-1.5"], "lam: got -1.5, must be > -2 mu / d = -1"),
        (["--dirichlet", "lft"], "dirichlet: got 'lft', must be one of bottom, left, right, top"),
        (["--start", "rest"], "u0: got max|u0 - G(0)| = 0.5 on the Dirichlet parts left"),
        (["--tau", "0.3"], "--tau: got 0.3, must divide T = 1 into equal steps"),
        (["--form", "index3"], "--form: got 'index3', must be one of regularized, original"),
        (["--damping", "viscous"], "--damping: got 'viscous', must be one of none, rayleigh"),
        (["--d0", "-1"], "--d0: got -1, must be >= 0"),
        (["--degree", "3"], "--degree: got 3, must be 1 or 2"),
    ],
)
def test_bad_input_is_one_line_and_exit_status_2(tmp_path, capsys, args, message):
    out = tmp_path / "bad"
    code, _, stderr = _run(
        ["run", "eld-mms", "--n", "2", "--out", str(out), "--quiet"] + args, capsys
    )
    assert code == 2
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("rothe: error: ")
    assert message in lines[0]
    assert not (out / "trajectory.npz").exists()  # stopped before the first step


def test_study_eld_convergence(tmp_path, capsys):
    out = tmp_path / "conv"
    code, stdout, _ = _run(
        [
            "study",
            "eld-convergence",
            "--n",
            "2",
            "--halvings",
            "2",
            "--out",
            str(out),
            "--no-plots",
        ],
        capsys,
    )
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["tau"] == [0.1, 0.05, 0.025]
    assert len(s["error_u"]) == 3 and len(s["error_v"]) == 3
    assert s["rate_u"] > 0.8 and s["rate_v"] > 0.7
    assert "fitted orders" in stdout and (out / "table.txt").is_file()
    # the multiplier's errors are kept too, and fall with tau
    assert len(s["error_lam"]) == 3 and s["error_lam"][-1] < s["error_lam"][0]


def test_study_eld_convergence_bdf2_summary(tmp_path, capsys):
    out = tmp_path / "conv2"
    code, _, _ = _run(
        [
            "study",
            "eld-convergence",
            "--scheme",
            "bdf2",
            "--n",
            "2",
            "--halvings",
            "2",
            "--out",
            str(out),
            "--no-plots",
        ],
        capsys,
    )
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["tau"] == [0.1, 0.05, 0.025]
    for key in ("error_u", "error_v", "error_lam"):
        assert len(s[key]) == 3 and s[key][-1] < s[key][0], key
    assert s["rate_u"] > 1.5 and s["rate_v"] > 1.5


def test_study_eld_perturbation(tmp_path, capsys):
    out = tmp_path / "pert"
    code, stdout, _ = _run(
        [
            "study",
            "eld-perturbation",
            "--taus",
            "0.1,0.01",
            "--n",
            "2",
            "--targets",
            "G",
            "--damping",
            "rayleigh",
            "--out",
            str(out),
        ],
        capsys,
    )
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["tau"] == [0.1, 0.01]
    for key in (
        "amp_regularized",
        "amp_original",
        "amp_v_regularized",
        "amp_v_original",
        "amp_u_regularized",
        "amp_u_original",
    ):
        assert len(s[key]) == 2, key
    assert s["amp_original"][1] > 5 * s["amp_original"][0]
    assert (out / "fig_perturbation_G.png").is_file()
    code, _, stderr = _run(
        ["study", "eld-perturbation", "--taus", "0.1", "--out", str(out)], capsys
    )
    assert code == 2 and "needs at least two step sizes" in stderr


def test_run_eld_beam_writes_xdmf_of_u_v_and_the_multiplier(tmp_path, capsys):
    out = tmp_path / "beam"
    code, _, _ = _run(
        [
            "run",
            "eld-beam",
            "--n",
            "1",
            "--T",
            "0.1",
            "--tau",
            "0.01",
            "--save-every",
            "2",
            "--out",
            str(out),
            "--quiet",
        ],
        capsys,
    )
    assert code == 0
    for name in (
        "beam.xdmf",
        "beam.h5",
        "beam_multiplier.xdmf",
        "beam_multiplier.h5",
        "fig_reaction.png",
        "summary.json",
        "trajectory.npz",
    ):
        assert (out / name).is_file(), name
    with meshio.xdmf.TimeSeriesReader(str(out / "beam_multiplier.xdmf")) as reader:
        reader.read_points_cells()
        t, point_data, _ = reader.read_data(reader.num_steps - 1)
    assert t == pytest.approx(0.1) and point_data["lambda"].shape[1] == 3
    s = json.loads((out / "summary.json").read_text())
    assert s["n_steps"] == 10 and s["xdmf_steps"] == 6  # t = 0 and every second step
    data = np.load(out / "trajectory.npz")
    assert data["reaction_left"].shape == (10, 3)
    # the held end is pulled up (+z): the support pushes the beam up at first
    assert data["reaction_left"][0, 2] > 0


@pytest.mark.parametrize(
    "degree, T, remedy",
    [("1", "0.3", "use --degree 2 or a larger --n"), ("2", "2", "use a larger --n")],
)
def test_eld_beam_reports_numerical_dissipation_and_a_coarse_mesh(
    tmp_path, capsys, degree, T, remedy
):
    """The note on a coarse mesh advises --degree 2 only when the degree is not 2 already
    (issue 21: ``eld-beam --n 1`` at its default degree 2 was told to use --degree 2)."""
    out = tmp_path / "coarse"
    code, stdout, _ = _run(
        ["run", "eld-beam", "--n", "1", "--degree", degree, "--T", T, "--no-plots"]
        + ["--out", str(out)],
        capsys,
    )
    assert code == 0
    assert "numerical dissipation: " in stdout and "put in by the support" in stdout
    (note,) = [line for line in stdout.splitlines() if line.startswith("note: coarse mesh")]
    assert "the sideways reactions are" in note and note.endswith(remedy), note
    s = json.loads((out / "summary.json").read_text())
    assert max(s["reaction_sideways_over_z"]) > 0.02
    assert 0 < s["numerical_dissipation_fraction"] < 1
    data = np.load(out / "trajectory.npz")
    assert data["nodes"].shape[1] == 3 and data["cells"].shape[1] == 4
    assert data["kept_step"][-1] == round(float(T) / 0.01)


@pytest.mark.parametrize(
    "args,message",
    [
        (["--scheme", "bdf3"], "--scheme: got 'bdf3', must be one of euler, bdf2"),
        (["--control", "adaptive", "--tol", "0"], "--tol: got 0, must be > 0"),
        (["--control", "adaptive", "--tol", "-1"], "--tol: got -1, must be > 0"),
        (["--tol", "1e-3"], "--tol: got 0.001, is used by --control adaptive only"),
        (
            ["--scheme", "bdf2", "--steps", "0.1,0.3,0.6"],
            "--steps: got tau_2/tau_1 = 3, must be < 1 + sqrt(2) = 2.41421 (zero-stability",
        ),
        (
            ["--scheme", "bdf2", "--d0", "2", "--tau", "0.8"],
            "--tau: got 0.8, must be < 1.5 rho/d0 = 0.75 (Lemma 3.2 for BDF2",
        ),
        # the CLI refuses it before the library would (i10-defects): at most 1e7 steps of T
        (["--tau", "1e-320"], "--tau: got 9.99989e-321, must be >= 1e-07 (at most 1e+07 steps"),
        (["--scheme", "bdf2", "--data", "means"], "--data: got 'means', with scheme bdf2 must be"),
        (["--load-quadrature", "0"], "--load-quadrature: got 0, must be an integer >= 1"),
    ],
)
def test_bad_eld_options_are_one_line_and_exit_2(tmp_path, capsys, args, message):
    code, _, err = _run(
        ["run", "eld-mms", "--n", "2", "--quiet", "--out", str(tmp_path)] + args, capsys
    )
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and message in lines[0], err


def test_perturbation_study_refuses_an_unknown_datum(tmp_path, capsys):
    code, _, err = _run(
        ["study", "eld-perturbation", "--targets", "G,H", "--out", str(tmp_path)], capsys
    )
    assert code == 2 and "--targets: got 'H', must be one of G, G_dot, G_ddot, F" in err


def test_adaptive_bdf2_run_from_the_run(tmp_path, capsys):
    out = tmp_path / "adaptive"
    code, stdout, _ = _run(
        [
            "run",
            "eld-mms",
            "--n",
            "2",
            "--scheme",
            "bdf2",
            "--control",
            "adaptive",
            "--tol",
            "1e-3",
            "--no-plots",
            "--out",
            str(out),
        ],
        capsys,
    )
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["scheme"] == "bdf2" and s["control"] == "adaptive" and s["tol"] == 1e-3
    assert s["status"] == "completed" and s["balance_residual_max"] < 1e-10
    assert s["tau_min_used"] < s["tau_max_used"]
    assert "(G-form part N_G" in stdout


def test_beam_overflow_is_a_failed_run(tmp_path, capsys):
    out = tmp_path / "beam"
    code, _, err = _run(
        [
            "run",
            "eld-beam",
            "--n",
            "1",
            "--degree",
            "1",
            "--T",
            "0.05",
            "--amplitude",
            "1e300",
            "--quiet",
            "--no-plots",
            "--out",
            str(out),
        ],
        capsys,
    )
    assert code == 1 and "non-finite" in err
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "failed" and "non-finite" in s["failure"]


@pytest.mark.parametrize(
    "command, option, default",
    [
        ("eld-pulse", "--scheme", "bdf2"),
        ("eld-mms", "--scheme", "euler"),
        ("eld-beam", "--scheme", "euler"),
        ("eld-beam", "--damping", "rayleigh"),
        ("eld-mms", "--damping", "nonlinear"),
        ("eld-mms", "--form", "regularized"),
        ("eld-mms", "--control", "uniform"),
        ("eld-mms", "--data", "points"),
        ("eld-mms", "--lifting", "nodal"),
        ("eld-beam", "--solver", "auto"),
    ],
)
def test_help_states_the_default_the_command_runs(capsys, command, option, default):
    """eld-pulse --help said the scheme defaults to implicit Euler while it ran BDF2."""
    from rothe.cli.main import build_parser

    parser = build_parser()
    args = parser.parse_args(["run", command])
    assert getattr(args, option.lstrip("-").replace("-", "_")) == default
    with pytest.raises(SystemExit):
        parser.parse_args(["run", command, "--help"])
    lines = capsys.readouterr().out.splitlines()
    start = next(
        i
        for i, line in enumerate(lines)
        if line.startswith(f"  {option} {option.lstrip('-').upper()}")
    )
    end = next(
        i for i in range(start + 1, len(lines) + 1) if i == len(lines) or lines[i].startswith("  -")
    )
    block = " ".join(" ".join(lines[start:end]).split())
    assert f"(default {default})" in block, block


def test_an_adaptive_run_prints_its_initial_final_and_largest_dofs(tmp_path, capsys):
    """Issue 21: the terminal summary of ``--adapt-space`` runs says how the mesh grew."""
    out = tmp_path / "mms"
    argv = ["run", "eld-mms", "--n", "2", "--T", "0.2", "--tau", "0.05", "--adapt-space"]
    argv += ["--space-tol", "1e-3", "--max-dofs", "2000", "--no-plots", "--out", str(out)]
    code, stdout, _ = _run(argv, capsys)
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    printed = {
        line.split()[0]: line.split()[1] for line in stdout.splitlines() if line.startswith("  nd")
    }
    assert list(printed) == ["ndofs_initial", "ndofs", "ndofs_max"]
    assert [int(v) for v in printed.values()] == [s["ndofs_initial"], s["ndofs"], s["ndofs_max"]]
    assert s["ndofs_initial"] == 50 < s["ndofs_max"]


def test_steps_takes_step_sizes_as_the_docs_say(tmp_path, capsys):
    """Issue 21: docs/eld.md wrote ``--steps t1,t2,...`` (times); the option takes the step
    sizes tau_1, ..., tau_n summing to T, and the docs now say so with this example."""
    doc = (Path(__file__).resolve().parents[2] / "docs" / "eld.md").read_text()
    assert "--steps t1" not in doc and "`--T 1 --steps 0.5,0.25,0.25` ends its steps" in doc
    out = tmp_path / "steps"
    argv = ["run", "eld-mms", "--n", "2", "--T", "1", "--steps", "0.5,0.25,0.25"]
    code, _, err = _run(argv + ["--no-plots", "--quiet", "--out", str(out)], capsys)
    assert code == 0, err
    with np.load(out / "trajectory.npz") as f:
        assert np.allclose(f["t"], [0.0, 0.5, 0.75, 1.0])
        assert np.allclose(f["tau"], [0.5, 0.25, 0.25])
