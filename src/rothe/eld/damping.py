"""Damping operators D: V -> V* (Sec. 2.2.2) with the constants of (2.5).

(2.5) asks D to be Lipschitz and strongly monotone up to an L2 part:

    ||D u - D v||_{V*} <= d2 ||u - v||,      d1 ||u - v||^2 - d0 |u - v|^2 <= <D u - D v, u - v>.

The constants are stated for differences w = u - v in V_B = ker B (that is where the Euler step
of Lemma 3.2 is solved) with ||w|| := <K w, w>^{1/2}, the energy norm of the stiffness (so
k1 = k2 = 1 in (2.4)), and |w| the L2 norm; C_emb is the constant of |w| <= C_emb ||w|| on V_B.
Then d2 = d2_energy + d2_l2 * C_emb^2.

Every damping object here is a *description* (numbers, validated where they enter); its
``operator(space, M, K)`` builds the discrete operator acting on dof vectors:

- :class:`NoDamping`: D = 0 (d0 = d1 = d2 = 0).
- :class:`RayleighDamping`: D v = a M v + b K v, a, b >= 0 (d0 = 0, d1 = b, d2 = b + a C_emb^2).
- :class:`NonlinearDamping`: D v = b K v - d0 M v + d_nl N(v) with the pointwise
  N(v) = v / sqrt(1 + |v|^2 / v_ref^2), i.e. <N(v), z> = int N(v(x)) . z(x) dx.
  N is the gradient of the convex v_ref^2 sqrt(1 + |v|^2/v_ref^2), so it is monotone with
  Lipschitz constant 1; hence (2.5) holds with d0 = d0, d1 = b, d2 = b + (d0 + d_nl) C_emb^2,
  and d0 > 0 makes the damping *anti*-damping in L2 up to the bound of Lemma 3.2 (tau < rho/d0).
- :class:`UserDamping`: your own D, either a matrix (linear) or a force with its Jacobian,
  with the constants you state.

A discrete operator (:class:`DampingOperator`) has the linear part C = a_M M + a_K K (+ a matrix)
with D v = C v + N(v), ``is_linear``, ``apply(v)``, ``linear_apply(v)``, ``jacobian(v)``
(sparse, = C + N'(v)), ``nonlinear_jacobian(v)`` and its matrix-free action.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..errors import check_nonnegative, check_positive, fail

DAMPINGS = ("none", "rayleigh", "nonlinear")


@dataclass(frozen=True)
class DampingConstants:
    """d0, d1 and d2 = d2_energy + d2_l2 C_emb^2 of (2.5) (see the module docstring).

    Parameters
    ----------
    d0 : float
        The L2 anti-damping constant of (2.5) (the step bound rho/d0 of Lemma 3.2).
    d1 : float
        The monotonicity constant of (2.5): d1 ||u - v||^2 - d0 |u - v|^2 <= <D u - D v, u - v>.
    d2_energy, d2_l2 : float
        The two parts of the Lipschitz constant d2 = d2_energy + d2_l2 C_emb^2 of (2.5).
    """

    d0: float
    d1: float
    d2_energy: float
    d2_l2: float

    def d2(self, c_emb: float) -> float:
        """d2 = d2_energy + d2_l2 C_emb^2, the constant of (2.5) for the embedding constant."""
        return self.d2_energy + self.d2_l2 * c_emb**2

    def as_dict(self) -> dict:
        """The constants as a dict (d2 with C_emb symbolic)."""
        return {"d0": self.d0, "d1": self.d1, "d2": f"{self.d2_energy:g} + {self.d2_l2:g} C_emb^2"}


class DampingOperator:
    """Discrete D acting on interleaved dof vectors: D v = C v + N(v).

    The linear part is kept as C = mass_coef M + stiffness_coef K (+ matrix), not as a new
    sparse matrix: at a million unknowns a third matrix of the size of K costs 0.6 GB, and the
    step matrix (rho/tau^2) M + C/tau + K is then built from M and K directly.
    """

    def __init__(
        self,
        M,
        K,
        *,
        mass_coef: float = 0.0,
        stiffness_coef: float = 0.0,
        matrix=None,
        nonlinear=None,
        nonlinear_jacobian=None,
        nonlinear_jacobian_action=None,
    ):
        self.M, self.K = M, K
        self.mass_coef = float(mass_coef)
        self.stiffness_coef = float(stiffness_coef)
        self.matrix = None if matrix is None else sp.csr_matrix(matrix)
        self._N = nonlinear
        self._dN = nonlinear_jacobian
        self._dN_action = nonlinear_jacobian_action

    @property
    def is_linear(self) -> bool:
        """True without a nonlinear part N(v)."""
        return self._N is None

    @property
    def linear(self) -> sp.csr_matrix:
        """C assembled (a new matrix; the schemes use :meth:`linear_apply` instead)."""
        C = self.mass_coef * self.M + self.stiffness_coef * self.K
        if self.matrix is not None:
            C = C + self.matrix
        return sp.csr_matrix(C)

    def linear_apply(self, v: np.ndarray) -> np.ndarray:
        """C v."""
        out = np.zeros_like(v, dtype=float)
        if self.mass_coef != 0.0:
            out += self.mass_coef * (self.M @ v)
        if self.stiffness_coef != 0.0:
            out += self.stiffness_coef * (self.K @ v)
        if self.matrix is not None:
            out += self.matrix @ v
        return out

    def nonlinear_apply(self, v: np.ndarray) -> np.ndarray:
        """N(v) (zero for linear damping)."""
        return np.zeros_like(v, dtype=float) if self._N is None else self._N(v)

    def apply(self, v: np.ndarray) -> np.ndarray:
        """D(v): the damping force at the velocity v (a dof vector)."""
        out = self.linear_apply(v)
        if self._N is not None:
            out = out + self._N(v)
        return out

    def jacobian(self, v: np.ndarray) -> sp.csr_matrix:
        """D'(v) = C + N'(v)."""
        if self._N is None:
            return self.linear
        return (self.linear + self._dN(v)).tocsr()

    def nonlinear_jacobian(self, v: np.ndarray) -> sp.csr_matrix:
        """N'(v) alone, assembled (zero matrix for linear damping)."""
        if self._N is None:
            return sp.csr_matrix(self.M.shape)
        return sp.csr_matrix(self._dN(v))

    def nonlinear_jacobian_action(self, v: np.ndarray):
        """w -> N'(v) w without assembling N'(v) (for Krylov iterations inside Newton)."""
        if self._N is None:
            return lambda w: np.zeros_like(w)
        if self._dN_action is not None:
            return self._dN_action(v)
        J = sp.csr_matrix(self._dN(v))
        return lambda w: J @ w


