"""Matplotlib set-up shared by every figure: a non-interactive backend and one way to save."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # figures are files; no display is needed (or present on CI machines)
import matplotlib.pyplot as plt  # noqa: E402

from ..io.atomic import atomic_path


def save_figure(fig, path, dpi: int = 120, tight: bool = True) -> Path:
    """Tight layout, PNG (120 dpi), written atomically; the figure is closed (long runs draw
    many)."""

    path = Path(path)
    try:
        if tight:
            fig.tight_layout()
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, format=path.suffix.lstrip(".") or "png")
    finally:
        plt.close(fig)
    return path


#: panels with more cells than this show no cell edges (they would only darken the picture)
MAX_EDGE_CELLS = 20_000


def snapshot_grid(count: int, extent, panel_width: float = 3.0):
    """Figure and axes for ``count`` panels of a 2D domain side by side with a colour bar: the
    panel height follows the domain's aspect ratio ``extent = (width, height)`` and the layout
    is "compressed" (constrained, with the gaps of fixed-aspect panels removed), so the panels
    fill the canvas (no wide empty margins)."""
    lx, ly = (float(e) for e in extent)
    aspect = min(max(ly / lx, 0.15), 3.0) if lx > 0 and ly > 0 else 1.0
    fig, axes = plt.subplots(
        1,
        count,
        figsize=(panel_width * count + 1.0, panel_width * aspect + 0.8),
        layout="compressed",
        squeeze=False,
    )
    return fig, axes[0]


def snapshot_axes(ax, first: bool) -> None:
    """Equal aspect, x (and on the first panel y) labelled, a few ticks."""
    ax.set_aspect("equal")
    ax.set_xlabel("x", labelpad=1)
    if first:
        ax.set_ylabel("y", labelpad=1)
    else:
        ax.set_yticklabels([])
    ax.tick_params(labelsize=7, length=2)
    ax.locator_params(nbins=3)


def draw_edges(ax, x, y, triangles) -> None:
    """The cell edges, thin and mid-grey (visible on viridis' dark and light ends alike),
    unless there are more than :data:`MAX_EDGE_CELLS` cells."""
    if len(triangles) <= MAX_EDGE_CELLS:
        ax.triplot(x, y, triangles, color="0.6", lw=0.3, alpha=0.85)
