"""The data of step j: F^j, G^j, G_dot^j, G_ddot^j (Sec. 3.1.1), optionally perturbed (Sec. 4.3).

Modes (t_j = j tau):

- ``points`` (3.3): every datum at t_j: F(t_j), G(t_j), G_dot(t_j), G_ddot(t_j).
- ``means`` (3.1): step means over (t_{j-1}, t_j]. For F by the two-point Gauss rule in time
  (exact for cubics). For the constraint the paper's recipe after Lemma 3.1: G by point values
  and its derivatives by means, which the fundamental theorem makes exact,
  G_dot^j = (G(t_j) - G(t_{j-1}))/tau = D G^j and G_ddot^j = (G_dot(t_j) - G_dot(t_{j-1}))/tau.
- ``differenced``: G_dot^j = D G^j and G_ddot^j = D G_dot^j from the point values of G (with
  G_dot^0 = S h, the boundary values of the initial velocity). These are exactly the
  derivatives the original form sees, so the regularized form then reproduces the original one
  to round-off. Provided to check that, not as a recommendation: it throws away the robustness
  of Theorem 4.5.

Perturbations (:class:`DataNoise`): Theorem 4.5 perturbs F^j by delta^j in V*, and G^j, G_dot^j,
G_ddot^j by theta^j, xi^j, vartheta^j in Q*, each its own delta-sized error. Here theta, xi,
vartheta are independent vectors of nodal values, uniform in [-delta, delta] on every
constrained dof, and the load noise is M r with r uniform in [-delta, delta] at every dof (an L2
body force of size delta). The noise of step j depends only on (seed, j), so two runs (e.g. the
two forms) see the same theta^j. In ``differenced`` mode the noise enters G only and is then
differenced, as in the original form.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import check_choice, check_nonnegative, check_positive

DATA_MODES = ("points", "means", "differenced")
NOISE_TARGETS = ("G", "F")

_GAUSS2 = (0.5 - 0.5 / np.sqrt(3.0), 0.5 + 0.5 / np.sqrt(3.0))


@dataclass
class DataNoise:
    """delta-sized noise in the constraint data (target 'G') or in the load (target 'F')."""

    delta: float
    target: str = "G"
    seed: int = 0

    def __post_init__(self):
        self.delta = check_nonnegative("delta", self.delta)
        self.target = check_choice("noise target", self.target, NOISE_TARGETS)

    def _uniform(self, j: int, stream: int, n: int) -> np.ndarray:
        rng = np.random.default_rng([int(self.seed), int(j), int(stream)])
        return self.delta * rng.uniform(-1.0, 1.0, n)

    def constraint_noise(self, j: int, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(theta^j, xi^j, vartheta^j), independent."""
        if self.target != "G":
            z = np.zeros(m)
            return z, z, z
        return self._uniform(j, 1, m), self._uniform(j, 2, m), self._uniform(j, 3, m)

    def load_noise(self, j: int, M) -> np.ndarray | None:
        if self.target != "F":
            return None
        return M @ self._uniform(j, 4, M.shape[0])


@dataclass
class StepValues:
    F: np.ndarray
    G: np.ndarray
    G_dot: np.ndarray
    G_ddot: np.ndarray


class StepData:
    """Evaluates the data of steps j = 1, 2, ... in order (see the module docstring)."""

    def __init__(self, problem, tau: float, mode: str = "points", noise: DataNoise | None = None):
        self.problem = problem
        self.tau = check_positive("tau", tau)
        self.mode = check_choice("data", mode, DATA_MODES)
        self.noise = noise
        self._j = 0
        c = problem.constraint
        self.G0 = problem.G(0.0)
        if self.mode == "differenced":
            self.G_dot0 = c.restrict(problem.v0)
        else:
            self.G_dot0 = problem.G_dot(0.0)
        self._prev_G = self.G0
        self._prev_G_dot = self.G_dot0
        self._prev_G_exact = self.G0
        self._prev_G_dot_exact = problem.G_dot(0.0) if self.mode == "means" else self.G_dot0

    def initial(self) -> tuple[np.ndarray, np.ndarray]:
        """(G^0, G_dot^0): the constraint data at t = 0 used to split the initial data."""
        return self.G0, self.G_dot0

    def at(self, j: int) -> StepValues:
        if j != self._j + 1:
            raise RuntimeError(f"StepData: step {j} requested after step {self._j}")
        self._j = j
        p, tau = self.problem, self.tau
        t = j * tau
        if self.mode == "means" and p.has_loads:
            F = sum(0.5 * p.load((j - 1) * tau + a * tau) for a in _GAUSS2)
        else:
            F = p.load(t)
        m = p.constraint.m
        theta, xi, vartheta = (self.noise.constraint_noise(j, m) if self.noise is not None
                               else (0.0, 0.0, 0.0))
        if self.noise is not None:
            dF = self.noise.load_noise(j, p.M)
            if dF is not None:
                F = F + dF
        G_exact = p.G(t)
        G = G_exact + theta
        if self.mode == "points":
            G_dot = p.G_dot(t) + xi
            G_ddot = p.G_ddot(t) + vartheta
        elif self.mode == "means":
            G_dot = (G_exact - self._prev_G_exact) / tau + xi
            G_dot_exact = p.G_dot(t)
            G_ddot = (G_dot_exact - self._prev_G_dot_exact) / tau + vartheta
            self._prev_G_dot_exact = G_dot_exact
        else:  # differenced: the perturbed G enters, its derivatives are difference quotients
            G_dot = (G - self._prev_G) / tau
            G_ddot = (G_dot - self._prev_G_dot) / tau
        self._prev_G, self._prev_G_dot, self._prev_G_exact = G, G_dot, G_exact
        return StepValues(F=F, G=G, G_dot=G_dot, G_ddot=G_ddot)
