"""Export: the input file again, every point once and in input order, with the results as extra dimensions.

The input is read a second time in the chunks used at ingest; for every
chunk, the store's index says how many of its points went to each tile,
and since a tile's results are kept in input order, they are the next
rows of that tile's result arrays.  Every byte of every original point
record (extra bytes included) is copied as it is; the new dimensions
(:data:`patchcloud.stream.lasio.OUTPUT_DIMS`) are appended.
"""

from __future__ import annotations

import laspy
import numpy as np

from patchcloud.core.errors import PatchcloudIOError

from .ingest import _pack, tile_keys
from .lasio import LasSource, _laz_backend, atomic_output, is_laz_name, output_header, read_chunks
from .progress import Progress
from .store import Store, tile_name

__all__ = ["export_normals"]


def export_normals(store: Store, src: LasSource, output: str, overwrite: bool = False, quiet: bool = False) -> None:
    """Write ``output`` (LAS, or LAZ when the name ends in .laz) from ``src`` and the store's results."""
    header = output_header(src)
    grid = store.grid
    chunk = int(store.attrs["chunk_points"])
    tiles = store.tiles
    tile_index = _pack(np.asarray(tiles, dtype=np.int64))  # sorted: the store lists tiles in key order
    patch_offsets = np.asarray(store.attrs["patch_offsets"], dtype=np.int64)
    index = store.group["index/chunk_tile"][...]
    bounds = np.searchsorted(index[:, 0], np.arange(-(-src.point_count // chunk) + 1))
    taken = np.zeros(len(tiles), dtype=np.int64)
    arrays = {ijk: None for ijk in tiles}
    bar = Progress("export", src.point_count, quiet=quiet)
    with atomic_output(output, overwrite) as f:
        with laspy.open(
            f, mode="w", header=header, do_compress=is_laz_name(output), closefd=False, laz_backend=_laz_backend()
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
                normal = np.empty((n, 3), np.float32)
                curvature = np.empty(n, np.float32)
                method = np.empty(n, np.uint8)
                patch = np.empty(n, np.uint32)
                s = 0
                for t, m in zip(rows[:, 1].tolist(), rows[:, 2].tolist()):
                    ijk = tiles[t]
                    if arrays[ijk] is None:
                        g = store.group[f"tiles/{tile_name(ijk)}"]
                        arrays[ijk] = (g["normal"], g["curvature"], g["method"], g["patch"])
                    a_n, a_c, a_m, a_p = arrays[ijk]
                    sl = slice(int(taken[t]), int(taken[t]) + m)
                    dst = order[s : s + m]
                    normal[dst] = a_n[sl]
                    curvature[dst] = a_c[sl]
                    method[dst] = a_m[sl]
                    patch[dst] = a_p[sl] + patch_offsets[t]
                    taken[t] += m
                    s += m
                out = laspy.PackedPointRecord.zeros(n, header.point_format)
                old = pts.array.dtype.itemsize
                new_bytes = out.array.view(np.uint8).reshape(n, out.array.dtype.itemsize)
                new_bytes[:, :old] = pts.array.view(np.uint8).reshape(n, old)
                out["NormalX"], out["NormalY"], out["NormalZ"] = normal[:, 0], normal[:, 1], normal[:, 2]
                out["Curvature"] = curvature
                out["NormalMethod"] = method
                out["PatchId"] = patch
                writer.write_points(out)
                bar.update(n)
    bar.close()

