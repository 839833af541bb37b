"""One step (rothe.eld.stepper): the checks of Lemma 3.2 and of the step sequences before the
first step, failed steps (never accepted), the local error estimate, and a stop signal between
Newton iterations that abandons the step (issue 21: begin_attempt / abandon, the resumed run bit
for bit)."""

import math

import numpy as np
import pytest
import scipy.sparse as sp

from rothe.eld import (
    BDF2,
    DirichletData,
    ELDCode,
    ELDProblem,
    ELDStepper,
    ImplicitEuler,
    Material,
    NewtonOptions,
    NonlinearDamping,
    Original,
    Regularized,
    UserDamping,
    make_damping,
    mms_problem,
    run_eld,
)
from rothe.eld.scheme import BDF2_ZERO_STABILITY
from rothe.eld.system import ELDSystem
from rothe.errors import RotheInputError, RunFailed, RunInterrupted
from rothe.fem import mesh as meshes
from rothe.io.checkpoint import CheckpointOptions, load_checkpoint
from rothe.stepping.controllers import Adaptive, Given, Uniform

from ..conftest import assert_same_trajectory


def test_step_bound_of_lemma_3_2_is_checked_before_any_step():
    problem, _ = mms_problem(2, 1, damping=NonlinearDamping(d0=2.0))
    with pytest.raises(
        RotheInputError,
        match=r"^tau: got 0.5, must be < rho/d0 = 0.5 "
        r"\(Lemma 3.2",
    ):
        run_eld(problem, control=Uniform(0.5))
    traj = run_eld(problem, form=Original(), control=Uniform(0.25)).trajectory  # runs
    assert len(traj["t"]) == 5
    # no bound without the L2 part
    problem0, _ = mms_problem(2, 1, damping=NonlinearDamping(d0=0.0))
    assert len(run_eld(problem0, control=Uniform(1.0)).trajectory["t"]) == 2


def test_bdf2_step_bound_is_checked_before_any_step():
    problem, _ = mms_problem(2, 1, damping=NonlinearDamping(d0=2.0))  # rho/d0 = 0.5
    with pytest.raises(
        RotheInputError,
        match=r"^tau: got 0.8, must be < 1.5 rho/d0 = 0.75 "
        r"\(Lemma 3.2 for BDF2",
    ):
        run_eld(problem, control=Uniform(0.8), scheme=BDF2())
    # 0.5 is refused by Euler but solvable for BDF2 (tau/alpha = 1/3 < 1/2)
    traj = run_eld(problem, form=Original(), control=Uniform(0.5), scheme=BDF2()).trajectory
    assert len(traj["t"]) == 3
    with pytest.raises(
        RotheInputError,
        match=r"^steps: got tau_1 = 0.8, must satisfy "
        r"tau_j/alpha_j < rho/d0 = 0.5 \(alpha_j = 1.5",
    ):
        run_eld(problem, scheme=BDF2(), control=Given([0.8, 0.2]))


def test_step_sequences_are_checked():
    problem, _ = mms_problem(2, 1)
    limit = f"{BDF2_ZERO_STABILITY:.6g}"
    with pytest.raises(
        RotheInputError,
        match=rf"^steps: got tau_3/tau_2 = 2.5, must be < 1 \+ "
        rf"sqrt\(2\) = {limit} \(zero-stability",
    ):
        run_eld(problem, scheme=BDF2(), control=Given([0.1, 0.1, 0.25, 0.55]))
    # Euler has no ratio limit
    traj = run_eld(problem, control=Given([0.1, 0.1, 0.25, 0.55])).trajectory
    assert len(traj["t"]) == 5
    with pytest.raises(RotheInputError, match=r"^steps: got steps summing to 0.9, must sum to T"):
        run_eld(problem, control=Given([0.5, 0.4]))
    with pytest.raises(RotheInputError, match=r"^steps: got tau_2 = -0.1, must be positive"):
        run_eld(problem, control=Given([1.1, -0.1]))


