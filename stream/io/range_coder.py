"""An adaptive binary range coder (LZMA's), for the symbols of a ``.pcz``'s coded residual points.

Each binary decision is coded with an adaptive probability (11 bits,
adapting by 1/32 of the gap at each use); a symbol of ``n`` bits is coded
as ``n`` decisions down a bit tree (``2**n`` probabilities, one per
prefix), and a *context* picks one of several trees.  Integer arithmetic
only: the same symbols give the same bytes on every machine.

State lives in small arrays so that coding can stop and go on (the
decoder of an octree decodes a level, then works out the contexts of the
next):

- encoder: :func:`encoder` -> ``(state, out)``; :func:`encode_tree`
  codes symbols; :func:`finish` returns the bytes;
- decoder: :func:`decoder` over the bytes; :func:`decode_tree` gives the
  symbols back.

>>> import numpy as np
>>> sym, ctx = np.array([3, 3, 3, 0, 7, 3]), np.array([0, 0, 1, 1, 0, 0])
>>> probs = new_trees(2, 3)
>>> st, out = encoder(64)
>>> out = encode_tree(st, out, probs, ctx, sym, 3)
>>> data = finish(st, out)
>>> d = decoder(data)
>>> decode_tree(d, data, new_trees(2, 3), ctx, 3).tolist()
[3, 3, 3, 0, 7, 3]
"""

from __future__ import annotations

import numba
import numpy as np

from patchcloud.core import PatchcloudIOError

__all__ = ["new_trees", "encoder", "encode_tree", "encode_direct", "finish", "decoder", "decode_tree", "decode_chain",
           "chain_contexts", "decode_direct"]

_BITS = 11  # probability precision
_ONE = 1 << _BITS
_MOVE = 5  # adaptation: 1/32 of the gap
_TOP = 1 << 24

# encoder state: low, range, cache, cache_size, bytes written
_LOW, _RANGE, _CACHE, _CACHE_SIZE, _POS = range(5)
# decoder state: code, range, next byte, error (1: ran past the end)
_CODE, _DRANGE, _NEXT, _ERROR = range(4)


