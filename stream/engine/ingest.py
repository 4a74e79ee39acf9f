"""Ingest: cut a LAS/LAZ file into the store's tiles, in parallel tasks; no point passes through the client.

The input is a :class:`~patchcloud.stream.io.catalog.Catalog`: one file,
or several taken as one cloud (their points in the order of the sorted
paths, their integer coordinates on one grid).  Each file is cut into
parts of consecutive points (:func:`catalog_parts`).  One task per part
(:func:`scatter_part`) reads and decodes its part (a range of LAZ chunks,
or of LAS records), groups its points by tile in input order and writes
them to the store as one fragment, with the part's
table of tiles and counts; a part done is not read again when a run
resumes.  The client adds up these small tables into the store's index
(which part sent how many points to which tile: how results find their
way back to the input order at export).  Then one task per tile
(:func:`sort_tile`) gathers the tile's fragments and sorts them by octree
key.  LAS integer coordinates are stored, so nothing is rounded; memory is
one part per task, not the file.  :func:`ensure_tiled` is what every job
calls: it reuses a store already made from the same file.
"""

from __future__ import annotations

import functools
import time

import laspy
import numpy as np

from patchcloud.core import PatchcloudValueError, level_occupancy, sort_points

from patchcloud.stream.io.budget import check_memory
from patchcloud.stream.io.catalog import Catalog
from patchcloud.stream.io.classes import MAX_CLASS, REASONS, Selection, classification_and_withheld
from patchcloud.stream.io.las import POSITION_AND_CLASS, LasSource, output_header, read_range
from patchcloud.stream.io import las_output
from patchcloud.stream.io.las_output import LAZ_CHUNK
from patchcloud.stream.engine.import_hooks import import_meanwhile
from patchcloud.stream.engine.runner import SCHEDULERS, Runner
from patchcloud.stream.engine.tasks import map_tiles
from patchcloud.stream.io.store import ANCHOR, MAX_TILE, Grid, Store

__all__ = [
    "ensure_tiled", "auto_tile_size", "check_tile_size", "make_grid", "check_points_per_tile", "MIN_POINTS_PER_TILE", "check_occupied_tiles", "MIN_POINTS_PER_OCCUPIED_TILE", "FEW_TILES", "TILE_POINT_BYTES", "NothingToResumeError", "TileSizeError", "tile_size_for", "tile_size_in", "footprint_area", "tile_size_of_tiles", "part_size", "part_ranges", "catalog_parts", "part_path",
    "scatter_part", "read_part", "route_path", "routes_pay", "part_selection", "store_selection", "check_store_selection",
    "sort_tile", "tile_pieces", "bucket_records", "gather_records", "occupancy_spacing", "tile_keys", "pack_tile_keys",
    "unpack_tile_keys", "TARGET_TILE_POINTS",
]

#: Points per tile the default tile size aims at (in the densest places of the header's extent).
TARGET_TILE_POINTS = 1_000_000
_BIAS = 1 << 20


def auto_tile_size(src: LasSource | Catalog, target: int = TARGET_TILE_POINTS) -> float:
    """A power-of-two tile size (metres) giving about ``target`` points per tile over the headers' extent (a catalog's:
    its files' boxes, :func:`footprint_area`)."""
    return tile_size_in(src.point_count, footprint_area(src), target)


def footprint_area(src: LasSource | Catalog, side: float = 1e-3) -> float:
    """The area the input's points cover by its headers (square units): its x, y box, each side at least ``side``;
    for a catalog, the sum of the boxes of its files that hold points, where that is smaller than the catalog's box
    (tiles of one survey far apart leave most of that box empty: their density is that of the files, not of the box).

    >>> from types import SimpleNamespace as F
    >>> a, b = F(mins=(0, 0, 0), maxs=(1000, 1000, 1)), F(mins=(300_000, 0, 0), maxs=(301_000, 1000, 1))
    >>> footprint_area(F(holding=(a, b), mins=(0, 0, 0), maxs=(301_000, 1000, 1)))  # 2 km², not 301
    2000000.0
    """
    def box(s) -> float:
        return max(s.maxs[0] - s.mins[0], side) * max(s.maxs[1] - s.mins[1], side)

    return float(min(box(src), sum(box(s) for s in getattr(src, "holding", (src,)))))


def tile_size_for(points: int, dx: float, dy: float, target: int = TARGET_TILE_POINTS) -> float:
    """A power-of-two tile size (metres) giving about ``target`` of ``points`` per tile over a footprint of ``dx`` by
    ``dy`` metres.

    >>> tile_size_for(1_000_000, 1000.0, 1000.0), tile_size_for(83_028, 0.0, 0.0)
    (512.0, 1.0)
    """
    return tile_size_in(points, max(dx, 1e-3) * max(dy, 1e-3), target)


