"""Elastodynamics as an operator DAE, discretized in time first (Altmann 2015).

    rho u'' + D(u') + K u + B* lambda = F,   B u = G      (2.7, original, index 3)
    u = u1 + u2, B u2 = G, B v2 = G', B w2 = G'',
    rho (u1'' + w2) + D(u1' + v2) + K (u1 + u2) + B* lambda = F   (2.8, regularized, index 1)

Implicit Euler (3.4) and variable-step BDF2 in both forms (:func:`run_eld`, ``scheme=``), with
uniform steps, a given step sequence or adaptive steps (``control='adaptive'``, ``tol=``) on
the shared evolve loop, on vector P1/P2 elements (:class:`rothe.fem.elasticity.VectorSpace`),
with Dirichlet data enforced weakly by a Lagrange multiplier (the boundary reaction), linear or
nonlinear damping with the constants of (2.5), the step bound of Lemma 3.2, energy bookkeeping,
the perturbation behaviour of Theorem 4.5, stresses (:mod:`rothe.eld.stress`) and outputs for
ParaView (:func:`write_eld_result`). See ``docs/eld.md``.

Coupled systems (``docs/coupling.md``, issue 19): components (:mod:`rothe.eld.components`),
couplings B u = G(t, q) and :class:`CoupledProblem` (:mod:`rothe.eld.coupling`), sensors and
controllers (:mod:`rothe.eld.control`), the bordered coupled step (:mod:`rothe.eld.coupled_step`),
interfaces between bodies (:mod:`rothe.eld.interface`), several materials
(:class:`PiecewiseMaterial`), analytic references (:mod:`rothe.eld.frequencies`).
"""

from .components import (
    Component,
    LinearComponent,
    MassSpringDamper,
    PointMass,
    RigidBody,
    TunedMassDamper,
    UserComponent,
)
from .constraint import DirichletConstraint, HarmonicLifting, NodalLifting
from .control import LinearController, PointSensor, ReactionSensor, UserController
from .coupled_step import CoupledStepSystem, coupled_modes, run_coupled_reference
from .coupling import (
    CoupledProblem,
    Coupling,
    RigidMotion,
    Translation,
    UserCoupling,
)
from .damping import (
    Damping,
    DampingConstants,
    NoDamping,
    NonlinearDamping,
    RayleighDamping,
    UserDamping,
    make_damping,
)
from .data import DataNoise, StepData
from .examples import ManufacturedSolution, beam_problem, mms_errors, mms_problem, ramp_problem
from .interface import Interface
from .materials import Material, PiecewiseMaterial
from .output import write_eld_result
from .problem import DirichletData, ELDProblem
from .schemes import (
    ELDRun,
    ELDState,
    ELDStepper,
    NewtonOptions,
    prepare_eld_run,
    run_eld,
    step_coefficients,
)
from .stress import StressEvaluator, cauchy_stress, von_mises
from .studies import convergence_study, perturbation_study

__all__ = [
    "Component",
    "CoupledProblem",
    "CoupledStepSystem",
    "Coupling",
    "Interface",
    "LinearComponent",
    "LinearController",
    "MassSpringDamper",
    "PiecewiseMaterial",
    "PointMass",
    "PointSensor",
    "ReactionSensor",
    "RigidBody",
    "RigidMotion",
    "Translation",
    "TunedMassDamper",
    "UserComponent",
    "UserController",
    "UserCoupling",
    "coupled_modes",
    "run_coupled_reference",
    "Damping",
    "DampingConstants",
    "DataNoise",
    "DirichletConstraint",
    "DirichletData",
    "ELDProblem",
    "ELDRun",
    "ELDState",
    "ELDStepper",
    "HarmonicLifting",
    "ManufacturedSolution",
    "Material",
    "NewtonOptions",
    "NoDamping",
    "NodalLifting",
    "NonlinearDamping",
    "RayleighDamping",
    "StepData",
    "StressEvaluator",
    "UserDamping",
    "beam_problem",
    "cauchy_stress",
    "convergence_study",
    "make_damping",
    "mms_errors",
    "mms_problem",
    "perturbation_study",
    "prepare_eld_run",
    "ramp_problem",
    "run_eld",
    "step_coefficients",
    "von_mises",
    "write_eld_result",
]
