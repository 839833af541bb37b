"""The PETSc backend on 1 and 2 processes (mpiexec), against the serial runs.

Each test starts ``mpiexec -n N python <script>`` (the scripts beside this file) and checks what
rank 0 prints; they skip, naming what is missing, where petsc4py/mpi4py or mpiexec cannot be
had (the default install: PETSc is the optional extra ``rothe[mpi]``, docs/scaling.md).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from rothe.errors import RotheInputError
from rothe.fem.petsc_env import petsc_available

HERE = Path(__file__).resolve().parent
SRC = HERE.parent.parent / "src"
MISSING = petsc_available()


def _mpiexec() -> str | None:
    local = Path(sys.executable).parent / "mpiexec"
    return str(local) if local.exists() else shutil.which("mpiexec")


needs_mpi = pytest.mark.skipif(
    MISSING is not None or _mpiexec() is None,
    reason=f"PETSc backend not available: {MISSING or 'no mpiexec'}",
)


def _env():
    return dict(
        os.environ,
        PYTHONPATH=str(SRC) + os.pathsep + os.environ.get("PYTHONPATH", ""),
        OMP_NUM_THREADS="1",
        OPENBLAS_NUM_THREADS="1",
    )


def _mpi(n: int, *args, cwd=None, check=True, timeout=600) -> subprocess.CompletedProcess:
    cmd = [_mpiexec(), "-n", str(n), sys.executable, *map(str, args)]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=_env(), cwd=cwd, timeout=timeout)
    if check and proc.returncode != 0:
        raise AssertionError(f"{' '.join(cmd)} exited {proc.returncode}:\n{proc.stderr[-3000:]}")
    return proc


def _json(proc) -> dict:
    return json.loads([ln for ln in proc.stdout.splitlines() if ln.startswith("{")][-1])


def _same_to_solver_tolerance(a, b) -> None:
    """Two runs whose solves are CG to rtol 1e-8 with different AMG hierarchies agree to the
    solver tolerance: u and lambda of every kept state in norm (the issue's measure), not entry
    by entry (an entry of u of 3e-6 differed by 1.4e-11, 4e-6 of itself), the reaction and the
    energy series entry by entry."""
    for key in ("u", "lam"):
        for k, (x, y) in enumerate(zip(b[key], a[key], strict=True)):
            assert np.linalg.norm(x - y) <= 1e-8 * np.linalg.norm(y), (key, k)
    for key in ("reaction_left", "energy"):
        np.testing.assert_allclose(b[key], a[key], rtol=1e-7, atol=1e-11, err_msg=key)


@needs_mpi
@pytest.mark.parametrize("degree", [1, 2])
def test_distributed_assembly_equals_serial(degree):
    got = _json(_mpi(2, HERE / "mpi_assembly.py", degree))
    assert got["M"] == 0.0 and got["K"] == 0.0  # the same element kernels, owned rows complete
    assert got["M_nnz"] == 0 and got["K_nnz"] == 0
    assert got["MG"] < 1e-15 and got["dofs"] == 0
    assert min(got["owned_sizes"]) > 0.4 * sum(got["owned_sizes"]) / 2  # balanced parts


@needs_mpi
@pytest.mark.parametrize("n,solver", [(1, "direct"), (2, "direct"), (2, "amg")])
def test_beam_equals_serial(n, solver):
    run = _json(_mpi(n, HERE / "mpi_run.py", solver))
    got = run["cases"]
    assert len(got) == 8
    if solver == "amg":  # every GAMG set-up let go of its products' data (coarse A, P): >= 2 levels
        assert run["released"] and min(run["released"]) >= 3, run["released"]
    else:
        assert run["released"] == []
    for case, r in got.items():
        assert r["steps"][0] == r["steps"][1], case
        assert r["reaction"] < 1e-6, (case, r)  # the target; measured ~1e-11
        assert r["u_energy"] < 1e-8, (case, r)
        assert r["balance"] < 1e-10, (case, r)
        assert r["tau"] < 1e-12, (case, r)  # adaptive: the same step sequence
        if case.startswith("nonlinear"):
            assert r["newton"][1] >= r["steps"][1] - 1, (case, r)  # Newton did iterate


@needs_mpi
def test_checkpoint_resume_and_signal_on_one_rank(tmp_path):
    ckpt = tmp_path / "ck"
    got = _json(_mpi(2, HERE / "mpi_resume.py", ckpt, "interrupt-then-resume"))
    assert got["interrupted"] is True
    assert got["steps_at_stop"] == 5  # both processes stopped after the same step
    assert all(got["equal"].values()), got["equal"]  # bit for bit after the resume
    other = _json(_mpi(1, HERE / "mpi_resume.py", ckpt, "resume"))
    assert other["refused"] is not None
    assert "written by 2 processes, this run has 1" in other["refused"]
    assert "\n" not in other["refused"]


@needs_mpi
def test_sigusr1_on_one_rank_writes_the_checkpoint_on_all(tmp_path):
    """SIGUSR1 reaches the last process only: every process writes the checkpoint at the same
    step boundary (the signal is agreed first, rothe.stepping.interrupt.agree) and the run goes
    on unchanged. Acting on its own flag, that process alone entered the checkpoint's gather
    and the job hung (also the race behind a SIGTERM that arrives during the agreement)."""
    proc = _mpi(2, HERE / "mpi_resume.py", tmp_path / "ck", "checkpoint-signal", timeout=240)
    got = _json(proc)
    assert got["equal"] is True  # the checkpoint changed nothing in the run
    notes = [ln for ln in proc.stderr.splitlines() if "SIGUSR1: checkpoint written" in ln]
    assert len(notes) == 1 and "after 6 accepted steps" in notes[0], proc.stderr[-2000:]


#: a small beam on the command line (P1, 2 cells across, 5 steps)
BEAM_ARGS = ["-m", "rothe.cli.main", "run", "eld-beam", "--n", "2", "--degree", "1"]
BEAM_ARGS += ["--T", "0.05", "--quiet"]


@needs_mpi
def test_cli_beam_petsc_writes_the_serial_files(tmp_path):
    args = BEAM_ARGS
    subprocess.run(
        [sys.executable, *args, "--backend", "serial", "--out", tmp_path / "s"],
        check=True,
        env=_env(),
        capture_output=True,
    )
    _mpi(2, *args, "--backend", "petsc", "--out", tmp_path / "p")
    a, b = np.load(tmp_path / "s" / "trajectory.npz"), np.load(tmp_path / "p" / "trajectory.npz")
    assert set(a.files) == set(b.files)
    for key in ("u", "v", "lam", "reaction_left", "energy", "nodes", "lam_dofs"):
        np.testing.assert_allclose(b[key], a[key], rtol=1e-8, atol=1e-12, err_msg=key)
    names = {p.name for p in (tmp_path / "p").iterdir()}
    assert {"beam.xdmf", "beam.h5", "beam_multiplier.xdmf", "summary.json"} <= names
    summary = json.loads((tmp_path / "p" / "summary.json").read_text())
    assert summary["processes"] == 2 and summary["status"] == "completed"


@needs_mpi
def test_cli_auto_takes_serial_on_one_process_where_petsc_is_installed(tmp_path):
    """Without --backend, an AMG run (here --solver amg) on one process, without mpiexec,
    takes the serial backend even where petsc4py is installed (its pyamg step is the faster
    one there, docs/scaling.md); --backend petsc on one process gives the same answer to the
    solver tolerance."""
    args = [*BEAM_ARGS, "--solver", "amg"]
    env = {k: v for k, v in _env().items() if k not in ("PMI_SIZE", "OMPI_COMM_WORLD_SIZE")}
    for out, extra in (("auto", []), ("petsc", ["--backend", "petsc"])):
        subprocess.run(
            [sys.executable, *args, *extra, "--out", tmp_path / out],
            check=True,
            env=env,
            capture_output=True,
        )
    auto = json.loads((tmp_path / "auto" / "summary.json").read_text())
    petsc = json.loads((tmp_path / "petsc" / "summary.json").read_text())
    assert auto["backend"] == "serial"
    assert petsc["backend"] == "petsc" and petsc["processes"] == 1
    a, b = (
        np.load(tmp_path / "auto" / "trajectory.npz"),
        np.load(tmp_path / "petsc" / "trajectory.npz"),
    )
    _same_to_solver_tolerance(a, b)


@needs_mpi
def test_cli_lean_amg_products_give_the_same_run(tmp_path):
    """--amg-products lean: GAMG's coarse operators by the all-at-once product (PETSc's -info
    logs no two-step PtAP, which the default logs on every level), the run equal to the
    default's to the solver tolerance, the choice in summary.json; the option is set for the
    set-up only (no 'option left' warning of PETSc at the end)."""
    # n = 10: a hierarchy with two distributed Galerkin products (n = 2 has one)
    args = [*BEAM_ARGS[:4], "--n", "10", *BEAM_ARGS[6:], "--backend", "petsc", "--solver", "amg"]
    logs = {}
    for products in ("fast", "lean"):
        env = dict(_env(), PETSC_OPTIONS="-info :mat")
        proc = subprocess.run(
            [_mpiexec(), "-n", "2", sys.executable, *args, "--amg-products", products]
            + ["--out", str(tmp_path / products)],
            capture_output=True,
            text=True,
            env=env,
            timeout=600,
        )
        assert proc.returncode == 0, proc.stderr[-2000:]
        logs[products] = proc.stdout + proc.stderr
        summary = json.loads((tmp_path / products / "summary.json").read_text())
        assert summary["amg_products"] == products and summary["processes"] == 2
    two_step = "[0] <mat:seqaij> MatPtAPSymbolic_MPIAIJ_MPIAIJ(): Nonscalable algorithm"
    default_products = logs["fast"].count(two_step)
    assert default_products >= 2  # the finest level's and a coarser one's
    assert logs["lean"].count(two_step) == 0
    assert "Option left" not in logs["lean"]
    a, b = (np.load(tmp_path / k / "trajectory.npz") for k in ("fast", "lean"))
    _same_to_solver_tolerance(a, b)


@needs_mpi
@pytest.mark.parametrize(
    "extra,says",
    [
        (["--adapt-space", "--space-tol", "1e-3"], "--adapt-space"),
        (["--backend", "mpi"], "--backend"),
    ],
)
def test_cli_refusals(tmp_path, extra, says):
    proc = _mpi(
        2,
        "-m",
        "rothe.cli.main",
        "run",
        "eld-beam",
        "--n",
        "2",
        "--degree",
        "1",
        "--backend",
        "petsc",
        "--out",
        tmp_path / "o",
        *extra,
        check=False,
    )
    assert proc.returncode == 2
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("rothe: error:")]
    assert lines and says in lines[0] and ("petsc" in lines[0] or "mpi" in lines[0])


def test_more_processes_than_the_mesh_allows():
    from rothe.fem import mesh as meshes
    from rothe.fem.distributed import Partition

    mesh = meshes.box(1, 1, 1)  # 8 vertices, 6 cells
    with pytest.raises(RotheInputError, match="processes: got 9, must be at most"):
        Partition(mesh, 1, SimpleNamespace(size=9, rank=0), 3)


@pytest.mark.skipif(
    MISSING is None, reason="petsc4py is installed here: the refusal is for installs without it"
)
def test_backend_petsc_without_petsc4py_is_one_line(tmp_path):
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "rothe.cli.main",
            "run",
            "eld-beam",
            "--n",
            "2",
            "--backend",
            "petsc",
            "--out",
            str(tmp_path / "o"),
        ],
        capture_output=True,
        text=True,
        env=_env(),
    )
    assert proc.returncode == 2
    err = proc.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("rothe: error: --backend petsc: needs")
    assert "pip install" in err[0]


@needs_mpi
def test_cli_sigterm_on_one_rank_then_resume(tmp_path):
    """SIGTERM to the last rank of a running command: every rank stops (exit 143) with the
    partial results; 'rothe resume' refuses 1 process and completes on 2."""
    import signal
    import time

    psutil = pytest.importorskip("psutil", reason="psutil finds the ranks of mpiexec")
    out = tmp_path / "o"
    cmd = [
        _mpiexec(),
        "-n",
        "2",
        sys.executable,
        "-m",
        "rothe.cli.main",
        "run",
        "eld-beam",
        "--backend",
        "petsc",
        "--n",
        "4",
        "--degree",
        "1",
        "--T",
        "8",
        "--quiet",
        "--out",
        str(out),
    ]
    proc = subprocess.Popen(
        cmd, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        deadline = time.monotonic() + 120
        while not (out / "checkpoint" / "checkpoint.npz").is_file():  # the start's checkpoint
            assert time.monotonic() < deadline and proc.poll() is None
            time.sleep(0.2)
        time.sleep(1.0)  # some steps
        ranks = [
            p
            for p in psutil.Process(proc.pid).children(recursive=True)
            if "rothe.cli.main" in " ".join(p.cmdline()) and "mpiexec" not in p.name()
        ]
        assert len(ranks) == 2
        max(ranks, key=lambda p: p.pid).send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 143, err[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["signal"] == "SIGTERM"
    assert 0 < summary["accepted_steps"] < 800
    one = subprocess.run(
        [
            _mpiexec(),
            "-n",
            "1",
            sys.executable,
            "-m",
            "rothe.cli.main",
            "resume",
            str(out),
            "--quiet",
        ],
        env=_env(),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert one.returncode == 2
    lines = [ln for ln in one.stderr.splitlines() if ln.startswith("rothe: error:")]
    assert len(lines) == 1 and "written by 2 processes, this run has 1" in lines[0]
    two = _mpi(2, "-m", "rothe.cli.main", "resume", out, "--quiet")
    assert two.returncode == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["accepted_steps"] == 800
    assert summary["sessions"] == 2


@needs_mpi
def test_lean_amg_products_on_one_process_set_up_petscs_default():
    """amg_products='lean' on one process: the products are sequential (they store no A P and
    PETSc's SeqAIJ knows no all-at-once algorithm: it refused '-matptap_via allatonce' with
    'Unknown option'), so the set-up is the default's and the run the default's, bit for bit."""
    from rothe.eld.examples import beam_problem
    from rothe.eld.run import run_eld

    problem = beam_problem(1, degree=1, T=0.02)
    runs = [
        run_eld(problem, backend="petsc", solver="amg", amg_products=products)
        for products in ("fast", "lean")
    ]
    a, b = (np.asarray(run.trajectory["reaction_left"]) for run in runs)
    assert a.shape[0] >= 2 and np.array_equal(a, b)
