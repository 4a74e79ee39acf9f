"""Normals from cell moments interpolated at each point, for points no patch surface models.

A leaf at ``d_min`` that fails the quadric criterion (vegetation, roof
edges, wires) and a leaf with fewer than ``n_min`` points have no patch, but
their points' neighbourhoods still have moments: those of the octree's
cells around them.  Each such point gets the PCA of the moments of the 8
cells whose centres surround it, each weighted by its trilinear weight at
the point and moved to the point (:func:`patchcloud.core._kernels.interpolated_pca`):
a neighbourhood about two cells wide centred on the point, found without a
point search, varying smoothly from point to point.

This is done at two scales: with the octree's deepest cells (edge ``h``,
``d_min <= h < 2 d_min``) and with the cells one level below (edge
``h / 2``), both anchored at the root cube's corner, so they are the same
cells whatever the tiling.  A scale counts where at least
:data:`MIN_POINTS` points lie in its cells of non-zero weight and they are
not a 3D curve (``lambda2 / sum >= min_sigma2``); of the scales that count,
the point takes the flatter (the smaller surface variation: the scale at
which its neighbourhood is most nearly one plane, so a ground point beside
a bush or a roof point beside a wall takes the scale that sees less of
the other surface).  Where neither counts, the point has no moment normal
and the caller falls back to its k nearest neighbours.

On the real aerial files of ../shared/data, against the PCA of the
same-class points within 1 m (2 m for ground), the points that left the
k-NN fallback for these normals are closer than their k-NN normals were,
pooled per class (``tools/bench_fallback.py --baseline``); one scale
alone was not (the finer: ground further; the deepest cells alone, or
whole cells without interpolation: every class further).

The curvature is the surface variation of the same moments; there is no
quadric, so the principal curvatures are 0 and the k1 direction is the
PCA's first axis.

The points may include the "skin" of neighbouring tiles (points beyond the
root cube's faces): the cells of a point near a face reach at most
``1.5 h < 3 d_min`` beyond it, within a skin of ``3 d_min``
(:data:`patchcloud.core.tiles.SKIN_HALO`), as in a run on the whole cloud.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import _kernels
from .argsort import stable_argsort
from .knn import near_queries

__all__ = ["MomentNormals", "moment_normals", "MIN_POINTS"]

#: A moment normal needs at least this many points in the cells that weigh on it.
MIN_POINTS = 4


@dataclass(frozen=True)
class MomentNormals:
    """Moment normals of M query points.

    Attributes
    ----------
    defined : (M,) bool
        Whether the point got a normal (else it needs another method).
    normal : (M, 3) float64
        Unit PCA normal, unoriented (``n . (0.001, 0.01, 1) >= 0``); zeros where not defined.
    sigma3 : (M,) float64
        Surface variation ``lambda3 / (lambda1 + lambda2 + lambda3)`` of the interpolated moments.
    dir1 : (M, 3) float64
        The PCA's first axis (unit, in the tangent plane).
    votes : (M, 3) float64
        The voters' vectors summed over the same cells with the same weights (zeros without voters).
    coarse : (M,) bool
        Where the deepest cells (edge ``h``) gave the normal, not the finer ones.
    """

    defined: np.ndarray
    normal: np.ndarray
    sigma3: np.ndarray
    dir1: np.ndarray
    votes: np.ndarray
    coarse: np.ndarray


def moment_normals(
    points: np.ndarray,
    query: np.ndarray,
    h: float,
    *,
    min_sigma2: float,
    votes: np.ndarray | None = None,
    voters: np.ndarray | None = None,
) -> MomentNormals:
    """Moment normals of ``points[query]`` from cells of edge ``h / 2`` and ``h`` anchored at the origin.

    Parameters
    ----------
    points : (N, 3) float64
        The points, in a frame whose origin is a corner of the cell grid (metres).
    query : (M,) int64
        Rows of the points that need a normal.
    h : float
        Edge of the octree's deepest cells (metres).
    min_sigma2 : float
        Below this ``lambda2 / (lambda1 + lambda2 + lambda3)`` the points are a 3D curve: no normal.
    votes : (N, 3) float64, optional
        A vector per point (an oriented normal), summed where ``voters`` with the moments' weights.
    voters : (N,) bool, optional

    Returns
    -------
    MomentNormals

    Examples
    --------
    A tilted plane, 20 cm point spacing, deepest cells of 1 m:

    >>> import numpy as np
    >>> g = np.arange(0.1, 4.0, 0.2)
    >>> x, y = (a.ravel() for a in np.meshgrid(g, g))
    >>> pts = np.column_stack([x, y, 1.0 + 0.5 * x])
    >>> res = moment_normals(pts, np.arange(len(pts)), 1.0, min_sigma2=0.01)
    >>> bool(res.defined.all()), (np.round(res.normal[0], 4) + 0.0).tolist()
    (True, [-0.4472, 0.0, 0.8944])
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    query = np.asarray(query, dtype=np.int64)
    n, m = points.shape[0], query.size
    if votes is None or voters is None:
        votes, voters = np.zeros((n, 3)), np.zeros(n, dtype=bool)
    votes, voters = np.asarray(votes, dtype=np.float64), np.asarray(voters, dtype=bool)
    defined = np.zeros(m, dtype=bool)
    coarse = np.zeros(m, dtype=bool)
    normal, dir1, vote = np.zeros((m, 3)), np.zeros((m, 3)), np.zeros((m, 3))
    sigma3 = np.zeros(m)
    best = np.full(m, np.inf)
    where = points[query]
    if m and 8 * m < n:  # few queries: only the points that may lie in their cells (each such cell whole, so the same sums)
        near = near_queries(points, where, 2.0 * h)  # a query's cells lie within 1.5 h of it along each axis, at both scales
        points, votes, voters = _kernels.rows_where(near, points), _kernels.rows_where(near, votes), voters[near]
    votes = np.ascontiguousarray(votes)
    for edge in (0.5 * h, h):  # the flatter of the two scales, the finer on a tie
        nrm, s2, s3, d1, v, count = _at_points(points, votes, voters, where, float(edge))
        ok = (count >= MIN_POINTS) & (s2 >= min_sigma2) & (s3 < best)
        best[ok] = s3[ok]
        defined |= ok
        coarse[ok] = edge == h
        for out, values in ((normal, nrm), (sigma3, s3), (dir1, d1), (vote, v)):  # the scale's values where it wins
            np.copyto(out, values, where=ok if values.ndim == 1 else ok[:, None])
    return MomentNormals(defined, normal, sigma3, dir1, vote, coarse)


