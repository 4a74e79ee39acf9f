"""Scaling of ``patchcloud normals``: workers, the I/O floor, worker occupancy and the Amdahl bound; one table.

    python tools/bench_scale.py [--laz-points 10000000] [--las-points 30000000] [--workers 1 2]
                                [--repeats 1] [--scheduler processes] [--tile-size METRES] [--workdir DIR]
                                [--out tools/results/bench_scale-DATE.txt] [--keep-profiles DIR]

For each file (a synthetic city, ``tools/city_las.py`` seed 0: a LAZ of
``--laz-points`` and a LAS of ``--las-points``; 0 skips one) and each
worker count, it runs ``patchcloud normals IN OUT --workers W --scheduler S
--profile P`` as its own process and reports:

- wall time (the whole process) and points per second, the speed-up over
  the first worker count;
- the I/O floor measured in the same run: W processes each reading its
  share of the file with laspy (lazrs' sequential codec) and writing it
  back as the same format; the job's time as a multiple of it;
- peak memory: the sum of the proportional set sizes of the job's
  processes (the command, the workers' fork server and every worker),
  sampled together every 0.1 s (a page k processes share counts 1/k in
  each: the workers share the fork server's);
- CPU time in user and system mode and minor page faults, summed over the
  command and its workers, as the run's ``--profile`` records them (the
  fork server's own, about a second of imports, is not counted); before
  the profile recorded them, ``getrusage(RUSAGE_CHILDREN)`` around the run;
- from the task stream (``--profile``): ``idle`` the share of the wall
  time during which fewer tasks run than there are workers (start-up and
  the client's own work included), ``client`` the share during which no
  task runs, the longest task, and the Amdahl bound: with ``c`` the time
  no task runs and ``w`` the summed task time, ``(c + w) / (c + w / N)`` is
  the most N workers can speed the run up (tasks assumed to split evenly);
  and the list bound (:func:`list_bound`): the same, with the tiles' tasks
  as they are (a step lasts at least as long as its longest task), except
  the big tiles' ``finish``, which N workers cut into pieces (modelled:
  :func:`cut_into_pieces`); ``whole 16`` is that bound with no piece cut.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import resource
import shutil
import subprocess
import sys
import threading
import time
from datetime import date
from pathlib import Path

import laspy
import numpy as np

HERE = Path(__file__).resolve().parent


def _tree_memory(root: int) -> int:
    """Memory of ``root`` and all its descendants (from /proc): their proportional set sizes summed (a page shared by
    k processes counts 1/k in each: the worker processes forked from one server share its pages), or their resident
    sizes where /proc has no ``smaps_rollup``."""
    parent = {}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat") as f:
                parent[int(d)] = int(f.read().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
    keep = {root}
    changed = True
    while changed:
        changed = False
        for pid, pp in parent.items():
            if pp in keep and pid not in keep:
                keep.add(pid)
                changed = True
    return sum(_memory(p) for p in keep)


def _memory(pid: int) -> int:
    """Proportional set size of ``pid`` (bytes), else its resident size, else 0 (a process gone)."""
    for path, key in ((f"/proc/{pid}/smaps_rollup", "Pss:"), (f"/proc/{pid}/status", "VmRSS:")):
        try:
            with open(path) as f:
                for line in f:
                    if line.startswith(key):
                        return int(line.split()[1]) * 1024
        except OSError:
            continue
    return 0


def run_measured(cmd: list[str]) -> tuple[float, int, str, dict]:
    """Run ``cmd``; return its wall time (s), the peak of its process tree's summed memory (bytes, :func:`_tree_memory`),
    its output, and its waited-for descendants' user and system CPU seconds and minor page faults (``user``, ``sys``,
    ``faults``: forked workers are not among them, see :func:`main`)."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    peak = [0]

    def sample():
        while p.poll() is None:
            peak[0] = max(peak[0], _tree_memory(p.pid))
            time.sleep(0.1)

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    out, err = p.communicate()
    wall = time.perf_counter() - t0
    th.join()
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({p.returncode}):\n{err[-2000:]}")
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = dict(user=r1.ru_utime - r0.ru_utime, sys=r1.ru_stime - r0.ru_stime, faults=r1.ru_minflt - r0.ru_minflt)
    return wall, peak[0], out + err, cpu


