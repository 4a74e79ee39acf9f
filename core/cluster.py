"""Euclidean clustering: connected components of the points under a distance tolerance.

Two points are in one cluster when a chain of points links them with every
step at most ``tolerance`` long (PCL's ``EuclideanClusterExtraction``, PDAL's
``filters.cluster``).  The points are bucketed in cells of edge
``tolerance / sqrt(3)``, inside which every pair is within tolerance, so a
cell is one node of a union-find; neighbouring cells are joined as soon as
one pair of their points is close enough.
"""

from __future__ import annotations

import numpy as np

from . import _radius_kernels as _rk
from .grid import CellGrid
from .checks import check_cluster_sizes, check_radius
from .radius import check_grid_step, check_points, tie_margin

__all__ = ["euclidean_clusters", "components", "number_by_first"]


def _half_offsets(reach: int, edge: float, tol: float) -> np.ndarray:
    """Cell offsets after (0, 0, 0) in lexicographic order whose cells can hold a point within ``tol``."""
    r = np.arange(-reach, reach + 1)
    o = np.stack(np.meshgrid(r, r, r, indexing="ij"), axis=-1).reshape(-1, 3)
    after = (o[:, 0] > 0) | ((o[:, 0] == 0) & ((o[:, 1] > 0) | ((o[:, 1] == 0) & (o[:, 2] > 0))))
    gap = np.maximum(np.abs(o) - 1, 0) * edge  # smallest distance between the two cells per axis
    near = (gap**2).sum(axis=1) <= tol * tol
    return o[after & near].astype(np.int64)


def components(points: np.ndarray, tolerance: float, grid_step: float = 0.0) -> np.ndarray:
    """Connected components of ``points`` under ``tolerance``, numbered 0.. by their first point.

    ``grid_step``: the step of the grid the coordinates lie on (a LAS
    file's smallest scale; 0: none): two points exactly ``tolerance``
    apart are then linked whatever the rounding of the coordinates' frame
    (:func:`~patchcloud.core.radius.tie_margin`).

    Returns
    -------
    (N,) int64
        Component of each point; component ``c`` is the ``c``-th to appear
        in the order of ``points``.
    """
    pts = check_points(points)
    tol = check_radius("tolerance", tolerance)
    n = pts.shape[0]
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    edge = tol / np.sqrt(3.0) * (1.0 - 1e-12)
    g = CellGrid.build(pts, edge, pad=2, grid_step=grid_step)
    parent = np.arange(g.keys.size, dtype=np.int64)
    limit = tol * tol + tie_margin(grid_step)
    _rk.union_cells(pts[g.order], g.keys, g.start, g.cells, g.dims, _half_offsets(2, edge, np.sqrt(limit)), limit, parent)
    # roots of every cell (the kernel compresses paths only on the way)
    root = parent.copy()
    while True:
        nxt = root[root]
        if np.array_equal(nxt, root):
            break
        root = nxt
    cell_of_sorted = np.repeat(np.arange(g.keys.size), np.diff(g.start))
    raw = np.empty(n, dtype=np.int64)
    raw[g.order] = root[cell_of_sorted]
    return number_by_first(raw)


def number_by_first(labels: np.ndarray) -> np.ndarray:
    """Renumber labels 0.. in order of first appearance (the numbering of :func:`components`)."""
    labels = np.asarray(labels)
    if labels.size == 0:
        return np.zeros(0, dtype=np.int64)
    uniq, first, inv = np.unique(labels, return_index=True, return_inverse=True)
    rank = np.empty(uniq.size, dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(uniq.size)
    return rank[inv.reshape(-1)]


def euclidean_clusters(
    points: np.ndarray, tolerance: float, *, min_points: int = 1, max_points: int | None = None, grid_step: float | None = None,
) -> np.ndarray:
    """Cluster id of every point: 1, 2, ... in order of each cluster's first point; 0 for none.

    Parameters
    ----------
    points : (N, 3) array, or laspy.LasData
        Coordinates (metres).
    tolerance : float
        Largest step (metres) between two points of one cluster.
    min_points, max_points : int
        Clusters with fewer than ``min_points`` or more than ``max_points``
        points are dropped (their points get 0).
    grid_step : float, optional
        The step of the grid the coordinates lie on (default: a
        ``laspy.LasData``'s smallest scale, else 0), as :func:`components`.

    Returns
    -------
    (N,) int64

    Examples
    --------
    >>> import numpy as np
    >>> euclidean_clusters(np.array([[0, 0, 0], [0.1, 0, 0], [5, 0, 0.0]]), 0.2).tolist()
    [1, 1, 2]
    >>> euclidean_clusters(np.array([[0, 0, 0], [0.1, 0, 0], [5, 0, 0.0]]), 0.2, min_points=2).tolist()
    [1, 1, 0]
    """
    min_points, max_points = check_cluster_sizes(min_points, max_points)
    comp = components(points, tolerance, check_grid_step(points, grid_step))
    if comp.size == 0:
        return comp
    size = np.bincount(comp)
    ok = size >= min_points
    if max_points is not None:
        ok &= size <= max_points
    ids = np.zeros(size.size, dtype=np.int64)
    ids[ok] = np.arange(1, int(ok.sum()) + 1)
    return ids[comp]
