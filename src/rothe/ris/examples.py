"""Example 7.1 of Andreia & Meyer (2022): a one-dimensional RIS with a known BV solution.

Z = V = R, V = 1, R(v) = |v|, T = 5, z_0 = -2 and (note the sign of the load)

    I(t, z) = 1/2 z^2 - (t + 1) z + p(z),
    p(z) = 4z + 8 (z <= -2),   4 - z^2 (|z| < 2),   -4z + 8 (z >= 2).

The paper prints f with a sign convention under which (7.1) is not a solution; with the energy
above, (7.1) is: D_z I(t, -2) = 1 - t, so z = -2 sticks while |1 - t| <= 1, i.e. until t = 2;
for -2 < z < 2, -D_z I(2, z) = z + 3 > 1, so there is no stable state until z >= 6, where
D_z I(2, z) = z - 7 reaches -1 (viscous jump from -2 to 6 at t = 2); then z - (t + 1) - 4 = -1
keeps the state on the slip line z = t + 4.

Exact V-parametrized BV solution (7.1), s in [0, 16]:
    t(s) = s, 2, (s - 6)/2     and     z(s) = -2, s - 4, (s + 2)/2
on [0, 2], (2, 10], (10, 16].
"""

from __future__ import annotations

import numpy as np

from .problem import RISProblem

S_EXACT = 16.0
BREAKPOINTS = np.array([0.0, 2.0, 10.0, 16.0])


def p(z):
    z = float(np.asarray(z).reshape(-1)[0])
    if z <= -2:
        return 4 * z + 8
    if z < 2:
        return 4 - z * z
    return -4 * z + 8


def dp(z):
    z = float(np.asarray(z).reshape(-1)[0])
    if z <= -2:
        return np.array([4.0])
    if z < 2:
        return np.array([-2 * z])
    return np.array([-4.0])


def d2p(z):
    """Generalized second derivative: one-sided value at the kinks z = -2 and z = 2."""
    z = float(np.asarray(z).reshape(-1)[0])
    return np.array([-2.0 if -2 < z < 2 else 0.0])


def example_7_1(T: float = 5.0) -> RISProblem:
    """The RIS of Example 7.1 (1 unknown)."""
    return RISProblem(
        A=np.array([[1.0]]),
        F=p,
        dF=dp,
        d2F=d2p,
        load=lambda t: np.array([t + 1.0]),
        load_rate=lambda t: np.array([1.0]),
        dissipation_weights=1.0,
        metric_weights=1.0,
        z0=np.array([-2.0]),
        T=T,
        name="ris-1d",
    )


def exact_solution(s):
    """(t(s), z(s)) of (7.1), continued constantly beyond S = 16."""
    s = np.asarray(s, dtype=float)
    t = np.where(s <= 2, s, np.where(s <= 10, 2.0, (np.minimum(s, S_EXACT) - 6) / 2))
    z = np.where(s <= 2, -2.0, np.where(s <= 10, s - 4, (np.minimum(s, S_EXACT) + 2) / 2))
    return t, z


def errors_against_exact(s_num, t_num, z_num) -> dict:
    """L2 and L-infinity errors of the affine interpolants (t^, z^) against (7.1), over s.

    Both curves are piecewise linear in s; on [0, max(S_h, 16)] the shorter one is continued
    constantly (as in the paper's convergence proofs). The difference is piecewise linear between
    the union of breakpoints, so the max over those points is the exact L-infinity norm and
    Simpson on each piece is the exact L2 norm. The pointwise error is the Euclidean norm of
    (t^ - t, z^ - z).
    """
    s_num = np.asarray(s_num, float)
    t_num = np.asarray(t_num, float)
    z_num = np.asarray(z_num, float).reshape(len(s_num))
    s_end = max(s_num[-1], S_EXACT)
    nodes = np.union1d(np.union1d(s_num, BREAKPOINTS), [s_end])

    def diff(x):
        te, ze = exact_solution(x)
        tn = np.interp(x, s_num, t_num)
        zn = np.interp(x, s_num, z_num)
        return tn - te, zn - ze

    dt, dz = diff(nodes)
    linf = float(np.max(np.hypot(dt, dz)))
    a, b = nodes[:-1], nodes[1:]
    mid = 0.5 * (a + b)
    # evaluate just inside each piece: both interpolants are continuous, so endpoints are exact
    dta, dza = dt[:-1], dz[:-1]
    dtb, dzb = dt[1:], dz[1:]
    dtm, dzm = diff(mid)
    sq = lambda u, v: u * u + v * v  # noqa: E731
    l2sq = np.sum((b - a) / 6 * (sq(dta, dza) + 4 * sq(dtm, dzm) + sq(dtb, dzb)))
    return {"error_l2": float(np.sqrt(l2sq)), "error_linf": linf}
