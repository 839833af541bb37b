"""Components: finite-dimensional mechanical systems coupled to an elastic body (issue 19).

A component has coordinates q in R^m, a constant symmetric positive definite mass matrix M_q,
internal forces f(t, q, p) (springs, dampers, nonlinear elements; p = q'), applied loads
f_ext(t), and is driven by the reactions of the couplings it carries
(:mod:`rothe.eld.coupling`) and by controllers' actuator forces (:mod:`rothe.eld.control`):

    M_q q'' + f(t, q, q') - sum_couplings (dG/dq)^T lambda = f_ext(t) + sum_controllers E w   (C.1b)

Sign convention (SPEC Sec. 7, ``docs/coupling.md``): written like the body's equation
rho M u'' + D u' + K u + B^T lambda = F, the constraint term is +B^T lambda on the body and
-(dG/dq)^T lambda on the component, i.e. the force *on* the component is +(dG/dq)^T lambda and
the force on the body is -B^T lambda. With B u = G(t, q) the two powers sum to
-lambda . (B u' - G_q q') = -lambda . G_t: the constraint does no work unless G depends on t
explicitly (tested in tests/eld/test_coupling.py).

Ready-made components (all linear: f = K_q q + C_q p, :class:`LinearComponent`):

- :class:`PointMass` (d coordinates: the displacement of the mass);
- :class:`MassSpringDamper` (a mass on a spring and a damper to the fixed ground; d coordinates);
- :class:`TunedMassDamper` (a carrier mass -- the coordinates a coupling ties to the body -- and
  an absorber mass on a spring and a damper to it; 2d coordinates);
- :class:`RigidBody` (linearized rigid motion with small rotations: the displacement of a
  material point x is a + theta x (x - x_ref); 2D: q = (a_x, a_y, theta), 3D: q = (a, theta),
  6 coordinates; mass matrix of the rigid body about x_ref, support springs and dampers).

:class:`UserComponent` takes a force callable with its Jacobians; they are compared with central
finite differences when the component is built (as RIS checks dF), and a disagreement is a
one-line :class:`~rothe.errors.RotheInputError`.

Energy: a component stores 1/2 p.M_q p + V(q) with the potential V of its conservative force
(1/2 q.K_q q for a linear one with symmetric K_q, user ``potential`` otherwise; None when not
known, then the work of f is booked whole), dissipates p.C_q p.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from ..errors import RotheInputError, check_int, check_positive, described, fail

#: relative symmetry tolerance of mass and stiffness matrices
SYMMETRY_TOL = 1e-12
#: relative tolerance of a Jacobian against central finite differences (two step sizes tried)
FD_TOL = 1e-5


def check_spd(name: str, M, size: int | None = None, symbol: str = "M") -> np.ndarray:
    """A symmetric positive definite (m, m) matrix, or a one-line error naming ``name``
    (``symbol``: the matrix's letter in the message)."""
    A = np.atleast_2d(np.asarray(M, dtype=float))
    if A.ndim != 2 or A.shape[0] != A.shape[1] or (size is not None and A.shape[0] != size):
        want = f"({size}, {size})" if size is not None else "square"
        raise fail(name, described(f"an array of shape {np.shape(M)}"), f"must be {want}")
    if not np.all(np.isfinite(A)):
        raise fail(name, described("non-finite entries"), "must be finite")
    A = _symmetric(name, A, symbol, "must be symmetric positive definite")
    eig = np.linalg.eigvalsh(A)
    if not eig[0] > 1e-12 * max(eig[-1], 0.0):
        raise fail(
            name,
            described(
                f"a singular or indefinite matrix (smallest eigenvalue "
                f"{eig[0]:.3g}, largest {eig[-1]:.3g})"
            ),
            "must be symmetric positive definite",
        )
    return A


def _matrix(name: str, value, size: int, symmetric: bool = False) -> np.ndarray:
    """A (size, size) matrix from a number (times I), a vector (diagonal) or a matrix."""
    A = np.asarray(value, dtype=float)
    if A.ndim == 0:
        A = float(A) * np.eye(size)
    elif A.ndim == 1 and A.shape == (size,):
        A = np.diag(A)
    if A.shape != (size, size):
        raise fail(
            name,
            described(f"an array of shape {np.shape(value)}"),
            f"must be a number, a vector of length {size} or a ({size}, {size}) matrix",
        )
    if not np.all(np.isfinite(A)):
        raise fail(name, described("non-finite entries"), "must be finite")
    if symmetric:
        A = _symmetric(name, A, "K", "must be symmetric (a potential force)")
    return A


def _symmetric(name: str, A: np.ndarray, symbol: str, allowed: str) -> np.ndarray:
    """(A + A^T)/2 if max |A - A^T| <= SYMMETRY_TOL max |A|, else a one-line error naming
    ``name`` (``symbol``: the matrix's letter in the message; ``allowed``: what it must be)."""
    scale = max(float(np.max(np.abs(A))), 1e-300)
    asym = float(np.max(np.abs(A - A.T)))
    if asym > SYMMETRY_TOL * scale:
        raise fail(
            name,
            described(f"a non-symmetric matrix (max |{symbol} - {symbol}^T| = {asym:.3g})"),
            allowed,
        )
    return 0.5 * (A + A.T)


def _set_coordinates(component, q0, p0, coordinates) -> None:
    """The initial q0, p0 (default zero) and the coordinates' names (default q0, q1, ...) of
    a component with ``component.size`` coordinates."""
    m = component.size
    component.q0 = _vector("q0", q0, m)
    component.p0 = _vector("p0", p0, m)
    names = tuple(f"q{k}" for k in range(m)) if coordinates is None else tuple(coordinates)
    if len(names) != m:
        raise fail("coordinates", list(names), f"must name the {m} coordinates")
    component.coordinates = names


def _vector(name: str, value, size: int) -> np.ndarray:
    if value is None:
        return np.zeros(size)
    v = np.asarray(value, dtype=float)
    if v.ndim == 0:
        v = np.full(size, float(v))
    if v.shape != (size,):
        raise fail(
            name, described(f"an array of shape {np.shape(value)}"), f"must have shape ({size},)"
        )
    if not np.all(np.isfinite(v)):
        raise fail(name, described("non-finite entries"), "must be finite")
    return v.copy()


def check_jacobian(
    name: str,
    f,
    jac,
    x0: np.ndarray,
    of: str,
    *,
    samples: int = 3,
    seed: int = 19,
    scale: float | None = None,
) -> None:
    """Compare ``jac(x)`` (an (k, n) matrix) with central differences of ``f`` at ``x0`` and
    at ``samples - 1`` random points around it, along random directions.

    A mismatch larger than the differencing error (relative :data:`FD_TOL`, two step sizes
    tried) raises a one-line RotheInputError naming ``name`` and what it should be the
    derivative ``of``."""
    rng = np.random.default_rng(seed)
    x0 = np.asarray(x0, dtype=float)
    s = max(1.0, float(np.max(np.abs(x0), initial=0.0))) if scale is None else scale
    for k in range(samples):
        x = x0 if k == 0 else x0 + 0.37 * s * rng.standard_normal(x0.shape)
        v = rng.standard_normal(x0.shape)
        v /= max(np.linalg.norm(v), 1e-300)
        J = np.asarray(jac(x), dtype=float)
        if not np.all(np.isfinite(J)):
            raise fail(name, described("a non-finite Jacobian"), "must be finite")
        ex = J @ v
        err = ref = 0.0
        for h in (1e-5 * s, 1e-7 * s):
            num = (
                np.asarray(f(x + h * v), dtype=float) - np.asarray(f(x - h * v), dtype=float)
            ) / (2 * h)
            if num.shape != ex.shape:
                raise fail(
                    name,
                    described(f"a Jacobian of shape {J.shape}"),
                    f"must map a direction of shape {x0.shape} to {num.shape}",
                )
            err = float(np.max(np.abs(ex - num), initial=0.0))
            ref = max(
                1.0, float(np.max(np.abs(num), initial=0.0)), float(np.max(np.abs(ex), initial=0.0))
            )
            if err <= FD_TOL * ref:
                break
        else:
            where = ", ".join(f"{c:.4g}" for c in np.ravel(x)[:6])
            raise RotheInputError(
                f"{name}: got a Jacobian that disagrees with finite differences of {of} at "
                f"({where}) (max error {err:.3g} against scale {ref:.3g}), must be its "
                f"derivative",
                name,
            )


class Component(ABC):
    """A finite-dimensional mechanical system (module docstring).

    Attributes
    ----------
    name : str
    size : int
        m, the number of coordinates.
    coordinates : tuple[str, ...]
        Their names (for outputs: ``q_<name>_<coordinate>``).
    mass : (m, m) ndarray
        M_q, symmetric positive definite (checked).
    q0, p0 : (m,) ndarrays
        Initial coordinates and velocities.
    """

    name: str
    size: int
    coordinates: tuple
    mass: np.ndarray
    q0: np.ndarray
    p0: np.ndarray

    @property
    @abstractmethod
    def is_linear(self) -> bool:
        """True if f(t, q, p) = K_q q + C_q p with constant K_q, C_q (:attr:`stiffness`,
        :attr:`damping`): a coupled step is then linear in q."""

    @abstractmethod
    def force(self, t: float, q: np.ndarray, p: np.ndarray) -> np.ndarray:
        """f(t, q, p) (m,), on the left side of (C.1b)."""

    @abstractmethod
    def jacobians(self, t: float, q: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(df/dq, df/dp), each (m, m)."""

    def load(self, t: float) -> np.ndarray:
        """f_ext(t) (m,): applied loads (zero by default)."""
        return np.zeros(self.size)

    def potential(self, q: np.ndarray) -> float | None:
        """V(q) with f = dV/dq + (dissipative part), or None if not known."""
        return None

    def kinetic_energy(self, p: np.ndarray) -> float:
        """The kinetic energy 1/2 p . (M p)."""
        return 0.5 * float(p @ (self.mass @ p))

    def describe(self) -> dict:
        """Type, name, size and coordinate names, for summaries."""
        return {
            "type": type(self).__name__,
            "name": self.name,
            "size": self.size,
            "coordinates": list(self.coordinates),
        }


class LinearComponent(Component):
    """M_q q'' + C_q q' + K_q q = f_ext(t): constant mass (SPD), stiffness (symmetric) and
    damping (any square matrix; its symmetric part dissipates p.C_q p).

    Parameters
    ----------
    mass : (m, m) array, or a vector (diagonal)
    stiffness, damping : number (times I), vector (diagonal) or (m, m) array; default 0
    load : callable t -> (m,) array, or None
    q0, p0 : initial coordinates and velocities (default 0)
    coordinates : names of the coordinates (default q0, q1, ...)
    name : str
    """

    def __init__(
        self,
        mass,
        stiffness=None,
        damping=None,
        *,
        load=None,
        q0=None,
        p0=None,
        coordinates=None,
        name: str = "component",
    ):
        M = np.asarray(mass, dtype=float)
        if M.ndim == 1:
            M = np.diag(M)
        self.mass = check_spd("mass", M)
        m = self.size = self.mass.shape[0]
        self.name = str(name)
        self.stiffness = _matrix(
            "stiffness", 0.0 if stiffness is None else stiffness, m, symmetric=True
        )
        self.damping = _matrix("damping", 0.0 if damping is None else damping, m)
        if load is not None and not callable(load):
            raise fail("load", type(load).__name__, "must be a callable t -> forces")
        self._load = load
        _set_coordinates(self, q0, p0, coordinates)

    @property
    def is_linear(self) -> bool:
        return True

    def force(self, t, q, p):
        """The linear force K q + C p (the component protocol)."""
        return self.stiffness @ q + self.damping @ p

    def jacobians(self, t, q, p):
        """(K, C): the constant stiffness and damping matrices (the component protocol)."""
        return self.stiffness, self.damping

    def load(self, t):
        """The user load at t (checked to have shape (size,)), or zeros without one."""
        if self._load is None:
            return np.zeros(self.size)
        f = np.asarray(self._load(float(t)), dtype=float)
        if f.shape != (self.size,):
            raise fail(
                "load", described(f"values of shape {f.shape}"), f"must return shape ({self.size},)"
            )
        return f

    def potential(self, q):
        """The elastic potential 1/2 q . (K q)."""
        return 0.5 * float(q @ (self.stiffness @ q))


def _dim(dim) -> int:
    d = check_int("dim", dim)
    if d not in (2, 3):
        raise fail("dim", dim, "must be 2 or 3")
    return d


_AXES = ("x", "y", "z")


class PointMass(LinearComponent):
    """A mass m > 0 whose displacement (d coordinates) a coupling ties to a boundary part.

    ``load``: callable t -> (d,) force (e.g. gravity ``lambda t: [0, -m g]``)."""

    def __init__(
        self, mass: float, dim: int = 2, *, load=None, q0=None, p0=None, name: str = "mass"
    ):
        d = _dim(dim)
        m = check_positive("mass", mass)
        super().__init__(m * np.eye(d), load=load, q0=q0, p0=p0, coordinates=_AXES[:d], name=name)


class MassSpringDamper(LinearComponent):
    """A mass on a spring (stiffness k) and a damper (c) to the fixed ground.

    ``stiffness``, ``damping``: number (isotropic), length-d vector (per axis) or d x d matrix.
    Coordinates: the displacement of the mass (d)."""

    def __init__(
        self,
        mass: float,
        stiffness,
        damping=0.0,
        dim: int = 2,
        *,
        load=None,
        q0=None,
        p0=None,
        name: str = "mass_spring",
    ):
        d = _dim(dim)
        m = check_positive("mass", mass)
        K = _matrix("stiffness", stiffness, d, symmetric=True)
        C = _matrix("damping", damping, d)
        super().__init__(
            m * np.eye(d), K, C, load=load, q0=q0, p0=p0, coordinates=_AXES[:d], name=name
        )


class TunedMassDamper(LinearComponent):
    """A carrier mass (coordinates 0..d-1: a coupling ties the body's part to them) with an
    absorber mass attached by a spring (k) and a damper (c); optionally the carrier on a
    spring/damper to the ground.

        [m_c  0 ] [q_c]''   [c + c_g  -c] [q_c]'   [k + k_g  -k] [q_c]
        [0   m_a] [q_a]   + [-c        c] [q_a]  + [-k       k] [q_a]  = f_ext

    Coordinates: carrier (d), absorber (d). Den Hartog's tuning for an absorber of mass ratio
    mu = m_a / M on a mode of modal mass M and frequency w: k = m_a (w/(1 + mu))^2,
    c = 2 m_a (w/(1 + mu)) sqrt(3 mu / (8 (1 + mu))) (:func:`den_hartog`)."""

    def __init__(
        self,
        carrier_mass: float,
        absorber_mass: float,
        stiffness,
        damping=0.0,
        dim: int = 2,
        *,
        ground_stiffness=0.0,
        ground_damping=0.0,
        load=None,
        q0=None,
        p0=None,
        name: str = "tmd",
    ):
        d = _dim(dim)
        mc = check_positive("carrier_mass", carrier_mass)
        ma = check_positive("absorber_mass", absorber_mass)
        k = _matrix("stiffness", stiffness, d, symmetric=True)
        c = _matrix("damping", damping, d)
        kg = _matrix("ground_stiffness", ground_stiffness, d, symmetric=True)
        cg = _matrix("ground_damping", ground_damping, d)
        M = np.diag(np.r_[np.full(d, mc), np.full(d, ma)])
        K = np.block([[k + kg, -k], [-k, k]])
        C = np.block([[c + cg, -c], [-c, c]])
        names = tuple(f"carrier_{a}" for a in _AXES[:d]) + tuple(f"absorber_{a}" for a in _AXES[:d])
        super().__init__(M, K, C, load=load, q0=q0, p0=p0, coordinates=names, name=name)


def den_hartog(modal_mass: float, frequency: float, mass_ratio: float) -> tuple[float, float]:
    """(k, c) of Den Hartog's optimal absorber for a mode of ``modal_mass`` and angular
    ``frequency`` w with absorber mass m_a = mu * modal_mass: the absorber's frequency
    w_a = w/(1 + mu), k = m_a w_a^2, and its damping ratio zeta_a = c/(2 m_a w_a) =
    sqrt(3 mu / (8 (1 + mu))), i.e. c/(2 m_a w) = sqrt(3 mu / (8 (1 + mu)^3)) (Den Hartog,
    Mechanical Vibrations, Sec. 3.3; the same c)."""
    M = check_positive("modal_mass", modal_mass)
    w = check_positive("frequency", frequency)
    mu = check_positive("mass_ratio", mass_ratio)
    ma = mu * M
    wa = w / (1 + mu)
    zeta = np.sqrt(3 * mu / (8 * (1 + mu)))
    return ma * wa**2, 2 * ma * wa * zeta


def skew(c: np.ndarray) -> np.ndarray:
    """[c]_x with [c]_x v = c x v (3D), or the 2D analogue column (-c_y, c_x)."""
    c = np.asarray(c, dtype=float)
    if c.shape == (2,):
        return np.array([[-c[1]], [c[0]]])
    return np.array([[0.0, -c[2], c[1]], [c[2], 0.0, -c[0]], [-c[1], c[0], 0.0]])


class RigidBody(LinearComponent):
    """A rigid body with small rotations (linearized rigid motion), coordinates
    q = (a, theta) at the reference point x_ref: a material point x moves by

        a + theta x (x - x_ref)        (2D: theta e_z x r = theta (-r_y, r_x); 3 coordinates;
                                        3D: 6 coordinates)

    Kinetic energy 1/2 int rho |a' + theta' x r|^2 (r = x - x_ref) gives, with
    c = x_cm - x_ref,

        M_q = [[m I, m S], [m S^T, J_ref]],
        3D: S = -[c]_x (a' . (theta' x c) = -a' . [c]_x theta'),
            J_ref = J_cm + m (|c|^2 I - c c^T)  (parallel axes);
        2D: S = (-c_y, c_x)^T,  J_ref = J_cm + m |c|^2,

    symmetric positive definite for m > 0 and J_cm SPD (checked).

    Parameters
    ----------
    mass : m > 0
    inertia : J_cm about the centre of mass: a number (2D), or a number (isotropic), vector
        (principal) or 3 x 3 SPD matrix (3D)
    center : x_cm (d,)
    reference : x_ref (d,), default x_cm (then M_q is diagonal in 2D)
    dim : 2 or 3
    stiffness, damping : support springs and dampers in the coordinates (m x m, m = 3 or 6),
        stiffness symmetric
    load : callable t -> (m,) generalized force (force, then moment about x_ref)
    """

    def __init__(
        self,
        mass: float,
        inertia,
        center,
        *,
        reference=None,
        dim: int = 2,
        stiffness=None,
        damping=None,
        load=None,
        q0=None,
        p0=None,
        name: str = "rigid_body",
    ):
        d = _dim(dim)
        m = check_positive("mass", mass)
        xc = _vector("center", center, d)
        xr = xc.copy() if reference is None else _vector("reference", reference, d)
        c = xc - xr
        nrot = 1 if d == 2 else 3
        if d == 2:
            J = np.atleast_2d(check_positive("inertia", inertia))
        else:
            # (not _matrix(symmetric=True): its refusal is a stiffness's, "a potential force")
            J = check_spd("inertia", _matrix("inertia", inertia, 3), symbol="J")
        S = skew(c).reshape(d, nrot)  # 2D: (-c_y, c_x); 3D: [c]_x, the translational coupling
        if d == 3:
            S = -S  # a' . (theta' x c) = a' . (-[c]_x theta')
        Jref = J + m * ((c @ c) * np.eye(nrot) - (np.outer(c, c) if d == 3 else 0.0))
        M = np.block([[m * np.eye(d), m * S], [m * S.T, Jref]])
        self.center = xc
        self.reference = xr
        self.body_mass = m
        rot = ("theta",) if d == 2 else ("theta_x", "theta_y", "theta_z")
        super().__init__(
            M,
            stiffness,
            damping,
            load=load,
            q0=q0,
            p0=p0,
            coordinates=tuple(f"a_{a}" for a in _AXES[:d]) + rot,
            name=name,
        )
        self.dim = d

    def displacement(self, q: np.ndarray, x: np.ndarray) -> np.ndarray:
        """a + theta x (x - x_ref) at points x (d, k): shape (d, k)."""
        R = rigid_motion_matrix(
            self.dim, np.asarray(x, dtype=float).reshape(self.dim, -1), self.reference
        )
        return np.einsum("dkm,m->dk", R, np.asarray(q, dtype=float))


def rigid_motion_matrix(dim: int, x: np.ndarray, x_ref: np.ndarray) -> np.ndarray:
    """The (d, k, m) array R with a + theta x (x_k - x_ref) = R[:, k, :] @ (a, theta).

    2D: m = 3, column 2 is (-(y - y_ref), x - x_ref); 3D: m = 6, theta x r = -[r]_x theta."""
    x = np.asarray(x, dtype=float)
    one = x.ndim == 1
    X = x[:, None] if one else x
    r = X - np.asarray(x_ref, dtype=float)[:, None]
    k = X.shape[1]
    if dim == 2:
        R = np.zeros((2, k, 3))
        R[0, :, 0] = R[1, :, 1] = 1.0
        R[0, :, 2], R[1, :, 2] = -r[1], r[0]
    else:
        R = np.zeros((3, k, 6))
        for a in range(3):
            R[a, :, a] = 1.0
        # theta x r: (th_y r_z - th_z r_y, th_z r_x - th_x r_z, th_x r_y - th_y r_x)
        R[0, :, 4], R[0, :, 5] = r[2], -r[1]
        R[1, :, 3], R[1, :, 5] = -r[2], r[0]
        R[2, :, 3], R[2, :, 4] = r[1], -r[0]
    return R[:, 0, :] if one else R


class UserComponent(Component):
    """A component with your own internal force f(t, q, p) and its Jacobians.

    Parameters
    ----------
    mass : (m, m) SPD matrix
    force : callable (t, q, p) -> (m,)
    jacobians : callable (t, q, p) -> (df/dq, df/dp), each (m, m); checked against central
        differences of ``force`` at (0, q0, p0) and two random points when built
    load : callable t -> (m,), optional
    potential : callable q -> V(q), optional (for the energy ledger; then f - dV/dq is the
        dissipative part)
    linear : declare f = K q + C p with constant K, C (the Jacobians at (0, q0, p0) are used)
    """

    def __init__(
        self,
        mass,
        force,
        jacobians,
        *,
        load=None,
        potential=None,
        q0=None,
        p0=None,
        coordinates=None,
        linear: bool = False,
        name: str = "component",
        check: bool = True,
    ):
        self.mass = check_spd("mass", mass)
        m = self.size = self.mass.shape[0]
        self.name = str(name)
        for label, f in (("force", force), ("jacobians", jacobians)):
            if not callable(f):
                raise fail(label, type(f).__name__, "must be a callable (t, q, p)")
        if load is not None and not callable(load):
            raise fail("load", type(load).__name__, "must be a callable t -> forces")
        if potential is not None and not callable(potential):
            raise fail("potential", type(potential).__name__, "must be a callable q -> V")
        self._force, self._jac, self._load, self._potential = force, jacobians, load, potential
        _set_coordinates(self, q0, p0, coordinates)
        self._linear = bool(linear)
        f0 = np.asarray(force(0.0, self.q0, self.p0), dtype=float)
        if f0.shape != (m,) or not np.all(np.isfinite(f0)):
            raise fail(
                "force",
                described(
                    f"values of shape {f0.shape}"
                    + ("" if np.all(np.isfinite(f0)) else ", non-finite")
                ),
                f"must return finite values of shape ({m},)",
            )
        if check:
            q0, p0 = self.q0, self.p0
            check_jacobian(
                "jacobians",
                lambda q: self._force(0.0, q, p0),
                lambda q: self._jac(0.0, q, p0)[0],
                q0,
                "force in q",
            )
            check_jacobian(
                "jacobians",
                lambda p: self._force(0.0, q0, p),
                lambda p: self._jac(0.0, q0, p)[1],
                p0,
                "force in p",
            )
            if potential is not None:
                check_jacobian(
                    "potential",
                    lambda q: np.atleast_1d(self._potential(q)),
                    lambda q: self._conservative(q)[None, :],
                    q0,
                    "potential (its gradient must be the force at p = 0)",
                )
        if self._linear:
            self.stiffness, self.damping = (
                np.asarray(J, dtype=float) for J in jacobians(0.0, self.q0, self.p0)
            )

    def _conservative(self, q):
        return np.asarray(self._force(0.0, q, np.zeros(self.size)), dtype=float)

    @property
    def is_linear(self) -> bool:
        return self._linear

    def force(self, t, q, p):
        """The user's force callable at (t, q, p), as a float array (the component protocol)."""
        return np.asarray(self._force(float(t), q, p), dtype=float)

    def jacobians(self, t, q, p):
        """The user's (df/dq, df/dp) at (t, q, p), as float arrays (the component protocol)."""
        fq, fp = self._jac(float(t), q, p)
        return np.asarray(fq, dtype=float), np.asarray(fp, dtype=float)

    def load(self, t):
        """The user's load at t, or zeros without one."""
        if self._load is None:
            return np.zeros(self.size)
        return np.asarray(self._load(float(t)), dtype=float)

    def potential(self, q):
        """The user's potential V(q), or None if none was given."""
        return None if self._potential is None else float(self._potential(q))
