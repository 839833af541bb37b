"""Figures of RIS runs: analogues of Figs. 1-5 of Andreia & Meyer (2022), for R^n and for P1 runs
(Fig. 4: t^(s) and tau_k; snapshots of z on the mesh)."""

from __future__ import annotations

from pathlib import Path

import matplotlib.tri as mtri
import numpy as np

from ..plotting.common import draw_edges, plt, save_figure, snapshot_axes, snapshot_grid
from .run import stored_states


def plot_path(traj, path, exact=None, title="", component=None) -> Path:
    """Fig. 1 analogue: t^(s) and z^(s) (the affine interpolants), with the exact solution.

    For vector states (a mesh), z^ is shown as its minimum and mean over the nodes, and its
    maximum only where that moves (on ris-2d it stays at the Dirichlet value 0: a flat line
    that said nothing), unless ``component`` selects one entry. A legend only where a panel has
    several curves.
    """
    s, t, z = stored_states(traj)
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    axes[0].plot(traj["s"], traj["t"], "-", lw=1.4, label="numerical")
    ragged = isinstance(z, list)  # states on different meshes (space adaptivity)
    what = r"$\hat z(s)$"
    if not ragged and z.ndim == 2 and z.shape[1] == 1:
        axes[1].plot(s, z[:, 0], "-", lw=1.4, label="numerical")
    elif component is not None and not ragged:
        axes[1].plot(s, z[:, component], "-", lw=1.4, label=f"z[{component}]")
        what = rf"$\hat z_{{{component}}}(s)$"
    else:
        lo = np.array([np.min(v) for v in z])
        hi = np.array([np.max(v) for v in z])
        axes[1].plot(s, lo, "-", lw=1.3, label="min over the nodes")
        axes[1].plot(s, [np.mean(v) for v in z], "-", lw=1.3, label="mean over the nodes")
        if np.ptp(hi) > 1e-12 * max(1.0, np.abs(hi).max()):
            axes[1].plot(s, hi, "-", lw=1.3, label="max over the nodes")
        what = r"$\hat z(s)$ at the nodes"
    if exact is not None:
        ss = np.linspace(0, max(s[-1], 16.0), 801)
        te, ze = exact(ss)
        axes[0].plot(ss, te, "k--", lw=1, label="exact (7.1)")
        axes[1].plot(ss, ze, "k--", lw=1, label="exact (7.1)")
    axes[0].set_ylabel(r"$\hat t(s)$")
    axes[0].set_title("physical time along the path", fontsize=9)
    axes[1].set_ylabel(what)
    axes[1].set_title("state along the path", fontsize=9)
    for ax in axes:
        ax.set_xlabel("s (arc length)")
        ax.grid(alpha=0.3)
        if len(ax.get_lines()) > 1:
            ax.legend(fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)


def plot_steps(traj, path, title="") -> Path:
    """Fig. 2/4 analogue: step sizes tau_k against s (accepted steps), and t^(s)."""
    s, tau, t = traj["s"], traj["tau"], traj["t"]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    axes[0].plot(s, t, "-", lw=1.4)
    axes[0].set_xlabel("s")
    axes[0].set_ylabel(r"$\hat t(s)$")
    axes[1].semilogy(s[1:], tau, ".", ms=3)
    axes[1].set_xlabel("s")
    axes[1].set_ylabel(r"$\tau_k$")
    for ax in axes:
        ax.grid(alpha=0.3, which="both")
    if title:
        fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)


def _by_control(rows, key: str):
    """(control, its rows sorted by ``key``) in the order the controls first appear."""
    groups: dict[str, list] = {}
    for r in rows:
        groups.setdefault(r["control"], []).append(r)
    return [(name, sorted(rs, key=lambda r: r[key])) for name, rs in groups.items()]


