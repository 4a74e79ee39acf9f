"""Synthetic scenes with known normals, for tests and benchmarks.

Every generator returns ``(points, normals)``: (N, 3) float64 coordinates in
metres and (N, 3) float64 unit normals pointing out of the solid (or up for
open surfaces).  Sampling is uniform by area; ``noise`` adds Gaussian noise
(metres, standard deviation) along the true normal.

Run ``python tools/synthetic.py --points 1000000 --out scene.npz`` to write
a scene file the benchmark can read.
"""

from __future__ import annotations

import argparse

import numpy as np

__all__ = ["plane", "sphere", "cylinder", "paraboloid", "torus", "box", "scene"]


def _noise(rng, p, n, noise):
    if noise > 0:
        p = p + n * rng.normal(scale=noise, size=(p.shape[0], 1))
    return p, n


def plane(rng, n, size=10.0, noise=0.0, tilt=(0.0, 0.0)):
    """Square ``size`` x ``size`` plane z = tx*x + ty*y, normal up."""
    xy = rng.uniform(-size / 2, size / 2, (n, 2))
    tx, ty = tilt
    p = np.column_stack([xy, tx * xy[:, 0] + ty * xy[:, 1]])
    nn = np.tile(np.array([-tx, -ty, 1.0]) / np.sqrt(1 + tx * tx + ty * ty), (n, 1))
    return _noise(rng, p, nn, noise)


