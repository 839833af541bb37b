"""One convention for the material on every ``rothe run eld-*`` command: ``--E/--nu`` or
``--lam/--mu`` (one pair, the command's default pair where none is given), ``--rho``, and
``--plane strain|stress`` on the 2D commands; mixing the pairs is one line naming both."""

from __future__ import annotations

import json

import meshio
import numpy as np
import pytest
from skfem import MeshTri

from rothe.cli import registry

from ..conftest import is_timing_array, run_cli, write_gmsh_body

registry.load_all()
#: every ``rothe run eld-*`` command (issue 19: "accept both, documented" on every command; the
#: list was eld-mms, eld-pulse, eld-beam, eld-tip-mass before -- the others took both pairs too,
#: untested)
RUNS = tuple(sorted(name for name in registry.commands("run") if name.startswith("eld-")))
#: the 3D commands: no --plane
RUNS_3D = ("eld-beam", "eld-pulse-3d")


def test_the_material_convention_covers_the_coupled_and_3d_commands():
    assert set(RUNS) >= {
        "eld-mms", "eld-pulse", "eld-pulse-3d", "eld-beam",
        "eld-tip-mass", "eld-tmd", "eld-control", "eld-two-bodies",
    }  # fmt: skip


@pytest.mark.parametrize("command", RUNS)
def test_every_eld_run_takes_both_pairs_and_refuses_mixing_them(tmp_path, capsys, command):
    out = tmp_path / "out"
    code, _, err = run_cli(capsys, "run", command, "--E", "5", "--mu", "1", "--out", out)
    assert code == 2 and err.strip().splitlines() == [
        "rothe: error: --E: got 5, must not be combined with --mu: give --E, --nu or --lam, --mu"
    ]
    assert not out.exists()
    code, _, err = run_cli(capsys, "run", command, "--lam", "1", "--nu", "0.2", "--out", out)
    assert code == 2 and err.strip() == (
        "rothe: error: --nu: got 0.2, must not be combined with --lam: "
        "give --E, --nu or --lam, --mu"
    )
    code, help_text, _ = run_cli(capsys, "run", command, "--help")
    text = " ".join(help_text.split())
    assert code == 0 and all(f"--{k} {k.upper()}" in text for k in ("E", "nu", "lam", "mu", "rho"))
    assert ("--plane PLANE" in text) == (command not in RUNS_3D)  # 2D commands only
    # several materials by region on a mesh file: every command (eld-mms lists it and refuses it
    # in one line); eld-two-bodies per body (issue 19; one material per body before)
    bodies = ("1", "2") if command == "eld-two-bodies" else ("",)
    for k in bodies:
        assert f"--material{k} NAME:KEY=VALUE,..." in text, k
        assert f"--region{k} NAME=GROUP[,GROUP]" in text, k


@pytest.mark.parametrize(
    "argv, line",
    [
        (["eld-pulse", "--plane", "shell"], "--plane: got 'shell', must be one of strain, stress"),
        (
            ["eld-beam", "--lam", "-400"],
            "--lam: got -400, must be > -2 mu / d = -256.41 (positive bulk modulus)",
        ),
        (["eld-tip-mass", "--E", "0"], "--E: got 0, must be > 0"),
        (["eld-mms", "--nu", "0.5"], "--nu: got 0.5, must satisfy -1 < nu < 0.5"),
        (
            ["eld-tip-mass", "--plane", "stress", "--lam", "-40"],
            "--lam: got -40, must be > -2 mu / 3 = -33.3333 for plane stress "
            "(an admissible 3D material)",
        ),
    ],
)
def test_bad_material_values_name_the_option(tmp_path, capsys, argv, line):
    code, _, err = run_cli(capsys, "run", *argv, "--out", tmp_path / "out")
    assert code == 2 and err.strip().splitlines() == ["rothe: error: " + line]


def _tip_mass(capsys, out, *args):
    code, _, _ = run_cli(
        capsys, "run", "eld-tip-mass", "--T", "0.2", "--tau", "0.01", "--quiet", "--no-plots",
        "--out", out, *args,
    )  # fmt: skip
    assert code == 0
    return json.loads((out / "summary.json").read_text()), np.load(out / "trajectory.npz")


