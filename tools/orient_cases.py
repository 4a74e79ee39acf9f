"""How ``--orient up`` orients synthetic scenes whose right sides are known: one table.

    python tools/orient_cases.py [--out tools/results/orient_cases-DATE.txt]

Each scene is sampled on a 0.1 m grid (0.05 m for the pipe) with 5 mm (2 mm)
Gaussian noise, shifted to UTM-sized coordinates, and run through
``patchcloud.core.estimate_normals(orient="up")`` (one tile, defaults):

- ``box``: a 10 x 10 x 6 m box building (roof and four walls) on 30 x 30 m
  of ground; the right sides are up for ground and roof and outward for
  each wall;
- ``deck``: a 30 x 10 m deck 1 m thick, 6 to 7 m above the ground, sampled
  on every face (as a mobile or terrestrial scan sees a bridge); the right
  side of its underside is down (outward);
- ``pipe R``: a horizontal pipe of radius R, 3 m above the ground, sampled
  all round; the right side is outward (its lower half facing down);
- ``gable``: a 7 x 8 m house, 4 m walls, a gable roof of 55 degrees whose
  eaves overhang the walls by 0.6 m (roof and wall meet in a T there); the
  right sides are outward, up for the roof planes.

Columns: the share of each surface's points whose normal is within 60
degrees of the right side (cos > 0.5).  The up rule cannot tell an
underside from a top by itself: it takes the side the linked neighbours
give, and a group of linked patches with no reliable link to anything
else follows its strongest single patch prior (see the README's
"Orientation" notes).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

SHIFT = np.array([500000.0, 5000000.0, 100.0])


def grid(a0: float, a1: float, b0: float, b1: float, step: float) -> np.ndarray:
    """The (a, b) nodes of a regular grid, (M, 2)."""
    return np.mgrid[a0:a1:step, b0:b1:step].reshape(2, -1).T


def box(step: float = 0.1) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Ground around a 10 x 10 x 6 m box building: (name, points, right side) per surface."""
    g = grid(0, 30, 0, 30, step)
    ground = np.column_stack([g, np.zeros(len(g))])
    ground = ground[~((ground[:, 0] > 10) & (ground[:, 0] < 20) & (ground[:, 1] > 10) & (ground[:, 1] < 20))]
    r = grid(10, 20, 10, 20, step)
    roof = np.column_stack([r, np.full(len(r), 6.0)])
    w = grid(10, 20, 0, 6, step)
    walls = [
        ("wall -y", np.column_stack([w[:, 0], np.full(len(w), 10.0), w[:, 1]]), (0.0, -1.0, 0.0)),
        ("wall +y", np.column_stack([w[:, 0], np.full(len(w), 20.0), w[:, 1]]), (0.0, 1.0, 0.0)),
        ("wall -x", np.column_stack([np.full(len(w), 10.0), w[:, 0], w[:, 1]]), (-1.0, 0.0, 0.0)),
        ("wall +x", np.column_stack([np.full(len(w), 20.0), w[:, 0], w[:, 1]]), (1.0, 0.0, 0.0)),
    ]
    parts = [("ground", ground, (0.0, 0.0, 1.0)), ("roof", roof, (0.0, 0.0, 1.0)), *walls]
    return [(n, p, np.tile(np.asarray(o), (len(p), 1))) for n, p, o in parts]


def deck(step: float = 0.1) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Ground under a 30 x 10 m deck, 6 to 7 m high, sampled on every face."""
    g = grid(0, 40, 0, 20, step)
    ground = np.column_stack([g, np.zeros(len(g))])
    t = grid(5, 35, 5, 15, step)
    top, bottom = np.column_stack([t, np.full(len(t), 7.0)]), np.column_stack([t, np.full(len(t), 6.0)])
    sx, sy = grid(5, 35, 6.0, 7.0, step), grid(5, 15, 6.0, 7.0, step)
    faces = [  # (points, outward) of the four sides
        (np.column_stack([sx[:, 0], np.full(len(sx), 5.0), sx[:, 1]]), (0.0, -1.0, 0.0)),
        (np.column_stack([sx[:, 0], np.full(len(sx), 15.0), sx[:, 1]]), (0.0, 1.0, 0.0)),
        (np.column_stack([np.full(len(sy), 5.0), sy[:, 0], sy[:, 1]]), (-1.0, 0.0, 0.0)),
        (np.column_stack([np.full(len(sy), 35.0), sy[:, 0], sy[:, 1]]), (1.0, 0.0, 0.0)),
    ]
    sides = np.vstack([f for f, _ in faces])
    side_out = np.vstack([np.tile(o, (len(f), 1)) for f, o in faces])
    return [
        ("ground", ground, np.tile([0.0, 0.0, 1.0], (len(ground), 1))),
        ("deck top", top, np.tile([0.0, 0.0, 1.0], (len(top), 1))),
        ("deck underside", bottom, np.tile([0.0, 0.0, -1.0], (len(bottom), 1))),
        ("deck sides", sides, side_out),
    ]


def pipe(radius: float, step: float = 0.05) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Ground under a horizontal pipe along x, sampled all round."""
    g = grid(0, 20, 0, 10, step)
    ground = np.column_stack([g, np.zeros(len(g))])
    th, xs = np.meshgrid(np.arange(0, 2 * np.pi, step / radius), np.arange(2, 18, step))
    th, xs = th.ravel(), xs.ravel()
    out = np.column_stack([np.zeros(th.size), np.cos(th), np.sin(th)])
    pts = np.column_stack([xs, 5 + radius * out[:, 1], 3 + radius * out[:, 2]])
    upper = out[:, 2] >= 0
    return [
        ("ground", ground, np.tile([0.0, 0.0, 1.0], (len(ground), 1))),
        ("pipe upper half", pts[upper], out[upper]),
        ("pipe lower half", pts[~upper], out[~upper]),
    ]


