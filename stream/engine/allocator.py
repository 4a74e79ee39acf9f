"""The C allocator of a dask worker process: large arrays reused from the heap, not mapped and zeroed afresh for each one.

dask's nanny starts every worker process with ``MALLOC_TRIM_THRESHOLD_=65536``
(its ``distributed.nanny.pre-spawn-environ``), so that a worker gives freed
memory back to the system at once.  In glibc, setting that threshold also
turns off the adaptive *mmap threshold*, which then stays at 128 KiB: every
array over 128 KiB (all of a task's point arrays) gets pages of its own
from the kernel, which the kernel zeroes, and gives them back when it is
freed.  A task of a patchcloud job makes and frees such arrays by the
hundred; on the 10-million-point city that was 4.7 million page faults and
15 s of system time in 28 s of wall time (2 workers).

:func:`tune_allocator` sets both thresholds with ``mallopt``: arrays of up
to :data:`MMAP_THRESHOLD` (64 MiB: a part's records, half a million points
of up to 134 bytes, fit under it) come from the heap and their memory is
reused by the next task's, and the heap gives memory back once more than
:data:`TRIM_THRESHOLD` of it is free at its top.  Measured with 2 workers:
on the 10M city LAZ 0.5 million page faults, the processes' summed peak
1.86 GiB against 1.71 GiB untuned (256 and 512 MiB: no faster, 2.0-2.1
GiB); on the 30M city LAS (67-byte output records: 33 MB a part) 0.68
million faults and 38.4 s against 1.2 million and 40.9 s with glibc's own
adaptive ceiling (32 and 64 MiB).  What a worker holds stays
bounded by its largest task (a part or a tile, not the file), plus that
margin.  Every local cluster's worker runs it as it starts
(:mod:`.worker_setup`); the workers of a cluster of your own run it with
``dask worker ... --preload patchcloud.stream.engine.allocator``.  Nothing
else changes: the same arrays, the same results.  A process that is not
on glibc (macOS, musl) is left alone.
"""

from __future__ import annotations

import ctypes
import platform
import sys

__all__ = ["tune_allocator", "dask_setup", "MMAP_THRESHOLD", "TRIM_THRESHOLD"]

#: Allocations up to this size (bytes) come from the heap, whose memory is reused; larger ones are mapped.
MMAP_THRESHOLD = 64 * 2**20
#: The heap gives memory back to the system once this much (bytes) is free at its top.
TRIM_THRESHOLD = 128 * 2**20

_M_TRIM_THRESHOLD = -1  # glibc's <malloc.h>
_M_MMAP_THRESHOLD = -3


def tune_allocator(mmap_threshold: int = MMAP_THRESHOLD, trim_threshold: int = TRIM_THRESHOLD) -> bool:
    """Set glibc's mmap and trim thresholds (bytes) for this process; True when both were taken.

    Returns False, changing nothing, where the C library is not glibc.

    >>> tune_allocator() in (True, False)
    True
    """
    if not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc":
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    mmap_ok = mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold)) == 1
    trim_ok = mallopt(_M_TRIM_THRESHOLD, int(trim_threshold)) == 1
    return mmap_ok and trim_ok


def dask_setup(worker) -> None:
    """Called by dask in a worker process that preloads this module (``dask worker --preload``): :func:`tune_allocator`."""
    tune_allocator()
