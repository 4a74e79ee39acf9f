"""How to code the positions of points mode (``compress --keep-points``): the world grid against the patches' frames.

    python tools/bench_point_coding.py [--max-error 0.01 0.02 0.05 0.1] [--files LAS ...] [--out FILE]

Points mode keeps every point in input order with its attributes exact,
so every variant below is a LAZ (lazrs) of all the input's records in
input order; only X, Y, Z differ.  For each real aerial file of
../shared/data (a missing one is skipped with the reason printed) and
each budget ``e``, bits per point of:

- **input LAZ** (the file as it is) and **attributes only** (X, Y, Z all
  zero: what the attributes cost whatever the positions);
- **world grid** (what points mode does): X, Y, Z rounded to a grid of
  step ``s = 2 e / sqrt(3)`` (every point within ``e``);
- **patch frame, one stream**: a point that a patch of
  ``patchcloud.core.fit_models`` (the whole file, budget ``e``) models
  as ``(u, v)`` on the same grid in its patch's frame and ``w`` as the
  rounded offset from the quadric at ``(u, v)``; the other points on the
  world grid; plus the patch of each point (its changes in input order,
  Zstd 19);
- **patch frame, two streams**: the same, patch points and the others
  in two LAZ streams.

Only the sizes are measured here (the decoding of the patch-frame
variants is not written); ``share w = 0`` is the share of patch points
whose rounded offset from the quadric is 0.
"""

from __future__ import annotations

import argparse
import datetime
import io
import sys
from pathlib import Path

import numpy as np

from bench_compress import REAL as COMPRESS_INPUTS  # tools/ is this script's directory
from bench_compress import SHARED as DATA

#: The airborne inputs of tools/bench_compress.py: name -> path under ../shared/data.
REAL = {k: COMPRESS_INPUTS[k] for k in ("ign-lidarhd-77055", "ign-stbarth", "lastools-fusa", "lastools-house")}


def laz_bytes(header, points, X, Y, Z, scale: float) -> int:
    """Bytes of a LAZ of ``points`` (all their fields) with X, Y, Z replaced, at ``scale``."""
    import laspy

    h = laspy.LasHeader(point_format=header.point_format, version=header.version)
    h.scales, h.offsets = np.array([scale] * 3), np.zeros(3)
    out = laspy.LasData(h)
    out.points = points.copy()
    out.X, out.Y, out.Z = X, Y, Z
    buf = io.BytesIO()
    out.write(buf, do_compress=True, laz_backend=laspy.LazBackend.Lazrs)
    return buf.getbuffer().nbytes


def measure(path: Path, budgets) -> list[str]:
    import laspy
    from numcodecs import Zstd

    from patchcloud.core import dequantise_models, fit_models, quantise_models

    las = laspy.read(path)
    n = len(las.points)
    xyz = np.column_stack([las.x, las.y, las.z])
    local = xyz - xyz.min(axis=0)
    zero = np.zeros(n, np.int32)
    attrs = laz_bytes(las.header, las.points, zero, zero, zero, 1.0)
    rows = [f"| {path.name} | input | {8 * path.stat().st_size / n:.2f} | | | |",
            f"| {path.name} | attributes only | {8 * attrs / n:.2f} | | | |"]
    for e in budgets:
        s = 2.0 * e / np.sqrt(3.0)
        W = np.rint(local / s).astype(np.int32)
        world = laz_bytes(las.header, las.points, W[:, 0], W[:, 1], W[:, 2], s)
        fit = fit_models(local, e)
        m = dequantise_models(quantise_models(fit.models, e))
        on = fit.patch >= 0
        p = fit.patch[on]
        uvw = np.einsum("nji,nj->ni", m.frame[p], local[on] - m.centroid[p])
        uq, vq = np.rint(uvw[:, 0] / s), np.rint(uvw[:, 1] / s)
        c, U, V = m.coeffs[p], uq * s, vq * s
        f = c[:, 0] * U * U + c[:, 1] * U * V + c[:, 2] * V * V + c[:, 3] * U + c[:, 4] * V + c[:, 5]
        wq = np.rint((uvw[:, 2] - f) / s)
        P = W.copy()
        P[on] = np.column_stack([uq, vq, wq]).astype(np.int32)
        ids = np.where(on, fit.patch, -1)
        id_bytes = len(Zstd(level=19).encode(np.diff(np.r_[0, ids]).astype(np.int32).tobytes()))
        one = laz_bytes(las.header, las.points, P[:, 0], P[:, 1], P[:, 2], s) + id_bytes
        r = ~on
        two = laz_bytes(las.header, las.points[on], P[on, 0], P[on, 1], P[on, 2], s) + id_bytes
        if r.any():
            two += laz_bytes(las.header, las.points[r], P[r, 0], P[r, 1], P[r, 2], s)
        rows.append(f"| {path.name} | {e:g} | {8 * world / n:.2f} | {8 * one / n:.2f} | {8 * two / n:.2f} | "
                    f"{on.mean():.0%} on patches, share w = 0 {np.mean(wq == 0):.0%}, patch ids {8 * id_bytes / n:.2f} bits/pt |")
    return rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--max-error", type=float, nargs="+", default=[0.01, 0.02, 0.05, 0.1])
    ap.add_argument("--files", nargs="*", type=Path, default=None)
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    files = a.files
    if files is None:
        files = []
        for name, rel in REAL.items():
            if (DATA / rel).exists():
                files.append(DATA / rel)
            else:
                print(f"# skipped {name}: {DATA / rel} not found", flush=True)
    lines = [f"# tools/bench_point_coding.py, {datetime.date.today()}: python tools/bench_point_coding.py "
             + " ".join(sys.argv[1:] if argv is None else argv), "",
             "| file | max-error m (or what) | world grid bits/pt | patch frame, one stream | patch frame, two streams | notes |",
             "|---|---|---:|---:|---:|---|"]
    for f in files:
        lines += measure(Path(f), a.max_error)
    text = "\n".join(lines)
    print(text)
    if a.out:
        a.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
