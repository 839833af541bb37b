"""Figures of RIS runs: analogues of Figs. 1-5 of Andreia & Meyer (2022)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .common import plt
from .common import save_figure as _save


def plot_path(traj, path, exact=None, title="", component=None) -> Path:
    """Fig. 1 analogue: t^(s) and z^(s) (the affine interpolants), with the exact solution.

    For vector states, z^ is shown as its min, max and V-mean over the nodes unless
    ``component`` selects one entry.
    """
    from ..stepping.ris import stored_states

    s, t, z = stored_states(traj)
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    axes[0].plot(traj["s"], traj["t"], "-", lw=1.4, label="numerical")
    ragged = isinstance(z, list)  # states on different meshes (space adaptivity)
    if not ragged and z.ndim == 2 and z.shape[1] == 1:
        z1 = z[:, 0]
        axes[1].plot(s, z1, "-", lw=1.4, label="numerical")
    elif component is not None and not ragged:
        axes[1].plot(s, z[:, component], "-", lw=1.4, label=f"z[{component}]")
    else:
        axes[1].plot(s, [np.max(v) for v in z], "-", lw=1.2, label="max z")
        axes[1].plot(s, [np.min(v) for v in z], "-", lw=1.2, label="min z")
    if exact is not None:
        ss = np.linspace(0, max(s[-1], 16.0), 801)
        te, ze = exact(ss)
        axes[0].plot(ss, te, "k--", lw=1, label="exact (7.1)")
        axes[1].plot(ss, ze, "k--", lw=1, label="exact (7.1)")
    axes[0].set_xlabel("s")
    axes[0].set_ylabel(r"$\hat t(s)$")
    axes[1].set_xlabel("s")
    axes[1].set_ylabel(r"$\hat z(s)$")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    return _save(fig, path)


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
    return _save(fig, path)


def plot_error_vs_work(rows, path, title="") -> Path:
    """Fig. 3 analogue: L2 and L-infinity error against the number of steps, per controller.

    Solid markers: inner solves (accepted + rejected); open markers: accepted steps only.
    """
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    groups = {}
    for r in rows:
        groups.setdefault(r["control"], []).append(r)
    styles = {"uniform": "o", "adaptive": "s", "order2": "^", "nested": "D"}
    for name, rs in groups.items():
        rs = sorted(rs, key=lambda r: r["inner_solves"])
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
    return _save(fig, path)


def plot_residual_vs_steps(rows, path, title="") -> Path:
    """Fig. 5 analogue: local max_k(I1+I2) and global sum_k(I1+I2) against the number of steps,
    and the global residual against the number of inner solves (accepted + rejected attempts)."""
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    groups = {}
    for r in rows:
        groups.setdefault(r["control"], []).append(r)
    styles = {"uniform": "o", "adaptive": "s", "order2": "^", "regime": "D"}
    for name, rs in groups.items():
        rs = sorted(rs, key=lambda r: r["accepted_steps"])
        n = [r["accepted_steps"] for r in rs]
        style = "-" + styles.get(name, "x")
        axes[0].loglog(n, [r["max_residual"] for r in rs], style, label=name)
        axes[1].loglog(n, [r["sum_residual"] for r in rs], style, label=name)
        axes[2].loglog([r["inner_solves"] for r in rs], [r["sum_residual"] for r in rs], style,
                       label=name)
    axes[0].set_ylabel(r"local residual $\max_k (I_1^k + I_2^k)$")
    axes[1].set_ylabel(r"global residual $\sum_k (I_1^k + I_2^k)$")
    axes[2].set_ylabel(r"global residual $\sum_k (I_1^k + I_2^k)$")
    for ax, xlabel in zip(axes, ("number of steps", "number of steps", "inner solves"),
                          strict=True):
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    return _save(fig, path)
