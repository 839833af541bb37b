"""One convention for the material on every ``rothe run eld-*`` command: ``--E/--nu`` or
``--lam/--mu`` (one pair, the command's default pair where none is given), ``--rho``, and
``--plane strain|stress`` on the 2D commands; mixing the pairs is one line naming both."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.conftest import run_cli

RUNS = ("eld-mms", "eld-pulse", "eld-beam", "eld-tip-mass")


@pytest.mark.parametrize("command", RUNS)
def test_every_eld_run_takes_both_pairs_and_refuses_mixing_them(tmp_path, capsys, command):
    out = tmp_path / "out"
    code, _, err = run_cli(capsys, "run", command, "--E", "5", "--mu", "1", "--out", out)
    assert code == 2 and err.strip().splitlines() == [
        "rothe: error: --E: got 5, must not be combined with --mu: give --E, --nu or --lam, --mu"
    ]
    assert not out.exists()
    code, _, err = run_cli(capsys, "run", command, "--lam", "1", "--nu", "0.2", "--out", out)
    assert code == 2 and err.strip() == (
        "rothe: error: --nu: got 0.2, must not be combined with --lam: "
        "give --E, --nu or --lam, --mu"
    )
    code, help_text, _ = run_cli(capsys, "run", command, "--help")
    text = " ".join(help_text.split())
    assert code == 0 and all(f"--{k} {k.upper()}" in text for k in ("E", "nu", "lam", "mu", "rho"))
    assert ("--plane PLANE" in text) == (command != "eld-beam")  # 2D commands only


@pytest.mark.parametrize(
    "argv, line",
    [
        (["eld-pulse", "--plane", "shell"], "--plane: got 'shell', must be one of strain, stress"),
        (
            ["eld-beam", "--lam", "-400"],
            "--lam: got -400, must be > -2 mu / d = -256.41 (positive bulk modulus)",
        ),
        (["eld-tip-mass", "--E", "0"], "--E: got 0, must be > 0"),
        (["eld-mms", "--nu", "0.5"], "--nu: got 0.5, must satisfy -1 < nu < 0.5"),
        (
            ["eld-tip-mass", "--plane", "stress", "--lam", "-40"],
            "--lam: got -40, must be > -2 mu / 3 = -33.3333 for plane stress "
            "(an admissible 3D material)",
        ),
    ],
)
def test_bad_material_values_name_the_option(tmp_path, capsys, argv, line):
    code, _, err = run_cli(capsys, "run", *argv, "--out", tmp_path / "out")
    assert code == 2 and err.strip().splitlines() == ["rothe: error: " + line]


def _tip_mass(capsys, out, *args):
    code, _, _ = run_cli(
        capsys, "run", "eld-tip-mass", "--T", "0.2", "--tau", "0.01", "--quiet", "--no-plots",
        "--out", out, *args,
    )  # fmt: skip
    assert code == 0
    return json.loads((out / "summary.json").read_text()), np.load(out / "trajectory.npz")


def test_the_same_material_by_either_pair_gives_the_same_run(tmp_path, capsys):
    """eld-tip-mass's default E = 100, nu = 0 is lam = 0, mu = 50 exactly: the run with
    --lam 0 --mu 50 is the default run bit for bit; the summary states both pairs."""
    s0, d0 = _tip_mass(capsys, tmp_path / "young")
    s1, d1 = _tip_mass(capsys, tmp_path / "lame", "--lam", "0", "--mu", "50")
    assert all(np.array_equal(d0[k], d1[k]) for k in d0.files if not k.startswith("stats_"))
    for s in (s0, s1):
        assert (s["E"], s["nu"], s["lam"], s["mu"], s["plane"]) == (100, 0, 0, 50, "stress")
    assert s0["frequency_analytic"] == s1["frequency_analytic"]


def test_plane_strain_on_the_tip_mass_bar_takes_the_strip_modulus(tmp_path, capsys):
    """In plane strain the free strip's axial modulus is E/(1 - nu^2): the analytic frequency
    with --plane strain --nu 0.3 is that of --E 100/0.91 in plane stress, and the discrete
    coupled system agrees with it to Poisson's lateral inertia."""
    strain, _ = _tip_mass(capsys, tmp_path / "a", "--plane", "strain", "--nu", "0.3")
    stress, _ = _tip_mass(capsys, tmp_path / "b", "--E", str(100 / 0.91))
    assert strain["frequency_analytic"][0] == pytest.approx(stress["frequency_analytic"][0], 1e-12)
    # 0.7 % (the lateral inertia of Poisson's contraction); with E instead of E/(1 - nu^2):
    # 4.8 %
    assert abs(strain["frequency_error_discrete"][0]) < 1e-2
    assert strain["plane"] == "strain" and strain["nu"] == 0.3


def test_mms_in_plane_stress_stays_exact_in_space(tmp_path, capsys):
    """The manufactured body force, traction and multiplier follow the model's lam*: in plane
    stress (lam* = 2 lam mu/(lam + 2 mu) = 1 for lam = 2, mu = 1) P2 is still exact in space,
    the errors are the time discretization's, as in plane strain (with lam instead of lam*
    the data would not fit the solution: 9.4e-2 instead of 3.6e-4 here)."""
    errors = {}
    for plane in ("strain", "stress"):
        out = tmp_path / plane
        code, _, _ = run_cli(
            capsys, "run", "eld-mms", "--n", "2", "--scheme", "bdf2", "--tau", "0.01", "--T",
            "0.2", "--plane", plane, "--quiet", "--no-plots", "--out", out,
        )  # fmt: skip
        assert code == 0
        s = json.loads((out / "summary.json").read_text())
        errors[plane] = s["error_u_l2"]
        assert s["material"]["plane"] == plane
    assert errors["stress"] < 3 * errors["strain"] and errors["stress"] < 1e-3
