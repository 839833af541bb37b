"""``rothe run eld-two-bodies``: the outputs (trajectory with each body's fields and the
interface multiplier, one ParaView series per body, figure, summary), the glue at the shared
nodes, mortar against matching meshes, two mesh files, help texts and one-line refusals."""

from __future__ import annotations

import json

import meshio
import numpy as np
import pytest
from scipy.spatial import cKDTree

from ..conftest import run_cli, write_gmsh_body


def _run(capsys, tmp_path, *args, plots=False):
    out = tmp_path / "out"
    argv = ["run", "eld-two-bodies", "--quiet", "--out", str(out), *args]
    if not plots:
        argv.append("--no-plots")
    code, _, err = run_cli(capsys, *argv)
    return code, out, err


def test_two_bodies_write_each_bodys_fields_the_multiplier_and_paraview(tmp_path, capsys):
    code, out, _ = _run(capsys, tmp_path, "--T", "0.5", "--tau", "0.01", plots=True)
    assert code == 0
    names = {p.name for p in out.iterdir()}
    assert names >= {
        "summary.json",
        "trajectory.npz",
        "fig_two_bodies.png",
        "body1.xdmf",
        "body2.xdmf",
        "body1_multiplier.xdmf",
        "body2_multiplier.xdmf",
    }
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "completed" and s["accepted_steps"] == 50
    assert s["interface_method"] == "matching" and s["ndofs"] == [90, 90]
    # the strip's sizes, no mesh files (mesh1 = mesh2 = null before)
    assert (s["n1"], s["n2"], s["split"]) == (2, 2, 0.5) and "mesh1" not in s
    assert s["material1"]["E"] == 100 and s["material2"]["rho"] == 2.0
    assert s["constraint_max"] < 1e-14
    assert s["balance_max"] < 1e-12 * max(s["energy_final"], s["work_loads"])
    assert s["tip_deflection_max"] > 1e-3
    d = np.load(out / "trajectory.npz")
    assert d["body1_u"].shape == (51, 90) and d["body2_u"].shape == (51, 90)
    lam = d["interface_right_lambda"]
    assert lam.shape == (51, 2 * d["interface_right_points"].shape[0])
    # the glue: equal displacements at the shared nodes, at every state
    x1, x2 = d["body1_doflocs"], d["body2_doflocs"]
    dist, k = cKDTree(x2).query(x1)
    shared = dist < 1e-12
    assert shared.sum() == 5  # P2, 2 cells across: 5 nodes on the interface
    u1 = d["body1_u"].reshape(51, -1, 2)[:, shared]
    u2 = d["body2_u"].reshape(51, -1, 2)[:, k[shared]]
    assert np.abs(u1 - u2).max() < 1e-14 and np.abs(u1).max() > 1e-4
    # the resultant on body 1 is -int lambda ds of the recorded multiplier (a nonzero force)
    assert np.abs(d["reaction_right"]).max() > 1e-3
    # ParaView: body 2's series has its u at the last time
    with meshio.xdmf.TimeSeriesReader(str(out / "body2.xdmf")) as reader:
        points, _ = reader.read_points_cells()
        assert reader.num_steps == 51
        t, point_data, _ = reader.read_data(50)
    assert t == pytest.approx(0.5)
    assert np.abs(point_data["u"][:, :2]).max() == pytest.approx(
        np.abs(d["body2_u"][-1]).max(), rel=1e-12
    )


@pytest.mark.parametrize("extra", [[], ["--scheme", "euler", "--lam2", "50", "--mu2", "80"]])
def test_compare_union_equals_the_single_body_with_two_materials(tmp_path, capsys, extra):
    """--compare-union: the glued run equals the union mesh's single body with per-cell
    materials to solver tolerance (displacements at every node at T, energy at every state)."""
    args = ["--T", "0.5", "--tau", "0.01", "--degree", "1", "--compare-union", *extra]
    code, out, _ = _run(capsys, tmp_path, *args)
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["union_accepted_steps"] == s["accepted_steps"] == 50
    assert s["union_difference_u"] < 1e-8 and s["union_difference_energy"] < 1e-8
    assert s["union_ndofs"] == sum(s["ndofs"]) - 2 * 3  # the 3 interface nodes counted once
    assert s["union_seconds_per_step"] > 0 and s["seconds_per_step_ratio"] > 0


def test_body_2_above_the_former_cap_of_6000_unknowns_runs_and_equals_the_union(tmp_path, capsys):
    """--n1 19: body 2 has 6006 unknowns (refused before: the glue's Jacobian was dense); the
    glued run equals the union body to solver round-off, the glue holds exactly."""
    code, out, err = _run(
        capsys, tmp_path, "--n1", "19", "--T", "0.04", "--tau", "0.01", "--compare-union"
    )
    assert code == 0, err
    s = json.loads((out / "summary.json").read_text())
    assert s["ndofs"] == [6006, 6006] and s["accepted_steps"] == 4
    assert s["union_difference_u"] < 1e-9 and s["union_difference_energy"] < 1e-9
    assert s["constraint_max"] < 1e-14 and s["tip_deflection_max"] > 0


