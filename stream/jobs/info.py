"""``info``: what a LAS/LAZ file, a patchcloud store or a .pcz holds."""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import laspy
import numpy as np

from patchcloud.core import PatchcloudError, PatchcloudIOError, PatchcloudValueError

from patchcloud.stream.io.classes import MAX_CLASS, REASONS, Selection, classification_and_withheld
from patchcloud.stream.io.crs import crs_description, units_of
from patchcloud.stream.io.dims import DECOMPRESS_DIMS, NORMALS_DIMS, PRINCIPAL_DIMS, SEGMENT_DIMS
from patchcloud.stream.io.las import LasSource, open_source, read_chunks
from patchcloud.stream.engine.background import stops_what_it_starts

__all__ = ["info", "format_info", "crs_line", "class_counts", "patchcloud_dims", "PATCHCLOUD_DIMS", "CLASS_NAMES"]

#: The dimensions each patchcloud command writes (``patchcloud info`` says which of them a file holds).
PATCHCLOUD_DIMS = {
    "normals": tuple(d[0] for d in NORMALS_DIMS),
    "normals --principal-curvatures": tuple(d[0] for d in PRINCIPAL_DIMS),
    "don": tuple(d[0] for d in SEGMENT_DIMS[:-1]),
    "segment": (SEGMENT_DIMS[-1][0],),
    "decompress": tuple(d[0] for d in DECOMPRESS_DIMS),
}
#: ASPRS names of the standard classes (LAS 1.4 R15, table 17).
CLASS_NAMES = {
    0: "never classified", 1: "unclassified", 2: "ground", 3: "low vegetation", 4: "medium vegetation", 5: "high vegetation",
    6: "building", 7: "low point (noise)", 8: "model key point", 9: "water", 10: "rail", 11: "road surface",
    12: "overlap", 13: "wire guard", 14: "wire conductor", 15: "transmission tower", 16: "wire connector",
    17: "bridge deck", 18: "high noise",
}
_CHUNK = 1 << 20



def _span(values) -> list[int]:
    """The smallest and largest of some integers ([0, 0] for none)."""
    values = [int(v) for v in values] or [0]
    return [min(values), max(values)]


def _residual_coding(d: dict) -> str:
    """What a model-mode ``.pcz`` (:func:`describe`'s ``d``) keeps of its residual points' attributes."""
    if d["version"] < 5:
        return "every attribute not dropped exact, in input order"
    from patchcloud.stream.io.residual_points import kept_words  # (numba: only for a .pcz)

    return kept_words(d.get("dropped", []), tuple(d.get("intensity_shifts", [0, 0])))


def class_counts(src: LasSource) -> tuple[dict[int, int], int]:
    """Points of each class present (code: count) and the withheld points of a file, read in chunks of 2^20 points."""
    by_class = np.zeros(MAX_CLASS + 1, dtype=np.int64)
    withheld = 0
    for _, pts in read_chunks(src, _CHUNK):
        cls, wh = classification_and_withheld(pts.array)
        by_class += np.bincount(cls, minlength=MAX_CLASS + 1)
        withheld += int(wh.sum())
    return {int(c): int(n) for c, n in enumerate(by_class) if n}, withheld


def patchcloud_dims(names) -> dict[str, list[str]]:
    """Which patchcloud dimensions ``names`` (a file's extra dimensions) holds, by the command that writes them.

    >>> patchcloud_dims(["Deviation", "NormalX", "NormalY", "NormalZ", "Curvature", "NormalMethod", "PatchId"])
    {'normals': ['NormalX', 'NormalY', 'NormalZ', 'Curvature', 'NormalMethod', 'PatchId']}
    """
    names = set(names)
    found = {job: [d for d in dims if d in names] for job, dims in PATCHCLOUD_DIMS.items()}
    return {job: d for job, d in found.items() if d}


