"""The semi-discrete closed loop's roots (:func:`rothe.eld.closed_loop_roots`, issue 19's
eld-control for any material) against runs: the first mode's root measured by the matrix
pencil of the base's q(t) (:func:`rothe.eld.frequencies.pencil_roots`) tends to it as
tau -> 0 at the scheme's order (docs/coupling.md, Sec. 11, eld-control)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from rothe.eld import (
    BDF2,
    CoupledProblem,
    ImplicitEuler,
    LinearController,
    MassSpringDamper,
    Material,
    ReactionSensor,
    Translation,
    closed_loop_roots,
    coupled_modes,
    run_coupled,
)
from rothe.eld.damping import RayleighDamping
from rothe.eld.examples import control_problem, rectangle
from rothe.eld.frequencies import decay_rate, pencil_roots
from rothe.stepping.controllers import Uniform

BAR = Material.from_young(100.0, 0.0, 1.0, dim=2, plane="stress")


def _first_root(system, scheme, tau, w1):
    """The run's first-mode root: the pencil's exponent nearest i w_1, and the maxima's rate."""
    tr = run_coupled(system, scheme=scheme, control=Uniform(tau)).trajectory
    t, q = np.asarray(tr["t"]), np.asarray(tr["q"])[:, 0]
    found = np.asarray(pencil_roots(t, q, 3))
    return found[np.argmin(np.abs(found.imag - w1))], decay_rate(t, q)


def test_pencil_roots_of_a_sum_of_damped_modes():
    """y = sum a_k e^{s_k t} + c.c. sampled at equal steps: the exponents to round-off,
    ascending in frequency; NaN for unequal steps."""
    s = np.array([-0.4 + 6.2j, -0.1 + 17.4j, -5.0 + 45.0j])
    t = np.linspace(0.0, 2.0, 401)
    y = (np.array([1.0, 0.3, 0.05]) * np.exp(np.outer(t, s))).real.sum(axis=1)
    assert np.abs(np.array(pencil_roots(t, y, 3)) - s).max() < 1e-8
    assert np.isnan(pencil_roots(t**1.1, y, 3)).all()


def test_control_run_tends_to_the_discrete_root_at_the_schemes_order():
    """eld-control's bar (P2, 4 x 1 cells, T = 2): the pencil's first-mode rate of a run against
    the discrete closed loop's sigma_1 = 0.46322: BDF2 relative errors ~ -8.7e-4, -2.2e-4 at
    tau = 0.005, 0.0025 (tau^2); implicit Euler ~ +0.21, +0.10 (tau: its numerical damping
    w_1^2 tau / 2 = 0.097 at 0.005), the Richardson value 2 s(tau/2) - s(tau) within 1e-3.
    (T = 2 has two maxima only: the maxima's rate is the CLI tests', T = 4.)"""
    ex = control_problem(1, 2, T=2.0)
    s1 = ex.roots_discrete[0]
    rel = {}
    for scheme in (BDF2(), ImplicitEuler()):
        roots = [_first_root(ex.controlled, scheme, tau, s1.imag) for tau in (0.005, 0.0025)]
        rel[type(scheme).__name__] = [r.real / s1.real - 1 for r, _ in roots]
        if isinstance(scheme, ImplicitEuler):
            assert abs((2 * roots[1][0].real - roots[0][0].real) / s1.real - 1) < 1e-3
    bdf2, euler = rel["BDF2"], rel["ImplicitEuler"]
    assert abs(bdf2[0]) < 2e-3 and abs(bdf2[1]) < 5e-4 and 3 < bdf2[0] / bdf2[1] < 5
    assert 0.15 < euler[0] < 0.25 and 1.8 < euler[0] / euler[1] < 2.2


def test_closed_loop_roots_with_a_reaction_sensor_match_a_run():
    """A controller fed by the base's reaction (lambda, through Y_lam: the loop's mass matrix
    gets the acceleration terms -E D_c Y_a and -B_c Y_a) with a lag state: the first axial
    root predicted 0.0867 + 6.2378 i (the feedback destabilizes it; without it -0.0033 +
    6.2299 i); a BDF2 run's pencil root at tau = 0.0025 within 1e-3 of it (measured 1e-4)."""
    mesh = rectangle(4, 1, 1.0, 0.25)

    def build(feedback, q0=None, u0=None):
        base = MassSpringDamper(1.0, [50.0, 1e4], q0=q0, name="base")
        sensor = ReactionSensor("left", axes=[0])
        lag = LinearController([[-10.0]], [[10.0]], [[0.3]], [[-0.2]], sensor, base,
                               directions=[[1.0], [0.0]])  # fmt: skip
        return CoupledProblem.from_body(
            mesh, BAR, degree=2, damping=RayleighDamping(0.0, 0.005), components=[base],
            couplings=[Translation("left", base)], controllers=[lag] if feedback else [],
            u0=u0, T=2.0,
        )  # fmt: skip

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="G_d")
        w, U, Q = coupled_modes(build(False), 8)
        k = int(np.flatnonzero(np.abs(Q[0]) > 10 * np.abs(Q[1]))[0])
        scale = 0.01 / abs(Q[0, k])
        system = build(True, Q[:, k] * scale, U[:, k] * scale)
        free = closed_loop_roots(build(False), w[[k]], U[:, [k]], Q[:, [k]])[0]
        s1 = closed_loop_roots(system, w[[k]], U[:, [k]], Q[:, [k]])[0]
        measured, _ = _first_root(system, BDF2(), 0.0025, s1.imag)
    assert free.real == pytest.approx(-0.0032968, rel=1e-4)
    assert s1.real == pytest.approx(0.08672, rel=1e-3) and s1.imag == pytest.approx(
        6.2378, rel=1e-4
    )
    assert abs(measured - s1) < 1e-3


def test_closed_loop_roots_are_the_same_on_every_call():
    """Two calls on one system give the same roots bit for bit (ARPACK's random start vector
    made them differ in the 14th digit, so two runs of eld-control wrote different
    summary.json files)."""
    ex = control_problem(2, 2, T=0.1)
    first = ex.roots_discrete
    again = control_problem(2, 2, T=0.1).roots_discrete
    assert np.isfinite(first).all() and np.array_equal(first, again)
