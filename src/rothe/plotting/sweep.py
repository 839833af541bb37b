"""Figure of a sweep: one column of ``sweep.csv`` against another, a line per group of runs."""

from __future__ import annotations

import math

from .common import plt, save_figure


def _number(v):
    if isinstance(v, bool) or v is None:
        return None
    if isinstance(v, (int, float)):
        return float(v) if math.isfinite(v) else None
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def wants_log(values) -> bool:
    """Log axis when every value is positive and they span at least a decade."""
    vals = [v for v in values if v is not None]
    return bool(vals) and min(vals) > 0 and max(vals) / min(vals) >= 10


def plot_sweep(rows, x: str, y: str, group_by, path, title: str = ""):
    """Y against X over the completed runs; one line per value of the ``group_by`` columns
    (the other swept parameters), points sorted by X. Log axes where the values span a
    decade or more. Returns the path, or None when no run has numeric X and Y."""
    groups: dict[tuple, list[tuple[float, float]]] = {}
    for r in rows:
        if r.get("status") != "completed":
            continue
        xv, yv = _number(r.get(x)), _number(r.get(y))
        if xv is None or yv is None:
            continue
        key = tuple((g, r.get(g)) for g in group_by)
        groups.setdefault(key, []).append((xv, yv))
    if not groups:
        return None
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    for key, pts in groups.items():
        pts.sort()
        label = ", ".join(f"{g}={v}" for g, v in key) or None
        ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=label)
    xs = [p[0] for pts in groups.values() for p in pts]
    ys = [p[1] for pts in groups.values() for p in pts]
    if wants_log(xs):
        ax.set_xscale("log")
    if wants_log(ys):
        ax.set_yscale("log")
    ax.set_xlabel(x)
    ax.set_ylabel(y)
    if title:
        ax.set_title(title)
    if any(k for k in groups):
        ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    return save_figure(fig, path)
