"""Points kept one by one in a ``.pcz``: positions on a coarser grid within the error budget, dimensions dropped.

A LAS file's coordinates are integers ``X`` on a grid of step ``scale``
(``x = X * scale + offset``).  Within a budget ``e`` (metres, Euclidean),
each integer is rounded to a multiple of ``k = floor(2 e / (sqrt(3) scale))``
(at least 1: then it is exact), so every coordinate moves by at most
``k scale / 2 <= e / sqrt(3)`` and every point by at most ``e``.  The
multiples are stored as ``X // k`` (LAZ codes the smaller integers in
fewer bits) and come back as integers of the input's grid: nothing is
rounded twice.

Dropping a dimension writes zeros in its place (LAZ codes a constant in
next to no bits); a decompressed file has the dimension, all zero.

>>> coarse_steps(0.05, [0.01, 0.01, 0.001])
(5, 5, 57)
>>> X = np.array([-7, -3, 0, 2, 3, 12])
>>> coarsen(X, 5), refine(coarsen(X, 5), 5)
(array([-1, -1,  0,  0,  1,  2]), array([-5, -5,  0,  0,  5, 10]))
"""

from __future__ import annotations

import math

import laspy
import numpy as np

from patchcloud.core import PatchcloudValueError

__all__ = ["PDAL_NAMES", "coarse_steps", "coarsen", "refine", "coarse_records", "dropped_fields", "check_drop", "zero_fields",
           "keep_only"]

#: laspy's field names and the PDAL dimension names users know them by (``--drop`` takes either, any case).
PDAL_NAMES = {
    "intensity": "Intensity", "return_number": "ReturnNumber", "number_of_returns": "NumberOfReturns",
    "scan_direction_flag": "ScanDirectionFlag", "edge_of_flight_line": "EdgeOfFlightLine", "classification": "Classification",
    "synthetic": "Synthetic", "key_point": "KeyPoint", "withheld": "Withheld", "overlap": "Overlap",
    "scanner_channel": "ScanChannel", "scan_angle_rank": "ScanAngleRank", "scan_angle": "ScanAngleRank", "user_data": "UserData",
    "point_source_id": "PointSourceId", "gps_time": "GpsTime", "red": "Red", "green": "Green", "blue": "Blue", "nir": "Infrared",
}
_XYZ = ("X", "Y", "Z")


def coarse_steps(max_error: float, scales) -> tuple[int, int, int]:
    """Per axis, the multiple ``k`` of the file's integers that keeps every point within ``max_error`` (Euclidean).

    ``k = floor(2 max_error / (sqrt(3) scale))``, at least 1 (exact).
    """
    out = []
    for s in np.asarray(scales, dtype=np.float64).reshape(3):
        k = math.floor(2.0 * max_error / (math.sqrt(3.0) * float(s)) * (1.0 - 1e-12))
        out.append(int(min(max(k, 1), 1 << 30)))
    return tuple(out)


def coarsen(X: np.ndarray, k: int) -> np.ndarray:
    """The integers ``X`` (any integer array) as multiples of ``k``: ``round(X / k)``, halves up; int64."""
    X = np.asarray(X, dtype=np.int64)
    return X if k == 1 else (X + k // 2) // k


def refine(Xq: np.ndarray, k: int) -> np.ndarray:
    """The integers of the file's grid that :func:`coarsen`'s ``Xq`` stand for (int64), within LAS's 32-bit range.

    A point within ``k / 2`` steps of the range's end rounds to a multiple
    of ``k`` beyond it: it comes back at the end, nearer to where it was.

    >>> refine(coarsen(np.array([2**31 - 1, -(2**31), 1000]), 57), 57).tolist()
    [2147483647, -2147483648, 1026]
    """
    return np.clip(np.asarray(Xq, dtype=np.int64) * k, -(2**31), 2**31 - 1)


def dropped_fields(point_format: laspy.PointFormat, names, where: str = "") -> tuple[str, ...]:
    """laspy's field names of the dimensions ``names`` name (PDAL's or laspy's names, any case; extra bytes by name).

    An unknown name, or X, Y or Z, is a PatchcloudValueError listing the
    dimensions the point format has.

    >>> dropped_fields(laspy.PointFormat(1), ["GpsTime", "user_data"])
    ('gps_time', 'user_data')
    """
    have = [d for d in point_format.dimension_names if d not in _XYZ]
    by = {}
    for d in have:
        by[d.lower()] = d
        if d in PDAL_NAMES:
            by[PDAL_NAMES[d].lower()] = d
    out = []
    for n in names:
        d = by.get(str(n).lower())
        if d is None:
            valid = ", ".join(PDAL_NAMES.get(d, d) for d in have)
            raise PatchcloudValueError(f"{where + ': ' if where else ''}cannot drop {n!r}: point format {point_format.id} has "
                                       f"{valid} (X, Y and Z are never dropped)")
        if d not in out:
            out.append(d)
    return tuple(out)


def zero_fields(points: laspy.PackedPointRecord, fields) -> None:
    """Set the stored values of the dimensions ``fields`` (laspy names) of ``points`` to zero, in place.

    A scaled extra-bytes dimension gets a stored 0 (its value is then its
    offset), as model mode's records have it: a scaled 0 may not fit its type
    (a uint8 of offset 100 and scale 0.5 cannot hold it).
    """
    for f in fields:
        if f in points.array.dtype.names:  # a whole field of the record: its bytes
            points.array[f] = 0
        else:  # a bit field (return_number, the flags, ...): its bits
            points[f] = np.zeros_like(np.asarray(points[f]))


def check_drop(catalog, names) -> None:
    """``--drop``'s ``names`` against every file of ``catalog`` (a :class:`~.catalog.Catalog`): an unknown name is
    refused before anything runs (:func:`dropped_fields`' error; no store is left behind for a typo)."""
    if not names:
        return
    for src in catalog.sources:
        with laspy.open(src.path) as r:
            dropped_fields(r.header.point_format, names, where=src.path)


def keep_only(point_format: laspy.PointFormat, kept) -> tuple[str, ...]:
    """The fields of ``point_format`` other than X, Y, Z and ``kept`` (those dropped when only ``kept`` are kept).

    >>> keep_only(laspy.PointFormat(0), ["intensity", "classification"])[:3]
    ('return_number', 'number_of_returns', 'scan_direction_flag')
    """
    return tuple(d for d in point_format.dimension_names if d not in _XYZ and d not in kept)


def coarse_records(records: np.ndarray, pf: laspy.PointFormat, steps, dropped) -> np.ndarray:
    """(R, L) uint8 records of ``pf`` (``records``: rows of bytes, or laspy's structured array) with X, Y, Z divided by
    ``steps`` (:func:`coarsen`) and the ``dropped`` dimensions zero: what a ``.pcz`` keeps of a point (points mode, and
    model mode's residual points)."""
    rec = laspy.PackedPointRecord(np.ascontiguousarray(records).view(pf.dtype()).reshape(-1).copy(), pf)
    zero_fields(rec, dropped)
    for name, k in zip("XYZ", steps):
        if k != 1:
            rec[name] = coarsen(rec[name], k).astype(np.int32)
    return rec.array.view(np.uint8).reshape(len(rec), pf.size)
