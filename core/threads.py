"""How the compiled loops use threads: numba's threads in one call, or one thread inside parallel tasks.

Every compiled kernel releases the GIL (``nogil``), so tasks running on
threads side by side compute at the same time.  A kernel with a parallel
loop (:func:`parallel_kernel`) is compiled twice from the same source:
with ``parallel=True`` for a call that has the machine to itself (an
in-memory :func:`patchcloud.core.estimate_normals`, say), and as a plain
sequential loop for calls made inside :func:`single_threaded`, which is
how the stream's tasks run when several share the machine: no task starts
a pool of threads, and no two threads enter numba's thread pool at once.
A call on small arrays (fewer than :data:`SEQUENTIAL_BELOW` rows in each)
runs the sequential version too: it takes milliseconds, and the parallel
one's first call costs more than that (loading it, starting numba's
threads: 0.06 s of a 60,000-point file's run).
Both give identical results (parallel loops only ever write rows of their own).
"""

from __future__ import annotations

import functools
import threading
import types
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np
from numba import njit

__all__ = ["parallel_kernel", "single_threaded", "in_single_threaded", "SEQUENTIAL_BELOW"]

#: A kernel call whose arrays all have fewer rows than this runs sequentially, even outside :func:`single_threaded`.
SEQUENTIAL_BELOW = 1 << 16

_state = threading.local()


def in_single_threaded() -> bool:
    """True inside :func:`single_threaded` (in this thread).

    >>> in_single_threaded()
    False
    >>> with single_threaded():
    ...     in_single_threaded()
    True
    """
    return getattr(_state, "depth", 0) > 0


@contextmanager
def single_threaded() -> Iterator[None]:
    """Within it, this thread's kernel calls run their sequential, GIL-free versions."""
    _state.depth = getattr(_state, "depth", 0) + 1
    try:
        yield
    finally:
        _state.depth -= 1


def parallel_kernel(func: Callable) -> Callable:
    """Compile ``func`` (with ``prange`` loops) twice, parallel and sequential, both cached and ``nogil``; call the one that fits.

    The sequential one runs inside :func:`single_threaded` and when every
    array argument has fewer than :data:`SEQUENTIAL_BELOW` rows.  The sequential version is a copy of the function under another name, so
    numba's on-disk cache keeps the two apart.
    """
    par = njit(cache=True, nogil=True, parallel=True)(func)
    copy = types.FunctionType(func.__code__, func.__globals__, func.__name__ + "_sequential", func.__defaults__, func.__closure__)
    copy.__qualname__ = func.__qualname__ + "_sequential"
    copy.__module__ = func.__module__
    seq = njit(cache=True, nogil=True)(copy)

    @functools.wraps(func)
    def call(*args):
        if in_single_threaded() or _small(args):
            return seq(*args)
        return par(*args)

    call.parallel = par
    call.sequential = seq
    return call


def _small(args: tuple) -> bool:
    """Whether every array among ``args`` has fewer than :data:`SEQUENTIAL_BELOW` rows."""
    for a in args:
        if isinstance(a, np.ndarray) and a.ndim and a.shape[0] >= SEQUENTIAL_BELOW:
            return False
    return True
