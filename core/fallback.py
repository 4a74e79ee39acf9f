"""Point-wise normals for points no patch surface models (edge and sparse leaves).

The paper leaves these points without a normal; here each gets the PCA
normal of its ``k`` nearest neighbours (scipy's cKDTree), the surface
variation of that neighbourhood, and principal curvatures from a quadric
fitted to the neighbourhood in its PCA frame.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from . import _kernels

__all__ = ["knn_normals"]


def knn_normals(
    points: np.ndarray, query: np.ndarray, k: int, near: tuple[np.ndarray, float] | None = None, chunk: int = 65536
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
    near : (subset, radius), optional
        Indices of a subset of ``points`` holding every point within
        ``radius`` of any query point: the search runs on the subset, and
        only queries whose k-th neighbour lies farther than ``radius`` are
        searched again in the whole cloud.  The result is the same.

    Returns
    -------
    normals : (M, 3) float64, unit, unoriented (``n . (0.001, 0.01, 1) >= 0``)
    sigma3 : (M,) surface variation of the neighbourhood
    k1, k2 : (M,) principal curvatures of the neighbourhood quadric (1/metre),
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
    subset, radius = near if near is not None else (np.arange(n), np.inf)
    tree = cKDTree(points[subset], balanced_tree=False, compact_nodes=False)
    full = None
    for lo in range(0, m, chunk):
        hi = min(lo + chunk, m)
        qi = query[lo:hi]
        dist, nb = tree.query(points[qi], k=k, workers=-1)
        dist, nb = dist.reshape(hi - lo, k), subset[nb.reshape(hi - lo, k)]
        far = np.flatnonzero(dist[:, -1] > radius)
        if far.size:
            if full is None:
                full = cKDTree(points, balanced_tree=False, compact_nodes=False)
            nb[far] = full.query(points[qi[far]], k=k, workers=-1)[1].reshape(far.size, k)
        neighbours[lo:hi] = nb
        _kernels.knn_pca(points, qi, nb, normals[lo:hi], sigma3[lo:hi], k1[lo:hi], k2[lo:hi], dir1[lo:hi])
    return normals, sigma3, k1, k2, dir1, neighbours
    subset, radius = near if near is not None else (np.arange(n), np.inf)
    tree = cKDTree(points[subset], balanced_tree=False, compact_nodes=False)
    full = None
    for lo in range(0, m, chunk):
        hi = min(lo + chunk, m)
        qi = query[lo:hi]
        dist, nb = tree.query(points[qi], k=k, workers=-1)
        dist, nb = dist.reshape(hi - lo, k), subset[nb.reshape(hi - lo, k)]
        far = np.flatnonzero(dist[:, -1] > radius)
        if far.size:
            if full is None:
                full = cKDTree(points, balanced_tree=False, compact_nodes=False)
            nb[far] = full.query(points[qi[far]], k=k, workers=-1)[1].reshape(far.size, k)
        neighbours[lo:hi] = nb
        nbp = points[nb]
        centroid = nbp.mean(axis=1)
        rel = nbp - centroid[:, None, :]
        cov = np.einsum("mki,mkj->mij", rel, rel) / k
        w, v = np.linalg.eigh(cov)
        tot = w.sum(axis=1)
        sigma3[lo:hi] = np.where(tot > 0, np.maximum(w[:, 0], 0) / np.where(tot > 0, tot, 1), 0.0)
        e3 = v[:, :, 0]
        s = np.where(e3 @ np.array([1e-3, 1e-2, 1.0]) < 0, -1.0, 1.0)
        e3 = e3 * s[:, None]
        e1 = v[:, :, 2]
        e2 = np.cross(e3, e1)
        frame = np.stack([e1, e2, e3], axis=2)
        normals[lo:hi] = e3
        # quadric of the neighbourhood in its PCA frame, scaled to order one
        uvw = np.einsum("mai,mka->mki", frame, rel)
        scale = np.sqrt(np.maximum(w[:, 2], 1e-300))[:, None]
        u, vv, ww = uvw[..., 0] / scale, uvw[..., 1] / scale, uvw[..., 2] / scale
        phi = np.stack([u * u, u * vv, vv * vv, u, vv, np.ones_like(u)], axis=2)
        G = np.einsum("mki,mkj->mij", phi, phi)
        b = np.einsum("mki,mk->mi", phi, ww)
        G += (1e-8 * np.trace(G, axis1=1, axis2=2) / 6 + 1e-300)[:, None, None] * np.eye(6)
        beta = np.linalg.solve(G, b[:, :, None])[:, :, 0]
        sc = scale[:, 0]
        coeffs = np.column_stack([beta[:, 0] / sc, beta[:, 1] / sc, beta[:, 2] / sc, beta[:, 3], beta[:, 4], beta[:, 5] * sc])
        kk1, kk2, d1 = surface_curvatures(points[qi], centroid, frame, coeffs)
        k1[lo:hi], k2[lo:hi], dir1[lo:hi] = kk1, kk2, d1
    return normals, sigma3, k1, k2, dir1, neighbours