def test_mortar_interface_is_close_to_the_matching_one(tmp_path, capsys):
    tips = {}
    for label, n2 in (("matching", "2"), ("mortar", "3")):
        code, out, _ = _run(capsys, tmp_path, "--T", "0.4", "--tau", "0.02", "--n2", n2)
        assert code == 0
        s = json.loads((out / "summary.json").read_text())
        assert s["interface_method"] == label
        tips[label] = s["tip_deflection_max"]
        assert s["balance_max"] < 1e-12 * s["work_loads"]
    assert abs(tips["mortar"] / tips["matching"] - 1) < 0.05


def test_two_mesh_files_glued_and_apart(tmp_path, capsys):
    one = write_gmsh_body(tmp_path / "one.msh", nx=4, ny=2, length=1.0, height=0.5)
    two = write_gmsh_body(tmp_path / "two.msh", nx=4, ny=2, length=1.0, height=0.5, x0=1.0)
    apart = write_gmsh_body(tmp_path / "apart.msh", nx=4, ny=2, length=1.0, height=0.5, x0=1.5)
    common = ["--interface", "outlet,inlet", "--clamp", "inlet", "--load-part", "outlet"]
    code, out, _ = _run(
        capsys,
        tmp_path,
        "--mesh1",
        one,
        "--mesh2",
        two,
        *common,
        "--degree",
        "1",
        "--T",
        "0.2",
        "--tau",
        "0.02",
    )
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["interface_method"] == "matching" and s["mesh2"] == str(two)
    assert s["mesh1"] == str(one) and "n1" not in s and "split" not in s
    code, _, err = _run(capsys, tmp_path, "--mesh1", one, "--mesh2", apart, *common)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1
    assert lines[0].startswith(
        "rothe: error: --interface: got parts 'outlet' (body 1) and 'inlet' (body 2) that do "
        "not touch: 0 % of 'outlet' lies on 'inlet' (nearest distance 0.5"
    ), lines


def test_two_3d_mesh_files_glued_matching_and_mortar(tmp_path, capsys):
    """3D bodies from gmsh files (refused before: '--mesh1: got a 3D mesh, must be 2D'): two
    boxes glued along x = 0.5, pulsed along z; the glue holds at every state (matching: equal
    displacements at the shared nodes; mortar with body 2 twice as fine across), the ledger
    closes, both bodies in ParaView; a 2D body 2, or z on 2D bodies, is one line."""
    one = write_gmsh_body(tmp_path / "one.msh", dim=3, nx=2, ny=1, length=0.5, height=0.25)
    two = write_gmsh_body(tmp_path / "two.msh", dim=3, nx=2, ny=1, length=0.5, height=0.25, x0=0.5)
    fine = write_gmsh_body(
        tmp_path / "fine.msh", dim=3, nx=2, ny=2, length=0.5, height=0.25, x0=0.5
    )
    flat = write_gmsh_body(tmp_path / "flat.msh", nx=2, ny=1, length=0.5, height=0.25, x0=0.5)
    common = ["--interface", "outlet,inlet", "--clamp", "inlet", "--load-part", "outlet"]
    run = [*common, "--degree", "1", "--T", "0.2", "--tau", "0.02", "--direction", "z"]
    tips = {}
    for label, mesh2 in (("matching", two), ("mortar", fine)):
        code, out, err = _run(capsys, tmp_path, "--mesh1", one, "--mesh2", mesh2, *run)
        assert code == 0, err
        s = json.loads((out / "summary.json").read_text())
        assert s["interface_method"] == label and len(s["interface_reaction_max"]) == 3
        # body 2's material in 3D: the Lamé constants of E = 300, nu = 0.2
        assert s["dim"] == 3 and s["material1"]["plane"] == "strain"
        assert s["material2"]["lam"] == pytest.approx(83.3333333) and s["material2"]["mu"] == 125
        assert s["constraint_max"] < 1e-14 and s["balance_max"] < 1e-12 * s["work_loads"]
        assert {"body1.xdmf", "body2.xdmf"} <= {p.name for p in out.iterdir()}
        tips[label] = s["tip_deflection_max"]
        d = np.load(out / "trajectory.npz")
        if label == "matching":  # the glue: equal displacements at the shared nodes
            dist, k = cKDTree(d["body2_doflocs"]).query(d["body1_doflocs"])
            shared = dist < 1e-12
            assert shared.sum() == 4  # P1, 1 x 1 cubes across: 4 nodes on the interface
            u1 = d["body1_u"].reshape(11, -1, 3)[:, shared]
            u2 = d["body2_u"].reshape(11, -1, 3)[:, k[shared]]
            assert np.abs(u1 - u2).max() < 1e-14 and np.abs(u1[..., 2]).max() > 1e-5
    # (coarse: P1, one cube across body 1; the same motion within half)
    assert abs(tips["mortar"] / tips["matching"] - 1) < 0.5
    for args, line in (
        (
            ["--mesh1", one, "--mesh2", flat],
            "--mesh2: got a 2D mesh, must have body 1's dimension 3",
        ),
        (["--direction", "z"], "--direction: got 'z', needs 3D bodies (--mesh1/--mesh2)"),
        (["--mesh1", one, "--mesh2", two, "--plane", "stress"], "--plane: got 'stress', must be"),
    ):
        code, out, err = _run(capsys, tmp_path, *(common if "--mesh1" in args else []), *args)
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and lines[0].startswith("rothe: error: " + line)


