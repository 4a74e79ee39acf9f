"""Point records of formats 0-3 as their LAS 1.4 twins 6 and 7, and back, bit for bit.

LAZ codes point formats 6 to 10 with LASzip's *layered* compressor (one
entropy-coded stream per field in each chunk) and formats 0 to 5 with the
older *point-wise* one.  The same points take fewer bytes in the layered
form (``python tools/bench_compress.py`` measures it: 0.9 % on St-Barth,
3.3 % on fusa, 5.6 % on the LAStools house, all of format 1), so a
``.pcz`` stores the records of formats 0 and 1 as format 6, and 2 and 3 as
format 7 (the same with RGB), and turns them back when it reads them.

Every field of the old format has a place in the new one that holds it
whole (byte offsets of the LAS 1.4 R15 tables):

======================  ==================  ====================
field                   formats 0-3         formats 6, 7
======================  ==================  ====================
X, Y, Z, intensity      0-13                0-13
return number           14, bits 0-2        14, bits 0-3
number of returns       14, bits 3-5        14, bits 4-7
scan direction, edge    14, bits 6-7        15, bits 6-7
classification          15, bits 0-4        16
synthetic, key, withheld  15, bits 5-7      15, bits 0-2
scan angle rank (int8)  16                  18-19 (int16, the same integer)
user data               17                  17
point source id         18-19               20-21
GPS time                20-27 (1, 3)        22-29 (zero for 0, 2)
red, green, blue        20-25 (2), 28-33 (3)  30-35
extra bytes             the rest            the rest
======================  ==================  ====================

The fields formats 6 and 7 have and 0-3 do not (overlap, scanner channel,
the fourth bit of the return numbers, classes above 31) are zero; a record
where they are not cannot come from this mapping and is refused.

>>> rows = np.zeros((1, 28), np.uint8)
>>> rows[0, 14], rows[0, 15], rows[0, 16] = 2 | 3 << 3 | 1 << 7, 6 | 1 << 5, 0xF6  # returns 2 of 3, edge; class 6, synthetic; -10 degrees
>>> lay = to_layered(rows, 1)
>>> lay.shape, int(lay[0, 14]), int(lay[0, 15]), int(lay[0, 16]), int(lay[0, 18:20].view("<i2")[0])
((1, 30), 50, 129, 6, -10)
>>> bool((from_layered(lay, 1) == rows).all())
True
"""

from __future__ import annotations

import laspy
import numpy as np

__all__ = ["LAYERED", "layered_format", "layered_size", "to_layered", "from_layered"]

#: The format a record of each of formats 0-3 is stored in.
LAYERED = {0: 6, 1: 6, 2: 7, 3: 7}

_BASE = {0: 20, 1: 28, 2: 26, 3: 34}  # bytes of the standard fields
_GPS = {1: 20, 3: 20}  # where GPS time starts
_RGB = {2: 20, 3: 28}  # where red, green, blue start
_LAYERED_BASE = {6: 30, 7: 36}


def layered_format(point_format: laspy.PointFormat) -> laspy.PointFormat | None:
    """The layered twin of ``point_format`` (format 6 or 7 with the same extra dimensions), or None if it has none."""
    twin = LAYERED.get(point_format.id)
    if twin is None:
        return None
    out = laspy.PointFormat(twin)
    out.dimensions.extend(d for d in point_format.dimensions if not d.is_standard)
    return out


def layered_size(point_format_id: int, record_size: int) -> int | None:
    """Bytes of the layered twin of a record of ``record_size`` bytes in format ``point_format_id``; None if it has none.

    >>> layered_size(1, 28), layered_size(3, 40), layered_size(6, 30)
    (30, 42, None)
    """
    twin = LAYERED.get(point_format_id)
    return None if twin is None else record_size - _BASE[point_format_id] + _LAYERED_BASE[twin]


def _rows(records: np.ndarray, size: int, what: str) -> np.ndarray:
    rows = np.ascontiguousarray(records, dtype=np.uint8)
    if rows.ndim != 2 or rows.shape[1] < size:
        raise ValueError(f"{what}: records of {rows.shape[1:] or 'no'} bytes, at least {size} expected")
    return rows


def to_layered(records: np.ndarray, point_format_id: int) -> np.ndarray:
    """(R, L) uint8 records of format 0-3 (extra bytes last) as (R, L + 10 or + 2) records of :func:`layered_format`."""
    pid = int(point_format_id)
    base = _BASE[pid]
    rows = _rows(records, base, f"point format {pid}")
    extra = rows.shape[1] - base
    twin = LAYERED[pid]
    out = np.zeros((rows.shape[0], _LAYERED_BASE[twin] + extra), dtype=np.uint8)
    out[:, :14] = rows[:, :14]
    flags, cls = rows[:, 14], rows[:, 15]
    out[:, 14] = (flags & 0x07) | ((flags >> 3) & 0x07) << 4
    out[:, 15] = (cls >> 5) | (flags & 0xC0)
    out[:, 16] = cls & 0x1F
    out[:, 17] = rows[:, 17]
    out[:, 18:20] = rows[:, 16].view(np.int8).astype("<i2")[:, None].view(np.uint8)
    out[:, 20:22] = rows[:, 18:20]
    if pid in _GPS:
        out[:, 22:30] = rows[:, _GPS[pid] : _GPS[pid] + 8]
    if pid in _RGB:
        out[:, 30:36] = rows[:, _RGB[pid] : _RGB[pid] + 6]
    out[:, _LAYERED_BASE[twin] :] = rows[:, base:]
    return out


def from_layered(records: np.ndarray, point_format_id: int) -> np.ndarray:
    """The records of format ``point_format_id`` (0-3) that :func:`to_layered` turned into ``records``.

    A ValueError if a record holds what no record of that format has
    (overlap, scanner channel, a return number above 7, a class above 31, a
    scan angle beyond int8, GPS time or RGB the format lacks).
    """
    pid = int(point_format_id)
    twin = LAYERED[pid]
    rows = _rows(records, _LAYERED_BASE[twin], f"point format {twin}")
    base, extra = _BASE[pid], rows.shape[1] - _LAYERED_BASE[twin]
    angle = rows[:, 18:20].copy().view("<i2")[:, 0]
    bad = ((rows[:, 14] & 0x88) != 0) | ((rows[:, 15] & 0x38) != 0) | (rows[:, 16] > 0x1F) | (angle < -128) | (angle > 127)
    if pid not in _GPS:
        bad |= rows[:, 22:30].any(axis=1)
    if bad.any():
        raise ValueError(f"record {int(np.argmax(bad))} holds fields point format {pid} does not have")
    out = np.zeros((rows.shape[0], base + extra), dtype=np.uint8)
    out[:, :14] = rows[:, :14]
    ret, flags = rows[:, 14], rows[:, 15]
    out[:, 14] = (ret & 0x07) | (ret >> 4) << 3 | (flags & 0xC0)
    out[:, 15] = rows[:, 16] | (flags & 0x07) << 5
    out[:, 16] = angle.astype(np.int8).view(np.uint8)
    out[:, 17] = rows[:, 17]
    out[:, 18:20] = rows[:, 20:22]
    if pid in _GPS:
        out[:, _GPS[pid] : _GPS[pid] + 8] = rows[:, 22:30]
    if pid in _RGB:
        out[:, _RGB[pid] : _RGB[pid] + 6] = rows[:, 30:36]
    out[:, base:] = rows[:, _LAYERED_BASE[twin] :]
    return out
