"""The linear solvers of the steps (rothe.eld.solvers): the AMG setup, the condensed bordered
solve of the original form."""

import numpy as np
import scipy.sparse as sp

from rothe.eld import ELDStepper, Original, RayleighDamping, beam_problem
from rothe.eld.solvers import ConstrainedSolver, ReferenceSolver
from rothe.eld.system import OriginalSystem
from rothe.stepping.controllers import Uniform


def test_amg_setup_is_reproducible_and_leaves_numpys_generator_alone():
    problem = beam_problem(3, damping=RayleighDamping(0.0, 0.002), T=0.02)
    stepper = ELDStepper(problem, control=Uniform(0.01), solver="direct")
    A = stepper.system.A_II
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


def test_condensed_bordered_solve_equals_the_kkt_solution():
    problem = beam_problem(2, damping=RayleighDamping(0.2, 0.01), T=0.02)
    stepper = ELDStepper(problem, form=Original(), control=Uniform(0.01), solver="direct")
    system = stepper.system
    assert (
        isinstance(system, OriginalSystem)
        and system.size == problem.space.ndofs + problem.constraint.m
    )
    c, n = problem.constraint, problem.space.ndofs
    A = ((1e4 + 0.2 / 0.01) * problem.M + (1.0 + 0.01 / 0.01) * problem.K).tocsr()
    kkt = system._kkt(A).tocsc()
    rng = np.random.default_rng(3)
    b = rng.standard_normal(n + c.m)
    z = sp.linalg.spsolve(kkt, b)
    for solver in (system.solver, ConstrainedSolver(c, "direct")):
        if not solver.factored:
            solver.factor(system._kkt(A))  # the Newton path hands over the bordered matrix
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