def plot_error_vs_work(rows, path, title="") -> Path:
    """Fig. 3 analogue: L2 and L-infinity error against the number of steps, per controller.

    Solid markers: inner solves (accepted + rejected); open markers: accepted steps only.
    """
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    styles = {"uniform": "o", "adaptive": "s", "order2": "^", "nested": "D"}
    for name, rs in _by_control(rows, "inner_solves"):
        solves = [r["inner_solves"] for r in rs]
        acc = [r["accepted_steps"] for r in rs]
        for ax, key in zip(axes, ("error_l2", "error_linf"), strict=False):
            err = [r[key] for r in rs]
            (line,) = ax.loglog(solves, err, "-" + styles.get(name, "x"), label=f"{name} (solves)")
            if name != "uniform":
                ax.loglog(
                    acc,
                    err,
                    ":" + styles.get(name, "x"),
                    mfc="none",
                    color=line.get_color(),
                    label=f"{name} (accepted)",
                )
    for ax, lab in zip(axes, ("L2 error", "L-infinity error"), strict=False):
        ax.set_xlabel("number of steps")
        ax.set_ylabel(lab)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    if title:
        fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)


def plot_residual_vs_steps(rows, path, title="") -> Path:
    """Fig. 5 analogue: local max_k(I1+I2) and global sum_k(I1+I2) against the number of steps,
    and the global residual against the number of inner solves (accepted + rejected attempts)."""
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    styles = {"uniform": "o", "adaptive": "s", "order2": "^", "regime": "D"}
    for name, rs in _by_control(rows, "accepted_steps"):
        n = [r["accepted_steps"] for r in rs]
        style = "-" + styles.get(name, "x")
        axes[0].loglog(n, [r["max_residual"] for r in rs], style, label=name)
        axes[1].loglog(n, [r["sum_residual"] for r in rs], style, label=name)
        axes[2].loglog(
            [r["inner_solves"] for r in rs], [r["sum_residual"] for r in rs], style, label=name
        )
    axes[0].set_ylabel(r"local residual $\max_k (I_1^k + I_2^k)$")
    axes[1].set_ylabel(r"global residual $\sum_k (I_1^k + I_2^k)$")
    axes[2].set_ylabel(r"global residual $\sum_k (I_1^k + I_2^k)$")
    for ax, xlabel in zip(
        axes, ("number of steps", "number of steps", "inner solves"), strict=True
    ):
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)


# -- finite-element runs ----------------------------------------------------------------------


def plot_fig4(runs, path, title: str = "") -> Path:
    """The step control of each run (one row): the accepted step sizes tau_k against s (left,
    Fig. 4 of the paper) and what decided them, the local residual I_1^k + I_2^k of every
    accepted step with the tolerance (right). t^(s), the other panel of the paper's Fig. 4, is
    in ``fig1_path.png`` and not repeated here."""
    runs = list(runs)
    fig, axes = plt.subplots(len(runs), 2, figsize=(10, 0.4 + 3.2 * len(runs)), squeeze=False)
    for row, traj in zip(axes, runs, strict=True):
        s, tau = traj["s"], traj["tau"]
        tol = traj.meta.get("tol")
        control = traj.meta.get("control")
        label = f"{control}" + (f", tol = {tol:g}" if tol is not None else "")
        if len(tau):
            row[0].semilogy(s[1:], tau, ".", ms=2.5)
        row[0].set_ylabel(r"step size $\tau_k$")
        row[0].set_title(f"{label}: {len(tau)} accepted steps", fontsize=9)
        if "I1" in traj and "I2" in traj and len(tau):
            residual = np.asarray(traj["I1"]) + np.asarray(traj["I2"])
            positive = residual > 0
            row[1].semilogy(
                s[1:][positive],
                residual[positive],
                ".",
                ms=2.5,
                color="C1",
                label=r"$I_1^k + I_2^k$",
            )
            if tol is not None and control != "uniform":
                row[1].axhline(tol, color="k", ls="--", lw=1, label=f"tol = {tol:g}")
                row[1].legend(fontsize=8, loc="lower right")
        row[1].set_ylabel(r"local residual $I_1^k + I_2^k$")
        row[1].set_title("residual of each accepted step", fontsize=9)
        row[1].set_xlim(row[0].get_xlim())
        for ax in row:
            ax.set_xlabel("s (arc length)")
            ax.grid(alpha=0.3, which="both")
    if title:
        fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)


