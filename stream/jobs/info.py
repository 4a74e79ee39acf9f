"""``info``: what a LAS/LAZ file, a patchcloud store or a .pcz holds."""

from __future__ import annotations

import os
import zipfile

import laspy
import numpy as np

from patchcloud.core import PatchcloudIOError

from patchcloud.stream.io.las import open_source
from patchcloud.stream.io.pcz import open_pcz
from patchcloud.stream.io.store import Store
from patchcloud.stream.engine.background import stops_what_it_starts

__all__ = ["info", "format_info"]


@stops_what_it_starts()  # no thread of the run's left running (stream.engine.background)
def info(path: str | os.PathLike) -> dict:
    """A description of a LAS/LAZ file (header), a store (source, grid, tiles, steps done) or a .pcz (counts).

    Raises
    ------
    PatchcloudIOError
        ``path`` is neither a readable LAS/LAZ file nor a patchcloud store.

    Examples
    --------
    >>> d = info(sample)
    >>> d["kind"], d["point_count"], d["point_format"]
    ('las', 60653, 8)
    """
    p = str(path)
    if os.path.isfile(p) and zipfile.is_zipfile(p):
        with open_pcz(p) as f:
            a = f.attrs
            return {"kind": "pcz", "path": p, "bytes": os.path.getsize(p), "version": a["version"],
                    "max_error": a["max_error"], "counts": a["counts"], "source": a["source"], "grid": a["grid"]}
    if os.path.isfile(p):
        src = open_source(p)
        with laspy.open(p) as r:
            dims = list(r.header.point_format.dimension_names)
            extra = list(r.header.point_format.extra_dimension_names)
        return {"kind": "las", **src.to_json(), "dimensions": dims, "extra_dimensions": extra}
    if Store.exists(p):
        st = Store.open(p, mode="r")
        a = st.attrs
        tiles = st.tiles
        done: dict[str, int] = {}
        for t in tiles:
            for step, v in st.tile_attrs(t).get("done", {}).items():
                if v:
                    done[step] = done.get(step, 0) + 1
        counts = np.asarray(a.get("tile_counts", []), dtype=np.int64)
        return {
            "kind": "store", "url": st.url, "source": a.get("source"), "grid": a.get("grid"), "tiles": len(tiles),
            "points": int(counts.sum()), "points_per_tile": [int(counts.min()), int(np.median(counts)), int(counts.max())] if counts.size else [],
            "steps": a.get("steps", {}), "tiles_done": done, "parameters": a.get("params"),
        }
    raise PatchcloudIOError(f"{p}: neither a LAS/LAZ file nor a patchcloud store")


def format_info(d: dict) -> str:
    """``info``'s dictionary as a few lines of text.

    Examples
    --------
    >>> print(format_info(info(sample)))                # doctest: +ELLIPSIS
    /...test_data_77055_627760_LA93_IGN69.laz: LAS 1.4 point format 8 (LAZ)
      points       60,653
    ...
    """
    if d["kind"] == "pcz":
        c = d["counts"]
        n = max(c["points"], 1)
        return "\n".join([
            f"{d['path']}: patchcloud .pcz version {d['version']}, {d['bytes']:,} bytes ({8 * d['bytes'] / n:.2f} bits/point)",
            f"  source       {d['source'].get('path')} ({d['source'].get('point_count', 0):,} points)",
            f"  points       {c['points']:,}: {c['points'] - c['residual']:,} on {c['patches']:,} patches ({c.get('cells', 0):,} octree cells), {c['residual']:,} residual",
            f"  max error    {d['max_error']:g} m",
            f"  tiles        {c['tiles']:,} of {d['grid']['tile_size']:g} m",
        ])
    if d["kind"] == "las":
        lines = [
            f"{d['path']}: LAS {d['version']} point format {d['point_format']}{' (LAZ)' if d['compressed'] else ''}",
            f"  points       {d['point_count']:,}",
            f"  bounds       x {d['mins'][0]:.3f} .. {d['maxs'][0]:.3f}, y {d['mins'][1]:.3f} .. {d['maxs'][1]:.3f}, z {d['mins'][2]:.3f} .. {d['maxs'][2]:.3f}",
            f"  scale        {d['scale']}  offset {d['offset']}",
            f"  dimensions   {', '.join(d['dimensions'])}",
            f"  CRS          {(d['crs'] or 'none')[:100]}",
        ]
        return "\n".join(lines)
    g = d["grid"] or {}
    src = d["source"] or {}
    steps = ", ".join(d["steps"]) or "none"
    done = ", ".join(f"{k} {v}/{d['tiles']}" for k, v in sorted(d["tiles_done"].items())) or "none"
    lines = [
        f"{d['url']}: patchcloud store",
        f"  source       {src.get('path')} ({src.get('point_count', 0):,} points)",
        f"  points       {d['points']:,} in {d['tiles']:,} tiles of {g.get('tile_size', 0):g} m (min/median/max per tile {d['points_per_tile']})",
        f"  origin       {g.get('origin')}",
        f"  steps done   {steps}",
        f"  tiles done   {done}",
    ]
    if d.get("parameters"):
        p = d["parameters"]
        lines.append(f"  parameters   {p['criterion']} threshold {p['threshold']:.4g}, d_min {p['d_min']:.3g} m, spacing {p['spacing']:.3g} m, orient {p['orient']}")
    return "\n".join(lines)
