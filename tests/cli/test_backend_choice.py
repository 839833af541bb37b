"""``rothe run eld-beam --backend auto`` (the default): which backend it takes, and when.

The choice itself needs no PETSc: petsc4py's presence and the launcher's process count are
replaced here; the runs that take the PETSc backend are in tests/mpi.
"""

from __future__ import annotations

import pytest

from rothe.cli.eld_commands import RunEldBeam
from rothe.cli.main import build_parser, parse_command
from rothe.fem import petsc_env


def _args(*extra):
    return parse_command(build_parser(), ["run", "eld-beam", *map(str, extra)])


@pytest.fixture
def one_process(monkeypatch):
    for name in petsc_env.LAUNCHER_SIZE_VARIABLES:
        monkeypatch.delenv(name, raising=False)


def _choice(*extra):
    args = _args(*extra)
    backend = RunEldBeam().validate(args)[-1]
    assert RunEldBeam.backend(args) == backend  # what execute runs
    return backend


def test_the_lu_limit_lies_between_n_12_and_13():
    from rothe.cli.eld_options import BEAM_LU_LIMIT, beam_unknowns

    assert beam_unknowns(12, 4.0, 1) == 3 * 49 * 13**2 <= BEAM_LU_LIMIT
    assert beam_unknowns(13, 4.0, 1) == 3 * 53 * 14**2 > BEAM_LU_LIMIT


@pytest.mark.parametrize(
    "extra,expected",
    [
        (["--n", "12", "--degree", "1"], "serial"),  # 24.8 k dofs: LU
        (["--n", "13", "--degree", "1"], "serial"),  # 31.2 k dofs: AMG
        (["--n", "16", "--degree", "1"], "serial"),  # 62 k dofs: AMG, pyamg
        (["--n", "4", "--degree", "1", "--solver", "amg"], "serial"),
        (["--n", "16", "--degree", "1", "--form", "original"], "serial"),
        (["--n", "16", "--degree", "1", "--adapt-space", "--space-tol", "1"], "serial"),
        (["--n", "16", "--degree", "1", "--backend", "serial"], "serial"),
        (["--n", "4", "--degree", "1", "--backend", "petsc"], "petsc"),
    ],
)
def test_auto_takes_serial_on_one_process(one_process, extra, expected):
    """On one process the serial pyamg step is faster than PETSc's GAMG (docs/scaling.md):
    auto takes serial there, whatever is installed (tests/mpi checks it where petsc4py is);
    --backend petsc is taken as given."""
    assert _choice(*extra) == expected


@pytest.mark.parametrize("variable", petsc_env.LAUNCHER_SIZE_VARIABLES)
def test_under_mpiexec_auto_is_petsc_and_refuses_adapt_space(monkeypatch, one_process, variable):
    monkeypatch.setenv(variable, "2")
    assert petsc_env.launched_processes() == 2
    # a small LU-sized beam too: N processes must share one mesh, not run it N times
    assert _choice("--n", "2", "--degree", "1") == "petsc"
    with pytest.raises(Exception, match=r"--adapt-space: got given, .* under mpiexec -n 2"):
        _choice("--n", "2", "--degree", "1", "--adapt-space", "--space-tol", 1)


def test_launched_processes_outside_a_launcher(monkeypatch, one_process):
    assert petsc_env.launched_processes() == 1
    monkeypatch.setenv("PMI_SIZE", "")  # set but empty: not a launcher's count
    assert petsc_env.launched_processes() == 1


def test_resume_follows_the_checkpoint_backend(monkeypatch, one_process, tmp_path, capsys):
    """A serial run's checkpoint resumes serially under auto even where petsc4py is installed
    (the PETSc backend would refuse it)."""
    from rothe.cli.main import main

    out = tmp_path / "o"
    argv = ["run", "eld-beam", "--n", "1", "--degree", "1", "--T", "0.02", "--quiet"]
    assert main([*argv, "--backend", "serial", "--out", str(out)]) == 0
    args = _args("--n", "1", "--degree", "1", "--T", "0.02", "--solver", "amg", "--resume", out)
    assert RunEldBeam.backend(args) == "serial"
    # a missing checkpoint: serial, and the session's own check names the problem
    args = _args("--n", "1", "--degree", "1", "--resume", tmp_path / "nothing")
    assert RunEldBeam.backend(args) == "serial"


def test_backend_name_is_checked(monkeypatch, one_process, capsys):
    from rothe.cli.main import main

    code = main(["run", "eld-beam", "--n", "1", "--backend", "mpi"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert err == ["rothe: error: --backend: got 'mpi', must be one of auto, serial, petsc"]


@pytest.mark.parametrize(
    "extra,line",
    [
        (
            ["--amg-products", "small"],
            "rothe: error: --amg-products: got 'small', must be one of fast, lean",
        ),
        (
            ["--amg-products", "lean", "--backend", "serial"],
            "rothe: error: --amg-products: got 'lean', is an option of the petsc backend "
            "(PETSc's GAMG); this run takes the serial backend (pyamg): use --backend petsc",
        ),
    ],
)
def test_amg_products_is_checked(monkeypatch, one_process, capsys, extra, line):
    from rothe.cli.main import main

    code = main(["run", "eld-beam", "--n", "1", *extra])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == [line]


def test_amg_products_on_the_serial_backend_is_refused():
    from rothe.eld import run_eld
    from rothe.eld.examples import beam_problem
    from rothe.errors import RotheInputError

    with pytest.raises(RotheInputError, match=r"^amg_products: got 'lean', is an option of"):
        run_eld(beam_problem(1, degree=1, T=0.02), amg_products="lean")
