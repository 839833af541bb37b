"""The tip-mass bar started in its first K axial modes (``tip_mass_problem(modes=K)``, issue
19): every excited frequency measured from the run's modal coordinates c_k = phi_k^T M x
converges to the semi-discrete one like tau^2 (BDF2's period error), K = 1 is the former
start bit for bit, and the modal coordinates separate the modes (the first mode's c_1 is the
same whether or not the others are excited)."""

import numpy as np
import pytest

from rothe.eld import BDF2
from rothe.eld.coupled_run import run_coupled
from rothe.eld.coupled_step import coupled_modes
from rothe.eld.examples import tip_mass_problem
from rothe.eld.frequencies import modal_frequencies
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
