"""The checks (points, positive numbers) and the root cube shared by the entry points that take one cloud.

:func:`patchcloud.core.estimate_normals` and :func:`patchcloud.core.fit_models`
both validate their ``points`` argument and place them in a root cube, the
octree's level 0; both do it here, so that their messages and their cubes
are the same.
"""

from __future__ import annotations

import numpy as np

from . import _kernels
from .checks import check_positive, check_viewpoint, coordinates
from .errors import PatchcloudValueError

__all__ = ["validate_points", "root_cube", "GRID_ANCHOR"]

#: The stream's tile grids start at a multiple of this (metres), so grids of every power-of-two tile size up to it
#: align, and their octrees' cells are those of ``root="grid"``.
GRID_ANCHOR = 4096.0


def validate_points(points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points as C-ordered float64, and their per-axis minimum and maximum.

    Parameters
    ----------
    points : (N, 3) array_like of float or int, or laspy.LasData
        Coordinates (a ``LasData``'s: :func:`~patchcloud.core.checks.coordinates`).

    Returns
    -------
    pts : (N, 3) float64
        The points, C-ordered (``points`` itself when it already is).
    lo, hi : (3,) float64
        Per-axis minimum and maximum of the points.

    Raises
    ------
    PatchcloudValueError
        A dtype that is not real numeric, a shape other than (N, 3), or NaN or
        infinite coordinates (the message gives their count and first row).

    Examples
    --------
    >>> pts, lo, hi = validate_points([[0, 1, 2], [3, -1, 5]])
    >>> pts.dtype, lo.tolist(), hi.tolist()
    (dtype('float64'), [0.0, -1.0, 2.0], [3.0, 1.0, 5.0])
    """
    arr = np.asarray(coordinates(points))
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise PatchcloudValueError(f"points must be a real numeric array (float or int), got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise PatchcloudValueError(f"points must have shape (N, 3), got {arr.shape}")
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    lo, hi, finite = _kernels.bounds(arr)
    if not finite:
        bad = ~np.isfinite(arr).all(axis=1)
        first = int(np.flatnonzero(bad)[0])
        raise PatchcloudValueError(
            f"points contain {int(bad.sum())} rows with NaN or infinite coordinates (first at row {first})"
        )
    return arr, lo, hi


#: The bounding cube's margins are multiples of 1 / _MARGIN_STEPS (metres, or the cloud's unit).
_MARGIN_STEPS = 2.0**20


def root_cube(lo: np.ndarray, hi: np.ndarray, root) -> tuple[np.ndarray, float]:
    """The root cube of the octree: the given one, checked, or the bounding cube of the points.

    Parameters
    ----------
    lo, hi : (3,) float64
        Per-axis minimum and maximum of the points (as :func:`validate_points`).
    root : ((3,) float, float), "grid" or None
        Minimum corner and edge of the root cube (a tile of the stream);
        "grid": the cube the stream's tiles are cells of, its corner the
        grid's origin (the multiple of :data:`GRID_ANCHOR` at or below the
        points), its edge :data:`GRID_ANCHOR` times a power of two; or None
        for the points' bounding cube: centred on the points' box, its
        edge the box's longest side plus a margin of 1e-6 of it (or a tiny
        positive edge when all points coincide).

    Returns
    -------
    corner : (3,) float64
        Minimum corner of the cube.
    edge : float
        Its edge.

    Raises
    ------
    PatchcloudValueError
        A given edge that is not a positive finite number, or points outside
        the given cube.

    Examples
    --------
    >>> import numpy as np
    >>> corner, edge = root_cube(np.zeros(3), np.array([4.0, 2.0, 1.0]), None)
    >>> bool(edge > 4.0), bool(np.all(corner < 0))
    (True, True)
    >>> root_cube(np.zeros(3), np.ones(3), ((0, 0, 0), 8))
    (array([0., 0., 0.]), 8.0)
    >>> corner, edge = root_cube(np.array([650100.0, 6860200.0, 10.0]), np.array([650900.0, 6860700.0, 90.0]), "grid")
    >>> corner.tolist(), edge
    ([647168.0, 6856704.0, 0.0], 4096.0)
    >>> corner, edge = root_cube(np.array([-1.0, 5.0, 5.0]), np.array([1.0, 6.0, 6.0]), "grid")  # across 0
    >>> corner.tolist(), edge
    ([-4096.0, 0.0, 0.0], 8192.0)
    """
    if isinstance(root, str):
        if root != "grid":
            raise PatchcloudValueError(f"root must be (corner, edge), 'grid' or None; got {root!r}")
        # the smallest cube of a power-of-two multiple of GRID_ANCHOR for an edge, from the grid's origin (the multiple of
        # GRID_ANCHOR at or below the points, where the stream's tiles start), holding every point: its cells of a tile's
        # size are the tiles.  (A cube at a multiple of its own edge never held a cloud across 0: 0 is on its face.)
        corner = np.floor(lo / GRID_ANCHOR) * GRID_ANCHOR
        edge = GRID_ANCHOR
        while not np.all(hi < corner + edge):
            edge *= 2.0
        return corner, edge
    if root is not None:
        try:
            corner, edge = root
        except (TypeError, ValueError):
            raise PatchcloudValueError(f"root must be (corner, edge), 'grid' or None; got {root!r}") from None
        corner = check_viewpoint(corner, "root corner")
        edge = check_positive("root edge", edge)
        if np.any(lo < corner) or np.any(hi > corner + edge):
            raise PatchcloudValueError("points lie outside the given root cube")
        return corner, edge
    extent = float((hi - lo).max())
    scale = max(extent, float(np.abs(lo).max()) * 1e-12, 1e-9)
    edge = extent + 1e-6 * scale if extent > 0 else scale
    # centred on the box, the margins rounded down to multiples of 2^-20: the corner, lo minus a number of few bits, and
    # every point's offset from it are then exact, so a cloud shifted exactly (by whole metres from UTM coordinates, say)
    # gets the same offsets, bit for bit, and the same results (the centre (lo + hi) / 2 rounded apart in the two frames)
    margin = np.floor((edge - (hi - lo)) / 2.0 * _MARGIN_STEPS) / _MARGIN_STEPS
    corner = lo - margin
    return corner, edge
