"""Rate-independent systems (RIS) in R^n: energy, dissipation, viscosity metric, dual distance.

Andreia & Meyer (2022), eq. (1.5):

    I(t, z) = 1/2 <A z, z> + F(z) - <l(t), z>,

with A symmetric (coercive on the unknowns), F smooth and possibly non-convex, and the load l(t)
given as the vector of nodal functionals. The dissipation and the viscosity metric are diagonal:

    R(v) = sum_i r_i |v_i|            (r_i = kappa * m_i for R = kappa ||.||_{L1} with lumped mass),
    ||v||_V^2 = sum_i m_i v_i^2       (V = lumped L2 metric, or the identity in R^n).

With these, the dual distance (2.4) has the closed form

    dist(eta)^2 = sum_i max(|eta_i| - r_i, 0)^2 / m_i,

since dR(0) = {xi : |xi_i| <= r_i} and ||w||_{V^-1}^2 = sum_i w_i^2 / m_i.

Sign convention: ``gradient(t, z)`` is D_z I(t, z) = A z + F'(z) - l(t); the residuals of the paper
use dist(-D_z I), and since dR(0) is symmetric, dist(-eta) = dist(eta).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from ..errors import DataError, RotheInputError, check_finite_array, check_positive, described, fail
from ..io.checkpoint import digest

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
    name : str
        The problem's name in ``trajectory.meta['example']``.
    check_derivatives : bool
        Check dF and d2F against finite differences of F and dF at a few points.
    check_coercivity : bool
        Refuse an A that is not positive definite (:func:`check_coercive`); switch off when F
        alone makes I(t, .) coercive.

    Every check raises a one-line :class:`~rothe.errors.RotheInputError` naming the parameter.
    Run it with :func:`rothe.ris.run.run_ris`.
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
        check_coercivity: bool = True,
    ):
        self.name = name
        self.T = check_positive("T", T)
        z0 = check_finite_array("z0", np.atleast_1d(np.asarray(z0, dtype=float)))
        if z0.ndim != 1:
            raise fail("z0", described(f"array of shape {z0.shape}"), "must be a 1-D vector")
        n = z0.size
        self.n = n
        self.z0 = z0.copy()

        self.A = _check_matrix(A, n)
        self.sparse = sp.issparse(self.A)
        self.A_diag = np.asarray(self.A.diagonal(), dtype=float).copy()

        self.r = _check_weights("dissipation_weights", dissipation_weights, n)
        self.m = _check_weights("metric_weights", metric_weights, n)

        for label, fn in (("F", F), ("dF", dF), ("d2F", d2F), ("load", load)):
            if not callable(fn):
                raise fail(label, described(f"a {type(fn).__name__}"), "must be a callable")
        if load_rate is not None and not callable(load_rate):
            raise fail(
                "load_rate",
                described(f"a {type(load_rate).__name__}"),
                "must be a callable or None",
            )
        self._F, self._dF, self._d2F = F, dF, d2F
        self._load, self._load_rate = load, load_rate
        self._load_cache: dict = {}  # t -> l(t), the last LOAD_CACHE_SIZE values (load)
        with np.errstate(over="ignore", invalid="ignore"):  # overflow is reported as such
            self._check_callables()
        if check_coercivity:
            check_coercive(self.A)
        if check_derivatives:
            self._check_derivatives()

    def _check_callables(self) -> None:
        """F, dF, d2F at z0 and the load at 0 and T: the shapes of (1.5) and finite values.

        The V^-1 norms of the load and of D_z I(0, z0) square the entries, so data near the
        overflow threshold of double precision is refused here rather than turning the
        residuals (3.3)-(3.4) into inf at the first step.
        """
        n, z0 = self.n, self.z0
        value = _evaluate("F", self._F, z0, "z0")
        arr = np.asarray(value, dtype=float) if _is_numeric(value) else None
        if arr is None or arr.size != 1:
            what = (
                f"an array of shape {arr.shape}" if arr is not None else f"a {type(value).__name__}"
            )
            raise fail("F", described(f"{what} at z0"), "must return a number (the energy F(z))")
        check_finite_array("F(z0)", arr)
        for label, fn in (("dF", self._dF), ("d2F", self._d2F)):
            value = _evaluate(label, fn, z0, "z0")
            if label == "d2F" and sp.issparse(value):
                shape, vals = value.shape, value.data
            else:
                vals = np.asarray(value, dtype=float) if _is_numeric(value) else None
                if vals is None:
                    raise fail(
                        label,
                        described(f"a {type(value).__name__} at z0"),
                        f"must return an array of shape ({n},)",
                    )
                shape = vals.shape
            allowed = [(n,)] if label == "dF" else [(n,), (n, n)]
            if shape not in allowed and not (n == 1 and int(np.prod(shape)) == 1):
                want = " or ".join(str(a) for a in allowed)
                raise fail(
                    label,
                    described(f"an array of shape {shape} at z0"),
                    f"must have shape {want} (n = {n} unknowns)",
                )
            check_finite_array(f"{label}(z0)", vals)
        for t_check in (0.0, self.T):
            value = _evaluate("load", self._load, t_check, f"t = {t_check:g}")
            vals = np.asarray(value, dtype=float) if _is_numeric(value) else None
            if vals is None or (vals.shape != (n,) and vals.size != n):
                what = f"shape {vals.shape}" if vals is not None else type(value).__name__
                raise fail(
                    f"load(t={t_check:g})",
                    described(f"an array of {what}"),
                    f"must return an array of shape ({n},)",
                )
            norm = self.norm_Vinv(self.load(t_check))
            if not math.isfinite(norm):
                raise fail(
                    f"load(t={t_check:g})",
                    described(f"a vector of norm {norm:g}"),
                    "must have a finite V^-1 norm (sum l_i^2 / m_i overflows)",
                )
        norm = self.norm_Vinv(self.gradient(0.0, z0))
        if not math.isfinite(norm):
            raise fail(
                "z0",
                described(f"a state where ||D_z I(0, z0)||_V^-1 = {norm:g}"),
                "must give a finite gradient of the energy (overflow)",
            )

    # -- the energy and its derivatives ------------------------------------------------------
    def F(self, z: np.ndarray) -> float:
        """F(z), the non-quadratic part of the energy."""
        return float(self._F(z))

    def dF(self, z: np.ndarray) -> np.ndarray:
        """F'(z) as an (n,) vector."""
        return np.asarray(self._dF(z), dtype=float).reshape(self.n)

    def d2F(self, z: np.ndarray):
        """Diagonal (n,) vector or (n, n) matrix of the (generalized) second derivative."""
        h = self._d2F(z)
        if sp.issparse(h):
            return h
        h = np.asarray(h, dtype=float)
        return h.reshape(self.n) if h.size == self.n else h.reshape(self.n, self.n)

    #: how many l(t) the problem keeps (the last ones asked for)
    LOAD_CACHE_SIZE = 4

    def load(self, t: float) -> np.ndarray:
        """l(t); a non-finite value raises :class:`~rothe.errors.DataError` naming t.

        The last :attr:`LOAD_CACHE_SIZE` values are kept, read-only: a step asks for l(t_{k-1})
        at every Newton iterate and line-search trial (t is fixed in (3.1)) and a viscous-jump
        step at all Simpson points; a finite-element load integrates a density at every
        quadrature point (on ris-front 26 % of a run's seconds were this recomputation).
        """
        t = float(t)
        cache = self._load_cache
        hit = cache.get(t)
        if hit is not None:
            return hit
        l_t = self._load_uncached(t).copy()  # never the caller's own array made read-only
        l_t.setflags(write=False)
        if len(cache) >= self.LOAD_CACHE_SIZE:
            cache.pop(next(iter(cache)))
        cache[t] = l_t
        return l_t

    def _load_uncached(self, t: float) -> np.ndarray:
        """l(t) from the data (:meth:`load`)."""
        try:
            l_t = np.asarray(self._load(t), dtype=float).reshape(self.n)
        except DataError:
            raise
        except Exception as exc:  # the user's function, e.g. data that ends at T
            raise DataError(
                f"load(t={t:g}): got an error ({type(exc).__name__}: {exc}), must "
                "evaluate for t in [0, T]"
            ) from None
        if not np.all(np.isfinite(l_t)):
            bad = float(l_t[~np.isfinite(l_t)][0])
            raise DataError(f"load(t={t:g}): got {bad}, must be finite (no NaN or inf)")
        return l_t

    def load_rate(self, t: float, h: float = 1e-6) -> np.ndarray:
        """dl/dt: the given ``load_rate``, else a central difference with step ``h``."""
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

    # -- identity (checkpoints) ----------------------------------------------------------------
    def fingerprint(self) -> dict:
        """Cheap hashes that identify the problem, compared entry by entry when a run resumes
        (:func:`rothe.io.checkpoint.problem_fingerprint`): class, n, T, A, z0, the weights,
        the load at t = 0, T/3, T and F, F', F'' at z0 and z0 + 1/2."""
        T = float(self.T)
        z0 = self.z0
        z1 = z0 + 0.5
        return {
            "class": type(self).__name__,
            "n": int(self.n),
            "T": T,
            "A": digest(self.A),
            "z0": digest(z0),
            "weights": digest(self.r, self.m),
            "load": digest(*[self.load(t) for t in (0.0, T / 3.0, T)]),
            "F": digest(
                np.array([self.F(z0), self.F(z1)]),
                self.dF(z0),
                self.dF(z1),
                self.d2F(z0),
                self.d2F(z1),
            ),
        }

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


