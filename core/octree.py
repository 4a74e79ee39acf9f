"""Anisotropic octree subdivision (paper section 2.1), level by level.

The points are sorted once by Morton key.  The moments of every node at
every level come from one pass over the points at the finest level and
shifted sums of children's moments above it (:mod:`patchcloud.core.moments`);
the subdivision then walks the levels from the root down, deciding for all
active nodes of a level at once whether they are uniform (a leaf) or split.
No Python loop runs per point or per node.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .calibration import rmse_histograms, threshold_from_histograms
from . import _kernels
from .argsort import stable_argsort
from .codes import PatchKind
from .morton import MAX_DEPTH, containing, decode, key_range
from .moments import EXPONENTS, shift_entries
from .quadric import NodeFit, fit_nodes

__all__ = ["Octree", "build_octree", "sort_points", "estimate_spacing", "max_level_for", "point_keys", "level_occupancy"]

#: Leaf kinds: a smooth patch modelled by its quadric, a sharp feature or 3D curve, too few points.


@dataclass(frozen=True)
class Octree:
    """Leaves of an anisotropic octree over points sorted by Morton key.

    All coordinates are relative to the root cube's minimum corner (metres).

    Attributes
    ----------
    edge : float
        Root cube edge (metres).
    max_level : int
        Deepest level a leaf may have (set by ``d_min``).
    order : (N,) int64
        ``order[k]`` is the input index of the k-th sorted point.
    local : (N, 3) float64
        Sorted points.
    q : (N, 3) int64
        Integer coordinates of the sorted points at depth ``MAX_DEPTH``.
    keys : (N,) uint64
        Their Morton keys (sorted).
    level, cell : (P,) int64, (P,) uint64
        Level and Morton cell id (at that level) of every leaf, in key order.
    start, count : (P,) int64
        Leaves own the sorted points ``start[k]:start[k] + count[k]``.
    fit : NodeFit
        PCA and quadric of every leaf (centroids relative to the leaf centre).
    kind : (P,) uint8
        a :class:`~patchcloud.core.codes.PatchKind` value.
    threshold : float
        The uniformity threshold that was used.
    """

    edge: float
    max_level: int
    order: np.ndarray
    local: np.ndarray
    q: np.ndarray
    keys: np.ndarray
    level: np.ndarray
    cell: np.ndarray
    start: np.ndarray
    count: np.ndarray
    fit: NodeFit
    kind: np.ndarray
    threshold: float

    @cached_property
    def leaf_edge(self) -> np.ndarray:
        """(P,) edge of every leaf (metres)."""
        return self.edge / np.exp2(self.level)

    @cached_property
    def ijk(self) -> np.ndarray:
        """(P, 3) integer coordinates of every leaf at its own level."""
        return decode(self.cell)

    @cached_property
    def lower(self) -> np.ndarray:
        """(P, 3) minimum corner of every leaf (metres, root-corner frame)."""
        return self.ijk * self.leaf_edge[:, None]

    @cached_property
    def centroid(self) -> np.ndarray:
        """(P, 3) centroid of every leaf's points (metres, root-corner frame)."""
        return self.lower + 0.5 * self.leaf_edge[:, None] + self.fit.centroid

    def point_leaf(self) -> np.ndarray:
        """(N,) leaf index of every sorted point."""
        return np.repeat(np.arange(len(self.start)), self.count)

    def find_leaf(self, qkeys: np.ndarray) -> np.ndarray:
        """Leaf containing each depth-``MAX_DEPTH`` key, or -1 where none does."""
        return containing(*key_range(self.cell, self.level), qkeys)


def max_level_for(edge: float, d_min: float) -> int:
    """Deepest octree level below a root cube of ``edge`` whose cubes are at least ``d_min``."""
    return int(np.clip(np.floor(np.log2(edge / d_min)), 0, MAX_DEPTH)) if d_min > 0 else MAX_DEPTH