def test_the_same_material_by_either_pair_gives_the_same_run(tmp_path, capsys):
    """eld-tip-mass's default E = 100, nu = 0 is lam = 0, mu = 50 exactly: the run with
    --lam 0 --mu 50 is the default run bit for bit; the summary states both pairs."""
    s0, d0 = _tip_mass(capsys, tmp_path / "young")
    s1, d1 = _tip_mass(capsys, tmp_path / "lame", "--lam", "0", "--mu", "50")
    assert all(np.array_equal(d0[k], d1[k]) for k in d0.files if not is_timing_array(k))
    for s in (s0, s1):
        assert (s["E"], s["nu"], s["lam"], s["mu"], s["plane"]) == (100, 0, 0, 50, "stress")
    assert s0["frequency_analytic"] == s1["frequency_analytic"]


def test_plane_strain_on_the_tip_mass_bar_takes_the_strip_modulus(tmp_path, capsys):
    """In plane strain the free strip's axial modulus is E/(1 - nu^2): the analytic frequency
    with --plane strain --nu 0.3 is that of --E 100/0.91 in plane stress, and the discrete
    coupled system agrees with it to Poisson's lateral inertia."""
    strain, _ = _tip_mass(capsys, tmp_path / "a", "--plane", "strain", "--nu", "0.3")
    stress, _ = _tip_mass(capsys, tmp_path / "b", "--E", str(100 / 0.91))
    assert strain["frequency_analytic"][0] == pytest.approx(stress["frequency_analytic"][0], 1e-12)
    # 0.7 % (the lateral inertia of Poisson's contraction); with E instead of E/(1 - nu^2):
    # 4.8 %
    assert abs(strain["frequency_error_discrete"][0]) < 1e-2
    assert strain["plane"] == "strain" and strain["nu"] == 0.3


def test_mms_in_plane_stress_stays_exact_in_space(tmp_path, capsys):
    """The manufactured body force, traction and multiplier follow the model's lam*: in plane
    stress (lam* = 2 lam mu/(lam + 2 mu) = 1 for lam = 2, mu = 1) P2 is still exact in space,
    the errors are the time discretization's, as in plane strain (with lam instead of lam*
    the data would not fit the solution: 9.4e-2 instead of 3.6e-4 here)."""
    errors = {}
    for plane in ("strain", "stress"):
        out = tmp_path / plane
        code, _, _ = run_cli(
            capsys, "run", "eld-mms", "--n", "2", "--scheme", "bdf2", "--tau", "0.01", "--T",
            "0.2", "--plane", plane, "--quiet", "--no-plots", "--out", out,
        )  # fmt: skip
        assert code == 0
        s = json.loads((out / "summary.json").read_text())
        errors[plane] = s["error_u_l2"]
        assert s["material"]["plane"] == plane
    assert errors["stress"] < 3 * errors["strain"] and errors["stress"] < 1e-3


# -- --mesh FILE: parts and material regions by gmsh physical-group name -------------------------


def _summary(out):
    return json.loads((out / "summary.json").read_text())


def test_pulse_on_a_gmsh_file_of_the_rectangle_is_the_built_in_run(tmp_path, capsys):
    """The built-in rectangle written as a gmsh file (meshio) with its left side as the physical
    group 'inlet': the same run, the reaction and energies to round-off."""
    mesh = write_gmsh_body(tmp_path / "rect.msh", nx=8, ny=4)
    common = ("--T", "0.1", "--tau", "0.01", "--no-adapt-space", "--quiet", "--no-plots")
    code, _, _ = run_cli(capsys, "run", "eld-pulse", "--out", tmp_path / "grid", *common)
    assert code == 0
    code, _, err = run_cli(
        capsys, "run", "eld-pulse", "--mesh", mesh, "--dirichlet", "inlet", "--out",
        tmp_path / "file", *common,
    )  # fmt: skip
    assert code == 0, err
    a, b = (
        np.load(tmp_path / "grid" / "trajectory.npz"),
        np.load(tmp_path / "file" / "trajectory.npz"),
    )
    scale = np.abs(a["reaction_left"]).max()
    assert scale > 0 and np.abs(a["reaction_left"] - b["reaction_inlet"]).max() < 1e-10 * scale
    assert np.allclose(a["energy"], b["energy"], rtol=1e-10, atol=1e-14)
    s = _summary(tmp_path / "file")
    assert (s["mesh_cells"], s["dim"], s["dirichlet"]) == (64, 2, ["inlet"])