# -- input checks ------------------------------------------------------------------------------


def _is_numeric(value) -> bool:
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


def _evaluate(label: str, fn, arg, at: str):
    """fn(arg) at construction; an exception of the user's function is one line naming it."""
    try:
        return fn(arg)
    except Exception as exc:  # the user's function: any failure is bad input
        raise fail(
            label,
            described(f"an error at {at} ({type(exc).__name__}: {exc})"),
            "must evaluate there",
        ) from None


def _check_matrix(A, n: int):
    """A as CSR or a dense (n, n) float array: square, of the size of z0, finite, symmetric."""
    if not sp.issparse(A) and not _is_numeric(A):
        raise fail(
            "A",
            described(f"a {type(A).__name__}"),
            "must be a square array or a scipy.sparse matrix",
        )
    if np.isscalar(A):
        A = np.array([[A]])
    if sp.issparse(A):
        A = sp.csr_matrix(A, dtype=float)
    else:
        A = np.asarray(A, dtype=float)
        if A.ndim == 0:
            A = A.reshape(1, 1)
    if A.ndim != 2 or A.shape != (n, n):
        raise fail(
            "A", described(f"matrix of shape {A.shape}"), f"must have shape ({n}, {n}) like z0"
        )
    if sp.issparse(A):
        A.sum_duplicates()
        A.sort_indices()
        values = A.data
    else:
        values = A
    check_finite_array("A", values)
    if sp.issparse(A):
        asym = abs(A - A.T).max() if A.nnz else 0.0
        scale = abs(A).max() if A.nnz else 1.0
    else:
        asym = np.max(np.abs(A - A.T)) if A.size else 0.0
        scale = np.max(np.abs(A)) if A.size else 1.0
    if asym > 1e-10 * max(scale, 1e-300):
        raise fail("A", described(f"a matrix with max|A - A^T| = {asym:.3g}"), "must be symmetric")
    return A


