"""What the user asks of each job: one frozen, validated dataclass per kind of job.

An options object holds the user's choices; ``None`` means "derive it from
the data".  It is checked when it is made, and an invalid value is a
:class:`~patchcloud.core.errors.PatchcloudValueError` that lists the valid
ones.  The same object serves the in-memory functions
(:func:`patchcloud.core.estimate_normals`,
:func:`patchcloud.core.difference_of_normals`, ...), the out-of-core jobs
(:func:`patchcloud.stream.normals`, ...) and the command line, which takes
its defaults from here.

The values a run *resolved* from the data (point spacing, ``d_min``, the
RMSE threshold, the root cube) are another thing:
:class:`patchcloud.core.NormalsParameters` holds them, and the stream's
"done with these parameters" keys hash them.

>>> NormalsOptions(criterion="sigma3").threshold is None
True
>>> NormalsOptions(orient="sideways")
Traceback (most recent call last):
...
patchcloud.core.errors.PatchcloudValueError: orient must be one of up, viewpoint, outward, none; got 'sideways'
>>> SegmentOptions(r_small=0.1, r_large=1.0, tolerance=0.5).min_cluster
50
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .checks import (
    CRITERIA, ORIENT_RULES, check_budget, check_cluster_sizes, check_mode, check_positive, check_radius, check_viewpoint,
)
from .errors import PatchcloudValueError

__all__ = [
    "NormalsOptions", "DonOptions", "SegmentOptions", "CompressOptions", "options_with", "check_scales", "check_threshold", "AXES", "MAX_K_FALLBACK",
]


def _set(obj, name: str, value) -> None:
    object.__setattr__(obj, name, value)


def _viewpoint(viewpoint) -> tuple[float, float, float] | None:
    return None if viewpoint is None else tuple(float(v) for v in check_viewpoint(viewpoint))


#: Names of the DoN vector's components, for thresholds on one of them.
AXES = ("x", "y", "z")
#: The most neighbours a k-NN fallback normal may take.
MAX_K_FALLBACK = 1000


def check_scales(r_small, r_large) -> tuple[float, float]:
    """Validated radii: both positive, ``r_small < r_large``."""
    rs = check_radius("r_small", r_small)
    rl = check_radius("r_large", r_large)
    if not rs < rl:
        raise PatchcloudValueError(f"r_small must be smaller than r_large; got r_small={rs:g}, r_large={rl:g} (in the coordinates' unit)")
    return rs, rl


def check_threshold(threshold, axis=None, axis_threshold=None) -> None:
    """Validated thresholds: magnitudes in [0, 1], an axis among :data:`AXES` with its own threshold."""
    for name, v in (("threshold", threshold), ("axis_threshold", axis_threshold)):
        if v is None and name == "axis_threshold":
            continue
        try:
            ok = not isinstance(v, (str, bytes)) and 0.0 <= float(v) <= 1.0
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise PatchcloudValueError(f"{name} must be a DoN magnitude in [0, 1] (a number); got {v!r}")
    if axis is None and axis_threshold is not None:
        raise PatchcloudValueError("axis_threshold needs an axis (one of x, y, z)")
    if axis is not None:
        if axis not in AXES:
            raise PatchcloudValueError(f"axis must be one of {', '.join(AXES)}; got {axis!r}")
        if axis_threshold is None:
            raise PatchcloudValueError(f"axis {axis!r} needs an axis_threshold in [0, 1]")



@dataclass(frozen=True)
class NormalsOptions:
    """What a normals run is asked for (lengths in metres); ``None``: from the data.

    Parameters
    ----------
    criterion : {"rmse", "sigma3"}
        When an octree node is one smooth patch: its quadric fit RMSE is at
        most ``threshold`` metres ("rmse"), or its surface variation sigma3
        is at most ``threshold`` ("sigma3", dimensionless).
    threshold : float, optional
        Default for "rmse": twice the median fit RMSE of the smallest nodes
        (the scanner noise) and at least 1/50 of the point spacing; for
        "sigma3": 0.005.
    d_min : float, optional
        Minimum leaf edge.  Default: 3 times the point spacing.
    max_edge : float, optional
        Maximum leaf edge: larger nodes are split even when uniform.
        Default: 256 times the point spacing.
    n_min : int
        Nodes with fewer points are not split and get no surface.
    min_sigma2 : float
        Leaves with sigma2 below this, in [0, 1/3), are 3D curves: edge patches.
    k_fallback : int
        Neighbours of the k-NN PCA normal of the points of edge and sparse
        leaves, 3 to :data:`MAX_K_FALLBACK` (a plane needs 3 points; more than
        a thousand is no longer a local normal, and the search slows as k^2).
    orient : {"up", "viewpoint", "outward", "none"}
        Which side normals face: +Z (aerial and mobile LiDAR), ``viewpoint``
        (every normal faces it, point by point, as PDAL's ``viewpoint``: the
        side a scanner at that point saw), away from the cloud's centroid
        (closed objects), or no rule (consistent but arbitrary sign).  The
        other rules decide for whole groups of linked patches.
    viewpoint : (3,) float, optional
        Required with ``orient="viewpoint"`` (the points' coordinates).
    blend : bool
        Blend normals and curvatures across leaf faces.
    """

    criterion: str = "rmse"
    threshold: float | None = None
    d_min: float | None = None
    max_edge: float | None = None
    n_min: int = 12
    min_sigma2: float = 0.01
    k_fallback: int = 16
    orient: str = "up"
    viewpoint: tuple[float, float, float] | None = None
    blend: bool = True

    def __post_init__(self) -> None:
        if self.criterion not in CRITERIA:
            raise PatchcloudValueError(f"criterion must be one of {', '.join(CRITERIA)}; got {self.criterion!r}")
        if self.orient not in ORIENT_RULES:
            raise PatchcloudValueError(f"orient must be one of {', '.join(ORIENT_RULES)}; got {self.orient!r}")
        _set(self, "n_min", check_positive("n_min", self.n_min, integer=True))
        k = self.k_fallback
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 3 <= k <= MAX_K_FALLBACK:
            raise PatchcloudValueError(f"k_fallback must be a whole number from 3 to {MAX_K_FALLBACK}; got {k!r}")
        _set(self, "k_fallback", int(k))
        for name in ("threshold", "d_min", "max_edge"):
            _set(self, name, check_positive(name, getattr(self, name)))
        if self.criterion == "sigma3" and self.threshold is not None and self.threshold >= 1 / 3:  # every leaf would pass
            raise PatchcloudValueError(f"threshold must be below 1/3 with criterion sigma3 (a surface variation is at most 1/3); "
                                       f"got {self.threshold:g}")
        if self.d_min is not None and self.max_edge is not None and self.d_min > self.max_edge:
            raise PatchcloudValueError(f"d_min must be at most max_edge; got d_min={self.d_min:g}, max_edge={self.max_edge:g}")
        if not (0 <= self.min_sigma2 < 1 / 3 + 1e-12):
            raise PatchcloudValueError(f"min_sigma2 must be in [0, 1/3), got {self.min_sigma2!r}")
        _set(self, "min_sigma2", float(self.min_sigma2))
        if self.orient == "viewpoint" and self.viewpoint is None:
            raise PatchcloudValueError('orient="viewpoint" needs a viewpoint (x, y, z): give viewpoint=(x, y, z)')
        if self.orient != "viewpoint" and self.viewpoint is not None:  # it would be ignored
            raise PatchcloudValueError(f'viewpoint goes with orient="viewpoint", not orient={self.orient!r}')
        _set(self, "viewpoint", _viewpoint(self.viewpoint))
        if not isinstance(self.blend, (bool, np.bool_)):
            raise PatchcloudValueError(f"blend must be True or False; got {self.blend!r}")
        _set(self, "blend", bool(self.blend))


@dataclass(frozen=True)
class DonOptions:
    """What a Difference-of-Normals run is asked for (lengths in metres).

    Parameters
    ----------
    r_small, r_large : float
        Support radii of the two normals, ``r_small < r_large``.
    mode : {"fast", "exact"}
        Radius normals from voxel moments (cost independent of the points
        per ball) or by PCA of every point in the ball (PCL's definition).
    viewpoint : (3,) float, optional
        Both normals face it (the points' coordinates).  Default: above the
        middle of the cloud, one extent above its top.
    resolution : int
        Fast mode's voxels per radius (at least 1).
    min_points : int
        Fewest points in a ball for a normal (at least 3).
    """

    r_small: float = 0.2
    r_large: float = 2.0
    mode: str = "fast"
    viewpoint: tuple[float, float, float] | None = None
    resolution: int = 4
    min_points: int = 3

    def __post_init__(self) -> None:
        rs, rl = check_scales(self.r_small, self.r_large)
        check_mode(self.mode, self.resolution, self.min_points)
        _set(self, "r_small", rs)
        _set(self, "r_large", rl)
        _set(self, "resolution", int(self.resolution))
        _set(self, "min_points", int(self.min_points))
        _set(self, "viewpoint", _viewpoint(self.viewpoint))


@dataclass(frozen=True)
class SegmentOptions(DonOptions):
    """What a DoN segmentation is asked for: the DoN's options, then which points are kept and how they are joined.

    Parameters
    ----------
    r_small, r_large, mode, viewpoint, resolution, min_points :
        As :class:`DonOptions`.
    threshold : float
        Smallest DoN magnitude of a point kept, in [0, 1].
    tolerance : float
        Largest gap (metres) between two points of one segment (PDAL's
        ``tolerance`` of filters.cluster).
    min_cluster, max_cluster : int
        Segments of fewer or more points get id 0 (PDAL's ``min_points`` and
        ``max_points``; the command line's ``--min-points``).
    axis : {"x", "y", "z"}, optional
        Also require ``|DoN_axis| >= axis_threshold`` (e.g. "z" for kerbs).
    axis_threshold : float, optional
        With ``axis``, in [0, 1].
    """

    threshold: float = 0.25
    tolerance: float = 0.2
    min_cluster: int = 50
    max_cluster: int | None = None
    axis: str | None = None
    axis_threshold: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        check_threshold(self.threshold, self.axis, self.axis_threshold)
        _set(self, "tolerance", check_radius("tolerance", self.tolerance))
        lo, hi = check_cluster_sizes(self.min_cluster, self.max_cluster)
        _set(self, "min_cluster", lo)
        _set(self, "max_cluster", hi)
        _set(self, "threshold", float(self.threshold))
        if self.axis_threshold is not None:
            _set(self, "axis_threshold", float(self.axis_threshold))

    @property
    def don(self) -> DonOptions:
        """The DoN part of these options."""
        return DonOptions(self.r_small, self.r_large, self.mode, self.viewpoint, self.resolution, self.min_points)


@dataclass(frozen=True)
class CompressOptions:
    """What a compression is asked for.

    Parameters
    ----------
    max_error : float
        The error budget (metres).  Model mode: patches are split until
        their quadric fits their points with an RMS error below it; the
        points no patch models within it are kept as residual points, each
        within it of where it was.  Points mode: every point within it
        of where it was (Euclidean, at most).
    keep_points : bool
        Points mode: every point back, in input order, its attributes
        exact (default False: model mode, the patch models).
    drop : tuple of str
        Dimensions not kept (written as zeros): PDAL's or laspy's names,
        checked against the file's point format by the stream.
    """

    max_error: float = 0.02
    keep_points: bool = False
    drop: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        _set(self, "max_error", check_budget(self.max_error))
        if not isinstance(self.keep_points, (bool, np.bool_)):
            raise PatchcloudValueError(f"keep_points must be True or False, got {self.keep_points!r}")
        drop = (self.drop,) if isinstance(self.drop, str) else self.drop
        if not all(isinstance(d, str) and d for d in drop):
            raise PatchcloudValueError(f"drop must be dimension names, got {self.drop!r}")
        _set(self, "keep_points", bool(self.keep_points))
        _set(self, "drop", tuple(drop))


def options_with(kind: type, options=None, overrides: dict | None = None):
    """``options`` (a ``kind``, default ``kind()``) with the fields named in ``overrides`` replaced, validated.

    An unknown name, or ``options`` of another kind, is a
    PatchcloudValueError listing the valid names.

    >>> options_with(NormalsOptions, None, {"orient": "outward"}).orient
    'outward'
    >>> options_with(DonOptions, DonOptions(r_small=0.1), {"radius": 1})
    Traceback (most recent call last):
    ...
    patchcloud.core.errors.PatchcloudValueError: unknown option radius; valid: min_points, mode, r_large, r_small, resolution, viewpoint
    """
    kinds = (NormalsOptions, DonOptions, SegmentOptions, CompressOptions)
    if kind not in kinds:
        raise PatchcloudValueError(f"kind must be one of {', '.join(k.__name__ for k in kinds)}, got {kind!r}")
    if options is not None and not isinstance(options, kind):
        raise PatchcloudValueError(f"options must be a {kind.__name__}, got {type(options).__name__}")
    overrides = dict(overrides or {})
    valid = sorted(f.name for f in dataclasses.fields(kind))
    unknown = sorted(set(overrides) - set(valid))
    if unknown:
        raise PatchcloudValueError(
            f"unknown option{'s' if len(unknown) > 1 else ''} {', '.join(unknown)}; valid: {', '.join(valid)}"
        )
    if options is None:
        return kind(**overrides)
    return dataclasses.replace(options, **overrides) if overrides else options
