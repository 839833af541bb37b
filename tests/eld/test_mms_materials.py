"""The manufactured solution with several materials (rothe.eld.examples.mms_problem with a
PiecewiseMaterial): per-cell body force, tractions and multipliers of the adjacent cell, and the
interface load (sigma_0 - sigma_1)(u + b u') n_0 on the facets between two materials, so that
the quadratic u stays exact for P2; and the command line (eld-mms --material/--region)."""

import json

import numpy as np
import pytest

from rothe.eld import (
    BDF2,
    Material,
    NonlinearDamping,
    PiecewiseMaterial,
    RayleighDamping,
    mms_errors,
    mms_problem,
    run_eld,
)
from rothe.eld.indicator import eld_indicators_for
from rothe.eld.problem import CellwiseLoad, ELDProblem
from rothe.eld.stepper import ELDStepper
from rothe.eld.studies import fitted_rate
from rothe.errors import RotheInputError
from rothe.fem.adapt import SpaceAdaptivity
from rothe.stepping.controllers import Uniform

from ..conftest import run_cli, write_gmsh_body

SOFT = Material(rho=1.0, lam=2.0, mu=1.0)
HARD = Material(rho=3.0, lam=10.0, mu=4.0)
TAUS = (0.1, 0.05, 0.025)


def _left(x):
    return x[0] < 0.5


def _right(x):
    return x[0] >= 0.5


def _halves(left=SOFT, right=HARD) -> PiecewiseMaterial:
    """``left`` on the cells with centroid x < 1/2 of the unit square, ``right`` on the rest."""
    return PiecewiseMaterial(
        {"left": left, "right": right}, regions={_left: "left", _right: "right"}
    )


def _static_residual(problem, exact, t):
    """max over the free dofs of |rho_ref M a + D(v) + K u - F(t)| at the interpolated exact
    u(t), u'(t), u''(t): P2 holds them exactly, so this is the consistency of the data."""
    space = problem.space
    u, v, a = (
        space.interpolate(lambda x, f=f: f(t, x)) for f in (exact.u, exact.u_dot, exact.u_ddot)
    )
    R = (
        problem.material.rho * (problem.M @ a)
        + problem.damping_op.apply(v)
        + problem.K @ u
        - problem.load(t)
    )
    free = np.setdiff1d(np.arange(space.ndofs), problem.constraint.dofs)
    return float(np.abs(R[free]).max())


@pytest.mark.parametrize(
    "damping",
    [NonlinearDamping(b=0.01, d0=0.5, d_nl=1.0), RayleighDamping(a=0.3, b=0.02)],
    ids=["nonlinear", "rayleigh"],
)
@pytest.mark.parametrize("plane", ["strain", "stress"])
def test_the_exact_u_is_a_static_solution_only_with_the_interface_load(damping, plane):
    # n = 3: the material boundary x = 1/2 cuts no cell, it zigzags along cell edges
    left = Material(rho=1.0, lam=2.0, mu=1.0, plane=plane)
    right = Material(rho=3.0, lam=10.0, mu=4.0, plane=plane)
    problem, exact = mms_problem(3, 2, material=_halves(left, right), damping=damping)
    assert problem.describe()["interface_load"] is True
    assert _static_residual(problem, exact, 0.37) < 1e-12
    problem._interface = None  # without the jump of the traction on the interface
    assert _static_residual(problem, exact, 0.37) > 1.0


def test_bdf2_errors_are_second_order_in_tau_and_stall_without_the_interface_load():
    # P2: the semi-discrete solution is u itself, so the errors are BDF2's (tau^2)
    problem, exact = mms_problem(2, 2, material=_halves(), T=0.5)
    errs = [
        mms_errors(exact, run_eld(problem, scheme=BDF2(), control=Uniform(tau), store_fields=False))
        for tau in TAUS
    ]
    for key in ("error_u_l2", "error_v_l2", "error_lam_l2"):
        assert fitted_rate(TAUS, [e[key] for e in errs]) >= 1.8, key
    assert errs[-1]["error_u_l2"] < 6e-3 and errs[-1]["error_lam_l2"] < 5e-2
    problem._interface = None
    stalled = [
        mms_errors(exact, run_eld(problem, scheme=BDF2(), control=Uniform(tau), store_fields=False))
        for tau in TAUS[1:]
    ]
    assert min(e["error_u_l2"] for e in stalled) > 1.0  # O(1): the jump of the traction


