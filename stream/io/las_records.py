"""The VLRs and EVLRs of a LAS file as raw bytes, and the records of the files patchcloud writes.

laspy parses the records it knows (the GeoTIFF keys among them) and writes
them again from what it parsed: the GeoKeyDirectory's key count, for one,
comes back changed (a directory of 21 keys padded to 22 slots is written as
22 keys, and PDAL then fails to make its SRS).  The outputs' records are
therefore taken from the input's bytes: every VLR and EVLR is copied as
it was (its record data byte for byte), except those the output must
change:

- the LASzip VLR (the output's own, for LAZ; none for LAS);
- the ExtraBytes VLR, which gains the new dimensions after the input's
  descriptors (a second ExtraBytes VLR, which readers ignore, is dropped:
  its descriptors would describe the wrong bytes);
- COPC's info VLR and hierarchy EVLR (user id ``copc``), dropped: the
  outputs are LAS/LAZ, not COPC.

A record of ``patchcloud`` (:func:`provenance_vlr`) says what made the file.

>>> r = RawRecord(b"LASF_Projection", 34735, b"GeoTiff GeoKeyDirectoryTag", b"\\x01\\x00")
>>> r.name, kept(r)
('LASF_Projection', True)
"""

from __future__ import annotations

import json
import os
import struct
from dataclasses import dataclass
from typing import TYPE_CHECKING

from patchcloud.core import PatchcloudIOError

if TYPE_CHECKING:  # laspy is imported where a VLR is made: the header fields here are read without it
    import laspy

__all__ = ["RawRecord", "parse_records", "file_records", "kept", "is_extra_bytes", "as_vlr", "provenance_vlr", "PROVENANCE_USER_ID",
           "software_version", "header_record_fields", "stated_point_count", "ascii_text", "VLR_BYTES", "EVLR_BYTES"]

#: The user id and record id of the record saying what made a file (JSON: software, version, job, parameters).
PROVENANCE_USER_ID, PROVENANCE_RECORD_ID = "patchcloud", 1


@dataclass(frozen=True)
class RawRecord:
    """One VLR or EVLR as its bytes: user id and description as stored (NUL-padded), record id, record data."""

    user_id: bytes
    record_id: int
    description: bytes
    data: bytes

    @property
    def name(self) -> str:
        """The user id as text (up to its first NUL)."""
        return self.user_id.split(b"\0", 1)[0].decode("ascii", "replace")


#: The smallest VLR and EVLR (their headers, bytes).
VLR_BYTES, EVLR_BYTES = 54, 60



def stated_point_count(head: bytes) -> int:
    """The point count a LAS/LAZ header states (its first bytes, at least 111): LAS 1.4's 64-bit count when set, else
    the legacy 32-bit one.

    >>> head = bytearray(255); head[25] = 4; head[107:111] = (7).to_bytes(4, "little")
    >>> stated_point_count(bytes(head)), stated_point_count(bytes(head[:247]))
    (7, 7)
    >>> head[247:255] = (5_000_000_000).to_bytes(8, "little"); stated_point_count(bytes(head))
    5000000000
    """
    legacy = int.from_bytes(head[107:111], "little")
    if head[25] >= 4 and len(head) >= 255:
        return int.from_bytes(head[247:255], "little") or legacy
    return legacy


def header_record_fields(head: bytes) -> tuple[int, int, int, int, int]:
    """Header size, offset to the point data, VLR count, start of the first EVLR and EVLR count of a LAS header's
    first bytes (``head``, at least 227); the EVLR fields are 0 where the header has none (before LAS 1.4, or cut short).

    >>> header_record_fields(b"LASF" + bytes(90) + (375).to_bytes(2, "little") + (400).to_bytes(4, "little") + bytes(131))
    (375, 400, 0, 0, 0)
    """
    header_size, offset, vlrs = struct.unpack_from("<HII", head, 94)
    if head[25] >= 4 and header_size >= 375 and len(head) >= 375:
        start, count = struct.unpack_from("<QI", head, 235)
        return header_size, offset, vlrs, start, count
    return header_size, offset, vlrs, 0, 0



