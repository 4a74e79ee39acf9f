"""The default RMSE threshold: the scanner noise, measured on small cells of an absolute grid.

The ``rmse`` criterion calls a node uniform when its quadric fits within a
threshold; by default that threshold is :data:`NOISE_FACTOR` times the
median fit RMSE of small cells (at least :data:`FLOOR_FACTOR` times the
point spacing, for noise-free data).  That median grows quickly with the
cell size on real LiDAR (vegetation and edges weigh more in larger cells),
so the cells must have one size whatever the extent of the cloud or its
tiling: the noise is taken at ``CALIBRATION_SCALE * d_min``, interpolated
(geometrically, in the cell edge) between the medians of the two
power-of-two grids that bracket that size.  Cells are those of an absolute
grid (multiples of their edge from an origin), one in
:data:`CALIBRATION_STRIDE` of them chosen by a hash of their index, so
that the histograms of the tiles of a cloud add up to the whole cloud's.
:func:`patchcloud.core.estimate_normals` anchors the grid at its root
cube's corner (the result does not change when the cloud is moved) and
``patchcloud normals`` at its tile grid's origin: the same cell sizes and
rule, so the two resolve about the same threshold (house.laz: 0.133 and
0.134 m), and any tiling of the store the same one.
"""

from __future__ import annotations

import numpy as np

from ._kernels import hashed_cell_picks, run_starts
from .argsort import stable_argsort
from .moments import cell_moments
from .quadric import fit_nodes

__all__ = [
    "CALIBRATION_SCALE", "CALIBRATION_STRIDE", "FLOOR_FACTOR", "NOISE_FACTOR", "RMSE_BINS", "calibration_edges",
    "rmse_histograms", "threshold_from_histograms",
]

#: Default RMSE threshold = NOISE_FACTOR x the median fit RMSE of the calibration cells ...
NOISE_FACTOR = 2.0
#: ... and at least FLOOR_FACTOR x the point spacing (noise-free data).
FLOOR_FACTOR = 0.02
#: The noise is measured on cells of this many ``d_min``.
CALIBRATION_SCALE = 1.5
#: Calibration cells used: those whose hash falls in 1 of this many.
CALIBRATION_STRIDE = 8
#: log10 bin edges of the fit-RMSE histograms (the coordinates' unit): 0.25 % wide, from 1e-12 to 1e12, so a cloud in
#: millimetres (or any unit) keeps every fit.  The edges from 1e-7 to 100 are those of versions before 2026-11-28,
#: exactly (their thresholds stand); those bins alone dropped the fits of more than 100 units, and the embedded tile
#: in millimetres got a threshold 0.60 times that in metres (0.80 now: the cells differ, see estimate_normals), 0.48
#: times in units of 1/1024 m (1.00 now) (review J).
_STEP = 9.0 / 3600.0
RMSE_BINS = np.concatenate([-7.0 - _STEP * np.arange(2000, 0, -1), np.linspace(-7.0, 2.0, 9 * 400 + 1), 2.0 + _STEP * np.arange(1, 4001)])
_HASH = np.array([73856093, 19349663, 83492791], dtype=np.int64)


def calibration_edges(d_min: float) -> tuple[float, float, float]:
    """The two power-of-two cell edges (metres) around ``CALIBRATION_SCALE * d_min``, and where it lies between them.

    Returns ``(c0, c1, w)`` with ``c1 = 2 c0``, ``c0 <= CALIBRATION_SCALE * d_min < c1``
    and ``w = log2(CALIBRATION_SCALE * d_min / c0)`` in [0, 1).

    >>> calibration_edges(1.0)
    (1.0, 2.0, 0.5849625007211562)
    """
    s = float(np.log2(CALIBRATION_SCALE * float(d_min)))
    e = int(np.floor(s))
    return float(2.0**e), float(2.0 ** (e + 1)), s - e


