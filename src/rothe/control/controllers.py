"""Step-size controllers: small objects that accept or reject a step and propose the next one.

All controllers run on the one evolve loop (:func:`rothe.stepping.evolve.evolve`). A controller

- ``propose(s, ...)`` returns the step to try from curve parameter s (and, for nested grids, the
  exact end point s_end the step must land on), and
- ``decide(result)`` looks at the step's error measures (``result.errors``, here I1 and I2) and
  whether its inner solve converged, and returns a :class:`Decision` (accept?, next step).

A failed inner solve is never accepted by any controller.

Implemented (Andreia & Meyer 2022): ``uniform`` (fixed tau, the local stationary scheme),
``adaptive`` (Alg. 3.2), ``nested`` (Alg. 6.2 for one tolerance of a decreasing sequence, given the
grids of the earlier runs), and ``order2`` (beyond the paper: uses I ~ C tau^2, Lemma 5.3).

Checkpoints (:mod:`rothe.io.checkpoint`): ``checkpoint_state() -> dict`` returns everything that
influences the controller's future decisions (the nominal step sigma and whatever history a
controller keeps), ``restore_state(data)`` puts it back into a controller built with the same
arguments. A controller that adds state extends both (``_extra_state`` / ``_restore_extra``).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from ..errors import check_positive, fail

CONTROLS = ("adaptive", "uniform", "nested", "order2")


@dataclass
class Decision:
    accept: bool
    next_tau: float
    reason: str = ""


def _max_error(result) -> float:
    return max(result.errors.values()) if result.errors else 0.0


class StepController(ABC):
    """Base class: holds tau_min / tau_max and the nominal step sigma."""

    name = "base"

    def __init__(self, tau0: float, tau_min: float = 1e-12, tau_max: float = math.inf):
        self.tau0 = check_positive("tau", tau0)
        self.tau_min = check_positive("tau_min", tau_min)
        self.tau_max = check_positive("tau_max", tau_max) if math.isfinite(tau_max) else math.inf
        if self.tau_min > self.tau0:
            raise fail("tau_min", self.tau_min, f"must be <= tau (= {self.tau0:g})")
        if self.tau_max < self.tau0:
            raise fail("tau_max", self.tau_max, f"must be >= tau (= {self.tau0:g})")
        self.sigma = self.tau0

    def propose(self, s: float) -> tuple[float, float | None]:
        """Step to try from s, and the exact end point if the step must land on a grid point."""
        return self.sigma, None

    @abstractmethod
    def decide(self, result) -> Decision:
        """Accept or reject the step from its error measures; propose the next step."""

    def _clamp(self, tau: float) -> float:
        return min(tau, self.tau_max)

    # -- checkpoint protocol -------------------------------------------------------------------
    def checkpoint_state(self) -> dict:
        """The state that decides future steps: {"controller": name, "sigma": ..., ...}."""
        return {"controller": self.name, "sigma": float(self.sigma), **self._extra_state()}

    def restore_state(self, data: dict) -> None:
        if data.get("controller") != self.name:
            raise ValueError(f"restore_state: a {data.get('controller')!r} controller's state "
                             f"given to a {self.name!r} controller")
        self.sigma = float(data["sigma"])
        self._restore_extra(data)

    def _extra_state(self) -> dict:
        return {}

    def _restore_extra(self, data: dict) -> None:
        return None


class UniformController(StepController):
    """Fixed step tau (the scheme with uniform step of [17, 18] compared in Sec. 7).

    Residuals are computed but never cause rejection. If an inner solve fails, the step is
    rejected and retried with half the step (then the nominal tau resumes): a failed solve is
    never an accepted step.
    """

    name = "uniform"

    def __init__(self, tau0: float, tau_min: float = 1e-12):
        super().__init__(tau0, tau_min)
        self._retry: float | None = None

    def propose(self, s):
        return (self._retry if self._retry is not None else self.tau0), None

    def decide(self, result) -> Decision:
        if not result.converged:
            self._retry = result.tau / 2
            return Decision(False, self._retry, f"inner solve failed ({result.code})")
        self._retry = None
        return Decision(True, self.tau0, "uniform")

    def _extra_state(self) -> dict:
        return {"retry": self._retry}

    def _restore_extra(self, data: dict) -> None:
        self._retry = None if data["retry"] is None else float(data["retry"])


class AdaptiveController(StepController):
    """Alg. 3.2 (and Alg. 6.2 when ``grid`` holds the points of earlier runs).

    Accept if I1 < tol and I2 < tol; then double the nominal step if both are < tol/2.
    Otherwise halve the step that was tried and redo the step. With ``grid``, a step never
    passes over a grid point: tau_k = min(sigma_k, sbar - s_{k-1}) with sbar the next grid point
    (6.1), and it then ends exactly on sbar, so the grids nest.
    """

    name = "adaptive"

    def __init__(
        self,
        tol: float,
        tau0: float,
        tau_min: float = 1e-12,
        tau_max: float = math.inf,
        grid: np.ndarray | None = None,
    ):
        super().__init__(tau0, tau_min, tau_max)
        self.tol = check_positive("tol", tol)
        self.grid = None if grid is None else np.unique(np.asarray(grid, dtype=float))
        if self.grid is not None:
            self.name = "nested"

    def propose(self, s):
        sigma = self._clamp(self.sigma)
        if self.grid is None:
            return sigma, None
        # a grid point within round-off of s counts as reached, and a step that would end within
        # round-off of the next grid point lands on it: otherwise s_k = s_{k-1} + tau falls a
        # few ulps short of sbar and the next step has tau ~ 1e-16
        eps = 1e-12 * max(1.0, abs(s))
        i = np.searchsorted(self.grid, s + eps, side="right")
        if i < self.grid.size:
            sbar = float(self.grid[i])
            if s + sigma >= sbar - max(eps, 1e-9 * sigma):
                return sbar - s, sbar
        return sigma, None

    def decide(self, result) -> Decision:
        tau = result.tau
        if not result.converged:
            self.sigma = tau / 2
            return Decision(False, self.sigma, f"inner solve failed ({result.code})")
        I1, I2 = result.errors["I1"], result.errors["I2"]
        if I1 < self.tol and I2 < self.tol:
            if I1 < self.tol / 2 and I2 < self.tol / 2:
                self.sigma = self._clamp(2 * self.sigma)
            return Decision(True, self.sigma, "accepted")
        self.sigma = tau / 2
        return Decision(False, self.sigma, f"I1={I1:.3g}, I2={I2:.3g} >= tol={self.tol:g}")


class Order2Controller(StepController):
    """Beyond the paper: propose tau from the known order of the residuals.

    Lemma 5.3 gives I1, I2 <= C tau^2 in finite dimensions. Each step measures
    C_k = max(I1, I2) / tau_k^2, and the next step is the one that would meet the tolerance
    with a safety factor, clamped against wild changes:

        tau_next = clip(safety * (tol / C)^(1/2), tau/4, 4 tau),   C = max(C_k, C_{k-1}).

    Taking the larger constant of the last two accepted steps matters: in rate-independent slip
    the scheme can carry a neutral period-2 oscillation of the time increments (in Example 7.1,
    dt_k = tau - dt_{k-1}), so I alternates between two levels at a fixed tau, and a controller
    that follows the last value alone oscillates and rejects every other step.
    Acceptance is that of Alg. 3.2 (I1 < tol and I2 < tol).
    """

    name = "order2"

    def __init__(self, tol, tau0, tau_min=1e-12, tau_max=math.inf, safety: float = 0.9):
        super().__init__(tau0, tau_min, tau_max)
        self.tol = check_positive("tol", tol)
        self.safety = check_positive("safety", safety)
        self._C_prev = 0.0

    def decide(self, result) -> Decision:
        tau = result.tau
        if not result.converged:
            self.sigma = tau / 4
            return Decision(False, self.sigma, f"inner solve failed ({result.code})")
        err = max(_max_error(result), 0.0)
        C = err / (tau * tau)
        accept = result.errors["I1"] < self.tol and result.errors["I2"] < self.tol
        C_eff = max(C, self._C_prev) if accept else C
        ideal = math.inf if C_eff == 0.0 else self.safety * math.sqrt(self.tol / C_eff)
        if accept:
            self._C_prev = C
            self.sigma = self._clamp(min(4 * tau, max(tau / 4, ideal)))
            return Decision(True, self.sigma, "accepted")
        self.sigma = min(tau / 2, max(tau / 4, ideal))
        return Decision(False, self.sigma, f"max(I1, I2)={err:.3g} >= tol={self.tol:g}")

    def _extra_state(self) -> dict:
        return {"C_prev": float(self._C_prev)}

    def _restore_extra(self, data: dict) -> None:
        self._C_prev = float(data["C_prev"])


def make_controller(
    control: str,
    *,
    tol: float | None = None,
    tau: float,
    tau_min: float = 1e-12,
    tau_max: float = math.inf,
    grid=None,
) -> StepController:
    """Build a controller by name (the CLI's --control)."""
    if control == "uniform":
        return UniformController(tau, tau_min)
    if control in ("adaptive", "nested"):
        return AdaptiveController(tol, tau, tau_min, tau_max, grid=grid)
    if control == "order2":
        return Order2Controller(tol, tau, tau_min, tau_max)
    raise fail("control", control, "must be one of " + ", ".join(CONTROLS))


# -- error-norm control (elastodynamics, issue 9): a self-contained block ----------------------

class ErrorNormController(StepController):
    """Accept or reject from a local error estimate; propose the next step by the order.

    The stepper reports ``result.errors[key]`` = est, an estimate of the local error of the step
    in the stepper's own (relative) norm. With err = est / tol:

    - accept iff the inner solve converged and err <= 1;
    - next step tau * clip(safety * err^(-1/(order + 1)), fac_min, fac_max), without growth
      on the step right after a rejection (fac_max = 1 there);
    - the proposal never exceeds ``tau_max``, ``max_ratio`` times the last *accepted* step (e.g.
      a zero-stability limit of a variable-step multistep method) and ``step_bound(tau_last)``
      (e.g. a solvability bound that depends on the last step; ``tau_last`` is None before the
      first accepted step);
    - a failed inner solve is a rejection with the step times ``fac_fail``.

    ``checkpoint_state()`` / ``restore_state(data)`` hold the nominal step, the last accepted
    step and whether the last attempt was rejected: everything that influences the proposals.
    """

    name = "error-norm"

    def __init__(self, tol: float, tau0: float, order: int, *, key: str = "local_error",
                 safety: float = 0.9, fac_min: float = 0.2, fac_max: float = 2.0,
                 fac_fail: float = 0.25, max_ratio: float = math.inf, tau_min: float = 1e-12,
                 tau_max: float = math.inf, step_bound=None):
        super().__init__(tau0, tau_min, tau_max)
        self.tol = check_positive("tol", tol)
        if int(order) < 1:
            raise fail("order", order, "must be an integer >= 1")
        self.order = int(order)
        self.key = key
        self.safety = check_positive("safety", safety)
        self.fac_min = check_positive("fac_min", fac_min)
        self.fac_max = check_positive("fac_max", fac_max)
        self.fac_fail = check_positive("fac_fail", fac_fail)
        if not self.fac_min < 1.0 < self.fac_max:
            raise fail("fac_min, fac_max", f"{self.fac_min:g}, {self.fac_max:g}",
                       "must satisfy fac_min < 1 < fac_max")
        self.max_ratio = float(max_ratio)
        if not self.max_ratio > 1.0:
            raise fail("max_ratio", max_ratio, "must be > 1")
        self.step_bound = step_bound
        self.tau_last: float | None = None
        self.last_rejected = False
        self.sigma = self._limit(self.tau0)

    def _limit(self, tau: float) -> float:
        tau = min(tau, self.tau_max)
        if self.tau_last is not None:
            tau = min(tau, self.max_ratio * self.tau_last)
        if self.step_bound is not None:
            tau = min(tau, self.step_bound(self.tau_last))
        return tau

    def propose(self, s):
        return self.sigma, None

    def decide(self, result) -> Decision:
        tau = result.tau
        if not result.converged:
            self.last_rejected = True
            self.sigma = self._limit(tau * self.fac_fail)
            return Decision(False, self.sigma, f"inner solve failed ({result.code})")
        est = float(result.errors[self.key])
        err = est / self.tol
        if not math.isfinite(err):
            self.last_rejected = True
            self.sigma = self._limit(tau * self.fac_fail)
            return Decision(False, self.sigma, f"{self.key} = {est:g} is not finite")
        ideal = math.inf if err == 0.0 else self.safety * err ** (-1.0 / (self.order + 1))
        if err <= 1.0:
            grow = 1.0 if self.last_rejected else self.fac_max
            self.tau_last = tau
            self.last_rejected = False
            self.sigma = self._limit(tau * min(grow, max(self.fac_min, ideal)))
            return Decision(True, self.sigma, "accepted")
        self.last_rejected = True
        self.sigma = self._limit(tau * min(0.9, max(self.fac_min, ideal)))
        return Decision(False, self.sigma, f"{self.key} = {est:.3g} > tol = {self.tol:g}")

    # the base class adds the name and sigma (and refuses another controller's state)
    def _extra_state(self) -> dict:
        return {"tau_last": self.tau_last, "last_rejected": bool(self.last_rejected)}

    def _restore_extra(self, data: dict) -> None:
        self.tau_last = None if data["tau_last"] is None else float(data["tau_last"])
        self.last_rejected = bool(data["last_rejected"])
