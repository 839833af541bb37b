"""Issue 18, item 3: the RIS front with a unique solution (``example_front_unique``).

The property the benchmark rests on: the energy is strictly convex, so the evolution is unique and
at each time the obstacle problem of ``front_unique_state``; every scheme step whose ball
constraint is inactive lands on it exactly, whatever the controller (path independence). Then:
uniform errors against a finer reference decrease monotonically under refinement, and an
adaptive run refines at the front and coarsens behind it.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from rothe.errors import RotheInputError
from rothe.fem.adapt import SpaceAdaptivity
from rothe.ris.examples import (
    FRONT_UNIQUE_DEFAULTS,
    example_front_unique,
    front_unique_error,
    front_unique_state,
)
from rothe.ris.run import run_ris
from rothe.ris.summary import viscous_jumps
from rothe.stepping.controllers import Adaptive, Uniform

from .conftest import DIRECT

A = FRONT_UNIQUE_DEFAULTS["reaction"]


def _steps_on_the_obstacle_curve(problem, traj):
    """max |z_k - z(t_{k-1})| over the steps with lambda_k = 0 that moved, and their count."""
    t, lam, z = np.asarray(traj["t"]), np.asarray(traj["lam"]), traj["z"]
    worst, count = 0.0, 0
    for k in range(1, len(t)):
        if lam[k - 1] == 0 and traj["step_norm"][k - 1] > 0:
            exact = problem.full_state(front_unique_state(problem, t[k - 1], A))
            worst = max(worst, float(np.max(np.abs(z[k] - exact))))
            count += 1
    return worst, count


def test_energy_is_strictly_convex_and_the_state_solves_the_obstacle_problem():
    problem = example_front_unique(8)
    # Hessian A + F'' = stiffness + a diag(m): smallest eigenvalue >= a min(m) > 0
    H = problem.A + __import__("scipy.sparse").sparse.diags(problem.d2F(np.zeros(problem.n)))
    smallest = spla.eigsh(H.tocsc(), k=1, sigma=0, which="LM", return_eigenvectors=False)[0]
    assert smallest >= A * problem.m.min() * (1 - 1e-10) > 0
    # KKT of min_{z >= 0} I(t, z) + kappa int z, checked independently of the solver
    z = front_unique_state(problem, 0.5, A)
    mu = problem.gradient(0.5, z) + problem.r
    assert z.min() >= 0 and mu.min() >= -1e-12
    assert np.max(np.abs(z * mu)) <= 1e-12
    assert 0.19 < z.max() <= 0.2 + 1e-12  # (A - kappa) / a behind the front
    assert np.count_nonzero(z > 0) < 0.5 * problem.n  # radius 0.45: the front is inside


@pytest.mark.parametrize("control", [Uniform(0.02), Adaptive(1e-4, tau=0.05)])
def test_every_free_step_is_the_exact_state_whatever_the_controller(control):
    """Uniqueness, seen by the scheme: two controllers with different steps both land on the
    obstacle curve (no branch to choose), and the run has no viscous step."""
    problem = example_front_unique(8)
    traj = run_ris(problem, control, inner=DIRECT).trajectory
    worst, count = _steps_on_the_obstacle_curve(problem, traj)
    assert count >= 0.9 * len(traj["lam"])
    assert worst <= 1e-8
    assert viscous_jumps(traj) == []  # the BV solution has none (catch-up steps aside)
    assert np.count_nonzero(np.diff(traj["t"]) <= 0) <= 0.05 * len(traj["lam"])
    assert traj["t"][-1] == pytest.approx(1.0)


def _error_near(reference, traj, problem, times=(0.25, 0.5, 0.75)):
    t = np.asarray(traj["t"])
    errs = []
    for tt in times:
        k = int(np.argmin(np.abs(t[:-1] - tt))) + 1
        mesh = problem.mesh
        errs.append(front_unique_error(reference, t[k - 1], traj["z"][k], mesh.p.T, mesh.t.T, A))
    return max(errs)


def test_uniform_errors_decrease_monotonically_under_refinement():
    """Against the exact state on a 64 x 64 grid (measured: 0.031, 0.022, 0.0096, 0.0035)."""
    reference = example_front_unique(64)
    errors = []
    for n in (4, 8, 16, 32):
        problem = example_front_unique(n)
        traj = run_ris(problem, Uniform(0.02), inner=DIRECT).trajectory
        errors.append(_error_near(reference, traj, problem))
    assert all(b < 0.8 * a for a, b in zip(errors, errors[1:], strict=False)), errors
    assert errors[-1] < 0.005


def test_error_of_the_exact_state_is_zero_and_nested_interpolation_exact():
    reference = example_front_unique(16)
    exact = reference.full_state(front_unique_state(reference, 0.4, A))
    mesh = reference.mesh
    assert front_unique_error(reference, 0.4, exact, mesh.p.T, mesh.t.T, A) <= 1e-12
    coarse = example_front_unique(8)
    z8 = coarse.full_state(front_unique_state(coarse, 0.4, A))
    assert front_unique_error(reference, 0.4, z8, coarse.mesh.p.T, coarse.mesh.t.T, A) > 1e-3


def test_adaptive_run_refines_at_the_front_and_beats_the_uniform_grid_of_its_start():
    problem = example_front_unique(8)
    adapt = SpaceAdaptivity(
        space_tol=0.05,
        refine_fraction=0.8,
        coarsen_fraction=0.02,
        max_dofs=33**2,
        max_level=4,
        adapt_every=4,
        refine_band=0.08,
    )
    traj = run_ris(problem, Uniform(0.02), inner=DIRECT, adapt=adapt).trajectory
    assert len(traj.meshes) > 3
    t = np.asarray(traj["t"])
    k = int(np.argmin(np.abs(t[:-1] - 0.5))) + 1
    points, cells = traj.meshes.mesh(traj["z_mesh_id"][k])
    # cell sizes against the distance of the cell's centre to the front (radius v t_{k-1})
    radius = FRONT_UNIQUE_DEFAULTS["speed"] * t[k - 1]
    centre = points[cells].mean(axis=1)
    dist = np.abs(np.hypot(centre[:, 0], centre[:, 1]) - radius)
    edge = np.linalg.norm(points[cells[:, 1]] - points[cells[:, 0]], axis=1)
    near, far = edge[dist < 0.05], edge[dist > 0.3]
    assert near.max() < far.min()  # the finest cells along the front, coarse far from it
    assert traj["n_dofs"][k] < 0.5 * 33**2
    # more accurate than the 8 x 8 grid it started from, and than 16 x 16
    reference = example_front_unique(64)
    err_adapt = front_unique_error(reference, t[k - 1], traj["z"][k], points, cells, A)
    uniform = example_front_unique(16)
    traj16 = run_ris(uniform, Uniform(0.02), inner=DIRECT).trajectory
    assert err_adapt < _error_near(reference, traj16, uniform, times=(0.5,))


@pytest.mark.parametrize(
    "kw, message",
    [
        ({"reaction": 0.0}, "reaction: got 0"),
        ({"reaction": -1.0}, "reaction: got -1"),
        ({"coefficient": 0.0}, "coefficient: got 0"),
        ({"width": -0.1}, "width: got -0.1"),
    ],
)
def test_bad_parameters_are_refused_in_one_line(kw, message):
    with pytest.raises(RotheInputError) as info:
        example_front_unique(4, **kw)
    assert str(info.value).startswith(message) and "\n" not in str(info.value)
