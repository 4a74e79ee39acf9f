"""Compression benchmark: patchcloud's ``.pcz`` against LAS, LAZ (lazrs) and Draco, rate and distortion.

    python tools/bench_compress.py [--max-error 0.01 0.02 0.05 0.1] [--real [NAME ...]] [--city-points 1000000]
                                   [--city-truth] [--files LAS ...] [--no-draco] [--out FILE] [--plot FILE.png]

Inputs: the real LAS/LAZ files of ../shared/data (a missing one is skipped
with the reason printed), the synthetic city of tools/city_las.py
(``--city-points``, 0 for none; LAS point format 6, its ground-truth extra
dimensions ObjectId and TrueNormalX/Y/Z dropped, as no real scan has them:
16 bytes a point that would inflate LAS and LAZ; ``--city-truth`` keeps
them) and any ``--files``.

For every input and every ``--max-error`` budget (metres):

- ``patchcloud.stream.compress`` to a ``.pcz`` (its bytes, bits per point),
  then ``patchcloud.stream.decompress`` to LAS (the patches sampled at
  their own point counts, the default); both in this process after a
  warm-up call (numba compilation not timed), wall time -> points/s;
- the decompressed points against the original ones, float64 coordinates
  minus the original minimum, scipy cKDTree: **point-to-point** distances
  (D1) original -> nearest reconstructed and reconstructed -> nearest
  original (mean, 95th percentile, max), and **point-to-plane** distances
  (D2: the same nearest-neighbour offsets projected on the original point's
  normal, estimated once by ``patchcloud.core.estimate_normals`` with its
  defaults; mean).  The symmetric mean is the larger of the two directions'
  means (as MPEG's point-cloud metrics);
- D1 of the modelled points only (original points that did not come back
  as residual points; found by their LAS integer coordinates);
- normal agreement: ``estimate_normals`` (defaults) on the reconstructed
  cloud too; the median angle (degrees, sign-insensitive) between each
  original point's normal and its nearest reconstructed point's normal;
- a check of the residual points: share whose record is byte for byte
  the record of an original point;
- a geometry-only estimate of the ``.pcz``: its bytes without the residual
  records, plus a LAZ of the residual points' XYZ alone (point format 0),
  to compare with Draco and LAZ-xyz, which store coordinates only.

Baselines, from the same points in the same run:

- LAS: the cloud written by laspy, uncompressed, all dimensions;
- LAZ: the same with lazrs (all dimensions);
- LAZ-xyz: point format 0 with only X, Y, Z set (same scale and offset,
  other fields zero), with lazrs: the geometry alone, lossless at the LAS
  resolution;
- Draco (DracoPy, optional extra ``bench``; ``--no-draco`` to skip):
  xyz only (local float64 -> float32), kd-tree point-cloud coder
  (compression level 7, order not preserved), at every quantisation from
  a 1 m to a 1 mm step for the rate-distortion curve, and at the bits of
  each budget (the fewest with ``extent / 2**bits <= 2 * max_error``) for
  the table; the same error measures as for ``.pcz``.  "x Draco @ D1" and
  "x Draco @ D2" compare with Draco's curve interpolated (log-log) at the
  ``.pcz`` symmetric mean error; "-" when that error is outside the curve.

Speed: the same points written to a LAZ file and read back with lazrs'
parallel codec (median of 3), in this process; the last table sets
compress and decompress times, both modes, against them (goals: compress
within 3x the LAZ write, decompress within 2x the LAZ read).

Ratios are "other bytes / .pcz bytes": above 1, the ``.pcz`` is smaller.
Draco and LAZ-xyz store only coordinates; a ``.pcz`` also keeps every
attribute of its residual points (byte for byte) and a class and an
intensity per patch, and LAS/LAZ all attributes of every point.
"""

from __future__ import annotations

import argparse
import datetime
import io
import math
import os
import platform
import shutil
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "data"
#: Real inputs: name -> path under ../shared/data.
REAL = {
    "ign-stbarth": "lidar-ign-stbarth/St_Barth_RGAF09_UTM20N_IGN_1988_SB_subset_100m.laz",
    "lastools-house": "lidar-lastools/house.laz",
    "lastools-fusa": "lidar-lastools/fusa.laz",
    "ign-extrabytes": "lidar-ign-extrabytes/las_with_several_extra_byte_bloc.laz",
    "ign-lidarhd-77055": "lidar-ign-lidarhd-tiles/test_data_77055_627760_LA93_IGN69.laz",
    "tls-lone-star": "tls-lone-star/lone-star.laz",
}
BUDGETS = (0.01, 0.02, 0.05, 0.1)
#: Draco's rate-distortion sweep: quantisation steps from COARSEST to FINEST metres.
DRACO_COARSEST, DRACO_FINEST = 1.0, 0.001
DRACO_LEVEL = 7
#: The error range that matters for city models (metres).
CITY_RANGE = (0.01, 0.05)


# ----------------------------------------------------------------------------- measures
def _stats(d: np.ndarray) -> dict:
    return {"mean": float(d.mean()), "p95": float(np.percentile(d, 95)), "max": float(d.max())} if d.size else \
        {"mean": float("nan"), "p95": float("nan"), "max": float("nan")}