def test_pulse_with_two_materials_by_region_and_a_held_part(tmp_path, capsys):
    """Two materials on the gmsh cell groups 'core' (x < 1) and 'shell': in the soft, heavy
    shell (wave speeds 0.3 and 0.17 instead of 2 and 1) the pulse reaches the held far side
    'outlet' later and weaker than in the one-material run; the ledger closes."""
    mesh = write_gmsh_body(tmp_path / "two.msh", nx=8, ny=4, split=1.0)
    common = (
        "run", "eld-pulse", "--mesh", mesh, "--dirichlet", "inlet,outlet", "--T", "0.6",
        "--tau", "0.02", "--no-adapt-space", "--quiet", "--no-plots",
    )  # fmt: skip
    code, _, err = run_cli(
        capsys, *common, "--material", "hard:lam=2,mu=1", "--material", "soft:E=0.3,nu=0.25,rho=4",
        "--region", "hard=core", "--region", "soft=shell", "--out", tmp_path / "two",
    )  # fmt: skip
    assert code == 0, err
    s = _summary(tmp_path / "two")
    assert s["material"]["regions"] == {"core": "hard", "shell": "soft"}
    assert s["material"]["materials"]["soft"]["rho"] == 4.0 and s["material"]["rho_ref"] == 4.0
    assert s["balance_residual_max"] < 1e-10 * s["energy_final"]
    d = np.load(tmp_path / "two" / "trajectory.npz")
    assert np.abs(d["reaction_outlet"]).max() > 0  # the held far side feels the wave
    code, _, _ = run_cli(capsys, *common, "--out", tmp_path / "one")
    one = np.load(tmp_path / "one" / "trajectory.npz")
    # the far side's reaction (0.3 of the one-material run's here)
    assert np.abs(d["reaction_outlet"]).max() < 0.5 * np.abs(one["reaction_outlet"]).max()


def test_pulse_on_a_3d_gmsh_body_with_space_adaptivity(tmp_path, capsys):
    mesh = write_gmsh_body(tmp_path / "box.msh", dim=3, nx=4, ny=2, length=2.0, height=1.0)
    code, _, err = run_cli(
        capsys, "run", "eld-pulse", "--mesh", mesh, "--dirichlet", "inlet", "--degree", "1",
        "--T", "0.06", "--tau", "0.02", "--width", "0.4", "--space-tol", "1e-4", "--max-dofs",
        "3000", "--adapt-every", "1", "--quiet", "--no-plots", "--out", tmp_path / "box",
    )  # fmt: skip
    assert code == 0, err
    s = _summary(tmp_path / "box")
    assert s["dim"] == 3 and s["adaptations"] >= 1 and s["ndofs_max"] > s["ndofs_initial"]
    assert len(s["reaction_inlet_final"]) == 3 and s["material"]["plane"] == "strain"


def test_tip_mass_on_a_3d_gmsh_bar_against_the_bar_equation(tmp_path, capsys):
    """A 3D P2 bar (nu = 0) read from a gmsh file, clamped on 'inlet', the mass on 'outlet':
    its discrete axial frequencies against beta L tan(beta L) = rho A L / m with L and A of the
    mesh."""
    mesh = write_gmsh_body(tmp_path / "bar.msh", dim=3, nx=4, ny=1, length=1.0, height=0.25)
    code, _, err = run_cli(
        capsys, "run", "eld-tip-mass", "--mesh", mesh, "--dirichlet", "inlet", "--tip", "outlet",
        "--T", "0.2", "--tau", "0.01", "--quiet", "--no-plots", "--out", tmp_path / "bar",
    )  # fmt: skip
    assert code == 0, err
    s = _summary(tmp_path / "bar")
    assert s["dim"] == 3 and s["length"] == 1.0 and s["area"] == pytest.approx(0.0625)
    assert s["frequency_analytic"][0] == pytest.approx(4.80094, rel=1e-5)
    assert abs(s["frequency_error_discrete"][0]) < 1e-6
    assert s["balance_max"] < 1e-12 * s["energy_initial"]


def _grid_and_file_runs(tmp_path, capsys, command, grid_args, file_args, common):
    """The command on its built-in grid and on a gmsh file of it: the two trajectories."""
    code, _, err = run_cli(capsys, "run", command, *grid_args, *common, "--out", tmp_path / "grid")
    assert code == 0, err
    code, _, err = run_cli(capsys, "run", command, *file_args, *common, "--out", tmp_path / "file")
    assert code == 0, err
    return (np.load(tmp_path / "grid" / "trajectory.npz"),
            np.load(tmp_path / "file" / "trajectory.npz"))  # fmt: skip