def tile_size_in(points: int, area: float, target: int = TARGET_TILE_POINTS) -> float:
    """A power-of-two tile size (metres) giving about ``target`` of ``points`` per tile over ``area`` square metres."""
    t = np.sqrt(target * area / max(points, 1))
    return float(np.clip(2.0 ** np.floor(np.log2(t)), 1.0, MAX_TILE))


def check_tile_size(tile_size) -> float | None:
    """``tile_size`` (metres) as a float, None kept; a PatchcloudValueError unless positive, finite and at most MAX_TILE.

    >>> check_tile_size(64), check_tile_size(None)
    (64.0, None)
    >>> check_tile_size(-1)
    Traceback (most recent call last):
    ...
    patchcloud.core.errors.PatchcloudValueError: tile_size must be a positive length in the coordinates' unit, got -1
    """
    if tile_size is None:
        return None
    if isinstance(tile_size, bool) or not isinstance(tile_size, (int, float, np.number)) or not np.isfinite(tile_size) or tile_size <= 0:
        raise PatchcloudValueError(f"tile_size must be a positive length in the coordinates' unit, got {tile_size!r}")
    if tile_size > MAX_TILE:
        raise PatchcloudValueError(f"tile_size must be at most {MAX_TILE:g} (in the coordinates' unit), got {tile_size:g}")
    return float(tile_size)


#: A tile size leaving fewer points per tile than this over the input's footprint is refused.
MIN_POINTS_PER_TILE = 10
#: A tile size leaving fewer points than this per occupied tile on average, over more than :data:`FEW_TILES` tiles, is
#: refused once the points are tiled: each tile costs a few milliseconds a step whatever its points (a 57,000-point file
#: in 1,806 tiles of 2 m: 46 s, against 0.6 s in one tile), and an octree of a few dozen points models nothing.
MIN_POINTS_PER_OCCUPIED_TILE = 50
#: So few tiles cost little whatever they hold (a file of 30 points is one tile of 30 points).
FEW_TILES = 64
#: Bytes a worker holds per point of the tile it works on, beyond its own start (about 300 measured: a tile of 2 million
#: points of the synthetic city took a worker to 811 MiB, one of its default tiles to about 490 MiB): what the memory
#: budget (``--max-memory``) is checked against once the tiles are known, for each task that runs at once
#: (``Job.tile_point_bytes``: ``compress`` holds more).
TILE_POINT_BYTES = 300


def check_points_per_tile(src: LasSource | Catalog, t: float) -> None:
    """Refuse tiles of edge ``t`` (metres) so small that the input's points spread over its footprint (x, y box) would
    leave fewer than :data:`MIN_POINTS_PER_TILE` per tile: a grid of many more tiles than useful, minutes of work on
    nothing.  A catalog's footprint is its files' boxes (:func:`footprint_area`)."""
    ext = np.maximum(np.asarray(src.maxs) - np.asarray(src.mins), t)
    area = footprint_area(src, t)
    tiles = area / (t * t) if t * t > 0 else float("inf")  # (a size whose square underflows: any number of points is too few)
    if src.point_count < MIN_POINTS_PER_TILE * tiles:
        where = f"{ext[0]:g} x {ext[1]:g}" if area == float(ext[0] * ext[1]) else f"files' boxes of {area:.4g} square units"
        raise PatchcloudValueError(
            f"a tile size of {t:g} leaves about {src.point_count / tiles:.2g} points per tile over the input's "
            f"{where} (in its unit; at least {MIN_POINTS_PER_TILE} needed); give a larger --tile-size, or leave it out"
        )


def tile_size_of_tiles(tiles, counts: np.ndarray, t: float) -> float | None:
    """The default tile size from where the points fell (``tiles``: occupied tile indices, ``counts`` their points, at
    tiles of ``t`` metres, the default size from the headers' bounds) where it is larger than ``t`` and tiles of ``t``
    hold fewer than a hundredth of :data:`TARGET_TILE_POINTS` on average: the headers' bounds understated the cloud
    (a writer that leaves them zero); else None.

    >>> tile_size_of_tiles([(0, 0, 0), (1, 0, 0)], np.array([10, 10]), 1.0) is None  # few tiles
    True
    >>> ijk = [(i, j, 0) for i in range(100) for j in range(100)]  # 10,000 tiles of 1 m holding 10 points each
    >>> tile_size_of_tiles(ijk, np.full(10_000, 10), 1.0)
    256.0
    """
    counts = np.asarray(counts)
    if counts.size <= FEW_TILES or counts.sum() >= TARGET_TILE_POINTS / 100 * counts.size:
        return None
    ijk = np.asarray(tiles, dtype=np.int64).reshape(-1, 3)
    span = (ijk.max(axis=0) - ijk.min(axis=0) + 1) * t
    bigger = tile_size_for(int(counts.sum()), float(span[0]), float(span[1]))
    return bigger if bigger > t else None


