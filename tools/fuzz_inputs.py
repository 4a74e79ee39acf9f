"""Fuzz the LAS/LAZ header checks and the ``.pcz`` reader: seeded mutated files through the CLI, in a capped child process.

    python tools/fuzz_inputs.py --target {las,pcz,all} --cases N --seed S [--memory-mib 1024] [--seconds 15]
                                [--keep-failures DIR] [--results PATH] [--only CASE_ID ...] [--workdir DIR]

Every case is a file made from a valid seed by one mutation, and one or two
``patchcloud`` commands on it.  What a case must end in (issue 16): exit 0
with an output consistent with its own header, or exit 2 with one line on
stderr (``error: ...``), never a traceback, within a memory cap and a time
cap.  Anything else is a failure of that case: a traceback, an ``internal
error`` line (the CLI's own name for a bug), a MemoryError (raised, or
swallowed into a one-line message: the exception's chain tells), the time
cap, several lines (warnings before the error), another exit status, an
exit 0 whose output disagrees with its header (:func:`check_outputs`) or
that printed warnings, or the child process dying.

Seeds (written afresh in the work directory, the same bytes for the same
versions of laspy and patchcloud):

- ``las``: :data:`LAS_SEEDS`, LAS and LAZ files of point formats 0, 1, 3,
  6, 7 and 8, LAS 1.2 and 1.4, with and without VLRs, EVLRs and extra
  bytes (a few hundred points of the synthetic scene each), and the
  embedded IGN sample (``data/``); mutations: :data:`LAS_KINDS`.
  Commands: ``patchcloud info F`` and, for about one case in
  :data:`NORMALS_EVERY`, ``patchcloud normals F OUT --in-memory -q``.
- ``pcz``: :data:`PCZ_SEEDS`, written by ``patchcloud compress``;
  mutations: :data:`PCZ_KINDS`.  Commands: ``patchcloud info F.pcz`` and
  ``patchcloud decompress F.pcz OUT`` (now and then with ``--lod 2`` or
  ``--density 5``).

Cases
-----
Case ``i`` of a target is a pure function of ``(--seed, target, i)``: its
mutation kind is the ``i``-th of :func:`schedule` (every kind in turn, so
that every kind gets its share of any run; the slow zip bomb in one round of
:data:`RARE_EVERY`), everything else is drawn from a generator seeded with
the three.  ``--cases 100`` is the first hundred cases of ``--cases 5000``,
and ``--only pcz-00042`` reruns one of them.  ``--keep-failures DIR`` keeps
each failing input as ``DIR/ID.las|laz|pcz`` beside ``DIR/ID.json`` (the
mutation, what each command printed, the commands to rerun it).

The child process
-----------------
The cases run in one child process (multiprocessing, ``spawn``) that
imports patchcloud and its CLI, runs every command once on the valid seeds
(numba's kernels compiled or loaded, the thread pools started), then caps
its address space at its size then plus ``--memory-mib``
(``RLIMIT_AS``; numba and the thread pools fail under it at import) and
runs each case's commands in process, with ``main.main(argv)`` in click's
standalone mode (what the ``patchcloud`` script does) and its file
descriptors 1 and 2 sent to files (what lazrs or a logging handler writes
is caught too).  A case's commands share a time cap of ``--seconds``
(``setitimer``; the alarm raises a BaseException, which the CLI's
one-line handler lets through).  A child that dies, or does not answer
within the cap plus :data:`GRACE_SECONDS` (stuck in native code), is
replaced; the case is marked.  After a failure a probe (``info`` on a seed)
checks that the child is still sound, and it is replaced if not.

Outputs are checked here, in the parent: see :func:`check_outputs`.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import functools
import json
import math
import multiprocessing as mp
import os
import random
import resource
import shutil
import signal
import struct
import sys
import tempfile
import time
import traceback
import warnings
import zipfile
import zlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = [
    "LAS_SEEDS", "PCZ_SEEDS", "LAS_KINDS", "PCZ_KINDS", "TARGETS", "RARE_KINDS", "NORMALS_EVERY", "GRACE_SECONDS", "OK_EXIT_0", "OK_EXIT_2",
    "Command", "Case", "Outcome", "Seeds", "Entry", "LasLayout",
    "make_seeds", "las_layout", "read_entries", "write_zip", "deflate_bomb", "schedule", "make_case", "cases", "Child", "judge",
    "check_outputs", "run_fuzz", "table", "failure_lines", "keep_failure", "main",
]

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SAMPLE = ROOT / "data" / "test_data_77055_627760_LA93_IGN69.laz"
#: The embedded sample is a seed only when it is at most this big (bytes): it is copied once per case.
SAMPLE_MAX_BYTES = 1 << 20

#: LAS/LAZ seeds: (file name, point format, LAS version, a VLR, an EVLR, extra bytes).
LAS_SEEDS = (
    ("pf0-v1.2.las", 0, "1.2", False, False, False),
    ("pf1-v1.2-vlr.laz", 1, "1.2", True, False, False),
    ("pf3-v1.2-vlr-extra.las", 3, "1.2", True, False, True),
    ("pf1-v1.4.laz", 1, "1.4", False, False, False),
    ("pf6-v1.4-evlr.las", 6, "1.4", False, True, False),
    ("pf6-v1.4-vlr-evlr.laz", 6, "1.4", True, True, False),
    ("pf7-v1.4-extra.laz", 7, "1.4", False, False, True),
    ("pf8-v1.4-vlr-evlr-extra.las", 8, "1.4", True, True, True),
)
#: Points of every LAS seed (the synthetic scene).
SEED_POINTS = 300
#: ``.pcz`` seeds: (file name, the LAS seed compressed (its points: :data:`PCZ_SOURCE_POINTS`), compress options).
PCZ_SEEDS = (
    ("pf6-v1.4-t32.pcz", "pf6-v1.4-evlr.las", ("--tile-size", "32")),
    ("pf1-v1.2.pcz", "pf1-v1.2-vlr.laz", ()),
    ("pf8-v1.4-t64.pcz", "pf8-v1.4-vlr-evlr-extra.las", ("--tile-size", "64")),
)
PCZ_SOURCE_POINTS = 2000
#: One LAS case in this many (about) also runs ``normals --in-memory``.
NORMALS_EVERY = 5
#: Seconds past the time cap after which a child that has not answered is killed (native code ignores the alarm).
GRACE_SECONDS = 30.0
TARGETS = ("las", "pcz")
OK_EXIT_0, OK_EXIT_2 = "exit 0 consistent", "exit 2 one line"
#: Decompressed points may lie this far outside the tiles the ``.pcz`` declares (metres; those of the seeds lie inside).
BOUNDS_SLACK = 0.1
#: ``decompress``'s promise: a sampled point lies within this share of its tile's edge of its tile
#: (patchcloud.stream.jobs.decompress.TILE_SLACK); the slack judged is the larger of the two.
TILE_SLACK = 0.25
#: An output of more points than this is not read back: the case is inconsistent (the seeds hold a few thousand).
MOST_POINTS_READ = 2_000_000
#: What is kept of a command's stdout and stderr (characters).
KEEP_TEXT = 20_000
MIB = 1 << 20


# -- cases ----------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Command:
    """One ``patchcloud`` command of a case: the subcommand, its options, the suffix of its output file (None: none)."""

    name: str
    options: tuple[str, ...] = ()
    output: str | None = None

    def argv(self, input: Path, output: Path | None) -> list[str]:
        """The command line (without ``patchcloud``) on ``input``, writing ``output``."""
        return [self.name, str(input), *([str(output)] if self.output else []), *self.options]


@dataclass
class Case:
    """A mutated file and the commands to run on it.

    ``id``: ``TARGET-NNNNN`` (the case's index); ``kind``: the mutation
    (a key of :data:`LAS_KINDS` or :data:`PCZ_KINDS`); ``detail``: what it
    changed, in words; ``seed``: the seed's file name; ``data``: the
    file's bytes; ``suffix``: its extension.
    """

    id: str
    target: str
    kind: str
    detail: str
    seed: str
    data: bytes
    suffix: str
    commands: tuple[Command, ...]

    def describe(self) -> dict:
        """The case without its bytes (JSON)."""
        return {"id": self.id, "target": self.target, "kind": self.kind, "detail": self.detail, "seed": self.seed,
                "commands": [dataclasses.asdict(c) for c in self.commands]}


@dataclass
class Outcome:
    """How a case ended: ``verdict`` (:data:`OK_EXIT_0`, :data:`OK_EXIT_2` or a failure class), ``reason`` in words,
    and each command's run (argv, exit, stdout, stderr, seconds, escaped, memory, timeout, exception)."""

    case: Case
    verdict: str
    reason: str
    runs: list[dict] = field(default_factory=list)

    @property
    def failed(self) -> bool:
        """Whether the case failed (anything but exit 0 consistent and exit 2 with one line)."""
        return self.verdict not in (OK_EXIT_0, OK_EXIT_2)

    def to_json(self) -> dict:
        """The case, its verdict, reason and runs (JSON)."""
        return {**self.case.describe(), "verdict": self.verdict, "reason": self.reason, "runs": self.runs}


# -- seeds ----------------------------------------------------------------------------------------------------------------


@dataclass
class Seeds:
    """The seed files of a run, by name: ``las`` and ``pcz`` (name -> bytes), and where they lie."""

    folder: Path
    las: dict[str, bytes]
    pcz: dict[str, bytes]

    def path(self, name: str) -> Path:
        """Where seed ``name`` lies."""
        return self.folder / name

    @functools.cached_property
    def layouts(self) -> dict[str, LasLayout]:
        """The :class:`LasLayout` of each LAS seed."""
        return {name: las_layout(data) for name, data in self.las.items()}


def _scene_las(path: Path, point_format: int, version: str, vlr: bool, evlr: bool, extra: bool, n: int, seed: int) -> None:
    """Write ``n`` points of the synthetic scene as LAS/LAZ (by the name) with the records asked for, dated 2024-01-01."""
    import laspy
    from laspy.vlrs.vlrlist import VLRList
    from synthetic import scene

    pts, _ = scene(n, seed=seed)
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([650000.0, 6860000.0, 0.0])
    header.creation_date = datetime.date(2024, 1, 1)
    if extra:
        header.add_extra_dims([laspy.ExtraBytesParams("FuzzValue", np.float32, description="a fuzz seed's extra bytes"),
                               laspy.ExtraBytesParams("FuzzTag", np.uint16)])
    if vlr:
        header.vlrs.append(laspy.VLR("fuzz", 1, "a fuzz seed VLR", bytes(range(48))))
    if evlr:
        header.evlrs = VLRList([laspy.VLR("fuzz", 2, "a fuzz seed EVLR", bytes(range(100)))])
    las = laspy.LasData(header)
    las.x, las.y, las.z = (pts + [650000.0, 6860000.0, 0.0]).T
    las.intensity = rng.integers(0, 65535, len(pts))
    las.classification = rng.integers(1, 7, len(pts))
    las.return_number, las.number_of_returns = np.ones(len(pts), np.uint8), np.ones(len(pts), np.uint8)
    names = set(las.point_format.dimension_names)
    if "gps_time" in names:
        las.gps_time = np.arange(len(pts), dtype=np.float64) * 1e-4
    for name in ("red", "green", "blue", "nir"):
        if name in names:
            las[name] = rng.integers(0, 65535, len(pts))
    if extra:
        las.FuzzValue = rng.normal(size=len(pts)).astype(np.float32)
        las.FuzzTag = np.arange(len(pts)) % 65535
    las.write(str(path))


def _compress(source: Path, output: Path, options: Iterable[str]) -> None:
    """``patchcloud compress SOURCE OUTPUT -q --in-memory OPTIONS``, in this process."""
    from patchcloud.stream.cli import main

    main.main(["compress", str(source), str(output), "-q", "--in-memory", "--overwrite", *options],
              prog_name="patchcloud", standalone_mode=False)


def make_seeds(folder: Path) -> Seeds:
    """Write the LAS/LAZ seeds, the ``.pcz`` seeds (by ``patchcloud compress``, in this process) and copy the sample.

    Returns
    -------
    Seeds
    """
    folder.mkdir(parents=True, exist_ok=True)
    las, pcz = {}, {}
    for k, (name, pf, version, vlr, evlr, extra) in enumerate(LAS_SEEDS):
        _scene_las(folder / name, pf, version, vlr, evlr, extra, SEED_POINTS, seed=k)
        las[name] = (folder / name).read_bytes()
    if SAMPLE.exists() and SAMPLE.stat().st_size <= SAMPLE_MAX_BYTES:
        las["ign-sample.laz"] = SAMPLE.read_bytes()
        (folder / "ign-sample.laz").write_bytes(las["ign-sample.laz"])
    for name, source, options in PCZ_SEEDS:
        spec = next(s for s in LAS_SEEDS if s[0] == source)
        src = folder / ("source-" + source)
        _scene_las(src, *spec[1:], PCZ_SOURCE_POINTS, seed=7)
        _compress(src, folder / name, options)
        pcz[name] = (folder / name).read_bytes()
    return Seeds(folder, las, pcz)


# -- numbers --------------------------------------------------------------------------------------------------------------


def _edges(rng: random.Random, bits: int, original: int, size: int) -> int:
    """A boundary value of an unsigned field of ``bits`` bits that holds ``original`` in a file of ``size`` bytes."""
    top = (1 << bits) - 1
    values = [0, 1, 2, top, top - 1, top >> 1, (top >> 1) + 1, original - 1, original + 1, original * 2, original // 2,
              original * 1000, size - 1, size, size + 1, rng.randrange(top + 1)]
    return rng.choice([v for v in values if 0 <= v <= top and v != original] or [0])


_ODD_FLOATS = (0.0, -0.0, -0.001, math.nan, math.inf, -math.inf, 1e300, -1e300, 1e-300, 5e-324, 1e9, 2.0**53)
#: Odd JSON values for attributes.
_ODD_JSON = (0, -1, 1, 0.5, 1e-300, 1e308, -1e308, math.nan, math.inf, -math.inf, 2**31, 2**32 - 1, 2**63 - 1, 2**64 + 1,
             10**30, "7", "", None, [], {}, True, [1, 2])


# -- LAS mutations ------------------------------------------------------------------------------------------------------

#: LAS header fields: name -> (byte offset, struct format).
_LAS_FIELDS = {
    "version major": (24, "<B"), "version minor": (25, "<B"), "header size": (94, "<H"), "offset to point data": (96, "<I"),
    "number of VLRs": (100, "<I"), "point format": (104, "<B"), "point record length": (105, "<H"),
    "legacy point count": (107, "<I"), "legacy count of returns 1": (111, "<I"),
    "x scale": (131, "<d"), "y scale": (139, "<d"), "z scale": (147, "<d"),
    "x offset": (155, "<d"), "y offset": (163, "<d"), "z offset": (171, "<d"),
    "max x": (179, "<d"), "min x": (187, "<d"), "max y": (195, "<d"), "min y": (203, "<d"), "max z": (211, "<d"), "min z": (219, "<d"),
    "start of waveform data": (227, "<Q"), "start of first EVLR": (235, "<Q"), "number of EVLRs": (243, "<I"),
    "point count": (247, "<Q"), "count of returns 1": (255, "<Q"),
}


@dataclass(frozen=True)
class LasLayout:
    """Where a LAS file's parts lie (bytes), read with :mod:`struct` alone: its size, version minor, header size, offset to
    the point data, point record length, the offsets of its VLR and EVLR headers, the end of its point data."""

    size: int
    minor: int
    header_size: int
    offset: int
    record: int
    vlrs: tuple[int, ...]
    evlrs: tuple[int, ...]
    points_end: int

    @property
    def has_14_fields(self) -> bool:
        """Whether the header holds LAS 1.4's fields (EVLRs, 64-bit counts)."""
        return self.minor >= 4 and self.header_size >= 375


def las_layout(data: bytes) -> LasLayout:
    """The :class:`LasLayout` of a valid LAS/LAZ file (or of the header and VLRs a ``.pcz`` keeps)."""
    minor = data[25]
    header_size, offset, nvlr = struct.unpack_from("<HII", data, 94)
    record = struct.unpack_from("<H", data, 105)[0]
    vlrs, at = [], header_size
    for _ in range(nvlr):
        if at + 54 > min(offset, len(data)):
            break
        vlrs.append(at)
        at += 54 + struct.unpack_from("<H", data, at + 20)[0]
    evlrs, end = [], len(data)
    if minor >= 4 and header_size >= 375 and len(data) >= 375:
        start, count = struct.unpack_from("<QI", data, 235)
        at, end = start, start if start else len(data)
        for _ in range(count):
            if at + 60 > len(data):
                break
            evlrs.append(at)
            at += 60 + struct.unpack_from("<Q", data, at + 20)[0]
    return LasLayout(len(data), minor, header_size, offset, record, tuple(vlrs), tuple(evlrs), end)


def _set_field(data: bytearray, name: str, value) -> str:
    """Write ``value`` into the header field ``name``; ``name: old -> new``."""
    at, fmt = _LAS_FIELDS[name]
    old = struct.unpack_from(fmt, data, at)[0]
    struct.pack_into(fmt, data, at, value)
    return f"{name} {old!r} -> {value!r}"


def _uint_field(rng: random.Random, data: bytearray, lay: LasLayout, names: list[str]) -> str:
    """One of the unsigned fields ``names`` set to a boundary value."""
    name = rng.choice(names)
    at, fmt = _LAS_FIELDS[name]
    bits = 8 * struct.calcsize(fmt)
    return _set_field(data, name, _edges(rng, bits, struct.unpack_from(fmt, data, at)[0], lay.size))


def _m_point_count(rng, data, lay):
    """The legacy or the LAS 1.4 point count (or count of first returns) at a boundary value."""
    names = ["legacy point count", "legacy count of returns 1"]
    return _uint_field(rng, data, lay, names + (["point count", "point count", "count of returns 1"] if lay.has_14_fields else []))


def _m_data_offset(rng, data, lay):
    """The offset to the point data at a boundary value."""
    return _uint_field(rng, data, lay, ["offset to point data"])


def _m_header_size(rng, data, lay):
    """The header size at a boundary value, or near 227 and 375."""
    return _uint_field(rng, data, lay, ["header size"]) if rng.random() < 0.7 else \
        _set_field(data, "header size", rng.choice([226, 227, 228, 235, 374, 375, 376]))


def _m_vlr_count(rng, data, lay):
    """The number of VLRs at a boundary value."""
    return _uint_field(rng, data, lay, ["number of VLRs"])


def _m_evlr_start(rng, data, lay):
    """The start of the first EVLR (now and then of the waveform data) at a boundary value."""
    return _uint_field(rng, data, lay, ["start of first EVLR", "start of waveform data"] if rng.random() < 0.2 else ["start of first EVLR"])


def _m_evlr_count(rng, data, lay):
    """The number of EVLRs at a boundary value."""
    return _uint_field(rng, data, lay, ["number of EVLRs"])


def _m_point_format(rng, data, lay):
    """Another point format id: 0 to 10, unknown ones, the LAZ bits set."""
    now = data[104]
    values = [v for v in range(11) if v != now] + [11, 63, 127, 128 | now, 64 | now, 255]
    return _set_field(data, "point format", rng.choice(values))


def _m_record_length(rng, data, lay):
    """The point record length one off, tiny, or at a boundary value."""
    if rng.random() < 0.5:
        return _set_field(data, "point record length", rng.choice([0, 1, 20, lay.record - 1, lay.record + 1, lay.record + 2]))
    return _uint_field(rng, data, lay, ["point record length"])


def _float_field(rng: random.Random, data: bytearray, names: list[str]) -> str:
    """One of the float fields ``names`` set to an odd value."""
    return _set_field(data, rng.choice(names), rng.choice(_ODD_FLOATS))


def _m_scale(rng, data, lay):
    """A scale set to 0, a negative, nan, inf, a huge or a subnormal value."""
    return _float_field(rng, data, ["x scale", "y scale", "z scale"])


def _m_offset(rng, data, lay):
    """An offset set to nan, inf, a huge or a tiny value."""
    return _float_field(rng, data, ["x offset", "y offset", "z offset"])


def _m_bounds(rng, data, lay):
    """A bound set to an odd value, or an axis's min and max swapped."""
    if rng.random() < 0.3:  # min and max of an axis swapped
        axis = rng.choice("xyz")
        lo, hi = _LAS_FIELDS[f"min {axis}"][0], _LAS_FIELDS[f"max {axis}"][0]
        data[lo:lo + 8], data[hi:hi + 8] = data[hi:hi + 8], data[lo:lo + 8]
        return f"min {axis} and max {axis} swapped"
    return _float_field(rng, data, [n for n in _LAS_FIELDS if n[:4] in ("max ", "min ")])


def _m_version(rng, data, lay):
    """The version major (0, 2, 255) or minor (0 to 5, 255) changed."""
    if rng.random() < 0.3:
        return _set_field(data, "version major", rng.choice([0, 2, 255]))
    return _set_field(data, "version minor", rng.choice([v for v in (0, 1, 2, 3, 4, 5, 255) if v != lay.minor]))


def _m_vlr_length(rng, data, lay):
    """The record length of a VLR or an EVLR at a boundary value."""
    spots = [(at, "<H", "VLR") for at in lay.vlrs] + [(at, "<Q", "EVLR") for at in lay.evlrs]
    at, fmt, what = rng.choice(spots)
    old = struct.unpack_from(fmt, data, at + 20)[0]
    new = _edges(rng, 8 * struct.calcsize(fmt), old, lay.size)
    struct.pack_into(fmt, data, at + 20, new)
    return f"{what} at byte {at}: record length {old} -> {new}"


def _flip(rng: random.Random, data: bytearray, lo: int, hi: int, most: int) -> str:
    """XOR 1 to ``most`` bytes of ``data[lo:hi]`` with random non-zero values; where, in words."""
    where = sorted(rng.randrange(lo, hi) for _ in range(rng.randint(1, most)))
    for at in where:
        data[at] ^= rng.randrange(1, 256)
    return f"bytes {', '.join(map(str, where))} flipped"


def _m_header_flip(rng, data, lay):
    """Random bytes of the header and VLRs flipped."""
    return _flip(rng, data, 0, min(lay.offset, lay.size), 16)


def _m_data_flip(rng, data, lay):
    """Random bytes of the point data flipped."""
    return _flip(rng, data, lay.offset, min(lay.points_end, lay.size), 8)


def _m_truncate(rng, data, lay):
    """The file cut in its header and VLRs or in its points."""
    cut = rng.randrange(0, lay.offset + 1) if rng.random() < 0.5 else rng.randrange(lay.offset, lay.size)
    del data[cut:]
    return f"cut at byte {cut} of {lay.size}"


def _m_append(rng, data, lay):
    """Random bytes, zeros, copies of the last records or a second signature appended."""
    how = rng.choice(["random", "zeros", "records", "signature"])
    n = rng.randint(1, 4096)
    if how == "records":  # whole records more (copies of the last ones, when the points end the file)
        tail = bytes(data[max(lay.offset, lay.points_end - lay.record * 4) : lay.points_end])
        more = tail * rng.randint(1, 3) or bytes(lay.record)
    else:
        more = {"random": rng.randbytes(n), "zeros": bytes(n), "signature": b"LASF" + rng.randbytes(n)}[how]
    data += more
    return f"{len(more)} bytes of {how} appended"


def _m_none(rng, data, lay):
    """The seed as it is (every other kind is judged against it)."""
    return "unchanged"


def _las_14(lay: LasLayout) -> bool:
    """Seeds with the LAS 1.4 header fields (EVLRs, 64-bit counts)."""
    return lay.has_14_fields


def _any_las(lay: LasLayout) -> bool:
    """Every seed."""
    return True


#: LAS mutation kinds: name -> (mutation(rng, bytearray, layout) -> detail, which seeds it applies to).
LAS_KINDS: dict[str, tuple[Callable, Callable[[LasLayout], bool]]] = {
    "none": (_m_none, _any_las),
    "point-count": (_m_point_count, _any_las),
    "data-offset": (_m_data_offset, _any_las),
    "header-size": (_m_header_size, _any_las),
    "vlr-count": (_m_vlr_count, _any_las),
    "evlr-start": (_m_evlr_start, _las_14),
    "evlr-count": (_m_evlr_count, _las_14),
    "point-format": (_m_point_format, _any_las),
    "record-length": (_m_record_length, _any_las),
    "scale": (_m_scale, _any_las),
    "offset": (_m_offset, _any_las),
    "bounds": (_m_bounds, _any_las),
    "version": (_m_version, _any_las),
    "vlr-length": (_m_vlr_length, lambda lay: bool(lay.vlrs or lay.evlrs)),
    "header-flip": (_m_header_flip, _any_las),
    "data-flip": (_m_data_flip, _any_las),
    "truncate": (_m_truncate, _any_las),
    "append": (_m_append, _any_las),
}


def _las_case(rng: random.Random, case_id: str, kind: str, seeds: Seeds) -> Case:
    """A LAS case of ``kind``: a seed it applies to, mutated; ``info``, and now and then ``normals``."""
    mutate, applies = LAS_KINDS[kind]
    layouts = seeds.layouts
    seed = rng.choice(sorted(n for n, lay in layouts.items() if applies(lay)))
    data = bytearray(seeds.las[seed])
    detail = mutate(rng, data, layouts[seed])
    suffix = Path(seed).suffix
    commands = [Command("info")]
    if rng.randrange(NORMALS_EVERY) == 0:
        commands.append(Command("normals", ("--in-memory", "-q"), suffix))
    return Case(case_id, "las", kind, detail, seed, bytes(data), suffix, tuple(commands))


# -- zip ------------------------------------------------------------------------------------------------------------------


@dataclass
class Entry:
    """A zip entry as written: ``data`` as stored (deflated when ``method`` is 8); ``crc`` and ``size`` those of the
    expanded content (None: of ``data``)."""

    name: str
    data: bytes
    method: int = 0
    crc: int | None = None
    size: int | None = None


def read_entries(blob: bytes) -> list[Entry]:
    """The entries of a zip (a ``.pcz``), in order, their content as stored."""
    import io

    with zipfile.ZipFile(io.BytesIO(blob)) as z:
        return [Entry(i.filename, z.read(i)) for i in z.infolist()]


#: Every entry is dated 1980-01-01 00:00 (DOS date 33, time 0), as the ``.pcz`` writer dates them.
_DOS_DATE, _DOS_TIME = 33, 0


def write_zip(entries: Iterable[Entry]) -> bytes:
    """A zip of ``entries`` in order, written here field by field (no zip64: each entry under 4 GiB expanded).

    Duplicate names, lying sizes and wrong CRCs are written as given: the zip module refuses some of them.
    """
    body, central = bytearray(), bytearray()
    count = 0
    for e in entries:
        name = e.name.encode()
        crc = zlib.crc32(e.data) if e.crc is None else e.crc
        size = len(e.data) if e.size is None else e.size
        head = struct.pack("<IHHHHHIIIHH", 0x04034B50, 20, 0, e.method, _DOS_TIME, _DOS_DATE, crc, len(e.data), size, len(name), 0)
        central += struct.pack("<IHHHHHHIIIHHHHHII", 0x02014B50, 0x0314, 20, 0, e.method, _DOS_TIME, _DOS_DATE, crc,
                               len(e.data), size, len(name), 0, 0, 0, 0, 0o100644 << 16, len(body)) + name
        body += head + name + e.data
        count += 1
    end = struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, count, count, len(central), len(body), 0)
    return bytes(body + central + end)


