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

from .cluster import check_cluster_sizes, euclidean_clusters
from .errors import PatchcloudValueError
from .radius import check_points, check_radius, default_viewpoint, radius_normals

__all__ = ["difference_of_normals", "don_magnitude", "don_mask", "segment_don", "check_scales", "check_threshold", "AXES"]

#: Names of the DoN vector's components, for thresholds on one of them.
AXES = ("x", "y", "z")


def check_scales(r_small, r_large) -> tuple[float, float]:
    """Validated radii: both positive, ``r_small < r_large``."""
    rs = check_radius("r_small", r_small)
    rl = check_radius("r_large", r_large)
    if not rs < rl:
        raise PatchcloudValueError(f"r_small must be smaller than r_large; got r_small={rs:g} m, r_large={rl:g} m")
    return rs, rl


def check_threshold(threshold, axis=None, axis_threshold=None) -> None:
    """Validated thresholds: magnitudes in [0, 1], an axis among :data:`AXES` with its own threshold."""
    for name, v in (("threshold", threshold), ("axis_threshold", axis_threshold)):
        if v is None and name == "axis_threshold":
            continue
        try:
            ok = 0.0 <= float(v) <= 1.0
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise PatchcloudValueError(f"{name} must be a DoN magnitude in [0, 1]; got {v!r}")
    if axis is None and axis_threshold is not None:
        raise PatchcloudValueError("axis_threshold needs an axis (one of x, y, z)")
    if axis is not None:
        if axis not in AXES:
            raise PatchcloudValueError(f"axis must be one of {', '.join(AXES)}; got {axis!r}")
        if axis_threshold is None:
            raise PatchcloudValueError(f"axis {axis!r} needs an axis_threshold in [0, 1]")


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
) -> np.ndarray:
    """The DoN vector of every point.

    Parameters
    ----------
    points : (N, 3) array
        Coordinates (metres).
    r_small, r_large : float
        Support radii (metres), ``r_small < r_large``.
    viewpoint : (3,) array, optional
        Both normals face it.  Default: above the middle of the cloud
        (:func:`patchcloud.core.radius.default_viewpoint`).
    mode, resolution, min_points, at :
        As :func:`patchcloud.core.radius_normals`.

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
    pts = check_points(points)
    rs, rl = check_scales(r_small, r_large)
    vp = default_viewpoint(pts) if viewpoint is None else viewpoint
    kw = dict(viewpoint=vp, mode=mode, resolution=resolution, min_points=min_points, at=at)
    return (radius_normals(pts, rs, **kw) - radius_normals(pts, rl, **kw)) / 2.0


def don_magnitude(don: np.ndarray) -> np.ndarray:
    """(N,) magnitude of DoN vectors, in [0, 1]; NaN where undefined."""
    d = np.asarray(don, dtype=np.float64)
    return np.sqrt(np.einsum("ij,ij->i", d, d))


def don_mask(don: np.ndarray, threshold: float, *, axis: str | None = None, axis_threshold: float | None = None) -> np.ndarray:
    """Points whose DoN magnitude is at least ``threshold`` (and ``|DoN_axis| >= axis_threshold``).

    Undefined DoN (NaN) is never kept.

    Examples
    --------
    >>> don_mask(np.array([[0.3, 0, 0], [0.1, 0, 0], [np.nan] * 3]), 0.25).tolist()
    [True, False, False]
    """
    check_threshold(threshold, axis, axis_threshold)
    d = np.asarray(don, dtype=np.float64)
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
    out[keep] = euclidean_clusters(pts[keep], tolerance, min_points=min_points, max_points=max_points)
    return out
