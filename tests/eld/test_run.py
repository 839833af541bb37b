"""Runs from t = 0 to T (rothe.eld.run): the orders of Euler (3.4) and BDF2 in both forms, their
equivalences, the multiplier as the reaction, the energy ledger, the result object, and bad
input at the API."""

import warnings

import numpy as np
import pytest

from rothe.eld import (
    BDF2,
    Differenced,
    DirichletData,
    ELDProblem,
    ELDResult,
    ImplicitEuler,
    Material,
    Means,
    NonlinearDamping,
    Original,
    Points,
    RayleighDamping,
    Regularized,
    UserDamping,
    mms_errors,
    mms_problem,
    prepare_eld_run,
    run_eld,
)
from rothe.eld.studies import fitted_rate
from rothe.errors import RotheInputError
from rothe.fem import mesh as meshes
from rothe.stepping.controllers import Adaptive, Given, Uniform

TAUS = (0.1, 0.05, 0.025, 0.0125)


@pytest.fixture(scope="module")
def mms():
    return mms_problem(2, 2)


# -- Euler ----------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "form,data",
    [(Regularized(), Points()), (Original(), Points()), (Regularized(), Means())],
    ids=["regularized-points", "original-points", "regularized-means"],
)
def test_first_order_in_tau_on_the_manufactured_solution(form, data):
    # P2 represents the quadratic manufactured solution exactly: all error is temporal
    problem, exact = mms_problem(2, 2)
    errs = [
        mms_errors(
            exact, run_eld(problem, form=form, control=Uniform(tau), data=data, store_fields=False)
        )
        for tau in TAUS
    ]
    rate_u = fitted_rate(TAUS, [e["error_u_l2"] for e in errs])
    rate_v = fitted_rate(TAUS, [e["error_v_l2"] for e in errs])
    rate_lam = fitted_rate(TAUS, [e["error_lam_l2"] for e in errs])
    assert rate_u >= 0.9
    assert rate_v >= 0.85
    assert rate_lam >= 0.85
    assert errs[-1]["error_u_l2"] < 0.1


@pytest.mark.parametrize("scheme", [ImplicitEuler(), BDF2()], ids=["euler", "bdf2"])
def test_regularized_with_differenced_data_reproduces_the_original_form(scheme):
    """SPEC 5: with G_dot, G_ddot the scheme's difference quotients of G the two forms coincide
    (for BDF2 with the same start history on Gamma_D)."""
    problem, _ = mms_problem(3, 1)
    tau = 0.02
    orig = run_eld(problem, form=Original(), control=Uniform(tau), scheme=scheme).trajectory
    for lifting in ("nodal", "harmonic"):
        reg = run_eld(
            problem,
            form=Regularized(lifting),
            control=Uniform(tau),
            data=Differenced(),
            scheme=scheme,
        ).trajectory
        scale = np.abs(orig["u"]).max()
        assert np.abs(reg["u"] - orig["u"]).max() <= 1e-9 * scale
        assert np.abs(reg["v"] - orig["v"]).max() <= 1e-8 * np.abs(orig["v"]).max()
        assert np.abs(reg["lam"] - orig["lam"]).max() <= 1e-7 * np.abs(orig["lam"]).max()
        # after the first step (whose start difference is booked as mismatch) X vanishes
        X = np.diff(reg["data_mismatch"])[1:]
        assert np.abs(X).max() <= 1e-9 * np.abs(reg["energy"]).max()
    if scheme == ImplicitEuler():
        # with consistent data the scheme's velocity is the difference quotient of u
        du = np.diff(orig["u"], axis=0) / tau
        assert np.abs(du - orig["v"][1:]).max() <= 1e-12 * np.abs(orig["v"]).max()
        # v = D u_1 + v_2 differs from D u
        exact_data = run_eld(problem, control=Uniform(tau)).trajectory
        du = np.diff(exact_data["u"], axis=0) / tau
        assert 1e-6 < np.abs(du - exact_data["v"][1:]).max() < 0.1 * np.abs(orig["v"]).max()


def test_choice_of_complement_does_not_change_u_with_exact_derivatives_up_to_order_tau():
    problem, exact = mms_problem(2, 2)
    a = run_eld(problem, form=Regularized("nodal"), control=Uniform(0.01), store_fields=False)
    b = run_eld(problem, form=Regularized("harmonic"), control=Uniform(0.01), store_fields=False)
    ea, eb = mms_errors(exact, a), mms_errors(exact, b)
    # both first order with similar constants; the multiplier is the same functional of u
    assert eb["error_u_l2"] == pytest.approx(ea["error_u_l2"], rel=0.5)
    assert eb["error_lam_l2"] == pytest.approx(ea["error_lam_l2"], rel=0.5)


