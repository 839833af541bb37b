"""Matplotlib set-up shared by every figure: a non-interactive backend and one way to save."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # figures are files; no display is needed (or present on CI machines)
import matplotlib.pyplot as plt  # noqa: E402


def save_figure(fig, path) -> Path:
    """Tight layout, 120 dpi PNG, and close the figure (long runs draw many)."""
    path = Path(path)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
