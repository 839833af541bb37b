"""The ELD state (rothe.eld.state): checkpoint round trips (bit for bit), the transfer interface
(mapped, adopt), the result codes."""

import copy

import numpy as np
import pytest
import scipy.sparse as sp

from rothe.eld import (
    BDF2,
    Differenced,
    ELDCode,
    Original,
    RayleighDamping,
    Regularized,
    mms_problem,
    prepare_eld_run,
    run_eld,
)
from rothe.errors import RotheInputError
from rothe.io.trajectory import Trajectory
from rothe.stepping.controllers import Adaptive, Given, Uniform
from rothe.stepping.evolve import evolve
from rothe.stepping.results import ResultCode

CASES = [
    ("euler, uniform, linear", dict(form=Regularized(), control=Uniform(0.05)), "rayleigh"),
    (
        "bdf2, uniform, nonlinear, original",
        dict(form=Original(), control=Uniform(0.05), scheme=BDF2()),
        "nonlinear",
    ),
    (
        "bdf2, adaptive, nonlinear",
        dict(form=Regularized(), control=Adaptive(1e-4, tau=0.02), scheme=BDF2()),
        "nonlinear",
    ),
    (
        "bdf2, given steps, differenced, harmonic",
        dict(
            form=Regularized("harmonic"),
            scheme=BDF2(),
            data=Differenced(),
            control=Given(np.r_[np.full(5, 0.05), np.full(10, 0.075)]),
        ),
        "rayleigh",
    ),
    (
        "euler, adaptive, linear",
        dict(form=Original(), control=Adaptive(1e-3, tau=0.05)),
        "rayleigh",
    ),
]


def _problem(kind):
    damping = RayleighDamping(0.1, 0.01) if kind == "rayleigh" else None
    return mms_problem(2, 2, damping=damping)[0]


def _run_until(run, k):
    """The prepared run's first k accepted steps (the evolve loop's ``max_steps``)."""
    return evolve(
        run.stepper, run.controller, run.state, run.trajectory, tau_min=run.tau_min, max_steps=k
    )


@pytest.mark.parametrize("label,options,damping", CASES, ids=[c[0] for c in CASES])
def test_checkpoint_round_trip_continues_bit_for_bit(label, options, damping):
    problem = _problem(damping)
    result = run_eld(problem, **options)
    full = result.trajectory
    k = 7
    run = prepare_eld_run(problem, **options)
    state = _run_until(run, k)
    assert state.j == k
    saved = copy.deepcopy(
        {
            "stepper": run.stepper.checkpoint_state(state),
            "controller": run.controller.checkpoint_state(),
        }
    )
    _plain(saved)
    fresh = prepare_eld_run(problem, **options)
    resumed = fresh.stepper.restore_state(saved["stepper"])
    fresh.controller.restore_state(saved["controller"])
    rest = Trajectory()
    final = evolve(fresh.stepper, fresh.controller, resumed, rest, tau_min=fresh.tau_min)
    for key in ("u", "v", "a", "lam", "kept_t"):
        assert np.array_equal(np.asarray(full[key])[k + 1 :], rest[key]), key
    for key in ("tau", "local_error", "energy", "balance_residual", "numerical_dissipation"):
        n_rest = len(rest[key])
        assert np.array_equal(full[key][-n_rest:], rest[key]), key
    for name, w in result.state.fields.items():
        assert np.array_equal(w, final.fields[name]), name


def _plain(data):
    """Only nested dicts/lists of arrays and Python scalars, str or None."""
    if isinstance(data, dict):
        for v in data.values():
            _plain(v)
    elif isinstance(data, list):
        for v in data:
            _plain(v)
    else:
        assert data is None or isinstance(data, (np.ndarray, float, int, bool, str)), type(data)


def test_restore_refuses_a_foreign_checkpoint():
    problem = _problem("rayleigh")
    run = prepare_eld_run(problem, scheme=BDF2(), control=Uniform(0.05))
    data = run.stepper.checkpoint_state(run.state)
    other = prepare_eld_run(problem, control=Uniform(0.05))
    with pytest.raises(
        RotheInputError,
        match=r"^checkpoint: got scheme 'bdf2', this run has "
        "'euler'",
    ):
        other.stepper.restore_state(data)
    with pytest.raises(
        RotheInputError,
        match=r"^checkpoint: got format 'rothe-eld-state-1', "
        r"must be 'rothe-eld-state-2'",
    ):
        other.stepper.restore_state(dict(data, format="rothe-eld-state-1"))


def test_transfer_interface_maps_every_history_vector_and_books_the_energy_change():
    """What space adaptivity does between steps: map the state, let the system adopt it."""
    problem = _problem("rayleigh")
    options = dict(form=Regularized(), control=Uniform(0.05), scheme=BDF2())
    full = run_eld(problem, **options).trajectory
    k = 6
    run = prepare_eld_run(problem, **options)
    state = _run_until(run, k)
    n, m = problem.space.ndofs, problem.constraint.m
    # identity transfer: the continuation agrees to round-off, no energy is booked
    same = run.stepper.adopt(state.mapped(sp.identity(n), sp.identity(m)))
    assert same is not state and same.fields is not state.fields
    assert set(same.fields) == set(state.fields) and set(same.products) == set(state.products)
    assert abs(same.ledger.transfer) <= 1e-14 * state.ledger.energy
    rest = Trajectory()
    evolve(run.stepper, run.controller, same, rest, tau_min=run.tau_min)
    assert np.abs(rest["u"][-1] - full["u"][-1]).max() <= 1e-10 * np.abs(full["u"]).max()
    # a perturbing transfer (interior values scaled, as an inexact projection would): the energy
    # change is booked as transfer and the balance still closes to round-off
    scale = np.ones(n)
    scale[problem.constraint.free] = 1.01
    moved = run.stepper.adopt(state.mapped(sp.diags(scale), None))
    assert moved.ledger.transfer != 0.0
    assert abs(moved.ledger.residual) <= 1e-13 * state.ledger.energy
    assert "lam" not in moved.boundary  # no boundary operator given: dropped
    assert state.ledger.transfer == 0.0  # the mapped state was not changed
    rest = Trajectory()
    run2 = prepare_eld_run(problem, **options)
    evolve(run2.stepper, run2.controller, moved, rest, tau_min=run2.tau_min)
    assert np.abs(rest["balance_residual"]).max() <= 1e-12 * np.abs(rest["energy"]).max()


def test_result_codes_carry_their_message_and_compare_as_strings():
    assert issubclass(ELDCode, ResultCode)
    assert [c.value for c in ELDCode] == ["ok", "linear-solve", "newton", "non-finite"]
    assert ELDCode("newton") is ELDCode.NEWTON and ELDCode.NEWTON == "newton"
    assert str(ELDCode.NON_FINITE) == "non-finite" and f"{ELDCode.LINEAR_SOLVE}" == "linear-solve"
    assert ELDCode.NEWTON.message == "Newton's method did not converge"
    assert ELDCode.OK.successful and not ELDCode.NEWTON.successful
