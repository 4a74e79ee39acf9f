"""How patchcloud's normals are made on real aerial LiDAR, and how good they are per ASPRS class.

    python tools/bench_fallback.py [--files PATH ...] [--save RUN.npz] [--baseline OLD.npz] [--results OUT.txt] [--workers 1]

For each file (default: the aerial LAS/LAZ of ../shared/data listed in
:data:`DEFAULT_FILES` and the embedded IGN tile of data/):

1. patchcloud's normals: ``patchcloud.core.estimate_normals`` with the
   options ``patchcloud normals`` uses by default (``NormalsOptions()``:
   rmse criterion, threshold from the data, orient up, blend), on float64
   coordinates minus the cloud's minimum corner; each point's normal and
   its ``NormalMethod`` code (:class:`patchcloud.core.Method`; whatever codes
   appear are printed by their enum name, so codes added later show up).
   The compiled kernels are warmed up on a small cloud first.  (The command
   itself, ``patchcloud normals``, resolves the point spacing and the RMSE
   threshold from its tiles, not from one in-memory octree: its thresholds,
   and so its method shares, can differ from these.)
2. A reference normal per point: the PCA normal of the points of the SAME
   ASPRS class within a ball around it (radius 1 m, 2 m for ground, class 2;
   the point itself included), from a scipy ``cKDTree`` per class.  A point
   with fewer than 3 other same-class points in its ball has no reference
   and is left out of the angles (counted in the ``no ref`` column).
3. One table: per file, its points, the seconds of patchcloud and of the
   reference, and the share of each method; per (file, class group), with
   ground = 2, building = 6, vegetation = 3/4/5, other = every other class:
   the points with a reference, and per method the count and the median
   unoriented angle (degrees, ``acos |n . ref|``) to the reference ("all":
   every method together).  The last rows pool all files.

``--save RUN.npz`` keeps every file's normals, methods, reference normals
and classes; ``--baseline OLD.npz`` compares this run with a saved one: for
the points whose method changed from the k-NN fallback (``Method.KNN``) to
another code, per file and class group, their count and the median angle to
the reference of their baseline (k-NN) normals and of today's normals, by
new method.  This shows whether points that leave the k-NN fallback are no
further from the same-class ball PCA than their k-NN normals were.

``--results OUT.txt`` also writes the printed tables there, the command line
at the top.  ``--workers`` (default 1) is the threads of the numeric work:
1 runs patchcloud's compiled kernels sequentially (``single_threaded``) and
scipy's searches on one thread (patchcloud's own k-NN search still uses
``workers=-1``); set ``NUMBA_NUM_THREADS=1`` too to keep numba's pool at one
thread.  A missing data directory is reported and the run exits 0.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SHARED = ROOT.parent / "shared" / "data"
SAMPLE = ROOT / "data" / "test_data_77055_627760_LA93_IGN69.laz"
#: Files of ../shared/data measured by default (globs relative to it), then the embedded sample.
DEFAULT_FILES = (
    "lidar-ign-stbarth/*.laz",
    "lidar-lastools/fusa.laz",
    "lidar-lastools/house.laz",
    "lidar-ign-extrabytes/*.laz",
    "lidar-ign-km-tile-decimated/*.laz",
    "lidar-ign-lidarhd-tiles/*.laz",
)
#: Class groups of the table: name and ASPRS codes (None: every code of no other group).
GROUPS = (("ground", (2,)), ("building", (6,)), ("vegetation", (3, 4, 5)), ("other", None))
#: Radius of the reference ball (metres) per ASPRS class; classes not listed use ``RADIUS``.
RADIUS = 1.0
RADIUS_BY_CLASS = {2: 2.0}
#: A reference needs at least this many other same-class points in the ball.
MIN_NEIGHBOURS = 3
#: At most this many (query, neighbour) pairs are held at once in the reference computation.
MAX_PAIRS = 4_000_000


# ----------------------------------------------------------------------------- measuring
def read_cloud(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) float64 coordinates minus their minimum corner, and (N,) uint8 ASPRS classes."""
    import laspy

    las = laspy.read(str(path))
    xyz = np.column_stack([np.asarray(las.x, dtype=np.float64), np.asarray(las.y, dtype=np.float64),
                           np.asarray(las.z, dtype=np.float64)])
    return xyz - xyz.min(axis=0), np.asarray(las.classification, dtype=np.uint8)


def _threads(workers: int):
    from patchcloud.core import single_threaded

    return single_threaded() if workers == 1 else contextlib.nullcontext()


