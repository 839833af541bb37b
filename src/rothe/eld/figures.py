"""Figures of elastodynamics runs: energy balance, reaction forces, convergence, perturbations."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..plotting.common import plt
from ..plotting.common import save_figure as _save


def plot_energy_balance(traj, path, title: str = "") -> Path:
    """Left: kinetic, elastic and total energy. Right: the terms of the energy identity,
    E(t) - E(0) = W_loads + W_support - D_physical - D_numerical - X_data, and its residual."""
    t = traj["t"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    ax = axes[0]
    ax.plot(t, traj["kinetic"], label="kinetic")
    ax.plot(t, traj["elastic"], label="elastic")
    ax.plot(t, traj["energy"], "k", lw=1.6, label="total E")
    ax.set_xlabel("t")
    ax.set_ylabel("energy")
    ax.set_title("kinetic, elastic and total energy", fontsize=9)
    ax.legend(fontsize=8)
    ax = axes[1]
    e0 = traj["energy"][0]
    ax.plot(t, traj["energy"] - e0, "k", lw=1.6, label="E(t) - E(0)")
    ax.plot(t, traj["work"], label="work of loads")
    ax.plot(t, traj["work_reaction"], label="work of the support")
    ax.plot(t, -traj["dissipated"], label="- physical dissipation")
    ax.plot(t, -traj["numerical_dissipation"], label="- numerical dissipation")
    if np.max(np.abs(traj["data_mismatch"])) > 0:
        ax.plot(t, -traj["data_mismatch"], ":", label="- data mismatch")
    res = np.max(np.abs(traj["balance_residual"]))
    ax.set_title(f"energy identity term by term (largest residual {res:.2e})", fontsize=9)
    ax.set_xlabel("t")
    ax.set_ylabel("energy change, work, dissipation")
    ax.legend(fontsize=7)
    for ax in axes:
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=10)
    return _save(fig, path)


def plot_reactions(traj, path, title: str = "") -> Path:
    """Reaction force per Dirichlet part (-int lambda ds, one curve per component) over time."""
    t = traj["t"][1:]
    parts = [k for k in traj.keys() if k.startswith("reaction_")]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    names = "xyz"
    for key in parts:
        R = traj[key]
        for c in range(R.shape[1]):
            axes[0].plot(t, R[:, c], label=f"{key[len('reaction_') :]}: R_{names[c]}")
    axes[0].set_xlabel("t")
    axes[0].set_ylabel(r"reaction force $-\int \lambda\, ds$")
    axes[0].legend(fontsize=8)
    axes[1].plot(t, traj["lam_norm"])
    axes[1].set_xlabel("t")
    axes[1].set_ylabel(r"$\|\lambda\|_{L^2(\Gamma_D)}$")
    for ax in axes:
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=10)
    return _save(fig, path)


def plot_convergence(
    taus, errors: dict, path, rates: dict | None = None, title: str = "", order: int = 1
) -> Path:
    """Log-log errors against tau, with a reference line of the given order."""
    taus = np.asarray(taus)
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for name, errs in errors.items():
        rate = None if not rates else rates.get(name)
        label = name if rate is None else f"{name} (rate {rate:.2f})"
        ax.loglog(taus, errs, "o-", label=label)
    first = np.asarray(next(iter(errors.values())))
    ax.loglog(
        taus,
        first[0] * (taus / taus[0]) ** order,
        "k--",
        lw=1,
        label=r"$O(\tau)$" if order == 1 else rf"$O(\tau^{order})$",
    )
    ax.set_xlabel(r"$\tau$")
    ax.set_ylabel("error at T")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)
    return _save(fig, path)


def plot_perturbation(taus, table: dict, path, title: str = "", labels=None) -> Path:
    """Amplification max_j |x_pert^j - x^j| / delta against tau, both forms (Theorem 4.5).
    ``labels``: the panels' titles by quantity (``lam``, ``v``, ``u``; default the multiplier,
    the velocity and the displacement of the body)."""
    taus = np.asarray(taus)
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    names = {"lam": r"multiplier $\lambda$", "v": "velocity", "u": "displacement"}
    names.update(labels or {})
    panels = (("amp", names["lam"]), ("amp_v", names["v"]), ("amp_u", names["u"]))
    for ax, (key, label) in zip(axes, panels, strict=True):
        for form, style in (("regularized", "o-"), ("original", "s--")):
            name = f"{key}_{form}"
            if name in table and np.any(np.asarray(table[name]) > 0):
                ax.loglog(taus, table[name], style, label=form)
        ax.set_xlabel(r"$\tau$")
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    axes[0].set_ylabel(r"$\max_j \|\cdot_{pert} - \cdot\| / \delta$")
    if title:
        fig.suptitle(title, fontsize=10)
    return _save(fig, path)


def plot_tip_mass(traj, path, title: str = "", modal=None) -> Path:
    """A coupled run (:func:`rothe.eld.run_coupled`): the component's coordinates q(t) and the
    reactions -int lambda ds on every constrained part over time; with ``modal`` (states, K)
    a third panel, the modal coordinates c_k(t) of the excited modes (eld-tip-mass --modes)."""
    t = traj["t"]
    q = np.asarray(traj["q"])
    panels = 2 if modal is None else 3
    fig, axes = plt.subplots(1, panels, figsize=(5.5 * panels, 4))
    names = "xyz"
    for c in range(q.shape[1]):
        axes[0].plot(t, q[:, c], label=f"q_{names[c]}")
    axes[0].set_xlabel("t")
    axes[0].set_ylabel("tip mass displacement q")
    axes[0].legend(fontsize=8)
    for key in [k for k in traj.keys() if k.startswith("reaction_")]:
        R = traj[key]
        for c in range(R.shape[1]):
            axes[1].plot(t, R[:, c], label=f"{key[len('reaction_') :]}: R_{names[c]}")
    axes[1].set_xlabel("t")
    axes[1].set_ylabel(r"reaction force $-\int \lambda\, ds$")
    axes[1].legend(fontsize=8)
    if modal is not None:
        modal = np.asarray(modal)
        for k in range(modal.shape[1]):
            axes[2].plot(t, modal[:, k], lw=1.0, label=f"mode {k + 1}")
        axes[2].set_xlabel("t")
        axes[2].set_ylabel(r"modal coordinate $c_k = \phi_k^T M x$")
        axes[2].legend(fontsize=8)
    for ax in axes:
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=10)
    return _save(fig, path)


def plot_comparison(
    runs: dict, path, *, coordinate: int, label: str, part: str, axis: int, title: str = ""
) -> Path:
    """Coupled runs side by side (``runs``: legend label -> trajectory): left the coordinate
    ``coordinate`` of q(t) (``label`` on the axis), right the component ``axis`` of the reaction
    -int lambda ds on ``part`` over time (eld-tmd: the tip's deflection and the base's y
    reaction with and without the absorber; eld-control: the base and its x reaction with and
    without the feedback)."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for name, traj in runs.items():
        t = traj["t"]
        axes[0].plot(t, np.asarray(traj["q"])[:, coordinate], lw=1.0, label=name)
        R = np.asarray(traj[f"reaction_{part}"])
        axes[1].plot(t, R[:, axis], lw=1.0, label=name)
    axes[0].set_xlabel("t")
    axes[0].set_ylabel(label)
    axes[1].set_xlabel("t")
    axes[1].set_ylabel(rf"reaction on '{part}' ({'xyz'[axis]}) $-\int \lambda\, ds$")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    return _save(fig, path)


