"""RISProblem validates what enters it (shapes and types name the parameter, A must be
coercive); the dual distance (2.4) in closed form; its fingerprint."""

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

from rothe import RISProblem
from rothe.errors import RotheInputError
from rothe.io.checkpoint import digest, problem_fingerprint
from rothe.ris.examples import example_7_1, example_7_2

from .conftest import readme_problem, ris_1d_problem


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


# -- shapes and types name the parameter (raw numpy errors before) --------------------------------


@pytest.mark.parametrize(
    "overrides, message",
    [
        (
            dict(A=np.ones((3, 2))),
            r"^A: got matrix of shape \(3, 2\), must have shape \(3, 3\) like "
            r"z0$",
        ),
        (
            dict(A=sp.csr_matrix(np.ones((2, 3)))),
            r"^A: got matrix of shape \(2, 3\), must have shape",
        ),
        (dict(A="stiff"), r"^A: got a str, must be a square array or a scipy.sparse matrix$"),
        (
            dict(
                A=np.array([[2.0, 0, 0], [0, np.nan, 0], [0, 0, 2]])
            ),  # "inner solve failed (stalled)"
            r"^A: got nan, must be finite \(no NaN or inf\)$",
        ),
        (
            dict(dissipation_weights=[1.0, 1.0]),
            r"^dissipation_weights: got an array of shape \(2,\), must be a number or an "
            r"array of shape "
            r"\(3,\)$",
        ),
        (dict(metric_weights=np.ones((3, 1))), r"^metric_weights: got an array of shape \(3, 1\)"),
        (
            dict(F=lambda z: (1 - z**2) ** 2),
            r"^F: got an array of shape \(3,\) at z0, must return a number \(the energy F\(z\)\)$",
        ),
        (dict(F=lambda z: "x"), r"^F: got a str at z0, must return a number"),
        (
            dict(dF=lambda z: z[:2]),
            r"^dF: got an array of shape \(2,\) at z0, must have shape \(3,\) "
            r"\(n = 3 unknowns\)$",
        ),
        (
            dict(d2F=lambda z: np.ones((3, 2))),
            r"^d2F: got an array of shape \(3, 2\) at z0, must have "
            r"shape \(3,\) or \(3, 3\)",
        ),
        (
            dict(load=lambda t: np.ones(4) * t),
            r"^load\(t=0\): got an array of shape \(4,\), must "
            r"return an array of shape \(3,\)$",
        ),
        (
            dict(load=lambda t: {}[t]),
            r"^load: got an error at t = 0 \(KeyError: 0\.0\), must evaluate "
            r"there$",
        ),
        (dict(F=3.0), r"^F: got a float, must be a callable$"),
    ],
)
def test_shape_and_type_errors_name_the_parameter(overrides, message):
    with pytest.raises(RotheInputError, match=message):
        readme_problem(**overrides)


# -- A must be coercive (the runs with A = -I or 0 never ended) -----------------------------------


@pytest.mark.parametrize(
    "A, got",
    [
        (-np.eye(1), r"a matrix with A\[0, 0\] = -1"),
        (np.zeros((1, 1)), r"a matrix with A\[0, 0\] = 0"),
    ],
)
def test_example_7_1_with_A_not_coercive_is_refused(A, got):
    """With A = -1 or 0 the energy of Example 7.1 is unbounded below (p is linear for
    |z| >= 2): z ran off to -1e156 with t = 0, or forever under uniform steps."""
    with pytest.raises(
        RotheInputError,
        match=rf"^A: got {got}, must be positive definite "
        r"\(coercive: <A z, z> >= alpha \|z\|\^2, "
        r"Andreia & Meyer 2022, Sec\. 1\.3\)",
    ):
        ris_1d_problem(A=A)


def test_indefinite_A_dense_and_sparse():
    A = np.array([[2.0, 3.0, 0.0], [3.0, 2.0, 0.0], [0.0, 0.0, 1.0]])  # eigenvalues -1, 1, 5
    with pytest.raises(RotheInputError, match=r"^A: got a matrix with smallest eigenvalue -1, "):
        readme_problem(A=A)
    with pytest.raises(
        RotheInputError,
        match=r"^A: got a matrix with 1 non-positive pivot\(s\) "
        r"in a symmetric LDL\^T, must be positive definite",
    ):
        readme_problem(A=sp.csr_matrix(A))
    n = 50  # a Neumann Laplacian: singular, positive diagonal
    L = sp.diags(
        [np.r_[1.0, 2 * np.ones(n - 2), 1.0], -np.ones(n - 1), -np.ones(n - 1)], [0, 1, -1]
    ).tocsr()
    kw = dict(
        F=lambda z: float(np.sum(z**4)),
        dF=lambda z: 4 * z**3,
        d2F=lambda z: 12 * z**2,
        load=lambda t: np.full(n, t),
        z0=np.zeros(n),
    )
    with pytest.raises(
        RotheInputError,
        match=r"^A: got a (singular matrix|matrix with 1 "
        r"non-positive pivot)",
    ):
        readme_problem(A=L, **kw)
    readme_problem(A=L + 1e-3 * sp.eye(n), **kw)  # positive definite: accepted
    # F of quartic growth makes the energy coercive without A: the check can be switched off
    readme_problem(A=L, check_coercivity=False, **kw)


def test_fingerprint_hashes_the_data_that_define_the_problem():
    """``fingerprint()`` is what a checkpoint compares on resume: class, n, T and hashes of A,
    z0, the weights, the load at 0, T/3, T and F, F', F'' at z0 and z0 + 1/2 (the mesh too for
    a FERISProblem)."""
    p = readme_problem()
    fp = p.fingerprint()
    assert fp == problem_fingerprint(p)
    z0, z1 = p.z0, p.z0 + 0.5
    assert fp == {
        "class": "RISProblem",
        "n": 3,
        "T": 1.0,
        "A": digest(p.A),
        "z0": digest(z0),
        "weights": digest(p.r, p.m),
        "load": digest(p.load(0.0), p.load(1.0 / 3.0), p.load(1.0)),
        "F": digest(np.array([p.F(z0), p.F(z1)]), p.dF(z0), p.dF(z1), p.d2F(z0), p.d2F(z1)),
    }
    assert readme_problem(T=2.0).fingerprint()["load"] != fp["load"]
    assert readme_problem(dissipation_weights=0.4).fingerprint()["weights"] != fp["weights"]
    fe = example_7_2(4)
    ffp = fe.fingerprint()
    assert ffp["class"] == "FERISProblem" and ffp["mesh"] == digest(fe.nodes, fe.cells)
    assert {k: v for k, v in ffp.items() if k != "mesh"} == {
        **RISProblem.fingerprint(fe),
        "class": "FERISProblem",
    }
    assert example_7_2(4, pattern="unionjack").fingerprint()["mesh"] != ffp["mesh"]
    assert problem_fingerprint(fe) == ffp
