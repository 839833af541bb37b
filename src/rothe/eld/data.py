"""The data of step j: F^j, G^j, G_dot^j, G_ddot^j (Sec. 3.1.1), optionally perturbed (Sec. 4.3).

The step runs from t_{j-1} to t_j = t_{j-1} + tau_j (steps may vary). Modes:

- :class:`Points` (3.3): every datum at t_j: F(t_j), G(t_j), G_dot(t_j), G_ddot(t_j).
- :class:`Means` (3.1): step means over (t_{j-1}, t_j]. For F by the two-point Gauss rule in time
  (exact for cubics). For the constraint the paper's recipe after Lemma 3.1: G by point values
  and its derivatives by means, which the fundamental theorem makes exact,
  G_dot^j = (G(t_j) - G(t_{j-1}))/tau_j and G_ddot^j = (G_dot(t_j) - G_dot(t_{j-1}))/tau_j.
  Step means are first-order data (they sit O(tau) away from the values at t_j): Euler only.
- :class:`Differenced`: G_dot^j and G_ddot^j are the scheme's own difference quotients of the
  (perturbed) point values of G: with the step coefficients (alpha_0, alpha_1, alpha_2) of
  :meth:`rothe.eld.scheme.Scheme.coefficients`,
  G_dot^j = (alpha_0 G^j + alpha_1 G^{j-1} + alpha_2 G^{j-2}) / tau_j and the same for G_ddot
  from G_dot. These are exactly the boundary velocity and acceleration the original form sees,
  so the regularized form then reproduces the original one to round-off. Provided to check
  that, not as a recommendation: it throws away the robustness of Theorem 4.5. The history
  G^{j-1}, G^{j-2}, G_dot^{j-1}, G_dot^{j-2} lives in the state's boundary vectors (so a
  rejected step and a resumed run see the same values): the mode says which
  (:meth:`DataMode.initial_history`, :meth:`DataMode.history`, :meth:`DataMode.next_history`).

All modes are pure functions of (j, t_{j-1}, t_j) and, for :class:`Differenced`, of the history
passed in: a rejected and retried step, a changed step size and a resumed run are consistent.

Perturbations (:class:`DataNoise`): Theorem 4.5 perturbs F^j by delta^j in V*, and G^j, G_dot^j,
G_ddot^j by theta^j, xi^j, vartheta^j in Q*, each its own delta-sized error. Here each datum
can be perturbed alone or together with others: theta, xi, vartheta are independent vectors of
nodal values, uniform in [-delta, delta] on every constrained dof, and the load noise is M r with
r uniform in [-delta, delta] at every dof (an L2 body force of size delta). The noise of step j
depends only on (seed, j, datum), so two runs (e.g. the two forms) see the same theta^j. The
original form uses G only (its derivatives are difference quotients of G + theta), so noise in
G_dot or G_ddot does not reach it; with differenced data the same holds for the regularized form.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import (
    check_choice,
    check_instance,
    check_int,
    check_nonnegative,
    described,
    fail,
)

#: the data a DataNoise may perturb, with their random streams
NOISE_TARGETS = ("G", "G_dot", "G_ddot", "F")
_STREAM = {"G": 1, "G_dot": 2, "G_ddot": 3, "F": 4}

_GAUSS2 = (0.5 - 0.5 / np.sqrt(3.0), 0.5 + 0.5 / np.sqrt(3.0))


@dataclass
class DataNoise:
    """delta-sized noise in one datum (``target='G'``, ``'G_dot'``, ``'G_ddot'`` or ``'F'``) or in
    several at once (``target=('G', 'G_dot', 'G_ddot')``: the separate data of (4.6)).

    Parameters
    ----------
    delta : float >= 0
        The size of the noise (uniform in [-delta, delta] per constrained dof; the load noise is
        M r with r uniform in [-delta, delta]).
    target : str or tuple of str
        The perturbed data, among ``'G'``, ``'G_dot'``, ``'G_ddot'``, ``'F'``.
    seed : int >= 0
        The noise of step j depends only on (seed, j, datum).
    """

    delta: float
    target: str | tuple = "G"
    seed: int = 0

    def __post_init__(self):
        self.delta = check_nonnegative("delta", self.delta)
        targets = (self.target,) if isinstance(self.target, str) else tuple(self.target)
        if not targets:
            raise fail(
                "noise target",
                described("()"),
                "must name at least one of " + ", ".join(NOISE_TARGETS),
            )
        for t in targets:
            check_choice("noise target", t, NOISE_TARGETS)
        self.target = targets[0] if len(targets) == 1 else targets
        self.targets = targets
        self.seed = check_int("seed", self.seed, minimum=0)

    def _uniform(self, j: int, stream: int, n: int) -> np.ndarray:
        rng = np.random.default_rng([int(self.seed), int(j), int(stream)])
        return self.delta * rng.uniform(-1.0, 1.0, n)

    def perturbs(self, datum: str) -> bool:
        """Whether ``datum`` ('G', 'G_dot', 'G_ddot' or 'F') is perturbed."""
        return datum in self.targets

    def datum_noise(self, datum: str, j: int, n: int) -> np.ndarray | None:
        """The noise of step j in one datum (a vector of length n), or None if not perturbed."""
        if datum not in self.targets:
            return None
        return self._uniform(j, _STREAM[datum], n)

    def constraint_noise(self, j: int, m: int) -> tuple:
        """(theta^j, xi^j, vartheta^j): the noise in G, G_dot, G_ddot (zeros where unperturbed)."""
        return tuple(
            self._uniform(j, _STREAM[k], m) if k in self.targets else np.zeros(m)
            for k in ("G", "G_dot", "G_ddot")
        )

    def load_noise(self, j: int, M) -> np.ndarray | None:
        """The noise of step j in F: M r with r uniform in [-delta, delta] (None if F is not
        perturbed).
        """
        if "F" not in self.targets:
            return None
        return M @ self._uniform(j, _STREAM["F"], M.shape[0])

    def describe(self) -> dict:
        """delta, the targets and the seed (for meta data and checkpoints)."""
        return {"delta": self.delta, "target": list(self.targets), "seed": self.seed}


class DataMode:
    """How the data of a step enter (module docstring): :class:`Points`, :class:`Means` or
    :class:`Differenced`. ``name`` is the mode as in trajectories and on the command line.

    The base class is the point-value behaviour of G_dot, G_ddot with no history; a mode that
    needs one keeps it in the state's boundary vectors through the ``*_history`` methods."""

    name: str = ""

    def load(self, problem, t_prev: float, t: float) -> np.ndarray:
        """F^j of the step (t_prev, t]: the load at t."""
        return problem.load(t)

    def derivatives(self, problem, G, t_prev: float, t: float, coefficients, history, noise):
        """(G_dot^j, G_ddot^j) given the (perturbed) G^j and the noise (xi^j, vartheta^j) of
        the two derivatives: the values at t plus the noise."""
        xi, vartheta = noise
        return problem.G_dot(t) + xi, problem.G_ddot(t) + vartheta

    def initial_velocity(self, problem) -> np.ndarray:
        """G_dot^0, the boundary velocity that splits the initial data: G_dot(0)."""
        return problem.G_dot(0.0)

    def check(self, scheme) -> None:
        """Refuse a scheme this mode cannot serve (one line naming ``data``)."""

    # -- the data history in the state's boundary vectors (none by default) ---------------------
    def initial_history(self, G0, G_dot0) -> dict:
        """The boundary vectors of the state at t = 0."""
        return {}

    def history(self, boundary: dict, coefficients) -> dict | None:
        """What :meth:`derivatives` needs of the state's boundary vectors (None: nothing)."""
        return None

    def start_history(self, U1, V0, V1, dofs) -> dict:
        """Boundary vectors of the BDF2 start history u^{-1} = U1, v^0 = V0, v^{-1} = V1."""
        return {}

    def next_history(self, boundary: dict, values) -> dict:
        """Boundary vectors of the state after a step with the data ``values``."""
        return {}


