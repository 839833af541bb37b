"""The 3D pulse (rothe.eld.examples.pulse_3d_problem, ``rothe run eld-pulse-3d``): on a coarse
block the adaptive meshes refine on the pressure front and coarsen behind it; the command runs
at a tiny size and writes its outputs; bad input is one line and exit 2."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import numpy as np
import pytest

from rothe.eld import BDF2, run_eld
from rothe.eld.examples import block, pulse_3d_problem
from rothe.fem.adapt import SpaceAdaptivity
from rothe.stepping.controllers import Uniform


def test_block_has_named_faces_and_the_pulse_pushes_its_centre():
    mesh = block(2, 1, 1, length=2.0)
    assert sorted(mesh.boundaries) == ["back", "bottom", "front", "left", "right", "top"]
    assert mesh.t.shape == (4, 2 * 6)
    problem = pulse_3d_problem(2, T=0.1)
    assert problem.name == "eld-pulse-3d" and problem.space.mesh.p.shape[0] == 3
    x = np.array([[0.0, 0.0], [0.5, 0.0], [0.5, 0.0]])
    g = problem.dirichlet["left"].G(0.05, x)  # the peak of s(t) = sin^4(pi t / 0.1)
    assert g[0, 0] == pytest.approx(0.01) and g[0, 1] == pytest.approx(
        0.01 * np.exp(-0.5 / 0.0225), rel=1e-12
    )
    assert np.all(g[1:] == 0.0)


@pytest.fixture(scope="module")
def adaptive_run():
    # P1 at this coarse size (3 s; the P2 default takes minutes here)
    problem = pulse_3d_problem(2, 1, T=0.3)
    space = SpaceAdaptivity(
        space_tol=1.5e-2, refine_fraction=0.5, coarsen_fraction=0.05, max_dofs=3000, adapt_every=1
    )
    return run_eld(problem, control=Uniform(0.02), scheme=BDF2(), keep_every=1, adapt=space)


def _cell_sizes(points, cells):
    X = points[cells]  # (nc, 4, 3)
    vol = np.abs(np.linalg.det(X[:, 1:] - X[:, :1])) / 6.0
    return X.mean(axis=1), vol


def test_adapts_refines_on_the_front_and_coarsens_behind(adaptive_run):
    result = adaptive_run
    traj, sp = result.trajectory, result.meshes
    assert len(sp.series.ids) > 2
    assert sum(a["merges"] for a in sp.adaptations) > 0  # some cells coarsened
    # behind the front: the cells near the pushed spot, refined while it pushes (t <= 0.1),
    # are merged again once the fronts have left it
    near = []
    for m in traj["kept_mesh_id"]:
        points, cells = sp.series.mesh(m)
        mid, _ = _cell_sizes(points, cells)
        near.append(int(np.sum(np.linalg.norm(mid - np.array([0.0, 0.5, 0.5]), axis=1) < 0.2)))
    peak = int(np.argmax(near))
    assert traj["kept_t"][peak] <= 0.12 and near[peak] >= 4 * near[0]
    assert near[-1] <= 0.6 * near[peak], (near, traj["kept_t"].tolist())
    assert np.max(np.abs(traj["balance_residual"])) <= 1e-12 * np.max(traj["energy"])
    # at some time the cells on the pressure front (distance 2 t - 0.2 .. 2 t from the pushed
    # spot (0, 1/2, 1/2)) are smaller on average than the cells away from it
    smaller = []
    for m, t in zip(traj["kept_mesh_id"], traj["kept_t"], strict=True):
        if t < 0.1:
            continue
        points, cells = sp.series.mesh(m)
        mid, vol = _cell_sizes(points, cells)
        r = np.linalg.norm(mid - np.array([0.0, 0.5, 0.5]), axis=1)
        front = (r >= 2 * t - 0.25) & (r <= 2 * t + 0.05)
        if front.any() and (~front).any():
            smaller.append(vol[front].mean() / vol[~front].mean())
    assert smaller and min(smaller) < 0.5, smaller


def test_cli_eld_pulse_3d_writes_its_outputs(tmp_path):
    import meshio

    from rothe.cli.main import main

    out = tmp_path / "p3"
    code = main(
        [
            "run",
            "eld-pulse-3d",
            "--n",
            "1",
            "--T",
            "0.04",
            "--tau",
            "0.02",
            "--keep-every",
            "1",
            "--adapt-every",
            "1",
            "--space-tol",
            "1e-3",
            "--max-dofs",
            "3000",
            "--out",
            str(out),
            "--quiet",
        ]
    )
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["example"] == "eld-pulse-3d" and s["degree"] == 2 and s["status"] == "completed"
    assert s["accepted_steps"] == 2 and s["ndofs_max"] > s["ndofs_initial"]
    assert s["balance_residual_max"] < 1e-12
    data = np.load(out / "trajectory.npz")
    assert len(data["kept_t"]) == 3
    for k in range(3):
        vtu = meshio.read(out / f"pulse-3d_{k:06d}.vtu")
        assert vtu.points.shape[1] == 3 and vtu.cells[0].type == "tetra"
        # issue 18, item 4: the adaptive VTU carries what the fixed-mesh XDMF does -- the Cauchy
        # stress and von Mises on cells and vertices, the multiplier on Gamma_D (x = 0 only)
        nc, nv = len(vtu.cells[0].data), len(vtu.points)
        assert vtu.cell_data["von_mises"][0].shape == (nc,)
        assert vtu.cell_data["stress"][0].shape == (nc, 9)
        assert vtu.point_data["stress_nodal"].shape == (nv, 9)
        assert vtu.point_data["von_mises_nodal"].shape == (nv,)
        lam = vtu.point_data["lambda"]
        assert lam.shape == (nv, 3) and np.all(np.isfinite(lam))
        assert np.array_equal(vtu.point_data["reaction_density"], -lam)
        left = vtu.points[:, 0] == 0.0
        assert not np.any(lam[~left])
        if data["kept_t"][k] > 0:  # the pulse pushes from t = 0 on: a reaction on Gamma_D
            assert np.any(lam[left]) and np.max(vtu.cell_data["von_mises"][0]) > 0
    assert (out / "pulse-3d.pvd").is_file()
    for fig in ("fig_dofs.png", "fig_energy.png", "fig_reaction.png"):  # (fig_mesh: 2D only)
        assert (out / fig).is_file(), fig


@pytest.mark.parametrize(
    "args, message",
    [
        (["--n", "0"], r"--n: got 0, must be an integer >= 1"),
        (["--degree", "3"], r"--degree: got 3, must be 1 or 2"),
        (["--length", "-1"], r"--length: got -1, must be > 0"),
        (["--width", "0"], r"--width: got 0, must be > 0"),
        (["--space-tol", "0"], r"--space-tol: got 0, must be > 0"),
        (["--adapt-every", "0"], r"--adapt-every: got 0, must be an integer"),
        (["--adapt-every", "auto"], r"--adapt-every: got 'auto', must be an integer >= 1$"),
        (["--coarsen-delay", "-1"], r"--coarsen-delay: got -1, must be an integer >= 0$"),
        (["--max-recoarsen", "x"], r"--max-recoarsen: got 'x', must be an integer >= 0$"),
        (["--refine-band", "-1"], r"--refine-band: got -1, must be >= 0 \(a length\)$"),
        (["--coarsen-batch", "1"], r"--coarsen-batch: got 1, must be in \[0, 1\)$"),
        (["--tau", "0.03"], r"--tau: got 0.03"),
        (["--rho", "0"], r"--rho: got 0"),
        (["--n", "400"], r"--n: got 400"),
    ],
)
def test_cli_bad_input_one_line_exit_2(tmp_path, capsys, args, message):
    from rothe.cli.main import main

    code = main(["run", "eld-pulse-3d", "--T", "0.04", "--out", str(tmp_path / "o"), *args])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert re.search(message, err), err


def test_importing_the_eld_family_loads_no_heavy_module_it_does_not_use():
    # the interpreter and imports are a third of the adaptive 3D pulse's peak memory
    # (docs/adaptivity.md): what only frequencies, figures or written files need is imported
    # there (scipy.optimize alone held 10 MB resident)
    code = (
        "import sys, rothe.eld, rothe.eld.examples, rothe.fem.adapt; "
        "print(' '.join(m for m in ('scipy.optimize', 'xml.sax.saxutils', 'urllib.request', "
        "'ssl', 'matplotlib', 'numba', 'h5py', 'meshio', 'dask', 'tqdm', 'skfem', 'pyamg') "
        "if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    assert out.stdout.split() == []


@pytest.mark.parametrize("original", [False, True])
def test_adaptive_p2_run_on_jacobi_cg_equals_the_run_on_amg(monkeypatch, original):
    """The meshes of an adaptive P2 run above 1.5k unknowns are solved by Jacobi-CG (their CFL
    number is below JACOBI_CFL); forcing AMG instead (JACOBI_CFL < 0) gives the same meshes
    (same dofs per step) and the same kept states to the solvers' tolerance (measured
    1.3e-10 / 2.0e-10 relative in u, 1.0e-10 in lambda of the original form; both stop on the
    scaled residual 1e-10), and the ledger closes in both. Regularized and original form
    (whose condensed solve runs Jacobi-CG on A_II)."""
    import rothe.eld.solvers as solvers
    import rothe.eld.system as system_mod
    from rothe.eld import Original, Regularized

    kinds = []
    resolve = system_mod.resolve_kind

    def recorded(*args, **kwargs):
        kinds.append(resolve(*args, **kwargs))
        return kinds[-1]

    monkeypatch.setattr(system_mod, "resolve_kind", recorded)
    runs = {}
    for limit in (solvers.JACOBI_CFL, -1.0):
        monkeypatch.setattr(solvers, "JACOBI_CFL", limit)
        kinds.clear()
        space = SpaceAdaptivity(
            space_tol=0.006,
            refine_fraction=0.5,
            coarsen_fraction=0.05,
            adapt_every=2,
            max_level=9,
        )
        runs[limit] = run_eld(
            pulse_3d_problem(2, T=0.08),
            form=Original() if original else Regularized(),
            control=Uniform(0.02),
            scheme=BDF2(),
            keep_every=1,
            adapt=space,
        )
        iterative = "jacobi" if limit > 0 else "amg"
        assert kinds.count(iterative) >= 3 and set(kinds) == {"direct", iterative}
        assert np.max(np.abs(runs[limit].trajectory["balance_residual"])) <= 1e-15
    jac, amg = runs.values()
    assert np.array_equal(jac.trajectory["step_dofs"], amg.trajectory["step_dofs"])
    assert max(jac.trajectory["step_dofs"]) > 5_000
    for name in ("u", "lam") if original else ("u",):
        for u, w in zip(jac.meshes.kept[name], amg.meshes.kept[name], strict=True):
            assert np.linalg.norm(u - w) <= 1e-8 * max(np.linalg.norm(w), 1e-300)