def test_help_states_the_defaults_of_both_bodies(capsys):
    code, out, _ = run_cli(capsys, "run", "eld-two-bodies", "--help")
    text = " ".join(out.split())
    assert code == 0
    for phrase in (
        "Young's modulus E (default 100)",
        "body 2's Young's modulus (default 300)",
        "body 2's density (default 2)",
        "cells across body 2 (default --n1",
        "(default bdf2)",
    ):
        assert phrase in text, phrase


@pytest.mark.parametrize(
    "args, line",
    [
        (["--n2", "0"], "--n2: got 0, must be an integer >= 1"),
        (["--degree2", "3"], "--degree2: got 3, must be 1 or 2"),
        (["--split", "1.5"], "--split: got 1.5, must lie strictly between 0 and --length 1"),
        (["--method", "nitsche"], "--method: got 'nitsche', must be one of auto, matching"),
        (["--direction", "w"], "--direction: got 'w', must be one of x, y, z"),
        (["--interface", "right"], "--interface: got 'right', must be PART1,PART2"),
        (["--interface", "rigth,left"], "--interface: got 'rigth', must be one of bottom, left"),
        (["--interface", "right,lft"], "--interface: got 'lft', must be one of bottom, left"),
        (["--clamp", "middle"], "--clamp: got 'middle', must be one of"),
        (["--load-part", "left"], "--load-part: got 'left', is the glued part"),
        # (before: "--interface: got 'right', also carries prescribed Dirichlet data", naming
        # an option not given)
        (
            ["--clamp", "right"],
            "--clamp: got 'right', is body 1's glued part (--interface right,left); a part is "
            "either clamped or glued",
        ),
        (["--load-part", "back"], "--load-part: got 'back', must be one of"),
        (["--E2", "-5"], "--E2: got -5, must be > 0"),
        (["--E2", "1", "--lam2", "2"], "--E2: got 1, must not be combined with --lam2"),
        (["--nu", "0.6"], "--nu: got 0.6, must satisfy -1 < nu < 0.5"),
        (["--mesh1", "a.msh"], "--mesh2: got None, must be given with the other mesh file"),
        # no fixed cap on body 2 (formerly 6000 unknowns): refused when it cannot fit in memory,
        # before a mesh is built (1.6e11 and 2.9e8 unknowns)
        (["--n2", "100000"], "--n2: got 100000, needs about"),
        (["--n1", "3000"], "--n1: got 3000, needs about"),
        (["--tau", "0.003"], "--tau: got 0.003, must divide T = 2 into equal steps"),
        (
            ["--compare-union", "--n2", "3"],
            "--compare-union: got it with --n2 3, needs the strip with matching meshes",
        ),
    ],
)
def test_bad_options_are_one_line_and_exit_2(tmp_path, capsys, args, line):
    code, out, err = _run(capsys, tmp_path, *args)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("rothe: error: " + line), lines
    assert not (out / "summary.json").exists()


# -- several materials per body: --material1/--region1, --material2/--region2 (issue 19; one
# material per body before) -------------------------------------------------------------------


def _region_bodies(tmp_path):
    """Body 1 on [0, 1] x [0, 0.5], body 2 on [1, 2] x [0, 0.5], each with the cell groups
    'core' (its left half) and 'shell'; the options that glue and load them."""
    one = write_gmsh_body(tmp_path / "one.msh", nx=4, ny=2, length=1.0, height=0.5, split=0.5)
    two = write_gmsh_body(
        tmp_path / "two.msh", nx=4, ny=2, length=1.0, height=0.5, x0=1.0, split=1.5
    )
    return [
        "--mesh1", one, "--mesh2", two, "--interface", "outlet,inlet", "--clamp", "inlet",
        "--load-part", "outlet", "--degree", "1", "--T", "0.2", "--tau", "0.02",
    ]  # fmt: skip