@pytest.mark.parametrize("form", [Regularized(), Original()], ids=["regularized", "original"])
def test_multiplier_balances_the_global_momentum_equation(form):
    """sum over each component of rho M a + D(v) - F equals the total reaction -int lambda.

    K annihilates rigid translations, so testing the equation with a translation leaves
    inertia + damping - loads = -B^T lambda tested with it = sum of the part reactions."""
    tau = 0.02
    problem, _ = mms_problem(3, 1, dirichlet=("left", "bottom"))
    traj = run_eld(problem, form=form, control=Uniform(tau)).trajectory
    v = traj["v"]
    M, D = problem.M, problem.damping_op
    rho, d = problem.material.rho, problem.space.dim
    c = problem.constraint
    lift = c.embed
    for j in range(1, len(traj["t"])):
        t = traj["t"][j]
        if form == Original():
            a = (v[j] - v[j - 1]) / tau
        else:  # a = D^2 u_1 + w_2 with u_1 = u - u_2 (nodal lifting)
            v1 = v[j] - lift(problem.G_dot(t))
            v1_prev = v[j - 1] - lift(problem.G_dot(t - tau))
            a = (v1 - v1_prev) / tau + lift(problem.G_ddot(t))
        residual = rho * (M @ a) + D.apply(v[j]) - problem.load(t)
        total = residual.reshape(-1, d).sum(axis=0)
        reactions = sum(traj[f"reaction_{p}"][j - 1] for p in ("left", "bottom"))
        scale = np.abs(problem.load(t)).sum() + np.abs(rho * (M @ a)).sum()
        assert np.allclose(total, reactions, atol=1e-9 * scale), (j, total, reactions)
    # both parts carry load
    assert np.abs(traj["reaction_left"]).max() > 0.1
    assert np.abs(traj["reaction_bottom"]).max() > 0.1


def zero(t, x):
    return np.zeros_like(x)


def _free_vibration(n=4, damping=None):
    mesh = meshes.unit_square(n, named=True)
    material = Material(rho=1.0, lam=2.0, mu=1.0, dim=2)
    return ELDProblem(
        mesh,
        material,
        degree=1,
        damping=damping,
        dirichlet={"left": DirichletData(zero, zero, zero)},
        u0=lambda x: np.stack([0.1 * x[0] ** 2, 0.2 * x[0] * x[1]]),
        v0=lambda x: np.stack([x[0] * x[1], -x[0]]),
        T=1.0,
    )


@pytest.mark.parametrize("form", [Regularized(), Original()], ids=["regularized", "original"])
def test_undamped_energy_never_increases_and_the_balance_closes(form):
    problem = _free_vibration()
    traj = run_eld(problem, form=form, control=Uniform(0.01)).trajectory
    E = traj["energy"]
    assert np.all(np.diff(E) <= 1e-13 * E[0])
    assert E[-1] < E[0]  # implicit Euler is dissipative
    # all of the decrease is numerical dissipation: no loads, no damping, a fixed support
    assert np.abs(traj["balance_residual"]).max() <= 1e-11 * E[0]
    assert E[0] - E[-1] == pytest.approx(traj["numerical_dissipation"][-1], rel=1e-10)
    assert np.abs(traj["work_reaction"]).max() <= 1e-12 * E[0]


@pytest.mark.parametrize("form", [Regularized(), Original()], ids=["regularized", "original"])
def test_energy_balance_closes_with_loads_moving_support_and_nonlinear_damping(form):
    problem, _ = mms_problem(3, 2)
    traj = run_eld(problem, form=form, control=Uniform(0.02)).trajectory
    scale = (
        np.abs(traj["energy"]).max()
        + np.abs(traj["work"]).max()
        + np.abs(traj["work_reaction"]).max()
    )
    assert np.abs(traj["balance_residual"]).max() <= 1e-9 * scale
    assert traj["numerical_dissipation"][-1] > 0
    # d0 > 0: the damping feeds energy in at small velocities
    assert problem.damping.constants.d0 == 0.5


