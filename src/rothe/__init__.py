"""rothe: time-first (Rothe) discretizations for solid mechanics.

Rate-independent systems with non-convex energy (adaptive balanced-viscosity paths, Andreia &
Meyer 2022) and elastodynamics with time-dependent Dirichlet constraints as operator DAEs
(Altmann 2015).
"""

from .control.controllers import (
    AdaptiveController,
    Order2Controller,
    UniformController,
    make_controller,
)
from .errors import RotheInputError, RunFailed
from .io.trajectory import RunStatistics, Trajectory
from .nonlinear.ris_inner import BallStepSolver, InnerOptions
from .problems.ris import RISProblem
from .stepping.evolve import evolve
from .stepping.ris import RISStepper, run_nested, run_ris

__version__ = "0.1.0"

__all__ = [
    "AdaptiveController",
    "BallStepSolver",
    "InnerOptions",
    "Order2Controller",
    "RISProblem",
    "RISStepper",
    "RotheInputError",
    "RunFailed",
    "RunStatistics",
    "Trajectory",
    "UniformController",
    "evolve",
    "make_controller",
    "run_nested",
    "run_ris",
]
