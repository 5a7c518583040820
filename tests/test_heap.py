"""Giving freed memory back to the system (:mod:`scantex.heap`)."""

from __future__ import annotations

import platform

import numpy as np
import pytest

from scantex import heap


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_trim_gives_freed_heap_memory_back_on_glibc():
    """Arrays of a few MB freed among live ones (as a room's photo views are) stay resident until trimmed."""
    def resident() -> int:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * 4096

    assert heap._malloc_trim() is not None
    big = np.ones(16 << 20, np.uint8)  # a block glibc maps on its own: freeing it raises its mmap threshold
    del big
    arrays = [np.ones(2 << 20, np.uint8) for _ in range(64)]  # 128 MB, now carved from the heap
    keep = arrays[1::2]
    del arrays  # every other array freed: 64 MB of holes under live arrays
    before = resident()
    heap.trim()
    assert before - resident() > 32 << 20
    assert sum(int(a[0]) for a in keep) == len(keep)


def test_trim_is_harmless_anywhere():
    heap.trim()
    heap.trim()
