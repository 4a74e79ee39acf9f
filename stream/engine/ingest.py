"""Ingest: read a LAS/LAZ file in chunks and cut it into the store's tiles.

The file is read once, in input order, ``chunk`` points at a time; each
chunk's points are bucketed by tile and appended to the tiles' ``raw``
arrays (LAS integer coordinates, so nothing is rounded), flushing the
buffers whenever they hold more than ``buffer`` points: memory is bounded
by these two settings, not by the file.  The store also records how many
points of every input chunk went to every tile, which is how results find
their way back to the input order at export.  The per-tile sort by octree
key (:func:`sort_tile`) then runs as dask tasks.  :func:`ensure_tiled` is
what every job calls: it reuses a store already made from the same file.
"""

from __future__ import annotations

import time

import numpy as np

from patchcloud.core import MAX_DEPTH, PatchcloudValueError, sort_points

from patchcloud.stream.io.las import LasSource, read_chunks
from patchcloud.stream.engine.progress import Progress
from patchcloud.stream.engine.runner import Runner
from patchcloud.stream.engine.tasks import map_tiles
from patchcloud.stream.io.store import ANCHOR, MAX_TILE, Grid, Store

__all__ = [
    "ensure_tiled", "auto_tile_size", "check_tile_size", "make_grid", "bucket", "bucket_records", "sort_tile", "occupancy_spacing", "tile_keys", "pack_tile_keys",
    "unpack_tile_keys", "TARGET_TILE_POINTS",
]

#: Points per tile the default tile size aims at (in the densest places of the header's extent).
TARGET_TILE_POINTS = 1_000_000
_BIAS = 1 << 20


def auto_tile_size(src: LasSource, target: int = TARGET_TILE_POINTS) -> float:
    """A power-of-two tile size (metres) giving about ``target`` points per tile over the header's extent."""
    dx = max(src.maxs[0] - src.mins[0], 1e-3)
    dy = max(src.maxs[1] - src.mins[1], 1e-3)
    density = src.point_count / (dx * dy)  # points per square metre of the footprint
    t = np.sqrt(target / density)
    return float(np.clip(2.0 ** np.floor(np.log2(t)), 1.0, MAX_TILE))


def check_tile_size(tile_size) -> float | None:
    """``tile_size`` (metres) as a float, None kept; a PatchcloudValueError unless positive, finite and at most MAX_TILE.

    >>> check_tile_size(64), check_tile_size(None)
    (64.0, None)
    >>> check_tile_size(-1)
    Traceback (most recent call last):
    ...
    patchcloud.core.errors.PatchcloudValueError: tile size must be a positive number of metres, got -1
    """
    if tile_size is None:
        return None
    if isinstance(tile_size, bool) or not isinstance(tile_size, (int, float, np.number)) or not np.isfinite(tile_size) or tile_size <= 0:
        raise PatchcloudValueError(f"tile size must be a positive number of metres, got {tile_size!r}")
    if tile_size > MAX_TILE:
        raise PatchcloudValueError(f"tile size must be at most {MAX_TILE:g} m, got {tile_size:g}")
    return float(tile_size)


def make_grid(src: LasSource, tile_size: float | None) -> Grid:
    """The tile grid of a file: ``tile_size`` rounded down to a power of two (metres), or the default."""
    tile_size = check_tile_size(tile_size)
    if tile_size is None:
        t = auto_tile_size(src)
    else:
        t = float(2.0 ** np.floor(np.log2(tile_size)))
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
    return pack_tile_keys(grid.tile_of(grid.local(xyz)))


