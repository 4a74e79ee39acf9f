"""LAS integer coordinates in a local frame: float64 metres, and the grid cells they fall in, each in one compiled pass.

``local = X * scale + shift`` per axis (``shift``: the file's offset minus
the frame's origin), with numpy's rounding: the product, then the sum, each
rounded once (no fused multiply-add), so the values are those of the numpy
expression bit for bit.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from .threads import parallel_kernel

__all__ = ["local_coordinates", "cell_indices"]


def local_coordinates(xyz: np.ndarray, scale, shift) -> np.ndarray:
    """(N, 3) float64 local coordinates (metres) of (N, 3) integer coordinates.

    >>> local_coordinates(np.array([[1000, -20, 7]], dtype=np.int32), (0.01, 0.01, 0.001), (5.0, 0.0, -1.0)).tolist()
    [[15.0, -0.2, -0.993]]
    """
    xyz = np.asarray(xyz)
    out = np.empty((xyz.shape[0], 3))
    _local(xyz, np.asarray(scale, dtype=np.float64), np.asarray(shift, dtype=np.float64), out)
    return out


def cell_indices(xyz: np.ndarray, scale, shift, edge: float) -> np.ndarray:
    """(N, 3) int64 indices ``floor(local / edge)`` of the cells of edge ``edge`` (metres) holding the points.

    >>> cell_indices(np.array([[1000, -20, 7]], dtype=np.int32), (0.01, 0.01, 0.001), (5.0, 0.0, -1.0), 8.0).tolist()
    [[1, -1, -1]]
    """
    xyz = np.asarray(xyz)
    out = np.empty((xyz.shape[0], 3), dtype=np.int64)
    _cells(xyz, np.asarray(scale, dtype=np.float64), np.asarray(shift, dtype=np.float64), float(edge), out)
    return out


@parallel_kernel
def _local(xyz, scale, shift, out):
    for i in prange(xyz.shape[0]):
        for a in range(3):
            out[i, a] = np.float64(xyz[i, a]) * scale[a] + shift[a]


@parallel_kernel
def _cells(xyz, scale, shift, edge, out):
    for i in prange(xyz.shape[0]):
        for a in range(3):
            out[i, a] = np.int64(np.floor((np.float64(xyz[i, a]) * scale[a] + shift[a]) / edge))
