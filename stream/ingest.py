"""Ingest: read a LAS/LAZ file in chunks and cut it into the store's tiles.

The file is read once, in input order, ``chunk`` points at a time; each
chunk's points are bucketed by tile and appended to the tiles' ``raw``
arrays (LAS integer coordinates, so nothing is rounded), flushing the
buffers whenever they hold more than ``buffer`` points: memory is bounded
by these two settings, not by the file.  The store also records how many
points of every input chunk went to every tile, which is how results find
their way back to the input order at export.  The per-tile sort by octree
key (:func:`patchcloud.stream.steps.sort_tile`) then runs as dask tasks.
"""

from __future__ import annotations

import numpy as np

from patchcloud.core.errors import PatchcloudValueError

from .lasio import LasSource, read_chunks
from .progress import Progress
from .store import ANCHOR, MAX_TILE, Grid, Store

__all__ = ["auto_tile_size", "make_grid", "bucket", "bucket_records", "TARGET_TILE_POINTS"]

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


def make_grid(src: LasSource, tile_size: float | None) -> Grid:
    """The tile grid of a file: ``tile_size`` rounded down to a power of two (metres), or the default."""
    if tile_size is None:
        t = auto_tile_size(src)
    else:
        if not np.isfinite(tile_size) or tile_size <= 0:
            raise PatchcloudValueError(f"tile size must be a positive number of metres, got {tile_size!r}")
        if tile_size > MAX_TILE:
            raise PatchcloudValueError(f"tile size must be at most {MAX_TILE:g} m, got {tile_size:g}")
        t = float(2.0 ** np.floor(np.log2(tile_size)))
    origin = tuple(float(np.floor(m / ANCHOR) * ANCHOR) for m in src.mins)
    return Grid(origin=origin, tile_size=t, scale=src.scale, offset=src.offset)


def _pack(ijk: np.ndarray) -> np.ndarray:
    b = ijk + _BIAS
    return (b[:, 0] << 42) | (b[:, 1] << 21) | b[:, 2]


def _unpack(key: np.ndarray) -> np.ndarray:
    key = np.asarray(key, dtype=np.int64)
    return np.column_stack([(key >> 42) & 0x1FFFFF, (key >> 21) & 0x1FFFFF, key & 0x1FFFFF]) - _BIAS


def tile_keys(grid: Grid, xyz: np.ndarray) -> np.ndarray:
    """Packed tile index of each point (LAS integer coordinates); ordering keys orders tiles lexicographically."""
    return _pack(grid.tile_of(grid.local(xyz)))


def _route(grid: Grid, local: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points of a chunk by tile: the stable order that groups them, the sorted tile keys, and each run's start and end."""
    keys = _pack(grid.tile_of(local))
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
            store.append(tuple(_unpack(np.array([key]))[0]), name, np.concatenate(buffers[key]))
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
            store.append(tuple(_unpack(np.array([key]))[0]), "raw", np.concatenate(buffers[key]))
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
    tiles = _unpack(tile_keys_sorted)
    counts = np.bincount(np.searchsorted(tile_keys_sorted, rec[:, 1]), weights=rec[:, 2], minlength=tiles.shape[0])
    index = np.column_stack([rec[:, 0], np.searchsorted(tile_keys_sorted, rec[:, 1]), rec[:, 2]]).astype(np.int64)
    a = store.group.create_array("index/chunk_tile", shape=index.shape, dtype=np.int64, chunks=(max(1, min(1 << 16, index.shape[0])), 3), overwrite=True)
    a[...] = index
    store.update(
        tiles=tiles.tolist(), tile_counts=counts.astype(np.int64).tolist(), chunk_points=int(chunk),
        centroid_local=(total / max(src.point_count, 1)).tolist(),
    )
