"""The C heap during long runs of sparse factorizations: freed memory kept for the next allocation.

A run of Gauss-Newton factorizations allocates and frees the same large blocks again and again: CHOLMOD's
workspace, the values handed to it, the Jacobians and their products (megabytes each at 10k vertices). With
glibc's default policy, free memory at the top of the heap beyond a threshold goes back to the operating system
and blocks above another come from ``mmap``, so the next allocation of the same size touches fresh pages: every
4 KiB page costs a page fault. Without it, a :class:`lacore.ShapeMixer` build of the CC0 body (13k vertices) faults
about 300,000 times (0.7-1.1 s of system time) and one of the 50k bar about 800,000 times (2-3 s); ten in-betweens
of the 50k bar by *Path* about 600,000 times. The mixer's build, Gauss-Newton reconstruction and the in-betweens of
:func:`lacore.interpolate` run inside :func:`retained_heap`.

:func:`retained_heap` keeps freed memory in the process while it runs (glibc's ``mallopt``: an ``mmap`` threshold
of :data:`MMAP_THRESHOLD` and a trim threshold of :data:`TRIM_THRESHOLD`), and on leaving returns what is free to
the system (``malloc_trim``) and leaves thresholds of :data:`MMAP_THRESHOLD` and twice that, which is where glibc's
own adaptive thresholds end after large blocks have been freed. Elsewhere than glibc (macOS, Windows, musl) it does
nothing. The measurements are in ``docs/shape-space.md``.
"""

import ctypes
import platform
import threading
from contextlib import contextmanager

__all__ = ["MMAP_THRESHOLD", "TRIM_THRESHOLD", "retained_heap", "heap_control"]

#: Blocks at least this large come from ``mmap`` (bytes): glibc's largest, 32 MiB on 64-bit systems.
MMAP_THRESHOLD = 32 * 1024 * 1024

#: Free memory at the top of the heap kept while :func:`retained_heap` runs (bytes).
TRIM_THRESHOLD = 1 << 30

_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3      # glibc's malloc.h
_LOCK = threading.Lock()
_DEPTH = [0]
_LIBC = []


def heap_control():
    """glibc's C library (a :class:`ctypes.CDLL` with ``mallopt`` and ``malloc_trim``), or None elsewhere."""
    if not _LIBC:
        libc = None
        if platform.system() == "Linux" and platform.libc_ver()[0] == "glibc":
            try:
                libc = ctypes.CDLL("libc.so.6")
                libc.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
                libc.malloc_trim.argtypes = [ctypes.c_size_t]
            except (OSError, AttributeError):
                libc = None
        _LIBC.append(libc)
    return _LIBC[0]


@contextmanager
def retained_heap():
    """Keep freed memory in the process while the block runs; return it to the system after.

    Nested and concurrent uses share one setting: the outermost block's exit restores. Does nothing where the C
    library is not glibc (:func:`heap_control`).

    Examples
    --------
    >>> import numpy as np
    >>> with retained_heap():
    ...     total = sum(float(np.ones(1 << 21).sum()) for _ in range(3))  # three 16 MiB blocks, one set of pages
    >>> total
    6291456.0
    """
    libc = heap_control()
    if libc is None:
        yield
        return
    with _LOCK:
        _DEPTH[0] += 1
        if _DEPTH[0] == 1:
            libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)
            libc.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
    try:
        yield
    finally:
        with _LOCK:
            _DEPTH[0] -= 1
            if _DEPTH[0] == 0:
                libc.mallopt(_M_TRIM_THRESHOLD, 2 * MMAP_THRESHOLD)
                libc.malloc_trim(0)
