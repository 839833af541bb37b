"""Residual indicators of ELD and RIS steps: exactness, efficiency band, adaptivity pays."""

from __future__ import annotations

import numpy as np
import pytest

from rothe.eld.efficiency import elasticity_study
from rothe.eld.examples import mms_problem
from rothe.eld.indicator import eld_indicators, eld_indicators_for
from rothe.errors import RotheInputError
from rothe.fem import mesh as meshes
from rothe.fem.adapt.efficiency import ScalarField, dofs_for_error
from rothe.fem.elasticity import VectorSpace


def polynomial_profile(dim: int, degree: int) -> ScalarField:
    """A global polynomial of the given degree (exactly represented by P``degree``)."""
    if degree == 1:
        w = np.array([1.0, 2.0, -0.5][:dim])
        return ScalarField(
            lambda x: 1 + np.tensordot(w, x, 1),
            lambda x: np.broadcast_to(w.reshape((dim,) + (1,) * (x.ndim - 1)), x.shape).copy(),
            lambda x: np.zeros((dim, dim) + x.shape[1:]),
        )

    def value(x):
        return 1 + x[0] * x[1] + x[0] ** 2

    def grad(x):
        g = np.zeros_like(x)
        g[0] = x[1] + 2 * x[0]
        g[1] = x[0]
        return g

    def hess(x):
        H = np.zeros((dim, dim) + x.shape[1:])
        H[0, 0] = 2.0
        H[0, 1] = H[1, 0] = 1.0
        return H

    return ScalarField(value, grad, hess)


@pytest.mark.parametrize("dim, degree", [(2, 1), (2, 2), (3, 1), (3, 2)])
def test_eld_indicator_vanishes_when_the_solution_is_in_the_space(dim, degree):
    rows = elasticity_study(
        dim,
        degree,
        polynomial_profile(dim, degree),
        n0=1 if dim == 3 else 2,
        adaptive=False,
        max_dofs=1,
    )
    assert rows[0]["error"] < 1e-11 and rows[0]["estimate"] < 1e-10


def test_eld_indicator_for_the_damped_manufactured_problem_vanishes_on_the_exact_fields():
    """mms_problem (P2, nonlinear damping b, d0, d_nl): with u, u', u'' of the exact solution
    the cell residual, the stress jumps and the traction mismatch are all zero."""
    problem, exact = mms_problem(n=3, degree=2)
    space = problem.space
    t = 0.37
    u = space.interpolate(lambda x: exact.u(t, x))
    v = space.interpolate(lambda x: exact.u_dot(t, x))
    a = space.interpolate(lambda x: exact.u_ddot(t, x))
    ind = eld_indicators_for(problem, t, u, v, a)
    assert ind.eta.shape == (space.mesh.t.shape[1],)
    assert ind.estimate < 1e-11
    # a wrong acceleration shows up in the cell residual only
    wrong = eld_indicators_for(problem, t, u, v, 1.1 * a)
    assert wrong.estimate > 1e-3 and np.allclose(wrong.jump, 0, atol=1e-20)


def test_eld_indicator_input_errors():
    space = VectorSpace(meshes.unit_square(2, named=True), 1)
    with pytest.raises(RotheInputError, match=r"^u: got an array of shape \(5,\), must be an"):
        eld_indicators(space.mesh, 1, 1.0, 1.0, np.zeros(5))
    with pytest.raises(RotheInputError, match=r"^mu: got 0, must be > 0$"):
        eld_indicators(space.mesh, 1, 1.0, 0.0, np.zeros(space.ndofs))


# -- efficiency band (coarse meshes; the tables on finer meshes: benchmarks/adapt_efficiency.py)

# measured (benchmarks/adapt_efficiency.py): ELD 5.2-20.5 on these coarse meshes (the wide end
# while the front of width 0.05 is not resolved), 9-12 asymptotically (RIS: tests/ris)
ELD_BAND = (4.0, 22.0)


