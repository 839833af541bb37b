"""Sensors and controllers: feedback from measured outputs of the body to components (issue 19).

**Sensors** measure linear outputs of the body's state, y = Y_u u + Y_v u' + Y_lam lambda:

- :class:`PointSensor`: the displacement or the velocity at a point x of the body (u_h(x):
  the basis functions of the cell containing x; a point outside the body is refused);
- :class:`ReactionSensor`: the reaction force the support exerts on the body through a
  constrained part P, -int_P lambda ds (the sign of :meth:`DirichletConstraint.reactions`).

**Controllers** are first-order systems with a state z in R^s driven by the outputs, acting on a
component through an actuator force (the controller's output w enters (C.1b) as + E w):

    z' = h(t, z, y),        w = k(t, z, y),        force on the component: E w.

:class:`LinearController` (h = A z + B y, k = C z + D y; s = 0 is static feedback; :meth:`
LinearController.pd` builds proportional-derivative feedback with a first-order filter on the
derivative) and :class:`UserController` (callables with Jacobians, checked against finite
differences when bound to a system).

Why controllers act through a component and not on the Dirichlet data directly: in the
regularized form the data enter as G, G' and G'' separately. If G depended on a controller
state whose right side contains a measured output y, G'' would contain y' -- the derivative of
a measurement (for a velocity sensor, the body's acceleration at the sensor), which a step
can only form by differencing the noisy y: noise would be amplified like 1/tau, the very
effect the regularization removes (Theorem 4.5). Through a component (an actuator force on a
support mass) the output enters an ODE's right side, where noise stays bounded in both forms
(``docs/coupling.md``).

Energy: the controller's power into the mechanical system is p . E w (p the velocity of the
actuated component); the ledger books it as ``controller_work``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np
import scipy.sparse as sp

from ..errors import check_nonnegative, check_positive, described, fail
from ..fem.elasticity import affine_geometry
from .components import Component, check_jacobian

QUANTITIES = ("displacement", "velocity")


def locate(mesh, point: np.ndarray, name: str = "point", tol: float = 1e-10):
    """(cell, reference coordinates X) of the cell of ``mesh`` containing ``point``.

    Barycentric coordinates of the point in every cell at once (affine maps); the cell whose
    smallest barycentric coordinate is largest wins, and it must be >= -tol (relative to
    the cell): otherwise the point is outside the body and a one-line error names ``name``.
    """
    p, t = np.asarray(mesh.p), np.asarray(mesh.t)
    x = np.asarray(point, dtype=float)
    inv, _ = affine_geometry(p, t)  # invJ[k, a, c]
    r = x[:, None] - p[:, t[0]]  # (d, ne)
    X = np.einsum("kac,ac->kc", inv, r)  # reference coordinates per cell (d, ne)
    bary = np.vstack([1.0 - X.sum(axis=0), X])
    best = int(np.argmax(bary.min(axis=0)))
    if not bary[:, best].min() >= -tol:
        lo, hi = p.min(axis=1), p.max(axis=1)
        box = " x ".join(f"[{a:g}, {b:g}]" for a, b in zip(lo, hi, strict=True))
        where = ", ".join(f"{v:g}" for v in x)
        raise fail(
            name,
            described(f"({where})"),
            f"must lie in the body (a mesh in the bounding box {box}; the point is in no cell)",
        )
    return best, X[:, best]


class Sensor(ABC):
    """A linear output of the body: y = Y_u u + Y_v v + Y_lam lambda (``rows``)."""

    size: int

    @abstractmethod
    def rows(self, system, name: str) -> dict:
        """{'u': (k, n) or None, 'v': (k, n) or None, 'lam': (k, m) or None} sparse."""

    def describe(self) -> dict:
        """The sensor's type, for summaries."""
        return {"type": type(self).__name__}


