"""Scale selection for Difference of Normals: the pair of radii that best separates labelled classes.

Given a cloud whose points carry a class (the LAS classification, or any
other dimension), the DoN magnitude ``|DoN(p, r_s, r_l)|`` is computed at a
stratified sample of query points for every pair ``r_s < r_l`` of a grid of
radii, summarised per class (count, mean, standard deviation, median), and
the pairs are ranked by a Fisher ratio of the magnitude:

.. math::

    F(r_s, r_l) = \\frac{\\sum_c n_c (\\mu_c - \\mu)^2}{\\sum_c n_c \\sigma_c^2}

with, for each class ``c`` kept, ``n_c`` its query points whose DoN is
defined, ``mu_c`` and ``sigma_c`` (population standard deviation) the mean
and spread of their magnitudes, and ``mu = sum_c n_c mu_c / sum_c n_c``.  It
is the ratio of the between-class to the within-class sum of squares (the
one-dimensional multi-class Fisher criterion): large when the classes'
magnitudes are far apart compared to their spread.  A class takes part in
the ratio of a pair only with at least ``min_class_points`` defined
magnitudes making up at least ``min_defined`` (default half) of its query
points, so that a radius below the point spacing, which leaves most balls
too sparse for a normal, is not scored on the few dense spots where it is
defined; a pair with fewer than two such classes has no ratio (NaN).
Because the query points are drawn with an equal share per class (see
:func:`stratified_sample`), the classes weigh about equally whatever their
sizes in the file.

The DoN of all pairs reuses one radius normal per distinct radius, every
normal facing one common viewpoint (:func:`patchcloud.core.default_viewpoint`
of the whole cloud), so ``DoN(r_s, r_l) = (n(r_s) - n(r_l)) / 2`` exactly as
:func:`patchcloud.core.difference_of_normals` computes it.  Neighbours are
always searched among *all* points of the cloud (every class, compared or
not); only the query points are sampled.

:func:`don_scales` reads a LAS/LAZ file **whole into memory** (about 25 bytes
per point plus the class dimension); :func:`select_scales` does the same on
arrays.
"""

from __future__ import annotations

import os
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import laspy
import numpy as np

from patchcloud.core import MODES, PatchcloudValueError, check_grid_step, check_points, check_rounding, coordinate_step, default_viewpoint, radius_normals

from patchcloud.stream.io.crs import units_of
from patchcloud.stream.io.las import open_source, read_chunks

__all__ = [
    "DEFAULT_RADII",
    "LAS_CLASS_NAMES",
    "ScalesResult",
    "don_scales",
    "select_scales",
    "scale_pairs",
    "check_radii",
    "stratified_sample",
    "fisher_ratio",
    "class_label",
]

#: Default grid of radii (metres): every pair ``r_s < r_l`` of it is scored.
DEFAULT_RADII = (0.1, 0.2, 0.5, 1.0, 2.0, 4.0)

#: Names of the ASPRS standard classes (LAS 1.4, point formats 6-10; 0-12 also for formats 0-5).
LAS_CLASS_NAMES = {
    0: "never classified", 1: "unclassified", 2: "ground", 3: "low vegetation", 4: "medium vegetation",
    5: "high vegetation", 6: "building", 7: "low point (noise)", 8: "key point", 9: "water", 10: "rail",
    11: "road surface", 12: "overlap", 13: "wire guard", 14: "wire conductor", 15: "transmission tower",
    16: "wire connector", 17: "bridge deck", 18: "high noise",
}

#: Most distinct values a class dimension may hold when ``classes`` is not given.
MAX_CLASSES = 64

_CHUNK = 1 << 20


def class_label(value, classes_from: str = "classification") -> str:
    """How a class value is shown: ``"2 ground"`` for a standard LAS class, else the value.

    Examples
    --------
    >>> class_label(6), class_label(64), class_label(2, "user_data")
    ('6 building', '64', '2')
    """
    v = float(value)
    text = f"{int(v)}" if v.is_integer() else f"{v:g}"
    if classes_from == "classification" and v.is_integer() and int(v) in LAS_CLASS_NAMES:
        return f"{text} {LAS_CLASS_NAMES[int(v)]}"
    return text


