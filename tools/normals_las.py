"""Normals and curvature of one LAS/LAZ file that fits in memory.

    python tools/normals_las.py IN.laz OUT.laz [--criterion rmse|sigma3] [--orient up|viewpoint|outward|none]

Reads every point (laspy with lazrs), runs ``patchcloud.core.estimate_normals``
on its coordinates (float64, relative to the cloud's own corner), and writes
the input back, every original dimension unchanged and in the same order,
with extra-bytes dimensions NormalX, NormalY, NormalZ, Curvature (float32;
PDAL's names; Curvature is the surface variation), PrincipalCurvature1 and 2
(float32, 1/unit), NormalMethod (uint8: 1 quadric, 2 blended, 3 k-NN) and
PatchId (int32).  The output is written to a temporary name and renamed when
complete.  This is the in-memory stand-in for ``patchcloud normals``, which
the stream package will provide for files of any size.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("input", type=Path)
    ap.add_argument("output", type=Path)
    ap.add_argument("--criterion", choices=["rmse", "sigma3"], default="rmse")
    ap.add_argument("--orient", choices=["up", "viewpoint", "outward", "none"], default="up")
    ap.add_argument("--viewpoint", type=float, nargs=3, metavar=("X", "Y", "Z"))
    ap.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    a = ap.parse_args(argv)

    import laspy

    from patchcloud.core import Method, NormalsOptions, PatchKind, estimate_normals

    if a.output.exists() and not a.overwrite:
        print(f"error: {a.output}: exists (use --overwrite to replace it)", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    try:
        las = laspy.read(a.input)
    except FileNotFoundError:
        print(f"error: {a.input}: no such file", file=sys.stderr)
        return 2
    except Exception as exc:  # laspy raises several types for bad files
        print(f"error: {a.input}: not a readable LAS/LAZ file ({exc})", file=sys.stderr)
        return 2
    n = len(las.points)
    if n == 0:
        print(f"error: {a.input}: the file holds no points", file=sys.stderr)
        return 2
    t_read = time.perf_counter() - t0
    xyz = np.column_stack([np.asarray(las.x, dtype=np.float64), np.asarray(las.y), np.asarray(las.z)])
    # load (or, on the first run after installation, compile) the numba kernels, timed apart
    t_k = time.perf_counter()
    estimate_normals(np.random.default_rng(0).normal(size=(2000, 3)))
    t_kernels = time.perf_counter() - t_k
    t1 = time.perf_counter()
    try:
        res = estimate_normals(xyz, NormalsOptions(criterion=a.criterion, orient=a.orient, viewpoint=a.viewpoint))
    except ValueError as exc:
        print(f"error: {a.input}: {exc}", file=sys.stderr)
        return 2
    t_fit = time.perf_counter() - t1

    t2 = time.perf_counter()
    dims = [
        ("NormalX", np.float32, res.normals[:, 0]),
        ("NormalY", np.float32, res.normals[:, 1]),
        ("NormalZ", np.float32, res.normals[:, 2]),
        ("Curvature", np.float32, res.curvature),
        ("PrincipalCurvature1", np.float32, res.k1),
        ("PrincipalCurvature2", np.float32, res.k2),
        ("NormalMethod", np.uint8, res.method),
        ("PatchId", np.int32, res.patch),
    ]
    existing = set(las.point_format.dimension_names)
    las.add_extra_dims([laspy.ExtraBytesParams(name=name, type=dt) for name, dt, _ in dims if name not in existing])
    for name, dt, values in dims:
        las[name] = values.astype(dt)
    tmp = a.output.with_name(a.output.name + ".partial")
    try:
        # through a file object: laspy decides compression from a path's suffix, and ours is .partial
        with open(tmp, "wb") as f:
            las.write(f, do_compress=a.output.suffix.lower() == ".laz")
        os.replace(tmp, a.output)
    finally:
        if tmp.exists():
            tmp.unlink()
    t_write = time.perf_counter() - t2

    t = res.patches
    kinds = np.bincount(t.kind, minlength=3)
    methods = np.bincount(res.method, minlength=len(Method) + 1)
    p = res.parameters
    print(f"{a.input} -> {a.output}")
    print(f"  points            {n:,}")
    print(f"  patches           {len(t):,}  (surface {kinds[PatchKind.SURFACE]:,}, edge {kinds[PatchKind.EDGE]:,}, sparse {kinds[PatchKind.SPARSE]:,})")
    print(
        f"  normals by        quadric {methods[Method.QUADRIC] / n:.1%}, blended {methods[Method.BLENDED] / n:.1%}, "
        f"cell moments {methods[Method.MOMENTS] / n:.1%}, k-NN fallback {methods[Method.KNN] / n:.1%}"
    )
    print(f"  criterion         {p.criterion}, threshold {p.threshold:.4g}, d_min {p.d_min:.3g}, n_min {p.n_min}, spacing {p.spacing:.3g}")
    print(f"  normals up        {np.mean(res.normals[:, 2] > 0):.1%} (orient={p.orient})")
    print(f"  time              read {t_read:.2f} s, normals {t_fit:.2f} s ({n / t_fit:,.0f} points/s), write {t_write:.2f} s")
    note = " (compiled: first run after installation; cached from now on)" if t_kernels > 2.0 else ""
    print(f"  kernels           {t_kernels:.2f} s{note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
