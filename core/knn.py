"""Exact k nearest neighbours by rings of octree cells: a compiled search without a k-d tree.

The points are grouped by the cells of one octree level (runs of their
sorted Morton keys); each query scans its own cell, then the rings of
cells around it, one ring at a time, until its k-th nearest neighbour is
closer than anything outside the cells scanned can be.  The level is the
deepest whose cells hold at least ``k / 2`` points on average, so one ring
is usually enough; a query still short after :data:`RINGS` rings (an
isolated point) starts again one level up, with cells twice as large.  Neighbours come sorted by distance, ties by
coordinates (x, then y, then z): the same neighbours, in the same order,
whatever the points' order or the tiling, so results built on them do not
depend on either.

>>> p = np.array([[0.0, 0, 0], [1, 0, 0], [0, 2, 0], [5, 5, 5], [0.5, 0, 0]])
>>> knn(p, np.array([0, 3]), 2)
array([[0, 4],
       [3, 2]])
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .morton import MAX_DEPTH, encode, quantize
from .threads import parallel_kernel

__all__ = ["knn", "knn_in_cells", "cell_shift", "RINGS"]

#: Rings of cells scanned at one level before the search moves one level up.
RINGS = 2


@njit(cache=True, nogil=True, inline="always")
def _spread(v):
    x = np.uint64(v) & np.uint64(0x1FFFFF)
    x = (x | (x << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    x = (x | (x << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    x = (x | (x << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    x = (x | (x << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    x = (x | (x << np.uint64(2))) & np.uint64(0x1249249249249249)
    return x


@njit(cache=True, nogil=True, inline="always")
def _before(d, points, j, best_d, best_j, slot):
    """Whether point ``j`` at squared distance ``d`` ranks before the one in ``slot`` (distance, then x, y, z, then index)."""
    if d != best_d[slot]:
        return d < best_d[slot]
    b = best_j[slot]
    for a in range(3):
        if points[j, a] != points[b, a]:
            return points[j, a] < points[b, a]
    return j < b


@parallel_kernel
def _search(points, q, cells_all, starts_all, offsets, order, shift0, unit, query, nb):
    """For each query ``m``, its ``k`` nearest points, nearest first, into ``nb[m]`` (see the module's docstring).

    ``q``: depth-21 integer coordinates (unit ``unit`` metres) of the points.
    Level ``21 - shift0 - v`` (v = 0, 1, ... up to the root): its occupied
    cells' sorted Morton ids ``cells_all[offsets[v]:offsets[v + 1]]``, and
    where their points start in ``order`` (the points sorted by key),
    ``starts_all[offsets[v] + v:offsets[v + 1] + v + 1]``.
    """
    M, k = nb.shape
    for m in prange(M):
        pi = query[m]
        best_d = np.full(k, np.inf)
        best_j = np.full(k, -1, np.int64)
        v = 0
        shift = shift0
        side = 1 << (MAX_DEPTH - shift)
        size = 1 << shift
        cells = cells_all[offsets[0] : offsets[1]]
        starts = starts_all[offsets[0] : offsets[1] + 1]
        c0, c1, c2 = q[pi, 0] >> shift, q[pi, 1] >> shift, q[pi, 2] >> shift
        margin = size
        for a in range(3):  # how far inside its cell the query is (depth-21 steps)
            f = q[pi, a] - ((q[pi, a] >> shift) << shift)
            margin = min(margin, f, size - f - 1)
        r = 0
        while True:
            for i in range(max(c0 - r, 0), min(c0 + r, side - 1) + 1):
                for j in range(max(c1 - r, 0), min(c1 + r, side - 1) + 1):
                    for l in range(max(c2 - r, 0), min(c2 + r, side - 1) + 1):
                        if max(abs(i - c0), abs(j - c1), abs(l - c2)) != r:
                            continue  # scanned in an earlier ring
                        ck = _spread(i) | (_spread(j) << np.uint64(1)) | (_spread(l) << np.uint64(2))
                        u = np.searchsorted(cells, ck)
                        if u >= cells.size or cells[u] != ck:
                            continue
                        for t in range(starts[u], starts[u + 1]):
                            jj = order[t]
                            d = 0.0
                            for a in range(3):
                                e = points[jj, a] - points[pi, a]
                                d += e * e
                            if best_j[k - 1] >= 0 and not _before(d, points, jj, best_d, best_j, k - 1):
                                continue
                            s = k - 1
                            while s > 0 and (best_j[s - 1] < 0 or _before(d, points, jj, best_d, best_j, s - 1)):
                                best_d[s] = best_d[s - 1]
                                best_j[s] = best_j[s - 1]
                                s -= 1
                            best_d[s] = d
                            best_j[s] = jj
            # nothing outside the scanned block is nearer than this
            reach = (r * size + margin) * unit * (1.0 - 1e-9)
            everything = (c0 - r <= 0 and c1 - r <= 0 and c2 - r <= 0
                          and c0 + r >= side - 1 and c1 + r >= side - 1 and c2 + r >= side - 1)
            if everything or (best_j[k - 1] >= 0 and best_d[k - 1] <= reach * reach):
                break
            r += 1
            if r > RINGS:  # an isolated query: start again one level up
                v += 1
                shift += 1
                side = 1 << (MAX_DEPTH - shift)
                size = 1 << shift
                cells = cells_all[offsets[v] : offsets[v + 1]]
                starts = starts_all[offsets[v] + v : offsets[v + 1] + v + 1]
                c0, c1, c2 = q[pi, 0] >> shift, q[pi, 1] >> shift, q[pi, 2] >> shift
                margin = size
                for a in range(3):
                    f = q[pi, a] - ((q[pi, a] >> shift) << shift)
                    margin = min(margin, f, size - f - 1)
                best_d[:] = np.inf
                best_j[:] = -1
                r = 0
        for s in range(k):
            nb[m, s] = best_j[s]


def cell_shift(keys: np.ndarray, k: int) -> int:
    """``MAX_DEPTH`` minus the deepest level whose occupied cells hold at least ``k / 2`` of the sorted ``keys`` on average."""
    n = keys.size
    for level in range(MAX_DEPTH, 0, -1):
        c = keys >> np.uint64(3 * (MAX_DEPTH - level))
        if n >= (k / 2.0) * (1 + np.count_nonzero(c[1:] != c[:-1])):
            return MAX_DEPTH - level
    return MAX_DEPTH


def knn_in_cells(points: np.ndarray, q: np.ndarray, keys: np.ndarray, unit: float, query: np.ndarray, k: int,
                 order: np.ndarray | None = None) -> np.ndarray:
    """:func:`knn` for points whose octree coordinates are known.

    Parameters
    ----------
    points : (N, 3) float64
        Metres.
    q : (N, 3) int64
        Their depth-21 integer coordinates in a root cube (``unit`` metres
        a step: the cube's edge / 2**21), every point inside the cube.
    keys : (N,) uint64
        Their Morton keys, sorted (``keys[t]`` is the key of point
        ``order[t]``; ``order`` None: the points themselves are sorted).
    query : (M,) int64 and k : int
        The points whose neighbours are wanted, and how many (capped at N).

    Returns
    -------
    (M, k) int64
        Indices of each query's neighbours, nearest first (itself among them).
    """
    k = int(min(k, points.shape[0]))
    query = np.ascontiguousarray(query, dtype=np.int64)
    nb = np.zeros((query.size, k), dtype=np.int64)
    if query.size == 0 or k == 0:
        return nb
    shift = cell_shift(keys, k)
    c = keys >> np.uint64(3 * shift)
    first = np.flatnonzero(np.r_[True, c[1:] != c[:-1]])
    cells, starts = [c[first]], [np.r_[first, keys.size]]
    for _ in range(shift, MAX_DEPTH):  # every level above, from the one below: each cell's points start with its first child's
        up = cells[-1] >> np.uint64(3)
        head = np.flatnonzero(np.r_[True, up[1:] != up[:-1]])
        cells.append(up[head])
        starts.append(np.r_[starts[-1][head], keys.size])
    offsets = np.cumsum([0] + [a.size for a in cells]).astype(np.int64)
    order = np.arange(points.shape[0], dtype=np.int64) if order is None else np.ascontiguousarray(order, dtype=np.int64)
    _search(np.ascontiguousarray(points, dtype=np.float64), np.ascontiguousarray(q, dtype=np.int64), np.concatenate(cells),
            np.concatenate(starts).astype(np.int64), offsets, order, shift, float(unit), query, nb)
    return nb


def knn(points: np.ndarray, query: np.ndarray, k: int) -> np.ndarray:
    """Exact k nearest neighbours of some points of a cloud, nearest first, ties broken by coordinates.

    Parameters
    ----------
    points : (N, 3) float64
        The cloud (metres).
    query : (M,) int64
        Indices of the points whose neighbours are wanted.
    k : int
        Neighbours per point, the point itself included (capped at N).

    Returns
    -------
    (M, k) int64
        Indices into ``points``.
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    lo = points.min(axis=0)
    edge = float(np.max(points.max(axis=0) - lo))
    edge = edge * (1.0 + 1e-9) + 1e-9  # every point strictly inside the cube
    q = quantize(points - lo, edge)
    keys = encode(q)
    order = np.argsort(keys, kind="stable")
    return knn_in_cells(points, q, keys[order], edge / 2.0**MAX_DEPTH, query, k, order)
