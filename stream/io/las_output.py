"""A LAS/LAZ file written in parts by independent tasks, byte for byte what laspy writes in one go.

The output's point records are cut into parts of consecutive points (the
export's parts, each a multiple of :data:`LAZ_CHUNK` points but the last).
Every part is written by its own task, in any order, on any worker:

- **LAS**: the client sizes the file (:func:`begin`); a task writes its
  records at their place (:func:`write_las_part`);
- **LAZ**: a task compresses its records into whole LAZ chunks (LAZ chunks
  are independent; lazrs compresses them) and writes them to a fragment
  file beside the output (:func:`write_laz_part`); the client then
  concatenates the fragments and writes the one chunk table
  (:func:`finish`), a copy of compressed bytes.  Where the input is a
  layered LAZ whose records the output keeps as they are, with new extra
  bytes after them (:func:`layered_source`), a task copies the input's
  compressed chunks and codes only the new bytes
  (:func:`write_laz_part_layered`, :mod:`.laz_layers`): the same bytes,
  without decoding and coding the input's fields again.

Each task also returns its records' :class:`PointStats` (bounds, counts by
return, GPS time and extra-bytes ranges), which :func:`finish` merges into
the header as laspy's ``LasHeader.grow`` would have, so the file does not
depend on the number of parts or on which worker wrote which.
"""

from __future__ import annotations

import ctypes
import io
import os
import shutil
import struct
from collections.abc import Iterable
from copy import deepcopy
from dataclasses import dataclass
from pathlib import Path

import laspy
import lazrs
import numpy as np
from laspy.vlrs.known import LasZipVlr

from patchcloud.core import PatchcloudIOError

from . import laz_layers
from .write_errors import naming_failed_writes
from .las import UNDESCRIBED_NAME, chunk_table, laz_point_range

__all__ = ["LAZ_CHUNK", "PointStats", "with_new_dims", "extra_bytes_structs", "LayeredSource", "layered_source", "LAYERED_SELECTION", "write_laz_part_layered", "copy_records", "prepare_header", "reset_statistics", "is_waveform_record", "point_stats", "begin", "write_las_part", "write_laz_part", "stitch", "finish",
           "fragments_dir", "remove_partial", "legacy_counts", "LEGACY_COUNT_AT", "keep_creation_date", "CREATION_AT", "rewrite_header", "restate"]

#: Points per LAZ chunk of the files patchcloud writes (lazrs' default); parts are multiples of it.
LAZ_CHUNK = 50_000


@dataclass(frozen=True)
class PointStats:
    """What the header records about some points: bounds (scaled), GPS time range, counts, extra-bytes ranges."""

    mins: np.ndarray  # (3,) float64
    maxs: np.ndarray  # (3,) float64
    gps: tuple[float, float]
    by_return: np.ndarray  # (15,) uint64
    count: int
    eb_min: tuple[bytes, ...]  # raw min/max of each extra-bytes struct, as laspy keeps them
    eb_max: tuple[bytes, ...]

    def to_json(self) -> dict:
        """A JSON-able dict that :meth:`from_json` turns back into these statistics, bit for bit."""
        return dict(mins=[float(v) for v in self.mins], maxs=[float(v) for v in self.maxs], gps=[float(v) for v in self.gps],
                    by_return=[int(v) for v in self.by_return], count=int(self.count), eb_min=[b.hex() for b in self.eb_min],
                    eb_max=[b.hex() for b in self.eb_max])

    @classmethod
    def from_json(cls, d: dict) -> "PointStats":
        return cls(mins=np.asarray(d["mins"], dtype=np.float64), maxs=np.asarray(d["maxs"], dtype=np.float64), gps=tuple(d["gps"]),
                   by_return=np.asarray(d["by_return"], dtype=np.uint64), count=int(d["count"]),
                   eb_min=tuple(bytes.fromhex(v) for v in d["eb_min"]), eb_max=tuple(bytes.fromhex(v) for v in d["eb_max"]))


def reset_statistics(h: laspy.LasHeader) -> None:
    """laspy's ``h.partial_reset()`` (bounds, counts, extra-bytes ranges), leaving entries of undocumented extra bytes
    (data type 0) as they are: their options field is their byte count, not flags, and laspy would write a range
    into their min and max (as its writer does: :func:`restate` puts them back)."""
    kept = undocumented_entries(h)
    h.partial_reset()
    put_undocumented_entries(h, kept)


