"""LAS integer coordinates in a local frame: float64 metres, and the grid cells they fall in, each in one compiled pass.

``local = (X + base) * scale + shift`` per axis, with numpy's rounding: the
sum of integers exact, then the product, then the sum, each rounded once (no
fused multiply-add), so the values are those of the numpy expression bit for
bit.  :func:`frame_shift` splits a file's offset minus the frame's origin into
the integer ``base`` and the float ``shift``: where the offset lies on the
origin's grid of steps ``scale`` (as the offsets of LAS files do: multiples of
their scale), ``shift`` is 0 and every local coordinate is one rounding of an
exact integer times the scale.  Then a point's local coordinates do not
depend on the file's offset (the same point on the same grid, written with
another offset, has the same ``X + base``), and neither does any cell a
point is found in: with ``X * scale + (offset - origin)``, two roundings, a
point exactly on a cell's face fell on one side or the other as the offset
made the roundings fall.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from .threads import parallel_kernel

__all__ = ["local_coordinates", "cell_indices", "frame_shift"]


def frame_shift(offset, origin, scale) -> tuple[np.ndarray, np.ndarray]:
    """``(base, shift)``: ``offset - origin`` as ``base * scale + shift`` per axis, ``base`` whole steps.

    Where ``(offset - origin) / scale`` is a whole number (within 1e-6 of
    one: the offset lies on the origin's grid), ``base`` is that number and
    ``shift`` 0; elsewhere ``base`` is 0 and ``shift`` is ``offset - origin``.

    Parameters
    ----------
    offset, origin, scale : (3,) float
        The file's offset and scale, the frame's origin (metres).

    Returns
    -------
    base : (3,) int64
    shift : (3,) float64

    Examples
    --------
    >>> base, shift = frame_shift((650123.45, 6860000.0, 0.005), (647168.0, 6856704.0, 0.0), (0.01, 0.01, 0.01))
    >>> base.tolist(), shift.tolist()
    ([295545, 329600, 0], [0.0, 0.0, 0.005])
    """
    offset, origin, scale = (np.asarray(v, dtype=np.float64).reshape(3) for v in (offset, origin, scale))
    steps = (offset - origin) / scale
    whole = np.round(steps)
    on_grid = (np.abs(steps - whole) <= 1e-6) & (np.abs(whole) < 2.0**52)
    base = np.where(on_grid, whole, 0.0).astype(np.int64)
    shift = np.where(on_grid, 0.0, offset - origin)
    return base, shift


def local_coordinates(xyz: np.ndarray, scale, shift, base=(0, 0, 0)) -> np.ndarray:
    """(N, 3) float64 local coordinates ``(X + base) * scale + shift`` (metres) of (N, 3) integer coordinates.

    >>> local_coordinates(np.array([[1000, -20, 7]], dtype=np.int32), (0.01, 0.01, 0.001), (5.0, 0.0, -1.0)).tolist()
    [[15.0, -0.2, -0.993]]
    >>> local_coordinates(np.array([[1000, -20, 7]], dtype=np.int32), (0.01, 0.01, 0.001), (0.0, 0.0, 0.0), (500, 0, -1000)).tolist()
    [[15.0, -0.2, -0.993]]
    """
    xyz = np.asarray(xyz)
    out = np.empty((xyz.shape[0], 3))
    _local(xyz, np.asarray(base, dtype=np.int64), np.asarray(scale, dtype=np.float64), np.asarray(shift, dtype=np.float64), out)
    return out


def cell_indices(xyz: np.ndarray, scale, shift, edge: float, base=(0, 0, 0)) -> np.ndarray:
    """(N, 3) int64 indices ``floor(local / edge)`` of the cells of edge ``edge`` (metres) holding the points.

    >>> cell_indices(np.array([[1000, -20, 7]], dtype=np.int32), (0.01, 0.01, 0.001), (5.0, 0.0, -1.0), 8.0).tolist()
    [[1, -1, -1]]
    """
    xyz = np.asarray(xyz)
    out = np.empty((xyz.shape[0], 3), dtype=np.int64)
    _cells(xyz, np.asarray(base, dtype=np.int64), np.asarray(scale, dtype=np.float64), np.asarray(shift, dtype=np.float64),
           float(edge), out)
    return out


@parallel_kernel
def _local(xyz, base, scale, shift, out):
    for i in prange(xyz.shape[0]):
        for a in range(3):
            out[i, a] = np.float64(np.int64(xyz[i, a]) + base[a]) * scale[a] + shift[a]


@parallel_kernel
def _cells(xyz, base, scale, shift, edge, out):
    for i in prange(xyz.shape[0]):
        for a in range(3):
            out[i, a] = np.int64(np.floor((np.float64(np.int64(xyz[i, a]) + base[a]) * scale[a] + shift[a]) / edge))
