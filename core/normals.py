"""``estimate_normals``: normals and curvature of one in-memory cloud.

The pipeline of the anisotropic-octrees paper, extended so that every point
gets a normal:

1. sort the points by Morton key in a local float64 frame and build the
   anisotropic octree (:mod:`.octree`), which fits a PCA plane and a quadric
   to every leaf;
2. give every point of a surface leaf the normal and principal curvatures of
   its projection on the leaf's quadric (:mod:`.quadric`);
3. orient the patches consistently by face sampling and apply a global rule
   (:mod:`.orient`);
4. blend normals and curvatures across leaf faces (:mod:`.blend`);
5. give the points of edge and sparse leaves a k-nearest-neighbour PCA
   normal, oriented like their neighbours (:mod:`.fallback`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from enum import IntEnum
from typing import Sequence

import numpy as np

from . import _kernels
from .errors import PatchcloudValueError
from .octree import CRITERIA, estimate_spacing, sort_points
from .orient import ORIENT_RULES
from .patches import PatchTable
from .tiles import finish_tile, fit_tile, patch_signs

__all__ = ["Method", "NormalsParameters", "NormalsResult", "check_parameters", "estimate_normals"]


class Method(IntEnum):
    """Which computation gave a point its normal."""

    #: The quadric of the point's own patch, at the point's projection.
    QUADRIC = 1
    #: The own quadric blended with neighbouring patches' (near a leaf face).
    BLENDED = 2
    #: PCA of the k nearest neighbours (points of edge and sparse leaves).
    KNN = 3


@dataclass(frozen=True)
class NormalsParameters:
    """The parameters a run used, defaults resolved (lengths in metres)."""

    criterion: str
    threshold: float
    d_min: float
    max_edge: float
    n_min: int
    min_sigma2: float
    k_fallback: int
    orient: str
    viewpoint: tuple[float, float, float] | None
    blend: bool
    spacing: float
    root_corner: tuple[float, float, float]
    root_edge: float


@dataclass(frozen=True)
class NormalsResult:
    """Per-point normals and curvature of a cloud, in input order (N points).

    Attributes
    ----------
    normals : (N, 3) float32
        Unit normals, oriented by the rule in ``parameters.orient``.
    curvature : (N,) float32
        Surface variation ``lambda3 / (lambda1 + lambda2 + lambda3)`` in
        [0, 1/3] (dimensionless): of the point's patch, blended near leaf
        faces, or of its k neighbours for ``Method.KNN`` points.  This is
        what PDAL and PCL call "curvature".
    k1, k2 : (N,) float32
        Principal curvatures ``k1 >= k2`` (1/metre) of the fitted quadric at
        the point, positive where the surface is convex seen from the side the
        normal points to (a sphere with outward normals has ``+1/R``).
    dir1 : (N, 3) float32
        Unit direction of ``k1`` (tangent); the ``k2`` direction is
        ``cross(normals, dir1)``.
    method : (N,) uint8
        :class:`Method` that gave each normal.
    patch : (N,) int32
        Row of :attr:`patches` whose leaf holds the point.
    patches : PatchTable
        The quadric patch models, oriented.
    parameters : NormalsParameters
        What was used, defaults resolved.
    timings : dict[str, float]
        Wall seconds of each step: sort, octree (fit), orient, evaluate
        (evaluation, blending and k-NN fallback), output.
    """

    normals: np.ndarray
    curvature: np.ndarray
    k1: np.ndarray
    k2: np.ndarray
    dir1: np.ndarray
    method: np.ndarray
    patch: np.ndarray
    patches: PatchTable
    parameters: NormalsParameters
    timings: dict

    @property
    def mean_curvature(self) -> np.ndarray:
        """(N,) ``(k1 + k2) / 2`` (1/metre)."""
        return 0.5 * (self.k1.astype(np.float64) + self.k2)

    @property
    def surface_variation(self) -> np.ndarray:
        """(N,) same as :attr:`curvature`, under its geometric name."""
        return self.curvature


def _validate_points(points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points as C-ordered float64, and their per-axis minimum and maximum."""
    arr = np.asarray(points)
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


def _positive(name: str, value, integer: bool = False):
    if value is None:
        return None
    if integer:
        if isinstance(value, bool) or int(value) != value or value < 1:
            raise PatchcloudValueError(f"{name} must be a positive integer, got {value!r}")
        return int(value)
    if not np.isfinite(value) or value <= 0:
        raise PatchcloudValueError(f"{name} must be a positive finite number, got {value!r}")
    return float(value)