def _route(grid: Grid, local: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points of a chunk by tile: the stable order that groups them, the sorted tile keys, and each run's start and end."""
    keys = pack_tile_keys(grid.tile_of(local))
    order = np.argsort(keys, kind="stable")
    sk = keys[order]
    starts = np.flatnonzero(np.r_[True, sk[1:] != sk[:-1]])
    return order, sk, starts, np.r_[starts[1:], sk.size]


def bucket_records(store: Store, src: LasSource, name: str = "record", chunk: int = 1 << 20, buffer: int = 4_000_000,
                   quiet: bool = False) -> None:
    """Append every point's whole record (its bytes) to its tile's array ``name``, in input order.

    Row ``r`` of a tile's ``name`` belongs to the tile's point of ``rank`` r
    (the tile's points in input order), as the stored ``raw`` points were.
    """
    grid = store.grid
    buffers: dict[int, list[np.ndarray]] = {}
    held = 0
    bar = Progress("records", src.point_count, quiet=quiet)

    def flush() -> None:
        nonlocal held
        for key in sorted(buffers):
            store.append(tuple(unpack_tile_keys(np.array([key]))[0]), name, np.concatenate(buffers[key]))
        buffers.clear()
        held = 0

    for _, pts in read_chunks(src, chunk):
        rec = pts.array.view(np.uint8).reshape(len(pts), pts.array.dtype.itemsize)
        xyz = np.column_stack([pts.array["X"], pts.array["Y"], pts.array["Z"]])
        order, sk, starts, ends = _route(grid, grid.local(xyz))
        for s, e in zip(starts.tolist(), ends.tolist()):
            buffers.setdefault(int(sk[s]), []).append(rec[order[s:e]])
        held += len(pts)
        if held >= buffer:
            flush()
        bar.update(len(pts))
    flush()
    bar.close()


def bucket(store: Store, src: LasSource, grid: Grid, chunk: int = 1 << 20, buffer: int = 4_000_000, quiet: bool = False) -> None:
    """Read ``src`` and append its points to the tiles' ``raw`` arrays; record the chunk/tile counts."""
    buffers: dict[int, list[np.ndarray]] = {}
    held = 0
    total = np.zeros(3)
    records: list[np.ndarray] = []
    bar = Progress("tile: read", src.point_count, quiet=quiet)

    def flush() -> None:
        nonlocal held
        for key in sorted(buffers):
            store.append(tuple(unpack_tile_keys(np.array([key]))[0]), "raw", np.concatenate(buffers[key]))
        buffers.clear()
        held = 0

    for first, pts in read_chunks(src, chunk):
        c = first // chunk
        xyz = np.column_stack([pts.array["X"], pts.array["Y"], pts.array["Z"]]).astype(np.int32, copy=False)
        local = grid.local(xyz)
        total += local.sum(axis=0)
        order, sk, starts, ends = _route(grid, local)
        for s, e in zip(starts.tolist(), ends.tolist()):
            buffers.setdefault(int(sk[s]), []).append(xyz[order[s:e]])
        records.append(np.column_stack([np.full(starts.size, c), sk[starts], ends - starts]))
        held += xyz.shape[0]
        if held >= buffer:
            flush()
        bar.update(xyz.shape[0])
    flush()
    bar.close()
    rec = np.concatenate(records) if records else np.zeros((0, 3), dtype=np.int64)
    tile_keys_sorted = np.unique(rec[:, 1])
    tiles = unpack_tile_keys(tile_keys_sorted)
    counts = np.bincount(np.searchsorted(tile_keys_sorted, rec[:, 1]), weights=rec[:, 2], minlength=tiles.shape[0])
    index = np.column_stack([rec[:, 0], np.searchsorted(tile_keys_sorted, rec[:, 1]), rec[:, 2]]).astype(np.int64)
    a = store.group.create_array("index/chunk_tile", shape=index.shape, dtype=np.int64, chunks=(max(1, min(1 << 16, index.shape[0])), 3), overwrite=True)
    a[...] = index
    store.update(
        tiles=tiles.tolist(), tile_counts=counts.astype(np.int64).tolist(), chunk_points=int(chunk),
        centroid_local=(total / max(src.point_count, 1)).tolist(),
    )


def sort_tile(url: str, ijk: tuple) -> list[int]:
    """Sort a tile's points by octree key; return the tile's occupancy per level (for the global spacing).

    ``occupancy[l]`` is the number of occupied cells of edge ``tile_size / 2**l``.
    """
    store = Store.open(url)
    if store.tile_done(ijk, "sort"):
        store.delete(ijk, "raw")
        return list(store.tile_attrs(ijk)["occupancy"])
    grid = store.grid
    raw = store.read(ijk, "raw")
    local = grid.local(raw) - grid.corner(ijk)
    order, keys, _ = sort_points(local, np.zeros(3), grid.tile_size)
    store.write(ijk, "xyz", raw[order])
    store.write(ijk, "rank", order.astype(np.uint32))
    occ = [int(np.count_nonzero(np.diff(keys >> np.uint64(3 * (MAX_DEPTH - lev))))) + 1 for lev in range(MAX_DEPTH + 1)]
    store.mark_tile(ijk, "sort", index=[int(v) for v in ijk], count=int(raw.shape[0]), occupancy=occ)
    store.delete(ijk, "raw")
    return occ


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


def ensure_tiled(src: LasSource, url: str, tile_size: float | None, runner: Runner, quiet: bool, chunk: int) -> tuple[Store, float]:
    """The store at ``url`` holding ``src`` tiled at ``tile_size``, and the seconds this took.

    A store made from the same file on the same grid is reused: as it is
    when complete, finishing the sort when only that was interrupted;
    anything else there is replaced.  Steps: bucket (:func:`bucket`, in
    this process), then one :func:`sort_tile` task per tile; the store
    then records the cloud's occupancy per cell size.
    """
    grid = make_grid(src, tile_size)
    t0 = time.perf_counter()
    if Store.exists(url):
        store = Store.open(url)
        a = store.attrs
        same = a.get("source") and src.same_file(a["source"]) and a.get("grid") == grid.to_json()
        if same and store.step_done("tile"):
            return store, 0.0
        if not (same and store.step_done("bucket")):  # else only the sort was interrupted: finish it below
            store = Store.create(url, overwrite=True)
    else:
        store = Store.create(url)
    if not store.step_done("bucket"):
        store.update(source=src.to_json(), grid=grid.to_json())
        bucket(store, src, grid, chunk=chunk, quiet=quiet)
        store.mark_step("bucket", {"chunk": chunk})
    occ = map_tiles(sort_tile, store, runner=runner, label="tile: sort")
    log_t = int(round(np.log2(grid.tile_size)))
    total: dict[int, int] = {}
    for o in occ.values():
        for lev, count in enumerate(o):
            total[log_t - lev] = total.get(log_t - lev, 0) + int(count)
    store.update(occupancy={str(k): v for k, v in total.items()})
    store.mark_step("tile", {"tile_size": grid.tile_size})
    return store, time.perf_counter() - t0
