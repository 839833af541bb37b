"""Generic step-size controllers: small objects that accept or reject a step and propose the next.

Every controller runs on the one evolve loop (:func:`rothe.stepping.evolve.evolve`). A controller

- ``propose(s)`` returns the step to try from curve parameter s (and, for nested grids, the exact
  end point s_end the step must land on), and
- ``decide(result)`` looks at the step's error measures (``result.errors``) and whether its solve
  converged, and returns a :class:`Decision` (accept?, next step, reason).

A failed solve is never accepted by any controller. The controllers here know no family:

- :class:`UniformController`: a fixed step; a failed solve is retried with half the step;
- :class:`FixedStepController`: steps given in advance (equal steps or a sequence); every step
  is accepted, a failed one stops the run (a fixed grid has no other step to try);
- :class:`ErrorNormController`: accept if one local error estimate is below tol, propose the next
  step from the method's order (elastodynamics).

The RIS controllers of Andreia & Meyer (2022), which read the residuals I1 and I2, are in
:mod:`rothe.ris.controllers`.

What a user passes to ``run_ris`` / ``run_eld`` is a *step-control object*, validated in its
constructor: :class:`Uniform` (tau), :class:`Given` (steps), :class:`Adaptive` (tol, first step,
range), and the RIS-only ``Order2``, ``Regime``, ``Nested`` of :mod:`rothe.ris.controllers`. The
family builds the controller from it (the command line maps its ``--control`` names to these
objects in one place).

Checkpoints (:mod:`rothe.io.checkpoint`): ``checkpoint_state() -> dict`` returns everything that
influences the controller's future decisions, ``restore_state(data)`` puts it back into a
controller built with the same arguments. A controller that adds state extends both
(``_extra_state`` / ``_restore_extra``).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from ..errors import RunFailed, check_positive, described, fail, integer_allowed


@dataclass
class Decision:
    """A controller's verdict on a step: ``accept``, the next step ``next_tau`` and a ``reason``."""

    accept: bool
    next_tau: float
    reason: str = ""


