"""LAZ chunks of an input with new extra bytes, its own layers copied as they are.

LASzip codes the point formats 6 to 10 in *layers*: in each chunk, every
field (the 9 streams of the point's own fields, RGB, NIR, and each extra
byte) is its own arithmetic-coded stream.  A chunk is

- the first point's record, raw;
- the chunk's point count (u32);
- the byte count of every layer (u32 each, in the order of the fields);
- the layers, in that order.

Each extra byte is coded alone (its own models, its own coder; the points'
scanner channels choose among 4 contexts), so the chunk of the same points
with ``k`` more extra bytes is the input chunk with ``k`` more layers at the
end of its layer list: :func:`extend_chunk` builds it from the input's
compressed chunk and codes only the new bytes (:func:`byte_layers`, the
coder of LASzip's ``BYTE14`` version 3 as lazrs runs it).  The input's
point fields are then neither decoded nor coded again, and the result is
byte for byte what lazrs writes when it compresses the whole records
(tested on every layered format, with several scanner channels).  For the
same reason the new bytes may go before some of the input's extra bytes
(an output keeps the bytes no ExtraBytes entry describes last: a real IGN
file has one): their layers then follow the new ones.

:func:`plan` says whether an input and an output can go this way: both
layered LAZ (compressor 3) of items version 3, the same chunk size of
fixed points, the output's items those of the input with a longer
``BYTE14`` and nothing else.

Two extra bytes of 4 points, the first never changing (no layer):

>>> vals = np.array([[7, 1], [7, 1], [7, 3], [7, 3]], dtype=np.uint8)
>>> layers, sizes = byte_layers(vals, byte_contexts(np.zeros(4, np.uint8)))
>>> sizes.tolist(), bytes(layers[1, : sizes[1]]).hex()
([0, 7], '00020000000000')
"""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass

import numpy as np
from numba import njit

__all__ = ["LayeredPlan", "plan", "read_vlr_items", "byte_contexts", "byte_layers", "extend_chunk", "POINT14_LAYERS"]

#: Layers of a ``POINT14`` item (LASzip 3: changed values with X and Y, Z, classification, flags, intensity, scan angle,
#: user data, point source, GPS time).
POINT14_LAYERS = 9
_POINT14, _RGB14, _RGBNIR14, _BYTE14 = 10, 11, 12, 14  # LASzip's item types (13, WAVEPACKET14, is not copied)
#: Layers of each item type of a layered chunk but BYTE14 (one layer per byte, counted apart).
_LAYERS = {_POINT14: POINT14_LAYERS, _RGB14: 1, _RGBNIR14: 2}
_VARIABLE = 0xFFFFFFFF


def read_vlr_items(record_data: bytes) -> tuple[int, int, list[tuple[int, int, int]]]:
    """(compressor, chunk size, items) of a LASzip VLR's data: each item (type, size, version).

    >>> read_vlr_items(bytes.fromhex("030000000202000000000000" "50c30000" + "ff" * 16 + "0200" "0a001e000300" "0e0010000300"))
    (3, 50000, [(10, 30, 3), (14, 16, 3)])
    """
    data = bytes(record_data)
    if len(data) < 34:
        raise ValueError(f"a LASzip VLR of {len(data)} bytes, fewer than its 34 fixed ones")
    compressor, = struct.unpack_from("<H", data, 0)
    chunk, = struct.unpack_from("<I", data, 12)
    n, = struct.unpack_from("<H", data, 32)
    if len(data) < 34 + 6 * n:
        raise ValueError(f"a LASzip VLR of {len(data)} bytes, too short for its {n} items")
    items = [struct.unpack_from("<3H", data, 34 + 6 * i) for i in range(n)]
    return int(compressor), int(chunk), [tuple(int(v) for v in it) for it in items]


