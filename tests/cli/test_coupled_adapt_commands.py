"""``--adapt-space`` on the coupled run commands (``rothe run eld-tip-mass|eld-control|eld-tmd|
eld-two-bodies``): the body's mesh changes, the ledger closes, the coupling holds at every
accepted state, the meshes are in ``trajectory.npz``; eld-two-bodies adapts body 1 (the base),
its glue turns mortar once the interface is refined and the tip of body 2 stays close to the
fixed-mesh run; bad adapt options are one line and exit 2."""

from __future__ import annotations

import json

import meshio
import numpy as np
import pytest

from rothe.cli.main import main


def _run(tmp_path, command, *args, name="out"):
    out = tmp_path / name
    argv = ["run", command, "--quiet", "--no-plots", "--out", str(out), *args]
    return main(argv), out


def _summary(out):
    return json.loads((out / "summary.json").read_text())


def _check_mesh_changes(s, data, suffix=""):
    """The mesh changes between recorded states in the steps refined in their rounds and
    after the adaptations, nowhere else; the summary counts both (every mesh of an accepted
    state or an adaptation once: the meshes of the recorded states, which are those after
    the adapt step, and those left by the adaptations)."""
    ids = data["mesh_id"]
    rounds = data["step_refinements"]
    assert s[f"refinements_in_steps{suffix}"] == rounds.sum()
    changed = np.diff(ids) != 0
    assert np.all(changed[rounds > 0])  # a step solved again on a refined mesh
    # any other change is an adaptation after the step (estimated there)
    assert np.all(np.isfinite(data["space_estimate"][changed & (rounds == 0)]))
    assert s[f"adaptations{suffix}"] >= np.count_nonzero(changed & (rounds == 0))
    assert s[f"adaptations{suffix}"] <= np.count_nonzero(changed)
    assert s[f"meshes{suffix}"] >= np.unique(ids).size


def test_tip_mass_adapts_the_bar_and_the_ledger_closes(tmp_path):
    code, out = _run(
        tmp_path, "eld-tip-mass", "--degree", "1", "--T", "0.5", "--adapt-space",
        "--space-tol", "1e-3",
    )  # fmt: skip
    assert code == 0
    s = _summary(out)
    assert s["adapt_space"] is True and s["meshes"] >= 3 and s["ndofs_max"] > s["ndofs_min"]
    assert s["balance_max"] <= 1e-10 * s["energy_initial"]
    assert s["constraint_max"] <= 1e-10
    data = np.load(out / "trajectory.npz")
    ids = data["mesh_id"]
    assert ids.shape == (101,) and np.array_equal(data["state_mesh_id"], ids)
    for k in np.unique(ids):  # every mesh once, with the unknowns each state had
        cells, points = data[f"mesh_cells_{k}"], data[f"mesh_points_{k}"]
        assert cells.shape[1] == 3 and points.shape[1] == 2
        assert np.all(data["ndofs"][ids == k] == 2 * points.shape[0])
    assert np.isfinite(data["space_estimate"]).sum() >= 3
    assert abs(data["transfer"][-1]) > 0
    # the keys of run_eld's summary (one function makes both: meshes_summary), read back
    dofs = data["ndofs"]
    assert s["ndofs"] == s["ndofs_final"] == dofs[-1] and s["ndofs_initial"] == dofs[0]
    assert s["ndofs_max"] == dofs.max() and s["ndofs_min"] == dofs.min()
    assert s["ndofs_summed_over_steps"] == dofs[1:].sum()
    assert s["adaptations"] >= 2
    _check_mesh_changes(s, data)
    assert s["bisections"] > 0 and s["merges"] >= 0
    assert s["transfer_energy"] == data["transfer"][-1]
    assert s["space"] == s["space_options"] and s["space"]["space_tol"] == 1e-3


def test_tip_mass_modes_with_adapt_space_fit_the_tip_signal(tmp_path):
    """--modes 2 with --adapt-space: the modes live on the first mesh, the states on others,
    so the frequencies are the matrix pencil's of the tip's q_x (the reason in the summary);
    T = 0.3 is less than half the first period and the meshes change, so they are rough:
    +2 % and -4 % from the discrete ones measured (BDF2 at w_2 tau = 0.34: -3.4 %)."""
    code, out = _run(
        tmp_path, "eld-tip-mass", "--degree", "1", "--T", "0.3", "--tau", "0.01",
        "--adapt-space", "--space-tol", "1e-2", "--max-dofs", "1000", "--modes", "2",
    )  # fmt: skip
    assert code == 0
    s = _summary(out)
    assert s["meshes"] >= 2
    assert s["frequencies_measured"] == s["frequencies_measured_tip"]
    assert np.all(np.abs(s["frequencies_error_measured_vs_discrete"]) < 0.1)
    assert "--adapt-space" in s["frequencies_measured_note"]


