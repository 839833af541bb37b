"""Elastodynamics as an operator DAE, discretized in time first (Altmann 2015).

    rho u'' + D(u') + K u + B* lambda = F,   B u = G      (2.7, original, index 3)
    u = u1 + u2, B u2 = G, B v2 = G', B w2 = G'',
    rho (u1'' + w2) + D(u1' + v2) + K (u1 + u2) + B* lambda = F   (2.8, regularized, index 1)

Implicit Euler (3.4) and variable-step BDF2 (``scheme=ImplicitEuler()`` or ``BDF2()``) in both
forms (``form=Regularized(lifting=...)`` or ``Original()``), with uniform steps, a given step
sequence or adaptive steps (``control=Uniform(tau)``, ``Given(steps)`` or ``Adaptive(tol)``) on
the shared evolve loop (:func:`run_eld`, returning an :class:`ELDResult`), on vector P1/P2
elements (:class:`rothe.fem.elasticity.VectorSpace`),
with Dirichlet data enforced weakly by a Lagrange multiplier (the boundary reaction), linear or
nonlinear damping with the constants of (2.5), the step bound of Lemma 3.2, energy bookkeeping,
the perturbation behaviour of Theorem 4.5, stresses (:mod:`rothe.eld.stress`) and outputs for
ParaView (:func:`write_eld_result`), and meshes that adapt between steps
(``adapt=SpaceAdaptivity(...)``, :mod:`rothe.eld.adapt`). See ``docs/eld.md``.

The package: :mod:`~rothe.eld.scheme` (the schemes' coefficients), :mod:`~rothe.eld.form`,
:mod:`~rothe.eld.data` (data modes and noise), :mod:`~rothe.eld.state` (state, energy ledger,
step result), :mod:`~rothe.eld.system` (the linear system on one mesh), :mod:`~rothe.eld.start`
(initial state, BDF2 history), :mod:`~rothe.eld.stepper` (one step, the adapt step, records,
checkpoints), :mod:`~rothe.eld.run` (the driver), :mod:`~rothe.eld.adapt` (space adaptivity).

Coupled systems (``docs/coupling.md``, issue 19): components (:mod:`rothe.eld.components`),
couplings B u = G(t, q) and :class:`CoupledProblem` (:mod:`rothe.eld.coupling`), sensors and
controllers (:mod:`rothe.eld.control`), the bordered coupled step (:mod:`rothe.eld.coupled_step`),
coupled runs on the evolve loop (:func:`run_coupled`, :mod:`rothe.eld.coupled_run`), interfaces
between bodies (:mod:`rothe.eld.interface`), glued bodies stepped in time (:func:`run_bodies`,
:mod:`rothe.eld.bodies`), several materials (:class:`PiecewiseMaterial`),
analytic references (:mod:`rothe.eld.frequencies`).
"""

from .adapt import ELDMeshes
from .bodies import Body, GluedBodies, run_bodies
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
from .coupled_run import CoupledResult, CoupledStepper, run_coupled, run_coupled_many
from .coupled_step import CoupledStepSystem, closed_loop_matrices, closed_loop_roots, coupled_modes
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
from .data import DataMode, DataNoise, Differenced, Means, Points, StepData
from .examples import ManufacturedSolution, beam_problem, mms_errors, mms_problem, ramp_problem
from .form import Form, Original, Regularized
from .interface import Interface
from .materials import Material, PiecewiseMaterial
from .output import write_eld_result
from .problem import CellwiseLoad, DirichletData, ELDProblem
from .run import ELDResult, ELDRun, prepare_eld_run, run_eld
from .scheme import BDF2, ImplicitEuler, Scheme
from .state import ELDCode, ELDState, ELDStepResult, EnergyLedger
from .stepper import ELDStepper, NewtonOptions
from .stress import StressEvaluator, cauchy_stress, von_mises
from .studies import convergence_study, perturbation_study
from .system import ELDSystem

__all__ = [
    "BDF2",
    "Body",
    "Component",
    "CoupledProblem",
    "CoupledResult",
    "CoupledStepper",
    "CoupledStepSystem",
    "Coupling",
    "Damping",
    "DampingConstants",
    "DataMode",
    "DataNoise",
    "Differenced",
    "DirichletConstraint",
    "DirichletData",
    "ELDCode",
    "ELDMeshes",
    "ELDProblem",
    "ELDResult",
    "ELDRun",
    "ELDState",
    "ELDStepResult",
    "ELDStepper",
    "ELDSystem",
    "EnergyLedger",
    "Form",
    "GluedBodies",
    "HarmonicLifting",
    "ImplicitEuler",
    "Interface",
    "LinearComponent",
    "LinearController",
    "ManufacturedSolution",
    "CellwiseLoad",
    "MassSpringDamper",
    "Material",
    "Means",
    "NewtonOptions",
    "NoDamping",
    "NodalLifting",
    "NonlinearDamping",
    "Original",
    "PiecewiseMaterial",
    "PointMass",
    "PointSensor",
    "Points",
    "RayleighDamping",
    "ReactionSensor",
    "Regularized",
    "RigidBody",
    "RigidMotion",
    "Scheme",
    "StepData",
    "StressEvaluator",
    "Translation",
    "TunedMassDamper",
    "UserComponent",
    "UserController",
    "UserCoupling",
    "UserDamping",
    "beam_problem",
    "cauchy_stress",
    "convergence_study",
    "closed_loop_matrices",
    "closed_loop_roots",
    "coupled_modes",
    "run_bodies",
    "run_coupled",
    "run_coupled_many",
    "make_damping",
    "mms_errors",
    "mms_problem",
    "perturbation_study",
    "prepare_eld_run",
    "ramp_problem",
    "run_eld",
    "von_mises",
    "write_eld_result",
]