@dataclass(frozen=True)
class LayeredPlan:
    """How an output's chunks are made from the input's: ``in_size`` bytes of the input's records (all copied),
    ``in_layers`` layers in its chunks, ``new_bytes`` extra bytes added, ``chunk`` points per chunk; the new bytes
    go before the input's last ``tail`` extra bytes (which the output moves after them), else at the end."""

    in_size: int
    in_layers: int
    new_bytes: int
    chunk: int
    tail: int = 0

    @property
    def at(self) -> int:
        """Where the new bytes start in an output record."""
        return self.in_size - self.tail


def plan(in_vlr: bytes, out_vlr: bytes, in_size: int, out_size: int, tail: int = 0) -> LayeredPlan | None:
    """The :class:`LayeredPlan` from an input's LASzip VLR data to an output's, or None where the output's chunks
    cannot be the input's with more extra bytes (then the whole records are coded).

    ``in_size``, ``out_size``: the records' bytes; the output record must be
    the input record as it is with the new bytes inserted before its last
    ``tail`` bytes, which must be extra bytes (the caller checks that the
    fields sit there; 0: the new bytes at the end).
    """
    try:
        ci, chunk_in, items_in = read_vlr_items(in_vlr)
        co, chunk_out, items_out = read_vlr_items(out_vlr)
    except ValueError:  # a damaged VLR: the records are read and coded whole, where its damage is reported
        return None
    if ci != 3 or co != 3 or chunk_in != chunk_out or chunk_in in (0, _VARIABLE) or out_size <= in_size:
        return None
    if any(v != 3 for _, _, v in items_in + items_out) or not items_in or items_in[0][0] != _POINT14:
        return None
    body_in = [it for it in items_in if it[0] != _BYTE14]
    body_out = [it for it in items_out if it[0] != _BYTE14]
    if body_in != body_out or any(t not in _LAYERS for t, _, _ in body_in):
        return None
    if items_in[: len(body_in)] != body_in or items_out[: len(body_out)] != body_out:  # BYTE14 last, at most once
        return None
    m = sum(s for t, s, _ in items_in if t == _BYTE14)
    mk = sum(s for t, s, _ in items_out if t == _BYTE14)
    if len(items_in) - len(body_in) > 1 or len(items_out) - len(body_out) != 1:
        return None
    if sum(s for _, s, _ in items_in) != in_size or sum(s for _, s, _ in items_out) != out_size or mk - m != out_size - in_size:
        return None
    if not 0 <= tail <= m:
        return None
    return LayeredPlan(in_size=in_size, in_layers=sum(_LAYERS[t] for t, _, _ in body_in) + m, new_bytes=mk - m, chunk=chunk_in,
                       tail=int(tail))


@njit(nogil=True, cache=True)
def byte_contexts(channels: np.ndarray) -> np.ndarray:
    """(n,) int64: the context each point of a chunk codes its extra bytes in, from its scanner channel (0-3).

    As lazrs's ``POINT14`` version 3 sets it: the first point's channel,
    then a point's channel where it differs from the previous point's, and
    0 where it does not (LASzip 3's rule, which version 4 changed).
    """
    n = channels.shape[0]
    out = np.zeros(n, dtype=np.int64)
    if n == 0:
        return out
    cur = np.int64(channels[0])
    out[0] = cur
    for j in range(1, n):
        c = np.int64(channels[j])
        if c != cur:
            out[j] = c
            cur = c
    return out


_M32 = 0xFFFFFFFF
_AC_MIN_LENGTH = 0x01000000
_DM_MAX_COUNT = 1 << 15


@njit(nogil=True, cache=True)
def _model_init(dist, count, state, c):
    """Context ``c``'s fresh 256-symbol adaptive model (LASzip's ``ArithmeticModel``): counts 1, then one update.

    ``dist``, ``count``: (4 * 256,) the contexts' distributions and symbol
    counts; ``state`` (4 * 3,): each one's total count, update cycle and
    symbols until the next update.
    """
    for s in range(256):
        count[c * 256 + s] = 1
    state[3 * c] = 0
    state[3 * c + 1] = 256
    _model_update(dist, count, state, c)
    state[3 * c + 1] = (256 + 6) >> 1
    state[3 * c + 2] = (256 + 6) >> 1