def _root_cube(lo: np.ndarray, hi: np.ndarray, root) -> tuple[np.ndarray, float]:
    if root is not None:
        corner, edge = root
        corner = np.asarray(corner, dtype=np.float64).reshape(3)
        edge = _positive("root edge", edge)
        if np.any(lo < corner) or np.any(hi > corner + edge):
            raise PatchcloudValueError("points lie outside the given root cube")
        return corner, edge
    extent = float((hi - lo).max())
    scale = max(extent, float(np.abs(lo).max()) * 1e-12, 1e-9)
    edge = extent + 1e-6 * scale if extent > 0 else scale
    corner = (lo + hi) / 2.0 - edge / 2.0
    return corner, edge


def check_parameters(
    criterion: str,
    orient: str,
    viewpoint=None,
    *,
    threshold: float | None = None,
    d_min: float | None = None,
    max_edge: float | None = None,
    n_min: int = 12,
    min_sigma2: float = 0.01,
    k_fallback: int = 16,
) -> dict:
    """The parameters of :func:`estimate_normals`, validated and normalised.

    Returns a dict with ``threshold``, ``d_min``, ``max_edge`` (float or
    None), ``n_min``, ``k_fallback`` (int) and ``viewpoint`` ((3,) float64
    with ``orient="viewpoint"``, else None).

    Raises
    ------
    PatchcloudValueError
        The first invalid parameter, with the valid values.
    """
    if criterion not in CRITERIA:
        raise PatchcloudValueError(f"criterion must be one of {', '.join(CRITERIA)}; got {criterion!r}")
    if orient not in ORIENT_RULES:
        raise PatchcloudValueError(f"orient must be one of {', '.join(ORIENT_RULES)}; got {orient!r}")
    out = {
        "n_min": _positive("n_min", n_min, integer=True),
        "k_fallback": _positive("k_fallback", k_fallback, integer=True),
        "threshold": _positive("threshold", threshold),
        "d_min": _positive("d_min", d_min),
        "max_edge": _positive("max_edge", max_edge),
        "viewpoint": None,
    }
    if not (0 <= min_sigma2 < 1 / 3 + 1e-12):
        raise PatchcloudValueError(f"min_sigma2 must be in [0, 1/3), got {min_sigma2!r}")
    if orient == "viewpoint":
        if viewpoint is None:
            raise PatchcloudValueError('orient="viewpoint" needs a viewpoint (x, y, z)')
        vp = np.asarray(viewpoint, dtype=np.float64).reshape(-1)
        if vp.shape != (3,) or not np.isfinite(vp).all():
            raise PatchcloudValueError(f"viewpoint must be three finite numbers, got {viewpoint!r}")
        out["viewpoint"] = vp
    return out


