"""Components: mass matrices (rigid body against a point cloud), validation, FD-checked user
Jacobians, Den Hartog's tuning."""

import numpy as np
import pytest

from rothe.eld.components import (
    LinearComponent,
    MassSpringDamper,
    PointMass,
    RigidBody,
    TunedMassDamper,
    UserComponent,
    den_hartog,
    rigid_motion_matrix,
)
from rothe.errors import RotheInputError


def _cloud(dim, n=40, seed=3):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1, 2, (dim, n))
    m = rng.uniform(0.5, 2.0, n)
    mass = m.sum()
    xc = (x * m).sum(axis=1) / mass
    r = x - xc[:, None]
    if dim == 2:
        J = float(np.sum(m * (r**2).sum(axis=0)))
    else:
        J = np.einsum("k,k,ab->ab", m, (r**2).sum(axis=0), np.eye(3)) - np.einsum(
            "k,ak,bk->ab", m, r, r
        )
    return x, m, mass, xc, J


@pytest.mark.parametrize("dim", [2, 3])
def test_rigid_body_mass_is_the_kinetic_energy_of_its_points(dim):
    """M_q = sum_k m_k R_k^T R_k for the rigid motion a + theta x (x - x_ref) of the points."""
    x, m, mass, xc, J = _cloud(dim)
    ref = xc + np.array([0.3, -0.7, 0.2][:dim])  # a reference point off the centre of mass
    body = RigidBody(mass, J, xc, reference=ref, dim=dim)
    R = rigid_motion_matrix(dim, x, ref)  # (d, k, m)
    expected = np.einsum("k,dki,dkj->ij", m, R, R)
    assert np.abs(body.mass - expected).max() < 1e-12 * np.abs(expected).max()
    # the displacement of the points is R q
    q = np.arange(1.0, body.size + 1) * 1e-3
    assert np.allclose(body.displacement(q, x), np.einsum("dki,i->dk", R, q), atol=1e-15)
    # about the centre of mass the 2D mass matrix is diag(m, m, J)
    if dim == 2:
        assert np.allclose(RigidBody(mass, J, xc).mass, np.diag([mass, mass, J]), atol=1e-13)


def test_rotation_is_theta_cross_r():
    R = rigid_motion_matrix(3, np.array([1.0, 2.0, 3.0]), np.zeros(3))
    theta = np.array([0.1, -0.2, 0.3])
    assert np.allclose(R @ np.r_[0, 0, 0, theta], np.cross(theta, [1.0, 2.0, 3.0]))
    R2 = rigid_motion_matrix(2, np.array([1.0, 2.0]), np.zeros(2))
    assert np.allclose(R2 @ np.array([0, 0, 0.5]), [-1.0, 0.5])


def test_ready_made_linear_components():
    tmd = TunedMassDamper(2.0, 0.5, stiffness=8.0, damping=0.1, dim=2, ground_stiffness=1.0)
    assert tmd.size == 4 and tmd.coordinates[0] == "carrier_x"
    assert np.allclose(tmd.mass, np.diag([2, 2, 0.5, 0.5]))
    # spring between carrier and absorber: f = k (q_c - q_a) on the carrier, the reverse on
    # the absorber; the ground spring on the carrier only
    f = tmd.force(0.0, np.array([1.0, 0, 0, 0]), np.zeros(4))
    assert np.allclose(f, [9.0, 0, -8.0, 0])
    assert tmd.potential(np.array([1.0, 0, 1.0, 0])) == pytest.approx(0.5)  # ground spring only
    msd = MassSpringDamper(3.0, [4.0, 5.0], 0.2, dim=2, load=lambda t: [0.0, -3.0 * 9.81])
    assert np.allclose(msd.stiffness, np.diag([4, 5])) and msd.load(0.0)[1] == -3 * 9.81
    pm = PointMass(1.5, dim=3)
    assert pm.is_linear and pm.size == 3 and pm.kinetic_energy(np.ones(3)) == 2.25


def test_den_hartog_tuning():
    k, c = den_hartog(modal_mass=10.0, frequency=2.0, mass_ratio=0.05)
    wa = 2.0 / 1.05
    assert k == pytest.approx(0.5 * wa**2)
    # Den Hartog: c / (2 m_a w) = sqrt(3 mu / (8 (1 + mu)^3)) with w the mode's frequency
    # (equivalently zeta_a = c / (2 m_a w_a) = sqrt(3 mu / (8 (1 + mu))))
    assert c / (2 * 0.5 * 2.0) == pytest.approx(np.sqrt(3 * 0.05 / (8 * 1.05**3)))
    assert c / (2 * 0.5 * wa) == pytest.approx(0.133631, abs=1e-6)


