"""The residuals I_1^k (3.3) and I_2^k (3.4) of one step, by composite Simpson.

On [s_{k-1}, s_k] (length tau) with theta = (s - s_{k-1}) / tau, the affine interpolants are
z^(theta) = z_{k-1} + theta d, t^(theta) = t_{k-1} + theta dt with d = z_k - z_{k-1},
dt = t_k - t_{k-1}; hence t^' = dt / tau and z^' = d / tau are constant, and

    I_1^k = int t^'(s) dist(-D_z I(t^, z^)) ds
          = dt * int_0^1 dist(theta) dtheta,                                             (3.3)
    I_2^k = int <D_z I(t^, z^) - D_z I(t_{k-1}, z_k), z^'>
            + ||z^'||_V (dist(t^, z^) - dist(t_{k-1}, z_k)) ds
          = int_0^1 <D_z I(theta) - gbar, d> + ||d||_V (dist(theta) - distbar) dtheta,   (3.4)

with gbar = D_z I(t_{k-1}, z_k) (the gradient at the inner solution) and distbar its distance.

Quadrature: composite Simpson with ``n`` subintervals (``n`` even; default 8). Why 8: the
integrands are only piecewise smooth (dist has kinks where some |eta_i| crosses r_i), so higher
order buys little; 8 subintervals cost 9 gradient evaluations (far below one Newton iteration),
and the embedded Simpson rule on the even points (n/2 = 4 subintervals) gives an error estimate
|S_n - S_{n/2}| for free. That estimate is the "quadrature error bound" against which Lemma 4.12
(I_2 >= 0) is checked: I_2 >= -|S_n - S_{n/2}|. The gradient along the segment is evaluated as
A z_{k-1} + theta A d + F'(z^) - l(t^): two matrix-vector products per step, not one per point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import check_int
from .problem import RISProblem


@dataclass
class StepResiduals:
    """I1 (3.3) and I2 (3.4) of one step, each with its quadrature error estimate."""

    I1: float
    I2: float
    I1_err: float  # |S_n - S_{n/2}| for I1
    I2_err: float  # |S_n - S_{n/2}| for I2
    # dist(-D_z I, dR(0)) at the two ends of the segment: (t_{k-1}, z_{k-1}) and (t_k, z_k);
    # in a viscous jump (t_k = t_{k-1}) their decrease tells how far the jump still goes
    dist_start: float = float("nan")
    dist_end: float = float("nan")


def simpson_weights(n: int) -> np.ndarray:
    """Weights of composite Simpson on [0, 1] with n (even) subintervals, n + 1 points."""
    n = check_int("simpson_subintervals", n, minimum=2)
    if n % 2:
        raise ValueError(f"simpson_subintervals: got {n}, must be even")
    w = np.ones(n + 1)
    w[1:-1:2] = 4.0
    w[2:-1:2] = 2.0
    return w / (3.0 * n)


def _coarse_weights(n: int) -> np.ndarray:
    """Weights of the embedded rule on the same n+1 points (Simpson on even points or trapezoid)."""
    w = np.zeros(n + 1)
    if n % 4 == 0:
        w[::2] = simpson_weights(n // 2)
    else:
        w[:] = 1.0 / n
        w[0] = w[-1] = 0.5 / n
    return w


def step_residuals(
    problem: RISProblem,
    t_prev: float,
    z_prev: np.ndarray,
    t_new: float,
    z_new: np.ndarray,
    gbar: np.ndarray,
    n: int = 8,
) -> StepResiduals:
    """I_1^k and I_2^k of (3.3), (3.4) with their embedded-rule error estimates."""
    w = simpson_weights(n)
    wc = _coarse_weights(n)
    theta = np.linspace(0.0, 1.0, n + 1)
    d = z_new - z_prev
    dt = t_new - t_prev
    moving = bool(np.any(d != 0.0))
    nd = problem.norm_V(d)
    distbar = problem.dist(gbar)

    A = problem.A
    Az_prev = A @ z_prev
    Ad = A @ d if moving else None
    f1 = np.empty(n + 1)
    f2 = np.zeros(n + 1)
    for j, th in enumerate(theta):
        z = z_prev + th * d if moving else z_prev
        g = Az_prev + (th * Ad if moving else 0.0) + problem.dF(z) - problem.load(t_prev + th * dt)
        dist = problem.dist(g)
        f1[j] = dist
        if moving:
            f2[j] = float((g - gbar) @ d) + nd * (dist - distbar)
    I1 = dt * float(w @ f1)
    I1c = dt * float(wc @ f1)
    I2 = float(w @ f2)
    I2c = float(wc @ f2)
    return StepResiduals(
        I1=I1,
        I2=I2,
        I1_err=abs(I1 - I1c),
        I2_err=abs(I2 - I2c),
        dist_start=float(f1[0]),
        dist_end=float(f1[-1]),
    )