class NothingToResumeError(PatchcloudValueError):
    """A refusal found once the points are tiled that the same command would meet again (no point left to compute
    on, too small a tile size): the run's store is removed (unless named), and the line says nothing of resuming."""


class TileSizeError(NothingToResumeError):
    """A tile size that leaves too few points per occupied tile (:func:`check_occupied_tiles`), found once the points
    are tiled: the run's store is removed (unless named), since the same command cannot resume from it."""


def check_occupied_tiles(counts: np.ndarray, t: float, where: str) -> None:
    """Refuse tiles of edge ``t`` (metres) holding fewer than :data:`MIN_POINTS_PER_OCCUPIED_TILE` points on average
    (``counts``: the points of each occupied tile), once tiled: what :func:`check_points_per_tile` cannot see from the
    footprint (a tall scene, a sparse one).  Tiles of :data:`MAX_TILE` pass whatever they hold: no larger size is
    there to ask for (a few thousand control points over 100 km run so, in tiles of 4,096 m).

    >>> check_occupied_tiles(np.array([40, 20]), 2.0, "small.laz")  # few tiles: whatever they hold
    >>> check_occupied_tiles(np.full(100, 8), MAX_TILE, "sparse.laz")  # the largest tiles: whatever they hold
    >>> check_occupied_tiles(np.full(100, 30), 2.0, "house.laz")
    Traceback (most recent call last):
    ...
    patchcloud.stream.engine.ingest.TileSizeError: house.laz: a tile size of 2 (in the file's unit, a power of two) leaves 30 points per occupied tile on average (100 tiles; at least 50 needed); give a larger --tile-size, or leave it out
    """
    if t < MAX_TILE and counts.size > FEW_TILES and counts.sum() < MIN_POINTS_PER_OCCUPIED_TILE * counts.size:
        raise TileSizeError(
            f"{where}: a tile size of {t:g} (in the file's unit, a power of two) leaves {counts.sum() / counts.size:.3g} "
            f"points per occupied tile on average "
            f"({counts.size:,} tiles; at least {MIN_POINTS_PER_OCCUPIED_TILE} needed); give a larger --tile-size, or leave it out"
        )


def make_grid(src: LasSource | Catalog, tile_size: float | None) -> Grid:
    """The tile grid of a file or catalog: ``tile_size`` rounded down to a power of two (metres), or the default."""
    tile_size = check_tile_size(tile_size)
    if tile_size is None:
        t = auto_tile_size(src)
    else:
        t = float(2.0 ** np.floor(np.log2(tile_size)))
        check_points_per_tile(src, t)
    origin = tuple(float(np.floor(m / ANCHOR) * ANCHOR) for m in src.mins)
    return Grid(origin=origin, tile_size=t, scale=src.scale, offset=src.offset)


def pack_tile_keys(ijk: np.ndarray) -> np.ndarray:
    """(T, 3) int64 tile indices as (T,) int64 keys (sorted like the store lists its tiles)."""
    b = ijk + _BIAS
    return (b[:, 0] << 42) | (b[:, 1] << 21) | b[:, 2]


def unpack_tile_keys(key: np.ndarray) -> np.ndarray:
    """The inverse of :func:`pack_tile_keys`."""
    key = np.asarray(key, dtype=np.int64)
    return np.column_stack([(key >> 42) & 0x1FFFFF, (key >> 21) & 0x1FFFFF, key & 0x1FFFFF]) - _BIAS


def tile_keys(grid: Grid, xyz: np.ndarray) -> np.ndarray:
    """Packed tile index of each point (LAS integer coordinates); ordering keys orders tiles lexicographically."""
    return pack_tile_keys(grid.tiles_of(xyz))


