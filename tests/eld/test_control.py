"""Sensors (point values, reactions) and controllers (linear, PD with filter, user)."""

import numpy as np
import pytest
from skfem import MeshTet, MeshTri

from rothe.eld import ELDProblem, Material
from rothe.eld.components import MassSpringDamper
from rothe.eld.control import LinearController, PointSensor, ReactionSensor, UserController
from rothe.eld.coupling import CoupledProblem, Translation
from rothe.errors import RotheInputError
from rothe.fem.mesh import tag_box_faces

MAT = Material(rho=1.0, lam=1.0, mu=1.0)


def _zero(t, x):
    return 0 * x


def _system(controllers, degree=2, dim=2):
    if dim == 2:
        mesh = tag_box_faces(MeshTri.init_tensor(np.linspace(0, 2, 9), np.linspace(0, 0.5, 3)))
    else:
        mesh = tag_box_faces(MeshTet.init_tensor(*(np.linspace(0, 1, 3),) * 3))
    support = MassSpringDamper(1.0, 1.0, dim=dim, name="support")
    problem = ELDProblem(
        mesh, Material(1.0, 1.0, 1.0, dim=dim), degree=degree, dirichlet={"right": _zero}
    )
    return CoupledProblem(problem, [support], [Translation("left", support)], controllers(support))


@pytest.mark.filterwarnings("ignore:G_d")
@pytest.mark.parametrize("degree,dim", [(1, 2), (2, 2), (2, 3)])
def test_point_sensor_interpolates_the_field(degree, dim):
    point = [1.3, 0.17] if dim == 2 else [0.3, 0.6, 0.45]
    sensor = PointSensor(point, "velocity", axes=[1])
    system = _system(
        lambda s: [
            LinearController.pd(
                0.5, 0.0, sensor, s, directions=[[0.0], [1.0]] + ([[0.0]] if dim == 3 else [])
            )
        ],
        degree,
        dim,
    )
    ctrl = system.controllers[0]
    space = system.body.space
    x = space.doflocs
    # a field of the space's degree is reproduced exactly at any point
    field = np.stack(
        [x[0] * x[1], 1 + 2 * x[0] ** degree - x[-1] ** degree] + ([x[2]] if dim == 3 else [])
    )
    v = np.ascontiguousarray(field.T).ravel()
    y = ctrl.measure(np.zeros_like(v), v, np.zeros(system.constraint.m))
    px = np.asarray(point)
    assert y[0] == pytest.approx(1 + 2 * px[0] ** degree - px[-1] ** degree, abs=1e-13)
    assert ctrl.Y_u.nnz == 0 and ctrl.output(0.0, np.zeros(0), y) == pytest.approx(-0.5 * y)
    assert ctrl.E.shape == (dim, 1)


@pytest.mark.filterwarnings("ignore:G_d")
def test_reaction_sensor_measures_minus_the_integral_of_lambda():
    sensor = ReactionSensor("right")
    system = _system(lambda s: [LinearController(None, None, None, -np.eye(2), sensor, s)])
    ctrl = system.controllers[0]
    lam = np.random.default_rng(2).standard_normal(system.constraint.m)
    y = ctrl.measure(np.zeros(system.body.space.ndofs), np.zeros(system.body.space.ndofs), lam)
    assert np.allclose(y, system.constraint.reactions(lam)["right"], rtol=1e-14)


def test_pd_controller_with_filter():
    sensor = PointSensor([1.0, 0.25], "velocity", axes=[0])
    ctrl = LinearController.pd(2.0, 0.3, sensor, MassSpringDamper(1.0, 1.0), filter_time=0.01)
    A, B, C, D = ctrl._mats
    # w = -(kp y + kd (y - z)/Tf), z' = (y - z)/Tf: for a ramp y = t, after the transient
    # z = t - Tf and w -> -(kp t + kd)
    Tf = 0.01
    z, t = -Tf, 0.0  # the steady state of the filter for y = t
    w = np.asarray(C) @ [z] + np.asarray(D) @ [t]
    assert w == pytest.approx(-(2.0 * t + 0.3))
    zdot = np.asarray(A) @ [z] + np.asarray(B) @ [t]
    assert zdot == pytest.approx(1.0)


