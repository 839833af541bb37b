"""The controllers' states z in the adaptive error norm of coupled runs (issue 19, item 2;
rothe.eld.coupled_run, module docstring *Local error estimate*): the estimate reacts to z, a
run without controllers' states steps as before (the z part is skipped when there is no z:
checked once against main's code on 71 series of three adaptive runs with np.array_equal,
docs/coupling.md Sec. 11; not kept as a test of hard-coded bits, which another CPU or BLAS
may change in the last place)."""

from __future__ import annotations

import numpy as np
import pytest

from rothe.eld import (
    BDF2,
    DirichletData,
    ELDProblem,
    Material,
    RayleighDamping,
    run_coupled,
)
from rothe.eld.components import MassSpringDamper
from rothe.eld.control import LinearController, PointSensor
from rothe.eld.coupling import CoupledProblem, Translation
from rothe.stepping.controllers import Adaptive

from .test_coupled_resume import assert_same, interrupted
from .test_coupled_step import H, _shake, _shake_ddot, _shake_dot, _strip

pytestmark = pytest.mark.filterwarnings("ignore:G_d")

OMEGA = 100.0  # the oscillator controller's frequency: omega tau ~ 1 on the body's steps


def _tip_with_oscillator(T=0.3):
    """The shaken strip with its tip mass (tests.eld.test_coupled_step._shaken_tip) and a
    controller that is a free oscillator z' = omega [[0, 1], [-1, 0]] z, z(0) = (1, 0), with no
    input and no output: z = (cos omega t, -sin omega t) exactly while the body, which does not
    feel it, keeps the steps of a run without it."""
    mat = Material.from_young(100.0, 0.3, 1.0, dim=2, plane="stress")
    tip = MassSpringDamper(
        0.3, [30.0, 5.0], 0.2, name="tip", load=lambda t: np.array([0.0, -0.3 * np.sin(t)])
    )
    oscillator = LinearController(
        OMEGA * np.array([[0.0, 1.0], [-1.0, 0.0]]),
        np.zeros((2, 1)),
        np.zeros((1, 2)),
        np.zeros((1, 1)),
        PointSensor([0.5, H / 2], "velocity", axes=[0]),
        tip,
        directions=[[1.0], [0.0]],
        z0=[1.0, 0.0],
        name="oscillator",
    )
    problem = ELDProblem(
        _strip(6),
        mat,
        degree=1,
        damping=RayleighDamping(0.1, 0.002),
        dirichlet={"left": DirichletData(_shake, _shake_dot, _shake_ddot)},
        body_force=lambda t, x: np.stack([0 * x[0], -0.1 + 0 * x[0]]),
        T=T,
    )
    return CoupledProblem(problem, [tip], [Translation("right", tip)], [oscillator])


def test_the_estimate_reacts_to_a_fast_controller_state():
    """The oscillator's z error against the exact (cos, -sin) falls with tol at BDF2's rate
    10^(2/3) = 4.6 per decade (measured 0.246 at 1e-3, 0.054 at 1e-4; the local errors add up
    over ~200 and ~400 steps): the steps resolve omega. Without z in the norm the body's steps
    (omega tau up to 1.8) left 1.27 and 1.22 at both tolerances: BDF2 damps the unresolved
    oscillation, and nothing measured it."""
    errors = []
    for tol in (1e-3, 1e-4):
        tr = run_coupled(
            _tip_with_oscillator(), scheme=BDF2(), control=Adaptive(tol, tau=0.01)
        ).trajectory
        t, z = tr["t"], tr["z"]
        exact = np.column_stack([np.cos(OMEGA * t), -np.sin(OMEGA * t)])
        errors.append(np.abs(z - exact).max())
        assert tr["local_error"].max() <= tol
        assert OMEGA * tr["tau"].max() < 0.3  # the oscillator's steps, not the body's
    assert errors[0] < 0.3 and errors[1] < 0.07, errors
    assert errors[0] / errors[1] > 3.5, errors


def test_resume_keeps_the_z_scale_bit_for_bit(tmp_path, signal_at_attempt):
    """The running maximum Z_j is in the checkpoint: a run whose steps the oscillator's z sets,
    stopped thrice and resumed, equals the uninterrupted run (with Z_j taken from the state's
    |z| on resume instead, the last bits of the estimate and then the steps differ)."""
    options = dict(scheme=BDF2(), control=Adaptive(1e-3, tau=0.01))
    full = run_coupled(_tip_with_oscillator(T=0.1), **options)

    def make_run(**kw):
        return run_coupled(_tip_with_oscillator(T=0.1), **options, **kw)

    res = interrupted(make_run, signal_at_attempt, tmp_path / "c", attempts=(5, 9, 7))
    assert_same(full.trajectory, res.trajectory)
    assert res.trajectory.meta["sessions"] == 4
