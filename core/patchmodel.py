"""Patch models of one cloud: the quadric surfaces that stand for its points, and points sampled back from them.

The anisotropic octree (criterion ``rmse`` with the error budget as its
threshold) splits the cloud into leaves whose quadric fits within the
budget.  A *surface* leaf becomes a patch model: its octree cell, point
count, PCA frame, quadric, and where its points lie in the frame (the
``(u, v)`` box and an 8 x 8 occupancy mask of that box).  Every other point
is *residual*: the points of edge and sparse leaves (vegetation, wires,
isolated returns), and the points of a surface leaf farther than
``outlier_factor`` x the budget from its quadric.  So every input point is
represented either by a surface or by itself.

Sampling a patch draws its point count (or any other) uniformly over the
occupied cells of its mask and lifts each ``(u, v)`` onto the quadric.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import PatchcloudValueError
from .normals import _root_cube, _validate_points
from .octree import estimate_spacing, sort_points
from .patches import PatchKind
from .tiles import fit_tile

__all__ = ["PatchModels", "ModelFit", "QuantisedModels", "fit_models", "sample_models", "quantise_models", "dequantise_models", "check_budget", "MASK_SIDE"]

#: The occupancy mask of a patch is MASK_SIDE x MASK_SIDE cells over its (u, v) box (one uint64).
MASK_SIDE = 8
#: Draws per sampled point at most: a draw outside the patch's octree cell is drawn again.
MAX_DRAWS = 8


@dataclass(frozen=True)
class PatchModels:
    """Quadric patch models (P rows) that stand for a cloud's smooth surfaces.

    The surface of patch ``k``, in its frame, is ``w = a u^2 + b uv + c v^2
    + d u + e v + f`` (``coeffs[k]``), with ``(u, v, w) = frame[k].T @ (p -
    centroid[k])``; it is kept where ``extent[k]`` and ``mask[k]`` say the
    patch's points were.

    Attributes
    ----------
    root_corner : (3,) float64
        Minimum corner of the octree's root cube (metres, caller's frame).
    root_edge : float
        Edge of the root cube (metres).
    level : (P,) uint8
        Octree level of the patch's cell.
    ijk : (P, 3) int64
        Integer coordinates of the cell at its level.
    count : (P,) int64
        Points the patch stands for.
    centroid : (P, 3) float64
        Origin of the patch frame (metres, caller's frame).
    frame : (P, 3, 3) float64
        Axes ``e1, e2, e3`` as columns (e3: the normal of the PCA plane).
    coeffs : (P, 6) float64
        Quadric coefficients ``a, b, c, d, e, f``.
    extent : (P, 4) float64
        ``u_min, u_max, v_min, v_max`` of the patch's points in its frame (metres).
    mask : (P,) uint64
        Bit ``i * MASK_SIDE + j`` set where cell (i, j) of the extent's
        MASK_SIDE x MASK_SIDE grid (i along u) holds a point.
    rmse : (P,) float64
        RMS distance (along e3) of the patch's points to its quadric (metres).
    """

    root_corner: np.ndarray
    root_edge: float
    level: np.ndarray
    ijk: np.ndarray
    count: np.ndarray
    centroid: np.ndarray
    frame: np.ndarray
    coeffs: np.ndarray
    extent: np.ndarray
    mask: np.ndarray
    rmse: np.ndarray

    def __len__(self) -> int:
        return int(self.level.shape[0])

    @classmethod
    def empty(cls, root_corner, root_edge: float) -> "PatchModels":
        """No patches (a cube whose points are all residual)."""
        z = np.zeros
        return cls(
            root_corner=np.asarray(root_corner, dtype=np.float64).copy(), root_edge=float(root_edge), level=z(0, np.uint8),
            ijk=z((0, 3), np.int64), count=z(0, np.int64), centroid=z((0, 3)), frame=z((0, 3, 3)), coeffs=z((0, 6)),
            extent=z((0, 4)), mask=z(0, np.uint64), rmse=z(0),
        )

    @property
    def edge(self) -> np.ndarray:
        """(P,) edge of every patch's octree cell (metres)."""
        return _cell_edge(self.root_edge, self.level)

    def mask_bits(self) -> np.ndarray:
        """(P, MASK_SIDE**2) bool: the occupied cells of each patch's mask, bit by bit."""
        return ((self.mask[:, None] >> np.arange(MASK_SIDE * MASK_SIDE, dtype=np.uint64)) & np.uint64(1)).astype(bool)

    def occupied(self) -> np.ndarray:
        """(P,) number of occupied cells of each patch's mask."""
        return self.mask_bits().sum(axis=1).astype(np.int64)


@dataclass(frozen=True)
class ModelFit:
    """What :func:`fit_models` gives.

    Attributes
    ----------
    models : PatchModels
    patch : (N,) int64
        Row of ``models`` each input point is represented by; -1 for a residual point.
    residual : (R,) int64
        Input rows of the residual points, ascending.
    error : (N,) float64
        Distance along the patch normal from each point to its quadric (metres); 0 for residual points.
    """

    models: PatchModels
    patch: np.ndarray
    residual: np.ndarray
    error: np.ndarray


def _cell_edge(root_edge: float, level: np.ndarray) -> np.ndarray:
    """Edge (metres) of octree cells at ``level`` below a root cube of edge ``root_edge``."""
    return root_edge / 2.0 ** level.astype(np.float64)


def check_budget(max_error) -> float:
    """The error budget as a positive float (metres), or a PatchcloudValueError."""
    try:
        budget = float(max_error)
    except (TypeError, ValueError):
        budget = float("nan")
    if not np.isfinite(budget) or budget <= 0:
        raise PatchcloudValueError(f"max_error must be a positive number of metres, got {max_error!r}")
    return budget


def _quadric(c: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return c[:, 0] * u * u + c[:, 1] * u * v + c[:, 2] * v * v + c[:, 3] * u + c[:, 4] * v + c[:, 5]


def _cells(u: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    span = np.where(hi > lo, hi - lo, 1.0)
    return np.clip(np.floor((u - lo) / span * MASK_SIDE), 0, MASK_SIDE - 1).astype(np.int64)


def fit_models(
    points: np.ndarray,
    max_error: float,
    *,
    d_min: float | None = None,
    max_edge: float | None = None,
    n_min: int = 12,
    min_sigma2: float = 0.01,
    outlier_factor: float = 3.0,
    root: tuple[np.ndarray, float] | None = None,
) -> ModelFit:
    """Patch models of a cloud within an error budget, and its residual points.

    Parameters
    ----------
    points : (N, 3) array
        Coordinates (metres); any order.
    max_error : float
        The error budget (metres): the octree splits a leaf until its
        quadric's fit RMSE is below it (criterion ``rmse``), down to ``d_min``.
    d_min, max_edge, n_min, min_sigma2 :
        As :func:`patchcloud.core.estimate_normals` (defaults from the point spacing).
    outlier_factor : float
        A point of a surface leaf farther than ``outlier_factor * max_error``
        from the quadric is kept as a residual point.
    root : (corner, edge), optional
        The octree's root cube (a tile of the stream); default: the points' bounding cube.

    Returns
    -------
    ModelFit

    Examples
    --------
    >>> import numpy as np
    >>> xy = np.random.default_rng(0).uniform(0, 8, (20000, 2))
    >>> fit = fit_models(np.column_stack([xy, 0.05 * xy[:, 0] ** 2]), 0.01)
    >>> len(fit.models) < 40, fit.residual.size, int(fit.models.count.sum())
    (True, 0, 20000)
    """
    pts, lo, hi = _validate_points(points)
    budget = check_budget(max_error)
    if not np.isfinite(outlier_factor) or outlier_factor < 1:
        raise PatchcloudValueError(f"outlier_factor must be at least 1, got {outlier_factor!r}")
    n = pts.shape[0]
    if n < n_min:
        raise PatchcloudValueError(f"the cloud has {n} points, fewer than n_min={n_min}")
    corner, edge = _root_cube(lo, hi, root)
    sorted_input = sort_points(pts - corner, np.zeros(3), edge)
    spacing = estimate_spacing(sorted_input[1], edge)
    if d_min is None:
        d_min = 3.0 * spacing if spacing > 0 else edge / 2.0**21
    if max_edge is None:
        max_edge = 256.0 * spacing if spacing > 0 else np.inf
    fit = fit_tile(
        pts, corner, edge, criterion="rmse", threshold=budget, d_min=d_min, max_edge=max_edge, n_min=n_min,
        min_sigma2=min_sigma2, orient="none", spacing=spacing, sorted_input=sorted_input,
    )
    t = fit.patches
    leaf = np.repeat(np.arange(len(t)), t.count)  # patch of each sorted point
    world = fit.local + corner
    surface = t.kind[leaf] == PatchKind.SURFACE
    d = world - t.centroid[leaf]
    uvw = np.einsum("nij,ni->nj", t.frame[leaf], d)
    err = np.zeros(n)
    err[surface] = uvw[surface, 2] - _quadric(t.coeffs[leaf[surface]], uvw[surface, 0], uvw[surface, 1])
    kept = surface & (np.abs(err) <= outlier_factor * budget)
    count = np.bincount(leaf[kept], minlength=len(t))
    keep_patch = count >= 3
    kept &= keep_patch[leaf]
    count = np.where(keep_patch, count, 0)
    rows = np.flatnonzero(keep_patch)
    new_row = np.full(len(t), -1, dtype=np.int64)
    new_row[rows] = np.arange(rows.size)

    # extents and occupancy masks of the kept points, per patch (kept points of a patch are contiguous)
    kp = leaf[kept]
    u, v = uvw[kept, 0], uvw[kept, 1]
    starts = np.r_[0, np.cumsum(count[rows])[:-1]] if rows.size else np.zeros(0, np.int64)
    extent = np.zeros((rows.size, 4))
    mask = np.zeros(rows.size, dtype=np.uint64)
    rms = np.zeros(rows.size)
    if rows.size:
        extent[:, 0] = np.minimum.reduceat(u, starts)
        extent[:, 1] = np.maximum.reduceat(u, starts)
        extent[:, 2] = np.minimum.reduceat(v, starts)
        extent[:, 3] = np.maximum.reduceat(v, starts)
        r = new_row[kp]
        bit = _cells(u, extent[r, 0], extent[r, 1]) * MASK_SIDE + _cells(v, extent[r, 2], extent[r, 3])
        mask = np.bitwise_or.reduceat(np.left_shift(np.uint64(1), bit.astype(np.uint64)), starts)
        rms = np.sqrt(np.bincount(r, weights=err[kept] ** 2, minlength=rows.size) / count[rows])
    models = PatchModels(
        root_corner=corner.copy(), root_edge=float(edge), level=t.level[rows], ijk=t.ijk[rows], count=count[rows],
        centroid=t.centroid[rows], frame=t.frame[rows], coeffs=t.coeffs[rows], extent=extent, mask=mask, rmse=rms,
    )
    patch = np.full(n, -1, dtype=np.int64)
    patch[fit.order[kept]] = new_row[kp]
    error = np.zeros(n)
    error[fit.order[kept]] = err[kept]
    return ModelFit(models=models, patch=patch, residual=np.sort(fit.order[~kept]), error=error)


def sample_models(models: PatchModels, counts: np.ndarray | None = None, *, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points on the patch surfaces: ``counts[k]`` (default: the patches' own counts) per patch.

    Each point is drawn uniformly over the occupied cells of the patch's
    mask, then lifted onto its quadric; a point that falls outside the
    patch's octree cell (where the box of its points overhangs the cell)
    is drawn again, up to :data:`MAX_DRAWS` times.  The same models,
    counts and seed give the same points.

    Returns
    -------
    points : (M, 3) float64
        Caller's frame (metres).
    patch : (M,) int64
        Row of ``models`` of each point; points come patch after patch.

    Examples
    --------
    >>> import numpy as np
    >>> xy = np.random.default_rng(0).uniform(0, 8, (20000, 2))
    >>> fit = fit_models(np.column_stack([xy, np.zeros(20000)]), 0.01)
    >>> p, k = sample_models(fit.models)
    >>> p.shape, float(np.abs(p[:, 2]).max()) < 1e-9
    ((20000, 3), True)
    """
    P = len(models)
    counts = models.count if counts is None else np.asarray(counts, dtype=np.int64)
    if counts.shape != (P,) or (counts < 0).any():
        raise PatchcloudValueError(f"counts must be {P} non-negative whole numbers, one per patch")
    k = np.repeat(np.arange(P), counts)
    rng = np.random.default_rng(seed)
    bits = models.mask_bits()
    occupied = bits.sum(axis=1)
    cell_order = np.argsort(~bits, axis=1, kind="stable")  # the occupied cells first, in index order
    edge = models.edge
    lo = models.root_corner + models.ijk * edge[:, None]
    pts = np.empty((k.size, 3))
    todo = np.arange(k.size)
    for attempt in range(MAX_DRAWS):  # a draw outside the patch's octree cell is drawn again
        kk = k[todo]
        r = rng.random((todo.size, 3))
        pick = np.minimum((r[:, 0] * occupied[kk]).astype(np.int64), np.maximum(occupied[kk] - 1, 0))
        cell = cell_order[kk, pick]
        e = models.extent[kk]
        u = e[:, 0] + (cell // MASK_SIDE + r[:, 1]) * (e[:, 1] - e[:, 0]) / MASK_SIDE
        v = e[:, 2] + (cell % MASK_SIDE + r[:, 2]) * (e[:, 3] - e[:, 2]) / MASK_SIDE
        w = _quadric(models.coeffs[kk], u, v)
        pts[todo] = models.centroid[kk] + np.einsum("nij,nj->ni", models.frame[kk], np.column_stack([u, v, w]))
        outside = np.any((pts[todo] < lo[kk]) | (pts[todo] > lo[kk] + edge[kk, None]), axis=1)
        todo = todo[outside]
        if todo.size == 0:
            break
    return pts, k


#: Share of the error budget each quantised quantity may use at most (four of them: < half the budget in all).
QUANT_SHARE = 1.0 / 8.0
#: Steps of the (u, v) extent: the cell edge over this (an extent only says where samples go along the surface).
EXTENT_STEPS = 1024


@dataclass(frozen=True)
class QuantisedModels:
    """Patch models as integers, each quantity with a step derived from the error budget and the patch's cell.

    With ``E`` the edge of a patch's octree cell and ``eps`` the budget,
    every point of the cell lies within ``sqrt(3) E`` of the centroid, so
    the steps below keep the surface of the dequantised model within
    ``4 * QUANT_SHARE * eps`` (half the budget) of the fitted one over the
    cell: centroid ``eps/8 / (sqrt(3)/2)`` per axis (offsets from the cell
    corner), rotation vector ``eps/8 / (3 E)`` radians per component,
    ``f`` ``eps/8``, ``d, e`` ``eps/8 / (2 sqrt(3) E)``, ``a, b, c``
    ``eps/8 / (9 E^2)``; extents in steps of ``E / EXTENT_STEPS`` from the
    centroid.

    Attributes
    ----------
    max_error : float
        The budget the steps derive from (metres).
    root_corner, root_edge, level, ijk, count, mask :
        As :class:`PatchModels` (exact).
    centroid : (P, 3) int64
    rotation : (P, 3) int64
        Rotation vector of the frame.
    coeffs : (P, 6) int64
    extent : (P, 4) int64
    rmse : (P,) float32
    """

    max_error: float
    root_corner: np.ndarray
    root_edge: float
    level: np.ndarray
    ijk: np.ndarray
    count: np.ndarray
    centroid: np.ndarray
    rotation: np.ndarray
    coeffs: np.ndarray
    extent: np.ndarray
    mask: np.ndarray
    rmse: np.ndarray

    def __len__(self) -> int:
        return int(self.level.shape[0])


def _steps(root_edge: float, level: np.ndarray, max_error: float) -> dict[str, np.ndarray]:
    """Quantisation steps per patch (see :class:`QuantisedModels`)."""
    E = _cell_edge(root_edge, level)
    share = QUANT_SHARE * max_error
    quad = share / (9.0 * E * E)
    lin = share / (2.0 * np.sqrt(3.0) * E)
    return {
        "centroid": np.full_like(E, share / (np.sqrt(3.0) / 2.0)),
        "rotation": share / (3.0 * E),
        "coeffs": np.column_stack([quad, quad, quad, lin, lin, np.full_like(E, share)]),
        "extent": E / EXTENT_STEPS,
        "edge": E,
    }


def quantise_models(models: PatchModels, max_error: float) -> QuantisedModels:
    """Integers standing for ``models`` within half of ``max_error`` (metres); see :class:`QuantisedModels`.

    Examples
    --------
    >>> import numpy as np
    >>> d = np.random.default_rng(0).normal(size=(20000, 3))
    >>> fit = fit_models(d / np.linalg.norm(d, axis=1)[:, None], 0.005)
    >>> back = dequantise_models(quantise_models(fit.models, 0.005))
    >>> float(np.abs(back.coeffs - fit.models.coeffs).max()) < 0.005
    True
    """
    from scipy.spatial.transform import Rotation

    budget = check_budget(max_error)
    st = _steps(models.root_edge, models.level, budget)
    corner = models.root_corner + models.ijk * st["edge"][:, None]
    rot = Rotation.from_matrix(models.frame).as_rotvec() if len(models) else np.zeros((0, 3))
    return QuantisedModels(
        max_error=budget, root_corner=models.root_corner.copy(), root_edge=models.root_edge, level=models.level.copy(),
        ijk=models.ijk.copy(), count=models.count.copy(), mask=models.mask.copy(),
        centroid=np.rint((models.centroid - corner) / st["centroid"][:, None]).astype(np.int64),
        rotation=np.rint(rot / st["rotation"][:, None]).astype(np.int64),
        coeffs=np.rint(models.coeffs / st["coeffs"]).astype(np.int64),
        extent=np.stack([np.floor(models.extent[:, [0, 2]] / st["extent"][:, None]),
                         np.ceil(models.extent[:, [1, 3]] / st["extent"][:, None])], axis=2).reshape(-1, 4).astype(np.int64),
        rmse=models.rmse.astype(np.float32),
    )


def dequantise_models(q: QuantisedModels) -> PatchModels:
    """The patch models a :class:`QuantisedModels` stands for."""
    from scipy.spatial.transform import Rotation

    st = _steps(q.root_edge, q.level, q.max_error)
    corner = q.root_corner + q.ijk * st["edge"][:, None]
    frame = Rotation.from_rotvec(q.rotation * st["rotation"][:, None]).as_matrix() if len(q) else np.zeros((0, 3, 3))
    return PatchModels(
        root_corner=q.root_corner.copy(), root_edge=q.root_edge, level=q.level.copy(), ijk=q.ijk.copy(),
        count=q.count.copy(), centroid=corner + q.centroid * st["centroid"][:, None], frame=frame.reshape(-1, 3, 3),
        coeffs=q.coeffs * st["coeffs"], extent=q.extent * st["extent"][:, None], mask=q.mask.copy(),
        rmse=q.rmse.astype(np.float64),
    )
