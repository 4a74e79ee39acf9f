"""Point records as a LAZ file in memory: the blocks a ``.pcz`` keeps points in (points mode, model mode's residual points).

>>> import laspy
>>> pf = laspy.PointFormat(6)
>>> rows = np.zeros((3, pf.size), np.uint8)
>>> raw = records_laz(rows, pf, "1.4", [0.01] * 3, [0.0] * 3)
>>> raw[:4], laspy.read(io.BytesIO(raw)).header.point_count
(b'LASF', 3)
"""

from __future__ import annotations

import io

import laspy
import numpy as np

from .las import laz_backend, undescribed_last, wave_packets_break_laz, writable_version
from .layered import layered_format, to_layered

__all__ = ["records_laz"]


def records_laz(records: np.ndarray, point_format: laspy.PointFormat, version: str, scales, offsets, parallel: bool = False) -> bytes:
    """A LAZ file (bytes) of whole point records ((R, L) uint8 rows in ``point_format``'s layout); LAS where LAZ would
    not give them back (:func:`~patchcloud.stream.io.las.wave_packets_break_laz`).

    Records of formats 0-3 are stored as their layered twins, 6 or 7
    (:mod:`~patchcloud.stream.io.layered`); reading turns them back.
    ``parallel``: compress with lazrs' multi-threaded coder (for tasks
    run inline, in the client's process; the same bytes as the sequential one).
    """
    twin = layered_format(point_format)
    if twin is not None:  # formats 0-3 as 6 or 7: LAZ's layered compressor takes fewer bytes
        records, point_format, version = to_layered(records, point_format.id), twin, "1.4"
    h = laspy.LasHeader(point_format=point_format, version=writable_version(version))
    h.scales, h.offsets = np.asarray(scales, dtype=np.float64), np.asarray(offsets, dtype=np.float64)
    las = laspy.LasData(h)
    rows = np.ascontiguousarray(records, dtype=np.uint8).reshape(-1, point_format.size).view(point_format.dtype()).reshape(-1)
    las.points = laspy.PackedPointRecord(rows, point_format)
    undescribed_last(las.header)  # undescribed bytes stay so: laspy cannot read back its own description of them
    buf = io.BytesIO()
    las.write(buf, do_compress=not wave_packets_break_laz(las.points), laz_backend=laz_backend(parallel))
    return buf.getvalue()
