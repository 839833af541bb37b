"""Issue 8 (RIS half): RIS runs on meshes that change between steps.

Every accepted step is checked on its own mesh, independently of the solver's own report:
the ball, (4.1), the stationarity (4.4) in its nodal form, the descent (3.2) from the
*transferred* z_{k-1}, and Lemma 4.12 (I2 >= 0). Further: transfer exact on refinement, a run in
which nothing is marked is the fixed-mesh run bit for bit, the front example coarsens behind its
front, bad input, the checkpoint round trip and an interrupted + resumed run.
"""

from __future__ import annotations

import copy
import os
import signal

import numpy as np
import pytest

from rothe.cli.main import main
from rothe.errors import RotheInputError, RunInterrupted
from rothe.fem.adapt import AdaptiveMesh, SpaceAdaptivity, free_transfer
from rothe.io.checkpoint import CheckpointOptions
from rothe.io.trajectory import Trajectory
from rothe.ris.controllers import make_controller
from rothe.ris.examples import example_7_1
from rothe.ris.fem_problem import FERISProblem, example_7_2, example_front, g_7_2
from rothe.ris.inner import InnerOptions
from rothe.ris.stepper import RISState, RISStepper, initial_trajectory, run_ris
from rothe.stepping.evolve import evolve

DIRECT = InnerOptions(linear_solver="direct")


E = r"^rothe: error: "


def run_cli(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def check_step_on_its_mesh(problem, t_prev, z_prev, result):
    """Lemma 4.1 and (3.2) for one accepted step, on the step's mesh (nodal closed forms)."""
    z, lam, tau = result.state.z, result.lam, result.tau
    d = z - z_prev
    assert z.shape == z_prev.shape == (problem.n,)
    nd = problem.norm_V(d)
    assert nd <= tau * (1 + 1e-10)  # the ball
    assert lam >= 0 and lam * abs(nd - tau) <= 1e-8 * max(1.0, lam * tau)  # (4.1)
    # (4.4) with R(v) = sum r_i |v_i|: eta = D_z I(t_prev, z) + lam m d satisfies eta_i =
    # -r_i sign(d_i) where d_i != 0 and |eta_i| <= r_i where d_i = 0
    eta = problem.gradient(t_prev, z) + lam * problem.m * d
    scale = 1e-6 * max(1.0, float(np.max(np.abs(problem.gradient(t_prev, z)))))
    moving = d != 0
    assert np.all(np.abs(eta[moving] + problem.r[moving] * np.sign(d[moving])) <= scale)
    assert np.all(np.abs(eta[~moving]) <= problem.r[~moving] + scale)
    # (3.2) from the transferred z_{k-1}, both energies on this mesh
    before = problem.energy(t_prev, z_prev)
    after = problem.energy(t_prev, z) + problem.dissipation(d)
    assert after <= before + 1e-12 * max(1.0, abs(before))
    assert result.I2 >= -(result.I2_err + 1e-12)  # Lemma 4.12
    assert result.I1 >= -1e-14


@pytest.fixture
def checked_steps(monkeypatch):
    """Wrap RISStepper.record: check every accepted step on the mesh it was computed on (the
    adapt step before the record may have moved the run to another one) and count the meshes
    the steps used."""
    seen = {"steps": 0, "mesh_ids": set()}
    original = RISStepper.record

    def record(self, traj, result, state):
        t_prev, z_prev = self._start
        check_step_on_its_mesh(result.problem, t_prev, z_prev, result)
        seen["steps"] += 1
        if self.space is not None:
            seen["mesh_ids"].add(result.mesh_id)
        return original(self, traj, result, state)

    monkeypatch.setattr(RISStepper, "record", record)
    return seen


def front_options(**kw):
    base = dict(space_tol=2.0, refine_fraction=0.5, coarsen_fraction=0.05, max_dofs=700)
    base.update(kw)
    return SpaceAdaptivity(**base)


@pytest.mark.parametrize("control", ["adaptive", "uniform"])
def test_every_step_of_an_adapted_run_is_kkt_exact_on_its_mesh(checked_steps, control):
    p = example_front(4, T=0.2)
    traj = run_ris(p, control, tol=1e-2, tau=0.05, inner=DIRECT, space=front_options(max_dofs=300))
    assert checked_steps["steps"] == len(traj) > 10
    assert len(checked_steps["mesh_ids"]) >= 3  # the steps ran on several meshes
    ids, dofs = np.asarray(traj["mesh_id"]), np.asarray(traj["n_dofs"])
    assert len(ids) == len(dofs) == len(traj) + 1 and np.all(np.diff(ids) >= 0)
    assert traj.meta["space_adaptations"] == ids[-1] and traj.meta["transfer_failures"] == 0
    # every stored z lives on the mesh it names, every distinct mesh is stored once
    for z, k in zip(traj["z"], traj["z_mesh_id"], strict=True):
        assert z.shape == (len(traj.meshes.mesh(k)[0]),)
    assert traj.meshes.ids == sorted(set(np.asarray(traj["z_mesh_id"]).tolist()))


def test_nested_control_adapts_every_run(checked_steps):
    from rothe.ris.stepper import run_nested

    p = example_front(4, T=0.1)
    runs = run_nested(p, [2e-2, 1e-2], tau=0.05, inner=DIRECT, space=front_options(max_dofs=200))
    assert len(runs) == 2 and all(r.meta["space_adaptations"] >= 1 for r in runs)
    assert checked_steps["steps"] == sum(len(r) for r in runs)


def test_transfer_is_exact_on_refinement():
    """Refining keeps the P1 function: old nodes keep their values, the stiffness energy and
    int z are unchanged to round-off (P1 on the coarse mesh is a subspace of P1 on the fine)."""
    p = example_front(6)
    rng = np.random.default_rng(3)
    z = rng.uniform(-1.0, 1.0, p.n)
    amesh = AdaptiveMesh(p.mesh)
    marked = rng.random(amesh.n_cells) < 0.3
    change = amesh.refine(marked)
    assert change.changed
    q = p.on_mesh(amesh.mesh)
    zn = free_transfer(change.transfer(1), p.free, q.free) @ z
    full_old, full_new = p.full_state(z), q.full_state(zn)
    nv0 = p.n_nodes
    assert np.array_equal(full_new[:nv0], full_old)  # initial vertices keep their numbers
    assert np.isclose(0.5 * zn @ (q.A @ zn), 0.5 * z @ (p.A @ z), rtol=1e-12)
    assert np.isclose(q.integral(zn), p.integral(z), rtol=1e-12)
    # the new nodal values are the old P1 function at the new vertices
    import matplotlib.tri as mtri

    old = mtri.LinearTriInterpolator(mtri.Triangulation(*p.mesh.p, p.mesh.t.T), full_old)
    pts = amesh.points
    assert np.allclose(full_new, old(pts[:, 0], pts[:, 1]).data, rtol=0, atol=1e-13)


def test_nothing_marked_is_the_fixed_mesh_run_bit_for_bit():
    p = example_7_2(5, T=0.4)
    fixed = run_ris(p, "adaptive", tol=1e-3, tau=0.1, inner=DIRECT)
    same = run_ris(
        p,
        "adaptive",
        tol=1e-3,
        tau=0.1,
        inner=DIRECT,
        space=SpaceAdaptivity(space_tol=1e9, coarsen_fraction=1e-300),
    )
    assert same.meta["space_adaptations"] == 0 and len(fixed) == len(same) > 5
    for key in fixed.keys():
        a, b = fixed[key], same[key]
        assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True)), key
    assert np.all(np.asarray(same["mesh_id"]) == 0)
    assert np.all(np.asarray(same["transfer_energy"]) == 0.0)


