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
