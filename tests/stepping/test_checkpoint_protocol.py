"""The checkpoint protocol at dict level: run k steps, checkpoint_state, deepcopy, restore into a
fresh stepper and controller, continue -- and get the uninterrupted run bit for bit.

These are the round trips docs/robustness.md asks of every stepper and controller.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from rothe.cli.ris_commands import control_object
from rothe.fem.linear import ReusableSolver
from rothe.io.checkpoint import encode
from rothe.io.trajectory import Trajectory
from rothe.ris.controllers import Order2, build_controller
from rothe.ris.examples import example_7_1, example_7_2
from rothe.ris.inner import InnerOptions
from rothe.ris.run import initial_trajectory
from rothe.ris.stepper import RISState, RISStepper
from rothe.stepping.controllers import Uniform
from rothe.stepping.evolve import evolve


def _ris_parts(problem, control, **kw):
    grid = kw.pop("grid", None)
    spec = control_object(
        "adaptive" if control == "nested" else control, tol=kw.get("tol"), tau=kw.get("tau", 0.1)
    )
    controller = build_controller(spec, grid=grid)
    stepper = RISStepper(problem, kw.get("inner"))
    return stepper, controller


def _assert_same(a: Trajectory, b: Trajectory):
    assert set(a.keys()) == set(b.keys())
    for key in a.keys():
        assert np.array_equal(a[key], b[key]), key
    assert a.stats.untimed() == b.stats.untimed()


@pytest.mark.parametrize(
    "control, problem, kw, k",
    [
        ("adaptive", "7.1", {"tol": 1e-3}, 20),
        ("order2", "7.1", {"tol": 1e-3}, 20),
        ("uniform", "7.1", {"tau": 0.05}, 25),
        ("nested", "7.1", {"tol": 1e-4, "grid": np.linspace(0.05, 15.0, 300)}, 30),
        ("adaptive", "7.2", {"tol": 1e-4, "inner": InnerOptions(linear_solver="direct")}, 70),
        # regime: right after the step out of sticking (its onset samples, models) and in slip
        ("regime", "7.1", {"tol": 1e-3}, 20),
        ("regime", "7.2", {"tol": 1e-4, "inner": InnerOptions(linear_solver="direct")}, 3),
        ("regime", "7.2", {"tol": 1e-4, "inner": InnerOptions(linear_solver="direct")}, 60),
    ],
)
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
    state = evolve(stepper, controller, RISState(0.0, 0.0, p.z0.copy()), part, max_steps=k)
    assert state.k == k
    saved = copy.deepcopy(
        {"stepper": stepper.checkpoint_state(state), "controller": controller.checkpoint_state()}
    )
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
    state = evolve(stepper, controller, RISState(0.0, 0.0, p.z0.copy()), part, max_steps=70)
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
    (x1,) = s1.solve(K, [b], rtol=1e-8)
    (x2,) = s2.solve(K, [b], rtol=1e-8)
    assert np.array_equal(x1, x2)
    assert s1.stats.as_dict() == s2.stats.as_dict()


@pytest.mark.parametrize(
    "form, damping, options",
    [
        ("regularized", "nonlinear", {}),
        ("original", "nonlinear", {}),
        ("regularized", "rayleigh", {}),
        ("original", "nonlinear", {"scheme": "bdf2", "tol": 1e-4}),
        ("regularized", "rayleigh", {"scheme": "bdf2", "data": "differenced"}),
    ],
)
def test_eld_stepper_round_trip(form, damping, options):
    """The stepper and the controller that run_eld uses (prepare_eld_run): Euler and BDF2,
    uniform and adaptive steps. The step data keeps no history of its own (the differenced
    mode's G^{j-1}, G^{j-2}, G_dot^{j-1}, G_dot^{j-2} are boundary vectors of the state)."""
    from rothe.eld import (
        BDF2,
        Differenced,
        ImplicitEuler,
        Original,
        Points,
        Regularized,
        make_damping,
        mms_problem,
        prepare_eld_run,
    )
    from rothe.stepping.controllers import Adaptive, Uniform

    p, _ = mms_problem(3, 2, damping=make_damping(damping, b=0.01, d0=0.5))
    objects = dict(
        form=Regularized() if form == "regularized" else Original(),
        scheme=BDF2() if options.get("scheme") == "bdf2" else ImplicitEuler(),
        control=Adaptive(options["tol"], tau=0.02) if "tol" in options else Uniform(0.02),
        data=Differenced() if options.get("data") == "differenced" else Points(),
    )

    def fresh():
        return prepare_eld_run(p, **objects)

    run_full = fresh()
    full = run_full.trajectory
    evolve(run_full.stepper, run_full.controller, run_full.state, full, tau_min=run_full.tau_min)
    run = fresh()
    part = run.trajectory
    state = evolve(run.stepper, run.controller, run.state, part, tau_min=run.tau_min, max_steps=17)
    assert state.j == 17
    saved = copy.deepcopy(
        {
            "stepper": run.stepper.checkpoint_state(state),
            "controller": run.controller.checkpoint_state(),
        }
    )
    encode(saved, {})
    run2 = fresh()
    state2 = run2.stepper.restore_state(saved["stepper"])
    run2.controller.restore_state(saved["controller"])
    evolve(run2.stepper, run2.controller, state2, part, tau_min=run2.tau_min)
    _assert_same(full, part)
    a, b = vars(run_full.stepper.system.solver.stats), vars(run2.stepper.system.solver.stats)
    assert {k: v for k, v in a.items() if k != "setup_seconds"} == {
        k: v for k, v in b.items() if k != "setup_seconds"
    }


def test_encode_refuses_what_would_need_pickle():
    with pytest.raises(TypeError, match=r"checkpoint state.solver: a function is not allowed"):
        encode({"solver": lambda x: x}, {})
    with pytest.raises(TypeError, match=r"state.a\[1\]: array of dtype object"):
        encode({"a": [np.zeros(2), np.array([None])]}, {})
    with pytest.raises(ValueError, match="uniform"):  # a controller refuses another's state
        build_controller(Order2(1e-3, tau=0.1)).restore_state(
            build_controller(Uniform(0.1)).checkpoint_state()
        )
