"""How a model-mode ``.pcz`` codes its residual points, and what each choice costs: bits per residual point.

    python tools/bench_residual_codec.py [--max-error 0.05] [--out FILE] [LAS ...]

For each file (default: the real aerial files of ../shared/data; a missing
one is skipped with the reason printed) the file is compressed at the
budget, its residual points are found in the input (the input points whose
coded position is that of a residual point of the ``.pcz``: a point of a
patch sharing a residual point's 5 cm cell counts too, a few in a
thousand), and their records, tile by tile in input order, are coded:

- ``v4``: version 4's residual records: position within the budget,
  classification, intensity and returns exact, input order;
- ``v5 input`` / ``v5 Morton`` / ``v5 columns``: version 5's
  (:mod:`patchcloud.stream.io.residual_points`: the class, the intensity on
  the tile's 64 levels, return 1 of 1) as LAZ in input order, in the
  Morton order of their coded positions, and column by column;
- ``v5 octree``: the same as an octree block (:mod:`patchcloud.stream.io.residual_octree`);
- ``v5``: the smallest of the four, tile by tile (what ``compress`` stores);
- ``v5, no intensity``, ``xyz``: what the intensity and the class cost
  (the same, with those zero; the returns, all 1 of 1, cost nothing);
- ``numcodecs``: version 5's records in input order under numcodecs'
  best of Blosc-Zstd 9 with byte shuffle and Zstd 19 on byte columns
  (why the blocks are LAZ).

Prints a table (bits per residual point; the last column bits per point of
the whole file for ``v5`` and the ``.pcz``'s size); ``--out`` writes it too.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import laspy
import numpy as np
from numcodecs import Blosc, Zstd

from patchcloud.stream import compress
from patchcloud.stream.io import pcz
from patchcloud.stream.io.laz_block import records_laz
from patchcloud.stream.io.point_coding import coarse_records, coarse_steps
from patchcloud.stream.io.residual_points import column_order, morton_order, octree_block, residual_dropped, stored_records

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
DEFAULT = [SHARED / "lidar-ign-stbarth/St_Barth_RGAF09_UTM20N_IGN_1988_SB_subset_100m.laz",
           SHARED / "lidar-ign-lidarhd-tiles/test_data_77055_627760_LA93_IGN69.laz",
           SHARED / "lidar-ign-extrabytes/las_with_several_extra_byte_bloc.laz",
           SHARED / "lidar-lastools/house.laz", SHARED / "lidar-lastools/fusa.laz"]
VARIANTS = ("v4", "v5 input", "v5 Morton", "v5 columns", "v5 octree", "v5", "v5, no intensity", "xyz", "numcodecs")


def residual_records(path: Path, out: Path, budget: float):
    """The input's records, its point format, the coded steps, and per tile of ``out`` (a model-mode .pcz of it):
    the positions of the input's residual points in input order and the tile's intensity shift."""
    las = laspy.read(path)
    steps = coarse_steps(budget, las.header.scales)
    X = np.column_stack([np.asarray(las.points[a], dtype=np.int64) for a in "XYZ"])
    coded = (X + np.asarray(steps) // 2) // np.asarray(steps)  # point_coding.coarsen, per axis
    with pcz.open_pcz(out) as f:
        T, origin = f.tile_size, np.asarray(f.attrs["grid"]["origin"], dtype=np.float64)
        scale, offset = np.asarray(las.header.scales), np.asarray(las.header.offsets)
        tile_of = np.floor((X * scale + offset - origin) / T).astype(np.int64)
        tiles = []
        for t in range(len(f.tiles)):
            rxyz, _ = f.residual(t)
            if not len(rxyz):
                continue
            mine = np.flatnonzero(np.all(tile_of == f.tiles[t], axis=1))
            want = {tuple(r) for r in (rxyz.astype(np.int64) // np.asarray(steps)).tolist()}
            keep = mine[[tuple(c) in want for c in coded[mine].tolist()]]
            tiles.append((keep, int(f.intensity_shift[t])))
    return las, steps, tiles


def sizes(path: Path, budget: float) -> dict:
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "r.pcz"
        t0 = time.perf_counter()
        s = compress(path, out, max_error=budget, quiet=True, units="m")
        seconds = time.perf_counter() - t0
        las, steps, tiles = residual_records(path, out, budget)
        pcz_bytes = out.stat().st_size
    pf = las.point_format
    rows_all = np.ascontiguousarray(las.points.array).view(np.uint8).reshape(len(las.points), pf.size)
    scales, offsets, version = las.header.scales, las.header.offsets, str(las.header.version)
    v5_drop = residual_dropped(pf)
    v4_drop = v5_drop
    total = dict.fromkeys(VARIANTS, 0)
    n = 0

    def laz(r):
        return len(records_laz(r, pf, version, np.asarray(scales) * np.asarray(steps), offsets))

    for keep, shift in tiles:
        rec = rows_all[keep]
        n += len(keep)
        total["v4"] += laz(coarse_records(rec, pf, steps, v4_drop))
        v5, _ = stored_records(rec, pf, steps, v5_drop, shift)
        a, b, c = laz(v5), laz(v5[morton_order(v5)]), laz(v5[column_order(v5)])
        octree = octree_block(v5, pf, True)
        d = len(octree) if octree is not None else a
        total["v5 input"] += a
        total["v5 Morton"] += b
        total["v5 columns"] += c
        total["v5 octree"] += d
        total["v5"] += min(a, b, c, d)
        for name, drop in (("v5, no intensity", ("intensity",)),
                           ("xyz", ("intensity", "return_number", "number_of_returns", "classification"))):
            r, _ = stored_records(rec, pf, steps, v5_drop + drop, shift)
            octree = octree_block(r, pf, "return_number" not in drop)
            total[name] += min(laz(r), laz(r[morton_order(r)]), laz(r[column_order(r)]), len(octree) if octree else 1 << 62)
        L = pf.size
        total["numcodecs"] += min(len(Blosc(cname="zstd", clevel=9, shuffle=Blosc.SHUFFLE, typesize=L).encode(v5)),
                                  len(Zstd(level=19).encode(np.ascontiguousarray(v5.T))))
    return {"residual": n, "points": s.points, "bytes": total, "pcz_bytes": pcz_bytes, "seconds": seconds}


def table(rows: list[tuple[str, dict]], budget: float) -> str:
    out = [f"| file (at {budget:g} m) | residual points | " + " | ".join(VARIANTS) + " | v5 bits/pt of the file | .pcz bits/pt |",
           "|---|---:|" + "---:|" * (len(VARIANTS) + 2)]
    for name, r in rows:
        n = max(r["residual"], 1)
        cells = " | ".join(f"{8 * r['bytes'][v] / n:.2f}" for v in VARIANTS)
        out.append(f"| {name} | {r['residual']:,} ({r['residual'] / r['points']:.0%}) | {cells} | "
                   f"{8 * r['bytes']['v5'] / r['points']:.2f} | {8 * r['pcz_bytes'] / r['points']:.2f} |")
    return "\n".join(out)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="*", type=Path, default=DEFAULT)
    ap.add_argument("--max-error", type=float, default=0.05)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    rows = []
    for path in a.files:
        if not path.exists():
            print(f"{path}: skipped (missing)", file=sys.stderr)
            continue
        print(f"# {path.name} ...", file=sys.stderr)
        rows.append((path.name, sizes(path, a.max_error)))
    head = [f"# tools/bench_residual_codec.py, {time.strftime('%Y-%m-%d')}: python tools/bench_residual_codec.py "
            + " ".join(argv if argv is not None else sys.argv[1:]),
            f"# {os.cpu_count()} cores ({platform.machine()}); bits per residual point unless said; laspy {laspy.__version__}",
            ""]
    text = "\n".join(head + [table(rows, a.max_error), ""])
    print(text)
    if a.out:
        a.out.write_text(text)


if __name__ == "__main__":
    main()
