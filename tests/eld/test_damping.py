"""Damping operators: the constants of (2.5), Jacobians, monotonicity, validation."""

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

from rothe.eld.damping import (
    NoDamping,
    NonlinearDamping,
    RayleighDamping,
    UserDamping,
    make_damping,
    saturating_velocity,
    saturating_velocity_jacobian,
)
from rothe.errors import RotheInputError
from rothe.fem import mesh as meshes
from rothe.fem.elasticity import VectorSpace

_SPACE = VectorSpace(meshes.unit_square(3, named=True), 2)
_M = _SPACE.mass()
_K = _SPACE.stiffness(2.0, 1.0)


def test_constants_of_each_damping():
    assert NoDamping().constants.d0 == 0.0
    c = RayleighDamping(a=0.3, b=0.02).constants
    assert (c.d0, c.d1, c.d2(2.0)) == (0.0, 0.02, pytest.approx(0.02 + 0.3 * 4.0))
    c = NonlinearDamping(b=0.01, d0=0.5, d_nl=2.0).constants
    assert (c.d0, c.d1, c.d2(1.0)) == (0.5, 0.01, pytest.approx(0.01 + 2.5))
    assert UserDamping(matrix=_M, d0=0.0, d1=0.1, d2=3.0).constants.d2(7.0) == 3.0


@settings(max_examples=30, deadline=None)
@given(scale=st.floats(0.01, 30.0), v_ref=st.floats(0.1, 10.0), seed=st.integers(0, 10**6))
def test_nonlinear_jacobian_matches_finite_differences(scale, v_ref, seed):
    rng = np.random.default_rng(seed)
    op = NonlinearDamping(b=0.1, d0=0.4, d_nl=1.5, v_ref=v_ref).operator(_SPACE, _M, _K)
    v = scale * rng.standard_normal(_SPACE.ndofs)
    w = rng.standard_normal(_SPACE.ndofs)
    eps = 1e-6 * max(1.0, scale)
    fd = (op.apply(v + eps * w) - op.apply(v - eps * w)) / (2 * eps)
    J = op.jacobian(v)
    assert np.linalg.norm(J @ w - fd) <= 1e-6 * np.linalg.norm(fd)
    # the matrix-free action is the assembled nonlinear part
    action = op.nonlinear_jacobian_action(v)(w)
    assert np.allclose(action, op.nonlinear_jacobian(v) @ w, rtol=1e-12, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(
    scale=st.floats(0.01, 50.0),
    seed=st.integers(0, 10**6),
    d0=st.floats(0.0, 5.0),
    b=st.floats(0.0, 1.0),
)
def test_monotone_up_to_the_l2_part(scale, seed, d0, b):
    """(2.5): <D u - D v, w> >= b |w|_K^2 - d0 |w|_M^2 for w = u - v (d1 = b in the K-norm)."""
    rng = np.random.default_rng(seed)
    op = NonlinearDamping(b=b, d0=d0, d_nl=3.0, v_ref=0.7).operator(_SPACE, _M, _K)
    u = scale * rng.standard_normal(_SPACE.ndofs)
    v = scale * rng.standard_normal(_SPACE.ndofs)
    w = u - v
    lhs = (op.apply(u) - op.apply(v)) @ w
    bound = b * (w @ (_K @ w)) - d0 * (w @ (_M @ w))
    assert lhs >= bound - 1e-10 * (abs(bound) + 1.0)


@settings(max_examples=50, deadline=None)
@given(
    v=st.lists(st.floats(-1e3, 1e3), min_size=2, max_size=2),
    w=st.lists(st.floats(-1e3, 1e3), min_size=2, max_size=2),
    v_ref=st.floats(0.01, 10.0),
)
def test_pointwise_saturation_is_monotone_and_1_lipschitz(v, w, v_ref):
    v, w = np.array(v), np.array(w)
    Nv, Nw = saturating_velocity(v, v_ref), saturating_velocity(w, v_ref)
    assert (Nv - Nw) @ (v - w) >= -1e-9 * (1 + np.linalg.norm(v - w) ** 2)
    assert np.linalg.norm(Nv - Nw) <= np.linalg.norm(v - w) * (1 + 1e-12) + 1e-12
    eig = np.linalg.eigvalsh(saturating_velocity_jacobian(v, v_ref))
    assert eig.min() > 0 and eig.max() <= 1 + 1e-12


def test_linear_and_user_operators():
    v = np.arange(_SPACE.ndofs, dtype=float) / _SPACE.ndofs
    ray = RayleighDamping(a=0.2, b=0.05).operator(_SPACE, _M, _K)
    assert ray.is_linear
    assert np.allclose(ray.apply(v), 0.2 * (_M @ v) + 0.05 * (_K @ v))
    user = UserDamping(
        force=lambda x: 2 * x, jacobian=lambda x: 2 * sp.identity(x.size), d0=0.0
    ).operator(_SPACE, _M, _K)
    assert not user.is_linear
    assert np.allclose(user.apply(v), 2 * v)
    assert np.allclose(user.jacobian(v) @ v, 2 * v)


def test_bad_damping_inputs():
    with pytest.raises(RotheInputError, match=r"^b: got -1, must be >= 0$"):
        RayleighDamping(b=-1)
    with pytest.raises(RotheInputError, match=r"^d0: got -0.5, must be >= 0$"):
        NonlinearDamping(d0=-0.5)
    with pytest.raises(RotheInputError, match=r"^v_ref: got 0, must be > 0$"):
        NonlinearDamping(v_ref=0)
    with pytest.raises(RotheInputError, match="give either matrix"):
        UserDamping(d0=0.0)
    with pytest.raises(RotheInputError, match="jacobian: got 'NoneType', must be a callable"):
        UserDamping(force=lambda x: x, d0=0.0)
    with pytest.raises(
        RotheInputError, match="damping: got 'viscous', must be one of none, rayleigh, nonlinear"
    ):
        make_damping("viscous")
