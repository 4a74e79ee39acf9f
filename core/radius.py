"""Radius normals: the PCA normal of all points within a radius, the normal Difference of Normals compares.

Two modes:

``"exact"``
    The reference definition (PCL's ``NormalEstimation`` with
    ``setRadiusSearch``): PCA of every point within ``radius`` of the query
    point, the point itself included, the normal turned towards the
    viewpoint.  Its cost grows with the points in the ball.
``"fast"``
    The points are summed per voxel of edge ``radius / resolution``
    (count, first and second moments about the voxel centre); a query sums
    the voxels whose *centre* lies within ``radius``, shifting each voxel's
    moments to the query point.  The cost per query is the number of
    occupied voxels in its ball, whatever the density; the ball is
    approximated to within half a voxel diagonal at its boundary.  Where
    the voxels in a ball hold at most two points each on average, the
    points themselves are summed (the exact ball), which is then no slower.

Both compute in float64 on offsets from the query point, so large
projected coordinates (UTM, Lambert-93) lose nothing.  A point with fewer
than ``min_points`` points in its ball, or whose ball's points are
collinear or coincident, gets an undefined normal: a row of NaN, never a
silent zero.
"""

from __future__ import annotations

import numpy as np

from . import _radius_kernels as _rk
from .errors import PatchcloudValueError
from .grid import CellGrid

__all__ = ["radius_normals", "radius_moments", "default_viewpoint", "halo_width", "MODES", "check_points", "check_radius", "check_mode"]

#: Valid values of ``mode``.
MODES = ("exact", "fast")


def check_points(points, name: str = "points") -> np.ndarray:
    """``points`` as a C-contiguous (N, 3) float64 array of finite values, or a PatchcloudValueError."""
    p = np.asarray(points)
    if p.ndim != 2 or p.shape[1] != 3:
        raise PatchcloudValueError(f"{name} must be an (N, 3) array, got shape {p.shape}")
    if not np.issubdtype(p.dtype, np.number):
        raise PatchcloudValueError(f"{name} must be numeric, got dtype {p.dtype}")
    p = np.ascontiguousarray(p, dtype=np.float64)
    if not np.isfinite(p).all():
        raise PatchcloudValueError(f"{name} holds NaN or infinite coordinates")
    return p


