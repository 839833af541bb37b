"""Figures of finite-element RIS runs: Fig. 4 analogue (t^(s), tau_k) and snapshots of z.

Fig. 5 (residuals against steps) is :func:`rothe.plotting.ris.plot_residual_vs_steps`.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.tri as mtri
import numpy as np

from .common import plt, save_figure


def plot_fig4(runs, path, title: str = "") -> Path:
    """Fig. 4 of the paper: for each run (one row), t^(s) (left) and tau_k against s (right)."""
    runs = list(runs)
    fig, axes = plt.subplots(len(runs), 2, figsize=(10, 3.0 * len(runs)), squeeze=False)
    for row, traj in zip(axes, runs, strict=True):
        s, t, tau = traj["s"], traj["t"], traj["tau"]
        tol = traj.meta.get("tol")
        label = f"{traj.meta.get('control')}" + (f", tol = {tol:g}" if tol is not None else "")
        row[0].plot(s, t, "-", lw=1.3)
        row[0].set_ylabel(r"$\hat t(s)$")
        row[0].set_title(label, fontsize=9)
        if len(tau):
            row[1].semilogy(s[1:], tau, ".", ms=2.5)
        row[1].set_ylabel(r"$\tau_k$")
        row[1].set_title(f"{len(tau)} accepted steps", fontsize=9)
        for ax in row:
            ax.set_xlabel("s")
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
    """z at a few s (nearest accepted states to S/4, S/2, 3S/4, S), one colour scale.

    In 3D the slice through the middle of the last coordinate is shown.
    """
    nodes, cells, Z = np.asarray(nodes), np.asarray(cells), np.asarray(Z)
    idx = snapshot_indices(s, count)
    tri, pick = _triangulation(nodes, cells)
    vals = Z[idx][:, pick]
    vmin, vmax = float(vals.min()), float(vals.max())
    if vmin == vmax:
        vmin, vmax = vmin - 1.0, vmax + 1.0
    fig, axes = plt.subplots(1, len(idx), figsize=(3.4 * len(idx) + 0.8, 3.4), squeeze=False)
    im = None
    for ax, k, v in zip(axes[0], idx, vals, strict=True):
        im = ax.tripcolor(tri, v, shading="gouraud", vmin=vmin, vmax=vmax, cmap="viridis")
        ax.set_aspect("equal")
        ax.set_title(f"s = {s[k]:.4g}, t = {t[k]:.4g}", fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(im, ax=axes[0].tolist(), shrink=0.85, label="z")
    if title:
        fig.suptitle(title + (" (mid-plane slice)" if nodes.shape[1] == 3 else ""), fontsize=10)
    return save_figure(fig, path, dpi=110, tight=False)
