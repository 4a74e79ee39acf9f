"""What the benchmarks in tools/ share to time a call: the median of repeats (one process, wall clock)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any

__all__ = ["median_time"]


def median_time(func: Callable[[], Any], repeats: int) -> tuple[float, Any]:
    """(median seconds of ``repeats`` calls of ``func``, the last call's result).

    >>> seconds, out = median_time(lambda: 2 + 2, 3)
    >>> seconds >= 0, out
    (True, 4)
    """
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = func()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out