def sphere(rng, n, radius=1.0, centre=(0.0, 0.0, 0.0), noise=0.0):
    """Sphere, outward normals."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    return _noise(rng, np.asarray(centre) + radius * d, d, noise)


def cylinder(rng, n, radius=1.0, height=4.0, centre=(0.0, 0.0, 0.0), noise=0.0):
    """Vertical open cylinder (side only), outward normals."""
    t = rng.uniform(0, 2 * np.pi, n)
    z = rng.uniform(-height / 2, height / 2, n)
    nn = np.column_stack([np.cos(t), np.sin(t), np.zeros(n)])
    p = np.asarray(centre) + np.column_stack([radius * nn[:, 0], radius * nn[:, 1], z])
    return _noise(rng, p, nn, noise)


def paraboloid(rng, n, size=2.0, a=0.5, b=0.25, noise=0.0):
    """z = a x^2 + b y^2 over a square, normal up; curvatures at 0 are 2a, 2b."""
    xy = rng.uniform(-size / 2, size / 2, (n, 2))
    x, y = xy.T
    p = np.column_stack([x, y, a * x * x + b * y * y])
    nn = np.column_stack([-2 * a * x, -2 * b * y, np.ones(n)])
    nn /= np.linalg.norm(nn, axis=1)[:, None]
    return _noise(rng, p, nn, noise)


def torus(rng, n, major=2.0, minor=0.5, noise=0.0):
    """Torus around the z axis, outward normals, area-uniform sampling."""
    u = rng.uniform(0, 2 * np.pi, 4 * n)
    v = rng.uniform(0, 2 * np.pi, 4 * n)
    keep = rng.uniform(0, major + minor, 4 * n) < major + minor * np.cos(v)
    u, v = u[keep][:n], v[keep][:n]
    nn = np.column_stack([np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v)])
    p = np.column_stack([(major + minor * np.cos(v)) * np.cos(u), (major + minor * np.cos(v)) * np.sin(u), minor * np.sin(v)])
    return _noise(rng, p, nn, noise)


def box(rng, n, size=(2.0, 3.0, 1.5), centre=(0.0, 0.0, 0.0), noise=0.0):
    """Closed box with sharp edges, outward normals, area-uniform sampling."""
    sx, sy, sz = size
    areas = np.array([sy * sz, sy * sz, sx * sz, sx * sz, sx * sy, sx * sy])
    face = rng.choice(6, size=n, p=areas / areas.sum())
    uv = rng.uniform(-0.5, 0.5, (n, 2))
    p = np.empty((n, 3))
    nn = np.zeros((n, 3))
    half = np.array(size) / 2
    for f in range(6):
        m = face == f
        axis, sgn = f // 2, (1 if f % 2 else -1)
        others = [a for a in range(3) if a != axis]
        p[m, axis] = sgn * half[axis]
        p[m, others[0]] = uv[m, 0] * size[others[0]]
        p[m, others[1]] = uv[m, 1] * size[others[1]]
        nn[m, axis] = sgn
    return _noise(rng, np.asarray(centre) + p, nn, noise)


def scene(n: int, seed: int = 0, noise: float = 0.002):
    """A 40 m x 40 m scene: ground, boxes (buildings), cylinders (poles), spheres.

    Point density is about uniform by area; normals are known everywhere.
    Parts: ground plane 40 x 40 m (up), three boxes of a few metres standing
    on it (outward; their bottom faces are dropped), two cylinders and two
    spheres.  Returns (points, normals).
    """
    rng = np.random.default_rng(seed)
    parts = []
    boxes = [((8.0, 6.0, 5.0), (-8.0, -6.0, 2.5)), ((5.0, 5.0, 9.0), (10.0, 8.0, 4.5)), ((3.0, 10.0, 3.0), (9.0, -10.0, 1.5))]
    cyl = [((-10.0, 10.0, 3.0), 0.3, 6.0), ((2.0, -14.0, 2.0), 0.15, 4.0)]
    sph = [((-12.0, 12.0, 6.5), 0.8), ((0.0, 5.0, 1.5), 1.5)]
    area = {"ground": 1600.0}
    for k, (sz, _) in enumerate(boxes):
        sx, sy, sz_ = sz
        area[f"box{k}"] = 2 * (sx * sz_ + sy * sz_) + 2 * sx * sy
    for k, (_, r, h) in enumerate(cyl):
        area[f"cyl{k}"] = 2 * np.pi * r * h
    for k, (_, r) in enumerate(sph):
        area[f"sph{k}"] = 4 * np.pi * r * r
    total = sum(area.values())
    counts = {k: int(round(n * a / total)) for k, a in area.items()}
    counts["ground"] += n - sum(counts.values())
    p, nn = plane(rng, int(counts["ground"] * 1.1) + 10, size=40.0, noise=noise)
    inside = np.zeros(len(p), dtype=bool)  # no ground under the buildings
    for sz, c in boxes:
        inside |= (np.abs(p[:, 0] - c[0]) < sz[0] / 2) & (np.abs(p[:, 1] - c[1]) < sz[1] / 2)
    parts.append((p[~inside][: counts["ground"]], nn[~inside][: counts["ground"]]))
    for k, (sz, c) in enumerate(boxes):
        m = counts[f"box{k}"]
        p, nn = box(rng, int(m * 1.25) + 10, size=sz, centre=c, noise=noise)
        keep = ~(nn[:, 2] < -0.5)  # no bottom face
        parts.append((p[keep][:m], nn[keep][:m]))
    for k, (c, r, h) in enumerate(cyl):
        parts.append(cylinder(rng, counts[f"cyl{k}"], radius=r, height=h, centre=c, noise=noise))
    for k, (c, r) in enumerate(sph):
        parts.append(sphere(rng, counts[f"sph{k}"], radius=r, centre=c, noise=noise))
    pts = np.concatenate([q for q, _ in parts])
    nrm = np.concatenate([q for _, q in parts])
    return pts, nrm


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--noise", type=float, default=0.002, help="metres")
    ap.add_argument("--out", required=True, help="output .npz with points and normals")
    a = ap.parse_args()
    pts, nrm = scene(a.points, a.seed, a.noise)
    np.savez(a.out, points=pts, normals=nrm)
    print(f"wrote {len(pts)} points to {a.out}")


if __name__ == "__main__":
    main()