def _assert_same_u_and_reaction(a, b):
    """u at every kept state and the reaction of the held part (the grid's ``left``, the
    file's ``inlet``) equal to 1e-12 of their largest values, which are not zero."""
    scale = np.abs(a["u"][-1]).max()
    assert scale > 0 and np.abs(a["u"] - b["u"]).max() < 1e-12 * scale
    scale = np.abs(a["reaction_left"]).max()
    assert scale > 0 and np.abs(a["reaction_left"] - b["reaction_inlet"]).max() < 1e-12 * scale


def test_beam_on_a_gmsh_file_of_the_box_is_the_built_in_run(tmp_path, capsys):
    """eld-beam's box 4 x 1 x 1 (n = 1, P1) written as a gmsh file with its end x = 0 as the
    physical group 'inlet' (--dirichlet inlet, moved along z): u at every kept state, the
    reaction and the energy equal the built-in run's (measured: bit for bit)."""
    mesh = write_gmsh_body(tmp_path / "beam.msh", dim=3, nx=4, ny=1, length=4.0, height=1.0)
    common = ("--T", "0.2", "--tau", "0.02", "--degree", "1", "--quiet", "--no-plots")
    a, b = _grid_and_file_runs(
        tmp_path, capsys, "eld-beam", ("--n", "1"), ("--mesh", mesh, "--dirichlet", "inlet"),
        common,
    )  # fmt: skip
    _assert_same_u_and_reaction(a, b)
    assert np.allclose(a["energy"], b["energy"], rtol=1e-12, atol=1e-15)
    s = _summary(tmp_path / "file")
    assert (s["mesh_cells"], s["dim"], s["dirichlet"]) == (24, 3, ["inlet"])
    assert len(s["reaction_inlet_max_abs"]) == 3 and "n" not in s
    # the terminal summary names the part's reactions; the coarse-mesh note a finer mesh
    code, out, _ = run_cli(
        capsys, "run", "eld-beam", "--mesh", mesh, "--dirichlet", "inlet", "--T", "0.1",
        "--tau", "0.02", "--degree", "1", "--no-plots", "--out", tmp_path / "printed",
    )  # fmt: skip
    assert code == 0 and "reaction_inlet_max_abs" in out
    assert "use --degree 2 or a finer --mesh" in out


def test_pulse_3d_on_a_gmsh_file_of_the_block_is_the_built_in_run(tmp_path, capsys):
    """eld-pulse-3d's block (n = 2, P1, fixed mesh) written as a gmsh file with its face x = 0
    as 'inlet': the pulse on the first --dirichlet part along its mean inward normal around its
    centre is the built-in e_x at (0, 1/2, 1/2): u, the reaction and the energy bit for bit."""
    mesh = write_gmsh_body(tmp_path / "block.msh", dim=3, nx=2, ny=2, length=1.0, height=1.0)
    common = ("--T", "0.06", "--tau", "0.02", "--degree", "1", "--no-adapt-space", "--quiet",
              "--no-plots")  # fmt: skip
    a, b = _grid_and_file_runs(
        tmp_path, capsys, "eld-pulse-3d", ("--n", "2"), ("--mesh", mesh, "--dirichlet", "inlet"),
        common,
    )  # fmt: skip
    _assert_same_u_and_reaction(a, b)
    assert np.allclose(a["energy"], b["energy"], rtol=1e-12, atol=1e-15)
    s = _summary(tmp_path / "file")
    assert (s["mesh_cells"], s["dim"], s["dirichlet"]) == (48, 3, ["inlet"]) and "n" not in s


