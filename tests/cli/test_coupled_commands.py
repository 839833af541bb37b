"""``rothe run eld-tip-mass|eld-tmd|eld-control``: the outputs, the physics each measures
(the tip-mass frequency against the transcendental equation, the amplitude reduction of a tuned
mass damper, the decay rate under feedback against the characteristic equation), adaptive
steps, the run sequence (an interrupted coupled run writes what it has), help texts and
one-line refusals (exit 2)."""

from __future__ import annotations

import json
import signal

import meshio
import numpy as np
import pytest

from rothe.cli.coupled_commands import crossing_frequency, decay_rate
from rothe.cli.main import main
from rothe.eld.coupled_run import CoupledStepper
from rothe.eld.frequencies import (
    Attachment,
    bar_frequencies,
    modal_frequencies,
    sliced_bar_frequencies,
)
from rothe.io.checkpoint import load_checkpoint
from rothe.io.trajectory import is_timing_array

from ..conftest import write_gmsh_body


def _run(tmp_path, *args, plots=False, command="eld-tip-mass"):
    out = tmp_path / "out"
    argv = ["run", command, "--quiet", "--out", str(out), *args]
    if not plots:
        argv.append("--no-plots")
    return main(argv), out


def test_tip_mass_run_writes_summary_trajectory_and_figure(tmp_path):
    code, out = _run(tmp_path, "--tau", "0.01", plots=True)
    assert code == 0
    assert {p.name for p in out.iterdir()} >= {"summary.json", "trajectory.npz", "fig_tip_mass.png"}
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "completed" and s["accepted_steps"] == 200
    # P2, 8 x 2 cells: the discrete frequencies against beta L tan(beta L) = rho A L / m
    assert abs(s["frequency_error_discrete"][0]) < 1e-6
    assert abs(s["frequency_error_discrete"][1]) < 1e-4
    # the run oscillates at the discrete frequency up to BDF2's phase error (2.4e-3 at
    # tau = 0.01, docs/coupling.md Sec. 9) and keeps the energy to O(tau^2)
    assert 1e-4 < abs(s["frequency_error_measured_vs_discrete"]) < 3e-3
    assert abs(s["energy_drift"]) < 1e-2
    assert s["balance_max"] < 1e-12 * s["energy_initial"]
    data = np.load(out / "trajectory.npz")
    assert data["q"].shape == (201, 2) and data["reaction_left"].shape == (201, 2)
    assert data["tau"].shape == (200,)
    assert abs(np.abs(data["q"][:, 0]).max() - 0.01) < 1e-3  # --amplitude
    # the reaction at the clamp balances the bar's and the mass's inertia: it oscillates
    assert np.ptp(data["reaction_left"][:, 0]) > 0.1
    # the body in ParaView (issue 19, "Outputs"; none before): u at the last state, and the
    # multiplier on the clamp and on the coupled tip, whose resultant is the recorded reaction
    # (--keep-every 5 by default: the states 0, 5, ..., 200)
    assert s["paraview"] == ["body.xdmf"] and data["u"].shape == (41, 170)
    assert np.array_equal(data["kept_states"], np.arange(0, 201, 5))
    with meshio.xdmf.TimeSeriesReader(str(out / "body.xdmf")) as reader:
        points, _ = reader.read_points_cells()
        assert reader.num_steps == 41
        t, point_data, _ = reader.read_data(40)
    assert t == pytest.approx(2.0)
    nv = len(points)
    assert np.array_equal(point_data["u"][:, :2], data["u"][-1].reshape(-1, 2)[:nv])
    with meshio.xdmf.TimeSeriesReader(str(out / "body_multiplier.xdmf")) as reader:
        points, _ = reader.read_points_cells()
        _, point_data, _ = reader.read_data(40)
    on = {"left": np.isclose(points[:, 0], 0.0), "right": np.isclose(points[:, 0], 1.0)}
    assert on["left"].any() and on["right"].any() and np.all(on["left"] | on["right"])
    assert np.abs(point_data["lambda"][on["right"]]).max() > 0


def test_tip_mass_on_a_spring_adaptive_steps_and_halved_tau_error(tmp_path):
    """With a spring k = 50 the frequency moves to the mass-spring root; the measured error
    falls like tau^2 (BDF2); adaptive Euler steps keep the local error below --tol."""
    errors = []
    for tau in ("0.01", "0.005"):
        code, out = _run(tmp_path, "--spring", "50", "--tau", tau)
        assert code == 0
        s = json.loads((out / "summary.json").read_text())
        errors.append(abs(s["frequency_error_measured_vs_discrete"]))
    assert s["frequency_analytic"][0] == pytest.approx(14.6717, rel=1e-4)
    assert errors[0] / errors[1] == pytest.approx(4.0, rel=0.1)
    code, out = _run(
        tmp_path,
        *("--spring", "50", "--T", "1", "--control", "adaptive", "--tol", "1e-4"),
        *("--scheme", "euler"),
    )
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["control"] == "adaptive" and s["scheme"] == "euler"
    assert s["balance_max"] < 1e-12 * s["energy_initial"]
    data = np.load(out / "trajectory.npz")
    assert data["local_error"].max() <= 1e-4 and data["t"][-1] == 1.0
    # one mode, one time scale: nearly equal steps, whose Euler phase error is small
    assert s["accepted_steps"] > 500 and abs(s["frequency_error_measured_vs_discrete"]) < 1e-3


def test_tip_mass_measures_three_frequencies_from_the_run(tmp_path):
    """--modes 3: the run starts in the sum of the first three axial modes (the tip at 3
    amplitudes) and measures each frequency from its modal coordinate: within BDF2's period
    error of the modal analysis (-6.2e-4, -9.4e-3, -3.1e-2 at tau = 0.005), the first equal to
    the single-mode run's; the figure gets the modal coordinates."""
    code, out = _run(tmp_path, "--modes", "3", plots=True)
    assert code == 0 and (out / "fig_tip_mass.png").exists()
    s = json.loads((out / "summary.json").read_text())
    assert s["modes"] == 3 and len(s["frequencies_measured"]) == 3
    assert s["frequency_measured"] == s["frequencies_measured"][0]
    vs_discrete = np.array(s["frequencies_error_measured_vs_discrete"])
    w_h = np.array(s["frequency_discrete"])
    # BDF2's period error -(w tau)^2 / 3 or so, growing with the mode
    assert np.all(vs_discrete < 0) and np.all(np.diff(vs_discrete) < 0)
    assert np.all(np.abs(vs_discrete) < 0.4 * (w_h * 0.005) ** 2), vs_discrete
    vs_analytic = np.array(s["frequencies_error_measured"])
    assert np.allclose(vs_analytic, vs_discrete, atol=5e-4)  # P2, 2 cells across: space 2e-4
    assert abs(np.load(out / "trajectory.npz")["q"][0, 0]) == pytest.approx(0.03, rel=1e-9)
    # the tip's q_x alone (matrix pencil): the same frequencies (1.2e-6 apart measured: the
    # crossings' interpolation)
    assert np.allclose(s["frequencies_measured_tip"], s["frequencies_measured"], rtol=1e-4)
    code, one = _run(tmp_path / "one")
    first = json.loads((one / "summary.json").read_text())
    assert first["frequencies_measured"] == [first["frequency_measured"]]
    assert first["frequency_measured"] == pytest.approx(s["frequency_measured"], rel=1e-12)