@stops_what_it_starts()  # no thread of the run's left running (stream.engine.background)
def info(path: str | os.PathLike) -> dict:
    """A description of a LAS/LAZ file, a store (source, grid, tiles, steps done) or a .pcz (counts).

    A LAS/LAZ file: its header (point format, count, bounds, scale and
    offset, CRS), its dimensions, the patchcloud dimensions it holds (by the
    command that writes them), and the classes present with their counts and
    the withheld points (which reads every point, in chunks).  A store: the
    classes of its input and the points its tiles leave out.

    Raises
    ------
    PatchcloudIOError
        ``path`` is neither a readable LAS/LAZ file nor a patchcloud store.

    Examples
    --------
    >>> d = info(sample)
    >>> d["kind"], d["point_count"], d["point_format"]
    ('las', 60653, 8)
    >>> d["classes"], d["withheld"], d["patchcloud_dimensions"]
    ({'1': 581, '2': 22343, '3': 2497, '4': 2449, '5': 17875, '6': 14908}, 0, {})
    """
    p = str(path)
    if os.path.isfile(p) and (zipfile.is_zipfile(p) or p.lower().endswith(".pcz") or _starts_as_zip(p)):  # (a truncated
        # zip has no central directory: still a .pcz, which open_pcz says is truncated)
        from patchcloud.stream.io.pcz import open_pcz  # what a .pcz and a store need (zarr, numba) only for them

        with open_pcz(p) as f:
            a = f.attrs
            return {"kind": "pcz", "path": p, "bytes": os.path.getsize(p), "version": a["version"],
                    "mode": a.get("mode", "model"), "max_error": a["max_error"], "counts": a["counts"], "source": a["source"],
                    "grid": a["grid"], "steps": list(f.steps), "dropped": f.dropped,
                    **({"intensity_shifts": _span(f.intensity_shift)} if hasattr(f, "intensity_shift") else {})}
    if os.path.isfile(p):
        src = open_source(p, allow_empty=True)  # an empty tile is described as any file (0 points)
        with laspy.open(p) as r:
            dims = list(r.header.point_format.dimension_names)
            extra = list(r.header.point_format.extra_dimension_names)
        classes, withheld = class_counts(src)
        bounds = {} if src.point_count else {"mins": None, "maxs": None}  # an empty file's header bounds bound nothing
        return {"kind": "las", **src.to_json(), **bounds, "dimensions": dims, "extra_dimensions": extra,
                "crs_info": _crs_info(src.crs, src.crs_error),
                "classes": {str(c): n for c, n in classes.items()}, "withheld": withheld, "patchcloud_dimensions": patchcloud_dims(extra)}
    from patchcloud.stream.io.store import Store

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
            "classes": a.get("classes"), "selection": a.get("selection"), "left_out": a.get("left_out"),
            "crs_info": _crs_info((a.get("catalog") or {}).get("crs") or (a.get("source") or {}).get("crs")),
            "files": [dict(path=f.get("path"), point_count=int(f.get("point_count", 0))) for f in (a.get("catalog") or {}).get("sources", [])],
            "unit": _store_unit(a),
        }
    if "://" not in str(p) and not Path(p).exists():
        raise PatchcloudIOError(f"{p}: no such file")  # as every other command says
    raise PatchcloudIOError(f"{p}: neither a LAS/LAZ file nor a patchcloud store")


def _store_unit(attrs: dict) -> str:
    """The symbol of the unit a store's lengths are in, from its files' CRS (as a run finds it; "(the file's unit)"
    where that cannot be said: a CRS refused without --units)."""
    src = attrs.get("source") or {}
    crs = (attrs.get("catalog") or {}).get("crs") or src.get("crs")
    try:  # (`tile --units`: the unit asked for, as the jobs on the store take it)
        return units_of(crs, src.get("mins", (0.0, 0.0)), src.get("maxs", (0.0, 0.0)), attrs.get("units_asked")).symbol
    except PatchcloudError:
        return "(the file's unit)"


def _starts_as_zip(path: str) -> bool:
    """Whether a file begins with a zip entry's signature (a ``.pcz``, whole or not)."""
    with open(path, "rb") as f:
        return f.read(4) == b"PK\x03\x04"


