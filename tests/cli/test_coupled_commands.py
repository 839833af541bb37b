"""``rothe run eld-tip-mass``: the outputs, the frequency measured from the run against the
transcendental equation, adaptive steps, help texts and one-line refusals (exit 2)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rothe.cli.coupled_commands import crossing_frequency
from rothe.cli.main import main


def _run(tmp_path, *args, plots=False):
    out = tmp_path / "out"
    argv = ["run", "eld-tip-mass", "--quiet", "--out", str(out), *args]
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
    ],
)
def test_bad_options_are_one_line_and_exit_2(tmp_path, capsys, args, line):
    code, out = _run(tmp_path, *args)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("rothe: error: " + line), err
    assert not (out / "summary.json").exists()