def warm_up(workers: int = 1) -> None:
    """Load (or compile) patchcloud's kernels on a small cloud, so no file's time includes it."""
    from patchcloud.core import NormalsOptions, estimate_normals

    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 20, (4000, 2))
    plane = np.column_stack([xy, 0.05 * xy[:, 0]])
    scatter = rng.uniform(0, 20, (1000, 3))  # edge and sparse leaves: the k-NN fallback's kernels too
    with _threads(workers):
        estimate_normals(np.vstack([plane, scatter]), NormalsOptions())


def patchcloud_normals(xyz: np.ndarray, workers: int = 1) -> tuple[np.ndarray, np.ndarray, float]:
    """(N, 3) float32 normals and (N,) uint8 method codes of ``estimate_normals`` with the command's defaults, and its seconds."""
    from patchcloud.core import NormalsOptions, estimate_normals

    t = time.perf_counter()
    with _threads(workers):
        res = estimate_normals(xyz, NormalsOptions())
    return res.normals, res.method, time.perf_counter() - t


def reference_normals(
    xyz: np.ndarray, classes: np.ndarray, radius: float = RADIUS, radius_by_class: dict | None = None,
    min_neighbours: int = MIN_NEIGHBOURS, workers: int = 1, max_pairs: int = MAX_PAIRS,
) -> tuple[np.ndarray, np.ndarray]:
    """Same-class ball PCA normal of every point.

    Parameters
    ----------
    xyz : (N, 3) float
        Coordinates in a local frame (metres).
    classes : (N,) int
        ASPRS class of each point; the ball of a point holds the points of its class only.
    radius, radius_by_class
        Ball radius (metres), and per class where it differs (default
        :data:`RADIUS_BY_CLASS`: 2 m for ground).
    min_neighbours : int
        A point with fewer other same-class points in its ball gets no reference.
    workers : int
        Threads of scipy's neighbour counting.
    max_pairs : int
        At most this many (point, neighbour) pairs are held at once (memory bound).

    Returns
    -------
    normals : (N, 3) float32
        Unit normal of the smallest eigenvalue of the ball's covariance (the
        point itself included), unoriented; NaN where there is no reference.
    neighbours : (N,) int32
        Other same-class points in each point's ball.
    """
    from scipy.spatial import cKDTree

    xyz = np.asarray(xyz, dtype=np.float64)
    classes = np.asarray(classes)
    radius_by_class = RADIUS_BY_CLASS if radius_by_class is None else radius_by_class
    n = xyz.shape[0]
    normals = np.full((n, 3), np.nan, dtype=np.float32)
    neighbours = np.zeros(n, dtype=np.int32)
    for c in np.unique(classes):
        members = np.flatnonzero(classes == c)
        r = float(radius_by_class.get(int(c), radius))
        pts = xyz[members]
        tree = cKDTree(pts)
        counts = tree.query_ball_point(pts, r, return_length=True, workers=workers)
        neighbours[members] = counts - 1
        # queries in the tree's leaf order (compact chunks), those with enough neighbours only
        order = tree.indices[counts[tree.indices] - 1 >= min_neighbours]
        if order.size == 0:
            continue
        ends = np.cumsum(counts[order])
        cuts = np.searchsorted(ends, np.arange(max_pairs, int(ends[-1]), max_pairs), side="right")
        for chunk in np.split(order, np.unique(np.maximum(cuts, 1))):
            if chunk.size:
                normals[members[chunk]] = _ball_pca(pts, tree, chunk, r)
    return normals, neighbours