def test_derivatives_of_G_by_differences_say_how_accurate_they_are():
    problem, exact = mms_problem(2, 1)
    mesh = problem.space.mesh
    with pytest.warns(UserWarning) as record:
        numeric = ELDProblem(
            mesh,
            problem.material,
            degree=1,
            damping=problem.damping,
            dirichlet={"left": exact.u},
            traction={p: exact.traction for p in ("right", "top", "bottom")},
            body_force=exact.body_force,
            u0=lambda x: exact.u(0.0, x),
            v0=lambda x: exact.u_dot(0.0, x),
        )
    messages = [str(w.message) for w in record]
    assert any(
        m.startswith("G_dot not given: central differences of G with h = ")
        and "estimated max error" in m
        for m in messages
    )
    assert any(
        m.startswith("G_ddot not given: central differences of G with h = ") for m in messages
    )
    info = numeric.derivative_info
    assert info["G_dot"]["estimated_error"] < 1e-8
    assert info["G_ddot"]["estimated_error"] < 1e-5
    a = run_eld(problem, control=Uniform(0.05)).trajectory
    b = run_eld(numeric, control=Uniform(0.05)).trajectory
    assert np.abs(a["u"] - b["u"]).max() < 1e-6
    assert np.abs(a["lam"] - b["lam"]).max() < 1e-4


def test_user_damping_matrix_reproduces_rayleigh_and_amg_matches_lu():
    problem, _ = mms_problem(2, 1, damping=RayleighDamping(a=0.2, b=0.01))
    ref = run_eld(problem, control=Uniform(0.05)).trajectory
    C = 0.2 * problem.M + 0.01 * problem.K
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        user = ELDProblem(
            problem.space.mesh,
            problem.material,
            degree=1,
            damping=UserDamping(matrix=C, d0=0.0),
            dirichlet=problem.dirichlet,
            traction={p: g for p, (g, _) in problem._traction.items()},
            body_force=problem.body_force,
            u0=problem.u0,
            v0=problem.v0,
        )
    other = run_eld(user, control=Uniform(0.05)).trajectory
    assert np.abs(other["u"] - ref["u"]).max() <= 1e-12 * np.abs(ref["u"]).max()
    amg = run_eld(problem, control=Uniform(0.05), solver="amg").trajectory
    assert amg.meta["solver"] == "amg"
    assert np.abs(amg["u"] - ref["u"]).max() <= 1e-7 * np.abs(ref["u"]).max()


@pytest.mark.parametrize(
    "scheme, order", [(ImplicitEuler(), 1.0), (BDF2(), 2.0)], ids=["euler", "bdf2"]
)
def test_multiplier_depends_on_the_lifting_at_the_order_of_the_scheme(scheme, order):
    """docs/eld.md: with point data the regularized solution, lambda included, changes with the
    lifting at O(tau) (Euler) and O(tau^2) (BDF2); only differenced data make it independent
    (test_regularized_with_differenced_data_reproduces_the_original_form)."""
    problem, _ = mms_problem(2, 2)
    gaps = []
    for tau in (0.1, 0.05, 0.025):
        lam = [
            run_eld(
                problem, form=Regularized(lifting), control=Uniform(tau), scheme=scheme
            ).trajectory["lam"]
            for lifting in ("nodal", "harmonic")
        ]
        gaps.append(float(np.max(np.abs(lam[0] - lam[1]))))
    assert gaps[0] > 1e-4  # a real difference, far above the solver tolerance
    rates = np.log2(np.array(gaps[:-1]) / np.array(gaps[1:]))
    assert np.all(rates > order - 0.3) and np.all(rates < order + 0.5), (gaps, rates)


# -- BDF2 ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("form", [Regularized(), Original()], ids=["regularized", "original"])
def test_second_order_for_u_v_and_lambda_at_T_and_over_all_steps(mms, form):
    problem, exact = mms  # P2 represents the solution exactly: all error is temporal
    errs = [
        mms_errors(exact, run_eld(problem, form=form, control=Uniform(tau), scheme=BDF2()))
        for tau in TAUS
    ]
    for key in (
        "error_u_l2",
        "error_v_l2",
        "error_lam_l2",
        "error_u_l2_max",
        "error_v_l2_max",
        "error_lam_l2_max",
    ):
        rate = fitted_rate(TAUS, [e[key] for e in errs])
        assert rate >= 1.8, (key, rate)
    assert errs[-1]["error_u_l2"] < 5e-3


def _sequence(n, T=1.0):
    """Alternating ratios about 1.6 and 1/1.6 on a smooth variation (largest ratio 1.75)."""
    k = np.arange(n)
    w = (1.0 + 0.6 * (k % 2)) * (1.0 + 0.5 * np.sin(2 * np.pi * (k + 0.5) / n))
    return T * w / w.sum()