@pytest.mark.parametrize("names", [("a", "b"), ("a", "a")], ids=["two-names", "one-name"])
def test_one_material_in_two_regions_is_the_one_material_run(names):
    one = Material(rho=2.0, lam=3.0, mu=1.5, plane="stress")
    same = Material(rho=2.0, lam=3.0, mu=1.5, plane="stress")
    piecewise = PiecewiseMaterial(
        {names[0]: one, names[1]: same}, regions={_left: names[0], _right: names[1]}
    )
    (p1, e1), (p2, e2) = (mms_problem(2, 2, material=m, T=0.2) for m in (one, piecewise))
    r1, r2 = (run_eld(p, scheme=BDF2(), control=Uniform(0.05)) for p in (p1, p2))
    for key in ("u", "v", "lam"):
        scale = np.abs(r1.trajectory[key]).max()
        assert np.abs(r1.trajectory[key] - r2.trajectory[key]).max() <= 1e-12 * scale
    a, b = mms_errors(e1, r1), mms_errors(e2, r2)
    assert all(abs(a[k] - b[k]) <= 1e-12 for k in a if isinstance(a[k], float))


def test_the_body_force_of_several_materials_needs_its_mesh_or_the_cells_materials():
    problem, exact = mms_problem(2, 2, material=_halves())
    mesh = problem.space.mesh
    with pytest.raises(RotheInputError, match=r"^body_force: got a call without the mesh"):
        exact.body_force(0.0, problem.space.quad_points)
    # the problem's data take each cell's material from its mesh (CellwiseLoad): the values of
    # each cell's (facet's) own constants, and no mesh held (space adaptivity takes them along)
    body, traction = problem.definition["body_force"], problem.definition["traction"]["top"]
    assert isinstance(body, CellwiseLoad) and isinstance(traction, CellwiseLoad)
    cells = problem.cell_material
    x, k = problem.space.quad_points, cells.names[:, None]
    per_cell = (cells.rho[:, None], cells.lam[:, None], cells.mu[:, None])
    weight = cells.density_weight[:, None]
    assert np.array_equal(body(0.3, x, k), exact._body_force(0.3, x, *per_cell, weight))
    top = problem.space.facets(("top",))
    q = problem.space.facet_quadrature(("top",))
    next_to = np.asarray(mesh.f2t)[0, top]
    kf = k[next_to]
    lam, mu = cells.lam[next_to][:, None], cells.mu[next_to][:, None]
    assert np.array_equal(
        traction(0.3, q.x, q.normals, kf), exact.traction(0.3, q.x, q.normals, lam, mu)
    )


def test_a_cellwise_load_needs_several_materials():
    problem, exact = mms_problem(2, 2)
    data = problem.definition
    data["body_force"] = CellwiseLoad(lambda t, x, k: 0 * x)
    with pytest.raises(RotheInputError, match=r"^body_force: got a CellwiseLoad with one material"):
        ELDProblem(problem.space.mesh, **data)
    with pytest.raises(RotheInputError, match=r"^f: got 'int', must be a callable"):
        CellwiseLoad(3)


def test_an_interface_load_needs_several_materials():
    problem, exact = mms_problem(2, 2)
    with pytest.raises(RotheInputError, match=r"^interface_load: got a load with one material"):
        type(problem)(problem.space.mesh, **problem.definition, interface_load=exact.u)


