"""Normal-estimation benchmark: patchcloud against point-wise peers, same points, same run.

    python tools/bench_normals.py [--sizes 1000000 4000000] [--real] [--orders shuffled morton]

Methods (each in its own subprocess, so peak memory is per method):

- ``patchcloud-rmse`` / ``patchcloud-sigma3``: ``patchcloud.core.estimate_normals``
  (compiled kernels warmed up on a strided sample of 20,000 points of the same
  cloud first, so loading them from numba's cache is excluded);
- ``knn-pca``: scipy cKDTree k=30 (both cores) + batched ``numpy.linalg.eigh``;
- ``open3d``: ``PointCloud.estimate_normals(KDTreeSearchParamKNN(30))`` (extra ``bench``);
- ``open3d-knn16``: the same with 16 neighbours;
- ``pcl-knn16``: PCL's ``NormalEstimationOMP`` with 16 neighbours on the same
  threads (k-d tree build included; built against Debian's libpcl-dev by
  tools/pcl_peer.py), on the cloud moved to its minimum corner (PCL is float32);
- ``cc-ls`` / ``cc-quadric``: CloudCompare ``-OCTREE_NORMALS`` with ``-MODEL LS`` /
  ``QUADRIC`` (Debian package cloudcompare) and the radius that holds 30
  neighbours at the median point, timed as the CloudCompare process minus a
  process that only loads and saves the same cloud (best of two runs each).

Missing peers are skipped with a printed reason.  Data: the synthetic scene of
tools/synthetic.py (known normals), the reference meshes of ../shared/data
(mesh normals are the reference) and, with ``--real``, its LAS/LAZ files
(no reference: the angle columns then give the difference from knn-pca).
Every cloud runs twice: shuffled, and sorted in Morton order.

After each block a comment line gives patchcloud's time per step and the
share of points that fell back to k-NN.

Columns: seconds (wall), points/s, peak RSS of the method's process (MB),
median and 90th-percentile sign-insensitive angle error (degrees), the same
median on smooth points only (all true normals of the 10 nearest neighbours
within 5 degrees), and the share of normals oriented against the reference.
Peers are given the same global rule afterwards (per point: up for scenes and
LiDAR, outward from the centroid for meshes), untimed.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "data"
METHODS = ["patchcloud-rmse", "patchcloud-sigma3", "knn-pca", "open3d", "open3d-knn16", "pcl-knn16", "cc-ls", "cc-quadric"]


# ----------------------------------------------------------------------------- workers
def _rss_mb() -> float:
    """Peak resident memory of this process (VmHWM; unlike ru_maxrss it is not inherited over exec)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return float(line.split()[1]) / 1024.0
    return float("nan")


