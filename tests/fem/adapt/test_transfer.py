"""Transfer of P1/P2 scalar and vector fields: exact on refinement, injection on coarsening."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from skfem import Basis, ElementTetP1, ElementTetP2, ElementTriP1, ElementTriP2

from rothe.eld.constraint import DirichletConstraint
from rothe.fem import mesh as meshes
from rothe.fem.adapt import AdaptiveMesh, free_transfer, transfer_vectors
from rothe.fem.elasticity import VectorSpace
from rothe.ris.examples import example_7_2

ELEMENTS = {(2, 1): ElementTriP1, (2, 2): ElementTriP2, (3, 1): ElementTetP1, (3, 2): ElementTetP2}


def old_field_at_new_nodes(old_mesh, new_mesh, dim, degree, u):
    """The old finite element function at the new Lagrange nodes, by scikit-fem's probes."""
    element = ELEMENTS[(dim, degree)]()
    old, new = Basis(old_mesh, element), Basis(new_mesh, element)
    return old.probes(new.doflocs) @ u, old.N, new.N


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    dim=st.sampled_from([2, 3]),
    degree=st.sampled_from([1, 2]),
    seed=st.integers(0, 2**31),
    fraction=st.floats(0.05, 0.9),
    rounds=st.integers(1, 3),
)
def test_refinement_transfer_reproduces_the_old_function(dim, degree, seed, fraction, rounds):
    rng = np.random.default_rng(seed)
    am = AdaptiveMesh(meshes.unit_square(2, named=True) if dim == 2 else meshes.box(1, 1, 1))
    for _ in range(rounds - 1):
        am.refine(rng.random(am.n_cells) < fraction)
    old_mesh = am.mesh
    change = am.refine(rng.random(am.n_cells) < fraction)
    element = ELEMENTS[(dim, degree)]()
    u = rng.standard_normal(Basis(old_mesh, element).N)
    expected, n_old, n_new = old_field_at_new_nodes(old_mesh, am.mesh, dim, degree, u)
    T = change.transfer(degree)
    assert T.shape == (n_new, n_old)
    assert np.allclose(T @ u, expected, rtol=0, atol=1e-12 * max(1, np.abs(u).max()))
    # rows are interpolation weights: they sum to one
    assert np.allclose(np.asarray(T.sum(axis=1)).ravel(), 1.0, rtol=0, atol=1e-14)
    # vector fields, interleaved: the scalar transfer per component
    Tv = change.transfer(degree, components=dim)
    U = rng.standard_normal((n_old, dim))
    assert np.allclose(Tv @ U.ravel(), (T @ U).ravel(), rtol=0, atol=1e-13)


@pytest.mark.parametrize("dim", [2, 3])
def test_coarsening_transfer_is_an_injection(dim):
    am = AdaptiveMesh(meshes.unit_square(2, named=True) if dim == 2 else meshes.box(1, 1, 1))
    rng = np.random.default_rng(2)
    for _ in range(3):
        am.refine(rng.random(am.n_cells) < 0.5)
    for degree in (1, 2):
        old_mesh = am.mesh
        change = am.coarsen(np.ones(am.n_cells, dtype=bool))
        assert change.merges > 0 and change.old_count.max() >= 2
        element = ELEMENTS[(dim, degree)]()
        old, new = Basis(old_mesh, element), Basis(am.mesh, element)
        T = change.transfer(degree)
        assert np.all(np.diff(T.indptr) == 1) and np.all(T.data == 1.0)
        # every new node is an old node, and takes its value
        cols = T.indices
        assert np.allclose(old.doflocs[:, cols], new.doflocs, rtol=0, atol=1e-15)
        u = rng.standard_normal(old.N)
        assert np.array_equal(T @ u, u[cols])


def test_mixed_adaptation_interpolates_and_unchanged_cells_map_exactly():
    am = AdaptiveMesh(meshes.unit_square(4, named=True))
    rng = np.random.default_rng(4)
    for _ in range(3):
        am.refine(rng.random(am.n_cells) < 0.4)
    old_mesh = am.mesh
    x = old_mesh.p[:, old_mesh.t].mean(axis=1)
    change = am.adapt(refine=x[0] < 0.3, coarsen=x[0] > 0.6)
    assert change.bisections and change.merges
    for degree in (1, 2):
        element = ELEMENTS[(2, degree)]()
        old, new = Basis(old_mesh, element), Basis(am.mesh, element)
        u = rng.standard_normal(old.N)
        T = change.transfer(degree)
        assert np.allclose(T @ u, old.probes(new.doflocs) @ u, rtol=0, atol=1e-12)
        # nodes that exist in both meshes keep their values bit for bit
        same = np.flatnonzero(np.diff(T.indptr) == 1)
        assert same.size > old.N // 4
        assert np.array_equal((T @ u)[same], u[T.indices[T.indptr[same]]])


