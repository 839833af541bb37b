"""Step-size controllers: small objects that accept or reject a step and propose the next one.

All controllers run on the one evolve loop (:func:`rothe.stepping.evolve.evolve`). A controller

- ``propose(s, ...)`` returns the step to try from curve parameter s (and, for nested grids, the
  exact end point s_end the step must land on), and
- ``decide(result)`` looks at the step's error measures (``result.errors``, here I1 and I2) and
  whether its inner solve converged, and returns a :class:`Decision` (accept?, next step).

A failed inner solve is never accepted by any controller.

What a user passes to :func:`rothe.ris.run.run_ris` is a *step-control object*, validated in its
constructor, from which the run builds its controller (:func:`build_controller`):

* :class:`~rothe.stepping.controllers.Uniform` (tau): fixed steps (the local stationary scheme),
  :class:`UniformController`;
* :class:`~rothe.stepping.controllers.Adaptive` (tol, tau, tau_min, tau_max): Alg. 3.2 of
  Andreia & Meyer (2022), :class:`AdaptiveController`;
* :class:`Order2` (beyond the paper: the next step from I ~ C tau^2, Lemma 5.3),
  :class:`Order2Controller`;
* :class:`Regime` (beyond the paper: one error model I ~ C tau^p per regime -- sticking, viscous
  jump, slip -- that puts every step at the same residual, which is what minimizes the steps for
  a given global residual sum_k(I1 + I2)), :class:`RegimeController`;
* :class:`Nested` (tols): Alg. 6.2, one run per tolerance of a decreasing sequence
  (:func:`rothe.ris.run.run_nested`); run n uses :class:`AdaptiveController` with the grids of
  the earlier runs.

Checkpoints (:mod:`rothe.io.checkpoint`): ``checkpoint_state() -> dict`` returns everything that
influences the controller's future decisions (the nominal step sigma and whatever history a
controller keeps), ``restore_state(data)`` puts it back into a controller built with the same
arguments. A controller that adds state extends both (``_extra_state`` / ``_restore_extra``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import check_decreasing, check_positive, described, fail
from ..stepping.controllers import (
    Adaptive,
    Decision,
    StepController,
    Uniform,
    UniformController,
    _check_step_range,
)

#: the step of a RIS run when the control object leaves it open: the first step, and its range
DEFAULT_TAU, DEFAULT_TAU_MIN, DEFAULT_TAU_MAX = 0.1, 1e-12, math.inf


def _max_error(result) -> float:
    return max(result.errors.values()) if result.errors else 0.0


class AdaptiveController(StepController):
    """Alg. 3.2 (and Alg. 6.2 when ``grid`` holds the points of earlier runs).

    Accept if I1 < tol and I2 < tol; then double the nominal step if both are < tol/2.
    Otherwise halve the step that was tried and redo the step. With ``grid``, a step never
    passes over a grid point: tau_k = min(sigma_k, sbar - s_{k-1}) with sbar the next grid point
    (6.1), and it then ends exactly on sbar, so the grids nest.

    Parameters
    ----------
    tol : float > 0
        The tolerance of I1 and I2.
    tau0 : float > 0
        The first nominal step sigma_1.
    tau_min, tau_max : float
        The range of the steps.
    grid : ndarray, optional
        The curve parameters s of an earlier run (Alg. 6.2): no step passes over them.
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
        """sigma, or the step that lands exactly on the next grid point of earlier runs."""
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
        """Accept iff I1 < tol and I2 < tol; double, keep or halve the step (Alg. 3.2)."""
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


