"""Step controllers on the shared evolve loop: Alg. 3.2, Alg. 6.2 (nested), order2, regime,
uniform; their decisions on designed error sequences and their checkpoint round trips; the
step-control objects (Uniform, Adaptive, Order2, Regime, Nested) refuse bad input in one line."""

import copy
import math
from types import SimpleNamespace

import numpy as np
import pytest

from rothe import RunFailed, run_nested, run_ris
from rothe.errors import RotheInputError
from rothe.io.trajectory import Trajectory
from rothe.ris.controllers import (
    AdaptiveController,
    Nested,
    Order2,
    Order2Controller,
    Regime,
    RegimeController,
    build_controller,
    step_regime,
)
from rothe.ris.examples import example_7_1
from rothe.ris.run import initial_trajectory
from rothe.ris.stepper import RISState, RISStepper
from rothe.stepping.controllers import Adaptive, Uniform, UniformController
from rothe.stepping.evolve import evolve

#: the step-control object of each control, at tolerance 1e-4 and first step 0.1
OBJECTS = {
    "uniform": lambda: Uniform(0.1),
    "adaptive": lambda: Adaptive(1e-4, tau=0.1),
    "order2": lambda: Order2(1e-4, tau=0.1),
    "regime": lambda: Regime(1e-4, tau=0.1),
}


def result(tau, I1, I2, converged=True, step_norm=None):
    r = SimpleNamespace(
        tau=tau,
        converged=converged,
        code="converged" if converged else "max_iterations",
        errors={"I1": I1, "I2": I2},
    )
    if step_norm is not None:
        r.step_norm = step_norm
    return r


def slip(tau, e, I2=0.0, converged=True):
    return result(tau, e, I2, converged, step_norm=0.5 * tau)


def jump(tau, e):
    return result(tau, 0.0, e, step_norm=tau)


def stick(tau, e):
    return result(tau, e, 0.0, step_norm=0.0)


def test_alg_3_2_accept_double_keep_halve():
    c = AdaptiveController(tol=1e-3, tau0=0.1)
    d = c.decide(result(0.1, 1e-4, 4e-4))  # both < tol/2: accept and double
    assert d.accept and d.next_tau == pytest.approx(0.2)
    d = c.decide(result(0.2, 6e-4, 1e-5))  # < tol but not < tol/2: accept, keep
    assert d.accept and d.next_tau == pytest.approx(0.2)
    d = c.decide(result(0.2, 1e-5, 1e-3))  # I2 = tol is not < tol: reject and halve
    assert not d.accept and d.next_tau == pytest.approx(0.1)
    d = c.decide(result(0.1, 0.0, 0.0, converged=False))  # a failed solve is never accepted
    assert not d.accept and d.next_tau == pytest.approx(0.05)


def test_order2_proposes_from_tau_squared_law():
    c = Order2Controller(tol=1e-4, tau0=0.1, safety=0.9)
    d = c.decide(result(0.1, 4e-5, 1e-5))  # C = 4e-3 -> 0.9 * sqrt(1e-4 / 4e-3)
    assert d.accept and d.next_tau == pytest.approx(0.9 * np.sqrt(1e-4 / 4e-3))
    d = c.decide(result(0.1, 4e-4, 0.0))  # rejected: at most half, at least a quarter
    assert not d.accept and d.next_tau == pytest.approx(0.045)
    # a zero residual right after C = 4e-3: the larger constant of the last two steps is used
    d = c.decide(result(0.05, 0.0, 0.0))
    assert d.accept and d.next_tau == pytest.approx(0.9 * np.sqrt(1e-4 / 4e-3))
    d = c.decide(result(0.1, 0.0, 0.0))  # two zero residuals in a row: grow by the clamp, 4
    assert d.accept and d.next_tau == pytest.approx(0.4)


