"""Step matrix and AMG path of the ELD steps (rothe.eld.solvers, ELDStepper's matrices)."""

import numpy as np
import pytest
import scipy.sparse as sp

from rothe.eld import ELDStepper, RayleighDamping, UserDamping, beam_problem, run_eld
from rothe.eld.solvers import ConstrainedSolver, ReferenceSolver


@pytest.mark.parametrize("degree", [1, 2])
def test_step_matrix_is_the_restriction_of_the_full_one(degree):
    problem = beam_problem(2, damping=RayleighDamping(0.3, 0.01), T=0.04, degree=degree)
    tau = 0.02
    stepper = ELDStepper(problem, "regularized", tau, solver="direct")
    I = problem.constraint.free
    A = ((1.0 / tau**2 + 0.3 / tau) * problem.M + (1.0 + 0.01 / tau) * problem.K).tocsr()
    expected = A[I][:, I]
    assert stepper.A_II.format == "bsr"
    assert abs(stepper.A_II - expected).max() <= 1e-12 * abs(expected).max()
    # the thin columns of M and K on the constrained dofs, taken from their rows
    C = problem.constraint.dofs
    assert abs(stepper._K_C - problem.K.tocsr()[:, C]).max() == 0
    assert abs(stepper._M_C - problem.M[:, C]).max() == 0
    # a user damping matrix takes the general path: same matrix
    C_user = sp.csr_matrix(0.3 * problem.M + 0.01 * problem.K)
    problem.damping_op = UserDamping(matrix=C_user, d0=0.0).operator(
        problem.space, problem.M, problem.K
    )
    user = ELDStepper(problem, "regularized", tau, solver="direct")
    assert abs(user.A_II - expected).max() <= 1e-12 * abs(expected).max()


def test_amg_setup_is_reproducible_and_leaves_numpys_generator_alone():
    problem = beam_problem(3, damping=RayleighDamping(0.0, 0.002), T=0.02)
    stepper = ELDStepper(problem, "regularized", 0.01, solver="direct")
    A = stepper.A_II
    rbm = problem.space.rigid_body_modes(
        np.setdiff1d(np.arange(problem.space.n_scalar), problem.constraint.scalar_dofs)
    )
    b = A @ np.linspace(-1.0, 1.0, A.shape[0])
    np.random.seed(7)
    state = np.random.get_state()
    solves = []
    for _ in range(2):
        solver = ReferenceSolver("amg", spd=True, near_nullspace=rbm, rtol=1e-10)
        solver.factor(A)
        # the coarse-level LU exists before the first solve (it is part of the setup)
        assert hasattr(solver._ml.coarse_solver, "LU")
        solves.append(solver.solve_reference(b))
        assert solver.stats.krylov_iterations <= 25
    assert np.array_equal(solves[0], solves[1])
    assert np.array_equal(np.random.get_state()[1], state[1])
    x = sp.linalg.spsolve(A.tocsc(), b)
    assert np.linalg.norm(solves[0] - x) <= 1e-8 * np.linalg.norm(x)


def test_amg_and_lu_give_the_same_reactions():
    problem = beam_problem(3, damping=RayleighDamping(0.0, 0.002), T=0.1)
    amg = run_eld(problem, "regularized", 0.01, solver="amg", store_fields=False, linear_rtol=1e-10)
    lu = run_eld(problem, "regularized", 0.01, solver="direct", store_fields=False)
    R_amg, R_lu = np.array(amg["reaction_left"]), np.array(lu["reaction_left"])
    assert np.abs(R_amg - R_lu).max() <= 1e-7 * np.abs(R_lu).max()
    assert np.abs(amg["balance_residual"]).max() <= 1e-8 * np.abs(amg["energy"]).max()


def test_condensed_bordered_solve_equals_the_kkt_solution():
    problem = beam_problem(2, damping=RayleighDamping(0.2, 0.01), T=0.02)
    stepper = ELDStepper(problem, "original", 0.01, solver="direct")
    c, n = problem.constraint, problem.space.ndofs
    A = ((1e4 + 0.2 / 0.01) * problem.M + (1.0 + 0.01 / 0.01) * problem.K).tocsr()
    kkt = stepper._kkt(A).tocsc()
    rng = np.random.default_rng(3)
    b = rng.standard_normal(n + c.m)
    z = sp.linalg.spsolve(kkt, b)
    for solver in (stepper.solver, ConstrainedSolver(c, "direct")):
        if not solver.factored:
            solver.factor(stepper._kkt(A))  # the Newton path hands over the bordered matrix
        assert np.linalg.norm(solver.solve_reference(b) - z) <= 1e-10 * np.linalg.norm(z)
    amg = ConstrainedSolver(
        c,
        "amg",
        near_nullspace=problem.space.rigid_body_modes(
            np.setdiff1d(np.arange(problem.space.n_scalar), c.scalar_dofs)
        ),
        rtol=1e-12,
    )
    amg.factor(A)
    assert np.linalg.norm(amg.solve_reference(b) - z) <= 1e-8 * np.linalg.norm(z)


def test_original_form_runs_with_amg_and_matches_lu():
    problem = beam_problem(3, damping=RayleighDamping(0.0, 0.002), T=0.05)
    amg = run_eld(problem, "original", 0.01, solver="amg", store_fields=False, linear_rtol=1e-11)
    lu = run_eld(problem, "original", 0.01, solver="direct", store_fields=False)
    assert amg.meta["linear_solver"]["kind"] == "amg"
    R_amg, R_lu = np.array(amg["reaction_left"]), np.array(lu["reaction_left"])
    assert np.abs(R_amg - R_lu).max() <= 1e-7 * np.abs(R_lu).max()