def plot_tip_mass_study(study: dict, path, title: str = "") -> Path:
    """The tip-mass study (:func:`rothe.eld.studies.tip_mass_study`), one line per measured
    mode k = 1..K (one colour each): left, against tau on the finest mesh, |w_k,run / w_k - 1|
    (solid; the study's ``error_modes[-1]``) and the time error |w_k,run / w_k,h - 1| (dashed;
    ``error_time_modes[-1]``; on top of the solid line where the space error is far
    smaller, as for P2); right, the space error |w_k,h / w_k - 1| of the semi-discrete
    system against h = 1/n (``error_space_modes``)."""
    taus = np.asarray(study["tau"], float)
    ns = list(study["n"])
    error = np.asarray(study["error_modes"], float)  # (n, tau, K)
    time_error = np.asarray(study["error_time_modes"], float)
    space = np.asarray(study["error_space_modes"], float)  # (n, K)
    modes = error.shape[2]
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.5))
    h = 1.0 / np.asarray(ns, float)
    for k in range(modes):
        color = colors[k % len(colors)]
        name = rf"$\omega_{{{k + 1}}}$"
        left.loglog(taus, np.abs(error[-1, :, k]), "o-", color=color, lw=3, alpha=0.4,
                    label=f"{name}, n = {ns[-1]}: run vs analytic")  # fmt: skip
        left.loglog(taus, np.abs(time_error[-1, :, k]), "x--", color=color,
                    label=f"{name}, n = {ns[-1]}: time error")  # fmt: skip
        right.loglog(h, np.abs(space[:, k]), "s-", color=color,
                     label=rf"{name}: $|\omega_h/\omega - 1|$")  # fmt: skip
    left.set_xlabel(r"$\tau$")
    left.set_ylabel(r"relative error of $\omega_k$")
    left.set_title(f"first {modes} frequencies, {study['scheme']}", fontsize=10)
    right.set_xlabel(r"$h \sim 1/n$")
    right.set_ylabel(r"space error of $\omega_k$")
    right.set_title(f"semi-discrete, P{study['degree']}", fontsize=10)
    for ax in (left, right):
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7, loc="lower right")
    drawn = np.abs(np.concatenate([error[-1].ravel(), time_error[-1].ravel()]))
    drawn = drawn[np.isfinite(drawn) & (drawn > 0)]
    if drawn.size:  # room below the lines (they rise to the right) for the six-line legend
        left.set_ylim(drawn.min() / 30, drawn.max() * 2)
    if title:
        fig.suptitle(title, fontsize=10)
    return _save(fig, path)