def test_uniform_only_rejects_failed_solves_then_resumes():
    c = UniformController(0.1)
    assert c.decide(result(0.1, 1.0, 1.0)).accept
    d = c.decide(result(0.1, 0.0, 0.0, converged=False))
    assert not d.accept and c.propose(0.0)[0] == pytest.approx(0.05)
    assert c.decide(result(0.05, 0.0, 0.0)).accept and c.propose(0.0)[0] == pytest.approx(0.1)


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: Adaptive(0.0, tau=0.1), r"^tol: got 0, must be > 0$"),
        (lambda: Adaptive(-1e-3, tau=0.1), r"^tol: got -0.001, must be > 0$"),
        (lambda: Order2(1e-3, tau=0.0), r"^tau: got 0, must be > 0$"),
        (lambda: Uniform(-1.0), r"^tau: got -1, must be > 0$"),
        (
            lambda: Adaptive(1e-3, tau=0.1, tau_min=0.2),
            r"^tau_min: got 0.2, must be <= the first step tau = 0.1$",
        ),
        (
            lambda: Uniform(0.1, tau_min=0.2),
            r"^tau_min: got 0.2, must be <= the first step tau = 0.1$",
        ),
    ],
)
def test_controller_inputs_are_validated(make, match):
    with pytest.raises(RotheInputError, match=match):
        make()


@pytest.mark.parametrize(
    "make, parameter, match",
    [
        (lambda: Uniform(0.0), "tau", r"^tau: got 0, must be > 0$"),
        (lambda: Uniform(0.1, tau_min=-1.0), "tau_min", r"^tau_min: got -1, must be > 0$"),
        (lambda: Adaptive(float("nan")), "tol", r"^tol: got nan, must be"),
        (
            lambda: Adaptive(1e-4, tau=0.1, tau_max=0.05),
            "tau_max",
            r"^tau_max: got 0.05, must be >= the first step tau = 0.1$",
        ),
        (lambda: Order2(0.0), "tol", r"^tol: got 0, must be > 0$"),
        (lambda: Order2(1e-4, tau=-0.1), "tau", r"^tau: got -0.1, must be > 0$"),
        (
            lambda: Order2(1e-4, tau=0.1, tau_min=0.5),
            "tau_min",
            r"^tau_min: got 0.5, must be <= the first step tau = 0.1$",
        ),
        (lambda: Order2(1e-4, safety=0.0), "safety", r"^safety: got 0, must be > 0$"),
        (lambda: Regime(-1.0), "tol", r"^tol: got -1, must be > 0$"),
        (lambda: Regime(1e-4, tau=0.0), "tau", r"^tau: got 0, must be > 0$"),
        (
            lambda: Regime(1e-4, theta=1.0),
            "theta",
            r"^theta: got 1, must be < 1 \(the target theta \* tol is below tol\)$",
        ),
        (lambda: Regime(1e-4, theta=0.0), "theta", r"^theta: got 0, must be > 0$"),
        (lambda: Regime(1e-4, grow=1.0), "grow", r"^grow: got 1, must be > 1$"),
        (
            lambda: Nested([1e-3, 1e-2]),
            "tols",
            r"^tols: got '0.001,0.01', must be strictly decreasing$",
        ),
        (lambda: Nested(1e-3), "tols", r"^tols: got a float, must be a sequence of decreasing "),
        (lambda: Nested("1e-3"), "tols", r"^tols: got a str, must be a sequence of decreasing "),
        (lambda: Nested([1e-3, -1e-4]), "tols", r"^tols: got "),
        (lambda: Nested([1e-3], tau=0.0), "tau", r"^tau: got 0, must be > 0$"),
        (
            lambda: Nested([1e-3], tau=0.1, tau_min=1.0),
            "tau_min",
            r"^tau_min: got 1, must be <= the first step tau = 0.1$",
        ),
    ],
)
def test_every_control_object_refuses_bad_input_in_one_line_naming_the_parameter(
    make, parameter, match
):
    with pytest.raises(RotheInputError, match=match) as info:
        make()
    assert info.value.parameter == parameter
    assert "\n" not in str(info.value)


def test_control_objects_keep_what_they_were_given_and_build_their_controllers():
    """The object is the specification; the run builds the controller with the RIS defaults
    (first step 0.1, tau_min 1e-12, no tau_max) where it left them open."""
    c = build_controller(Order2(1e-3, safety=0.5))
    assert isinstance(c, Order2Controller) and (c.tol, c.tau0, c.safety) == (1e-3, 0.1, 0.5)
    assert c.tau_min == 1e-12 and c.tau_max == math.inf
    c = build_controller(Regime(1e-3, tau=0.2, tau_min=1e-6, tau_max=0.5, theta=0.25, grow=2.0))
    assert isinstance(c, RegimeController)
    assert (c.tau0, c.tau_min, c.tau_max, c.theta, c.grow) == (0.2, 1e-6, 0.5, 0.25, 2.0)
    c = build_controller(Uniform(0.05, tau_min=1e-3))
    assert isinstance(c, UniformController) and (c.tau0, c.tau_min) == (0.05, 1e-3)
    c = build_controller(Adaptive(1e-3), grid=np.array([0.3, 0.1]))
    assert isinstance(c, AdaptiveController) and c.name == "nested"
    assert np.array_equal(c.grid, [0.1, 0.3])
    assert Nested((1e-2, 1e-3)).tols == (1e-2, 1e-3)
    with pytest.raises(
        RotheInputError,
        match=r"^control: got 'adaptive', must be a step-control "
        r"object: Uniform\(tau\), Adaptive\(tol\)",
    ):
        build_controller("adaptive")