def compare(A: np.ndarray, nA: np.ndarray, treeA, B: np.ndarray) -> dict:
    """Distances between the original cloud ``A`` (normals ``nA``, tree ``treeA``) and a reconstruction ``B``.

    D1 point-to-point both ways (mean, p95, max), D2 point-to-plane both
    ways (mean; offsets projected on the original normal), the symmetric
    means (larger direction), and the index of each original point's
    nearest reconstructed point.
    """
    from scipy.spatial import cKDTree

    treeB = cKDTree(B)
    dab, iab = treeB.query(A, workers=-1)  # original -> reconstructed
    dba, iba = treeA.query(B, workers=-1)  # reconstructed -> original
    pab = np.abs(np.einsum("ij,ij->i", A - B[iab], nA))
    pba = np.abs(np.einsum("ij,ij->i", B - A[iba], nA[iba]))
    o2r, r2o = _stats(dab), _stats(dba)
    return {
        "o2r": o2r, "r2o": r2o, "o2r_plane": float(pab.mean()), "r2o_plane": float(pba.mean()),
        "d1": max(o2r["mean"], r2o["mean"]), "d2": max(float(pab.mean()), float(pba.mean())),
        "nearest": iab, "o2r_d": dab,
    }


def normal_angle(nA: np.ndarray, B: np.ndarray, nearest: np.ndarray) -> float:
    """Median angle (degrees, sign-insensitive) between original normals and their nearest reconstructed point's."""
    from patchcloud.core import estimate_normals

    nB = estimate_normals(B).normals.astype(np.float64)
    cos = np.abs(np.einsum("ij,ij->i", nA, nB[nearest]))
    ok = np.isfinite(cos)
    return float(np.degrees(np.arccos(np.clip(np.median(cos[ok]), 0.0, 1.0)))) if ok.any() else float("nan")


def _keys(*ints: np.ndarray) -> list[np.ndarray]:
    """One int64 key per row of each (n, 3) integer array, equal keys for equal rows (mixed radix over all)."""
    lo = np.min([a.min(axis=0) for a in ints if len(a)], axis=0)
    hi = np.max([a.max(axis=0) for a in ints if len(a)], axis=0)
    span = (hi - lo + 1).astype(np.int64)
    if float(span[0]) * float(span[1]) * float(span[2]) >= 2.0**62:
        raise OverflowError("coordinate ranges too wide for one int64 key")
    return [((a[:, 0] - lo[0]) * span[1] + (a[:, 1] - lo[1])) * span[2] + (a[:, 2] - lo[2]) for a in
            (x.astype(np.int64) for x in ints)]


def coded_records(las, budget: float, dropped, shifts) -> tuple[np.ndarray, np.ndarray]:
    """What a model-mode .pcz gives back of each original point were it residual: its coded X, Y, Z (N, 3) and, per
    intensity shift in ``shifts`` (the tiles'), its record (N, L) bytes, stacked (``patchcloud.stream.io.residual_points``:
    position within the budget, class, intensity on 64 levels, return 1 of 1, every other byte zero)."""
    from patchcloud.stream.io.point_coding import coarse_steps
    from patchcloud.stream.io.residual_points import decoded_records

    k = coarse_steps(budget, las.header.scales)
    recs = [decoded_records(las.points.array, las.point_format, k, dropped, int(sh)) for sh in sorted(set(shifts))]
    xyz = recs[0][:, :12].copy().view("<i4").reshape(-1, 3).astype(np.int64)
    return xyz, np.concatenate(recs)


def residual_check(orig, recon, budget: float, pcz_path, dropped) -> tuple[np.ndarray, float]:
    """Mask of the original points that came back as residual points; share of residual points whose record is that of
    an original point as a model-mode .pcz codes it (:func:`coded_records`: within the budget, class, intensity on 64
    levels of its tile's, one return).
    """
    from patchcloud.stream.io.pcz import open_pcz

    with open_pcz(pcz_path) as f:
        shifts = f.intensity_shift.tolist()
    res = np.asarray(recon["Reconstructed"]) == 0
    oi, orec = coded_records(orig, budget, dropped, shifts)
    ri = np.column_stack([recon.X, recon.Y, recon.Z])[res]
    if not len(ri):
        return np.zeros(len(oi), bool), float("nan")
    ko, kr = _keys(oi, ri)
    is_res = np.isin(ko, kr)
    L = orig.point_format.size
    rec = np.dtype((np.void, L))
    a = orec.view(rec).ravel()
    b = np.ascontiguousarray(recon.points.array[res].view(np.uint8).reshape(-1, recon.point_format.size)[:, :L]).view(rec).ravel()
    return is_res, float(np.isin(b, a).mean())


def points_mode(path: Path, las, budget: float, tmp: Path, units) -> dict:
    """``compress --keep-points`` at ``budget`` and back: bytes, times, the largest move of a point, attributes exact."""
    import laspy

    from patchcloud.stream import compress, decompress

    pcz, out = tmp / "points.pcz", tmp / "points.las"
    t = time.perf_counter()
    s = compress(path, pcz, max_error=budget, keep_points=True, quiet=True, overwrite=True, units=units)
    tc = time.perf_counter() - t
    t = time.perf_counter()
    decompress(pcz, out, overwrite=True)
    td = time.perf_counter() - t
    b = laspy.read(out)
    d = np.sqrt((np.asarray(las.x) - b.x) ** 2 + (np.asarray(las.y) - b.y) ** 2 + (np.asarray(las.z) - b.z) ** 2)
    same = all(np.asarray(las[n]).tobytes() == np.asarray(b[n]).tobytes()
               for n in las.point_format.dimension_names if n not in ("X", "Y", "Z"))
    pcz.unlink()
    out.unlink()
    return {"bytes": s.output_bytes, "bpp": 8.0 * s.output_bytes / len(las.points), "max_move": float(d.max()),
            "attributes_exact": same and len(b.points) == len(las.points), "compress_s": tc, "decompress_s": td,
            "steps": s.steps}