def test_quadratic_fields_are_reproduced_through_refine_and_coarsen():
    """A global quadratic is a P2 function on every mesh: refine, coarsen, refine -- exact."""
    am = AdaptiveMesh(meshes.box(1, 1, 1))

    def quad(x):
        return 1 + x[0] - 2 * x[1] * x[2] + 3 * x[0] ** 2

    u = quad(Basis(am.mesh, ElementTetP2()).doflocs)
    rng = np.random.default_rng(0)
    for step in range(6):
        if step % 3 == 2:
            change = am.coarsen(rng.random(am.n_cells) < 0.7)
        else:
            change = am.refine(rng.random(am.n_cells) < 0.4)
        (u,) = transfer_vectors(change.transfer(2), u)
        assert np.allclose(u, quad(Basis(am.mesh, ElementTetP2()).doflocs), atol=1e-13)


def test_dirichlet_values_hold_after_every_change():
    """S u = G on the new Dirichlet dofs after transfer (ELD constraint B u = G): exactly for
    data in the space (refine and coarsen); for other data exactly on coarsening, and on
    refinement up to the interpolation error of the old mesh (the history keeps the old
    interpolant of G; the stepper rebuilds u2 from G on the new mesh); coarsening adds no
    deviation."""
    am = AdaptiveMesh(meshes.unit_square(3, named=True))

    def G_quadratic(x):
        return np.array([x[1] ** 2, 1 - x[1] + 0.5 * x[1] ** 2])

    def G_smooth(x):
        return np.array([np.sin(3 * x[1]), np.exp(x[1])])

    space = VectorSpace(am.mesh, 2)
    u, w = space.interpolate(G_quadratic), space.interpolate(G_smooth)
    worst = 0.0
    for step in range(6):
        x = am.points[am.cells].mean(axis=1)
        coarsen_only = step % 3 == 2
        change = am.adapt(
            refine=None if coarsen_only else x[:, 0] < 0.3,
            coarsen=np.full(am.n_cells, coarsen_only),
        )
        u, w = transfer_vectors(change.transfer(2, components=2), u, w)
        space = VectorSpace(am.mesh, 2)
        con = DirichletConstraint(space, ("left",))
        pts = con.scalar_points
        assert np.allclose(con.restrict(u), G_quadratic(pts).T.ravel(), rtol=0, atol=1e-14)
        err = np.abs(con.restrict(w) - G_smooth(pts).T.ravel()).max()
        if coarsen_only:  # an injection: no new deviation from G
            assert change.merges and err <= worst
        else:
            assert change.bisections and err < 1e-2
            worst = max(worst, err)
    assert worst > 1e-5


def test_ris_state_on_free_nodes():
    """z on the free P1 nodes of an FE-RIS problem: Tf = T[new_free][:, old_free]."""
    am = AdaptiveMesh(meshes.unit_square(4, named=True))
    old = example_7_2(mesh=am.mesh)
    rng = np.random.default_rng(1)
    z = rng.standard_normal(old.free.size)
    change = am.refine(rng.random(am.n_cells) < 0.5)
    new = example_7_2(mesh=am.mesh)
    T = change.transfer(1)
    Tf = free_transfer(T, old.free, new.free)
    assert sp.issparse(Tf) and Tf.shape == (new.free.size, old.free.size)
    assert np.allclose(Tf @ z, (T @ old.full_state(z))[new.free], rtol=0, atol=1e-15)
    assert np.allclose(new.full_state(Tf @ z)[new.fixed], 0.0)


def test_refinement_keeps_the_energy_coarsening_changes_it():
    """E(u) = 1/2 u.Ku + 1/2 u.Mu is the same after a refinement transfer (the same function);
    after coarsening it is the energy of the interpolant (the ELD ledger's transfer term)."""
    am = AdaptiveMesh(meshes.unit_square(4, named=True))
    space = VectorSpace(am.mesh, 2)

    def energy(space, u):
        K, M = space.stiffness(2.0, 1.0), space.mass()
        return 0.5 * u @ (K @ u) + 0.5 * u @ (M @ u)

    u = space.interpolate(lambda x: np.array([np.sin(7 * x[0]) * x[1], np.cos(5 * x[1])]))
    e0 = energy(space, u)
    rng = np.random.default_rng(6)
    for _ in range(3):
        change = am.refine(rng.random(am.n_cells) < 0.5)
        u = change.transfer(2, 2) @ u
        space = VectorSpace(am.mesh, 2)
        assert np.isclose(energy(space, u), e0, rtol=1e-12)
    # a field that the fine mesh resolves and the coarser one does not
    u = space.interpolate(lambda x: np.array([np.sin(17 * x[0]) * x[1], np.cos(15 * x[1])]))
    e1 = energy(space, u)
    change = am.coarsen(np.ones(am.n_cells, dtype=bool))
    u = change.transfer(2, 2) @ u
    space = VectorSpace(am.mesh, 2)
    assert abs(energy(space, u) - e1) > 1e-3 * e1
