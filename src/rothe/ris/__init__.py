"""Rate-independent systems with non-convex energy, discretized in time first (Andreia & Meyer
2022): parametrized balanced-viscosity solutions by the local incremental stationary scheme.

    I(t, z) = 1/2 <A z, z> + F(z) - <l(t), z>,   R(v) = sum_i r_i |v_i|,
    ||v||_V^2 = sum_i m_i v_i^2                                                        (1.5)

One step (Alg. 3.2, Steps 3-6): z_k a stationary point of I(t_{k-1}, .) + R(. - z_{k-1}) on the
ball ||z - z_{k-1}||_V <= tau_k that does not increase it ((3.1), (3.2); multiplier lambda_k of
Lemma 4.1), t_k = t_{k-1} + tau_k - ||z_k - z_{k-1}||_V, and the residuals I1 (3.3), I2 (3.4).

The modules, each in one role (the same roles as :mod:`rothe.eld`):

* :mod:`~rothe.ris.problem` (:class:`RISProblem`, R^n) and :mod:`~rothe.ris.fem_problem`
  (:class:`FERISProblem`, P1 finite elements, Example 1.4);
* :mod:`~rothe.ris.examples`: Example 7.1 (exact solution (7.1)), Example 7.2 and its 3D
  analogue, a phase front for meshes that change between steps;
* :mod:`~rothe.ris.inner`: the inner solver of (3.1)-(3.2) (:class:`BallStepSolver`, result
  codes :class:`RISCode`);
* :mod:`~rothe.ris.stepper`: one step (:class:`RISStepper`), never deciding acceptance;
* :mod:`~rothe.ris.run`: the run driver (:func:`run_ris` -> :class:`RISResult`,
  :func:`run_nested`);
* :mod:`~rothe.ris.controllers`: the step-control objects :class:`Order2`, :class:`Regime`,
  :class:`Nested` (besides :class:`~rothe.stepping.controllers.Uniform` and
  :class:`~rothe.stepping.controllers.Adaptive`, Alg. 3.2) and the controllers built from them;
* :mod:`~rothe.ris.residuals` (I1, I2), :mod:`~rothe.ris.indicator` (the error indicator of a
  step on its mesh), :mod:`~rothe.ris.adapt` (the RIS side of the adapt cycle);
* :mod:`~rothe.ris.summary` (the summary of a run, work ratios, branches) and
  :mod:`~rothe.ris.figures`.

Example::

    from rothe.ris import Adaptive, example_7_2, run_ris

    result = run_ris(example_7_2(16), Adaptive(tol=1e-4))
    result.trajectory["t"][-1], result.statistics.accepted_steps

See docs/ris.md (scheme, inner solver, step control) and docs/ris_fem.md (finite elements).
"""

from ..stepping.controllers import Adaptive, Uniform
from .controllers import Nested, Order2, Regime
from .examples import (
    example_7_1,
    example_7_2,
    example_7_2_3d,
    example_front,
    example_front_unique,
)
from .fem_problem import FERISProblem
from .inner import BallStepSolver, InnerOptions, RISCode
from .problem import RISProblem
from .run import RISResult, run_nested, run_ris
from .stepper import RISState, RISStepper

__all__ = [
    "Adaptive",
    "BallStepSolver",
    "FERISProblem",
    "InnerOptions",
    "Nested",
    "Order2",
    "RISCode",
    "RISProblem",
    "RISResult",
    "RISState",
    "RISStepper",
    "Regime",
    "Uniform",
    "example_7_1",
    "example_7_2",
    "example_7_2_3d",
    "example_front",
    "example_front_unique",
    "run_nested",
    "run_ris",
]