def test_nested_tolerances_must_decrease():
    with pytest.raises(ValueError, match=r"tols: got '0.001,0.01', must be strictly decreasing"):
        run_nested(example_7_1(), Nested([1e-3, 1e-2]))


def test_nested_grids_are_nested():
    """Alg. 6.2: every grid point of an earlier run is a grid point of every later run (6.1)."""
    runs = [r.trajectory for r in run_nested(example_7_1(), Nested([1e-2, 1e-3, 1e-4], tau=0.1))]
    grids = [r["s"] for r in runs]
    for i, coarse in enumerate(grids):
        for fine in grids[i + 1 :]:
            reach = coarse[coarse <= fine[-1]]
            assert np.all(np.isin(reach, fine)), "a grid point of an earlier run was skipped"
    assert len(grids[2]) > len(grids[1]) > len(grids[0])
    for r in runs:
        assert np.all(r["I1"] < r.meta["tol"]) and np.all(r["I2"] < r.meta["tol"])
        assert r["t"][-1] == pytest.approx(5.0, abs=1e-9)


def test_step_size_underflow_stops_with_where_and_keeps_trajectory():
    with pytest.raises(
        RunFailed, match=r"step size fell below tau_min = 0.001 at step \d+ \(s = "
    ) as info:
        run_ris(example_7_1(), Adaptive(1e-9, tau=0.1, tau_min=1e-3))
    exc = info.value
    assert {"step", "s", "t", "tau", "I1", "I2"} <= set(exc.where)
    traj = exc.trajectory
    assert traj is not None and len(traj) == exc.where["step"] - 1
    assert traj["t"][-1] == pytest.approx(exc.where["t"])


def test_run_lands_on_T():
    for control in (Adaptive(1e-3, tau=0.07), Order2(1e-3, tau=0.07), Uniform(0.07)):
        traj = run_ris(example_7_1(), control).trajectory
        assert traj["t"][-1] == pytest.approx(5.0, abs=1e-9)
        assert traj["t"][-2] < 5.0


def test_step_regime_from_the_increment():
    assert step_regime(stick(0.1, 0.0)) == "stick"
    assert step_regime(jump(0.1, 0.0)) == "jump"
    assert step_regime(slip(0.1, 0.0)) == "slip"
    assert step_regime(result(0.1, 0.0, 0.0)) == "slip"  # a stepper without step_norm


def test_regime_accepts_as_alg_3_2_and_equidistributes():
    c = RegimeController(tol=1e-4, tau0=0.1)  # target theta * tol = 5e-5
    d = c.decide(slip(0.1, 4e-5))  # C = 4e-3: tau = sqrt(5e-5 / 4e-3)
    assert d.accept and d.next_tau == pytest.approx(math.sqrt(5e-5 / 4e-3))
    # a smaller error right after: the larger constant of the last two steps (period-2 guard)
    d = c.decide(slip(0.1, 1e-6))
    assert d.accept and d.next_tau == pytest.approx(math.sqrt(5e-5 / 4e-3))
    d = c.decide(slip(0.1, 1e-4))  # I1 = tol is not < tol: rejected, tau (5e-5/1e-4)^(1/2)
    assert not d.accept and d.next_tau == pytest.approx(0.1 * math.sqrt(0.5))
    d = c.decide(slip(0.1, 1e-3, I2=2e-4))  # e = max(I1, I2)
    assert not d.accept and d.next_tau == pytest.approx(0.1 * math.sqrt(5e-5 / 1e-3))
    d = c.decide(slip(0.1, 1.0))
    assert not d.accept and d.next_tau == pytest.approx(0.01)
    d = c.decide(slip(0.1, 0.0, converged=False))  # a failed solve is never accepted
    assert not d.accept and d.next_tau == pytest.approx(0.025)