#: Expanded bytes a zip bomb is built of (one block, compressed once).
BOMB_BLOCK = 16 * MIB
_BOMBS: dict[int, tuple[bytes, int]] = {}


def deflate_bomb(size: int) -> tuple[bytes, int]:
    """A raw deflate stream of ``size`` zero bytes (a multiple of :data:`BOMB_BLOCK`) and their CRC-32; cached.

    After a full flush the compressor starts afresh, so every further block
    compresses to the same bytes: one block is compressed, not ``size``.

    >>> data, crc = deflate_bomb(2 * BOMB_BLOCK)
    >>> d = zlib.decompressobj(-15); n = len(d.decompress(data, 0)); d.eof, n == 2 * BOMB_BLOCK
    (True, True)
    """
    if size not in _BOMBS:
        block = bytes(BOMB_BLOCK)
        c = zlib.compressobj(9, zlib.DEFLATED, -15)
        first = c.compress(block) + c.flush(zlib.Z_FULL_FLUSH)
        again = c.compress(block) + c.flush(zlib.Z_FULL_FLUSH)
        k = size // BOMB_BLOCK
        crc = 0
        for _ in range(k):
            crc = zlib.crc32(block, crc)
        _BOMBS[size] = (first + again * (k - 1) + c.flush(), crc)
    return _BOMBS[size]


