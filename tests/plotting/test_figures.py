"""Figures a person reads (issue 21): every panel has labelled axes, a legend where it has
several curves, a colour bar with a label, a title that says what is shown; snapshot panels
fill their canvas; fig4 does not repeat fig1's t^(s); fig1 draws no flat "max z".

The figures are captured where they are saved (after the layout is done) and inspected as
matplotlib objects."""

from __future__ import annotations

import numpy as np
import pytest

from rothe.io.mesh_series import MeshSeries


@pytest.fixture
def captured(monkeypatch):
    """Every figure saved by the plotting modules, laid out and drawn, before it is closed."""
    import rothe.eld.figures as eld_figures
    import rothe.plotting.adapt as adapt
    import rothe.ris.figures as ris_figures
    from rothe.plotting import common

    figures = []

    def keep(fig, path, *args, tight=True, **kwargs):
        if tight:  # as save_figure does
            fig.tight_layout()
        fig.canvas.draw()
        figures.append(fig)
        return path

    for module, name in (
        (ris_figures, "save_figure"),
        (adapt, "save_figure"),
        (eld_figures, "_save"),
        (common, "save_figure"),
    ):
        monkeypatch.setattr(module, name, keep)
    return figures


def _panels(fig):
    return [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]


def _colorbars(fig):
    return [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]


def _check_readable(fig, min_fill: float):
    """Labels, legends, title, and the share of the canvas the panels and colour bars use."""
    for ax in _panels(fig):
        assert ax.get_xlabel(), ax
        lines = [ln for ln in ax.get_lines() if not ln.get_label().startswith("_")]
        if len(lines) > 1:
            assert ax.get_legend() is not None, [ln.get_label() for ln in lines]
        if len(lines) == 1 and not ax.collections:
            assert ax.get_legend() is None  # a one-entry legend says nothing
    for cb in _colorbars(fig):
        assert cb.get_ylabel(), "a colour bar without a label"
    assert fig._suptitle is not None and fig._suptitle.get_text()
    boxes = [ax.get_position() for ax in fig.axes]
    x0, y0 = min(b.x0 for b in boxes), min(b.y0 for b in boxes)
    x1, y1 = max(b.x1 for b in boxes), max(b.y1 for b in boxes)
    assert (x1 - x0) * (y1 - y0) > min_fill, f"the panels use {(x1 - x0) * (y1 - y0):.2f}"


def _unit_square_run():
    from rothe.ris import Adaptive, run_ris
    from rothe.ris.examples import example_7_2

    problem = example_7_2(4)
    return problem, run_ris(problem, Adaptive(tol=1e-2, tau=0.1)).trajectory


def test_ris_snapshots_path_and_steps(tmp_path, captured):
    from rothe.ris.figures import plot_fig4, plot_path, plot_snapshots
    from rothe.ris.run import stored_states

    problem, traj = _unit_square_run()
    s, t, z = stored_states(traj)
    plot_snapshots(problem.nodes, problem.cells, s, t, z, tmp_path / "snap.png", title="run")
    plot_path(traj, tmp_path / "path.png", title="run")
    plot_fig4([traj], tmp_path / "steps.png", title="run")
    snap, path, steps = captured
    _check_readable(snap, min_fill=0.55)  # was 0.36: small panels on a wide canvas
    panels = _panels(snap)
    assert len(panels) == 4 and panels[0].get_ylabel() == "y"
    assert all(ax.collections and ax.get_lines() for ax in panels)  # the field, the edges
    assert _colorbars(snap)[0].get_ylabel().startswith("$z$")
    assert "the state z at 4 points of the path" in snap._suptitle.get_text()
    _check_readable(path, min_fill=0.6)
    left, right = _panels(path)
    assert left.get_legend() is None  # one curve: no legend
    labels = [ln.get_label() for ln in right.get_lines()]
    assert labels == ["min over the nodes", "mean over the nodes"]  # max z is 0 throughout
    _check_readable(steps, min_fill=0.6)
    ylabels = [ax.get_ylabel() for ax in _panels(steps)]
    assert not any("hat t" in y for y in ylabels), ylabels  # t^(s) is fig1's
    assert ylabels == [r"step size $\tau_k$", r"local residual $I_1^k + I_2^k$"]


