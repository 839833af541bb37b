"""P1 assembly: agreement with scikit-fem, exactness on affine functions, boundary selection."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from skfem import Basis, ElementTetP1, ElementTriP1, MeshTri, asm
from skfem.models.poisson import laplace
from skfem.models.poisson import mass as sk_mass

from rothe.errors import RotheInputError
from rothe.fem.mesh import unit_cube, unit_square
from rothe.fem.scalar import (
    boundary_nodes,
    cell_coefficient,
    lumped_mass,
    mass,
    split_dofs,
    stiffness,
)


def _jiggled_square(n, amplitude=0.25, seed=0):
    """The unit-square grid with interior nodes moved randomly by up to amplitude * h."""
    m = unit_square(n)
    rng = np.random.default_rng(seed)
    p = m.p.copy()
    inner = np.ones(p.shape[1], bool)
    inner[m.boundary_nodes()] = False
    p[:, inner] += amplitude / n * rng.uniform(-1, 1, (2, inner.sum()))
    return MeshTri(p, m.t)


@pytest.mark.parametrize(
    "mesh, element",
    [
        (unit_square(5, "unionjack"), ElementTriP1()),
        (_jiggled_square(6), ElementTriP1()),
        (unit_cube(3), ElementTetP1()),
    ],
)
def test_matches_scikit_fem(mesh, element):
    basis = Basis(mesh, element)
    assert abs(stiffness(mesh) - asm(laplace, basis)).max() < 1e-12
    M = asm(sk_mass, basis)
    assert abs(mass(mesh) - M).max() < 1e-15
    assert np.allclose(lumped_mass(mesh), np.asarray(M.sum(axis=1)).ravel(), rtol=0, atol=1e-15)


def test_coefficient_callable_per_cell_and_checks():
    m = unit_square(4)
    c = lambda x: 1.0 + x[0]  # noqa: E731  (evaluated at barycentres)
    K = stiffness(m, c)
    centroids = m.p[:, m.t].mean(axis=1)
    assert np.allclose(cell_coefficient(m, c), 1.0 + centroids[0])
    K2 = stiffness(m, 1.0 + centroids[0])
    assert abs(K - K2).max() == 0.0
    assert abs(stiffness(m, 3.0) - 3.0 * stiffness(m)).max() < 1e-13
    with pytest.raises(RotheInputError, match=r"^coefficient: got -1, must be finite and > 0"):
        stiffness(m, -1.0)
    with pytest.raises(RotheInputError, match=r"^coefficient: got an array of shape \(3,\)"):
        stiffness(m, np.ones(3))


@settings(max_examples=30, deadline=None)
@given(
    n=st.integers(2, 6),
    amp=st.floats(0.0, 0.3),
    seed=st.integers(0, 10_000),
    a=st.floats(-3, 3),
    b=st.floats(-3, 3),
    c=st.floats(-3, 3),
    scale=st.floats(0.2, 5.0),
)
def test_affine_functions_are_harmonic_and_mass_is_area(n, amp, seed, a, b, c, scale):
    """On any mesh: K 1 = 0, interior rows of K (affine u) vanish, sum of lumped mass = area."""
    m = _jiggled_square(n, amp, seed)
    m = MeshTri(scale * m.p, m.t)
    K = stiffness(m)
    u = a * m.p[0] + b * m.p[1] + c
    free, _ = split_dofs(m.p.shape[1], boundary_nodes(m))
    r = K @ u
    assert np.max(np.abs(K @ np.ones(m.p.shape[1]))) < 1e-11 * (1 + abs(K).max())
    assert np.max(np.abs(r[free]), initial=0.0) < 1e-10 * (1 + abs(K).max()) * (1 + abs(u).max())
    assert np.isclose(lumped_mass(m).sum(), scale**2, rtol=1e-12)
    assert abs(K - K.T).max() < 1e-13 * abs(K).max()


def test_affine_exactness_3d():
    m = unit_cube(3)
    u = 2 * m.p[0] - m.p[1] + 0.5 * m.p[2]
    free, _ = split_dofs(m.p.shape[1], boundary_nodes(m))
    assert np.max(np.abs((stiffness(m) @ u)[free])) < 1e-12
    assert np.isclose(lumped_mass(m).sum(), 1.0)


def test_boundary_parts():
    m = unit_square(4)
    assert boundary_nodes(m).size == 16
    left = boundary_nodes(m, "left")
    assert left.size == 5 and np.allclose(m.p[0, left], 0)
    lb = boundary_nodes(m, ["left", "bottom"])
    assert lb.size == 9
    free, fixed = split_dofs(m.p.shape[1], lb)
    assert free.size + fixed.size == 25 and np.intersect1d(free, fixed).size == 0
    with pytest.raises(
        RotheInputError,
        match=r"^dirichlet: got 'inlet', must be one of bottom, left, right, top "
        r"\(sides of the bounding box; the mesh has no named parts\)$",
    ):
        boundary_nodes(m, ["inlet"])
    with pytest.raises(RotheInputError, match=r"^dirichlet: got 'front', must be one of bottom"):
        boundary_nodes(m, ["front"])  # no z sides in 2D
    with pytest.raises(RotheInputError, match=r"^dirichlet: got an empty list"):
        boundary_nodes(m, [])
    named = m.with_boundaries({"inlet": lambda x: x[0] < 1e-12})
    assert np.array_equal(boundary_nodes(named, "inlet"), left)
    with pytest.raises(RotheInputError, match=r"^dirichlet: got 'left', must be one of inlet$"):
        boundary_nodes(named, ["left"])  # named parts replace the box sides


@settings(max_examples=25, deadline=None)
@given(
    n=st.integers(2, 7),
    amp=st.floats(0.0, 0.3),
    seed=st.integers(0, 10_000),
    unionjack=st.booleans(),
)
def test_boundary_detection_matches_scikit_fem(n, amp, seed, unionjack):
    """Own facet counting == scikit-fem's boundary nodes and default side tags, any mesh."""
    m = unit_square(n, "unionjack" if unionjack else "tensor")
    rng = np.random.default_rng(seed)
    p = m.p.copy()
    inner = np.ones(p.shape[1], bool)
    inner[m.boundary_nodes()] = False
    p[:, inner] += amp / n * rng.uniform(-1, 1, (2, inner.sum()))
    m = MeshTri(p, m.t)
    assert np.array_equal(boundary_nodes(m), m.boundary_nodes())
    tagged = m.with_defaults()
    for name in ("left", "right", "bottom", "top"):
        assert np.array_equal(boundary_nodes(m, name), boundary_nodes(tagged, name))


def test_boundary_detection_3d():
    c = unit_cube(3)
    assert np.array_equal(boundary_nodes(c), c.boundary_nodes())
    tagged = c.with_defaults()
    for name in tagged.boundaries:
        assert np.array_equal(boundary_nodes(c, name), boundary_nodes(tagged, name))