def _zip_parts(path: Path) -> dict:
    """Bytes of a .pcz by top-level group (residual, patches, the rest)."""
    out = {"residual": 0, "patches": 0, "other": 0}
    with zipfile.ZipFile(path) as z:
        for i in z.infolist():
            top = i.filename.split("/")[0]
            out[top if top in out and "/" in i.filename else "other"] += i.compress_size
    return out


# ----------------------------------------------------------------------------- baselines
def laz_xyz_bytes(X: np.ndarray, Y: np.ndarray, Z: np.ndarray, header) -> int:
    """Bytes of a LAZ (lazrs) of point format 0 with only X, Y, Z set (``header``'s scale and offset)."""
    import laspy

    h = laspy.LasHeader(point_format=0, version="1.2")
    h.scales, h.offsets = header.scales, header.offsets
    xyz = laspy.LasData(h)
    xyz.points = laspy.ScaleAwarePointRecord.zeros(len(X), header=h)
    xyz.X, xyz.Y, xyz.Z = X, Y, Z
    buf = io.BytesIO()
    xyz.write(buf, do_compress=True, laz_backend=laspy.LazBackend.Lazrs)
    return buf.getbuffer().nbytes


def baseline_sizes(las) -> dict:
    """Bytes of the cloud as LAS (all dimensions), LAZ (lazrs, all dimensions) and LAZ of XYZ alone."""
    import laspy

    out = {}
    for key, compress in (("las", False), ("laz", True)):
        buf = io.BytesIO()
        las.write(buf, do_compress=compress, laz_backend=laspy.LazBackend.Lazrs if compress else None)
        out[key] = buf.getbuffer().nbytes
    out["laz_xyz"] = laz_xyz_bytes(las.X, las.Y, las.Z, las.header)
    # LAZ-4: the same points with x, y, z, intensity, returns and classification, every other field zero
    from patchcloud.stream.io.point_coding import keep_only, zero_fields

    four = laspy.LasData(las.header)
    four.points = las.points.copy()
    zero_fields(four.points, keep_only(las.point_format, ("intensity", "return_number", "number_of_returns", "classification")))
    buf = io.BytesIO()
    four.write(buf, do_compress=True, laz_backend=laspy.LazBackend.Lazrs)
    out["laz4"] = buf.getbuffer().nbytes
    return out


def draco_bits_for(extent: float, budget: float) -> int:
    """The fewest quantisation bits with ``extent / 2**bits <= 2 * budget`` (1..30)."""
    return int(min(30, max(1, math.ceil(math.log2(max(extent, 1e-9) / (2.0 * budget))))))


def run_draco(A: np.ndarray, nA: np.ndarray, treeA, bits: int, normals: bool = False) -> dict:
    """Draco point-cloud coding of ``A`` (float32) at ``bits``: bytes, times, the errors of :func:`compare`."""
    import DracoPy

    P = np.ascontiguousarray(A, dtype=np.float32)
    t = time.perf_counter()
    buf = DracoPy.encode(P, quantization_bits=bits, compression_level=DRACO_LEVEL)
    te = time.perf_counter() - t
    t = time.perf_counter()
    B = np.asarray(DracoPy.decode(buf).points, dtype=np.float64).reshape(-1, 3)
    td = time.perf_counter() - t
    err = compare(A, nA, treeA, B)
    r = {"bits": bits, "bytes": len(buf), "bpp": 8.0 * len(buf) / len(A), "points_out": len(B), "encode_s": te,
         "decode_s": td, **{k: v for k, v in err.items() if k not in ("nearest", "o2r_d")}}
    if normals:
        r["normal_deg"] = normal_angle(nA, B, err["nearest"])
    return r


def interp_bpp(curve: list[dict], error: float, key: str) -> float:
    """Draco's bits per point at mean error ``error`` (``key`` "d1" or "d2"), log-log interpolation; NaN outside."""
    pts = sorted((c[key], c["bpp"]) for c in curve if c[key] > 0 and c["bpp"] > 0)
    if len(pts) < 2 or not np.isfinite(error) or error <= 0 or not pts[0][0] <= error <= pts[-1][0]:
        return float("nan")
    e, b = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    keep = np.concatenate([[True], np.diff(e) > 0])  # strictly increasing errors for np.interp
    return float(np.exp(np.interp(np.log(error), e[keep], b[keep])))


# ----------------------------------------------------------------------------- one input
def _warm_up(tmp: Path) -> None:
    """One small compress/decompress so numba compilation (or its cache load) is not timed."""
    import laspy

    from patchcloud.stream import compress, decompress

    rng = np.random.default_rng(0)
    n = 20_000
    h = laspy.LasHeader(point_format=1, version="1.2")
    h.scales, h.offsets = np.array([0.001] * 3), np.zeros(3)
    las = laspy.LasData(h)
    xy = rng.uniform(0, 20, (n, 2))
    las.x, las.y, las.z = xy[:, 0], xy[:, 1], 0.1 * xy[:, 0] + rng.normal(0, 0.002, n)
    las.write(tmp / "warm.las")
    compress(tmp / "warm.las", tmp / "warm.pcz", max_error=0.02, quiet=True, overwrite=True)
    decompress(tmp / "warm.pcz", tmp / "warm_out.las", overwrite=True)
    from patchcloud.core import estimate_normals

    estimate_normals(np.column_stack([las.x, las.y, las.z]))