def _at_points(points, votes, voters, where, edge):
    """The kernel's outputs at ``where`` (M, 3) for cells of ``edge`` (``votes`` summed where ``voters``)."""
    m = where.shape[0]
    if m == 0:
        return np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)
    # the queries' base cells floor(p / edge - 0.5) span lo to lo + span - 2 (floor is monotonic: from the extremes)
    low, high = _kernels.bounds(where)[:2]  # the points are finite
    lo = np.floor(low / edge - 0.5).astype(np.int64)
    span = np.floor(high / edge - 0.5).astype(np.int64) - lo + 2
    if float(np.prod(span.astype(np.float64))) >= 2.0**62:  # the keys would overflow: two halves along the widest axis
        axis = int(np.argmax(span))  # > 2^20 cells wide, so the queries' cells there differ
        base = np.floor(where[:, axis] / edge - 0.5).astype(np.int64)
        left = base <= np.median(base)
        if left.all():
            left = base < base.max()
        out = [np.empty(shape) for shape in ((m, 3), m, m, (m, 3), (m, 3), m)]
        for part in (left, ~left):
            for o, values in zip(out, _at_points(points, votes, voters, where[part], edge)):
                o[part] = values
        return tuple(out)
    keys = np.empty(points.shape[0], dtype=np.int64)
    _kernels.box_cell_keys(points, float(edge), lo, span, keys)
    inside = np.flatnonzero(keys >= 0)
    keys = keys[inside]
    order = stable_argsort(keys)
    keys = keys[order]  # one (N,) array at a time freed as the next is made: this runs on whole tiles
    rows = inside[order]
    del inside, order
    starts = _kernels.run_starts(keys)
    ckeys = keys[starts]
    cmom, cvotes = np.empty((starts.size, 10)), np.empty((starts.size, 3))
    _kernels.box_cell_stats(points, votes, voters, rows, starts, ckeys, float(edge), lo, span, cmom, cvotes)
    normals, dir1, votes = np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3))
    sigma2, sigma3, count = np.empty(m), np.empty(m), np.empty(m)
    _kernels.interpolated_pca(
        np.ascontiguousarray(where), edge, lo, span, ckeys, cmom, np.ascontiguousarray(cvotes), normals, sigma2, sigma3, dir1,
        votes, count,
    )
    return normals, sigma2, sigma3, dir1, votes, count
