"""Step controllers on the shared evolve loop: Alg. 3.2, Alg. 6.2 (nested), order2, uniform."""

from types import SimpleNamespace

import numpy as np
import pytest

from rothe import RunFailed, run_nested, run_ris
from rothe.control.controllers import (
    AdaptiveController,
    Order2Controller,
    UniformController,
    make_controller,
)
from rothe.problems.ris_1d import example_7_1


def result(tau, I1, I2, converged=True):
    return SimpleNamespace(
        tau=tau,
        converged=converged,
        code="converged" if converged else "max_iterations",
        errors={"I1": I1, "I2": I2},
    )


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
    "kwargs, match",
    [
        (dict(control="adaptive", tol=0.0, tau=0.1), r"tol: got 0, must be > 0"),
        (dict(control="adaptive", tol=-1e-3, tau=0.1), r"tol: got -0.001, must be > 0"),
        (dict(control="order2", tol=1e-3, tau=0.0), r"tau: got 0, must be > 0"),
        (dict(control="uniform", tau=-1.0), r"tau: got -1, must be > 0"),
        (
            dict(control="adaptive", tol=1e-3, tau=0.1, tau_min=0.2),
            r"tau_min: got 0.2, must be <= tau",
        ),
        (dict(control="bogus", tol=1e-3, tau=0.1), r"control: got 'bogus', must be one of"),
    ],
)
def test_controller_inputs_are_validated(kwargs, match):
    with pytest.raises(ValueError, match=match):
        make_controller(**kwargs)


def test_nested_tolerances_must_decrease():
    with pytest.raises(ValueError, match=r"tols: got '0.001,0.01', must be strictly decreasing"):
        run_nested(example_7_1(), [1e-3, 1e-2])


def test_nested_grids_are_nested():
    """Alg. 6.2: every grid point of an earlier run is a grid point of every later run (6.1)."""
    runs = run_nested(example_7_1(), [1e-2, 1e-3, 1e-4], tau=0.1)
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
        run_ris(example_7_1(), "adaptive", tol=1e-9, tau=0.1, tau_min=1e-3)
    exc = info.value
    assert {"step", "s", "t", "tau", "I1", "I2"} <= set(exc.where)
    traj = exc.trajectory
    assert traj is not None and len(traj) == exc.where["step"] - 1
    assert traj["t"][-1] == pytest.approx(exc.where["t"])


def test_run_lands_on_T():
    for control, tol in (("adaptive", 1e-3), ("order2", 1e-3), ("uniform", None)):
        traj = run_ris(example_7_1(), control, tol=tol, tau=0.07)
        assert traj["t"][-1] == pytest.approx(5.0, abs=1e-9)
        assert traj["t"][-2] < 5.0
