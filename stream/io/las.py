"""LAS/LAZ input and output in chunks (laspy with the lazrs backend).

Every problem with an input file becomes one :class:`PatchcloudIOError`
naming the file and what is wrong with it: missing, not LAS/LAZ, empty,
truncated, or a header whose point count disagrees with the data.  Output
files are written under a temporary name (``NAME.partial``) and renamed
only when complete.
"""

from __future__ import annotations

import errno
import functools
import json
import os
import struct
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import laspy
import lazrs
import numpy as np
from laspy.vlrs.known import ExtraBytesStruct

from patchcloud.core import PatchcloudExistsError, PatchcloudIOError, PatchcloudValueError

from .crs import is_crs_record, with_crs
from .crs_cache import header_crs
from .renamed import partial_path, rename_into_place
from .write_errors import naming_failed_writes
from .las_records import (
    EVLR_BYTES, VLR_BYTES, RawRecord, as_vlr, ascii_text, file_records, header_record_fields, is_extra_bytes, kept, software_version,
)

__all__ = [
    "LasSource", "CorruptPointsError", "open_source", "read_chunks", "read_range", "output_header", "assemble_header", "OUTPUT_VERSION", "check_writable", "check_directory_writable", "check_not_input", "same_file", "atomic_output", "is_laz_name", "laz_backend", "WAVE_PACKET_FIELDS", "has_wave_packets", "wave_packets_break_laz", "check_laz_keeps",
    "is_copc_name", "without_copc", "check_las_output", "laz_point_range", "writable_version", "check_header_sizes",
    "check_record_sizes", "check_header_values", "header_record_fields", "VLR_BYTES", "EVLR_BYTES", "NEWEST_FORMAT", "MAX_SCALE", "MAX_OFFSET", "undescribed_last", "check_chunk_table", "chunk_table", "POINTWISE_COMPRESSOR", "raw_header", "waves_of_las13", "split_evlrs", "is_waveform_evlr",
    "POSITION_AND_CLASS", "check_last_chunk", "INTERRUPTS", "content_fingerprint", "FINGERPRINT_BLOCKS", "FINGERPRINT_BLOCK", "holds", "check_dims_fit",
]

#: What a ``except BaseException`` around lazrs lets through: lazrs' Rust panics come as pyo3's PanicException, which
#: is not an Exception (a fuzzed LASzip VLR made ``info`` print a traceback), but these are the user's or Python's.
INTERRUPTS = (KeyboardInterrupt, SystemExit, GeneratorExit)


class CorruptPointsError(PatchcloudIOError):
    """An input's point data that cannot be decoded (corrupt, or ending before its header's count): a run's store is
    not kept for it, since a rerun reads the file anew (a file replaced by a good copy is tiled again anyway)."""


#: The fields of a LAS 1.4 layered LAZ record (point formats 6 to 10) that say where a point is and whether it takes
#: part: coordinates, return numbers and channel, classification and its flags (withheld).  What the ingest decodes.
POSITION_AND_CLASS = (
    laspy.DecompressionSelection.XY_RETURNS_CHANNEL | laspy.DecompressionSelection.Z
    | laspy.DecompressionSelection.CLASSIFICATION | laspy.DecompressionSelection.FLAGS
)


@dataclass(frozen=True)
class LasSource:
    """What the stream records about an input file."""

    path: str
    size: int
    mtime_ns: int
    point_count: int
    point_format: int
    version: str
    scale: tuple[float, float, float]
    offset: tuple[float, float, float]
    mins: tuple[float, float, float]
    maxs: tuple[float, float, float]
    compressed: bool
    crs: str | None
    fingerprint: int = 0  # content_fingerprint of the file (0: not known, a store written before 2026-11-27)
    crs_error: str | None = None  # why a CRS record it has cannot be read (then crs is None): said, not taken for none

    def to_json(self) -> dict:
        return dict(self.__dict__)

    @property
    def step(self) -> float:
        """The step its coordinates are rounded to: its largest scale (file units)."""
        return float(max(self.scale))

    @classmethod
    def from_json(cls, d: dict) -> "LasSource":
        """The inverse of :meth:`to_json`."""
        d = dict(d)
        for k in ("scale", "offset", "mins", "maxs"):
            d[k] = tuple(d[k])
        d.setdefault("fingerprint", 0)
        d.setdefault("crs_error", None)
        return cls(**{f: d[f] for f in cls.__dataclass_fields__})

    def same_file(self, other: dict) -> bool:
        """True when ``other`` (a :meth:`to_json` dict) describes this file unchanged: every field, the header's and
        the :func:`content_fingerprint` too (a file rewritten in place keeps its size, and ``touch -r`` or a coarse
        file system its time)."""
        mine = json.loads(json.dumps(self.to_json()))  # tuples as lists, as other came back from JSON
        if not other.get("fingerprint"):  # recorded before 2026-11-27: every other field compared, as then and more
            mine.pop("fingerprint")
        return all(other.get(k) == v for k, v in mine.items())


#: :func:`content_fingerprint` reads this many blocks of :data:`FINGERPRINT_BLOCK` bytes, spread evenly over the file.
FINGERPRINT_BLOCKS = 64
FINGERPRINT_BLOCK = 65536


def content_fingerprint(path: str | os.PathLike, size: int) -> int:
    """crc32 of :data:`FINGERPRINT_BLOCKS` blocks of the file spread evenly from its first byte to its last (the whole
    file below 4 MiB): what tells a file rewritten in place from the one a store was made of, for a few milliseconds
    whatever its size.  A change confined to bytes between the blocks is not seen.

    >>> import tempfile
    >>> with tempfile.NamedTemporaryFile() as f:
    ...     _ = f.write(bytes(100)); f.flush()
    ...     a = content_fingerprint(f.name, 100)
    ...     _ = f.seek(50); _ = f.write(b"x"); f.flush()
    ...     a != content_fingerprint(f.name, 100)
    True
    """
    crc = 0
    with open(path, "rb") as f:
        if size <= FINGERPRINT_BLOCKS * FINGERPRINT_BLOCK:
            return zlib.crc32(f.read())
        step = (size - FINGERPRINT_BLOCK) / (FINGERPRINT_BLOCKS - 1)
        for k in range(FINGERPRINT_BLOCKS):
            f.seek(int(round(k * step)))
            crc = zlib.crc32(f.read(FINGERPRINT_BLOCK), crc)
    return crc


def is_laz_name(path: str | os.PathLike) -> bool:
    return str(path).lower().endswith(".laz")


def is_copc_name(path: str | os.PathLike) -> bool:
    """True for a name that PDAL and QGIS take for COPC (``*.copc.laz``).

    >>> is_copc_name("a/x.copc.laz"), is_copc_name("x.laz")
    (True, False)
    """
    return str(path).lower().endswith(".copc.laz")


