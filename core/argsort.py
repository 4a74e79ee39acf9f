"""``stable_argsort``: numpy's stable argsort of a big key array, on numba's threads where a call has the machine.

``np.argsort(keys, kind="stable")`` runs on one core (and releases the
GIL while it sorts).  :func:`stable_argsort` cuts the keys into as many
consecutive parts as numba has threads, sorts the parts side by side on
Python threads, and merges the sorted parts, the left one first on equal
keys: the permutation is the stable sort's, element for element (tested),
so every result that follows is bit for bit the same.  Inside
:func:`patchcloud.core.threads.single_threaded` (the stream's tasks, which
share the machine already), and for fewer than :data:`MIN_PARALLEL` keys,
it is ``np.argsort`` itself.

Keys that come in runs of equal values (the cells of points already in
space order: a tile's points sorted by Morton key, keyed by their cells
of some level) are sorted run by run: the runs, by their key then their
place, each run's rows kept in order, which is again the stable sort's
permutation.  Runs of :data:`MIN_RUN` keys or more on average make it
pay (``python tools/bench_runs_argsort.py``, tools/results/bench_runs_argsort-2026-11-28.txt:
a million points in Morton order keyed by their moment cells, 3.4x faster
at runs of 11 keys, 1.6x at runs of 3, the same on random keys); finding out costs one pass over
the keys.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
from numba import njit

from ._kernels import run_starts
from .threads import in_single_threaded

__all__ = ["stable_argsort", "MIN_PARALLEL", "MIN_RUN", "MIN_RUNS_SORT"]

#: Fewer keys than this are sorted in one call: the threads and the merge would cost more than they save.
MIN_PARALLEL = 200_000
#: Keys whose runs of equal values are at least this long on average are sorted run by run.
MIN_RUN = 2
#: Fewer keys than this are never sorted run by run (nothing to gain).
MIN_RUNS_SORT = 4096


def stable_argsort(keys: np.ndarray, threads: int | None = None) -> np.ndarray:
    """``np.argsort(keys, kind="stable")`` of a 1-D array, with the parts sorted on several threads.

    Parameters
    ----------
    keys : (N,) array of an integer dtype (others are sorted by numpy in one call)
    threads : int, optional
        How many parts to sort side by side (default: numba's thread count;
        1 inside :func:`~patchcloud.core.threads.single_threaded`).

    Returns
    -------
    (N,) int64
        The same permutation as numpy's stable argsort.

    Examples
    --------
    >>> k = np.array([3, 1, 2, 1, 3, 0])
    >>> stable_argsort(k).tolist() == np.argsort(k, kind="stable").tolist()
    True
    """
    keys = np.ascontiguousarray(keys)
    n = keys.shape[0]
    integers = keys.ndim == 1 and keys.dtype.kind in "iu"
    if integers and n >= MIN_RUNS_SORT and 1 + np.count_nonzero(keys[1:] != keys[:-1]) <= n // MIN_RUN:
        # few enough runs: the runs sorted stably (by key, then place), each expanded in place
        starts = run_starts(keys)
        order = stable_argsort(keys[starts], threads)
        return _expand_runs(starts[order], np.append(starts[1:], n)[order], n)
    parts = 1
    if integers and n >= MIN_PARALLEL:  # else numba's thread pool is not even asked about
        if threads is None:
            threads = 1 if in_single_threaded() else numba.get_num_threads()
        parts = min(int(threads), n // (MIN_PARALLEL // 2))
    if parts < 2:
        return np.argsort(keys, kind="stable").astype(np.int64, copy=False)
    bounds = np.linspace(0, n, parts + 1).astype(np.int64)
    spans = list(zip(bounds[:-1].tolist(), bounds[1:].tolist()))
    with ThreadPoolExecutor(parts) as pool:  # numpy's sort releases the GIL: the parts are sorted at the same time
        runs = list(pool.map(lambda s: np.argsort(keys[s[0]:s[1]], kind="stable").astype(np.int64) + s[0], spans))
        while len(runs) > 1:  # merge neighbouring runs pairwise, the pairs side by side (the kernel releases the GIL)
            pairs = [(runs[i], runs[i + 1]) for i in range(0, len(runs) - 1, 2)]
            merged = list(pool.map(lambda ab: _merge(keys, ab[0], ab[1]), pairs))
            runs = merged + ([runs[-1]] if len(runs) % 2 else [])
    return runs[0]


@njit(cache=True, nogil=True)
def _merge(keys, a, b):
    """Merge two runs of indices, each sorted stably by ``keys`` and ``a``'s all before ``b``'s in the input: ``a`` first on ties."""
    out = np.empty(a.shape[0] + b.shape[0], dtype=np.int64)
    i = j = k = 0
    while i < a.shape[0] and j < b.shape[0]:
        if keys[b[j]] < keys[a[i]]:
            out[k] = b[j]
            j += 1
        else:
            out[k] = a[i]
            i += 1
        k += 1
    while i < a.shape[0]:
        out[k] = a[i]
        i += 1
        k += 1
    while j < b.shape[0]:
        out[k] = b[j]
        j += 1
        k += 1
    return out


@njit(cache=True, nogil=True)
def _expand_runs(firsts, ends, n):
    """Rows ``firsts[r]`` to ``ends[r] - 1`` of every run ``r`` in turn: (n,) int64."""
    out = np.empty(n, dtype=np.int64)
    k = 0
    for r in range(firsts.shape[0]):
        for i in range(firsts[r], ends[r]):
            out[k] = i
            k += 1
    return out
