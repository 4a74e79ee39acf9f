"""Why the residual points of a ``.pcz`` are LAZ: their bytes under LAZ (lazrs) and under numcodecs' best.

    python tools/bench_residual_codec.py [--max-error 0.05] [LAS ...]

For each file (default: two IGN files of ../shared/data; a missing one is
skipped with the reason printed) the file is compressed at the budget, its
residual records (whole LAS records, byte for byte) are read back, and
their size is printed under: LAZ as stored (lazrs, one stream per tile),
Blosc-Zstd 9 with byte shuffle, Zstd 19 on byte columns, and Zstd 19 on
XYZ deltas plus byte columns.  Prints one line per file.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from numcodecs import Blosc, Zstd

from patchcloud.stream import compress, pcz

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
DEFAULT = [SHARED / "lidar-ign-stbarth/St_Barth_RGAF09_UTM20N_IGN_1988_SB_subset_100m.laz",
           SHARED / "lidar-ign-lidarhd-tiles/test_data_77055_627760_LA93_IGN69.laz"]


def sizes(path: Path, budget: float) -> tuple[int, int, dict[str, int]]:
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "r.pcz"
        compress(path, out, max_error=budget, quiet=True)
        laz, raw = 0, []
        with pcz.open_pcz(out) as f:
            for t in range(len(f.tiles)):
                laz += int(f.residual_byte_start[t + 1] - f.residual_byte_start[t])
                xyz, rec = f.residual(t)
                raw.append(np.hstack([xyz.view(np.uint8).reshape(-1, 12), rec]))
    raw = np.ascontiguousarray(np.vstack(raw))
    n, L = raw.shape
    xyz = raw[:, :12].copy().view("<i4").reshape(-1, 3).astype(np.int64)
    deltas = np.diff(xyz, axis=0, prepend=0).astype("<i4").view(np.uint8).reshape(-1, 12)
    z19 = Zstd(level=19)
    return n, L, {
        "LAZ (lazrs, as stored)": laz,
        "Blosc-Zstd 9, byte shuffle": len(Blosc(cname="zstd", clevel=9, shuffle=Blosc.SHUFFLE, typesize=L).encode(raw)),
        "Zstd 19, byte columns": len(z19.encode(np.ascontiguousarray(raw.T))),
        "Zstd 19, XYZ deltas + byte columns": len(z19.encode(np.ascontiguousarray(deltas.T)))
        + len(z19.encode(np.ascontiguousarray(raw[:, 12:].T))),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="*", type=Path, default=DEFAULT)
    ap.add_argument("--max-error", type=float, default=0.05)
    a = ap.parse_args()
    for path in a.files:
        if not path.exists():
            print(f"{path}: skipped (missing)")
            continue
        n, L, s = sizes(path, a.max_error)
        laz = s["LAZ (lazrs, as stored)"]
        cells = "; ".join(f"{k} {v:,} B = {8 * v / n:.1f} bits/pt ({v / laz:.2f}x LAZ)" for k, v in s.items())
        print(f"{path.name}: {n:,} residual points of {L} B at {a.max_error:g} m: {cells}")


if __name__ == "__main__":
    main()
