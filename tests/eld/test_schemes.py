"""Implicit Euler (3.4), both forms: order, equivalences, multiplier = reaction, energy, inputs."""

import warnings

import numpy as np
import pytest

from rothe.eld import (
    DirichletData,
    ELDProblem,
    Material,
    NewtonOptions,
    NonlinearDamping,
    RayleighDamping,
    UserDamping,
    mms_errors,
    mms_problem,
    run_eld,
)
from rothe.eld.studies import fitted_rate
from rothe.errors import RotheInputError, RunFailed
from rothe.fem import mesh as meshes

TAUS = (0.1, 0.05, 0.025, 0.0125)


@pytest.mark.parametrize(
    "form,data", [("regularized", "points"), ("original", "points"), ("regularized", "means")]
)
def test_first_order_in_tau_on_the_manufactured_solution(form, data):
    # P2 represents the quadratic manufactured solution exactly: all error is temporal
    problem, exact = mms_problem(2, 2)
    errs = [
        mms_errors(problem, exact, run_eld(problem, form, tau, data=data, store_fields=False))
        for tau in TAUS
    ]
    rate_u = fitted_rate(TAUS, [e["error_u_l2"] for e in errs])
    rate_v = fitted_rate(TAUS, [e["error_v_l2"] for e in errs])
    rate_lam = fitted_rate(TAUS, [e["error_lam_l2"] for e in errs])
    assert rate_u >= 0.9
    assert rate_v >= 0.85
    assert rate_lam >= 0.85
    assert errs[-1]["error_u_l2"] < 0.1


@pytest.mark.parametrize("scheme", ["euler", "bdf2"])
def test_regularized_with_differenced_data_reproduces_the_original_form(scheme):
    """SPEC 5: with G_dot, G_ddot the scheme's difference quotients of G the two forms coincide
    (for BDF2 with the same start history on Gamma_D)."""
    problem, _ = mms_problem(3, 1)
    tau = 0.02
    orig = run_eld(problem, "original", tau, scheme=scheme)
    for lifting in ("nodal", "harmonic"):
        reg = run_eld(
            problem, "regularized", tau, scheme=scheme, data="differenced", lifting=lifting
        )
        scale = np.abs(orig["u"]).max()
        assert np.abs(reg["u"] - orig["u"]).max() <= 1e-9 * scale
        assert np.abs(reg["v"] - orig["v"]).max() <= 1e-8 * np.abs(orig["v"]).max()
        assert np.abs(reg["lam"] - orig["lam"]).max() <= 1e-7 * np.abs(orig["lam"]).max()
        # after the first step (whose start difference is booked as mismatch) X vanishes
        X = np.diff(reg["data_mismatch"])[1:]
        assert np.abs(X).max() <= 1e-9 * np.abs(reg["energy"]).max()
    if scheme == "euler":
        # with consistent data the scheme's velocity is the difference quotient of u
        du = np.diff(orig["u"], axis=0) / tau
        assert np.abs(du - orig["v"][1:]).max() <= 1e-12 * np.abs(orig["v"]).max()
        exact_data = run_eld(problem, "regularized", tau)  # v = D u_1 + v_2 differs from D u
        du = np.diff(exact_data["u"], axis=0) / tau
        assert 1e-6 < np.abs(du - exact_data["v"][1:]).max() < 0.1 * np.abs(orig["v"]).max()


def test_choice_of_complement_does_not_change_u_with_exact_derivatives_up_to_order_tau():
    problem, exact = mms_problem(2, 2)
    a = run_eld(problem, "regularized", 0.01, lifting="nodal", store_fields=False)
    b = run_eld(problem, "regularized", 0.01, lifting="harmonic", store_fields=False)
    ea, eb = mms_errors(problem, exact, a), mms_errors(problem, exact, b)
    # both first order with similar constants; the multiplier is the same functional of u
    assert eb["error_u_l2"] == pytest.approx(ea["error_u_l2"], rel=0.5)
    assert eb["error_lam_l2"] == pytest.approx(ea["error_lam_l2"], rel=0.5)


@pytest.mark.parametrize("form", ["regularized", "original"])
def test_multiplier_balances_the_global_momentum_equation(form):
    """sum over each component of rho M a + D(v) - F equals the total reaction -int lambda.

    K annihilates rigid translations, so testing the equation with a translation leaves
    inertia + damping - loads = -B^T lambda tested with it = sum of the part reactions."""
    tau = 0.02
    problem, _ = mms_problem(3, 1, dirichlet=("left", "bottom"))
    traj = run_eld(problem, form, tau)
    v = traj["v"]
    M, D = problem.M, problem.damping_op
    rho, d = problem.material.rho, problem.space.dim
    c = problem.constraint
    lift = c.embed
    for j in range(1, len(traj["t"])):
        t = traj["t"][j]
        if form == "original":
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


def _free_vibration(form, damping=None):
    mesh = meshes.unit_square(4, named=True)
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


@pytest.mark.parametrize("form", ["regularized", "original"])
def test_undamped_energy_never_increases_and_the_balance_closes(form):
    problem = _free_vibration(form)
    traj = run_eld(problem, form, 0.01)
    E = traj["energy"]
    assert np.all(np.diff(E) <= 1e-13 * E[0])
    assert E[-1] < E[0]  # implicit Euler is dissipative
    # all of the decrease is numerical dissipation: no loads, no damping, a fixed support
    assert np.abs(traj["balance_residual"]).max() <= 1e-11 * E[0]
    assert E[0] - E[-1] == pytest.approx(traj["numerical_dissipation"][-1], rel=1e-10)
    assert np.abs(traj["work_reaction"]).max() <= 1e-12 * E[0]


