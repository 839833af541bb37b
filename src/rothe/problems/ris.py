"""Rate-independent systems (RIS) in R^n: energy, dissipation, viscosity metric, dual distance.

Andreia & Meyer (2022), eq. (1.5):

    I(t, z) = 1/2 <A z, z> + F(z) - <l(t), z>,

with A symmetric (coercive on the unknowns), F smooth and possibly non-convex, and the load l(t)
given as the vector of nodal functionals. The dissipation and the viscosity metric are diagonal:

    R(v) = sum_i r_i |v_i|            (r_i = kappa * m_i for R = kappa ||.||_{L1} with lumped mass),
    ||v||_V^2 = sum_i m_i v_i^2       (V = lumped L2 metric, or the identity in R^n).

With these, the dual distance (2.4) has the closed form (SPEC section 1)

    dist(eta)^2 = sum_i max(|eta_i| - r_i, 0)^2 / m_i,

since dR(0) = {xi : |xi_i| <= r_i} and ||w||_{V^-1}^2 = sum_i w_i^2 / m_i.

Sign convention: ``gradient(t, z)`` is D_z I(t, z) = A z + F'(z) - l(t); the residuals of the paper
use dist(-D_z I), and since dR(0) is symmetric, dist(-eta) = dist(eta).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp

from ..errors import RotheInputError, check_finite_array, check_positive, described, fail

ArrayFn = Callable[[np.ndarray], np.ndarray]


class RISProblem:
    """A rate-independent system I(t, z) + R on R^n with diagonal dissipation and metric.

    Parameters
    ----------
    A : (n, n) array or sparse matrix
        Symmetric quadratic part of the energy.
    F, dF, d2F : callables
        F(z) -> float, dF(z) -> (n,), d2F(z) -> (n,) diagonal (a nodal F) or (n, n) matrix.
        Where F' is only piecewise smooth, d2F is a generalized (Clarke) second derivative.
    load : callable
        t -> (n,) vector l(t) of nodal functionals; enters I with a minus sign.
    dissipation_weights : (n,) array, r_i > 0
        R(v) = sum_i r_i |v_i|.
    metric_weights : (n,) array, m_i > 0
        ||v||_V^2 = sum_i m_i v_i^2.
    z0 : (n,) array
        Initial state.
    T : float
        Final time.
    load_rate : callable, optional
        t -> dl/dt (used only for energy diagnostics: d/dt I = -<l'(t), z>).
    check_derivatives : bool
        Check dF and d2F against finite differences of F and dF at a few points.
    """

    def __init__(
        self,
        A,
        F: Callable[[np.ndarray], float],
        dF: ArrayFn,
        d2F: ArrayFn,
        load: Callable[[float], np.ndarray],
        dissipation_weights,
        metric_weights,
        z0,
        T: float,
        *,
        load_rate: Callable[[float], np.ndarray] | None = None,
        name: str = "ris",
        check_derivatives: bool = True,
    ):
        self.name = name
        self.T = check_positive("T", T)
        z0 = check_finite_array("z0", np.atleast_1d(np.asarray(z0, dtype=float)))
        if z0.ndim != 1:
            raise fail("z0", described(f"array of shape {z0.shape}"), "must be a 1-D vector")
        n = z0.size
        self.n = n
        self.z0 = z0.copy()

        if np.isscalar(A):
            A = np.array([[float(A)]])
        if sp.issparse(A):
            A = sp.csr_matrix(A, dtype=float)
            A.sum_duplicates()
            A.sort_indices()
            asym = abs(A - A.T).max() if A.nnz else 0.0
            scale = abs(A).max() if A.nnz else 1.0
        else:
            A = np.asarray(A, dtype=float)
            if A.ndim == 0:
                A = A.reshape(1, 1)
            asym = np.max(np.abs(A - A.T)) if A.size else 0.0
            scale = np.max(np.abs(A)) if A.size else 1.0
        if A.shape != (n, n):
            raise fail(
                "A", described(f"matrix of shape {A.shape}"), f"must have shape ({n}, {n}) like z0"
            )
        if asym > 1e-10 * max(scale, 1e-300):
            raise fail(
                "A", described(f"a matrix with max|A - A^T| = {asym:.3g}"), "must be symmetric"
            )
        self.A = A
        self.sparse = sp.issparse(A)
        self.A_diag = np.asarray(A.diagonal(), dtype=float).copy()

        r = np.broadcast_to(np.asarray(dissipation_weights, dtype=float), (n,)).copy()
        m = np.broadcast_to(np.asarray(metric_weights, dtype=float), (n,)).copy()
        for label, w in (("dissipation_weights", r), ("metric_weights", m)):
            if not np.all(np.isfinite(w)) or np.any(w <= 0):
                bad = w[~(np.isfinite(w) & (w > 0))][0]
                raise fail(label, float(bad), "every weight must be finite and > 0")
        self.r = r
        self.m = m

        self._F, self._dF, self._d2F = F, dF, d2F
        self._load, self._load_rate = load, load_rate
        for t_check in (0.0, self.T):
            check_finite_array(f"load(t={t_check:g})", self.load(t_check))
        check_finite_array("F(z0)", [self.F(z0)])
        if check_derivatives:
            self._check_derivatives()

    # -- the energy and its derivatives ------------------------------------------------------
    def F(self, z: np.ndarray) -> float:
        return float(self._F(z))

    def dF(self, z: np.ndarray) -> np.ndarray:
        return np.asarray(self._dF(z), dtype=float).reshape(self.n)

    def d2F(self, z: np.ndarray):
        """Diagonal (n,) vector or (n, n) matrix of the (generalized) second derivative."""
        h = self._d2F(z)
        if sp.issparse(h):
            return h
        h = np.asarray(h, dtype=float)
        return h.reshape(self.n) if h.size == self.n else h.reshape(self.n, self.n)

    def load(self, t: float) -> np.ndarray:
        return np.asarray(self._load(t), dtype=float).reshape(self.n)

    def load_rate(self, t: float, h: float = 1e-6) -> np.ndarray:
        if self._load_rate is not None:
            return np.asarray(self._load_rate(t), dtype=float).reshape(self.n)
        return (self.load(t + h) - self.load(t - h)) / (2 * h)

    def energy(self, t: float, z: np.ndarray) -> float:
        """I(t, z) = 1/2 <A z, z> + F(z) - <l(t), z>   (1.5)."""
        return float(0.5 * z @ (self.A @ z) + self.F(z) - self.load(t) @ z)

    def gradient(self, t: float, z: np.ndarray) -> np.ndarray:
        """D_z I(t, z) = A z + F'(z) - l(t)."""
        return self.A @ z + self.dF(z) - self.load(t)

    def dissipation(self, v: np.ndarray) -> float:
        """R(v) = sum_i r_i |v_i|."""
        return float(self.r @ np.abs(v))

    def norm_V(self, v: np.ndarray) -> float:
        """||v||_V = (sum_i m_i v_i^2)^(1/2)."""
        return float(np.sqrt(self.m @ (v * v)))

    def norm_Vinv(self, w: np.ndarray) -> float:
        """Dual norm ||w||_{V^-1} = (sum_i w_i^2 / m_i)^(1/2)."""
        return float(np.sqrt(np.sum(w * w / self.m)))

    def dist(self, eta: np.ndarray) -> float:
        """dist_{V*}(eta, dR(0)) of (2.4): (sum_i max(|eta_i| - r_i, 0)^2 / m_i)^(1/2)."""
        excess = np.maximum(np.abs(eta) - self.r, 0.0)
        return float(np.sqrt(np.sum(excess * excess / self.m)))

    # -- mapping to output ---------------------------------------------------------------------
    def full_state(self, z: np.ndarray) -> np.ndarray:
        """The state as written to output (identity here; FE problems add boundary nodes)."""
        return z

    # -- validation ----------------------------------------------------------------------------
    def _check_derivatives(self, samples: int = 3, seed: int = 12345) -> None:
        """Compare dF with central differences of F and d2F with those of dF (directional).

        Points are drawn around z0; a mismatch larger than the differencing error (relative
        1e-4 of the scale, plus kinks of piecewise-smooth F, tolerated by a two-step-size test)
        raises RotheInputError naming the derivative.
        """
        rng = np.random.default_rng(seed)
        scale = max(1.0, float(np.max(np.abs(self.z0))))
        for _ in range(samples):
            z = self.z0 + 0.37 * scale * rng.standard_normal(self.n)
            v = rng.standard_normal(self.n)
            v /= max(np.linalg.norm(v), 1e-300)
            for label, exact, numeric in (
                ("dF", lambda z=z, v=v: float(self.dF(z) @ v), self._fd_first),
                ("d2F", lambda z=z, v=v: self._apply_d2F(z, v), self._fd_second),
            ):
                ex = exact()
                if not np.all(np.isfinite(ex)):
                    raise fail(label, described("a non-finite value"), "must be finite")
                ok = False
                for h in (1e-5 * scale, 1e-7 * scale):
                    num = numeric(z, v, h)
                    err = np.max(np.abs(np.asarray(ex) - num))
                    ref = max(1.0, float(np.max(np.abs(num))), float(np.max(np.abs(ex))))
                    if err <= 1e-4 * ref:
                        ok = True
                        break
                if not ok:
                    raise RotheInputError(
                        f"{label}: disagrees with finite differences of "
                        f"{'F' if label == 'dF' else 'dF'} at a test point (max error "
                        f"{err:.3g} vs scale {ref:.3g}); check the derivative you supplied"
                    )

    def _apply_d2F(self, z, v):
        h = self.d2F(z)
        if sp.issparse(h) or (isinstance(h, np.ndarray) and h.ndim == 2):
            return np.asarray(h @ v).ravel()
        return h * v

    def _fd_first(self, z, v, h):
        return (self.F(z + h * v) - self.F(z - h * v)) / (2 * h)

    def _fd_second(self, z, v, h):
        return (self.dF(z + h * v) - self.dF(z - h * v)) / (2 * h)