def undocumented_entries(h: laspy.LasHeader) -> list[tuple[int, bytes, bytes]]:
    """(position, min bytes, max bytes) of each entry of undocumented extra bytes (data type 0) of ``h``'s ExtraBytes VLR."""
    return [(i, bytes(st._min), bytes(st._max)) for i, st in enumerate(extra_bytes_structs(h)) if st.data_type == 0]


def put_undocumented_entries(h: laspy.LasHeader, kept: list[tuple[int, bytes, bytes]]) -> None:
    """Put back the min and max bytes :func:`undocumented_entries` took, in place."""
    structs = extra_bytes_structs(h)
    for i, lo, hi in kept:
        ctypes.memmove(ctypes.addressof(structs[i]._min), lo, len(lo))
        ctypes.memmove(ctypes.addressof(structs[i]._max), hi, len(hi))


def prepare_header(header: laspy.LasHeader, compressed: bool) -> laspy.LasHeader:
    """The header as laspy's writer makes it before the first point (statistics reset, LAZ VLR added when ``compressed``)."""
    h = deepcopy(header)
    try:
        h.vlrs.pop(h.vlrs.index("LasZipVlr"))
    except ValueError:
        pass
    reset_statistics(h)
    h.are_points_compressed = compressed
    if compressed:
        pf = h.point_format
        h.vlrs.append(LasZipVlr(lazrs.LazVlr.new_for_compression(pf.id, pf.num_extra_bytes).record_data()))
    return h


def copy_records(records: np.ndarray, out: np.ndarray) -> None:
    """Copy the input ``records`` into the output records ``out`` (structured arrays of one length), field by field.

    The fields at the same byte offsets in both (all but the input's
    undescribed bytes, which :func:`~patchcloud.stream.io.las.undescribed_last`
    moves to the end) are copied as one block of bytes; the others by name.
    """
    n, a, b = len(records), records.dtype, out.dtype
    moved = [a.fields[name][1] for name in a.names if name not in b.fields or b.fields[name][1] != a.fields[name][1]]
    prefix = min(moved, default=a.itemsize)
    out.view(np.uint8).reshape(n, b.itemsize)[:, :prefix] = records.view(np.uint8).reshape(n, a.itemsize)[:, :prefix]
    for name in a.names:
        if a.fields[name][1] >= prefix:
            out[name] = records[name]


def extra_bytes_structs(h: laspy.LasHeader) -> list:
    """The extra-bytes descriptors of ``h``'s ExtraBytes VLR, in order ([] without one)."""
    vlrs = h.vlrs.get("ExtraBytesVlr")
    return list(vlrs[0].extra_bytes_structs) if vlrs else []