def _check_owner(controller, data: dict) -> None:
    """Refuse (ValueError) the checkpoint state of another kind of controller."""
    if data.get("controller") != controller.name:
        raise ValueError(
            f"restore_state: a {data.get('controller')!r} controller's state "
            f"given to a {controller.name!r} controller"
        )


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
        """Put back :meth:`checkpoint_state` (a ValueError for another controller's state)."""
        _check_owner(self, data)
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

    Parameters
    ----------
    tau0 : float > 0
        The step tau.
    tau_min : float
        The run stops where a retry would go below it.
    """

    name = "uniform"

    def __init__(self, tau0: float, tau_min: float = 1e-12):
        super().__init__(tau0, tau_min)
        self._retry: float | None = None

    def propose(self, s):
        """tau0, or half the failed step after a failed solve."""
        return (self._retry if self._retry is not None else self.tau0), None

    def decide(self, result) -> Decision:
        """Accept every converged step (next: tau0); reject a failed one (next: half of it)."""
        if not result.converged:
            self._retry = result.tau / 2
            return Decision(False, self._retry, f"inner solve failed ({result.code})")
        self._retry = None
        return Decision(True, self.tau0, "uniform")

    def _extra_state(self) -> dict:
        return {"retry": self._retry}

    def _restore_extra(self, data: dict) -> None:
        self._retry = None if data["retry"] is None else float(data["retry"])


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
        """``n`` equal steps ``tau``."""
        return cls(tau=tau, n=n)

    def step_size(self, k: int) -> float:
        """tau_{k+1}: the k-th step (0-based) of the sequence, or the equal step."""
        return self.tau_uniform if self.steps is None else float(self.steps[k])

    def propose(self, s):
        """The next step of the sequence (the last one again after its end)."""
        return self.step_size(min(self.k, self.n - 1)), None

    def decide(self, result) -> Decision:
        """Accept every converged step; a failed solve raises :class:`RunFailed`."""
        if not result.converged:
            raise RunFailed(result.message, where=result.where)
        self.k += 1
        return Decision(True, self.step_size(min(self.k, self.n - 1)), "fixed step")

    def checkpoint_state(self) -> dict:
        """The name and the index of the next step."""
        return {"controller": self.name, "k": int(self.k)}

    def restore_state(self, data: dict) -> None:
        """Put back :meth:`checkpoint_state` (a ValueError for another controller's state)."""
        _check_owner(self, data)
        self.k = int(data["k"])


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

    def __init__(
        self,
        tol: float,
        tau0: float,
        order: int,
        *,
        key: str = "local_error",
        safety: float = 0.9,
        fac_min: float = 0.2,
        fac_max: float = 2.0,
        fac_fail: float = 0.25,
        max_ratio: float = math.inf,
        tau_min: float = 1e-12,
        tau_max: float = math.inf,
        step_bound=None,
    ):
        super().__init__(tau0, tau_min, tau_max)
        self.tol = check_positive("tol", tol)
        if int(order) < 1:
            raise fail("order", order, integer_allowed(1))
        self.order = int(order)
        self.key = key
        self.safety = check_positive("safety", safety)
        self.fac_min = check_positive("fac_min", fac_min)
        self.fac_max = check_positive("fac_max", fac_max)
        self.fac_fail = check_positive("fac_fail", fac_fail)
        if not self.fac_min < 1.0 < self.fac_max:
            raise fail(
                "fac_min, fac_max",
                f"{self.fac_min:g}, {self.fac_max:g}",
                "must satisfy fac_min < 1 < fac_max",
            )
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
        """The nominal step sigma."""
        return self.sigma, None

    def decide(self, result) -> Decision:
        """With err = est / tol and ideal = safety err^(-1/(p+1)): accept if err <= 1, next step
        tau min(fac_max, max(fac_min, ideal)) (growth 1 right after a rejection); else reject, next
        tau min(0.9, max(fac_min, ideal)); a failed solve or a non-finite estimate: tau fac_fail.
        Every next step is limited to tau_max, max_ratio times the last accepted step and the step
        bound.
        """
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


# -- step control as the user asks for it: validated objects, built into controllers by a family -


@dataclass(frozen=True)
class Uniform:
    """Equal steps ``tau`` (RIS: in s, a failed solve retried with half the step, the run
    stopping where that would go below ``tau_min``, None: the family's default; ELD: in t,
    T/tau must be an integer, a failed step stops the run).

    Parameters
    ----------
    tau : float > 0
        The step.
    tau_min : float, optional
        RIS only: the smallest step a failed solve may be retried with (None: the default).
    """

    tau: float
    tau_min: float | None = None

    def __post_init__(self):
        object.__setattr__(self, "tau", check_positive("tau", self.tau))
        _check_step_range(self)


@dataclass(frozen=True)
class Given:
    """Steps tau_1, ..., tau_n given in advance (elastodynamics: they must sum to T)."""

    steps: tuple

    def __post_init__(self):
        try:
            arr = np.asarray(self.steps, dtype=float).ravel()
        except (TypeError, ValueError):
            raise fail(
                "steps", described(type(self.steps).__name__), "must be a sequence of step sizes"
            ) from None
        if arr.size == 0:
            raise fail("steps", described("[]"), "must hold at least one step size")
        bad = np.flatnonzero(~(np.isfinite(arr) & (arr > 0)))
        if bad.size:
            k = int(bad[0])
            raise fail(
                "steps", described(f"tau_{k + 1} = {arr[k]:g}"), "must be positive and finite"
            )
        object.__setattr__(self, "steps", tuple(float(x) for x in arr))


@dataclass(frozen=True)
class Adaptive:
    """Adaptive steps: a step is accepted when its error measure is below ``tol``.

    The family defines the measure and the rule: RIS, Alg. 3.2 of Andreia & Meyer (2022) on the
    residuals I1 (3.3) and I2 (3.4); elastodynamics, the local error estimate in the energy norm
    with steps from the scheme's order (:class:`ErrorNormController`): local (what one step
    adds), relative (to the run's largest energy norm), per step -- no bound on the error at T,
    which the steps' errors add up to (docs/eld.md, *Step control*: a measured table).
    ``tau``: the first step (None: the family's default); steps stay in [tau_min, tau_max]
    (None: the family's defaults).

    Parameters
    ----------
    tol : float > 0
        The tolerance of the family's error measure.
    tau : float, optional
        The first step (None: the family's default).
    tau_min, tau_max : float, optional
        The range of the steps (None: the family's defaults); tau_min <= tau <= tau_max.
    """

    tol: float
    tau: float | None = None
    tau_min: float | None = None
    tau_max: float | None = None

    def __post_init__(self):
        object.__setattr__(self, "tol", check_positive("tol", self.tol))
        _check_step_range(self)


def _check_step_range(spec) -> None:
    """tau, tau_min, tau_max of a step-control object: positive, and tau_min <= tau <= tau_max."""
    for name in ("tau", "tau_min", "tau_max"):
        value = getattr(spec, name, None)
        if value is not None:
            if name == "tau_max" and value == math.inf:
                continue
            object.__setattr__(spec, name, check_positive(name, value))
    tau, lo, hi = spec.tau, spec.tau_min, getattr(spec, "tau_max", None)
    if tau is not None and lo is not None and lo > tau:
        raise fail("tau_min", lo, f"must be <= the first step tau = {tau:g}")
    if tau is not None and hi is not None and hi < tau:
        raise fail("tau_max", hi, f"must be >= the first step tau = {tau:g}")
