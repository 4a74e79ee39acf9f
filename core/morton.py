"""Morton (Z-order) keys of integer octree coordinates.

A key interleaves the bits of three unsigned integer coordinates of at most
:data:`MAX_DEPTH` bits each (x in bit 0, y in bit 1, z in bit 2 of every
triple), so sorting points by key groups them node by node at every octree
level: the node of a point at level ``L`` is ``key >> 3 * (MAX_DEPTH - L)``.
"""

from __future__ import annotations

import numpy as np

from .errors import PatchcloudValueError

__all__ = ["MAX_DEPTH", "encode", "decode", "quantize", "key_range", "containing", "face_neighbours"]

#: Bits per axis; 3 * 21 = 63 bits fit an unsigned 64-bit key.
MAX_DEPTH = 21

_M = np.uint64


def _spread(v: np.ndarray) -> np.ndarray:
    """Insert two zero bits between each of the low 21 bits of ``v``."""
    x = v.astype(np.uint64) & _M(0x1FFFFF)
    x = (x | (x << _M(32))) & _M(0x1F00000000FFFF)
    x = (x | (x << _M(16))) & _M(0x1F0000FF0000FF)
    x = (x | (x << _M(8))) & _M(0x100F00F00F00F00F)
    x = (x | (x << _M(4))) & _M(0x10C30C30C30C30C3)
    x = (x | (x << _M(2))) & _M(0x1249249249249249)
    return x


def _compact(x: np.ndarray) -> np.ndarray:
    """Inverse of :func:`_spread`."""
    x = x.astype(np.uint64) & _M(0x1249249249249249)
    x = (x | (x >> _M(2))) & _M(0x10C30C30C30C30C3)
    x = (x | (x >> _M(4))) & _M(0x100F00F00F00F00F)
    x = (x | (x >> _M(8))) & _M(0x1F0000FF0000FF)
    x = (x | (x >> _M(16))) & _M(0x1F00000000FFFF)
    x = (x | (x >> _M(32))) & _M(0x1FFFFF)
    return x


def encode(ijk: np.ndarray) -> np.ndarray:
    """Morton keys of integer coordinates.

    Parameters
    ----------
    ijk : (N, 3) integer array
        Coordinates in ``[0, 2**21)``.

    Returns
    -------
    (N,) uint64 array

    Examples
    --------
    >>> encode(np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1]]))
    array([1, 2, 4], dtype=uint64)
    """
    ijk = np.asarray(ijk)
    return _spread(ijk[:, 0]) | (_spread(ijk[:, 1]) << _M(1)) | (_spread(ijk[:, 2]) << _M(2))


def decode(keys: np.ndarray) -> np.ndarray:
    """Integer coordinates ``(N, 3)`` int64 of Morton keys (inverse of :func:`encode`)."""
    keys = np.asarray(keys, dtype=np.uint64)
    out = np.empty((keys.shape[0], 3), dtype=np.int64)
    out[:, 0] = _compact(keys)
    out[:, 1] = _compact(keys >> _M(1))
    out[:, 2] = _compact(keys >> _M(2))
    return out


def quantize(local: np.ndarray, edge: float) -> np.ndarray:
    """Integer coordinates at depth :data:`MAX_DEPTH` of points in a root cube.

    Parameters
    ----------
    local : (N, 3) float64
        Coordinates relative to the root cube's minimum corner, in metres.
    edge : float
        Edge of the root cube, in metres.

    Returns
    -------
    (N, 3) int64 in ``[0, 2**21)``; points on the upper faces go to the last cell.
    """
    n = 1 << MAX_DEPTH
    q = np.floor(local * (n / edge)).astype(np.int64)
    np.clip(q, 0, n - 1, out=q)
    return q


def key_range(cell: np.ndarray, level: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth-``MAX_DEPTH`` keys ``[lo, hi)`` covered by cells of given Morton ids at given levels."""
    shift = (3 * (MAX_DEPTH - np.asarray(level, dtype=np.int64))).astype(np.uint64)
    cell = np.asarray(cell, dtype=np.uint64)
    return cell << shift, (cell + _M(1)) << shift


def containing(lo: np.ndarray, hi: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Index of the range ``[lo[i], hi[i])`` holding each key, or -1; ``lo`` ascending, ranges disjoint."""
    idx = np.searchsorted(lo, keys, side="right") - 1
    safe = np.maximum(idx, 0)
    return np.where((idx >= 0) & (keys < hi[safe]), idx, -1)


def face_neighbours(keys: np.ndarray) -> np.ndarray:
    """For each cell of one level, how many of its six face neighbours are cells of the level.

    Parameters
    ----------
    keys : (N,) uint64
        Morton keys of the level's cells, sorted, unique.

    Returns
    -------
    (N,) int64, 0 to 6

    Examples
    --------
    >>> keys = np.sort(encode(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]])))
    >>> face_neighbours(keys).tolist()
    [2, 1, 1, 0]
    """
    from ._kernels import face_neighbour_counts

    keys = np.ascontiguousarray(keys, dtype=np.uint64)
    if keys.size > 1 and not bool(np.all(keys[1:] > keys[:-1])):  # the kernel finds siblings next to each other
        raise PatchcloudValueError("keys must be sorted and unique")
    out = np.zeros(len(keys), dtype=np.int64)
    face_neighbour_counts(keys, out)
    return out