def check_radius(name: str, value) -> float:
    """A finite, positive radius (metres), or a PatchcloudValueError."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise PatchcloudValueError(f"{name} must be a positive number of metres, got {value!r}") from None
    if not np.isfinite(v) or v <= 0:
        raise PatchcloudValueError(f"{name} must be a positive number of metres, got {value!r}")
    return v


def check_mode(mode: str, resolution: int = 4, min_points: int = 3) -> None:
    """Validated ``mode`` (one of :data:`MODES`), ``resolution`` (>= 1) and ``min_points`` (>= 3)."""
    if mode not in MODES:
        raise PatchcloudValueError(f"mode must be one of {', '.join(MODES)}; got {mode!r}")
    if not isinstance(resolution, (int, np.integer)) or resolution < 1:
        raise PatchcloudValueError(f"resolution must be a whole number of voxels per radius, at least 1; got {resolution!r}")
    if not isinstance(min_points, (int, np.integer)) or min_points < 3:
        raise PatchcloudValueError(f"min_points must be a whole number, at least 3 (a plane needs three points); got {min_points!r}")


def default_viewpoint(points: np.ndarray) -> np.ndarray:
    """The default viewpoint: above the middle of the cloud's bounding box, one extent above its top.

    ``(x_mid, y_mid, z_max + max(x_extent, y_extent, z_extent, 1 m))``.
    """
    p = check_points(points)
    if p.shape[0] == 0:
        return np.array([0.0, 0.0, 1.0])
    lo, hi = p.min(axis=0), p.max(axis=0)
    ext = float(max((hi - lo).max(), 1.0))
    return np.array([(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0, hi[2] + ext])


def halo_width(radius: float, mode: str = "exact", resolution: int = 4) -> float:
    """How far (metres) beyond a region the points must be known for the radius normals inside it to be complete.

    ``radius`` in exact mode; in fast mode half a voxel diagonal more: a
    voxel whose centre is within ``radius`` may hold points beyond it.
    """
    if mode == "fast":
        return radius * (1.0 + np.sqrt(3.0) / (2.0 * resolution)) * (1.0 + 1e-9)
    return radius * (1.0 + 1e-9)


def _block_rows(resolution: int, block: int) -> np.ndarray:
    """Runs of voxels (a, b, c_lo, c_hi), offsets from a block's first voxel, that can hold a point within
    ``resolution`` voxels of the block (voxel a spans [a, a + 1), the block [0, block))."""
    s = float(resolution) + 1e-9
    span = int(np.ceil(s)) + 1
    rows = []
    for a in range(-span, block + span):
        ga = max(0, a - block, -a - 1)
        for b in range(-span, block + span):
            gb = max(0, b - block, -b - 1)
            left = s * s - ga * ga - gb * gb
            if left < 0:
                continue
            gc = int(np.floor(np.sqrt(left)))
            rows.append((a, b, -1 - gc, block + gc))
    return np.asarray(rows, dtype=np.int64)


def radius_moments(
    points: np.ndarray, radius: float, *, mode: str = "exact", resolution: int = 4, at: np.ndarray | None = None,
) -> np.ndarray:
    """Count and moments of the points within ``radius`` of each query point (the PCA's input).

    Returns
    -------
    (M, 10) float64
        n, sum(d) (3), sum(d d^T) as xx, xy, xz, yy, yz, zz, with d the
        offsets from the query point; M = N, or len(at).
    """
    pts = check_points(points)
    r = check_radius("radius", radius)
    check_mode(mode, resolution, 3)
    q = pts if at is None else pts[np.asarray(at, dtype=np.int64)]
    out = np.zeros((q.shape[0], 10))
    if q.shape[0] == 0:
        return out
    if mode == "exact":
        # Cells of edge r/2 and a reach of 2 cells: the searched cube is 2.5 r wide instead of 3 r.
        g = CellGrid.build(pts, r / 2.0)
        _rk.ball_moments_exact(pts[g.order], g.keys, g.start, g.dims, q, g.cell_of(q), 2, r * r, out)
    else:
        h = r / resolution
        block = max(1, resolution // 2)  # queries are grouped by blocks of block**3 voxels
        g = CellGrid.build(pts, h, pad=resolution + block + 2)
        sorted_pts = pts[g.order]
        centres = g.centres()
        vm = np.empty((g.keys.size, 10))
        _rk.voxel_moments(sorted_pts, g.start, centres, vm)
        qb = (np.floor(q / (block * h)).astype(np.int64) * block) - g.base  # first voxel of each query's block
        qkey = (qb[:, 0] * g.dims[1] + qb[:, 1]) * g.dims[2] + qb[:, 2]
        qorder = np.argsort(qkey, kind="stable")
        sk = qkey[qorder]
        first = np.flatnonzero(np.r_[True, sk[1:] != sk[:-1]])
        gstart = np.r_[first, sk.size].astype(np.int64)
        tmp = np.empty_like(out)
        _rk.ball_moments_voxels(
            sorted_pts, g.start, g.keys, vm, centres, g.dims, _block_rows(resolution, block),
            np.ascontiguousarray(q[qorder]), gstart, qb[qorder[first]], r * r, tmp,
        )
        out[qorder] = tmp
    return out


def radius_normals(
    points: np.ndarray,
    radius: float,
    *,
    viewpoint: np.ndarray | None = None,
    mode: str = "exact",
    resolution: int = 4,
    min_points: int = 3,
    at: np.ndarray | None = None,
    return_variation: bool = False,
):
    """Unit normals from the PCA of all points within ``radius`` of each point.

    Parameters
    ----------
    points : (N, 3) array
        Coordinates (metres), any order; large projected values are fine.
    radius : float
        Support radius (metres).
    viewpoint : (3,) array, optional
        Every normal is turned to face it.  Default: :func:`default_viewpoint`
        (above the middle of the cloud).
    mode : {"exact", "fast"}
        The reference PCA of the ball's points, or voxel moments (see the
        module's text); "exact" by default.
    resolution : int
        Fast mode: voxels per radius (voxel edge ``radius / resolution``).
    min_points : int
        Fewest points in a ball for a normal (at least 3).
    at : (M,) int array, optional
        Indices of the points to compute normals at (neighbours are still
        all of ``points``).  Default: every point.
    return_variation : bool
        Also return the surface variation l3 / (l1 + l2 + l3) of each ball.

    Returns
    -------
    normals : (M, 3) float64
        Unit normals; rows of NaN where the normal is undefined (too few
        points, or collinear or coincident ones).
    variation : (M,) float64, only with ``return_variation``

    Raises
    ------
    PatchcloudValueError
        Points not (N, 3) or not finite, a radius not positive, an unknown
        mode.

    Examples
    --------
    >>> import numpy as np
    >>> xy = np.random.default_rng(0).uniform(0, 4, (2000, 2))
    >>> n = radius_normals(np.column_stack([xy, np.zeros(2000)]), 0.5)
    >>> np.allclose(n, [0, 0, 1])
    True
    """
    pts = check_points(points)
    r = check_radius("radius", radius)
    check_mode(mode, resolution, min_points)
    vp = default_viewpoint(pts) if viewpoint is None else np.asarray(viewpoint, dtype=np.float64).reshape(-1)
    if vp.shape != (3,) or not np.isfinite(vp).all():
        raise PatchcloudValueError(f"viewpoint must be three finite coordinates (x, y, z), got {viewpoint!r}")
    q = pts if at is None else pts[np.asarray(at, dtype=np.int64)]
    mom = radius_moments(pts, r, mode=mode, resolution=resolution, at=at)
    normals = np.empty((q.shape[0], 3))
    variation = np.empty(q.shape[0])
    if q.shape[0]:
        _rk.pca_normals(mom, q, vp, float(min_points), normals, variation)
    return (normals, variation) if return_variation else normals