def test_the_front_example_coarsens_behind_its_front():
    """The refined band follows the front: the dofs rise while it crosses and fall after it
    passed; the final mesh has cells of the initial level where the front was.

    Counted where the front has been and nothing else is (x < 0.75): the boundary layer at the
    Dirichlet side x = 1 is static and stays refined (it is resolved further once the state
    behind the front has arrived there)."""
    p = example_front(4, T=1.0)
    traj = run_ris(
        p,
        "uniform",
        tol=None,
        tau=0.1,
        inner=DIRECT,
        space=front_options(max_dofs=400, space_tol=3.0),
    )
    dofs = np.asarray(traj["n_dofs"])
    peak = int(np.argmax(dofs))
    assert dofs[peak] > 2 * dofs[0]

    def behind(i):  # mesh nodes away from the Dirichlet side
        return int(np.count_nonzero(traj.meshes.mesh(traj["mesh_id"][i])[0][:, 0] < 0.75))

    assert behind(len(dofs) - 1) < 0.7 * behind(peak)  # coarsened after the front passed
    assert np.all(np.asarray(traj["z"][-1]) <= 1e-12)  # the whole square flipped
    points, cells = traj.meshes.mesh(traj["z_mesh_id"][peak])
    last_points, last_cells = traj.meshes.mesh(traj["z_mesh_id"][-1])
    assert len(last_cells) < len(cells)


