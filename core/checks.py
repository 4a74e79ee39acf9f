"""Validation of the options and arguments of the core's functions: the valid values and the checks.

Light on purpose (numpy only): :mod:`patchcloud.core.options` and the
command line import it without loading the compiled kernels.
"""

from __future__ import annotations

import numpy as np

from .errors import PatchcloudValueError

__all__ = [
    "coordinates", "CRITERIA", "ORIENT_RULES", "MODES", "check_positive", "check_radius", "check_viewpoint", "check_mode",
    "check_cluster_sizes", "check_budget", "check_indices", "check_rounding", "is_lasdata", "MAX_COORDINATE", "check_flag",
]

#: Octree split criteria: quadric fit RMSE (metres) or surface variation.
CRITERIA = ("rmse", "sigma3")
#: Global orientation rules: towards +Z, towards a viewpoint, away from the centre, none.
ORIENT_RULES = ("up", "viewpoint", "outward", "none")
#: Valid values of ``mode`` (radius neighbourhoods).
MODES = ("exact", "fast")


def coordinates(points):
    """What the functions taking a cloud read its coordinates from: ``points`` itself, or a ``laspy.LasData``'s ``xyz``.

    A ``laspy.LasData`` (anything with ``xyz``, ``header`` and
    ``point_format``: laspy is not imported here) gives its scaled
    coordinates, ``X * scale + offset`` as (N, 3) float64 in the file's
    coordinates (metres), in the file's point order; exact to about 1e-9 m
    for coordinates of a few million metres.  The functions then work in a
    local frame of their own (the root cube's corner, each query point), so
    that a viewpoint or a patch is in the file's coordinates as well.

    Examples
    --------
    >>> import laspy
    >>> las = laspy.read(sample)
    >>> xyz = coordinates(las)
    >>> xyz.shape, xyz.dtype, bool((xyz.min(axis=0) == las.header.mins).all())
    ((60653, 3), dtype('float64'), True)
    >>> coordinates([[0, 1, 2]])
    [[0, 1, 2]]
    """
    return points.xyz if is_lasdata(points) else points


def is_lasdata(points) -> bool:
    """Whether ``points`` is a ``laspy.LasData`` (anything with ``xyz``, ``header`` and ``point_format``).

    >>> is_lasdata(np.zeros((2, 3)))
    False
    """
    return hasattr(points, "xyz") and hasattr(points, "header") and hasattr(points, "point_format")


def check_positive(name: str, value, integer: bool = False):
    """``value`` as a positive float (or int with ``integer``), None kept; else a PatchcloudValueError naming ``name``.

    >>> check_positive("d_min", 0.5), check_positive("n_min", 12.0, integer=True), check_positive("x", None)
    (0.5, 12, None)
    >>> check_positive("k", 2.5, integer=True)
    Traceback (most recent call last):
    ...
    patchcloud.core.errors.PatchcloudValueError: k must be a positive integer, got 2.5
    """
    if value is None:
        return None
    number = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))
    if integer:
        if not number or not np.isfinite(value) or int(value) != value or value < 1:
            raise PatchcloudValueError(f"{name} must be a positive integer, got {value!r}")
        return int(value)
    if not number or not np.isfinite(value) or value <= 0:
        raise PatchcloudValueError(f"{name} must be a positive finite number, got {value!r}")
    return float(value)


