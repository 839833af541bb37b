"""Stresses against a homogeneous deformation, and the outputs of a user's own run."""

import json

import meshio
import numpy as np
import pytest

from rothe.cli.main import main
from rothe.eld import Material, StressEvaluator, mms_problem, run_eld, von_mises, write_eld_result
from rothe.fem import mesh as meshes
from rothe.fem.elasticity import VectorSpace


def _hand_stress(grad, lam, mu):
    """sigma of the affine field u = grad x + c: lam tr(eps) I + 2 mu eps as a 3 x 3 tensor; in
    2D plane strain eps_zz = 0 and sigma_zz = lam tr(eps)."""
    d = grad.shape[0]
    eps = np.zeros((3, 3))
    eps[:d, :d] = 0.5 * (grad + grad.T)
    return lam * np.trace(eps) * np.eye(3) + 2 * mu * eps


def _hand_von_mises(s):
    return np.sqrt(
        0.5 * ((s[0, 0] - s[1, 1]) ** 2 + (s[1, 1] - s[2, 2]) ** 2 + (s[2, 2] - s[0, 0]) ** 2)
        + 3 * (s[0, 1] ** 2 + s[1, 2] ** 2 + s[0, 2] ** 2)
    )


@pytest.mark.parametrize("dim,degree", [(2, 1), (2, 2), (3, 1), (3, 2)])
def test_stress_of_a_homogeneous_deformation(dim, degree):
    rng = np.random.default_rng(dim * 10 + degree)
    grad = rng.uniform(-0.3, 0.3, (dim, dim))
    shift = rng.uniform(-1, 1, dim)
    mesh = meshes.unit_square(3, named=True) if dim == 2 else meshes.box(2, 2, 2)
    space = VectorSpace(mesh, degree)
    lam, mu = 1.7, 0.6
    u = space.interpolate(lambda x: grad @ x + shift[:, None])
    ev = StressEvaluator(space, Material(1.0, lam, mu, dim))
    expected = _hand_stress(grad, lam, mu)
    sigma = ev.stress(u)
    assert sigma.shape == (mesh.t.shape[1], 3, 3)
    assert np.abs(sigma - expected).max() <= 1e-12
    if dim == 2:
        assert abs(expected[2, 2]) > 0.01  # plane strain: sigma_zz = lam tr(eps) is not zero
    vm = von_mises(sigma)
    assert np.abs(vm - _hand_von_mises(expected)).max() <= 1e-12
    nodal = ev.nodal(sigma)
    assert nodal.shape == (mesh.p.shape[1], 3, 3)
    assert np.abs(nodal - expected).max() <= 1e-12  # averages of a constant are exact
    # a rigid motion has no stress
    rigid = space.rigid_body_modes() @ rng.standard_normal(3 if dim == 2 else 6)
    assert np.abs(ev.stress(rigid)).max() <= 1e-12


def test_von_mises_of_pure_shear_and_hydrostatic_states():
    shear = np.zeros((3, 3))
    shear[0, 1] = shear[1, 0] = 2.0
    assert von_mises(shear) == pytest.approx(2.0 * np.sqrt(3.0))
    assert von_mises(5.0 * np.eye(3)) == pytest.approx(0.0, abs=1e-14)


def test_write_eld_result_for_a_users_run(tmp_path):
    problem, _ = mms_problem(2, 2)
    traj = run_eld(problem, "regularized", 0.1, scheme="bdf2", keep_every=3)
    paths = write_eld_result(traj, problem, tmp_path, name="mine")
    data = np.load(paths["npz"])
    kept = data["kept_step"]
    assert list(kept) == [0, 3, 6, 9, 10]  # every 3rd, t = 0 and the last
    assert data["u"].shape == (5, problem.space.ndofs)
    assert data["lam"].shape == (5, problem.constraint.m)
    assert np.array_equal(data["lam_dofs"], problem.constraint.dofs)
    assert data["nodes"].shape == (problem.space.mesh.p.shape[1], 2)
    meta = json.loads(str(data["meta"]))
    assert meta["scheme"] == "bdf2" and meta["keep_every"] == 3
    ev = StressEvaluator(problem.space, problem.material)
    with meshio.xdmf.TimeSeriesReader(str(tmp_path / "mine.xdmf")) as reader:
        reader.read_points_cells()
        assert reader.num_steps == 5
        t, point_data, cell_data = reader.read_data(4)
    assert t == pytest.approx(1.0)
    assert np.allclose(cell_data["stress"][0], ev.stress(traj["u"][-1]).reshape(-1, 9))
    assert np.allclose(cell_data["von_mises"][0], von_mises(ev.stress(traj["u"][-1])))
    assert point_data["stress_nodal"].shape == (problem.space.mesh.p.shape[1], 9)
    for name in ("fig_energy.png", "fig_reaction.png", "mine_multiplier.xdmf"):
        assert (tmp_path / name).is_file()
    # without stored fields there is nothing to write to XDMF: one line
    bare = run_eld(problem, "regularized", 0.5, store_fields=False)
    with pytest.raises(ValueError, match=r"^traj: got a run without stored fields, must come"):
        write_eld_result(bare, problem, tmp_path / "bare", figures=False)


def _cli(argv, capsys):
    code = main(argv)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.mark.parametrize(
    "args,message",
    [
        (["--scheme", "bdf3"], "--scheme: got 'bdf3', must be one of euler, bdf2"),
        (["--control", "adaptive", "--tol", "0"], "--tol: got 0, must be > 0"),
        (["--control", "adaptive", "--tol", "-1"], "--tol: got -1, must be > 0"),
        (["--tol", "1e-3"], "--tol: got 0.001, is used by --control adaptive only"),
        (
            ["--scheme", "bdf2", "--steps", "0.1,0.3,0.6"],
            "steps: got tau_2/tau_1 = 3, must be < 1 + sqrt(2) = 2.41421 (zero-stability",
        ),
        (
            ["--scheme", "bdf2", "--d0", "2", "--tau", "0.8"],
            "tau: got 0.8, must be < 1.5 rho/d0 = 0.75 (Lemma 3.2 for BDF2",
        ),
        # the CLI refuses it before the library would (i10-defects): at most 1e7 steps of T
        (["--tau", "1e-320"], "--tau: got 9.99989e-321, must be >= 1e-07 (at most 1e+07 steps"),
        (["--scheme", "bdf2", "--data", "means"], "data: got 'means', with scheme bdf2 must be"),
        (["--load-quadrature", "0"], "load_quadrature: got 0, must be an integer >= 1"),
    ],
)
def test_bad_eld_options_are_one_line_and_exit_2(tmp_path, capsys, args, message):
    code, _, err = _cli(
        ["run", "eld-mms", "--n", "2", "--quiet", "--out", str(tmp_path)] + args, capsys
    )
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and message in lines[0], err


def test_perturbation_study_refuses_an_unknown_datum(tmp_path, capsys):
    code, _, err = _cli(
        ["study", "eld-perturbation", "--targets", "G,H", "--out", str(tmp_path)], capsys
    )
    assert code == 2 and "--targets: got 'H', must be one of G, G_dot, G_ddot, F" in err


def test_adaptive_bdf2_run_from_the_cli(tmp_path, capsys):
    out = tmp_path / "adaptive"
    code, stdout, _ = _cli(
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
    code, _, err = _cli(
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