@pytest.mark.parametrize(
    "dim, degree, profile, max_dofs",
    [
        (2, 1, "bump", 1500),
        (2, 1, "front", 1500),
        (2, 2, "bump", 1500),
        (2, 2, "front", 1500),
        (3, 1, "bump", 700),
    ],
)
def test_eld_efficiency_band(dim, degree, profile, max_dofs):
    for adaptive in (False, True):
        rows = elasticity_study(
            dim, degree, profile, adaptive=adaptive, max_dofs=max_dofs, n0=1 if dim == 3 else 2
        )
        eff = np.array([r["efficiency"] for r in rows])
        assert len(rows) >= 3
        assert ELD_BAND[0] <= eff.min() and eff.max() <= ELD_BAND[1], eff
        assert eff.max() / eff.min() <= 3.0, eff


def test_adaptive_refinement_reaches_the_error_with_fewer_dofs():
    """A steep front (width 0.02): the indicator-driven meshes reach the error of the uniform
    mesh with 2178 dofs with less than half the dofs."""
    uniform = elasticity_study(2, 1, "front", width=0.02, adaptive=False, max_dofs=2000)
    adaptive = elasticity_study(2, 1, "front", width=0.02, adaptive=True, max_dofs=2000)
    target = uniform[-1]["error"]
    assert uniform[-1]["dofs"] == 2178
    assert dofs_for_error(adaptive, target) < 0.5 * uniform[-1]["dofs"]


@pytest.mark.parametrize("dim, degree", [(2, 2), (3, 2)])
def test_the_indicators_chunks_change_no_value(monkeypatch, dim, degree):
    """The cell residual, the vertex gradients and the jumps are computed in chunks of cells
    and facets (the estimate's temporaries were the peak memory of an adaptive 3D run): chunks
    of 7, 5 and 3 (not dividing the counts) give the indicators of one chunk, bit for bit,
    with body force, acceleration, damping and a traction."""
    import rothe.eld.indicator as indicator
    import rothe.fem.simplex as simplex

    mesh = meshes.unit_square(4, named=True) if dim == 2 else meshes.box(2, 2, 2)
    rng = np.random.default_rng(11)
    n = VectorSpace(mesh, degree).ndofs
    u, v, a = (rng.standard_normal(n) for _ in range(3))

    def run():
        return eld_indicators(
            mesh,
            degree,
            2.0,
            1.5,
            u,
            rho=1.3,
            accel=a,
            velocity=v,
            body_force=lambda x: np.sin(x),
            traction={"right": lambda x, nrm: x * nrm},
            mass_damping=0.2,
            stiffness_damping=0.01,
            pointwise_damping=lambda vq: vq**3,
            reaction=4.0,
        )

    whole = run()
    for name, module, size in (
        ("CELL_CHUNK", indicator, 7),
        ("FACET_CHUNK", indicator, 5),
        ("VERTEX_CHUNK", simplex, 3),
    ):
        monkeypatch.setattr(module, name, size)
    chunked = run()
    for part in ("eta", "cell", "jump", "boundary"):
        assert np.array_equal(getattr(whole, part), getattr(chunked, part)), part
    assert np.all(whole.cell > 0) and np.any(whole.boundary > 0)


@pytest.mark.parametrize("dim, degree", [(2, 1), (2, 2), (3, 2)])
def test_gradients_from_vertex_values_are_the_basis_gradients(dim, degree):
    """The jump terms take grad w on a facet as the barycentric combination of its values at
    the cell's vertices (the gradient of P1/P2 is affine on a cell): the same numbers as the
    n_local basis gradients, to round-off, on cells of unsorted vertices."""
    from rothe.fem.simplex import SimplexEvaluator

    mesh = meshes.unit_square(3, named=True) if dim == 2 else meshes.box(2, 2, 2)
    ev = SimplexEvaluator(mesh, degree)
    rng = np.random.default_rng(5)
    U = rng.standard_normal((ev.ndofs, dim))
    topo = ev.topology
    cells, local = topo.inner_cells[0], topo.inner_local[0]
    lam = ev.facet_lambda(cells, local, topo.facets[:, topo.interior])
    direct = ev.gradients_at(U, cells, lam)
    via = ev.gradients_from_vertices(ev.vertex_gradients(U), cells, lam)
    assert direct.shape == via.shape
    assert np.max(np.abs(direct - via)) <= 1e-12 * np.max(np.abs(direct))
    # and the Hessians from the same vertex values are the ones computed alone
    assert np.array_equal(ev.hessians(U), ev.hessians(U, ev.vertex_gradients(U)))
