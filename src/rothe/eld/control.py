"""Step controllers of the elastodynamics runs (all on the shared evolve loop).

- :class:`FixedStepController`: the steps are given (``control='uniform'``: n = T/tau equal
  steps; or a user's sequence ``steps=[tau_1, ..., tau_n]``). Every step is accepted; a step
  that failed (Newton or a linear solve did not converge, or the state is not finite) stops the
  run with :class:`~rothe.errors.RunFailed` naming the step: a fixed grid has no other step to
  try, and a failed step is never accepted.
- ``control='adaptive'``: :class:`rothe.control.controllers.ErrorNormController` with the
  stepper's local error estimate (``result.errors['local_error']``, see
  :mod:`rothe.eld.schemes`), order 1 (Euler) or 2 (BDF2), safety 0.9, factors in [0.2, 2],
  no growth right after a rejection, and never above the solvability bound of the next step or
  (BDF2) :data:`~rothe.eld.schemes.BDF2_RATIO_CAP` times the last accepted step
  (:func:`adaptive_controller`).
"""

from __future__ import annotations

import numpy as np

from ..control.controllers import Decision, ErrorNormController
from ..errors import RunFailed, check_positive


class FixedStepController:
    """Steps tau_1, ..., tau_n given in advance (equal steps: ``FixedStepController.uniform``)."""

    name = "fixed"

    def __init__(self, steps=None, *, tau: float | None = None, n: int | None = None):
        if steps is not None:
            self.steps = np.asarray(steps, dtype=float)
            self.n = int(self.steps.size)
            self.tau_uniform = None
        else:
            self.steps = None
            self.tau_uniform = check_positive("tau", tau)
            self.n = int(n)
        self.k = 0  # index of the next step

    @classmethod
    def uniform(cls, tau: float, n: int) -> FixedStepController:
        return cls(tau=tau, n=n)

    def step_size(self, k: int) -> float:
        return self.tau_uniform if self.steps is None else float(self.steps[k])

    def propose(self, s):
        return self.step_size(min(self.k, self.n - 1)), None

    def decide(self, result) -> Decision:
        if not result.converged:
            raise RunFailed(result.message, where=result.where)
        self.k += 1
        return Decision(True, self.step_size(min(self.k, self.n - 1)), "fixed step")

    def checkpoint_state(self) -> dict:
        return {"controller": self.name, "k": int(self.k)}

    def restore_state(self, data: dict) -> None:
        if data.get("controller") != self.name:
            raise ValueError(f"restore_state: a {data.get('controller')!r} controller's state "
                             f"given to a {self.name!r} controller")
        self.k = int(data["k"])


def adaptive_controller(stepper, tol: float, tau0: float, *, tau_min: float,
                        tau_max: float) -> ErrorNormController:
    """The adaptive controller for an :class:`~rothe.eld.schemes.ELDStepper`."""
    return ErrorNormController(
        tol, tau0, stepper.order, key="local_error", safety=0.9, fac_min=0.2, fac_max=2.0,
        fac_fail=0.25, max_ratio=stepper.max_ratio, tau_min=tau_min, tau_max=tau_max,
        step_bound=stepper.max_step)
