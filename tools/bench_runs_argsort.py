"""The stable argsort of keys that come in runs: run by run against numpy's, one table.

    python tools/bench_runs_argsort.py [--points 1000000] [--repeats 5] [--out FILE]

A synthetic scene (``tools/synthetic.py``, ``--points`` points) is put in
Morton order in its bounding cube, as a tile's points are; its points are
then keyed by their cells of edge ``h`` and ``h / 2`` (the moment cells of
:mod:`patchcloud.core.moment_normals`, ``h`` the octree's deepest cells at 3
point spacings), and for comparison by random keys (no runs).  For each
key array: the runs' mean length, the time of
:func:`patchcloud.core.argsort.stable_argsort` (which sorts run by run where
runs average :data:`~patchcloud.core.argsort.MIN_RUN` keys or more), of
``np.argsort(kind="stable")``, and whether the permutations are the same.
One thread (as inside a task).  Times are medians of ``--repeats``.
"""

from __future__ import annotations

import argparse
import platform
import sys
from datetime import date
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from timing import median_time  # noqa: E402  (tools/ shares it)

__all__ = ["main"]


def key_sets(points: int, seed: int = 0) -> list[tuple[str, np.ndarray]]:
    """(name, int64 keys) of the scene's points in Morton order: cells of edge h and h/2, and random keys."""
    import synthetic

    from patchcloud.core.octree import estimate_spacing, sort_points

    pts, _ = synthetic.scene(points, seed=seed)
    corner = pts.min(axis=0)
    edge = float((pts.max(axis=0) - corner).max()) * (1 + 1e-9)
    local = pts - corner
    order, keys, _ = sort_points(local, np.zeros(3), edge)
    local = local[order]
    spacing = estimate_spacing(keys, edge)  # as the calibration estimates it
    h = edge / 2.0 ** np.floor(np.log2(edge / (3.0 * spacing)))  # the deepest cells: d_min = 3 spacings <= h < 2 d_min
    out = []
    for name, e in (("cells of h", h), ("cells of h/2", h / 2)):
        c = np.floor(local / e).astype(np.int64)
        span = c.max(axis=0) + 1
        out.append((f"{name} ({e:.3g} m)", (c[:, 0] * span[1] + c[:, 1]) * span[2] + c[:, 2]))
    out.append(("random keys", np.random.default_rng(seed).integers(0, points, points)))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out")
    a = ap.parse_args(argv)
    if a.points < 1000 or a.repeats < 1:
        ap.error("--points must be at least 1000 and --repeats at least 1")
    from patchcloud.core import single_threaded
    from patchcloud.core.argsort import stable_argsort

    lines = [
        f"# bench_runs_argsort {date.today()} on {platform.node()}: python {platform.python_version()}, one thread",
        f"# command: python tools/bench_runs_argsort.py {' '.join(sys.argv[1:] if argv is None else argv)}",
        "",
        f"{'keys':<28} {'keys':>10} {'mean run':>9} {'stable_argsort s':>17} {'np.argsort s':>13} {'ratio':>6} {'same':>5}",
    ]
    same_all = True
    with single_threaded():
        for name, keys in key_sets(a.points):
            stable_argsort(keys[:5000])  # compiled and cached before timing
            runs = 1 + int(np.count_nonzero(keys[1:] != keys[:-1]))
            ours, p = median_time(lambda: stable_argsort(keys), a.repeats)
            numpy_s, q = median_time(lambda: np.argsort(keys, kind="stable"), a.repeats)
            same = bool(np.array_equal(p, q))
            same_all &= same
            lines.append(f"{name:<28} {keys.size:>10,} {keys.size / runs:>9.1f} {ours:>17.4f} {numpy_s:>13.4f} "
                         f"{numpy_s / ours:>5.2f}x {'yes' if same else 'NO':>5}")
    text = "\n".join(lines)
    print(text)
    if a.out:
        Path(a.out).write_text(text + "\n")
    return 0 if same_all else 1


if __name__ == "__main__":
    sys.exit(main())
