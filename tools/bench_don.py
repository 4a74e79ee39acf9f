"""Difference-of-Normals benchmark: patchcloud's exact and fast modes against PCL and a scipy cKDTree baseline.

    python tools/bench_don.py [--sizes 1000000 4000000] [--real [NAME ...]] [--rs 0.2] [--rl 2.0] [--aerial-radii 1 5]
                              [--baseline-queries 20000] [--exact-queries 0] [--out FILE]

Inputs: the first N points of the synthetic city of tools/city_las.py (75 %
mobile-LiDAR points, then 25 % aerial ones over the same streets), and the
real LAS/LAZ files and KITTI scan of ../shared/data (a missing file is
skipped with the reason printed).  Every cloud is moved to a local frame
(its minimum subtracted) and kept in its file order; one viewpoint (the
default one of ``patchcloud.core.radius.default_viewpoint``) serves all
methods.

Methods, each in a fresh subprocess that loads the cloud from a temporary
.npy (only the computation is timed):

- ``exact``: ``patchcloud.core.difference_of_normals(mode="exact")``, all
  points (or a random sample of ``--exact-queries`` points via ``at=``);
- ``fast``: the same with ``mode="fast"``, all points;
- ``fast-shifted``: fast mode on the cloud moved by (0.377, 0.613, 0.131)
  times r_l: its voxels fall elsewhere on the points, so its agreement
  with ``fast`` shows how much fast mode depends on the frame's origin;
- ``pcl``: PCL's ``NormalEstimationOMP`` (radius search) at both radii and
  ``DifferenceOfNormalsEstimation``, k-d tree build included, on as many
  threads as patchcloud uses (tools/pcl_peer.py builds the C++ peer
  against the Debian package libpcl-dev; skipped with the reason when
  missing); PCL writes a zero DoN where a normal is undefined, so its
  undefined share reads 0 %;
- ``baseline``: scipy ``cKDTree.query_ball_point`` (both cores) + PCA of
  each ball (moments by ``np.bincount``, batched ``np.linalg.eigh``) at
  both radii, on a random sample of ``--baseline-queries`` points with the
  tree over all points; its points/s is sample size / time.

The patchcloud workers first run one warm-up call on a small subset, so
numba compilation (or loading its cache) is not timed; the baseline builds
its tree before the clock starts.  Both appear in the ``setup s`` column.
Peak RSS is the worker's VmHWM: ``ru_maxrss`` is useless here, as a child
started by ``subprocess`` inherits its parent's high-water mark.

The agreement table compares DoN magnitudes on the same points: fast
against exact (all points, and the mobile points of the city apart), and
the baseline against exact on the baseline's sample (a check of the
baseline: both implement PCL's definition).
"""

from __future__ import annotations

import argparse
import datetime
import itertools
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "data"
METHODS = ("exact", "fast", "fast-shifted", "pcl", "baseline")
#: fast-shifted moves the cloud by this many r_l (not a multiple of any voxel edge)
SHIFT = np.array([0.377, 0.613, 0.131])
#: the DoN threshold at which the agreement table compares the points kept
IOU_AT = 0.25
#: Real inputs: name -> path under ../shared/data.
REAL = {
    "ign-extrabytes": "lidar-ign-extrabytes/las_with_several_extra_byte_bloc.laz",
    "ign-stbarth": "lidar-ign-stbarth/St_Barth_RGAF09_UTM20N_IGN_1988_SB_subset_100m.laz",
    "lastools-house": "lidar-lastools/house.laz",
    "lastools-fusa": "lidar-lastools/fusa.laz",
    "tls-lone-star": "tls-lone-star/lone-star.laz",
    "ign-lidarhd-77055": "lidar-ign-lidarhd-tiles/test_data_77055_627760_LA93_IGN69.laz",
    "kitti-000008": "mobile-kitti/000008.bin",
}
#: Airborne inputs (5-35 points/m2): with --aerial-radii they get radii suited to their density.
AERIAL = ("ign-extrabytes", "ign-stbarth", "lastools-house", "lastools-fusa", "ign-lidarhd-77055")
#: Points of the warm-up call of the patchcloud workers.
WARMUP_POINTS = 20_000


