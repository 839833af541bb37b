"""The checkpoint protocol at dict level: run k steps, checkpoint_state, deepcopy, restore into a
fresh stepper and controller, continue -- and get the uninterrupted run bit for bit.

These are the round trips docs/robustness.md asks of every stepper and controller.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from rothe.control.controllers import make_controller
from rothe.io.checkpoint import encode
from rothe.io.trajectory import Trajectory
from rothe.nonlinear.linear import ReusableSolver
from rothe.nonlinear.ris_inner import InnerOptions
from rothe.problems.ris_1d import example_7_1
from rothe.problems.ris_fem import example_7_2
from rothe.stepping.evolve import evolve
from rothe.stepping.ris import RISState, RISStepper, initial_trajectory


class StopAfter:
    """A stepper that reports 'finished' after k accepted steps (everything else delegated)."""

    def __init__(self, stepper, k: int, index=lambda s: s.k):
        self.stepper, self.k, self.index = stepper, k, index

    def __getattr__(self, name):
        return getattr(self.stepper, name)

    def finished(self, state):
        return self.index(state) >= self.k or self.stepper.finished(state)


def _ris_parts(problem, control, **kw):
    grid = kw.pop("grid", None)
    controller = make_controller(control, tol=kw.get("tol"), tau=kw.get("tau", 0.1), grid=grid)
    stepper = RISStepper(problem, kw.get("inner"))
    return stepper, controller


def _assert_same(a: Trajectory, b: Trajectory):
    assert set(a.keys()) == set(b.keys())
    for key in a.keys():
        assert np.array_equal(a[key], b[key]), key
    sa, sb = a.stats.as_dict(), b.stats.as_dict()
    sa.pop("wall_time_s"), sb.pop("wall_time_s")
    assert sa == sb


@pytest.mark.parametrize("control, problem, kw, k", [
    ("adaptive", "7.1", {"tol": 1e-3}, 20),
    ("order2", "7.1", {"tol": 1e-3}, 20),
    ("uniform", "7.1", {"tau": 0.05}, 25),
    ("nested", "7.1", {"tol": 1e-4, "grid": np.linspace(0.05, 15.0, 300)}, 30),
    ("adaptive", "7.2", {"tol": 1e-4, "inner": InnerOptions(linear_solver="direct")}, 70),
])
def test_ris_stepper_and_controller_round_trip(control, problem, kw, k):
    make = (lambda: example_7_1()) if problem == "7.1" else (lambda: example_7_2(6, T=0.3))
    p = make()
    # uninterrupted
    stepper, controller = _ris_parts(p, control, **dict(kw))
    full = initial_trajectory(p)
    evolve(stepper, controller, RISState(0.0, 0.0, p.z0.copy()), full)
    # k steps, then a checkpoint dict, deep-copied, restored into fresh objects
    stepper, controller = _ris_parts(p, control, **dict(kw))
    part = initial_trajectory(p)
    state = evolve(StopAfter(stepper, k), controller, RISState(0.0, 0.0, p.z0.copy()), part)
    assert state.k == k
    saved = copy.deepcopy({"stepper": stepper.checkpoint_state(state),
                           "controller": controller.checkpoint_state()})
    encode(saved, {})  # only arrays, numbers, str, None, dicts and lists
    del stepper, controller
    stepper2, controller2 = _ris_parts(p, control, **dict(kw))
    state2 = stepper2.restore_state(saved["stepper"])
    controller2.restore_state(saved["controller"])
    evolve(stepper2, controller2, state2, part)
    _assert_same(full, part)


def test_restoring_the_stored_lu_is_what_makes_the_ris_continuation_exact():
    """Without the stored factorization (GMRES preconditioned by another LU) the continued run
    differs in the last bits: the cache changes results, so it is part of the state."""
    p = example_7_2(6, T=0.3)  # 146 steps, 16 LU factorizations
    kw = {"tol": 1e-4, "inner": InnerOptions(linear_solver="direct")}
    stepper, controller = _ris_parts(p, "adaptive", **kw)
    full = initial_trajectory(p)
    evolve(stepper, controller, RISState(0.0, 0.0, p.z0.copy()), full)
    stepper, controller = _ris_parts(p, "adaptive", **kw)
    part = initial_trajectory(p)
    state = evolve(StopAfter(stepper, 70), controller, RISState(0.0, 0.0, p.z0.copy()), part)
    saved = copy.deepcopy(stepper.checkpoint_state(state))
    assert saved["linear"]["reference"] is not None  # an LU is stored at step 70
    saved["linear"]["reference"] = None
    stepper2, _ = _ris_parts(p, "adaptive", **kw)
    evolve(stepper2, controller, stepper2.restore_state(saved), part)
    assert not all(np.array_equal(full[key], part[key]) for key in ("z", "lam", "kkt"))


def test_reusable_solver_round_trip_rebuilds_the_same_lu():
    import scipy.sparse as sp

    rng = np.random.default_rng(1)
    n = 60
    A = sp.diags([-1.0, 2.2, -1.0], [-1, 0, 1], shape=(n, n), format="csr")
    s1 = ReusableSolver("direct")
    s1.solve(A, [rng.standard_normal(n)])
    K = (A + sp.diags(0.05 * rng.standard_normal(n))).tocsr()  # drifted: GMRES on the old LU
    b = rng.standard_normal(n)
    data = copy.deepcopy(s1.checkpoint_state())
    s2 = ReusableSolver("direct")
    s2.restore_state(data)
    x1, = s1.solve(K, [b], rtol=1e-8)
    x2, = s2.solve(K, [b], rtol=1e-8)
    assert np.array_equal(x1, x2)
    assert s1.stats.as_dict() == s2.stats.as_dict()


@pytest.mark.parametrize("form, damping", [("regularized", "nonlinear"),
                                           ("original", "nonlinear"),
                                           ("regularized", "rayleigh")])
def test_eld_stepper_round_trip(form, damping):
    from rothe.control.controllers import UniformController
    from rothe.eld import ELDStepper, make_damping, mms_problem

    p, _ = mms_problem(3, 2, damping=make_damping(damping, b=0.01, d0=0.5))

    def fresh():
        st = ELDStepper(p, form, 0.02)
        return st, UniformController(0.02)

    def start(st):
        traj = Trajectory()
        s0 = st.initial_state()
        st.record_initial(traj, s0)
        return traj, s0

    st_full, ctl = fresh()
    full, s0 = start(st_full)
    evolve(st_full, ctl, s0, full, tau_min=0.02)
    st, ctl = fresh()
    part, s0 = start(st)
    state = evolve(StopAfter(st, 17, index=lambda s: s.j), ctl, s0, part, tau_min=0.02)
    saved = copy.deepcopy({"stepper": st.checkpoint_state(state),
                           "controller": ctl.checkpoint_state()})
    encode(saved, {})
    st2, ctl2 = fresh()
    state2 = st2.restore_state(saved["stepper"])
    ctl2.restore_state(saved["controller"])
    evolve(st2, ctl2, state2, part, tau_min=0.02)
    _assert_same(full, part)
    a, b = vars(st_full.solver.stats), vars(st2.solver.stats)
    assert {k: v for k, v in a.items() if k != "setup_seconds"} == {
        k: v for k, v in b.items() if k != "setup_seconds"}


def test_encode_refuses_what_would_need_pickle():
    with pytest.raises(TypeError, match=r"checkpoint state.solver: a function is not allowed"):
        encode({"solver": lambda x: x}, {})
    with pytest.raises(TypeError, match=r"state.a\[1\]: array of dtype object"):
        encode({"a": [np.zeros(2), np.array([None])]}, {})
    with pytest.raises(ValueError, match="uniform"):  # a controller refuses another's state
        make_controller("order2", tol=1e-3, tau=0.1).restore_state(
            make_controller("uniform", tau=0.1).checkpoint_state())
