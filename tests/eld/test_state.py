"""The ELD state: checkpoint round trips (bit for bit), the transfer interface, failed steps."""

import copy

import numpy as np
import pytest
import scipy.sparse as sp

from rothe.eld import (
    DataNoise,
    DirichletData,
    ELDProblem,
    Material,
    RayleighDamping,
    StepData,
    UserDamping,
    mms_problem,
    prepare_eld_run,
    run_eld,
)
from rothe.errors import RotheInputError, RunFailed
from rothe.fem import mesh as meshes
from rothe.io.trajectory import Trajectory
from rothe.stepping.evolve import evolve

CASES = [
    ("euler, uniform, linear", dict(form="regularized", tau=0.05), "rayleigh"),
    (
        "bdf2, uniform, nonlinear, original",
        dict(form="original", tau=0.05, scheme="bdf2"),
        "nonlinear",
    ),
    (
        "bdf2, adaptive, nonlinear",
        dict(form="regularized", tau=0.02, scheme="bdf2", control="adaptive", tol=1e-4),
        "nonlinear",
    ),
    (
        "bdf2, given steps, differenced, harmonic",
        dict(
            form="regularized",
            tau=0.1,
            scheme="bdf2",
            data="differenced",
            lifting="harmonic",
            steps=np.r_[np.full(5, 0.05), np.full(10, 0.075)],
        ),
        "rayleigh",
    ),
    (
        "euler, adaptive, linear",
        dict(form="original", tau=0.05, control="adaptive", tol=1e-3),
        "rayleigh",
    ),
]


def _problem(kind):
    damping = RayleighDamping(0.1, 0.01) if kind == "rayleigh" else None
    return mms_problem(2, 2, damping=damping)[0]


@pytest.mark.parametrize("label,options,damping", CASES, ids=[c[0] for c in CASES])
def test_checkpoint_round_trip_continues_bit_for_bit(label, options, damping):
    problem = _problem(damping)
    full = run_eld(problem, **options)
    k = 7
    run = prepare_eld_run(problem, **options)
    finished = run.stepper.finished
    run.stepper.finished = lambda st: st.j >= k or finished(st)
    state = evolve(run.stepper, run.controller, run.state, run.trajectory, tau_min=run.tau_min)
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
    for name, w in full.final_state.fields.items():
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
    run = prepare_eld_run(problem, "regularized", 0.05, scheme="bdf2")
    data = run.stepper.checkpoint_state(run.state)
    other = prepare_eld_run(problem, "regularized", 0.05)
    with pytest.raises(
        RotheInputError,
        match=r"^checkpoint: got scheme 'bdf2', this run has "
        "'euler'",
    ):
        other.stepper.restore_state(data)


def test_transfer_interface_maps_every_history_vector_and_books_the_energy_change():
    """What space adaptivity will do between steps: map the state, let the stepper adopt it."""
    problem = _problem("rayleigh")
    options = dict(form="regularized", tau=0.05, scheme="bdf2")
    full = run_eld(problem, **options)
    k = 6
    run = prepare_eld_run(problem, **options)
    finished = run.stepper.finished
    run.stepper.finished = lambda st: st.j >= k or finished(st)
    state = evolve(run.stepper, run.controller, run.state, run.trajectory, tau_min=run.tau_min)
    n, m = problem.space.ndofs, problem.constraint.m
    # identity transfer: the continuation agrees to round-off, no energy is booked
    same = run.stepper.adopt(state.mapped(sp.identity(n), sp.identity(m)))
    assert set(same.fields) == set(state.fields) and set(same.products) == set(state.products)
    assert abs(same.ledger.transfer) <= 1e-14 * state.ledger.energy
    run.stepper.finished = finished
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
    rest = Trajectory()
    run2 = prepare_eld_run(problem, **options)
    evolve(run2.stepper, run2.controller, moved, rest, tau_min=run2.tau_min)
    assert np.abs(rest["balance_residual"]).max() <= 1e-12 * np.abs(rest["energy"]).max()