def new_trees(contexts: int, bits: int) -> np.ndarray:
    """Probabilities of ``contexts`` bit trees of symbols of ``bits`` bits, all at one half: (contexts, 2**bits) uint16."""
    return np.full((contexts, 1 << bits), _ONE // 2, dtype=np.uint16)


def encoder(capacity: int) -> tuple[np.ndarray, np.ndarray]:
    """A fresh encoder: its state and an output buffer of ``capacity`` bytes (grown as needed)."""
    st = np.zeros(5, dtype=np.uint64)
    st[_RANGE] = 0xFFFFFFFF
    st[_CACHE_SIZE] = 1
    return st, np.zeros(max(int(capacity), 16), dtype=np.uint8)


@numba.njit(cache=True, nogil=True)
def _shift_low(st, out):
    low = st[_LOW]
    if low < np.uint64(0xFF000000) or low >= np.uint64(1 << 32):
        carry = low >> np.uint64(32)
        temp = st[_CACHE]
        while True:
            out[st[_POS]] = np.uint8((temp + carry) & np.uint64(0xFF))
            st[_POS] += np.uint64(1)
            temp = np.uint64(0xFF)
            st[_CACHE_SIZE] -= np.uint64(1)
            if st[_CACHE_SIZE] == 0:
                break
        st[_CACHE] = (low >> np.uint64(24)) & np.uint64(0xFF)
    st[_CACHE_SIZE] += np.uint64(1)
    st[_LOW] = (low & np.uint64(0x00FFFFFF)) << np.uint64(8)


@numba.njit(cache=True, nogil=True)
def _encode_bit(st, out, probs, c, i, bit):
    p = np.uint64(probs[c, i])
    bound = (st[_RANGE] >> np.uint64(_BITS)) * p
    if bit == 0:
        st[_RANGE] = bound
        probs[c, i] = np.uint16(p + ((np.uint64(_ONE) - p) >> np.uint64(_MOVE)))
    else:
        st[_LOW] += bound
        st[_RANGE] -= bound
        probs[c, i] = np.uint16(p - (p >> np.uint64(_MOVE)))
    while st[_RANGE] < np.uint64(_TOP):
        st[_RANGE] = (st[_RANGE] << np.uint64(8)) & np.uint64(0xFFFFFFFF)
        _shift_low(st, out)


@numba.njit(cache=True, nogil=True)
def _encode_tree(st, out, probs, contexts, symbols, bits):
    for k in range(symbols.shape[0]):
        if st[_POS] + np.uint64(16) >= np.uint64(out.shape[0]):
            return k  # the caller grows the buffer and goes on from k
        s = np.int64(symbols[k])
        c = contexts[k]
        node = 1
        for b in range(bits - 1, -1, -1):
            bit = (s >> b) & 1
            _encode_bit(st, out, probs, c, node, bit)
            node = (node << 1) | bit
    return symbols.shape[0]


def encode_tree(st: np.ndarray, out: np.ndarray, probs: np.ndarray, contexts: np.ndarray, symbols: np.ndarray,
                bits: int) -> np.ndarray:
    """Code ``symbols`` (each below ``2**bits``) down the bit trees ``probs[contexts[k]]``; returns the output buffer
    (a larger one when it filled up: use the returned one)."""
    contexts = np.ascontiguousarray(contexts, dtype=np.int64)
    symbols = np.ascontiguousarray(symbols, dtype=np.int64)
    done = 0
    while done < symbols.shape[0]:
        done += _encode_tree(st, out, probs, contexts[done:], symbols[done:], bits)
        if done < symbols.shape[0]:
            out = np.concatenate([out, np.zeros(out.shape[0] + 16 * (symbols.shape[0] - done) * bits // 8 + 64, np.uint8)])
    return out


@numba.njit(cache=True, nogil=True)
def _encode_direct(st, out, values, bits):
    probs = np.empty((1, 2), dtype=np.uint16)  # one node, set back to a half before each bit
    for k in range(values.shape[0]):
        if st[_POS] + np.uint64(16 + bits // 8) >= np.uint64(out.shape[0]):
            return k
        for b in range(bits - 1, -1, -1):
            probs[0, 1] = _ONE // 2
            _encode_bit(st, out, probs, 0, 1, (values[k] >> b) & 1)
    return values.shape[0]


def encode_direct(st: np.ndarray, out: np.ndarray, values: np.ndarray, bits: int) -> np.ndarray:
    """Code ``values`` (each below ``2**bits``) with fixed probabilities of one half (no adaptation, ``bits`` bits each);
    returns the output buffer (as :func:`encode_tree`)."""
    values = np.ascontiguousarray(values, dtype=np.int64)
    done = 0
    while done < values.shape[0]:
        done += _encode_direct(st, out, values[done:], bits)
        if done < values.shape[0]:
            out = np.concatenate([out, np.zeros(out.shape[0] + (values.shape[0] - done) * bits // 8 + 64, np.uint8)])
    return out


def finish(st: np.ndarray, out: np.ndarray) -> bytes:
    """Flush the encoder: the coded bytes."""
    if st[_POS] + np.uint64(8) >= np.uint64(out.shape[0]):
        out = np.concatenate([out, np.zeros(16, np.uint8)])
    for _ in range(5):
        _shift_low(st, out)
    return out[: int(st[_POS])].tobytes()


def decoder(data: bytes | np.ndarray, start: int = 0) -> np.ndarray:
    """A decoder over ``data`` from byte ``start``: its state."""
    buf = np.frombuffer(data, dtype=np.uint8) if isinstance(data, (bytes, bytearray)) else data
    st = np.zeros(4, dtype=np.uint64)
    st[_DRANGE] = 0xFFFFFFFF
    code = 0
    for k in range(5):
        code = (code << 8) | (int(buf[start + k]) if start + k < buf.shape[0] else 0)
    st[_CODE] = code & 0xFFFFFFFF
    st[_NEXT] = start + 5
    st[_ERROR] = 1 if start + 5 > buf.shape[0] else 0
    return st


@numba.njit(cache=True, nogil=True)
def _decode_symbol(st, data, probs, c, bits):
    node = 1
    for _ in range(bits):
        p = np.uint64(probs[c, node])
        bound = (st[_DRANGE] >> np.uint64(_BITS)) * p
        if st[_CODE] < bound:
            st[_DRANGE] = bound
            probs[c, node] = np.uint16(p + ((np.uint64(_ONE) - p) >> np.uint64(_MOVE)))
            node = node << 1
        else:
            st[_CODE] -= bound
            st[_DRANGE] -= bound
            probs[c, node] = np.uint16(p - (p >> np.uint64(_MOVE)))
            node = (node << 1) | 1
        while st[_DRANGE] < np.uint64(_TOP):
            st[_DRANGE] = (st[_DRANGE] << np.uint64(8)) & np.uint64(0xFFFFFFFF)
            nxt = st[_NEXT]
            byte = np.uint64(0)
            if nxt < np.uint64(data.shape[0]):
                byte = np.uint64(data[nxt])
            else:
                st[_ERROR] = 1
            st[_CODE] = ((st[_CODE] << np.uint64(8)) | byte) & np.uint64(0xFFFFFFFF)
            st[_NEXT] = nxt + np.uint64(1)
    return node - (1 << bits)


@numba.njit(cache=True, nogil=True)
def _decode_tree(st, data, probs, contexts, bits, out):
    for k in range(contexts.shape[0]):
        out[k] = _decode_symbol(st, data, probs, contexts[k], bits)


@numba.njit(cache=True, nogil=True)
def _decode_chain(st, data, probs, bits, shift, out):
    prev = 0
    for k in range(out.shape[0]):
        prev = _decode_symbol(st, data, probs, prev >> shift, bits)
        out[k] = prev


def decode_tree(st: np.ndarray, data: bytes | np.ndarray, probs: np.ndarray, contexts: np.ndarray, bits: int) -> np.ndarray:
    """Symbols of ``bits`` bits coded by :func:`encode_tree` with these ``contexts`` (int64); a
    PatchcloudIOError if the data ran out (damaged)."""
    buf = np.frombuffer(data, dtype=np.uint8) if isinstance(data, (bytes, bytearray)) else data
    out = np.zeros(len(contexts), dtype=np.int64)
    _decode_tree(st, buf, probs, np.ascontiguousarray(contexts, dtype=np.int64), bits, out)
    if st[_ERROR]:
        raise PatchcloudIOError("the coded points end early (damaged)")
    return out


def decode_chain(st: np.ndarray, data: bytes | np.ndarray, probs: np.ndarray, count: int, bits: int, shift: int) -> np.ndarray:
    """``count`` symbols coded by :func:`encode_tree` each in the context of the previous symbol ``>> shift`` (the first
    in context 0): :func:`chain_contexts` gives the encoder's contexts."""
    buf = np.frombuffer(data, dtype=np.uint8) if isinstance(data, (bytes, bytearray)) else data
    out = np.zeros(count, dtype=np.int64)
    _decode_chain(st, buf, probs, bits, shift, out)
    if st[_ERROR]:
        raise PatchcloudIOError("the coded points end early (damaged)")
    return out


def chain_contexts(symbols: np.ndarray, shift: int) -> np.ndarray:
    """The contexts :func:`decode_chain` decodes ``symbols`` in: each the previous symbol ``>> shift``, the first 0.

    >>> chain_contexts(np.array([9, 17, 3]), 3).tolist()
    [0, 1, 2]
    """
    s = np.asarray(symbols, dtype=np.int64)
    return np.r_[0, s[:-1]] >> shift if len(s) else s


@numba.njit(cache=True, nogil=True)
def _decode_direct(st, data, bits, out):
    probs = np.empty((1, 2), dtype=np.uint16)
    for k in range(out.shape[0]):
        v = 0
        for _ in range(bits):
            probs[0, 1] = _ONE // 2
            v = (v << 1) | _decode_symbol(st, data, probs, 0, 1)
        out[k] = v


def decode_direct(st: np.ndarray, data: bytes | np.ndarray, count: int, bits: int) -> np.ndarray:
    """``count`` values of ``bits`` bits coded by :func:`encode_direct`."""
    buf = np.frombuffer(data, dtype=np.uint8) if isinstance(data, (bytes, bytearray)) else data
    out = np.zeros(count, dtype=np.int64)
    _decode_direct(st, buf, bits, out)
    if st[_ERROR]:
        raise PatchcloudIOError("the coded points end early (damaged)")
    return out