def test_regime_grows_by_at_most_grow_and_respects_tau_max():
    c = RegimeController(tol=1e-4, tau0=0.1, tau_max=0.3)
    d = c.decide(stick(0.1, 0.0))  # zero residual (stable sticking): grow, clamped to tau_max
    assert d.accept and d.next_tau == pytest.approx(0.3)
    c = RegimeController(tol=1e-4, tau0=0.1)
    assert c.decide(stick(0.1, 0.0)).next_tau == pytest.approx(0.4)
    assert c.decide(stick(0.4, 0.0)).next_tau == pytest.approx(1.6)
    d = c.decide(slip(1.6, 9e-5))  # a new regime: its own constant, no memory of sticking
    assert d.accept and d.next_tau == pytest.approx(1.6 * math.sqrt(5e-5 / 9e-5))


def test_regime_measures_the_order_from_a_rejection_and_its_retry():
    """The viscous jump of Example 7.2 has I2 ~ tau^3: the exponent comes from the two attempts."""
    c = RegimeController(tol=1e-5, tau0=0.02)  # target 5e-6
    d = c.decide(jump(0.02, 10 * 0.02**3))  # 8e-5 >= tol; p = 2 so far
    assert not d.accept and d.next_tau == pytest.approx(0.02 * math.sqrt(5e-6 / 8e-5))
    tau = d.next_tau  # 0.005
    d = c.decide(jump(tau, 10 * tau**3))  # accepted; the pair gives p = 3 and C = 10
    assert d.accept and d.next_tau == pytest.approx((5e-6 / 10) ** (1 / 3))
    assert c.checkpoint_state()["models"]["jump"]["p"] == pytest.approx(3.0)
    assert c.checkpoint_state()["models"].get("slip") is None


def test_regime_floor_keeps_tau_above_half_the_tau_squared_step():
    """(5.7): after an accepted step, never below min(grow tau, sqrt(theta tol / C2) / 2)."""
    c = RegimeController(tol=1e-4, tau0=0.02)  # target 5e-5
    d = c.decide(jump(0.02, 1.6e-3))
    tau = d.next_tau
    d = c.decide(jump(tau, 5e-7))  # measured order 4.7, clipped to 4: tau (100)^(1/4) = 3.16 tau
    assert d.accept
    assert d.next_tau == pytest.approx(min(4 * tau, 0.5 * tau * math.sqrt(5e-5 / 5e-7)))
    assert d.next_tau > 3.2 * tau


def test_regime_leaves_sticking_at_the_target_residual():
    """While sticking, I1 = L (s_end - s*)^2 / 2 (L = 1 here): two rejections locate s*, and the
    step that leaves sticking aims at crossing_fraction * theta * tol."""
    c = RegimeController(tol=1e-3, tau0=0.4)  # target 5e-4

    def stuck_until_2(s, tau):
        return stick(tau, 0.5 * max(s + tau - 2.0, 0.0) ** 2)

    s = 1.9
    tau, _ = c.propose(s)
    assert not c.decide(stuck_until_2(s, tau)).accept  # ends at 2.3
    tau, _ = c.propose(s)
    assert c.decide(stuck_until_2(s, tau)).accept  # ends before 2: I1 = 0
    s += tau
    tau, _ = c.propose(s)
    assert not c.decide(stuck_until_2(s, tau)).accept  # the second sample
    tau, _ = c.propose(s)
    q = c.crossing_fraction
    assert s + tau == pytest.approx(2.0 + math.sqrt(2 * q * 5e-4))
    assert stuck_until_2(s, tau).errors["I1"] == pytest.approx(q * 5e-4)
    assert c.decide(stuck_until_2(s, tau)).accept


def test_regime_inputs_are_validated():
    with pytest.raises(ValueError, match=r"theta: got 1, must be < 1"):
        RegimeController(tol=1e-4, tau0=0.1, theta=1.0)
    with pytest.raises(ValueError, match=r"grow: got 1, must be > 1"):
        RegimeController(tol=1e-4, tau0=0.1, grow=1.0)
    with pytest.raises(ValueError, match=r"tol: got 0, must be > 0"):
        build_controller(Regime(0.0, tau=0.1))
    with pytest.raises(ValueError, match=r"tau_min: got 0.5, must be <= the first step tau"):
        build_controller(Regime(1e-4, tau=0.1, tau_min=0.5))
    with pytest.raises(ValueError, match=r"control: got 'bogus', must be a step-control object"):
        build_controller("bogus")
    with pytest.raises(ValueError, match=r"tau_min: got 0.5, must be <= tau \(= 0.1\)"):
        RegimeController(tol=1e-4, tau0=0.1, tau_min=0.5)