@njit(nogil=True, cache=True)
def _model_update(dist, count, state, c):
    o = c * 256
    total = state[3 * c] + state[3 * c + 1]
    if total > _DM_MAX_COUNT:
        total = 0
        for s in range(256):
            count[o + s] = (count[o + s] + 1) >> 1
            total += count[o + s]
    scale = 0x80000000 // total
    acc = 0
    for s in range(256):
        dist[o + s] = ((scale * acc) & _M32) >> 16
        acc += count[o + s]
    cycle = (5 * state[3 * c + 1]) >> 2
    if cycle > (256 + 6) << 3:
        cycle = (256 + 6) << 3
    state[3 * c] = total
    state[3 * c + 1] = cycle
    state[3 * c + 2] = cycle


@njit(nogil=True, cache=True)
def _carry(buf, pos):
    p = pos - 1
    while p >= 0 and buf[p] == 0xFF:
        buf[p] = 0
        p -= 1
    if p >= 0:
        buf[p] += 1


@njit(nogil=True, cache=True)
def _layer(values, ctx, buf, dist, count, state):
    """Code the byte ``values`` (n,) of every point but the first into ``buf``; return (bytes written, whether the
    byte ever changed), or (-1, False) if ``buf`` is too small."""
    n = values.shape[0]
    cap = buf.shape[0]
    unused = np.ones(4, dtype=np.bool_)
    last = np.zeros(4, dtype=np.int64)
    c0 = ctx[0]
    last[c0] = values[0]
    unused[c0] = False
    _model_init(dist, count, state, c0)
    last_used = c0
    base = 0
    length = _M32
    pos = 0
    changed = False
    for j in range(1, n):
        c = ctx[j]
        last_idx = last_used
        if last_used != c:
            last_used = c
            if unused[c]:
                _model_init(dist, count, state, c)
                unused[c] = False
                last[c] = last[last_idx]
                last_idx = c
        v = np.int64(values[j])
        sym = (v - last[last_idx]) & 0xFF
        if sym != 0:
            changed = True
            last[last_idx] = v
        o = c * 256 + sym
        init_base = base
        if sym == 255:
            x = dist[o] * (length >> 15)
            base = (base + x) & _M32
            length -= x
        else:
            length >>= 15
            x = dist[o] * length
            base = (base + x) & _M32
            length = dist[o + 1] * length - x
        if init_base > base:
            _carry(buf, pos)
        if length < _AC_MIN_LENGTH:
            if pos + 8 > cap:
                return -1, False
            while length < _AC_MIN_LENGTH:
                buf[pos] = base >> 24
                pos += 1
                base = (base << 8) & _M32
                length = length << 8
        count[o] += 1
        state[3 * c + 2] -= 1
        if state[3 * c + 2] == 0:
            _model_update(dist, count, state, c)
        last_used = c
    # the coder's end (LASzip's ArithmeticEncoder::done)
    init_base = base
    another = length > 2 * _AC_MIN_LENGTH  # then the interval keeps 2**23 (one byte out, one zero more), else 2**15 (two)
    base = (base + (_AC_MIN_LENGTH if another else _AC_MIN_LENGTH >> 1)) & _M32
    if init_base > base:
        _carry(buf, pos)
    if pos + 16 > cap:
        return -1, False
    for _ in range(1 if another else 2):  # the renormalisation of those lengths
        buf[pos] = base >> 24
        pos += 1
        base = (base << 8) & _M32
    buf[pos] = 0
    buf[pos + 1] = 0
    pos += 2
    if another:
        buf[pos] = 0
        pos += 1
    return pos, changed


