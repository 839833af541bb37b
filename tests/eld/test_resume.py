"""Checkpoint and resume of elastodynamics runs with variable steps: adaptive BDF2 through the
Python API, through ``rothe run eld-mms`` + SIGINT + ``rothe resume``, and through kill -9 of a
real process + ``rothe resume``; each equal to the uninterrupted run bit for bit."""

from __future__ import annotations

import contextlib
import json
import random
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from rothe.eld import (
    BDF2,
    ELDStepper,
    ImplicitEuler,
    Original,
    Regularized,
    make_damping,
    mms_problem,
    run_eld,
)
from rothe.io.checkpoint import MAIN, CheckpointError, load_checkpoint
from rothe.stepping.controllers import Adaptive

from ..conftest import assert_same_trajectory, interrupted_thrice, run_cli

ROTHE = [sys.executable, "-m", "rothe.cli.main"]
#: adaptive BDF2 on the manufactured solution: 39 accepted and 3 rejected steps at n = 3
MMS_ADAPTIVE = [
    "run",
    "eld-mms",
    "--n",
    "3",
    "--scheme",
    "bdf2",
    "--control",
    "adaptive",
    "--tol",
    "1e-4",
    "--tau",
    "0.02",
    "--no-plots",
    "--quiet",
]


@pytest.mark.parametrize(
    "form, damping",
    [
        (Original(), "nonlinear"),
        (Regularized(lifting="harmonic"), "rayleigh"),
    ],
    ids=["original-nonlinear", "regularized-rayleigh-harmonic"],
)
def test_run_eld_adaptive_bdf2_interrupted_thrice_equals_the_uninterrupted_run(
    tmp_path, signal_at_attempt, form, damping
):
    p, _ = mms_problem(3, 2, damping=make_damping(damping, b=0.01, d0=0.5))
    results = []

    def make_run(**kw):
        results.append(run_eld(p, form=form, scheme=BDF2(), control=Adaptive(1e-4, tau=0.02), **kw))
        return results[-1].trajectory

    full = make_run()
    assert full.stats.rejected_steps > 0  # the controller's state matters
    resumed = interrupted_thrice(
        make_run, ELDStepper, signal_at_attempt, tmp_path / "c", attempts=(1, 12, 15)
    )
    assert_same_trajectory(full, resumed)
    assert resumed.meta["sessions"] == 4
    assert full.meta["linear_solver"] == resumed.meta["linear_solver"] | {
        "setup_seconds": full.meta["linear_solver"]["setup_seconds"]
    }
    assert full.meta["error_scale"] == resumed.meta["error_scale"]
    for name, w in results[0].state.fields.items():
        assert np.array_equal(w, results[-1].state.fields[name]), name


def _square(damping):
    import scipy.sparse as sp

    from rothe.eld import DirichletData, ELDProblem, Material, UserDamping
    from rothe.fem import mesh as meshes

    def zero(t, x):
        return np.zeros_like(x)

    c = {"one": 1.0, "two": 2.0}[damping]
    user = UserDamping(force=lambda v: c * v, jacobian=lambda v: c * sp.identity(v.size), d0=0.0)
    return ELDProblem(
        meshes.unit_square(2, named=True),
        Material(rho=1.0, lam=2.0, mu=1.0, dim=2),
        degree=1,
        damping=user,
        dirichlet={"left": DirichletData(zero, zero, zero)},
        v0=lambda x: np.stack([x[0], 0 * x[0]]),
        T=0.5,
    )


def test_run_eld_resume_refuses_other_arguments_and_another_damping(tmp_path):
    """A user's damping function is not in the problem's description: the fingerprint
    evaluates the damping force instead."""
    options = dict(scheme=BDF2(), control=Adaptive(1e-3, tau=0.05))
    d = tmp_path / "c"
    run_eld(_square("one"), checkpoint=d, **options)
    assert load_checkpoint(d).status == "completed"
    with pytest.raises(
        CheckpointError,
        match=r"the arguments differ from the checkpoint's: "
        r"tol = 0\.0001 \(checkpoint: 0\.001\)",
    ):
        run_eld(_square("one"), resume=d, **(options | {"control": Adaptive(1e-4, tau=0.05)}))
    with pytest.raises(CheckpointError, match=r"scheme = 'euler' \(checkpoint: 'bdf2'\)"):
        run_eld(_square("one"), resume=d, **(options | {"scheme": ImplicitEuler()}))
    with pytest.raises(
        CheckpointError,
        match=r"the problem differs from the checkpoint's "
        r"\(in: damping\); resume with the same problem",
    ):
        run_eld(_square("two"), resume=d, **options)