class PointSensor(Sensor):
    """The displacement or velocity at ``point`` (all d components, or those in ``axes``)."""

    def __init__(self, point, quantity: str = "displacement", axes=None):
        x = np.asarray(point, dtype=float).ravel()
        if x.size not in (2, 3) or not np.all(np.isfinite(x)):
            raise fail(
                "point",
                described(f"{np.asarray(point).tolist()}"),
                "must be a finite point in 2D or 3D",
            )
        if quantity not in QUANTITIES:
            raise fail("quantity", quantity, "must be one of " + ", ".join(QUANTITIES))
        self.point = x
        self.quantity = quantity
        self.axes = None if axes is None else [int(a) for a in np.atleast_1d(axes)]
        if self.axes is not None and any(not 0 <= a < x.size for a in self.axes):
            raise fail("axes", self.axes, f"must be axes 0..{x.size - 1}")
        self.size = x.size if self.axes is None else len(self.axes)

    def rows(self, system, name):
        """Sparse rows giving the displacement or velocity at the point (the sensor protocol)."""
        space = system.body.space
        d = space.dim
        if self.point.size != d:
            raise fail(
                f"{name}.point",
                described(f"a {self.point.size}D point"),
                f"must be a point in {d}D like the mesh",
            )
        cell, X = locate(space.mesh, self.point, f"{name}.point")
        nbf = space.element_dofs.shape[0]
        phi = np.array(
            [float(np.ravel(space.element.lbasis(X[:, None], i)[0])[0]) for i in range(nbf)]
        )
        dofs = space.element_dofs[:, cell]
        axes = list(range(d)) if self.axes is None else self.axes
        rows = np.repeat(np.arange(len(axes)), nbf)
        cols = (d * dofs[None, :] + np.asarray(axes)[:, None]).ravel()
        Y = sp.csr_matrix((np.tile(phi, len(axes)), (rows, cols)), shape=(len(axes), space.ndofs))
        return {
            "u": Y if self.quantity == "displacement" else None,
            "v": Y if self.quantity == "velocity" else None,
            "lam": None,
        }

    def describe(self):
        """Type, point, quantity and axes, for summaries."""
        return {
            "type": "PointSensor",
            "point": self.point.tolist(),
            "quantity": self.quantity,
            "axes": self.axes,
        }


class ReactionSensor(Sensor):
    """The reaction force on the body through a constrained part: -int_P lambda ds."""

    def __init__(self, part: str, axes=None):
        if not isinstance(part, str) or not part:
            raise fail("part", part, "must name a constrained boundary part")
        self.part = part
        self.axes = None if axes is None else [int(a) for a in np.atleast_1d(axes)]
        self.size = None if axes is None else len(self.axes)

    def rows(self, system, name):
        """Sparse rows giving -int_P lambda ds from lambda (the sensor protocol)."""
        c = system.constraint
        d = system.body.space.dim
        if self.part not in c.parts:
            raise fail(
                f"{name}.part",
                self.part,
                "must be a constrained part (prescribed or coupled): " + ", ".join(sorted(c.parts)),
            )
        w = c._reaction_weights[self.part]  # int_P lambda_c ds = w . lambda_c
        axes = list(range(d)) if self.axes is None else self.axes
        if any(not 0 <= a < d for a in axes):  # (the body's dimension is known only here)
            raise fail(f"{name}.axes", self.axes, f"must be axes 0..{d - 1} of the {d}D body")
        Y = np.zeros((len(axes), c.m))
        for k, a in enumerate(axes):
            Y[k, a::d] = -w
        self.size = len(axes)
        return {"u": None, "v": None, "lam": sp.csr_matrix(Y)}

    def describe(self):
        """Type, part and axes, for summaries."""
        return {"type": "ReactionSensor", "part": self.part, "axes": self.axes}


