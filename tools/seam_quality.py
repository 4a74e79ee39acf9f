"""Does tiling show in the result?  Tiled runs of ``patchcloud normals`` against a single-tile run.

    python tools/seam_quality.py FILE.las|laz [--tiles 16 32 64] [--single 4096]

For each tile size: the median, 90th percentile and 99th percentile of the
angle between the tiled run's normals and the single-tile run's (same
points, same parameters: the single tile is a cube that holds the whole
file), and the share of points oriented the same way: of all points, of the
points the single-tile run gave a patch normal (NormalMethod 1 quadric, 2
blended) and of the others (k-NN fallback; their count in brackets).  Then the angle
jump between each point and its nearest neighbour, for neighbour pairs
that straddle a tile face against pairs that straddle a patch (leaf) face
inside a tile: if tiling showed, the first would be larger.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import laspy
import numpy as np
from scipy.spatial import cKDTree


def run(src: Path, out: Path, tile: float) -> tuple[np.ndarray, np.ndarray, dict]:
    from patchcloud.stream import normals

    store = str(out) + ".store"
    s = normals(src, out, tile_size=tile, scheduler="threads", quiet=True, overwrite=True, store=store)
    las = laspy.read(str(out))
    grid = json.loads((Path(store) / "zarr.json").read_text())["attributes"]["grid"]
    import shutil

    shutil.rmtree(store)
    info = {"grid": grid, "tiles": s.tiles, "method": np.asarray(las.NormalMethod)}
    return np.column_stack([las.NormalX, las.NormalY, las.NormalZ]).astype(np.float64), np.asarray(las.PatchId), info


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("file", type=Path)
    ap.add_argument("--tiles", type=float, nargs="+", default=[16, 32, 64])
    ap.add_argument("--single", type=float, default=4096)
    a = ap.parse_args()
    las = laspy.read(str(a.file))
    xyz = np.column_stack([las.x, las.y, las.z])
    tmp = Path(tempfile.mkdtemp())
    ref, _, info = run(a.file, tmp / "single.las", a.single)
    if info["tiles"] != 1:
        sys.exit(f"--single {a.single} gives {info['tiles']} tiles; use a larger one")
    tree = cKDTree(xyz)
    _, nb = tree.query(xyz, k=2)
    nb = nb[:, 1]
    print(f"{a.file.name}: {len(xyz):,} points")
    print(f"{'tile m':>7} | {'tiles':>5} | {'median deg':>10} | {'p90 deg':>8} | {'p99 deg':>8} | {'same side':>9} | "
          f"{'same side, patch':>16} | {'same side, others':>17} | {'jump tile faces (median/p90)':>28} | {'jump leaf faces (median/p90)':>28}")
    patch_pts = np.isin(info["method"], [1, 2])  # quadric and blended points of the single-tile run
    for T in a.tiles:
        nrm, patch, info = run(a.file, tmp / f"t{T:g}.las", T)
        cos = np.clip(np.einsum("ij,ij->i", nrm, ref), -1, 1)
        ang = np.degrees(np.arccos(np.abs(cos)))
        local = xyz - np.asarray(info["grid"]["origin"])
        tid = np.floor(local / info["grid"]["tile_size"]).astype(np.int64)
        cross_tile = np.any(tid != tid[nb], axis=1)
        cross_leaf = ~cross_tile & (patch != patch[nb])
        jump = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", nrm, nrm[nb]), -1, 1)))
        jt = np.percentile(jump[cross_tile], [50, 90]) if cross_tile.any() else [np.nan, np.nan]
        jl = np.percentile(jump[cross_leaf], [50, 90]) if cross_leaf.any() else [np.nan, np.nan]
        print(
            f"{T:7g} | {info['tiles']:5d} | {np.median(ang):10.4f} | {np.percentile(ang, 90):8.4f} | {np.percentile(ang, 99):8.3f} | "
            f"{np.mean(cos > 0):9.4%} | {np.mean(cos[patch_pts] > 0):16.4%} | {np.mean(cos[~patch_pts] > 0):17.4%} ({(~patch_pts).sum():,}) | {jt[0]:12.3f} / {jt[1]:7.3f} ({cross_tile.sum():,}) | {jl[0]:12.3f} / {jl[1]:7.3f} ({cross_leaf.sum():,})"
        )


if __name__ == "__main__":
    main()