def test_materials_per_body_by_region_equal_the_one_material_run(tmp_path, capsys):
    """--material1/--region1 and --material2/--region2 with each body's default constants on
    its two regions: the same run as the one material per body (q, both bodies' u at every
    state: bit for bit measured); with different constants the run differs, the glue holds and
    the ledger closes; the summary lists each body's materials by region."""
    common = _region_bodies(tmp_path)
    runs = {}
    for label, extra in (
        ("one", []),
        ("equal", ["--material1", "a:E=100,nu=0.3", "--material1", "b:E=100,nu=0.3",
                   "--region1", "a=core", "--region1", "b=shell",
                   "--material2", "c:E=300,nu=0.2,rho=2", "--material2", "d:E=300,nu=0.2,rho=2",
                   "--region2", "c=core", "--region2", "d=shell"]),
        # (without --region2 each material fills the group of its name)
        ("soft", ["--material1", "a:E=100,nu=0.3", "--material1", "b:E=20,nu=0.3,rho=3",
                  "--region1", "a=core", "--region1", "b=shell",
                  "--material2", "core:E=300,nu=0.2", "--material2", "shell:E=30,nu=0.2"]),
    ):  # fmt: skip
        code, out, err = _run(capsys, tmp_path / label, *common, *extra)
        assert code == 0, err
        runs[label] = (
            json.loads((out / "summary.json").read_text()),
            np.load(out / "trajectory.npz"),
        )
    (s1, a), (s2, b) = runs["one"], runs["equal"]
    for key in ("q", "body1_u", "body2_u"):
        scale = np.abs(a[key]).max()
        assert scale > 0 and np.abs(a[key] - b[key]).max() <= 1e-12 * scale, key
    assert s2["material1"]["regions"] == {"core": "a", "shell": "b"}
    assert s2["material2"]["materials"]["c"]["rho"] == 2.0 and s2["material2"]["rho_ref"] == 2.0
    s3, c = runs["soft"]
    assert s3["material2"]["regions"] == {"core": "core", "shell": "shell"}
    assert s3["material2"]["materials"]["shell"]["rho"] == 2.0  # (--rho2's default)
    assert s3["material1"]["materials"]["b"]["rho"] == 3.0
    # softer halves: the load deflects the tip more
    assert s3["tip_deflection_max"] > 1.5 * s1["tip_deflection_max"]
    assert s3["constraint_max"] < 1e-14 and s3["balance_max"] < 1e-12 * s3["work_loads"]


@pytest.mark.parametrize(
    "args, line",
    [
        (["--region1", "a=core"], "--region1: got 'a=core', needs --material1 (the materials it "
         "places)"),
        (["--region2", "a=core", "--material1", "a:E=1,nu=0"],
         "--region2: got 'a=core', needs --material2"),
        (["--material1", "a:E=1,nu=0", "--region1", "a=core,mantle"],
         "--region1: got 'mantle', must be one of the mesh's subdomains: core, shell"),
        (["--material2", "core:E=1,nu=0"],
         "--material2: got 8 of 16 cells in no region with a material (the first at (1.583, "
         "0.1667)), every cell must be in one of the regions core"),
        (["--material1", "a:E=1,nu=0", "--region1", "b=core"],
         "--region1: got 'core' -> 'b', must map each region to one of the materials: a"),
        (["--material1", "core:E=-1,nu=0"], "--material1: got 'core' with E: got -1, must be > 0"),
        (["--material2", "core"],
         "--material2: got 'core', must be NAME:KEY=VALUE,... (keys E, nu, lam, mu, rho)"),
        (["--material1", "a:E=1,nu=0", "--E", "3"],
         "--E: got 3, must not be combined with --material1 (give body 1's constants in each "
         "--material1)"),
        (["--material2", "a:E=1,nu=0", "--nu2", "0.1"],
         "--nu2: got 0.1, must not be combined with --material2"),
    ],
)  # fmt: skip
def test_material_per_body_refusals_are_one_line(tmp_path, capsys, args, line):
    code, out, err = _run(capsys, tmp_path, *_region_bodies(tmp_path), *args)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("rothe: error: " + line), lines
    assert not (out / "summary.json").exists()


def test_material_per_body_needs_its_mesh_file(tmp_path, capsys):
    code, out, err = _run(capsys, tmp_path, "--material1", "a:E=1,nu=0")
    assert code == 2 and err.strip().splitlines() == [
        "rothe: error: --material1: got 'a:E=1,nu=0', is used with --mesh1 only (its regions "
        "are the mesh file's physical groups)"
    ]
    assert not out.exists()