def rmse_histograms(points: np.ndarray, d_min: float, n_min: int, origin=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Histograms (over :data:`RMSE_BINS`) of the quadric-fit RMSE of the calibration cells of some points.

    Parameters
    ----------
    points : (N, 3) float64
        Coordinates (metres) relative to ``origin``.
    d_min : float
        The octree's smallest cell edge (metres): it sets the cell sizes
        (:func:`calibration_edges`).
    n_min : int
        Cells with fewer points are left out.
    origin : (3,) float
        Where the coordinates' zero lies in the absolute frame (the
        stream's grid origin), so that cells and their hashes are those of
        the absolute grid.

    Returns
    -------
    (2, len(RMSE_BINS) - 1) int64
        Counts of the cells of edge ``c0`` and ``c1`` per log10-RMSE bin.
        Histograms of disjoint sets of whole cells (tiles of edge at least
        ``c1`` on the same grid) add up.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> xy = rng.uniform(0, 40, (40000, 2))
    >>> plane = np.column_stack([xy, 0.3 + rng.normal(0, 0.01, len(xy))])   # 1 cm noise
    >>> h = rmse_histograms(plane, d_min=0.6, n_min=12)   # cells of 0.5 m and 1 m
    >>> h.sum(axis=1)   # cells with at least 12 points, one in 8 of them
    array([ 25, 199])
    >>> round(threshold_from_histograms(h, 0.6, spacing=0.2), 3)   # about twice the fit RMSE of 1 cm noise
    0.017
    """
    pts = np.asarray(points, dtype=np.float64)
    out = np.zeros((2, RMSE_BINS.size - 1), dtype=np.int64)
    o = np.asarray(origin, dtype=np.float64)
    for row, c in enumerate(calibration_edges(d_min)[:2]):
        picked = np.empty(pts.shape[0], dtype=np.bool_)
        hashed_cell_picks(pts, o, float(c), _HASH, CALIBRATION_STRIDE, picked)  # one cell in CALIBRATION_STRIDE
        chosen = np.flatnonzero(picked)
        if chosen.size == 0:
            continue
        cells = np.floor((pts[chosen] + o) / c).astype(np.int64)  # absolute cells
        order, starts = _cell_runs(cells)
        cells = cells[order]
        counts = np.diff(np.r_[starts, cells.shape[0]])
        keep = counts >= n_min
        if not keep.any():
            continue
        centres = (cells[starts] + 0.5) * c - o
        moments = cell_moments(np.ascontiguousarray(pts[chosen[order]]), starts.astype(np.int64), centres)
        fit = fit_nodes(moments[keep], np.full(int(keep.sum()), c / 2.0))
        rmse = np.maximum(np.nan_to_num(fit.rmse, nan=0.0), 10.0 ** RMSE_BINS[0])
        out[row] = np.histogram(np.log10(rmse), bins=RMSE_BINS)[0]
    return out


def _cell_runs(cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The stable order of integer cells (M, 3) by x, then y, then z (``np.lexsort`` of them), and where each cell's run starts.

    One int64 key per cell, row by row in the cells' box, sorted stably: the
    same order as the lexicographic sort, on numba's threads where a call
    has the machine (:func:`~patchcloud.core.argsort.stable_argsort`).
    """
    lo = cells.min(axis=0)
    span = cells.max(axis=0) - lo + 1
    if float(np.prod(span.astype(np.float64))) >= 2.0**62:  # the keys would overflow: the lexicographic sort itself
        order = np.lexsort(cells.T[::-1])
        srt = cells[order]
        return order, np.flatnonzero(np.r_[True, np.any(srt[1:] != srt[:-1], axis=1)])
    key = ((cells[:, 0] - lo[0]) * span[1] + (cells[:, 1] - lo[1])) * span[2] + (cells[:, 2] - lo[2])
    order = stable_argsort(key)
    return order, run_starts(key[order])


def _median(hist: np.ndarray) -> float:
    total = int(hist.sum())
    k = int(np.searchsorted(np.cumsum(hist), (total + 1) // 2))
    return float(10.0 ** (0.5 * (RMSE_BINS[k] + RMSE_BINS[k + 1])))


def threshold_from_histograms(hists: np.ndarray, d_min: float, spacing: float) -> float:
    """The default RMSE threshold (metres) from :func:`rmse_histograms` (summed over tiles).

    ``NOISE_FACTOR`` times the noise at ``CALIBRATION_SCALE * d_min``: the
    geometric interpolation of the two grids' medians (one grid's median
    where the other has no cell), at least ``FLOOR_FACTOR * spacing``.
    """
    _, _, w = calibration_edges(d_min)
    h0, h1 = np.asarray(hists[0]), np.asarray(hists[1])
    if h0.sum() and h1.sum():
        noise = _median(h0) ** (1.0 - w) * _median(h1) ** w
    elif h0.sum() or h1.sum():
        noise = _median(h0 if h0.sum() else h1)
    else:
        noise = 0.0
    return max(NOISE_FACTOR * noise, FLOOR_FACTOR * float(spacing))