@njit(nogil=True, cache=True)
def _layers(columns, ctx, out, sizes):
    """Each row of ``columns`` (k, n) coded into the same row of ``out``; False if a row of ``out`` is too small."""
    dist = np.zeros(4 * 256, dtype=np.int64)
    count = np.zeros(4 * 256, dtype=np.int64)
    state = np.zeros(4 * 3, dtype=np.int64)
    for col in range(columns.shape[0]):
        pos, changed = _layer(columns[col], ctx, out[col], dist, count, state)
        if pos < 0:
            return False
        sizes[col] = pos if changed else 0
    return True


def byte_layers(values: np.ndarray, contexts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The layers of a chunk's extra bytes: ``values`` (n, k) uint8, the bytes of the chunk's n points (n >= 1);
    ``contexts`` (n,) int64 from :func:`byte_contexts`.

    Returns ``(layers, sizes)``: (k, capacity) uint8 and (k,) int64, layer
    ``i`` being ``layers[i, :sizes[i]]`` (size 0: the byte never changes
    in the chunk, and its layer is left out, as LASzip does).
    """
    columns = np.ascontiguousarray(np.asarray(values, dtype=np.uint8).T)
    contexts = np.ascontiguousarray(contexts, dtype=np.int64)
    k, n = columns.shape
    sizes = np.zeros(k, dtype=np.int64)
    for per_point in (2, 5):  # about 1 byte a point at most in practice; 5 covers every symbol's 15 bits and more
        out = np.empty((k, per_point * n + 64), dtype=np.uint8)
        if _layers(columns, contexts, out, sizes):
            return out, sizes
    raise RuntimeError("LAZ extra-bytes layers larger than 5 bytes a point")  # cannot happen: a symbol codes in < 3 bytes


def extend_chunk(chunk: bytes | memoryview, lp: LayeredPlan, values: np.ndarray, channels: np.ndarray) -> bytes:
    """The input's compressed ``chunk`` of n points with ``values`` (n, ``lp.new_bytes``) uint8 added to each
    record as extra bytes (before its last ``lp.tail`` bytes): its records and layers copied, the new layers coded.

    ``channels`` (n,): the points' scanner channels (what the new bytes'
    contexts follow).

    Raises
    ------
    ValueError
        The chunk is not the layered chunk of n points the plan says.
    """
    mv = memoryview(chunk)
    n = values.shape[0]
    head = lp.in_size + 4 + 4 * lp.in_layers
    if len(mv) < head:
        raise ValueError(f"LAZ chunk of {len(mv)} bytes, shorter than its head ({head})")
    count, = struct.unpack_from("<I", mv, lp.in_size)
    sizes_in = np.frombuffer(mv[lp.in_size + 4 : head], dtype="<u4")
    if count != n or head + int(sizes_in.sum(dtype=np.int64)) != len(mv):
        raise ValueError(f"LAZ chunk of {count:,} points and {len(mv):,} bytes is not the layered chunk of {n:,} points expected")
    layers, sizes = byte_layers(values, byte_contexts(np.asarray(channels)))
    at = lp.at  # where the new bytes go in the first record,
    kept = lp.in_layers - lp.tail  # among the layers
    moved = head + int(sizes_in[:kept].sum(dtype=np.int64))  # and in the layers' bytes
    out = io.BytesIO()
    out.write(mv[:at])  # the first point's record, raw
    out.write(values[0].tobytes())
    out.write(mv[at : lp.in_size])
    out.write(mv[lp.in_size : lp.in_size + 4 + 4 * kept])  # the point count, the layers' sizes
    out.write(sizes.astype("<u4").tobytes())
    out.write(mv[lp.in_size + 4 + 4 * kept : head])
    out.write(mv[head:moved])  # the layers
    for i in range(lp.new_bytes):
        out.write(layers[i, : sizes[i]].tobytes())
    out.write(mv[moved:])
    return out.getvalue()