@pytest.mark.parametrize("form", [Regularized(), Original()], ids=["regularized", "original"])
def test_variable_steps_keep_order_two(mms, form):
    problem, exact = mms
    rows = []
    for n in (10, 20, 40, 80):
        steps = _sequence(n)
        assert (steps[1:] / steps[:-1]).max() > 1.5
        result = run_eld(problem, form=form, scheme=BDF2(), control=Given(steps))
        traj = result.trajectory
        assert np.allclose(traj["tau"], steps, rtol=0, atol=1e-15)
        assert traj["t"][-1] == 1.0
        rows.append((steps.max(), mms_errors(exact, result)))
    h = [r[0] for r in rows]
    for key in ("error_u_l2", "error_v_l2", "error_lam_l2", "error_u_l2_max"):
        assert fitted_rate(h, [r[1][key] for r in rows]) >= 1.8, key


def test_energy_ledger_closes_to_round_off_for_bdf2_uniform_given_and_adaptive_steps():
    problem, _ = mms_problem(3, 2)  # nonlinear damping, loads, moving support
    runs = [
        run_eld(problem, form=form, control=Uniform(0.02), scheme=BDF2())
        for form in (Regularized(), Original())
    ]
    runs.append(run_eld(problem, scheme=BDF2(), control=Given(_sequence(30))))
    runs.append(run_eld(problem, form=Original(), scheme=BDF2(), control=Adaptive(1e-3, tau=0.01)))
    for result in runs:
        traj = result.trajectory
        scale = (
            np.abs(traj["energy"]).max()
            + np.abs(traj["work"]).max()
            + np.abs(traj["work_reaction"]).max()
        )
        assert np.abs(traj["balance_residual"]).max() <= 1e-12 * scale
        # N = N_G + S + C^n - C^0 at every state, with C^0 the start's boundary term
        N, NG, S = (
            traj[k] for k in ("numerical_dissipation", "numerical_dissipation_G", "step_change")
        )
        C = N - NG - S
        assert np.abs(C).max() < 0.5 * scale  # a boundary term, not accumulating
        # Newton to 1e-10: the algebraic residual's work is small but booked
        assert np.abs(traj["residual_work"]).max() <= 1e-6 * scale


def test_bdf2_G_dissipation_is_nonnegative_with_equal_steps_and_far_below_euler():
    problem = _free_vibration()
    euler = run_eld(problem, control=Uniform(0.01)).trajectory
    bdf2 = run_eld(problem, control=Uniform(0.01), scheme=BDF2()).trajectory
    E0 = bdf2["energy"][0]
    assert np.abs(bdf2["balance_residual"]).max() <= 1e-12 * E0
    assert np.diff(bdf2["numerical_dissipation_G"]).min() >= -1e-14 * E0
    assert np.abs(bdf2["step_change"]).max() <= 1e-14 * E0
    # no loads, no damping, fixed support: all energy change is numerical
    assert E0 - bdf2["energy"][-1] == pytest.approx(bdf2["numerical_dissipation"][-1], rel=1e-9)
    lost_euler = 1 - euler["energy"][-1] / E0
    lost_bdf2 = 1 - bdf2["energy"][-1] / E0
    assert lost_euler > 0.15 and 0 < lost_bdf2 < lost_euler / 10


# -- the result, the defaults, bad input --------------------------------------------------------


def test_run_eld_returns_a_result_object_with_the_final_state_and_the_statistics():
    problem, exact = mms_problem(2, 1)
    result = run_eld(problem)  # the defaults: implicit Euler, regularized, Uniform(0.01)
    assert isinstance(result, ELDResult) and result.meshes is None
    traj = result.trajectory
    assert result.statistics is traj.stats and traj.stats.accepted_steps == 100
    assert (
        traj.meta["scheme"],
        traj.meta["form"],
        traj.meta["control"],
        traj.meta["data"],
        traj.meta["lifting"],
        traj.meta["tau"],
    ) == ("euler", "regularized", "uniform", "points", "nodal", 0.01)
    assert result.state.t == 1.0 and result.state.j == 100 and result.problem is problem
    assert np.array_equal(result.state.u, traj["u"][-1])
    assert result.controller is not None and result.stepper.finished(result.state)
    # nothing is attached to the trajectory any more
    for name in ("final_state", "stepper", "controller", "space"):
        assert not hasattr(traj, name), name
    run = prepare_eld_run(problem, control=Uniform(0.5))
    assert run.result().state.j == 0 and run.evolve().state.j == 2


