"""How well does Difference-of-Normals segmentation find labelled classes and objects?

    python tools/eval_segments.py FILE.las|laz|pcd [FILE ...] [--city N] [--seed 0]
        [--rs 0.2] [--rl 2.0] [--threshold 0.25] [--tolerance 0.2]
        [--min-points 50] [--max-points M] [--mode fast|exact]
        [--axis x|y|z --axis-threshold T] [--out FILE [--append]]

Each input is segmented with :func:`patchcloud.core.difference_of_normals`
and :func:`patchcloud.core.segment_don` (one parameter set per run, the same
for every input), then scored against its ground-truth labels.  Inputs:

``FILE.las`` / ``FILE.laz``
    Read with ``laspy.read``; coordinates in float64 minus their minimum;
    truth = ``classification``; object ids from an extra dimension
    ``ObjectId`` when the file has one (files written by ``city_las.py`` do),
    otherwise no object-level scores (n/a).
``FILE.pcd``
    An ISPRS filter-test sample (``sampNN-utm.pcd``, ``DATA
    binary_compressed``) with its manually labelled ground subset
    ``sampNN-utm-ground.pcd`` beside it: truth = 2 (ground) for the points
    whose xyz is bit-identical to a point of the ground file, 1 (non-ground)
    otherwise.  LZF decompression uses the ``lzf`` package when it is
    importable (python-lzf), else the small pure-Python decompressor here
    (about 0.1 s for an ISPRS sample).
``--city N``
    The first ``N`` points of the synthetic city of ``city_las.py`` (seed
    ``--seed``), generated in memory; truth = its classes (2 ground, 5 tree,
    6 building, 64 pole, 65 car), objects = its ``object_id`` (0 = none).

Definitions
-----------
- *kept*: share of a class's points whose DoN magnitude passes the
  threshold (:func:`patchcloud.core.don_mask`), before clustering;
  *in segs*: share that ends up in a segment (clusters of at least
  ``--min-points`` and at most ``--max-points`` points); *DoN undef*: share
  whose DoN is undefined (too few points in one of the two balls), which
  are never kept.
- Every segment takes the *majority* ground-truth class of its points (ties:
  the smallest class code).
- Per class c: *precision* = points of class c in segments labelled c /
  points in segments labelled c (undefined, "-", when no segment is labelled
  c); *recall* = points of class c in segments labelled c / points of class c.
- *Object recall* (where object ids exist): an object counts as *found* when
  more than 50 % of its points fall in one single segment; per class (the
  majority class of the object's points) the number of objects with at least
  ``--min-points`` points and the share of them found.  The table also gives
  the number of objects whose DoN is defined on more than half their points
  (the others cannot be found) and the median over objects of the largest
  share of an object in one segment.

Examples (the runs of ``tools/results/eval_segments-2026-11-22.txt``)::

    python tools/eval_segments.py --city 1000000                     # defaults: mobile-mapping scales
    python tools/eval_segments.py --city 4000000 --rs 0.4 --rl 4 --tolerance 0.35
    python tools/eval_segments.py ../shared/data/lidar-lastools/house.laz --rs 1 --rl 5 --tolerance 1
    python tools/eval_segments.py ../shared/data/labelled-isprs-filtertest/samp11-utm.pcd \
        --rs 2 --rl 10 --tolerance 2 --min-points 20

Airborne data (1-35 points/m2) need radii that hold enough points: with
``rs`` below about twice the point spacing most DoN values are undefined
(the "DoN undef" column says so).

All scores are pure functions of arrays (:func:`majority_labels`,
:func:`class_scores`, :func:`object_scores`, :func:`object_recall`).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

DEFINITIONS = """\
Definitions: each segment takes the majority ground-truth class of its points (ties: smallest code).
Per class c: precision = points of c in segments labelled c / points in segments labelled c ("-" if none);
recall = points of c in segments labelled c / points of c; kept = share of c's points whose DoN magnitude
passes the threshold (before clustering); in segs = share of c's points in any segment (after the size limits);
DoN undef = share of c's points whose DoN is undefined (too few points within r_small or r_large: never kept).
Object recall: an object (object id > 0, at least min_points points) is found when more than 50 % of its
points fall in one single segment; its class is the majority class of its points; "DoN defined" = objects
whose DoN is defined on more than half of their points (the others cannot be found); "median best" = median
over objects of the largest share of the object in one segment."""

#: ASPRS class names (LAS 1.4, with the IGN LiDAR HD extras 64-67).
ASPRS_NAMES = {
    0: "never classified", 1: "unclassified", 2: "ground", 3: "low vegetation", 4: "medium vegetation",
    5: "high vegetation", 6: "building", 7: "noise", 9: "water", 17: "bridge deck", 18: "high noise",
    64: "IGN other above-ground", 65: "IGN artefact", 66: "IGN virtual", 67: "IGN misc",
}
#: Class names of the synthetic city (city_las.py).
CITY_NAMES = {2: "ground", 5: "tree", 6: "building", 64: "pole", 65: "car"}
#: Class names of the ISPRS filter-test labels.
ISPRS_NAMES = {1: "non-ground", 2: "ground"}


# ----------------------------------------------------------------------------- metrics (pure functions)


def majority_labels(segments: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The majority ground-truth class of every segment.

    Parameters
    ----------
    segments : (N,) int array
        Segment id per point; 0 = in no segment.
    truth : (N,) int array
        Ground-truth class per point.

    Returns
    -------
    seg_ids : (S,) int64
        The segment ids present (> 0), sorted.
    seg_class : (S,) int64
        Majority class of each segment; ties go to the smallest class code.
    predicted : (N,) int64
        The class of each point's segment; -1 for points in no segment.

    Examples
    --------
    >>> s, c, p = majority_labels(np.array([0, 1, 1, 2]), np.array([5, 5, 6, 6]))
    >>> s.tolist(), c.tolist(), p.tolist()
    ([1, 2], [5, 6], [-1, 5, 5, 6])
    """
    seg = np.asarray(segments).astype(np.int64, copy=False).reshape(-1)
    tru = np.asarray(truth).astype(np.int64, copy=False).reshape(-1)
    if seg.shape != tru.shape:
        raise ValueError(f"segments and truth must have one value per point; got {seg.shape} and {tru.shape}")
    predicted = np.full(seg.shape, -1, dtype=np.int64)
    inseg = seg > 0
    if not inseg.any():
        return np.zeros(0, np.int64), np.zeros(0, np.int64), predicted
    seg_ids, si = np.unique(seg[inseg], return_inverse=True)
    classes, ci = np.unique(tru[inseg], return_inverse=True)
    table = np.bincount(si * classes.size + ci, minlength=seg_ids.size * classes.size).reshape(seg_ids.size, classes.size)
    seg_class = classes[np.argmax(table, axis=1)]  # argmax takes the first maximum: the smallest code
    predicted[inseg] = seg_class[si]
    return seg_ids, seg_class, predicted