def laz_times(las, tmp: Path, repeats: int = 3) -> dict:
    """Seconds to write the cloud as a LAZ file (all dimensions) and to read it back, lazrs on every core (the median of
    ``repeats``): the speed baselines of compress and decompress, in this process, as they run."""
    import laspy

    path = tmp / "speed.laz"
    backend = laspy.LazBackend.LazrsParallel
    write, read = [], []
    for _ in range(repeats):
        t = time.perf_counter()
        las.write(path, do_compress=True, laz_backend=backend)
        write.append(time.perf_counter() - t)
        t = time.perf_counter()
        laspy.read(path, laz_backend=backend)
        read.append(time.perf_counter() - t)
    path.unlink()
    return {"write_s": float(np.median(write)), "read_s": float(np.median(read))}


def bench_file(name: str, path: Path, budgets, draco: bool, tmp: Path, log) -> dict:
    """Everything measured on one input; a dict for :func:`file_table` and :func:`plot`."""
    import laspy
    from scipy.spatial import cKDTree

    from patchcloud.core import estimate_normals
    from patchcloud.stream import compress, decompress

    las = laspy.read(path)
    n = len(las.points)
    lo = np.array([las.x.min(), las.y.min(), las.z.min()])
    A = np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)]) - lo
    extent = float((A.max(axis=0)).max())
    cls = np.asarray(las.classification)
    info = {"name": name, "path": str(path), "points": n, "file_bytes": path.stat().st_size,
            "point_format": las.point_format.id, "record_bytes": las.point_format.size,
            "extra_dims": list(las.point_format.extra_dimension_names), "scale": float(las.header.scales[0]),
            "extent": A.max(axis=0).tolist(), "building_share": float(np.mean(cls == 6)), "ground_share": float(np.mean(cls == 2))}
    log(f"# {name}: {n:,} points, baselines ...")
    info["sizes"] = baseline_sizes(las)
    info["laz_speed"] = laz_times(las, tmp)
    t = time.perf_counter()
    nA = estimate_normals(A).normals.astype(np.float64)
    info["normals_s"] = time.perf_counter() - t
    treeA = cKDTree(A)

    info["draco_curve"], info["draco"] = [], {}
    if draco:
        b_lo = draco_bits_for(extent, DRACO_COARSEST / 2)
        b_hi = draco_bits_for(extent, DRACO_FINEST / 2)
        log(f"# {name}: Draco sweep, {b_lo}..{b_hi} bits ...")
        for bits in range(b_lo, b_hi + 1):
            info["draco_curve"].append(run_draco(A, nA, treeA, bits))
        for budget in budgets:
            info["draco"][budget] = run_draco(A, nA, treeA, draco_bits_for(extent, budget), normals=True)

    rows = []
    for budget in budgets:
        log(f"# {name}: compress --max-error {budget:g} ...")
        pcz = tmp / f"{name}-{budget:g}.pcz"
        out = tmp / f"{name}-{budget:g}.las"
        t = time.perf_counter()
        # lone-star's GeoTIFF keys say geocentric WGS 84 (metres; laspy read them as geographic EPSG:4326): --units m as before
        s = compress(path, pcz, max_error=budget, quiet=True, overwrite=True, units="m" if "lone-star" in str(path) else None)
        tc = time.perf_counter() - t
        t = time.perf_counter()
        d = decompress(pcz, out, overwrite=True)
        td = time.perf_counter() - t
        rec = laspy.read(out)
        B = np.column_stack([np.asarray(rec.x), np.asarray(rec.y), np.asarray(rec.z)]) - lo
        err = compare(A, nA, treeA, B)
        is_res, exact = residual_check(las, rec, budget, pcz, s.dropped)
        modelled = ~is_res
        parts = _zip_parts(pcz)
        res = np.asarray(rec["Reconstructed"]) == 0
        # geometry only: the .pcz without its residual records, plus a LAZ of the residual points' XYZ alone
        bytes_xyz = s.output_bytes - parts["residual"] + laz_xyz_bytes(rec.X[res], rec.Y[res], rec.Z[res], las.header)
        row = {
            "budget": budget, "bytes": s.output_bytes, "bpp": 8.0 * s.output_bytes / n, "patches": s.patches,
            "residual": s.residual, "residual_share": s.residual / max(n, 1), "parts": parts,
            "bytes_xyz": bytes_xyz, "bpp_xyz": 8.0 * bytes_xyz / n,
            "points_out": len(B), "sampled": d.reconstructed, "compress_s": tc, "decompress_s": td,
            "fit_error": s.mean_error, "residual_exact": exact,
            "modelled": _stats(err["o2r_d"][modelled]), "modelled_n": int(modelled.sum()),
            "normal_deg": normal_angle(nA, B, err["nearest"]),
            **{k: v for k, v in err.items() if k not in ("nearest", "o2r_d")},
        }
        log(f"# {name}: compress --keep-points --max-error {budget:g} ...")
        row["points_mode"] = points_mode(path, las, budget, tmp, "m" if "lone-star" in str(path) else None)
        if info["draco_curve"]:
            row["draco_d1_bpp"] = interp_bpp(info["draco_curve"], row["d1"], "d1")
            row["draco_d2_bpp"] = interp_bpp(info["draco_curve"], row["d2"], "d2")
        else:
            row["draco_d1_bpp"] = row["draco_d2_bpp"] = float("nan")
        rows.append(row)
        pcz.unlink()
        out.unlink()
    info["rows"] = rows
    return info


# ----------------------------------------------------------------------------- tables
def _x(a: float, b: float) -> str:
    """Ratio a / b as '12.3x', '-' when undefined."""
    return f"{a / b:.2f}x" if b > 0 and np.isfinite(a) and np.isfinite(b) else "-"


def _cm(v: float) -> str:
    return f"{100 * v:.2f}" if np.isfinite(v) else "-"