def check_las_output(path: str | os.PathLike) -> None:
    """A PatchcloudValueError for a LAS/LAZ output named like COPC: patchcloud writes plain LAS/LAZ, not COPC.

    >>> check_las_output("x.copc.laz")
    Traceback (most recent call last):
    ...
    patchcloud.core.errors.PatchcloudValueError: x.copc.laz: patchcloud writes LAS/LAZ, not COPC; name the output x.laz (a .copc.laz name is taken for COPC by PDAL and QGIS)
    """
    p = Path(path)
    if is_copc_name(p):
        plain = p.name[: -len(".copc.laz")] + ".laz"
        raise PatchcloudValueError(
            f"{path}: patchcloud writes LAS/LAZ, not COPC; name the output {plain} (a .copc.laz name is taken for COPC by PDAL and QGIS)"
        )


#: The fields of point formats 9 and 10 that LAZ (lazrs 0.8) gives back shifted when the scanner channel changes.
WAVE_PACKET_FIELDS = ("wavepacket_index", "wavepacket_offset", "wavepacket_size", "return_point_wave_location", "x_t", "y_t", "z_t")


def has_wave_packets(points: laspy.PackedPointRecord) -> bool:
    """Whether any of these records (point format 9 or 10) has a non-zero field of :data:`WAVE_PACKET_FIELDS`."""
    return any(np.asarray(points[d]).any() for d in WAVE_PACKET_FIELDS)


def wave_packets_break_laz(points: laspy.PackedPointRecord) -> bool:
    """Whether LAZ (lazrs 0.8) would not give these records back.

    Point formats 9 and 10 whose points change scanner channel come back
    with their wave packet offsets, sizes, return locations and
    x(t), y(t), z(t) shifted (measured with laspy and lazrs alone); when
    all those fields are zero nothing is lost.

    >>> pts = laspy.PackedPointRecord.zeros(3, laspy.PointFormat(9))
    >>> pts["scanner_channel"] = [0, 1, 0]
    >>> wave_packets_break_laz(pts)
    False
    >>> pts["wavepacket_size"] = [10, 20, 30]
    >>> wave_packets_break_laz(pts)
    True
    """
    if points.point_format.id not in (9, 10) or len(points) == 0:
        return False
    ch = np.asarray(points["scanner_channel"])
    return bool((ch != ch[0]).any()) and has_wave_packets(points)


def check_laz_keeps(src: LasSource, output: str | os.PathLike, chunk: int = 1_000_000) -> None:
    """A PatchcloudValueError when ``output`` is LAZ and LAZ would not give back the records of ``src``
    (:func:`wave_packets_break_laz`, over the whole file: read only for point formats 9 and 10).

    Raises
    ------
    PatchcloudValueError
        Naming the output, the input and the way out (a .las output).
    """
    if not is_laz_name(output) or src.point_format not in (9, 10):
        return
    channels, waves = set(), False
    for _, pts in read_chunks(src, chunk):
        if len(pts) == 0:
            continue
        channels.update(np.unique(np.asarray(pts["scanner_channel"])).tolist())
        waves = waves or has_wave_packets(pts)
        if waves and len(channels) > 1:
            raise PatchcloudValueError(
                f"{output}: LAZ (lazrs 0.8) would not keep the wave packet fields of {src.path} (point format "
                f"{src.point_format}, whose scanner channel changes); give an output ending in .las (in --out-dir an output takes its input's suffix)")


def without_copc(header: laspy.LasHeader) -> laspy.LasHeader:
    """``header`` without the COPC records (the info VLR, the hierarchy EVLR, user id "copc"), changed in place and returned.

    A COPC file read in input order is a plain LAZ 1.4 file; what is written
    from it is LAS/LAZ, whose points are no longer in COPC's octree order,
    so its COPC records would lie (and laspy refuses to write them).  Every
    other VLR and EVLR (the CRS among them) is kept.
    """
    header.vlrs = [v for v in header.vlrs if v.user_id != "copc"]
    if header.evlrs is not None:
        header.evlrs = type(header.evlrs)([v for v in header.evlrs if v.user_id != "copc"])
    return header