@dataclass
class ClassScores:
    """Point-level scores per ground-truth class (arrays aligned with ``classes``)."""

    classes: np.ndarray  #: class codes, sorted
    points: np.ndarray  #: points of the class
    undefined: np.ndarray  #: share of them with an undefined DoN (NaN if no mask given)
    kept: np.ndarray  #: share of them kept by the DoN threshold (NaN if no mask given)
    in_segments: np.ndarray  #: share of them in any segment
    segments: np.ndarray  #: number of segments labelled with the class
    precision: np.ndarray  #: NaN where no segment is labelled with the class
    recall: np.ndarray


def class_scores(
    truth: np.ndarray, segments: np.ndarray, kept: np.ndarray | None = None, defined: np.ndarray | None = None,
) -> ClassScores:
    """Per-class precision and recall of the points, segments labelled by majority.

    Parameters
    ----------
    truth : (N,) int array
        Ground-truth class per point.
    segments : (N,) int array
        Segment id per point, 0 = none.
    kept : (N,) bool array, optional
        Points that passed the DoN threshold (for the "kept" share).
    defined : (N,) bool array, optional
        Points whose DoN is defined (for the "undefined" share).

    Returns
    -------
    ClassScores
        One row per class present in ``truth``.

    Examples
    --------
    >>> r = class_scores(np.array([5, 5, 6, 6]), np.array([0, 1, 1, 2]))
    >>> r.precision.tolist(), r.recall.tolist()
    ([0.5, 1.0], [0.5, 0.5])
    """
    tru = np.asarray(truth).astype(np.int64, copy=False).reshape(-1)
    seg_ids, seg_class, predicted = majority_labels(segments, tru)
    classes, ci = np.unique(tru, return_inverse=True)
    k = classes.size
    points = np.bincount(ci, minlength=k)
    inseg = predicted >= 0
    in_segments = np.bincount(ci[inseg], minlength=k) / np.maximum(points, 1)
    shares = []
    for name, mask in (("kept", kept), ("defined", defined)):
        if mask is None:
            shares.append(np.full(k, np.nan))
            continue
        mk = np.asarray(mask, dtype=bool).reshape(-1)
        if mk.shape != tru.shape:
            raise ValueError(f"{name} must have one value per point; got {mk.shape} for {tru.shape[0]} points")
        shares.append(np.bincount(ci[mk], minlength=k) / np.maximum(points, 1))
    kept_share, undefined = shares[0], 1.0 - shares[1]
    correct = np.bincount(ci[predicted == tru], minlength=k)  # predicted == -1 never equals a class
    # points predicted as each class (predicted classes are classes of truth, so searchsorted is exact)
    labelled = np.bincount(np.searchsorted(classes, predicted[inseg]), minlength=k)
    nseg = np.bincount(np.searchsorted(classes, seg_class), minlength=k) if seg_class.size else np.zeros(k, np.int64)
    with np.errstate(invalid="ignore", divide="ignore"):
        precision = np.where(labelled > 0, correct / np.maximum(labelled, 1), np.nan)
    recall = correct / np.maximum(points, 1)
    return ClassScores(classes, points, undefined, kept_share, in_segments, nseg, precision, recall)