def test_mms_on_a_gmsh_file_of_the_square_is_the_built_in_run(tmp_path, capsys):
    """eld-mms on the unit square (n = 4, P1) written as a gmsh file: --dirichlet inlet is the
    built-in --dirichlet left bit for bit (u, the reaction, the errors against the exact
    solution); without --dirichlet every physical group of the boundary is held, the built-in
    run held on all four sides."""
    mesh = write_gmsh_body(tmp_path / "square.msh", nx=4, ny=4, length=1.0, height=1.0)
    common = ("--T", "0.1", "--tau", "0.02", "--degree", "1", "--quiet", "--no-plots")
    a, b = _grid_and_file_runs(
        tmp_path, capsys, "eld-mms", ("--n", "4"), ("--mesh", mesh, "--dirichlet", "inlet"),
        common,
    )  # fmt: skip
    _assert_same_u_and_reaction(a, b)
    grid, file = _summary(tmp_path / "grid"), _summary(tmp_path / "file")
    for key in ("error_u_l2", "error_v_l2", "error_lam_l2"):
        assert file[key] == pytest.approx(grid[key], rel=1e-12), key
    assert (file["mesh_cells"], file["dim"], file["dirichlet"]) == (32, 2, ["inlet"])
    for out, args in (
        ("all", ("--mesh", mesh)),
        ("sides", ("--n", "4", "--dirichlet", "left,right,top,bottom")),
    ):
        code, _, err = run_cli(capsys, "run", "eld-mms", *args, *common, "--out", tmp_path / out)
        assert code == 0, err
    every, sides = _summary(tmp_path / "all"), _summary(tmp_path / "sides")
    assert every["dirichlet"] == ["inlet", "outlet", "wall"]
    assert every["error_u_l2"] == pytest.approx(sides["error_u_l2"], rel=1e-10)
    assert every["error_lam_l2"] == pytest.approx(sides["error_lam_l2"], rel=1e-10)


def test_mms_refuses_a_mesh_with_unnamed_boundary_facets(tmp_path, capsys):
    """A boundary facet in no physical group would be traction-free, not the manufactured
    solution's: one line naming --mesh, the count and the first facet."""
    path = write_gmsh_body(tmp_path / "square.msh", nx=4, ny=4, length=1.0, height=1.0)
    m = meshio.read(path)
    tags = m.cell_data["gmsh:physical"]
    named = tags[0] != 3  # (drop the group 'wall': top and bottom)
    meshio.Mesh(
        m.points,
        [(m.cells[0].type, m.cells[0].data[named]), (m.cells[1].type, m.cells[1].data)],
        cell_data={"gmsh:physical": [tags[0][named], tags[1]],
                   "gmsh:geometrical": [tags[0][named], tags[1]]},
        field_data={k: v for k, v in m.field_data.items() if k != "wall"},
    ).write(tmp_path / "open.msh", file_format="gmsh22", binary=False)  # fmt: skip
    code, _, err = run_cli(
        capsys, "run", "eld-mms", "--mesh", tmp_path / "open.msh", "--out", tmp_path / "out"
    )
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert lines[0] == (
        "rothe: error: --mesh: got 8 boundary facets in no named part (the first at (0.125, 0)), "
        "must put every boundary facet in a physical group (the exact data or traction goes on "
        "each part)"
    )


def _write_l_body(path):
    """The L-shaped body [0, 1]^2 minus [0.5, 1]^2 of 8 x 8 squares' triangles as a gmsh file:
    the facets 'inlet' (x = 0), 'ends' (x = 1 and y = 1 with x > 1/8: their centroid (0.705,
    0.571) lies in the cut-out square) and 'wall'; the cells 'core'."""
    m = MeshTri.init_tensor(np.linspace(0, 1, 9), np.linspace(0, 1, 9))
    c = m.p[:, m.t].mean(axis=1)
    m = MeshTri(m.p, m.t[:, ~((c[0] > 0.5) & (c[1] > 0.5))])
    facets = m.facets[:, m.boundary_facets()]
    mid = m.p[:, facets].mean(axis=1)
    ends = np.isclose(mid[0], 1) | (np.isclose(mid[1], 1) & (mid[0] > 0.125))
    tags = np.where(np.isclose(mid[0], 0), 1, np.where(ends, 2, 3))
    cells = np.full(m.t.shape[1], 4)
    groups = {"inlet": [1, 1], "ends": [2, 1], "wall": [3, 1], "core": [4, 2]}
    meshio.Mesh(
        m.p.T,
        [("line", facets.T), ("triangle", m.t.T)],
        cell_data={"gmsh:physical": [tags, cells], "gmsh:geometrical": [tags, cells]},
        field_data={k: np.array(v) for k, v in groups.items()},
    ).write(path, file_format="gmsh22", binary=False)
    return path