@pytest.mark.parametrize(
    "damping",
    [NonlinearDamping(b=0.01, d0=0.5, d_nl=1.0), RayleighDamping(a=0.3, b=0.02)],
    ids=["nonlinear", "rayleigh"],
)
def test_the_indicator_of_the_exact_solution_is_round_off_only_with_the_interface_load(damping):
    """P2 holds the exact u, u', u'' of two materials: every residual of the step vanishes --
    the cell residual with each cell's body force and mass damping (rho_c/rho_ref), the
    Neumann facets with the traction of the cell next to them, the interface facets' jump
    [sigma n] with the interface load taken off. Without that load the jump is O(1), on the
    cells at x = 1/2 only (an adaptive run would refine the interface for nothing)."""
    problem, exact = mms_problem(4, 2, material=_halves(), damping=damping)
    t, space = 0.37, problem.space
    u, v, a = (
        space.interpolate(lambda x, f=f: f(t, x)) for f in (exact.u, exact.u_dot, exact.u_ddot)
    )
    with_load = eld_indicators_for(problem, t, u, v, a, reaction=50.0)
    assert with_load.estimate < 1e-12  # measured 7.8e-14 (nonlinear damping)
    problem._interface = None
    without = eld_indicators_for(problem, t, u, v, a, reaction=50.0)
    assert np.sqrt(without.jump.sum()) > 1.0  # measured 4.2 (reaction 0: 14.9)
    assert np.sqrt(without.cell.sum() + without.boundary.sum()) < 1e-12
    mesh = space.mesh
    x = mesh.p[0, mesh.t]  # (3, cells): the cells with an edge on x = 1/2 carry it all
    on_interface = np.sum(np.abs(x - 0.5) < 1e-12, axis=0) == 2
    assert np.all(without.eta[~on_interface] < 1e-12) and np.all(without.eta[on_interface] > 0.1)


def test_an_adaptive_bdf2_run_of_two_materials_has_the_fixed_mesh_errors():
    """Space adaptivity with the loads of each cell's material (CellwiseLoad): the run refines
    (a cap of 400 dofs, so it also coarsens), every cell keeps the material of its side, the
    constraint holds and the ledger closes, and the errors at T are the fixed mesh's within 20 %
    (P2 holds u exactly: both are BDF2's time error; measured within 6 %, the H1 error of v
    within 25 %: the history transferred through coarsenings)."""
    problem, exact = mms_problem(2, 2, material=_halves(), T=0.5)
    opts = dict(scheme=BDF2(), control=Uniform(0.05), store_fields=False)
    fixed = mms_errors(exact, run_eld(problem, **opts))
    res = run_eld(problem, **opts, adapt=SpaceAdaptivity(space_tol=1e-3, max_dofs=400))
    tr = res.trajectory
    assert len(res.meshes.adaptations) >= 1 and np.sum(tr["step_bisections"]) > 0
    final = res.problem
    assert final.space.ndofs > problem.space.ndofs
    mesh = final.space.mesh
    cx = mesh.p[0, mesh.t].mean(axis=0)
    np.testing.assert_array_equal(final.cell_material.names, np.where(cx < 0.5, 0, 1))
    assert np.array_equal(final.constraint.restrict(res.state.u), final.G(res.state.t))
    assert np.abs(tr["balance_residual"]).max() <= 1e-10 * np.abs(tr["energy"]).max()
    adaptive = mms_errors(exact, res)
    for key in ("error_u_l2", "error_u_h1", "error_v_l2", "error_lam_l2"):
        assert abs(adaptive[key] / fixed[key] - 1) < 0.2, key


def _split_mesh(tmp_path):
    # [0, 2] x [0, 1], 'core' x < 1, 'shell' x > 1; boundary parts inlet, outlet, wall
    return write_gmsh_body(tmp_path / "split.msh", nx=4, ny=2, split=1.0)


MATERIALS = ["--material", "A:lam=2,mu=1,rho=1", "--material", "B:lam=10,mu=4,rho=3"]