@dataclass
class ObjectScores:
    """Per-object scores (arrays aligned with ``ids``)."""

    ids: np.ndarray  #: object ids (> 0) with at least min_points points, sorted
    classes: np.ndarray  #: majority ground-truth class of each object
    points: np.ndarray  #: points of each object
    best_share: np.ndarray  #: largest share of the object's points in one segment (0 if none)
    found: np.ndarray  #: best_share > share
    defined: np.ndarray  #: share of the object's points with a defined DoN (NaN if no mask given)


def object_scores(
    object_ids: np.ndarray, segments: np.ndarray, truth: np.ndarray, *, min_points: int = 1, share: float = 0.5,
    defined: np.ndarray | None = None,
) -> ObjectScores:
    """Which objects fall mostly in one segment.

    Parameters
    ----------
    object_ids : (N,) int array
        Object id per point; 0 = in no object (ground, say).
    segments : (N,) int array
        Segment id per point, 0 = none.
    truth : (N,) int array
        Ground-truth class per point (an object's class is its majority).
    min_points : int
        Objects with fewer points are left out.
    share : float
        An object is found when strictly more than this share of its points
        lies in one segment.
    defined : (N,) bool array, optional
        Points whose DoN is defined (for each object's defined share).

    Returns
    -------
    ObjectScores

    Examples
    --------
    >>> o = object_scores(np.array([1, 1, 1, 2, 2]), np.array([3, 3, 0, 4, 5]), np.array([6, 6, 6, 5, 5]))
    >>> o.ids.tolist(), o.found.tolist()
    ([1, 2], [True, False])
    """
    oid = np.asarray(object_ids).astype(np.int64, copy=False).reshape(-1)
    seg = np.asarray(segments).astype(np.int64, copy=False).reshape(-1)
    tru = np.asarray(truth).astype(np.int64, copy=False).reshape(-1)
    if not (oid.shape == seg.shape == tru.shape):
        raise ValueError(f"object_ids, segments and truth must have one value per point; got {oid.shape}, {seg.shape}, {tru.shape}")
    obj = oid > 0
    if not obj.any():
        z = np.zeros(0, np.int64)
        return ObjectScores(z, z, z, np.zeros(0), np.zeros(0, bool), np.zeros(0))
    ids, oi = np.unique(oid[obj], return_inverse=True)
    points = np.bincount(oi, minlength=ids.size)
    # majority class per object
    _, oclass, _ = majority_labels(oi + 1, tru[obj])
    # largest count of one object in one segment: count (object, segment) pairs
    s = seg[obj]
    ins = s > 0
    pair = oi[ins] * (int(s.max()) + 1) + s[ins]
    keys, counts = np.unique(pair, return_counts=True)
    best = np.zeros(ids.size, dtype=np.int64)
    np.maximum.at(best, keys // (int(s.max()) + 1), counts)
    best_share = best / points
    if defined is None:
        dshare = np.full(ids.size, np.nan)
    else:
        df = np.asarray(defined, dtype=bool).reshape(-1)
        if df.shape != oid.shape:
            raise ValueError(f"defined must have one value per point; got {df.shape} for {oid.shape[0]} points")
        dshare = np.bincount(oi[df[obj]], minlength=ids.size) / points
    big = points >= min_points
    return ObjectScores(ids[big], oclass[big], points[big], best_share[big], best_share[big] > share, dshare[big])


def object_recall(scores: ObjectScores) -> tuple[np.ndarray, ...]:
    """Per class: number of objects, number found, share found, median best share, objects mostly defined.

    Returns
    -------
    classes, objects, found : (K,) int64
    recall, median_best : (K,) float64
    measurable : (K,) int64
        Objects whose DoN is defined on more than half of their points
        (all of them when ``scores.defined`` is NaN).
    """
    classes, ci = np.unique(scores.classes, return_inverse=True)
    objects = np.bincount(ci, minlength=classes.size)
    found = np.bincount(ci[scores.found], minlength=classes.size)
    median_best = np.array([np.median(scores.best_share[ci == k]) for k in range(classes.size)])  # a loop per class
    measurable = np.bincount(ci[~(scores.defined <= 0.5)], minlength=classes.size)  # NaN counts as measurable
    return classes, objects, found, found / np.maximum(objects, 1), median_best, measurable


# ----------------------------------------------------------------------------- inputs


@dataclass
class Labelled:
    """A labelled cloud: local float64 coordinates, truth classes, optional object ids."""

    name: str
    points: np.ndarray
    truth: np.ndarray
    object_ids: np.ndarray | None
    class_names: dict
    note: str = ""


def _lzf_decompress_py(src: bytes, out_len: int) -> bytes:
    """LZF (liblzf) decompression in pure Python, one token (literal run or back reference) at a time."""
    out = bytearray()
    ip, n = 0, len(src)
    while ip < n:
        ctrl = src[ip]
        ip += 1
        if ctrl < 32:  # literal run of ctrl + 1 bytes
            ln = ctrl + 1
            if ip + ln > n:
                raise ValueError("corrupt LZF block: literal run past the end of the input")
            out += src[ip:ip + ln]
            ip += ln
            continue
        ln = ctrl >> 5  # back reference: length (3 bits, + one byte if 7) and a 13-bit distance
        if ln == 7:
            ln += src[ip]
            ip += 1
        if ip >= n:
            raise ValueError("corrupt LZF block: back reference past the end of the input")
        dist = ((ctrl & 0x1F) << 8) + src[ip] + 1
        ip += 1
        ln += 2
        ref = len(out) - dist
        if ref < 0:
            raise ValueError("corrupt LZF block: back reference before the start of the output")
        if dist >= ln:
            out += out[ref:ref + ln]
        else:  # overlapping: the last dist bytes repeat
            pat = bytes(out[ref:])
            out += (pat * (ln // dist + 1))[:ln]
    if len(out) != out_len:
        raise ValueError(f"corrupt LZF block: decompressed to {len(out)} bytes, expected {out_len}")
    return bytes(out)


def lzf_decompress(data: bytes, out_len: int) -> bytes:
    """Decompress one LZF block to ``out_len`` bytes (with python-lzf when importable, else in pure Python).

    Examples
    --------
    >>> lzf_decompress(bytes([2]) + b"abc" + bytes([(2 << 5) | 0, 2]), 7)
    b'abcabca'
    """
    try:
        import lzf  # python-lzf

        res = lzf.decompress(data, out_len)
        if res is not None and len(res) == out_len:
            return res
    except ImportError:
        pass
    return _lzf_decompress_py(bytes(data), int(out_len))


def read_pcd_xyz(path: str | Path) -> np.ndarray:
    """(N, 3) float32 xyz of a PCD file with fields x y z (``DATA ascii``, ``binary`` or ``binary_compressed``)."""
    raw = Path(path).read_bytes()
    header: dict[str, list[str]] = {}
    pos = 0
    while True:
        end = raw.index(b"\n", pos)
        line = raw[pos:end].decode("ascii").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *vals = line.split()
        header[key.upper()] = vals
        if key.upper() == "DATA":
            break
    fields, sizes, types = header["FIELDS"], [int(s) for s in header["SIZE"]], header["TYPE"]
    counts = [int(c) for c in header.get("COUNT", ["1"] * len(fields))]
    n = int(header["POINTS"][0])
    if fields[:3] != ["x", "y", "z"] or sizes[:3] != [4, 4, 4] or types[:3] != ["F"] * 3 or counts[:3] != [1, 1, 1]:
        raise ValueError(f"{path}: expected float32 fields x y z first, got {fields} {sizes} {types}")
    kind = header["DATA"][0]
    if kind == "ascii":
        return np.loadtxt(raw[pos:].decode("ascii").splitlines(), dtype=np.float32, ndmin=2)[:, :3]
    dtype = np.dtype([(f"f{i}", f"<{'f' if t == 'F' else 'i' if t == 'I' else 'u'}{s}", (c,))
                      for i, (s, t, c) in enumerate(zip(sizes, types, counts))])
    if kind == "binary":
        rec = np.frombuffer(raw, dtype=dtype, count=n, offset=pos)
        return np.column_stack([rec[f"f{i}"][:, 0] for i in range(3)]).astype(np.float32)
    if kind != "binary_compressed":
        raise ValueError(f"{path}: unknown PCD DATA {kind!r}")
    csize, usize = np.frombuffer(raw, dtype="<u4", count=2, offset=pos)
    data = lzf_decompress(raw[pos + 8:pos + 8 + int(csize)], int(usize))
    # column-major: all values of field 0, then field 1, ...
    cols, off = [], 0
    for s, t, c in zip(sizes, types, counts):
        width = s * c * n
        cols.append(data[off:off + width])
        off += width
    return np.column_stack([np.frombuffer(cols[i], dtype="<f4", count=n) for i in range(3)])


def _member(rows: np.ndarray, of: np.ndarray) -> np.ndarray:
    """Rows of ``rows`` bit-identical to some row of ``of`` (both (N, 3) float32)."""
    a = np.ascontiguousarray(rows, dtype=np.float32).view(np.uint32)
    b = np.ascontiguousarray(of, dtype=np.float32).view(np.uint32)
    _, inv = np.unique(np.concatenate([a, b]), axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    return np.isin(inv[: a.shape[0]], inv[a.shape[0]:])


def load_isprs(path: str | Path) -> Labelled:
    """An ISPRS filter-test sample: all points, truth 2 where the point is in the ``-ground.pcd`` file, else 1."""
    p = Path(path)
    gpath = p.with_name(p.name[:-4] + "-ground.pcd")
    if not gpath.exists():
        raise FileNotFoundError(f"{p}: no ground file {gpath.name} beside it")
    xyz = read_pcd_xyz(p)
    ground = read_pcd_xyz(gpath)
    truth = np.where(_member(xyz, ground), 2, 1).astype(np.int64)
    pts = xyz.astype(np.float64)
    note = f"ground file {gpath.name}: {ground.shape[0]:,} points, {int((truth == 2).sum()):,} of the cloud's points match one"
    return Labelled(p.name, pts - pts.min(axis=0), truth, None, ISPRS_NAMES, note)


def load_las(path: str | Path) -> Labelled:
    """A LAS/LAZ file: float64 coordinates minus the minimum, ``classification``, ``ObjectId`` if present."""
    import laspy

    las = laspy.read(str(path))
    pts = np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)])
    extra = list(las.point_format.extra_dimension_names)
    oid = np.asarray(las["ObjectId"]).astype(np.int64) if "ObjectId" in extra else None
    note = f"LAS {las.header.version} point format {las.point_format.id}; object ids: " + ("ObjectId" if oid is not None else "none (n/a)")
    return Labelled(Path(path).name, pts - pts.min(axis=0), np.asarray(las.classification).astype(np.int64), oid, ASPRS_NAMES, note)


def load_city(n: int, seed: int = 0) -> Labelled:
    """The first ``n`` points of the synthetic city (``city_las.iter_city_chunks``), in memory."""
    here = str(Path(__file__).resolve().parent)
    if here not in sys.path:
        sys.path.insert(0, here)
    from city_las import iter_city_chunks

    chunks = list(iter_city_chunks(int(n), seed=int(seed)))
    cat = {k: np.concatenate([c[k] for c in chunks]) for k in ("x", "y", "z", "classification", "object_id")}
    pts = np.column_stack([cat["x"], cat["y"], cat["z"]])
    return Labelled(f"synthetic city, first {n:,} points (seed {seed})", pts - pts.min(axis=0),
                    cat["classification"].astype(np.int64), cat["object_id"].astype(np.int64), CITY_NAMES,
                    "objects: city_las object_id (0 = ground, no object)")


def load(path: str | Path) -> Labelled:
    """Load a ``.las``/``.laz`` file or an ISPRS ``.pcd`` sample."""
    return load_isprs(path) if str(path).lower().endswith(".pcd") else load_las(path)


# ----------------------------------------------------------------------------- report


def _pct(v: float) -> str:
    return "-" if not np.isfinite(v) else f"{100.0 * v:.1f} %"


def _name(names: dict, c: int) -> str:
    return f"{c} {names.get(int(c), '')}".rstrip()


def parameter_line(a: argparse.Namespace) -> str:
    """The one-line description of the parameters of a run."""
    ax = "none" if a.axis is None else f"{a.axis} >= {a.axis_threshold:g}"
    return (f"parameters: rs={a.rs:g} m, rl={a.rl:g} m, threshold={a.threshold:g}, tolerance={a.tolerance:g} m, "
            f"min_points={a.min_points}, max_points={a.max_points if a.max_points is not None else 'none'}, "
            f"mode={a.mode}, axis={ax}, viewpoint=default (above the middle of the cloud)")


def evaluate(cloud: Labelled, a: argparse.Namespace) -> str:
    """Segment one labelled cloud and format its tables (markdown)."""
    from patchcloud.core import difference_of_normals, don_mask, segment_don

    t0 = time.perf_counter()
    don = difference_of_normals(cloud.points, a.rs, a.rl, mode=a.mode)
    t1 = time.perf_counter()
    seg = segment_don(cloud.points, don, a.threshold, a.tolerance, min_points=a.min_points, max_points=a.max_points,
                      axis=a.axis, axis_threshold=a.axis_threshold)
    t2 = time.perf_counter()
    kept = don_mask(don, a.threshold, axis=a.axis, axis_threshold=a.axis_threshold)
    n = cloud.points.shape[0]
    ext = cloud.points.max(axis=0) if n else np.zeros(3)
    defined = ~np.isnan(don).any(axis=1)
    cs = class_scores(cloud.truth, seg, kept, defined)
    lines = [
        f"## {cloud.name}",
        "",
        parameter_line(a),
        f"{n:,} points, extent {ext[0]:.0f} x {ext[1]:.0f} x {ext[2]:.0f} m; {cloud.note}",
        f"DoN undefined for {_pct(np.isnan(don[:, 0]).mean())}, kept by the threshold {_pct(kept.mean())}; "
        f"{int(seg.max()):,} segments holding {_pct((seg > 0).mean())} of the points; "
        f"DoN {t1 - t0:.1f} s, segmentation {t2 - t1:.1f} s",
        "",
        "| class | points | DoN undef | kept | in segs | segments | precision | recall |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for i, c in enumerate(cs.classes):
        lines.append(f"| {_name(cloud.class_names, c)} | {cs.points[i]:,} | {_pct(cs.undefined[i])} | {_pct(cs.kept[i])} | {_pct(cs.in_segments[i])} | "
                     f"{cs.segments[i]:,} | {_pct(cs.precision[i])} | {_pct(cs.recall[i])} |")
    lines.append("")
    if cloud.object_ids is None:
        lines.append("object recall: n/a (no object ids)")
    else:
        os_ = object_scores(cloud.object_ids, seg, cloud.truth, min_points=a.min_points, defined=defined)
        classes, objects, found, recall, median_best, measurable = object_recall(os_)
        lines += [f"| object class | objects (>= {a.min_points} pts) | DoN defined | found | object recall | median best |",
                  "| --- | ---: | ---: | ---: | ---: | ---: |"]
        for i, c in enumerate(classes):
            lines.append(f"| {_name(cloud.class_names, c)} | {objects[i]:,} | {measurable[i]:,} | {found[i]:,} | "
                         f"{_pct(recall[i])} | {_pct(median_best[i])} |")
    lines.append("")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """The command line."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="*", type=Path, help="LAS/LAZ files or ISPRS sampNN-utm.pcd samples")
    ap.add_argument("--city", type=int, action="append", default=[], metavar="N",
                    help="also the first N points of the synthetic city (repeatable)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the synthetic city (default 0)")
    ap.add_argument("--rs", type=float, default=0.2, help="small DoN radius, m (default 0.2)")
    ap.add_argument("--rl", type=float, default=2.0, help="large DoN radius, m (default 2.0)")
    ap.add_argument("--threshold", type=float, default=0.25, help="DoN magnitude threshold (default 0.25)")
    ap.add_argument("--tolerance", type=float, default=0.2, help="clustering tolerance, m (default 0.2)")
    ap.add_argument("--min-points", type=int, default=50, help="smallest segment, and smallest object scored (default 50)")
    ap.add_argument("--max-points", type=int, default=None, help="largest segment (default none)")
    ap.add_argument("--mode", choices=("fast", "exact"), default="fast", help="radius normals mode (default fast)")
    ap.add_argument("--axis", choices=("x", "y", "z"), default=None, help="also threshold |DoN| along this axis")
    ap.add_argument("--axis-threshold", type=float, default=None, help="threshold for --axis")
    ap.add_argument("--title", default=None, help="a line to print under the header (what this run is for)")
    ap.add_argument("--out", type=Path, default=None, help="also write the text to this file")
    ap.add_argument("--append", action="store_true", help="append to --out instead of overwriting it")
    return ap


def main(argv: list[str] | None = None) -> int:
    """Run the evaluation; returns the exit code."""
    a = build_parser().parse_args(argv)
    if not a.files and not a.city:
        build_parser().error("give at least one FILE or --city N")
    head = ["# eval_segments: DoN segmentation against ground-truth labels", "", parameter_line(a)]
    if a.title:
        head.append(a.title)
    head += ["", DEFINITIONS, ""]
    text = "\n".join(head)
    print(text, flush=True)
    parts = [text]
    clouds = [lambda n=n: load_city(n, a.seed) for n in a.city] + [lambda f=f: load(f) for f in a.files]
    for make in clouds:
        t = evaluate(make(), a)
        print(t, flush=True)
        parts.append(t)
    if a.out is not None:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        with open(a.out, "a" if a.append else "w", encoding="utf-8") as fh:
            fh.write("\n".join(parts) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