@pytest.mark.parametrize(
    "command, args, line",
    [
        ("eld-pulse", ["--mesh", "{dir}/none.msh"], "--mesh: got '{dir}/none.msh', no such file"),
        ("eld-pulse", ["--mesh", "{two}"],
         "--dirichlet: got 'left', must be one of inlet, outlet, wall"),
        ("eld-tip-mass", ["--mesh", "{two}", "--dirichlet", "inlet", "--tip", "top"],
         "--tip: got 'top', must be one of inlet, outlet, wall (boundary parts of the mesh)"),
        ("eld-pulse", ["--mesh", "{two}", "--dirichlet", "inlet", "--material", "a:E=1,nu=0",
                       "--region", "a=core,mantle", "--no-adapt-space"],
         "--region: got 'mantle', must be one of the mesh's subdomains: core, shell"),
        ("eld-pulse", ["--mesh", "{two}", "--dirichlet", "inlet", "--material", "core:E=1,nu=0",
                       "--no-adapt-space"],
         "--material: got 32 of 64 cells in no region with a material "
         "(the first at (1.083, 0.1667))"),
        ("eld-pulse", ["--mesh", "{two}", "--dirichlet", "inlet", "--material", "a:E=1,nu=0",
                       "--region", "b=core"],
         "--region: got 'core' -> 'b', must map each region to one of the materials: a"),
        ("eld-pulse", ["--mesh", "{two}", "--material", "core:E=-1,nu=0"],
         "--material: got 'core' with E: got -1, must be > 0"),
        ("eld-pulse", ["--mesh", "{two}", "--material", "core:E=one"],
         "--material: got 'core:E=one', must give numbers (E='one')"),
        ("eld-pulse", ["--mesh", "{two}", "--material", "core"],
         "--material: got 'core', must be NAME:KEY=VALUE,... (keys E, nu, lam, mu, rho)"),
        ("eld-pulse", ["--mesh", "{two}", "--material", "core:E=1,nu=0", "--mu", "2"],
         "--mu: got 2, must not be combined with --material"),
        ("eld-pulse", ["--material", "core:E=1,nu=0"],
         "--material: got 'core:E=1,nu=0', is used with --mesh only"),
        ("eld-tip-mass", ["--mesh", "{two}", "--height", "0.5"],
         "--height: got 0.5, cannot be combined with --mesh (the mesh fixes the body)"),
        ("eld-pulse", ["--mesh", "{box}", "--dirichlet", "inlet", "--plane", "stress"],
         "--plane: got 'stress', must be 'strain' (the default) in 3D"),
        ("eld-beam", ["--mesh", "{two}", "--dirichlet", "inlet"],
         "--mesh: got a 2D mesh (45 nodes, 64 triangles), must be 3D (tetrahedra: the held end "
         "moves along z)"),
        ("eld-beam", ["--mesh", "{box}"],
         "--dirichlet: got 'left', must be one of inlet, outlet, wall (boundary parts of the "
         "mesh)"),
        ("eld-beam", ["--mesh", "{box}", "--length", "2"],
         "--length: got 2, cannot be combined with --mesh (the mesh fixes the body)"),
        ("eld-beam", ["--mesh", "{box}", "--dirichlet", "inlet", "--backend", "petsc"],
         "--mesh: got '{box}', is not supported with --backend petsc (the distributed beam "
         "builds its own box)"),
        ("eld-pulse-3d", ["--mesh", "{two}", "--dirichlet", "inlet"],
         "--mesh: got a 2D mesh (45 nodes, 64 triangles), must be 3D (tetrahedra; the 2D pulse "
         "is eld-pulse)"),
        ("eld-pulse-3d", ["--mesh", "{box}"],
         "--dirichlet: got 'left', must be one of inlet, outlet, wall"),
        ("eld-pulse-3d", ["--mesh", "{box}", "--n", "3"],
         "--n: got 3, cannot be combined with --mesh (the mesh fixes the body)"),
        ("eld-pulse-3d", ["--mesh", "{box}", "--dirichlet", "inlet", "--material", "a:E=1,nu=0",
                          "--region", "a=core,mantle", "--no-adapt-space"],
         "--region: got 'mantle', must be one of the mesh's subdomains: core"),
        ("eld-mms", ["--mesh", "{box}"],
         "--mesh: got a 3D mesh (12 nodes, 12 tetrahedra), must be 2D (triangles: the "
         "manufactured solution is plane)"),
        ("eld-mms", ["--mesh", "{two}", "--dirichlet", "left"],
         "--dirichlet: got 'left', must be one of inlet, outlet, wall"),
        ("eld-mms", ["--mesh", "{two}", "--n", "4"],
         "--n: got 4, cannot be combined with --mesh (the mesh fixes the body)"),
        ("eld-mms", ["--mesh", "{two}", "--material", "a:E=1,nu=0"],
         "--material: got 'a', must be one of the mesh's subdomains: core, shell"),
        ("eld-beam", ["--dirichlet", ","],
         "--dirichlet: got ',', must name at least one boundary part"),
        # issue 19's bad input on the command line (docs/coupling.md Sec. 18): eld-beam named
        # the API's 'materials' and 'regions' (it had no table of its parameters)
        ("eld-beam", ["--mesh", "{box2}", "--dirichlet", "inlet", "--material", "a:E=1,nu=0",
                      "--region", "a=core"],
         "--material: got 6 of 12 cells in no region with a material (the first at "),
        ("eld-beam", ["--mesh", "{box}", "--dirichlet", "inlet", "--material", "a:E=1,nu=0",
                      "--region", "a=mantle"],
         "--region: got 'mantle', must be one of the mesh's subdomains: core"),
        # a material without --region fills the cell group of its name: --region was named
        # although not given
        ("eld-pulse", ["--mesh", "{two}", "--dirichlet", "inlet", "--material", "steel:E=1,nu=0",
                       "--no-adapt-space"],
         "--material: got 'steel', must be one of the mesh's subdomains: core, shell (a material "
         "without a region fills the cell group of its name)"),
        ("eld-beam", ["--mesh", "{box}", "--dirichlet", "inlet", "--material", "a:E=1,nu=0"],
         "--material: got 'a', must be one of the mesh's subdomains: core (a material without a "
         "region fills the cell group of its name)"),
        # eld-tmd's couplings named couplings[0].part (the base) and couplings[1].part (the tip)
        ("eld-tmd", ["--mesh", "{two}", "--base", "inlet", "--tip", "wall"],
         "--base: got 'inlet', shares 2 node(s) with the constrained part 'wall'; coupled parts "
         "must not touch other constrained parts"),
        ("eld-tmd", ["--mesh", "{two}", "--base", "inlet", "--tip", "inlet"],
         "--tip: got 'inlet', must not be the base's part (the base and the tip are two ends)"),
        # the sensor at the centroid of an L-shaped body's two ends, in no cell: it named the
        # API's controllers[0].sensors[0].point
        ("eld-control", ["--mesh", "{ell}", "--base", "inlet", "--tip", "ends"],
         "--tip: got 'ends', has its centroid (0.7054, 0.5714) outside the body, where the "
         "sensor of v_L would sit; must be a part whose centroid lies in the body (e.g. a "
         "straight end)"),
    ],
)  # fmt: skip
def test_bad_mesh_input_is_one_line_and_exit_2(tmp_path, capsys, command, args, line):
    files = {
        "dir": tmp_path,
        "two": write_gmsh_body(tmp_path / "two.msh", nx=8, ny=4, split=1.0),
        "box": write_gmsh_body(tmp_path / "box.msh", dim=3, nx=2, ny=1),
        "box2": write_gmsh_body(tmp_path / "box2.msh", dim=3, nx=2, ny=1, split=1.0),
        "ell": _write_l_body(tmp_path / "ell.msh"),
    }
    argv = [a.format(**files) for a in args]
    code, _, err = run_cli(capsys, "run", command, *argv, "--out", tmp_path / "out")
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert lines[0].startswith("rothe: error: " + line.format(**files)), lines[0]
    assert not (tmp_path / "out" / "summary.json").exists()