def _pendulum_force(t, q, p):  # a nonlinear spring and a cubic damper
    return np.array([np.sin(q[0]) + 0.1 * p[0] ** 3, q[1] ** 3 + p[1]])


def _pendulum_jac(t, q, p):
    return (np.diag([np.cos(q[0]), 3 * q[1] ** 2]), np.diag([0.3 * p[0] ** 2, 1.0]))


def test_user_component_with_correct_jacobians_is_accepted():
    c = UserComponent(
        np.eye(2),
        _pendulum_force,
        _pendulum_jac,
        q0=[0.3, 0.1],
        p0=[0.2, 0],
        potential=lambda q: 1 - np.cos(q[0]) + q[1] ** 4 / 4,
    )
    assert not c.is_linear
    assert c.potential(np.array([0.0, 0.0])) == 0.0


def test_bad_component_input_is_one_line_each():
    def wrong(t, q, p):  # d/dq sin = cos, not -cos
        fq, fp = _pendulum_jac(t, q, p)
        fq = fq.copy()
        fq[0, 0] = -fq[0, 0]
        return fq, fp

    cases = [
        (
            lambda: LinearComponent([[1.0, 0.5], [0.0, 1.0]]),
            r"^mass: got a non-symmetric matrix \(max \|M - M\^T\| = 0\.5\), must be symmetric "
            r"positive definite$",
        ),
        (
            lambda: LinearComponent([[1.0, 1.0], [1.0, 1.0]]),
            r"^mass: got a singular or indefinite matrix \(smallest eigenvalue .*\), must be "
            r"symmetric positive definite$",
        ),
        (
            lambda: LinearComponent([[1.0, 0], [0, -1.0]]),
            r"^mass: got a singular or indefinite matrix",
        ),
        (
            lambda: LinearComponent(np.eye(2), stiffness=[[1.0, 2.0], [0.0, 1.0]]),
            r"^stiffness: got a non-symmetric matrix .*must be symmetric \(a potential force\)$",
        ),
        (
            lambda: LinearComponent(np.eye(2), damping=np.ones(3)),
            r"^damping: got an array of shape \(3,\), must be a number, a vector of length 2",
        ),
        (lambda: PointMass(0.0), r"^mass: got 0, must be > 0$"),
        (lambda: PointMass(1.0, dim=4), r"^dim: got 4, must be 2 or 3$"),
        (
            lambda: RigidBody(1.0, [[1, 0, 0], [0, 1, 0], [0, 0, -1]], [0, 0, 0], dim=3),
            r"^inertia: got a singular or indefinite matrix",
        ),
        (
            # (before: "max |K - K^T| ..., must be symmetric (a potential force)", a stiffness's)
            lambda: RigidBody(1.0, [[1, 0.3, 0], [0, 1, 0], [0, 0, 1]], [0, 0, 0], dim=3),
            r"^inertia: got a non-symmetric matrix \(max \|J - J\^T\| = 0\.3\), must be "
            r"symmetric positive definite$",
        ),
        (
            lambda: RigidBody(1.0, 1.0, [0, 0, 0], dim=2),
            r"^center: got an array of shape "
            r"\(3,\), must have shape \(2,\)$",
        ),
        (
            lambda: UserComponent(np.eye(2), _pendulum_force, wrong, q0=[0.3, 0.1]),
            r"^jacobians: got a Jacobian that disagrees with finite differences of force in q at "
            r"\(0\.3, 0\.1\) \(max error .* against scale .*\), must be its derivative$",
        ),
        (
            lambda: UserComponent(
                np.eye(2), _pendulum_force, _pendulum_jac, potential=lambda q: np.cos(q[0])
            ),
            r"^potential: got a Jacobian that disagrees with finite differences of potential",
        ),
        (
            lambda: UserComponent(np.eye(2), lambda t, q, p: np.zeros(3), _pendulum_jac),
            r"^force: got values of shape \(3,\), must return finite values of shape \(2,\)$",
        ),
    ]
    for make, message in cases:
        with pytest.raises(RotheInputError, match=message) as info:
            make()
        assert "\n" not in str(info.value)
