"""Difference of Normals (Ioannou et al.): a multi-scale operator for segmenting unorganised clouds.

``DoN(p, r_s, r_l) = (n(p, r_s) - n(p, r_l)) / 2``, with ``n(p, r)`` the unit
radius normal of :mod:`.radius`, both turned towards one viewpoint.  Its
magnitude lies in [0, 1]: near 0 where the surface is the same at both
scales (planes, smooth terrain), large where it changes between them
(poles, kerbs, street furniture of a size between ``r_s`` and ``r_l``).
Thresholding the magnitude and clustering the points kept gives segments.
"""

from __future__ import annotations

import numpy as np

from .checks import check_cluster_sizes, check_radius, check_rounding
from .cluster import euclidean_clusters
from .errors import PatchcloudValueError
from .options import AXES, DonOptions, check_threshold
from .radius import check_grid_step, check_points, coordinate_step, default_viewpoint, grid_origin, radius_normals

__all__ = ["difference_of_normals", "don_magnitude", "don_mask", "segment_don"]

def difference_of_normals(
    points: np.ndarray,
    r_small: float,
    r_large: float,
    *,
    viewpoint: np.ndarray | None = None,
    mode: str = "fast",
    resolution: int = 4,
    min_points: int = 3,
    at: np.ndarray | None = None,
    origin=None,
    rounding: float | None = None,
    grid_step: float | None = None,
) -> np.ndarray:
    """The DoN vector of every point.

    Parameters
    ----------
    points : (N, 3) array, or laspy.LasData
        Coordinates (metres).
    r_small, r_large : float
        Support radii (metres), ``r_small < r_large``.
    viewpoint : (3,) array, optional
        Both normals face it.  Default: above the middle of the cloud
        (:func:`patchcloud.core.radius.default_viewpoint`).
    mode, resolution, min_points :
        As :class:`patchcloud.core.DonOptions` (which checks all of these).
    at, origin, rounding, grid_step :
        As :func:`patchcloud.core.radius_normals` (``origin``: where fast
        mode's voxels are laid from; by default as ``patchcloud don`` lays
        them, so the whole file's DoN is the command's; ``rounding``: the
        coordinates' step, a ``laspy.LasData``'s scale by default).

    Returns
    -------
    (M, 3) float64
        ``(n(p, r_small) - n(p, r_large)) / 2``; rows of NaN where either
        normal is undefined (too few points within ``r_small``, say).

    Examples
    --------
    >>> import numpy as np
    >>> xy = np.random.default_rng(1).uniform(0, 6, (4000, 2))
    >>> d = difference_of_normals(np.column_stack([xy, np.zeros(4000)]), 0.3, 1.0)
    >>> float(np.abs(d).max())
    0.0
    """
    step = coordinate_step(points) if rounding is None else check_rounding(rounding)
    tie = check_grid_step(points, grid_step)
    pts = check_points(points)
    o = DonOptions(r_small, r_large, mode=mode, viewpoint=viewpoint, resolution=resolution, min_points=min_points)
    vp = default_viewpoint(pts) if o.viewpoint is None else np.asarray(o.viewpoint)
    kw = dict(viewpoint=vp, mode=o.mode, resolution=o.resolution, min_points=o.min_points, at=at,
              origin=grid_origin(pts) if origin is None else origin, rounding=step, grid_step=tie)
    return (radius_normals(pts, o.r_small, **kw) - radius_normals(pts, o.r_large, **kw)) / 2.0


def don_magnitude(don: np.ndarray) -> np.ndarray:
    """(N,) magnitude of DoN vectors ((N, 3), as :func:`difference_of_normals` gives), in [0, 1]; NaN where undefined.

    >>> don_magnitude(np.array([[0.3, 0.0, 0.4], [np.nan] * 3])).tolist()
    [0.5, nan]
    """
    d = _don_vectors(don)
    return np.sqrt(np.einsum("ij,ij->i", d, d))


def _don_vectors(don) -> np.ndarray:
    try:
        d = np.asarray(don, dtype=np.float64)
    except (TypeError, ValueError):
        raise PatchcloudValueError(f"don must be an (N, 3) array of DoN vectors (numbers), got {type(don).__name__} "
                                   f"{str(don)[:40]!r}") from None
    if d.ndim != 2 or d.shape[1] != 3:
        raise PatchcloudValueError(f"don must be an (N, 3) array of DoN vectors, got shape {d.shape}")
    return d


def don_mask(don: np.ndarray, threshold: float, *, axis: str | None = None, axis_threshold: float | None = None) -> np.ndarray:
    """Points whose DoN magnitude is at least ``threshold`` (and ``|DoN_axis| >= axis_threshold``).

    Undefined DoN (NaN) is never kept.

    Examples
    --------
    >>> don_mask(np.array([[0.3, 0, 0], [0.1, 0, 0], [np.nan] * 3]), 0.25).tolist()
    [True, False, False]
    """
    check_threshold(threshold, axis, axis_threshold)
    d = _don_vectors(don)
    keep = don_magnitude(d) >= threshold
    if axis is not None:
        keep &= np.abs(d[:, AXES.index(axis)]) >= axis_threshold
    return keep


def segment_don(
    points: np.ndarray,
    don: np.ndarray,
    threshold: float,
    tolerance: float,
    *,
    min_points: int = 1,
    max_points: int | None = None,
    axis: str | None = None,
    axis_threshold: float | None = None,
    grid_step: float | None = None,
) -> np.ndarray:
    """Segment id per point: Euclidean clusters of the points :func:`don_mask` keeps; 0 = no segment.

    Segments are numbered 1, 2, ... in order of their first point.

    Examples
    --------
    >>> import numpy as np
    >>> p = np.array([[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [3, 0, 0]])
    >>> segment_don(p, np.array([[0.5, 0, 0], [0.5, 0, 0], [0, 0, 0], [0.5, 0, 0]]), 0.25, 0.15).tolist()
    [1, 1, 0, 2]
    """
    pts = check_points(points)
    d = np.asarray(don, dtype=np.float64)
    if d.shape != pts.shape:
        raise PatchcloudValueError(f"don must have the shape of points {pts.shape}, got {d.shape}")
    check_radius("tolerance", tolerance)
    check_cluster_sizes(min_points, max_points)
    keep = don_mask(d, threshold, axis=axis, axis_threshold=axis_threshold)
    out = np.zeros(pts.shape[0], dtype=np.int64)
    tie = check_grid_step(points, grid_step)
    out[keep] = euclidean_clusters(pts[keep], tolerance, min_points=min_points, max_points=max_points, grid_step=tie)
    return out