def gable(step: float = 0.1, eave: float = 0.6, rise: float = 5.0) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Ground round a house with a gable roof whose eaves overhang its walls: (name, points, right side) per surface."""
    x0, y0, sx, sy, h = 6.3, 5.7, 7.0, 8.0, 4.0
    xm, half = x0 + sx / 2, sx / 2
    g = grid(0, 20, 0, 20, step)
    g = g[~((g[:, 0] > x0) & (g[:, 0] < x0 + sx) & (g[:, 1] > y0) & (g[:, 1] < y0 + sy))]
    end = grid(x0, x0 + sx, 0, h + rise, step)
    end = end[end[:, 1] <= h + rise * (1 - np.abs(end[:, 0] - xm) / half)]  # the gable end walls
    side = grid(y0, y0 + sy, 0, h, step)
    r = grid(x0 - eave, x0 + sx + eave, y0 - eave, y0 + sy + eave, step)
    z = h + rise * (1 - np.abs(r[:, 0] - xm) / half)
    n, left = np.hypot(rise, half), r[:, 0] < xm
    parts = [
        ("ground", np.column_stack([g, np.zeros(len(g))]), (0.0, 0.0, 1.0)),
        ("gable wall -y", np.column_stack([end[:, 0], np.full(len(end), y0), end[:, 1]]), (0.0, -1.0, 0.0)),
        ("gable wall +y", np.column_stack([end[:, 0], np.full(len(end), y0 + sy), end[:, 1]]), (0.0, 1.0, 0.0)),
        ("wall -x", np.column_stack([np.full(len(side), x0), side[:, 0], side[:, 1]]), (-1.0, 0.0, 0.0)),
        ("wall +x", np.column_stack([np.full(len(side), x0 + sx), side[:, 0], side[:, 1]]), (1.0, 0.0, 0.0)),
        ("roof plane -x", np.column_stack([r[left], z[left]]), (-rise / n, 0.0, half / n)),
        ("roof plane +x", np.column_stack([r[~left], z[~left]]), (rise / n, 0.0, half / n)),
    ]
    return [(name, p, np.tile(np.asarray(o), (len(p), 1))) for name, p, o in parts]


def run(scene: str, parts, noise: float) -> list[str]:
    """One row per surface: the share of its normals within 60 degrees of its right side."""
    from patchcloud.core import estimate_normals

    rng = np.random.default_rng(0)
    pts = np.vstack([p for _, p, _ in parts])
    pts = pts + rng.normal(0.0, noise, pts.shape) + SHIFT
    res = estimate_normals(pts, orient="up")
    rows, k = [], 0
    for name, p, right in parts:
        n = res.normals[k:k + len(p)].astype(np.float64)
        k += len(p)
        good = np.einsum("ij,ij->i", n, right) > 0.5
        rows.append(f"| {scene} | {name} | {len(p):,} | {100.0 * good.mean():.1f} % |")
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, help="also write the table to this file")
    args = ap.parse_args(argv)
    import patchcloud

    lines = [
        f"# tools/orient_cases.py: python tools/orient_cases.py {' '.join(sys.argv[1:])}",
        f"# patchcloud {patchcloud.__version__}; estimate_normals(orient='up'), one tile, default parameters",
        "",
        "| scene | surface | points | right side |",
        "|---|---|---:|---:|",
    ]
    lines += run("box", box(), 0.005)
    lines += run("deck", deck(), 0.005)
    for r in (1.0, 0.5):
        lines += run(f"pipe R {r:g} m", pipe(r), 0.002)
    lines += run("gable", gable(), 0.005)
    text = "\n".join(lines)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