def _worker(method: str, inp: str, out: str, orient: str) -> None:
    pts = np.load(inp)
    base = _rss_mb()
    if method.startswith("patchcloud"):
        from patchcloud.core import estimate_normals

        crit = method.split("-")[1]
        # warm the compiled kernels on a strided sample of the same cloud, so every path it takes (moment
        # normals, k-NN fallback) is loaded from numba's cache before the timing, as Open3D's code is loaded
        estimate_normals(pts[:: max(1, len(pts) // 20000)], criterion=crit)
        t = time.perf_counter()
        res = estimate_normals(pts, criterion=crit, orient=orient)
        dt = time.perf_counter() - t
        n = res.normals
        steps = {k: round(v, 3) for k, v in res.timings.items()}
        steps["knn_share"] = round(float(np.mean(res.method == 3)), 3)
    elif method == "knn-pca":
        from scipy.spatial import cKDTree

        t = time.perf_counter()
        tree = cKDTree(pts)
        n = np.empty_like(pts)
        for lo in range(0, len(pts), 200_000):
            _, nb = tree.query(pts[lo : lo + 200_000], k=30, workers=-1)
            q = pts[nb]
            q -= q.mean(axis=1)[:, None, :]
            _, v = np.linalg.eigh(np.einsum("mki,mkj->mij", q, q))
            n[lo : lo + 200_000] = v[:, :, 0]
        dt = time.perf_counter() - t
    elif method in ("open3d", "open3d-knn16"):
        import open3d as o3d

        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        t = time.perf_counter()
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(30 if method == "open3d" else 16))
        dt = time.perf_counter() - t
        n = np.asarray(pc.normals)
    else:
        raise SystemExit(f"unknown method {method}")
    np.save(out, n.astype(np.float32))
    info = {"seconds": dt, "peak_mb": _rss_mb(), "base_mb": base}
    if method.startswith("patchcloud"):
        info["steps"] = steps
    print(json.dumps(info))


def _write_ply(path: Path, pts: np.ndarray) -> None:
    header = f"ply\nformat binary_little_endian 1.0\nelement vertex {len(pts)}\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    with open(path, "wb") as f:
        f.write(header.encode())
        f.write(pts.astype("<f4").tobytes())


def _cloudcompare(model: str, pts: np.ndarray, tmp: Path):
    exe = shutil.which("CloudCompare") or shutil.which("cloudcompare")
    if exe is None:
        return None, "CloudCompare not installed (apt-get install cloudcompare)"
    sys.path.insert(0, str(HERE))
    from plyio import read_ply

    from scipy.spatial import cKDTree

    # a radius holding about 30 neighbours, like the k=30 of the other peers
    sample = pts[:: max(1, len(pts) // 5000)]
    radius = float(np.median(cKDTree(pts).query(sample, k=30, workers=-1)[0][:, -1]))
    inp, out = tmp / "cc_in.ply", tmp / "cc_out.ply"
    _write_ply(inp, pts)
    env = dict(os.environ, QT_QPA_PLATFORM="offscreen")
    base = [exe, "-SILENT", "-AUTO_SAVE", "OFF", "-O", str(inp)]
    save = ["-C_EXPORT_FMT", "PLY", "-PLY_EXPORT_FMT", "BINARY_LE", "-SAVE_CLOUDS", "FILE", str(out)]

    gnu_time = shutil.which("time") or ("/usr/bin/time" if Path("/usr/bin/time").exists() else None)
    mem_file = tmp / "cc_mem.txt"

    def run(args):
        if gnu_time:  # GNU time reports the peak RSS of CloudCompare itself
            args = [gnu_time, "-f", "%M", "-o", str(mem_file)] + args
        t = time.perf_counter()
        r = subprocess.run(args, env=env, capture_output=True, text=True, timeout=3600)
        dt = time.perf_counter() - t
        peak = float(mem_file.read_text().split()[-1]) / 1024.0 if gnu_time and mem_file.exists() else float("nan")
        return r, dt, peak

    # best of two runs each: the difference of two process times is otherwise noisy
    t_io = min(run(base + save)[1] for _ in range(2))
    runs = [run(base + ["-OCTREE_NORMALS", f"{radius:.6g}", "-MODEL", model] + save) for _ in range(2)]
    r, t_all, peak = min(runs, key=lambda x: x[1])
    if r.returncode != 0 or not out.exists():
        return None, f"CloudCompare failed: {r.stderr[-300:] or r.stdout[-300:]}"
    v, _ = read_ply(out)
    if "nx" not in v:
        return None, "CloudCompare wrote no normals"
    n = np.column_stack([v["nx"], v["ny"], v["nz"]])
    # the difference of two process times is noisy for small clouds: never below 1 ms
    return {"seconds": max(t_all - t_io, 1e-3), "peak_mb": peak, "normals": n}, None


def _run_method(method: str, pts: np.ndarray, tmp: Path, orient: str):
    if method.startswith("cc-"):
        return _cloudcompare("LS" if method == "cc-ls" else "QUADRIC", pts, tmp)
    if method == "pcl-knn16":
        sys.path.insert(0, str(HERE))
        from pcl_peer import run_pcl

        local = pts - pts.min(axis=0)
        viewpoint = (*(0.5 * local.max(axis=0)[:2]), float(local[:, 2].max()) + 1000.0)
        try:
            seconds, normals = run_pcl(local, "knn", (16,), viewpoint, os.cpu_count() or 1)
        except RuntimeError as e:
            return None, str(e)
        return {"seconds": seconds, "peak_mb": float("nan"), "normals": np.nan_to_num(normals)}, None
    if method in ("open3d", "open3d-knn16"):
        try:
            import open3d  # noqa: F401
        except (ImportError, OSError):
            return None, "open3d not importable (pip install '.[bench]'; it needs Debian's libusb-1.0-0)"
    inp, out = tmp / "pts.npy", tmp / "normals.npy"
    np.save(inp, pts)
    r = subprocess.run(
        [sys.executable, __file__, "--worker", method, str(inp), str(out), orient], capture_output=True, text=True
    )
    if r.returncode != 0:
        return None, f"failed: {r.stderr.strip().splitlines()[-1] if r.stderr.strip() else r.returncode}"
    info = json.loads(r.stdout.strip().splitlines()[-1])
    info["normals"] = np.load(out).astype(np.float64)
    return info, None


# ----------------------------------------------------------------------------- data
def _morton_order(pts: np.ndarray) -> np.ndarray:
    from patchcloud.core.morton import encode, quantize

    lo = pts.min(axis=0)
    edge = float((pts.max(axis=0) - lo).max()) * 1.000001 + 1e-12
    return np.argsort(encode(quantize(pts - lo, edge)), kind="stable")


def _smooth_mask(pts: np.ndarray, ref: np.ndarray) -> np.ndarray:
    from scipy.spatial import cKDTree

    _, nb = cKDTree(pts).query(pts, k=10, workers=-1)
    cos = np.abs(np.einsum("nkj,nj->nk", ref[nb], ref))
    return cos.min(axis=1) > np.cos(np.radians(5.0))


def datasets(sizes, real: bool):
    sys.path.insert(0, str(HERE))
    import synthetic
    from plyio import MESHES, mesh_points

    for n in sizes:
        p, nn = synthetic.scene(n, seed=0)
        yield f"synthetic-scene-{n // 1000}k", p, nn, "up"
    for name, rel in MESHES:
        path = SHARED / rel
        if not path.exists():
            print(f"# skipping mesh {name}: {path} not found")
            continue
        xyz, ref = mesh_points(path)
        yield f"mesh-{name}", xyz, ref, "outward"
    if real:
        import laspy

        for rel in [
            "lidar-lastools/house.laz",
            "lidar-ign-lidarhd-tiles/test_data_77050_627755_LA93_IGN69.laz",
            "lidar-ign-stbarth/St_Barth_RGAF09_UTM20N_IGN_1988_SB_subset_100m.laz",
            "tls-lone-star/lone-star.laz",
            "lidar-ign-extrabytes/las_with_several_extra_byte_bloc.laz",
        ]:
            path = SHARED / rel
            if not path.exists():
                print(f"# skipping {rel}: not found")
                continue
            las = laspy.read(path)
            xyz = np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)])
            yield f"las-{path.stem[:24]}", xyz - xyz.min(axis=0), None, "up"


# ----------------------------------------------------------------------------- main
def _angles(a, b):
    cos = np.abs(np.einsum("ij,ij->i", a, b)) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    return np.degrees(np.arccos(np.clip(cos, 0, 1)))


def _apply_rule(n, pts, orient):
    if orient == "up":
        s = n[:, 2]
    else:
        s = np.einsum("ij,ij->i", n, pts - pts.mean(axis=0))
    return n * np.where(s < 0, -1.0, 1.0)[:, None]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="*", default=[1_000_000, 4_000_000])
    ap.add_argument("--real", action="store_true", help="also the LAS/LAZ files of ../shared/data")
    ap.add_argument("--orders", nargs="*", default=["shuffled", "morton"], choices=["shuffled", "morton"])
    ap.add_argument("--methods", nargs="*", default=METHODS, choices=METHODS)
    ap.add_argument("--worker", nargs=4, metavar=("METHOD", "IN", "OUT", "ORIENT"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.worker:
        _worker(*a.worker)
        return
    print(f"# {os.cpu_count()} cores; times are wall seconds of the estimation alone")
    hdr = f"{'data':28s} {'order':8s} {'method':18s} {'points':>9s} {'seconds':>8s} {'pts/s':>10s} {'peakMB':>7s} {'med°':>6s} {'p90°':>6s} {'smooth°':>7s} {'wrong':>6s} {'speedup':>7s}"
    print(hdr)
    tmp = Path(tempfile.mkdtemp(prefix="pcbench"))
    try:
        for name, pts, ref, orient in datasets(a.sizes, a.real):
            rng = np.random.default_rng(0)
            for order in a.orders:
                perm = rng.permutation(len(pts)) if order == "shuffled" else _morton_order(pts)
                p = np.ascontiguousarray(pts[perm])
                r = None if ref is None else ref[perm]
                smooth = None if r is None else _smooth_mask(p, r)
                rows = {}
                for m in a.methods:
                    info, why = _run_method(m, p, tmp, orient)
                    if info is None:
                        print(f"# {name} {order} {m}: skipped: {why}")
                        continue
                    n = info["normals"]
                    if not m.startswith("patchcloud"):
                        n = _apply_rule(n, p, orient)
                    rows[m] = (info, n)
                peers = [rows[m][0]["seconds"] for m in rows if not m.startswith("patchcloud") and m != "knn-pca"]
                fastest_peer = min(peers) if peers else None
                knn_n = rows["knn-pca"][1] if "knn-pca" in rows else None
                for m, (info, n) in rows.items():
                    truth = r if r is not None else knn_n
                    if truth is not None:
                        ang = _angles(n, truth)
                        med, p90 = np.median(ang), np.percentile(ang, 90)
                        sm = np.median(ang[smooth]) if smooth is not None else float("nan")
                        wrong = np.mean(np.einsum("ij,ij->i", n, truth) < 0) if r is not None else float("nan")
                    else:
                        med = p90 = sm = wrong = float("nan")
                    sp = fastest_peer / info["seconds"] if fastest_peer else float("nan")
                    print(
                        f"{name:28s} {order:8s} {m:18s} {len(p):9d} {info['seconds']:8.2f} {len(p) / info['seconds']:10.0f} "
                        f"{info['peak_mb']:7.0f} {med:6.2f} {p90:6.2f} {sm:7.2f} {wrong:6.3f} {sp:7.2f}",
                        flush=True,
                    )
                for m, (info, n) in rows.items():
                    if "steps" in info:
                        print(f"#   {name} {order} {m} steps (s): {info['steps']}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print("# speedup = fastest peer's seconds (open3d, open3d-knn16, pcl-knn16, cc-*) / this method's seconds, same data and order")
    print("# angle columns for LAS files (no reference) are differences from knn-pca")


if __name__ == "__main__":
    main()
