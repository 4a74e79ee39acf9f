"""Whole-process times of ``patchcloud normals`` against PDAL ``filters.normal`` on the files users have, same run.

    python tools/bench_small.py [--pdal PATH] [--repeats 5] [--city-points 4000000 ...] [--out tools/results/bench_small-DATE.txt]
    python tools/bench_small.py --modes --city-points 2000000 4000000 10000000 --only city [--repeats 3]

For each file (the embedded IGN tile, every LAS/LAZ of ../shared/data, and
a synthetic city of ``--city-points`` points from tools/city_las.py), both
tools run as a whole process, input file to output file, output in the
input's format (LAS or LAZ), ``--repeats`` times each, alternately:

- patchcloud: ``patchcloud normals IN OUT --overwrite -q`` (defaults: in
  memory up to 2 million points (10 million on a machine of at most 2 cores), else a local cluster of worker processes),
  after one untimed run so the numba cache and Python's byte-code cache
  are warm (as after ``pip install``: the runs unset
  ``PYTHONDONTWRITEBYTECODE``), and so is the cache of pyproj's answers
  about the file's CRS (``~/.cache/patchcloud/crs``: as for every file
  after the first of a catalog or a directory in one CRS);
- PDAL: ``pdal translate IN OUT normal --filters.normal.knn=8
  --writers.las.extra_dims=all`` (knn 8 as the issue measures it;
  PDAL's ``filters.normal`` is single-threaded).

The table gives each tool's minimum / median / maximum seconds, the ratio
PDAL median / patchcloud median (above 1: patchcloud is faster), and
patchcloud's peak RSS (GNU time's %M: the largest single process's peak,
not a sum over worker processes).  The goals (issue 15): the embedded tile under 1 s;
no slower than PDAL on any file; at least 3x faster on files of 500,000
points or more and on the city.  A missing PDAL is skipped with the reason
printed, and then no goal is met.  The machine (cores, CPU) heads the table.

With ``--modes``, no PDAL: patchcloud ``--in-memory`` against ``--on-disk``
(a store and a local cluster of worker processes) on each file, to show
where running in memory pays (the ``IN_MEMORY_POINTS`` default).
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SHARED = ROOT.parent / "shared" / "data"
SAMPLE = ROOT / "data" / "test_data_77055_627760_LA93_IGN69.laz"
#: Files of at least this many points must be 3x faster than PDAL.
BIG = 500_000
#: Options a file needs (by label): none since the GeoTIFF keys are read as PDAL reads them (lone-star's say geocentric
#: WGS 84, in metres; laspy read them as geographic EPSG:4326, refused without ``--units m``).
FILE_OPTIONS: dict[str, list[str]] = {}


def point_count(path: Path) -> int:
    import laspy

    with laspy.open(str(path)) as r:
        return int(r.header.point_count)


def inputs(city_points: list[int], work: Path) -> list[tuple[str, Path]]:
    """(label, path) of every file to time: the embedded tile, ../shared/data's LAS/LAZ, the synthetic city."""
    out = [("embedded IGN tile", SAMPLE)]
    if SHARED.is_dir():
        for p in sorted(SHARED.glob("*/*")):
            if p.suffix.lower() in (".las", ".laz"):
                out.append((f"{p.parent.name}/{p.name}", p))
    else:
        print(f"# ../shared/data not found beside the repo ({SHARED}): its files are skipped")
    for n in city_points:
        if n:
            city = work / f"city-{n}.laz"
            subprocess.run([sys.executable, str(HERE / "city_las.py"), str(city), "--points", str(n)], check=True,
                           stdout=subprocess.DEVNULL)
            out.append((f"synthetic city {n / 1e6:g}M", city))
    return out


#: The runs' environment: Python may cache byte code (``PYTHONDONTWRITEBYTECODE`` unset), as after ``pip install``,
#: which byte-compiles the package; a shell that sets it would time the compiling of every module at every start.
RUN_ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def timed(cmd: list[str]) -> tuple[float, float]:
    """Wall seconds and peak RSS (MiB, of the process and its children) of ``cmd``; raises if it fails."""
    t0 = time.perf_counter()
    proc = subprocess.run(["/usr/bin/time", "-f", "%M", *cmd], capture_output=True, text=True, env=RUN_ENV)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}): {proc.stderr.strip()[-400:]}")
    rss = float(proc.stderr.strip().splitlines()[-1]) / 1024.0
    return wall, rss


