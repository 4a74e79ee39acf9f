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
    the voxels wholly within ``radius``, shifting each voxel's moments to
    the query point, and of each voxel the sphere cuts the share of its
    points within: its points taken as spread uniformly along the
    direction from the query to their centroid (over sqrt(3) standard
    deviations each side), cut by the plane across that direction at
    ``radius`` (``_radius_kernels._add_straddling``).  The cost per query
    is the number of occupied voxels in its ball, whatever the density.
    No voxel jumps in or out of a ball as the query moves, so the result
    hardly depends on where the voxels fall: moving the cloud by a
    fraction of a voxel changes |DoN| by about 0.01 at the 99th
    percentile on the real files (0.12-0.15 with a voxel-centre test),
    and fast-mode |DoN| is within 0.011-0.016 of exact mode's at the 99th
    percentile (tools/bench_don.py).  Where
    voxels would hold five points or fewer on average (the cloud is sparse
    at this radius: :func:`uses_voxels`), or a ball's voxels hold at most
    two each, the points themselves are summed (the exact ball), which is
    then faster.

Both compute in float64 on offsets from the query point, so large
projected coordinates (UTM, Lambert-93) lose nothing.  A point with fewer
than ``min_points`` points in its ball, or whose ball's points are
collinear or coincident, gets an undefined normal: a row of NaN, never a
silent zero.  Collinear up to the coordinates' rounding counts: with
``rounding`` the step the coordinates are rounded to (a LAS file's scale,
taken from a ``laspy.LasData`` by default), a ball whose points spread
less than one step across their line (the PCA's second eigenvalue below
``rounding**2``) has no normal.  Three points of a line rounded to 1 cm
otherwise give a plane the rounding turns at will: on a plane of 3,000
points rounded to 1 cm, |DoN| (0.2 m / 2 m) reached 0.72, and 0.08 with
the rule.
"""

from __future__ import annotations

import numpy as np

from . import _radius_kernels as _rk
from .checks import check_indices, check_mode, check_positive, check_radius, check_rounding, check_viewpoint, coordinates, is_lasdata
from .errors import PatchcloudValueError
from .grid import CellGrid
from .points import GRID_ANCHOR

__all__ = [
    "radius_normals", "radius_moments", "default_viewpoint", "halo_width", "cell_density", "uses_voxels", "voxel_points", "VOXEL_MIN_POINTS", "check_points",
    "grid_origin", "coordinate_step", "grid_step_of", "check_grid_step", "tie_margin",
]

def check_points(points, name: str = "points") -> np.ndarray:
    """``points`` (an array, or a ``laspy.LasData``: :func:`~patchcloud.core.checks.coordinates`) as a C-contiguous
    (N, 3) float64 array of finite values, or a PatchcloudValueError."""
    p = np.asarray(coordinates(points))
    if p.ndim != 2 or p.shape[1] != 3:
        raise PatchcloudValueError(f"{name} must be an (N, 3) array, got shape {p.shape}")
    if not np.issubdtype(p.dtype, np.number) or np.iscomplexobj(p):
        raise PatchcloudValueError(f"{name} must be real numbers, got dtype {p.dtype}")
    p = np.ascontiguousarray(p, dtype=np.float64)
    if not np.isfinite(p).all():
        raise PatchcloudValueError(f"{name} holds NaN or infinite coordinates")
    return p


def coordinate_step(points) -> float:
    """The step ``points``' coordinates are rounded to: a ``laspy.LasData``'s largest scale, else 0 (not rounded).

    >>> import laspy
    >>> coordinate_step(laspy.read(sample)), coordinate_step(np.zeros((4, 3)))
    (0.01, 0.0)
    """
    return float(np.max(np.asarray(points.header.scales, dtype=np.float64))) if is_lasdata(points) else 0.0


def grid_step_of(points) -> float:
    """The step of the grid ``points``' coordinates lie on: a ``laspy.LasData``'s smallest scale, else 0 (none).

    >>> import laspy
    >>> grid_step_of(laspy.read(sample)), grid_step_of(np.zeros((4, 3)))
    (0.01, 0.0)
    """
    return float(np.min(np.asarray(points.header.scales, dtype=np.float64))) if is_lasdata(points) else 0.0


def check_grid_step(points, grid_step: float | None) -> float:
    """``grid_step`` checked (a length of at least 0), or, when None, :func:`grid_step_of` ``points``: what the functions
    taking ``grid_step=`` use.

    >>> check_grid_step(np.zeros((2, 3)), None), check_grid_step(np.zeros((2, 3)), 0.01)
    (0.0, 0.01)
    """
    return grid_step_of(points) if grid_step is None else check_rounding(grid_step, "grid_step")


def tie_margin(grid_step: float) -> float:
    """What a squared distance may exceed the squared radius by and still count as within it: half the smallest
    difference between two squared distances of points on a grid of ``grid_step`` (scales that are a power of ten
    apart: every squared distance a multiple of the smallest step's square), far above the rounding of any frame.
    So a point exactly at the radius counts, whatever rounding its coordinates had, and the next one out does not.

    >>> tie_margin(0.01), tie_margin(0.0)
    (5e-05, 0.0)
    """
    return 0.5 * grid_step * grid_step


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

    ``radius`` in exact mode; in fast mode a voxel diagonal more: a voxel
    whose centre is within half a diagonal beyond ``radius`` takes part,
    and its points may lie half a diagonal beyond its centre.
    """
    if mode == "fast":
        return radius * (1.0 + np.sqrt(3.0) / resolution) * (1.0 + 1e-9)
    return radius * (1.0 + 1e-9)


def _block_rows(reach: int, block: int) -> np.ndarray:
    """Runs of cells (a, b, c_lo, c_hi), offsets from a block's first cell, that can hold a point within
    ``reach`` cells of the block (cell a spans [a, a + 1), the block [0, block))."""
    s = float(reach) + 1e-9
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


def cell_density(points: np.ndarray, edge: float) -> float:
    """Mean points per occupied cell of edge ``2**floor(log2(edge))`` (metres), cells anchored at 0.

    Power-of-two cells anchored at 0 are those of the stream's tile octree,
    so the stream gets the whole file's value from its occupancy counts
    without a pass over the points.
    """
    pts = check_points(points)
    if pts.shape[0] == 0:
        return 0.0
    e = 2.0 ** np.floor(np.log2(edge))
    c = np.floor(pts / e).astype(np.int64)
    c -= c.min(axis=0)
    d = c.max(axis=0) + 1
    key = np.sort((c[:, 0] * d[1] + c[:, 1]) * d[2] + c[:, 2])
    return pts.shape[0] / (1 + np.count_nonzero(key[1:] != key[:-1]))


#: Fast mode sums voxels only where they hold more than this many points on average (:func:`uses_voxels`).
VOXEL_MIN_POINTS = 5.0


def uses_voxels(radius: float, resolution: int, density: float) -> bool:
    """Whether fast mode sums voxels at ``radius``: only where a voxel holds more than :data:`VOXEL_MIN_POINTS` points on average.

    ``density`` is :func:`cell_density` at the voxel edge ``radius /
    resolution``; scaled from its power-of-two cell to the voxel as a
    surface's count scales (with the area).  Sparser, the voxels cost more
    than the points, and fast mode sums the points (exact) instead.
    Measured (``python tools/bench_voxels.py``: compute only, 2 cores, both
    ways on the same cloud and radius): the points were faster up to 4.9
    points a voxel on every real file (1.7-2x: St-Barth at 2 m, fusa at
    5 m, lone-star at 0.5 m), the voxels from 5.4 (2x on the synthetic
    city at 2 m, whose dense facades beside sparse roofs make a mean per
    occupied cell read low) to 334 (53x).
    """
    return voxel_points(radius, resolution, density) > VOXEL_MIN_POINTS


def voxel_points(radius: float, resolution: int, density: float) -> float:
    """Points a voxel of edge ``radius / resolution`` holds on average: ``density`` (:func:`cell_density` at that edge,
    on power-of-two cells) scaled to the voxel as a surface's count scales, with the area.

    >>> voxel_points(5.0, 4, 16.0)  # 1.25 m voxels, 16 points a 1 m cell
    25.0
    """
    h = radius / resolution
    e = 2.0 ** np.floor(np.log2(h))
    return float(density * (h / e) ** 2)


def grid_origin(points: np.ndarray) -> np.ndarray:
    """(3,) the multiple of :data:`~patchcloud.core.points.GRID_ANCHOR` at or below the points' smallest coordinates:
    where a tiled run's store frame starts, and so where the cells and voxels of these functions are laid from.

    >>> grid_origin(np.array([[650012.5, 6860001.0, -3.0]])).tolist()
    [647168.0, 6856704.0, -4096.0]

    No points: (0, 0, 0).  Points not (N, 3) or not finite: a PatchcloudValueError.
    """
    p = check_points(points)
    return np.floor(p.min(axis=0) / GRID_ANCHOR) * GRID_ANCHOR if p.shape[0] else np.zeros(3)


def radius_moments(
    points: np.ndarray, radius: float, *, mode: str = "fast", resolution: int = 4, at: np.ndarray | None = None,
    density: float | None = None, origin=None, grid_step: float = 0.0,
) -> np.ndarray:
    """Count and moments of the points within ``radius`` of each query point (the PCA's input).

    ``density``: fast mode's :func:`cell_density` at the voxel edge
    (default: from ``points``; the stream passes the whole file's).
    ``origin``: the cells (fast mode's voxels) lie at multiples of their
    edge from it (default :func:`grid_origin` of ``points``, as in a tiled
    run's store frame; the stream, in that frame, passes 0).
    ``grid_step``: the step of the grid the coordinates lie on (a LAS
    file's smallest scale; 0: none), which decides ties the same way
    whatever the rounding of the frame (:func:`grid_step_of`).

    Returns
    -------
    (M, 10) float64
        n, sum(d) (3), sum(d d^T) as xx, xy, xz, yy, yz, zz, with d the
        offsets from the query point; M = N, or len(at).
    """
    pts = check_points(points)
    r = check_radius("radius", radius)
    check_mode(mode, resolution, 3)
    at = None if at is None else check_indices(at, pts.shape[0])
    shift = grid_origin(pts) if origin is None else check_viewpoint(origin, "origin")
    if np.any(shift != 0):  # offsets from each query point: the frame changes where the cells lie, and the roundings
        pts = pts - shift
    q = pts if at is None else pts[at]
    out = np.zeros((q.shape[0], 10))
    if q.shape[0] == 0:
        return out
    if density is not None:
        density = check_positive("density", density)
    if mode == "fast" and density is None:
        density = cell_density(pts, r / resolution)
    voxels = mode == "fast" and uses_voxels(r, resolution, density)
    # exact: cells of r/2 and blocks of one cell; voxels: cells of r/resolution and blocks about r wide
    edge, block, reach = (r / resolution, max(1, resolution // 2), resolution + 1) if voxels else (r / 2.0, 1, 2)
    g = CellGrid.build(pts, edge, pad=reach + block + 1, grid_step=grid_step)
    sorted_pts = pts[g.order]
    row_key = g.keys // g.dims[2]
    first = np.flatnonzero(np.r_[True, row_key[1:] != row_key[:-1]])
    row_start = np.r_[first, g.keys.size].astype(np.int64)
    bits = max(4, int(np.ceil(np.log2(2 * first.size + 1))))
    table_keys, table_vals = _rk.build_row_table(row_key[first], bits)
    if voxels:
        centres = g.centres()
        moments = np.empty((g.keys.size, 10))
        _rk.voxel_moments(sorted_pts, g.start, centres, moments)
        stats = np.empty((g.keys.size, 9))
        _rk.voxel_stats(moments, stats)
    else:
        centres = moments = stats = np.zeros((1, 10))
    # first cell of each query's block (blocks moved as the cells are, so the rows of cells each block scans reach)
    qb = np.floor(q / (block * edge) + g.nudge / block).astype(np.int64) * block - g.base
    qkey = (qb[:, 0] * g.dims[1] + qb[:, 1]) * g.dims[2] + qb[:, 2]
    qorder = np.argsort(qkey, kind="stable")
    sk = qkey[qorder]
    del qkey
    gfirst = np.flatnonzero(np.r_[True, sk[1:] != sk[:-1]])
    _rk.ball_moments(
        voxels, sorted_pts, g.start, np.ascontiguousarray(g.cells[:, 2]), row_start, table_keys, table_vals, bits,
        g.dims, _block_rows(reach, block), q, qorder, np.r_[gfirst, sk.size].astype(np.int64), qb[qorder[gfirst]],
        r * r + tie_margin(grid_step), moments, stats, centres, np.sqrt(3.0) / 2.0 * edge, out,
    )
    return out


def radius_normals(
    points: np.ndarray,
    radius: float,
    *,
    viewpoint: np.ndarray | None = None,
    mode: str = "fast",
    resolution: int = 4,
    min_points: int = 3,
    at: np.ndarray | None = None,
    density: float | None = None,
    return_variation: bool = False,
    origin=None,
    rounding: float | None = None,
    grid_step: float | None = None,
):
    """Unit normals from the PCA of all points within ``radius`` of each point.

    Parameters
    ----------
    points : (N, 3) array, or laspy.LasData
        Coordinates (metres), any order; large projected values are fine.
    radius : float
        Support radius (metres).
    viewpoint : (3,) array, optional
        Every normal is turned to face it.  Default: :func:`default_viewpoint`
        (above the middle of the cloud).
    mode : {"fast", "exact"}
        Voxel moments (default; see the module's text) or the reference PCA
        of the ball's points (PCL's values).  Measured on the synthetic city
        and the real files (tools/bench_don.py), fast-mode DoN magnitudes
        are within about 0.015 of exact ones at the 99th percentile, at
        1.5-3 times the speed, hence the default.
    resolution : int
        Fast mode: voxels per radius (voxel edge ``radius / resolution``).
    min_points : int
        Fewest points in a ball for a normal (at least 3).
    at : (M,) int array or (N,) bool array, optional
        Indices of the points to compute normals at, or a mask of them
        (neighbours are still all of ``points``).  Default: every point.
    density : float, optional
        Fast mode: :func:`cell_density` of the cloud at the voxel edge,
        which decides whether voxels pay off at this radius (default: from
        ``points``; give the whole cloud's when ``points`` is a part of it).
    return_variation : bool
        Also return the surface variation l3 / (l1 + l2 + l3) of each ball.
    origin : (3,) float, optional
        Fast mode's voxels lie at multiples of their edge from this point
        (default: :func:`grid_origin` of ``points``, where a tiled run's
        frame starts, so the whole file's values are those of
        ``patchcloud don``; moving the origin by a fraction of a voxel moves
        fast-mode values a little, exact ones only by rounding).
    rounding : float, optional
        The step the coordinates are rounded to (metres; default
        :func:`coordinate_step` of ``points``: a ``laspy.LasData``'s largest
        scale, else 0): a ball whose points lie within it of a line (second
        eigenvalue below ``rounding**2``) has no normal.
    grid_step : float, optional
        The step of the grid the coordinates lie on (default
        :func:`grid_step_of` of ``points``: a ``laspy.LasData``'s smallest
        scale, else 0).  A point exactly ``radius`` from a query point is
        within the ball, and a point on a voxel's face in the voxel above
        it, however the coordinates' frame rounds them: the same file with
        another offset, or cut into other tiles, gives the same balls (the
        frame rounded these ties either way).

    Returns
    -------
    normals : (M, 3) float64
        Unit normals; rows of NaN where the normal is undefined (too few
        points, or collinear, up to ``rounding``, or coincident ones).
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
    step = coordinate_step(points) if rounding is None else check_rounding(rounding)
    pts = check_points(points)
    r = check_radius("radius", radius)
    check_mode(mode, resolution, min_points)
    vp = default_viewpoint(pts) if viewpoint is None else check_viewpoint(viewpoint)
    at = None if at is None else check_indices(at, pts.shape[0])
    q = pts if at is None else pts[at]
    tie = check_grid_step(points, grid_step)
    mom = radius_moments(pts, r, mode=mode, resolution=resolution, at=at, density=density, origin=origin, grid_step=tie)
    normals = np.empty((q.shape[0], 3))
    variation = np.empty(q.shape[0])
    if q.shape[0]:
        _rk.pca_normals(mom, q, vp, float(min_points), step * step, normals, variation)
    return (normals, variation) if return_variation else normals