def test_cli_eld_mms_with_two_materials_on_cell_groups(tmp_path, capsys):
    out = tmp_path / "out"
    code, _, err = run_cli(
        capsys,
        *("run", "eld-mms", "--mesh", _split_mesh(tmp_path), *MATERIALS),
        *("--region", "A=core", "--region", "B=shell", "--dirichlet", "inlet"),
        *("--scheme", "bdf2", "--degree", "2", "--tau", "0.0125", "--T", "0.5"),
        *("--out", out, "--no-plots", "--quiet"),
    )
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["material"]["regions"] == {"core": "A", "shell": "B"}
    assert summary["material"]["rho_ref"] == 3.0
    # BDF2 at tau = 0.0125 (measured 4.04e-3, 5.98e-3, 6.60e-3; O(1) without the interface load)
    assert summary["error_u_l2"] < 5e-3
    assert summary["error_v_l2"] < 7e-3
    assert summary["error_lam_l2"] < 8e-3


def test_cli_eld_mms_with_two_materials_adapts_in_space(tmp_path, capsys):
    """--adapt-space with --material (refused before: the loads held the fixed mesh's cells):
    the run adapts, and its errors at T are the fixed mesh's (P2 holds u; measured 1.586e-2,
    2.367e-2, 2.553e-2 against 1.586e-2, 2.360e-2, 2.598e-2 with 14 adaptations)."""
    common = [
        *("run", "eld-mms", "--mesh", _split_mesh(tmp_path), *MATERIALS),
        *("--region", "A=core", "--region", "B=shell", "--dirichlet", "inlet"),
        *("--scheme", "bdf2", "--degree", "2", "--tau", "0.025", "--T", "0.5"),
        *("--no-plots", "--quiet"),
    ]
    fixed, adaptive = tmp_path / "fixed", tmp_path / "adaptive"
    assert run_cli(capsys, *common, "--out", fixed)[0] == 0
    code, _, err = run_cli(
        capsys,
        *common,
        *("--adapt-space", "--space-tol", "1e-3", "--max-dofs", "600", "--out", adaptive),
    )
    assert code == 0, err
    a, f = (json.loads((d / "summary.json").read_text()) for d in (adaptive, fixed))
    assert a["status"] == "completed" and a["adaptations"] >= 1
    assert a["ndofs_initial"] == f["ndofs"] < a["ndofs_max"] <= 600
    for key in ("error_u_l2", "error_v_l2", "error_lam_l2"):
        assert abs(a[key] / f[key] - 1) < 0.2, key


@pytest.mark.parametrize(
    "extra,message",
    [
        (
            ["--region", "A=core"],
            "--material: got 8 of 16 cells in no region with a material",
        ),
    ],
    ids=["region-missing"],
)
def test_cli_eld_mms_refusals_with_materials(tmp_path, capsys, extra, message):
    code, _, err = run_cli(
        capsys,
        *("run", "eld-mms", "--mesh", _split_mesh(tmp_path), *MATERIALS, *extra),
        *("--dirichlet", "inlet", "--out", tmp_path / "out", "--no-plots", "--quiet"),
    )
    assert code == 2
    assert message in err and len(err.strip().splitlines()) == 1


def test_cli_eld_mms_with_two_materials_interrupted_then_resumed_bit_for_bit(
    tmp_path, capsys, signal_at_attempt
):
    """SIGINT at the 10th step of a two-material eld-mms run (exit 130, a checkpoint), then
    ``rothe resume``: the trajectory equals the uninterrupted run's bit for bit."""
    mesh = _split_mesh(tmp_path)
    argv = [
        *("run", "eld-mms", "--mesh", mesh, *MATERIALS, "--region", "A=core"),
        *("--region", "B=shell", "--dirichlet", "inlet", "--tau", "0.02", "--T", "0.4"),
        *("--no-plots", "--quiet"),
    ]
    ref, out = tmp_path / "ref", tmp_path / "out"
    assert run_cli(capsys, *argv, "--out", ref)[0] == 0
    signal_at_attempt(ELDStepper, 10)
    code, _, err = run_cli(capsys, *argv, "--out", out)
    assert code == 130 and f"rothe resume {out}" in err
    signal_at_attempt(ELDStepper, 10**9)
    assert run_cli(capsys, "resume", out, "--quiet")[0] == 0
    with np.load(ref / "trajectory.npz") as a, np.load(out / "trajectory.npz") as b:
        for key in ("t", "u", "v", "lam"):
            assert np.array_equal(a[key], b[key]), key
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "completed" and s["sessions"] == 2