def check_radius(name: str, value) -> float:
    """A finite, positive radius (metres), or a PatchcloudValueError (a string too: numbers are numbers here, as
    :func:`check_positive` takes them).

    >>> check_radius("r", 2), check_radius("r", np.float32(0.5))
    (2.0, 0.5)
    """
    if isinstance(value, (str, bytes, bool, np.bool_)):
        raise PatchcloudValueError(f"{name} must be a positive length in the coordinates' unit, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise PatchcloudValueError(f"{name} must be a positive length in the coordinates' unit, got {value!r}") from None
    if not np.isfinite(v) or v <= 0:
        raise PatchcloudValueError(f"{name} must be a positive length in the coordinates' unit, got {value!r}")
    return v


def check_viewpoint(viewpoint, name: str = "viewpoint") -> np.ndarray:
    """``viewpoint`` (or another point, ``name``) as a (3,) float64 array of finite coordinates, or a PatchcloudValueError.

    >>> check_viewpoint([0, 1, 2]).tolist()
    [0.0, 1.0, 2.0]
    >>> check_viewpoint([float("nan"), 0, 0], "origin")
    Traceback (most recent call last):
    ...
    patchcloud.core.errors.PatchcloudValueError: origin must be three finite coordinates (x, y, z), got [nan, 0, 0]
    """
    try:
        vp = np.asarray(viewpoint, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        vp = np.zeros(0)
    if vp.shape != (3,) or not np.isfinite(vp).all():
        raise PatchcloudValueError(f"{name} must be three finite coordinates (x, y, z), got {viewpoint!r}")
    if np.abs(vp).max() > MAX_COORDINATE:  # (1e308: squared distances overflow, and numpy warned on stderr)
        raise PatchcloudValueError(f"{name} must lie within {MAX_COORDINATE:g} of the origin, got {viewpoint!r}")
    return vp


#: The largest coordinate a point given as an option may have (a billion kilometres: past any CRS, and far from where
#: squared distances overflow).
MAX_COORDINATE = 1e12


def check_rounding(rounding, name: str = "rounding") -> float:
    """``rounding`` (the step the coordinates are rounded to, metres) as a float >= 0, or a PatchcloudValueError naming
    ``name`` (the argument as the caller calls it).

    >>> check_rounding(0.01)
    0.01
    >>> check_rounding(-1, "grid_step")
    Traceback (most recent call last):
    ...
    patchcloud.core.errors.PatchcloudValueError: grid_step must be a finite length of at least 0 (the coordinates' step), got -1
    """
    try:
        value = float(rounding)
    except (TypeError, ValueError):
        value = float("nan")
    if not (np.isfinite(value) and value >= 0):
        raise PatchcloudValueError(f"{name} must be a finite length of at least 0 (the coordinates' step), got {rounding!r}")
    return value


def check_mode(mode: str, resolution: int = 4, min_points: int = 3) -> None:
    """Validated ``mode`` (one of :data:`MODES`), ``resolution`` (>= 1) and ``min_points`` (>= 3)."""
    if mode not in MODES:
        raise PatchcloudValueError(f"mode must be one of {', '.join(MODES)}; got {mode!r}")
    if not isinstance(resolution, (int, np.integer)) or resolution < 1:
        raise PatchcloudValueError(f"resolution must be a whole number of voxels per radius, at least 1; got {resolution!r}")
    if not isinstance(min_points, (int, np.integer)) or min_points < 3:
        raise PatchcloudValueError(f"min_points must be a whole number, at least 3 (a plane needs three points); got {min_points!r}")


def check_cluster_sizes(min_points, max_points) -> tuple[int, int | None]:
    """Validated ``min_points`` (1 to 2**63 - 1) and ``max_points`` (None or min_points to 2**63 - 1): counts of points."""
    most = np.iinfo(np.int64).max
    if not isinstance(min_points, (int, np.integer)) or not 1 <= min_points <= most:
        raise PatchcloudValueError(f"min_points must be a whole number of points, at least 1 (at most {most}); got {min_points!r}")
    if max_points is not None and (not isinstance(max_points, (int, np.integer)) or max_points < min_points):
        raise PatchcloudValueError(f"max_points must be a whole number no smaller than min_points ({min_points}), or None; got {max_points!r}")
    if max_points is not None and max_points > most:
        raise PatchcloudValueError(f"max_points must be a whole number of points, at most {most}, or None; got {max_points!r}")
    return int(min_points), None if max_points is None else int(max_points)


def check_budget(max_error) -> float:
    """The error budget as a positive float (metres), or a PatchcloudValueError: a length, as :func:`check_radius` takes it."""
    return check_radius("max_error", max_error)


def check_indices(at, n: int, name: str = "at") -> np.ndarray:
    """``at`` as (M,) int64 indices of ``n`` points: whole numbers in ``[0, n)``, or a boolean mask of length ``n``
    (its True rows); else a PatchcloudValueError saying which.

    >>> check_indices([3, 0], 5).tolist(), check_indices(np.array([True, False, True]), 3).tolist()
    ([3, 0], [0, 2])
    >>> check_indices([5], 5)
    Traceback (most recent call last):
    ...
    patchcloud.core.errors.PatchcloudValueError: at must hold indices of the 5 points (0 to 4) or be a mask of 5 booleans; got 5
    """
    a = np.asarray(at)
    if a.dtype == bool:
        if a.shape != (n,):
            raise PatchcloudValueError(f"{name} as a mask must hold {n} booleans, one per point; got shape {a.shape}")
        return np.flatnonzero(a)
    valid = f"indices of the {n} points (0 to {n - 1}) or be a mask of {n} booleans"
    if a.ndim != 1 or (a.size and not np.issubdtype(a.dtype, np.integer)):
        raise PatchcloudValueError(f"{name} must hold {valid}; got an array of shape {a.shape} and type {a.dtype}")
    a = a.astype(np.int64)
    if a.size and (a.min() < 0 or a.max() >= n):
        bad = a[(a < 0) | (a >= n)][0]
        raise PatchcloudValueError(f"{name} must hold {valid}; got {bad}")
    return a


def check_flag(name: str, value, allow_none: bool = False) -> bool | None:
    """``value`` as a bool when it is one (numpy's included; None too where ``allow_none``); a PatchcloudValueError
    naming ``name`` otherwise, so that ``overwrite="no"`` is not taken as true.

    >>> check_flag("overwrite", np.True_), check_flag("keep_store", None, allow_none=True)
    (True, None)
    >>> check_flag("overwrite", "no")
    Traceback (most recent call last):
    ...
    patchcloud.core.errors.PatchcloudValueError: overwrite must be True or False, got 'no'
    """
    if value is None and allow_none:
        return None
    if not isinstance(value, (bool, np.bool_)):
        valid = "True, False or None" if allow_none else "True or False"
        raise PatchcloudValueError(f"{name} must be {valid}, got {value!r}")
    return bool(value)