def _crs_info(wkt: str | None, error: str | None = None) -> dict | None:
    """:func:`patchcloud.stream.io.crs.crs_description` of a CRS (None for none; a CRS pyproj cannot read: its error;
    ``error``: why the file's CRS record could not be read, where it has one but ``wkt`` is None)."""
    if wkt is None:
        return None if error is None else {"label": f"unreadable: its CRS record ({error})", "horizontal_unit": None,
                                           "vertical_unit": None}
    try:
        return crs_description(wkt)
    except Exception as exc:  # a CRS pyproj does not read: say so, the file is still described
        return {"label": f"unreadable ({str(exc)[:80]})", "horizontal_unit": None, "vertical_unit": None}


def crs_line(c: dict | None) -> str:
    """The CRS as ``info`` prints it: EPSG code or name, then the horizontal and vertical units.

    >>> crs_line({"label": "EPSG:2154 (RGF93 v1 / Lambert-93)", "horizontal_unit": ["metre", 1.0], "vertical_unit": ["metre", 1.0]})
    'EPSG:2154 (RGF93 v1 / Lambert-93); units: horizontal metre (1 m), vertical metre (1 m)'
    >>> crs_line({"label": "EPSG:4326 (WGS 84)", "geographic": True, "horizontal_unit": ["degree", 0.0174532925199433],
    ...           "vertical_unit": ["degree", 0.0174532925199433]})
    'EPSG:4326 (WGS 84); units: horizontal degree (geographic: lengths need a projected CRS, or --units m|ft|us-ft)'
    >>> crs_line(None)
    'none (distances are taken in metres unless --units says otherwise)'
    """
    if c is None:
        return "none (distances are taken in metres unless --units says otherwise)"
    if not c.get("horizontal_unit"):
        return c["label"]
    if c.get("geographic"):  # degrees are angles, not lengths: no factor to metres, and no vertical unit from them
        return f"{c['label']}; units: horizontal degree (geographic: lengths need a projected CRS, or --units m|ft|us-ft)"
    (hn, hf), (vn, vf) = c["horizontal_unit"], c["vertical_unit"]
    name = {"foot": "international foot"}  # pyproj's "foot" is 0.3048 m; "US survey foot" says itself
    return f"{c['label']}; units: horizontal {name.get(hn, hn)} ({hf:g} m), vertical {name.get(vn, vn)} ({vf:g} m)"


def _class_lines(classes: dict | None, points: int) -> list[str]:
    """``info``'s lines of the classes present: code, ASPRS name, count and share, one per line.

    >>> print("\\n".join(_class_lines({"2": 75, "7": 25}, 100)))
      classes      2 ground                        75  75.0%
                   7 low point (noise)             25  25.0%
    """
    if not classes:
        return []
    out = []
    for k, (c, n) in enumerate(sorted(classes.items(), key=lambda kv: int(kv[0]))):
        name = CLASS_NAMES.get(int(c), "user defined" if int(c) >= 64 else "reserved")
        out.append(f"  {'classes' if k == 0 else '':<11}{int(c):>3} {name:<20}{n:>12,} {n / max(points, 1):>6.1%}")
    return out


