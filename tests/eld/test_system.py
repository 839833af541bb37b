"""The linear system of the steps on one mesh (rothe.eld.system): the step matrix, AMG against
LU in both forms, one factorization for linear damping, the timed phases, the rebuild on another
mesh."""

import numpy as np
import pytest
import scipy.sparse as sp

from rothe.eld import (
    ELDStepper,
    ELDSystem,
    Original,
    RayleighDamping,
    Regularized,
    UserDamping,
    beam_problem,
    mms_problem,
    run_eld,
)
from rothe.eld.examples import pulse_problem
from rothe.eld.materials import Material, PiecewiseMaterial
from rothe.eld.system import RegularizedSystem
from rothe.stepping.controllers import Uniform


@pytest.mark.parametrize("degree", [1, 2])
def test_step_matrix_is_the_restriction_of_the_full_one(degree):
    problem = beam_problem(2, damping=RayleighDamping(0.3, 0.01), T=0.04, degree=degree)
    tau = 0.02
    stepper = ELDStepper(problem, control=Uniform(tau), solver="direct")
    system = stepper.system
    assert isinstance(system, RegularizedSystem)
    I = problem.constraint.free
    A = ((1.0 / tau**2 + 0.3 / tau) * problem.M + (1.0 + 0.01 / tau) * problem.K).tocsr()
    expected = A[I][:, I]
    assert system.A_II.format == "bsr"
    assert abs(system.A_II - expected).max() <= 1e-12 * abs(expected).max()
    # the thin columns of M and K on the constrained dofs, taken from their rows
    C = problem.constraint.dofs
    M_C, K_C = system._thin
    assert abs(K_C - problem.K.tocsr()[:, C]).max() == 0
    assert abs(M_C - problem.M[:, C]).max() == 0
    # a user damping matrix takes the general path: same matrix
    C_user = sp.csr_matrix(0.3 * problem.M + 0.01 * problem.K)
    problem.damping_op = UserDamping(matrix=C_user, d0=0.0).operator(
        problem.space, problem.M, problem.K
    )
    user = ELDStepper(problem, control=Uniform(tau), solver="direct")
    assert abs(user.system.A_II - expected).max() <= 1e-12 * abs(expected).max()


def test_amg_and_lu_give_the_same_reactions():
    problem = beam_problem(3, damping=RayleighDamping(0.0, 0.002), T=0.1)
    amg = run_eld(
        problem, control=Uniform(0.01), solver="amg", store_fields=False, linear_rtol=1e-10
    ).trajectory
    lu = run_eld(problem, control=Uniform(0.01), solver="direct", store_fields=False).trajectory
    R_amg, R_lu = np.array(amg["reaction_left"]), np.array(lu["reaction_left"])
    assert np.abs(R_amg - R_lu).max() <= 1e-7 * np.abs(R_lu).max()
    assert np.abs(amg["balance_residual"]).max() <= 1e-8 * np.abs(amg["energy"]).max()


def test_original_form_runs_with_amg_and_matches_lu():
    problem = beam_problem(3, damping=RayleighDamping(0.0, 0.002), T=0.05)
    amg = run_eld(
        problem,
        form=Original(),
        control=Uniform(0.01),
        solver="amg",
        store_fields=False,
        linear_rtol=1e-11,
    ).trajectory
    lu = run_eld(
        problem, form=Original(), control=Uniform(0.01), solver="direct", store_fields=False
    ).trajectory
    assert amg.meta["linear_solver"]["kind"] == "amg"
    R_amg, R_lu = np.array(amg["reaction_left"]), np.array(lu["reaction_left"])
    assert np.abs(R_amg - R_lu).max() <= 1e-7 * np.abs(R_lu).max()


def test_linear_damping_factors_once_and_backsubstitutes_per_step():
    problem, _ = mms_problem(3, 2, damping=RayleighDamping(a=0.1, b=0.01))
    for form in (Regularized(), Original()):
        traj = run_eld(problem, form=form, control=Uniform(0.05)).trajectory
        info = traj.meta["linear_solver"]
        assert info["factorizations"] == 1
        assert info["backsolves"] == 20  # one per step
        assert traj.stats.newton_iterations == 0
        # the factorization and the solves are timed
        assert traj.stats.seconds["factor"] > 0 and traj.stats.seconds["solve"] > 0


def test_a_system_rebuilt_on_a_new_problem_continues_the_counters():
    problem, _ = mms_problem(2, 2, damping=RayleighDamping(a=0.1, b=0.01))
    system = ELDSystem.build(problem, Regularized("harmonic"), tau_eff=0.01, variable_steps=False)
    assert system.initial_factorizations == 1 and system.reference == {"tau_eff": 0.01, "v": None}
    system.solver.stats.backsolves = 7
    other, _ = mms_problem(3, 2, damping=RayleighDamping(a=0.1, b=0.01))
    new = system.rebuilt(other)
    assert type(new) is RegularizedSystem and new.problem is other
    assert new.lifting is not system.lifting and new.ndofs == other.space.ndofs
    assert new.solver.stats.backsolves == 7 and new.solver.stats.factorizations == 2
    assert system.solver.stats.factorizations == 1  # the old system is not changed


@pytest.mark.parametrize("form", [Regularized("nodal"), Original()])
def test_several_densities_step_with_the_weighted_mass(form):
    """The step matrix on the free dofs is gathered from K and the scalar mass
    (VectorSpace.restricted_combination); with several materials that mass must be the cells'
    rho_c/rho_ref, as the problem's M (it was density 1: the solver then solved another system,
    the ledger's residual work was 30 % of the energy and rho_ref = 1 blew the run up). The run
    does not depend on the reference density, and the algebraic residual is round-off."""
    mesh = pulse_problem(2, T=0.1).space.mesh
    centroids = mesh.p[:, mesh.t].mean(axis=1)
    mesh = mesh.with_subdomains(
        {"a": np.flatnonzero(centroids[0] < 1), "b": np.flatnonzero(centroids[0] >= 1)}
    )
    runs = []
    for reference in (None, 1.0):
        mats = PiecewiseMaterial(
            {"light": Material(1.0, 2.0, 1.0), "heavy": Material(4.0, 2.0, 1.0)},
            regions={"a": "light", "b": "heavy"},
            reference_density=reference,
        )
        problem = pulse_problem(mesh=mesh, material=mats, T=0.2, degree=2)
        runs.append(run_eld(problem, form=form, control=Uniform(0.02)).trajectory)
    for traj in runs:
        assert np.abs(traj["residual_work"]).max() < 1e-12 * traj["energy"].max()
        assert np.abs(traj["balance_residual"]).max() < 1e-12 * traj["energy"].max()
    assert np.allclose(runs[0]["energy"], runs[1]["energy"], rtol=1e-10, atol=0)
    assert np.allclose(runs[0]["reaction_left"], runs[1]["reaction_left"], rtol=1e-9, atol=1e-14)
