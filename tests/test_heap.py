"""lacore.linalg.heap: freed memory kept in the process while a build runs, returned after (glibc only)."""

import os
import resource

import numpy as np
import pytest

from lacore.linalg.heap import heap_control, retained_heap

pytestmark = pytest.mark.skipif(heap_control() is None or not os.path.exists("/proc/self/statm"),
                                reason="glibc's malloc and /proc are needed")

BLOCK = 16 << 20          # bytes: three blocks alive at once, above glibc's default thresholds of trimming


def _faults():
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt


def _resident():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def _rounds(n):
    """Page faults of ``n`` rounds of three blocks allocated, written and freed."""
    out = []
    for _ in range(n):
        f0 = _faults()
        blocks = [np.ones(BLOCK // 8) for _ in range(3)]
        del blocks
        out.append(_faults() - f0)
    return out


def test_freed_blocks_are_reused_inside_and_returned_after():
    pages = 3 * BLOCK // os.sysconf("SC_PAGE_SIZE")
    with retained_heap():
        with retained_heap():                                 # nested: the inner exit keeps the heap
            inside = _rounds(4)
        kept = _resident()
    after = _resident()
    # the first round touches fresh pages; the next ones reuse them: measured 0 faults a round
    assert max(inside[1:]) <= 0.02 * pages, inside
    # the outer exit gives the free blocks back: measured 49 of the 48 MiB
    assert kept - after >= 0.6 * 3 * BLOCK, (kept >> 20, after >> 20)
