"""``decompress``: the points of a ``.pcz`` back to LAS/LAZ, at any density, in any box.

It reads a ``.pcz`` tile by tile (or only the tiles that meet a box),
samples every patch cell by cell (its own count, a density, or a level of
detail) and writes the samples and the residual points to LAS/LAZ with
the original header and a ``Reconstructed`` dimension (1 sampled from a
patch, 0 a residual point as the ``.pcz`` keeps it: version 5, its coded
position, class and intensity, one return; versions 2-4, its record but
the dimensions dropped).  It needs no store
and no scheduler: one pass over the file.
"""

from __future__ import annotations

import os
import struct
import time
from dataclasses import dataclass
from pathlib import Path

import laspy
import numpy as np

from patchcloud.core import MASK_SIDE, PatchcloudIOError, PatchcloudValueError, dequantise_models, sample_models
from patchcloud.stream.io import pcz
from patchcloud.stream.io.budget import check_memory
from patchcloud.stream.io.dims import DECOMPRESS_DIMS
from patchcloud.stream.io.store import tile_name
from patchcloud.stream.io.las import (EVLR_BYTES, assemble_header, atomic_output, check_las_output, check_not_input, check_writable,
                                      is_laz_name, laz_backend, wave_packets_break_laz, waves_of_las13)
from patchcloud.stream.io.las_output import copy_records, is_waveform_record, point_stats, restate, rewrite_header
from patchcloud.stream.io.las_records import parse_records, provenance_vlr
from patchcloud.stream.engine.background import stops_what_it_starts

__all__ = ["decompress", "DecompressSummary", "SAMPLE_BATCH", "MAX_UPSAMPLING", "SAMPLED_POINT_BYTES", "TILE_SLACK", "MAX_LOD", "check_in_tile", "check_box_meets"]


@dataclass
class DecompressSummary:
    """What a ``decompress`` run wrote."""

    input: str
    output: str
    reconstructed: int
    residual: int
    seconds: float
    mode: str = "model"  # or "points": every point of the input, in its order

    def format(self) -> str:
        if self.mode == "points":
            return (f"{self.input} -> {self.output}\n  points          {self.residual:,}, in input order\n"
                    f"  time            {self.seconds:.1f} s")
        return (f"{self.input} -> {self.output}\n  points          {self.reconstructed + self.residual:,}: "
                f"{self.reconstructed:,} sampled from patches, {self.residual:,} residual\n  time            {self.seconds:.1f} s")


#: Most points sampled at once: a tile's cells are sampled in batches of about this many (memory bounded whatever the
#: density; a tile within one batch is sampled as it always was).
SAMPLE_BATCH = 8_000_000
#: ``density`` may ask for at most this many times the points the ``.pcz`` stands for.
MAX_UPSAMPLING = 100
#: Sampled points may lie this share of the tile's edge outside their tile (a patch's extent box, rotated, may poke out
#: of its cell); beyond, or not finite, the models were damaged or crafted: the file is refused.
TILE_SLACK = 0.25
#: The largest ``lod`` that divides a count (a cell holds fewer than 4**31 points): a larger one samples as it does.
MAX_LOD = 31
#: Bytes a sampled point takes while its batch is made, besides its record (coordinates, cell, integer coordinates, temporaries):
#: a batch is checked against the memory budget (``--max-memory``) before it is sampled.
SAMPLED_POINT_BYTES = 112


