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
from typing import Sequence

import numpy as np

from . import _kernels
from .errors import PatchcloudValueError
from .calibration import rmse_histograms, threshold_from_histograms
from .octree import estimate_spacing, sort_points
from .options import NormalsOptions, options_with
from .patches import PatchTable
from .points import root_cube, validate_points
from .tiles import finish_tile, fit_tile, patch_signs

__all__ = ["NormalsParameters", "NormalsResult", "estimate_normals"]


@dataclass(frozen=True)
class NormalsParameters:
    """The parameters a run used, defaults resolved from the data (lengths in metres).

    What the user asked is a :class:`~patchcloud.core.options.NormalsOptions`;
    this is what the run made of it: ``threshold``, ``d_min`` and
    ``max_edge`` as computed, the point ``spacing`` they came from, and the
    root cube of the octree.
    """

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
        Principal curvatures ``k1 >= k2`` (1/unit of the coordinates) of the fitted quadric at
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
        """(N,) ``(k1 + k2) / 2`` (1/unit of the coordinates)."""
        return 0.5 * (self.k1.astype(np.float64) + self.k2)

    @property
    def surface_variation(self) -> np.ndarray:
        """(N,) same as :attr:`curvature`, under its geometric name."""
        return self.curvature


def estimate_normals(
    points: np.ndarray,
    options: NormalsOptions | None = None,
    *,
    root: tuple[Sequence[float], float] | None = None,
    **kwargs,
) -> NormalsResult:
    """Normals, curvatures and quadric patch models of one cloud.

    Parameters
    ----------
    points : (N, 3) array_like of float or int, or laspy.LasData
        Coordinates (metres, or any unit: the defaults scale with the data,
        exactly for a change of unit by a power of two; otherwise the
        threshold's calibration cells, of power-of-two edges in the
        coordinates' unit, are other cells, and the default threshold
        differs by up to about 20 %: 0.80 times as large for the embedded
        IGN tile in millimetres as in metres).
        Large offsets such as UTM are fine: everything is computed in float64
        relative to the root cube's corner.
    options : NormalsOptions, optional
        What to compute: the criterion and its threshold, ``d_min``,
        ``max_edge``, ``n_min``, ``min_sigma2``, ``k_fallback``, the
        orientation rule (``orient``, ``viewpoint``) and ``blend``; see
        :class:`~patchcloud.core.options.NormalsOptions` for each one's
        meaning and default (None: from the data).
    root : ((3,) float, float) or "grid", optional
        Minimum corner and edge of the root cube; default: the bounding cube
        of the points (results then do not move with the cloud).  The stream
        passes a tile's cube so per-tile octrees are subtrees of one global
        octree; "grid" takes that global octree's cube
        (:data:`~patchcloud.core.GRID_ANCHOR`), so a whole file's points in
        memory give the normals of ``patchcloud normals`` of the file (its
        noise and withheld points left out, as the command does).
    **kwargs
        Any field of :class:`~patchcloud.core.options.NormalsOptions` by
        name (``criterion="sigma3"``, ``orient="outward"``), overriding
        ``options``.

    Returns
    -------
    NormalsResult

    Raises
    ------
    PatchcloudValueError (a ValueError)
        Wrong shape or dtype, NaN or infinite coordinates, or an invalid
        parameter; the message says which.  (A cloud of fewer than ``n_min``
        points is taken: no patch then, every point a moment or k-NN normal.)

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
    pts, lo, hi = validate_points(points)
    opts = options_with(NormalsOptions, options, kwargs)
    criterion, threshold, d_min, max_edge = opts.criterion, opts.threshold, opts.d_min, opts.max_edge
    n_min, min_sigma2, k_fallback, orient, blend = opts.n_min, opts.min_sigma2, opts.k_fallback, opts.orient, opts.blend
    vp = np.asarray(opts.viewpoint, dtype=np.float64) if orient == "viewpoint" else None
    n = pts.shape[0]
    if n == 0:
        raise PatchcloudValueError("the cloud has no points")

    clock = _Clock()
    corner, edge = root_cube(lo, hi, root)
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
    elif threshold is None:  # the scanner noise, on cells anchored at the root cube's corner (the stream: its grid's origin)
        threshold = threshold_from_histograms(rmse_histograms(local, d_min, n_min), d_min, spacing)
    centre = corner + local.mean(axis=0) if orient == "outward" else None  # only the outward rule has a centre
    fit = fit_tile(
        pts, corner, edge, criterion=criterion, threshold=threshold, d_min=d_min, max_edge=max_edge, n_min=n_min,
        min_sigma2=min_sigma2, orient=orient, viewpoint=vp, centre=centre, spacing=spacing, sorted_input=sorted_input,
    )
    clock.lap("octree")
    sign, _ = patch_signs(len(fit.patches), fit.links, fit.agreement, fit.score, orient)
    clock.lap("orient")
    tile = finish_tile(
        fit.local, fit.patches, sign, d_min=d_min, min_sigma2=min_sigma2, k_fallback=k_fallback, orient=orient,
        viewpoint=vp, centre=centre,
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
