"""Issue 10: RISProblem input checks, the coercivity of A, stagnation, data errors midway, and
the landing of a run on T."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import scipy.sparse as sp

from rothe import RISProblem, RunFailed, run_ris
from rothe.errors import RotheInputError
from rothe.ris import examples as ris_1d


def readme_problem(**overrides):
    """The README's first Python example."""
    n = 3
    kw = dict(
        A=np.diag([2.0, 2.0, 2.0]) - np.diag([1.0, 1.0], 1) - np.diag([1.0, 1.0], -1),
        F=lambda z: float(np.sum((1 - z**2) ** 2)),
        dF=lambda z: -4 * z * (1 - z**2),
        d2F=lambda z: 12 * z**2 - 4,
        load=lambda t: np.full(n, 3.0 * t),
        dissipation_weights=0.5,
        metric_weights=1.0,
        z0=np.full(n, -1.0),
        T=1.0,
    )
    kw.update(overrides)
    return RISProblem(**kw)


def example_7_1(**overrides):
    kw = dict(
        A=np.array([[1.0]]),
        F=ris_1d.p,
        dF=ris_1d.dp,
        d2F=ris_1d.d2p,
        load=lambda t: np.array([t + 1.0]),
        dissipation_weights=1.0,
        metric_weights=1.0,
        z0=np.array([-2.0]),
        T=5.0,
    )
    kw.update(overrides)
    return RISProblem(**kw)


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
            r"^dissipation_weights: got an array of shape \(2,\), must be a number or an array of shape "
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
        example_7_1(A=A)


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


def test_fe_problem_needs_a_dirichlet_node_on_every_part_of_the_mesh():
    """The stiffness on the free nodes is singular on a part of the mesh without Dirichlet
    nodes; FE problems check it by connected components instead of a factorization."""
    from skfem import MeshTri

    from rothe.fem.mesh import unit_square
    from rothe.ris.fem_problem import FERISProblem, d2g_7_2, dg_7_2, g_7_2

    a = unit_square(3)
    b = MeshTri(a.p + np.array([[3.0], [0.0]]), a.t)  # a second square, apart from the first
    two = MeshTri(np.hstack([a.p, b.p]), np.hstack([a.t, b.t + a.p.shape[1]]))
    left = lambda x: x[0] < 1e-9  # noqa: E731
    two = two.with_boundaries({"left": left})
    with pytest.raises(
        RotheInputError,
        match=r"^mesh: got a mesh of 2 disconnected parts, 1 of "
        r"them without a node on boundary parts \['left'\]",
    ):
        FERISProblem(two, g_7_2, dg_7_2, d2g_7_2, load=lambda t: -200 * t**3, dirichlet=["left"])
    FERISProblem(two, g_7_2, dg_7_2, d2g_7_2, load=lambda t: -200 * t**3)  # both held


# -- a wrong dF: stagnation is detected and named (spun to the 10^6-attempt cap before) ----------


def wrong_for_positive_z(z):
    """dF of Example 7.1, doubled where z > 0: the derivative check's test points near z0 = -2
    do not see it."""
    g = ris_1d.dp(z)
    return 2 * g if float(z[0]) > 0.0 else g


@pytest.mark.parametrize("check", [True, False])
def test_wrong_dF_stops_with_a_message_naming_the_cause(check):
    problem = example_7_1(dF=wrong_for_positive_z, check_derivatives=check)
    with pytest.raises(
        RunFailed,
        match=r"^no progress: 200 step attempts advanced s by .* at "
        r"t = 2\.0.* dF or d2F probably does not belong to F",
    ) as e:
        run_ris(problem, "adaptive", tol=1e-4, tau=0.1)
    traj = e.value.trajectory
    assert traj is not None and 2.0 <= traj["t"][-1] < 2.1  # the steps before the jump are kept
    assert e.value.where["failed_solves"] > 50


def test_stagnation_monitor_state_round_trip():
    """Checkpoint protocol: the monitor's state is plain data and restores exactly."""
    from rothe.ris.stepper import RISState, RISStepper, StagnationMonitor

    stepper = RISStepper(example_7_1())
    state = RISState(s=0.0, t=0.0, z=np.array([-2.0]))
    for tau in (0.1, 0.05, 0.3):
        result = stepper.step(state, tau)
        state = result.state
    data = copy.deepcopy(stepper.monitor.checkpoint_state())
    assert data["attempts"] == 3 and data["s_start"] == 0.0
    fresh = StagnationMonitor()
    fresh.restore_state(data)
    assert fresh.checkpoint_state() == stepper.monitor.checkpoint_state()


# -- data that turns bad midway: a failed run that keeps its steps ---------------------------------


def test_nan_load_midway_keeps_the_trajectory():
    from rothe.fem.mesh import unit_square
    from rothe.ris.fem_problem import FERISProblem, d2g_7_2, dg_7_2, g_7_2

    problem = FERISProblem(
        unit_square(4),
        g_7_2,
        dg_7_2,
        d2g_7_2,
        load=lambda t: np.nan if 0.5 < t < 0.52 else -200.0 * t**3,
    )
    with pytest.raises(
        RunFailed,
        match=r"^load\(t=0\.5\d*\): got nan, must be finite \(no NaN "
        r"or inf\) \(at step \d+, s = ",
    ) as e:
        run_ris(problem, "adaptive", tol=1e-4, tau=0.1)
    traj = e.value.trajectory
    assert len(traj) == e.value.where["step"] - 1 and traj["t"][-1] <= 0.5


def test_load_undefined_beyond_T_only_shortens_the_last_step():
    """An attempt that overshoots T into times where the load is not defined is a failed
    attempt, not a failed run."""

    def load(t):
        if t > 1.0 + 1e-9:
            raise ValueError("no data after T")
        return np.full(3, 3.0 * t)

    traj = run_ris(readme_problem(load=load), "uniform", tol=None, tau=0.07)
    assert abs(traj["t"][-1] - 1.0) <= 1e-10


# -- the run ends on T (it ended at t = 1.0001418 for T = 1) --------------------------------------


@pytest.mark.parametrize(
    "control, tol, tau",
    [
        ("adaptive", 1e-5, 0.05),  # the README's call
        ("order2", 1e-5, 0.05),
        ("uniform", None, 0.013),
    ],
)
def test_readme_example_ends_on_T(control, tol, tau):
    traj = run_ris(readme_problem(), control, tol=tol, tau=tau)
    assert abs(traj["t"][-1] - 1.0) <= 1e-10
    assert traj["t"][-2] < 1.0
    landing = traj.meta["landing"]
    assert landing["landed"] and landing["ended_by"] == "T"
    assert landing["t_final_minus_T"] == traj["t"][-1] - 1.0
    if control == "adaptive":
        # t(tau) = t_{k-1} + max(tau - d*, 0) near the end of a slip: one slope-one Newton step
        # from the overshooting attempt lands (regula falsi from tau = 0 took six and missed by
        # 1.4e-4)
        assert traj.stats.landing_retries == 1