# -- .pcz mutations -------------------------------------------------------------------------------------------------------


@dataclass
class _Pcz:
    """A ``.pcz`` being mutated: its entries, and each array's metadata by path."""

    entries: list[Entry]

    def get(self, name: str) -> Entry:
        """The (first) entry named ``name``."""
        return next(e for e in self.entries if e.name == name)

    @property
    def attrs(self) -> dict:
        """The root group's attributes."""
        return json.loads(self.get("zarr.json").data)["attributes"]

    def set_attrs(self, attrs: dict) -> None:
        """Write ``attrs`` into the root group's zarr.json."""
        meta = json.loads(self.get("zarr.json").data)
        meta["attributes"] = attrs
        self.get("zarr.json").data = json.dumps(meta, indent=2).encode()

    @property
    def arrays(self) -> dict[str, dict]:
        """Each array's metadata (its zarr.json) by path."""
        out = {}
        for e in self.entries:
            if e.name.endswith("zarr.json"):
                meta = json.loads(e.data)
                if meta.get("node_type") == "array":
                    out[e.name[: -len("/zarr.json")]] = meta
        return out

    def chunks(self, arrays: Iterable[str] | None = None) -> list[Entry]:
        """Chunk entries (of ``arrays`` only, if given)."""
        names = None if arrays is None else tuple(a + "/c/" for a in arrays)
        return [e for e in self.entries if "/c/" in e.name and (names is None or e.name.startswith(names))]

    def _store(self) -> dict:
        """The entries as the values of a zarr MemoryStore (name -> Buffer)."""
        from zarr.core.buffer import default_buffer_prototype

        buffer = default_buffer_prototype().buffer
        return {e.name: buffer.from_bytes(e.data) for e in self.entries}

    def read_array(self, path: str) -> np.ndarray:
        """Array ``path``'s values."""
        import zarr
        from zarr.storage import MemoryStore

        return zarr.open_array(MemoryStore(self._store(), read_only=True), path=path, mode="r")[...]

    def edit_array(self, path: str, change: Callable[[np.ndarray], np.ndarray]) -> None:
        """Replace array ``path``'s values by ``change(values)`` (its shape may change), re-encoded by zarr."""
        import zarr
        from zarr.storage import MemoryStore

        held = self._store()
        a = zarr.open_array(MemoryStore(held), path=path, mode="r+")
        values = np.asarray(change(a[...].copy()), dtype=a.dtype)
        if values.shape != a.shape:
            a.resize(values.shape)
        if values.size:
            a[...] = values
        self.entries = [Entry(name, held[name].to_bytes()) for name in sorted(held)]


