"""rothe: time-first (Rothe) discretizations for solid mechanics.

Two families, each with its own API:

* Rate-independent systems with non-convex energy (Andreia & Meyer 2022): parametrized
  balanced-viscosity solutions by the local incremental stationary scheme with uniform,
  adaptive (Alg. 3.2), nested (Alg. 6.2), order2 and regime step control. Exported here:
  ``RISProblem`` (I(t, z) = 1/2 <Az, z> + F(z) - <l(t), z> in R^n), ``run_ris(problem,
  Adaptive(tol=1e-4))`` -> ``RISResult``, ``run_nested(problem, Nested(tols))``, the
  step-control objects ``Uniform``, ``Adaptive``, ``Order2``, ``Regime``, ``Nested``,
  ``Trajectory``; the whole family in ``rothe.ris`` (``help(rothe.ris)``: ``FERISProblem``,
  the examples 7.1, 7.2 and the front) and meshes in ``rothe.fem.mesh`` (``unit_square``,
  ``load_mesh``).
* Elastodynamics with time-dependent Dirichlet constraints as operator DAEs (Altmann 2015):
  ``rothe.eld`` (``run_eld`` with implicit Euler or BDF2 and uniform or adaptive steps,
  ``ELDProblem``, ``Material``, the damping classes, ``DirichletData``); see
  ``help(rothe.eld)``.

Shared by both, in layers that know no family (``docs/architecture.md``): the step-control
objects ``Uniform(tau)``, ``Given(steps)``, ``Adaptive(tol, ...)`` (``rothe.stepping.controllers``)
and the loop ``evolve`` that shows every phase (propose, step, accept or reject, adapt, record,
checkpoint); meshes that change between steps (``rothe.fem.adapt.SpaceAdaptivity``, passed as
``adapt=`` to ``run_ris`` and ``run_eld``, through the one adapt cycle
``rothe.fem.adapt.cycle.MeshAdaptation``); checkpoints and bit-for-bit resume (``checkpoint=`` /
``resume=`` of the run functions); ParaView output and figures (``rothe.io``,
``rothe.plotting``); independent runs on Dask (``rothe.parallel``). Input errors are
``RotheInputError`` naming the parameter; a failed solve is ``RunFailed`` (never an accepted
step).

Command line: ``rothe`` lists the commands (``rothe run ris-1d``, ``rothe run eld-beam``,
``rothe sweep``, ``rothe resume``, ...); ``rothe <verb> <name> --help`` their options.
Documentation with the papers' equation numbers: docs/architecture.md (read first),
docs/ris.md, docs/ris_fem.md, docs/eld.md, docs/adaptivity.md, docs/robustness.md and
docs/scaling.md in the source distribution, and the docstrings.
"""

from ._version import __version__ as __version__
from .errors import RotheInputError, RunFailed
from .io.trajectory import RunStatistics, Trajectory
from .ris.controllers import (
    AdaptiveController,
    Nested,
    Order2,
    Order2Controller,
    Regime,
    RegimeController,
)
from .ris.inner import BallStepSolver, InnerOptions
from .ris.problem import RISProblem
from .ris.run import RISResult, run_nested, run_ris
from .ris.stepper import RISStepper
from .stepping.controllers import Adaptive, Given, Uniform, UniformController
from .stepping.evolve import evolve

__all__ = [
    "Adaptive",
    "AdaptiveController",
    "BallStepSolver",
    "Given",
    "InnerOptions",
    "Nested",
    "Order2",
    "Order2Controller",
    "Regime",
    "RegimeController",
    "RISProblem",
    "RISResult",
    "RISStepper",
    "RotheInputError",
    "RunFailed",
    "RunStatistics",
    "Trajectory",
    "Uniform",
    "UniformController",
    "evolve",
    "run_nested",
    "run_ris",
]
