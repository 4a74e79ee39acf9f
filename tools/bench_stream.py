"""Benchmark of ``patchcloud normals`` (or ``don``, ``segment``, ``compress``) on synthetic city scans of growing size, against the I/O floor.

    python tools/bench_stream.py [--sizes 5e6 20e6 100e6] [--workdir /tmp/bench_stream] [--ext laz]
                                 [--scheduler auto] [--job normals|don|segment|compress] [--options "--rs 0.2 --rl 2"]

For every size: a synthetic city (tools/city_las.py, streamed to disk) is
made once; then, each in its own process,

* the I/O floor: laspy reads the file in chunks of 2**20 points and writes
  it back with four float32 extra dimensions (what any tool writing
  normals must at least do);
* ``patchcloud JOB IN OUT`` with default settings (plus ``--options``);
  OUT is a ``.pcz`` for ``compress``.

Printed: wall seconds, points/s, the ratio to the floor, peak RSS (of the
whole process tree: the child's own high-water mark, and patchcloud's sum
over its worker processes), and the time per point relative to the
smallest size.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent

FLOOR = r'''
import copy, sys, resource, time, laspy, numpy as np
src, dst = sys.argv[1], sys.argv[2]
t = time.perf_counter()
with laspy.open(src, laz_backend=laspy.LazBackend.LazrsParallel) as r:
    h = copy.deepcopy(r.header)
    h.add_extra_dims([laspy.ExtraBytesParams(name=n, type=np.float32) for n in ("NX", "NY", "NZ", "Curv")])
    with laspy.open(dst, mode="w", header=h, do_compress=dst.endswith(".laz")) as w:
        for pts in r.chunk_iterator(1 << 20):
            n = len(pts)
            out = laspy.PackedPointRecord.zeros(n, h.point_format)
            old = pts.array.dtype.itemsize
            out.array.view(np.uint8).reshape(n, -1)[:, :old] = pts.array.view(np.uint8).reshape(n, old)
            out["NX"] = np.ones(n, np.float32)
            w.write_points(out)
print(time.perf_counter() - t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)
'''


def run_floor(src: Path, dst: Path) -> tuple[float, int]:
    out = subprocess.run([sys.executable, "-c", FLOOR, str(src), str(dst)], check=True, capture_output=True, text=True)
    t, rss = out.stdout.split()
    return float(t), int(rss)


def run_job(job: str, src: Path, dst: Path, scheduler: str, options: list[str]) -> tuple[float, int, int, str]:
    exe = Path(sys.executable).with_name("patchcloud")
    cmd = [str(exe), job, str(src), str(dst), "--overwrite", "--scheduler", scheduler, *options]
    t = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    _, status, usage = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t
    text = p.stdout.read()
    if status != 0:
        raise RuntimeError(f"patchcloud {job} failed on {src}:\n{text}")
    m = re.search(r"peak memory\s+([\d,]+) MiB", text)
    summed = int(m.group(1).replace(",", "")) * 2**20 if m else 0
    return wall, usage.ru_maxrss * 1024, summed, text


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=float, nargs="+", default=[5e6, 20e6, 100e6])
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/bench_stream"))
    ap.add_argument("--ext", choices=["las", "laz"], default="laz")
    ap.add_argument("--scheduler", default="auto")
    ap.add_argument("--job", choices=["normals", "don", "segment", "compress"], default="normals")
    ap.add_argument("--options", default="", help="more options of the job, as one string")
    a = ap.parse_args()
    sys.path.insert(0, str(HERE))
    import city_las

    a.workdir.mkdir(parents=True, exist_ok=True)
    rows = []
    for size in a.sizes:
        n = int(size)
        src = a.workdir / f"city_{n}.{a.ext}"
        if not src.exists():
            t = time.perf_counter()
            city_las.write_city(src, n)
            print(f"generated {src} in {time.perf_counter() - t:.0f} s", flush=True)
        t_floor, rss_floor = run_floor(src, a.workdir / f"floor.{a.ext}")
        wall, rss_child, rss_sum, text = run_job(a.job, src, a.workdir / f"out.{'pcz' if a.job == 'compress' else a.ext}", a.scheduler,
                                                a.options.split())
        print(text, flush=True)
        rows.append((n, t_floor, rss_floor, wall, rss_child, rss_sum))
        print(f"{n:>12,}  floor {t_floor:7.1f} s  {a.job} {wall:7.1f} s  ratio {wall / t_floor:4.2f}  peak {max(rss_child, rss_sum) / 2**20:6.0f} MiB", flush=True)
    base = rows[0][3] / rows[0][0]
    print()
    print(f"patchcloud {a.job} {a.options} vs I/O floor ({a.ext}, scheduler {a.scheduler}, {os.cpu_count()} cores)")
    print(f"{'points':>12} | {'floor s':>8} | {'floor pts/s':>11} | {a.job + ' s':>9} | {'pts/s':>9} | {'x floor':>7} | {'peak RSS MiB':>12} | {'floor RSS':>9} | {'s/pt vs first':>13}")
    for n, tf, rf, w, rc, rs in rows:
        print(f"{n:>12,} | {tf:8.1f} | {n / tf:11,.0f} | {w:9.1f} | {n / w:9,.0f} | {w / tf:7.2f} | {max(rc, rs) / 2**20:12,.0f} | {rf / 2**20:9,.0f} | {(w / n) / base:13.2f}")


if __name__ == "__main__":
    main()