def estimate_normals(
    points: np.ndarray,
    criterion: str = "rmse",
    *,
    threshold: float | None = None,
    d_min: float | None = None,
    max_edge: float | None = None,
    n_min: int = 12,
    min_sigma2: float = 0.01,
    k_fallback: int = 16,
    orient: str = "up",
    viewpoint: Sequence[float] | None = None,
    blend: bool = True,
    root: tuple[Sequence[float], float] | None = None,
) -> NormalsResult:
    """Normals, curvatures and quadric patch models of one cloud.

    Parameters
    ----------
    points : (N, 3) array_like of float or int
        Coordinates (metres, or any unit: the defaults scale with the data).
        Large offsets such as UTM are fine: everything is computed in float64
        relative to the root cube's corner.
    criterion : {"rmse", "sigma3"}
        When a node is uniform: its quadric fit RMSE is at most
        ``threshold`` metres ("rmse"), or its surface variation sigma3 is at
        most ``threshold`` ("sigma3", dimensionless).
    threshold : float, optional
        Default for "rmse": twice the median fit RMSE of the smallest
        nodes (the scanner noise) and at least 1/50 of the point spacing;
        for "sigma3": 0.005.
    d_min : float, optional
        Minimum leaf edge (metres). Default: 3 times the point spacing
        estimated from the octree occupancy.
    max_edge : float, optional
        Maximum leaf edge (metres): larger nodes are split even when
        uniform, so one patch never spans a whole flat tile.  Default: 256
        times the point spacing.
    n_min : int
        Nodes with fewer points are not split and get no surface (default 12).
    min_sigma2 : float
        Leaves with sigma2 (paper eq. 4) below this are 3D curves: edge
        patches (default 0.01).
    k_fallback : int
        Neighbours of the k-NN PCA normal of points in edge and sparse
        leaves (default 16).
    orient : {"up", "viewpoint", "outward", "none"}
        Global orientation rule applied to every connected group of patches
        after propagation: towards +Z (LiDAR default), towards
        ``viewpoint``, away from the cloud's centroid (closed objects), or
        none (consistent but arbitrary sign).
    viewpoint : (3,) float, optional
        Required with ``orient="viewpoint"``, in the points' coordinates.
    blend : bool
        Blend normals and curvatures across leaf faces (paper 2.4).
    root : ((3,) float, float), optional
        Minimum corner and edge of the root cube; default: the bounding cube
        of the points.  The stream passes a tile's cube so per-tile octrees
        are subtrees of one global octree.

    Returns
    -------
    NormalsResult

    Raises
    ------
    PatchcloudValueError (a ValueError)
        Wrong shape or dtype, NaN or infinite coordinates, fewer points than
        ``n_min``, or an invalid parameter; the message says which.

    Examples
    --------
    >>> import numpy as np
    >>> from patchcloud.core import estimate_normals
    >>> rng = np.random.default_rng(1)
    >>> d = rng.normal(size=(20000, 3))
    >>> sphere = d / np.linalg.norm(d, axis=1)[:, None]
    >>> res = estimate_normals(sphere, orient="outward")
    >>> cos = np.einsum("ij,ij->i", res.normals, sphere)
    >>> bool(np.median(cos) > 0.9998)
    True
    """
    pts, lo, hi = _validate_points(points)
    checked = check_parameters(
        criterion, orient, viewpoint, threshold=threshold, d_min=d_min, max_edge=max_edge, n_min=n_min,
        min_sigma2=min_sigma2, k_fallback=k_fallback,
    )
    threshold, d_min, max_edge = checked["threshold"], checked["d_min"], checked["max_edge"]
    n_min, k_fallback, vp = checked["n_min"], checked["k_fallback"], checked["viewpoint"]
    n = pts.shape[0]
    if n < n_min:
        raise PatchcloudValueError(f"the cloud has {n} points, fewer than n_min={n_min}")

    clock = _Clock()
    corner, edge = _root_cube(lo, hi, root)
    local = pts - corner
    sorted_input = sort_points(local, np.zeros(3), edge)
    spacing = estimate_spacing(sorted_input[1], edge)
    clock.lap("sort")
    if d_min is None:
        d_min = 3.0 * spacing if spacing > 0 else edge / 2.0**21
    if max_edge is None:
        max_edge = 256.0 * spacing if spacing > 0 else np.inf
    if threshold is None and criterion == "sigma3":
        threshold = 0.005
    centre = corner + local.mean(axis=0)
    fit = fit_tile(
        pts, corner, edge, criterion=criterion, threshold=threshold, d_min=d_min, max_edge=max_edge, n_min=n_min,
        min_sigma2=min_sigma2, orient=orient, viewpoint=vp, centre=centre, spacing=spacing, sorted_input=sorted_input,
    )
    clock.lap("octree")
    sign, _ = patch_signs(len(fit.patches), fit.links, fit.agreement, fit.score, orient)
    clock.lap("orient")
    tile = finish_tile(
        fit.local, fit.patches, sign, d_min=d_min, k_fallback=k_fallback, orient=orient, viewpoint=vp, centre=centre,
        blend=blend,
    )
    clock.lap("evaluate")

    params = NormalsParameters(
        criterion=criterion, threshold=fit.threshold, d_min=float(d_min), max_edge=float(max_edge), n_min=n_min, min_sigma2=float(min_sigma2),
        k_fallback=k_fallback, orient=orient, viewpoint=None if vp is None else tuple(vp.tolist()), blend=bool(blend),
        spacing=float(spacing), root_corner=tuple(corner.tolist()), root_edge=float(edge),
    )
    outputs = dict(
        normals=np.empty((n, 3), np.float32), curvature=np.empty(n, np.float32), k1=np.empty(n, np.float32),
        k2=np.empty(n, np.float32), dir1=np.empty((n, 3), np.float32), method=np.empty(n, np.uint8),
        patch=np.empty(n, np.int32),
    )
    _kernels.unsort_outputs(fit.order, tile.normals, tile.scalars, tile.dir1, tile.method, tile.patch, *outputs.values())
    clock.lap("output")
    return NormalsResult(**outputs, patches=tile.patches, parameters=params, timings=dict(clock.laps))


class _Clock:
    """Wall time of consecutive steps."""

    def __init__(self) -> None:
        self.laps: dict[str, float] = {}
        self._t = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.laps[name] = self.laps.get(name, 0.0) + now - self._t
        self._t = now