class CatchUp:
    """The catch-up rule of the residual controllers (beyond the paper; issue 18, item 0).

    Step (3.1) minimizes at the old time t_{k-1}: a step that advances t leaves z_k behind the
    load, unstable at t_k (dist(-D_z I(t_k, z_k), dR(0)) = d1 > 0), and the next step first
    moves z at fixed t. Where the state must move faster than t in V (a front: ||z'||_V / t'
    > 1) the split t_k - t_{k-1} = tau_k - ||z_k - z_{k-1}||_V swings to its extremes and the
    run alternates steps that only advance t with viscous-jump steps that only catch z up: the
    "lattice jumps" of ris-front (half of its steps), each a real step on the sphere.

    The rule sizes the next step as the catch-up plus the wanted advance of t,

        tau_{k+1} = d1_k / kappa + dt*,   kappa = (d0 - d1) / tau_j,   dt* = safety sqrt(tol / C_t),

    kappa the decay of dist per unit of arclength measured on the last viscous-jump step j (at
    fixed t the jump is the V-gradient flow of I + R, so dist falls about linearly to 0 at its
    end), C_t = max(I1, I2) / (t_k - t_{k-1})^2 on the last step that advanced t (Lemma 5.3's
    quotient in the advance of t). A step of that size lands where the catch-up is done and t
    has moved by dt*, instead of one step for each. None when kappa or C_t is not known yet,
    or the state at the end is stable (d1 = 0), or neither this step nor the one before it was
    a viscous-jump step (no catch-up cycle: in a slip where z keeps pace with t, as in
    Example 7.1, the lag is the slip's own and kappa a stale value of an earlier jump): the
    controller's own proposal then stands.
    """

    def __init__(self):
        self.kappa: list = []  # (d0 - d1) / tau of the last two viscous-jump steps
        self.C_t = 0.0
        self.C3: list = []  # e / tau^3 of the last three viscous-jump steps
        self.last_was_jump = False

    def propose(self, result, tol: float, safety: float) -> float | None:
        """The catch-up step after the accepted ``result``, or None (class docstring)."""
        d0 = getattr(result, "dist_start", math.nan)
        d1 = getattr(result, "dist_end", math.nan)
        if not (math.isfinite(d0) and math.isfinite(d1)):
            return None
        tau = result.tau
        e = max(_max_error(result), 0.0)
        jump = step_regime(result) == "jump"
        in_cycle = jump or self.last_was_jump
        self.last_was_jump = jump
        if jump:
            if d0 > d1 >= 0.0:
                self.kappa = (self.kappa + [(d0 - d1) / tau])[-2:]
            if e > 0.0:  # the jump's own residual: I2 ~ C3 tau^3 (Example 7.2's order)
                self.C3 = (self.C3 + [e / tau**3])[-3:]
        else:
            dt = tau - getattr(result, "step_norm", 0.0)
            if dt > 0.0 and e > 0.0:
                self.C_t = e / (dt * dt)
        if not in_cycle or not self.kappa or self.C_t <= 0.0 or d1 <= 0.0:
            return None
        step = d1 / min(self.kappa) + safety * math.sqrt(tol / self.C_t)
        if self.C3:  # no longer than one jump step can go within tol
            step = min(step, safety * (tol / max(self.C3)) ** (1.0 / 3.0))
        return step

    def state(self) -> dict:
        """What a checkpoint keeps."""
        return {
            "kappa": list(map(float, self.kappa)),
            "C_t": float(self.C_t),
            "C3": list(map(float, self.C3)),
            "last_was_jump": bool(self.last_was_jump),
        }

    def restore(self, data: dict | None) -> None:
        """Put back :meth:`state` (None: start afresh)."""
        if data is not None:
            self.kappa = [float(k) for k in data["kappa"]]
            self.C_t = float(data["C_t"])
            self.C3 = [float(c) for c in data["C3"]]
            self.last_was_jump = bool(data["last_was_jump"])


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
    Acceptance is that of Alg. 3.2 (I1 < tol and I2 < tol). After an accepted step whose end
    state lags behind the load, the proposal is the :class:`CatchUp` step instead (clipped to
    [tau/4, 4 tau] like the model's).

    Parameters
    ----------
    tol, tau0, tau_min, tau_max : float
        As in :class:`AdaptiveController`.
    safety : float
        The safety factor of the proposal.
    """

    name = "order2"

    def __init__(self, tol, tau0, tau_min=1e-12, tau_max=math.inf, safety: float = 0.9):
        super().__init__(tau0, tau_min, tau_max)
        self.tol = check_positive("tol", tol)
        self.safety = check_positive("safety", safety)
        self._C_prev = 0.0
        self._catch_up = CatchUp()

    def decide(self, result) -> Decision:
        """Accept as Alg. 3.2; the next step from C = max(I1, I2) / tau^2 (class docstring)."""
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
            new = min(4 * tau, max(tau / 4, ideal))
            guided = self._catch_up.propose(result, self.tol, self.safety)
            if guided is not None:
                new = min(4 * tau, max(tau / 4, guided))
            self.sigma = self._clamp(new)
            return Decision(True, self.sigma, "accepted")
        self.sigma = min(tau / 2, max(tau / 4, ideal))
        return Decision(False, self.sigma, f"max(I1, I2)={err:.3g} >= tol={self.tol:g}")

    def _extra_state(self) -> dict:
        return {"C_prev": float(self._C_prev), "catch_up": self._catch_up.state()}

    def _restore_extra(self, data: dict) -> None:
        self._C_prev = float(data["C_prev"])
        self._catch_up.restore(data.get("catch_up"))  # None: a checkpoint before the rule


#: the three regimes of a BV solution, read off one step (t' = 1 - ||z'||_V on [s_{k-1}, s_k])
REGIMES = ("stick", "jump", "slip")


def step_regime(result) -> str:
    """Regime of one step from its increment: ``stick`` (z_k = z_{k-1}, t' = 1), ``jump``
    (||z_k - z_{k-1}||_V = tau_k: on the sphere, t' = 0) or ``slip`` (both move).

    A result without ``step_norm`` (a stepper that is not the RIS one) counts as ``slip``.
    """
    norm = getattr(result, "step_norm", None)
    if norm is None:
        return "slip"
    if norm == 0.0:
        return "stick"
    if norm >= result.tau * (1.0 - 1e-9):
        return "jump"
    return "slip"


class RegimeController(StepController):
    """Beyond the paper: every step at the same residual, from an error model per regime.

    **Acceptance is that of Alg. 3.2, Step 7**: a step is accepted iff its inner solve converged
    and I1 < tol and I2 < tol. Only the proposal of the next step differs.

    **Model.** For each regime r of :func:`step_regime` (sticking, viscous jump, slip) the error
    e = max(I1, I2) of a step of length tau is modelled as e = C tau^p. Lemma 5.3 gives
    I1, I2 <= C tau^2, so p = 2 is the default; a measured order replaces it: when a rejected
    attempt and the next attempt start from the same state and lie in the same regime,
    p = log(e_rej / e) / log(tau_rej / tau), clipped to [1, 4] (the viscous jump of Example 7.2
    has I2 ~ tau^3).

    **Proposal.** After an accepted step k (error e_k, step tau_k, regime r):

        C  = max(e_k / tau_k^p, e_j / tau_j^p)       (j: the previous accepted step, if in r)
        C2 = max(e_k / tau_k^2, e_j / tau_j^2)       (the quotient that Lemma 5.3 bounds)
        tau_{k+1} = clip((theta tol / C)^(1/p), tau_k / 4, grow tau_k),
        tau_{k+1} = max(tau_{k+1}, min(grow tau_k, 1/2 sqrt(theta tol / C2)))      (floor)

    (tau_{k+1} = grow tau_k if C = 0, e.g. while sticking at a stable state); where the state
    at the end of step k lags behind the load, the :class:`CatchUp` step aimed at theta tol
    replaces the model's (clipped to [tau_k / 4, grow tau_k]), and the floor still applies, so
    the bound (5.7) below is unchanged. After a rejected
    attempt (e >= tol): tau = clip(tau (theta tol / e)^(1/p), tau / 10, 0.9 tau). Leaving
    sticking: two rejected sticking attempts locate the onset s* of instability and the slope L
    of dist there (:meth:`_sticking_crossing`); from s <= s* the step ends at s* + delta,
    delta = sqrt(2 q theta tol / L) (I1 = q theta tol, q = :attr:`crossing_fraction`).

    **Why every step at the same target theta tol.** With I_k = C(s_k) tau_k^2, a run needs
    N = int ds / tau steps and leaves the global residual G = sum_k I_k = int C tau ds; minimizing
    N at fixed G (Lagrange: -1/tau^2 + mu C = 0) gives C tau^2 = 1/mu, i.e. the same residual in
    every step. Targets that grow with tau (error per unit step) need more steps: measured 0.63 of
    uniform's solves against 0.54 (Example 7.2, 16 x 16, tol 1e-5). theta only sets where a run
    lands on the work-vs-residual curve (theta = 0.25 ... 0.9 gave 0.532 ... 0.540); 1/2 leaves
    a margin to tol that the model error never used up in our runs.

    **Why the larger of the last two constants.** The time increments of the scheme in slip obey
    dt_k = tau_k - ||z_k - z_{k-1}||_V ~ tau_k - v dt_{k-1}: a period-2 oscillation (neutral in
    Example 7.1, damped in 7.2), so e alternates between two levels at fixed tau; following the
    last value alone rejected 416 slip steps at tol 1e-5 on 16 x 16 (0 with the max). Extrapolating
    the constant (C_k^2 / C_{k-1}, Gustafsson-type) amplified the oscillation: 822 rejections.

    **Convergence (Theorem 5.4).** The proof of Theorem 5.4 (Z = V; a finite-element
    discretization on a fixed mesh is R^n) uses the step-size rule only through (a) Step 7,
    I1^k < tol and I2^k < tol for every accepted step -- our acceptance test -- and (b) the bound
    N_tol <= (T + C) / (c sqrt(tol)) on the number of steps (5.8), which follows from
    tau_k >= c sqrt(tol) (5.7); the results of Section 4 hold for any step sizes (Remark 4.13).
    (5.7) holds here as for Alg. 3.2: an attempt after a rejection at tau' (where
    tol <= e <= C tau'^2 by Lemma 5.3) has tau >= tau'/10 >= sqrt(tol / C) / 10, and the floor
    after an accepted step gives tau_{k+1} >= min(grow tau_k, 1/2 sqrt(theta tol / C)) because
    C2 <= C (Lemma 5.3), and the step out of sticking is >= delta >= sqrt(q theta tol / C)
    (a sticking step from s* has I1 = L tau^2 / 2 <= C tau^2, so L <= 2 C); by induction
    tau_k >= c sqrt(tol) with c = min(tau_1 / sqrt(tol), 1/2 sqrt(theta / C), sqrt(q theta / C),
    1 / (10 sqrt(C))) (the step shortened to land on T excepted, as in the paper). So
    Theorem 5.4 applies to this controller exactly as to Alg. 3.2. Theorem 6.4 (Z != V, the
    limit h -> 0 as well) needs in addition the pointwise monotone step sizes of
    Assumption 6.1(3), which neither Alg. 3.2 nor this controller provides; Alg. 6.2
    (``nested``) does.

    Parameters
    ----------
    tol, tau0, tau_min, tau_max : float
        As in :class:`AdaptiveController`.
    theta : float
        Every step aims at the residual theta tol.
    grow : float
        The largest growth of the step after an accepted one.
    """

    name = "regime"
    #: the step that leaves sticking aims at I1 = crossing_fraction * theta * tol: its overshoot
    #: delta = sqrt(2 I1 / L) past the onset t* is the lag in t that the whole following viscous
    #: jump inherits (t stays at t* + delta), an error the residuals of the jump steps do not see
    #: (I1 = I2 = 0 in a 1-D jump). One step, so nothing for the global residual; on Example 7.1
    #: 1/100 gave 0.12-0.23 of uniform's solves at equal L-infinity error instead of 0.12-0.38.
    crossing_fraction = 0.01

    def __init__(
        self, tol, tau0, tau_min=1e-12, tau_max=math.inf, theta: float = 0.5, grow: float = 4.0
    ):
        super().__init__(tau0, tau_min, tau_max)
        self.tol = check_positive("tol", tol)
        self.theta = check_positive("theta", theta)
        if self.theta >= 1.0:
            raise fail("theta", self.theta, "must be < 1 (the target theta * tol is below tol)")
        self.grow = check_positive("grow", grow)
        if self.grow <= 1.0:
            raise fail("grow", self.grow, "must be > 1")
        # per regime: the exponent p and (e, tau) of the last two accepted steps in a row there
        self._models: dict = {}
        self._last_regime: str | None = None
        # the last rejected attempt from the current state: {"tau", "e", "regime"}
        self._rejected: dict | None = None
        self._s = 0.0  # s_{k-1} of the step being tried (from propose)
        # end of a sticking phase: [s_end, I1] of rejected sticking attempts with I1 > 0
        self._onset_samples: list = []
        self._catch_up = CatchUp()

    def _model(self, regime: str) -> dict:
        return self._models.setdefault(regime, {"p": 2.0, "history": []})

    def propose(self, s):
        """sigma, or from before the onset of instability the step out of sticking."""
        self._s = float(s)
        sigma = self._clamp(self.sigma)
        crossing = self._sticking_crossing()
        if crossing is not None and s <= crossing[0]:
            # from before the onset: a step >= delta (the floor behind (5.7)); the rejected
            # attempts ended beyond its end (their I1 >= tol > q theta tol)
            # never below tau_min (a denormal tol gives a delta of 1e-161): such a step is then
            # rejected and the run stops with 'step size fell below tau_min' like the others
            sigma = self._clamp(max(crossing[0] + crossing[1] - s, self.tau_min))
        return sigma, None

    def _sticking_crossing(self) -> tuple[float, float] | None:
        """(s*, delta): the onset of instability and the overshoot past it with I1 = q theta tol.

        While z sticks, t - s is constant and dist(-D_z I(t, z)) = 0 up to t*, then about
        L (t - t*); so every sticking attempt that ends at s_end > s* has
        I1 = int_{t*}^{t_end} dist dt ~ L (s_end - s*)^2 / 2 whatever its start: sqrt(I1) is
        affine in s_end (exactly when dist is affine in t, as in Example 7.1: L = 1, the
        issue's I1 = tau^2/2). Two rejected sticking attempts give s* and L, and the step that
        ends at s* + delta, delta = sqrt(2 q theta tol / L), q = :attr:`crossing_fraction`,
        leaves sticking with I1 = q theta tol. None until two samples exist.
        """
        if len(self._onset_samples) < 2:
            return None
        (s1, e1), (s2, e2) = self._onset_samples[-2:]
        u1, u2 = math.sqrt(e1), math.sqrt(e2)
        if s1 == s2:
            return None
        slope = (u1 - u2) / (s1 - s2)  # sqrt(L / 2)
        if slope <= 0.0:
            return None
        s_star = s1 - u1 / slope
        return s_star, math.sqrt(self.crossing_fraction * self.theta * self.tol) / slope

    def decide(self, result) -> Decision:
        """Accept as Alg. 3.2; the next step from the error model of the regime."""
        tau = result.tau
        if not result.converged:
            self._rejected = None  # no error measure: nothing to learn from this attempt
            self.sigma = tau / 4
            return Decision(False, self.sigma, f"inner solve failed ({result.code})")
        I1, I2 = result.errors["I1"], result.errors["I2"]
        e = max(I1, I2, 0.0)  # I2 >= 0 up to quadrature error (Lemma 4.12)
        accept = I1 < self.tol and I2 < self.tol
        regime = step_regime(result)
        if regime == "stick" and not accept and I1 > 0.0:
            self._onset_samples = (self._onset_samples + [[self._s + tau, I1]])[-2:]
        elif regime != "stick":
            self._onset_samples = []
        model = self._model(regime)
        rej = self._rejected
        if rej is not None and rej["regime"] == regime and e > 0.0 and rej["e"] > 0.0:
            ratio = rej["tau"] / tau
            if ratio > 1.1:  # two attempts from the same state: the local order of e(tau)
                p_obs = math.log(rej["e"] / e) / math.log(ratio)
                model["p"] = min(max(p_obs, 1.0), 4.0)
        p = model["p"]
        target = self.theta * self.tol
        if not accept:
            self._rejected = {"tau": tau, "e": e, "regime": regime}
            self.sigma = min(max(tau * (target / e) ** (1.0 / p), tau / 10), 0.9 * tau)
            return Decision(False, self.sigma, f"I1={I1:.3g}, I2={I2:.3g} >= tol={self.tol:g}")
        self._rejected = None
        history = model["history"] if regime == self._last_regime else []
        C = _quotient(e, tau, p)
        C2 = _quotient(e, tau, 2.0)  # the quotient that Lemma 5.3 bounds
        for e_j, tau_j in history[-1:]:
            C = max(C, _quotient(e_j, tau_j, p))
            C2 = max(C2, _quotient(e_j, tau_j, 2.0))
        model["history"] = (history + [[e, tau]])[-2:]
        self._last_regime = regime
        ideal = self.grow * tau if C == 0.0 else (target / C) ** (1.0 / p)
        new = min(max(ideal, tau / 4), self.grow * tau)
        guided = self._catch_up.propose(result, target, 1.0)
        if guided is not None:
            new = min(max(guided, tau / 4), self.grow * tau)
        if C2 > 0.0:  # the floor behind (5.7): never below half the tau^2-law step
            new = max(new, min(self.grow * tau, 0.5 * math.sqrt(target / C2)))
        self.sigma = self._clamp(new)
        return Decision(True, self.sigma, "accepted")

    def _extra_state(self) -> dict:
        return {
            "models": {
                r: {"p": float(m["p"]), "history": [[float(e), float(t)] for e, t in m["history"]]}
                for r, m in self._models.items()
            },
            "last_regime": self._last_regime,
            "rejected": None if self._rejected is None else dict(self._rejected),
            "s": float(self._s),
            "onset_samples": [[float(a), float(b)] for a, b in self._onset_samples],
            "catch_up": self._catch_up.state(),
        }

    def _restore_extra(self, data: dict) -> None:
        self._models = {
            r: {"p": float(m["p"]), "history": [[float(e), float(t)] for e, t in m["history"]]}
            for r, m in data["models"].items()
        }
        self._last_regime = data["last_regime"]
        rej = data["rejected"]
        self._rejected = (
            None
            if rej is None
            else {"tau": float(rej["tau"]), "e": float(rej["e"]), "regime": str(rej["regime"])}
        )
        self._s = float(data["s"])
        self._onset_samples = [[float(a), float(b)] for a, b in data["onset_samples"]]
        self._catch_up.restore(data.get("catch_up"))  # None: a checkpoint before the rule


def _quotient(e: float, tau: float, p: float) -> float:
    """e / tau^p, inf where tau^p underflows (tiny steps of tiny tolerances)."""
    tp = tau**p
    return e / tp if tp > 0.0 else (0.0 if e == 0.0 else math.inf)


# -- step control as the user asks for it: validated objects (Uniform, Adaptive: stepping) -------


@dataclass(frozen=True)
class Order2:
    """Alg. 3.2's acceptance with the next step from the order of the residuals (Lemma 5.3).

    Parameters
    ----------
    tol : float > 0
        Accept a step iff I1 < tol and I2 < tol.
    tau : float > 0, optional
        The first step (None: 0.1).
    tau_min, tau_max : float > 0, optional
        The range of the steps (None: 1e-12 and no upper bound); a run stops when a rejection
        would go below ``tau_min``.
    safety : float > 0
        tau_next = clip(safety sqrt(tol / C), tau/4, 4 tau) (:class:`Order2Controller`).
    """

    tol: float
    tau: float | None = None
    tau_min: float | None = None
    tau_max: float | None = None
    safety: float = 0.9

    def __post_init__(self):
        object.__setattr__(self, "tol", check_positive("tol", self.tol))
        _check_step_range(self)
        object.__setattr__(self, "safety", check_positive("safety", self.safety))


@dataclass(frozen=True)
class Regime:
    """Alg. 3.2's acceptance, every step aimed at the same residual theta tol from an error
    model I ~ C tau^p per regime (sticking, viscous jump, slip; :class:`RegimeController`).

    Parameters
    ----------
    tol, tau, tau_min, tau_max
        As for :class:`Order2`: accept iff I1 < tol and I2 < tol; the first step (None: 0.1)
        and the range of the steps (None: 1e-12 and no upper bound).
    theta : float in (0, 1)
        Every step aims at the residual theta tol.
    grow : float > 1
        The largest growth of the step from one accepted step to the next.
    """

    tol: float
    tau: float | None = None
    tau_min: float | None = None
    tau_max: float | None = None
    theta: float = 0.5
    grow: float = 4.0

    def __post_init__(self):
        object.__setattr__(self, "tol", check_positive("tol", self.tol))
        _check_step_range(self)
        theta = check_positive("theta", self.theta)
        if theta >= 1.0:
            raise fail("theta", theta, "must be < 1 (the target theta * tol is below tol)")
        grow = check_positive("grow", self.grow)
        if grow <= 1.0:
            raise fail("grow", grow, "must be > 1")
        object.__setattr__(self, "theta", theta)
        object.__setattr__(self, "grow", grow)


@dataclass(frozen=True)
class Nested:
    """Alg. 6.2: one run per tolerance tol_1 > tol_2 > ..., run n never stepping over a grid
    point of the runs before it (6.1), so that the s-grids nest (Assumption 6.1(3)).

    Passed to :func:`rothe.ris.run.run_nested` (one result per tolerance); the first run is
    Alg. 3.2 (:class:`AdaptiveController`), run n the same with the grids of runs 1 ... n-1.

    Parameters
    ----------
    tols : sequence of float
        Strictly decreasing positive tolerances.
    tau : float > 0, optional
        The first step of every run (None: 0.1).
    tau_min, tau_max : float > 0, optional
        The range of the steps (None: 1e-12 and no upper bound).
    """

    tols: tuple
    tau: float | None = None
    tau_min: float | None = None
    tau_max: float | None = None

    def __post_init__(self):
        if isinstance(self.tols, (str, bytes)) or not hasattr(self.tols, "__len__"):
            raise fail(
                "tols",
                described(f"a {type(self.tols).__name__}"),
                "must be a sequence of decreasing tolerances",
            )
        object.__setattr__(self, "tols", tuple(check_decreasing("tols", self.tols)))
        _check_step_range(self)


#: the step-control objects a single RIS run takes (run_nested takes :class:`Nested`)
RUN_CONTROLS = (Uniform, Adaptive, Order2, Regime)


def step_range(control) -> tuple[float, float, float]:
    """(tau, tau_min, tau_max) of a step-control object, the RIS defaults where it has None."""
    tau = control.tau if control.tau is not None else DEFAULT_TAU
    tau_min = getattr(control, "tau_min", None)
    tau_max = getattr(control, "tau_max", None)
    return (
        tau,
        DEFAULT_TAU_MIN if tau_min is None else tau_min,
        DEFAULT_TAU_MAX if tau_max is None else tau_max,
    )


def check_control(control) -> None:
    """Refuse anything but the step-control objects of one run (one line naming ``control``)."""
    if isinstance(control, RUN_CONTROLS):
        return
    what = repr(control) if isinstance(control, str) else f"a {type(control).__name__}"
    hint = (
        "; run_nested runs a Nested sequence of tolerances" if isinstance(control, Nested) else ""
    )
    raise fail(
        "control",
        described(what),
        "must be a step-control object: Uniform(tau), Adaptive(tol) "
        "(rothe.stepping.controllers), Order2(tol) or Regime(tol) (rothe.ris.controllers)" + hint,
    )


def build_controller(control, grid=None) -> StepController:
    """The runtime controller of a step-control object (``grid``: the points of earlier runs
    that a run of Alg. 6.2 must not step over; only with an :class:`Adaptive`)."""
    check_control(control)
    tau, tau_min, tau_max = step_range(control)
    if isinstance(control, Uniform):
        return UniformController(tau, tau_min)
    if isinstance(control, Order2):
        return Order2Controller(control.tol, tau, tau_min, tau_max, safety=control.safety)
    if isinstance(control, Regime):
        return RegimeController(
            control.tol, tau, tau_min, tau_max, theta=control.theta, grow=control.grow
        )
    return AdaptiveController(control.tol, tau, tau_min, tau_max, grid=grid)
