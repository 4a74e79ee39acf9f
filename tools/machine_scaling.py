"""What two (or N) threads of this machine give on compute-bound and on memory-bound work: the ceiling of any speed-up.

    python tools/machine_scaling.py [--threads 2] [--repeats 5] [--out FILE]

Three loops, each timed once per thread one after the other, then on all
threads at once (GIL released: numba ``nogil`` kernels, numpy's copies):

- ``compute``: a floating-point loop over no memory (sin of a counter);
- ``memory, streaming``: a loop reading and writing 32 MB arrays (more than
  the caches), 20 passes;
- ``memory, random``: a gather of 3-float rows by a random permutation (the
  access of the k-NN and moment kernels), 4 M rows.

speed-up = (one thread's time x threads) / (the threads' wall time); the
median of ``--repeats``.  A machine whose memory bandwidth does not grow
with its cores shows a speed-up near 1 on the memory rows, and no job that
streams its points through memory can scale better than them there.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import threading
import time
from datetime import date
from pathlib import Path

import numba
import numpy as np

__all__ = ["main"]


@numba.njit(nogil=True, cache=True)
def _compute(n):
    s = 0.0
    for i in range(n):
        s += np.sin(i * 1e-3)
    return s


@numba.njit(nogil=True, cache=True)
def _stream(a, out):
    for _ in range(20):
        for i in range(a.size):
            out[i] = a[i] * 1.0001 + out[i]


@numba.njit(nogil=True, cache=True)
def _gather(values, order, out):
    for i in range(order.size):
        r = order[i]
        out[i, 0] = values[r, 0]
        out[i, 1] = values[r, 1]
        out[i, 2] = values[r, 2]


def _work(kind: str, threads: int, rows: int):
    """One callable per thread, each on its own arrays of ``rows`` values (or 3-float rows)."""
    rng = np.random.default_rng(0)
    calls = []
    for _ in range(threads):
        if kind == "compute":
            calls.append(lambda: _compute(5 * rows))
        elif kind == "memory, streaming":
            a, o = rng.random(rows), np.zeros(rows)
            calls.append(lambda a=a, o=o: _stream(a, o))
        else:
            v, p, o = rng.random((rows, 3)), rng.permutation(rows), np.empty((rows, 3))
            calls.append(lambda v=v, p=p, o=o: _gather(v, p, o))
    return calls


def measure(kind: str, threads: int, repeats: int, rows: int = 4_000_000) -> tuple[float, float]:
    """(one thread's median seconds, all threads' median wall seconds)."""
    calls = _work(kind, threads, rows)
    for c in calls:  # compiled (or loaded) and the pages touched before timing
        c()
    alone, together = [], []
    for _ in range(repeats):
        for c in calls:
            t = time.perf_counter()
            c()
            alone.append(time.perf_counter() - t)
        ts = [threading.Thread(target=c) for c in calls]
        t = time.perf_counter()
        for x in ts:
            x.start()
        for x in ts:
            x.join()
        together.append(time.perf_counter() - t)
    return statistics.median(alone), statistics.median(together)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 2)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--rows", type=int, default=4_000_000, help="array length per thread (default: past the caches)")
    ap.add_argument("--out")
    a = ap.parse_args(argv)
    if a.threads < 2 or a.repeats < 1 or a.rows < 1:
        ap.error("--threads must be at least 2, --repeats and --rows at least 1")
    lines = [
        f"# machine_scaling {date.today()} on {platform.node()}: {os.cpu_count()} cores, {platform.machine()}, "
        f"python {platform.python_version()}",
        f"# command: python tools/machine_scaling.py {' '.join(sys.argv[1:] if argv is None else argv)}",
        "",
        f"{'work':<20} {'1 thread s':>10} {f'{a.threads} threads s':>12} {'speed-up':>9}",
    ]
    for kind in ("compute", "memory, streaming", "memory, random"):
        one, many = measure(kind, a.threads, a.repeats, a.rows)
        lines.append(f"{kind:<20} {one:>10.3f} {many:>12.3f} {one * a.threads / many:>8.2f}x")
    text = "\n".join(lines)
    print(text)
    if a.out:
        Path(a.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