def _attr_value(rng: random.Random, old) -> object:
    """An odd value for an attribute that holds ``old``: near it, or from :data:`_ODD_JSON`."""
    if isinstance(old, (int, float)) and not isinstance(old, bool) and rng.random() < 0.4:
        return rng.choice([old + 1, old - 1, old * 1000, -old, old * 1e-9])
    return rng.choice(_ODD_JSON)


def _p_attrs_counts(rng, p):
    """An attribute of ``counts`` (or ``counts`` itself) set to an odd value or removed."""
    a = p.attrs
    key = rng.choice([*a["counts"], "counts"])
    if key == "counts":
        a["counts"] = rng.choice([None, {}, [], 0, "counts"])
        detail = f"counts -> {a['counts']!r}"
    elif rng.random() < 0.1:
        del a["counts"][key]
        detail = f"counts.{key} removed"
    else:
        old = a["counts"][key]
        a["counts"][key] = _attr_value(rng, old)
        detail = f"counts.{key} {old!r} -> {a['counts'][key]!r}"
    p.set_attrs(a)
    return detail


def _p_attrs_grid(rng, p):
    """``grid``'s tile size, origin, scale or offset set to 0, negative, nan, inf, huge or the wrong type or length."""
    a = p.attrs
    key = rng.choice(["tile_size", "tile_size", "origin", "scale", "offset", "grid"])
    if key == "grid":
        a["grid"] = rng.choice([None, {}, [], 1.0])
        detail = f"grid -> {a['grid']!r}"
    elif key == "tile_size":
        old = a["grid"]["tile_size"]
        a["grid"]["tile_size"] = rng.choice([0, -old, math.nan, math.inf, 1e308, 1e-300, old / 2, old * 2, 2**70, "16", None])
        detail = f"grid.tile_size {old!r} -> {a['grid']['tile_size']!r}"
    else:
        old = list(a["grid"][key])
        how = rng.choice(["component", "length", "whole"])
        if how == "component":
            axis = rng.randrange(3)
            a["grid"][key][axis] = rng.choice([0, -old[axis], math.nan, math.inf, -math.inf, 1e308, 1e-300, 2 * old[axis] + 1])
        elif how == "length":
            a["grid"][key] = old[: rng.randrange(3)] if rng.random() < 0.5 else old + [1.0]
        else:
            a["grid"][key] = rng.choice([None, 0, "x", {}])
        detail = f"grid.{key} {old!r} -> {a['grid'][key]!r}"
    p.set_attrs(a)
    return detail


def _p_attrs_other(rng, p):
    """``record_bytes``, ``max_error``, ``version``, ``source`` or ``format`` set to an odd value."""
    a = p.attrs
    key = rng.choice(["record_bytes", "record_bytes", "max_error", "max_error", "version", "source", "format"])
    old = a.get(key)
    if key == "version":
        a[key] = rng.choice([1, 3, "2", 2.0, None, -2, 2**64])
    elif key == "source":
        sub = rng.choice(["point_count", "point_format", "version", "mins", "path", "crs"])
        a[key] = rng.choice([None, {}, [], 1]) if rng.random() < 0.2 else {**old, sub: _attr_value(rng, old.get(sub))}
    elif key == "format":
        a[key] = rng.choice([None, "patchcloud-PCZ", 1])
    else:
        a[key] = _attr_value(rng, old)
    p.set_attrs(a)
    return f"{key} {old!r} -> {a[key]!r}"


_DATA_TYPES = ("bool", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "float32", "float64",
               "complex128", "string", "no-such-type")


def _p_array_meta(rng, p):
    """An array's zarr.json changed: shape, chunk shape, data type, codecs, fill value or node type."""
    path = rng.choice(sorted(p.arrays))
    entry = p.get(path + "/zarr.json")
    meta = json.loads(entry.data)
    what = rng.choice(["shape", "shape", "chunk_shape", "data_type", "codecs", "fill_value", "node"])
    if what == "shape":
        old = meta["shape"][0]
        meta["shape"][0] = rng.choice([0, old + 1, max(old - 1, 0), old * 1000, 2**40, 2**62, -1])
        detail = f"{path} shape[0] {old} -> {meta['shape'][0]}"
    elif what == "chunk_shape":
        shape = meta["chunk_grid"]["configuration"]["chunk_shape"]
        old = shape[0]
        shape[0] = rng.choice([0, 1, old + 1, 2**31, 2**62, -1])
        detail = f"{path} chunk_shape[0] {old} -> {shape[0]}"
    elif what == "data_type":
        old = meta["data_type"]
        meta["data_type"] = rng.choice([t for t in _DATA_TYPES if t != old])
        detail = f"{path} data_type {old} -> {meta['data_type']}"
    elif what == "codecs":
        detail = f"{path} codecs: " + _odd_codecs(rng, meta)
    elif what == "fill_value":
        meta["fill_value"] = rng.choice(["NaN", 2**70, -1, None, "x", [0]])
        detail = f"{path} fill_value -> {meta['fill_value']!r}"
    else:
        key, value = rng.choice([("node_type", "group"), ("zarr_format", 2), ("zarr_format", 4), ("chunk_key_encoding", {"name": "v2"})])
        meta[key] = value
        detail = f"{path} {key} -> {value!r}"
    entry.data = json.dumps(meta, indent=2).encode()
    return detail


def _odd_codecs(rng: random.Random, meta: dict) -> str:
    """``meta``'s codecs changed (none, no compressor, big endian, unknown, another, twice); how, in words."""
    codecs = meta["codecs"]
    how = rng.choice(["none", "drop compressor", "big endian", "unknown", "gzip", "blosc typesize", "twice"])
    if how == "none":
        meta["codecs"] = []
    elif how == "drop compressor":
        meta["codecs"] = codecs[:1]
    elif how == "big endian":
        codecs[0]["configuration"] = {"endian": "big"}
    elif how == "unknown":
        codecs.append({"name": "no-such-codec"})
    elif how == "gzip":
        meta["codecs"] = codecs[:1] + [{"name": "gzip", "configuration": {"level": 5}}]
    elif how == "blosc typesize":
        meta["codecs"] = codecs[:1] + [{"name": "blosc", "configuration": {"typesize": 0, "cname": "zstd", "clevel": 9,
                                                                            "shuffle": "shuffle", "blocksize": 0}}]
    else:
        meta["codecs"] = codecs + codecs[1:]
    return how