@dataclass(frozen=True)
class Points(DataMode):
    """(3.3): F, G, G_dot, G_ddot at t_j (the default)."""

    name = "points"


@dataclass(frozen=True)
class Means(DataMode):
    """(3.1): step means over (t_{j-1}, t_j]: F by the two-point Gauss rule in time, G at t_j,
    G_dot^j = (G(t_j) - G(t_{j-1}))/tau_j, G_ddot^j = (G_dot(t_j) - G_dot(t_{j-1}))/tau_j.
    First-order data: implicit Euler only."""

    name = "means"

    def load(self, problem, t_prev, t):
        """F^j by the two-point Gauss rule on (t_{j-1}, t_j] (F(t_j) for a problem without
        loads).
        """
        if not problem.has_loads:
            return problem.load(t)
        tau = t - t_prev
        return sum(0.5 * problem.load(t_prev + a * tau) for a in _GAUSS2)

    def derivatives(self, problem, G, t_prev, t, coefficients, history, noise):
        """G_dot^j = (G(t_j) - G(t_{j-1}))/tau_j + xi^j and G_ddot^j = (G_dot(t_j) -
        G_dot(t_{j-1}))/tau_j
        + vartheta^j (the recipe after Lemma 3.1).
        """
        xi, vartheta = noise
        tau = t - t_prev
        return (
            (problem.G(t) - problem.G(t_prev)) / tau + xi,
            (problem.G_dot(t) - problem.G_dot(t_prev)) / tau + vartheta,
        )

    def check(self, scheme) -> None:
        """Refuse a scheme of order > 1 (step means are first-order data)."""
        if scheme.order > 1:
            raise fail(
                "data",
                self.name,
                f"with scheme {scheme.name} must be points or "
                "differenced (step means are first-order data: they sit O(tau) away from "
                "t_j)",
            )