class Damping(ABC):
    """Base class of the damping descriptions."""

    name = "base"

    @property
    @abstractmethod
    def constants(self) -> DampingConstants:
        """d0, d1, d2 of (2.5)."""

    @abstractmethod
    def operator(self, space, M, K) -> DampingOperator:
        """The discrete damping operator on the given space."""

    def describe(self) -> dict:
        """The damping as in a trajectory's meta data (name and constants)."""
        return {"name": self.name, **self.constants.as_dict()}


class NoDamping(Damping):
    """D v = 0: d0 = d1 = d2 = 0 (no bound on the steps)."""

    name = "none"

    @property
    def constants(self) -> DampingConstants:
        return DampingConstants(0.0, 0.0, 0.0, 0.0)

    def operator(self, space, M, K) -> DampingOperator:
        """No damping: the operator of M and K with zero coefficients."""
        return DampingOperator(M, K)


class RayleighDamping(Damping):
    """D v = a M v + b K v with a, b >= 0 (M the mass of density 1).

    Parameters
    ----------
    a : float >= 0
        Mass-proportional coefficient.
    b : float >= 0
        Stiffness-proportional coefficient.
    """

    name = "rayleigh"

    def __init__(self, a: float = 0.0, b: float = 0.0):
        self.a = check_nonnegative("a", a)
        self.b = check_nonnegative("b", b)

    @property
    def constants(self) -> DampingConstants:
        return DampingConstants(0.0, self.b, self.b, self.a)

    def operator(self, space, M, K) -> DampingOperator:
        """The linear operator a M + b K."""
        return DampingOperator(M, K, mass_coef=self.a, stiffness_coef=self.b)

    def describe(self) -> dict:
        """The damping as in a trajectory's meta data (name, constants, a, b)."""
        return {**super().describe(), "a": self.a, "b": self.b}