def snapshot_indices(s: np.ndarray, count: int = 4) -> np.ndarray:
    """Indices of the accepted states nearest to s = S/count, 2S/count, ..., S."""
    s = np.asarray(s)
    if s.size <= count:
        return np.arange(s.size)
    targets = s[-1] * np.arange(1, count + 1) / count
    idx = np.searchsorted(s, targets).clip(0, s.size - 1)
    return np.unique(idx)


def _triangulation(nodes: np.ndarray, cells: np.ndarray):
    """A 2D triangulation to draw on, and the node indices it uses.

    2D: the mesh itself. 3D: the nodes in the layer nearest the mid-plane of the last coordinate
    (exact for the structured cube; a slab approximation for unstructured meshes), triangulated
    by Delaunay in the first two coordinates.
    """
    if nodes.shape[1] == 2:
        return mtri.Triangulation(nodes[:, 0], nodes[:, 1], cells), np.arange(len(nodes))
    zc = nodes[:, 2]
    mid = 0.5 * (zc.min() + zc.max())
    levels = np.unique(np.round(zc, 12))
    if levels.size < len(nodes) / 4:  # layered (structured) mesh: take the nearest layer
        level = levels[np.argmin(np.abs(levels - mid))]
        pick = np.nonzero(np.abs(zc - level) <= 1e-9 * max(1.0, abs(level)))[0]
    else:
        h = (zc.max() - zc.min()) / max(2.0, len(nodes) ** (1 / 3))
        pick = np.nonzero(np.abs(zc - mid) <= h)[0]
    return mtri.Triangulation(nodes[pick, 0], nodes[pick, 1]), pick


def plot_snapshots(nodes, cells, s, t, Z, path, count: int = 4, title: str = "") -> Path:
    """z at a few s (nearest accepted states to S/4, S/2, 3S/4, S), one colour scale, with the
    cell edges; panels sized by the domain's aspect ratio (no empty margins).

    In 3D the slice through the middle of the last coordinate is shown.
    """
    nodes, cells, Z = np.asarray(nodes), np.asarray(cells), np.asarray(Z)
    idx = snapshot_indices(s, count)
    tri, pick = _triangulation(nodes, cells)
    vals = Z[idx][:, pick]
    vmin, vmax = float(vals.min()), float(vals.max())
    if vmin == vmax:
        vmin, vmax = vmin - 1.0, vmax + 1.0
    extent = np.ptp(nodes[:, :2], axis=0)
    fig, axes = snapshot_grid(len(idx), extent)
    im = None
    for i, (ax, k, v) in enumerate(zip(axes, idx, vals, strict=True)):
        im = ax.tripcolor(tri, v, shading="gouraud", vmin=vmin, vmax=vmax, cmap="viridis")
        if nodes.shape[1] == 2:  # a 3D slice is triangulated for drawing: no mesh edges
            draw_edges(ax, tri.x, tri.y, tri.triangles)
        snapshot_axes(ax, first=i == 0)
        ax.set_title(f"s = {s[k]:.4g}, t = {t[k]:.4g}", fontsize=9)
    fig.colorbar(im, ax=list(axes), shrink=0.9, label=r"$z$ (state at the nodes)")
    slice_note = " (mid-plane slice)" if nodes.shape[1] == 3 else ""
    fig.suptitle(
        (f"{title}: " if title else "") + f"the state z at {len(idx)} points of the "
        f"path{slice_note}",
        fontsize=10,
    )
    return save_figure(fig, path, dpi=110, tight=False)
