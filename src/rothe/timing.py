"""Seconds per phase of a run: step, adapt (estimate, mark, refine, transfer, rebuild), factor,
solve, record, checkpoint.

A :class:`PhaseTimes` is a dict of accumulated wall-clock seconds by phase name. The evolve loop
times its own phases (``step``, ``adapt``, ``record``, ``checkpoint``); the adapt cycle
(:mod:`rothe.fem.adapt.cycle`) and the steppers time the phases inside them (``estimate``,
``mark``, ``refine``, ``transfer``, ``rebuild``, ``factor``, ``solve``) into the stepper's
``times``, which the loop adds to ``trajectory.stats.seconds``. Nested phases overlap: ``adapt``
contains ``estimate`` ... ``rebuild``; ``step`` contains ``factor`` and ``solve``. Timings are
never part of a result that must be reproducible (checkpoints carry them, comparisons skip them).
"""

from __future__ import annotations

import time
from contextlib import contextmanager


class PhaseTimes(dict):
    """Accumulated seconds by phase name (a dict; ``with times.phase("solve"): ...``)."""

    @contextmanager
    def phase(self, name: str):
        """Add the wall-clock seconds of the block to phase ``name``."""
        start = time.perf_counter()
        try:
            yield
        finally:
            self[name] = self.get(name, 0.0) + (time.perf_counter() - start)

    def add(self, other: dict) -> None:
        """Add another set of phase seconds to these."""
        for name, seconds in other.items():
            self[name] = self.get(name, 0.0) + float(seconds)

    def take(self) -> dict:
        """The seconds so far, and start again from zero (to hand them on exactly once)."""
        out = dict(self)
        self.clear()
        return out