def find_pdal(asked: str | None) -> tuple[str | None, str]:
    """The PDAL command and its version line, or None and why not."""
    cmd = asked or os.environ.get("PDAL") or shutil.which("pdal")
    if not cmd:
        return None, "no pdal on PATH (give --pdal or $PDAL; PDAL 2.8 from source, see DEVELOPERS.md)"
    try:
        v = subprocess.run([cmd, "--version"], capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError) as exc:
        return None, f"{cmd} does not run ({exc})"
    line = next((ln.strip() for ln in v.splitlines() if "pdal" in ln.lower() and any(c.isdigit() for c in ln)), v.strip())
    return cmd, line


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pdal", default=None, help="The pdal command (default: $PDAL, else pdal on PATH).")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--city-points", type=int, nargs="*", default=[4_000_000], help="Points of the synthetic cities (0: none).")
    ap.add_argument("--modes", action="store_true", help="patchcloud in memory against on disk, no PDAL.")
    ap.add_argument("--only", nargs="*", default=None, help="Only the files whose label contains one of these.")
    ap.add_argument("--out", default=None, help="Also write the table here.")
    args = ap.parse_args()

    patchcloud = str(Path(sys.executable).with_name("patchcloud"))
    if args.modes:
        return modes(args, patchcloud)
    pdal, pdal_line = find_pdal(args.pdal)
    lines = [
        f"# bench_small: whole-process normals, patchcloud vs PDAL filters.normal (knn 8); {os.cpu_count()} cores, "
        f"{platform.processor() or platform.machine()}, Python {platform.python_version()}",
        f"# command: python tools/bench_small.py {' '.join(sys.argv[1:])}",
        f"# PDAL: {pdal_line}" if pdal else f"# PDAL skipped: {pdal_line}; no goal can be met",
        f"# {args.repeats} runs each, alternately, after a warm-up run (numba and byte-code caches warm, as after pip install); "
        f"seconds min / median / max; ratio = PDAL median / patchcloud median",
        f"{'file':<58} {'points':>10} {'patchcloud s':>20} {'PDAL s':>20} {'ratio':>6} {'RSS MiB':>8}  goal   (RSS: patchcloud's largest process)",
    ]
    for ln in lines:
        print(ln, flush=True)
    met_all = pdal is not None
    with tempfile.TemporaryDirectory(prefix="bench_small_") as tmp:
        work = Path(tmp)
        for label, path in inputs(args.city_points, work):
            if args.only and not any(o in label for o in args.only):
                continue
            n = point_count(path)
            out = work / f"out{path.suffix.lower()}"
            ours = [patchcloud, "normals", str(path), str(out), "--overwrite", "-q", *FILE_OPTIONS.get(label, [])]
            timed(ours)  # warm the numba cache (and the file in the page cache) first
            theirs = [pdal, "translate", str(path), str(out), "normal", "--filters.normal.knn=8",
                      "--writers.las.extra_dims=all"] if pdal else None
            if theirs:
                timed(theirs)
            a, b, rss = [], [], 0.0
            for _ in range(args.repeats):
                w, r = timed(ours)
                a.append(w)
                rss = max(rss, r)
                if theirs:
                    b.append(timed(theirs)[0])
            ma = statistics.median(a)
            fa = f"{min(a):.2f}/{ma:.2f}/{max(a):.2f}"
            if b:
                mb = statistics.median(b)
                fb, ratio = f"{min(b):.2f}/{mb:.2f}/{max(b):.2f}", mb / ma
                need = 3.0 if (n >= BIG or label.startswith("synthetic")) else 1.0
                ok = ratio >= need and (label != "embedded IGN tile" or ma < 1.0)
                goal = f"{'met' if ok else 'MISSED'} (>= {need:g}x{', < 1 s' if label == 'embedded IGN tile' else ''})"
                met_all &= ok
                rs = f"{ratio:.2f}"
            else:
                fb, rs, goal = "skipped", "-", "no peer"
            line = f"{label:<58} {n:>10,} {fa:>20} {fb:>20} {rs:>6} {rss:>8.0f}  {goal}"
            lines.append(line)
            print(line, flush=True)
    tail = f"# all goals met: {'yes' if met_all else 'no'}"
    lines.append(tail)
    print(tail)
    if args.out:
        Path(args.out).write_text("\n".join(lines) + "\n")


def modes(args, patchcloud: str) -> None:
    """patchcloud --in-memory against --on-disk, whole process, each file (see the module's docstring)."""
    lines = [
        f"# bench_small --modes: whole-process patchcloud normals, in memory vs on disk; {os.cpu_count()} cores, "
        f"{platform.processor() or platform.machine()}, Python {platform.python_version()}",
        f"# command: python tools/bench_small.py {' '.join(sys.argv[1:])}",
        f"# {args.repeats} runs each, alternately; seconds min / median / max; RSS: peak of the largest process (MiB); "
        "ratio = on-disk median / in-memory median",
        f"{'file':<40} {'points':>11} {'in memory s':>20} {'RSS':>6} {'on disk s':>20} {'RSS':>6} {'ratio':>6}",
    ]
    for ln in lines:
        print(ln, flush=True)
    with tempfile.TemporaryDirectory(prefix="bench_small_") as tmp:
        work = Path(tmp)
        for label, path in inputs(args.city_points, work):
            if args.only and not any(o in label for o in args.only):
                continue
            out = work / f"out{path.suffix.lower()}"
            runs = {m: [patchcloud, "normals", str(path), str(out), "--overwrite", "-q", m, *FILE_OPTIONS.get(label, [])]
                    for m in ("--in-memory", "--on-disk")}
            timed(runs["--in-memory"])  # warm
            got = {m: ([], 0.0) for m in runs}
            for _ in range(args.repeats):
                for m, cmd in runs.items():
                    w, r = timed(cmd)
                    got[m] = (got[m][0] + [w], max(got[m][1], r))
            (a, ra), (b, rb) = got["--in-memory"], got["--on-disk"]
            fa, fb = (f"{min(x):.2f}/{statistics.median(x):.2f}/{max(x):.2f}" for x in (a, b))
            line = (f"{label:<40} {point_count(path):>11,} {fa:>20} {ra:>6.0f} {fb:>20} {rb:>6.0f} "
                    f"{statistics.median(b) / statistics.median(a):>6.2f}")
            lines.append(line)
            print(line, flush=True)
    if args.out:
        Path(args.out).write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
