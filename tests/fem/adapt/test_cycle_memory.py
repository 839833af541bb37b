"""return_free_memory (rothe.fem.adapt.cycle): the free pages of the heap go back to the system
(what an adaptive rebuild calls first, docs/adaptivity.md)."""

from __future__ import annotations

import subprocess
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


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc and /proc only")
def test_mesh_arrays_get_their_own_mapping_during_a_rebuild():
    """Inside mesh_arrays_mapped an array of MAPPED_FROM bytes or more is mapped on its own:
    freed, it leaves the resident set at once, even with arrays allocated after it still live
    (on the heap it would leave a resident hole below them). In a fresh process: glibc serves
    a large request from a free heap chunk if one is big enough, whatever the threshold."""
    code = """
import numpy as np
from rothe.fem.adapt.cycle import MAPPED_FROM, mesh_arrays_mapped
def rss():
    for line in open('/proc/self/status'):
        if line.startswith('VmRSS'):
            return int(line.split()[1]) / 1024
x = np.ones(20 << 17)
del x  # a freed 20 MB mapping raises glibc's dynamic threshold to 20 MB
n = (MAPPED_FROM + (2 << 20)) // 8  # 7 MB
def dropped(mapped):
    with mesh_arrays_mapped() if mapped else open('/dev/null'):
        big = np.ones(n)
        after_it = [np.ones(8192) for _ in range(64)]
    before = rss()
    del big
    assert all(float(a.sum()) == 8192.0 for a in after_it)
    return before - rss()
print(dropped(True), dropped(False))
"""
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    mapped, heap = (float(x) for x in out.stdout.split())
    assert mapped > 6.0 and heap < 3.0, out.stdout  # on the heap: a resident hole