def _eb_range(st, points: laspy.PackedPointRecord | None, columns: dict, n: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Stored (unscaled) min and max of one extra-bytes dimension over ``points``, no-data and NaN values left out.

    laspy's own ``grow`` takes each call's first value for the whole call,
    so its ranges depend on how the points were cut: these are the true ones.
    ``columns``: contiguous copies of some dimensions' stored values, read
    instead of the records' strided field (``points`` None: the dimension
    is one of them, ``n`` the number of points).
    """
    t, k = np.dtype(st._long_type()), st.num_elements()
    info = np.finfo(t) if t.kind == "f" else np.iinfo(t)
    lo, hi = np.full(k, info.max, dtype=t), np.full(k, info.min, dtype=t)
    n = len(points) if points is not None else int(n)
    if st.data_type == 0 or n == 0:
        return lo, hi
    name = st.format_name()
    v = np.asarray(columns[name] if name in columns else points.array[name]).reshape(n, k)
    for i in range(k):
        col = np.ascontiguousarray(v[:, i])  # a record's field is strided: one pass to copy it, then the passes below
        lo[i], hi[i] = _valid_range(col, None if st.no_data is None else st.no_data[i], lo[i], hi[i])
    return lo, hi


def _described_later(structs, points: laspy.PackedPointRecord, columns: dict) -> dict:
    """``columns`` with the values of the descriptors that name no field of ``points``: those of an input's second
    ExtraBytes VLR (:func:`~.las.assemble_header`), whose bytes laspy reads as the record's last, undescribed field,
    in order from its start."""
    names = points.array.dtype.names or ()
    if UNDESCRIBED_NAME not in names or not len(points):
        return columns
    later = [st for st in structs if st.data_type != 0 and st.format_name() not in names and st.format_name() not in columns]
    if not any(st.min_is_relevant() or st.max_is_relevant() for st in later):
        return columns
    raw = np.ascontiguousarray(points.array[UNDESCRIBED_NAME]).view(np.uint8).reshape(len(points), -1)
    out, at = dict(columns), 0
    for st in structs:
        name = st.format_name()
        if st.data_type == 0 or name in names or name in columns:
            continue
        size = st.dtype().itemsize
        if st.min_is_relevant() or st.max_is_relevant():  # else its range is not written: its bytes are not read (a
            out[name] = np.ascontiguousarray(raw[:, at : at + size]).view(st.dtype().base)  # layered LAZ decodes them)
        at += size
    return out


def _valid_range(col: np.ndarray, no_data, lo, hi):
    """(min, max) of ``col`` without ``no_data`` and NaN values; (``lo``, ``hi``) where none is left.

    Where every value counts (no no-data value among them, no NaN) the two
    reductions run on the column itself, with no mask and no copy: the same
    values as the masked ones.
    """
    skip = np.zeros(0, dtype=bool) if no_data is None else col == no_data
    if col.dtype.kind == "f":
        nan = np.isnan(col)
        skip = nan if skip.size == 0 else skip | nan
    if skip.size == 0 or not skip.any():
        return col.min(), col.max()
    valid = col[~skip]
    return (valid.min(), valid.max()) if valid.size else (lo, hi)


def _grow(h: laspy.LasHeader, points: laspy.PackedPointRecord) -> None:
    """``h.grow(points)`` without the extra bytes (``h`` has no ExtraBytes VLR): the same statistics, bit for bit.

    laspy counts the returns with ``np.unique`` (a sort of every point's
    return number); a histogram gives the same counts.  Each record field is
    copied out once (the records are strided) before its two reductions.
    """
    a = points.array
    for axis, name in enumerate("XYZ"):
        col = np.ascontiguousarray(a[name])
        scale, offset = h.scales[axis], h.offsets[axis]
        h.maxs[axis] = max(h.maxs[axis], (col.max() * scale) + offset)
        h.mins[axis] = min(h.mins[axis], (col.min() * scale) + offset)
    if "gps_time" in a.dtype.names:
        gps = np.ascontiguousarray(a["gps_time"])
        h.max_gps_time = max(h.max_gps_time, gps.max())
        h.min_gps_time = min(h.min_gps_time, gps.min())
    by_return = np.bincount(np.asarray(points.return_number, dtype=np.intp).reshape(-1), minlength=16)
    slots = len(h.number_of_points_by_return)
    for r in np.flatnonzero(by_return[1 : slots + 1]) + 1:
        h.number_of_points_by_return[r - 1] += by_return[r]
    h.point_count += len(points)


def point_stats(header: laspy.LasHeader, points: laspy.PackedPointRecord, columns: dict | None = None) -> PointStats:
    """The header statistics of ``points`` alone (``header`` from :func:`prepare_header`).

    ``columns``: optional ``{name: array}``, the stored values of some
    extra-bytes dimensions of ``points`` as they were set (same dtype, one
    row per point), so their ranges are read from these contiguous arrays.
    """
    columns = columns or {}
    structs = extra_bytes_structs(header)
    h = deepcopy(header)
    try:  # laspy's grow would set wrong extra-bytes ranges (see _eb_range): they are computed here
        h.vlrs.pop(h.vlrs.index("ExtraBytesVlr"))
    except ValueError:
        pass
    reset_statistics(h)
    if len(points):
        _grow(h, points)
    cols = _described_later(structs, points, columns)
    names = points.array.dtype.names or ()
    ranges = [_eb_range(st, points, cols) if st.data_type == 0 or st.format_name() in names or st.format_name() in cols
              else _eb_range(st, None, cols, 0) for st in structs]  # (one that declares no range: no values read)
    return PointStats(
        mins=np.asarray(h.mins, dtype=np.float64), maxs=np.asarray(h.maxs, dtype=np.float64),
        gps=(float(h.min_gps_time), float(h.max_gps_time)), by_return=np.asarray(h.number_of_points_by_return, dtype=np.uint64),
        count=int(h.point_count), eb_min=tuple(lo.tobytes() for lo, _ in ranges), eb_max=tuple(hi.tobytes() for _, hi in ranges),
    )


def with_new_dims(stats: PointStats, header: laspy.LasHeader, columns: dict, n: int) -> PointStats:
    """The statistics of records that are those ``stats`` describe (their own extra bytes' ranges first) with new
    extra-bytes dimensions appended: ``header``'s last extra-bytes descriptors, whose stored values ``columns``
    holds (name: (n,) array), give their ranges (what :func:`point_stats` of the whole records gives)."""
    structs = extra_bytes_structs(header)[len(stats.eb_min):]
    # (after them, descriptors of the input's undescribed bytes that declare no range: no values, none read)
    ranges = [_eb_range(st, None, columns, n if st.format_name() in columns else 0) for st in structs]
    return PointStats(mins=stats.mins, maxs=stats.maxs, gps=stats.gps, by_return=stats.by_return, count=stats.count,
                      eb_min=stats.eb_min + tuple(lo.tobytes() for lo, _ in ranges),
                      eb_max=stats.eb_max + tuple(hi.tobytes() for _, hi in ranges))


def _merge(header: laspy.LasHeader, parts: list[PointStats]) -> laspy.LasHeader:
    """``header`` with the statistics of all ``parts`` (what growing it by every point in turn gives)."""
    h = deepcopy(header)
    reset_statistics(h)
    mins, maxs = np.asarray(h.mins, dtype=np.float64), np.asarray(h.maxs, dtype=np.float64)
    lo, hi = h.min_gps_time, h.max_gps_time
    by_return = np.zeros(15, dtype=np.uint64)
    count = 0
    structs = extra_bytes_structs(h)
    for s in parts:
        mins, maxs = np.minimum(mins, s.mins), np.maximum(maxs, s.maxs)
        lo, hi = min(lo, s.gps[0]), max(hi, s.gps[1])
        by_return += s.by_return
        count += s.count
        for st, a, b in zip(structs, s.eb_min, s.eb_max):
            if st.data_type == 0:  # undocumented bytes: no range (their options field is their count, not flags)
                continue
            n, t = st.num_elements(), st._long_type()
            if st.min_is_relevant():
                raw = st._raw_min()
                raw[:] = np.minimum(raw, np.frombuffer(a, dtype=t)[:n])
            if st.max_is_relevant():
                raw = st._raw_max()
                raw[:] = np.maximum(raw, np.frombuffer(b, dtype=t)[:n])
    h.mins, h.maxs = mins, maxs
    h.min_gps_time, h.max_gps_time = lo, hi
    h.number_of_points_by_return = by_return[: len(h.number_of_points_by_return)]
    h.point_count = count
    if count == 0:
        h.maxs = [0.0, 0.0, 0.0]
        h.mins = [0.0, 0.0, 0.0]
    return h


def restate(written: laspy.LasHeader, stats: list[PointStats], header: laspy.LasHeader | None = None) -> laspy.LasHeader:
    """The header laspy's writer wrote (``written``, after its close) with the statistics merged from ``stats`` of
    every point written (:func:`point_stats`): what is written over it, the file's layout kept.  ``header``: the
    header given to the writer (before it reset the ranges), whose entries of undocumented extra bytes are put back."""
    h = _merge(written, stats)
    if header is not None:
        put_undocumented_entries(h, undocumented_entries(header))
    for name in ("offset_to_point_data", "start_of_first_evlr", "number_of_evlrs", "start_of_waveform_data_packet_record"):
        setattr(h, name, getattr(written, name))
    return h


def fragments_dir(tmp: str | os.PathLike) -> Path:
    """Where the LAZ parts of the file being written at ``tmp`` wait to be stitched."""
    return Path(str(tmp) + ".parts")


def begin(header: laspy.LasHeader, tmp: str | os.PathLike, point_count: int) -> int:
    """Create ``tmp`` for ``point_count`` points; return the offset of the point data.

    LAS: the file is sized for every record (tasks write into it); LAZ: an
    empty directory of fragments is made beside it, and the point data
    begins with the chunk table's offset (0 until :func:`finish`), after
    which the fragments are appended (:func:`stitch`).
    """
    buf = io.BytesIO()
    header.write_to(buf)
    start = len(buf.getvalue())
    with naming_failed_writes(tmp), open(tmp, "wb") as f:
        f.write(buf.getvalue())
        if not header.are_points_compressed:
            f.truncate(start + point_count * header.point_format.size)
        else:
            f.write(struct.pack("<q", 0))
    if header.are_points_compressed:
        d = fragments_dir(tmp)
        shutil.rmtree(d, ignore_errors=True)
        d.mkdir()
    return start


def write_las_part(tmp: str | os.PathLike, start: int, first: int, points: laspy.PackedPointRecord) -> None:
    """Write the records of points ``first, first + 1, ...`` into the LAS file ``tmp`` (its point data at ``start``)."""
    fd = os.open(tmp, os.O_WRONLY)
    try:
        data = memoryview(points.array).cast("B")
        off, done = start + first * points.array.dtype.itemsize, 0
        with naming_failed_writes(tmp):
            while done < len(data):
                done += os.pwrite(fd, data[done:], off + done)
    finally:
        os.close(fd)


def write_laz_part(tmp: str | os.PathLike, part: int, header: laspy.LasHeader, points: laspy.PackedPointRecord,
                   parallel: bool = False) -> list:
    """Compress ``points`` as whole LAZ chunks into fragment ``part`` of ``tmp``; return their chunk-table entries.

    ``parallel``: compress the chunks on lazrs' threads (for tasks that
    run inline, in the client's process, which hold the GIL for the call); the
    bytes are the same either way.
    """
    vlr = lazrs.LazVlr(header.vlrs.get("LasZipVlr")[0].record_data)
    data = bytes(lazrs.compress_points(vlr, np.frombuffer(points.array, np.uint8), bool(parallel)))
    table_at = struct.unpack("<q", data[:8])[0]
    table = lazrs.read_chunk_table(io.BytesIO(data), vlr)
    _write_fragment(tmp, part, [memoryview(data)[8:table_at]])
    return [tuple(int(v) for v in e) for e in table]


@dataclass(frozen=True)
class LayeredSource:
    """An input whose compressed chunks an output copies (:func:`layered_source`): its path, the
    :class:`~patchcloud.stream.io.laz_layers.LayeredPlan`, and its chunk table ((C, 2) int64: each chunk's byte
    offset in the file and byte count)."""

    path: str
    plan: laz_layers.LayeredPlan
    chunks: np.ndarray
    #: What a task decodes of the input's records (:data:`LAYERED_SELECTION`, with the GPS time for a LAS 1.5
    #: output, whose header records its range).
    selection: laspy.DecompressionSelection


#: What a task decodes of an input whose chunks it copies (:func:`write_laz_part_layered`): what places each point
#: in its tile (coordinates, classification and its flags), what the header counts (return numbers, the extra
#: bytes' ranges) and the scanner channel (which the new bytes' coding follows); not intensity, scan angle, user
#: data, point source, colours, nor the GPS time (a LAS 1.4 header has no GPS range).
LAYERED_SELECTION = (
    laspy.DecompressionSelection.XY_RETURNS_CHANNEL | laspy.DecompressionSelection.Z
    | laspy.DecompressionSelection.CLASSIFICATION | laspy.DecompressionSelection.FLAGS
    | laspy.DecompressionSelection.ALL_EXTRA_BYTES
)


def layered_source(path: str | os.PathLike, header: laspy.LasHeader, new_dims) -> LayeredSource | None:
    """How the LAZ output of ``header`` (from :func:`prepare_header`) can copy the compressed chunks of the input
    ``path``; None where it cannot, and the output's records are then coded whole (:func:`write_laz_part`).

    It can when the input is a layered LAZ (point formats 6, 7 and 8) in
    chunks of :data:`LAZ_CHUNK` points, and the output's records are the
    input's, every field at its place, followed by the dimensions
    ``new_dims`` (names) and nothing else; or followed by them and then
    the input's last extra bytes (the bytes no ExtraBytes entry describes,
    which :func:`~patchcloud.stream.io.las.undescribed_last` moves last).
    """
    if not header.are_points_compressed:
        return None
    with laspy.open(path) as reader:
        h_in = reader.header
    zips = h_in.vlrs.get("LasZipVlr") if h_in.are_points_compressed else []
    outs = header.vlrs.get("LasZipVlr")
    if not zips or not outs:
        return None
    if not (np.array_equal(h_in.scales, header.scales) and np.array_equal(h_in.offsets, header.offsets)):
        return None
    a, b = h_in.point_format.dtype(), header.point_format.dtype()
    if any(name not in b.fields for name in a.names):
        return None
    moved = {name for name in a.names if b.fields[name][1] != a.fields[name][1]}
    tail = a.itemsize - min((a.fields[name][1] for name in moved), default=a.itemsize)  # the input's bytes moved last
    grow = b.itemsize - a.itemsize
    if any((a.fields[name][1] >= a.itemsize - tail) != (name in moved) for name in a.names):  # every field of the tail moves,
        return None
    if any(b.fields[name][1] != a.fields[name][1] + grow for name in moved):  # after the new ones
        return None
    if any(name not in b.fields or not a.itemsize - tail <= b.fields[name][1] < b.itemsize - tail for name in new_dims):
        return None
    lp = laz_layers.plan(zips[0].record_data, outs[0].record_data, a.itemsize, b.itemsize, tail)
    if lp is None or lp.chunk != LAZ_CHUNK:
        return None
    n = int(h_in.point_count)
    # the chunks hold exactly the header's points (its last chunk's own count read; the table checked before lazrs
    # allocates it), else, e.g. a header that counts fewer points than the last chunk holds, read and coded whole
    if laz_point_range(path, h_in.offset_to_point_data, a.itemsize, h_in.point_format.id) != (n, n):
        return None
    try:
        table = chunk_table(path, h_in.offset_to_point_data, zips[0].record_data)
    except Exception:  # no usable chunk table: the records are read and coded whole, as before
        return None
    if len(table) != -(-n // lp.chunk):
        return None
    selection = LAYERED_SELECTION | (laspy.DecompressionSelection.GPS_TIME if header.version.minor >= 5 else 0)
    return LayeredSource(path=str(path), plan=lp, chunks=table, selection=selection)


def write_laz_part_layered(tmp: str | os.PathLike, part: int, source: LayeredSource, first: int, new: np.ndarray,
                           channels: np.ndarray) -> list:
    """:func:`write_laz_part` for records that are the input's (``source``) points ``first, first + 1, ...`` with new
    extra bytes: the input's chunks copied, the new bytes coded (:func:`~patchcloud.stream.io.laz_layers.extend_chunk`).

    ``new`` (n, k) uint8: each point's new bytes; ``channels`` (n,): the
    points' scanner channels.  ``first`` is a multiple of the chunk size.

    Raises
    ------
    PatchcloudIOError
        A chunk of the input is not what its chunk table says.
    """
    lp = source.plan
    n = len(new)
    if first % lp.chunk:
        raise ValueError(f"part starts at point {first}, not at a LAZ chunk of {lp.chunk} points")
    c0, c1 = first // lp.chunk, -(-(first + n) // lp.chunk)
    rows = source.chunks[c0:c1]
    start = int(rows[0, 0])
    with open(source.path, "rb") as f:
        f.seek(start)
        raw = f.read(int(rows[-1, 0] + rows[-1, 1]) - start)
    pieces, table = [], []
    for c, (at, size) in zip(range(c0, c1), rows.tolist()):
        s, e = c * lp.chunk - first, min((c + 1) * lp.chunk - first, n)
        try:
            data = laz_layers.extend_chunk(memoryview(raw)[at - start : at - start + size], lp, new[s:e], channels[s:e])
        except ValueError as exc:
            raise PatchcloudIOError(f"{source.path}: corrupt LAZ chunk {c} ({exc})") from None
        pieces.append(data)
        table.append((e - s, len(data)))
    _write_fragment(tmp, part, pieces)
    return table


def _write_fragment(tmp: str | os.PathLike, part: int, pieces) -> None:
    """Fragment ``part`` of ``tmp``: the bytes ``pieces``, in order, under a temporary name renamed when complete."""
    name = fragments_dir(tmp) / f"{part:06d}"
    with naming_failed_writes(tmp), open(str(name) + ".tmp", "wb") as f:
        for piece in pieces:
            f.write(piece)
    os.replace(str(name) + ".tmp", name)


def _append(src, dst, first: int = 0) -> None:
    """Copy the file ``src`` from byte ``first`` to its end onto ``dst`` at its position (both open, ``dst`` flushed):
    in the kernel where it can."""
    size = max(0, os.fstat(src.fileno()).st_size - first)
    copy = getattr(os, "copy_file_range", None)
    at = dst.tell()
    if copy is not None:
        try:
            done = 0
            while done < size:
                n = copy(src.fileno(), dst.fileno(), size - done, first + done, at + done)
                if n == 0:
                    break
                done += n
            if done == size:
                dst.seek(at + size)
                return
            dst.seek(at)
        except OSError:  # e.g. across file systems on old kernels: copy through user space
            dst.seek(at)
    src.seek(first)
    shutil.copyfileobj(src, dst, 1 << 24)


def is_waveform_record(v) -> bool:
    """Whether the (E)VLR ``v`` (laspy's) is a waveform data packet record (LASF_Spec, record 65535)."""
    return v.user_id == "LASF_Spec" and v.record_id == 65535


def legacy_counts(f, h: laspy.LasHeader) -> None:
    """Write LAS 1.4's legacy point count and counts by return into the header at the start of the open file ``f``
    (laspy writes them 0): set for point formats 0 to 5 with at most 2**32 - 1 points, as LAS 1.4 asks, so that readers
    of LAS 1.2 fields find the counts too; 0 otherwise.  As PDAL writes them: points of returns 6 and 7 (which
    formats 0 to 5 can hold) are in the count, and returns 1 to 5 in the five counts by return (these left the
    counts 0, so a reader of the LAS 1.2 fields saw an empty file)."""
    if h.version.minor < 4:
        return
    n, by = int(h.point_count), [int(v) for v in h.number_of_points_by_return]
    ok = h.point_format.id < 6 and n <= 0xFFFFFFFF
    at = f.tell()
    f.seek(LEGACY_COUNT_AT)
    f.write(struct.pack("<6I", *([n] + by[:5] if ok else [0] * 6)))
    f.seek(at)


#: Byte of a LAS header where the legacy point count is, followed by the 5 legacy counts by return.
LEGACY_COUNT_AT = 107
#: Byte of a LAS header where the file's creation day of year is, followed by its year (two uint16).
CREATION_AT = 90


def rewrite_header(f, h: laspy.LasHeader, raw: bytes = b"") -> None:
    """Write ``h`` over the header at the start of the open file ``f`` (its size unchanged), with LAS 1.4's legacy
    counts (:func:`legacy_counts`) and the creation date of the input's raw header ``raw`` as it is written there
    (:func:`keep_creation_date`; none: laspy's)."""
    at = f.tell()
    f.seek(0)
    h.write_to(f, ensure_same_size=True)
    legacy_counts(f, h)
    keep_creation_date(f, raw)
    f.seek(at)


def keep_creation_date(f, raw: bytes) -> None:
    """Write the creation day of year and year of the raw header ``raw`` (an input's first bytes) into the header at
    the start of the open file ``f``, as they are.  laspy reads a day 0 (every IGN LiDAR HD tile has it) as the 31
    December of the year before, and writes that: the output said day 365 of 2023 for day 0 of 2024."""
    if len(raw) < CREATION_AT + 4 or raw[:4] != b"LASF":
        return
    at = f.tell()
    f.seek(CREATION_AT)
    f.write(raw[CREATION_AT:CREATION_AT + 4])
    f.seek(at)


def stitch(tmp: str | os.PathLike, parts: Iterable[int]) -> None:
    """Append the LAZ fragments ``parts`` (the next ones, in order) to ``tmp``'s point data and remove them.

    The writer calls it as the parts come in, each as soon as every part
    before it is in, so that :func:`finish` has only the last ones left to
    copy: the copy of the compressed points is not a serial step at the end.
    """
    d = fragments_dir(tmp)
    with naming_failed_writes(tmp), open(tmp, "r+b") as f:
        f.seek(0, os.SEEK_END)
        for part in parts:
            name = d / f"{part:06d}"
            with open(name, "rb") as src:
                _append(src, f)
            name.unlink()


def finish(header: laspy.LasHeader, tmp: str | os.PathLike, start: int, stats: list[PointStats], tables: list | None = None,
           source: str | None = None, stitched: int = 0) -> None:
    """Complete ``tmp``: the header with the merged ``stats``; for LAZ, the fragments not yet stitched (in part order)
    and the chunk table; then the header's EVLRs (LAS 1.4: a CRS WKT is often one), after the point data.

    ``tables``: each LAZ part's chunk-table entries, in part order (the
    parts :func:`stitch` appended first, then the others).
    ``stitched``: how many parts :func:`stitch` has appended already (parts
    0 to ``stitched - 1``); the others' fragments are appended here, each
    of which must be there.  A fragment of a part appended already is not
    appended again: on a cluster, a worker lost after its part was in has
    its task run again, which writes the same fragment a second time.
    ``source``: the input file, whose creation date the output keeps as it
    is written there (:func:`keep_creation_date`), and whose internal waveform data packet record
    follows the points of the output too, the header pointing at it: a
    LAS 1.4 input's is one of its EVLRs, kept with the others; a LAS 1.3
    input's (from the header's offset to the end of the file, a record of
    the layout of an EVLR) becomes the output's first EVLR.  The wave
    packet descriptors of the points are relative to its start, so they
    stay true.
    """
    h = _merge(header, stats)
    evlrs = list(header.evlrs) if header.version.minor >= 4 and header.evlrs else []
    waves = h.global_encoding.waveform_data_packets_internal
    h.start_of_waveform_data_packet_record = 0
    if h.are_points_compressed:  # the fragments not stitched yet (those stitched came first)
        stitch(tmp, range(stitched, len(tables)))
    with naming_failed_writes(tmp), open(tmp, "r+b") as f:
        if h.are_points_compressed:
            table_at = f.seek(0, os.SEEK_END)
            vlr = lazrs.LazVlr(h.vlrs.get("LasZipVlr")[0].record_data)
            lazrs.write_chunk_table(f, [e for t in tables for e in t], vlr)
            f.truncate()
            f.seek(start)
            f.write(struct.pack("<q", table_at))
        f.seek(0, os.SEEK_END)
        first, count = f.tell(), 0
        if waves and source is not None:
            with open(source, "rb") as src:
                sh = laspy.LasHeader.read_from(src)
                if sh.version.minor < 4 and sh.start_of_waveform_data_packet_record:
                    f.flush()
                    h.start_of_waveform_data_packet_record = f.tell()
                    _append(src, f, sh.start_of_waveform_data_packet_record)
                    count += 1
        for v in evlrs:
            if waves and is_waveform_record(v) and not h.start_of_waveform_data_packet_record:
                h.start_of_waveform_data_packet_record = f.tell()
            type(header.evlrs)([v]).write_to(f, as_extended=True)
            count += 1
        if h.version.minor >= 4:
            h.start_of_first_evlr, h.number_of_evlrs = (first, count) if count else (0, 0)
        h.global_encoding.waveform_data_packets_internal = bool(h.start_of_waveform_data_packet_record)
        raw = b""
        if source is not None:
            with open(source, "rb") as src:
                raw = src.read(CREATION_AT + 4)
        rewrite_header(f, h, raw)
    if h.are_points_compressed:
        shutil.rmtree(fragments_dir(tmp), ignore_errors=True)


def remove_partial(tmp: str | os.PathLike) -> None:
    """Remove what an unfinished output left: ``tmp`` and its fragments."""
    Path(tmp).unlink(missing_ok=True)
    shutil.rmtree(fragments_dir(tmp), ignore_errors=True)
