"""The residual indicator of a RIS step (3.1) on its mesh (rothe.ris.indicator)."""

from __future__ import annotations

import numpy as np

from rothe.fem import mesh as meshes
from rothe.fem.adapt import AdaptiveMesh
from rothe.fem.simplex import SimplexEvaluator
from rothe.ris.examples import example_7_2
from rothe.ris.indicator import ris_indicators, ris_indicators_for


def test_ris_indicator_measures_the_stability_violation_of_a_sticking_state():
    """z = z_prev = 0 (sticking): no jumps; the cell residual is max(|l - g'(0)| - kappa, 0)."""
    mesh = AdaptiveMesh(meshes.unit_square(3, named=True)).mesh
    zero = np.zeros(mesh.p.shape[1])
    stable = ris_indicators(mesh, zero, zero, dg=lambda z: 0 * z, load=0.8, kappa=1.0)
    assert stable.estimate == 0.0
    ev = SimplexEvaluator(mesh, 1, cell_order=4, facet_order=1)
    unstable = ris_indicators(
        mesh, zero, zero, dg=lambda z: 0 * z, load=-1.5, kappa=1.0, evaluator=ev
    )
    assert np.allclose(unstable.eta**2, ev.h**2 * 0.5**2 * ev.vol, rtol=1e-12)
    assert np.all(unstable.jump == 0) and np.all(unstable.boundary == 0)


def test_ris_indicator_for_example_7_2():
    problem = example_7_2(n=6)
    rng = np.random.default_rng(0)
    z_prev = rng.random(problem.free.size)
    z = z_prev + 0.1 * rng.standard_normal(problem.free.size)
    ind = ris_indicators_for(problem, 0.5, z, z_prev, lam=3.0)
    assert ind.eta.shape == (problem.mesh.t.shape[1],) and np.all(np.isfinite(ind.eta))
    assert ind.jump.sum() > 0 and ind.boundary.sum() == 0  # z = 0 on the whole boundary
