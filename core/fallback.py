"""Point-wise normals for points no patch surface models (edge and sparse leaves).

The paper leaves these points without a normal; here each gets the PCA
normal of its ``k`` nearest neighbours (:mod:`.knn`), the surface
variation of that neighbourhood, and principal curvatures from a quadric
fitted to the neighbourhood in its PCA frame.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from . import _kernels
from .knn import PointGrid, nearest_neighbours, point_grid

__all__ = ["knn_normals", "coincident", "COINCIDENT"]


def knn_normals(
    points: np.ndarray, query: np.ndarray, k: int, grids: Sequence[PointGrid] | None = None, chunk: int = 65536,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """k-nearest-neighbour PCA normals of some points of a cloud.

    Parameters
    ----------
    points : (N, 3) float64
        The whole cloud (metres, local frame).
    query : (M,) int64
        Indices of the points that need a normal.
    k : int
        Neighbours per point, the point itself included (capped at N).
    grids : sequence of PointGrid, optional
        The search index: grids that hold every point once between them,
        with their rows of ``points`` as ids (a tile's sorted points as
        :func:`~patchcloud.core.knn.sorted_point_grid` indexes them without
        a sort, and its skin's); default: :func:`~patchcloud.core.knn.point_grid`
        of ``points``.  The neighbours are the same either way.

    Returns
    -------
    normals : (M, 3) float64, unit, unoriented (``n . (0.001, 0.01, 1) >= 0``); zeros where not ``defined``
    sigma3 : (M,) surface variation of the neighbourhood
    k1, k2 : (M,) principal curvatures of the neighbourhood quadric (1/unit of the coordinates),
        "convex positive" with respect to ``normals``
    dir1 : (M, 3) direction of ``k1``
    neighbours : (M, k) int64 indices of the neighbours
    defined : (M,) bool
        False where the neighbours are coincident (duplicates: their spread
        is the rounding of their coordinates, :func:`coincident`): they say
        nothing of a direction, so there is no normal; every output of that
        row is then zero.  Collinear neighbours (a wire) still give a unit
        normal perpendicular to their line.

    Examples
    --------
    >>> pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5], [5, 5, 5], [5, 5, 5]])
    >>> res = knn_normals(pts, np.array([0, 3]), 3)  # point 0 and its nearest: a plane; point 3's: three copies of it
    >>> res[6].tolist(), res[0][0].round(6).tolist(), res[0][1].tolist()
    ([True, False], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0])
    """
    n = points.shape[0]
    k = int(min(k, n))
    m = query.shape[0]
    if m == 0:
        return (np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0), np.zeros((0, 3)), np.zeros((0, k), dtype=np.int64),
                np.ones(0, dtype=bool))
    if grids is None:
        grids = [point_grid(points, k)]
    # a query at the very coordinates of the one before it (copies of a point, which a sorted cloud holds side by
    # side) has its neighbours and its normal: searched once, not once per copy (a pile of n copies cost n searches
    # of n points each, found by a sweep of 2026-11-27: 20,000 copies, 2 s; 40,000, 9 s)
    qpts = points[query]
    repeat = np.zeros(m, dtype=bool)
    repeat[1:] = (qpts[1:] == qpts[:-1]).all(axis=1)
    unique = query[~repeat]
    u = unique.size
    normals, sigma3, k1, k2, dir1 = np.zeros((u, 3)), np.zeros(u), np.zeros(u), np.zeros(u), np.zeros((u, 3))
    neighbours = np.zeros((u, k), dtype=np.int64)
    defined = np.ones(u, dtype=bool)
    for lo in range(0, u, chunk):
        qi = unique[lo : lo + chunk]
        nb = nearest_neighbours(grids, points[qi], k)[1]
        neighbours[lo : lo + chunk] = nb
        hi = lo + qi.size
        _kernels.knn_pca(points, qi, nb, normals[lo:hi], sigma3[lo:hi], k1[lo:hi], k2[lo:hi], dir1[lo:hi])
        defined[lo:hi] = ~coincident(points, nb)
    for out in (normals, sigma3, k1, k2, dir1):
        out[~defined] = 0.0
    if u < m:  # each copy gets its first copy's row
        of = np.cumsum(~repeat) - 1
        normals, sigma3, k1, k2, dir1, neighbours, defined = (a[of] for a in (normals, sigma3, k1, k2, dir1, neighbours, defined))
    return normals, sigma3, k1, k2, dir1, neighbours, defined


#: Neighbours whose spread is at most this share of their coordinates' size are coincident (duplicates): no normal.
COINCIDENT = 1e-12


def coincident(points: np.ndarray, nb: np.ndarray) -> np.ndarray:
    """(M,) bool: whether the points ``points[nb[m]]`` ((M, k) indices) are one point, to rounding: the sum of their
    PCA eigenvalues at most ``COINCIDENT`` squared times their largest coordinate squared."""
    p = points[nb]
    d = p - p.mean(axis=1, keepdims=True)
    total = np.einsum("mki,mki->m", d, d) / nb.shape[1]  # the covariance's trace: the sum of its eigenvalues
    scale = np.abs(p).max(axis=(1, 2))
    return ~(total > COINCIDENT**2 * scale * scale)