def test_bad_input_is_refused_with_one_line():
    p = example_7_2(4)
    with pytest.raises(RotheInputError, match=r"^space: got a dict, must be a "):
        run_ris(p, "adaptive", space={"space_tol": 1.0})
    with pytest.raises(RotheInputError, match=r"^space: got a RISProblem problem"):
        run_ris(example_7_1(), "adaptive", space=SpaceAdaptivity(space_tol=1.0))
    nodal = FERISProblem(
        p.mesh,
        g_7_2,
        lambda z: -192 * z * (1 - z * z),
        lambda z: 576 * z * z - 192,
        load=lambda t: -200 * t**3 * p.m_all,
    )
    with pytest.raises(RotheInputError, match=r"^space: got a load given as nodal functionals"):
        run_ris(nodal, "adaptive", space=SpaceAdaptivity(space_tol=1.0))
    with pytest.raises(RotheInputError, match=r"^max_dofs: got 10, must be >= the 25 dofs"):
        run_ris(p, "adaptive", space=SpaceAdaptivity(space_tol=1.0, max_dofs=10))


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--space-tol", "1"], E + r"--space-tol: got 1(\.0)?, is only used with --adapt-space"),
        (
            ["--adapt-space", "--refine-fraction", "1.5"],
            E + r"--refine-fraction: got 1.5, must be in \(0, 1\)",
        ),
        (["--adapt-space", "--space-tol", "0"], E + r"--space-tol: got 0(\.0)?, must be > 0"),
        (["--adapt-space", "--adapt-every", "0"], E + r"--adapt-every: got 0, must be an integ"),
        (
            ["--adapt-space", "--refine-fraction", "0.7", "--coarsen-fraction", "0.4"],
            E + r"--refine-fraction \+ --coarsen-fraction: got 0.7 \+ 0.4 = 1.1, must be <= 1",
        ),
        (["--adapt-space", "--max-dofs", "10"], E + r"--max-dofs: got 10, must be >= the 25 d"),
    ],
)
def test_cli_refuses_bad_space_options(capsys, tmp_path, argv, message):
    code, out, err = run_cli(
        capsys, "run", "ris-front", "--n", "4", "--out", str(tmp_path / "o"), *argv
    )
    assert code == 2 and err.count("\n") == 1, err
    assert __import__("re").match(message, err), err


def test_cli_refuses_a_quadrilateral_mesh(capsys, tmp_path):
    import meshio

    pts = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [2, 0], [2, 1]], dtype=float)
    path = tmp_path / "quads.vtu"
    meshio.write(str(path), meshio.Mesh(pts, [("quad", np.array([[0, 1, 2, 3], [1, 4, 5, 2]]))]))
    capsys.readouterr()  # meshio's warning about 2D points
    code, out, err = run_cli(
        capsys, "run", "ris-2d", "--mesh", str(path), "--adapt-space", "--out", str(tmp_path / "o")
    )
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith("rothe: error: --adapt-space: got a mesh of quadrilaterals"), err


def test_cli_run_writes_meshes_pvd_and_figures(capsys, tmp_path):
    import meshio

    from rothe.io.mesh_series import read_pvd

    out = tmp_path / "front"
    code, stdout, err = run_cli(
        capsys,
        "run",
        "ris-front",
        "--n",
        "4",
        "--adapt-space",
        "--control",
        "uniform",
        "--tau",
        "0.1",
        "--max-dofs",
        "300",
        "--space-tol",
        "3",
        "--out",
        str(out),
        "--quiet",
    )
    assert code == 0, err
    traj = Trajectory.load_npz(out / "trajectory.npz")
    assert traj.meshes is not None and len(traj.meshes) > 1
    assert len(traj["z"]) == len(traj["z_mesh_id"]) == len(traj) + 1
    times, files = read_pvd(out / "solution.pvd")
    assert len(files) == len(traj["z"]) and np.all(np.diff(times) > 0)
    m = meshio.read(files[-1])
    assert np.allclose(m.point_data["z"], traj["z"][-1])
    for name in ("fig_dofs.png", "fig_mesh_snapshots.png", "fig1_path.png"):
        assert (out / name).stat().st_size > 0


def _run_to(stepper, controller, traj, state, S):
    stepper.S = S
    return evolve(stepper, controller, state, traj)


def test_checkpoint_round_trip_continues_bit_for_bit():
    p = example_front(4, T=0.15)
    opts = front_options(max_dofs=250)

    def fresh():
        st = RISStepper(p, DIRECT, space=opts)
        return st, make_controller("adaptive", tol=1e-2, tau=0.05)

    stepper, controller = fresh()
    traj = initial_trajectory(p, {}, stepper.space)
    state = RISState(s=0.0, t=0.0, z=p.z0.copy())
    state = _run_to(stepper, controller, traj, state, 0.4)  # after several mesh changes
    assert stepper.space.mesh_id >= 2
    saved = copy.deepcopy((stepper.checkpoint_state(state), controller.checkpoint_state()))
    a_traj, b_traj = Trajectory(), Trajectory()
    a_traj.set_ragged("z")
    b_traj.set_ragged("z")
    a = _run_to(stepper, controller, a_traj, state, None)
    stepper2, controller2 = fresh()
    state2 = stepper2.restore_state(saved[0])
    controller2.restore_state(saved[1])
    b = _run_to(stepper2, controller2, b_traj, state2, None)
    assert np.array_equal(a.z, b.z) and a.s == b.s and a.t == b.t
    for key in a_traj.keys():
        assert all(np.array_equal(x, y) for x, y in zip(a_traj[key], b_traj[key], strict=True)), key
    assert stepper2.space.mesh_id == stepper.space.mesh_id