def saturating_velocity(v: np.ndarray, v_ref: float) -> np.ndarray:
    """N(v) = v / sqrt(1 + |v|^2 / v_ref^2) pointwise; v has the components first (d, ...)."""
    return v / np.sqrt(1.0 + np.sum(v * v, axis=0) / v_ref**2)


def saturating_velocity_jacobian(v: np.ndarray, v_ref: float) -> np.ndarray:
    """N'(v) = (I - v v^T / (v_ref^2 + |v|^2)) / sqrt(1 + |v|^2 / v_ref^2): shape (d, d, ...)."""
    d = v.shape[0]
    sq = np.sum(v * v, axis=0)
    s = 1.0 + sq / v_ref**2
    outer = v[:, None] * v[None, :] / (v_ref**2 + sq)
    eye = np.eye(d).reshape((d, d) + (1,) * (v.ndim - 1))
    return (eye - outer) / np.sqrt(s)


class NonlinearDamping(Damping):
    """D v = b K v - d0 M v + d_nl N(v), N(v) = v / sqrt(1 + |v|^2 / v_ref^2) pointwise.

    N is integrated with the degree-2p quadrature of the space (exact for the mass part).

    Parameters
    ----------
    b : float >= 0
        Stiffness-proportional coefficient.
    d0 : float >= 0
        L2 anti-damping constant.
    d_nl : float >= 0
        Coefficient of the saturating part.
    v_ref : float > 0
        Saturation velocity.
    """

    name = "nonlinear"

    def __init__(self, b: float = 0.0, d0: float = 0.0, d_nl: float = 1.0, v_ref: float = 1.0):
        self.b = check_nonnegative("b", b)
        self.d0 = check_nonnegative("d0", d0)
        self.d_nl = check_nonnegative("d_nl", d_nl)
        self.v_ref = check_positive("v_ref", v_ref)

    @property
    def constants(self) -> DampingConstants:
        return DampingConstants(self.d0, self.b, self.b, self.d0 + self.d_nl)

    def force_density(self, v: np.ndarray) -> np.ndarray:
        """Pointwise part of the force density, -d0 v + d_nl N(v) (b K is -b div sigma(v))."""
        return -self.d0 * v + self.d_nl * saturating_velocity(v, self.v_ref)

    def operator(self, space, M, K) -> DampingOperator:
        """The operator b K - d0 M plus d_nl N(v), with N's Jacobian (assembled and as an
        action).
        """
        linear = dict(mass_coef=-self.d0, stiffness_coef=self.b)
        if self.d_nl == 0.0:
            return DampingOperator(M, K, **linear)
        d_nl, v_ref = self.d_nl, self.v_ref

        def N(v):
            return space.load_from_quad(d_nl * saturating_velocity(space.values_at_quad(v), v_ref))

        def dN(v):
            C = d_nl * saturating_velocity_jacobian(space.values_at_quad(v), v_ref)
            return space.coefficient_mass(C)

        def dN_action(v):
            # N'(v) w = int (d_nl N'(v(x)) w(x)) . phi dx: the d x d field at the quadrature
            # points once, then two passes over the elements per product
            C = d_nl * saturating_velocity_jacobian(space.values_at_quad(v), v_ref)

            def apply(w):
                return space.load_from_quad(np.einsum("abeq,beq->aeq", C, space.values_at_quad(w)))

            return apply

        return DampingOperator(
            M, K, **linear, nonlinear=N, nonlinear_jacobian=dN, nonlinear_jacobian_action=dN_action
        )

    def describe(self) -> dict:
        """The damping as in a trajectory's meta data (name, constants, b, d_nl, v_ref)."""
        return {**super().describe(), "b": self.b, "d_nl": self.d_nl, "v_ref": self.v_ref}