def point_keys(points: np.ndarray, edge: float, corner=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Depth-``MAX_DEPTH`` integer coordinates (N, 3) and Morton keys (N,) of points in the cube at ``corner``."""
    n = points.shape[0]
    q = np.empty((n, 3), dtype=np.int64)
    keys = np.empty(n, dtype=np.uint64)
    _kernels.morton_keys(np.ascontiguousarray(points, dtype=np.float64), np.asarray(corner, dtype=np.float64), float(edge), q, keys)
    return q, keys


def sort_points(points: np.ndarray, corner: np.ndarray, edge: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sort points by Morton key in the root cube, ties broken by coordinates.

    The result does not depend on the input order (exact duplicates are
    interchangeable), which makes every later sum bit-reproducible.

    Parameters
    ----------
    points : (N, 3) float64
    corner : (3,) float64
        Minimum corner of the root cube.
    edge : float
        Root cube edge.

    Returns
    -------
    order : (N,) int64, keys : (N,) uint64 sorted, q : (N, 3) int64 sorted.
    """
    q, keys = point_keys(points, edge, corner)
    order = stable_argsort(keys)
    keys = keys[order]
    tie = np.flatnonzero(keys[1:] == keys[:-1])
    if tie.size:
        pos = np.unique(np.concatenate([tie, tie + 1]))
        sub = points[order[pos]]
        sub_order = np.lexsort((sub[:, 2], sub[:, 1], sub[:, 0], keys[pos]))
        order[pos] = order[pos[sub_order]]
    return order, keys, _kernels.take_rows(q, order)


def level_occupancy(keys: np.ndarray) -> list[int]:
    """Occupied cells at each level 0 to ``MAX_DEPTH`` of points with sorted Morton ``keys`` ((N,) uint64, N > 0).

    >>> level_occupancy(np.array([0, 1, 8, 2**63], dtype=np.uint64))[:3], level_occupancy(np.array([0, 1, 8, 2**63], dtype=np.uint64))[-1]
    ([2, 2, 2], 4)
    """
    counts = np.zeros(MAX_DEPTH + 1, dtype=np.int64)
    _kernels.first_split_levels(np.ascontiguousarray(keys, dtype=np.uint64), MAX_DEPTH, counts)
    return (np.cumsum(counts) + 1).tolist()


def estimate_spacing(keys: np.ndarray, edge: float, target: float = 16.0) -> float:
    """Typical distance between neighbouring points (metres), from octree occupancy.

    Finds the first level whose occupied cells hold fewer than ``target``
    points on average and treats the cloud as a surface there: a cell of
    edge ``h`` holding ``m`` points gives a spacing ``h / sqrt(m)``.
    """
    n = keys.shape[0]
    occupied = level_occupancy(keys)  # grows with the level
    lo = next((lev for lev in range(MAX_DEPTH) if n / occupied[lev] < target), MAX_DEPTH)
    m = n / occupied[lo]
    return edge / 2.0**lo / np.sqrt(max(m, 1.0))


@dataclass
class _Level:
    cells: np.ndarray
    starts: np.ndarray
    moments: np.ndarray
    parent: np.ndarray | None = None


def _bottom_up(local, keys, edge, max_level) -> list[_Level]:
    shift = np.uint64(3 * (MAX_DEPTH - max_level))
    c = keys >> shift
    starts = np.flatnonzero(np.r_[True, c[1:] != c[:-1]])
    cells = c[starts]
    h = edge / 2.0**max_level
    centre = (decode(cells) + 0.5) * h
    moments = np.empty((cells.shape[0], EXPONENTS.shape[0]))
    _kernels.cell_moments(local, starts, centre, moments)
    levels: list[_Level] = [None] * (max_level + 1)  # type: ignore[list-item]
    levels[max_level] = _Level(cells, starts, moments)
    bits = np.array([[(o >> a) & 1 for a in range(3)] for o in range(8)], dtype=np.float64)
    for lev in range(max_level - 1, -1, -1):
        child = levels[lev + 1]
        pc = child.cells >> np.uint64(3)
        gstart = np.flatnonzero(np.r_[True, pc[1:] != pc[:-1]])
        octant = (child.cells & np.uint64(7)).astype(np.int64)
        hc = edge / 2.0 ** (lev + 1)
        coef = shift_entries((2.0 * bits - 1.0) * (0.5 * hc))[2]
        moments = np.empty((gstart.shape[0], child.moments.shape[1]))
        _kernels.shift_to_parents(child.moments, gstart, octant, coef, moments)
        child.parent = np.repeat(np.arange(len(gstart)), np.diff(np.r_[gstart, len(pc)]))
        levels[lev] = _Level(pc[gstart], child.starts[gstart], moments)
    return levels


def build_octree(
    local: np.ndarray,
    edge: float,
    *,
    criterion: str,
    threshold: float | None,
    d_min: float,
    n_min: int,
    min_sigma2: float,
    spacing: float,
    max_edge: float = np.inf,
    sorted_input: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> Octree:
    """Anisotropic subdivision of points in a root cube.

    Parameters
    ----------
    local : (N, 3) float64
        Points relative to the root cube's minimum corner (metres).
    edge : float
        Root cube edge (metres).
    criterion : {"rmse", "sigma3"}
        Uniformity test: quadric fit RMSE (metres) or surface variation.
    threshold : float or None
        A node is uniform when its measure is at most this; None picks
        the default of :mod:`.calibration` for "rmse", from these points
        (cells anchored at the root cube's corner).
    d_min : float
        No leaf has an edge below this (metres).
    n_min : int
        Nodes with fewer points are not split and have no surface (sparse).
    min_sigma2 : float
        Leaves with ``sigma2`` below this hold a 3D curve, not a surface (edge).
    spacing : float
        Point spacing (metres), used only for the default threshold.
    max_edge : float
        Nodes with a larger edge are split even when uniform (metres).
    sorted_input : tuple, optional
        ``sort_points(local, zeros(3), edge)`` when the caller already has it.
    """
    order, keys, q = sorted_input if sorted_input is not None else sort_points(local, np.zeros(3), edge)
    pts = _kernels.take_rows(local, order)
    max_level = max_level_for(edge, d_min)
    levels = _bottom_up(pts, keys, edge, max_level)
    if threshold is None:
        if criterion != "rmse":
            raise ValueError("threshold None is only resolved for the rmse criterion")
        threshold = threshold_from_histograms(rmse_histograms(local, d_min, n_min), d_min, spacing)

    # levels whose nodes are larger than max_edge are never leaves (unless sparse)
    min_level = int(np.clip(np.ceil(np.log2(edge / max_edge)), 0, max_level)) if np.isfinite(max_edge) else 0
    leaf_level, leaf_node, leaf_uniform = [], [], []
    active = np.zeros(1, dtype=np.int64)
    for lev in range(max_level + 1):
        lv = levels[lev]
        mom = lv.moments[active]
        n = mom[:, 0]
        sparse = n < n_min
        dense = ~sparse
        uniform = np.zeros(active.shape[0], dtype=bool)
        if dense.any():
            half = np.full(int(dense.sum()), edge / 2.0 ** (lev + 1))
            fit = fit_nodes(mom[dense], half, quadric=criterion == "rmse")
            measure = fit.rmse if criterion == "rmse" else fit.sigma3
            uniform[dense] = measure <= threshold
        if lev < min_level:
            uniform[:] = False
        leaf = sparse | uniform | (lev == max_level)
        leaf_level.append(np.full(int(leaf.sum()), lev))
        leaf_node.append(active[leaf])
        leaf_uniform.append(uniform[leaf])
        if lev == max_level:
            break
        split = np.zeros(lv.cells.shape[0], dtype=bool)
        split[active[~leaf]] = True
        active = np.flatnonzero(split[levels[lev + 1].parent])
        if active.size == 0:
            break

    level = np.concatenate(leaf_level)
    node = np.concatenate(leaf_node)
    uniform = np.concatenate(leaf_uniform)
    cell = np.empty(level.shape[0], dtype=np.uint64)
    start = np.empty(level.shape[0], dtype=np.int64)
    moments = np.empty((level.shape[0], levels[0].moments.shape[1]))
    for lev in np.unique(level).tolist():
        m = level == lev
        cell[m] = levels[lev].cells[node[m]]
        start[m] = levels[lev].starts[node[m]]
        moments[m] = levels[lev].moments[node[m]]
    srt = np.argsort(start, kind="stable")
    level, cell, start, moments, uniform = level[srt], cell[srt], start[srt], moments[srt], uniform[srt]
    count = np.diff(np.r_[start, pts.shape[0]])
    fit = fit_nodes(moments, edge / np.exp2(level + 1))
    kind = np.full(level.shape[0], PatchKind.SURFACE, dtype=np.uint8)
    spread = fit.eigenvalues.sum(axis=1) > _kernels.ROUNDING_SPREAD * (edge / np.exp2(level)) ** 2  # else copies of one point
    kind[~uniform | (fit.sigma2 < min_sigma2) | ~spread] = PatchKind.EDGE
    kind[count < n_min] = PatchKind.SPARSE
    return Octree(
        edge=float(edge),
        max_level=max_level,
        order=order,
        local=pts,
        q=q,
        keys=keys,
        level=level.astype(np.int64),
        cell=cell,
        start=start,
        count=count,
        fit=fit,
        kind=kind,
        threshold=float(threshold),
    )