def test_interrupted_adaptive_run_resumes_bit_for_bit(tmp_path, monkeypatch):
    p = example_front(4, T=0.15)

    def make_run(**kw):
        return run_ris(
            p, "adaptive", tol=1e-2, tau=0.05, inner=DIRECT, space=front_options(max_dofs=250), **kw
        )

    full = make_run()
    original = RISStepper.step
    calls = [0]

    def step(self, state, tau, s_end=None):
        calls[0] += 1
        if calls[0] in (12, 40):
            os.kill(os.getpid(), signal.SIGINT)
        return original(self, state, tau, s_end)

    monkeypatch.setattr(RISStepper, "step", step)
    ckpt = tmp_path / "c"
    with pytest.raises(RunInterrupted):
        make_run(checkpoint=CheckpointOptions(ckpt, every_seconds=0.01))
    with pytest.raises(RunInterrupted):
        make_run(resume=ckpt)
    resumed = make_run(resume=ckpt)
    assert resumed.meta["sessions"] == 3 and full.meta["space_adaptations"] >= 2
    for key in full.keys():
        assert all(np.array_equal(x, y) for x, y in zip(full[key], resumed[key], strict=True)), key
    assert full.meshes.ids == resumed.meshes.ids
    for k in full.meshes.ids:
        assert all(
            np.array_equal(x, y)
            for x, y in zip(full.meshes.mesh(k), resumed.meshes.mesh(k), strict=True)
        )
    a = full.arrays()
    b = resumed.arrays()
    assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def test_cli_ris_3d_adapts_tetrahedra_under_the_cap(capsys, tmp_path):
    """The 3D command adapts (bisected tetrahedra, coarsening included) and keeps every mesh
    within --max-dofs; the run still ends on T with every step KKT-exact."""
    import json

    out = tmp_path / "cube"
    code, _, err = run_cli(
        capsys,
        "run",
        "ris-3d",
        "--n",
        "3",
        "--adapt-space",
        "--control",
        "uniform",
        "--tau",
        "0.1",
        "--max-dofs",
        "400",
        "--out",
        str(out),
        "--quiet",
        "--no-plots",
    )
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["adapt_space"]["max_dofs"] == 400
    assert summary["n_meshes"] > 2 and abs(summary["t_final"] - 1.0) <= 1e-10
    traj = Trajectory.load_npz(out / "trajectory.npz")
    for mesh_id in set(traj["z_mesh_id"].tolist()):
        points, cells = traj.meshes.mesh(mesh_id)
        assert points.shape[1] == 3 and cells.shape[1] == 4  # tetrahedra
        assert points.shape[0] <= 400
    assert np.all(traj["kkt"] <= traj["kkt_tol"])
    assert np.all(traj["descent"] >= 0.0)


@pytest.mark.parametrize(
    "command, cap", [("ris-2d", 100_000), ("ris-front", 100_000), ("ris-3d", 50_000)]
)
def test_cli_adaptivity_has_a_default_cap_on_the_mesh(capsys, command, cap):
    # Example 7.2's state has kinks that keep the estimate above any --space-tol: uncapped, a
    # 3D run at --n 4 went from 27 to 740 000 unknowns (4.7 GB) before t = 0.64
    import argparse

    from rothe.cli.ris_fem_commands import add_space_options, space_from_args

    parser = argparse.ArgumentParser()
    parser.add_argument("--mesh", default=None)
    add_space_options(parser, 1.0, cap)
    space = space_from_args(parser.parse_args(["--adapt-space"]), 1.0, cap)
    assert space.max_dofs == cap
    assert (
        space_from_args(
            parser.parse_args(["--adapt-space", "--max-dofs", "500"]), 1.0, cap
        ).max_dofs
        == 500
    )
    capsys.readouterr()
    try:
        main(["run", command, "--help"])
    except SystemExit:
        pass
    help_text = " ".join(capsys.readouterr().out.split())
    number = f"{cap:_}".replace("_", " ")
    assert f"--max-dofs MAX_DOFS cap on the nodes of an adapted mesh (default {number}" in help_text
