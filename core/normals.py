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
from .blend import blend_across_faces
from .errors import PatchcloudValueError
from .fallback import knn_normals
from .octree import CRITERIA, KIND_SURFACE, Octree, build_octree, estimate_spacing, sort_points
from .orient import (
    ORIENT_RULES,
    component_rule_signs,
    face_agreement,
    face_neighbours,
    point_rule_signs,
    propagate_signs,
    rule_prior,
)
from .patches import PatchTable
from .quadric import turn_over

__all__ = ["Method", "NormalsParameters", "NormalsResult", "estimate_normals"]


#: Smallest |cos| between the PCA normals of an edge or sparse leaf and a neighbour for them to link.
DOT_MIN = 0.9
#: Smallest |agreement| of a face-neighbour pair for it to carry orientation.
MIN_RELIABILITY = 0.5


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
        Wall seconds of each step: sort, octree, orient, evaluate, blend,
        fallback, output.
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
    if criterion not in CRITERIA:
        raise PatchcloudValueError(f"criterion must be one of {', '.join(CRITERIA)}; got {criterion!r}")
    if orient not in ORIENT_RULES:
        raise PatchcloudValueError(f"orient must be one of {', '.join(ORIENT_RULES)}; got {orient!r}")
    n_min = _positive("n_min", n_min, integer=True)
    k_fallback = _positive("k_fallback", k_fallback, integer=True)
    threshold = _positive("threshold", threshold)
    d_min = _positive("d_min", d_min)
    max_edge = _positive("max_edge", max_edge)
    if not (0 <= min_sigma2 < 1 / 3 + 1e-12):
        raise PatchcloudValueError(f"min_sigma2 must be in [0, 1/3), got {min_sigma2!r}")
    vp = None
    if orient == "viewpoint":
        if viewpoint is None:
            raise PatchcloudValueError('orient="viewpoint" needs a viewpoint (x, y, z)')
        vp = np.asarray(viewpoint, dtype=np.float64).reshape(-1)
        if vp.shape != (3,) or not np.isfinite(vp).all():
            raise PatchcloudValueError(f"viewpoint must be three finite numbers, got {viewpoint!r}")
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
    tree = build_octree(
        local, edge, criterion=criterion, threshold=threshold, d_min=d_min, n_min=n_min,
        min_sigma2=min_sigma2, spacing=spacing, max_edge=max_edge, sorted_input=sorted_input,
    )
    clock.lap("octree")
    vp_local = None if vp is None else vp - corner
    centre_local = tree.local.mean(axis=0)
    normals, scalars, dir1, method, frames, coeffs = _surface_pass(tree, orient, vp_local, centre_local, blend, clock)
    _fallback_pass(tree, normals, scalars, dir1, method, k_fallback, orient, vp_local, centre_local)
    clock.lap("fallback")

    table = PatchTable(
        root_corner=corner.copy(),
        root_edge=float(edge),
        level=tree.level.astype(np.uint8),
        ijk=tree.ijk,
        count=tree.count,
        centroid=tree.centroid + corner,
        frame=frames,
        eigenvalues=tree.fit.eigenvalues,
        coeffs=coeffs,
        rmse=tree.fit.rmse,
        kind=tree.kind,
    )
    params = NormalsParameters(
        criterion=criterion, threshold=tree.threshold, d_min=float(d_min), max_edge=float(max_edge), n_min=n_min, min_sigma2=float(min_sigma2),
        k_fallback=k_fallback, orient=orient, viewpoint=None if vp is None else tuple(vp.tolist()), blend=bool(blend),
        spacing=float(spacing), root_corner=tuple(corner.tolist()), root_edge=float(edge),
    )
    outputs = dict(
        normals=np.empty((n, 3), np.float32), curvature=np.empty(n, np.float32), k1=np.empty(n, np.float32),
        k2=np.empty(n, np.float32), dir1=np.empty((n, 3), np.float32), method=np.empty(n, np.uint8),
        patch=np.empty(n, np.int32),
    )
    _kernels.unsort_outputs(tree.order, normals, scalars, dir1, method, tree.point_leaf(), *outputs.values())
    clock.lap("output")
    return NormalsResult(**outputs, patches=table, parameters=params, timings=dict(clock.laps))


class _Clock:
    """Wall time of consecutive steps."""

    def __init__(self) -> None:
        self.laps: dict[str, float] = {}
        self._t = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.laps[name] = self.laps.get(name, 0.0) + now - self._t
        self._t = now