def test_absurd_tau_is_one_line():
    problem, _ = mms_problem(2, 1)
    with pytest.raises(
        RotheInputError,
        match=r"^tau: got 9.99989e-321, must divide T = 1 into "
        r"equal steps \(T/tau = inf\)",
    ):
        run_eld(problem, control=Uniform(1e-320))
    assert math.isinf(1.0 / 1e-320)
    with pytest.raises(RotheInputError, match=r"^tau: got 1e\+300, must be < rho/d0"):
        run_eld(problem, control=Uniform(1e300))
    with pytest.raises(
        RotheInputError,
        match=r"^tau: got 0.3, must divide T = 1 into equal "
        r"steps",
    ):
        run_eld(problem, control=Uniform(0.3))


def test_failed_newton_solve_stops_the_run_without_accepting_the_step():
    problem, _ = mms_problem(2, 1)
    with pytest.raises(
        RunFailed, match="Newton's method did not converge in 1 iterations at step 1"
    ) as info:
        run_eld(problem, control=Uniform(0.1), newton=NewtonOptions(tol=1e-15, max_iter=1))
    exc = info.value
    assert exc.where["step"] == 1 and exc.where["t"] == 0.0
    assert len(exc.trajectory["t"]) == 1  # only the initial state
    assert exc.trajectory.stats.accepted_steps == 0
    # the step's result: not converged, its code and message
    stepper = ELDStepper(problem, control=Uniform(0.1), newton=NewtonOptions(tol=1e-15, max_iter=1))
    result = stepper.step(stepper.initial_state(), 0.1)
    assert not result.converged and result.state is None and result.code is ELDCode.NEWTON
    assert result.code == "newton" and result.message.startswith(ELDCode.NEWTON.message)


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


@pytest.mark.parametrize("adaptive", [False, True], ids=["uniform", "adaptive"])
def test_non_finite_data_midway_stops_the_run_without_accepting_the_step(adaptive):
    def force(t, x):
        return np.full_like(x, np.nan if t > 0.5 else 1.0)

    problem = _square(body_force=force)
    control = Adaptive(1e-3, tau=0.1) if adaptive else Uniform(0.1)
    with pytest.raises(
        RunFailed,
        match=r"^non-finite data at step \d+ \(t = 0\.[56]\d*\): "
        r"the load F",
    ):
        run_eld(problem, scheme=BDF2(), control=control)

    def G(t, x):
        return np.full_like(x, np.nan) if t > 0.35 else np.zeros_like(x)

    problem = _square(dirichlet=DirichletData(G, lambda t, x: 0 * x, lambda t, x: 0 * x))
    with pytest.raises(RunFailed, match="the Dirichlet data G has NaN") as info:
        run_eld(problem, form=Original(), control=Uniform(0.1))
    traj = info.value.trajectory
    assert traj.stats.accepted_steps == 3 and np.all(np.isfinite(traj["u"]))


@pytest.mark.parametrize("scheme", [ImplicitEuler(), BDF2()], ids=["euler", "bdf2"])
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
        run_eld(problem, scheme=scheme, control=Uniform(0.1))
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
        run_eld(_square(damping=damping), scheme=scheme, control=Uniform(0.1))
    assert np.all(np.isfinite(info.value.trajectory["u"]))


@pytest.mark.parametrize("scheme,order", [(ImplicitEuler(), 1), (BDF2(), 2)], ids=["euler", "bdf2"])
def test_local_error_estimate_has_the_order_of_the_local_error(scheme, order):
    """local_error ~ tau^(p+1) on a smooth solution: halving tau divides it by 2^(p+1)."""
    problem, _ = mms_problem(2, 2)
    a = run_eld(problem, scheme=scheme, control=Uniform(0.02), store_fields=False).trajectory
    b = run_eld(problem, scheme=scheme, control=Uniform(0.01), store_fields=False).trajectory
    # compare at the same times t = 0.2, 0.4, ..., 1.0 (away from the start)
    ea = a["local_error"][9::10]
    eb = b["local_error"][19::20]
    ratio = np.median(ea / eb)
    assert 2 ** (order + 1) * 0.8 <= ratio <= 2 ** (order + 1) * 1.25