def _index_change(rng: random.Random, values: np.ndarray) -> tuple[np.ndarray, str]:
    """``tiles/*_start`` values made non-monotonic, negative, beyond their arrays, ...; what, in words."""
    v = values.copy()
    n = v.shape[0]
    how = rng.choice(["swap", "last + 1", "last huge", "first -1", "one min", "zeros", "reversed", "last max", "middle huge"])
    if how == "swap" and n > 2:
        i = rng.randrange(1, n - 1)
        v[i], v[i + 1] = v[i + 1] + 1, v[i]
    elif how == "last + 1":
        v[-1] += 1
    elif how == "last huge":
        v[-1] = rng.choice([2**40, 2**62])
    elif how == "first -1":
        v[0] = -1
    elif how == "one min":
        v[rng.randrange(n)] = np.iinfo(np.int64).min
    elif how == "zeros":
        v[:] = 0
    elif how == "reversed":
        v = v[::-1].copy()
    elif how == "last max":
        v[-1] = np.iinfo(np.int64).max
    else:
        v[n // 2] = 2**40
    return v, how


def _ijk_change(rng: random.Random, values: np.ndarray) -> tuple[np.ndarray, str]:
    """``tiles/ijk`` with a tile moved to a huge or negative index, or onto another tile; what, in words."""
    v = values.copy()
    t = rng.randrange(v.shape[0])
    how = rng.choice(["huge", "negative huge", "int32 edge", "duplicate"])
    if how == "duplicate" and v.shape[0] > 1:
        v[t] = v[(t + 1) % v.shape[0]]
    else:
        v[t, rng.randrange(3)] = {"huge": 2**62, "negative huge": -(2**63), "int32 edge": 2**31}.get(how, 2**62)
    return v, f"tile {t} {how}"


def _p_chunk_index(rng, p):
    """A ``tiles/*`` array re-encoded with crafted values (non-monotonic, negative, beyond the arrays, huge tiles)."""
    path = rng.choice(["tiles/ijk", "tiles/patch_start", "tiles/cell_start", "tiles/residual_start", "tiles/residual_byte_start"])
    said = []

    def change(v):
        new, how = (_ijk_change if path == "tiles/ijk" else _index_change)(rng, v)
        said.append(how)
        return new

    p.edit_array(path, change)
    return f"{path}: {said[0]}"


#: Crafted values per array: path -> values one of them (or all its elements) is set to.
_CELL_VALUES = {
    "cells/count": (2**32 - 1, 2**31, 0, 10**9), "cells/level": (255, 0, 21, 22, 40, 64), "cells/ijk": (-1, 2**31 - 1, -(2**31), 1 << 20),
    "cells/extent": (-(2**31), 2**31 - 1, 0, -1), "cells/mask": (0, 2**64 - 1), "cells/classification": (255, 0),
    "cells/intensity": (65535,),
    "patches/cells": (2**32 - 1, 0, 2**31, 1000), "patches/scale": (-128, 127, 0, -1), "patches/centroid": (2**31 - 1, -(2**31)),
    "patches/rotation": (2**31 - 1, -(2**31), 0), "patches/coeffs": (2**63 - 1, -(2**63), 2**40),
    "patches/rmse": (math.nan, math.inf, -1.0, 3e38),
}


def _crafted(rng: random.Random, paths: list[str], p: _Pcz) -> str:
    """One of the arrays ``paths`` re-encoded with a crafted value (in one row, every row, or a row plus one)."""
    path = rng.choice(paths)
    value = rng.choice(_CELL_VALUES[path])
    where = rng.choice(["one", "one", "all", "plus one"])
    said = []

    def change(v):
        if v.shape[0] == 0:
            said.append("empty")
            return v
        row = rng.randrange(v.shape[0])
        if where == "all":
            v[...] = value
            said.append(f"all = {value!r}")
        elif where == "plus one" and np.issubdtype(v.dtype, np.integer):
            v[row] = v[row] + 1
            said.append(f"row {row} + 1")
        else:
            v[row] = value
            said.append(f"row {row} = {value!r}")
        return v

    p.edit_array(path, change)
    return f"{path}: {said[0]}"


def _p_chunk_cells(rng, p):
    """A ``cells/*`` array re-encoded with a value at its type's limits (count 2**32 - 1, level 255, ...)."""
    return _crafted(rng, [k for k in _CELL_VALUES if k.startswith("cells/")], p)


def _p_chunk_patches(rng, p):
    """A ``patches/*`` array re-encoded with a value at its limits (cells inflated, scale -128, coeffs 2**63 - 1, ...)."""
    return _crafted(rng, [k for k in _CELL_VALUES if k.startswith("patches/")], p)


def _p_chunk_residual(rng, p):
    """A tile's residual LAZ bytes flipped, a header field of it changed, zeroed, or the array cut."""
    starts = p.read_array("tiles/residual_byte_start")
    tiles = [t for t in range(len(starts) - 1) if starts[t + 1] > starts[t]]
    t = rng.choice(tiles)
    a, b = int(starts[t]), int(starts[t + 1])
    how = rng.choice(["flip", "flip", "field", "zeros", "cut"])
    said = []

    def change(v):
        seg = bytearray(v[a:b].tobytes())
        if how == "flip":
            said.append(_flip(rng, seg, 0, len(seg), 8))
        elif how == "field":
            said.append(_uint_field(rng, seg, las_layout(bytes(seg)), ["legacy point count", "point count", "offset to point data",
                                                                       "header size", "number of VLRs", "point record length"]))
        elif how == "zeros":
            seg = bytearray(len(seg))
            said.append("zeroed")
        else:
            cut = rng.randrange(a, b)
            said.append(f"the array cut at byte {cut}")
            return v[:cut]
        v[a:b] = np.frombuffer(bytes(seg), np.uint8)
        return v

    p.edit_array("residual/laz", change)
    return f"tile {t}'s residual LAZ (bytes {a} to {b}): {said[0]}"


#: The LAS mutations applied to the header a ``.pcz`` keeps.
_HEADER_KINDS = ("point-count", "data-offset", "header-size", "vlr-count", "evlr-start", "evlr-count", "point-format",
                 "record-length", "scale", "offset", "version", "vlr-length", "header-flip")


def _p_chunk_header(rng, p):
    """The LAS header the ``.pcz`` keeps changed as a LAS kind does, or cut; or its EVLRs flipped or cut."""
    has_evlrs = p.arrays["evlrs"]["shape"][0] > 0
    what = rng.choice(["field"] * 6 + ["cut", "evlrs"] if has_evlrs else ["field"] * 6 + ["cut"])
    said = []

    def header(v):
        data = bytearray(v.tobytes())
        if what == "cut":
            cut = rng.randrange(0, len(data))
            said.append(f"header cut to {cut} bytes")
            return np.frombuffer(bytes(data[:cut]), np.uint8)
        lay = las_layout(bytes(data))
        kinds = [k for k in _HEADER_KINDS if LAS_KINDS[k][1](lay) and (k != "vlr-length" or lay.vlrs)]
        kind = rng.choice(kinds)
        said.append(f"header {kind}: " + LAS_KINDS[kind][0](rng, data, lay))
        return np.frombuffer(bytes(data), np.uint8)

    def evlrs(v):
        data = bytearray(v.tobytes())
        if rng.random() < 0.5:
            said.append("evlrs " + _flip(rng, data, 0, len(data), 8))
        else:
            cut = rng.randrange(0, len(data))
            said.append(f"evlrs cut to {cut} bytes")
            data = data[:cut]
        return np.frombuffer(bytes(data), np.uint8)

    p.edit_array("evlrs" if what == "evlrs" else "header", evlrs if what == "evlrs" else header)
    return said[0]


def _p_chunk_flip(rng, p):
    """Random bytes of a chunk flipped (the zip's CRC made to match)."""
    e = rng.choice(p.chunks())
    data = bytearray(e.data)
    detail = _flip(rng, data, 0, len(data), 8)
    e.data = bytes(data)
    return f"{e.name}: {detail}"


def _blosc_arrays(p: _Pcz) -> list[str]:
    """The arrays compressed by Blosc."""
    return [path for path, meta in p.arrays.items() if any(c.get("name") == "blosc" for c in meta.get("codecs", []))]


def _p_blosc_nbytes(rng, p):
    """The Blosc header of a chunk claiming a huge (or zero) nbytes, blocksize or cbytes."""
    e = rng.choice(p.chunks(_blosc_arrays(p)))
    data = bytearray(e.data)
    at, name = rng.choice([(4, "nbytes")] * 4 + [(8, "blocksize"), (12, "cbytes")])
    old = struct.unpack_from("<I", data, at)[0]
    new = rng.choice([2**31 - 1, 2**32 - 1, 2**31, 2**30, old * 1000, old + 1, 0])
    struct.pack_into("<I", data, at, new)
    e.data = bytes(data)
    return f"{e.name}: Blosc {name} {old} -> {new}"


#: Zip bomb sizes (bytes expanded): past the default memory cap, and inflated by every read in about 2.5 s here.
BOMB_SIZES = (1 << 30,)


def _p_zip_bomb(rng, p):
    """An entry replaced by a deflated one expanding to :data:`BOMB_SIZES` (its CRC right or wrong, its size told or not)."""
    names = [e.name for e in p.entries]
    r = rng.random()
    name = "zarr.json" if r < 0.2 else rng.choice([n for n in names if n.endswith("/zarr.json")] if r < 0.5 else
                                                 [e.name for e in p.chunks()])
    size = rng.choice(BOMB_SIZES)
    data, crc = deflate_bomb(size)
    how = rng.choice(["honest", "honest", "honest", "wrong crc", "says small"])
    e = p.get(name)
    e.data, e.method = data, 8
    e.crc = crc if how != "wrong crc" else crc ^ 1
    e.size = size if how != "says small" else 1000
    return f"{name}: deflated to {len(data):,} bytes expanding to {size:,} ({how})"


def _p_entry_drop(rng, p):
    """An entry left out."""
    e = rng.choice(p.entries)
    p.entries.remove(e)
    return f"{e.name} dropped"


def _p_entry_dup(rng, p):
    """An entry written twice (the same or other content)."""
    e = rng.choice(p.entries)
    twin = Entry(e.name, e.data if rng.random() < 0.3 else rng.choice(p.entries).data)
    at = p.entries.index(e) + 1 if rng.random() < 0.5 else len(p.entries)
    p.entries.insert(at, twin)
    return f"{e.name} twice ({'same' if twin.data == e.data else 'other'} content, at {at})"


def _truncate_zip(rng: random.Random, blob: bytes) -> tuple[bytes, str]:
    """The zip cut at a random length."""
    cut = rng.randrange(0, len(blob))
    return blob[:cut], f"cut at byte {cut} of {len(blob)}"


def _garbage_zip(rng: random.Random, blob: bytes) -> tuple[bytes, str]:
    """Garbage appended or prepended, bytes of the central directory, of a local header or anywhere flipped, or a random
    file that starts as a zip."""
    data = bytearray(blob)
    how = rng.choice(["append", "prepend", "central directory", "local header", "random zip", "flips"])
    if how == "append":
        data += rng.randbytes(rng.randint(1, 65536))
    elif how == "prepend":
        data[:0] = rng.randbytes(rng.randint(1, 4096))
    elif how == "central directory":
        how += ": " + _flip(rng, data, len(data) - len(data) // 8, len(data), 32)
    elif how == "local header":
        at = rng.choice([i for i in range(len(data) - 4) if data[i : i + 4] == b"PK\x03\x04"])
        how += ": " + _flip(rng, data, at, at + 30, 8)
    elif how == "random zip":
        data = bytearray(b"PK\x03\x04" + rng.randbytes(rng.randint(1, 65536)))
    else:
        how += ": " + _flip(rng, data, 0, len(data), 32)
    return bytes(data), how


def _p_none(rng, p):
    """The seed as it is (every other kind is judged against it)."""
    return "unchanged"


#: ``.pcz`` mutation kinds: name -> mutation(rng, _Pcz) -> detail, or for the whole-file kinds (rng, bytes) -> (bytes, detail).
PCZ_KINDS: dict[str, Callable] = {
    "none": _p_none,
    "attrs-counts": _p_attrs_counts,
    "attrs-grid": _p_attrs_grid,
    "attrs-other": _p_attrs_other,
    "array-meta": _p_array_meta,
    "chunk-index": _p_chunk_index,
    "chunk-cells": _p_chunk_cells,
    "chunk-patches": _p_chunk_patches,
    "chunk-residual": _p_chunk_residual,
    "chunk-header": _p_chunk_header,
    "chunk-flip": _p_chunk_flip,
    "blosc-nbytes": _p_blosc_nbytes,
    "zip-bomb": _p_zip_bomb,
    "entry-drop": _p_entry_drop,
    "entry-dup": _p_entry_dup,
    "zip-truncate": _truncate_zip,
    "garbage": _garbage_zip,
}
_WHOLE_FILE = {"zip-truncate", "garbage"}


def _decompress_command(rng: random.Random) -> Command:
    """``decompress``: as it is (most often), ``--lod 2`` or ``--density 5``; to LAZ or LAS."""
    r = rng.random()
    options = ("-q",) if r < 0.6 else ("-q", "--lod", "2") if r < 0.8 else ("-q", "--density", "5")
    return Command("decompress", options, rng.choice([".laz", ".las"]))


def _pcz_case(rng: random.Random, case_id: str, kind: str, seeds: Seeds) -> Case:
    """A ``.pcz`` case of ``kind``: a seed, mutated; ``info`` and a ``decompress``."""
    seed = rng.choice(sorted(seeds.pcz))
    blob = seeds.pcz[seed]
    if kind in _WHOLE_FILE:
        data, detail = PCZ_KINDS[kind](rng, blob)
    else:
        p = _Pcz(read_entries(blob))
        detail = PCZ_KINDS[kind](rng, p)
        data = write_zip(p.entries)
    return Case(case_id, "pcz", kind, detail, seed, data, ".pcz", (Command("info"), _decompress_command(rng)))


# -- generation -----------------------------------------------------------------------------------------------------------


#: Kinds slow to run (seconds a case), taken in one round of :data:`RARE_EVERY` only.
RARE_KINDS = frozenset({"zip-bomb"})
RARE_EVERY = 3


def schedule(target: str) -> list[str]:
    """The kinds of ``target`` in the order cases take them, again and again: each kind once per round, a kind of
    :data:`RARE_KINDS` in the first of every :data:`RARE_EVERY` rounds only.

    >>> s = schedule("pcz"); s[: len(PCZ_KINDS)] == list(PCZ_KINDS), s.count("zip-bomb"), s.count("garbage")
    (True, 1, 3)
    """
    kinds = list(LAS_KINDS if target == "las" else PCZ_KINDS)
    return [k for r in range(RARE_EVERY) for k in kinds if r == 0 or k not in RARE_KINDS]


def make_case(target: str, index: int, seed: int, seeds: Seeds) -> Case:
    """Case ``index`` of ``target`` for run seed ``seed``: its kind by :func:`schedule`, the rest drawn from
    ``(seed, target, index)``."""
    kinds = schedule(target)
    kind = kinds[index % len(kinds)]
    rng = random.Random(f"{seed}/{target}/{index}")
    make = _las_case if target == "las" else _pcz_case
    return make(rng, f"{target}-{index:05d}", kind, seeds)


def cases(targets: Iterable[str], count: int | dict[str, int], seed: int, seeds: Seeds, only: Iterable[str] = ()) -> Iterator[Case]:
    """The first ``count`` cases of each target (``count[target]`` for a dict), or only the case ids ``only``, made one
    at a time."""
    only = list(only)
    for target in targets:
        n = count[target] if isinstance(count, dict) else count
        indices = [int(c.split("-")[1]) for c in only if c.startswith(target + "-")] if only else range(n)
        for i in indices:
            yield make_case(target, i, seed, seeds)


# -- the child process ------------------------------------------------------------------------------------------------


class _Timeout(BaseException):
    """A case ran past its time cap (a BaseException: the CLI turns every Exception into one line)."""


_ARMED = False  # the alarm raises only while a command runs: never inside this harness's own bookkeeping
_EXPIRED = False


def _on_alarm(signum, frame) -> None:
    """SIGALRM: the case is past its time cap (raise only while a command runs)."""
    global _EXPIRED
    _EXPIRED = True
    if _ARMED:
        raise _Timeout()


def _vm_kib(key: str = "VmSize") -> int:
    """A field of /proc/self/status, in KiB."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1])
    return 0


def _status(code) -> int:
    """The exit status of a SystemExit's code (as the interpreter would exit)."""
    if code is None:
        return 0
    return code if isinstance(code, int) else 1


def _call(main, argv: list[str]) -> tuple[int | None, BaseException | None, bool]:
    """Run the CLI once: (exit status (None: timed out), the exception that ended it, whether it escaped the CLI).

    An exception that escapes is printed as the interpreter would (a traceback on stderr).
    """
    global _ARMED
    try:
        try:
            _ARMED = True
            main.main(argv, prog_name="patchcloud")
            return 0, None, False
        finally:
            _ARMED = False
    except SystemExit as exc:
        return _status(exc.code), exc, False
    except _Timeout as exc:
        return None, exc, False
    except BaseException as exc:  # noqa: BLE001 - what a real process would die of, with a traceback
        traceback.print_exc()
        return 1, exc, True


def _chain(exc: BaseException | None) -> Iterator[BaseException]:
    """``exc`` and every exception it was raised from or while handling."""
    seen = set()
    todo = [exc]
    while todo:
        e = todo.pop()
        if e is None or id(e) in seen:
            continue
        seen.add(id(e))
        yield e
        todo += [e.__cause__, e.__context__]


def _text(f) -> str:
    """What a capture file holds, decoded, cut at :data:`KEEP_TEXT` characters."""
    f.seek(0)
    return f.read(KEEP_TEXT * 4).decode("utf-8", "replace")[:KEEP_TEXT]


def _invoke(main, argv: list[str]) -> dict:
    """Run one command with fds 1 and 2 sent to files; what happened (see :class:`Outcome`)."""
    t0 = time.perf_counter()
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        sys.stdout.flush()
        sys.stderr.flush()
        saved = os.dup(1), os.dup(2)
        os.dup2(out.fileno(), 1)
        os.dup2(err.fileno(), 2)
        try:
            with warnings.catch_warnings():  # a fresh registry: each warning is shown once per command, as per process
                code, exc, escaped = _call(main, argv)
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])
        from patchcloud.core import PatchcloudMemoryError  # a refusal before allocating (the budget), not a MemoryError

        chain = list(_chain(exc))
        return {
            "argv": argv, "exit": code, "stdout": _text(out), "stderr": _text(err), "seconds": round(time.perf_counter() - t0, 3),
            "escaped": escaped, "timeout": _EXPIRED or code is None,
            "memory": any(isinstance(e, MemoryError) and not isinstance(e, PatchcloudMemoryError) for e in chain),
            "exception": " <- ".join(f"{type(e).__name__}" for e in chain if not isinstance(e, SystemExit)),
        }