def _run(argv, capsys):
    return run_cli(capsys, *argv)


def test_eld_mms_adaptive_bdf2_sigint_then_resume_is_bit_identical(
    tmp_path, capsys, signal_at_attempt
):
    ref = tmp_path / "ref"
    assert _run(MMS_ADAPTIVE + ["--out", ref], capsys)[0] == 0
    out = tmp_path / "run"
    signal_at_attempt(ELDStepper, 20)
    code, _, err = _run(MMS_ADAPTIVE + ["--out", out], capsys)
    assert code == 130
    assert err.strip().startswith("rothe: interrupted by SIGINT after ")
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "interrupted" and 0 < s["accepted_steps"] < 20
    assert "error_u_l2" not in s  # errors at T only for a completed run
    with np.load(out / "trajectory.npz") as f:  # the result so far, with its mesh
        assert f["tau"].size == s["accepted_steps"] and f["u"].shape[0] == f["t"].size
        assert "nodes" in f.files
    assert load_checkpoint(out).status == "interrupted"
    signal_at_attempt(ELDStepper, 10**9)
    code, _, err = _run(["resume", out, "--quiet"], capsys)
    assert code == 0 and err == ""
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "completed" and s["sessions"] == 2
    r = json.loads((ref / "summary.json").read_text())
    for key in (
        "accepted_steps",
        "rejected_steps",
        "error_u_l2",
        "error_lam_l2_max",
        "balance_residual_max",
        "linear_factorizations",
        "backsolves",
    ):
        assert s[key] == r[key], key
    with np.load(ref / "trajectory.npz") as a, np.load(out / "trajectory.npz") as b:
        assert_same_trajectory(a, b)
    assert (ref / "mms.xdmf").read_text() == (out / "mms.xdmf").read_text()


def _wait_for_checkpoint(out, proc, min_steps: int, timeout: float = 120.0) -> dict:
    """Poll the run's checkpoint until it records at least ``min_steps`` accepted steps."""
    end = time.monotonic() + timeout
    while time.monotonic() < end and proc.poll() is None:
        with contextlib.suppress(CheckpointError):
            where = load_checkpoint(out, header_only=True).where
            if where.get("accepted_steps", 0) >= min_steps:
                return where
        time.sleep(0.01)
    return {}


def test_eld_kill_9_then_rothe_resume_is_bit_identical(tmp_path, capsys):
    """Two SIGKILLs of `rothe run eld-mms` (adaptive BDF2, ~190 steps) at random points after a
    checkpoint has recorded progress (fixed seed), each followed by `rothe resume`; the final
    trajectory equals the uninterrupted run's, computed in this process."""
    argv = [
        "run",
        "eld-mms",
        "--n",
        "3",
        "--scheme",
        "bdf2",
        "--control",
        "adaptive",
        "--tol",
        "1e-6",
        "--tau",
        "0.02",
        "--no-plots",
        "--quiet",
    ]
    ref = tmp_path / "ref"
    assert _run(argv + ["--out", ref], capsys)[0] == 0
    n_ref = json.loads((ref / "summary.json").read_text())["accepted_steps"]
    out = tmp_path / "run"
    rng = random.Random(20261124)
    proc = subprocess.Popen(
        ROTHE + argv + ["--out", str(out), "--checkpoint-every", "0.02"], cwd=tmp_path
    )
    log, kills, reached = [], 0, 0
    try:
        for _ in range(2):
            target = reached + rng.randint(10, n_ref // 3)
            where = _wait_for_checkpoint(out, proc, target)
            if proc.poll() is not None:
                break  # finished before the kill
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            kills += 1
            reached = where.get("accepted_steps", reached)
            log.append(f"kill after checkpoint at {where}")
            assert (out / "checkpoint" / MAIN).exists(), log
            proc = subprocess.Popen(ROTHE + ["resume", str(out), "--quiet"], cwd=tmp_path)
        assert proc.wait(timeout=300) == 0, log
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert kills == 2, log
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "completed" and s["sessions"] == 3, log
    with np.load(ref / "trajectory.npz") as a, np.load(out / "trajectory.npz") as b:
        assert_same_trajectory(a, b)
    assert not [p for p in out.iterdir() if p.name.startswith(".rothe-tmp")]