def test_mesh_snapshots_label_their_colour_bar_and_state_the_mesh_sizes(tmp_path, captured):
    import skfem

    from rothe.fem.adapt import AdaptiveMesh
    from rothe.plotting.adapt import plot_mesh_snapshots

    amesh = AdaptiveMesh(skfem.MeshTri.init_tensor(np.linspace(0, 2, 9), np.linspace(0, 1, 5)))
    series = MeshSeries()
    series.add(0, amesh.points, amesh.cells)
    centers = amesh.points[amesh.cells].mean(axis=1)
    amesh.refine(np.linalg.norm(centers, axis=1) < 0.5)
    series.add(1, amesh.points, amesh.cells)
    values = [series.mesh(k)[0][:, 0] for k in (0, 1)]
    plot_mesh_snapshots(
        tmp_path / "m.png",
        series,
        [0, 1],
        [0.0, 0.5],
        values,
        [0, 1],
        title="eld-pulse",
        label="|u|",
    )
    (fig,) = captured
    _check_readable(fig, min_fill=0.5)
    n0, n1 = len(series.mesh(0)[0]), len(series.mesh(1)[0])
    assert fig._suptitle.get_text() == f"eld-pulse: |u| on the adapted meshes ({n0}-{n1} vertices)"
    assert _colorbars(fig)[0].get_ylabel() == "|u|"
    assert [ax.get_title() for ax in _panels(fig)] == [
        f"t = 0, {n0} vertices",
        f"t = 0.5, {n1} vertices",
    ]
    # a 2:1 strip: the canvas follows the domain (it was 3.4 high for any domain)
    width, height = fig.get_size_inches()
    assert height < 0.45 * width


def test_energy_figure_labels_both_panels(tmp_path, captured):
    from rothe.eld.figures import plot_energy_balance
    from rothe.io.trajectory import Trajectory

    traj = Trajectory()
    for k in range(5):
        t = 0.1 * k
        traj.append(
            t=t,
            kinetic=t,
            elastic=t * t,
            energy=t + t * t,
            work=0.0,
            work_reaction=t + t * t,
            dissipated=0.0,
            numerical_dissipation=0.0,
            data_mismatch=0.0,
            balance_residual=1e-15,
        )
    plot_energy_balance(traj, tmp_path / "e.png", title="eld-beam")
    (fig,) = captured
    _check_readable(fig, min_fill=0.6)
    left, right = _panels(fig)
    assert left.get_ylabel() == "energy" and right.get_ylabel()  # was empty on the right
    assert right.get_title().startswith("energy identity term by term")


def test_tip_mass_study_figure_draws_every_mode_from_the_summary(tmp_path, monkeypatch):
    """``rothe study eld-tip-mass`` (K = 3 by default) writes fig_tip_mass_frequency.png with a
    line per mode in both panels (before: the first mode only): against tau the finest mesh's
    error vs analytic and its time error, against h the space error -- the summary's
    ``error_modes[-1]``, ``error_time_modes[-1]``, ``error_space_modes`` of that mode."""
    import json

    import rothe.eld.figures as eld_figures
    from rothe.cli.main import main

    figures, save = [], eld_figures._save

    def spy(fig, path, *args, **kwargs):  # the figure as drawn, then written as always
        figures.append(fig)
        return save(fig, path, *args, **kwargs)

    monkeypatch.setattr(eld_figures, "_save", spy)
    out = tmp_path / "study"
    argv = ["study", "eld-tip-mass", "--ns", "1,2", "--taus", "0.02,0.01", "--T", "1"]
    assert main([*argv, "--workers", "1", "--quiet", "--out", str(out)]) == 0
    assert (out / "fig_tip_mass_frequency.png").stat().st_size > 0
    (fig,) = figures
    _check_readable(fig, min_fill=0.6)
    s = json.loads((out / "summary.json").read_text())
    left, right = _panels(fig)
    lines = {ln.get_label(): ln for ax in (left, right) for ln in ax.get_lines()}
    error = np.abs(np.array(s["error_modes"]))
    time_error = np.abs(np.array(s["error_time_modes"]))
    space = np.abs(np.array(s["error_space_modes"]))
    assert s["modes"] == 3 and left.get_title().startswith("first 3 frequencies")
    for k in range(3):
        name = rf"$\omega_{{{k + 1}}}$"
        for label, values in (
            (f"{name}, n = 2: run vs analytic", error[-1, :, k]),
            (f"{name}, n = 2: time error", time_error[-1, :, k]),
            (rf"{name}: $|\omega_h/\omega - 1|$", space[:, k]),
        ):
            assert np.array_equal(lines[label].get_ydata(), values), label
        assert np.array_equal(lines[rf"{name}: $|\omega_h/\omega - 1|$"].get_xdata(), [1, 0.5])
    assert len(lines) == 9