def test_tip_mass_trajectory_stores_the_modal_coordinates(tmp_path):
    """trajectory.npz holds what --modes measures from (before: only q and the kept u): the
    modal coordinates c_k(t) (``modal_c``, every state, at ``modal_t``) and the rows that
    project on them (``modal_rows_u``, ``modal_rows_q``); c_1 equals the projection recomputed
    from the stored u and q at the kept states, and re-fitting the stored c_k gives the
    summary's frequencies."""
    code, out = _run(tmp_path, "--modes", "2", "--T", "1", "--tau", "0.01")
    assert code == 0
    d = np.load(out / "trajectory.npz")
    s = json.loads((out / "summary.json").read_text())
    assert d["modal_c"].shape == (101, 2) and np.array_equal(d["modal_t"], d["t"])
    assert d["modal_rows_u"].shape == (2, d["u"].shape[1]) and d["modal_rows_q"].shape == (2, 2)
    keep = d["kept_states"]
    c1 = d["u"] @ d["modal_rows_u"][0] + d["q"][keep] @ d["modal_rows_q"][0]
    scale = np.abs(d["modal_c"][:, 0]).max()
    assert scale > 0 and np.abs(d["modal_c"][keep, 0] - c1).max() <= 1e-12 * scale
    assert modal_frequencies(d["modal_t"], d["modal_c"]) == s["frequencies_measured"]


# -- several materials in slices along x: the sliced bar's analytic frequencies (issue 19) ----

_HALVES = ("--material=soft:E=100,nu=0", "--material=stiff:E=400,nu=0,rho=2",
           "--region=soft=core", "--region=stiff=shell")  # fmt: skip


def _two_materials(tmp_path, name, *materials, split_axis=0):
    """eld-tip-mass on the default strip (1 x 0.25, 8 x 2 cells, P2) as a gmsh file whose cells
    are 'core' (x < 1/2, or y < 1/8 with ``split_axis`` 1) and 'shell'."""
    split = 0.5 if split_axis == 0 else 0.125
    mesh = write_gmsh_body(tmp_path / f"{name}.msh", nx=8, ny=2, length=1.0, height=0.25,
                           split=split, split_axis=split_axis)  # fmt: skip
    code, out = _run(tmp_path / name, "--mesh", str(mesh), "--dirichlet", "inlet", "--tip",
                     "outlet", "--modes", "3", *materials)  # fmt: skip
    assert code == 0
    return _strict_json(out / "summary.json")


def test_tip_mass_of_two_slices_against_the_sliced_bar(tmp_path):
    """E = 100, rho = 1 on x < 1/2 and E = 400, rho = 2 on x > 1/2 (before: frequency_analytic
    null, the bar equation takes one E and rho): the transfer matrix of the two slices with the
    tip mass (9.0434, 48.480, 72.214); the discrete frequencies converge to it (9.0e-8, 4.1e-5,
    2.9e-4 on 8 x 2 cells), the measured ones within BDF2's period error (tau = 0.005)."""
    s = _two_materials(tmp_path, "slices", *_HALVES)
    exact = sliced_bar_frequencies(
        [0.5, 0.5], [100.0, 400.0], [1.0, 2.0], area=0.25, right=Attachment.mass_spring(0.25, 0)
    )
    assert s["analytic"] == "sliced bar"
    assert np.allclose(s["frequency_analytic"], exact, rtol=1e-12, atol=0)
    assert [(p["x"], p["material"], p["modulus"], p["rho"]) for p in s["slices"]] == [
        ([0.0, 0.5], "soft", 100.0, 1.0),
        ([0.5, 1.0], "stiff", 400.0, 2.0),
    ]
    assert np.all(np.abs(s["frequency_error_discrete"]) < [1e-6, 1e-4, 1e-3])
    errors = np.abs(s["frequencies_error_measured"])
    assert errors[0] < 1e-3 and np.all(errors < 0.05), errors
    # the uniform bar of the first material is 4 % off: the check would fail for one E, rho
    uniform = bar_frequencies(1.0, 100.0, 1.0, area=0.25, right=Attachment.mass_spring(0.25, 0))
    assert abs(uniform[0] / exact[0] - 1) > 0.04


def test_tip_mass_of_layers_along_the_length_has_no_analytic_frequencies(tmp_path):
    """The same materials as layers along x (y < 1/8 and y > 1/8): their intervals of x
    overlap, no slices -- frequency_analytic null with the reason; the run is measured."""
    s = _two_materials(tmp_path, "layers", *_HALVES, split_axis=1)
    assert s["analytic"].startswith("n/a: the materials do not fill slices along x")
    assert s["frequency_analytic"] == [None, None, None] and "slices" not in s
    assert s["frequencies_error_measured"] == [None, None, None]
    assert len(s["frequencies_measured"]) == 3 and s["frequencies_measured"][0] > 0


def test_one_material_in_two_slices_is_the_bar_equation(tmp_path):
    """Two materials of equal constants on the two halves: the sliced bar's frequencies are the
    one-material bar equation's (to 1e-12)."""
    two = _two_materials(
        tmp_path, "two", "--material=a:E=100,nu=0", "--material=b:E=100,nu=0",
        "--region=a=core", "--region=b=shell",
    )  # fmt: skip
    one = _two_materials(tmp_path, "one")
    assert two["analytic"] == "sliced bar" and one["analytic"] == "bar"
    assert len(two["slices"]) == 2
    assert np.allclose(two["frequency_analytic"], one["frequency_analytic"], rtol=1e-12, atol=0)


def _strict_json(path):
    """summary.json parsed as strict JSON: NaN or Infinity, which json.dumps writes for
    non-finite floats and JSON parsers refuse, is an error."""

    def refuse(constant):
        raise AssertionError(f"{path.name} holds {constant}, not JSON")

    return json.loads(path.read_text(), parse_constant=refuse)


def test_a_run_too_short_to_measure_writes_null_not_nan(tmp_path):
    """T = 0.1 is less than half a period of the first mode: no two zero crossings, so the
    measured frequency and its errors are unknown -- null in summary.json, which stays strict
    JSON (before: NaN for the errors, numpy floats, while the frequency itself was null)."""
    code, out = _run(tmp_path, "--T", "0.1", "--tau", "0.01")
    assert code == 0
    s = _strict_json(out / "summary.json")
    assert s["frequency_measured"] is None
    assert s["frequency_error_measured"] is None
    assert s["frequency_error_measured_vs_discrete"] is None
    assert abs(s["frequency_error_discrete"][0]) < 1e-6  # the modal analysis is there


