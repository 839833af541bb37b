"""Issue 10: FE-RIS defects on the command line -- cracks, the XDMF time axis, viscous jumps."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rothe.cli.main import main
from rothe.fem.mesh import load_mesh, unit_square
from rothe.io.xdmf import read_series


def run_cli(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def cracked_square(n: int = 8):
    """unit_square(n) cut along x = 1/2 for 0.3 < y < 0.7: the cells right of the cut use copies
    of the nodes on it (what a mesh glued from two parts without merging looks like)."""
    from skfem import MeshTri

    m = unit_square(n)
    p, t = m.p, m.t.copy()
    cut = np.nonzero(np.isclose(p[0], 0.5) & (p[1] > 0.3) & (p[1] < 0.7))[0]
    right = p[0, t].mean(axis=0) > 0.5
    copy = np.arange(p.shape[1])
    copy[cut] = p.shape[1] + np.arange(cut.size)
    t[:, right] = copy[t[:, right]]
    return MeshTri(np.hstack([p, p[:, cut]]), t), m


def wall(mid):
    on = (mid[0] < 1e-9) | (mid[0] > 1 - 1e-9) | (mid[1] < 1e-9) | (mid[1] > 1 - 1e-9)
    return np.where(on, "wall", "cut")


def test_duplicate_nodes_refused_merged_or_kept(tmp_path, capsys, gmsh_text):
    cracked, plain = cracked_square(4)
    path = gmsh_text.write_msh22(tmp_path / "crack.msh", cracked, wall)
    # accepted before, with another energy (-45.6 instead of -102.3 on this grid, tol 1e-3)
    code, _, err = run_cli(
        capsys, "run", "ris-2d", "--mesh", str(path), "--out", str(tmp_path / "a")
    )
    assert code == 2 and err.strip() == (
        f"rothe: error: --mesh: got '{path}', has 1 pair(s) of coincident nodes used by "
        "different cells (the first at (0.5, 0.5)): the mesh is cut there like a crack; "
        "--duplicate-nodes merge glues them, keep takes the cut as intended"
    )
    energies = {}
    for how, mesh in (("merge", str(path)), ("keep", str(path)), (None, None)):
        out = tmp_path / str(how)
        if how is None:
            argv = ["--n", "4"]
        else:
            argv = ["--mesh", mesh, "--duplicate-nodes", how]
        code, _, err = run_cli(
            capsys,
            "run",
            "ris-2d",
            *argv,
            "--control",
            "uniform",
            "--tau",
            "0.1",
            "--no-plots",
            "--quiet",
            "--out",
            str(out),
        )
        assert code == 0, err
        energies[how] = json.loads((out / "summary.json").read_text())["energy_final"]
    assert energies["merge"] == pytest.approx(energies[None], rel=1e-9)
    assert energies["keep"] > energies[None] + 10  # the cut is a Dirichlet boundary there


def test_load_mesh_merge_gives_the_uncut_mesh(tmp_path, gmsh_text):
    cracked, plain = cracked_square(6)
    path = gmsh_text.write_msh22(tmp_path / "crack.msh", cracked, wall)
    merged = load_mesh(path, duplicate_nodes="merge")
    kept = load_mesh(path, duplicate_nodes="keep")
    assert merged.p.shape == plain.p.shape and kept.p.shape == cracked.p.shape
    # same cells on the same coordinates
    cells = lambda m: {tuple(sorted(map(tuple, np.round(m.p[:, c].T, 12)))) for c in m.t.T}  # noqa: E731
    assert cells(merged) == cells(plain)
    assert merged.boundary_nodes().size == plain.boundary_nodes().size
    assert kept.boundary_nodes().size > plain.boundary_nodes().size  # the cut's faces
    with pytest.raises(ValueError, match=r"^duplicate_nodes: got 'glue', must be one of error, "):
        load_mesh(path, duplicate_nodes="glue")


@pytest.mark.parametrize("axis", ["s", "t"])
def test_xdmf_time_axis(tmp_path, capsys, axis):
    out = tmp_path / axis
    code, _, err = run_cli(
        capsys,
        "run",
        "ris-2d",
        "--n",
        "4",
        "--control",
        "uniform",
        "--tau",
        "0.1",
        "--no-plots",
        "--quiet",
        "--xdmf-time",
        axis,
        "--out",
        str(out),
    )
    assert code == 0, err
    with np.load(out / "trajectory.npz") as f:
        s, t, z = f["s"], f["t"], f["z"]
    _, _, times, data = read_series(out / "solution.xdmf")
    assert np.all(np.diff(times) > 0)  # ParaView's slider needs distinct, increasing times
    if axis == "s":
        assert np.array_equal(times, s) and np.array_equal(data["z"], z)
    else:
        assert len(times) < len(t)  # the jump's states share one t: only its end state is kept
        assert times[-1] == t[-1] and np.array_equal(data["z"][-1], z[-1])
        keep = [int(np.nonzero(t == x)[0][-1]) for x in times]
        assert np.array_equal(data["z"], z[keep])
    text = (out / "solution.xdmf").read_text()
    assert f'Name="{"t" if axis == "s" else "s"}"' in text  # the other axis as Information


def test_disk_mesh_reports_one_viscous_jump(tmp_path, capsys, gmsh_text):
    """The issue's disk (skfem init_circle(4), 545 nodes, Dirichlet on the left half): the t(s)
    figure shows one plateau, the summary said n_viscous_jumps 318 and printed 318 times."""
    from skfem import MeshTri

    path = gmsh_text.write_msh22(
        tmp_path / "disk.msh",
        MeshTri.init_circle(4),
        lambda mid: np.where(mid[0] < 0, "wall", "free"),
    )
    out = tmp_path / "o"
    code, stdout, err = run_cli(
        capsys,
        "run",
        "ris-2d",
        "--mesh",
        str(path),
        "--dirichlet",
        "wall",
        "--no-plots",
        "--out",
        str(out),
    )
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_nodes"] == 545
    assert summary["n_viscous_jumps"] == 1
    assert summary["viscous_jumps"][0]["t"] == pytest.approx(0.1719, abs=1e-3)
    assert summary["catch_up_steps"] > 100  # the single t' = 0 steps, not counted
    branch = next(line for line in stdout.splitlines() if line.strip().startswith("branch"))
    assert "1 viscous jump(s) at t = 0.1719 (+" in branch and len(branch) < 200
