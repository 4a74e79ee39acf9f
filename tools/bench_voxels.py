"""When DoN's fast mode should sum voxels: the same radius moments computed both ways, timed, per file and radius.

    python tools/bench_voxels.py [--city-points 1000000] [--radii 0.5 1 2 5] [--out FILE]

For each cloud (the synthetic city's first N points and the real files of
../shared/data, as tools/bench_don.py loads them: a missing one is skipped
with the reason printed) and each radius, ``patchcloud.core.radius.radius_moments``
runs with voxels forced and with the points forced (the ``density`` argument
set far above or below the threshold), the best of two runs each, compute
only, on every core.  The table gives the points a voxel holds on average
(what ``uses_voxels`` compares with ``VOXEL_MIN_POINTS``), both times, their
ratio, what fast mode chooses and whether that is the faster way.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bench_don import REAL, city_cloud, real_clouds  # noqa: E402  (tools/ is not a package)
from patchcloud.core.radius import VOXEL_MIN_POINTS, cell_density, radius_moments, uses_voxels, voxel_points  # noqa: E402

#: Voxels per radius, as patchcloud don's default --resolution.
RESOLUTION = 4


def best_time(pts: np.ndarray, radius: float, density: float, runs: int = 2) -> float:
    """Best wall time of ``runs`` calls of radius_moments with this ``density`` (which decides voxels or points)."""
    best = np.inf
    for _ in range(runs):
        t = time.perf_counter()
        radius_moments(pts, radius, density=density)
        best = min(best, time.perf_counter() - t)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--city-points", type=int, default=1_000_000, help="points of the synthetic city (0: none)")
    ap.add_argument("--radii", type=float, nargs="+", default=[0.5, 1.0, 2.0, 5.0])
    ap.add_argument("--out", default=None, help="also write the table here")
    a = ap.parse_args()
    warm = np.random.default_rng(0).uniform(0, 10, (5000, 3))
    radius_moments(warm, 1.0, density=1e9)  # numba's cache loaded (or the kernels compiled) before any timing
    radius_moments(warm, 1.0, density=1e-9)
    lines = [
        f"# bench_voxels {datetime.date.today()} on {platform.node()}: {os.cpu_count()} cores; "
        f"command: python tools/bench_voxels.py {' '.join(sys.argv[1:])}",
        f"# VOXEL_MIN_POINTS = {VOXEL_MIN_POINTS:g}; times: compute only, best of 2, every core",
        f"{'cloud':<22} {'points':>9} {'r':>5} {'pts/voxel':>9} {'voxels s':>9} {'points s':>9} {'pts/vox':>8} "
        f"{'chosen':>7} {'faster?':>8}",
    ]
    print("\n".join(lines), flush=True)
    clouds = ([(f"city-{a.city_points // 1000}k", city_cloud(a.city_points)[0])] if a.city_points else [])
    for name, pts in [*clouds, *real_clouds(list(REAL))]:
        for r in a.radii:
            density = cell_density(pts, r / RESOLUTION)
            per_voxel = voxel_points(r, RESOLUTION, density)
            vox, points = best_time(pts, r, 1e12), best_time(pts, r, 1e-12)
            chosen = "voxels" if uses_voxels(r, RESOLUTION, density) else "points"
            right = (chosen == "voxels") == (vox < points)
            line = (f"{name:<22} {len(pts):>9,} {r:>5g} {per_voxel:>9.1f} {vox:>9.3f} {points:>9.3f} {points / vox:>8.2f} "
                    f"{chosen:>7} {'yes' if right else 'no':>8}")
            lines.append(line)
            print(line, flush=True)
    if a.out:
        Path(a.out).write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