def test_stepper_options_refuse_bad_input_in_one_line_naming_the_parameter():
    problem, _ = mms_problem(2, 1)
    for kwargs, pattern in (
        (
            dict(control="uniform"),
            r"^control: got 'uniform', must be Uniform\(tau\), "
            r"Given\(steps\) or Adaptive\(tol, tau=\.\.\.\)",
        ),
        (dict(newton={"tol": 1e-8}), r"^newton: got dict, must be a rothe.eld.NewtonOptions"),
        (dict(keep_every=0), r"^keep_every: got 0, must be an integer >= 1$"),
        (dict(error_scale=-1.0), r"^error_scale: got -1, must be > 0$"),
        (dict(solver="gmres"), r"^solver: got 'gmres', must be one of auto, direct, amg$"),
    ):
        with pytest.raises(RotheInputError, match=pattern) as info:
            ELDStepper(problem, **kwargs)
        assert info.value.parameter == pattern[1:].split(":")[0]
        assert len(str(info.value).splitlines()) == 1
    with pytest.raises(RotheInputError, match=r"^newton max_iter: got 0, must be >= 1$"):
        NewtonOptions(max_iter=0)


# -- a stop signal between Newton iterations (issue 21, item 3) -------------------------------


@pytest.mark.parametrize("form", [Regularized(), Original()], ids=["regularized", "original"])
def test_a_signal_between_newton_iterations_abandons_the_step_and_resumes_bit_for_bit(
    tmp_path, signal_at_call, form
):
    """Nonlinear damping, adaptive BDF2 steps: every step is Newton's method with Krylov solves
    on the stored factorization (refactored when they stall). A stop signal sent at a Newton
    solve abandons the step after that iteration; the checkpoint holds the last accepted state
    with the solver as it was then (abandon puts back the factorization, its key and the
    counters), and the resumed run is the uninterrupted one, bit for bit."""
    p, _ = mms_problem(3, 2, damping=make_damping("nonlinear", b=0.01, d0=0.5))

    def make_run(**kw):
        return run_eld(p, form=form, scheme=BDF2(), control=Adaptive(1e-4, tau=0.02), **kw)

    solves = signal_at_call(ELDSystem, "solve", 10**9)
    full = make_run()
    n = solves[0]
    assert n > 50 and full.trajectory.stats.rejected_steps > 0
    ckpt, resume = tmp_path / "c", None
    for k in (n // 6, n // 5, n // 4):
        signal_at_call(ELDSystem, "solve", k)
        with pytest.raises(RunInterrupted) as info:
            make_run(checkpoint=CheckpointOptions(ckpt, every_seconds=0.01), resume=resume)
        exc = info.value
        assert exc.exit_status == 130 and exc.where["abandoned_step"] is True
        traj = exc.trajectory
        assert exc.where["accepted_steps"] == traj.stats.accepted_steps == len(traj["tau"])
        saved = load_checkpoint(ckpt)
        assert saved.status == "interrupted" and saved.state["stepper"]["j"] == len(traj["tau"])
        resume = ckpt
    signal_at_call(ELDSystem, "solve", 10**9)
    resumed = make_run(resume=ckpt)
    assert_same_trajectory(full.trajectory, resumed.trajectory)
    ls = resumed.trajectory.meta["linear_solver"]
    assert full.trajectory.meta["linear_solver"] == ls | {
        "setup_seconds": full.trajectory.meta["linear_solver"]["setup_seconds"]
    }
    for name, w in full.state.fields.items():
        assert np.array_equal(w, resumed.state.fields[name]), name