def _run_case(main, argvs: list[list[str]], seconds: float) -> list[dict]:
    """Run a case's commands under one time cap."""
    global _EXPIRED
    _EXPIRED = False
    runs = []
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        for argv in argvs:
            runs.append(_invoke(main, argv))
            if runs[-1]["timeout"]:
                break
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
    return runs


def _serve(conn, memory_mib: int, warm: list[list[str]]) -> None:
    """The child: import, warm up, cap the address space, then run the cases the parent sends until it sends None."""
    from patchcloud.stream.cli import main
    import patchcloud.stream  # noqa: F401 - what the commands import lazily

    for _ in range(2):  # twice: the thread pools and arenas of a second run are there too
        for argv in warm:
            run = _invoke(main, argv)
            if run["exit"] != 0:
                conn.send({"error": f"patchcloud {' '.join(argv)} exited {run['exit']} on a valid seed: {run['stderr'][-2000:]}"})
                return
    size = _vm_kib() * 1024
    limit = size + memory_mib * MIB
    resource.setrlimit(resource.RLIMIT_AS, (limit, resource.getrlimit(resource.RLIMIT_AS)[1]))
    signal.signal(signal.SIGALRM, _on_alarm)
    conn.send({"vm_bytes": size, "limit_bytes": limit})
    while (message := conn.recv()) is not None:
        argvs, seconds = message
        runs = _run_case(main, argvs, seconds)
        for r in runs:
            r["vm_kib"] = _vm_kib()
        conn.send(runs)


class Child:
    """The capped child process that runs the cases; replaced when it dies or hangs.

    Parameters
    ----------
    memory_mib : int
        Address space it may add after its warm-up (MiB).
    seconds : float
        Time cap of a case.
    warm : list of argv
        Commands run on valid seeds before the cap (their output files overwritten).
    """

    def __init__(self, memory_mib: int, seconds: float, warm: list[list[str]]):
        self.memory_mib, self.seconds, self.warm = memory_mib, seconds, warm
        self.process = self.conn = None
        self.started = 0
        self.info: dict = {}

    def start(self) -> None:
        """Start the child; wait until it is warm and capped (:attr:`info`: its size and limit)."""
        ctx = mp.get_context("spawn")
        self.conn, theirs = ctx.Pipe()
        self.process = ctx.Process(target=_serve, args=(theirs, self.memory_mib, self.warm), daemon=True)
        self.process.start()
        theirs.close()
        if not self.conn.poll(900):
            self.stop()
            raise RuntimeError("the fuzz child did not start within 900 s")
        try:
            self.info = self.conn.recv()
        except EOFError:
            raise RuntimeError(f"the fuzz child died while starting (exit {self.process.exitcode})") from None
        if "error" in self.info:
            self.stop()
            raise RuntimeError(f"the fuzz child's warm-up failed: {self.info['error']}")
        self.started += 1

    def run(self, argvs: list[list[str]]) -> list[dict] | str:
        """The runs of a case's commands, or what happened to the child (then replaced) in words."""
        if self.process is None:
            self.start()
        self.conn.send((argvs, self.seconds))
        if self.conn.poll(self.seconds + GRACE_SECONDS):
            try:
                return self.conn.recv()
            except EOFError:
                pass
            self.process.join(5)
            what = f"the child died (exit status {self.process.exitcode}{_signal_name(self.process.exitcode)})"
        else:
            what = f"the child did not answer within {self.seconds + GRACE_SECONDS:g} s (stuck in native code?): killed"
        self.stop()
        return what

    def stop(self) -> None:
        """Ask the child to end (kill it if it does not)."""
        if self.process is not None:
            if self.process.is_alive():
                try:
                    self.conn.send(None)
                except OSError:
                    pass
                self.process.join(5)
            if self.process.is_alive():
                self.process.kill()
                self.process.join(5)
        self.process = None


def _signal_name(code: int | None) -> str:
    """``, SIGNAME`` for a process killed by a signal (negative exit code), else ''."""
    if code is not None and code < 0:
        try:
            return f", {signal.Signals(-code).name}"
        except ValueError:
            pass
    return ""


# -- judging ------------------------------------------------------------------------------------------------------------


def _lines(text: str) -> list[str]:
    """The non-blank lines of ``text``."""
    return [line for line in text.splitlines() if line.strip()]