def _copy_share(path: str, out: str, first: int, count: int) -> None:
    """Read points ``first .. first + count`` of ``path`` and write them to ``out`` (one I/O floor worker)."""
    with laspy.open(path, laz_backend=laspy.LazBackend.Lazrs) as r:
        header = r.header
        r.seek(first)
        with laspy.open(out, mode="w", header=header, laz_backend=laspy.LazBackend.Lazrs, do_compress=out.endswith(".laz")) as w:
            done = 0
            while done < count:
                pts = r.read_points(min(1_000_000, count - done))
                w.write_points(pts)
                done += len(pts)


def io_floor(path: Path, workers: int, workdir: Path) -> float:
    """Seconds for ``workers`` processes to read and write their shares of ``path`` (same format)."""
    with laspy.open(str(path)) as r:
        n = r.header.point_count
    share = -(-n // workers)
    args = [(str(path), str(workdir / f"floor{k}{path.suffix}"), k * share, min(share, n - k * share)) for k in range(workers)]
    t0 = time.perf_counter()
    with mp.get_context("spawn").Pool(workers) as pool:
        pool.starmap(_copy_share, args)
    t = time.perf_counter() - t0
    for a in args:
        Path(a[1]).unlink(missing_ok=True)
    return t


def occupancy(profile: dict) -> dict:
    """Idle and client shares of the wall time, longest task, summed task time, from a ``--profile`` file."""
    slots = int(profile["slots"])
    t0, t1 = float(profile["started"]), float(profile["ended"])
    tasks = np.asarray([[s, e] for _, s, e, _ in profile["tasks"]], dtype=np.float64).reshape(-1, 2)
    tasks = np.clip(tasks, t0, t1)
    events = np.r_[tasks[:, 0], tasks[:, 1], t0, t1]
    delta = np.r_[np.ones(len(tasks)), -np.ones(len(tasks)), 0, 0]
    o = np.lexsort((delta, events))
    events, delta = events[o], delta[o]
    running = np.cumsum(delta)[:-1]
    span = np.diff(events)
    wall = t1 - t0
    idle = float(span[running < slots].sum())
    client = float(span[running <= 0].sum())
    durations = tasks[:, 1] - tasks[:, 0]
    return dict(
        wall=wall, idle=idle / wall, client=client / wall, client_s=client, longest=float(durations.max(initial=0.0)),
        work=float(durations.sum()), slots=slots,
    )


#: Steps whose tasks are parts of the input (cut finer for more workers: ``part_size``), not tiles.
PART_STEPS = ("tile: read", "records: read", "export", "export: ids")


#: Steps whose tiles a run on more workers cuts into pieces (:func:`patchcloud.stream.engine.tasks.pieces_for`).
PIECE_STEPS = ("finish",)
#: The share of a tile's finish time that each of its pieces repeats (reading the tile, its octree, the patch normals
#: of all its points): ``python tools/bench_finish_pieces.py STORE`` on the 10M city's largest tile, 0.31 and 0.29 at
#: 3 and 5 pieces (tools/results/bench_finish_pieces-2026-11-26.txt).
PIECE_OVERHEAD = 0.3


def cut_into_pieces(durations: list[float], n: int, overhead: float = PIECE_OVERHEAD, min_share: float = 0.0) -> list[float]:
    """The tasks of a piece step on ``n`` workers, from its tasks' times as recorded whole.

    As :func:`patchcloud.stream.engine.tasks.pieces_for` cuts by points,
    with time for points: a task longer than the step's time over ``n``
    (but at least ``min_share``, the time of the fewest points a piece
    gets) is cut into ``k = ceil(d / share)`` pieces of
    ``d (f + (1 - f) / k)`` each (``f`` the ``overhead``).  Largest first,
    as the step submits them.
    """
    share = max(sum(durations) / max(n, 1), min_share)
    pieces = []
    for d in durations:
        k = int(np.ceil(d / share)) if share > 0 and d > share else 1
        pieces += [d] if k == 1 else [d * (overhead + (1.0 - overhead) / k)] * k
    return sorted(pieces, reverse=True)


def _makespan(durations: list[float], n: int) -> float:
    """When the last of ``durations`` ends on ``n`` workers each taking the next task as it frees (in the given order)."""
    free = np.zeros(n)
    for d in durations:
        k = int(np.argmin(free))
        free[k] += d
    return float(free.max(initial=0.0))


def list_bound(profile: dict, points: int, n: int, pieces: bool = True) -> float:
    """The speed-up over one worker that ``n`` workers could give, step by step, from a run's task stream.

    Unlike Amdahl's bound, tasks do not split: each step's recorded tasks
    (a tile's, whatever the worker count) are dealt in their order to the
    first free of ``n`` workers, and the next step starts when the last
    ends, so a step of few or uneven tasks is as long as its longest.  The
    steps over parts of the input (:data:`PART_STEPS`) are cut as ``n``
    workers would cut them (``part_size(points, n)``), their work split
    evenly over those parts; with ``pieces``, the tiles of the steps that
    cut big tiles (:data:`PIECE_STEPS`) are cut as N workers would cut
    them (:func:`cut_into_pieces`: a model, from a run that may have cut
    none).  The client's time (no task running) stays as it was.  Tasks run no slower on more workers here: memory bandwidth
    and the file system shared by the workers are left out, so this is a
    bound, not a forecast.
    """
    from patchcloud.stream.engine.ingest import part_size
    from patchcloud.stream.engine.tasks import PIECE_MIN_POINTS

    t0, t1 = float(profile["started"]), float(profile["ended"])
    steps: dict[str, list[float]] = {}
    for label, s, e, _ in sorted(profile["tasks"], key=lambda t: t[1]):
        steps.setdefault(label, []).append(max(0.0, min(e, t1) - max(s, t0)))
    occ = occupancy(profile)
    span = 0.0
    for label, durations in steps.items():
        if label in PART_STEPS:
            parts = -(-points // part_size(points, n))
            durations = [sum(durations) / parts] * parts
        if label in PIECE_STEPS and pieces:  # no piece under PIECE_MIN_POINTS points: their share of the step's time
            durations = cut_into_pieces(durations, n, min_share=sum(durations) * PIECE_MIN_POINTS / max(points, 1))
        span += _makespan(durations, n)
    return (occ["client_s"] + occ["work"]) / (occ["client_s"] + span)


def amdahl(client_s: float, work: float, n: int) -> float:
    """The speed-up bound for ``n`` workers over one: (c + w) / (c + w / n)."""
    return (client_s + work) / (client_s + work / n)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--laz-points", type=int, default=10_000_000)
    ap.add_argument("--las-points", type=int, default=30_000_000)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--scheduler", default="processes")
    ap.add_argument("--repeats", type=int, default=1, help="runs of each case: the table shows the median run and the range")
    ap.add_argument("--tile-size", type=float, default=None, help="passed to patchcloud normals (default: its own)")
    ap.add_argument("--workdir", default="/tmp/bench_scale")
    ap.add_argument("--out", default=None, help="also write the table there")
    ap.add_argument("--floor", choices=("each", "first", "none"), default="each",
                    help="measure the I/O floor before each run (each), before the first worker count's runs only (first), or not")
    ap.add_argument("--keep-profiles", default=None, metavar="DIR",
                    help="keep each run's task stream there, as profile-FILE-wW.json (tools/task_stream.py reads them)")
    a = ap.parse_args(argv)
    work = Path(a.workdir)
    work.mkdir(parents=True, exist_ok=True)
    exe = [sys.executable, "-m", "patchcloud.stream.console"]  # the patchcloud command (console script)
    files = []
    for n, suffix in ((a.laz_points, ".laz"), (a.las_points, ".las")):
        if n:
            path = work / f"city-{n}{suffix}"
            if not path.exists():
                subprocess.run([sys.executable, str(HERE / "city_las.py"), str(path), "--points", str(n)], check=True)
            files.append((path, n))
    # warm the numba cache so that no run pays for compiling
    subprocess.run(exe + ["normals", str(HERE.parent / "data" / "test_data_77055_627760_LA93_IGN69.laz"), str(work / "warm.laz"),
                          "--overwrite", "-q", "--scheduler", a.scheduler, "--workers", "1"], check=True)
    lines = [
        f"# bench_scale {date.today()} on {platform.node()}: {os.cpu_count()} cores, {platform.processor() or platform.machine()}; "
        f"scheduler {a.scheduler}; python {platform.python_version()}",
        f"# command: python tools/bench_scale.py --laz-points {a.laz_points} --las-points {a.las_points} "
        f"--workers {' '.join(map(str, a.workers))} --scheduler {a.scheduler}" + (f" --tile-size {a.tile_size:g}" if a.tile_size else "")
        + (f" --repeats {a.repeats}" if a.repeats > 1 else "") + (f" --floor {a.floor}" if a.floor != "each" else ""),
        "",
        f"{'file':<22} {'tiles':>5} {'workers':>7} {'wall s':>8} {'range s':>11} {'Mpts/s':>7} {'speed-up':>8} {'floor s':>8} {'x floor':>7} {'peak MiB':>9} "
        f"{'user s':>7} {'sys s':>6} {'faults M':>8} {'idle':>6} {'client':>7} {'longest s':>9} {'Amdahl 16':>9} {'Amdahl 64':>9} "
        f"{'list 16':>7} {'list 64':>7} {'whole 16':>8}",
    ]
    print("\n".join(lines), flush=True)
    for path, n in files:
        base = None
        for w in a.workers:
            runs = []  # each: wall, peak, cpu, profile, floor (the I/O floor measured just before that run)
            for _ in range(a.repeats):
                floor = io_floor(path, w, work) if a.floor == "each" or (a.floor == "first" and w == a.workers[0]) else float("nan")
                out = work / f"out{path.suffix}"
                out.unlink(missing_ok=True)  # the last run's output: replacing it would charge its removal to this run
                prof = work / "profile.json"
                wall, peak, _, cpu = run_measured(exe + ["normals", str(path), str(out), "--overwrite", "-q", "--workers", str(w),
                                                    "--scheduler", a.scheduler, "--profile", str(prof)]
                                                  + (["--tile-size", f"{a.tile_size:g}"] if a.tile_size else []))
                profile = json.loads(prof.read_text())
                # the workers are the fork server's children, not this command's: their CPU time is in the profile
                cpu = profile.get("cpu", cpu)
                runs.append((wall, peak, cpu, profile, floor))
                if a.keep_profiles:
                    Path(a.keep_profiles).mkdir(parents=True, exist_ok=True)
                    shutil.copyfile(prof, Path(a.keep_profiles) / f"profile-{path.stem}-w{w}.json")
            runs.sort(key=lambda r: r[0])
            wall, peak, cpu, profile, floor = runs[(len(runs) - 1) // 2]  # the median run (the lower one of an even count)
            spread = f"{runs[0][0]:.1f}-{runs[-1][0]:.1f}"
            occ = occupancy(profile)
            if w == a.workers[0]:
                base = wall
            line = (
                f"{path.name:<22} {sum(1 for t in profile['tasks'] if t[0] == 'fit'):>5} {w:>7} {wall:>8.1f} {spread:>11} {n / wall / 1e6:>7.2f} {base / wall:>7.2f}x {floor:>8.1f} {wall / floor:>6.1f}x "
                f"{peak / 2**20:>9,.0f} {cpu['user']:>7.1f} {cpu['sys']:>6.1f} {cpu['faults'] / 1e6:>8.2f} {occ['idle']:>6.1%} {occ['client']:>7.1%} {occ['longest']:>9.2f} "
                f"{amdahl(occ['client_s'], occ['work'], 16):>8.1f}x {amdahl(occ['client_s'], occ['work'], 64):>8.1f}x "
                f"{list_bound(profile, n, 16):>6.1f}x {list_bound(profile, n, 64):>6.1f}x {list_bound(profile, n, 16, pieces=False):>7.1f}x"
            )
            print(line, flush=True)
            lines.append(line)
    lines += [
        "",
        "# tiles: the store's tiles (fit tasks); wall: the whole `patchcloud normals` process (start-up and export included), the",
        "# median of --repeats runs (range: all of them; the other columns are the median run's); floor: W processes reading and writing",
        "# their shares of the file with laspy + lazrs' sequential codec (nan: not measured, --floor); peak: proportional set sizes summed over the job's",
        "# processes, sampled together every 0.1 s; user, sys: CPU seconds of the command and its workers (the run's profile);",
        "# faults: their minor page faults (millions);",
        "# idle: share of the wall time with fewer tasks running than workers; client: with none;",
        "# Amdahl N: (c + w) / (c + w / N), c the time no task runs, w the summed task time (speed-up bound over one worker);",
        "# list N: (c + w) / (c + sum of the steps' makespans on N workers), tiles' tasks as recorded, parts recut for N, the big",
        "# tiles' finish cut in pieces as N workers would cut them (a model: PIECE_OVERHEAD); whole 16: no piece cut.",
    ]
    if a.out:
        Path(a.out).write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