def test_a_body_of_two_materials_adapts_its_mesh(tmp_path, capsys):
    """Refused before (the space indicator took one material): the regions are carried to the
    refined cells and the indicator takes per-cell constants (tests/eld/
    test_indicator_materials.py), so eld-pulse adapts a two-material gmsh body by default."""
    two = write_gmsh_body(tmp_path / "two.msh", nx=8, ny=4, split=1.0)
    code, _, err = run_cli(
        capsys, "run", "eld-pulse", "--mesh", two, "--dirichlet", "inlet",
        "--material", "core:E=1,nu=0", "--material", "shell:E=2,nu=0", "--out", tmp_path / "out",
    )  # fmt: skip
    assert code == 0, err
    s = json.loads((tmp_path / "out" / "summary.json").read_text())
    data = np.load(tmp_path / "out" / "trajectory.npz")
    assert len(np.unique(data["mesh_id"])) >= 3
    assert s["balance_residual_max"] < 1e-10


# -- the summary's material: one helper (summary_material) for every run eld-* -------------------

_SHORT = ("--T", "0.02", "--tau", "0.01", "--quiet", "--no-plots")
_LAME = {"E": 93.33333333333333, "nu": 0.16666666666666666, "lam": 20.0, "mu": 40.0}


@pytest.mark.parametrize(
    "argv, expected",
    [
        (
            ["eld-beam", "--n", "1", "--degree", "1", "--lam", "500", "--mu", "300"],
            {
                "E": 787.5,
                "nu": 0.3125,
                "material": {"E": 787.5, "nu": 0.3125, "lam": 500.0, "mu": 300.0, "rho": 1.0,
                             "plane": "strain"},
            },
        ),
        (
            ["eld-mms", "--n", "2", "--E", "3", "--nu", "0.2"],
            {"material": {"E": 3.0, "nu": 0.2, "lam": 5 / 6, "mu": 1.25, "rho": 1.0,
                          "plane": "strain"}},
        ),
        (
            ["eld-tip-mass", "--lam", "1", "--mu", "40", "--plane", "strain"],
            {"E": 80.97560975609755, "nu": 0.012195121951219513, "lam": 1.0, "mu": 40.0,
             "rho": 1.0, "plane": "strain"},
        ),
        (
            ["eld-control", "--E", "80", "--nu", "0.1", "--rho", "2"],
            {"material": {"E": 80.0, "nu": 0.1, "lam": 100 / 11, "mu": 400 / 11, "rho": 2.0,
                          "plane": "stress"}},
        ),
        (
            ["eld-tmd", "--lam", "20", "--mu", "40"],
            {"material": {**_LAME, "rho": 1.0, "plane": "stress"}},
        ),
        (
            ["eld-two-bodies", "--lam", "20", "--mu", "40", "--E2", "7"],
            {
                "material1": {**_LAME, "rho": 1.0, "plane": "stress"},
                "material2": {"rho": 2.0, "lam": 1.9444444444444446, "mu": 2.916666666666667,
                              "plane": "stress"},
            },
        ),
    ],
    ids=lambda v: v[0] if isinstance(v, list) else "",
)  # fmt: skip
def test_the_summary_states_the_material_as_each_command_always_did(tmp_path, capsys, argv,
                                                                      expected):  # fmt: skip
    """``summary_material`` (cli/eld_options.py) chooses the material's description for every
    command (it was chosen three ways): the pair as given and the other derived, rho and the
    model; eld-tip-mass's flat at the top level and eld-beam's E, nu before ``material``, as
    before the helper (the summaries of 19 runs of the 8 commands, with and without
    --material, compared key by key before and after: equal)."""
    out = tmp_path / "out"
    code, _, err = run_cli(capsys, "run", *argv, *_SHORT, "--out", out)
    assert code == 0, err
    s = _summary(out)

    def close(v):
        return v if isinstance(v, str) else pytest.approx(v, rel=1e-14)

    for key, value in expected.items():
        if isinstance(value, dict):
            assert list(s[key]) == list(value)
            assert all(s[key][k] == close(v) for k, v in value.items())
        else:
            assert s[key] == close(value)
    keys = list(s)
    assert keys[keys.index(next(iter(expected))) :][: len(expected)] == list(expected)
    if "E" in expected and "material" not in expected:  # eld-tip-mass: flat
        assert "material" not in s


def test_summary_material_with_material_is_the_piecewise_description(tmp_path, capsys):
    """With --material (eld-tip-mass on a gmsh strip of two regions): the materials, their
    regions, the reference density, under ``material``."""
    mesh = write_gmsh_body(tmp_path / "two.msh", nx=8, ny=2, length=1.0, height=0.25, split=0.5)
    code, _, err = run_cli(
        capsys, "run", "eld-tip-mass", "--mesh", mesh, "--dirichlet", "inlet", "--tip", "outlet",
        "--material", "hard:lam=2,mu=1", "--material", "soft:E=3,nu=0.25,rho=4",
        "--region", "hard=core", "--region", "soft=shell", *_SHORT, "--out", tmp_path / "out",
    )  # fmt: skip
    assert code == 0, err
    s = _summary(tmp_path / "out")
    assert "E" not in s and s["material"] == {
        "materials": {
            "hard": {"rho": 1.0, "lam": 2.0, "mu": 1.0, "plane": "stress"},
            "soft": {"rho": 4.0, "lam": pytest.approx(1.2), "mu": pytest.approx(1.2),
                     "plane": "stress"},
        },
        "regions": {"core": "hard", "shell": "soft"},
        "rho_ref": 4.0,
    }  # fmt: skip
