"""Point-wise normals for points no patch surface models (edge and sparse leaves).

The paper leaves these points without a normal; here each gets the PCA
normal of its ``k`` nearest neighbours (:mod:`.knn`), the surface
variation of that neighbourhood, and principal curvatures from a quadric
fitted to the neighbourhood in its PCA frame.
"""

from __future__ import annotations

import numpy as np

from . import _kernels
from .knn import PointGrid, near_queries, nearest_neighbours, point_grid
from .morton import MAX_DEPTH, decode, encode

__all__ = ["knn_normals", "points_near"]


def points_near(q: np.ndarray, keys: np.ndarray, level: int, query: np.ndarray, reach: int = 1) -> np.ndarray:
    """Indices of the sorted points in the cells around the query points.

    Cells are those of octree ``level``; every cell within ``reach`` cells
    (per axis) of a query point's cell is taken, so any point closer to a
    query than ``reach`` cell edges is among the result.

    Parameters
    ----------
    q : (N, 3) int64 and keys : (N,) uint64
        Depth-21 integer coordinates and Morton keys of the points, sorted by key.
    level : int
    query : (M,) int64 indices of the query points.
    """
    shift = MAX_DEPTH - level
    cells = np.unique(encode(q[query] >> shift))
    cells = decode(cells)
    r = np.arange(-reach, reach + 1)
    steps = np.stack(np.meshgrid(r, r, r, indexing="ij"), axis=-1).reshape(-1, 3)
    around = (cells[:, None, :] + steps[None, :, :]).reshape(-1, 3)
    around = around[np.all((around >= 0) & (around < (1 << level)), axis=1)]
    wanted = np.unique(encode(around))
    # the points of a cell are one run of the sorted keys
    s3 = np.uint64(3 * shift)
    lo = np.searchsorted(keys, wanted << s3)
    hi = np.searchsorted(keys, (wanted + np.uint64(1)) << s3)
    size = hi - lo
    total = int(size.sum())
    offsets = np.cumsum(size) - size
    return np.repeat(lo - offsets, size) + np.arange(total)


def knn_normals(
    points: np.ndarray, query: np.ndarray, k: int, grid: tuple[np.ndarray, np.ndarray, int, float] | None = None,
    chunk: int = 65536, near: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """k-nearest-neighbour PCA normals of some points of a cloud.

    Parameters
    ----------
    points : (N, 3) float64
        The whole cloud (metres, local frame).
    query : (M,) int64
        Indices of the points that need a normal.
    k : int
        Neighbours per point, the point itself included (capped at N).
    grid : (q, keys, level, cell_edge), optional
        The points' depth-21 coordinates and Morton keys (``points`` sorted
        by key) and an octree level with its cell edge: the search then runs
        on the points of the cells around the queries only (see
        :func:`points_near`), widening for the queries whose k-th neighbour
        lies beyond; the result is the same as a search in the whole cloud.
    near : float, optional
        Without ``grid``: a distance (metres) within which most queries
        have their ``k`` neighbours.  Few queries (at most a tenth of the
        points) are then searched among the points within ``near`` of them
        only, widening fourfold for those whose k-th neighbour lies beyond:
        the same result as a search in the whole cloud, without indexing
        all of it for a handful of points.

    Returns
    -------
    normals : (M, 3) float64, unit, unoriented (``n . (0.001, 0.01, 1) >= 0``)
    sigma3 : (M,) surface variation of the neighbourhood
    k1, k2 : (M,) principal curvatures of the neighbourhood quadric (1/unit of the coordinates),
        "convex positive" with respect to ``normals``
    dir1 : (M, 3) direction of ``k1``
    neighbours : (M, k) int64 indices of the neighbours
    """
    n = points.shape[0]
    k = int(min(k, n))
    m = query.shape[0]
    normals = np.zeros((m, 3))
    sigma3 = np.zeros(m)
    k1 = np.zeros(m)
    k2 = np.zeros(m)
    dir1 = np.zeros((m, 3))
    neighbours = np.zeros((m, k), dtype=np.int64)
    if m == 0:
        return normals, sigma3, k1, k2, dir1, neighbours
    if m > n // 10:
        grid = near = None  # many queries: one tree over the whole cloud is cheaper than cells
    whole: list[PointGrid] = []  # the whole-cloud grid, built at most once
    for lo in range(0, m, chunk):
        qi = query[lo : lo + chunk]
        nb = _knn_near(points, qi, k, float(near), whole) if near is not None and grid is None else _knn(points, qi, k, grid, whole)
        neighbours[lo : lo + chunk] = nb
        hi = lo + qi.size
        _kernels.knn_pca(points, qi, nb, normals[lo:hi], sigma3[lo:hi], k1[lo:hi], k2[lo:hi], dir1[lo:hi])
    return normals, sigma3, k1, k2, dir1, neighbours


def _knn_near(points, qi, k, reach: float, whole: list) -> np.ndarray:
    """Exact k nearest neighbours of ``points[qi]`` among the points within ``reach`` (metres) of them, widening as needed."""
    subset = np.flatnonzero(near_queries(points, points[qi], reach)) if reach > 0 and np.isfinite(reach) else None
    if subset is None or 4 * subset.size > points.shape[0]:  # most of the cloud: index all of it, once
        return _knn(points, qi, k, None, whole)
    dist, nb = nearest_neighbours(point_grid(points[subset], k, ids=subset), points[qi], k)  # inf where fewer than k
    far = np.flatnonzero(dist[:, -1] >= 0.999 * reach)  # (a margin for the rounding of the cells that found the subset)
    if far.size:
        nb[far] = _knn_near(points, qi[far], k, 4.0 * reach, whole)
    return nb


def _knn(points, qi, k, grid, whole: list, reach: int = 1) -> np.ndarray:
    """Exact k nearest neighbours of ``points[qi]``, searched in as few cells as possible.

    ``whole`` caches the grid over the whole cloud between calls.
    """
    if grid is None:
        if not whole:
            whole.append(point_grid(points, k))
        return nearest_neighbours(whole[0], points[qi], k)[1]
    q, keys, level, h = grid
    subset = points_near(q, keys, level, qi, reach)
    dist, nb = nearest_neighbours(point_grid(points[subset], k, ids=subset), points[qi], k)  # inf where fewer than k
    far = np.flatnonzero(dist[:, -1] > reach * h)
    if far.size:
        nxt = reach * 4
        # the cells around the queries would be many (a lone point: (2 reach + 1)^3 cells each): the points within a
        # distance of them instead, found in one pass over the cloud (a grid over all of it costs a sort of the cloud)
        if nxt >= (1 << level) or far.size > 256 or far.size * (2 * nxt + 1) ** 3 > 1 << 20:
            nb[far] = _knn_near(points, qi[far], k, nxt * h, whole)
        else:
            nb[far] = _knn(points, qi[far], k, grid, whole, nxt)
    return nb