def ascii_text(text: str | bytes) -> str:
    r"""``text`` with every character that is not ASCII written as '?' (bytes: decoded as ASCII the same way).

    >>> ascii_text("Géo"), ascii_text(b"G\xe9o")
    ('G?o', 'G?o')
    """
    if isinstance(text, bytes):
        text = text.decode("ascii", "replace").replace("\ufffd", "?")
    return text if text.isascii() else text.encode("ascii", "replace").decode("ascii")


def parse_records(raw: bytes, at: int, count: int, extended: bool, where: str = "") -> list[RawRecord]:
    """``count`` records from byte ``at`` of ``raw``: VLRs (54-byte headers) or, ``extended``, EVLRs (60 bytes).

    Raises
    ------
    PatchcloudIOError
        A record runs past the end of ``raw`` (``where`` names the file).
    """
    out = []
    head = EVLR_BYTES if extended else VLR_BYTES
    for i in range(count):
        if at + head > len(raw):
            raise PatchcloudIOError(f"{where}: {'E' if extended else ''}VLR {i + 1} of {count:,} runs past its bytes")
        user_id, record_id = raw[at + 2 : at + 18], struct.unpack_from("<H", raw, at + 18)[0]
        length = struct.unpack_from("<Q" if extended else "<H", raw, at + 20)[0]
        desc_at = at + (28 if extended else 22)
        end = at + head + length
        if end > len(raw):
            raise PatchcloudIOError(f"{where}: {'E' if extended else ''}VLR {i + 1} of {count:,} runs past its bytes")
        out.append(RawRecord(bytes(user_id), int(record_id), bytes(raw[desc_at : desc_at + 32]), bytes(raw[at + head : end])))
        at = end
    return out


def file_records(path: str | os.PathLike) -> tuple[list[RawRecord], list[RawRecord]]:
    """The VLRs and EVLRs of the LAS/LAZ file ``path`` (already checked by
    :func:`patchcloud.stream.io.las.open_source`), as their bytes."""
    with open(path, "rb") as f:
        header_size, offset, count, start, n = header_record_fields(f.read(375))
        f.seek(0)
        vlrs = parse_records(f.read(offset), header_size, count, False, str(path))
        evlrs: list[RawRecord] = []
        if n:
            f.seek(start)
            evlrs = parse_records(f.read(), 0, n, True, str(path))
    return vlrs, evlrs


def is_extra_bytes(r: RawRecord) -> bool:
    return r.name == "LASF_Spec" and r.record_id == 4


def kept(r: RawRecord) -> bool:
    """Whether an output copies ``r`` as it is: all but the LASzip, ExtraBytes and COPC records."""
    return not (r.name == "laszip encoded" and r.record_id == 22204) and not is_extra_bytes(r) and r.name != "copc"


def as_vlr(r: RawRecord) -> laspy.VLR:
    """A laspy VLR that writes ``r``'s record data byte for byte (laspy would write its parse of a record it knows).

    A user id or description that is not ASCII (LAS texts are) has its other characters written as '?'.
    """
    import laspy

    return laspy.VLR(ascii_text(r.user_id.split(b"\0", 1)[0]), r.record_id, ascii_text(r.description.split(b"\0", 1)[0]), r.data)


def software_version() -> str:
    """patchcloud's version (:mod:`patchcloud.core.version`)."""
    from patchcloud.core import __version__

    return __version__


def provenance_vlr(job: str, parameters: dict) -> laspy.VLR:
    """The VLR saying what made a file: JSON ``{"software": "patchcloud", "version", "job", "parameters"}``.

    User id ``patchcloud``, record id 1; keys sorted, so a run's file is the
    same bytes whenever it is made.

    >>> v = provenance_vlr("normals", {"criterion": "rmse"})
    >>> json.loads(v.record_data)["job"], v.user_id
    ('normals', 'patchcloud')
    """
    data = json.dumps({"software": "patchcloud", "version": software_version(), "job": job, "parameters": parameters},
                      sort_keys=True, separators=(",", ":"), default=str).encode()
    import laspy

    return laspy.VLR(PROVENANCE_USER_ID, PROVENANCE_RECORD_ID, f"patchcloud {job} parameters"[:31], data)
