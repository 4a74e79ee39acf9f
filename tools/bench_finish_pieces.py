"""What cutting a big tile's ``finish`` into pieces costs and gains: one table.

    python tools/bench_finish_pieces.py STORE [--pieces 1 2 3 5 8] [--repeats 3] [--out FILE]

``STORE`` is a store kept by ``patchcloud normals IN OUT --keep-store``
(every step done).  On its largest tile, one process, the kernels'
sequential versions (as inside a worker), it times the finish step's
computation (:func:`patchcloud.stream.jobs.normals_tiles.finish_values`:
reading the tile and its neighbours, then :func:`patchcloud.core.finish_tile`)
for the whole tile and for each of ``k`` pieces (ranges of the tile's input
order, as the step cuts them), and prints per ``k``: the
longest piece, the pieces' sum, the sum over the whole tile's time, and
``overhead``: the share ``f`` of the whole tile's time that each piece
repeats, from ``sum = whole * (1 + (k - 1) f)`` (reading the tile, its
octree, the moment cells over all its points).  It checks that the pieces
give the whole tile's values, bit for bit.  Each time is the median of
``--repeats`` runs.  The parameters are the store's as the fit resolved
them: without principal curvatures or always_up.  ``tools/bench_scale.py``'s list bound takes ``f`` to
model the pieces a run on more workers would cut.
"""

from __future__ import annotations

import argparse
import platform
import sys
from datetime import date
from itertools import product
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from timing import median_time  # noqa: E402  (tools/ shares it)


def measure(url: str, pieces: list[int], repeats: int) -> tuple[dict, list[dict]]:
    """The largest tile's facts and one row per piece count (see the module's docstring)."""
    from patchcloud.core import single_threaded
    from patchcloud.stream.io.store import Store
    from patchcloud.stream.io.store import piece_rows
    from patchcloud.stream.jobs.normals_tiles import finish_values

    store = Store.open(url, mode="r")
    if not store.tiles or not all(store.tile_done(t, "finish") for t in store.tiles):
        raise SystemExit(f"{url}: not a store with every tile finished (run patchcloud normals IN OUT --keep-store)")
    tiles, counts = store.tiles, store.tile_counts
    big = tiles[int(np.argmax(counts))]
    present = set(tiles)
    neighbours = [tuple(int(a + d) for a, d in zip(big, step)) for step in product((-1, 0, 1), repeat=3) if any(step)]
    neighbours = [n for n in neighbours if n in present]
    params = dict(store.attrs["params"])
    rank = store.read(big, "rank").astype(np.int64)
    rows = []
    with single_threaded():
        finish_values(url, big, params, neighbours)  # compiled and cached before timing
        whole_s, whole = median_time(lambda: finish_values(url, big, params, neighbours), repeats)
        for k in pieces:
            times, parts = [], []
            masks = []
            for j in range(k):
                lo, hi = piece_rows(rank.size, j, k)  # a piece: rows of the tile's input order, as the finish step cuts it
                only = (rank >= lo) & (rank < hi)
                t, out = median_time(lambda: finish_values(url, big, params, neighbours, only), repeats)
                times.append(t)
                parts.append(out)
                masks.append(only)
            same = True
            for i, w in enumerate(whole):
                got = np.empty_like(w)
                for only, part in zip(masks, parts):
                    got[only] = part[i]
                same &= bool(np.array_equal(got, w))
            total = sum(times)
            rows.append(dict(k=k, longest=max(times), total=total, ratio=total / whole_s,
                             overhead=(total / whole_s - 1.0) / (k - 1) if k > 1 else float("nan"), identical=same))
    tile = dict(tile=big, points=int(counts.max()), tiles=len(tiles), cloud=int(counts.sum()), whole_s=whole_s)
    return tile, rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("store")
    ap.add_argument("--pieces", type=int, nargs="+", default=[1, 2, 3, 5, 8])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out")
    a = ap.parse_args(argv)
    if any(k < 1 for k in a.pieces):
        ap.error(f"--pieces must be 1 or more, got {a.pieces}")
    tile, rows = measure(a.store, a.pieces, a.repeats)
    lines = [
        f"# bench_finish_pieces {date.today()} on {platform.node()}: python {platform.python_version()}",
        f"# command: python tools/bench_finish_pieces.py {' '.join(sys.argv[1:] if argv is None else argv)}",
        f"# largest tile {tile['tile']}: {tile['points']:,} points of {tile['cloud']:,} in {tile['tiles']} tiles; "
        f"whole tile {tile['whole_s']:.3f} s (median of {a.repeats})",
        "",
        f"{'pieces':>6} {'longest s':>9} {'sum s':>7} {'sum/whole':>9} {'overhead f':>10} {'identical':>9}",
    ]
    for r in rows:
        f = "" if np.isnan(r["overhead"]) else f"{r['overhead']:.3f}"
        lines.append(f"{r['k']:>6} {r['longest']:>9.3f} {r['total']:>7.3f} {r['ratio']:>8.2f}x {f:>10} {'yes' if r['identical'] else 'NO':>9}")
    lines.append("")
    lines.append("# times: finish_values (read the tile and its neighbours, finish_tile), whole tile or one piece (rows of the "
                 "tile's input order); overhead f: sum = whole * (1 + (k - 1) f)")
    text = "\n".join(lines)
    print(text)
    if a.out:
        Path(a.out).write_text(text + "\n")
    return 0 if all(r["identical"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