def _judge_run(run: dict, seconds: float) -> tuple[str, str] | None:
    """The failure class of one command's run and why, or None when it ended as allowed (exit 0 is checked apart)."""
    err = _lines(run["stderr"])
    last = err[-1] if err else ""
    if run["timeout"]:
        return "timeout", f"past the {seconds:g} s cap"
    if run["memory"]:
        return "memory", f"MemoryError under the cap ({run['exception']}): {last[:300]}"
    if run["escaped"] or any(line.startswith("Traceback (most recent call last)") for line in err):
        return "traceback", f"{run['exception'] or 'traceback on stderr'}: {last[:300]}"
    if run["exit"] == 2:
        if len(err) != 1:
            return ("several lines", f"{len(err)} lines: {' | '.join(err)[:300]}") if err else ("no message", "exit 2, nothing on stderr")
        if err[0].startswith("error: internal error:"):
            return "internal error", err[0][:400]
        return None if err[0].startswith("error: ") else ("odd message", err[0][:300])
    if run["exit"] == 0:
        return None
    return f"exit {run['exit']}", last[:300]


def _judge_command(case: Case, command: Command, run: dict, paths: dict[str, Path], seconds: float) -> tuple[str, str] | None:
    """The failure class of a command and why, or None when it ended as allowed."""
    bad = _judge_run(run, seconds)
    if bad is None and run["exit"] == 0:
        problem = check_outputs(case, command, run, paths)
        if problem:
            bad = "inconsistent", problem
        elif run["stderr"].strip():  # a quiet command that exits 0 says nothing on stderr unless something went wrong
            bad = "exit 0 with stderr", " | ".join(_lines(run["stderr"]))[:300]
    return bad


def judge(case: Case, runs: list[dict] | str, paths: dict[str, Path], seconds: float) -> Outcome:
    """The outcome of a case from its runs (or what happened to the child), its outputs checked against its input.

    The verdict is the failure class of its first failing command (the
    reason names every failing one), else :data:`OK_EXIT_0` when every
    command exited 0, else :data:`OK_EXIT_2`.
    """
    if isinstance(runs, str):
        return Outcome(case, "child died" if "died" in runs else "hang", runs, [])
    failures = [(c.name, bad) for c, r in zip(case.commands, runs) if (bad := _judge_command(case, c, r, paths, seconds))]
    if failures:
        return Outcome(case, failures[0][1][0], "; ".join(f"{name}: {why}" for name, (_, why) in failures), runs)
    if len(runs) < len(case.commands):
        return Outcome(case, "timeout", "the cap ended the case", runs)
    why = "; ".join(_lines(r["stderr"])[0] for r in runs if r["exit"] == 2)
    return Outcome(case, OK_EXIT_0 if all(r["exit"] == 0 for r in runs) else OK_EXIT_2, why[:300], runs)


# -- consistency of exit 0 --------------------------------------------------------------------------------------------


def check_outputs(case: Case, command: Command, run: dict, paths: dict[str, Path]) -> str:
    """What is wrong with what a command that exited 0 printed or wrote ('' when nothing is).

    - ``info`` of a LAS/LAZ file: the description was printed (version,
      point format, the header's point count).
    - ``info`` of a ``.pcz``: the description was printed, and the counts of
      its attributes (which it prints) are whole numbers, at least 0, that
      agree with its tile index: ``tiles`` its tiles, ``patches``, ``cells``
      and ``residual`` the last of ``tiles/patch_start``, ``cell_start`` and
      ``residual_start``, ``points`` at least ``residual`` + ``cells``.
    - ``normals``: the output's header count is what laspy reads from it and
      from the input; X, Y, Z are the input's; the points lie within the
      bounds of the output's header and of the input's (give or take a
      scale step).
    - ``decompress``: the output's header count is what laspy reads; the
      points lie within the output header's bounds, and each within one of
      the tiles the ``.pcz`` declares (grid origin + tile index x tile size,
      give or take :data:`BOUNDS_SLACK`); the count is the
      ``.pcz``'s ``counts.points`` (exactly without --lod or --density,
      between ``counts.residual`` and it with --lod, at most 100 times it with
      --density).

    The ``.pcz`` is read back here with zarr; a check that cannot read what
    it needs says so (the command read it, or should not have exited 0).
    """
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):  # odd values are the point: no warnings here
            warnings.simplefilter("ignore")
            if command.name == "info":
                return _check_pcz_info(paths["input"], run["stdout"]) if case.target == "pcz" else _check_las_info(case, run["stdout"])
            if command.name == "normals":
                return _check_normals(paths["input"], paths[command.name])
            return _check_decompress(paths["input"], paths[command.name], command.options)
    except Exception as exc:  # noqa: BLE001 - what the checks cannot read is itself the finding
        return f"cannot be checked ({type(exc).__name__}: {str(exc)[:200]})"


def _check_las_info(case: Case, stdout: str) -> str:
    """``info`` of a LAS file printed its description, with the header's point count."""
    lines = _lines(stdout)
    points = [line for line in lines if line.strip().startswith("points")]
    if not lines or ": LAS " not in lines[0] or "point format" not in lines[0] or not points:
        return f"printed {lines[0][:200] if lines else ''!r}..."
    n = int(points[0].split()[1].replace(",", ""))
    data = case.data
    legacy = struct.unpack_from("<I", data, 107)[0]
    wide = struct.unpack_from("<Q", data, 247)[0] if data[25] >= 4 and len(data) >= 255 else legacy
    return "" if n > 0 and n in (legacy, wide) else f"says {n:,} points, the header {legacy:,} (legacy) or {wide:,}"


