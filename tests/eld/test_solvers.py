"""The linear solvers of the steps (rothe.eld.solvers): the AMG setup, the condensed bordered
solve of the original form."""

import numpy as np
import scipy.sparse as sp

from rothe.eld import ELDStepper, Original, RayleighDamping, beam_problem
from rothe.eld.solvers import (
    JACOBI_CFL,
    SHORT_LIVED_AMG,
    ConstrainedSolver,
    ReferenceSolver,
    jacobi_scaled,
)
from rothe.eld.system import OriginalSystem
from rothe.fem.elasticity import BlockMatrix
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


def test_auto_takes_amg_earlier_on_the_meshes_of_an_adaptive_3d_run():
    """'auto': LU up to 200k unknowns in 2D, 30k in 3D, and on a 3D mesh a space-adaptive run
    built (it lives adapt_every steps, its LU is not amortized) up to 1.5k; 2D unchanged."""
    from rothe.eld.solvers import resolve_kind

    assert resolve_kind("auto", 150_000, 2) == resolve_kind("auto", 150_000, 2, True) == "direct"
    assert resolve_kind("auto", 10_000, 3) == "direct"
    assert resolve_kind("auto", 10_000, 3, short_lived=True) == "amg"
    assert resolve_kind("auto", 2_000, 3, short_lived=True) == "amg"
    assert resolve_kind("auto", 1_500, 3, short_lived=True) == "direct"
    assert resolve_kind("direct", 10_000, 3, short_lived=True) == "direct"
    # above the LU limit: Jacobi-CG when the mesh's CFL number is moderate, else AMG; never
    # on fixed meshes, in 2D, or when a kind is asked for
    assert resolve_kind("auto", 10_000, 3, True, cfl=0.4) == "jacobi"
    assert resolve_kind("auto", 10_000, 3, True, cfl=JACOBI_CFL) == "jacobi"
    assert resolve_kind("auto", 10_000, 3, True, cfl=1.01 * JACOBI_CFL) == "amg"
    assert resolve_kind("auto", 1_000, 3, True, cfl=0.4) == "direct"
    assert resolve_kind("auto", 40_000, 3, False, cfl=0.4) == "amg"
    assert resolve_kind("auto", 250_000, 2, True, cfl=0.4) == "amg"
    assert resolve_kind("amg", 10_000, 3, True, cfl=0.4) == "amg"


def test_a_rebuilt_3d_mesh_above_the_short_lived_limit_runs_on_jacobi_cg_or_amg(monkeypatch):
    """The adapt step's rebuild passes short_lived: the first mesh keeps LU (below 30k), the
    rebuilt one above 1.5k unknowns gets Jacobi-CG at its CFL number (0.09 here) and AMG
    above JACOBI_CFL; either solves to the LU answer on the same mesh (to the Krylov
    tolerance: the scaled residual 1e-10 of a matrix of condition ~10)."""
    import rothe.eld.solvers as solvers
    from rothe.eld import BDF2, prepare_eld_run
    from rothe.eld.examples import pulse_3d_problem
    from rothe.fem.adapt import SpaceAdaptivity
    from rothe.stepping.controllers import Uniform

    problem = pulse_3d_problem(6, T=0.04)  # P2, 6 591 dofs
    run = prepare_eld_run(
        problem,
        scheme=BDF2(),
        control=Uniform(0.02),
        adapt=SpaceAdaptivity(space_tol=1e-6, max_dofs=60_000, adapt_every=1),
    )
    first = run.stepper.system
    assert first.kind == "direct"
    new = run.stepper.adaptivity.rebuild(first, first.problem.space.mesh)
    te = 0.02 / 1.5  # BDF2's tau / alpha_0
    # c_p tau_eff / h_min with the Rayleigh term: c_p = 2, h_min = sqrt(3)/6
    cfl = 2.0 * np.sqrt((1.0 + 0.001 / te) / (1.0 / te**2)) / (np.sqrt(3.0) / 6)
    assert abs(new.cfl(te) - cfl) <= 1e-12 * cfl and cfl < 0.1
    assert 1_500 < new.I.size < 30_000 and new.kind == "jacobi"
    # no setup: the stored step matrix itself and its inverse diagonal, no hierarchy
    assert new.solver._A is new.A_II and new.solver._ml is None
    assert np.array_equal(new.solver._scale, 1.0 / new.A_II.diagonal())
    monkeypatch.setattr(solvers, "JACOBI_CFL", 0.5 * cfl)
    amg = run.stepper.adaptivity.rebuild(new, first.problem.space.mesh)
    assert amg.kind == "amg"
    # the short-lived mesh's AMG: plain aggregation (one level of smoothed prolongation less)
    assert amg.solver.amg_options == SHORT_LIVED_AMG == {"smooth": None}
    assert first.rebuilt(first.problem, solver="amg").solver.amg_options == {}
    lu = first.rebuilt(first.problem, symmetric_lu=True)
    rhs = np.random.default_rng(0).standard_normal(first.I.size)
    assert lu.kind == "direct"
    x_lu = lu.solver.solve_reference(rhs)
    for system, most in ((new.revived(), 40), (amg, 15)):
        before = system.solver.stats.krylov_iterations
        x = system.solver.solve_reference(rhs)
        assert system.solver.stats.krylov_iterations - before <= most
        assert np.linalg.norm(x - x_lu) <= 1e-8 * np.linalg.norm(x_lu)