@dataclass(frozen=True)
class Differenced(DataMode):
    """G_dot^j, G_ddot^j the scheme's own difference quotients of the point values of G (the
    original form's boundary velocity and acceleration; module docstring). The history
    G^{j-1}, G^{j-2}, G_dot^{j-1}, G_dot^{j-2} lives in the state's boundary vectors ``G``,
    ``G_1``, ``G_dot``, ``G_dot_1``."""

    name = "differenced"

    def derivatives(self, problem, G, t_prev, t, coefficients, history, noise):
        """The scheme's quotients of the perturbed G (the noise in G_dot, G_ddot does not
        reach them)."""
        a0, a1, a2 = coefficients
        h = history
        tau = t - t_prev
        G_dot = (a0 * G + a1 * h["G"] + (a2 * h["G_1"] if a2 else 0.0)) / tau
        G_ddot = (a0 * G_dot + a1 * h["G_dot"] + (a2 * h["G_dot_1"] if a2 else 0.0)) / tau
        return G_dot, G_ddot

    def initial_velocity(self, problem):
        """The boundary value of the initial velocity (what the original form's Euler start
        sees)."""
        return problem.constraint.restrict(problem.v0)

    def initial_history(self, G0, G_dot0):
        """The boundary vectors G^0 and G_dot^0 of the initial state."""
        return {"G": G0, "G_dot": G_dot0}

    def history(self, boundary, coefficients):
        """G^{j-1}, G_dot^{j-1} and, when alpha_2 != 0, G^{j-2}, G_dot^{j-2} from the state."""
        hist = {k: boundary[k] for k in ("G", "G_dot")}
        if coefficients[2]:
            hist.update(G_1=boundary["G_1"], G_dot_1=boundary["G_dot_1"])
        return hist

    def start_history(self, U1, V0, V1, dofs):
        """The BDF2 start history as G^{-1} = U1, G_dot^0 = V0, G_dot^{-1} = V1 on the
        constrained dofs.
        """
        return {"G_1": U1[dofs], "G_dot": V0[dofs], "G_dot_1": V1[dofs]}

    def next_history(self, boundary, values):
        """Shift the history: this step's G, G_dot become G^{j-1}, G_dot^{j-1}."""
        return {
            "G": values.G,
            "G_1": boundary["G"],
            "G_dot": values.G_dot,
            "G_dot_1": boundary["G_dot"],
        }


#: the data mode of a run that names none
DEFAULT_DATA = Points()
#: the data modes by name (the command line's ``--data``)
DATA_MODES = {"points": Points, "means": Means, "differenced": Differenced}


def as_data_mode(data) -> DataMode:
    """``data`` if it is a :class:`DataMode`, else a one-line error naming ``data``."""
    return check_instance(
        "data", data, DataMode, "Points(), Means() or Differenced() (rothe.eld.data)"
    )


@dataclass
class StepValues:
    """The data of one step j (module docstring): F^j (dof vector), G^j, G_dot^j, G_ddot^j
    (constraint vectors), perturbed if the run has a :class:`DataNoise`.
    """

    F: np.ndarray
    G: np.ndarray
    G_dot: np.ndarray
    G_ddot: np.ndarray

    def first_nonfinite(self) -> str | None:
        """The name of the first datum with a NaN or inf entry, or None."""
        for name in ("F", "G", "G_dot", "G_ddot"):
            if not np.all(np.isfinite(getattr(self, name))):
                return name
        return None


class StepData:
    """Evaluates the data of a step from t_prev to t (see the module docstring).

    Parameters
    ----------
    problem : ELDProblem
    mode : DataMode, optional
        Points (default), Means or Differenced.
    noise : DataNoise, optional
        The perturbation of the data (Theorem 4.5).
    """

    def __init__(self, problem, mode: DataMode | None = None, noise: DataNoise | None = None):
        self.problem = problem
        self.mode = DEFAULT_DATA if mode is None else as_data_mode(mode)
        if noise is not None and not isinstance(noise, DataNoise):
            raise fail("noise", type(noise).__name__, "must be a rothe.eld.DataNoise")
        self.noise = noise

    def initial(self) -> tuple[np.ndarray, np.ndarray]:
        """(G^0, G_dot^0): the constraint data at t = 0 used to split the initial data.

        With differenced data G_dot^0 is the boundary value of the initial velocity (what the
        original form's Euler start sees)."""
        p = self.problem
        return p.G(0.0), self.mode.initial_velocity(p)

    def at(self, j: int, t_prev: float, t: float, coefficients=None, history=None) -> StepValues:
        """The data of step j on (t_prev, t].

        ``coefficients`` (alpha_0, alpha_1, alpha_2) and ``history`` (a dict with ``G``, ``G_1``,
        ``G_dot``, ``G_dot_1``: the perturbed G^{j-1}, G^{j-2} and the differenced G_dot^{j-1},
        G_dot^{j-2}) are needed with differenced data only.
        """
        p = self.problem
        F = self.mode.load(p, t_prev, t)
        m = p.constraint.m
        if self.noise is not None:
            theta, xi, vartheta = self.noise.constraint_noise(j, m)
            dF = self.noise.load_noise(j, p.M)
            if dF is not None:
                F = F + dF
        else:
            theta = xi = vartheta = 0.0
        G = p.G(t) + theta
        G_dot, G_ddot = self.mode.derivatives(
            p, G, t_prev, t, coefficients, history, (xi, vartheta)
        )
        return StepValues(F=F, G=G, G_dot=G_dot, G_ddot=G_ddot)