def test_bad_inputs_are_one_line_errors():
    problem, _ = mms_problem(2, 1)
    with pytest.raises(RotheInputError, match=r"^tau: got 0.3, must divide T = 1 into equal steps"):
        run_eld(problem, control=Uniform(0.3))
    with pytest.raises(
        RotheInputError,
        match=r"^dirichlet: got 'lft', must be one of bottom, "
        "left, right, top",
    ):
        mms_problem(2, 1, dirichlet=("lft",))
    with pytest.raises(
        RotheInputError,
        match=r"^u0: got max\|u0 - G\(0\)\| = 0.5 on the "
        "Dirichlet parts left, must equal G\\(0\\)",
    ):
        run_eld(mms_problem(2, 1, start="rest")[0], control=Uniform(0.1))
    with pytest.raises(RotheInputError, match=r"^rho: got -1, must be > 0$"):
        Material(rho=-1.0, lam=1.0, mu=1.0)
    with pytest.raises(RotheInputError, match=r"^mu: got 0, must be > 0$"):
        Material(rho=1.0, lam=1.0, mu=0.0)
    with pytest.raises(RotheInputError, match=r"^lam: got -2, must be > -2 mu / d = -0.666667"):
        Material(rho=1.0, lam=-2.0, mu=1.0, dim=3)
    mesh = meshes.unit_square(2, named=True)
    mat = Material(1.0, 1.0, 1.0)
    with pytest.raises(RotheInputError, match=r"^traction: got 'left', is also a Dirichlet part"):
        ELDProblem(
            mesh,
            mat,
            dirichlet={"left": lambda t, x: 0 * x},
            traction={"left": lambda t, x, n: 0 * x},
        )
    with pytest.raises(RotheInputError, match=r"^dirichlet: got \{\}, must map at least one"):
        ELDProblem(mesh, mat, dirichlet={})


def test_step_control_objects_refuse_bad_input_in_one_line_naming_the_parameter():
    problem, _ = mms_problem(2, 1)
    cases = [
        (lambda: Uniform(0.0), "tau", r"^tau: got 0, must be > 0$"),
        (lambda: Given([]), "steps", r"^steps: got \[\], must hold at least one step size$"),
        (lambda: Adaptive(0), "tol", r"^tol: got 0, must be > 0$"),
        (lambda: Adaptive(None), "tol", r"^tol: got None, must be a real number$"),
        (
            lambda: Adaptive(1e-3, tau=0.1, tau_max=0.01),
            "tau_max",
            r"^tau_max: got 0.01, must be >= the first step tau = 0.1$",
        ),
        # the first step by default 0.01: the range is checked against it where it is known
        (
            lambda: run_eld(problem, control=Adaptive(1e-3, tau_max=0.001)),
            "tau_max",
            r"^tau_max: got 0.001, must be >= the first step tau = 0.01$",
        ),
        (
            lambda: run_eld(problem, control=Adaptive(1e-3, tau_min=0.1)),
            "tau_min",
            r"^tau_min: got 0.1, must be <= the first step tau = 0.01$",
        ),
        (
            lambda: run_eld(problem, control=Adaptive(1e-3, tau=2.0)),
            "tau",
            r"^tau: got 2, \(the first step\) must be <= T",
        ),
        # a name is not a control: the objects carry what the names did (tol, steps, ...)
        (
            lambda: run_eld(problem, control="adaptive"),
            "control",
            r"^control: got 'adaptive', must be Uniform\(tau\), Given\(steps\) or Adaptive",
        ),
        (lambda: run_eld(problem, control="pid"), "control", r"^control: got 'pid', must be "),
        (
            lambda: run_eld(problem, adapt={"space_tol": 1}),
            "adapt",
            r"^adapt: got dict, must be a rothe.fem.adapt.SpaceAdaptivity",
        ),
    ]
    for make, parameter, pattern in cases:
        with pytest.raises(RotheInputError, match=pattern) as info:
            make()
        assert info.value.parameter == parameter, pattern
        assert len(str(info.value).splitlines()) == 1


def test_the_solvability_bound_does_not_depend_on_how_the_data_enter():
    problem, _ = mms_problem(2, 1, damping=NonlinearDamping(d0=2.0))
    for data in (Points(), Means(), Differenced()):
        with pytest.raises(RotheInputError, match=r"^tau: got 0.5, must be < rho/d0 = 0.5"):
            run_eld(problem, control=Uniform(0.5), data=data)