def _whole(value) -> bool:
    """A JSON whole number, at least 0 (not a bool)."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _check_pcz_info(path: Path, stdout: str) -> str:
    """``info`` of a ``.pcz`` printed its description; its counts agree with its tile index."""
    lines = _lines(stdout)
    if not lines or "patchcloud .pcz version" not in lines[0]:
        return f"printed {lines[0][:200] if lines else ''!r}..."
    d = _pcz_declared(path)
    c = d["attrs"]["counts"]
    if not all(_whole(c.get(k)) for k in ("tiles", "patches", "cells", "residual", "points")):
        return f"printed counts that are not whole numbers >= 0: {c}"
    short = [k for k in ("patch_start", "cell_start", "residual_start") if len(d[k]) != len(d["ijk"]) + 1]
    if short:
        return f"exited 0 on a tile index of {len(d['ijk'])} tiles whose {', '.join(short)} do not hold {len(d['ijk']) + 1} rows"
    index = {"tiles": len(d["ijk"]), "patches": d["patch_start"][-1], "cells": d["cell_start"][-1], "residual": d["residual_start"][-1]}
    wrong = {k: (c[k], int(v)) for k, v in index.items() if c[k] != v}
    if wrong:
        return "printed counts the tile index disagrees with: " + ", ".join(f"{k} {a:,} (index {b:,})" for k, (a, b) in wrong.items())
    if c["points"] < c["residual"] + c["cells"]:
        return f"printed {c['points']:,} points, fewer than residual {c['residual']:,} + cells {c['cells']:,}"
    return ""


def _read_output(path: Path):
    """The output read back with laspy (and a problem with it in words, '' if none)."""
    import laspy

    with laspy.open(str(path)) as r:
        n = int(r.header.point_count)
    if n > MOST_POINTS_READ:
        return None, f"wrote {n:,} points (not read back)"
    try:
        las = laspy.read(str(path))
    except Exception as exc:  # noqa: BLE001
        return None, f"laspy cannot read its output ({type(exc).__name__}: {str(exc)[:200]})"
    if len(las.points) != n:
        return las, f"its header says {n:,} points, laspy reads {len(las.points):,}"
    if n:
        xyz = np.column_stack([las.x, las.y, las.z])
        if not np.isfinite(xyz).all():
            return las, "non-finite coordinates written"
        problem = _outside(xyz, las.header.mins, las.header.maxs, las.header.scales)
        if problem:
            return las, f"points outside its header's bounds: {problem}"
    return las, ""


def _outside(xyz: np.ndarray, mins, maxs, scales) -> str:
    """'' when every point lies within ``mins`` .. ``maxs`` give or take a scale step, else how far out."""
    lo, hi = np.asarray(mins, float), np.asarray(maxs, float)
    step = np.abs(np.asarray(scales, float))
    low, high = xyz.min(axis=0), xyz.max(axis=0)
    with np.errstate(invalid="ignore"):
        if np.all(low >= lo - step) and np.all(high <= hi + step):
            return ""
    return f"{low} .. {high} vs {lo} .. {hi}"


def _check_normals(input: Path, output: Path) -> str:
    """The output of ``normals`` against its input (see :func:`check_outputs`)."""
    import laspy

    las, problem = _read_output(output)
    if problem:
        return problem
    try:
        src = laspy.read(str(input))
    except Exception as exc:  # noqa: BLE001
        return f"wrote {len(las.points):,} points from an input laspy cannot read ({type(exc).__name__}: {str(exc)[:150]})"
    if len(src.points) != len(las.points):
        return f"wrote {len(las.points):,} points, laspy reads {len(src.points):,} from the input"
    for axis in "XYZ":
        if not np.array_equal(np.asarray(src[axis]), np.asarray(las[axis])):
            return f"{axis} differs from the input's"
    # consistent with its own header: patchcloud accepts an input's points outside its header's (stale) bounds, and the
    # output's header states the points' true bounds
    head = output.read_bytes()[:227]
    maxs = struct.unpack_from("<d", head, 179) + struct.unpack_from("<d", head, 195) + struct.unpack_from("<d", head, 211)
    mins = struct.unpack_from("<d", head, 187) + struct.unpack_from("<d", head, 203) + struct.unpack_from("<d", head, 219)
    problem = _outside(np.column_stack([las.x, las.y, las.z]), mins, maxs, las.header.scales) if len(las.points) else ""
    return f"points outside the output header's bounds: {problem}" if problem else ""


def _pcz_declared(path: Path) -> dict:
    """A ``.pcz``'s attributes (``attrs``) and tile index (``ijk``, ``patch_start``, ``cell_start``, ``residual_start``),
    read back here with zarr."""
    import zarr
    from zarr.storage import ZipStore

    store = ZipStore(str(path), mode="r")
    try:
        root = zarr.open_group(store, mode="r")
        out = {"attrs": dict(root.attrs)}
        for name in ("ijk", "patch_start", "cell_start", "residual_start"):
            out[name] = np.asarray(root["tiles/" + name][...])
        return out
    finally:
        store.close()


def _outside_tiles(xyz: np.ndarray, origin: np.ndarray, T: float, ijk: np.ndarray, slack: float) -> np.ndarray:
    """Which points lie in none of the tiles ``origin + ijk * T`` (cubes of edge ``T``) grown by ``slack``."""
    out = np.ones(len(xyz), bool)
    with np.errstate(invalid="ignore", over="ignore"):
        for t in ijk.astype(np.float64):
            lo = origin + t * T - slack
            out &= ~np.all((xyz >= lo) & (xyz <= lo + T + 2 * slack), axis=1)
    return out


def _check_decompress(input: Path, output: Path, options: tuple[str, ...]) -> str:
    """The output of ``decompress`` against its ``.pcz`` (see :func:`check_outputs`)."""
    las, problem = _read_output(output)
    if problem:
        return problem
    d = _pcz_declared(input)
    attrs = d["attrs"]
    counts, grid = attrs["counts"], attrs["grid"]
    n = len(las.points)
    points, residual = int(counts["points"]), int(counts["residual"])
    if "--lod" in options:
        if not residual <= n <= points:
            return f"wrote {n:,} points at --lod, outside {residual:,} .. {points:,} (counts.residual .. counts.points)"
    elif "--density" in options:
        if n > 100 * points + residual:
            return f"wrote {n:,} points at --density, more than 100 x counts.points ({points:,})"
    elif n != points:
        return f"wrote {n:,} points, counts.points says {points:,}"
    if n == 0:
        return ""
    xyz = np.column_stack([las.x, las.y, las.z])
    outside = _outside_tiles(xyz, np.asarray(grid["origin"], float), float(grid["tile_size"]), d["ijk"],
                             max(BOUNDS_SLACK, TILE_SLACK * float(grid["tile_size"])))
    if outside.any():
        return f"{int(outside.sum()):,} of {n:,} points in none of the declared tiles, e.g. {xyz[outside][0]}"
    return ""


# -- running --------------------------------------------------------------------------------------------------------


def _warm_commands(seeds: Seeds, folder: Path) -> list[list[str]]:
    """Every command of the fuzz on valid seeds (LAS, LAZ, .pcz), their outputs in ``folder``."""
    las = seeds.path("pf6-v1.4-evlr.las")
    laz = seeds.path("pf7-v1.4-extra.laz")
    pcz = seeds.path(PCZ_SEEDS[0][0])
    out = folder / "warm"
    return [
        ["info", str(las)], ["info", str(laz)], ["info", str(pcz)],
        ["normals", str(las), str(out) + ".las", "--in-memory", "-q", "--overwrite"],
        ["normals", str(laz), str(out) + ".laz", "--in-memory", "-q", "--overwrite"],
        ["decompress", str(pcz), str(out) + "-d.laz", "-q", "--overwrite"],
        ["decompress", str(pcz), str(out) + "-d.las", "-q", "--overwrite", "--lod", "2"],
        ["decompress", str(pcz), str(out) + "-d.laz", "-q", "--overwrite", "--density", "5"],
    ]


def _probe_ok(child: Child, seeds: Seeds) -> bool:
    """Whether the child still reads a valid seed as it should (after a failure)."""
    runs = child.run([["info", str(seeds.path(PCZ_SEEDS[0][0]))], ["info", str(seeds.path(LAS_SEEDS[0][0]))]])
    return not isinstance(runs, str) and all(r["exit"] == 0 and not r["stderr"].strip() for r in runs)


def _run_one(case: Case, child: Child, folder: Path) -> tuple[Outcome, Path]:
    """Write the case's file, run its commands in the child, judge them; the case's folder (for keeping)."""
    work = folder / case.id
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    paths = {"input": work / f"input{case.suffix}"}
    paths["input"].write_bytes(case.data)
    argvs = []
    for c in case.commands:
        paths[c.name] = work / f"{c.name}-out{c.output}" if c.output else None
        argvs.append(c.argv(paths["input"], paths[c.name]))
    runs = child.run(argvs)
    return judge(case, runs, paths, child.seconds), work


def keep_failure(outcome: Outcome, work: Path, folder: Path) -> Path:
    """Save a failing case's input (``ID.ext``) and what happened (``ID.json``, with the commands to rerun) in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    case = outcome.case
    kept = folder / f"{case.id}{case.suffix}"
    shutil.copyfile(work / f"input{case.suffix}", kept)
    d = outcome.to_json()
    d["rerun"] = [" ".join(["patchcloud", *c.argv(kept, folder / f"{case.id}-{c.name}-out{c.output}" if c.output else None)])
                  for c in case.commands]
    (folder / f"{case.id}.json").write_text(json.dumps(d, indent=2, default=str))
    return kept


def run_fuzz(targets: Iterable[str], count: int | dict[str, int], seed: int, *, memory_mib: int = 1024, seconds: float = 15.0,
             workdir: Path | None = None, keep_failures: Path | None = None, results: Path | None = None,
             only: Iterable[str] = (), progress: bool = False) -> list[Outcome]:
    """Make the seeds, run ``count`` cases of each target in a capped child process, judge them.

    Parameters
    ----------
    targets : iterable of str
        ``las``, ``pcz``.
    count : int or dict
        Cases per target (the first ``count``, see :func:`make_case`; a dict: by target).
    seed : int
        Seed of the run.
    memory_mib, seconds
        The caps: address space the child may add after its warm-up, time of a case.
    workdir : Path, optional
        Where the seeds and the cases go (default: a temporary directory, removed at the end).
    keep_failures : Path, optional
        Where to save the input and the record of each failing case.
    results : Path, optional
        A JSON line per case.
    only : iterable of str
        Only these case ids (e.g. ``pcz-00042``).
    progress : bool
        A line on stderr every hundred cases.

    Returns
    -------
    list of Outcome
    """
    own = workdir is None
    folder = Path(tempfile.mkdtemp(prefix="patchcloud-fuzz-")) if own else Path(workdir)
    folder.mkdir(parents=True, exist_ok=True)
    seeds = make_seeds(folder / "seeds")
    child = Child(memory_mib, seconds, _warm_commands(seeds, folder / "seeds"))
    out = []
    sink = open(results, "w") if results else None
    t0 = time.perf_counter()
    try:
        for case in cases(targets, count, seed, seeds, only):
            outcome, work = _run_one(case, child, folder / "cases")
            if outcome.failed and keep_failures is not None:
                keep_failure(outcome, work, Path(keep_failures))
            shutil.rmtree(work, ignore_errors=True)
            if outcome.failed and child.process is not None and not _probe_ok(child, seeds):
                child.stop()
            out.append(outcome)
            if sink:
                sink.write(json.dumps(outcome.to_json(), default=str) + "\n")
            if progress and len(out) % 100 == 0:
                print(f"{len(out)} cases, {sum(o.failed for o in out)} failures, {time.perf_counter() - t0:.0f} s, "
                      f"child started {child.started} times", file=sys.stderr)
    finally:
        child.stop()
        if sink:
            sink.close()
        if own:
            shutil.rmtree(folder, ignore_errors=True)
    return out


# -- report ---------------------------------------------------------------------------------------------------------


def table(outcomes: list[Outcome]) -> str:
    """target | mutation kind | cases | exit 0 consistent | exit 2 one line | failures, a row per kind, then totals."""
    rows: dict[tuple[str, str], list[int]] = {}
    for o in outcomes:
        r = rows.setdefault((o.case.target, o.case.kind), [0, 0, 0, 0])
        r[0] += 1
        r[1 if o.verdict == OK_EXIT_0 else 2 if o.verdict == OK_EXIT_2 else 3] += 1
    head = ("target", "mutation kind", "cases", OK_EXIT_0, OK_EXIT_2, "failures")
    body = [(t, k, *map(str, v)) for (t, k), v in rows.items()]
    total = [sum(v[i] for v in rows.values()) for i in range(4)]
    body.append(("all", "", *map(str, total)))
    widths = [max(len(r[i]) for r in [head, *body]) for i in range(len(head))]
    fmt = lambda r: " | ".join(c.ljust(w) if i < 2 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths)))  # noqa: E731
    return "\n".join([fmt(head), "-+-".join("-" * w for w in widths), *map(fmt, body)])


def failure_lines(outcomes: list[Outcome]) -> list[str]:
    """One line per failing case: id, kind, seed and mutation, failure class, what happened."""
    return [f"{o.case.id}  {o.case.kind}  [{o.case.seed}: {o.case.detail}]  {o.verdict}: {o.reason}" for o in outcomes if o.failed]


def main(argv: list[str] | None = None) -> int:
    """The command line (see the module's docstring); exit status 1 when a case failed."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--target", choices=["las", "pcz", "all"], default="all")
    ap.add_argument("--cases", type=int, default=200, help="cases per target")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--memory-mib", type=int, default=1024, help="address space the child may add after its warm-up (MiB)")
    ap.add_argument("--seconds", type=float, default=15.0, help="time cap of a case")
    ap.add_argument("--keep-failures", type=Path, default=None, metavar="DIR", help="save failing inputs and their records there")
    ap.add_argument("--results", type=Path, default=None, metavar="PATH", help="a JSON line per case")
    ap.add_argument("--only", nargs="*", default=[], metavar="CASE_ID", help="only these cases (e.g. pcz-00042)")
    ap.add_argument("--workdir", type=Path, default=None, help="seeds and cases here (kept) instead of a temporary directory")
    args = ap.parse_args(argv)
    targets = TARGETS if args.target == "all" else (args.target,)
    t0 = time.perf_counter()
    outcomes = run_fuzz(targets, args.cases, args.seed, memory_mib=args.memory_mib, seconds=args.seconds, workdir=args.workdir,
                        keep_failures=args.keep_failures, results=args.results, only=args.only, progress=True)
    print(table(outcomes))
    failures = failure_lines(outcomes)
    print(f"\n{len(outcomes)} cases in {time.perf_counter() - t0:.0f} s, {len(failures)} failures (seed {args.seed})")
    for line in failures:
        print("  " + line)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
