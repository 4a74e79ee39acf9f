"""Residual points coded as an octree: their coded positions as node occupancies, their class and intensity after.

A tile's residual points (:mod:`.residual_points`: X, Y, Z on the coded
grid, the class, the intensity on 64 levels, one return, every other
byte zero) take about 15 bits a point for their position under LAZ,
whatever the order.  As a set, they are an octree: from the root (the
box of their positions, ``2**depth`` coded steps wide), each node gives
the byte of its occupied children, coded by :mod:`.range_coder` in a
context of how many of the node's six face neighbours are occupied: points
on a surface or a crown fill neighbouring nodes, isolated ones do not.  Then, point by point in Morton order, how
many points share a position (mostly one), the class (in the context of
the previous point's class) and the intensity level (in the context of
the previous point's level; 127 and above escaped to 16 bits).

The block::

    magic "PCZO", version 1 (1 byte), flags (1 byte: bit 0, every point return 1 of 1),
    points (uint32), positions (uint32), origin (3 int64: the smallest coded X, Y, Z), depth (1 byte),
    then the range coder's bytes.

Points come back in Morton order of their positions (nothing reads them
in an order).  :func:`encode` returns None where the positions span more
than 2**21 steps (LAZ codes those).

>>> xyz = np.array([[5, 5, 5], [6, 5, 5], [5, 5, 5], [40, 2, 9]])
>>> block = encode(xyz, np.array([2, 2, 6, 5]), np.array([10, 11, 12, 200]), single_return=True)
>>> back = decode(block, "example")
>>> back.xyz.tolist(), back.classification.tolist(), back.intensity.tolist(), back.single_return
([[5, 5, 5], [5, 5, 5], [6, 5, 5], [40, 2, 9]], [2, 6, 2, 5], [10, 12, 11, 200], True)
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import laspy
import numba
import numpy as np

from patchcloud.core import MAX_DEPTH, PatchcloudIOError, decode as morton_decode, encode as morton_encode, face_neighbours

from .range_coder import (
    chain_contexts, decode_chain, decode_direct, decode_tree, decoder, encode_direct, encode_tree, encoder, finish, new_trees,
)

__all__ = ["MAGIC", "OctreePoints", "encode", "decode", "records_of", "child_keys"]

MAGIC = b"PCZO"
_HEAD = struct.Struct("<4sBBIIqqqB")
_ESCAPE = 127  # intensity levels from here on: escaped, 16 bits
_MANY = 15  # points on one position from 1 + here on: escaped, 32 bits


@dataclass(frozen=True)
class OctreePoints:
    """Decoded residual points: coded positions (n, 3) int64, classes (n,) uint8, intensity levels (n,) int64."""

    xyz: np.ndarray
    classification: np.ndarray
    intensity: np.ndarray
    single_return: bool


def encode(xyz: np.ndarray, classification: np.ndarray, intensity: np.ndarray, single_return: bool) -> bytes | None:
    """The block of points at coded positions ``xyz`` ((n, 3) integers) with these classes (0-255) and intensity levels
    (0-65535); None where their positions span more than ``2**21`` steps."""
    xyz = np.asarray(xyz, dtype=np.int64).reshape(-1, 3)
    n = len(xyz)
    origin = xyz.min(axis=0) if n else np.zeros(3, np.int64)
    rel = xyz - origin
    span = int(rel.max()) if n else 0
    depth = span.bit_length()
    if depth > MAX_DEPTH:
        return None
    keys = morton_encode(rel)
    order = np.argsort(keys, kind="stable")
    keys = keys[order]
    unique, count = np.unique(keys, return_counts=True)
    st, out = encoder(64 + 3 * n)
    trees = new_trees(7, 8)  # one per count of occupied neighbours (a context of the depth too measured 1-3 % larger)
    for level in range(depth):  # level 0: the root; each node codes the byte of its children
        shift = np.uint64(3 * (depth - level))
        children = unique >> (shift - np.uint64(3))
        nodes, first = np.unique(children >> np.uint64(3), return_index=True)
        occupancy = np.bitwise_or.reduceat(np.left_shift(1, (children & np.uint64(7)).astype(np.int64)), first)
        out = encode_tree(st, out, trees, face_neighbours(nodes), occupancy, 8)
    many = np.minimum(count - 1, _MANY)
    out = encode_tree(st, out, new_trees(1, 4), np.zeros(len(many), np.int64), many, 4)
    out = encode_direct(st, out, count[count - 1 >= _MANY] - 1 - _MANY, 32)
    cls = np.asarray(classification, dtype=np.int64)[order]
    out = encode_tree(st, out, new_trees(256, 8), chain_contexts(cls, 0), cls, 8)
    q = np.asarray(intensity, dtype=np.int64)[order]
    sym = np.minimum(q, _ESCAPE)
    out = encode_tree(st, out, new_trees(16, 7), chain_contexts(sym, 3), sym, 7)
    out = encode_direct(st, out, q[q >= _ESCAPE], 16)
    head = _HEAD.pack(MAGIC, 1, 1 if single_return else 0, n, len(unique), *(int(v) for v in origin), depth)
    return head + finish(st, out)


def decode(block: bytes, where: str) -> OctreePoints:
    """The points of a block :func:`encode` made; a PatchcloudIOError naming ``where`` if it is damaged."""
    if len(block) < _HEAD.size:
        raise PatchcloudIOError(f"{where}: coded points of {len(block)} bytes, shorter than their header")
    magic, version, flags, n, npos, ox, oy, oz, depth = _HEAD.unpack_from(block)
    if magic != MAGIC or version != 1 or depth > MAX_DEPTH or npos > n or (n and not npos):
        raise PatchcloudIOError(f"{where}: damaged coded points (header {magic!r}, version {version}, {n:,} points at "
                                f"{npos:,} positions, depth {depth})")
    if 8 * len(block) < n:  # at least a bit a point: a header that claims more is damaged (or a bomb)
        raise PatchcloudIOError(f"{where}: {len(block):,} bytes cannot hold the {n:,} points their header says")
    data = np.frombuffer(block, dtype=np.uint8)
    try:
        return _decode(data, n, npos, np.array([ox, oy, oz], np.int64), depth, bool(flags & 1))
    except PatchcloudIOError as exc:
        raise PatchcloudIOError(f"{where}: {exc}") from None


def _decode(data: np.ndarray, n: int, npos: int, origin: np.ndarray, depth: int, single: bool) -> OctreePoints:
    st = decoder(data, _HEAD.size)
    trees = new_trees(7, 8)
    nodes = np.zeros(1 if n else 0, dtype=np.uint64)
    for _ in range(depth):
        occupancy = decode_tree(st, data, trees, face_neighbours(nodes), 8)
        nodes = child_keys(nodes, np.ascontiguousarray(occupancy, dtype=np.int64), npos)
        if nodes is None:
            raise PatchcloudIOError("damaged coded points (an empty node, or more positions than the header says)")
    if len(nodes) != npos:
        raise PatchcloudIOError(f"damaged coded points ({len(nodes):,} positions, the header says {npos:,})")
    many = decode_tree(st, data, new_trees(1, 4), np.zeros(npos, np.int64), 4)
    big = many >= _MANY
    many[big] += decode_direct(st, data, int(big.sum()), 32)
    count = many + 1
    if int(count.sum()) != n:
        raise PatchcloudIOError(f"damaged coded points ({int(count.sum()):,} points, the header says {n:,})")
    keys = np.repeat(nodes, count)
    cls = np.zeros(n, np.int64)
    q = np.zeros(n, np.int64)
    if n:  # the contexts are the previous symbols: decoded one at a time
        cls = decode_chain(st, data, new_trees(256, 8), n, 8, 0)
        q = decode_chain(st, data, new_trees(16, 7), n, 7, 3)
        esc = q >= _ESCAPE
        q[esc] = decode_direct(st, data, int(esc.sum()), 16)
    xyz = morton_decode(keys) + origin
    return OctreePoints(xyz, cls.astype(np.uint8), q, single)


def child_keys(nodes: np.ndarray, occupancy: np.ndarray, limit: int) -> np.ndarray | None:
    """The keys of the children ``occupancy`` (a byte per node, bit c: child c) says the ``nodes`` have, parents in
    order and children in bit order, so the keys stay sorted; None for an empty node or more than ``limit``."""
    out = np.empty(_child_count(occupancy), dtype=np.uint64)
    if out.size > limit or (occupancy.size and not _fill_children(nodes, occupancy, out)):
        return None
    return out


@numba.njit(cache=True, nogil=True)
def _child_count(occupancy):
    total = 0
    for i in range(occupancy.shape[0]):
        o = occupancy[i] & 255
        while o:
            total += 1
            o &= o - 1
    return total


@numba.njit(cache=True, nogil=True)
def _fill_children(nodes, occupancy, out):
    """Write the children's keys to ``out``; False at an empty node (its byte 0)."""
    j = 0
    for i in range(occupancy.shape[0]):
        o = occupancy[i]
        if o <= 0 or o > 255:
            return False
        base = nodes[i] << np.uint64(3)
        for c in range(8):
            if (o >> c) & 1:
                out[j] = base | np.uint64(c)
                j += 1
    return True


def records_of(points: OctreePoints, point_format_id: int, size: int) -> np.ndarray:
    """(n, size) uint8: the points as LAS records of format ``point_format_id`` (its first bytes; the rest, extra
    bytes, zero): X, Y, Z the coded positions, the class, the intensity level, return 1 of 1 if ``single_return``."""
    pf = laspy.PointFormat(point_format_id)
    n = len(points.xyz)
    if n and point_format_id <= 5 and int(points.classification.max()) > 31:
        raise PatchcloudIOError(f"damaged coded points (class {int(points.classification.max())} in point format {point_format_id})")
    rec = laspy.PackedPointRecord.zeros(n, pf)
    if n:
        rec["X"], rec["Y"], rec["Z"] = (points.xyz[:, a].astype(np.int32) for a in range(3))
        rec["classification"] = points.classification
        rec["intensity"] = points.intensity.astype(np.uint16)
        if points.single_return:
            one = np.ones(n, np.uint8)
            rec["return_number"], rec["number_of_returns"] = one, one
    rows = np.zeros((n, size), np.uint8)
    rows[:, : pf.size] = np.ascontiguousarray(rec.array).view(np.uint8).reshape(n, pf.size)
    return rows
