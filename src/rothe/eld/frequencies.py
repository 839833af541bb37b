"""Analytic references for coupled examples: bars and beams with attached components, the rigid
limit, and the decay of the first mode under feedback (issue 19).

**Longitudinal bar** (length L, Young's modulus E, density rho, cross-section A; wave speed
c = (E/rho)^{1/2}): harmonic motion u(x, t) = phi(x) e^{i w t} with phi = a cos(beta x) +
b sin(beta x), beta = w/c, normal force N = E A phi'. An end is ``"clamped"`` (phi = 0),
``"free"`` (N = 0) or tied to a linear component (an :class:`Attachment`: mass and stiffness
matrices, the coordinate k that moves with the end): (K - w^2 M) q = f e_k, phi(end) = q_k, with
the force of the bar on the component f = +N(0) at x = 0 and f = -N(L) at x = L.
:func:`bar_frequencies` finds the zeros of the determinant of this (2 + m_0 + m_L) linear
system (entire in w: no poles to mistake for roots) by sign changes on a grid refined by
Brent's method.

- Tip mass m at x = L, clamped at 0: beta L tan(beta L) = rho A L / m (:func:`tip_mass_roots`;
  e.g. for a mass equal to the bar's, beta L = 0.8603, 3.4256, 6.4373).
- A bar on a mass-spring support (mass m, spring k to the ground) at x = 0, free at L:
  k - m w^2 = E A beta tan(beta L); the **rigid limit** E -> infinity gives the single degree
  of freedom w^2 = k / (m + rho A L) (:func:`rigid_limit_frequency`), with the first correction
  w^2 = k/(m + m_b) (1 - k m_b^2/(3 E A/L (m + m_b)^2) + ...) (m_b = rho A L; the bar's
  compliance L/(E A) in series, weighted by its mass distribution) -- not used by the tests,
  which compare with the determinant.

**A bar of slices** along x (:func:`sliced_bar_frequencies`): the transfer matrices of the
slices carry (phi, N) from x = 0 to x = L, the same end conditions.

**Measured from a run**: :func:`crossing_frequency` (zero crossings), :func:`modal_frequencies`
(the crossings of each modal coordinate phi_k^T M x of a run), :func:`pencil_frequencies` (the
matrix pencil of one signal on equal steps), :func:`decay_rate`.

**Euler-Bernoulli beam** (bending stiffness E I, mass per length rho A; beta^4 = rho A w^2/(E I)):
w = a_1 cos + a_2 sin + a_3 cosh + a_4 sinh (beta x); ``"clamped"`` (w = w' = 0), ``"free"``
(w'' = w''' = 0) or an :class:`Attachment` moving with the end's deflection (no moment:
w'' = 0, force of the beam on the component -E I w'''(0) at x = 0, +E I w'''(L) at x = L).
Clamped-free: 1 + cos(bL) cosh(bL) = 0, bL = 1.8751, 4.6941, 7.8548; with a tip mass m:
1 + cos cosh + (m/(rho A L)) bL (cos sinh - sin cosh) = 0 (:func:`beam_tip_mass_equation`).
In 2D (plane strain) the beam's E is E/(1 - nu^2); plane stress and 3D: E.

**Feedback on a bar** (:func:`controlled_bar_roots`, the ``eld-control`` set-up): the bar's end
x = 0 is held by a base (mass m_b, spring k_b to the ground) driven by an actuator force
f = -H(s) u(L) from the tip's displacement u(L) (velocity feedback: H = k_v s; PD on the tip
velocity with a filtered derivative: H = s (k_p + k_d s/(1 + T_f s))); the tip x = L is free.
With u = phi(x) e^{s t}, phi = a cosh(s x/c) + b sinh(s x/c):

    phi'(L) = 0,   (m_b s^2 + k_b) phi(0) = E A phi'(0) - H(s) phi(L).

Its roots s = -alpha + i w near the uncontrolled i w_1 give the decay rate alpha of the first
mode (complex Newton from i w_1). For small gains the first-order perturbation is the modal
formula (:func:`first_mode_decay_rate`)

    alpha_1 = Re[H(i w_1)/(i w_1)] W_1 U_1 / (2 m_1),

W_1, U_1 the base and tip amplitudes of the first mode, m_1 = m_b W_1^2 + rho A int phi_1^2 its
modal mass; for velocity feedback alpha_1 = k_v W_1 U_1/(2 m_1) > 0 when base and tip move in
phase (the first mode), while modes with W U < 0 are destabilized (spillover of non-collocated
feedback): what the ``eld-control`` example must show against the analytic rates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import check_int, check_positive, fail
from .components import Component, check_spd

ENDS = ("clamped", "free")


@dataclass
class Attachment:
    """A linear component (mass M, stiffness K; damping ignored: undamped frequencies) tied to
    an end of a bar or beam by its coordinate ``at`` (moving with the end's displacement)."""

    mass: np.ndarray
    stiffness: np.ndarray
    at: int = 0

    def __post_init__(self):
        self.mass = check_spd("mass", np.atleast_2d(np.asarray(self.mass, dtype=float)))
        m = self.mass.shape[0]
        K = np.asarray(self.stiffness, dtype=float)
        self.stiffness = np.zeros((m, m)) + (
            K if K.ndim == 2 else np.diag(np.atleast_1d(K)) if K.size == m else float(K) * np.eye(m)
        )
        self.at = check_int("at", self.at)
        if not 0 <= self.at < m:
            raise fail("at", self.at, f"must be a coordinate index 0..{m - 1}")

    @classmethod
    def of(cls, component: Component, at: int = 0) -> Attachment:
        """From a linear component (its mass and stiffness)."""
        if not component.is_linear:
            raise fail("component", component.name, "must be linear for frequencies")
        return cls(component.mass, component.stiffness, at)

    @classmethod
    def point_mass(cls, m: float) -> Attachment:
        """A point mass m tied to the end (zero stiffness)."""
        return cls(np.array([[check_positive("mass", m)]]), np.zeros((1, 1)))

    @classmethod
    def mass_spring(cls, m: float, k: float) -> Attachment:
        """A mass on a spring to the ground, tied to the end."""
        return cls(np.array([[check_positive("mass", m)]]), np.array([[float(k)]]))

    @classmethod
    def suspended(cls, m_end: float, m: float, k: float) -> Attachment:
        """A mass m_end at the end carrying a mass m on a spring k (a tuned mass damper)."""
        return cls(
            np.diag([check_positive("m_end", m_end), check_positive("mass", m)]),
            np.array([[k, -k], [-k, k]], dtype=float),
            at=0,
        )


def _end(name, value):
    if isinstance(value, Attachment):
        return value
    if value not in ENDS:
        raise fail(name, value, "must be 'clamped', 'free' or an Attachment")
    return value


def _find_roots(f, w_max: float, count: int, n_grid: int) -> np.ndarray:
    """The first ``count`` sign changes of f on (0, w_max], refined by Brent's method."""
    # heavy: scipy.optimize (10 MB resident) only when frequencies are computed, not on
    # every run that imports rothe.eld
    from scipy.optimize import brentq

    w = np.linspace(w_max / n_grid, w_max, n_grid)
    vals = np.array([f(x) for x in w])
    roots = []
    for k in range(n_grid - 1):
        if vals[k] == 0.0:
            roots.append(w[k])
        elif vals[k] * vals[k + 1] < 0:
            roots.append(brentq(f, w[k], w[k + 1], xtol=1e-14 * w[k + 1], rtol=1e-15, maxiter=200))
        if len(roots) == count:
            break
    return np.asarray(roots)


def _bar_ends(left, right):
    """The two ends of a bar (:func:`_end`), refused both free (a rigid motion), with the
    determinant's layout: (left, right, m0 the left component's coordinates, size = 2 + m0 +
    the right one's), the unknowns (phi(0) or its coefficients, 2) then each component's q."""
    left, right = _end("left", left), _end("right", right)
    if left == "free" and right == "free":
        raise fail("left", left, "and right both free: the bar is not held (rigid motion)")
    m0 = left.mass.shape[0] if isinstance(left, Attachment) else 0
    mL = right.mass.shape[0] if isinstance(right, Attachment) else 0
    return left, right, m0, 2 + m0 + mL


def _end_rows(M, row, end, off, sgn, w, phi, force, free, *, scale=1.0) -> int:
    """The rows of one end's condition in the frequency determinant of :func:`bar_frequencies`
    and :func:`sliced_bar_frequencies`, from ``row`` on; returns the next row. ``phi`` and
    ``force`` are the rows of phi and N = E A phi' at the end acting on the two unknowns of the
    bar, ``free`` the row of a free end (N = 0, of a convenient size). Clamped: phi = 0. An
    :class:`Attachment` with coordinates q at column ``off``: phi - q_at = 0 and
    (K - w^2 M) q - sgn N e_at = 0 (sgn = +1 at x = 0, -1 at x = L: the bar's force on the
    component), both divided by ``scale``."""
    if end == "clamped":
        M[row, :2] = phi
        return row + 1
    if end == "free":
        M[row, :2] = free
        return row + 1
    m = end.mass.shape[0]
    M[row, :2] = phi
    M[row, off + end.at] = -1.0
    row += 1
    K = end.stiffness - w * w * end.mass
    M[row : row + m, off : off + m] = K if scale == 1.0 else K / scale
    M[row + end.at, :2] -= sgn * force if scale == 1.0 else sgn * force / scale
    return row + m


def bar_frequencies(
    length: float,
    E: float,
    rho: float,
    *,
    area: float = 1.0,
    left="clamped",
    right="free",
    count: int = 3,
    w_max: float | None = None,
    n_grid: int = 4000,
) -> np.ndarray:
    """The first ``count`` angular frequencies of a longitudinal bar with the given ends
    (module docstring): 'clamped', 'free' or an :class:`Attachment` at each end."""
    L = check_positive("length", length)
    E = check_positive("E", E)
    rho = check_positive("rho", rho)
    A = check_positive("area", area)
    count = check_int("count", count, minimum=1)
    left, right, m0, size = _bar_ends(left, right)
    c = np.sqrt(E / rho)
    EA = E * A

    def det(w):
        beta = w / c
        M = np.zeros((size, size))
        row = 0
        for x, end, off, sgn in ((0.0, left, 2, +1.0), (L, right, 2 + m0, -1.0)):
            cb, sb = np.cos(beta * x), np.sin(beta * x)
            phi = np.array([cb, sb])
            dphi = beta * np.array([-sb, cb])  # phi' (N = E A phi')
            row = _end_rows(M, row, end, off, sgn, w, phi, EA * dphi, dphi / beta)
        return np.linalg.det(M)

    if w_max is None:
        w_max = (count + 2) * np.pi * c / L
    return _find_roots(det, w_max, count, n_grid)


def _per_slice(name: str, value, n: int) -> np.ndarray:
    """A positive value per slice (a scalar for all), one-line refusals."""
    v = np.atleast_1d(np.asarray(value, dtype=float))
    if v.size == 1:
        v = np.full(n, float(v[0]))
    if v.size != n:
        raise fail(name, v.tolist(), f"must be one value or one per slice ({n})")
    for x in v:
        check_positive(name, float(x))
    return v


def sliced_bar_frequencies(
    lengths,
    E,
    rho,
    *,
    area=1.0,
    left="clamped",
    right="free",
    count: int = 3,
    w_max: float | None = None,
    n_grid: int = 4000,
) -> np.ndarray:
    """The first ``count`` angular frequencies of a longitudinal bar made of slices along x
    (slice i: length l_i, E_i, rho_i, A_i; each a scalar for all slices or one per slice),
    with 'clamped', 'free' or :class:`Attachment` ends as :func:`bar_frequencies`.

    In slice i (c_i = (E_i/rho_i)^{1/2}, beta_i = w/c_i, Z_i = E_i A_i beta_i) the state
    (phi, N = E A phi') at its right end is T_i times the state at its left end,

        T_i = [[cos(beta_i l_i), sin(beta_i l_i)/Z_i], [-Z_i sin(beta_i l_i), cos(beta_i l_i)]],

    continuous across the interfaces (displacement and normal force); T = T_n ... T_1 (entire
    in w: sin(beta l)/Z = l/(E A) sinc). The unknowns are (phi(0), N(0)) and the components'
    coordinates; the rows are the end conditions of :func:`bar_frequencies` with
    (phi(L), N(L)) = T (phi(0), N(0)); its frequencies are the zeros of their determinant.
    One slice is :func:`bar_frequencies`."""
    ell = np.atleast_1d(np.asarray(lengths, dtype=float))
    if ell.size == 0:
        raise fail("lengths", [], "must hold at least one slice")
    for x in ell:
        check_positive("lengths", float(x))
    n = ell.size
    E = _per_slice("E", E, n)
    rho = _per_slice("rho", rho, n)
    A = _per_slice("area", area, n)
    count = check_int("count", count, minimum=1)
    left, right, m0, size = _bar_ends(left, right)
    c = np.sqrt(E / rho)
    EA = E * A
    # N in units of the stiffest slice's E A / L: the rows of phi and N of one size
    scale = EA.max() / ell.sum()

    def transfer(w):
        """T (phi, N / scale) from x = 0 to x = L."""
        T = np.eye(2)
        for li, ci, EAi in zip(ell, c, EA, strict=True):
            bl = w / ci * li
            sinc = np.sinc(bl / np.pi)  # sin(bl)/bl
            Ti = np.array(
                [
                    [np.cos(bl), li / EAi * sinc * scale],  # sin(beta l)/Z
                    [-EAi * (w / ci) * np.sin(bl) / scale, np.cos(bl)],
                ]
            )
            T = Ti @ T
        return T

    def det(w):
        M = np.zeros((size, size))
        T = transfer(w)
        row = 0
        # (phi, N) at each end as rows acting on the unknowns (phi(0), N(0)/scale)
        for state, end, off, sgn in ((np.eye(2), left, 2, +1.0), (T, right, 2 + m0, -1.0)):
            phi, N = state[0], state[1] * scale
            # (the component's rows in units of scale)
            row = _end_rows(M, row, end, off, sgn, w, phi, N, N / scale, scale=scale)
        return np.linalg.det(M)

    if w_max is None:
        # the slowest slice's wave time sets the spacing of the roots
        w_max = (count + 2) * np.pi / float(np.sum(ell / c))
    return _find_roots(det, w_max, count, n_grid)


def tip_mass_roots(mass_ratio: float, count: int = 3) -> np.ndarray:
    """The roots x_k of x tan x = mass_ratio (= rho A L / m_tip), one in each
    (k pi, k pi + pi/2): the frequencies of a clamped bar with a tip mass are
    w_k = x_k c / L."""
    mu = check_positive("mass_ratio", mass_ratio)
    count = check_int("count", count, minimum=1)
    # heavy: scipy.optimize (10 MB resident) only when frequencies are computed
    from scipy.optimize import brentq

    return np.array(
        [
            brentq(
                lambda x: x * np.sin(x) - mu * np.cos(x),
                k * np.pi,
                k * np.pi + np.pi / 2,
                xtol=1e-15,
            )
            for k in range(count)
        ]
    )


def rigid_limit_frequency(stiffness: float, *masses: float) -> float:
    """w = (k / sum of the masses)^{1/2}: a rigid body on a spring (the limit of a stiff
    elastic body on a mass-spring)."""
    k = check_positive("stiffness", stiffness)
    m = sum(check_positive("masses", x) for x in masses)
    return float(np.sqrt(k / m))


def beam_frequencies(
    length: float,
    EI: float,
    rho_A: float,
    *,
    left="clamped",
    right="free",
    count: int = 3,
    w_max: float | None = None,
    n_grid: int = 4000,
) -> np.ndarray:
    """The first angular frequencies of an Euler-Bernoulli beam (bending stiffness EI, mass
    per length rho_A) with 'clamped', 'free' or :class:`Attachment` ends (translational:
    module docstring)."""
    L = check_positive("length", length)
    EI = check_positive("EI", EI)
    rA = check_positive("rho_A", rho_A)
    count = check_int("count", count, minimum=1)
    left, right = _end("left", left), _end("right", right)
    m0 = left.mass.shape[0] if isinstance(left, Attachment) else 0
    mL = right.mass.shape[0] if isinstance(right, Attachment) else 0
    size = 4 + m0 + mL

    def derivs(b, x):
        """(4, 4): rows w, w', w'', w''' of the basis cos, sin, cosh, sinh (beta x)."""
        c, s, ch, sh = np.cos(b * x), np.sin(b * x), np.cosh(b * x), np.sinh(b * x)
        return np.array(
            [
                [c, s, ch, sh],
                [-b * s, b * c, b * sh, b * ch],
                [-(b**2) * c, -(b**2) * s, b**2 * ch, b**2 * sh],
                [b**3 * s, -(b**3) * c, b**3 * sh, b**3 * ch],
            ]
        )

    def det(w):
        b = (rA * w * w / EI) ** 0.25
        M = np.zeros((size, size))
        row = 0
        for x, end, off, sgn in ((0.0, left, 4, -1.0), (L, right, 4 + m0, +1.0)):
            D = derivs(b, x) / np.array([1.0, b, b**2, b**3])[:, None] / np.cosh(b * L)
            if end == "clamped":
                M[row : row + 2, :4] = D[:2]
                row += 2
            elif end == "free":
                M[row : row + 2, :4] = D[2:]
                row += 2
            else:
                m = end.mass.shape[0]
                M[row, :4] = D[2]  # no moment
                M[row + 1, :4] = D[0]  # w(end) = q_at
                M[row + 1, off + end.at] = -1.0 / np.cosh(b * L)
                row += 2
                # (K - w^2 M) q = (force of the beam on the component) e_at, i.e. with the
                # rows scaled like D: (K - w^2 M)/(E I b^3 cosh(bL)) q - sgn D[3] e_at = 0
                M[row : row + m, off : off + m] = (end.stiffness - w * w * end.mass) / (
                    EI * b**3 * np.cosh(b * L)
                )
                M[row + end.at, :4] -= sgn * D[3]
                row += m
        return np.linalg.det(M)

    if w_max is None:
        w_max = ((count + 1.5) * np.pi / L) ** 2 * np.sqrt(EI / rA)
    return _find_roots(det, w_max, count, n_grid)


def beam_tip_mass_equation(lam: float, mass_ratio: float) -> float:
    """1 + cos(l) cosh(l) + mu l (cos(l) sinh(l) - sin(l) cosh(l)): zero at l = beta L of a
    clamped beam with a tip mass mu rho A L (no rotary inertia)."""
    c, s, ch, sh = np.cos(lam), np.sin(lam), np.cosh(lam), np.sinh(lam)
    return 1.0 + c * ch + mass_ratio * lam * (c * sh - s * ch)


def _controlled_char(s, L, E, rho, A, m_b, k_b, H, b=0.0):
    """det of the 3 x 3 system in (a, b, W) of the controlled bar (module docstring); with
    Kelvin-Voigt damping sigma = E (eps + b eps') the modulus is E (1 + b s)."""
    Es = E * (1.0 + b * s)
    c = np.sqrt(Es / rho + 0j)
    z = s * L / c
    ch, sh = np.cosh(z), np.sinh(z)
    EA = Es * A
    # phi = a cosh(s x/c) + b sinh(s x/c); phi'(x) = (s/c)(a sinh + b cosh)
    M = np.array(
        [
            [1.0, 0.0, -1.0],  # phi(0) = W
            [sh, ch, 0.0],  # phi'(L) = 0 (divided by s/c)
            [0.0, -EA * s / c, m_b * s * s + k_b],  # (m_b s^2 + k_b) W - E A phi'(0) + H phi(L)
        ],
        dtype=complex,
    )
    M[2, 0] += H(s) * ch
    M[2, 1] += H(s) * sh
    return np.linalg.det(M) / np.cosh(z)


def controlled_bar_roots(
    length: float,
    E: float,
    rho: float,
    *,
    area: float = 1.0,
    base_mass: float,
    base_stiffness: float = 0.0,
    H=None,
    kelvin_voigt: float = 0.0,
    count: int = 2,
) -> np.ndarray:
    """The roots s = -alpha + i w of the controlled bar (module docstring) near the first
    ``count`` uncontrolled frequencies; H(s) the feedback's transfer function from the tip
    displacement to the actuator force (None: no feedback); ``kelvin_voigt`` b of the bar's
    stiffness-proportional damping (Rayleigh b K: the modulus E (1 + b s))."""
    L = check_positive("length", length)
    E = check_positive("E", E)
    rho = check_positive("rho", rho)
    A = check_positive("area", area)
    mb = check_positive("base_mass", base_mass)
    kb = float(base_stiffness)
    kv = float(kelvin_voigt)
    H0 = (lambda s: 0.0) if H is None else H
    free = bar_frequencies(
        L,
        E,
        rho,
        area=A,
        left=Attachment.mass_spring(mb, kb),
        right="free",
        count=count + (1 if kb == 0 else 0),
    )
    if kb == 0:
        free = free[free > 1e-9 * free.max()][:count]
    out = []
    for w in free:
        s = 1j * w
        for _ in range(100):
            f = _controlled_char(s, L, E, rho, A, mb, kb, H0, kv)
            h = 1e-7 * abs(s)
            df = (
                _controlled_char(s + h, L, E, rho, A, mb, kb, H0, kv)
                - _controlled_char(s - h, L, E, rho, A, mb, kb, H0, kv)
            ) / (2 * h)
            step = f / df
            s = s - step
            if abs(step) < 1e-13 * abs(s):
                break
        else:  # pragma: no cover - Newton from the uncontrolled root
            raise RuntimeError("controlled_bar_roots: Newton did not converge")
        out.append(s)
    return np.asarray(out)


def bar_mode(length: float, E: float, rho: float, w: float, *, area: float = 1.0, n: int = 2001):
    """Base and tip amplitudes (W, U) and the modal mass of the mode of the base-mounted,
    free-tipped bar at frequency w, normalized to W = 1: phi = cos(beta (L - x))/cos(beta L).
    Returns (W, U, rho A int phi^2 dx)."""
    c = np.sqrt(E / rho)
    beta = w / c
    x = np.linspace(0.0, length, n)
    phi = np.cos(beta * (length - x)) / np.cos(beta * length)
    integral = float(np.sum((phi[1:] ** 2 + phi[:-1] ** 2) / 2 * np.diff(x)))  # trapezoid
    return 1.0, float(phi[-1]), rho * area * integral


def first_mode_decay_rate(
    length: float,
    E: float,
    rho: float,
    *,
    area: float = 1.0,
    base_mass: float,
    base_stiffness: float = 0.0,
    H,
) -> float:
    """alpha_1 = Re[H(i w_1)/(i w_1)] W_1 U_1 / (2 m_1) (module docstring): the first-order
    decay rate of the first mode under feedback H (for small gains)."""
    w1 = controlled_bar_roots(
        length,
        E,
        rho,
        area=area,
        base_mass=base_mass,
        base_stiffness=base_stiffness,
        H=None,
        count=1,
    )[0].imag
    W, U, m_bar = bar_mode(length, E, rho, w1, area=area)
    m1 = base_mass * W**2 + m_bar
    return float((H(1j * w1) / (1j * w1)).real * W * U / (2 * m1))


# -- frequencies and decay rates measured from a run's series -----------------------------------


def crossing_frequency(t: np.ndarray, y: np.ndarray) -> float:
    """pi / the mean time between the zero crossings of y(t) (linear interpolation); nan with
    fewer than two crossings."""
    s = np.sign(y)
    k = np.flatnonzero(s[:-1] * s[1:] < 0)
    if k.size < 2:
        return float("nan")
    tz = t[k] - y[k] * (t[k + 1] - t[k]) / (y[k + 1] - y[k])
    return float(np.pi / np.mean(np.diff(tz)))


def decay_rate(t: np.ndarray, y: np.ndarray) -> float:
    """alpha of y ~ e^{-alpha t} cos(w t + phi): minus the slope of log y at its local maxima
    (least squares); nan with fewer than three positive maxima."""
    k = np.flatnonzero((y[1:-1] > y[:-2]) & (y[1:-1] >= y[2:]) & (y[1:-1] > 0)) + 1
    if k.size < 3:
        return float("nan")
    return float(-np.polyfit(t[k], np.log(y[k]), 1)[0])


def modal_frequencies(t: np.ndarray, C: np.ndarray, floor: float = 1e-9) -> list:
    """The frequency of each column of the modal coordinates C (states, K) of a run
    (:func:`crossing_frequency` of c_k(t) = phi_k^T M x(t)), each cut where |c_k| last
    exceeds ``floor`` times its maximum: a mode a dissipative scheme (implicit Euler on a high
    mode) has damped to round-off crosses zero at random; nan (None in JSON) without two
    crossings."""
    t = np.asarray(t, dtype=float)
    C = np.asarray(C, dtype=float).reshape(t.size, -1)
    out = []
    for c in C.T:
        big = np.flatnonzero(np.abs(c) > floor * np.abs(c).max(initial=0.0))
        end = big[-1] + 1 if big.size else 0
        out.append(crossing_frequency(t[:end], c[:end]))
    return out


#: the Hankel matrix of :func:`pencil_frequencies`: at most this many columns, built from the
#: first this many samples (the frequencies of a linear run are the same in any window). On
#: the tip-mass runs (K = 3, BDF2 and Euler, tau = 0.01 .. 0.00125) 126 columns of 1000
#: samples gave the schemes' frequencies to 5e-13, as 501 of 2000 did (4e-13) in a sixth of
#: the time; 65 of 500: 1.6e-11. (A 1501 x 501 SVD took 0.1 s on one thread but 4.7 s on two
#: OpenBLAS threads of the loaded machine, measured.)
PENCIL_MAX_COLUMNS = 125
PENCIL_MAX_SAMPLES = 1000


def pencil_frequencies(t: np.ndarray, y: np.ndarray, count: int, rtol: float = 1e-10) -> list:
    """The ``count`` angular frequencies of largest amplitude in a signal sampled at equal
    steps (the tip's q_x of a run: what an experimenter records), by the matrix pencil
    method: y_j = sum_i a_i z_i^j with z_i = e^{(-alpha_i + i w_i) tau}; the Hankel matrix
    H = [y_{j+l}] (L + 1 columns, L = min(N/2, PENCIL_MAX_COLUMNS)), its right singular
    vectors V of the r largest singular values (of the first PENCIL_MAX_SAMPLES samples), z
    the eigenvalues of V_-^+ V_+ (V without its last / first row), a by least squares,
    w = |arg z| / tau of the ``count`` largest |a| with arg z > 0.

    r: the singular values above ``rtol`` times the largest, at most 4 ``count`` -- a linear
    two-step scheme (BDF2) steps every mode with two pairs of roots, its own and the
    parasitic one. A run of a linear scheme on uniform steps IS such a sum, so w_i is the
    scheme's discrete frequency to round-off (docs/coupling.md Sec. 11). NaN for every
    frequency when the steps are not equal (adaptive steps) or the signal too short."""
    return [float(s.imag) for s in pencil_roots(t, y, count, rtol)]


def pencil_roots(t: np.ndarray, y: np.ndarray, count: int, rtol: float = 1e-10) -> list:
    """The exponents s_i = log(z_i)/tau = -alpha_i + i w_i (complex, ascending in w) of the
    ``count`` components of largest amplitude of :func:`pencil_frequencies`'s matrix pencil:
    their decay rates alpha_i as well as their frequencies. A linear scheme's run on uniform
    steps is exactly such a sum, so s_i is the scheme's discrete root of mode i to round-off,
    unaffected by the other modes a start excites (which bias :func:`decay_rate`'s maxima):
    s_i -> the semi-discrete root as tau -> 0, at the scheme's order (docs/coupling.md,
    Sec. 11, eld-control). NaN (complex) where :func:`pencil_frequencies` has NaN."""
    count = check_int("count", count, minimum=1)
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    nan = [complex(float("nan"), float("nan"))] * count
    if t.size < 8 * count:
        return nan
    dt = np.diff(t)
    tau = float(dt.mean())
    if np.abs(dt - tau).max() > 1e-9 * tau:
        return nan
    y = y[:PENCIL_MAX_SAMPLES]
    L = min(y.size // 2, PENCIL_MAX_COLUMNS)
    # (a contiguous copy for LAPACK, not the strided view)
    H = np.ascontiguousarray(np.lib.stride_tricks.sliding_window_view(y, L + 1))
    _, s, Vh = np.linalg.svd(H, full_matrices=False)
    if s[0] == 0.0:
        return nan
    r = int(min(4 * count, np.count_nonzero(s > rtol * s[0])))
    V = Vh[:r].T
    z = np.linalg.eigvals(np.linalg.pinv(V[:-1]) @ V[1:])
    Z = z[None, :] ** np.arange(y.size)[:, None]
    a = np.linalg.lstsq(Z, y.astype(complex), rcond=None)[0]
    up = np.angle(z) > 0
    z, a = z[up], a[up]
    z = z[np.argsort(-np.abs(a))[:count]]
    roots = np.log(z) / tau
    roots = roots[np.argsort(roots.imag)]
    return [complex(v) for v in roots] + nan[roots.size :]
