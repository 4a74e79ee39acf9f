"""What a model-mode ``.pcz`` keeps of a residual point (version 5): its position within the budget, its class, its
intensity on 64 levels, one return; and the intensity levels of a tile.

A *residual* point is one no patch fits within the budget (vegetation,
wires, edges, noise).  Model mode is a model: its sampled points carry
their cell's majority class and mean intensity and are single returns.
Its residual points are summarised the same way, point by point:

- X, Y, Z rounded to multiples ``k`` of the input's integers
  (:mod:`.point_coding`): every point within the budget;
- classification exact (LAZ codes it in about a bit a point);
- intensity on ``2**INTENSITY_BITS`` levels: ``round(I / 2**s)``, with
  ``s`` per tile the smallest shift that brings the 99th percentile of
  the tile's intensities below ``2**INTENSITY_BITS``
  (:func:`intensity_shift`), so every intensity comes back within
  ``2**(s - 1)``, at most 1/64 of that percentile (32 to 64 levels lie
  below it); the mean intensities of the
  tile's cells are stored the same way;
- one return (return 1 of 1, as the sampled points); every other
  dimension zero (and those ``--drop`` names).

A tile's residual points are one block: a LAZ file
(:func:`~.laz_block.records_laz`) in input order (scan lines), in the
Morton order of their coded positions or column by column
(:func:`column_order`), or an octree (:mod:`.residual_octree`), whichever
is smallest: nothing reads them in an order.

Measured at 5 cm on real aerial files, bits per point of the whole
``.pcz``, version 4 (exact records in input order) -> 5: St-Barth 15.9
-> 10.6, LAStools house 20.4 -> 13.7, IGN tile 77055 19.7 -> 14.6, fusa
11.5 -> 10.3 (``tools/bench_compress.py``); per residual point, each
choice (``tools/bench_residual_codec.py``): the intensity on 64 levels
costs 3.5-5 bits where version 4's exact one and its returns cost 3-15
more; the octree is the smallest block on every one of those files.

>>> I = np.array([0, 100, 1000, 30000, 65535])
>>> s = intensity_shift(I)
>>> s, coarse_intensity(I, s), fine_intensity(coarse_intensity(I, s), s)
(9, array([  0,   0,   2,  59, 128], dtype=uint16), array([    0,     0,  1024, 30208, 65535], dtype=uint16))
"""

from __future__ import annotations

import laspy
import numpy as np

from patchcloud.core import MAX_DEPTH, encode

from .laz_block import records_laz
from .residual_octree import OctreePoints, encode as octree_encode, records_of as octree_records
from .point_coding import coarse_records, keep_only, refine

__all__ = ["KEPT", "RETURNS", "residual_dropped", "kept_words", "INTENSITY_BITS", "CODING", "intensity_shift", "coarse_intensity", "fine_intensity", "stored_records", "decoded_records",
           "residual_block", "octree_block", "morton_order", "column_order", "COLUMN_STEPS"]

#: What a residual point keeps besides its position (its returns as return 1 of 1); every other dimension is zero.
KEPT = ("intensity", "return_number", "number_of_returns", "classification", "withheld")
#: The two return fields: one dropped drops both (return 1 of 0 is no point).
RETURNS = ("return_number", "number_of_returns")
#: Levels of a residual point's intensity, in bits: 64 levels below a tile's 99th percentile.
INTENSITY_BITS = 6
#: How residual points are coded (a compress run's parameters hold it: a store's tiles coded otherwise are redone).
CODING = {"version": 5, "intensity_bits": INTENSITY_BITS, "returns": "single", "blocks": "LAZ (input, Morton, columns) or octree",
          "flags": "withheld"}
#: The width of :func:`column_order`'s columns, in coded steps (2 m at a 5 cm budget on a 1 cm grid): of 16, 32, 64 and
#: 128, the best on the aerial files of ../shared/data but fusa (whose scan lines are better in input order).
COLUMN_STEPS = 32


def residual_dropped(pf: laspy.PointFormat, drop=()) -> tuple[str, ...]:
    """The dimensions of ``pf`` residual points keep as zeros: every one but :data:`KEPT`, then ``drop`` (laspy's names,
    as ``--drop`` gives them); if either return field is dropped, both are.

    >>> residual_dropped(laspy.PointFormat(1), ["number_of_returns"])[-3:]
    ('gps_time', 'number_of_returns', 'return_number')
    """
    out = list(dict.fromkeys(keep_only(pf, KEPT) + tuple(drop)))
    if any(r in out for r in RETURNS):
        out += [r for r in RETURNS if r not in out]
    return tuple(out)