@pytest.mark.parametrize("form", ["regularized", "original"])
def test_energy_balance_closes_with_loads_moving_support_and_nonlinear_damping(form):
    problem, _ = mms_problem(3, 2)
    traj = run_eld(problem, form, 0.02)
    scale = (
        np.abs(traj["energy"]).max()
        + np.abs(traj["work"]).max()
        + np.abs(traj["work_reaction"]).max()
    )
    assert np.abs(traj["balance_residual"]).max() <= 1e-9 * scale
    assert traj["numerical_dissipation"][-1] > 0
    # d0 > 0: the damping feeds energy in at small velocities
    assert problem.damping.constants.d0 == 0.5


def test_step_bound_of_lemma_3_2_is_checked_before_any_step():
    problem, _ = mms_problem(2, 1, damping=NonlinearDamping(d0=2.0))
    with pytest.raises(
        RotheInputError,
        match=r"^tau: got 0.5, must be < rho/d0 = 0.5 "
        r"\(Lemma 3.2",
    ):
        run_eld(problem, "regularized", 0.5)
    traj = run_eld(problem, "original", 0.25)  # below the bound: runs
    assert len(traj["t"]) == 5
    # no bound without the L2 part
    problem0, _ = mms_problem(2, 1, damping=NonlinearDamping(d0=0.0))
    assert len(run_eld(problem0, "regularized", 1.0)["t"]) == 2


def test_bad_inputs_are_one_line_errors():
    problem, _ = mms_problem(2, 1)
    with pytest.raises(RotheInputError, match=r"^tau: got 0.3, must divide T = 1 into equal steps"):
        run_eld(problem, "regularized", 0.3)
    with pytest.raises(
        RotheInputError,
        match=r"^form: got 'index3', must be one of regularized, "
        "original",
    ):
        run_eld(problem, "index3", 0.1)
    with pytest.raises(RotheInputError, match=r"^data: got 'mean', must be one of points, means"):
        run_eld(problem, "regularized", 0.1, data="mean")
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
        run_eld(mms_problem(2, 1, start="rest")[0], "regularized", 0.1)
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


def test_failed_newton_solve_stops_the_run_without_accepting_the_step():
    problem, _ = mms_problem(2, 1)
    with pytest.raises(
        RunFailed, match="Newton's method did not converge in 1 iterations at step 1"
    ) as info:
        run_eld(problem, "regularized", 0.1, newton=NewtonOptions(tol=1e-15, max_iter=1))
    exc = info.value
    assert exc.where["step"] == 1 and exc.where["t"] == 0.0
    assert len(exc.trajectory["t"]) == 1  # only the initial state
    assert exc.trajectory.stats.accepted_steps == 0


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
    a = run_eld(problem, "regularized", 0.05)
    b = run_eld(numeric, "regularized", 0.05)
    assert np.abs(a["u"] - b["u"]).max() < 1e-6
    assert np.abs(a["lam"] - b["lam"]).max() < 1e-4


def test_user_damping_matrix_reproduces_rayleigh_and_amg_matches_lu():
    problem, _ = mms_problem(2, 1, damping=RayleighDamping(a=0.2, b=0.01))
    ref = run_eld(problem, "regularized", 0.05)
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
    other = run_eld(user, "regularized", 0.05)
    assert np.abs(other["u"] - ref["u"]).max() <= 1e-12 * np.abs(ref["u"]).max()
    amg = run_eld(problem, "regularized", 0.05, solver="amg")
    assert amg.meta["solver"] == "amg"
    assert np.abs(amg["u"] - ref["u"]).max() <= 1e-7 * np.abs(ref["u"]).max()


def test_linear_damping_factors_once_and_backsubstitutes_per_step():
    problem, _ = mms_problem(3, 2, damping=RayleighDamping(a=0.1, b=0.01))
    for form in ("regularized", "original"):
        traj = run_eld(problem, form, 0.05)
        info = traj.meta["linear_solver"]
        assert info["factorizations"] == 1
        assert info["backsolves"] == 20  # one per step
        assert traj.stats.newton_iterations == 0


@pytest.mark.parametrize("scheme, order", [("euler", 1.0), ("bdf2", 2.0)])
def test_multiplier_depends_on_the_lifting_at_the_order_of_the_scheme(scheme, order):
    """docs/eld.md: with point data the regularized solution, lambda included, changes with the
    lifting at O(tau) (Euler) and O(tau^2) (BDF2); only data="differenced" makes it independent
    (test_regularized_with_differenced_data_reproduces_the_original_form)."""
    problem, _ = mms_problem(2, 2)
    gaps = []
    for tau in (0.1, 0.05, 0.025):
        lam = [
            run_eld(problem, "regularized", tau, scheme=scheme, lifting=lifting)["lam"]
            for lifting in ("nodal", "harmonic")
        ]
        gaps.append(float(np.max(np.abs(lam[0] - lam[1]))))
    assert gaps[0] > 1e-4  # a real difference, far above the solver tolerance
    rates = np.log2(np.array(gaps[:-1]) / np.array(gaps[1:]))
    assert np.all(rates > order - 0.3) and np.all(rates < order + 0.5), (gaps, rates)
