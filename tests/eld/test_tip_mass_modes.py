"""The tip-mass bar started in its first K axial modes (``tip_mass_problem(modes=K)``, issue
19): every excited frequency measured from the run's modal coordinates c_k = phi_k^T M x
converges to the semi-discrete one like tau^2 (BDF2's period error), K = 1 is the former
start bit for bit, and the modal coordinates separate the modes (the first mode's c_1 is the
same whether or not the others are excited)."""

import numpy as np
import pytest

from rothe.eld import BDF2, ImplicitEuler
from rothe.eld.coupled_run import run_coupled
from rothe.eld.coupled_step import coupled_modes
from rothe.eld.examples import tip_mass_problem
from rothe.eld.frequencies import modal_frequencies, pencil_frequencies
from rothe.eld.studies import fitted_rate
from rothe.errors import RotheInputError
from rothe.stepping.controllers import Uniform

TAUS = (0.005, 0.0025, 0.00125)


def _measured(example, tau, scheme=None):
    traj = run_coupled(
        example.system, scheme=scheme or BDF2(), control=Uniform(tau), watch=example.watch
    ).trajectory
    return traj, np.array(modal_frequencies(traj["t"], example.modal_coordinates(traj)))


def test_measured_frequencies_of_three_modes_converge_to_the_discrete_ones_like_tau_squared():
    """P2, 4 x 1 cells, T = 1 (about 1.4 periods of the first mode, 15 of the third): the
    run's w_k against the modal analysis' (8.6, 34.3, 64.4); measured orders 2.00, 1.97,
    1.92 and |w_run - w_h| / (w_h (w_h tau)^2) about 0.33, BDF2's period error."""
    example = tip_mass_problem(1, 2, modes=3, T=1.0)
    assert example.modes == 3 and example.discrete.size == 3
    w_h = example.discrete
    errors = np.array([np.abs(_measured(example, tau)[1] - w_h) for tau in TAUS])
    orders = [fitted_rate(TAUS, errors[:, k]) for k in range(3)]
    assert all(1.8 <= p <= 2.2 for p in orders), orders
    for tau, row in zip(TAUS, errors, strict=True):
        assert np.all(row < 0.4 * w_h * (w_h * tau) ** 2), (tau, row)
    # and against the analytic frequencies of the bar with the tip mass: the space error of
    # this coarse mesh (3e-3 for the third mode) is below the time error at these steps
    assert np.all(np.abs(example.discrete / example.analytic - 1) < 4e-3)


def test_one_mode_is_the_former_start_and_the_modes_are_separated():
    one = tip_mass_problem(1, 2, T=0.5)
    again = tip_mass_problem(1, 2, T=0.5, modes=1)
    # the former start (main before --modes): the first axial mode, its tip at the amplitude
    w, U, Q = coupled_modes(one.system, 16)
    axial = np.flatnonzero(np.abs(Q[0]) > 10 * np.abs(Q[1:]).max(axis=0))
    k = axial[0]
    q0 = one.system.components[0].q0
    assert np.array_equal(q0, Q[:, k] * (0.01 / abs(Q[0, k])))
    a, _ = _measured(one, 0.01)
    b, _ = _measured(again, 0.01)
    assert np.array_equal(a["q"], b["q"])
    # the sum of three modes: the tip starts at 3 amplitudes; the first modal coordinate is
    # the single mode's (the scheme steps each c_k on its own), to round-off
    three = tip_mass_problem(1, 2, T=0.5, modes=3)
    assert three.system.components[0].q0[0] == pytest.approx(3 * q0[0], rel=1e-12)
    c1 = one.modal_coordinates(a)[:, 0]
    c3 = three.modal_coordinates(_measured(three, 0.01)[0])
    assert np.abs(c3[:, 0] - c1).max() < 1e-10 * np.abs(c1).max()
    assert np.abs(c3[:, 1:]).max() > 0.3 * np.abs(c1).max()


@pytest.mark.parametrize(
    "modes, line",
    [
        (0, "modes: got 0, must be an integer >= 1"),
        (1.5, "modes: got 1.5, must be an integer"),
        (99, "modes: got 99, must be at most 5 (the axial modes among the first 16"),
    ],
)
def test_modes_refusals_name_the_parameter(modes, line):
    with pytest.raises(RotheInputError) as err:
        tip_mass_problem(1, 2, T=0.5, modes=modes)
    assert str(err.value).startswith(line), str(err.value)


def _scheme_frequency(scheme, w, tau):
    """arg z / tau of the root of the scheme on x' = i w x (the oscillator's first-order
    form): implicit Euler z = 1/(1 - i w tau); BDF2 the larger root of (3/2 - i w tau) z^2 -
    2 z + 1/2 = 0 (the other is parasitic)."""
    if isinstance(scheme, ImplicitEuler):
        return np.angle(1.0 / (1.0 - 1j * w * tau)) / tau
    roots = np.roots([1.5 - 1j * w * tau, -2.0, 0.5])
    return np.angle(roots[np.argmax(np.abs(roots))]) / tau


@pytest.mark.parametrize("scheme", [BDF2(), ImplicitEuler()], ids=["bdf2", "euler"])
def test_both_measurements_are_the_schemes_discrete_frequency(scheme):
    """The run of a linear scheme on uniform steps is, mode by mode, the scheme's recurrence:
    its frequency is arg z / tau of the scheme's root at w_h tau. The tip's q_x alone fitted by
    the matrix pencil finds it to round-off (1e-13 measured), the modal coordinates' zero
    crossings to their linear interpolation (1e-4 for Euler's third mode at tau = 0.01, damped
    by 1e-9 within T: measured 1.2e-4 at n = 2, T = 2)."""
    example = tip_mass_problem(1, 2, modes=3, T=1.0)
    tau = 0.01
    traj, modal = _measured(example, tau, scheme)
    exact = np.array([_scheme_frequency(scheme, w, tau) for w in example.discrete])
    tip = np.array(pencil_frequencies(traj["t"], np.asarray(traj["q"])[:, 0], 3))
    assert np.all(np.abs(tip / exact - 1) < 1e-10), tip / exact - 1
    assert np.all(np.abs(modal / exact - 1) < 3e-4), modal / exact - 1


def test_pencil_of_damped_cosines_and_its_refusals():
    t = np.linspace(0.0, 2.0, 401)
    y = np.exp(-0.3 * t) * np.cos(5.0 * t + 0.2) + 0.5 * np.cos(23.0 * t) + 1e-3 * np.cos(40 * t)
    assert pencil_frequencies(t, y, 2) == pytest.approx([5.0, 23.0], rel=1e-10)
    assert pencil_frequencies(t, y, 3) == pytest.approx([5.0, 23.0, 40.0], rel=1e-10)
    uneven = np.sort(np.r_[t[:-1], 0.00123])
    assert np.isnan(pencil_frequencies(uneven, np.cos(5 * uneven), 1)).all()  # adaptive steps
    assert np.isnan(pencil_frequencies(t[:5], y[:5], 1)).all()  # too short
    with pytest.raises(RotheInputError, match=r"^count: got 0, must be an integer >= 1"):
        pencil_frequencies(t, y, 0)