@pytest.mark.parametrize("command", ["eld-control", "eld-tmd"])
def test_control_and_tmd_adapt_both_runs(tmp_path, command):
    T = {"eld-control": "0.2", "eld-tmd": "0.4"}[command]
    code, out = _run(
        tmp_path, command, "--degree", "1", "--T", T, "--tau", "0.01", "--adapt-space",
        "--space-tol", {"eld-control": "1e-3", "eld-tmd": "1e-4"}[command], "--adapt-every", "2",
    )  # fmt: skip
    assert code == 0
    s = _summary(out)
    second = {"eld-control": "uncontrolled", "eld-tmd": "without_tmd"}[command]
    for suffix, name in (("", "trajectory.npz"), (f"_{second}", f"trajectory_{second}.npz")):
        assert s[f"meshes{suffix}"] >= 3, suffix
        assert s[f"constraint_max{suffix}"] <= 1e-10
        data = np.load(out / name)
        assert np.abs(data["balance"]).max() <= 1e-10 * np.abs(data["energy"]).max()
        assert np.array_equal(data["state_mesh_id"], data["mesh_id"])
        assert s[f"ndofs{suffix}"] == s[f"ndofs_final{suffix}"] == data["ndofs"][-1]
        assert s[f"ndofs_initial{suffix}"] == data["ndofs"][0]
        _check_mesh_changes(s, data, suffix)
        assert s[f"bisections{suffix}"] > 0 and f"merges{suffix}" in s
        # each run's body in ParaView: one VTU per kept state (--keep-every 5: 0, 5, ..., the
        # last) on the mesh it was computed on
        pvd = out / f"body{suffix}.pvd"
        vtus = sorted(out.glob(f"body{suffix}_[0-9]*.vtu"))
        n = data["t"].size
        assert n == data["kept_t"].size and data["kept_states"][-1] == n - 1
        keep = np.union1d(np.arange(0, n, 5), [n - 1])
        assert pvd.exists() and len(vtus) == keep.size
        assert np.array_equal(data["kept_states"], keep)
        last = meshio.read(vtus[-1])
        offsets = data["kept_u_offsets"]
        u = data["kept_u"][offsets[-2] : offsets[-1]].reshape(-1, 2)
        assert np.array_equal(last.point_data["u"][:, :2], u[: len(last.points)])
    assert "space" in s and f"space_{second}" not in s
    assert s["paraview"] == ["body.pvd", f"body_{second}.pvd"]


def test_two_bodies_adapt_body_1_the_glue_turns_mortar_and_the_tip_stays(tmp_path):
    """P1 strips of 2 cells across, T = 0.5: the adaptive base against the fixed coarse one and
    a fine reference (body 1 with 16 cells across, glued by the mortar projection): measured
    tip deflections 0.010236 (coarse), 0.011251 (adaptive, 14 meshes), 0.011177 (reference),
    0.011199 (32 across)."""
    common = ["--T", "0.5", "--degree", "1"]
    tips = {}
    for name, extra in (
        ("coarse", []),
        ("reference", ["--n1", "16", "--n2", "2"]),
        ("adapt", ["--adapt-space", "--space-tol", "2e-3"]),
    ):
        code, out = _run(tmp_path, "eld-two-bodies", *common, *extra, name=name)
        assert code == 0
        tips[name] = _summary(out)["tip_deflection_max"]
    s = _summary(out)
    assert s["adaptive_body"] == "body1" and s["meshes"] >= 3
    assert s["interface_method"] == "matching" and s["interface_method_final"] == "mortar"
    assert s["constraint_max"] <= 1e-10
    assert s["balance_max"] <= 1e-10 * s["energy_final"]
    # one ParaView series per body: the adaptive base one VTU per state on its own mesh
    assert s["paraview"] == ["body1.pvd", "body2.xdmf"]
    assert (out / "body2_multiplier.xdmf").exists() and not (out / "body1.xdmf").exists()
    assert len(list(out.glob("body1_*.vtu"))) == s["accepted_steps"] + 1
    # body 2 (attached, on its fixed mesh) sees the refined base: its tip is within 1 % of the
    # fine reference, ten times closer than on the coarse fixed meshes
    ref = tips["reference"]
    assert abs(tips["adapt"] - ref) < 1e-2 * ref
    assert abs(tips["adapt"] - ref) < 0.15 * abs(tips["coarse"] - ref)
    data = np.load(out / "trajectory.npz")
    assert np.array_equal(data["state_mesh_id"], data["mesh_id"])
    _check_mesh_changes(s, data)
    assert s["refinements_in_steps"] > 0
    # ndofs per body: the adaptive base's last, body 2's
    assert s["ndofs"][0] == data["ndofs"][-1] == s["ndofs_final"] and s["ndofs"][1] > 0


@pytest.mark.parametrize(
    "command, args, line",
    [
        ("eld-tip-mass", ["--space-tol", "1e-3"], "--space-tol: got 0.001, is used by "
         "--adapt-space only"),
        ("eld-tip-mass", ["--adapt-space"], "--space-tol: got None, must be given (> 0) with "
         "--adapt-space"),
        ("eld-tip-mass", ["--adapt-space", "--space-tol", "-1"], "--space-tol: got -1"),
        ("eld-control", ["--adapt-space", "--space-tol", "1e-3", "--refine-fraction", "1.5"],
         "--refine-fraction: got 1.5"),
        ("eld-tmd", ["--adapt-space", "--space-tol", "1e-3", "--adapt-every", "0"],
         "--adapt-every: got 0"),
        ("eld-two-bodies", ["--adapt-space", "--space-tol", "1e-3", "--space-norm", "h1"],
         "--space-norm: got 'h1', must be one of"),
        ("eld-two-bodies", ["--adapt-space", "--space-tol", "1e-3", "--compare-union"],
         "--compare-union: got it with --adapt-space, needs the fixed matching meshes"),
    ],
)  # fmt: skip
def test_bad_adapt_options_are_one_line_and_exit_2(tmp_path, capsys, command, args, line):
    code, out = _run(tmp_path, command, *args)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("rothe: error: " + line), err
    assert not (out / "summary.json").exists()