def test_jacobi_cg_stops_on_the_scaled_residual_and_gives_up_at_maxiter():
    """jacobi_cg: ||D^{-1/2}(b - A x)|| <= rtol ||D^{-1/2} b|| at the end (the AMG path's
    rule), the iterates of CG on the scaled system (same iteration count as scipy's CG on
    D^{-1/2} A D^{-1/2}), no iteration from the solution, None at maxiter."""
    from rothe.eld.solvers import jacobi_cg

    problem = beam_problem(4, damping=RayleighDamping(0.0, 0.002), T=0.02)
    stepper = ELDStepper(problem, control=Uniform(0.01), solver="direct")
    A = stepper.system.A_II
    inv = 1.0 / A.diagonal()
    b = A @ np.linspace(-1.0, 1.0, A.shape[0])
    x, its = jacobi_cg(A, inv, b, None, 1e-10, 500)
    r = np.sqrt(inv) * (b - A @ x)
    assert np.linalg.norm(r) <= 1.01e-10 * np.linalg.norm(np.sqrt(inv) * b)
    As, s = jacobi_scaled(A)
    count = [0]
    sp.linalg.cg(
        As,
        s * b,
        rtol=1e-10,
        atol=0.0,
        maxiter=500,
        callback=lambda _: count.__setitem__(0, count[0] + 1),
    )
    assert abs(its - count[0]) <= 1 and its > 5
    exact = sp.linalg.spsolve(A.tocsc(), b)
    assert np.linalg.norm(x - exact) <= 1e-7 * np.linalg.norm(exact)
    assert jacobi_cg(A, inv, b, exact, 1e-10, 500)[1] <= 1
    assert jacobi_cg(A, inv, b, None, 1e-10, its - 2) == (None, its - 2)
    # the solver kind: the same answer, its iterations counted; nothing to solve: zero
    solver = ReferenceSolver("jacobi", spd=True, rtol=1e-10)
    solver.factor(A)
    assert np.array_equal(solver.solve_reference(b), x)
    assert solver.stats.krylov_iterations == its and solver.stats.solves == 1
    assert not np.any(solver.solve_reference(np.zeros_like(b)))


def test_jacobi_iterations_are_bounded_by_the_cfl_number_not_the_mesh():
    """At the same CFL number c_p tau_eff / h_min the Jacobi-CG iterations of the step matrix
    stay put when the mesh is refined (8 times the cells; measured for a random right-hand
    side, n = 2, 3, 4, 6, 8: 72-74 at CFL 0.5, 105-132 at 1), and grow with the CFL number."""
    from rothe.eld.examples import pulse_3d_problem
    from rothe.eld.form import Regularized
    from rothe.eld.system import ELDSystem

    rng = np.random.default_rng(4)
    its = {}
    for n in (3, 6):
        problem = pulse_3d_problem(n, T=0.1)
        h = np.sqrt(3.0) / n
        for cfl in (0.5, 1.0):
            system = ELDSystem.build(
                problem, Regularized(), tau_eff=cfl * h / 2.0, variable_steps=False, solver="direct"
            )
            solver = ReferenceSolver("jacobi", spd=True, rtol=1e-10)
            solver.factor(system.A_II)
            solver.solve_reference(rng.standard_normal(system.I.size))
            its[n, cfl] = solver.stats.krylov_iterations
    for cfl in (0.5, 1.0):
        assert its[6, cfl] <= 1.2 * its[3, cfl]
    assert its[3, 1.0] > 1.4 * its[3, 0.5] and its[6, 1.0] > 1.4 * its[6, 0.5]