def _trip(s: dict) -> str:
    return f"{_cm(s['mean'])} / {_cm(s['p95'])} / {_cm(s['max'])}"


def _rate(n: int, s: float) -> str:
    return f"{n / s:,.0f}" if s > 0 else "-"


def file_table(info: dict) -> list[str]:
    """Markdown lines of one input: header notes, the .pcz table, the Draco rows."""
    n, sz = info["points"], info["sizes"]
    ext = info["extent"]
    out = [f"### {info['name']}", "",
           f"- {info['path']}: {n:,} points, point format {info['point_format']} ({info['record_bytes']} bytes/record"
           + (f"; extra dims {', '.join(info['extra_dims'])}" if info["extra_dims"] else "") + f"), scale {info['scale']:g} m, "
           f"extent {ext[0]:.0f} x {ext[1]:.0f} x {ext[2]:.0f} m; class 6 (building) {info['building_share']:.0%}, "
           f"class 2 (ground) {info['ground_share']:.0%}; file {info['file_bytes']:,} bytes",
           f"- baselines: LAS {sz['las']:,} B ({8 * sz['las'] / n:.1f} bits/pt), LAZ {sz['laz']:,} B ({8 * sz['laz'] / n:.2f} bits/pt), "
           f"LAZ-xyz {sz['laz_xyz']:,} B ({8 * sz['laz_xyz'] / n:.2f} bits/pt), LAZ-4 (xyz, intensity, returns, class) "
           f"{sz['laz4']:,} B ({8 * sz['laz4'] / n:.2f} bits/pt)", ""]
    out += ["| max-error m | .pcz bits/pt | x LAS | x LAZ | x LAZ-4 | x LAZ-xyz | x Draco @ budget bits | x Draco @ D1 | x Draco @ D2 "
            "| geometry-only .pcz bits/pt | its x LAZ-xyz | its x Draco @ D2 "
            "| D1 o->r cm mean/p95/max | D1 r->o cm mean/p95/max | D2 o->r / r->o cm | D1 modelled o->r cm mean/p95 "
            "| normal median deg | compress pts/s | decompress pts/s | patches | residual pts | residual bytes |",
            "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in info["rows"]:
        dr = info["draco"].get(r["budget"])
        parts = r["parts"]
        out.append(
            f"| {r['budget']:g} | {r['bpp']:.2f} | {_x(sz['las'], r['bytes'])} | {_x(sz['laz'], r['bytes'])} | "
            f"{_x(sz['laz4'], r['bytes'])} | "
            f"{_x(sz['laz_xyz'], r['bytes'])} | {_x(dr['bytes'], r['bytes']) if dr else '-'} | "
            f"{_x(r['draco_d1_bpp'], r['bpp'])} | {_x(r['draco_d2_bpp'], r['bpp'])} | "
            f"{r['bpp_xyz']:.2f} | {_x(sz['laz_xyz'], r['bytes_xyz'])} | {_x(r['draco_d2_bpp'], r['bpp_xyz'])} | "
            f"{_trip(r['o2r'])} | {_trip(r['r2o'])} | {_cm(r['o2r_plane'])} / {_cm(r['r2o_plane'])} | "
            f"{_cm(r['modelled']['mean'])} / {_cm(r['modelled']['p95'])} | {r['normal_deg']:.1f} | "
            f"{_rate(n, r['compress_s'])} | {_rate(n, r['decompress_s'])} | {r['patches']:,} | {r['residual_share']:.1%} | "
            f"{parts['residual'] / max(r['bytes'], 1):.0%} |")
    if info["draco"]:
        out += ["", "Draco (xyz only) at each budget's quantisation and along its curve:", "",
                "| for max-error m | bits | step cm | Draco bits/pt | D1 o->r cm mean/p95/max | D1 r->o cm mean/p95/max "
                "| D2 o->r / r->o cm | normal median deg | encode pts/s | decode pts/s |",
                "|---:|---:|---:|---:|---|---|---|---:|---:|---:|"]
        ext_max = max(ext)
        for b, d in info["draco"].items():
            out.append(f"| {b:g} | {d['bits']} | {_cm(ext_max / (2**d['bits'] - 1))} | {d['bpp']:.2f} | {_trip(d['o2r'])} | "
                       f"{_trip(d['r2o'])} | {_cm(d['o2r_plane'])} / {_cm(d['r2o_plane'])} | {d['normal_deg']:.1f} | "
                       f"{_rate(n, d['encode_s'])} | {_rate(n, d['decode_s'])} |")
        out += ["", "Draco curve (bits: bits/pt @ symmetric D1 mean cm, D2 mean cm): " + "; ".join(
            f"{d['bits']}: {d['bpp']:.2f} @ {_cm(d['d1'])}, {_cm(d['d2'])}" for d in info["draco_curve"])]
    out += ["", "Points mode (`--keep-points`: every point in input order, attributes exact):", "",
            "| max-error m | steps | bits/pt | x input file | x LAZ | largest move cm | attributes exact | compress pts/s "
            "| decompress pts/s |", "|---:|---|---:|---:|---:|---:|---|---:|---:|"]
    for r in info["rows"]:
        p = r["points_mode"]
        out.append(f"| {r['budget']:g} | {'x'.join(map(str, p['steps']))} | {p['bpp']:.2f} | {_x(info['file_bytes'], p['bytes'])} | "
                   f"{_x(sz['laz'], p['bytes'])} | {_cm(p['max_move'])} | {'yes' if p['attributes_exact'] else 'NO'} | "
                   f"{_rate(n, p['compress_s'])} | {_rate(n, p['decompress_s'])} |")
    checks = [f"{r['budget']:g}: {r['residual_exact']:.2%}" for r in info["rows"]]
    fits = [f"{r['budget']:g}: {_cm(r['fit_error'])}" for r in info["rows"]]
    outs = [f"{r['budget']:g}: {r['points_out']:,}" for r in info["rows"]]
    out += ["", f"- residual points whose record is an original record as model mode codes it (position within the budget; "
            f"class; intensity on 64 levels; return 1 of 1; the rest zero): {', '.join(checks)}",
            f"- compress's own mean distance of the modelled points to their surface (before quantisation), cm: {', '.join(fits)}",
            f"- points decompressed: {', '.join(outs)} (original {n:,})", ""]
    return out


def goals_table(infos: list[dict]) -> list[str]:
    """Markdown lines: per input and budget, how the goals fare.

    (a) mean error within the budget and at least 10x smaller than LAZ;
    (b) smaller than Draco at the same mean error, in the 1-5 cm range.
    """
    lo, hi = CITY_RANGE
    out = ["### Goals per input", "",
           "- (a): symmetric mean error <= --max-error (D1 point-to-point, D2 point-to-plane) and .pcz >= 10x smaller than LAZ;",
           f"- (b): .pcz smaller than Draco at the same symmetric mean error, where that error is in {100 * lo:g}-{100 * hi:g} cm "
           "(x Draco > 1); 'geometry-only' is the .pcz with its residual points' records replaced by a LAZ of their XYZ alone "
           "(an estimate of a .pcz as bare as Draco's xyz); '-': the error is outside 1-5 cm or Draco's curve.", "",
           "| input | max-error m | D1 mean cm | D2 mean cm | x LAZ | (a) with D1 | (a) with D2 | x Draco @ D1 | x Draco @ D2 "
           "| geometry-only x Draco @ D2 | (b) with D2 |",
           "|---|---:|---:|---:|---:|---|---|---:|---:|---:|---|"]
    for info in infos:
        laz = info["sizes"]["laz"]
        for r in info["rows"]:
            ratio = laz / r["bytes"]
            a1 = "yes" if r["d1"] <= r["budget"] and ratio >= 10 else "no"
            a2 = "yes" if r["d2"] <= r["budget"] and ratio >= 10 else "no"
            in1, in2 = lo <= r["d1"] <= hi, lo <= r["d2"] <= hi
            d1x = _x(r["draco_d1_bpp"], r["bpp"]) if in1 else "-"
            d2x = _x(r["draco_d2_bpp"], r["bpp"]) if in2 else "-"
            g2x = _x(r["draco_d2_bpp"], r["bpp_xyz"]) if in2 else "-"
            if not info["draco_curve"]:
                b = "Draco skipped"
            elif not in2 or not np.isfinite(r["draco_d2_bpp"]):
                b = "-"
            else:
                b = ("yes" if r["draco_d2_bpp"] > r["bpp"] else "no") + (
                    ", geometry-only yes" if r["draco_d2_bpp"] > r["bpp_xyz"] else ", geometry-only no")
            out.append(f"| {info['name']} | {r['budget']:g} | {_cm(r['d1'])} | {_cm(r['d2'])} | {ratio:.2f}x | {a1} | {a2} | "
                       f"{d1x} | {d2x} | {g2x} | {b} |")
    return out + [""]


def speed_goals_table(infos: list[dict]) -> list[str]:
    """Markdown lines: compress and decompress times against writing and reading the same points as LAZ, both modes.

    Goals (issue 19): compress within 3x the time of writing the same
    points as LAZ with lazrs, decompress within 2x the time of reading them,
    same machine, same threads, same run.
    """
    out = ["### Speed against LAZ", "",
           f"- LAZ: the same points, all dimensions, written to a file and read back with laspy + lazrs' parallel codec "
           f"({os.cpu_count()} threads; median of 3); compress and decompress run in this process with their defaults "
           f"(in memory, numba on {os.cpu_count()} threads): compress from the input file (read, tile, fit, write the .pcz), "
           "decompress from the .pcz to a LAS file;",
           "- goals: compress / LAZ write <= 3, decompress / LAZ read <= 2.", "",
           "| input | max-error m | mode | compress s | LAZ write s | compress / write | decompress s | LAZ read s "
           "| decompress / read | goal |",
           "|---|---:|---|---:|---:|---:|---:|---:|---:|---|"]
    for info in infos:
        w, rd = info["laz_speed"]["write_s"], info["laz_speed"]["read_s"]
        for r in info["rows"]:
            for mode, m in (("model", r), ("points", r["points_mode"])):
                c, d = m["compress_s"] / w, m["decompress_s"] / rd
                out.append(f"| {info['name']} | {r['budget']:g} | {mode} | {m['compress_s']:.2f} | {w:.2f} | {c:.1f}x | "
                           f"{m['decompress_s']:.2f} | {rd:.2f} | {d:.1f}x | {'yes' if c <= 3 and d <= 2 else 'no'} |")
    return out + [""]


def modes_goals_table(infos: list[dict]) -> list[str]:
    """Markdown lines: the goals of the two modes per input and budget.

    Model mode at 5 cm: >= 4x smaller than LAZ-4 of the same points, the
    symmetric mean point-to-point error <= 5 cm, every point back (count).
    Points mode: never larger than the input file at any budget >= 1 cm; >= 1.5x smaller than LAZ of the same
    points (all dimensions) at 5 cm; every point within the budget (largest move) and every attribute exact.
    """
    out = ["### Goals of the two modes", "",
           "- model mode at 5 cm: x LAZ-4 >= 4, D1 symmetric mean <= 5 cm, the same point count;",
           "- points mode: x input file >= 1 at every budget >= 1 cm, x LAZ >= 1.5 at 5 cm; largest move <= budget, attributes exact.", "",
           "| input | max-error m | model x LAZ-4 | model D1 mean cm | model points out / in | model goal | points x file | "
           "points x LAZ | largest move cm | points goal |",
           "|---|---:|---:|---:|---:|---|---:|---:|---:|---|"]
    for info in infos:
        sz, n = info["sizes"], info["points"]
        for r in info["rows"]:
            p = r["points_mode"]
            five = abs(r["budget"] - 0.05) < 1e-9
            x4 = sz["laz4"] / r["bytes"]
            mg = ("yes" if x4 >= 4 and r["d1"] <= 0.05 and r["points_out"] == n else "no") if five else "-"
            xf, xl = info["file_bytes"] / p["bytes"], sz["laz"] / p["bytes"]
            ok = xf >= 1 and p["max_move"] <= r["budget"] + 1e-9 and p["attributes_exact"] and (xl >= 1.5 or not five)
            out.append(f"| {info['name']} | {r['budget']:g} | {x4:.2f}x | {_cm(r['d1'])} | {r['points_out']:,} / {n:,} | {mg} | "
                       f"{xf:.2f}x | {xl:.2f}x | {_cm(p['max_move'])} | {'yes' if ok else 'no'} |")
    return out + [""]


# ----------------------------------------------------------------------------- figure
def plot(infos: list[dict], path: Path) -> Path:
    """Rate-distortion curves (bits/pt against symmetric mean error, log-log), one panel per input."""
    from matplotlib.lines import Line2D

    from patchcloud.stream.views.plots import STYLE, new_figure, save_png, style_axes

    cols = min(4, len(infos) + 1)
    rows = math.ceil((len(infos) + 1) / cols)
    fig, first = new_figure(3.4 * cols, 3.0 * rows + 0.4, 1)
    fig.delaxes(first[0])  # new_figure gives one row; the panels go on a grid
    axes = list(fig.subplots(rows, cols, squeeze=False).ravel())
    pcz_c, draco_c = "C0", "C3"
    for ax, info in zip(axes, infos):
        n, sz = info["points"], info["sizes"]
        ax.axvspan(100 * CITY_RANGE[0], 100 * CITY_RANGE[1], color="0.92", zorder=0)
        for key, style, fill in (("d1", "-", pcz_c), ("d2", "--", "white")):
            xs = [100 * r[key] for r in info["rows"]]
            ys = [r["bpp"] for r in info["rows"]]
            ax.plot(xs, ys, style, color=pcz_c, marker="o", ms=4, mfc=fill, lw=1.2)
        if all("bpp_xyz" in r for r in info["rows"]):
            ax.plot([100 * r["d2"] for r in info["rows"]], [r["bpp_xyz"] for r in info["rows"]], ":", color=pcz_c,
                    marker="^", ms=3.5, mfc="white", lw=1.2)
        for r in info["rows"]:
            ax.annotate(f"{100 * r['budget']:g}", (100 * r["d2"], r["bpp"]), textcoords="offset points", xytext=(-3, 4),
                        ha="right", fontsize=STYLE["annotation"] - 1, color=pcz_c)
        if info["draco_curve"]:
            cur = info["draco_curve"]
            for key, style, fill in (("d1", "-", draco_c), ("d2", "--", "white")):
                ax.plot([100 * d[key] for d in cur], [d["bpp"] for d in cur], style, color=draco_c, marker="s", ms=3,
                        mfc=fill, lw=1.0)
        for key, style in (("laz", "-"), ("laz_xyz", ":"), ("las", "-.")):
            ax.axhline(8 * sz[key] / n, color="0.35", ls=style, lw=0.9)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlim(0.003, 200)
        ax.grid(True, which="major", color="0.85", lw=0.5)
        style_axes(ax, f"{info['name']} ({n / 1e6:.2f} M pts)", "symmetric mean error (cm)", "bits per point")
    for ax in axes[len(infos):]:
        ax.axis("off")
    handles = [
        Line2D([], [], color=pcz_c, marker="o", ms=4, label=".pcz point-to-point (D1)"),
        Line2D([], [], color=pcz_c, ls="--", marker="o", ms=4, mfc="white", label=".pcz point-to-plane (D2)"),
        Line2D([], [], color=pcz_c, ls=":", marker="^", ms=3.5, mfc="white", label=".pcz geometry-only est., D2"),
        Line2D([], [], color=draco_c, marker="s", ms=3, label="Draco xyz, D1"),
        Line2D([], [], color=draco_c, ls="--", marker="s", ms=3, mfc="white", label="Draco xyz, D2"),
        Line2D([], [], color="0.35", ls="-", label="LAZ (lazrs, all dims)"),
        Line2D([], [], color="0.35", ls=":", label="LAZ xyz only"),
        Line2D([], [], color="0.35", ls="-.", label="LAS"),
        Line2D([], [], color="0.92", lw=6, label="1-5 cm"),
    ]
    axes[len(infos)].legend(handles=handles, loc="center", fontsize=STYLE["annotation"] + 1, frameon=False,
                            title="labels on .pcz points:\n--max-error in cm", title_fontsize=STYLE["annotation"] + 1)
    fig.suptitle("Rate-distortion: patchcloud .pcz against Draco, LAZ and LAS", fontsize=STYLE["suptitle"])
    return save_png(fig, path)


# ----------------------------------------------------------------------------- main
def drop_extra_dims(path: Path) -> None:
    """Rewrite the LAS at ``path`` without its extra-bytes dimensions (same header otherwise, same points)."""
    import laspy

    las = laspy.read(path)
    h = laspy.LasHeader(point_format=las.point_format.id, version=las.header.version)
    h.scales, h.offsets = las.header.scales, las.header.offsets
    h.generating_software = las.header.generating_software
    out = laspy.LasData(h)
    out.points = laspy.ScaleAwarePointRecord.zeros(len(las.points), header=h)
    for name in laspy.PointFormat(las.point_format.id).dimension_names:
        out[name] = las[name]
    out.write(path)


def _inputs(a, tmp: Path, log):
    """(name, path) of every input; a missing one skipped with the reason printed."""
    if a.city_points > 0:
        sys.path.insert(0, str(HERE))
        from city_las import write_city

        p = tmp / "city.las"
        log(f"# writing the synthetic city, {a.city_points:,} points ...")
        write_city(p, a.city_points, seed=0)
        if not a.city_truth:
            drop_extra_dims(p)
        label = f"{a.city_points // 1_000_000}M" if a.city_points % 1_000_000 == 0 else f"{a.city_points // 1000}k"
        yield f"city-{label}", p
    for name in a.real:
        p = SHARED / REAL[name]
        if not p.exists():
            print(f"# skipping {name}: {p} not found", flush=True)
            continue
        yield name, p
    for f in a.files:
        if not Path(f).exists():
            print(f"# skipping {f}: not found", flush=True)
            continue
        yield Path(f).stem, Path(f)


def main(argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--max-error", type=float, nargs="+", default=list(BUDGETS), metavar="M", help="budgets (metres)")
    ap.add_argument("--real", nargs="*", default=list(REAL), choices=list(REAL), metavar="NAME",
                    help=f"real inputs (default all: {', '.join(REAL)}; none if given empty)")
    ap.add_argument("--city-points", type=int, default=1_000_000, help="points of the synthetic city (0: none)")
    ap.add_argument("--city-truth", action="store_true",
                    help="keep the city's ground-truth extra dimensions (ObjectId, TrueNormalX/Y/Z: 16 bytes a point)")
    ap.add_argument("--files", nargs="*", default=[], metavar="LAS", help="other LAS/LAZ inputs")
    ap.add_argument("--no-draco", action="store_true", help="skip the Draco baseline")
    ap.add_argument("--out", type=Path, help="also write the tables to this file")
    ap.add_argument("--plot", type=Path, help="write the rate-distortion figure to this PNG")
    a = ap.parse_args(argv)

    text: list[str] = []

    def emit(lines: list[str]) -> None:
        text.extend(lines)
        print("\n".join(lines), flush=True)

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    from importlib.metadata import PackageNotFoundError, version

    def _version(dist: str) -> str:
        try:
            return version(dist)
        except PackageNotFoundError:
            return "?"

    draco = not a.no_draco
    draco_note = "Draco: --no-draco"
    if draco:
        try:
            import DracoPy  # noqa: F401

            draco_note = f"DracoPy {_version('DracoPy')}"
        except ImportError as e:
            draco, draco_note = False, f"Draco skipped: DracoPy not importable ({e}); pip install DracoPy (extra 'bench')"
            print(f"# {draco_note}", flush=True)
    import laspy

    started = time.perf_counter()
    budgets = sorted(set(a.max_error))
    try:
        import subprocess

        git = lambda *c: subprocess.run(["git", *c], cwd=HERE, capture_output=True, text=True, timeout=10).stdout.strip()
        dirty = git("status", "--porcelain", "--", "stream", "core")
        commit = git("rev-parse", "--short", "HEAD") + (" (stream/ or core/ modified)" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        commit = "?"
    emit([f"# tools/bench_compress.py, {datetime.date.today()}: {' '.join(['python', 'tools/bench_compress.py'] + (sys.argv[1:] if argv is None else list(argv)))}",
          f"# {os.cpu_count()} cores ({platform.processor() or platform.machine()}), load average at start "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}; the machine is shared with other work, so timings are noisy.",
          f"# patchcloud at commit {commit or '?'}; laspy {laspy.__version__}, lazrs {_version('lazrs')}, {draco_note}; budgets {', '.join(f'{b:g}' for b in budgets)} m.",
          "# Sizes: ratios are other bytes / .pcz bytes (> 1: the .pcz is smaller). Errors in cm, coordinates minus the original "
          "minimum; D1 point-to-point, D2 point-to-plane (original normals); symmetric = larger direction's mean.",
          "# Decompression samples each patch at its own point count (the default): D1 o->r is the distance to a *resampled* "
          "surface and is bounded below by about half the point spacing, whatever the budget; D2 measures the surface.",
          "# Timings: wall, in this process, after a warm-up; compress includes tiling to its temporary store; "
          "decompress writes LAS.", ""])
    tmp = Path(tempfile.mkdtemp(prefix="bench_compress"))
    infos = []
    try:
        _warm_up(tmp)
        for name, path in _inputs(a, tmp, log):
            try:
                info = bench_file(name, path, budgets, draco, tmp, log)
            except Exception as e:  # an unreadable input: say why, go on
                print(f"# skipping {name}: {type(e).__name__}: {e}", flush=True)
                continue
            infos.append(info)
            emit(file_table(info))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if infos:
        emit(goals_table(infos))
        emit(modes_goals_table(infos))
        emit(speed_goals_table(infos))
    emit([f"- total wall time {time.perf_counter() - started:.0f} s; load average at end "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}.", ""])
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text("\n".join(text) + "\n")
    if a.plot and infos:
        plot(infos, a.plot)
    return infos


if __name__ == "__main__":
    main()