def _square(body_force=None, dirichlet=None, damping=None):
    mesh = meshes.unit_square(2, named=True)
    material = Material(rho=1.0, lam=2.0, mu=1.0, dim=2)

    def zero(t, x):
        return np.zeros_like(x)

    return ELDProblem(
        mesh,
        material,
        degree=1,
        damping=damping,
        dirichlet={"left": dirichlet or DirichletData(zero, zero, zero)},
        body_force=body_force,
        u0=None,
        v0=lambda x: np.stack([x[0], 0 * x[0]]),
        T=1.0,
    )


@pytest.mark.parametrize("control", ["uniform", "adaptive"])
def test_non_finite_data_midway_stops_the_run_without_accepting_the_step(control):
    def force(t, x):
        return np.full_like(x, np.nan if t > 0.5 else 1.0)

    problem = _square(body_force=force)
    tol = 1e-3 if control == "adaptive" else None
    with pytest.raises(
        RunFailed,
        match=r"^non-finite data at step \d+ \(t = 0\.[56]\d*\): "
        r"the load F",
    ):
        run_eld(problem, "regularized", 0.1, scheme="bdf2", control=control, tol=tol)

    def G(t, x):
        return np.full_like(x, np.nan) if t > 0.35 else np.zeros_like(x)

    problem = _square(dirichlet=DirichletData(G, lambda t, x: 0 * x, lambda t, x: 0 * x))
    with pytest.raises(RunFailed, match="the Dirichlet data G has NaN") as info:
        run_eld(problem, "original", 0.1)
    traj = info.value.trajectory
    assert traj.stats.accepted_steps == 3 and np.all(np.isfinite(traj["u"]))


@pytest.mark.parametrize("scheme", ["euler", "bdf2"])
def test_non_finite_state_is_a_failed_step(scheme):
    """Finite data whose response overflows (as eld-beam --amplitude 1e300 did)."""

    def force(t, x):
        return np.full_like(x, 1e308 if t > 0.45 else 0.0)

    problem = _square(body_force=force)
    with pytest.raises(
        RunFailed,
        match=r"^non-finite state at step 5 \(t = 0.5, tau = 0.1\): "
        r".* has NaN or inf entries; the step is not accepted",
    ) as info:
        run_eld(problem, "regularized", 0.1, scheme=scheme)
    traj = info.value.trajectory
    assert traj.stats.accepted_steps == 4 and np.all(np.isfinite(traj["energy"]))
    # nonlinear damping whose force turns NaN: Newton fails, the step is not accepted
    calls = {"n": 0}

    def nan_later(v):
        calls["n"] += 1
        return v * (np.nan if calls["n"] > 12 else 1.0)

    damping = UserDamping(force=nan_later, jacobian=lambda v: sp.identity(v.size), d0=0.0)
    with pytest.raises(
        RunFailed,
        match="(Newton's method did not converge|non-finite state).*the step is not accepted",
    ) as info:
        run_eld(_square(damping=damping), "regularized", 0.1, scheme=scheme)
    assert np.all(np.isfinite(info.value.trajectory["u"]))


@pytest.mark.parametrize("datum", ["G", "G_dot", "G_ddot", "F"])
def test_noise_in_one_datum_changes_only_that_datum(datum):
    problem, _ = mms_problem(2, 1)
    clean = StepData(problem, "points").at(3, 0.2, 0.3)
    noisy = StepData(problem, "points", DataNoise(1e-3, datum, seed=1)).at(3, 0.2, 0.3)
    for name in ("G", "G_dot", "G_ddot", "F"):
        diff = np.abs(getattr(noisy, name) - getattr(clean, name)).max()
        if name == datum:
            assert diff > 1e-5
        else:
            assert diff == 0.0, name
    with pytest.raises(
        RotheInputError,
        match=r"^noise target: got 'H', must be one of G, "
        "G_dot, G_ddot, F",
    ):
        DataNoise(1e-3, "H")
    with pytest.raises(RotheInputError, match=r"^seed: got -1, must be an integer >= 0"):
        DataNoise(1e-3, "G", seed=-1)