@pytest.mark.filterwarnings("ignore:G_d")
def test_bad_control_input_is_one_line_each():
    inside = PointSensor([1.0, 0.25])
    outside = PointSensor([2.5, 0.1])

    def user(rhs_jac_factor):
        return lambda s: [
            UserController(
                lambda t, z, y: -(z**3) + y[:1],
                lambda t, z, y: -z,
                lambda t, z, y: (
                    np.diag(-3 * z**2) * rhs_jac_factor,
                    np.eye(1, 2),
                    -np.eye(1),
                    np.zeros((1, 2)),
                ),
                inside,
                s,
                z0=[0.2],
                outputs=1,
                directions=[[1.0], [0.0]],
            )
        ]

    cases = [
        (
            lambda: _system(lambda s: [LinearController(None, None, None, -np.eye(2), outside, s)]),
            r"^controllers\[0\]\.sensors\[0\]\.point: got \(2\.5, 0\.1\), must lie in the body \(a "
            r"mesh in the bounding box \[0, 2\] x \[0, 0\.5\]; the point is in no cell\)$",
        ),
        (
            lambda: _system(
                lambda s: [LinearController(None, None, None, -np.eye(2), ReactionSensor("top"), s)]
            ),
            r"^controllers\[0\]\.sensors\[0\]\.part: got 'top', must be a constrained part "
            r"\(prescribed or coupled\): left, right$",
        ),
        (
            lambda: _system(lambda s: [LinearController(None, None, None, -np.eye(3), inside, s)]),
            r"^controllers\[0\]\.D: got an array of shape \(3, 3\), must have shape \(3, 2\)",
        ),
        (
            lambda: _system(
                lambda s: [
                    LinearController(
                        None, None, None, -np.eye(2), inside, MassSpringDamper(1.0, 1.0, name="x")
                    )
                ]
            ),
            r"^controllers\[0\]\.component: got 'x', must be one of the system's components: "
            r"support$",
        ),
        (
            lambda: _system(
                lambda s: [
                    LinearController(None, None, None, -np.eye(2), inside, s, directions=np.ones(3))
                ]
            ),
            r"^controllers\[0\]\.directions: got an array of shape \(3, 1\), must have shape ",
        ),
        (
            lambda: LinearController(None, None, None, 1.0, [], MassSpringDamper(1.0, 1.0)),
            r"^sensors: got \[\], must hold at least one sensor$",
        ),
        (
            lambda: PointSensor([1.0, 2.0], "acceleration"),
            r"^quantity: got 'acceleration', must be one of displacement, velocity$",
        ),
        (
            lambda: LinearController.pd(1.0, 0.5, inside, MassSpringDamper(1.0, 1.0)),
            r"^filter_time: got None, must be a real number$",
        ),
        (
            lambda: LinearController.pd(
                1.0, 0.0, ReactionSensor("left"), MassSpringDamper(1.0, 1.0)
            ),
            r"^sensor: got 'ReactionSensor', must be a sensor of known size",
        ),
        (
            # (before: numpy's "could not broadcast input array from shape (10,) into shape (9,)")
            lambda: _system(
                lambda s: [
                    LinearController(
                        None, None, None, -np.eye(2, 1), ReactionSensor("left", axes=[2]), s
                    )
                ]
            ),
            r"^controllers\[0\]\.sensors\[0\]\.axes: got \[2\], must be axes 0\.\.1 of the 2D "
            r"body$",
        ),
        (
            lambda: _system(user(2.0)),
            r"^controllers\[0\]\.jacobians: got a Jacobian that disagrees with finite differences "
            r"of rhs in \(z, y\)",
        ),
    ]
    for make, message in cases:
        with pytest.raises(RotheInputError, match=message) as info:
            make()
        assert "\n" not in str(info.value)
    _system(user(1.0))  # the correct Jacobians pass
