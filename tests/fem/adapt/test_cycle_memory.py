"""return_free_memory (rothe.fem.adapt.cycle): the free pages of the heap go back to the system
(what an adaptive rebuild calls first, docs/adaptivity.md)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from rothe.fem.adapt.cycle import return_free_memory


def _rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc and /proc only")
def test_freed_fragmented_heap_is_returned():
    """80 MB of 4 KB arrays (heap, not mmap), every 64th kept (the free pages lie between
    live ones, which the heap does not give back by itself): after return_free_memory the
    resident size is at least 40 MB lower."""
    arrays = [np.ones(512) for _ in range(20000)]
    keep = arrays[::64]
    del arrays
    before = _rss_mb()
    return_free_memory()
    after = _rss_mb()
    assert before - after > 40.0, (before, after)
    assert all(float(a.sum()) == 512.0 for a in keep)  # the live arrays are intact