def format_info(d: dict) -> str:
    """``info``'s dictionary as a few lines of text.

    Examples
    --------
    >>> print(format_info(info(sample)))                # doctest: +ELLIPSIS
    /...test_data_77055_627760_LA93_IGN69.laz: LAS 1.4 point format 8 (LAZ)
      points       60,653
    ...
    """
    if not isinstance(d, dict) or "kind" not in d:
        raise PatchcloudValueError(f"format_info takes the dictionary info() returns, got {type(d).__name__} "
                                   f"{sorted(d)[:3] if isinstance(d, dict) else ''}".rstrip())
    if d["kind"] == "pcz":
        c = d["counts"]
        n = max(c["points"], 1)
        head = [
            f"{d['path']}: patchcloud .pcz version {d['version']} ({d.get('mode', 'model')} mode), {d['bytes']:,} bytes "
            f"({8 * d['bytes'] / n:.2f} bits/point)",
            f"  source       {d['source'].get('path')} ({d['source'].get('point_count', 0):,} points)",
        ]
        u = d["source"].get("units") or "(the file's unit)"  # recorded since 2026-11-27; older files: not known
        kept = [f"  positions    multiples {', '.join(map(str, d.get('steps', [1, 1, 1])))} of the source's integers",
                f"  dropped      {', '.join(d.get('dropped') or []) or 'none'}"]
        if d.get("mode") == "points":
            return "\n".join([*head, f"  points       {c['points']:,}, every one in input order, in {c['blocks']:,} blocks",
                              f"  max error    {d['max_error']:g} {u}", *kept])
        return "\n".join([
            *head,
            f"  points       {c['points']:,}: {c['points'] - c['residual']:,} on {c['patches']:,} patches ({c.get('cells', 0):,} octree cells), {c['residual']:,} residual",
            f"  max error    {d['max_error']:g} {u}",
            f"  tiles        {c['tiles']:,} of {d['grid']['tile_size']:g} {u}",
            *kept,
            f"  residual     {_residual_coding(d)}",
        ])
    if d["kind"] == "las":
        lines = [
            f"{d['path']}: LAS {d['version']} point format {d['point_format']}{' (LAZ)' if d['compressed'] else ''}",
            f"  points       {d['point_count']:,}",
            f"  bounds       x {d['mins'][0]:.3f} .. {d['maxs'][0]:.3f}, y {d['mins'][1]:.3f} .. {d['maxs'][1]:.3f}, z {d['mins'][2]:.3f} .. {d['maxs'][2]:.3f}"
            if d["point_count"] else "  bounds       none (no points)",
            f"  scale        {d['scale']}  offset {d['offset']}",
            f"  dimensions   {', '.join(d['dimensions'])}",
            f"  CRS          {crs_line(d.get('crs_info'))}",
            *_class_lines(d.get("classes"), d["point_count"]),
            f"  withheld     {d.get('withheld', 0):,}",
            "  patchcloud   " + ("; ".join(f"{job}: {', '.join(dims)}" for job, dims in d["patchcloud_dimensions"].items())
                                  if d.get("patchcloud_dimensions") else "no patchcloud dimensions"),
        ]
        return "\n".join(lines)
    g = d["grid"] or {}
    src = d["source"] or {}
    steps = ", ".join(d["steps"]) or "none"
    done = ", ".join(f"{k} {v}/{d['tiles']}" for k, v in sorted(d["tiles_done"].items())) or "none"
    files = d.get("files") or []
    total = sum(f["point_count"] for f in files) if files else int(src.get("point_count", 0))
    where = (f"{len(files):,} files, {Path(files[0]['path']).name} to {Path(files[-1]['path']).name}" if len(files) > 1
             else src.get("path"))
    lines = [
        f"{d['url']}: patchcloud store",
        f"  source       {where} ({total:,} points)",
        (f"  points       {d['points']:,} in {d['tiles']:,} tiles of {g.get('tile_size', 0):g} {d.get('unit', 'm')} (min/median/max per tile {d['points_per_tile']})"
         if "bucket" in d["steps"] else
         f"  points       not yet in tiles of {g.get('tile_size', 0):g} {d.get('unit', 'm')}: the tiling was stopped while reading the "
         "file (the command that made the store resumes it)"),
        f"  origin       {g.get('origin')}",
        f"  CRS          {crs_line(d.get('crs_info'))}",
        f"  steps done   {steps}",
        f"  tiles done   {done}",
    ]
    lines += _class_lines(d.get("classes"), total or d["points"])
    if d.get("selection") is not None:
        left = d.get("left_out") or {}
        lines.append(f"  points of    {Selection.from_json(d['selection']).describe()}; left out "
                     + ", ".join(f"{r} {int(left.get(r, 0)):,}" for r in REASONS))
    if d.get("parameters"):
        p = d["parameters"]
        lines.append(f"  parameters   {p['criterion']} threshold {p['threshold']:.4g}, d_min {p['d_min']:.3g} {d.get('unit', 'm')}, spacing {p['spacing']:.3g} {d.get('unit', 'm')}, orient {p['orient']}")
    return "\n".join(lines)