# -- checkpoint protocol (issue 10) ---------------------------------------------------------------

SEQUENCE = [
    slip(0.1, 4e-5),
    slip(0.11, 1e-6),
    slip(0.1, 2e-4),
    slip(0.05, 2e-5),
    jump(0.05, 3e-4),
    jump(0.02, 1e-6),
    stick(0.4, 0.0),
    stick(1.6, 0.0),
    slip(0.1, 0.0, converged=False),
    slip(0.02, 3e-5),
    jump(0.03, 2e-5),
]


def _build(control):
    if control == "nested":
        return build_controller(Adaptive(1e-4, tau=0.1), grid=np.array([0.05, 0.3, 0.7]))
    return build_controller(OBJECTS[control]())


@pytest.mark.parametrize("control", ["uniform", "adaptive", "nested", "order2", "regime"])
def test_controller_checkpoint_round_trip_on_a_designed_sequence(control):
    """Checkpoint after k decisions, deepcopy, restore into a fresh controller: both decide the
    rest of the sequence identically (decisions and proposals, to the bit)."""
    for k in range(len(SEQUENCE)):
        a = _build(control)
        s = 0.0
        for r in SEQUENCE[:k]:
            a.propose(s)
            if a.decide(r).accept:
                s += r.tau
        data = copy.deepcopy(a.checkpoint_state())
        b = _build(control)
        b.restore_state(data)
        for r in SEQUENCE[k:]:
            pa, pb = a.propose(s), b.propose(s)
            assert pa == pb
            da, db = a.decide(r), b.decide(r)
            assert (da.accept, da.next_tau) == (db.accept, db.next_tau)
            if da.accept:
                s += r.tau


def _plain_data(x):
    if isinstance(x, dict):
        return all(isinstance(k, str) and _plain_data(v) for k, v in x.items())
    if isinstance(x, list):
        return all(_plain_data(v) for v in x)
    return x is None or isinstance(x, (bool, int, float, str, np.ndarray))


@pytest.mark.parametrize("control", ["uniform", "adaptive", "nested", "order2", "regime"])
def test_controller_checkpoint_holds_only_plain_data(control):
    c = _build(control)
    for r in SEQUENCE[:6]:
        c.propose(0.0)
        c.decide(r)
    assert _plain_data(c.checkpoint_state())


def test_restore_into_a_different_controller_fails():
    data = _build("regime").checkpoint_state()
    with pytest.raises(
        ValueError,
        match=r"restore_state: a 'regime' controller's state given "
        r"to a 'order2' controller",
    ):
        _build("order2").restore_state(data)


@pytest.mark.parametrize("control", ["uniform", "adaptive", "order2", "regime"])
def test_run_resumed_from_controller_checkpoint_is_bit_identical(control):
    """Example 7.1: k steps, checkpoint the controller, restore a fresh one, finish the run:
    the same trajectory as the uninterrupted run, to the bit (the stepper continues as is)."""
    problem = example_7_1()
    full = initial_trajectory(problem)
    evolve(
        RISStepper(problem),
        build_controller(OBJECTS[control]()),
        RISState(0.0, 0.0, problem.z0.copy()),
        full,
    )
    stepper = RISStepper(problem)
    first = build_controller(OBJECTS[control]())
    traj = initial_trajectory(problem)
    state = evolve(stepper, first, RISState(0.0, 0.0, problem.z0.copy()), traj, max_steps=40)
    assert state.k == 40
    second = build_controller(OBJECTS[control]())
    second.restore_state(copy.deepcopy(first.checkpoint_state()))
    evolve(stepper, second, state, traj)
    assert len(traj) == len(full) > 40
    for key in ("s", "t", "z", "tau", "I1", "I2", "lam"):
        assert np.array_equal(traj[key], full[key]), key
    assert isinstance(traj, Trajectory)


def test_regime_with_a_denormal_tolerance_stops_below_tau_min():
    """tol = 1e-320: the step out of sticking (delta ~ sqrt(tol)) and tau^p underflow; the run
    must stop like the other controllers' (RunFailed naming tau_min), not divide by zero."""
    with pytest.raises(RunFailed, match="step size fell below tau_min"):
        run_ris(example_7_1(), Regime(1e-320, tau=0.1))
