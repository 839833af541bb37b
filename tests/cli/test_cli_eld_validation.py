"""Issue 10, item 5: ELD options validated where they enter (one line naming the option, exit 2).

Kept out of tests/eld (another branch owns it); the validations are the small functions at the
top of each ELD command's ``execute`` (rothe.cli.eld_commands) and in rothe.eld.studies.
"""

from __future__ import annotations

import pytest

from rothe.cli.main import main
from rothe.errors import RotheInputError


@pytest.mark.parametrize(
    "argv, line",
    [
        # OverflowError: cannot convert float infinity to integer
        (
            ["run", "eld-mms", "--tau", "1e-320"],
            "rothe: error: --tau: got 9.99989e-321, must be >= 1e-07 (at most 1e+07 steps of "
            "T = 1)",
        ),
        (
            ["run", "eld-beam", "--tau", "1e-320"],
            "rothe: error: --tau: got 9.99989e-321, must be >= 2e-07 (at most 1e+07 steps of "
            "T = 2)",
        ),
        # exited 0: --a is not read by the nonlinear damping
        (
            ["run", "eld-mms", "--a", "-1"],
            "rothe: error: --a: got -1, is not used by --damping nonlinear; --a is for --damping "
            "rayleigh",
        ),
        (
            ["run", "eld-beam", "--d0", "0.5"],  # the beam's default damping is rayleigh
            "rothe: error: --d0: got 0.5, is not used by --damping rayleigh; --d0 is for --damping "
            "nonlinear",
        ),
        (
            ["run", "eld-mms", "--damping", "none", "--b", "0.1"],
            "rothe: error: --b: got 0.1, is not used by --damping none; --b is for --damping "
            "nonlinear "
            "or rayleigh",
        ),
        # no bound: 2^60 steps
        (
            ["study", "eld-convergence", "--halvings", "60"],
            "rothe: error: --halvings: got 60, must be <= 16 (the finest run would take "
            "1.15e+19 steps "
            "of tau0/2^60; at most 1e+06)",
        ),
        (
            ["study", "eld-convergence", "--tau0", "1e-320"],
            "rothe: error: --tau0: got 9.99989e-321, must be >= 1e-07 (at most 1e+07 steps of "
            "T = 1)",
        ),
        # StopIteration
        (
            ["study", "eld-perturbation", "--targets", ""],
            "rothe: error: --targets: got '', must name at least one of G, G_dot, G_ddot, F",
        ),
        (
            ["study", "eld-perturbation", "--targets", "G,X"],
            "rothe: error: --targets: got 'X', must be one of G, G_dot, G_ddot, F",
        ),
        # ValueError: expected non-negative integer (numpy)
        (
            ["study", "eld-perturbation", "--seed", "-1"],
            "rothe: error: --seed: got -1, must be an integer >= 0",
        ),
        # RuntimeError: Factor is exactly singular
        (
            ["study", "eld-perturbation", "--delta", "1e300"],
            "rothe: error: --delta: got 1e+300, must be <= 1 (noise small against the data, "
            "which are "
            "of size about 1)",
        ),
        (
            ["study", "eld-coupled-perturbation", "--targets", "q,G"],
            "rothe: error: --targets: got 'G', must be one of q, q_dot, q_ddot",
        ),
        (
            ["study", "eld-coupled-perturbation", "--n", "0"],
            "rothe: error: --n: got 0, must be an integer >= 1",
        ),
        (
            ["study", "eld-tip-mass", "--ns", "0,2"],
            "rothe: error: --ns: got 0, must be an integer >= 1",
        ),
        (
            ["study", "eld-tip-mass", "--ns", "2", "--taus", "0.01"],
            "rothe: error: --ns: got '2', needs two meshes, or --taus two step sizes, to fit an "
            "order",
        ),
        (
            ["study", "eld-tip-mass", "--degree", "3"],
            "rothe: error: --degree: got 3, must be 1 or 2",
        ),
        (
            ["study", "eld-perturbation", "--taus", "1e-320,0.1"],
            "rothe: error: --taus: got 9.99989e-321, must be >= 1e-07 (at most 1e+07 steps of "
            "T = 1)",
        ),
    ],
)
def test_eld_bad_input_is_one_line_naming_the_option(tmp_path, capsys, argv, line):
    out = tmp_path / "o"
    code = main([*argv, "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.strip() == line and "Traceback" not in err
    assert not out.exists()  # refused before anything is written


def test_study_functions_validate_their_parameters():
    from rothe.eld.studies import convergence_study, perturbation_study

    with pytest.raises(RotheInputError, match=r"^halvings: got 40, must be <= 16 "):
        convergence_study(halvings=40)
    with pytest.raises(RotheInputError, match=r"^targets: got '', must name at least one of G, "):
        perturbation_study(targets=())
    with pytest.raises(RotheInputError, match=r"^seed: got -3, must be an integer >= 0$"):
        perturbation_study(seed=-3)
    with pytest.raises(RotheInputError, match=r"^delta: got 10, must be <= 1 "):
        perturbation_study(delta=10.0)