class Controller(ABC):
    """z' = h(t, z, y), w = k(t, z, y), force E w on ``component`` (module docstring)."""

    name: str
    size: int  # s, the number of states
    outputs: int  # the length of w
    sensors: list
    component: Component
    is_linear: bool = True

    def __init__(self, sensors, component: Component, directions, name: str):
        sensors = list(sensors) if isinstance(sensors, list | tuple) else [sensors]
        if not sensors:
            raise fail("sensors", [], "must hold at least one sensor")
        for k, s in enumerate(sensors):
            if not isinstance(s, Sensor):
                raise fail(
                    f"sensors[{k}]", type(s).__name__, "must be a PointSensor or ReactionSensor"
                )
        if not isinstance(component, Component):
            raise fail(
                "component",
                type(component).__name__,
                "must be the rothe.eld component the controller acts on",
            )
        self.sensors = sensors
        self.component = component
        self.name = str(name)
        self._directions = directions

    def bind(self, system, label: str) -> None:
        """Check the sensors and the actuated component against ``system``, build the output
        rows Y_u, Y_v, Y_lam and the actuation matrix E (component size x outputs)."""
        if id(self.component) not in {id(c) for c in system.components}:
            raise fail(
                f"{label}.component",
                self.component.name,
                "must be one of the system's components: "
                + (", ".join(c.name for c in system.components) or "(none)"),
            )
        parts = [s.rows(system, f"{label}.sensors[{k}]") for k, s in enumerate(self.sensors)]
        n, m = system.body.space.ndofs, system.constraint.m

        def stack(key, cols):
            blocks = [
                p[key] if p[key] is not None else sp.csr_matrix((s.size, cols))
                for p, s in zip(parts, self.sensors, strict=True)
            ]
            return sp.vstack(blocks, format="csr")

        self.Y_u, self.Y_v, self.Y_lam = stack("u", n), stack("v", n), stack("lam", m)
        self.n_inputs = self.Y_u.shape[0]
        mc = self.component.size
        E = (
            np.eye(mc, self.outputs)
            if self._directions is None
            else np.asarray(self._directions, dtype=float)
        )
        if E.ndim == 1:  # one output: a column
            E = E[:, None]
        if E.shape != (mc, self.outputs):
            raise fail(
                f"{label}.directions",
                described(f"an array of shape {E.shape}"),
                f"must have shape ({mc}, {self.outputs}) (component coordinates x "
                "controller outputs)",
            )
        self.E = E
        self._check(label)

    @abstractmethod
    def _check(self, label: str) -> None:
        """Shapes (and, for user controllers, derivatives) once the inputs are known."""

    def measure(self, u, v, lam) -> np.ndarray:
        """y = Y_u u + Y_v v + Y_lam lambda."""
        return self.Y_u @ u + self.Y_v @ v + self.Y_lam @ lam

    @abstractmethod
    def rhs(self, t, z, y) -> np.ndarray:
        """h(t, z, y) (s,)."""

    @abstractmethod
    def output(self, t, z, y) -> np.ndarray:
        """k(t, z, y) (outputs,)."""

    @abstractmethod
    def jacobians(self, t, z, y):
        """(h_z, h_y, k_z, k_y)."""

    def describe(self) -> dict:
        """Type, name, number of states, component and sensors, for summaries."""
        return {
            "type": type(self).__name__,
            "name": self.name,
            "states": self.size,
            "component": self.component.name,
            "sensors": [s.describe() for s in self.sensors],
        }


class LinearController(Controller):
    """z' = A z + B y, w = C z + D y, force E w on ``component``.

    Parameters
    ----------
    A, B, C, D : arrays (s x s, s x k, o x s, o x k), k = sum of the sensors' sizes; s may be
        0 (static feedback w = D y: pass A = B = C = None)
    sensors : Sensor or list of them
    component : the actuated Component
    directions : E (component size x o), default the identity on the first o coordinates
    z0 : initial state (default 0)
    """

    def __init__(
        self, A, B, C, D, sensors, component, *, directions=None, z0=None, name: str = "controller"
    ):
        self._mats = (A, B, C, D)
        Dm = np.atleast_2d(np.asarray(D, dtype=float))
        self.outputs = Dm.shape[0]
        super().__init__(sensors, component, directions, name)
        s = 0 if A is None else np.atleast_2d(np.asarray(A, dtype=float)).shape[0]
        self.size = s
        self.z0 = np.zeros(s) if z0 is None else np.asarray(z0, dtype=float).reshape(s)

    def _check(self, label):
        A, B, C, D = self._mats
        s, k, o = self.size, self.n_inputs, self.outputs

        def mat(name, X, shape):
            X = np.zeros(shape) if X is None else np.asarray(X, dtype=float)
            if X.size == int(np.prod(shape)) and X.size:
                X = X.reshape(shape)
            if X.shape != shape:
                raise fail(
                    f"{label}.{name}",
                    described(f"an array of shape {X.shape}"),
                    f"must have shape {shape} (states {s}, inputs {k}, outputs {o})",
                )
            if not np.all(np.isfinite(X)):
                raise fail(f"{label}.{name}", described("non-finite entries"), "must be finite")
            return X

        self.A, self.B = mat("A", A, (s, s)), mat("B", B, (s, k))
        self.C, self.D = mat("C", C, (o, s)), mat("D", D, (o, k))

    def rhs(self, t, z, y):
        """The state equation's right side A z + B y (the controller protocol)."""
        return self.A @ z + self.B @ y

    def output(self, t, z, y):
        """The output C z + D y (the controller protocol)."""
        return self.C @ z + self.D @ y

    def jacobians(self, t, z, y):
        """The constant matrices (A, B, C, D) (the controller protocol)."""
        return self.A, self.B, self.C, self.D

    @classmethod
    def pd(
        cls,
        kp: float,
        kd: float,
        sensor: Sensor,
        component: Component,
        *,
        filter_time: float | None = None,
        directions=None,
        name: str = "pd",
    ):
        """w = -(kp y + kd y'), y' by the filtered derivative (y - z)/T_f with z' = (y - z)/T_f
        (one state; without ``filter_time`` kd must be 0: static feedback w = -kp y).
        For a velocity sensor, kp is a damper (-kp v) and kd an inertance."""
        kp = float(kp)
        kd = check_nonnegative("kd", kd)
        if not isinstance(sensor, Sensor) or sensor.size is None:
            raise fail(
                "sensor",
                type(sensor).__name__,
                "must be a sensor of known size (a PointSensor, or a ReactionSensor with axes)",
            )
        eye = np.eye(sensor.size)
        if kd == 0.0:
            return cls(
                None, None, None, -kp * eye, sensor, component, directions=directions, name=name
            )
        Tf = check_positive("filter_time", filter_time)
        return cls(
            -eye / Tf,
            eye / Tf,
            kd * eye / Tf,
            -(kp + kd / Tf) * eye,
            sensor,
            component,
            directions=directions,
            name=name,
        )


