"""Exact k nearest neighbours on an octree of cells (compiled), for the k-NN fallback and its orientation.

The points are sorted by the Morton key of their cell in a grid whose
cells hold about ``k`` points each; a cell of any coarser level is then one
run of that order.  A query visits the cells of the finest level ring by
ring (Chebyshev distance 0, 1, 2 from its own cell) and stops when its
k-th nearest point so far is closer than any point of the next ring can
be; when two rings are not enough (an isolated point, a sparse region) it
starts again at the next coarser level, up to the root, which holds every
point: so an outlier costs a few levels, not a walk through empty cells.
Neighbours come sorted by distance, ties by index, so the result is one
answer whatever the order the cells were visited in and the thread count.

An octree's points are already sorted by Morton key, so their index needs
no sort (:func:`sorted_point_grid`: a cell is a run of the keys' prefixes),
and several indexes can be searched as one (:func:`nearest_neighbours` of
a sequence: a tile's own points, then its neighbours' few), each search
starting from the lists the ones before left.
This replaces scipy's cKDTree, whose import alone (``scipy.spatial``,
0.15 s) was a sixth of a whole run on a small file.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from . import _kernels
from .argsort import stable_argsort
from .morton import MAX_DEPTH, encode
from .octree import level_occupancy
from .threads import parallel_kernel

#: ``np.iinfo(np.int64).min`` as a plain int: a kernel that calls ``np.iinfo`` makes numba import
#: numba.np.arraymath (0.3 s) whenever its cached code is loaded.
_INT64_MIN = -(2**63)

__all__ = ["PointGrid", "point_grid", "sorted_point_grid", "nearest_neighbours", "near_queries"]


@dataclass(frozen=True)
class PointGrid:
    """Points sorted by the Morton key of their cell: the index :func:`nearest_neighbours` searches.

    Attributes
    ----------
    points : (N, 3) float64
        The points, in key order.
    ids : (N,) int64
        Their indices in the caller's array.
    cells : (C,) uint64
        The occupied cells' Morton keys (level ``levels``), ascending.
    starts : (C + 1,) int64
        Where each cell's points begin in ``points``.
    corner : (3,) float64
        The low corner of the root cube.
    edge : float
        The cells' edge (the points' unit); the root cube's is ``edge * 2**levels``.
    levels : int
        The cells' level below the root cube (0 to 21).
    scale : float
        Cells per unit of length, as the points' cells were found: a point
        lies in cell ``floor((p - corner) * scale)`` (about ``1 / edge``;
        the search finds a query's cells the same way, so both agree to the
        last bit).
    """

    points: np.ndarray
    ids: np.ndarray
    cells: np.ndarray
    starts: np.ndarray
    corner: np.ndarray
    edge: float
    levels: int
    scale: float


def _cell_numbers(points: np.ndarray, corner: np.ndarray, span: np.ndarray, edge: float) -> np.ndarray:
    """One number per cell of edge ``edge`` from ``corner``, for the points (N, 3) in ``[corner, corner + span]``."""
    ijk = np.floor((points - corner) / edge).astype(np.int64)
    dims = np.floor(span / edge).astype(np.int64) + 1
    return (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]


def point_grid(points: np.ndarray, k: int, ids: np.ndarray | None = None) -> PointGrid:
    """Bucket ``points`` ((N, 3) float64) into cells holding about ``k`` points each.

    The edge is found from the occupancy (points per occupied cell) of a
    strided sample of at most 32,767 points: a few secant steps in log-log
    find the edge where the sample holds about max(k / stride, 8) points per
    cell (enough to measure it), and the growth of the occupancy there (the
    edge squared on surfaces, cubed in volumes) takes it down to ``k``
    points of the whole cloud per cell.
    ``ids``: the points' indices to report (default 0 to N-1).

    >>> g = point_grid(np.random.default_rng(0).uniform(0, 10, (1000, 3)), k=8)
    >>> int(g.starts[-1]), bool(np.all(np.diff(g.cells) > 0))
    (1000, True)
    """
    pts = np.ascontiguousarray(points, dtype=np.float64)
    n = len(pts)
    ids = np.arange(n, dtype=np.int64) if ids is None else np.asarray(ids, dtype=np.int64)
    corner, top = _kernels.bounds(pts)[:2] if n else (np.zeros(3), np.zeros(3))
    extent = float(np.max(top - corner)) if n else 0.0
    if n == 0 or extent == 0.0:
        edge = 1.0
    else:
        span = np.maximum(top - corner, extent * 1e-6)
        want = float(max(k, 1))
        step = max(1, n // 16384)
        sample = pts[::step]
        goal = max(want / step, 8.0)  # sample points per cell where the sample still measures the occupancy

        def per_cell(e: float) -> float:  # sample points per occupied cell at edge e
            return len(sample) / np.unique(_cell_numbers(sample, corner, span, e)).size

        edge = float(np.cbrt(np.prod(span) * goal * step / n))
        got, growth = per_cell(edge), 2.0  # as for points on surfaces
        for _ in range(8):  # secant steps in log-log: the occupancy grows as edge**growth, growth 1 (lines) to 3 (volumes)
            if 0.7 * goal <= got <= 1.5 * goal:
                break
            nxt = edge * float(np.clip((goal / got) ** (1.0 / growth), 1 / 64, 64))
            now = per_cell(nxt)
            if now != got:
                growth = float(np.clip(np.log(now / got) / np.log(nxt / edge), 1.0, 3.0))
            edge, got = nxt, now
        half = per_cell(edge / 2)  # the growth at this scale, to go down to want points per cell of the whole cloud
        growth = float(np.clip(np.log2(got / half), 1.0, 3.0)) if half < got else 2.0
        edge *= float((want / (got * step)) ** (1.0 / growth))
    edge = max(edge, extent * 2.0 ** -21, np.finfo(np.float64).tiny)
    levels = int(np.clip(np.ceil(np.log2(max(extent, edge) / edge)), 0, 21)) if n else 0
    edge = max(edge, extent / 2.0**levels * (1.0 + 1e-12))  # the root cube holds every point
    scale = 1.0 / edge
    q = np.clip(np.floor((pts - corner) * scale), 0, 2**levels - 1).astype(np.int64) if n else np.zeros((0, 3), np.int64)
    keys = encode(q)
    order = stable_argsort(keys)
    keys = keys[order]
    first = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]]) if n else np.zeros(0, np.int64)
    return PointGrid(points=pts[order], ids=ids[order], cells=keys[first], starts=np.r_[first, n].astype(np.int64),
                     corner=corner.astype(np.float64), edge=float(edge), levels=levels, scale=scale)


def sorted_point_grid(points: np.ndarray, keys: np.ndarray, edge: float, k: int, ids: np.ndarray | None = None) -> PointGrid:
    """The :class:`PointGrid` of points already sorted by Morton key: no sort, one pass over the keys.

    Parameters
    ----------
    points : (N, 3) float64
        Points relative to the low corner of a cube of ``edge``, sorted by ``keys``
        (an octree's sorted points, or a subset of them in the same order).
    keys : (N,) uint64
        Their depth-21 Morton keys in that cube, as :func:`patchcloud.core.octree.point_keys` gives them, ascending.
    edge : float
        The cube's edge.
    k : int
        About how many points a cell should hold: the level is the one
        whose occupied cells hold, on average, nearest to ``k`` points
        (in ratio).
    ids : (N,) int64, optional
        The points' indices to report (default 0 to N-1).

    A point's cell is its key's prefix, and the search finds a query's
    cell with the same arithmetic as :func:`~patchcloud.core.octree.point_keys`
    (scaled by a power of two, exactly), so the neighbours are those of a
    search in a grid of the same cells built by sorting.

    >>> from patchcloud.core.octree import sort_points
    >>> pts = np.random.default_rng(0).uniform(0, 8, (500, 3))
    >>> order, keys, _ = sort_points(pts, np.zeros(3), 8.0)
    >>> g = sorted_point_grid(pts[order], keys, 8.0, k=8, ids=order)
    >>> q = np.array([[4.0, 4.0, 4.0]])
    >>> bool((nearest_neighbours(g, q, 5)[1] == nearest_neighbours(point_grid(pts, 8), q, 5)[1]).all())
    True
    """
    pts = np.ascontiguousarray(points, dtype=np.float64)
    keys = np.ascontiguousarray(keys, dtype=np.uint64)
    n = pts.shape[0]
    ids = np.arange(n, dtype=np.int64) if ids is None else np.ascontiguousarray(ids, dtype=np.int64)
    level = 0
    if n:
        occupied = np.asarray(level_occupancy(keys), dtype=np.float64)  # occupied cells at levels 0 to 21
        level = int(np.argmin(np.abs(np.log(n / occupied) - np.log(max(k, 1)))))
    shift = 3 * (MAX_DEPTH - level)
    first = _kernels.run_starts(keys, shift)
    scale = (2.0**MAX_DEPTH / edge) * 2.0 ** (level - MAX_DEPTH)  # point_keys' scale, then a power of two: exact
    return PointGrid(points=pts, ids=ids, cells=keys[first] >> np.uint64(shift), starts=np.r_[first, n].astype(np.int64),
                     corner=np.zeros(3), edge=float(edge) / 2.0**level, levels=level, scale=float(scale))


def near_queries(points: np.ndarray, queries: np.ndarray, reach: float) -> np.ndarray:
    """Which ``points`` may lie within ``reach`` of a query: a superset, found without a search.

    A point is kept when its cell, in a grid of cells of edge ``reach``, is
    one of the 27 around a query's cell; so every point within ``reach`` of
    a query is kept.  Searching the points kept instead of all of them
    gives the same neighbours within ``reach`` at a fraction of the cost
    when the queries are few.  (N, 3) and (M, 3) float64 in, (N,) bool out.

    >>> near_queries(np.array([[0.0, 0, 0], [2.5, 0, 0], [9.0, 0, 0]]), np.array([[1.0, 0, 0]]), 1.0).tolist()
    [True, False, False]
    """
    pts = np.asarray(points, dtype=np.float64)
    q = np.asarray(queries, dtype=np.float64).reshape(-1, 3)
    keep = np.zeros(len(pts), dtype=bool)
    if len(q) == 0 or len(pts) == 0 or not reach > 0:
        return keep
    low, high = _kernels.bounds(np.ascontiguousarray(q))[:2]  # numpy's min over axis 0 of (M, 3) is several times slower
    lo, hi = low - reach, high + reach
    dims = np.floor((hi - lo) / reach).astype(np.int64) + 1

    def number(ijk):
        return (ijk[..., 0] * dims[1] + ijk[..., 1]) * dims[2] + ijk[..., 2]

    cells = np.minimum(np.floor((q - lo) / reach).astype(np.int64), dims - 1)
    if len(cells) > 64:  # queries in the same cell want the same 27 cells: each cell once
        u = np.unique(number(cells))
        cells = np.column_stack([u // (dims[1] * dims[2]), (u // dims[2]) % dims[1], u % dims[2]])
    r = np.arange(-1, 2)
    steps = np.stack(np.meshgrid(r, r, r, indexing="ij"), axis=-1).reshape(-1, 3)
    around = number(np.clip(cells[:, None, :] + steps[None, :, :], 0, dims - 1))
    total = float(np.prod(dims.astype(np.float64)))
    if total <= 4.0 * (around.size + len(pts)) + 4096:  # a mask of every cell of the box costs less than sorting
        mask = np.zeros(int(total), dtype=bool)
        mask[around.ravel()] = True
        wanted = np.zeros(0, dtype=np.int64)
    else:
        mask = np.zeros(0, dtype=bool)
        wanted = np.unique(around)
    _keep_near(np.ascontiguousarray(pts), lo, hi, float(reach), dims, mask, wanted, keep)
    return keep


@njit(cache=True, nogil=True)
def _keep_near(pts, lo, hi, reach, dims, mask, wanted, keep):
    """:func:`near_queries`' last step, one pass: ``keep[i]`` where point ``i`` lies in the box ``[lo, hi]`` and its cell
    (edge ``reach`` from ``lo``, numbered row by row) is wanted: ``mask[cell]``, or, where ``mask`` is empty, ``cell`` in
    the sorted ``wanted``."""
    dense = mask.size > 0
    for i in range(pts.shape[0]):
        x, y, z = pts[i, 0], pts[i, 1], pts[i, 2]
        if not (x >= lo[0] and x <= hi[0] and y >= lo[1] and y <= hi[1] and z >= lo[2] and z <= hi[2]):
            continue
        a = min(int(np.floor((x - lo[0]) / reach)), dims[0] - 1)
        b = min(int(np.floor((y - lo[1]) / reach)), dims[1] - 1)
        c = min(int(np.floor((z - lo[2]) / reach)), dims[2] - 1)
        cell = (a * dims[1] + b) * dims[2] + c
        if dense:
            keep[i] = mask[cell]
        else:
            at = _kernels.lower_bound(wanted, cell)
            keep[i] = at < wanted.size and wanted[at] == cell


def nearest_neighbours(
    grid: PointGrid | Sequence[PointGrid], queries: np.ndarray, k: int, max_distance: float = np.inf,
) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` points of ``grid`` nearest to each query, nearest first (ties: smaller index first).

    Parameters
    ----------
    grid : PointGrid, or a sequence of them
        Several grids are searched as one grid of all their points would
        be (their ids should then differ): a tile's points, sorted already,
        and its neighbours' few, say.
    queries : (M, 3) float64
        Anywhere (inside the grid's box or not).
    k : int
        Neighbours per query (a query that is one of the points finds itself first).
    max_distance : float
        Points farther are not neighbours.

    Returns
    -------
    distances : (M, k) float64, ``inf`` where fewer than ``k`` points lie within ``max_distance``
    indices : (M, k) int64, the points' ``ids``; -1 where there is none

    Examples
    --------
    >>> pts = np.array([[0.0, 0, 0], [1, 0, 0], [3, 0, 0], [0, 2, 0]])
    >>> d, i = nearest_neighbours(point_grid(pts, k=2), np.array([[0.9, 0, 0]]), k=3)
    >>> i.tolist(), d.round(3).tolist()
    ([[1, 0, 2]], [[0.1, 0.9, 2.1]])
    >>> nearest_neighbours(point_grid(pts, k=2), np.array([[0.9, 0, 0]]), k=3, max_distance=1.0)[1].tolist()
    [[1, 0, -1]]
    """
    q = np.ascontiguousarray(queries, dtype=np.float64).reshape(-1, 3)
    k = int(k)
    if k < 1:
        raise ValueError(f"k must be at least 1; got {k}")
    grids = [grid] if isinstance(grid, PointGrid) else list(grid)
    dist = np.full((len(q), k), np.inf)
    idx = np.full((len(q), k), -1, dtype=np.int64)
    limit = float(max_distance) ** 2 if np.isfinite(max_distance) else np.inf
    for g in grids:  # each grid's points offered to the lists the grids before left (the same as one grid of them all)
        if len(q) and len(g.ids):
            _search(g.points, g.ids, g.cells, g.starts, g.corner, float(g.edge), float(g.scale), g.levels, q, limit, dist.copy(),
                    idx.copy(), dist, idx)
    np.sqrt(dist, out=dist)
    return dist, idx


@njit(cache=True, nogil=True)
def _offer(points, ids, a, b, qx, qy, qz, limit, bd, bi):
    """Offer points ``a`` to ``b`` to the lists ``bd`` (squared distances) and ``bi``, kept sorted by (distance, index)."""
    k = bd.size
    for p in range(a, b):
        dx = points[p, 0] - qx
        dy = points[p, 1] - qy
        dz = points[p, 2] - qz
        d = dx * dx + dy * dy + dz * dz
        if d > limit:
            continue
        i = ids[p]
        j = k - 1  # an empty place holds (inf, -1) and sorts last
        if not (d < bd[j] or (d == bd[j] and i < bi[j])):
            continue
        while j > 0 and (d < bd[j - 1] or (d == bd[j - 1] and i < bi[j - 1])):
            bd[j] = bd[j - 1]
            bi[j] = bi[j - 1]
            j -= 1
        bd[j] = d
        bi[j] = i


@njit(cache=True, nogil=True)
def _rings(points, ids, cells, starts, corner, edge, scale, level, levels, qx, qy, qz, limit, bd, bi, rings, memo, memo_of):
    """Rings 0 to ``rings - 1`` (at most 2) of the cells of ``level`` (edge ``edge``, ``scale`` cells per unit) around the query; True when the lists are final.

    ``memo`` (125, 2) holds the point ranges of the 5 x 5 x 5 cells around
    the cell ``memo_of`` (4,: level and cell), -2 where not looked up yet:
    the queries come in space order, so most share the last one's cell and
    its neighbours' ranges (a cell lookup is two binary searches).
    """
    n = np.int64(1) << np.int64(level)
    shift = np.uint64(3 * (levels - level))
    fx = (qx - corner[0]) * scale
    fy = (qy - corner[1]) * scale
    fz = (qz - corner[2]) * scale
    cx = np.int64(np.floor(fx))
    cy = np.int64(np.floor(fy))
    cz = np.int64(np.floor(fz))
    # the query's distance to the nearest face of its own cell: a point beyond ring r is at least r edges farther
    inner = min(min(min(fx - cx, cx + 1 - fx), min(fy - cy, cy + 1 - fy)), min(fz - cz, cz + 1 - fz)) * edge
    far = max(max(max(abs(cx), abs(cx - n + 1)), max(abs(cy), abs(cy - n + 1))), max(abs(cz), abs(cz - n + 1)))
    if memo_of[0] != level or memo_of[1] != cx or memo_of[2] != cy or memo_of[3] != cz:
        memo_of[0], memo_of[1], memo_of[2], memo_of[3] = level, cx, cy, cz
        memo[:, 0] = -2
    k = bd.size
    for r in range(rings):
        for i in range(max(cx - r, 0), min(cx + r, n - 1) + 1):
            gx = max(max(i - fx, fx - (i + 1)), 0.0)  # the query's distance to the cells' slab, in edges
            for j in range(max(cy - r, 0), min(cy + r, n - 1) + 1):
                gy = max(max(j - fy, fy - (j + 1)), 0.0)
                side = abs(i - cx) == r or abs(j - cy) == r
                for t in range(2 * r + 1 if side else 2):
                    z = cz - r + t if side else (cz - r if t == 0 else cz + r)
                    if z < 0 or z >= n:
                        continue
                    # a cell whose every point would be farther than the limit or than the k-th nearest so far
                    # (with a margin for rounding, and a tie kept: it may hold a smaller index) is not looked up
                    gz = max(max(z - fz, fz - (z + 1)), 0.0)
                    gap = (gx * gx + gy * gy + gz * gz) * edge * edge * (1.0 - 1e-9)
                    if gap > limit or gap > bd[k - 1]:
                        continue
                    slot = ((i - cx + 2) * 5 + (j - cy + 2)) * 5 + (z - cz + 2)
                    if memo[slot, 0] == -2:
                        key = _kernels.morton_key(i, j, z) << shift
                        a = _kernels.lower_bound(cells, key)
                        if shift == 0:  # a finest cell: one key
                            b = a + 1 if a < cells.size and cells[a] == key else a
                        else:
                            b = _kernels.lower_bound(cells, key + (np.uint64(1) << shift))
                        memo[slot, 0], memo[slot, 1] = starts[a], starts[b]
                    if memo[slot, 1] > memo[slot, 0]:
                        _offer(points, ids, memo[slot, 0], memo[slot, 1], qx, qy, qz, limit, bd, bi)
        reach = r * edge + inner
        if r >= far or reach * reach >= limit:
            return True  # every cell of the grid seen, or the rest beyond max_distance
        if bi[bd.size - 1] >= 0 and bd[bd.size - 1] <= reach * reach:
            return True
    return False


@njit(cache=True, nogil=True)
def _any_near(cells, level, levels, cx, cy, cz):
    """1 when any point lies in the 27 cells of ``level`` around the cell ``(cx, cy, cz)`` (its own first), else 0."""
    n = np.int64(1) << np.int64(level)
    shift = np.uint64(3 * (levels - level))
    for t in range(27):
        u = (t + 13) % 27  # 13: the query's own cell, (0, 0, 0)
        i, j, z = cx + u // 9 - 1, cy + (u // 3) % 3 - 1, cz + u % 3 - 1
        if i < 0 or j < 0 or z < 0 or i >= n or j >= n or z >= n:
            continue
        key = _kernels.morton_key(i, j, z) << shift
        a = _kernels.lower_bound(cells, key)
        if a < cells.size and cells[a] < key + (np.uint64(1) << shift):
            return 1
    return 0


@parallel_kernel
def _search(points, ids, cells, starts, corner, edge, scale, levels, queries, limit, dist0, idx0, dist, idx):
    # dist0, idx0: the lists before this grid's points (a restart goes back to them); dist, idx: the lists, in place
    # scale: the grid's cells per unit of length (about 1 / edge), as its points' cells were found
    # with a finite limit: the level whose cells are the smallest at least sqrt(limit) wide, where the 27 cells
    # around a query hold every point within the limit, so a query with none there is done at once, and the others
    # search rings 0 and 1 of that level, no second try (on real aerial files faster than rings 0 to 2 of cells
    # half as wide, now that cell lookups are kept; both the same neighbours)
    coarse = -1
    coarse_edge, coarse_scale = edge, scale
    rings = 3
    if limit < np.inf:
        coarse = levels
        while coarse > 0 and coarse_edge * coarse_edge < limit:
            coarse -= 1
            coarse_edge *= 2.0
            coarse_scale *= 0.5
        rings = 2
    first, first_edge, first_scale = (levels, edge, scale) if coarse < 0 else (coarse, coarse_edge, coarse_scale)
    M = queries.shape[0]
    for chunk in prange((M + _kernels.CHUNK - 1) // _kernels.CHUNK):  # a memo of cell ranges per chunk of queries
        memo = np.empty((125, 2), dtype=np.int64)
        memo_of = np.full(4, -1, dtype=np.int64)
        near_of = np.array([_INT64_MIN, 0, 0, 0], dtype=np.int64)  # the coarse cell last tested, and the answer
        for m in range(chunk * _kernels.CHUNK, min(M, (chunk + 1) * _kernels.CHUNK)):
            bd = dist[m]
            bi = idx[m]
            if coarse >= 0:  # whether any point lies in the 27 cells around the query's (once per cell: they come in runs)
                qc0 = np.int64(np.floor((queries[m, 0] - corner[0]) * coarse_scale))
                qc1 = np.int64(np.floor((queries[m, 1] - corner[1]) * coarse_scale))
                qc2 = np.int64(np.floor((queries[m, 2] - corner[2]) * coarse_scale))
                if qc0 != near_of[0] or qc1 != near_of[1] or qc2 != near_of[2]:
                    near_of[0], near_of[1], near_of[2] = qc0, qc1, qc2
                    near_of[3] = _any_near(cells, coarse, levels, qc0, qc1, qc2)
                if near_of[3] == 0:
                    continue
            level = first
            e = first_edge
            sc = first_scale
            while True:
                if level == 0:  # the root cell: every point
                    _offer(points, ids, 0, points.shape[0], queries[m, 0], queries[m, 1], queries[m, 2], limit, bd, bi)
                    break
                if _rings(points, ids, cells, starts, corner, e, sc, level, levels, queries[m, 0], queries[m, 1], queries[m, 2],
                          limit, bd, bi, rings, memo, memo_of):
                    break
                # two rings were not enough: start again on cells twice as large (the root cell holds every point)
                bd[:] = dist0[m]
                bi[:] = idx0[m]
                level -= 1
                e *= 2.0
                sc *= 0.5