def test_summary_json_writes_every_non_finite_float_as_null(tmp_path):
    from rothe.cli.common import write_summary

    values = {"a": np.float64("nan"), "b": np.array([1.0, np.inf]), "c": [np.float32("-inf")]}
    s = _strict_json(write_summary(tmp_path, {**values, "d": float("nan"), "e": np.int64(3)}))
    assert s == {"a": None, "b": [1.0, None], "c": [None], "d": None, "e": 3}


def test_crossing_frequency_of_a_sine():
    t = np.linspace(0, 3, 3001)
    assert crossing_frequency(t, np.sin(7.0 * t + 0.3)) == pytest.approx(7.0, rel=1e-5)
    assert np.isnan(crossing_frequency(t, 1 + 0 * t))


def test_help_states_the_defaults(capsys):
    assert main(["run", "eld-tip-mass", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    for phrase in (
        "tip mass m (default 0.25",
        "(default bdf2)",
        "time step; must divide T (default 0.005)",
        "Poisson ratio (default 0",
        "end time (default 2",
    ):
        assert phrase in text, phrase


@pytest.mark.parametrize(
    "args, line",
    [
        (["--mass", "-1"], "--mass: got -1, must be > 0"),
        (["--spring", "-1"], "--spring: got -1, must be >= 0"),
        (["--degree", "3"], "--degree: got 3, must be 1 or 2"),
        (["--n", "0"], "--n: got 0, must be an integer >= 1"),
        (["--n", "40"], "--n: got 40, gives 12800 cells, must give at most 4000"),
        (["--tau", "0.003"], "--tau: got 0.003, must divide T = 2 into equal steps"),
        (["--control", "adaptive"], "--tol: got None, must be given (> 0) with --control adaptive"),
        (["--scheme", "rk4"], "--scheme: got 'rk4', must be one of euler, bdf2"),
        (["--E", "-5"], "--E: got -5, must be > 0"),
        (["--nu", "0.6"], "--nu: got 0.6, must satisfy -1 < nu < 0.5"),
        (["--height", "0"], "--height: got 0, must be > 0"),
        (["--lifting", "l2"], "--lifting: got 'l2', must be one of"),
        (["--keep-every", "0"], "--keep-every: got 0, must be an integer >= 1"),
        (["--modes", "0"], "--modes: got 0, must be an integer >= 1"),
        (["--modes", "1.5"], "argument --modes: got '1.5', must be an integer >= 1"),
        (
            ["--modes", "6"],
            "--modes: got 6, must be at most 5 (the axial modes among the first 16 of the "
            "discrete system)",
        ),
    ],
)
def test_bad_options_are_one_line_and_exit_2(tmp_path, capsys, args, line):
    code, out = _run(tmp_path, *args)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("rothe: error: " + line), err
    assert not (out / "summary.json").exists()


@pytest.mark.parametrize(
    "args, line",
    [
        (["--dim", "4"], "--dim: got 4, must be 2 or 3"),
        (
            ["--dim", "3", "--ns", "2,6"],
            "--ns: got 6, gives 24843 unknowns in 3D (P2), must give at most 16000",
        ),
    ],
)
def test_tip_mass_study_3d_refusals_are_one_line(tmp_path, capsys, args, line):
    out = tmp_path / "out"
    code = main(["study", "eld-tip-mass", "--quiet", "--out", str(out), *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("rothe: error: " + line), err
    assert not out.exists()


def test_decay_rate_of_a_damped_cosine():
    t = np.linspace(0, 6, 6001)
    assert decay_rate(t, np.exp(-0.4 * t) * np.cos(6.0 * t)) == pytest.approx(0.4, rel=1e-3)
    assert np.isnan(decay_rate(t, np.exp(-t)))


def test_tuned_mass_damper_reduces_the_resonant_tip_amplitude(tmp_path):
    """Forced at the first bending frequency of the strip on its support, the tip's amplitude
    grows without the absorber (linearly: no damping) and stays bounded with it; Den Hartog's
    tuning; both runs' ledgers close."""
    code, out = _run(tmp_path, "--T", "6", "--tau", "0.02", command="eld-tmd", plots=True)
    assert code == 0
    files = {p.name for p in out.iterdir()}
    assert files >= {"summary.json", "trajectory.npz", "trajectory_without_tmd.npz", "fig_tmd.png"}
    # both runs' bodies in ParaView
    assert files >= {"body.xdmf", "body_multiplier.xdmf", "body_without_tmd.xdmf"}
    s = json.loads((out / "summary.json").read_text())
    # 4.0 at T = 6 (8.3 at the default T = 12): the resonance is detuned by the absorber
    assert s["amplitude_reduction"] > 3 and s["reaction_reduction"] > 3
    mu, w1, m1 = s["mass_ratio"], s["frequency_first_bending"], s["modal_mass"]
    assert s["absorber_stiffness"] == pytest.approx(mu * m1 * (w1 / (1 + mu)) ** 2, rel=1e-12)
    # the end plate and the support's compliance lower w_1 below the clamped beam's
    assert 0.8 * s["frequency_beam_theory"] < w1 < s["frequency_beam_theory"]
    assert s["forcing_frequency"] == w1
    for name in ("trajectory.npz", "trajectory_without_tmd.npz"):
        d = np.load(out / name)
        tip = d["q"][:, 3]
        half = d["t"] >= d["t"][-1] / 2
        growth = np.abs(tip[half]).max() / np.abs(tip[~half]).max()
        if name == "trajectory.npz":
            assert growth < 1.1  # bounded
            assert np.abs(d["q"][:, 5]).max() > 3 * np.abs(tip).max()  # the absorber swings
        else:
            assert growth > 1.8  # resonance: the amplitude grows like t
        # the ledger closes to round-off of its largest term (the support's work)
        scale = max(np.abs(d[k]).max() for k in ("energy", "work_components", "dissipated"))
        assert np.abs(d["balance"]).max() < 1e-10 * scale


def test_feedback_decay_rate_against_the_characteristic_equation(tmp_path):
    """Velocity feedback k_p = 1 on the base: the first mode decays at the rate of the
    controlled bar's root (measured +0.4 % at T = 4), 140 times faster than without it (then
    only the material damping, within 3 %); the feedback takes energy out; without material
    damping the second mode would grow (spillover)."""
    code, out = _run(tmp_path, "--T", "4", "--no-plots", command="eld-control")
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["decay_rate_measured"] == pytest.approx(s["decay_rate_predicted"], rel=0.01)
    assert s["decay_rate_predicted"] == pytest.approx(0.46322, rel=1e-4)
    assert s["decay_rate_modal"] == pytest.approx(s["decay_rate_predicted"], rel=0.01)
    free = s["decay_rate_measured_uncontrolled"]
    assert free == pytest.approx(s["decay_rate_predicted_uncontrolled"], rel=0.03)
    assert s["decay_rate_measured"] > 100 * free
    assert s["frequency_measured"] == pytest.approx(s["frequency_predicted"], rel=2e-3)
    assert s["work_controller"] < 0 and s["mode2_rate_without_material_damping"] < 0
    assert s["mode2_rate"] > 0  # held by the bar's damping b
    d = np.load(out / "trajectory_uncontrolled.npz")
    assert d["z"].shape[1] == 0 and np.load(out / "trajectory.npz")["q"].shape[1] == 2
    # the discrete closed loop's roots: the bar's (P2 on 8 x 2 cells: 5e-8, s_2 2e-5), the pencil's
    # first-mode rate of the run within BDF2's error at tau = 0.005 (-8.6e-4 measured)
    discrete = s["decay_rate_predicted_discrete"]
    assert discrete == pytest.approx(s["decay_rate_predicted"], rel=1e-6)
    assert np.allclose(s["roots_discrete"], s["roots"], rtol=1e-4)
    assert s["decay_rate_measured_pencil"] == pytest.approx(discrete, rel=2e-3)
    assert s["decay_rate_pencil_error"] == pytest.approx(
        s["decay_rate_measured_pencil"] / discrete - 1, abs=1e-15
    )
    assert s["decay_rate_measured_pencil_uncontrolled"] == pytest.approx(
        s["decay_rate_predicted_discrete_uncontrolled"], rel=0.02
    )


def test_negative_gain_grows_at_the_predicted_negative_rate_and_the_ledger_closes(tmp_path):
    """k_p = -1 feeds energy in (a study of instability, accepted): the first mode grows at
    the controlled bar's root, the summary's decay rate negative (-0.455, measured within 1 %),
    the controller's work positive, and the ledger still closes to round-off of the largest
    energy (docs/coupling.md Sec. 18)."""
    code, out = _run(
        tmp_path, "--gain", "-1", "--T", "4", "--tau", "0.01", "--no-plots", command="eld-control"
    )
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["decay_rate_predicted"] == pytest.approx(-0.455078, rel=1e-4)
    assert s["decay_rate_measured"] == pytest.approx(s["decay_rate_predicted"], rel=0.01)
    assert s["decay_rate_error"] == pytest.approx(
        s["decay_rate_measured"] / s["decay_rate_predicted"] - 1, abs=1e-15
    )
    assert abs(s["decay_rate_error"]) < 0.01
    assert s["decay_rate_predicted_discrete"] == pytest.approx(-0.455078, rel=1e-4)
    assert s["decay_rate_measured_pencil"] == pytest.approx(-0.455078, rel=5e-3)
    assert s["energy_ratio"] > 20 and s["work_controller"] > 0
    d = np.load(out / "trajectory.npz")
    assert d["work_controllers"][-1] == pytest.approx(s["work_controller"])
    assert s["balance_max"] == np.abs(d["balance"]).max()
    assert s["balance_max_relative"] == pytest.approx(s["balance_max"] / d["energy"].max())
    assert s["balance_max_relative"] < 1e-13


def test_no_gain_and_no_damping_gives_no_relative_decay_error(tmp_path):
    """--gain 0 --b 0: the predicted rate is 0, the relative error undefined: null (a
    ZeroDivisionError's traceback before)."""
    code, out = _run(tmp_path, "--gain", "0", "--b", "0", *CONTROL_SHORT, command="eld-control")
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["decay_rate_predicted"] == 0 and s["decay_rate_error"] is None
    # the discrete loop's rate is 0 to round-off (1e-18 measured), no scale either
    assert abs(s["decay_rate_predicted_discrete"]) < 1e-12
    assert s["decay_rate_error_discrete"] is None and s["decay_rate_pencil_error"] is None
    assert s["balance_max_relative"] < 1e-13


def _same_npz(a, b):
    """Every array of two trajectory files equal (NaN where the other has NaN), the timings
    and the meta data (the number of sessions) aside."""

    def same(x, y):
        return np.array_equal(x, y, equal_nan=x.dtype.kind == "f")

    with np.load(a) as fa, np.load(b) as fb:
        keys = {k for k in fa.files if not is_timing_array(k) and k != "meta"}
        assert keys == {k for k in fb.files if not is_timing_array(k) and k != "meta"}
        bad = [k for k in sorted(keys) if not same(fa[k], fb[k])]
    assert not bad, f"differ: {bad}"


CONTROL_SHORT = ("--T", "0.5", "--tau", "0.01", "--no-plots")


def test_a_coupled_run_interrupted_then_resumed_equals_the_uninterrupted_run(
    tmp_path, capsys, signal_at_attempt
):
    """eld-control (two runs, one checkpoint): SIGINT in the second run writes what it has
    (status interrupted, exit 130, the checkpoint and 'rothe resume'); ``rothe resume OUT``
    completes it; both trajectories equal the uninterrupted run's bit for bit."""
    ref = tmp_path / "ref"
    argv = ["run", "eld-control", "--quiet", *CONTROL_SHORT]
    assert main([*argv, "--out", str(ref)]) == 0
    out = tmp_path / "out"
    # 50 steps per run: the second run's 20th step (it finishes: the signal is seen after it)
    signal_at_attempt(CoupledStepper, 70)
    code = main([*argv, "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 130 and f"rothe resume {out}" in err
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "interrupted" and s["resume"] == f"rothe resume {out}"
    assert s["accepted_steps"] == 50 and s["where"]["accepted_steps"] == 20
    assert np.load(out / "trajectory_uncontrolled.npz")["t"].size == 21
    assert load_checkpoint(out).status == "interrupted"
    signal_at_attempt(CoupledStepper, 10**9)
    assert main(["resume", str(out), "--quiet"]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "completed" and s["sessions"] == 2
    assert not (out / "checkpoint").exists()  # removed once the results are committed
    r = json.loads((ref / "summary.json").read_text())
    for key in ("decay_rate_measured", "decay_rate_measured_uncontrolled", "balance_max"):
        assert s[key] == r[key], key
    for name in ("trajectory.npz", "trajectory_uncontrolled.npz"):
        _same_npz(ref / name, out / name)


def test_two_bodies_with_an_adaptive_base_sigterm_then_resume(tmp_path, capsys, signal_at_attempt):
    """eld-two-bodies --adapt-space: SIGTERM (exit 143), then --resume: the meshes and the
    trajectory are the uninterrupted run's bit for bit."""
    argv = ["run", "eld-two-bodies", "--quiet", "--no-plots", "--T", "0.3", "--tau", "0.01"]
    argv += ["--n1", "2", "--degree", "1", "--adapt-space", "--space-tol", "2e-3"]
    ref = tmp_path / "ref"
    assert main([*argv, "--out", str(ref)]) == 0
    assert json.loads((ref / "summary.json").read_text())["adaptations"] >= 2
    out = tmp_path / "out"
    signal_at_attempt(CoupledStepper, 12, signal.SIGTERM)
    assert main([*argv, "--out", str(out)]) == 143
    s = json.loads((out / "summary.json").read_text())
    # the run that stopped has no series of meshes yet: its counts from the states' mesh ids
    assert s["status"] == "interrupted" and s["bisections"] is None and s["meshes"] >= 1
    assert s["ndofs"][0] == np.load(out / "trajectory.npz")["ndofs"][-1]
    signal_at_attempt(CoupledStepper, 10**9)
    capsys.readouterr()
    assert main([*argv, "--resume", str(out)]) == 0
    _same_npz(ref / "trajectory.npz", out / "trajectory.npz")


@pytest.mark.parametrize(
    "args, line",
    [
        (["--gain", "2"], "--gain 2 (checkpoint: 1)"),
        (["--scheme", "euler"], "--scheme euler (checkpoint: bdf2)"),
        (["--adapt-space", "--space-tol", "0.01"], "--adapt-space True (checkpoint: False)"),
    ],
)
def test_a_resume_with_other_options_is_refused_in_one_line(
    tmp_path, capsys, signal_at_attempt, args, line
):
    out = tmp_path / "out"
    argv = ["run", "eld-control", "--quiet", *CONTROL_SHORT]
    signal_at_attempt(CoupledStepper, 5)
    assert main([*argv, "--out", str(out)]) == 130
    capsys.readouterr()
    signal_at_attempt(CoupledStepper, 10**9)
    code = main([*argv, *args, "--resume", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert "the command line differs from the checkpoint's" in err[0] and line in err[0], err
    code = main(["run", "eld-tmd", "--quiet", *CONTROL_SHORT, "--resume", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert "the checkpoint is of 'rothe run eld-control', not 'rothe run eld-tmd'" in err[0]


@pytest.mark.parametrize(
    "command, args, line",
    [
        ("eld-tmd", ["--mass-ratio", "0"], "--mass-ratio: got 0, must be > 0"),
        ("eld-tmd", ["--forcing-ratio", "-1"], "--forcing-ratio: got -1, must be > 0"),
        ("eld-tmd", ["--b", "-0.1"], "--b: got -0.1, must be >= 0"),
        ("eld-tmd", ["--tau", "0.007"], "--tau: got 0.007, must divide T = 12 into equal steps"),
        ("eld-tmd", ["--E", "1", "--lam", "2"], "--E: got 1, must not be combined with --lam"),
        ("eld-control", ["--base-mass", "0"], "--base-mass: got 0, must be > 0"),
        # (named base_stiffness, control_problem's parameter, before)
        ("eld-control", ["--base-spring", "-1"], "--base-spring: got -1, must be >= 0"),
        ("eld-control", ["--kd", "-1"], "--kd: got -1, must be >= 0"),
        ("eld-control", ["--kd", "1", "--filter-time", "0"], "--filter-time: got 0, must be > 0"),
        ("eld-control", ["--n", "0"], "--n: got 0, must be an integer >= 1"),
        ("eld-control", ["--plane", "shell"], "--plane: got 'shell', must be one of"),
        # (issue 19, "a part also carrying ... data": eld-tmd named the API's couplings[1].part,
        # "is already coupled (couplings[0])"; eld-control ran, the sensor on the pushed end, the
        # predicted roots those of the feedback from the far end)
        (
            "eld-tmd",
            ["--base", "right", "--tip", "right"],
            "--tip: got 'right', must not be the base's part (the base and the tip are two ends)",
        ),
        (
            "eld-control",
            ["--base", "right", "--tip", "right"],
            "--tip: got 'right', must not be the base's part (the base and the tip are two ends)",
        ),
    ],
)
def test_tmd_and_control_refusals_are_one_line(tmp_path, capsys, command, args, line):
    code, out = _run(tmp_path, *args, command=command)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("rothe: error: " + line), err
    assert not out.exists()


# -- --mesh FILE on eld-tmd and eld-control: the strip as a gmsh file reproduces the strip's run --


@pytest.mark.parametrize(
    "command, nx, ny, height, tau",
    [("eld-tmd", 20, 2, 0.1, "0.02"), ("eld-control", 8, 2, 0.25, "0.01")],
)
def test_a_gmsh_file_of_the_strip_is_the_built_in_run(tmp_path, command, nx, ny, height, tau):
    """The built-in strip written as a gmsh file (meshio) with the parts 'inlet' (x = 0) and
    'outlet' (x = L) as --base and --tip: the same modes (the plate's centre and length, the
    sensor point from the tip's facets; L, H from the mesh), the same run: q and the base's
    reaction equal to round-off of the modal analysis (measured 5e-10 of max |q|)."""
    mesh = write_gmsh_body(tmp_path / "strip.msh", nx=nx, ny=ny, length=1.0, height=height)
    common = ("--T", "0.4", "--tau", tau)
    code, grid = _run(tmp_path / "grid", *common, command=command)
    assert code == 0
    code, file = _run(
        tmp_path / "file", *common, "--mesh", str(mesh), "--base", "inlet", "--tip", "outlet",
        command=command,
    )  # fmt: skip
    assert code == 0
    for name in (
        "trajectory.npz",
        f"trajectory_{'without_tmd' if command == 'eld-tmd' else 'uncontrolled'}.npz",
    ):
        a, b = np.load(grid / name), np.load(file / name)
        assert np.abs(a["q"] - b["q"]).max() < 1e-8 * np.abs(a["q"]).max()
        scale = np.abs(a["reaction_left"]).max()
        assert scale > 0 and np.abs(a["reaction_left"] - b["reaction_inlet"]).max() < 1e-8 * scale
    s = json.loads((file / "summary.json").read_text())
    assert (s["mesh_cells"], s["dim"], s["base"], s["tip"]) == (2 * nx * ny, 2, "inlet", "outlet")
    assert s["length"] == 1.0 and s["height"] == pytest.approx(height, rel=1e-14)
    assert "n" not in s


def _same_run_in_another_frame(tmp_path, command, tau, mesh, moved, axis, order, sign):
    """``command`` on ``mesh`` (along x) and on ``moved`` (the same body along ``axis``): the
    second run's q, its components reordered by ``order`` and multiplied by ``sign``, equal to
    the first's to 1e-8 of its maximum (the modal analyses differ in the last digits; a
    mode's sign is free); the predicted rate, frequencies and amplitudes to 1e-8. Returns both
    summaries."""
    common = ("--T", "0.4", "--tau", tau, "--base", "inlet", "--tip", "outlet")
    code, along_x = _run(tmp_path / "x", *common, "--mesh", str(mesh), command=command)
    assert code == 0
    code, along = _run(
        tmp_path / axis, *common, "--mesh", str(moved), "--axis", axis, command=command
    )
    assert code == 0
    a, b = np.load(along_x / "trajectory.npz")["q"], np.load(along / "trajectory.npz")["q"]
    b = b[:, order] * sign
    b = b * np.sign(b[0] @ a[0]) if np.abs(a[0]).max() > 0 else b
    assert np.abs(a).max() > 0 and np.abs(a - b).max() < 1e-8 * np.abs(a).max()
    sa, sb = (json.loads((d / "summary.json").read_text()) for d in (along_x, along))
    assert sb["axis"] == axis and sb["length"] == 1.0
    for key in ("decay_rate_predicted", "frequency_first", "frequency_first_bending",
                "tip_amplitude_max", "base_reaction_max"):  # fmt: skip
        if key in sa:
            assert sb[key] == pytest.approx(sa[key], rel=1e-8), key
    return sa, sb


def _swap_xy(path, out):
    """The gmsh file ``path`` reflected in y = x (x and y swapped, the triangles reversed to
    keep their orientation), written to ``out``."""
    m = meshio.read(path)
    p = m.points.copy()
    p[:, [0, 1]] = p[:, [1, 0]]
    cells = [(c.type, c.data[:, ::-1] if c.type == "triangle" else c.data) for c in m.cells]
    meshio.Mesh(p, cells, cell_data=m.cell_data, field_data=m.field_data).write(
        out, file_format="gmsh22", binary=False
    )
    return out


@pytest.mark.parametrize(
    "command, nx, height, tau, swap, sign",
    [
        # q = (base x, y; plate a_x, a_y, theta, absorber): x <-> y, theta -> -theta
        ("eld-tmd", 20, 0.1, "0.02", [1, 0, 3, 2, 4, 5], [1, 1, 1, 1, -1, 1]),
        ("eld-control", 8, 0.25, "0.01", [1, 0], [1, 1]),
    ],
)
def test_axis_y_on_the_reflected_strip_is_the_strip_run(
    tmp_path, command, nx, height, tau, swap, sign
):
    """--axis y on the strip reflected in y = x (a body along y): the support/base pushed and
    measured in the reflected directions, the same run with x and y swapped (the plate's
    rotation changes sign): q to 1e-8 of its maximum (the modal analyses differ in the 10th
    digit); the same predicted rate, frequencies and amplitudes."""
    mesh = write_gmsh_body(tmp_path / "x.msh", nx=nx, ny=2, length=1.0, height=height)
    sa, sb = _same_run_in_another_frame(
        tmp_path, command, tau, mesh, _swap_xy(mesh, tmp_path / "y.msh"), "y", swap, sign
    )
    # (absorber_amplitude_max read the plate's theta along y before branch tmd3d19)
    if command == "eld-tmd":
        assert sb["absorber_amplitude_max"] == pytest.approx(sa["absorber_amplitude_max"], rel=1e-8)


@pytest.mark.parametrize("command", ["eld-tmd", "eld-control"])
@pytest.mark.parametrize(
    "args, line",
    [
        (["--mesh", "{two}", "--base", "inlet", "--tip", "top"],
         "--tip: got 'top', must be one of inlet, outlet, wall (boundary parts of the mesh)"),
        (["--mesh", "{two}"],
         "--base: got 'left', must be one of inlet, outlet, wall (boundary parts of the mesh)"),
        (["--base", "nope"],
         "--base: got 'nope', must be one of bottom, left, right, top (boundary parts of the "
         "mesh)"),
        (["--mesh", "{two}", "--base", "inlet", "--tip", "outlet", "--height", "0.5"],
         "--height: got 0.5, cannot be combined with --mesh (the mesh fixes the body)"),
        (["--mesh", "{two}", "--base", "inlet", "--tip", "outlet", "--material", "a:E=1,nu=0",
          "--region", "a=core,mantle"],
         "--region: got 'mantle', must be one of the mesh's subdomains: core, shell"),
        (["--mesh", "{two}", "--base", "inlet", "--tip", "outlet", "--material", "core:E=1,nu=0"],
         "--material: got 32 of 64 cells in no region with a material (the first at"),
        (["--mesh", "{two}", "--material", "a:E=1,nu=0", "--E", "2"],
         "--E: got 2, must not be combined with --material"),
        (["--material", "a:E=1,nu=0"], "--material: got 'a:E=1,nu=0', is used with --mesh only"),
        (["--mesh", "{two}", "--base", "inlet", "--tip", "outlet", "--axis", "z"],
         "--axis: got 'z', needs a 3D --mesh (got a 2D mesh: 45 nodes, 64 triangles)"),
        (["--region", "a=core"], "--region: got 'a=core', is used with --mesh only"),
        (["--axis", "y"], "--axis: got 'y', needs --mesh (the built-in strip lies along x)"),
        (["--axis", "z"], "--axis: got 'z', needs --mesh (the built-in strip lies along x)"),
        (["--axis", "w"], "--axis: got 'w', must be one of x, y, z"),
    ],
)  # fmt: skip
def test_tmd_and_control_mesh_refusals_are_one_line(tmp_path, capsys, command, args, line):
    files = {
        "command": command,
        "two": write_gmsh_body(tmp_path / "two.msh", nx=8, ny=4, split=1.0),
    }
    code, out = _run(tmp_path, *[a.format(**files) for a in args], command=command)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith("rothe: error: " + line.format(**files)), err
    assert not (out / "summary.json").exists()


# -- several materials on eld-tmd and eld-control (issue 19; refused before: "--material: got
# 'a:E=1,nu=0', is not taken by eld-tmd (one material ...)") -----------------------------------

#: the strips of the --mesh tests as gmsh files with the cell groups 'core' (x < 1/2), 'shell'
_STRIPS = {"eld-tmd": (20, 0.1, "0.02", 1e4), "eld-control": (8, 0.25, "0.01", 100.0)}


def _two_regions(tmp_path, command, *materials, T="0.4", plots=False):
    nx, height, tau, _ = _STRIPS[command]
    mesh = write_gmsh_body(tmp_path / "two.msh", nx=nx, ny=2, length=1.0, height=height, split=0.5)
    args = ["--mesh", mesh, "--base", "inlet", "--tip", "outlet", "--T", T, "--tau", tau]
    code, out = _run(tmp_path / "-".join(materials or ("one",)), *map(str, args), *materials,
                     command=command, plots=plots)  # fmt: skip
    assert code == 0
    return out


@pytest.mark.parametrize("command", ["eld-tmd", "eld-control"])
def test_two_regions_of_one_material_are_the_one_material_run(tmp_path, command):
    """--material a --material b with equal constants on the regions core and shell: the
    PiecewiseMaterial's per-cell K and M are the single material's, so both runs (q, the body's
    u at the kept states, the base's reaction) equal the --E/--nu run to round-off (measured:
    bit for bit); the summary lists the materials by region, the uniform strip's predictions
    are null with the reason (they need one E and rho)."""
    E = _STRIPS[command][3]
    T = "0.4" if command == "eld-tmd" else "4"  # (eld-control: 3 maxima for the decay rate)
    one = _two_regions(tmp_path, command, "--E", str(E), "--nu", "0", T=T)
    two = _two_regions(
        tmp_path, command, f"--material=a:E={E},nu=0", f"--material=b:E={E},nu=0",
        "--region=a=core", "--region=b=shell", T=T,
    )  # fmt: skip
    second = "trajectory_without_tmd.npz" if command == "eld-tmd" else "trajectory_uncontrolled.npz"
    for name in ("trajectory.npz", second):
        a, b = np.load(one / name), np.load(two / name)
        for key in ("q", "u", "reaction_inlet"):
            scale = np.abs(a[key]).max()
            assert scale > 0 and np.abs(a[key] - b[key]).max() <= 1e-12 * scale, (name, key)
    s1, s2 = (json.loads((d / "summary.json").read_text()) for d in (one, two))
    assert s2["material"]["regions"] == {"core": "a", "shell": "b"}
    assert s2["prediction"].startswith("n/a: several materials")
    if command == "eld-tmd":
        assert s2["frequency_first_bending"] == pytest.approx(s1["frequency_first_bending"], 1e-12)
        assert s2["frequency_beam_theory"] is None and s1["frequency_beam_theory"] > 10
        assert s2["amplitude_reduction"] == pytest.approx(s1["amplitude_reduction"], rel=1e-12)
    else:
        assert s2["decay_rate_measured"] == pytest.approx(s1["decay_rate_measured"], rel=1e-12)
        assert s2["decay_rate_predicted"] is None and s2["decay_rate_error"] is None
        assert s2["roots"] == [[None, None], [None, None]] and s2["mode2_rate"] is None
        assert s1["decay_rate_predicted"] == pytest.approx(0.4632, rel=1e-3)
        # the discrete closed loop's roots are defined for both, the same to round-off
        assert np.allclose(s2["roots_discrete"], s1["roots_discrete"], rtol=1e-10)
        assert s2["decay_rate_error_discrete"] == pytest.approx(s1["decay_rate_error_discrete"])


def test_tmd_with_two_materials_tunes_and_sizes_by_the_body_as_built(tmp_path):
    """A stiffer, heavier half (E 3x, rho 2x at x > 1/2): the support sized by the clamped
    body's discrete frequency w_c (the beam formula needs one E and rho), the absorber tuned to
    the discrete first bending mode of the body as built -- both lower than the uniform strip's
    (the tip half weighs twice as much for 3x the stiffness); the absorber still reduces the
    resonant amplitude, the ledgers close."""
    out = _two_regions(
        tmp_path, "eld-tmd", "--material=a:E=1e4,nu=0", "--material=b:E=3e4,nu=0,rho=2",
        "--region=a=core", "--region=b=shell", T="6",
    )  # fmt: skip
    s = json.loads((out / "summary.json").read_text())
    assert s["frequency_beam_theory"] is None and s["prediction"].startswith("n/a")
    assert 6.5 < s["frequency_first_bending"] < 7.1 and 7.1 < s["frequency_clamped"] < 7.6
    assert s["absorber_stiffness"] == pytest.approx(
        s["absorber_mass"] * (s["frequency_first_bending"] / 1.05) ** 2, rel=1e-12
    )  # (Den Hartog: w_a = w_1 / (1 + mu))
    assert s["amplitude_reduction"] > 2
    for name in ("trajectory.npz", "trajectory_without_tmd.npz"):
        # the ledger closes to round-off of its largest term (the support's work)
        d = np.load(out / name)
        scale = max(np.abs(d[k]).max() for k in ("energy", "work_components", "dissipated"))
        assert np.abs(d["balance"]).max() < 1e-10 * scale


def test_control_with_two_materials_measures_the_decay_against_the_discrete_loop(tmp_path):
    """Two materials (E 3x, rho 2x at x > 1/2): the decay rates of both runs measured (the
    feedback damps the first mode > 50x faster than the material damping alone), the
    predictions of the uniform bar null with the reason; the discrete closed loop's root
    predicts the rate (0.41750; the run's pencil within 0.5 %, the maxima within 2 %: -0.3 %
    and -0.8 % measured at tau = 0.01); the ledgers close."""
    out = _two_regions(
        tmp_path, "eld-control", "--material=a:E=100,nu=0", "--material=b:E=300,nu=0,rho=2",
        "--region=a=core", "--region=b=shell", T="4", plots=True,
    )  # fmt: skip
    assert (out / "fig_control.png").stat().st_size > 0
    s = json.loads((out / "summary.json").read_text())
    assert s["prediction"].startswith("n/a: several materials")
    for key in ("decay_rate_predicted", "decay_rate_error", "decay_rate_modal",
                "decay_rate_predicted_uncontrolled", "frequency_predicted", "mode2_rate",
                "mode2_rate_without_material_damping"):  # fmt: skip
        assert s[key] is None, key
    assert 0.3 < s["decay_rate_measured"] and 0 < s["decay_rate_measured_uncontrolled"] < 0.02
    assert s["decay_rate_measured"] > 50 * s["decay_rate_measured_uncontrolled"]
    discrete = s["decay_rate_predicted_discrete"]
    assert discrete == pytest.approx(0.41750, rel=1e-4)
    assert s["frequency_predicted_discrete"] == pytest.approx(5.8125, rel=1e-4)
    assert abs(s["decay_rate_pencil_error"]) < 0.005 and abs(s["decay_rate_error_discrete"]) < 0.02
    assert s["decay_rate_measured_pencil_uncontrolled"] == pytest.approx(
        s["decay_rate_predicted_discrete_uncontrolled"], rel=0.05
    )
    assert s["mode2_rate_discrete"] > 0  # (held by b, as for one material)
    assert s["frequency_measured"] == pytest.approx(s["frequency_first"], rel=0.02)
    assert s["material"]["materials"]["b"]["rho"] == 2.0
    for suffix in ("", "_uncontrolled"):
        assert s[f"balance_max{suffix}"] < 1e-13


# -- eld-tmd and eld-control on 3D bodies (refused before: "--mesh: got a 3D mesh (...), must be
# 2D") -------------------------------------------------------------------------------------------


def _bar_3d(tmp_path, name, nx, height):
    """The 3D bar [0, 1] x [0, height]^2 of nx x 1 x 1 cubes (6 tetrahedra each) as a gmsh
    file with the parts 'inlet' (x = 0), 'outlet' (x = 1) and 'wall'."""
    return write_gmsh_body(tmp_path / name, dim=3, nx=nx, ny=1, length=1.0, height=height)


def test_tmd_on_a_3d_bar_reduces_the_tip_amplitude(tmp_path):
    """eld-tmd on the 3D bar 1 x 0.1 x 0.1 (8 cubes, P2, 459 unknowns) along x, pushed and
    damped along y (--direction's default): both runs' ledgers close to round-off, the plate
    stays on the tip (B u = G(q) to round-off), and the absorber tuned to the discrete first
    bending mode cuts the resonant tip amplitude (measured 2.64 at T = 4, tau = 0.02)."""
    mesh = _bar_3d(tmp_path, "bar.msh", 8, 0.1)
    code, out = _run(
        tmp_path, "--T", "4", "--tau", "0.02", "--mesh", str(mesh), "--base", "inlet",
        "--tip", "outlet", command="eld-tmd",
    )  # fmt: skip
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert (s["dim"], s["axis"], s["direction"], s["ndofs"]) == (3, "x", "y", 459)
    assert s["length"] == 1.0 and s["area"] == pytest.approx(0.01, rel=1e-12)
    assert "height" not in s and s["material"]["plane"] == "strain"
    assert s["frequency_beam_theory"] is None and s["prediction"].startswith("n/a: a 3D body")
    assert 9.0 < s["frequency_first_bending"] < s["frequency_clamped"] < 10.2
    assert s["amplitude_reduction"] > 2.0 and s["amplitude_reduction_last"] > 2.0
    assert s["reaction_reduction"] > 1.5
    assert max(s["balance_max"], s["balance_max_without_tmd"]) < 1e-15  # (energies ~1e-5)
    for name in ("trajectory.npz", "trajectory_without_tmd.npz"):
        data = np.load(out / name)
        assert np.abs(data["constraint"]).max() < 1e-15
        assert data["reaction_inlet"].shape == (201, 3)
    q = np.load(out / "trajectory.npz")["q"]  # base (3), plate a, theta (3 + 3), absorber s
    assert q.shape == (201, 10)
    assert s["absorber_amplitude_max"] == float(np.abs(q[:, 9]).max())
    # the plate's a_z: the tetrahedra's split of the cubes is not symmetric in y and z, which
    # couples the two bending axes weakly (measured 1.2 % of a_y)
    assert np.abs(q[:, 5]).max() < 0.03 * np.abs(q[:, 4]).max()


def test_control_on_a_3d_bar_decays_at_the_discrete_rate(tmp_path):
    """eld-control on the 3D bar 1 x 0.25 x 0.25 (4 cubes, P2, nu = 0): the feedback damps the
    first axial mode at the discrete closed loop's rate (measured 3.1e-4 apart at tau = 0.005;
    the uniform bar's roots with A = volume / L hold in 3D: 3.1e-4 too)."""
    mesh = _bar_3d(tmp_path, "bar.msh", 4, 0.25)
    code, out = _run(
        tmp_path, "--T", "4", "--tau", "0.005", "--mesh", str(mesh), "--base", "inlet",
        "--tip", "outlet", command="eld-control",
    )  # fmt: skip
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert (s["dim"], s["axis"], s["ndofs"]) == (3, "x", 243)
    assert s["area"] == pytest.approx(0.0625, rel=1e-12)
    assert abs(s["decay_rate_error_discrete"]) < 0.01
    assert abs(s["decay_rate_error"]) < 0.01
    assert s["decay_rate_measured"] > 100 * s["decay_rate_measured_uncontrolled"] > 0
    assert s["balance_max"] < 1e-15
    assert np.load(out / "trajectory.npz")["q"].shape == (801, 3)


def _rotate_xyz(path, out):
    """The 3D gmsh file ``path`` turned so that x goes to z (x, y, z) -> (y, z, x): a cyclic
    permutation, a rotation, so the tetrahedra keep their orientation; written to ``out``."""
    m = meshio.read(path)
    p = m.points[:, [1, 2, 0]]
    meshio.Mesh(p, m.cells, cell_data=m.cell_data, field_data=m.field_data).write(
        out, file_format="gmsh22", binary=False
    )
    return out


@pytest.mark.parametrize(
    "command, nx, height, tau, back",
    [
        # q = (base a; plate a, theta, s), each vector (x, y, z) of the turned run = (y, z, x)
        ("eld-tmd", 8, 0.1, "0.02", [2, 0, 1, 5, 3, 4, 8, 6, 7, 9]),
        ("eld-control", 4, 0.25, "0.01", [2, 0, 1]),
    ],
)
def test_axis_z_on_the_turned_bar_is_the_x_run(tmp_path, command, nx, height, tau, back):
    """--axis z on the 3D bar turned to lie along z: eld-tmd's default --direction is then x
    (the next after z), the turned y; the same run with the axes permuted, q to 1e-8 of its
    maximum (the modal analyses differ in the last digits), the same frequencies."""
    mesh = _bar_3d(tmp_path, "x.msh", nx, height)
    _, sb = _same_run_in_another_frame(
        tmp_path, command, tau, mesh, _rotate_xyz(mesh, tmp_path / "z.msh"), "z", back, 1
    )
    if command == "eld-tmd":
        assert sb["direction"] == "x"


@pytest.mark.parametrize(
    "args, line",
    [
        (["--direction", "x"], "--direction: got 'x', must differ from --axis x (the absorber "
         "swings across the body)"),
        (["--direction", "z"], "--direction: got 'z', needs a 3D --mesh (got the built-in strip)"),
        (["--direction", "w"], "--direction: got 'w', must be one of x, y, z"),
        (["--mesh", "{bar}", "--base", "inlet", "--tip", "outlet", "--axis", "y",
          "--direction", "y"], "--direction: got 'y', must differ from --axis y"),
        (["--mesh", "{two}", "--base", "inlet", "--tip", "outlet", "--direction", "z"],
         "--direction: got 'z', needs a 3D --mesh (got a 2D mesh: 45 nodes, 64 triangles)"),
        (["--mesh", "{bar}", "--base", "inlet", "--tip", "outlet", "--plane", "stress"],
         "--plane: got 'stress', must be 'strain' (the default) in 3D"),
    ],
)  # fmt: skip
def test_tmd_direction_refusals_are_one_line(tmp_path, capsys, args, line):
    files = {
        "two": write_gmsh_body(tmp_path / "two.msh", nx=8, ny=4),
        "bar": _bar_3d(tmp_path, "bar.msh", 2, 0.5),
    }
    code, out = _run(tmp_path, *[a.format(**files) for a in args], command="eld-tmd")
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith("rothe: error: " + line), err
    assert not (out / "summary.json").exists()
