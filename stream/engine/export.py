"""Export: the input file again, every point once and in input order, with the results as extra dimensions.

The input is read a second time in the chunks used at ingest; for every
chunk, the store's index says how many of its points went to each tile,
and since a tile's results are kept in input order, they are the next
rows of that tile's result arrays.  Every byte of every original point
record (extra bytes included) is copied as it is; the new dimensions are
appended.  :func:`export_columns` does this for any set of per-tile result
arrays: a job declares its :class:`Column` s (see
:meth:`patchcloud.stream.engine.job.Job.columns`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import laspy
import numpy as np

from patchcloud.core import PatchcloudIOError

from patchcloud.stream.engine.ingest import pack_tile_keys, tile_keys
from patchcloud.stream.io.las import LasSource, atomic_output, is_laz_name, laz_backend, output_header, read_chunks
from patchcloud.stream.engine.progress import Progress
from patchcloud.stream.io.store import Store, tile_name

__all__ = ["Column", "export_columns", "FirstSeenIds"]


@dataclass(frozen=True)
class Column:
    """A per-tile result array (in the tile's input order) and the output dimensions it fills.

    ``array`` is the tile array's name; ``dims`` the output dimensions, one
    per column of the array (one for a 1-D array).  ``per_tile(t, values)``,
    when given, turns a tile's rows into output values (``t`` the tile's
    position in the store's list), e.g. to make ids global; ``per_chunk``
    then sees the whole chunk's values in input order.
    """

    array: str
    dims: tuple[str, ...]
    dtype: type
    per_tile: Callable[[int, np.ndarray], np.ndarray] | None = None
    per_chunk: Callable[[np.ndarray], np.ndarray] | None = None


class FirstSeenIds:
    """Renumbers ids 1, 2, ... in the order they first appear in the file (0 stays 0), chunk after chunk.

    Examples
    --------
    >>> f = FirstSeenIds()
    >>> f(np.array([0, 7, 3, 7])).tolist(), f(np.array([3, 9, 0])).tolist()
    ([0, 1, 2, 1], [2, 3, 0])
    """

    def __init__(self) -> None:
        self.known = np.zeros(0, dtype=np.int64)  # sorted ids seen so far
        self.number = np.zeros(0, dtype=np.int64)  # their new numbers

    def __call__(self, ids: np.ndarray) -> np.ndarray:
        ids = np.asarray(ids, dtype=np.int64)
        out = np.zeros(ids.shape, dtype=np.int64)
        nz = ids != 0
        if not nz.any():
            return out
        v = ids[nz]
        uniq, first = np.unique(v, return_index=True)
        pos = np.searchsorted(self.known, uniq)
        seen = np.zeros(uniq.size, dtype=bool)
        inside = pos < self.known.size
        seen[inside] = self.known[pos[inside]] == uniq[inside]
        new = uniq[~seen][np.argsort(first[~seen], kind="stable")]
        start = self.number.size + 1
        ids_all = np.r_[self.known, new]
        num_all = np.r_[self.number, np.arange(start, start + new.size)]
        o = np.argsort(ids_all, kind="stable")
        self.known, self.number = ids_all[o], num_all[o]
        out[nz] = self.number[np.searchsorted(self.known, v)]
        return out


def export_columns(
    store: Store, src: LasSource, output: str, columns: list[Column], dims, overwrite: bool = False, quiet: bool = False,
) -> None:
    """Write ``output`` (LAS, or LAZ when the name ends in .laz): ``src`` plus ``columns`` as dimensions ``dims``.

    ``dims`` are (name, numpy type, description) of the dimensions added,
    as :func:`patchcloud.stream.io.las.output_header` takes them.
    """
    header = output_header(src, dims)
    grid = store.grid
    chunk = int(store.attrs["chunk_points"])
    tiles = store.tiles
    tile_index = pack_tile_keys(np.asarray(tiles, dtype=np.int64))  # sorted: the store lists tiles in key order
    index = store.group["index/chunk_tile"][...]
    bounds = np.searchsorted(index[:, 0], np.arange(-(-src.point_count // chunk) + 1))
    taken = np.zeros(len(tiles), dtype=np.int64)
    arrays: dict[tuple, list] = {}
    bar = Progress("export", src.point_count, quiet=quiet)
    with atomic_output(output, overwrite) as f:
        with laspy.open(
            f, mode="w", header=header, do_compress=is_laz_name(output), closefd=False, laz_backend=laz_backend()
        ) as writer:
            for first, pts in read_chunks(src, chunk):
                c = first // chunk
                n = len(pts)
                xyz = np.column_stack([pts.array["X"], pts.array["Y"], pts.array["Z"]])
                tid = np.searchsorted(tile_index, tile_keys(grid, xyz))
                order = np.argsort(tid, kind="stable")
                rows = index[bounds[c] : bounds[c + 1]]
                counts = np.bincount(tid, minlength=len(tiles))
                if not np.array_equal(counts[rows[:, 1]], rows[:, 2]) or counts.sum() != rows[:, 2].sum():
                    raise PatchcloudIOError(f"{src.path}: the file no longer matches the store {store.url} (chunk {c})")
                values = [np.empty((n, len(col.dims)) if len(col.dims) > 1 else n, col.dtype) for col in columns]
                s = 0
                for t, m in zip(rows[:, 1].tolist(), rows[:, 2].tolist()):
                    ijk = tiles[t]
                    if ijk not in arrays:
                        g = store.group[f"tiles/{tile_name(ijk)}"]
                        arrays[ijk] = [g[col.array] for col in columns]
                    sl = slice(int(taken[t]), int(taken[t]) + m)
                    dst = order[s : s + m]
                    for col, a, v in zip(columns, arrays[ijk], values):
                        rows_t = a[sl]
                        v[dst] = col.per_tile(t, rows_t) if col.per_tile else rows_t
                    taken[t] += m
                    s += m
                out = laspy.PackedPointRecord.zeros(n, header.point_format)
                old = pts.array.dtype.itemsize
                new_bytes = out.array.view(np.uint8).reshape(n, out.array.dtype.itemsize)
                new_bytes[:, :old] = pts.array.view(np.uint8).reshape(n, old)
                for col, v in zip(columns, values):
                    if col.per_chunk:
                        v = col.per_chunk(v)
                    if len(col.dims) == 1:
                        out[col.dims[0]] = v.reshape(n)
                    else:
                        for k, name in enumerate(col.dims):
                            out[name] = v[:, k]
                writer.write_points(out)
                bar.update(n)
    bar.close()