def _route(grid: Grid, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points of a chunk (LAS integer coordinates) by tile: the stable order that groups them, the sorted tile keys, and
    each run's start and end."""
    keys = tile_keys(grid, xyz)
    order = np.argsort(keys, kind="stable")
    sk = keys[order]
    starts = np.flatnonzero(np.r_[True, sk[1:] != sk[:-1]]) if sk.size else np.zeros(0, dtype=np.int64)
    return order, sk, starts, np.r_[starts[1:], sk.size] if sk.size else starts


def part_size(point_count: int, slots: int, chunk: int | None = None) -> int:
    """Points per part of the input (what one ingest or export task reads): ``chunk``, or a default for ``slots`` workers.

    The default gives every worker about eight parts (so that the last
    parts, which may leave some workers waiting, are short), in multiples
    of :data:`~patchcloud.stream.io.las_output.LAZ_CHUNK` (so that every
    part but the last is whole LAZ chunks of the output), between 2 and 10
    LAZ chunks.  Results do not depend on it.

    >>> part_size(60_653, 2), part_size(10_000_000, 2), part_size(20_000_000, 16)
    (100000, 500000, 200000)
    """
    if chunk:
        return int(chunk)
    per = -(-point_count // (8 * max(1, slots)))
    return int(np.clip(-(-per // LAZ_CHUNK) * LAZ_CHUNK, 2 * LAZ_CHUNK, 10 * LAZ_CHUNK))


def part_ranges(point_count: int, size: int, unit: int = LAZ_CHUNK, taper: bool = True) -> list[tuple[int, int]]:
    """(first point, points) of every part of a file of ``point_count`` points cut every ``size`` points, its last
    ``2 size`` points or fewer cut finer.

    Tasks run in the order of their parts, so the last parts are the step's
    tail, during which workers that have finished wait for the others.  With
    ``taper``, where ``size`` is a whole number of ``unit`` (a LAZ chunk) and the file holds
    more than two parts, the points left after the last whole part that
    leaves more than ``2 size`` are cut into parts of a quarter of what
    remains, rounded up to a whole ``unit``, down to one ``unit``: the
    step ends with parts of one unit, not of ``size`` (10M-point LAZ, 2
    workers: parts of 10 chunks end with 5, 4, 3, 2, 2, 1, 1, 1, 1 chunks).
    Every part but a file's last is still a whole number of units.

    >>> part_ranges(250, 100)
    [(0, 100), (100, 100), (200, 50)]
    >>> [c for _, c in part_ranges(50, 10, unit=1)]
    [10, 10, 10, 5, 4, 3, 2, 2, 1, 1, 1, 1]
    """
    if not taper or point_count <= 2 * size or size % unit:
        return [(first, min(size, point_count - first)) for first in range(0, point_count, size)]
    whole = (point_count - 2 * size - 1) // size + 1  # whole parts while more than 2 size points would be left after
    out = [(k * size, size) for k in range(whole)]
    first = whole * size
    while first < point_count:
        left = point_count - first
        quarter = -(-left // 4)
        count = min(left, max(unit, -(-quarter // unit) * unit))
        out.append((first, count))
        first += count
    return out


def catalog_parts(catalog: Catalog, size: int) -> list[tuple[int, int, int]]:
    """(file, first point in the file, points) of every part of a catalog: each file cut every ``size`` points.

    Parts are numbered in this order (files in catalog order); no part spans two files.  Only the last file's end is
    cut finer (:func:`part_ranges`): the others' ends are not a step's tail.
    """
    last = len(catalog.sources) - 1
    return [(f, first, count) for f, s in enumerate(catalog.sources)
            for first, count in part_ranges(s.point_count, size, taper=f == last)]


def part_path(p: int) -> str:
    """Where part ``p``'s fragments are in the store.

    >>> part_path(3)
    'parts/000003'
    """
    return f"parts/{p:06d}"


def store_selection(store: Store) -> Selection:
    """The points the store's tiles hold (:class:`~patchcloud.stream.io.classes.Selection`; a store that records none:
    every point)."""
    return Selection.from_json(store.attrs.get("selection"))


def check_store_selection(attrs: dict, url: str, tiles: Selection, asked: Selection, job: str) -> None:
    """Refuse a named store (``url``, of the run's files, its attributes ``attrs``) whose tiles hold another selection
    only because another kind of job made it.

    ``tiles`` is what this job tiles (``compress`` tiles every point and
    models its selection; the other jobs tile the points they select),
    ``asked`` the run's own selection.  A store made from the same files with
    ``asked`` (by a selecting job) or with every point (by ``compress``) but
    holding other tiles than ``tiles`` would be tiled again here, taking its
    tiles and the other job's records with it, though the user asked for
    nothing new: one PatchcloudValueError instead, nothing touched.  A store
    made with a selection this run asks to change (``--classes``,
    ``--keep-noise``) is tiled again, as asked.
    """
    if "selection" not in attrs:
        return
    held = Selection.from_json(attrs["selection"])
    if held == tiles or not (held == asked or held.everything):
        return
    raise PatchcloudValueError(
        f"{url}: its tiles hold {held.describe()} (an earlier run made it), and {job} tiles {tiles.describe()}: one store "
        f"holds one tiling, so give this run another --store (or remove {url} to tile it again)"
    )


def part_selection(selection: Selection, records: np.ndarray) -> tuple[np.ndarray, list[int], list[int]]:
    """Which of a part's records take part: (n,) bool, the points left out by reason (:data:`REASONS`), and the
    part's points by class (MAX_CLASS + 1 counts, every point)."""
    cls, _ = classification_and_withheld(records)
    by_class = np.bincount(cls, minlength=MAX_CLASS + 1).tolist()
    if selection.everything:
        return np.ones(len(records), dtype=bool), [0] * len(REASONS), by_class
    why = selection.reasons(records)
    return why == 0, np.bincount(why, minlength=len(REASONS) + 1)[1:].tolist(), by_class


def scatter_part(url: str, p: int, f: int, first: int, count: int, field: str = "xyz", laz_parallel: bool = False) -> None:
    """Ingest task: read part ``p`` (points ``first:first + count`` of file ``f``) and store its points grouped by tile.

    Coordinates are put on the catalog's grid (:meth:`Catalog.common`).
    Only the points of the store's selection (:func:`store_selection`: by
    default noise and withheld points are left out) go to the tiles: the
    others enter no neighbourhood of any step, and the export writes them
    with empty values.

    ``field`` "xyz": the LAS integer coordinates, with the part's tiles, their
    counts, the coordinates' sums, the points left out by reason and the
    points by class in the part's attributes; "record":
    every point's whole record (its bytes), for ``compress``.  Within a
    tile the points keep their input order.  A part already done is skipped.
    """
    if field not in ("xyz", "record"):
        raise PatchcloudValueError(f"field must be 'xyz' or 'record', got {field!r}")
    store = Store.open(url)
    path = part_path(p)
    if store.group_attrs(path).get(f"done_{field}"):
        return
    cat = store.catalog
    grid = store.grid
    # a route: the export copies the part's compressed chunks as they are, so every field is decoded here, once (a
    # damaged chunk is then one error now, not an output that cannot be read); an export in memory keeps no records
    routed = field == "xyz" and routes_pay(cat.sources[f])
    records = read_part(store, p, cat.sources[f], first, count, laz_parallel, whole=field == "record" or routed, keep=not routed)
    all_records = records
    keep, left_out, by_class = part_selection(store_selection(store), records)
    if not keep.all():
        records = records[keep]
    xyz = cat.common(f, records["X"], records["Y"], records["Z"])
    order, sk, starts, ends = _route(grid, xyz)
    if field == "xyz":
        if routed:
            _put_route(store, p, cat.sources[f], all_records, keep, order, starts, ends)
        store.put(f"{path}/xyz", xyz[order])
        sums = xyz.astype(np.int64).sum(axis=0)
        store.set_group_attrs(path, keys=sk[starts].tolist(), counts=(ends - starts).tolist(), sums=sums.tolist(),
                              left_out=left_out, by_class=by_class, done_xyz=True)
    else:
        rec = records.view(np.uint8).reshape(len(records), records.dtype.itemsize)
        store.put(f"{path}/record", rec[order])
        store.set_group_attrs(path, done_record=True)


def route_path(p: int) -> str:
    """Where part ``p``'s route is in the store: each of its points' tile, for the export (:func:`_put_route`).

    >>> route_path(3)
    'routes/000003'
    """
    return f"routes/{p:06d}"


@functools.lru_cache(maxsize=256)
def routes_pay(src: LasSource) -> bool:
    """Whether the ingest records the parts' routes of ``src``: where a LAZ output of it with new dimensions can copy
    its compressed chunks (:func:`~patchcloud.stream.io.las_output.layered_source`: a layered LAZ, point formats 6
    to 8, in chunks of 50,000 points, whose records an output keeps as they are), so that the export need not decode
    it.  Elsewhere the export reads the records anyway (and in memory keeps them from the ingest)."""
    if not src.compressed or not 6 <= int(src.point_format) <= 8:  # (9 and 10: wave packets, which the export codes whole)
        return False
    header = las_output.prepare_header(output_header(src, _PROBE_DIMS), True)
    return las_output.layered_source(src.path, header, [d[0] for d in _PROBE_DIMS]) is not None


#: A new dimension as a job adds one: what :func:`routes_pay` asks an output to hold.
_PROBE_DIMS = (("PatchcloudRouteProbe", np.float32, "probe"),)


def _put_route(store: Store, p: int, src: LasSource, records: np.ndarray, keep: np.ndarray, order: np.ndarray,
               starts: np.ndarray, ends: np.ndarray) -> None:
    """Record part ``p``'s route, so that its export need not decode the input's records again
    (:func:`patchcloud.stream.engine.export.export_part`): ``tile`` (n,) int32, each point's tile among the part's
    (in key order; -1: left out), ``channel`` (n,) uint8 the scanner channels where any is not 0, and the header
    statistics of its records (:class:`~patchcloud.stream.io.las_output.PointStats`, the input's fields)."""
    n = len(records)
    tile = np.full(n, -1, dtype=np.int32)
    local = np.empty(len(order), dtype=np.int32)
    local[order] = np.repeat(np.arange(len(starts), dtype=np.int32), ends - starts)
    tile[np.flatnonzero(keep)] = local
    with laspy.open(src.path) as reader:
        header = las_output.prepare_header(reader.header, False)
    packed = laspy.PackedPointRecord(records, header.point_format)
    stats = las_output.point_stats(header, packed)
    route = route_path(p)
    store.put(f"{route}/tile", tile)
    channel = np.asarray(packed["scanner_channel"], dtype=np.uint8)  # (a layered format: routes_pay)
    if channel.any():
        store.put(f"{route}/channel", channel)
    store.set_group_attrs(route, stats=stats.to_json(), points=n)


def read_part(store: Store, p: int, src: LasSource, first: int, count: int, laz_parallel: bool = False,
              whole: bool = True, selection: laspy.DecompressionSelection | None = None, keep: bool = True) -> np.ndarray:
    """The records of part ``p`` (points ``first:first + count`` of ``src``) as laspy's structured array.

    A store in memory keeps each part's records from its first read (the
    ingest; not with ``keep`` False: a layered LAZ, whose export copies the
    compressed chunks), so its export does not decode the file a second time; any
    other store reads the file each time (:func:`patchcloud.stream.io.las.read_range`).
    With ``whole`` False, a store on disk decodes only what the ingest
    routes points by (:data:`~patchcloud.stream.io.las.POSITION_AND_CLASS`,
    for the layered LAZ of point formats 6 to 10: about half the decoding):
    the records' other fields are then not to be read.  ``selection``,
    when given, is what a store on disk decodes instead (with ``whole``).
    """
    path = f"inputs/{p:06d}"
    if store.in_memory and store.has_array(path):
        return store.get(path)
    if store.in_memory:
        selection = None
    elif selection is None and not whole:
        selection = POSITION_AND_CLASS
    records = read_range(src, first, count, parallel=laz_parallel, selection=selection).array
    if store.in_memory and keep:
        store.put(path, records)
    return records


def _scatter(store: Store, runner: Runner, field: str, label: str) -> None:
    """Run :func:`scatter_part` on every part not yet done."""
    parts = catalog_parts(store.catalog, int(store.attrs["part_points"]))
    todo = [p for p in range(len(parts)) if not store.group_attrs(part_path(p)).get(f"done_{field}")]
    laz_parallel = runner.laz_parallel  # tasks in this process: lazrs may use the cores
    runner.map(scatter_part, [((store.url, p, *parts[p]), {"field": field, "laz_parallel": laz_parallel}) for p in todo], label)


def _starts(group: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Where each row's run starts within its group (rows of a group consecutive): the counts summed before it.

    >>> _starts(np.array([0, 0, 1, 1, 1]), np.array([2, 3, 1, 1, 4])).tolist()
    [0, 2, 0, 1, 2]
    """
    c = np.cumsum(counts) - counts
    first = np.r_[True, group[1:] != group[:-1]]
    return c - c[np.maximum.accumulate(np.where(first, np.arange(group.size), 0))]


def _index_parts(store: Store) -> None:
    """From the parts' attributes: the tiles, their counts, the centroid, and the index of parts and tiles.

    ``index/part_tile`` (K, 3) int64: part, tile (position in the store's
    list), points of the part in the tile; ``index/part_start`` where that
    run starts in the part's fragment, ``index/tile_start`` its first row
    among the tile's points (in input order).
    """
    rows, sums = [], [0, 0, 0]
    left_out = np.zeros(len(REASONS), dtype=np.int64)
    by_class = np.zeros(MAX_CLASS + 1, dtype=np.int64)
    cat = store.catalog
    for p in range(len(catalog_parts(cat, int(store.attrs["part_points"])))):
        a = store.group_attrs(part_path(p))
        keys, counts = np.asarray(a["keys"], dtype=np.int64), np.asarray(a["counts"], dtype=np.int64)
        rows.append(np.column_stack([np.full(keys.size, p), keys, counts]).reshape(-1, 3))
        sums = [s + int(v) for s, v in zip(sums, a["sums"])]
        left_out += np.asarray(a["left_out"], dtype=np.int64)
        by_class += np.asarray(a["by_class"], dtype=np.int64)
    rec = np.concatenate(rows)
    kept = int(rec[:, 2].sum())
    classes = {str(c): int(n) for c, n in enumerate(by_class) if n}
    if kept == 0:  # the same command would find none again: nothing to resume
        raise NothingToResumeError(
            f"{cat.path}: no point left to compute on ({store_selection(store).describe()}); the input holds "
            + ", ".join(f"class {c}: {n:,}" for c, n in classes.items())
            + " (--classes chooses the classes, --keep-noise keeps noise and withheld points)"
        )
    keys_sorted = np.unique(rec[:, 1])
    t = np.searchsorted(keys_sorted, rec[:, 1])
    counts = np.bincount(t, weights=rec[:, 2], minlength=keys_sorted.size).astype(np.int64)
    index = np.column_stack([rec[:, 0], t, rec[:, 2]]).astype(np.int64)
    by_tile = np.lexsort((index[:, 0], index[:, 1]))
    tile_start = np.empty(index.shape[0], dtype=np.int64)
    tile_start[by_tile] = _starts(index[by_tile, 1], index[by_tile, 2])
    store.put("index/part_tile", index)
    store.put("index/part_start", _starts(index[:, 0], index[:, 2]))
    store.put("index/tile_start", tile_start)
    g = store.grid
    base, shift = g.frame
    mean = np.asarray([(s + int(b) * kept) / kept for s, b in zip(sums, base)])  # exact integer sums: whatever the parts
    centroid = mean * np.asarray(g.scale) + shift
    store.update(tiles=unpack_tile_keys(keys_sorted).tolist(), tile_counts=counts.tolist(), centroid_local=centroid.tolist(),
                 left_out=dict(zip(REASONS, left_out.tolist())), classes=classes)


def tile_pieces(store: Store, ijk: tuple) -> list[tuple[int, int, int]]:
    """(part, first row in the part's fragment, rows) of every fragment of tile ``ijk``, in input order."""
    t = store.tiles.index(tuple(ijk))
    index = store.get("index/part_tile")
    rows = np.flatnonzero(index[:, 1] == t)
    starts = store.get("index/part_start")[rows]
    return [(int(index[r, 0]), int(s), int(index[r, 2])) for r, s in zip(rows, starts)]


def _gather(store: Store, ijk: tuple, field: str) -> np.ndarray:
    """The tile's points (their ``field``) from every part, in input order."""
    return np.concatenate([store.get(f"{part_path(p)}/{field}", slice(s, s + m)) for p, s, m in tile_pieces(store, ijk)])


def sort_tile(url: str, ijk: tuple) -> list[int]:
    """Task: gather a tile's points from the parts, sort them by octree key; return the tile's occupancy per level.

    ``occupancy[l]`` is the number of occupied cells of edge ``tile_size / 2**l``.
    """
    store = Store.open(url)
    if store.tile_done(ijk, "sort"):
        return list(store.tile_attrs(ijk)["occupancy"])
    grid = store.grid
    raw = _gather(store, ijk, "xyz")
    local = grid.local(raw) - grid.corner(ijk)
    order, keys, _ = sort_points(local, np.zeros(3), grid.tile_size)
    store.write(ijk, "xyz", raw[order])
    store.write(ijk, "rank", order.astype(np.uint32))
    occ = level_occupancy(keys)
    store.mark_tile(ijk, "sort", index=[int(v) for v in ijk], count=int(raw.shape[0]), occupancy=occ)
    return occ


def gather_records(url: str, ijk: tuple) -> None:
    """Task: the tile's records from every part, as its ``record`` array (rows in the tile's input order)."""
    store = Store.open(url)
    if store.tile_done(ijk, "records"):
        return
    store.write(ijk, "record", _gather(store, ijk, "record"), chunk=Store.CHUNK * 4)
    store.mark_tile(ijk, "records")


def bucket_records(store: Store, runner: Runner) -> None:
    """Every point's whole record (its bytes) in its tile's array ``record``, in the tile's input order.

    Row ``r`` of a tile's ``record`` belongs to the tile's point of ``rank``
    r, as the coordinates do: the same parts are read again, scattered by
    :func:`scatter_part` tasks and gathered by :func:`gather_records` tasks.
    """
    _scatter(store, runner, "record", "records: read")
    map_tiles(gather_records, store, runner=runner, label="records: gather")
    store.remove("parts", wait=False)  # on a thread: the next step need not wait for 0.1-0.3 s of unlinking


def occupancy_spacing(occupancy: dict[int, int], n: int, target: float = 16.0) -> float:
    """Point spacing (metres) from occupied-cell counts per power-of-two cell size.

    ``occupancy[e]`` counts the occupied cells of edge ``2**e`` metres over
    the whole cloud; as :func:`patchcloud.core.octree.estimate_spacing`, the
    largest cell size whose cells hold fewer than ``target`` points on
    average gives ``2**e / sqrt(points per cell)``.  The counts add up
    across tiles for any cell no larger than a tile, so the result does
    not depend on the tile size.
    """
    for e in sorted(occupancy, reverse=True):
        m = n / occupancy[e]
        if m < target:
            return float(2.0**e / np.sqrt(max(m, 1.0)))
    e = min(occupancy)
    return float(2.0**e / np.sqrt(max(n / occupancy[e], 1.0)))


def ensure_tiled(src: LasSource | Catalog, url: str, tile_size: float | None, runner: Runner, quiet: bool,
                 chunk: int | None = None, selection: Selection | None = None,
                 point_bytes: int = TILE_POINT_BYTES) -> tuple[Store, float]:
    """The store at ``url`` holding ``src`` (a file or a catalog) tiled at ``tile_size``, and the seconds this took.

    ``selection``: the points the tiles hold (default ``Selection()``: noise
    and withheld points left out; :mod:`patchcloud.stream.io.classes`).
    A store made from the same files on the same grid with the same selection is reused (without a
    ``tile_size``, on the store's own tile size): as it is
    when complete, else resuming from the parts and tiles done; anything
    else there is replaced.  Steps, all of them tasks on the workers: one
    :func:`scatter_part` per part of the file (``chunk`` points, default
    :func:`part_size`), then one :func:`sort_tile` per tile, which gathers
    the tile's fragments; the client only adds up the parts' tables
    (:func:`_index_parts`).  The store then records the cloud's occupancy
    per cell size.  Once the tiles are known, the largest tile times
    ``point_bytes`` (a task's bytes per point of its tile) times the tasks
    that run at once on this machine (the runner's slots; one per worker of
    a cluster reached by its address, whose workers have budgets of their
    own) is checked against the memory budget.
    """
    cat = src if isinstance(src, Catalog) else Catalog.of(src)
    grid = make_grid(cat, tile_size)
    selection = Selection() if selection is None else selection
    t0 = time.perf_counter()
    asked = tile_size is not None  # a tile size someone asked for is kept; the default one may be found too small below
    if Store.exists(url):
        store = Store.open(url)
        a = store.attrs
        if tile_size is None and a.get("grid") and a.get("catalog") and cat.same_files(a["catalog"]):
            kept = Grid.from_json(a["grid"])  # no tile size asked for: a store of these files keeps its own (`tile --tile-size`)
            if (kept.origin, kept.scale, kept.offset) == (grid.origin, grid.scale, grid.offset):
                grid = kept
                asked = bool(a.get("tile_size_asked", True))  # (a store of before this record: asked, as its grid is kept)
        same = (a.get("catalog") and cat.same_files(a["catalog"]) and a.get("grid") == grid.to_json() and "part_points" in a
                and a.get("selection") == selection.to_json())
        if same and store.step_done("tile"):
            return store, 0.0
        if not same:  # else resume from the parts and tiles done
            store = Store.create(url, overwrite=True)
    else:
        store = Store.create(url)
    for attempt in range(2):
        if "part_points" not in store.attrs:
            store.update(source=cat.holding[0].to_json(), catalog=cat.to_json(), grid=grid.to_json(), selection=selection.to_json(),
                         part_points=part_size(cat.point_count, runner.slots, chunk), tile_size_asked=asked)
        if not store.step_done("bucket"):
            if not store.in_memory:  # the index the client writes next is blosc-coded: numcodecs, imported during the step
                import_meanwhile("numcodecs")
            _scatter(store, runner, "xyz", "tile: read")
            _index_parts(store)
            store.mark_step("bucket", {"part_points": int(store.attrs["part_points"])})
        bigger = tile_size_of_tiles(store.tiles, store.tile_counts, grid.tile_size) if not asked and attempt == 0 else None
        if bigger is None:
            break
        # the headers' bounds understated the cloud (the default tile size comes from them): tiled again at the size its
        # points give, found from the tiles they fell in
        grid = Grid(origin=grid.origin, tile_size=bigger, scale=grid.scale, offset=grid.offset)
        store = Store.create(url, overwrite=True)
    check_occupied_tiles(store.tile_counts, grid.tile_size, cat.path)
    if store.tile_counts.size:  # a tile's steps hold all its points at once, in one process, as many as run at once
        most = int(store.tile_counts.max())
        at_once = max(1, runner.slots) if runner.scheduler in SCHEDULERS else 1  # (a cluster's workers: budgets of their own)
        check_memory(point_bytes * most * at_once, f"{cat.path}: a tile of {grid.tile_size:g} (in its unit) holding {most:,} points"
                     + (f", {at_once} tasks at once" if at_once > 1 else ""), hint="give a smaller --tile-size, or fewer --workers")
    occ = map_tiles(sort_tile, store, runner=runner, label="tile: sort")
    store.remove("parts", wait=False)  # on a thread: the next step need not wait for 0.1-0.3 s of unlinking
    log_t = int(round(np.log2(grid.tile_size)))
    total: dict[int, int] = {}
    for o in occ.values():
        for lev, count in enumerate(o):
            total[log_t - lev] = total.get(log_t - lev, 0) + int(count)
    store.update(occupancy={str(k): v for k, v in total.items()})
    store.mark_step("tile", {"tile_size": grid.tile_size})
    return store, time.perf_counter() - t0