def _check_weights(label: str, weights, n: int) -> np.ndarray:
    w = np.asarray(weights, dtype=float) if _is_numeric(weights) else None
    if w is None or (w.ndim > 0 and w.shape != (n,)):
        what = f"an array of shape {w.shape}" if w is not None else f"a {type(weights).__name__}"
        raise fail(label, described(what), f"must be a number or an array of shape ({n},)")
    w = np.broadcast_to(w, (n,)).copy()
    if not np.all(np.isfinite(w)) or np.any(w <= 0):
        bad = w[~(np.isfinite(w) & (w > 0))][0]
        raise fail(label, float(bad), "every weight must be finite and > 0")
    return w


#: largest n for which the coercivity of a dense A is decided by its eigenvalues (beyond: a
#: Cholesky attempt), and of a sparse A by the pivots of a symmetric LU (beyond: the diagonal)
DENSE_EIGEN_LIMIT = 1000
SPARSE_LU_LIMIT = 50_000


def check_coercive(A) -> None:
    """Refuse an A that is not positive definite (Andreia & Meyer 2022, Sec. 1.3: A coercive).

    The paper's analysis rests on <A z, z> >= alpha ||z||^2 with F >= 0: then I(t, .) is
    bounded below and coercive, every viscous jump ends and the run reaches T. With A = -I or 0
    and an F of at most quadratic growth the energy is unbounded below: the state runs off
    along a viscous jump that never ends (t stays at 0 while s grows without bound).

    Cost: dense n <= 1000 eigenvalues (under 0.2 s), larger dense a Cholesky factorization;
    sparse n <= 50k an LU with diagonal pivots in a symmetric ordering (inertia by Sylvester's
    law: A is positive definite iff every pivot is > 0); larger sparse matrices only the
    diagonal (a_ii = <A e_i, e_i> > 0 is necessary), the run's stagnation check covers the rest.
    """
    n = A.shape[0]
    tail = (
        "must be positive definite (coercive: <A z, z> >= alpha |z|^2, Andreia & Meyer "
        "2022, Sec. 1.3), else the energy can be unbounded below and the run never ends; "
        "pass check_coercivity=False if F alone makes I(t, .) coercive"
    )
    diag = np.asarray(A.diagonal(), dtype=float)
    if np.any(diag <= 0):
        i = int(np.nonzero(diag <= 0)[0][0])
        raise fail("A", described(f"a matrix with A[{i}, {i}] = {diag[i]:g}"), tail)
    if not sp.issparse(A):
        if n <= DENSE_EIGEN_LIMIT:
            lam = np.linalg.eigvalsh(A)
            if not lam[0] > n * np.finfo(float).eps * max(abs(lam[-1]), abs(lam[0])):
                raise fail("A", described(f"a matrix with smallest eigenvalue {lam[0]:.3g}"), tail)
        else:
            try:
                np.linalg.cholesky(A)
            except np.linalg.LinAlgError:
                raise fail(
                    "A", described("a matrix whose Cholesky factorization fails"), tail
                ) from None
        return
    if n > SPARSE_LU_LIMIT:
        return
    try:
        lu = splu(
            sp.csc_matrix(A),
            permc_spec="MMD_AT_PLUS_A",
            diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        )
    except RuntimeError:  # "Factor is exactly singular"
        raise fail("A", described("a singular matrix"), tail) from None
    pivots = lu.U.diagonal()
    if not np.array_equal(lu.perm_r, lu.perm_c) or np.any(pivots <= 0):
        neg = int(np.count_nonzero(pivots <= 0))
        raise fail(
            "A",
            described(f"a matrix with {max(neg, 1)} non-positive pivot(s) in a symmetric LDL^T"),
            tail,
        )