# ----------------------------------------------------------------------------- workers
def _peak_rss_mib() -> float:
    """Peak resident memory of this process (VmHWM, MiB); unlike ru_maxrss it is not inherited from the parent."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return float(line.split()[1]) / 1024.0
    return float("nan")


def baseline_normals(pts: np.ndarray, tree, query: np.ndarray, radius: float, viewpoint: np.ndarray, batch: int = 1000) -> np.ndarray:
    """PCA normals of the points within ``radius`` of each query point, from a cKDTree ball query.

    Same definition as patchcloud's exact mode: covariance of the ball's
    points about their centroid, smallest eigenvector, turned towards
    ``viewpoint``; NaN rows for fewer than three points or a collinear or
    coincident ball.
    """
    out = np.full((len(query), 3), np.nan)
    pairs = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
    for lo in range(0, len(query), batch):
        q = query[lo : lo + batch]
        m = len(q)
        nb = tree.query_ball_point(q, radius, workers=-1, return_sorted=False)
        lens = np.fromiter(map(len, nb), dtype=np.int64, count=m)
        flat = np.fromiter(itertools.chain.from_iterable(nb), dtype=np.int64, count=int(lens.sum()))
        owner = np.repeat(np.arange(m), lens)
        d = pts[flat] - q[owner]  # offsets from the query point: no loss in large coordinates
        n = np.maximum(lens, 1).astype(np.float64)
        mean = np.stack([np.bincount(owner, d[:, i], minlength=m) for i in range(3)], axis=1) / n[:, None]
        cov = np.empty((m, 3, 3))
        for i, j in pairs:
            cov[:, i, j] = cov[:, j, i] = np.bincount(owner, d[:, i] * d[:, j], minlength=m) / n - mean[:, i] * mean[:, j]
        w, v = np.linalg.eigh(cov)
        normal = v[:, :, 0]
        flip = np.einsum("ij,ij->i", viewpoint - q, normal) < 0
        normal[flip] *= -1.0
        ok = (lens >= 3) & (w[:, 1] > 1e-12 * w[:, 2]) & (w[:, 2] > 0)
        out[lo : lo + batch][ok] = normal[ok]
    return out


def _worker(method: str, cloud: str, at: str, out: str, params: str) -> None:
    """Run one method in this (fresh) process; save the DoN magnitudes to ``out`` and print a JSON summary."""
    prm = json.loads(params)
    rs, rl, vp = prm["rs"], prm["rl"], np.asarray(prm["viewpoint"])
    pts = np.load(cloud)
    idx = np.load(at) if at != "-" else None
    split: list[float] = []  # seconds of the normals at r_s, then at r_l
    if method in ("exact", "fast", "fast-shifted"):
        import patchcloud.core.don as don_module
        from patchcloud.core import difference_of_normals, don_magnitude

        normals = don_module.radius_normals

        def timed_normals(*args, **kwargs):
            t0 = time.perf_counter()
            res = normals(*args, **kwargs)
            split.append(time.perf_counter() - t0)
            return res

        don_module.radius_normals = timed_normals  # difference_of_normals calls it at r_s, then at r_l
        mode = "fast" if method == "fast-shifted" else method
        if method == "fast-shifted":
            pts, vp = pts + SHIFT * rl, vp + SHIFT * rl
        t = time.perf_counter()
        difference_of_normals(pts[:WARMUP_POINTS], rs, rl, viewpoint=vp, mode=mode)
        setup = time.perf_counter() - t
        split.clear()
        t = time.perf_counter()
        mag = don_magnitude(difference_of_normals(pts, rs, rl, viewpoint=vp, mode=mode, at=idx))
        dt = time.perf_counter() - t
    elif method == "pcl":
        from numba import get_num_threads
        from pcl_peer import run_pcl

        setup = 0.0
        dt, don = run_pcl(pts, "don", (rs, rl), vp, get_num_threads())
        mag = np.sqrt(np.einsum("ij,ij->i", don, don))
        if idx is not None:
            mag = mag[idx]
    elif method == "baseline":
        from scipy.spatial import cKDTree

        t = time.perf_counter()
        tree = cKDTree(pts)
        setup = time.perf_counter() - t
        q = pts[idx]
        t = time.perf_counter()
        small = baseline_normals(pts, tree, q, rs, vp)
        split.append(time.perf_counter() - t)
        large = baseline_normals(pts, tree, q, rl, vp)
        split.append(time.perf_counter() - t - split[0])
        don = (small - large) / 2.0
        mag = np.sqrt(np.einsum("ij,ij->i", don, don))
        dt = time.perf_counter() - t
    else:
        raise SystemExit(f"unknown method {method}")
    np.save(out, mag)
    peak = _peak_rss_mib()
    if method == "pcl":  # the peer's own peak (a child's high-water mark starts at its parent's at the fork)
        import resource

        peak = max(peak, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0)
    print(json.dumps({"seconds": dt, "split": split, "setup": setup, "queries": len(mag), "peak_mib": peak}))


def run_method(method: str, cloud: Path, at: np.ndarray | None, tmp: Path, params: dict):
    """Run ``method`` in a subprocess on the cloud saved at ``cloud``: (summary dict, magnitudes), or (None, reason)."""
    at_file, out = "-", tmp / f"{method}_mag.npy"
    if at is not None:
        at_file = str(tmp / f"{method}_at.npy")
        np.save(at_file, at)
    r = subprocess.run(
        [sys.executable, __file__, "--worker", method, str(cloud), at_file, str(out), json.dumps(params)],
        capture_output=True, text=True,
    )
    if r.returncode != 0:
        err = r.stderr.strip().splitlines()
        return None, f"failed: {err[-1] if err else r.returncode}"
    return json.loads(r.stdout.strip().splitlines()[-1]), np.load(out)


# ----------------------------------------------------------------------------- data
def _label(n: int) -> str:
    """1000000 -> '1M', 100000 -> '100k'."""
    return f"{n // 1_000_000}M" if n % 1_000_000 == 0 else f"{n // 1000}k"


def city_cloud(n: int) -> tuple[np.ndarray, np.ndarray]:
    """The first ``n`` points of the synthetic city (local frame) and the mask of its mobile-LiDAR points."""
    sys.path.insert(0, str(HERE))
    from city_las import iter_city_chunks

    chunks = list(iter_city_chunks(n, seed=0))
    pts = np.column_stack([np.concatenate([c[k] for c in chunks]) for k in "xyz"])
    mobile = np.concatenate([c["point_source_id"] for c in chunks]) == 1
    return pts - pts.min(axis=0), mobile


def real_clouds(names):
    """Yield (name, local-frame points) for the real inputs ``names``; print why a missing one is skipped."""
    for name in names:
        path = SHARED / REAL[name]
        if not path.exists():
            print(f"# skipping {name}: {path} not found", flush=True)
            continue
        if path.suffix == ".bin":
            pts = np.fromfile(path, "<f4").reshape(-1, 4)[:, :3].astype(np.float64)
        else:
            try:
                import laspy

                las = laspy.read(path)
            except Exception as e:  # laspy missing, or no LAZ backend
                print(f"# skipping {name}: cannot read {path.name}: {e}", flush=True)
                continue
            pts = np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)])
        yield name, pts - pts.min(axis=0)


# ----------------------------------------------------------------------------- statistics and tables
def agreement(a: np.ndarray, b: np.ndarray) -> dict:
    """Median, 95th and 99th percentiles of |a - b|, Spearman's rho where both are defined, shares undefined, and the
    intersection over union of the points each keeps at the threshold IOU_AT (a >= IOU_AT, b >= IOU_AT)."""
    from scipy.stats import spearmanr

    ok = np.isfinite(a) & np.isfinite(b)
    diff = np.abs(a[ok] - b[ok])
    with np.errstate(invalid="ignore"):
        ka, kb = a >= IOU_AT, b >= IOU_AT
    rho = spearmanr(a[ok], b[ok]).statistic if ok.sum() > 2 else float("nan")
    return {
        "points": len(a), "undef_a": float(np.mean(~np.isfinite(a))), "undef_b": float(np.mean(~np.isfinite(b))),
        "median": float(np.median(diff)) if diff.size else float("nan"),
        "p95": float(np.percentile(diff, 95)) if diff.size else float("nan"),
        "p99": float(np.percentile(diff, 99)) if diff.size else float("nan"), "rho": float(rho),
        "iou": float(np.sum(ka & kb) / max(np.sum(ka | kb), 1)),
    }


def _density(pts: np.ndarray, tree_sample: int = 2000, radius: float = 2.0) -> float:
    """Median number of points within ``radius`` of a random sample of points (for the notes)."""
    from scipy.spatial import cKDTree

    idx = np.random.default_rng(1).choice(len(pts), min(len(pts), tree_sample), replace=False)
    return float(np.median(cKDTree(pts).query_ball_point(pts[idx], radius, workers=-1, return_length=True)))


def speed_table(name: str, n: int, rows: dict, skipped: dict, notes: list[str]) -> list[str]:
    """Markdown lines of one input's timing table."""
    base, pcl = rows.get("baseline"), rows.get("pcl")
    base_rate = base["queries"] / base["seconds"] if base else float("nan")
    pcl_rate = pcl["queries"] / pcl["seconds"] if pcl else float("nan")
    out = [f"### {name}", "",
           "| input | points | method | queries | seconds | r_s + r_l s | points/s | peak RSS MiB | setup s | speed / baseline | speed / PCL |",
           "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for m in METHODS:
        if m in rows:
            r = rows[m]
            rate = r["queries"] / r["seconds"]
            out.append(f"| {name} | {n:,} | {m} | {r['queries']:,} | {r['seconds']:.2f} | {' + '.join(f'{x:.2f}' for x in r['split'])} | {rate:,.0f} | "
                       f"{r['peak_mib']:,.0f} | {r['setup']:.2f} | {rate / base_rate:.1f}x | {rate / pcl_rate:.2f}x |")
        else:
            out.append(f"| {name} | {n:,} | {m} | - | - | - | - | - | - | - | skipped: {skipped.get(m, 'not run')} |")
    return out + [""] + [f"- {s}" for s in notes] + [""]


def agreement_table(rows: list[tuple[str, str, str, dict]]) -> list[str]:
    """Markdown lines of the agreement table: (input, subset, compared, agreement dict) per row."""
    out = ["### Agreement of DoN magnitudes", "",
           f"| input | subset | compared | points | undefined (1st) | undefined (2nd) | median abs diff | p95 abs diff | p99 abs diff | Spearman rho | IoU at {IOU_AT:g} |",
           "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, subset, what, a in rows:
        out.append(f"| {name} | {subset} | {what} | {a['points']:,} | {a['undef_a']:.1%} | {a['undef_b']:.1%} | "
                   f"{a['median']:.2e} | {a['p95']:.2e} | {a['p99']:.3f} | {a['rho']:.4f} | {a['iou']:.3f} |")
    return out + [""]


# ----------------------------------------------------------------------------- main
def bench_input(name: str, pts: np.ndarray, mobile: np.ndarray | None, a, tmp: Path, emit) -> list[tuple]:
    """Run the methods on one cloud, emit its timing table; return its agreement rows."""
    from patchcloud.core.radius import default_viewpoint

    n = len(pts)
    rng = np.random.default_rng(0)
    rs, rl = (a.aerial_radii if a.aerial_radii and name in AERIAL else (a.rs, a.rl))
    params = {"rs": rs, "rl": rl, "viewpoint": default_viewpoint(pts).tolist()}
    cloud = tmp / "cloud.npy"
    np.save(cloud, np.ascontiguousarray(pts))
    base_at = np.sort(rng.choice(n, min(n, a.baseline_queries), replace=False))
    exact_at = np.sort(rng.choice(n, a.exact_queries, replace=False)) if 0 < a.exact_queries < n else None
    rows, mags, skipped = {}, {}, {}
    for m in a.methods:
        print(f"# {name}: {m} ...", file=sys.stderr, flush=True)
        at = base_at if m == "baseline" else exact_at if m == "exact" else None
        info, res = run_method(m, cloud, at, tmp, params)
        if info is None:
            skipped[m] = res
            continue
        rows[m], mags[m] = info, res
    notes = [f"r_s = {rs:g} m, r_l = {rl:g} m; cloud {pts.nbytes / 2**20:,.1f} MiB as float64; median points within {rl:g} m of a point: {_density(pts, radius=rl):,.0f}"]
    if "baseline" in rows:
        notes.append(f"baseline: {len(base_at):,} random query points, tree over all {n:,}; points/s = queries / seconds "
                     f"(the tree build, in 'setup s', excluded)")
    if exact_at is not None and "exact" in rows:
        notes.append(f"exact: {len(exact_at):,} random query points (at=), neighbours among all {n:,}; points/s = queries / seconds")
    emit(speed_table(name, n, rows, skipped, notes))

    agree = []
    if "fast" in mags and "fast-shifted" in mags:
        agree.append((name, f"all, moved {np.round(SHIFT * rl, 3).tolist()} m", "fast-shifted vs fast", agreement(mags["fast-shifted"], mags["fast"])))
    if "exact" in mags:
        ex_idx = np.arange(n) if exact_at is None else exact_at
        ex = mags["exact"]
        if "fast" in mags:
            sub = "" if exact_at is None else f" ({len(ex_idx):,} sampled)"
            agree.append((name, f"all{sub}, r {rs:g}/{rl:g} m", "fast vs exact", agreement(mags["fast"][ex_idx], ex)))
            if mobile is not None:
                keep = mobile[ex_idx]
                agree.append((name, "mobile" + sub, "fast vs exact", agreement(mags["fast"][ex_idx][keep], ex[keep])))
        if "pcl" in mags:
            agree.append((name, "all" if exact_at is None else f"exact sample ({len(ex_idx):,})", "pcl vs exact", agreement(mags["pcl"][ex_idx], ex)))
        if "baseline" in mags:
            pos = np.searchsorted(ex_idx, base_at)
            inside = (pos < len(ex_idx)) & (ex_idx[np.minimum(pos, len(ex_idx) - 1)] == base_at)
            if inside.any():
                agree.append((name, f"baseline sample{'' if inside.all() else ' (in exact sample)'}", "baseline vs exact",
                              agreement(mags["baseline"][inside], ex[pos[inside]])))
    return agree


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="*", default=[1_000_000, 4_000_000], help="points of the synthetic city")
    ap.add_argument("--real", nargs="*", default=list(REAL), choices=list(REAL), metavar="NAME",
                    help=f"real inputs (default all: {', '.join(REAL)}; none if given empty)")
    ap.add_argument("--rs", type=float, default=0.2, help="small radius (m)")
    ap.add_argument("--rl", type=float, default=2.0, help="large radius (m)")
    ap.add_argument("--aerial-radii", type=float, nargs=2, metavar=("RS", "RL"), default=None,
                    help=f"radii for the airborne files ({', '.join(AERIAL)}) instead of --rs/--rl, e.g. 1 5")
    ap.add_argument("--methods", nargs="*", default=list(METHODS), choices=METHODS)
    ap.add_argument("--baseline-queries", type=int, default=20_000, help="random query points of the baseline")
    ap.add_argument("--exact-queries", type=int, default=0, help="random query points of exact mode (0: all points)")
    ap.add_argument("--out", type=Path, help="also write the tables to this file")
    ap.add_argument("--worker", nargs=5, metavar=("METHOD", "CLOUD", "AT", "OUT", "PARAMS"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.worker:
        _worker(*a.worker)
        return

    text: list[str] = []

    def emit(lines: list[str]) -> None:
        text.extend(lines)
        print("\n".join(lines), flush=True)

    started = time.perf_counter()
    emit([f"# tools/bench_don.py, {datetime.date.today()}: {' '.join(['python', 'tools/bench_don.py'] + sys.argv[1:])}",
          f"# {os.cpu_count()} cores ({platform.processor() or platform.machine()}), load average at start "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}; the machine is shared with other work, so timings are noisy.",
          f"# r_s = {a.rs:g} m, r_l = {a.rl:g} m" + (f" (airborne files: {a.aerial_radii[0]:g} m, {a.aerial_radii[1]:g} m)" if a.aerial_radii else " for every input (the sparse aerial files too)")
          + "; points in file order, local frame.",
          f"# seconds: wall time of the DoN computation alone (both radii), in a fresh process per method; setup s: "
          f"patchcloud's warm-up call on {WARMUP_POINTS:,} points (numba compile / cache load), the baseline's cKDTree build;",
          "# r_s + r_l s: the part of 'seconds' spent on the normals at each radius.", ""])
    tmp = Path(tempfile.mkdtemp(prefix="bench_don"))
    agree = []
    try:
        for n in a.sizes:
            pts, mobile = city_cloud(n)
            agree += bench_input(f"city-{_label(n)}", pts, mobile, a, tmp, emit)
        for name, pts in real_clouds(a.real):
            agree += bench_input(name, pts, None, a, tmp, emit)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    emit(agreement_table(agree))
    emit(["- undefined (1st)/(2nd): share of points whose DoN is undefined (NaN) in the first/second method; "
          "differences and rho over the points where both are defined.",
          "- city 'mobile': the city's mobile-LiDAR points (point_source_id 1) only.",
          f"- total wall time {time.perf_counter() - started:.0f} s; load average at end {' '.join(f'{x:.2f}' for x in os.getloadavg())}.", ""])
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text("\n".join(text) + "\n")


if __name__ == "__main__":
    main()
