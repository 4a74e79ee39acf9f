"""A sparse grid of cubic cells over a cloud: the neighbour search behind radius normals and clustering.

Cells are ``floor(x / edge)`` in the coordinates given, so two clouds that
share points (a tile and the whole file, in the same frame) put those
points in the same cells.  Inside a cell, points are ordered by their
coordinates; sums over a cell therefore do not depend on input order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import PatchcloudValueError

__all__ = ["CellGrid"]


@dataclass(frozen=True)
class CellGrid:
    """Occupied cells of edge ``edge`` (metres) and the points sorted by cell.

    Attributes
    ----------
    edge : float
    base : (3,) int64
        Absolute index of the grid's cell (0, 0, 0).
    dims : (3,) int64
        Cells per axis (the points' cells plus ``pad`` on each side).
    order : (N,) int64
        ``points[order]`` are the points sorted by cell, then x, y, z.
    keys : (C,) int64
        Sorted keys of the occupied cells (``(i * dims[1] + j) * dims[2] + k``).
    start : (C + 1,) int64
        The sorted points of cell ``c`` are ``start[c]:start[c + 1]``.
    cells : (C, 3) int64
        Grid index of every occupied cell.
    """

    edge: float
    base: np.ndarray
    dims: np.ndarray
    order: np.ndarray
    keys: np.ndarray
    start: np.ndarray
    cells: np.ndarray

    @classmethod
    def build(cls, points: np.ndarray, edge: float, pad: int = 1) -> "CellGrid":
        """Bucket ``points`` ((N, 3) float64) into cells of ``edge``."""
        absolute = np.floor(points / edge).astype(np.int64)
        if points.shape[0]:
            lo, hi = absolute.min(axis=0), absolute.max(axis=0)
        else:
            lo = hi = np.zeros(3, dtype=np.int64)
        base = lo - pad
        dims = hi - lo + 1 + 2 * pad
        if float(dims[0]) * float(dims[1]) * float(dims[2]) >= 2.0**62:
            raise PatchcloudValueError(
                f"a grid of {edge:g} m cells over this cloud's extent has too many cells; use a larger radius or split the cloud"
            )
        idx = absolute - base
        key = (idx[:, 0] * dims[1] + idx[:, 1]) * dims[2] + idx[:, 2]
        order = np.lexsort((points[:, 2], points[:, 1], points[:, 0], key))
        sk = key[order]
        first = np.flatnonzero(np.r_[True, sk[1:] != sk[:-1]]) if sk.size else np.zeros(0, dtype=np.int64)
        start = np.r_[first, sk.size].astype(np.int64)
        return cls(
            edge=float(edge), base=base, dims=dims.astype(np.int64), order=order.astype(np.int64),
            keys=sk[first].astype(np.int64), start=start, cells=idx[order[first]],
        )

    def cell_of(self, points: np.ndarray) -> np.ndarray:
        """(M, 3) int64 grid index of the cells of ``points`` (may lie outside the grid)."""
        return np.floor(points / self.edge).astype(np.int64) - self.base

    def centres(self) -> np.ndarray:
        """(C, 3) float64 centres of the occupied cells."""
        return (self.cells + self.base + 0.5) * self.edge
