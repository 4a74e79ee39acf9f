"""``info``: what a LAS/LAZ file, a patchcloud store or a .pcz holds."""

from __future__ import annotations

import os
import zipfile

import laspy
import numpy as np

from patchcloud.core import PatchcloudIOError

from patchcloud.stream.io.crs import crs_description
from patchcloud.stream.io.las import open_source
from patchcloud.stream.io.pcz import open_pcz
from patchcloud.stream.io.store import Store
from patchcloud.stream.engine.background import stops_what_it_starts

__all__ = ["info", "format_info", "crs_line"]


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
        return {"kind": "las", **src.to_json(), "dimensions": dims, "extra_dimensions": extra, "crs_info": _crs_info(src.crs)}
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
            "crs_info": _crs_info((a.get("catalog") or {}).get("crs") or (a.get("source") or {}).get("crs")),
        }
    raise PatchcloudIOError(f"{p}: neither a LAS/LAZ file nor a patchcloud store")


def _crs_info(wkt: str | None) -> dict | None:
    """:func:`patchcloud.stream.io.crs.crs_description` of a CRS (None for none; a CRS pyproj cannot read: its error)."""
    if wkt is None:
        return None
    try:
        return crs_description(wkt)
    except Exception as exc:  # a CRS pyproj does not read: say so, the file is still described
        return {"label": f"unreadable ({str(exc)[:80]})", "horizontal_unit": None, "vertical_unit": None}


def crs_line(c: dict | None) -> str:
    """The CRS as ``info`` prints it: EPSG code or name, then the horizontal and vertical units.

    >>> crs_line({"label": "EPSG:2154 (RGF93 v1 / Lambert-93)", "horizontal_unit": ["metre", 1.0], "vertical_unit": ["metre", 1.0]})
    'EPSG:2154 (RGF93 v1 / Lambert-93); units: horizontal metre (1 m), vertical metre (1 m)'
    >>> crs_line(None)
    'none (distances are taken in metres unless --units says otherwise)'
    """
    if c is None:
        return "none (distances are taken in metres unless --units says otherwise)"
    if not c.get("horizontal_unit"):
        return c["label"]
    (hn, hf), (vn, vf) = c["horizontal_unit"], c["vertical_unit"]
    name = {"foot": "international foot"}  # pyproj's "foot" is 0.3048 m; "US survey foot" says itself
    return f"{c['label']}; units: horizontal {name.get(hn, hn)} ({hf:g} m), vertical {name.get(vn, vn)} ({vf:g} m)"


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
            f"  CRS          {crs_line(d.get('crs_info'))}",
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
        f"  CRS          {crs_line(d.get('crs_info'))}",
        f"  steps done   {steps}",
        f"  tiles done   {done}",
    ]
    if d.get("parameters"):
        p = d["parameters"]
        lines.append(f"  parameters   {p['criterion']} threshold {p['threshold']:.4g}, d_min {p['d_min']:.3g} m, spacing {p['spacing']:.3g} m, orient {p['orient']}")
    return "\n".join(lines)
