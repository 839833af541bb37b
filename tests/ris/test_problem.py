"""RISProblem validates what enters it; the dual distance (2.4) in closed form."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rothe import RISProblem
from rothe.ris.examples import example_7_1


def make(**overrides):
    n = 3
    kw = dict(
        A=np.eye(n),
        F=lambda z: float(np.sum(z**4)),
        dF=lambda z: 4 * z**3,
        d2F=lambda z: 12 * z**2,
        load=lambda t: np.full(n, t),
        dissipation_weights=1.0,
        metric_weights=1.0,
        z0=np.zeros(n),
        T=1.0,
    )
    kw.update(overrides)
    return RISProblem(**kw)


@pytest.mark.parametrize(
    "overrides, match",
    [
        (dict(A=np.array([[1.0, 2.0, 0], [0, 1, 0], [0, 0, 1]])), r"A: got .* must be symmetric"),
        (dict(A=np.eye(2)), r"A: got matrix of shape \(2, 2\), must have shape \(3, 3\)"),
        (
            dict(dissipation_weights=[1.0, -1.0, 1.0]),
            r"dissipation_weights: got -1, every weight must be finite and > 0",
        ),
        (dict(metric_weights=0.0), r"metric_weights: got 0, every weight"),
        (dict(T=0.0), r"T: got 0, must be > 0"),
        (dict(z0=np.array([0.0, np.nan, 0.0])), r"z0: got nan, must be finite"),
        (
            dict(load=lambda t: np.full(3, np.inf) if t > 0.5 else np.zeros(3)),
            r"load\(t=1\): got inf, must be finite",
        ),
        (dict(dF=lambda z: 3 * z**3), r"dF: disagrees with finite differences of F"),
        (dict(d2F=lambda z: 11 * z**2), r"d2F: disagrees with finite differences of dF"),
    ],
)
def test_bad_problem_inputs(overrides, match):
    with pytest.raises(ValueError, match=match):
        make(**overrides)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(-10, 10), min_size=1, max_size=6), st.floats(0.01, 3), st.floats(0.1, 3))
def test_dist_is_the_distance_to_the_box(eta, r, m):
    """dist(eta) = min over xi in dR(0) = [-r, r]^n of ||eta - xi||_{V^-1} (2.4)."""
    eta = np.array(eta)
    n = eta.size
    p = make(
        A=np.eye(n),
        F=lambda z: 0.0,
        dF=lambda z: np.zeros(n),
        d2F=lambda z: np.zeros(n),
        load=lambda t: np.zeros(n),
        dissipation_weights=r,
        metric_weights=m,
        z0=np.zeros(n),
    )
    xi = np.clip(eta, -r, r)  # the projection onto the box is the minimizer for a diagonal metric
    assert p.dist(eta) == pytest.approx(np.sqrt(np.sum((eta - xi) ** 2 / m)), abs=1e-12)
    assert p.dist(-eta) == p.dist(eta)


def test_example_7_1_energy_matches_spec():
    p = example_7_1()
    for t, z in ((0.0, -2.0), (2.0, 0.5), (3.0, 7.0)):
        pz = 4 * z + 8 if z <= -2 else (4 - z * z if z < 2 else -4 * z + 8)
        assert p.energy(t, np.array([z])) == pytest.approx(0.5 * z * z - (t + 1) * z + pz)