def open_source(path: str | os.PathLike, allow_empty: bool = False) -> LasSource:
    """Check that ``path`` is a readable, non-empty, complete LAS/LAZ file and describe it.

    ``allow_empty``: a file of no points is described too (a catalog's
    empty tile), not refused.

    Raises
    ------
    PatchcloudIOError
        The file is missing, not LAS/LAZ, empty, or truncated, or its header's
        point count disagrees with the size of its point data.
    """
    p = Path(path)
    if not p.exists():
        raise PatchcloudIOError(f"{p}: no such file")
    if p.is_dir():
        raise PatchcloudIOError(f"{p}: is a directory, not a LAS/LAZ file")
    st = p.stat()
    with open(p, "rb") as f:
        head = f.read(375)
        if head[:4] != b"LASF":
            raise PatchcloudIOError(f"{p}: not a LAS/LAZ file (no 'LASF' signature)")
        check_header_sizes(p, head, st.st_size)
        check_record_sizes(p, f, head, st.st_size)
    try:
        with laspy.open(p) as reader:
            h = reader.header
            check_header_values(p, h)
            compressed = bool(h.are_points_compressed)
            crs, crs_error = header_crs(h)  # (pyproj's answer, kept on disk: crs_cache)
            src = LasSource(
                path=str(p.resolve()), size=int(st.st_size), mtime_ns=int(st.st_mtime_ns), point_count=int(h.point_count),
                point_format=int(h.point_format.id), version=str(h.version), scale=tuple(map(float, h.scales)),
                offset=tuple(map(float, h.offsets)), mins=tuple(map(float, h.mins)), maxs=tuple(map(float, h.maxs)),
                compressed=compressed, crs=crs, fingerprint=content_fingerprint(p, int(st.st_size)), crs_error=crs_error,
            )
            record = int(h.point_format.size)
            start = int(h.offset_to_point_data)
            evlr = int(getattr(h, "start_of_first_evlr", 0) or 0)
            if h.global_encoding.waveform_data_packets_internal:
                waves = int(getattr(h, "start_of_waveform_data_packet_record", 0) or 0)
                evlr = min(v for v in (evlr, waves) if v > 0) if max(evlr, waves) > 0 else 0
    except PatchcloudIOError:
        raise
    except Exception as exc:
        raise PatchcloudIOError(f"{p}: not a readable LAS/LAZ file ({exc})") from exc
    if src.point_count == 0 and not allow_empty:
        raise PatchcloudIOError(f"{p}: the file holds no points")
    if compressed and (src.point_count or st.st_size > start + 8):  # (a LAZ of no points may end with its header, or
        # its chunk table's offset: PDAL and laspy read it so; one that holds chunks is checked as any)
        held = laz_point_range(p, start, record, src.point_format)
        if held is not None and not held[0] <= src.point_count <= held[1]:
            what = f"{held[0]:,}" if held[0] == held[1] else f"{held[0]:,} to {held[1]:,} (its chunks of fixed size)"
            raise PatchcloudIOError(f"{p}: the header says {src.point_count:,} points but the LAZ chunk table holds {what}")
        if src.point_count:
            check_last_chunk(src)
    if not compressed:
        end = start + src.point_count * record
        if st.st_size < end:
            have = max(0, (st.st_size - start) // record)
            raise PatchcloudIOError(
                f"{p}: truncated: the header says {src.point_count:,} points but the file holds only {have:,}"
            )
        data_end = evlr if evlr > 0 else st.st_size
        if data_end > end and (data_end - end) >= record:
            extra = (data_end - start) // record
            raise PatchcloudIOError(
                f"{p}: the header says {src.point_count:,} points but the point data holds {extra:,}"
            )
    return src


def check_header_sizes(path: str | os.PathLike, head: bytes, size: int, *, evlrs: bool = True) -> None:
    """Refuse a LAS header whose sizes and counts the file cannot hold, before anything is read or allocated from them.

    The header's size, the offset to the point data, the number of VLRs
    (each at least 54 bytes, between the header and the points), and for
    LAS 1.4 the start and number of the EVLRs (each at least 60 bytes) are
    checked against the file's ``size`` (bytes): a crafted header claiming a
    billion VLRs is one error, not hours of parsing.  ``head``: the file's
    first 375 bytes (fewer if it is shorter); ``path`` names it in the error;
    ``evlrs`` False: the EVLRs are not in these bytes (a header kept apart
    from its file), leave them out.

    Raises
    ------
    PatchcloudIOError
        Naming the file, the field and what the file can hold.
    """
    if len(head) < 227:
        raise PatchcloudIOError(f"{path}: truncated: {len(head)} bytes, less than a LAS header (227)")
    header_size, offset, vlrs, start, count = header_record_fields(head)
    if not 227 <= header_size <= min(size, 65535):
        raise PatchcloudIOError(f"{path}: the header says it is {header_size:,} bytes long, in a file of {size:,} bytes")
    if not header_size <= offset <= size:
        raise PatchcloudIOError(f"{path}: the header puts the point data at byte {offset:,}, outside the file "
                                f"({header_size:,} to {size:,})")
    if vlrs * VLR_BYTES > offset - header_size:
        raise PatchcloudIOError(f"{path}: the header says {vlrs:,} VLRs, but the {offset - header_size:,} bytes before the "
                                f"point data hold at most {(offset - header_size) // VLR_BYTES:,}")
    if evlrs and count and start < offset:
        raise PatchcloudIOError(f"{path}: the header puts its {count:,} EVLRs at byte {start:,}, before its point data "
                                f"(byte {offset:,})")
    if evlrs and count and (start > size or count * EVLR_BYTES > size - start):
        room = max(0, size - start) // EVLR_BYTES
        raise PatchcloudIOError(f"{path}: the header says {count:,} EVLRs from byte {start:,}, but the file "
                                f"({size:,} bytes) holds at most {room:,} there")


#: The largest scale and offset a header may state (metres or feet; a real file's are 0.01 to 1e-7, and a few million):
#: beyond, coordinates overflow the arithmetic of a run, so such a header is refused as damaged.
MAX_SCALE, MAX_OFFSET = 1e3, 1e12
#: The newest point format each LAS 1.x version defines (1.0 and 1.1: 0 and 1; 1.2: 0 to 3; 1.3: 0 to 5; 1.4: 0 to 10).
NEWEST_FORMAT = {0: 1, 1: 1, 2: 3, 3: 5, 4: 10}


def check_header_values(path: str | os.PathLike, header: laspy.LasHeader) -> None:
    """Refuse a header laspy parsed whose version, point format, scales, offsets or bounds no LAS file can have.

    A LAS 1.0 to 1.4 version, a point format that version defines, positive
    scales up to :data:`MAX_SCALE`, offsets within :data:`MAX_OFFSET`, finite bounds, each minimum at most
    its maximum and within what the scales and offsets can reach: anything
    else (a crafted or damaged header) is one error before any point is
    read.  Points outside the header's bounds are accepted (writers leave
    stale bounds): the tiles hold them, and outputs state their true bounds.

    Raises
    ------
    PatchcloudIOError
        Naming the file and the field.
    """
    v, fmt = header.version, header.point_format.id
    if v.major != 1 or v.minor not in NEWEST_FORMAT:
        raise PatchcloudIOError(f"{path}: LAS version {v.major}.{v.minor} does not exist (1.0 to 1.4)")
    if fmt > NEWEST_FORMAT[v.minor]:
        raise PatchcloudIOError(f"{path}: point format {fmt} does not exist in LAS {v.major}.{v.minor} "
                                f"(0 to {NEWEST_FORMAT[v.minor]})")
    scales, offsets = np.asarray(header.scales, dtype=np.float64), np.asarray(header.offsets, dtype=np.float64)
    bounds = np.concatenate([np.asarray(header.mins, dtype=np.float64), np.asarray(header.maxs, dtype=np.float64)])
    if not (np.isfinite(scales).all() and (scales > 0).all() and (scales <= MAX_SCALE).all() and np.isfinite(offsets).all()
            and (np.abs(offsets) <= MAX_OFFSET).all() and np.isfinite(bounds).all()):
        raise PatchcloudIOError(f"{path}: the header's scales {scales.tolist()}, offsets {offsets.tolist()} or bounds "
                                f"{bounds.tolist()} are not scales in (0, {MAX_SCALE:g}], offsets within ±{MAX_OFFSET:g} and finite numbers")
    reach = np.abs(offsets) + scales * 2.0**31  # no point's coordinate can be further from 0 than this
    if np.any(bounds[:3] > bounds[3:]) or np.any(np.abs(bounds) > np.tile(reach, 2)):
        raise PatchcloudIOError(f"{path}: the header's bounds {bounds[:3].tolist()} .. {bounds[3:].tolist()} are not bounds "
                                f"of any points it can hold (a minimum above its maximum, or beyond its scales and offsets)")


def check_record_sizes(path: str | os.PathLike, f, head: bytes, size: int) -> None:
    """Refuse a VLR running into the point data, or an EVLR running past the end of the file, before laspy reads them.

    Walks the VLR headers from the end of the header (each states the
    length of its record) and, for LAS 1.4, the EVLR headers from the first
    EVLR; ``f``: the open file, ``head`` its first 375 bytes, already passed
    by :func:`check_header_sizes`.  A crafted record length would otherwise
    have laspy allocate it.

    Raises
    ------
    PatchcloudIOError
        Naming the file, the record and where it ends.
    """
    header_size, offset, vlrs, start, evlrs = header_record_fields(head)
    walks = [("VLR", header_size, vlrs, VLR_BYTES, "<H", offset, "the point data at byte")]
    if evlrs:
        walks.append(("EVLR", start, evlrs, EVLR_BYTES, "<Q", size, "the end of the file at byte"))
    for kind, pos, count, head_bytes, length_format, end, what in walks:
        for i in range(count):
            f.seek(pos + 20)
            raw = f.read(struct.calcsize(length_format))
            length = struct.unpack(length_format, raw)[0] if len(raw) == struct.calcsize(length_format) else 0
            pos += head_bytes + length
            if pos > end:
                raise PatchcloudIOError(f"{path}: {kind} {i + 1} of {count:,} ({length:,} bytes of data) runs past {what} {end:,}")


def check_chunk_table(path: str | os.PathLike, f, start: int, size: int, record: int) -> int:
    """Refuse a LAZ chunk table that the file cannot hold, before lazrs reads it; return its offset (bytes).

    The point data at ``start`` begins with the table's offset (-1: the
    offset is in the file's last 8 bytes, as LASzip writes it when it cannot
    seek back); the table opens with its version and number of chunks.  A
    chunk holds at least one point, whose record (``record`` bytes) LASzip
    stores raw, so the bytes between the offset and the table bound the
    number of chunks.  lazrs allocates the table before reading it: a
    corrupt count would otherwise abort the process (a failed allocation
    in Rust is not an exception).  ``f``: the file, open for reading.

    Raises
    ------
    PatchcloudIOError
        The offset lies outside the point data or the table lists more chunks than that data can hold.
    """
    f.seek(start)
    raw = f.read(8)
    if len(raw) < 8:
        raise PatchcloudIOError(f"{path}: truncated: the LAZ point data ends before its chunk table's offset")
    at = struct.unpack("<q", raw)[0]
    if at == -1 and size >= start + 16:
        f.seek(size - 8)
        at = struct.unpack("<q", f.read(8))[0]
    if at > size - 8 >= start + 8:
        raise PatchcloudIOError(f"{path}: truncated or damaged LAZ file (its chunk table's offset, byte {at:,}, lies past its "
                                f"end, byte {size:,})")
    if not start + 8 <= at <= size - 8:
        raise PatchcloudIOError(f"{path}: damaged LAZ file (its chunk table's offset, byte {at:,}, lies outside its point "
                                f"data, bytes {start + 8:,} to {size:,})")
    f.seek(at)
    _, count = struct.unpack("<II", f.read(8))
    data = at - start - 8
    if count > data // max(record, 1) + 1:
        raise PatchcloudIOError(f"{path}: damaged LAZ file (its chunk table lists {count:,} chunks, more than its "
                                f"{data:,} bytes of point data can hold)")
    return at


#: LASzip's compressor of points one by one, not in chunks (no chunk table).
POINTWISE_COMPRESSOR = 1


def laz_point_range(path: str | os.PathLike, start: int, record: int, point_format: int) -> tuple[int, int] | None:
    """The fewest and the most points the LAZ point data at ``start`` can hold, by its chunk table: (n, n) when exact.

    Exact for variable-size chunks (COPC, ...), whose table counts each
    chunk's points, and for the layered formats 6 to 10, whose last chunk
    starts with its first point and its point count.  Chunks of a fixed size
    in formats 0 to 5 hold that many points each but the last, of which the
    table only says it holds at least one.  None: no readable chunk table
    (a LAZ written without one, or cut short: the reading then fails).

    ``record``: the point record's size (bytes).

    Raises
    ------
    PatchcloudIOError
        A chunk table the file cannot hold (:func:`check_chunk_table`), or
        chunks whose bytes run past the table.
    """
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        try:
            vlrs = laspy.LasHeader.read_from(f).vlrs.get("LasZipVlr")
            if not vlrs:
                return None
            vlr = lazrs.LazVlr(vlrs[0].record_data)
            if struct.unpack("<H", bytes(vlrs[0].record_data[:2]))[0] == POINTWISE_COMPRESSOR:
                return None
        except Exception:
            return None
        at = check_chunk_table(path, f, start, size, record)
        try:
            f.seek(start)
            table = lazrs.read_chunk_table(f, vlr)
        except Exception:
            return None
        if not table:
            return None
        data = sum(int(c[1]) for c in table)
        if data > at - start - 8:
            raise PatchcloudIOError(f"{path}: damaged LAZ file (its chunk table gives its chunks {data:,} bytes, more than "
                                    f"the {at - start - 8:,} before the table)")
        if vlr.uses_variable_size_chunks():
            n = sum(int(c[0]) for c in table)
            return n, n
        size, k = int(vlr.chunk_size()), len(table)
        if point_format < 6:
            return size * (k - 1) + 1, size * k
        f.seek(start + 8 + data - int(table[-1][1]) + record)  # the last chunk's first point, raw, then its count
        last = f.read(4)
        if len(last) < 4:
            return None
        n = size * (k - 1) + struct.unpack("<I", last)[0]
        return n, n


def read_range(src: LasSource, first: int, count: int, parallel: bool = False,
               selection: laspy.DecompressionSelection | None = None) -> laspy.ScaleAwarePointRecord:
    """Points ``first`` to ``first + count`` of the file (what one ingest or export task reads).

    ``parallel``: decode LAZ with lazrs' multi-threaded decoder (for tasks run
    inline, in the client's process: lazrs holds the GIL for the whole
    call, so there they decode one at a time anyway); worker processes
    use the sequential one, so that no process starts a thread per core.

    ``selection``: decode only these fields of a LAZ file whose records are
    layered (point formats 6 to 10, e.g. :data:`POSITION_AND_CLASS`): the
    other fields of the records returned hold meaningless values.  LAS
    files and the older LAZ formats are read whole.  Default: every field.

    Raises
    ------
    PatchcloudIOError
        The data ends before ``first + count`` (truncated or corrupt).
    """
    p = src.path
    if src.compressed:
        plan = _chunk_plan(p, src.size, src.mtime_ns)
        if plan is not None:  # chunks decoded from the chunk table (laspy's seek in COPC's gives other points, or zeros)
            return _decode_chunks(src, plan, first, count, parallel, selection)
    try:
        extra = {} if selection is None else {"decompression_selection": selection}
        with laspy.open(p, laz_backend=laz_backend(parallel), **extra) as reader:
            if first:
                reader.seek(first)
            try:
                pts = reader.read_points(count)
            except Exception as exc:
                raise CorruptPointsError(f"{p}: corrupt or truncated point data in points {first:,} to {first + count:,} "
                                        f"({exc})") from exc
    except PatchcloudIOError:
        raise
    except Exception as exc:
        raise CorruptPointsError(f"{p}: cannot read point data ({exc})") from exc
    if len(pts) != count:
        raise CorruptPointsError(
            f"{p}: truncated: the header says {src.point_count:,} points but the data ends after {first + len(pts):,}"
        )
    return pts


@dataclass(frozen=True)
class _ChunkPlan:
    """Where a LAZ file's points are: its header, LASzip VLR, each chunk's byte offset and byte count (``table``,
    (C, 2)), each chunk's first point (``firsts``, (C + 1,), the last the total), and the fixed chunk size (``chunk``;
    0 for variable-size chunks, COPC's: one chunk per octree node)."""

    header: laspy.LasHeader
    vlr: bytes
    table: np.ndarray
    firsts: np.ndarray
    chunk: int


def _laszip_vlr(path: str):
    """(header, the LASzip VLR's bytes, lazrs.LazVlr) of a LAZ file, None for a file without that VLR; laspy's and
    lazrs' errors (a Rust panic too) pass through."""
    with open(path, "rb") as f:
        header = laspy.LasHeader.read_from(f)
    vlrs = header.vlrs.get("LasZipVlr")
    if not vlrs:
        return None
    data = bytes(vlrs[0].record_data)
    return header, data, lazrs.LazVlr(data)


def chunk_table(path: str | os.PathLike, offset_to_points: int, vlr_data: bytes) -> np.ndarray:
    """(C, 2) int64: each chunk's byte offset in the file and byte count, from the LAZ file's chunk table
    (its VLR's bytes ``vlr_data``, its point data at byte ``offset_to_points``)."""
    with open(path, "rb") as f:
        f.seek(offset_to_points)
        entries = lazrs.read_chunk_table(f, lazrs.LazVlr(vlr_data))
    sizes = np.asarray([int(e[1]) for e in entries], dtype=np.int64)
    starts = offset_to_points + 8 + np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    return np.column_stack([starts, sizes])


@functools.lru_cache(maxsize=8)
def _chunk_plan(path: str, size: int, mtime_ns: int) -> _ChunkPlan | None:
    """The chunks of a LAZ file (read once per file version), fixed or variable in size; None for a file whose points
    are not in chunks with a table (LASzip's point-wise compressor, a LAS file), or a fixed-chunk file whose table or
    VLR cannot be read (the caller then reads as laspy does, and reports what it finds).

    Raises
    ------
    PatchcloudIOError
        A file of variable-size chunks whose chunk table cannot be read, or
        whose chunks hold other than the header's point count (no reader
        but the chunk table's can read such a file in parts).
    """
    try:
        found = _laszip_vlr(path)
        if found is None:
            return None
        header, data, vlr = found
        variable = vlr.uses_variable_size_chunks()
        if not variable and (struct.unpack("<H", data[:2])[0] == POINTWISE_COMPRESSOR
                             or vlr.item_size() != header.point_format.size):  # (a damaged VLR: lazrs would panic)
            return None
        if not variable:
            table = chunk_table(path, header.offset_to_point_data, data)
            if not len(table):
                return None
            chunk, n = int(vlr.chunk_size()), int(header.point_count)
            firsts = np.minimum(np.arange(len(table) + 1, dtype=np.int64) * chunk, n)
            return _ChunkPlan(header, data, table, firsts, chunk)
    except BaseException as exc:  # (a Rust panic too: pyo3's PanicException)
        if isinstance(exc, INTERRUPTS):
            raise
        return None  # not such a file, or one laspy reports on when it reads it
    try:
        with open(path, "rb") as f:
            f.seek(header.offset_to_point_data)
            entries = lazrs.read_chunk_table(f, vlr)
    except BaseException as exc:
        if isinstance(exc, INTERRUPTS):
            raise
        raise PatchcloudIOError(f"{path}: damaged LAZ file: its table of variable-size chunks cannot be read ({exc})") from None
    points = np.asarray([int(e[0]) for e in entries], dtype=np.int64)
    sizes = np.asarray([int(e[1]) for e in entries], dtype=np.int64)
    if int(points.sum()) != header.point_count:
        raise PatchcloudIOError(f"{path}: damaged LAZ file: its chunks hold {int(points.sum()):,} points, its header says "
                                f"{header.point_count:,}")
    starts = header.offset_to_point_data + 8 + np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    return _ChunkPlan(header, data, np.column_stack([starts, sizes]), np.concatenate([[0], np.cumsum(points)]), 0)


def _decode_chunks(src: LasSource, plan: _ChunkPlan, first: int, count: int, parallel: bool,
                   selection) -> laspy.ScaleAwarePointRecord:
    """Points ``first`` to ``first + count`` of a LAZ file in chunks: the chunks that hold them read and decoded from
    their bytes and the chunk table (lazrs), the points before ``first`` in the first of them dropped; no seek.

    laspy's seek in a file of variable-size chunks (COPC's) gives other points,
    or zeros, and lazrs' parallel decoder takes about as long to seek as to
    decode 100,000 points.  ``parallel``: the chunks decoded on lazrs'
    threads in one call; else one chunk a call, on one core (a worker
    process's tasks, or a run told to use one core).
    """
    pf = plan.header.point_format
    if count <= 0:
        return laspy.ScaleAwarePointRecord.zeros(0, point_format=pf, scales=plan.header.scales, offsets=plan.header.offsets)
    if first < 0 or first + count > int(plan.firsts[-1]):
        raise CorruptPointsError(f"{src.path}: truncated: the header says {src.point_count:,} points but the data ends "
                                f"after {int(plan.firsts[-1]):,}")
    c0 = int(np.searchsorted(plan.firsts, first, side="right")) - 1
    c1 = int(np.searchsorted(plan.firsts, first + count, side="left"))
    skip = first - int(plan.firsts[c0])
    table = [(int(plan.firsts[c + 1] - plan.firsts[c]), int(plan.table[c, 1])) for c in range(c0, c1)]
    out = np.empty(sum(n for n, _ in table) * pf.size, dtype=np.uint8)
    sel = (selection if selection is not None else laspy.DecompressionSelection.all()).to_lazrs()
    try:
        with open(src.path, "rb") as f:
            f.seek(int(plan.table[c0, 0]))
            data = f.read(int(plan.table[c0:c1, 1].sum()))
        if parallel:
            lazrs.decompress_points_with_chunk_table(data, plan.vlr, out, table, sel)
        else:
            at, written, view = 0, 0, memoryview(data)
            for n, size in table:
                lazrs.decompress_points_with_chunk_table(view[at: at + size], plan.vlr, out[written: written + n * pf.size],
                                                         [(n, size)], sel)
                at, written = at + size, written + n * pf.size
    except BaseException as exc:  # (a Rust panic too: pyo3's PanicException)
        if isinstance(exc, INTERRUPTS):
            raise
        raise CorruptPointsError(f"{src.path}: corrupt or truncated point data in points {first:,} to {first + count:,} "
                                f"({exc})") from None
    records = laspy.PackedPointRecord.from_buffer(out[skip * pf.size: (skip + count) * pf.size], pf)
    return laspy.ScaleAwarePointRecord(records.array, pf, plan.header.scales, plan.header.offsets)


def check_last_chunk(src: LasSource) -> None:
    """A LAZ file of fixed-size chunks whose last chunk does not hold the points its header implies (a count too high,
    a chunk cut short) is refused: decoded from its own bytes, the chunk runs out (found by a sweep of 2026-11-27: a
    count one too high gave a made-up last point to the runs that read the file in parts).  Decodes X, Y, Z of that
    chunk once per file version; nothing for other files."""
    _check_last_chunk(src.path, src.size, src.mtime_ns, src.point_count)


@functools.lru_cache(maxsize=64)
def _check_last_chunk(path: str, size: int, mtime_ns: int, point_count: int) -> None:
    try:
        plan = _chunk_plan(path, size, mtime_ns)
    except PatchcloudIOError:  # (variable-size chunks: not this check's)
        return
    if plan is None or not plan.chunk:
        return
    c = len(plan.table) - 1
    n = point_count - c * plan.chunk
    if not 0 < n <= plan.chunk:
        raise PatchcloudIOError(f"{path}: the header says {point_count:,} points, its {len(plan.table)} LAZ chunks of "
                                f"{plan.chunk:,} hold {(c * plan.chunk + 1):,} to {(c + 1) * plan.chunk:,}")
    out = np.empty(n * plan.header.point_format.size, dtype=np.uint8)
    try:
        with open(path, "rb") as f:
            f.seek(int(plan.table[c, 0]))
            data = f.read(int(plan.table[c, 1]))
        lazrs.decompress_points_with_chunk_table(data, plan.vlr, out, [(n, int(plan.table[c, 1]))],
                                                 POSITION_AND_CLASS.to_lazrs())
    except BaseException as exc:  # lazrs' Rust panics (a damaged LASzip VLR) come as pyo3's PanicException, a BaseException
        if isinstance(exc, INTERRUPTS):
            raise
        raise PatchcloudIOError(f"{path}: corrupt or truncated point data: its last LAZ chunk does not hold the "
                                f"{n:,} points the header's count of {point_count:,} implies ({exc})") from None


def read_chunks(src: LasSource, chunk: int, start_chunk: int = 0) -> Iterator[tuple[int, laspy.ScaleAwarePointRecord]]:
    """Chunks of ``chunk`` points of the file, from chunk ``start_chunk`` on, with their first index.

    Raises
    ------
    PatchcloudIOError
        The data ends before the header's point count (truncated or corrupt).
    """
    p = src.path
    if start_chunk:  # from a point inside the file: read_range, which reads every kind of LAZ file there
        for first in range(start_chunk * chunk, src.point_count, chunk):
            yield first, read_range(src, first, min(chunk, src.point_count - first))
        return
    try:
        with laspy.open(p, laz_backend=laz_backend()) as reader:
            done = start_chunk * chunk
            while done < src.point_count:
                want = min(chunk, src.point_count - done)
                try:
                    pts = reader.read_points(want)
                except Exception as exc:
                    raise CorruptPointsError(f"{p}: corrupt or truncated point data after point {done:,} ({exc})") from exc
                if len(pts) != want:
                    raise CorruptPointsError(
                        f"{p}: truncated: the header says {src.point_count:,} points but the data ends after {done + len(pts):,}"
                    )
                yield done, pts
                done += want
    except PatchcloudIOError:
        raise
    except Exception as exc:
        raise PatchcloudIOError(f"{p}: cannot read point data ({exc})") from exc


def laz_backend(parallel: bool = True):
    """lazrs: multi-threaded when ``parallel`` and the installed build offers it, else sequential."""
    try:
        if parallel and laspy.LazBackend.LazrsParallel.is_available():
            return laspy.LazBackend.LazrsParallel
        return laspy.LazBackend.Lazrs
    except Exception:
        return None


def writable_version(version) -> str:
    """The LAS version written for an input of LAS ``version``: 1.2 for 1.0 and 1.1, else the same.

    laspy writes LAS 1.2 to 1.4 only; the 1.0 and 1.1 point formats (0 and
    1) and header fields are those of 1.2, so the records stay the same.

    >>> writable_version("1.0"), writable_version("1.1"), writable_version("1.4")
    ('1.2', '1.2', '1.4')
    """
    v = str(version)
    return "1.2" if v in ("1.0", "1.1") else v


#: The LAS version of every output: 1.4, whose ExtraBytes VLR every reader (PDAL's without options) takes; point
#: formats 0 to 5 stay 0 to 5 (LAS 1.4 defines them all), so every record keeps its bytes.
OUTPUT_VERSION = "1.4"


def output_header(src: LasSource, dims, provenance: laspy.VLR | None = None, crs: str | None = None) -> laspy.LasHeader:
    """The header of an output of the file ``src``: its point format, scales, offsets, VLRs and EVLRs (the CRS among
    them) with ``dims`` added, as LAS 1.4 (:func:`assemble_header`).

    ``dims``: (name, numpy type, description[, no-data value]) of every
    dimension to add (each job declares its own, e.g.
    :data:`patchcloud.stream.io.dims.NORMALS_DIMS`).  ``provenance``:
    a VLR saying what made the file
    (:func:`patchcloud.stream.io.las_records.provenance_vlr`), appended.

    A dimension of the same name already in the input (a file that went
    through ``patchcloud normals`` or PDAL's ``filters.normal`` before) is
    reused, with its type, where that type holds the new values
    (:func:`holds`: PDAL's double ``NormalX`` takes the float32 normals
    exactly, its int64 ``ClusterID`` the ids); else it is an error.

    ``crs``: the CRS (WKT) the catalog is in (``Catalog.crs``).  An input
    without a CRS of its own, taken to be in it by ``--assume-crs``
    (``assume_crs``), gets it in its output (:func:`~patchcloud.stream.io.crs.with_crs`), as PDAL's
    ``writers.las`` writes the ``a_srs`` it was given; an input with a CRS
    keeps its own records.
    """
    with laspy.open(src.path) as reader:
        header = reader.header
    vlrs, evlrs = file_records(src.path)
    return assemble_header(header, vlrs, evlrs, dims, provenance, where=src.path, crs=crs if src.crs is None else None)


def check_dims_fit(src: LasSource, dims) -> None:
    """Refuse, from its header alone, a file with a dimension of the name of one of ``dims`` that cannot hold its values
    (what :func:`assemble_header` refuses, for a check before a job runs): a PatchcloudValueError naming the file."""
    with laspy.open(src.path) as reader:
        _check_dims_hold(reader.header, dims, src.path)


def _check_dims_hold(header: laspy.LasHeader, dims, where: str) -> None:
    """A PatchcloudValueError for the first of ``dims`` whose name is a dimension of ``header`` that cannot hold its type."""
    existing = {d.name: d.dtype for d in header.point_format.dimensions}
    for name, dtype, *_ in dims:
        if name in existing and not holds(existing[name], dtype):
            raise PatchcloudValueError(
                f"{where}: already has a dimension {name} of type {existing[name]}, which cannot hold this "
                f"run's {np.dtype(dtype)} values: remove it first (e.g. pdal translate with "
                f"--filters.ferry or writers.las.extra_dims listing the dimensions to keep)"
            )


def holds(existing, new) -> bool:
    """Whether an input's dimension of type ``existing`` can take a run's values of type ``new`` without loss: the same
    type, a wider float for a float, an integer at least as wide for an integer (signed for unsigned too: the values
    patchcloud writes, method codes and cluster ids, lie far below the signed type's top).

    >>> holds("float64", "float32"), holds("int64", "uint64"), holds("float32", "float64"), holds("uint8", "float32")
    (True, True, False, False)
    """
    e, n = np.dtype(existing), np.dtype(new)
    if e == n:
        return True
    if n.kind == "f":
        return e.kind == "f" and e.itemsize >= n.itemsize
    return n.kind in "iu" and e.kind in "iu" and e.itemsize >= n.itemsize


def assemble_header(header: laspy.LasHeader, vlrs: list[RawRecord], evlrs: list[RawRecord], dims, provenance: laspy.VLR | None = None,
                    where: str = "", crs: str | None = None) -> laspy.LasHeader:
    """``header`` (laspy's parse of an input, changed in place and returned) made the header of an output.

    - version :data:`OUTPUT_VERSION`, the same point format;
    - ``dims`` added (:func:`output_header`), the input's undescribed bytes
      last (:func:`undescribed_last`);
    - the input's VLRs and EVLRs (``vlrs``, ``evlrs``: their bytes) copied as
      they are, but LASzip's, COPC's and the ExtraBytes VLR
      (:mod:`patchcloud.stream.io.las_records`); the ExtraBytes VLR holds the
      input's descriptors first, each as its bytes (their min and max set
      to the output's points when they declare them), then those of
      ``dims``, each with its no-data value (the options' no-data bit set);
    - generating software: ``patchcloud VERSION``; ``provenance`` appended;
    - ``crs`` (WKT or anything pyproj takes), where given: written in place
      of the input's CRS records (:func:`~patchcloud.stream.io.crs.with_crs`;
      the CRS ``--assume-crs`` gives an input without one).
    """
    if crs is not None:  # (an input's unreadable CRS records among them)
        vlrs, evlrs = [r for r in vlrs if not is_crs_record(r)], [r for r in evlrs if not is_crs_record(r)]
    header.version = laspy.header.Version.from_str(OUTPUT_VERSION)
    _check_dims_hold(header, dims, where)
    existing = {d.name for d in header.point_format.dimensions}
    new = [laspy.ExtraBytesParams(name=name, type=dtype, description=desc, no_data=no_data or None)
           for name, dtype, desc, *no_data in dims if name not in existing]
    if new:
        header.add_extra_dims(new)
    # laspy's setter rebuilds the ExtraBytes VLR from the point format (appended): it is set right after
    header.vlrs = [as_vlr(r) for r in vlrs if kept(r)] + ([provenance] if provenance is not None else [])
    undescribed_last(header)
    eb = header.vlrs.get("ExtraBytesVlr")
    inputs = next((i for i, r in enumerate(vlrs) if is_extra_bytes(r)), None)
    if eb and inputs is not None:  # the input's descriptors as they were, the VLR where the input's was
        structs, data = eb[0].extra_bytes_structs, vlrs[inputs].data
        for i in range(min(len(data) // 192, len(structs))):
            raw = ExtraBytesStruct.from_buffer_copy(data[192 * i : 192 * (i + 1)])
            # the same bytes (laspy reads an entry of undocumented bytes, type 0, as the deprecated array type of as
            # many uint8: the type differs, the dtype does not)
            if raw.format_name() == structs[i].format_name() and raw.dtype() == structs[i].dtype():
                structs[i] = raw
        # the bytes another ExtraBytes VLR of the input describes (RIEGL's files hold two; laspy reads the first), last in
        # the record and undescribed here: their descriptors follow, in the one VLR (PDAL then names them)
        later = _entries(b"".join(r.data for r in vlrs[inputs + 1:] if is_extra_bytes(r)))
        extra = list(header.point_format.extra_dimensions)
        if later and len(structs) == len(extra) - 1 and extra[-1].name == UNDESCRIBED_NAME and \
                extra[-1].num_bytes == sum(e.dtype().itemsize for e in later):
            structs.extend(later)
        header.vlrs.remove(eb[0])
        header.vlrs.insert(sum(kept(r) for r in vlrs[:inputs]), eb[0])
    header.evlrs = laspy.vlrs.vlrlist.VLRList([as_vlr(r) for r in evlrs if kept(r)])
    header.system_identifier = ascii_text(header.system_identifier)
    header.generating_software = f"patchcloud {software_version()}"
    return header if crs is None else with_crs(header, crs)


def _entries(data: bytes) -> list:
    """The ExtraBytes descriptors (192 bytes each) of an ExtraBytes VLR's data, as laspy's structs."""
    return [ExtraBytesStruct.from_buffer_copy(data[192 * i : 192 * (i + 1)]) for i in range(len(data) // 192)]


#: The name and description laspy gives the bytes of a record that no extra-bytes VLR entry describes.
UNDESCRIBED_NAME, UNDESCRIBED_DESCRIPTION = "ExtraBytes", "Un-registered ExtraBytes"


def undescribed_last(header: laspy.LasHeader) -> laspy.LasHeader:
    """``header`` with the input's undescribed extra bytes last in each record and left undescribed, as they came.

    A record may end in bytes that no extra-bytes VLR entry describes
    (a real IGN file has one).  laspy reads them as one dimension named
    ``ExtraBytes`` and, on adding dimensions, describes it in the VLR as an
    entry of "undocumented extra bytes" (data type 0) whose ``options``
    field holds their count, which its own reader then takes for option
    bits (a count of 8 reads as "scaled").  Kept after the added
    dimensions and out of the VLR, they are read back as they were read.
    """
    pf = header.point_format
    tail = [d for d in pf.dimensions if d.name == UNDESCRIBED_NAME and d.description == UNDESCRIBED_DESCRIPTION]
    vlrs = header.vlrs.get("ExtraBytesVlr")
    if not tail or not vlrs:
        return header
    pf.dimensions.remove(tail[0])
    pf.dimensions.append(tail[0])
    structs = vlrs[0].extra_bytes_structs
    # laspy describes them as "undocumented extra bytes" (data type 0), but one byte as an unsigned char (data type 1),
    # with its own description: left in the VLR, that entry would say the added dimensions start a byte further
    structs[:] = [st for st in structs if st.format_name() != UNDESCRIBED_NAME or (st.data_type != 0 and not _laspy_described(st))]
    if not structs:
        header.vlrs.pop(header.vlrs.index("ExtraBytesVlr"))
    return header


def _laspy_described(st: ExtraBytesStruct) -> bool:
    """Whether an extra-bytes entry is laspy's own description of undescribed bytes (not one read from a file)."""
    return bytes(st.description).split(b"\0", 1)[0].decode("ascii", "replace") == UNDESCRIBED_DESCRIPTION


def raw_header(path: str | os.PathLike, waveforms: bool = True) -> tuple[bytes, bytes]:
    """A LAS/LAZ file's header and VLRs, and its extended VLRs (after the points), as raw bytes.

    A LAS 1.3 file's internal waveform data packet record (from the
    header's offset to the end, an EVLR's layout) is its one EVLR.  With
    ``waveforms`` False the waveform record is left out (points that keep
    no wave packet descriptors do not point into it), and the header says
    so: no internal waveform data, no offset to it, one EVLR fewer.
    """
    with open(path, "rb") as f:
        h = laspy.LasHeader.read_from(f)
        f.seek(0)
        head = f.read(h.offset_to_point_data)
        evlrs = b""
        if h.version.minor >= 4 and h.number_of_evlrs > 0:
            f.seek(h.start_of_first_evlr)
            evlrs = f.read()
        elif waves_of_las13(h):
            f.seek(h.start_of_waveform_data_packet_record)
            evlrs = f.read()
    if waveforms or not h.global_encoding.waveform_data_packets_internal:
        return head, evlrs
    head = bytearray(head)
    struct.pack_into("<H", head, 6, struct.unpack_from("<H", head, 6)[0] & ~2)  # global encoding: no internal waveforms
    if h.version.minor >= 3:
        struct.pack_into("<Q", head, 227, 0)  # start of the waveform data packet record
    if h.version.minor < 4:
        return bytes(head), b""
    kept = [r for r in split_evlrs(evlrs, h.number_of_evlrs) if not is_waveform_evlr(r)]
    if len(kept) < h.number_of_evlrs:
        struct.pack_into("<QI", head, 235, h.start_of_first_evlr if kept else 0, len(kept))
    return bytes(head), b"".join(kept)


def waves_of_las13(h: laspy.LasHeader) -> bool:
    """Whether ``h`` is a LAS 1.3 header whose internal waveform data packet record follows the points."""
    return h.version.minor == 3 and bool(h.global_encoding.waveform_data_packets_internal) \
        and int(h.start_of_waveform_data_packet_record or 0) > 0


#: An EVLR's header: reserved, user id, record id, length after the header, description (60 bytes).
_EVLR_HEADER = struct.Struct("<H16sHQ32s")


def split_evlrs(raw: bytes, count: int) -> list[bytes]:
    """The first ``count`` EVLRs of ``raw`` (EVLRs one after the other), each its bytes; fewer where ``raw`` ends."""
    out, at = [], 0
    while len(out) < count and at + _EVLR_HEADER.size <= len(raw):
        size = _EVLR_HEADER.size + _EVLR_HEADER.unpack_from(raw, at)[3]
        out.append(raw[at : at + size])
        at += size
    return out


def is_waveform_evlr(raw: bytes) -> bool:
    """Whether the EVLR ``raw`` (its bytes) is a waveform data packet record (LASF_Spec, record 65535)."""
    _, user, record, _, _ = _EVLR_HEADER.unpack_from(raw, 0)
    return user.rstrip(b"\0") == b"LASF_Spec" and record == 65535


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether ``a`` and ``b`` name one file (same inode: links and other spellings included; else the same resolved path).

    >>> same_file("x/../a.las", "a.las")
    True
    """
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet)
        return Path(a).resolve() == Path(b).resolve()


def check_not_input(output: str | os.PathLike, inputs) -> None:
    """Refuse an output (or store, or report) that is one of the ``inputs``: an input is never replaced, ``--overwrite`` or not.

    >>> check_not_input("out.laz", ["in.laz"])
    >>> check_not_input("in.laz", ["./in.laz"])
    Traceback (most recent call last):
    ...
    patchcloud.core.errors.PatchcloudIOError: in.laz: is the input ./in.laz; give another output (an input is never replaced)
    """
    for i in inputs:
        if same_file(output, i):
            raise PatchcloudIOError(f"{output}: is the input {i}; give another output (an input is never replaced)")


def check_writable(path: str | os.PathLike, overwrite: bool) -> Path:
    """``path`` as a Path, after checking an output can be written there: absent (or ``overwrite``, and then a file: not
    a directory, a device or a pipe, which ``--overwrite`` would have replaced by a file), its directory there and
    writable (a file made and removed there: a read-only mount or directory is refused before any work)."""
    p = Path(path)
    if p.exists() and not p.is_file():
        raise PatchcloudIOError(f"{p}: exists and is not a file (a directory, device or pipe): name a file to write")
    if p.exists() and not overwrite:
        raise PatchcloudExistsError(f"{p}: exists (use --overwrite to replace it)")
    if not p.parent.exists():
        raise PatchcloudIOError(f"{p}: the directory {p.parent} does not exist")
    check_directory_writable(p.parent, p)
    return p


def check_directory_writable(directory: str | os.PathLike, for_path: str | os.PathLike) -> None:
    """A PatchcloudIOError naming ``for_path`` unless a file can be made in ``directory`` (made and removed at once)."""
    import tempfile

    try:
        fd, probe = tempfile.mkstemp(prefix=".patchcloud-probe-", dir=os.fspath(directory))
    except OSError as exc:
        raise PatchcloudIOError(f"{for_path}: cannot write in {directory} ({exc.strerror or exc})") from None
    os.close(fd)
    os.unlink(probe)


@contextmanager
def atomic_output(path: str | os.PathLike, overwrite: bool):
    """Open ``path``'s temporary name ``PATH.partial`` for binary writing; rename it to ``path`` on success, remove it
    on failure.

    The commands that write one file without a lock (``decompress``,
    ``render``, reports, ``--summary-json``) may run twice at once on the
    same output: the temporary file is held with an exclusive ``flock``
    while it is written, so a second run refuses it (one error naming the
    output) instead of writing into the same file, and neither run removes
    a temporary file that is not its own.  The lock ends with its process,
    so a temporary file left by a run that was killed is taken over.
    Without ``overwrite``, a file that another run put at ``path``
    meanwhile is not replaced.

    Raises
    ------
    PatchcloudIOError
        Another run is writing ``path`` now.
    PatchcloudExistsError
        ``path`` exists (at the start, or at the end without ``overwrite``).
    """
    p = check_writable(path, overwrite)
    tmp = partial_path(p)
    fd = _locked_partial(p, tmp)
    try:
        ours = os.fstat(fd).st_ino
        os.ftruncate(fd, 0)
        try:
            with naming_failed_writes(p), os.fdopen(os.dup(fd), "wb") as f:
                yield f
            if not overwrite and p.exists():
                raise PatchcloudExistsError(f"{p}: exists: another run wrote it meanwhile (use --overwrite to replace it)")
            rename_into_place(tmp, p)
        except BaseException:
            try:
                if os.stat(tmp).st_ino == ours:  # still ours: no other run has made its own since
                    tmp.unlink()
            except OSError:
                pass
            raise
    finally:
        os.close(fd)  # (the lock ends with it)


def _locked_partial(p: Path, tmp: Path) -> int:
    """A descriptor of ``tmp`` (made if absent, not truncated) under an exclusive ``flock``, still named ``tmp``: a
    file that another run renamed to its output between our open and our lock is let go, and ``tmp`` opened again."""
    try:
        import fcntl
    except ImportError:  # (Windows: no flock) the temporary file as it is
        return os.open(tmp, os.O_RDWR | os.O_CREAT, 0o666)
    for _ in range(100):
        fd = os.open(tmp, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):  # a file system without locks: as it is
                return fd
            os.close(fd)
            raise PatchcloudIOError(f"{p}: another run is writing it now (its temporary file {tmp.name} is locked)") from None
        try:
            same = os.stat(tmp).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)  # renamed away (another run's finished output): not ours to write
    raise PatchcloudIOError(f"{p}: its temporary file {tmp.name} keeps being replaced by other runs")