class UserDamping(Damping):
    """Your own damping on dof vectors: a matrix C (linear), or a force D(v) with Jacobian D'(v).

    ``force(v)`` and ``jacobian(v)`` receive the interleaved dof vector v (component c of scalar
    dof k at index d*k + c) and return a vector of the same length and a sparse matrix. State
    the constants of (2.5): d0 (used for the step-size bound of Lemma 3.2), d1 and d2 (reported).

    Parameters
    ----------
    matrix : sparse matrix, optional
        The linear damping C (shape of M).
    force, jacobian : callable(v), optional
        The nonlinear damping D(v) and its Jacobian (instead of ``matrix``).
    d0, d1, d2 : float
        The constants of (2.5).
    """

    name = "user"

    def __init__(
        self,
        matrix=None,
        force=None,
        jacobian=None,
        *,
        d0: float,
        d1: float = 0.0,
        d2: float = math.nan,
    ):
        if (matrix is None) == (force is None):
            raise fail(
                "damping",
                "matrix and force" if matrix is not None else "neither",
                "give either matrix (linear) or force with jacobian",
            )
        if force is not None and not (callable(force) and callable(jacobian)):
            raise fail(
                "jacobian",
                type(jacobian).__name__,
                "must be a callable returning the Jacobian of force",
            )
        self.matrix = matrix
        self.force = force
        self.jacobian = jacobian
        self.d0 = check_nonnegative("d0", d0)
        self.d1 = check_nonnegative("d1", d1)
        self.d2 = float(d2)

    @property
    def constants(self) -> DampingConstants:
        return DampingConstants(self.d0, self.d1, self.d2, 0.0)

    def operator(self, space, M, K) -> DampingOperator:
        """The given matrix C (shape checked against M), or the given force D(v) with its
        Jacobian.
        """
        if self.matrix is not None:
            C = sp.csr_matrix(self.matrix)
            if C.shape != M.shape:
                raise fail("damping matrix", f"shape {C.shape}", f"must be {M.shape}")
            return DampingOperator(M, K, matrix=C)
        return DampingOperator(
            M, K, nonlinear=self.force, nonlinear_jacobian=lambda v: sp.csr_matrix(self.jacobian(v))
        )


def make_damping(
    kind: str,
    *,
    a: float = 0.0,
    b: float = 0.0,
    d0: float = 0.0,
    d_nl: float = 1.0,
    v_ref: float = 1.0,
) -> Damping:
    """Build a damping by name (the CLI's --damping).

    Parameters
    ----------
    kind : {'none', 'rayleigh', 'nonlinear'}
    a, b : float
        Rayleigh: D v = a M v + b K v (nonlinear: b only).
    d0, d_nl, v_ref : float
        Nonlinear damping (:class:`NonlinearDamping`).

    Returns
    -------
    Damping
    """
    if kind == "none":
        return NoDamping()
    if kind == "rayleigh":
        return RayleighDamping(a=a, b=b)
    if kind == "nonlinear":
        return NonlinearDamping(b=b, d0=d0, d_nl=d_nl, v_ref=v_ref)
    raise fail("damping", kind, "must be one of " + ", ".join(DAMPINGS))