def _batches(counts: np.ndarray, size: int) -> list[slice]:
    """Runs of cells whose counts add up to about ``size`` points each (a cell is never split).

    >>> _batches(np.array([3, 3, 3, 3]), 6)
    [slice(0, 2, None), slice(2, 4, None)]
    """
    total = np.cumsum(counts)
    cuts = np.unique(np.searchsorted(total, np.arange(size, int(total[-1]) if total.size else 0, size), side="right"))
    edges = [0] + [int(c) for c in cuts if 0 < c < counts.size] + [counts.size]
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def check_in_tile(path, points: np.ndarray, ijk: np.ndarray, tile_size: float, max_error: float = 0.0) -> None:
    """Refuse sampled ``points`` ((M, 3), the grid's frame) that are not finite or lie further than :data:`TILE_SLACK`
    of the tile's edge, and twice the file's ``max_error`` (a surface may stray that far from the points it models, a
    residual point's coded position that far from the point), outside tile ``ijk``: a damaged or crafted ``.pcz``
    (PatchcloudIOError naming the tile)."""
    slack = TILE_SLACK * tile_size + 2.0 * max_error
    lo = np.asarray(ijk, dtype=np.float64) * tile_size - slack
    hi = lo + tile_size + 2.0 * slack
    if not points.size or (np.all(points.min(axis=0) >= lo) and np.all(points.max(axis=0) <= hi)):  # NaN fails both
        return
    ok = np.isfinite(points).all(axis=1) & np.all((points >= lo) & (points <= hi), axis=1)
    if not ok.all():
        raise PatchcloudIOError(f"{path}: damaged .pcz file (tile {tile_name(ijk)}'s patches put {int((~ok).sum()):,} points "
                                f"outside it)")