def _surface_pass(tree: Octree, orient: str, vp, centre, blend: bool, clock: "_Clock"):
    """Normals of the points of surface leaves; orientation; blending."""
    n = tree.local.shape[0]
    P = tree.level.shape[0]
    fit = tree.fit
    frames, coeffs = fit.frame, fit.coeffs
    centroid = tree.centroid
    surface = tree.kind == KIND_SURFACE

    # Relative orientation over the leaf adjacency graph: face sampling of the
    # two quadrics between surface patches (paper 2.3); between a surface and
    # an edge or sparse leaf, or two of those, the sign of the dot product of
    # their PCA normals, so groups of patches separated by a sharp feature or
    # a sparse spot still propagate their orientation through it.
    i, j, d = face_neighbours(tree)
    usable = tree.count >= 3
    keep = usable[i] & usable[j]
    i, j, d = i[keep], j[keep], d[keep]
    both = surface[i] & surface[j]
    agreement = np.einsum("ni,ni->n", frames[i, :, 2], frames[j, :, 2])
    # a PCA normal of a sharp or sparse spot is rough: trust only nearly parallel ones
    agreement[~both & (np.abs(agreement) < DOT_MIN)] = 0.0
    agreement[both] = face_agreement(tree, frames, coeffs, i[both], j[both], d[both])
    usable_e3 = frames[:, :, 2] * usable[:, None]
    prior = rule_prior(orient, usable_e3, centroid, vp, centre)
    sign, comp, ruled = propagate_signs(P, i, j, agreement, min_reliability=MIN_RELIABILITY, prior=prior)
    if orient != "none" and not ruled.all():
        # groups no reliable link ties to the rule: the rule decides for each as a whole
        e3 = frames[:, :, 2] * sign[:, None]
        weights = np.where(usable & ~ruled, tree.count, 0).astype(np.float64)
        sign = sign * np.where(ruled, 1.0, component_rule_signs(orient, comp, e3, centroid, weights, vp, centre))
    frames, coeffs = turn_over(frames, coeffs, sign < 0)
    clock.lap("orient")

    normals = np.zeros((n, 3))
    scalars = np.zeros((n, 3))
    dir1 = np.zeros((n, 3))
    _kernels.eval_surface_points(
        tree.local, tree.start, tree.count, surface, centroid, frames, coeffs, fit.sigma3, normals, scalars, dir1
    )
    method = np.repeat(np.where(surface, Method.QUADRIC, 0).astype(np.uint8), tree.count)
    clock.lap("evaluate")
    if blend:
        was = blend_across_faces(tree, frames, coeffs, normals, scalars, dir1)
        method[was] = Method.BLENDED
    clock.lap("blend")
    return normals, scalars, dir1, method, frames, coeffs


def _fallback_pass(tree: Octree, normals, scalars, dir1, method, k, orient, vp, centre, rounds: int = 4) -> None:
    """k-NN PCA normals for points of edge and sparse leaves, oriented by their neighbours."""
    query = np.flatnonzero(method == 0)
    if query.size == 0:
        return
    nrm, s3, k1, k2, t1, nb = knn_normals(
        tree.local, query, k, grid=(tree.q, tree.keys, tree.max_level, tree.edge / 2.0**tree.max_level)
    )
    oriented = method != 0
    normals[query] = nrm
    scalars[query] = np.column_stack([s3, k1, k2])
    # the quadric's k1 direction lies in the quadric's tangent plane at the point;
    # keep it tangent to the PCA normal that is reported
    t = t1 - np.einsum("ni,ni->n", t1, nrm)[:, None] * nrm
    length = np.linalg.norm(t, axis=1)
    flat = length < 1e-9  # k1 direction along the normal: any tangent will do
    t[flat] = np.cross(nrm[flat], np.where(np.abs(nrm[flat, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]]))
    dir1[query] = t / np.linalg.norm(t, axis=1)[:, None]
    method[query] = Method.KNN
    todo = np.ones(query.size, dtype=bool)
    sign = np.empty(query.size)
    for _ in range(rounds):
        # each round orients the points that have oriented neighbours, from the state before the round
        if _kernels.neighbour_signs(query, nb, normals, oriented, todo, sign) == 0:
            break
        done = todo & (sign != 0)
        _turn(normals, scalars, dir1, query[done], sign[done])
        oriented[query[done]] = True
        todo &= ~done
    rest = query[todo]
    if rest.size and orient != "none":
        _turn(normals, scalars, dir1, rest, point_rule_signs(orient, normals[rest], tree.local[rest], vp, centre))


def _turn(normals: np.ndarray, scalars: np.ndarray, dir1: np.ndarray, rows: np.ndarray, sign: np.ndarray) -> None:
    """Turn the normals of ``rows`` where ``sign`` is -1, in place, with what depends on their side.

    Seen from the other side a surface's curvatures change sign, so
    ``(k1, k2)`` becomes ``(-k2, -k1)`` (still ``k1 >= k2``) and the k1
    direction becomes the old k2 direction, ``cross(n, dir1)``.
    """
    rows = rows[sign < 0]
    n, d = normals[rows], dir1[rows]
    dir1[rows] = np.cross(n, d)
    normals[rows] = -n
    k1, k2 = scalars[rows, 1].copy(), scalars[rows, 2].copy()
    scalars[rows, 1], scalars[rows, 2] = -k2, -k1