def kept_words(dropped, shifts: tuple[int, int] | None = None) -> str:
    """What residual points keep of their attributes, in words (the compress summary's and ``info``'s): ``dropped`` as
    :func:`residual_dropped` gives it; ``shifts``: the smallest and largest intensity shift of a file, said if given.

    >>> kept_words(["gps_time"]), kept_words(["intensity", "return_number", "number_of_returns", "withheld"], (0, 3))
    ('class exact, withheld flag, intensity on 64 levels, return 1 of 1', 'class exact')
    >>> kept_words([], (2, 5))
    'class exact, withheld flag, intensity on 64 levels (divided by 2**2 to 2**5, rounded), return 1 of 1'
    """
    levels = f"intensity on {2**INTENSITY_BITS} levels"
    if shifts is not None:
        lo, hi = shifts
        levels += f" (divided by 2**{lo}{'' if lo == hi else f' to 2**{hi}'}, rounded)"
    kept = [what for name, what in (("classification", "class exact"), ("withheld", "withheld flag"), ("intensity", levels),
                                    ("return_number", "return 1 of 1")) if name not in dropped]
    return ", ".join(kept) or "no attribute"


def intensity_shift(intensity: np.ndarray) -> int:
    """The shift ``s`` that puts the 99th percentile of ``intensity`` (any integers) below ``2**INTENSITY_BITS``; 0 for none.

    The percentile is the sorted value at ``floor(0.99 (n - 1))`` (no interpolation: integers in, an integer out).
    """
    I = np.sort(np.asarray(intensity, dtype=np.int64).ravel())
    if not I.size:
        return 0
    p99 = int(I[(99 * (I.size - 1)) // 100])
    return max(0, p99.bit_length() - INTENSITY_BITS)


def coarse_intensity(intensity: np.ndarray, shift: int) -> np.ndarray:
    """``round(I / 2**shift)`` (halves up) of intensities ``I`` in 0..65535: uint16 (at most ``2**(16 - shift)``)."""
    I = np.asarray(intensity, dtype=np.int64)
    half = (1 << shift) >> 1
    return ((I + half) >> shift).astype(np.uint16)


def fine_intensity(coded: np.ndarray, shift: int) -> np.ndarray:
    """The intensities :func:`coarse_intensity`'s values stand for: ``q * 2**shift`` (at most 65535), uint16."""
    q = np.asarray(coded, dtype=np.int64)
    return np.minimum(q << shift, 65535).astype(np.uint16)


def stored_records(records: np.ndarray, pf: laspy.PointFormat, steps, dropped, shift: int | None = None) -> tuple[np.ndarray, int]:
    """Residual points' records as a version-5 ``.pcz`` stores them, and the intensity shift.

    Parameters
    ----------
    records : (R, L) uint8
        The points' records in ``pf``'s layout (rows of bytes, or laspy's structured array).
    steps : 3 ints
        X, Y, Z are stored divided by these (:func:`~.point_coding.coarse_records`).
    dropped : sequence of str
        Dimensions stored as zeros (every one but intensity, returns, classification and the withheld flag, and those ``--drop`` names).
    shift : int, optional
        The intensity shift; by default :func:`intensity_shift` of these points'.

    Returns
    -------
    rows : (R, L) uint8
        X, Y, Z divided by ``steps``, intensity by ``2**shift`` (rounded), return 1 of 1, ``dropped`` zero.
    shift : int
    """
    rows = coarse_records(records, pf, steps, dropped)
    rec = laspy.PackedPointRecord(rows.view(pf.dtype()).reshape(-1), pf)
    shift = intensity_shift(rec["intensity"]) if shift is None else int(shift)
    rec["intensity"] = coarse_intensity(rec["intensity"], shift)
    one = np.ones(len(rec), np.uint8)
    for name in ("return_number", "number_of_returns"):
        if name not in dropped:
            rec[name] = one
    return rec.array.view(np.uint8).reshape(len(rec), pf.size), shift


def decoded_records(records: np.ndarray, pf: laspy.PointFormat, steps, dropped, shift: int) -> np.ndarray:
    """(R, L) uint8: what a reader of a version-5 ``.pcz`` gives back for residual points of these ``records``
    (:func:`stored_records` with ``shift``): X, Y, Z on the input's grid, within the budget; the intensity within
    ``2**(shift - 1)``; the classification; return 1 of 1; every other byte zero."""
    rows, _ = stored_records(records, pf, steps, dropped, shift)
    rec = laspy.PackedPointRecord(rows.view(pf.dtype()).reshape(-1), pf)
    for name, k in zip("XYZ", steps):
        rec[name] = refine(rec[name], int(k)).astype(np.int32)
    rec["intensity"] = fine_intensity(rec["intensity"], shift)
    return rec.array.view(np.uint8).reshape(len(rec), pf.size)


def residual_block(records: np.ndarray, pf: laspy.PointFormat, version: str, steps, dropped, scales, offsets, shift: int,
                   parallel: bool = False) -> bytes:
    """A tile's residual points as one block (bytes): a LAZ file or an octree, whichever is smallest.

    ``records`` ((R, L) uint8, in input order), ``steps``, ``dropped`` and
    ``shift`` (the tile's intensity shift) as :func:`stored_records` takes
    them; ``version``: the input's LAS version;
    ``scales``, ``offsets``: the input's (the LAZ file's scales are ``scales
    * steps``).  The candidates: LAZ in input order, :func:`morton_order` or
    :func:`column_order`, and :func:`octree_block` (the first of these on a tie); no bytes for no point.
    """
    if not len(records):
        return b""  # no residual point: no block (a reader reads none)
    rows, _ = stored_records(records, pf, steps, dropped, shift)
    blocks = [records_laz(r, pf, version, np.asarray(scales) * np.asarray(steps), offsets, parallel=parallel)
              for r in (rows, rows[morton_order(rows)], rows[column_order(rows)])]
    octree = octree_block(rows, pf, "return_number" not in dropped)
    if octree is not None:
        blocks.append(octree)
    return min(blocks, key=len)


def octree_block(rows: np.ndarray, pf: laspy.PointFormat, single_return: bool) -> bytes | None:
    """Stored records ``rows`` ((R, L) uint8, :func:`stored_records`) as a :mod:`.residual_octree` block; None where
    that block would not give them back byte for byte (a dimension not zero that it does not hold, a wide span)."""
    rec = laspy.PackedPointRecord(np.ascontiguousarray(rows).view(pf.dtype()).reshape(-1), pf)
    xyz = np.column_stack([np.asarray(rec[a], dtype=np.int64) for a in "XYZ"])
    cls, inten = np.asarray(rec["classification"]), np.asarray(rec["intensity"], dtype=np.int64)
    block = octree_encode(xyz, cls, inten, single_return)
    if block is None:
        return None
    same = octree_records(OctreePoints(xyz, cls.astype(np.uint8), inten, single_return), pf.id, pf.size)
    return block if np.array_equal(same, rows) else None


def column_order(rows: np.ndarray) -> np.ndarray:
    """The order of records ``rows`` ((R, L) uint8) column by column: by X // COLUMN_STEPS, then Y // COLUMN_STEPS,
    then Z (ties in input order): vegetation and walls as vertical runs.

    >>> xyz = np.array([[40, 0, 5], [0, 0, 9], [1, 0, 2], [0, 40, 1]], dtype="<i4")
    >>> column_order(np.hstack([xyz.view(np.uint8).reshape(4, 12), np.zeros((4, 2), np.uint8)])).tolist()
    [2, 1, 3, 0]
    """
    xyz = _positions(rows)
    return np.lexsort((xyz[:, 2], xyz[:, 1] // COLUMN_STEPS, xyz[:, 0] // COLUMN_STEPS))


def morton_order(rows: np.ndarray) -> np.ndarray:
    """The order of records ``rows`` ((R, L) uint8) by the Morton key of their X, Y, Z (ties in input order).

    Positions are taken from their smallest; a span wider than the key's 21 bits an axis loses its low bits.
    """
    xyz = _positions(rows)
    if not len(xyz):
        return np.zeros(0, np.int64)
    rel = xyz - xyz.min(axis=0)
    drop = max(0, int(rel.max()).bit_length() - MAX_DEPTH)
    return np.argsort(encode(rel >> drop), kind="stable")


def _positions(rows: np.ndarray) -> np.ndarray:
    """X, Y, Z of records ``rows`` ((R, L) uint8: their first 12 bytes), (R, 3) int64."""
    return rows[:, :12].copy().view("<i4").reshape(-1, 3).astype(np.int64)
