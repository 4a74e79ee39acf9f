"""numba's compilation of the kernels, timed apart from the job: a first run's compiling is not its speed.

The kernels are compiled on their first call and cached on disk
(``NUMBA_CACHE_DIR``, :mod:`patchcloud.core` sets a user cache directory):
the first run after an installation (or a change of the sources) compiles
them, 10 to 20 seconds, and every later run loads them in well under a
second.  A :class:`CompileClock` records when compiling happened (numba's
``numba:compile`` events, which fire on a compilation and not on a load
from the cache): the run's own process is watched for the whole run, and
each task on a worker (:meth:`patchcloud.stream.engine.runner.Runner.map`)
for its duration.  The job takes that wall time out of its steps' times and
reports it on a line of its own, "compiling kernels, once" (:data:`COMPILING`).

>>> import numba
>>> @numba.njit
... def twice(x):
...     return 2 * x
>>> with CompileClock() as clock:
...     _ = twice(1.0)
>>> len(clock.intervals), clock.seconds > 0
(1, True)
>>> with CompileClock() as clock:
...     _ = twice(2.0)                          # compiled already
>>> clock.intervals
[]
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Iterable

__all__ = ["COMPILING", "CompileClock", "merge_intervals", "seconds_within", "compiling_line", "announce_on_stderr"]

#: How a job's summary and progress name the compiling.
COMPILING = "compiling kernels, once"


def merge_intervals(intervals: Iterable[tuple[float, float]]) -> list[tuple[float, float]]:
    """The union of (start, end) intervals as sorted, disjoint intervals.

    >>> merge_intervals([(5, 6), (0, 2), (1, 3)])
    [(0, 3), (5, 6)]
    """
    out: list[tuple[float, float]] = []
    for a, b in sorted(intervals):
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


def seconds_within(intervals: Iterable[tuple[float, float]], start: float, end: float) -> float:
    """Seconds of the union of ``intervals`` that lie between ``start`` and ``end``.

    >>> seconds_within([(0, 2), (1, 3), (5, 6)], 2.5, 5.5)
    1.0
    """
    return float(sum(max(0.0, min(b, end) - max(a, start)) for a, b in merge_intervals(intervals)))


def compiling_line(seconds: float) -> list[str]:
    """A summary's line for the compiling (none when nothing was compiled).

    >>> compiling_line(0.0)
    []
    >>> compiling_line(13.42)
    ['  compiling       kernels, once: 13.4 s (numba: the first run of these kernels since installing; cached for later runs; not in the times below)']
    """
    if seconds <= 0:
        return []
    return [f"  compiling       kernels, once: {seconds:.1f} s (numba: the first run of these kernels since installing; cached for "
            "later runs; not in the times below)"]


class CompileClock:
    """Wall-clock intervals (seconds since the epoch) during which numba compiled, while the clock is on (a context manager).

    Parameters
    ----------
    this_thread : bool
        Count only compilations in the thread that starts the clock (a task
        among others running on threads of one worker); default: every thread
        of the process (numba compiles one function at a time per process).
    announce : callable, optional
        Called once, with no argument, when a first compilation starts (to
        tell a user waiting before a progress bar moves).
    """

    def __init__(self, this_thread: bool = False, announce: Callable[[], None] | None = None) -> None:
        self.this_thread = threading.get_ident() if this_thread else None
        self.announce = announce
        self.intervals: list[tuple[float, float]] = []
        self._open: dict[int, tuple[int, float]] = {}  # thread -> (nesting depth, start)
        self._listener = None

    @property
    def seconds(self) -> float:
        """Wall seconds during which a compilation was running."""
        return sum(b - a for a, b in merge_intervals(self.intervals))

    def _start(self) -> None:
        me = threading.get_ident()
        if self.this_thread is not None and me != self.this_thread:
            return
        depth, t0 = self._open.get(me, (0, 0.0))
        if depth == 0:
            t0 = time.time()
            if self.announce is not None:
                announce, self.announce = self.announce, None
                announce()
        self._open[me] = (depth + 1, t0)

    def _end(self) -> None:
        me = threading.get_ident()
        if me not in self._open:
            return
        depth, t0 = self._open[me]
        if depth == 1:
            del self._open[me]
            self.intervals.append((t0, time.time()))
        else:
            self._open[me] = (depth - 1, t0)

    def __enter__(self) -> "CompileClock":
        from numba.core import event

        clock = self

        class Listener(event.Listener):
            def on_start(self, ev) -> None:
                clock._start()

            def on_end(self, ev) -> None:
                clock._end()

        self._listener = Listener()
        event.register("numba:compile", self._listener)
        return self

    def __exit__(self, *exc) -> None:
        from numba.core import event

        event.unregister("numba:compile", self._listener)
        self._listener = None


def announce_on_stderr() -> None:
    """Say on standard error that the kernels are compiling (a progress bar being drawn gets its own line)."""
    sys.stderr.write(("\n" if sys.stderr.isatty() else "") + f"{COMPILING} (numba: the first run of these kernels since installing; cached for later runs) ...\n")
    sys.stderr.flush()