def _ball_pca(pts: np.ndarray, tree, chunk: np.ndarray, r: float) -> np.ndarray:
    """(M, 3) smallest-eigenvalue eigenvectors of the ball covariances of ``pts[chunk]`` (``tree`` holds ``pts``)."""
    from scipy.spatial import cKDTree

    q = pts[chunk]
    pairs = cKDTree(q).sparse_distance_matrix(tree, r, output_type="ndarray")
    i, j = pairs["i"], pairs["j"]
    m = chunk.size
    d = pts[j] - q[i]  # relative to the query point: no cancellation
    cnt = np.bincount(i, minlength=m).astype(np.float64)
    mean = np.stack([np.bincount(i, d[:, a], minlength=m) for a in range(3)], axis=1) / cnt[:, None]
    cov = np.empty((m, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            cov[:, a, b] = cov[:, b, a] = np.bincount(i, d[:, a] * d[:, b], minlength=m) / cnt - mean[:, a] * mean[:, b]
    return np.linalg.eigh(cov)[1][:, :, 0]


def angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Unoriented angle (degrees) between the rows of ``a`` and ``b``: ``acos |a . b|`` of the unit vectors."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    cos = np.abs(np.einsum("ij,ij->i", a, b)) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    return np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))


def class_groups(classes: np.ndarray) -> np.ndarray:
    """(N,) index into :data:`GROUPS` of each point's class."""
    classes = np.asarray(classes)
    out = np.full(classes.shape, [k for k, (_, codes) in enumerate(GROUPS) if codes is None][0], dtype=np.int8)
    for k, (_, codes) in enumerate(GROUPS):
        if codes is not None:
            out[np.isin(classes, codes)] = k
    return out


def method_name(code: int) -> str:
    """The :class:`patchcloud.core.Method` name of a code, lower case (``code7`` for one the enum lacks)."""
    from patchcloud.core import Method

    try:
        return Method(int(code)).name.lower()
    except ValueError:
        return f"code{int(code)}"


# ----------------------------------------------------------------------------- tables
def _median(x: np.ndarray) -> str:
    return f"{np.median(x):6.2f}" if x.size else f"{'-':>6}"


def quality_table(runs: list[dict]) -> list[str]:
    """The per-file / per-class-group table of :mod:`bench_fallback` as lines.

    Each run is a dict with ``label``, ``method`` (N,), ``normals`` (N, 3),
    ``reference`` (N, 3, NaN rows: none), ``classes`` (N,) and optionally
    ``seconds`` and ``ref_seconds``, and ``same_as``: the label of an earlier
    run of the same bytes.  With more than one run, "all files" rows pool them,
    each file once (a ``same_as`` run is left out, with a note).
    """
    codes = sorted({int(c) for r in runs for c in np.unique(r["method"])})
    names = [method_name(c) for c in codes]
    w = max([len(short_label(r["label"])) for r in runs] + [9])
    share_w = max([len(m) + 1 for m in names] + [7])
    head = (f"{'file':<{w}} {'points':>9} {'pc s':>6} {'ref s':>6} "
            + " ".join(f"{m + '%':>{share_w}}" for m in names)
            + f" | {'group':<10} {'points':>9} {'no ref':>7} "
            + " ".join(f"{m + ' n':>{max(len(m) + 2, 8)}} {'med°':>6}" for m in names + ["all"]))
    lines = [head]
    pooled = {k: {c: [] for c in codes + [-1]} for k in range(len(GROUPS))}
    pooled_n = {k: [0, 0] for k in range(len(GROUPS))}
    total, total_counts = 0, np.zeros(len(codes), dtype=np.int64)

    def group_row(lead: str, name: str, npts: int, noref: int, per: dict) -> str:
        cells = []
        for c, m in zip(codes + [-1], names + ["all"]):
            a = per[c]
            cells.append(f"{a.size:>{max(len(m) + 2, 8)},} {_median(a)}")
        return f"{lead} | {name:<10} {npts:>9,} {noref:>7,} " + " ".join(cells)

    for r in runs:
        method = np.asarray(r["method"])
        n = method.size
        counts = np.array([np.count_nonzero(method == c) for c in codes])
        if not r.get("same_as"):
            total += n
            total_counts += counts
        has = np.isfinite(np.asarray(r["reference"])[:, 0])
        ang = np.full(n, np.nan)
        ang[has] = angles(np.asarray(r["normals"])[has], np.asarray(r["reference"])[has])
        grp = class_groups(r["classes"])
        shares = " ".join(f"{100.0 * k / max(n, 1):>{share_w}.2f}" for k in counts)
        secs = f"{r.get('seconds', float('nan')):6.2f} {r.get('ref_seconds', float('nan')):6.2f}"
        first = f"{short_label(r['label']):<{w}} {n:>9,} {secs} {shares}"
        blank = " " * len(first)
        for k, (gname, _) in enumerate(GROUPS):
            in_g = grp == k
            if not in_g.any():
                continue
            per = {c: ang[in_g & has & (method == c)] for c in codes}
            per[-1] = ang[in_g & has]
            npts, noref = int(in_g.sum()), int((in_g & ~has).sum())
            if not r.get("same_as"):
                for c in per:
                    pooled[k][c].append(per[c])
                pooled_n[k][0] += npts
                pooled_n[k][1] += noref
            lines.append(group_row(first, gname, npts, noref, per))
            first = blank
    if len(runs) > 1:
        shares = " ".join(f"{100.0 * k / max(total, 1):>{share_w}.2f}" for k in total_counts)
        first = f"{'all files':<{w}} {total:>9,} {'':>6} {'':>6} {shares}"
        for k, (gname, _) in enumerate(GROUPS):
            if pooled_n[k][0]:
                per = {c: np.concatenate(v) for c, v in pooled[k].items()}
                lines.append(group_row(first, gname, pooled_n[k][0], pooled_n[k][1], per))
                first = " " * len(first)
        for r in runs:
            if r.get("same_as"):
                lines.append(f"# {r['label']} holds the same bytes as {r['same_as']}: counted once in 'all files'")
    return lines


def baseline_table(runs: list[dict], base: dict) -> list[str]:
    """Points whose method was the k-NN fallback in ``base`` and is another code now, per file and class group.

    ``base`` maps a label to a dict with ``method``, ``normals``, ``classes``
    (a loaded ``--save`` file: :func:`load_runs`).  Angles are to this run's
    reference normals.
    """
    from patchcloud.core import Method

    knn = int(Method.KNN)
    lines = []
    rows = []
    for r in runs:
        b = base.get(r["label"])
        if b is None:
            lines.append(f"# {r['label']}: not in the baseline")
            continue
        if b["method"].size != r["method"].size or not np.array_equal(b["classes"], r["classes"]):
            lines.append(f"# {r['label']}: other points than in the baseline (count or classes differ): skipped")
            continue
        method, bm = np.asarray(r["method"]), np.asarray(b["method"])
        ref = np.asarray(r["reference"])
        has = np.isfinite(ref[:, 0])
        moved = (bm == knn) & (method != knn)
        back = (bm != knn) & (method == knn)
        changed = int(np.count_nonzero(bm != method))
        lines.append(f"# {r['label']}: {changed:,} points changed method; {int(moved.sum()):,} left k-NN, "
                     f"{int(back.sum()):,} became k-NN; k-NN share {100.0 * np.mean(bm == knn):.2f}% -> "
                     f"{100.0 * np.mean(method == knn):.2f}%")
        grp = class_groups(r["classes"])
        for k, (gname, _) in enumerate(GROUPS):
            sel = moved & (grp == k)
            if not sel.any():
                continue
            s = sel & has
            before = angles(np.asarray(b["normals"])[s], ref[s])
            now = angles(np.asarray(r["normals"])[s], ref[s])
            new = method[s]
            by = ", ".join(f"{method_name(c)} {np.count_nonzero(new == c):,} ({_median(now[new == c]).strip()}°)"
                           for c in np.unique(new))
            rows.append((short_label(r["label"]), gname, int(sel.sum()), int(s.sum()), _median(before), _median(now), by))
    if not rows:
        return lines + ["no point left the k-NN fallback"]
    w = max(len(x[0]) for x in rows)
    lines.append(f"{'file':<{w}} | {'group':<10} {'left kNN':>9} {'with ref':>9} {'kNN med°':>9} {'now med°':>9}  now by method (median°)")
    for label, gname, n, nref, before, now, by in rows:
        lines.append(f"{label:<{w}} | {gname:<10} {n:>9,} {nref:>9,} {before:>9} {now:>9}  {by}")
    return lines


# ----------------------------------------------------------------------------- files
def default_files() -> list[Path]:
    """The aerial files of ../shared/data measured by default, then the embedded tile (absent ones left out)."""
    out = []
    for pattern in DEFAULT_FILES:
        out += sorted(SHARED.glob(pattern))
    if SAMPLE.exists():
        out.append(SAMPLE)
    return out


def label_of(path: Path) -> str:
    """A file's label: ``folder/name`` under ../shared/data, ``data/name`` for the embedded tile, else the path."""
    path = Path(path).resolve()
    for base in (SHARED, ROOT):
        try:
            return str(path.relative_to(base.resolve()))
        except ValueError:
            continue
    return str(path)


def short_label(label: str) -> str:
    """A label as the table shows it: the file name without its extension (the folder kept for data/ files)."""
    p = Path(label)
    return str(p.with_suffix("")) if p.parent.name == "data" else p.stem


def save_runs(path: Path, runs: list[dict], commit: str) -> None:
    """Every run's normals, methods, reference normals and classes in one .npz (``--save``)."""
    arrays = {"labels": np.array([r["label"] for r in runs]), "commit": np.array(commit)}
    for k, r in enumerate(runs):
        arrays[f"{k}_normals"] = np.asarray(r["normals"], dtype=np.float32)
        arrays[f"{k}_method"] = np.asarray(r["method"], dtype=np.uint8)
        arrays[f"{k}_reference"] = np.asarray(r["reference"], dtype=np.float32)
        arrays[f"{k}_classes"] = np.asarray(r["classes"], dtype=np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **arrays)


def load_runs(path: Path) -> tuple[dict, str]:
    """A ``--save`` file as {label: {normals, method, reference, classes}} and the commit it was made at."""
    with np.load(path) as z:
        runs = {}
        for k, label in enumerate(z["labels"].tolist()):
            runs[label] = {key: z[f"{k}_{key}"] for key in ("normals", "method", "reference", "classes")}
        return runs, str(z["commit"])


def git_commit() -> str:
    """This checkout's commit (short), with "+changes" when the work tree differs from it."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT, capture_output=True, text=True)
        return head.stdout.strip() + ("+changes" if dirty.stdout.strip() else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


# ----------------------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--files", nargs="*", type=Path, default=None,
                    help="LAS/LAZ files (default: the aerial files of ../shared/data and the embedded tile).")
    ap.add_argument("--save", type=Path, default=None, help="Save normals, methods and references here (.npz).")
    ap.add_argument("--baseline", type=Path, default=None, help="Compare with a run saved by --save.")
    ap.add_argument("--results", type=Path, default=None, help="Also write the printed tables here.")
    ap.add_argument("--workers", type=int, default=1, help="Threads of the numeric work (1: leave the other cores free).")
    a = ap.parse_args(argv)
    argv = sys.argv[1:] if argv is None else argv

    if a.files is None:
        if not SHARED.is_dir():
            print(f"# no data: {SHARED} not found (the shared data set sits beside the repository); nothing to measure")
            return 0
        files = default_files()
    else:
        files = a.files
    missing = [p for p in files if not Path(p).exists()]
    files = [p for p in files if Path(p).exists()]
    if not files:
        print("# no data: none of the files exists" + (f" ({', '.join(map(str, missing))})" if missing else ""))
        return 0
    base, base_commit = (None, "")
    if a.baseline is not None:
        base, base_commit = load_runs(a.baseline)

    commit = git_commit()
    out: list[str] = [
        f"# bench_fallback {time.strftime('%Y-%m-%d')}: {os.cpu_count()} cores, {platform.machine()}, python "
        f"{platform.python_version()}; patchcloud at {commit}; workers {a.workers}",
        f"# command: python tools/bench_fallback.py {' '.join(map(str, argv))}",
        f"# normals: estimate_normals(NormalsOptions()), in memory with the command's default options; reference: PCA of the same-class points "
        f"within {RADIUS:g} m ({', '.join(f'class {c}: {v:g} m' for c, v in RADIUS_BY_CLASS.items())}), "
        f"at least {MIN_NEIGHBOURS} other points; angles unoriented, degrees",
    ]
    for p in missing:
        out.append(f"# skipped {p}: not found")
    for ln in out:
        print(ln, flush=True)

    t_all = time.perf_counter()
    warm_up(a.workers)
    runs = []
    digests: dict[str, str] = {}
    for path in files:
        label = label_of(path)
        digest = hashlib.sha1(Path(path).read_bytes()).hexdigest()
        xyz, classes = read_cloud(Path(path))
        normals, method, secs = patchcloud_normals(xyz, a.workers)
        t = time.perf_counter()
        ref, _ = reference_normals(xyz, classes, workers=a.workers)
        runs.append(dict(label=label, normals=normals, method=method, reference=ref, classes=classes, seconds=secs,
                         ref_seconds=time.perf_counter() - t, same_as=digests.get(digest)))
        digests.setdefault(digest, label)
        print(f"#   {label}: {len(xyz):,} points, patchcloud {secs:.2f} s, reference {runs[-1]['ref_seconds']:.2f} s", flush=True)

    table = quality_table(runs)
    table.append(f"# pc s: estimate_normals wall seconds; ref s: reference normals; 'no ref': fewer than {MIN_NEIGHBOURS} "
                 f"other same-class points in the ball; 'all': every method; methods: {describe_codes()}")
    if base is not None:
        table += ["", f"# against the baseline {a.baseline} (patchcloud at {base_commit}): points that left the k-NN fallback",
                  *baseline_table(runs, base)]
    table.append(f"# total {time.perf_counter() - t_all:.1f} s for {sum(r['method'].size for r in runs):,} points")
    print("\n".join(table), flush=True)
    if a.save is not None:
        save_runs(a.save, runs, commit)
        print(f"# saved {a.save}")
    if a.results is not None:
        a.results.parent.mkdir(parents=True, exist_ok=True)
        a.results.write_text("\n".join(out + table) + "\n")
    return 0


def describe_codes() -> str:
    """Every :class:`patchcloud.core.Method` code by its name, as the enum has them now."""
    from patchcloud.core import Method

    return ", ".join(f"{m.value} {m.name.lower()}" for m in Method)


if __name__ == "__main__":
    sys.exit(main())
