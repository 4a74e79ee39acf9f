"""Where the normal error on the reference meshes comes from: one table per mesh.

    python tools/mesh_error.py [--out tools/results/mesh_error-DATE.txt]

The meshes of ../shared/data (tools/plyio.MESHES) are scans: their vertices are
the points and their reference normals are the area-weighted normals of each
vertex's ring of triangles.  The table sets patchcloud beside estimators whose
neighbourhood size is known, so the error can be read as a function of how
many points one normal averages:

- ``reference roughness``: median angle between the reference normal of a
  point and that of its nearest neighbour (how fast the reference itself
  turns from one vertex to the next);
- ``pca-k``: PCA of the k nearest points (k-NN normals as Open3D and PCL give
  them);
- ``jet-k``: a quadric ``z = f(x, y)`` fitted to the k nearest points in their
  PCA frame, its normal taken at the point (osculating jets, as CGAL's
  ``jet_estimate_normals``);
- ``patchcloud ...``: ``estimate_normals(orient="outward")`` with the default
  parameters and with each of the choices the issue asks about (blending off,
  a smaller RMSE threshold, a smaller ``d_min``); ``points/fit`` is the mean
  number of points in the leaf whose quadric gave a point its normal.

Columns: median and 90th-percentile angle to the reference (degrees,
sign-insensitive), the share of normals facing inward (patchcloud only: the
others have no orientation here), ``points/fit`` and the share of each
``NormalMethod`` (1 quadric, 2 blended, 3 k-NN, 4 moments).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "data"
sys.path.insert(0, str(HERE))

from plyio import MESHES, mesh_points  # noqa: E402


def angles(n: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Sign-insensitive angle (degrees) between rows of two unit-vector arrays."""
    n = n / np.linalg.norm(n, axis=1)[:, None]
    return np.degrees(np.arccos(np.abs(np.einsum("ij,ij->i", n, ref)).clip(0.0, 1.0)))


def neighbourhood_frames(xyz: np.ndarray, k: int):
    """The k nearest points of each point, centred, and their PCA frames (columns: normal, then tangents)."""
    _, nb = cKDTree(xyz).query(xyz, k=k)
    centre = xyz[nb].mean(axis=1)
    d = xyz[nb] - centre[:, None, :]
    _, vec = np.linalg.eigh(np.einsum("nki,nkj->nij", d, d))
    return d, xyz - centre, vec


def pca_normals(xyz: np.ndarray, k: int) -> np.ndarray:
    return neighbourhood_frames(xyz, k)[2][:, :, 0]


def jet_normals(xyz: np.ndarray, k: int) -> np.ndarray:
    """Normal at each point of the quadric z = ax² + bxy + cy² + dx + ey + f of its k nearest points."""
    d, own, vec = neighbourhood_frames(xyz, k)
    loc = np.einsum("nki,nij->nkj", d, vec)  # (z, y, x) in the frame: column 0 is the normal
    z, y, x = loc[..., 0], loc[..., 1], loc[..., 2]
    a = np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], axis=-1)
    ata = np.einsum("nki,nkj->nij", a, a) + 1e-12 * np.eye(6)
    coef = np.linalg.solve(ata, np.einsum("nki,nk->ni", a, z)[..., None])[..., 0]
    p = np.einsum("ni,nij->nj", own, vec)
    py, px = p[:, 1], p[:, 2]
    gx = 2 * coef[:, 0] * px + coef[:, 1] * py + coef[:, 3]
    gy = coef[:, 1] * px + 2 * coef[:, 2] * py + coef[:, 4]
    return vec[:, :, 0] - gx[:, None] * vec[:, :, 2] - gy[:, None] * vec[:, :, 1]


def table(name: str, xyz: np.ndarray, ref: np.ndarray) -> list[str]:
    from patchcloud.core import estimate_normals

    rows = [f"## mesh-{name}: {len(xyz):,} points", ""]
    rows.append("| estimator | median ° | p90 ° | inward | points/fit | quadric | blended | k-NN | moments |")
    rows.append("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    _, nb = cKDTree(xyz).query(xyz, k=2)
    rough = angles(ref[nb[:, 1]], ref)
    rows.append(f"| reference roughness | {np.median(rough):.2f} | {np.percentile(rough, 90):.2f} | | 2 | | | | |")
    for k in (8, 12, 16, 30):
        a = angles(pca_normals(xyz, k), ref)
        rows.append(f"| pca-{k} | {np.median(a):.2f} | {np.percentile(a, 90):.2f} | | {k} | | | | |")
    for k in (8, 12, 16, 24, 32):
        a = angles(jet_normals(xyz, k), ref)
        rows.append(f"| jet-{k} | {np.median(a):.2f} | {np.percentile(a, 90):.2f} | | {k} | | | | |")
    base = estimate_normals(xyz, orient="outward").parameters
    variants = [
        ("patchcloud defaults", {}),
        ("patchcloud blend off", {"blend": False}),
        ("patchcloud threshold x0.5", {"threshold": 0.5 * base.threshold}),
        ("patchcloud threshold x0.25", {"threshold": 0.25 * base.threshold}),
        ("patchcloud d_min x0.5", {"d_min": 0.5 * base.d_min}),
        ("patchcloud d_min x0.5, threshold x0.25", {"d_min": 0.5 * base.d_min, "threshold": 0.25 * base.threshold}),
    ]
    for label, kw in variants:
        res = estimate_normals(xyz, orient="outward", **kw)
        a = angles(res.normals.astype(np.float64), ref)
        inward = np.mean(np.einsum("ij,ij->i", res.normals, ref) < 0)
        fit = res.method <= 2
        per_patch = np.bincount(res.patch[fit], minlength=len(res.patches))
        size = per_patch[res.patch[fit]].mean() if fit.any() else float("nan")
        share = [np.mean(res.method == m) for m in (1, 2, 3, 4)]
        rows.append(
            f"| {label} | {np.median(a):.2f} | {np.percentile(a, 90):.2f} | {inward:.3f} | {size:.1f} | "
            + " | ".join(f"{s:.2f}" for s in share) + " |"
        )
    rows.append("")
    rows.append(f"(defaults resolved: spacing {base.spacing:.4g}, d_min {base.d_min:.4g}, RMSE threshold {base.threshold:.4g})")
    rows.append("")
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, help="also write the tables to this file")
    args = ap.parse_args(argv)
    lines = [f"# {Path(__file__).name}: {' '.join(['python', 'tools/mesh_error.py', *(argv or sys.argv[1:])])}", ""]
    for name, rel in MESHES:
        path = SHARED / rel
        if not path.exists():
            lines.append(f"# skipping mesh {name}: {path} not found")
            continue
        xyz, ref = mesh_points(path)
        lines += table(name, xyz, ref)
    text = "\n".join(lines)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