def test_amg_is_blind_to_a_diagonal_scaling_of_the_matrix():
    """The hierarchy is built for D^{-1/2} A D^{-1/2}: a matrix S A S with a diagonal S spread
    over two orders of magnitude (the diagonal of a graded mesh's step matrix spreads with the
    cell volumes) takes as many CG iterations as A itself, and the answer is right; the BSR
    scaling equals the CSR product to round-off."""
    problem = beam_problem(6, damping=RayleighDamping(0.0, 0.002), T=0.02)  # 3 528 unknowns
    stepper = ELDStepper(problem, control=Uniform(0.01), solver="direct")
    A = stepper.system.A_II
    rbm = problem.space.rigid_body_modes(
        np.setdiff1d(np.arange(problem.space.n_scalar), problem.constraint.scalar_dofs)
    )
    rng = np.random.default_rng(1)
    scale = 10.0 ** rng.uniform(0.0, 2.0, A.shape[0] // 3).repeat(3)
    S = sp.diags(scale)
    graded = sp.bsr_matrix(S @ A @ S, blocksize=(3, 3))
    As, s = jacobi_scaled(graded)
    dense = sp.diags(s) @ graded.tocsr() @ sp.diags(s)
    assert As.format == "bsr" and abs(As - dense).max() <= 1e-14 * abs(dense).max()
    # a BlockMatrix stays one (its compiled product is the AMG cycle's main cost at scale)
    assert type(jacobi_scaled(A)[0]) is type(A) is BlockMatrix
    iterations = []
    for M, modes in ((A, rbm), (graded, rbm / scale[:, None])):
        b = M @ np.linspace(-1.0, 1.0, M.shape[0])
        # three levels (max_coarse 50); without the scaling the graded matrix took 349
        # iterations instead of 15
        solver = ReferenceSolver(
            "amg", spd=True, near_nullspace=modes, rtol=1e-10, amg_options={"max_coarse": 50}
        )
        solver.factor(M)
        assert len(solver._ml.levels) == 3
        x = solver.solve_reference(b)
        assert np.linalg.norm(x - np.linspace(-1.0, 1.0, M.shape[0])) <= 1e-7 * np.sqrt(M.shape[0])
        iterations.append(solver.stats.krylov_iterations)
    assert abs(iterations[1] - iterations[0]) <= 1 and iterations[0] <= 25


def test_v_cycle_is_pyamgs_cycle_and_the_solve_pyamgs_cg_with_fewer_fine_products():
    """rothe.fem.linear.v_cycle is the cycle of pyamg's aspreconditioner bit for bit (three
    levels, Chebyshev smoothing), without its two fine-level residual products; the ELD solve
    (scipy's CG preconditioned by it) takes pyamg's iterations to the same answer, with at most
    7 + 2/its products with the fine matrix per iteration (pyamg's: 9 and more)."""
    from rothe.fem.linear import v_cycle

    problem = beam_problem(6, damping=RayleighDamping(0.0, 0.002), T=0.02)
    stepper = ELDStepper(problem, control=Uniform(0.01), solver="direct")
    A = stepper.system.A_II
    rbm = problem.space.rigid_body_modes(
        np.setdiff1d(np.arange(problem.space.n_scalar), problem.constraint.scalar_dofs)
    )
    solver = ReferenceSolver(
        "amg", spd=True, near_nullspace=rbm, rtol=1e-10, amg_options={"max_coarse": 50}
    )
    solver.factor(A)
    ml = solver._ml
    assert len(ml.levels) == 3
    r = np.cos(np.arange(A.shape[0]) * 0.37)
    assert np.array_equal(v_cycle(ml, r), ml.aspreconditioner(cycle="V") @ r)

    x_true = np.linspace(-1.0, 1.0, A.shape[0])
    b = A @ x_true
    As = ml.levels[0].A
    calls = [0]
    product = type(As)._matmul_vector

    def counted(self, other):
        if self is As:
            calls[0] += 1
        return product(self, other)

    type(As)._matmul_vector = counted
    try:
        x = solver.solve_reference(b)
        ours = calls[0]
        calls[0] = 0
        residuals = []
        ml.solve(solver._scale * b, tol=1e-10, accel="cg", maxiter=500, residuals=residuals)
        theirs = calls[0]
    finally:
        type(As)._matmul_vector = product
    its = solver.stats.krylov_iterations
    assert its == len(residuals) - 1
    assert np.linalg.norm(x - x_true) <= 1e-7 * np.linalg.norm(x_true)
    assert ours <= 7 * its + 2 and theirs >= 9 * its