def check_radii(name: str, values) -> np.ndarray:
    """Validated radii (metres): finite, positive, at least one; sorted, duplicates removed.

    Raises
    ------
    PatchcloudValueError
        A value is not a positive number, or the list is empty.

    Examples
    --------
    >>> check_radii("radii", [2, 0.5, 2]).tolist()
    [0.5, 2.0]
    """
    try:
        r = np.asarray(values, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise PatchcloudValueError(
            f"{name} must be positive lengths in the file's unit, e.g. {', '.join(f'{v:g}' for v in DEFAULT_RADII)}; got {values!r}"
        ) from None
    if r.size == 0 or not np.isfinite(r).all() or (r <= 0).any():
        raise PatchcloudValueError(
            f"{name} must be positive lengths in the file's unit, e.g. {', '.join(f'{v:g}' for v in DEFAULT_RADII)}; got {values!r}"
        )
    return np.unique(r)


def scale_pairs(radii=DEFAULT_RADII, *, small=None, large=None) -> np.ndarray:
    """Every pair ``(r_s, r_l)`` with ``r_s < r_l``: of ``radii``, or of ``small`` x ``large``.

    Parameters
    ----------
    radii : sequence of float
        Radii (metres); used for whichever of ``small``, ``large`` is not given.
        At least two distinct values when neither is given.
    small, large : sequence of float, optional
        Explicit candidate small and large radii (metres).

    Returns
    -------
    (P, 2) float64
        Pairs sorted by ``r_s`` then ``r_l``.

    Raises
    ------
    PatchcloudValueError
        A radius not positive, or no pair with ``r_s < r_l``.

    Examples
    --------
    >>> scale_pairs([0.5, 1, 2]).tolist()
    [[0.5, 1.0], [0.5, 2.0], [1.0, 2.0]]
    >>> scale_pairs(small=[0.2], large=[1, 3]).tolist()
    [[0.2, 1.0], [0.2, 3.0]]
    """
    rs = check_radii("small radii" if small is not None else "radii", radii if small is None else small)
    rl = check_radii("large radii" if large is not None else "radii", radii if large is None else large)
    s, l = np.meshgrid(rs, rl, indexing="ij")
    keep = s < l
    if not keep.any():
        if small is None and large is None:
            raise PatchcloudValueError(
                f"radii must hold at least two distinct positive values (metres), e.g. "
                f"{', '.join(f'{v:g}' for v in DEFAULT_RADII)}; got {', '.join(f'{v:g}' for v in rs)}"
            )
        raise PatchcloudValueError(
            f"no pair r_small < r_large: small radii {', '.join(f'{v:g}' for v in rs)}, "
            f"large radii {', '.join(f'{v:g}' for v in rl)}; some small radius must be below some large one"
        )
    return np.column_stack([s[keep], l[keep]])


def stratified_sample(labels: np.ndarray, classes: np.ndarray, size: int, *, seed: int = 0) -> np.ndarray:
    """Indices of at most ``size`` points of ``classes``, an equal share per class, drawn without replacement.

    The budget is shared out by water-filling: a class with fewer points
    than its share gives all of them and the rest goes to the others.  The
    draw depends only on ``labels``, ``classes``, ``size`` and ``seed``.

    Parameters
    ----------
    labels : (N,) array
        Class of every point.
    classes : (C,) array
        The classes to draw from.
    size : int
        Most points drawn in all.
    seed : int
        Seed of the random generator.

    Returns
    -------
    (M,) int64
        Sorted point indices, ``M = min(size, points of classes)``.

    Examples
    --------
    >>> lab = np.array([1] * 100 + [2] * 10 + [3] * 1000)
    >>> idx = stratified_sample(lab, np.array([1, 2, 3]), 90)
    >>> np.unique(lab[idx], return_counts=True)[1].tolist()
    [40, 10, 40]
    """
    labels = np.asarray(labels)
    members = [np.flatnonzero(labels == c) for c in np.asarray(classes)]
    counts = np.array([m.size for m in members], dtype=np.int64)
    take = np.zeros(counts.size, dtype=np.int64)
    left = int(size)
    for i, k in enumerate(np.argsort(counts, kind="stable")):  # smallest classes first: water-filling
        take[k] = min(counts[k], left // (counts.size - i))
        left -= int(take[k])
    rng = np.random.default_rng(seed)
    picks = [m[rng.choice(m.size, t, replace=False)] if t < m.size else m for m, t in zip(members, take)]
    return np.sort(np.concatenate(picks)).astype(np.int64) if picks else np.zeros(0, dtype=np.int64)


def _fisher(n: np.ndarray, mean: np.ndarray, std: np.ndarray, min_count, usable=None) -> np.ndarray:
    """Fisher ratio per row of (P, C) per-class counts, means and standard deviations.

    A class counts in a row with at least ``min_count`` values (and where ``usable``, (P, C) bool, says so).
    """
    ok = n >= max(int(min_count), 1)
    if usable is not None:
        ok &= usable
    w = np.where(ok, n, 0).astype(np.float64)
    mu_c = np.where(ok, mean, 0.0)
    sd_c = np.where(ok, std, 0.0)
    tot = w.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mu = (w * mu_c).sum(axis=1) / tot
        between = (w * (mu_c - mu[:, None]) ** 2).sum(axis=1)
        within = (w * sd_c**2).sum(axis=1)
        f = between / within
    f = np.where((within == 0) & (between > 0), np.inf, f)
    f = np.where((within == 0) & (between == 0), 0.0, f)  # every value alike (a plane's DoN, all 0): nothing separates
    return np.where(ok.sum(axis=1) >= 2, f, np.nan)


def fisher_ratio(values: np.ndarray, labels: np.ndarray, *, min_count: int = 1) -> float:
    """Between-class over within-class sum of squares of ``values``: ``sum n_c (mu_c - mu)^2 / sum n_c sigma_c^2``.

    NaN values are left out; a class takes part with at least ``min_count``
    finite values.  NaN with fewer than two such classes; ``inf`` when the
    classes differ but each is constant; 0 when every value is the same.

    Examples
    --------
    >>> fisher_ratio(np.array([0.0, 0.2, 1.0, 1.2]), np.array([1, 1, 2, 2]))
    25.0
    >>> fisher_ratio(np.array([0.0, 0.2, np.nan]), np.array([1, 1, 2]))
    nan
    >>> fisher_ratio(np.zeros(4), np.array([1, 1, 2, 2]))
    0.0
    """
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    lab = np.asarray(labels).reshape(-1)
    n, mean, std, _ = _class_stats(v[None, :], lab, np.unique(lab))
    return float(np.round(_fisher(n, mean, std, min_count)[0], 12))


def _class_stats(mag: np.ndarray, labels: np.ndarray, classes: np.ndarray):
    """Count, mean, std (population) and median of the finite entries of (P, M) ``mag`` per class: (P, C) arrays."""
    p, c = mag.shape[0], classes.size
    n = np.zeros((p, c), dtype=np.int64)
    mean, std, median = (np.full((p, c), np.nan) for _ in range(3))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN slices: the NaN result is what we want
        for j, cl in enumerate(classes):
            sub = mag[:, labels == cl]
            n[:, j] = np.isfinite(sub).sum(axis=1)
            if sub.shape[1]:
                mean[:, j] = np.nanmean(sub, axis=1)
                std[:, j] = np.nanstd(sub, axis=1)
                median[:, j] = np.nanmedian(sub, axis=1)
    return n, mean, std, median


def _frozen(a) -> np.ndarray:
    a = np.array(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class ScalesResult:
    """Per-class statistics of the DoN magnitude over a grid of radius pairs, and the pair that separates best.

    Attributes
    ----------
    r_small, r_large : (P,) float64
        The pairs of radii (metres), ``r_small < r_large``.
    classes : (C,) array
        The class values compared (the dtype of the class dimension).
    count : (P, C) int64
        Query points of each class whose DoN is defined at each pair.
    mean, std, median : (P, C) float64
        Mean, population standard deviation and median of ``|DoN|`` (in [0, 1])
        over those points; NaN where the count is 0.
    fisher : (P,) float64
        Fisher ratio of each pair (module text); NaN where fewer than two
        classes have ``min_class_points`` defined magnitudes.
    best : int
        Row of the pair with the largest Fisher ratio.
    class_points : (C,) int64
        Points of each compared class in the cloud.
    sampled : (C,) int64
        Query points drawn from each compared class.
    excluded : tuple
        Class values present in the cloud but not compared (too few points,
        or not in the requested subset).
    classes_from : str
        The dimension the classes come from.
    mode : str
        Radius-normal mode, ``"exact"`` or ``"fast"``.
    min_class_points : int
    min_defined : float
        The thresholds of a class's defined magnitudes at a pair (module text).
    seed : int
    point_count : int
        Points in the cloud (all classes: the neighbours of every query).
    source : str or None
        The file read, or None for arrays.
    unit : str
        The symbol of the radii's unit: the file's horizontal unit (``m``, ``ft``, ``us-ft``), ``m`` for arrays.
    """

    r_small: np.ndarray
    r_large: np.ndarray
    classes: np.ndarray
    count: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    median: np.ndarray
    fisher: np.ndarray
    best: int
    class_points: np.ndarray
    sampled: np.ndarray
    excluded: tuple = ()
    classes_from: str = "classification"
    mode: str = "fast"
    min_class_points: int = 100
    min_defined: float = 0.5
    seed: int = 0
    point_count: int = 0
    source: str | None = None
    unit: str = "m"

    @property
    def pairs(self) -> np.ndarray:
        """(P, 2) float64 ``(r_small, r_large)`` per row, metres."""
        return np.column_stack([self.r_small, self.r_large])

    @property
    def best_pair(self) -> tuple[float, float]:
        """``(r_small, r_large)`` of the best pair, metres."""
        return float(self.r_small[self.best]), float(self.r_large[self.best])

    @property
    def best_fisher(self) -> float:
        """The Fisher ratio of the best pair."""
        return float(self.fisher[self.best])

    def labels(self) -> list[str]:
        """Display label of each compared class (``"2 ground"`` for standard LAS classes)."""
        return [class_label(c, self.classes_from) for c in self.classes]

    def format(self) -> str:
        """A markdown table of every pair (Fisher ratio, per-class mean ± std of ``|DoN|``), best pair marked, and a
        table of the classes at the best pair."""
        labels = self.labels()
        defined = self.count.sum(axis=1) / max(int(self.sampled.sum()), 1)
        name = Path(self.source).name if self.source else "points"
        lines = [
            f"DoN scale selection: {name}, {self.point_count:,} points, classes from '{self.classes_from}', "
            f"{int(self.sampled.sum()):,} query points, radius normals '{self.mode}'",
            "criterion: Fisher ratio F = sum_c n_c (mu_c - mu)^2 / sum_c n_c sigma_c^2 of |DoN| "
            f"(classes with >= {self.min_class_points} defined values, >= {100 * self.min_defined:g}% of their queries; "
            "higher separates better)",
        ]
        if self.excluded:
            lines.append("not compared: " + ", ".join(class_label(c, self.classes_from) for c in self.excluded))
        lines.append("")
        head = [f"r_s ({self.unit})", f"r_l ({self.unit})", "Fisher", "defined"] + [f"{lab}: mean ± std" for lab in labels] + ["best"]
        lines.append("| " + " | ".join(head) + " |")
        lines.append("|" + "|".join(["---:"] * (len(head) - 1) + [":---:"]) + "|")
        for i in range(self.r_small.size):
            cells = [f"{self.r_small[i]:g}", f"{self.r_large[i]:g}", _ratio(self.fisher[i]), f"{100 * defined[i]:.0f}%"]
            cells += [
                "–" if self.count[i, j] == 0 else f"{self.mean[i, j]:.3f} ± {self.std[i, j]:.3f}" for j in range(len(labels))
            ]
            cells.append("**<-**" if i == self.best else "")
            if i == self.best:
                cells[:3] = [f"**{c}**" for c in cells[:3]]
            lines.append("| " + " | ".join(cells) + " |")
        rs, rl = self.best_pair
        lines += [
            "",
            f"best pair: r_s = {rs:g} {self.unit}, r_l = {rl:g} {self.unit}, Fisher ratio {_ratio(self.best_fisher)}",
            "",
            "| class | points | sampled | defined | mean | std | median |",
            "|---|---:|---:|---:|---:|---:|---:|",
        ]
        b = self.best
        for j, lab in enumerate(labels):
            lines.append(
                f"| {lab} | {int(self.class_points[j]):,} | {int(self.sampled[j]):,} | {int(self.count[b, j]):,} | "
                f"{_num(self.mean[b, j], 3)} | {_num(self.std[b, j], 3)} | {_num(self.median[b, j], 3)} |"
            )
        return "\n".join(lines)


def _num(v: float, digits: int = 3) -> str:
    v = float(v)
    if np.isnan(v):
        return "–"
    if np.isinf(v):
        return "inf"
    return f"{v:.{digits}f}" if abs(v) < 1000 else f"{v:.4g}"


def _ratio(v: float) -> str:
    v = float(v)
    return "–" if np.isnan(v) else "inf" if np.isinf(v) else f"{v:.4g}"


def _check_fraction(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = np.nan
    if not 0.0 <= v <= 1.0:
        raise PatchcloudValueError(f"{name} must be a fraction in [0, 1]; got {value!r}")
    return v


def _check_int(name: str, value, lowest: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lowest:
        raise PatchcloudValueError(f"{name} must be a whole number, at least {lowest:,}; got {value!r}")
    return int(value)


def _choose_classes(labels: np.ndarray, classes, min_class_points: int, classes_from: str):
    """(compared classes, their point counts, excluded classes) after the checks on the class subset."""
    present, counts = np.unique(labels, return_counts=True)
    shown = ", ".join(f"{class_label(v, classes_from)} ({c:,})" for v, c in zip(present, counts))
    if classes is None:
        if present.size > MAX_CLASSES:
            raise PatchcloudValueError(
                f"the dimension '{classes_from}' holds {present.size:,} distinct values, too many for classes "
                f"(at most {MAX_CLASSES}); give the classes to compare"
            )
        wanted = present
    else:
        try:
            asked = np.unique(np.asarray(classes, dtype=np.float64).reshape(-1))
        except (TypeError, ValueError):
            raise PatchcloudValueError(f"classes must be values of '{classes_from}'; got {classes!r}; present: {shown}") from None
        present_f = present.astype(np.float64)
        missing = asked[~np.isin(asked, present_f)]
        if asked.size == 0 or missing.size:
            raise PatchcloudValueError(
                f"class {', '.join(class_label(v, classes_from) for v in missing) or '(none given)'} not in "
                f"'{classes_from}'; the values present (points) are: {shown}"
            )
        wanted = present[np.isin(present_f, asked)]
    n_wanted = counts[np.searchsorted(present, wanted)]
    enough = n_wanted >= min_class_points
    if enough.sum() < 2:
        raise PatchcloudValueError(
            f"fewer than two classes of '{classes_from}' have at least min_class_points={min_class_points:,} points "
            f"(present, with points: {shown}); DoN scale selection needs two classes to compare"
        )
    excluded = tuple(v.item() for v in present if v not in set(wanted[enough].tolist()))
    return wanted[enough], n_wanted[enough].astype(np.int64), excluded


def select_scales(
    points: np.ndarray,
    labels: np.ndarray,
    *,
    radii: Sequence[float] = DEFAULT_RADII,
    small: Sequence[float] | None = None,
    large: Sequence[float] | None = None,
    classes: Sequence | None = None,
    sample: int = 200_000,
    mode: str = "fast",
    resolution: int = 4,
    min_points: int = 3,
    min_class_points: int = 100,
    min_defined: float = 0.5,
    seed: int = 0,
    classes_from: str = "classification",
    progress: Callable[[str], None] | None = None,
    _source: str | None = None,
    rounding: float | None = None,
    grid_step: float | None = None,
    unit: str = "m",
) -> ScalesResult:
    """Per-class DoN magnitude statistics over radius pairs, for points in memory (see the module text).

    Parameters
    ----------
    points : (N, 3) array
        Coordinates (metres); every point is a neighbour of the queries.
    labels : (N,) array
        Class of each point.
    radii, small, large :
        The pairs scored, as :func:`scale_pairs` (metres).
    classes : sequence, optional
        The class values to compare (each must be present).  Default: every
        class present.  Classes with fewer than ``min_class_points`` points
        are left out (listed in ``excluded``).
    sample : int
        Most query points, drawn by :func:`stratified_sample` (equal share per class).
    mode, resolution, min_points :
        As :func:`patchcloud.core.radius_normals`; ``"fast"`` by default here.
    min_class_points : int
        Fewest points of a class in the cloud to compare it, and fewest
        defined magnitudes of a class at a pair to count in its Fisher ratio.
    min_defined : float
        Smallest fraction, in [0, 1], of a class's query points with a
        defined DoN for the class to count in a pair's Fisher ratio.
    seed : int
        Seed of the query draw.
    classes_from : str
        Name of the class dimension, for display.
    progress : callable, optional
        Called with a one-line message after each radius (all arguments and
        classes are checked before the first call).
    rounding, grid_step : float, optional
        The coordinates' step and the step of their grid, as :func:`patchcloud.core.radius_normals`
        (default: a ``laspy.LasData``'s scale, else 0).
    unit : str
        The symbol of the coordinates' unit, which the radii are in (for display).

    Returns
    -------
    ScalesResult

    Raises
    ------
    PatchcloudValueError
        Bad radii or parameters, fewer than two classes with enough points,
        or no pair with two classes of enough defined magnitudes.

    Examples
    --------
    Ground (class 2) and a pole of radius 0.1 m (class 64) standing on it: at
    the pole the small ball sees a cylinder, the large one mostly ground.

    >>> g = np.arange(-3, 3, 0.1)
    >>> a, b = np.meshgrid(g, g)
    >>> ground = np.column_stack([a.ravel(), b.ravel(), np.zeros(a.size)])
    >>> t, z = np.meshgrid(np.arange(0, 6.28, 0.5), np.arange(0.05, 3, 0.05))
    >>> pole = np.column_stack([0.1 * np.cos(t.ravel()), 0.1 * np.sin(t.ravel()), z.ravel()])
    >>> labels = np.repeat([2, 64], [len(ground), len(pole)])
    >>> r = select_scales(np.vstack([ground, pole]), labels, radii=[0.3, 1, 2], mode="exact")
    >>> r.best_pair, r.classes.tolist(), r.fisher.round(1).tolist()
    ((0.3, 2.0), [2, 64], [0.7, 1.7, 0.8])
    """
    step = coordinate_step(points) if rounding is None else check_rounding(rounding)
    tie = check_grid_step(points, grid_step)
    pts = check_points(points)
    lab = np.asarray(labels).reshape(-1)
    if lab.shape[0] != pts.shape[0]:
        raise PatchcloudValueError(f"labels must hold one class per point ({pts.shape[0]:,}); got {lab.shape[0]:,}")
    pairs = scale_pairs(radii, small=small, large=large)
    if mode not in MODES:
        raise PatchcloudValueError(f"mode must be one of {', '.join(MODES)}; got {mode!r}")
    _check_int("resolution", resolution, 1)
    _check_int("min_points", min_points, 3)
    sample = _check_int("sample", sample, 2)
    min_class_points = _check_int("min_class_points", min_class_points, 1)
    min_defined = _check_fraction("min_defined", min_defined)
    seed = _check_int("seed", seed, 0)
    cls, class_points, excluded = _choose_classes(lab, classes, min_class_points, classes_from)

    at = stratified_sample(lab, cls, sample, seed=seed)
    qlab = lab[at]
    sampled = np.array([(qlab == c).sum() for c in cls], dtype=np.int64)
    vp = default_viewpoint(pts)
    normals = {}
    for r in np.unique(pairs):
        t0 = time.perf_counter()
        normals[float(r)] = radius_normals(pts, float(r), viewpoint=vp, mode=mode, resolution=resolution, min_points=min_points, at=at,
                                            rounding=step, grid_step=tie)
        if progress is not None:
            progress(f"radius normals r = {r:g} {unit} at {at.size:,} points in {time.perf_counter() - t0:.1f} s")
    mag = np.empty((pairs.shape[0], at.size))
    for i, (rs, rl) in enumerate(pairs):
        d = (normals[float(rs)] - normals[float(rl)]) / 2.0
        mag[i] = np.sqrt(np.einsum("ij,ij->i", d, d))
    n, mean, std, median = _class_stats(mag, qlab, cls)
    fisher = _fisher(n, mean, std, min_class_points, n >= min_defined * sampled[None, :])
    if np.isnan(fisher).all():
        raise PatchcloudValueError(
            f"no pair of radii has two classes with at least min_class_points={min_class_points:,} defined DoN values "
            f"making up min_defined={min_defined:g} of their query points (radii "
            f"{', '.join(f'{v:g}' for v in np.unique(pairs))} {unit}, {at.size:,} query points); "
            "use larger radii, a larger sample or smaller min_class_points / min_defined"
        )
    if np.nanmax(fisher) == 0:
        raise PatchcloudValueError(
            f"no pair of radii separates the classes: at every pair their DoN magnitudes are alike (radii "
            f"{', '.join(f'{v:g}' for v in np.unique(pairs))} {unit}, {at.size:,} query points; a plane's are all 0)"
        )
    best = int(np.nanargmax(np.where(np.isnan(fisher), -np.inf, fisher)))
    return ScalesResult(
        r_small=_frozen(pairs[:, 0]), r_large=_frozen(pairs[:, 1]), classes=_frozen(cls), count=_frozen(n),
        mean=_frozen(mean), std=_frozen(std), median=_frozen(median), fisher=_frozen(fisher), best=best,
        class_points=_frozen(class_points), sampled=_frozen(sampled), excluded=excluded, classes_from=classes_from,
        mode=mode, min_class_points=min_class_points, min_defined=min_defined, seed=seed, point_count=int(pts.shape[0]),
        source=_source, unit=unit,
    )


def don_scales(
    input: str | os.PathLike,
    *,
    radii: Sequence[float] = DEFAULT_RADII,
    small: Sequence[float] | None = None,
    large: Sequence[float] | None = None,
    classes_from: str = "classification",
    classes: Sequence | None = None,
    sample: int = 200_000,
    mode: str = "fast",
    resolution: int = 4,
    min_points: int = 3,
    min_class_points: int = 100,
    min_defined: float = 0.5,
    max_points: int = 50_000_000,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
    units: str | None = None,
) -> ScalesResult:
    """The pair of DoN radii that best separates the classes of a labelled LAS/LAZ file.

    This **loads the whole file into memory** (float64 coordinates and the
    class dimension, about 25 bytes per point), hence ``max_points``.
    Coordinates are local, in float64: ``X * scale + offset`` minus the
    header's minimum, computed as ``X * scale + (offset - minimum)``.  The criterion is the Fisher ratio
    ``sum_c n_c (mu_c - mu)^2 / sum_c n_c sigma_c^2`` of the DoN magnitude
    over the classes (module text); the statistics are taken at a seeded,
    stratified sample of query points, the neighbours being every point.

    Parameters
    ----------
    input : path
        A LAS or LAZ file.
    radii : sequence of float
        Radii (metres); every pair ``r_s < r_l`` is scored.  Default
        :data:`DEFAULT_RADII`.
    small, large : sequence of float, optional
        Explicit candidate small and large radii instead (metres).
    classes_from : str
        The dimension holding the classes: ``"classification"`` or any other
        dimension of the file (extra bytes included).
    classes : sequence, optional
        The class values to compare; default every value present.
    sample : int
        Most query points; every compared class gets an equal share.
    mode : {"fast", "exact"}
        Radius-normal mode (:func:`patchcloud.core.radius_normals`).
    resolution, min_points :
        As :func:`patchcloud.core.radius_normals`.
    min_class_points : int
        Fewest points (and, per pair, defined magnitudes) of a class to compare it.
    min_defined : float
        Smallest fraction of a class's query points with a defined DoN for
        it to count in a pair's ratio.
    max_points : int
        Largest file read; above it a PatchcloudValueError.
    seed : int
        Seed of the query draw (same seed, same result).
    progress : callable, optional
        Called with a one-line message after each step (all arguments and
        classes are checked before the first call).
    units : {"m", "ft", "us-ft"}, optional
        The unit of the file's coordinates, which the radii are in (default:
        its CRS's horizontal unit, metres for a file without one; a
        geographic CRS is refused): :func:`patchcloud.stream.io.crs.units_of`.

    Returns
    -------
    ScalesResult

    Raises
    ------
    PatchcloudIOError
        The file is missing, not LAS/LAZ, empty or truncated (named).
    PatchcloudValueError
        More points than ``max_points``, an unknown dimension (the valid
        names listed), fewer than two classes with enough points, bad radii
        or parameters (valid values listed).

    Examples
    --------
    >>> r = don_scales(sample, radii=[0.5, 1, 2], classes=[2, 5], sample=1000)   # ground vs high vegetation
    >>> r.labels(), r.sampled.tolist(), r.pairs.tolist()
    (['2 ground', '5 high vegetation'], [500, 500], [[0.5, 1.0], [0.5, 2.0], [1.0, 2.0]])
    >>> r.best_pair, round(r.best_fisher, 2)
    ((0.5, 2.0), 0.75)
    >>> bool(r.mean[r.best, 0] < r.mean[r.best, 1])   # at the best pair, the ground's |DoN| is the smaller
    True
    >>> print(r.format())   # doctest: +ELLIPSIS
    DoN scale selection: test_data_77055_627760_LA93_IGN69.laz, 60,653 points, classes from 'classification', ...
    ...
    best pair: r_s = 0.5 m, r_l = 2 m, Fisher ratio 0.7533
    ...
    """
    # Arguments first: nothing is read before they are known to be good.
    scale_pairs(radii, small=small, large=large)
    if mode not in MODES:
        raise PatchcloudValueError(f"mode must be one of {', '.join(MODES)}; got {mode!r}")
    _check_int("resolution", resolution, 1)
    _check_int("min_points", min_points, 3)
    _check_int("sample", sample, 2)
    _check_int("min_class_points", min_class_points, 1)
    _check_fraction("min_defined", min_defined)
    max_points = _check_int("max_points", max_points, 1)
    _check_int("seed", seed, 0)
    if not isinstance(classes_from, str) or not classes_from:
        raise PatchcloudValueError(f"classes_from must be the name of a dimension; got {classes_from!r}")

    src = open_source(input)
    # the radii are in the file's unit, as every distance option (a geographic CRS refused, as by every job)
    unit = units_of(src.crs, src.mins, src.maxs, units, where=str(input)).symbol
    with laspy.open(src.path) as reader:
        names = list(reader.header.point_format.dimension_names)
    if classes_from not in names:
        raise PatchcloudValueError(f"{input}: no dimension '{classes_from}'; the file's dimensions are: {', '.join(names)}")
    if src.point_count > max_points:
        raise PatchcloudValueError(
            f"{input}: holds {src.point_count:,} points, more than max_points={max_points:,}; don-scales loads the whole "
            "file into memory: crop it to a representative area or raise max_points"
        )
    t0 = time.perf_counter()
    n = src.point_count
    pts = np.empty((n, 3))
    lab = None
    shift = np.asarray(src.offset) - np.asarray(src.mins)
    scale = np.asarray(src.scale)
    for first, chunk in read_chunks(src, _CHUNK):
        e = first + len(chunk)
        for k, dim in enumerate("XYZ"):
            pts[first:e, k] = np.asarray(chunk[dim], dtype=np.float64) * scale[k] + shift[k]
        values = np.asarray(chunk[classes_from])
        if values.ndim != 1:
            raise PatchcloudValueError(
                f"{input}: the dimension '{classes_from}' holds {values.shape[1]} values per point; classes need one"
            )
        if lab is None:
            lab = np.empty(n, dtype=values.dtype)
        lab[first:e] = values
    said = f"read {n:,} points of {Path(input).name} in {time.perf_counter() - t0:.1f} s"

    def step(msg: str) -> None:  # the read is reported once the classes are known to be good
        nonlocal said
        if said:
            progress(said)
            said = ""
        progress(msg)

    return select_scales(
        pts, lab, radii=radii, small=small, large=large, classes=classes, sample=sample, mode=mode,
        resolution=resolution, min_points=min_points, min_class_points=min_class_points, min_defined=min_defined,
        seed=seed, classes_from=classes_from, progress=None if progress is None else step, _source=src.path,
        rounding=src.step,  # the file's step: a ball collinear up to it has no normal
        grid_step=float(min(src.scale)),  # and its grid, on which ties are decided
        unit=unit,
    )