def _counts(models, density: float | None, lod: int | None) -> np.ndarray:
    """Points to sample per cell: its own count, ``density`` per square unit (the file's) of its occupied extent, or count / 4**lod."""
    if density is not None:
        e = models.extent
        area = (e[:, 1] - e[:, 0]) * (e[:, 3] - e[:, 2]) * models.occupied() / MASK_SIDE**2
        return np.maximum(np.rint(area * density), 1).astype(np.int64)
    if lod is not None:  # beyond MAX_LOD every cell has one point anyway (and 4**32 is past int64)
        return np.maximum(models.count // 4 ** min(lod, MAX_LOD), 1).astype(np.int64)
    return models.count.astype(np.int64)


def _check_laz_keeps(points: laspy.PackedPointRecord, output) -> None:
    """Refuse to write to LAZ records that LAZ would not give back (:func:`~patchcloud.stream.io.las.wave_packets_break_laz`)."""
    if is_laz_name(output) and wave_packets_break_laz(points):
        raise PatchcloudValueError(f"{output}: LAZ (lazrs) does not keep the wave packet fields of point format "
                                   f"{points.point_format.id} when the scanner channel changes; write LAS (.las) instead")


def _output_header(f, input, dims, parameters: dict) -> tuple[laspy.LasHeader, np.dtype]:
    """The output's header (the input's, its VLRs and EVLRs, ``dims`` added, a provenance VLR of ``parameters``) and the
    input's record type (as the ``.pcz`` holds its records).  An input that had no CRS of its own gets the one
    ``--assume-crs`` gave it, when the ``.pcz`` records one (as ``normals`` and the other jobs write it)."""
    header = f.las_header()
    raw = f.header_bytes
    size, _, count = struct.unpack_from("<HII", raw, 94)
    vlrs = parse_records(raw, size, count, False, f"{input}: the input's header")
    if waves_of_las13(header):  # a LAS 1.3 input's waveform record, kept as its one EVLR (none by versions before)
        stored = f.evlr_bytes(0, stored=True)
        n_evlrs = 1 if len(stored) >= EVLR_BYTES else 0
    else:
        n_evlrs = header.number_of_evlrs if header.version.minor >= 4 else 0
        stored = f.evlr_bytes(n_evlrs)
    evlrs = parse_records(stored, 0, n_evlrs, True, f"{input}: the input's EVLRs")
    kept = header.point_format.dtype()
    assumed = f.attrs["source"].get("assumed_crs")
    from pyproj.exceptions import CRSError

    try:
        assemble_header(header, vlrs, evlrs, dims, provenance_vlr("decompress", parameters), where=str(input),
                        crs=assumed if isinstance(assumed, str) else None)
    except CRSError as exc:  # pyproj refuses the recorded text: a damaged file
        raise PatchcloudIOError(f"{input}: damaged .pcz file (its assumed CRS is not a CRS: {exc})") from exc
    return header, kept


def _finish(out, writer, stats: list, raw: bytes, header: laspy.LasHeader) -> None:
    """Rewrite the written file's header with the statistics of what was written (bounds, counts by return), and the
    creation date of the input's header ``raw`` as it was written there (``header``: the one given to the writer).

    The header points at the waveform data packet record among the EVLRs
    written (the input's, where it had one inside: a LAS 1.3 input's is the
    output's first EVLR), and says the wave packets are internal only then.
    """
    h = restate(writer.header, stats, header)
    h.start_of_waveform_data_packet_record = _waveform_record_at(h, header.evlrs)
    h.global_encoding.waveform_data_packets_internal = bool(h.start_of_waveform_data_packet_record)
    rewrite_header(out, h, raw)


def _waveform_record_at(h: laspy.LasHeader, evlrs) -> int:
    """Where the written file of header ``h`` holds a waveform data packet record among its EVLRs (``evlrs``, laspy's
    records, written in this order from ``h.start_of_first_evlr``); 0 where none."""
    if not h.number_of_evlrs or not h.start_of_first_evlr:
        return 0
    where = h.start_of_first_evlr
    for v in list(evlrs)[: h.number_of_evlrs]:
        if is_waveform_record(v):
            return where
        where += EVLR_BYTES + len(v.record_data_bytes())
    return 0


def _stored_points(header: laspy.LasHeader, kept: np.dtype, xyz: np.ndarray, rest: np.ndarray) -> laspy.PackedPointRecord:
    """Records of the output's point format from stored points: X, Y, Z (n, 3) and the rest of the input's records (n, B)
    bytes, ``kept`` the input's record type; the dimensions the output adds are zero."""
    records = np.zeros(len(xyz), kept)
    rows = records.view(np.uint8).reshape(len(xyz), kept.itemsize)
    rows[:, :12] = xyz.astype("<i4").view(np.uint8).reshape(len(xyz), 12)
    rows[:, 12 : 12 + rest.shape[1]] = rest
    rec = laspy.PackedPointRecord.zeros(len(xyz), header.point_format)
    copy_records(records, rec.array)
    return rec


def _write_points(writer, header: laspy.LasHeader, rec: laspy.PackedPointRecord, box: np.ndarray | None, output, stats: list) -> int:
    """Write those of ``rec`` inside ``box`` (the file's coordinates; all without one), keeping their header statistics in
    ``stats``; a LAZ output of records LAZ would not give back is refused.  Returns how many were written."""
    if box is not None and len(rec):
        p = np.column_stack([rec["X"], rec["Y"], rec["Z"]]) * np.asarray(header.scales) + np.asarray(header.offsets)
        inside = np.all((p >= box[:3]) & (p <= box[3:]), axis=1)
        rec = laspy.PackedPointRecord(rec.array[inside], header.point_format)
    _check_laz_keeps(rec, output)
    if len(rec):
        writer.write_points(rec)
        stats.append(point_stats(header, rec))
    return len(rec)


def check_box_meets(box: np.ndarray, header: laspy.LasHeader, input, reach: float = 0.0) -> None:
    """Refuse a box (xmin, ymin, zmin, xmax, ymax, zmax) outside the bounds of the input ``header`` says, grown by
    ``reach`` (the file's ``--max-error``: a decoded point lies up to that far from its input point): it would give
    an output without points.

    >>> h = laspy.LasHeader(point_format=1)
    >>> h.mins, h.maxs = [0.0, 0.0, 0.0], [10.0, 20.0, 5.0]
    >>> check_box_meets(np.array([5.0, 5, 0, 6, 6, 1]), h, "a.pcz")
    >>> check_box_meets(np.array([0.0, 0, 0, 1, 1, 1]) - 100, h, "a.pcz")
    Traceback (most recent call last):
    ...
    patchcloud.core.errors.PatchcloudValueError: a.pcz: the box x -100 to -99, y -100 to -99, z -100 to -99 lies outside the input's bounds (x 0 to 10, y 0 to 20, z 0 to 5): no point to write
    """
    lo, hi = np.asarray(header.mins, dtype=np.float64), np.asarray(header.maxs, dtype=np.float64)
    if np.all(box[:3] <= hi + reach) and np.all(box[3:] >= lo - reach):
        return
    span = lambda a, b: ", ".join(f"{c} {a[i]:.10g} to {b[i]:.10g}" for i, c in enumerate("xyz"))  # noqa: E731
    raise PatchcloudValueError(f"{input}: the box {span(box[:3], box[3:])} lies outside the input's bounds ({span(lo, hi)}): "
                               "no point to write")


def _decompress_points(f: pcz.PointsPczFile, input, output, box: np.ndarray | None, overwrite: bool) -> int:
    """Write a points-mode ``.pcz``'s points (those in ``box``, if given) to ``output`` in input order; return how many."""
    header, kept = _output_header(f, input, (), dict(bbox=None if box is None else box.tolist()))
    evlrs = header.evlrs
    scale, offset = np.asarray(header.scales), np.asarray(header.offsets)
    blocks = range(len(f.bounds))
    if box is not None:  # the box in the input's integers, widened to whole steps
        blocks = f.blocks_in(np.floor((box[:3] - offset) / scale), np.ceil((box[3:] - offset) / scale))
    stats, written = [], 0
    with atomic_output(output, overwrite) as out:
        with laspy.open(out, mode="w", header=header, do_compress=is_laz_name(output), closefd=False,
                        laz_backend=laz_backend()) as writer:
            for b in blocks:
                written += _write_points(writer, header, _stored_points(header, kept, *f.block(int(b))), box, output, stats)
            if evlrs:
                writer.write_evlrs(evlrs)
        _finish(out, writer, stats, f.header_bytes, header)
    return written


@stops_what_it_starts()  # no thread of the run's left running (stream.engine.background)
def decompress(
    input: str | os.PathLike, output: str | os.PathLike, *, density: float | None = None, lod: int | None = None,
    bbox=None, seed: int = 0, overwrite: bool = False,
) -> DecompressSummary:
    """Points of a ``.pcz``, written to LAS/LAZ: samples of every patch and the residual points as it keeps them.

    Parameters
    ----------
    input : path
        A ``.pcz`` written by :func:`compress`.
    output : path
        LAS or LAZ (by its name), with the input file's header and VLRs and
        a ``Reconstructed`` dimension (uint8: 1 sampled from a patch, 0 a
        residual point).  Sampled points carry the majority class and
        mean intensity of their patch's points in their octree cell; their other dimensions are 0.
    density : float, optional
        Points per square unit of the file's CRS (m² in metres, ft² in feet) of each cell's occupied extent; at most
        :data:`MAX_UPSAMPLING` times the points the file stands for in all
        (checked before anything is written).
    lod : int, optional
        Level of detail: each cell's own count divided by ``4**lod`` (at
        least one point); 0 (the default, with no density) is the count.
    bbox : (xmin, ymin, zmin, xmax, ymax, zmax), optional
        Only this box (the file's coordinates): only the tiles that meet it
        are read, and only points inside it are written.
    seed : int
        Seed of the sampling (the same seed, the same points).

    Returns
    -------
    DecompressSummary

    Examples
    --------
    >>> from patchcloud.stream import compress
    >>> _ = compress(sample, tmp / "sample.pcz", max_error=0.05, quiet=True)
    >>> s = decompress(tmp / "sample.pcz", tmp / "back.laz", lod=1)
    >>> s.residual > 0, s.reconstructed + s.residual < 60653
    (True, True)
    """
    if density is not None and lod is not None:
        raise PatchcloudValueError(f"density={density!r} and lod={lod!r}: give one of them, not both")
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or not 0 <= seed < 2**62:
        raise PatchcloudValueError(f"seed must be a whole number from 0 to 2**62 - 1; got {seed!r}")
    numeric = isinstance(density, (int, float, np.integer, np.floating)) and not isinstance(density, bool)
    if density is not None and (not numeric or not np.isfinite(density) or density <= 0):
        raise PatchcloudValueError(f"density must be a positive number of points per square unit of the file's CRS, got {density!r}")
    if lod is not None and (not isinstance(lod, (int, np.integer)) or lod < 0):
        raise PatchcloudValueError(f"lod must be a whole number, at least 0; got {lod!r}")
    box = None
    if bbox is not None:
        box = np.asarray(bbox, dtype=np.float64).reshape(-1)
        if box.shape != (6,) or not np.isfinite(box).all() or np.any(box[:3] > box[3:]):
            raise PatchcloudValueError(f"bbox must be xmin ymin zmin xmax ymax zmax with each min <= max; got {bbox!r}")
    check_las_output(output)
    check_not_input(output, [input])
    if Path(output).suffix.lower() not in (".las", ".laz"):
        raise PatchcloudValueError(f"{output}: an output's name ends in .las (LAS) or .laz (LAZ), any case")
    check_writable(output, overwrite)
    t0 = time.perf_counter()
    with pcz.open_pcz(input) as f:
        source = f.las_header()  # the input's header: its bounds bound the box asked for and the points sampled
        if box is not None:
            check_box_meets(box, source, input, reach=float(f.max_error))
        if isinstance(f, pcz.PointsPczFile):
            if density is not None or lod is not None:
                raise PatchcloudValueError(f"{input}: holds every point (compress --keep-points): density and lod (--density, --lod) "
                                           "apply to patch models only")
            n = _decompress_points(f, input, output, box, overwrite)
            return DecompressSummary(input=str(input), output=str(output), reconstructed=0, residual=n,
                                     seconds=time.perf_counter() - t0, mode="points")
        parameters = dict(density=density, lod=lod, bbox=None if box is None else box.tolist(), seed=seed)
        header, kept = _output_header(f, input, DECOMPRESS_DIMS, parameters)
        evlrs = header.evlrs
        g = f.attrs["grid"]
        origin, scale, offset = (np.asarray(g[k], dtype=np.float64) for k in ("origin", "scale", "offset"))
        if not (np.array_equal(scale, header.scales) and np.array_equal(offset, header.offsets)):
            raise PatchcloudIOError(f"{input}: damaged .pcz file (the grid's scale {scale.tolist()} and offset {offset.tolist()} "
                                    f"are not the header's {list(header.scales)} and {list(header.offsets)})")
        # a residual point's coded position may lie up to the budget past its tile's faces (it is rounded): a box that
        # reaches a tile's neighbourhood reads the tile
        reach = float(f.max_error)
        tiles = range(len(f.tiles)) if box is None else f.tiles_in(box[:3] - origin - reach, box[3:] - origin + reach)
        L = header.point_format.size
        per_point = SAMPLED_POINT_BYTES + L
        if lod is not None or density is None:  # each cell's own count, or fewer: the largest cell, before writing
            check_memory(per_point * (f.largest_cell // 4 ** min(lod or 0, MAX_LOD)), f"{input}: a cell of {f.largest_cell:,} points")
        if density is not None:
            want = sum(int(_counts(dequantise_models(f.patches(int(t))[0]), density, None).sum()) for t in tiles)
            have = int(f.attrs["counts"]["points"])
            if want > MAX_UPSAMPLING * have:
                raise PatchcloudValueError(
                    f"{input}: a density of {density:g} per square unit would sample about {want:,} points, more than {MAX_UPSAMPLING} "
                    f"times the {have:,} the file stands for; give a lower density"
                )
        written = [0, 0]  # sampled, residual
        stats = []  # each written batch's header statistics (laspy's writer records the extra bytes' first values only)

        def write(writer, rec, is_res: bool) -> None:
            written[int(is_res)] += _write_points(writer, header, rec, box, output, stats)

        # the input's bounds in its integers: a sampled point stays within them
        lowest = np.maximum(np.ceil((np.asarray(source.mins) - offset) / scale - 1e-9), -(2.0**31)).astype(np.int64)
        highest = np.minimum(np.floor((np.asarray(source.maxs) - offset) / scale + 1e-9), 2.0**31 - 1).astype(np.int64)
        # a tile holding input points reaches at most a tile (and its slack) past LAS's 32-bit range: farther is damage
        beyond = float(np.max((1.0 + 2.0 * TILE_SLACK) * f.tile_size / scale + 4.0 * reach / scale))
        with atomic_output(output, overwrite) as out:
            with laspy.open(out, mode="w", header=header, do_compress=is_laz_name(output), closefd=False,
                            laz_backend=laz_backend()) as writer:
                for t in tiles:
                    q, cls, inten = f.patches(int(t))
                    if header.point_format.id < 6 and cls.size and int(cls.max()) > 31:
                        raise PatchcloudIOError(f"{input}: damaged .pcz file (class {int(cls.max())} in point format "
                                                f"{header.point_format.id}, whose classes end at 31)")
                    models = dequantise_models(q)
                    counts = _counts(models, density, lod)
                    for b, cells in enumerate(_batches(counts, SAMPLE_BATCH)):  # each batch written before the next
                        some = np.zeros_like(counts)
                        some[cells] = counts[cells]
                        check_memory(per_point * int(some.sum()), f"{input}: tile {int(t)}'s batch of {int(some.sum()):,} points")
                        pts, k = sample_models(models, some, seed=seed + int(t) if b == 0 else [seed + int(t), b])
                        check_in_tile(input, pts, f.tiles[int(t)], f.tile_size, reach)
                        xyz = np.rint((pts + origin - offset) / scale)  # within the tile and its reach (checked)
                        if xyz.size and (xyz.min() < -(2**31) - beyond or xyz.max() >= 2**31 + beyond):
                            raise PatchcloudIOError(f"{input}: damaged .pcz file (tile {tile_name(f.tiles[int(t)])} lies beyond "
                                                    "what LAS coordinates can hold)")
                        # a patch's mask cell may reach past the cloud's edge (a tile cut at the file's border, or at
                        # the end of LAS's 32-bit range): such samples are brought back onto the input's bounds, not
                        # made up beyond them
                        xyz = np.clip(xyz.astype(np.int64), lowest, highest)
                        sampled = laspy.PackedPointRecord.zeros(len(xyz), header.point_format)
                        sampled["X"], sampled["Y"], sampled["Z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
                        sampled["classification"] = cls[k]
                        sampled["intensity"] = inten[k]
                        one = np.ones(len(xyz), np.uint8)  # a point of a surface: one return (the LAS spec allows no 0)
                        sampled["return_number"], sampled["number_of_returns"] = one, one
                        sampled["Reconstructed"] = one
                        write(writer, sampled, False)
                    rxyz, rrec = f.residual(int(t))
                    check_in_tile(input, rxyz * scale + offset - origin, f.tiles[int(t)], f.tile_size, reach)
                    write(writer, _stored_points(header, kept, rxyz, rrec), True)
                if evlrs:
                    writer.write_evlrs(evlrs)
            _finish(out, writer, stats, f.header_bytes, header)
    return DecompressSummary(input=str(input), output=str(output), reconstructed=written[0], residual=written[1],
                             seconds=time.perf_counter() - t0)
