"""Point-wise normals for points no patch surface models (edge and sparse leaves).

The paper leaves these points without a normal; here each gets the PCA
normal of its ``k`` nearest neighbours (:mod:`.knn`: a compiled search by
rings of octree cells), the surface variation of that neighbourhood, and
principal curvatures from a quadric fitted to the neighbourhood in its PCA
frame.
"""

from __future__ import annotations

import numpy as np

from . import _kernels
from .knn import knn, knn_in_cells

__all__ = ["knn_normals"]


def knn_normals(
    points: np.ndarray, query: np.ndarray, k: int, grid: tuple[np.ndarray, np.ndarray, float] | None = None,
    chunk: int = 65536,
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
    grid : (q, keys, unit), optional
        The points' depth-21 integer coordinates in a root cube of
        ``unit * 2**21`` metres, and their Morton keys, ``points`` sorted by
        key (a tile's octree: :func:`patchcloud.core.knn.knn_in_cells`);
        without it the search makes its own.  The neighbours are the same
        either way.

    Returns
    -------
    normals : (M, 3) float64, unit, unoriented (``n . (0.001, 0.01, 1) >= 0``)
    sigma3 : (M,) surface variation of the neighbourhood
    k1, k2 : (M,) principal curvatures of the neighbourhood quadric (1/metre),
        "convex positive" with respect to ``normals``
    dir1 : (M, 3) direction of ``k1``
    neighbours : (M, k) int64 indices of the neighbours, nearest first
    """
    n = points.shape[0]
    k = int(min(k, n))
    m = query.shape[0]
    normals = np.zeros((m, 3))
    sigma3 = np.zeros(m)
    k1 = np.zeros(m)
    k2 = np.zeros(m)
    dir1 = np.zeros((m, 3))
    if m == 0:
        return normals, sigma3, k1, k2, dir1, np.zeros((0, k), dtype=np.int64)
    if grid is None:
        neighbours = knn(points, query, k)
    else:
        q, keys, unit = grid
        neighbours = knn_in_cells(points, q, keys, unit, query, k)
    for lo in range(0, m, chunk):
        hi = min(lo + chunk, m)
        _kernels.knn_pca(points, query[lo:hi], neighbours[lo:hi], normals[lo:hi], sigma3[lo:hi], k1[lo:hi], k2[lo:hi], dir1[lo:hi])
    return normals, sigma3, k1, k2, dir1, neighbours