class UserController(Controller):
    """z' = h(t, z, y), w = k(t, z, y) by callables with their Jacobians.

    ``rhs(t, z, y)``, ``output(t, z, y)``; ``jacobians(t, z, y) -> (h_z, h_y, k_z, k_y)``,
    compared with finite differences of rhs and output at (0, z0, 0) and two random points
    when bound to a system."""

    is_linear = False

    def __init__(
        self,
        rhs,
        output,
        jacobians,
        sensors,
        component,
        *,
        z0,
        outputs: int,
        directions=None,
        name: str = "controller",
    ):
        for label, f in (("rhs", rhs), ("output", output), ("jacobians", jacobians)):
            if not callable(f):
                raise fail(label, type(f).__name__, "must be a callable (t, z, y)")
        self.outputs = int(outputs)
        super().__init__(sensors, component, directions, name)
        self.z0 = np.atleast_1d(np.asarray(z0, dtype=float))
        self.size = self.z0.size
        self._h, self._k, self._jac = rhs, output, jacobians

    def _check(self, label):
        s, k = self.size, self.n_inputs
        z0, y0 = self.z0, np.zeros(k)
        h0 = np.asarray(self._h(0.0, z0, y0), dtype=float)
        w0 = np.asarray(self._k(0.0, z0, y0), dtype=float)
        if h0.shape != (s,) or w0.shape != (self.outputs,):
            raise fail(
                f"{label}.rhs",
                described(f"shapes {h0.shape} and {w0.shape}"),
                f"must return ({s},) (rhs) and ({self.outputs},) (output)",
            )
        x0 = np.concatenate([z0, y0])

        def split(x):
            return x[:s], x[s:]

        check_jacobian(
            f"{label}.jacobians",
            lambda x: self._h(0.0, *split(x)),
            lambda x: np.hstack(self._jac(0.0, *split(x))[:2]),
            x0,
            "rhs in (z, y)",
        )
        check_jacobian(
            f"{label}.jacobians",
            lambda x: self._k(0.0, *split(x)),
            lambda x: np.hstack(self._jac(0.0, *split(x))[2:]),
            x0,
            "output in (z, y)",
        )

    def rhs(self, t, z, y):
        """The user's h(t, z, y), as a float array (the controller protocol)."""
        return np.asarray(self._h(float(t), z, y), dtype=float)

    def output(self, t, z, y):
        """The user's k(t, z, y), as a float array (the controller protocol)."""
        return np.asarray(self._k(float(t), z, y), dtype=float)

    def jacobians(self, t, z, y):
        """The user's (h_z, h_y, k_z, k_y), each as a 2-D float array (the controller protocol)."""
        return tuple(np.atleast_2d(np.asarray(J, dtype=float)) for J in self._jac(float(t), z, y))
