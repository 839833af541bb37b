"""Stresses (rothe.eld.stress) against a homogeneous deformation."""

import numpy as np
import pytest

from rothe.eld import Material, StressEvaluator, von_mises
from rothe.fem import mesh as meshes
from rothe.fem.elasticity import VectorSpace


def _hand_stress(grad, lam, mu):
    """sigma of the affine field u = grad x + c: lam tr(eps) I + 2 mu eps as a 3 x 3 tensor; in
    2D plane strain eps_zz = 0 and sigma_zz = lam tr(eps)."""
    d = grad.shape[0]
    eps = np.zeros((3, 3))
    eps[:d, :d] = 0.5 * (grad + grad.T)
    return lam * np.trace(eps) * np.eye(3) + 2 * mu * eps


def _hand_von_mises(s):
    return np.sqrt(
        0.5 * ((s[0, 0] - s[1, 1]) ** 2 + (s[1, 1] - s[2, 2]) ** 2 + (s[2, 2] - s[0, 0]) ** 2)
        + 3 * (s[0, 1] ** 2 + s[1, 2] ** 2 + s[0, 2] ** 2)
    )


@pytest.mark.parametrize("dim,degree", [(2, 1), (2, 2), (3, 1), (3, 2)])
def test_stress_of_a_homogeneous_deformation(dim, degree):
    rng = np.random.default_rng(dim * 10 + degree)
    grad = rng.uniform(-0.3, 0.3, (dim, dim))
    shift = rng.uniform(-1, 1, dim)
    mesh = meshes.unit_square(3, named=True) if dim == 2 else meshes.box(2, 2, 2)
    space = VectorSpace(mesh, degree)
    lam, mu = 1.7, 0.6
    u = space.interpolate(lambda x: grad @ x + shift[:, None])
    ev = StressEvaluator(space, Material(1.0, lam, mu, dim))
    expected = _hand_stress(grad, lam, mu)
    sigma = ev.stress(u)
    assert sigma.shape == (mesh.t.shape[1], 3, 3)
    assert np.abs(sigma - expected).max() <= 1e-12
    if dim == 2:
        assert abs(expected[2, 2]) > 0.01  # plane strain: sigma_zz = lam tr(eps) is not zero
    vm = von_mises(sigma)
    assert np.abs(vm - _hand_von_mises(expected)).max() <= 1e-12
    nodal = ev.nodal(sigma)
    assert nodal.shape == (mesh.p.shape[1], 3, 3)
    assert np.abs(nodal - expected).max() <= 1e-12  # averages of a constant are exact
    # a rigid motion has no stress
    rigid = space.rigid_body_modes() @ rng.standard_normal(3 if dim == 2 else 6)
    assert np.abs(ev.stress(rigid)).max() <= 1e-12


def test_von_mises_of_pure_shear_and_hydrostatic_states():
    shear = np.zeros((3, 3))
    shear[0, 1] = shear[1, 0] = 2.0
    assert von_mises(shear) == pytest.approx(2.0 * np.sqrt(3.0))
    assert von_mises(5.0 * np.eye(3)) == pytest.approx(0.0, abs=1e-14)
