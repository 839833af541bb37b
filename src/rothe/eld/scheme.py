"""The time schemes: implicit Euler (3.4) and variable-step BDF2, as validated objects.

Both schemes apply one difference operator twice, to the displacement and to the velocity (for
BDF2 this is BDF2 on the first-order system (u, v)), with steps tau_j = t_j - t_{j-1} that may
vary:

    delta_j z := (alpha_0 z^j + alpha_1 z^{j-1} + alpha_2 z^{j-2}) / tau_j,
    ImplicitEuler:  (alpha_0, alpha_1, alpha_2) = (1, -1, 0),
    BDF2:           omega = tau_j / tau_{j-1},  alpha_0 = (1 + 2 omega)/(1 + omega),
                    alpha_1 = -(1 + omega),  alpha_2 = omega^2 / (1 + omega)    (= 3/2, -2, 1/2)

(:meth:`Scheme.coefficients`). With equal steps, Euler is the paper's D u^j and D^2 u^j (3.4).
Variable-step BDF2 is zero-stable only for ratios omega < 1 + sqrt(2) (Grigorieff 1983): a given
step sequence beyond that is refused, and the adaptive controller never proposes more than
:data:`BDF2_RATIO_CAP` = 1.8 (below also Becker's (2 + sqrt 13)/3 = 1.87 of the variable-step
BDF2 energy estimates).

**Solvability (Lemma 3.2 for these schemes).** The step operator in the scheme's unknown is
A(tau_eff) with the effective step tau_eff = tau_j / alpha_0; on V_B,
<A u - A w, u - w> >= (d1/tau_eff + k1) ||u - w||^2 + (rho/tau_eff^2 - d0/tau_eff) |u - w|^2 by
(2.4), (2.5): every step is uniquely solvable if tau_j / alpha_0 < rho/d0, i.e. tau_j < rho/d0
(Euler) and, for BDF2, tau_j (1 + omega_j)/(1 + 2 omega_j) < rho/d0: tau_j < 1.5 rho/d0 with
equal steps, and in general tau_j < [2c - tau_{j-1} + sqrt(tau_{j-1}^2 + 4 c^2)] / 2 with
c = rho/d0 (the left side increases with tau_j; :meth:`Scheme.max_step`). No bound if d0 = 0.

**Local error estimate.** The trapezoidal residuals of a step are O(tau^3); c(omega) times them
estimates the local error of BDF2 (its local error is -tau^3 (1 + omega)^2 / (6 omega (1 + 2
omega)) u''' and the residual -tau^3 u''' (1/12 + (1 + omega)^2/(6 omega (1 + 2 omega))), so
c(omega) = 2 (1 + omega)^2 / (omega (1 + 2 omega) + 2 (1 + omega)^2), 8/11 for equal steps); for
Euler the residual tau^2/2 u'' is the local error itself (c = 1). :meth:`Scheme.estimate_factor`.

**The BDF2 start** (``BDF2(start=...)``, :mod:`rothe.eld.start`): ``'taylor'`` (default: a
history on the Taylor polynomial of the solution, order 2 for u, u' and the multiplier at every
step), and for studies of the start only ``'taylor2'`` (without the cubic Gamma_D term: O(tau)
multiplier error at steps 1 and 3 in the original form) and ``'euler'`` (one implicit Euler step
first: O(1) multiplier error at step 2).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

from ..errors import check_choice, check_instance, fail

#: BDF2 starts: the Taylor history (default), the same without the cubic Gamma_D term, and one
#: implicit Euler step (the last two only to show why not; :mod:`rothe.eld.start`)
STARTS = ("taylor", "taylor2", "euler")
#: variable-step BDF2 is zero-stable for step ratios below 1 + sqrt(2)
BDF2_ZERO_STABILITY = 1.0 + math.sqrt(2.0)
#: the adaptive controller's largest step ratio for BDF2 (well below the zero-stability limit)
BDF2_RATIO_CAP = 1.8
#: the adaptive controller stays below this fraction of the solvability bound
BOUND_SAFETY = 0.95


class Scheme(ABC):
    """A time scheme of the form delta_j z = (alpha_0 z^j + alpha_1 z^{j-1} + alpha_2 z^{j-2})
    / tau_j (module docstring). Subclasses: :class:`ImplicitEuler`, :class:`BDF2`.

    Attributes
    ----------
    name : str
        ``'euler'`` or ``'bdf2'`` (as in trajectories, summaries and on the command line).
    order : int
        The order p of the scheme (the adaptive controller's exponent 1/(p + 1)).
    alpha0 : float
        alpha_0 for equal steps (1 or 3/2): the effective step tau/alpha0 of the first matrix,
        and the reaction rho (alpha0/tau)^2 of the error indicator.
    ratio_cap : float
        The largest step ratio the adaptive controller proposes (inf: none).
    zero_stability : float
        Step ratios tau_j/tau_{j-1} must stay below this (inf: no limit).
    g_weight : float
        nu of the G-stability split of the numerical dissipation (0 for Euler, 1/4 for BDF2;
        :mod:`rothe.eld.state`).
    """

    name: str = ""
    order: int = 1
    alpha0: float = 1.0
    ratio_cap: float = math.inf
    zero_stability: float = math.inf
    g_weight: float = 0.0

    @abstractmethod
    def coefficients(self, tau: float, tau_prev: float | None = None) -> tuple[float, float, float]:
        """(alpha_0, alpha_1, alpha_2) of the step tau after the step tau_prev (None: the
        first step, with a fictitious equal step before it).

        Parameters
        ----------
        tau : float
            The step tau_j.
        tau_prev : float or None
            The step before it, tau_{j-1}.

        Returns
        -------
        tuple of three floats
        """

    @abstractmethod
    def max_step(self, bound: float, tau_prev: float | None) -> float:
        """The supremum of the steps tau with tau / alpha_0(tau / tau_prev) < bound.

        Parameters
        ----------
        bound : float
            The solvability bound rho/d0 of Lemma 3.2 (inf: no bound).
        tau_prev : float or None
            The previous step (None before the first).

        Returns
        -------
        float
        """

    @abstractmethod
    def estimate_factor(self, omega: float) -> float:
        """c(omega): the local error of a step is c(omega) times its trapezoidal residual
        (module docstring), omega = tau_j / tau_{j-1}."""

    @abstractmethod
    def check_step(self, tau: float, bound: float) -> None:
        """Refuse (one line naming ``tau``) an equal step tau that violates Lemma 3.2."""

    def first_step(self) -> Scheme:
        """The scheme of the first step (BDF2 with ``start='euler'``: implicit Euler)."""
        return self

    @property
    def prehistory(self) -> bool:
        """Whether the first step needs a history before t = 0 (:mod:`rothe.eld.start`)."""
        return False

    def describe(self) -> dict:
        """The scheme as in the trajectory's meta data: ``scheme`` and ``start``."""
        return {"scheme": self.name, "start": None}


@dataclass(frozen=True)
class ImplicitEuler(Scheme):
    """Implicit Euler (3.4), the paper's scheme: first order, (alpha_0, alpha_1, alpha_2) =
    (1, -1, 0) whatever the steps; steps tau < rho/d0 (Lemma 3.2); estimate factor c = 1."""

    name = "euler"
    order = 1
    alpha0 = 1.0

    def coefficients(self, tau, tau_prev=None):
        """(1, -1, 0) whatever the steps."""
        return 1.0, -1.0, 0.0

    def max_step(self, bound, tau_prev):
        """``bound`` itself: tau < rho/d0 (alpha_0 = 1)."""
        return bound

    def estimate_factor(self, omega):
        """c = 1: the residual tau^2/2 u'' is the local error itself."""
        return 1.0

    def check_step(self, tau, bound):
        """Refuse tau >= rho/d0 (Lemma 3.2)."""
        if not tau < bound:
            raise fail(
                "tau",
                tau,
                f"must be < rho/d0 = {bound:g} (Lemma 3.2: unique solvability of the Euler steps)",
            )


@dataclass(frozen=True)
class BDF2(Scheme):
    """Variable-step BDF2 (second order), applied to u and to v (module docstring).

    Parameters
    ----------
    start : {'taylor', 'taylor2', 'euler'}
        How the first step gets its history: ``'taylor'`` (default) on the Taylor polynomial of
        the solution before t = 0; ``'taylor2'`` and ``'euler'`` only to study why not
        (:mod:`rothe.eld.start`).
    """

    start: str = "taylor"
    name = "bdf2"
    order = 2
    alpha0 = 1.5
    ratio_cap = BDF2_RATIO_CAP
    zero_stability = BDF2_ZERO_STABILITY
    g_weight = 0.25

    def __post_init__(self):
        check_choice("start", self.start, STARTS)

    def coefficients(self, tau, tau_prev=None):
        """alpha_0 = (1 + 2 omega)/(1 + omega), alpha_1 = -(1 + omega), alpha_2 = omega^2/(1 +
        omega)
        with omega = tau/tau_prev (omega = 1 for the first step).
        """
        w = 1.0 if tau_prev is None else tau / tau_prev
        return (1.0 + 2.0 * w) / (1.0 + w), -(1.0 + w), w * w / (1.0 + w)

    def max_step(self, bound, tau_prev):
        """1.5 bound for the first step (fictitious tau_0 = tau_1), otherwise the positive root
        of tau (tau_prev + tau) = bound (tau_prev + 2 tau)."""
        if not math.isfinite(bound):
            return math.inf
        if tau_prev is None:
            return 1.5 * bound
        c, tp = bound, tau_prev
        return 0.5 * (2.0 * c - tp + math.sqrt(tp * tp + 4.0 * c * c))

    def estimate_factor(self, omega):
        """c(omega) = 2 (1 + omega)^2 / (omega (1 + 2 omega) + 2 (1 + omega)^2) (8/11 for omega =
        1).
        """
        w = omega
        return 2.0 * (1.0 + w) ** 2 / (w * (1.0 + 2.0 * w) + 2.0 * (1.0 + w) ** 2)

    def check_step(self, tau, bound):
        """Refuse an equal step with tau/1.5 >= rho/d0 (Lemma 3.2 with alpha_0 = 3/2)."""
        if not tau / 1.5 < bound:
            raise fail(
                "tau",
                tau,
                f"must be < 1.5 rho/d0 = {1.5 * bound:g} (Lemma 3.2 for "
                "BDF2: tau_j/alpha_j < rho/d0 with alpha_j = (1 + 2 omega)/(1 + omega) "
                "= 1.5 for equal steps)",
            )

    def first_step(self) -> Scheme:
        """Implicit Euler with ``start='euler'``, else this BDF2."""
        return ImplicitEuler() if self.start == "euler" else self

    @property
    def prehistory(self) -> bool:
        return self.start != "euler"

    def describe(self) -> dict:
        """``scheme`` and the ``start`` of the history."""
        return {"scheme": self.name, "start": self.start}


#: the scheme of a run that names none (the paper's)
DEFAULT_SCHEME = ImplicitEuler()


def as_scheme(scheme) -> Scheme:
    """``scheme`` if it is a :class:`Scheme`, else a one-line error naming ``scheme``."""
    return check_instance(
        "scheme", scheme, Scheme, "ImplicitEuler() or BDF2(start=...) (rothe.eld.scheme)"
    )
