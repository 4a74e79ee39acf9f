"""The pixel layout of a picture: a PNG exactly ``width`` pixels wide, with its image, axes, title and legend inside.

``patchcloud render --width W`` writes a PNG W pixels wide: the title,
the axes' ticks and labels and the legend (or colour bar) are laid out in
pixels around the image, and the image gets the columns that are left.
:func:`figure_layout` decides, before a single point is read, how many
columns that is (the tick labels are chosen from the frame's coordinates
and measured with the Agg renderer that draws them), so the points are
decimated straight into the image that is drawn, one image pixel on one
PNG pixel.  Above the image: the title; under it: the x axis, then the
colour bar or legend; the PNG's height is whatever they take.

Fonts shrink with narrow pictures (:func:`font_scale`); text wider than
the picture wraps at spaces, and a word that cannot fit is shortened with
an ellipsis (:func:`wrap_text`).  Below :data:`AXES_MIN` of the width for
the image, the axes are left out rather than squeezing it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from patchcloud.core import PatchcloudValueError

from patchcloud.stream.views.plots import STYLE, shorten

__all__ = [
    "DPI", "PAD", "MIN_WIDTH", "AXES_MIN", "FigureLayout", "figure_layout", "layout_around", "font_scale", "text_size",
    "wrap_text", "choose_ticks", "tick_labels", "thin_ticks", "TICK", "axis_metrics",
]

#: Dots per inch of every picture (figure pixels per inch).
DPI = STYLE["dpi"]
#: Pixels per typographic point.
PX_PER_PT = DPI / 72.0
#: Empty margin (pixels) around the picture and between its parts.
PAD = 6
#: Narrowest picture (pixels): room for a title word and an image.
MIN_WIDTH = 64
#: The axes are drawn only when the image keeps at least this share of the width.
AXES_MIN = 0.45
#: Tick length and the gap from tick to label, and from tick labels to the axis label (points, before scaling).
TICK, TICK_PAD, LABEL_PAD = 3.5, 3.5, 4.0


def font_scale(width: int) -> float:
    """The factor applied to every :data:`~patchcloud.stream.views.plots.STYLE` font size in a picture ``width`` px wide.

    Examples
    --------
    >>> font_scale(1600), font_scale(400), font_scale(100)
    (1.0, 0.6, 0.6)
    """
    return float(np.clip(width / 800.0, 0.6, 1.0))


@lru_cache(maxsize=1)
def _renderer():
    from matplotlib.backends.backend_agg import RendererAgg

    return RendererAgg(1, 1, DPI)


@lru_cache(maxsize=4096)
def text_size(text: str, points: float) -> tuple[float, float]:
    """(width, height) in pixels of one line of ``text`` at ``points`` drawn by Agg (the height with the descent).

    Examples
    --------
    >>> w, h = text_size("Easting (m)", 9.0)
    >>> 60 < w < 120 and 15 < h < 30
    True
    """
    from matplotlib.font_manager import FontProperties

    if not text:
        return 0.0, 0.0
    w, h, _ = _renderer().get_text_width_height_descent(text, FontProperties(size=points), ismath=False)
    return float(w), float(h)


def line_height(points: float) -> float:
    """Pixels between the tops of two lines of text at ``points``."""
    return math.ceil(1.25 * text_size("Ålp|", points)[1])


def _fit(word: str, width: float, points: float) -> str:
    """``word`` shortened in the middle (ellipsis) until it is at most ``width`` pixels wide."""
    if text_size(word, points)[0] <= width:
        return word
    lo, hi = 1, len(word) - 1  # characters kept: the largest that fits
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if text_size(shorten(word, mid), points)[0] <= width:
            lo = mid
        else:
            hi = mid - 1
    return shorten(word, lo)


def wrap_text(text: str, width: float, points: float) -> list[str]:
    """The lines of ``text`` (its own lines, wrapped at spaces) that each fit in ``width`` pixels at ``points``.

    Examples
    --------
    >>> wrap_text("one two three", 1000, 9.0)
    ['one two three']
    >>> lines = wrap_text("one two three", 40, 9.0)
    >>> len(lines) > 1 and all(text_size(t, 9.0)[0] <= 40 for t in lines)
    True
    >>> wrap_text("a_very_long_file_name.laz", 100, 9.0)[0]
    'a_ve….laz'
    """
    lines: list[str] = []
    for para in str(text).split("\n"):
        line = ""
        for word in para.split(" "):
            cand = word if not line else f"{line} {word}"
            if text_size(cand, points)[0] <= width:
                line = cand
                continue
            if line:
                lines.append(line)
            line = _fit(word, width, points)
        lines.append(line)
    return lines


def tick_labels(ticks) -> list[str]:
    """Labels of ``ticks``: plain decimals with as many places as the step needs (no offset); values all under 0.001
    (or one over 1e9) in scientific notation.

    Examples
    --------
    >>> tick_labels([6860000.0, 6860020.0, 6860040.0])
    ['6860000', '6860020', '6860040']
    >>> tick_labels([0.0, 0.0025, 0.005]), tick_labels([-0.5, 0.0, 0.5]), tick_labels([2.5])
    (['0.0000', '0.0025', '0.0050'], ['-0.5', '0.0', '0.5'], ['2.5'])
    >>> tick_labels([1.93e-8, 1.94e-8, 1.95e-8])
    ['1.93e-08', '1.94e-08', '1.95e-08']
    """
    t = np.asarray(ticks, dtype=np.float64)
    if t.size == 0:
        return []
    diffs = np.abs(np.diff(t))
    step = float(diffs[diffs > 0].min()) if (diffs > 0).any() else (abs(float(t[0])) or 1.0)
    big = float(np.abs(t).max())
    if 0 < big < 1e-3 or big >= 1e9:
        digits = max(0, math.floor(math.log10(big) + 1e-9) - math.floor(math.log10(step) + 1e-6))
        for digits in range(digits, digits + 12):
            labels = [f"{v:.{digits}e}" for v in t]
            if all(abs(float(s) - v) <= 1e-6 * step for s, v in zip(labels, t)):
                return labels
        return labels
    places = max(0, math.ceil(-math.log10(step) - 1e-9))
    for places in range(places, places + 12):
        labels = [f"{v + 0.0:.{places}f}" for v in t]
        if all(abs(float(s) - v) <= 1e-6 * step for s, v in zip(labels, t)):
            break
    return [s if s.lstrip("-").strip("0.") else s.lstrip("-") for s in labels]  # no "-0.0"


def choose_ticks(lo: float, hi: float, length: float, across: bool, points: float) -> tuple[list[float], list[str]]:
    """Ticks within [lo, hi] on an axis ``length`` pixels long, as many as their labels (at ``points``) leave room for.

    ``across``: the labels' widths lie along the axis (a horizontal axis);
    else their heights do (a vertical one).  A label takes 1.6 times its
    size along the axis.

    Examples
    --------
    >>> choose_ticks(0.0, 100.0, 600, True, 8.0)[1]
    ['0', '20', '40', '60', '80', '100']
    >>> choose_ticks(0.0, 100.0, 40, True, 8.0)[1]
    ['0']
    """
    from matplotlib.ticker import MaxNLocator

    if not hi > lo or length <= 0:
        return [], []
    best: tuple[list[float], list[str]] = ([], [])
    for n in range(9, 0, -1):
        t = MaxNLocator(nbins=n, steps=[1, 2, 2.5, 5, 10]).tick_values(lo, hi)
        t = [float(v) for v in t if lo - 1e-9 * (hi - lo) <= v <= hi + 1e-9 * (hi - lo)]
        if not t:
            continue
        labels = tick_labels(t)
        size = max(text_size(s, points)[0 if across else 1] for s in labels)
        best = (t, labels)
        if len(t) == 1 or length * (t[1] - t[0]) / (hi - lo) >= 1.6 * size:
            return best
    t, labels = best
    return (t[:1], labels[:1]) if t else best


def thin_ticks(ticks, labels, lo: float, hi: float, length: float, across: bool, points: float):
    """Every k-th of ``ticks`` (and ``labels``), the smallest k that gives each label 1.6 times its size on an axis ``length`` px long.

    Examples
    --------
    >>> thin_ticks([0, 1, 2, 3, 4], list("01234"), 0, 4, 40, True, 8.0)[1]   # 10 px apart, labels 11 px wide
    ['0', '2', '4']
    """
    if len(ticks) < 2 or not hi > lo:
        return list(ticks), list(labels)
    size = max(text_size(s, points)[0 if across else 1] for s in labels)
    gap = length * (ticks[1] - ticks[0]) / (hi - lo)
    k = max(1, math.ceil(1.6 * size / max(gap, 1e-9)))
    return list(ticks[::k]), list(labels[::k])


def axis_metrics(scale: float) -> dict[str, float]:
    """Font sizes (points) and tick sizes (pixels) of the axes of a picture drawn at font ``scale``."""
    return {
        "tick_pt": STYLE["tick"] * scale, "label_pt": STYLE["label"] * scale, "title_pt": STYLE["title"] * scale,
        "note_pt": STYLE["annotation"] * scale + 1.0, "tick_len": TICK * scale * PX_PER_PT, "tick_pad": TICK_PAD * scale * PX_PER_PT,
        "label_pad": LABEL_PAD * scale * PX_PER_PT,
    }


@dataclass(frozen=True)
class FigureLayout:
    """Columns of a picture ``width`` px wide: ``left`` columns, then ``raster`` for the image, then the rest.

    The image sits in columns [left, left + raster) (a narrower image, such
    as a frame taller than 4 x its width, is centred there); with ``axes``
    a one-pixel frame surrounds it and the x ticks (``xticks``, labels
    ``xtick_labels``, file coordinates) go under it, the y ticks left of it.

    Examples
    --------
    >>> lay = figure_layout(800, (0.0, 100.0, 0.0, 50.0), "Easting (m)", "Northing (m)")
    >>> lay.width, lay.left + lay.raster < 800, lay.axes
    (800, True, True)
    """

    width: int
    scale: float
    left: int
    raster: int
    axes: bool
    xlabel: str | None = None
    ylabel: str | None = None
    xticks: tuple = ()
    xtick_labels: tuple = ()
    yticks: tuple = ()
    ytick_labels: tuple = ()

    def axis_height(self) -> int:
        """Pixels under the image's frame taken by the x ticks, their labels and the axis label (0 without axes)."""
        if not self.axes:
            return 0
        m = axis_metrics(self.scale)
        tick_h = max([text_size(s, m["tick_pt"])[1] for s in self.xtick_labels] or [0.0])
        return math.ceil(m["tick_len"] + m["tick_pad"] + tick_h + m["label_pad"] + text_size(self.xlabel or "", m["label_pt"])[1]) + 2


def _margins(width: int, box, xlabel: str, ylabel: str) -> tuple[float, int, int, tuple, tuple]:
    """Font scale, left and right margins (pixels, the image's frame included) and the ticks of a picture ``width`` px wide."""
    s = font_scale(width)
    m = axis_metrics(s)
    u0, u1, v0, v1 = (float(b) for b in box)
    du, dv = max(u1 - u0, 1e-12), max(v1 - v0, 0.0)
    est_w = max(width - 130.0 * s, 1.0)
    est_h = min(est_w * dv / du, 4.0 * est_w)
    xt = choose_ticks(u0, u1, est_w, True, m["tick_pt"])
    yt = choose_ticks(v0, v1, est_h, False, m["tick_pt"])
    ytw = max([text_size(t, m["tick_pt"])[0] for t in yt[1]] or [0.0])
    half = max([text_size(t, m["tick_pt"])[0] for t in xt[1]] or [0.0]) / 2.0
    left = PAD + text_size(ylabel, m["label_pt"])[1] + m["label_pad"] + ytw + m["tick_pad"] + m["tick_len"] + 1.0
    left = math.ceil(max(left, PAD + half + 1.0))
    right = math.ceil(max(PAD, half + 2.0) + 1.0)
    return s, left, right, xt, yt


def figure_layout(width: int, box, xlabel: str | None, ylabel: str | None) -> FigureLayout:
    """The layout of a picture ``width`` px wide of the frame ``box`` = (left, right, bottom, top) in the coordinates of its axes.

    ``xlabel``/``ylabel`` None: no axes (the oblique view); the image then
    takes all the width but a :data:`PAD` each side.

    Raises
    ------
    PatchcloudValueError
        ``width`` under :data:`MIN_WIDTH`.

    Examples
    --------
    >>> figure_layout(300, (0, 1, 0, 1), None, None).raster
    288
    """
    width = int(width)
    if width < MIN_WIDTH:
        raise PatchcloudValueError(f"width must be at least {MIN_WIDTH} pixels for a picture with its title; got {width}")
    plain = FigureLayout(width=width, scale=font_scale(width), left=PAD, raster=width - 2 * PAD, axes=False)
    if xlabel is None or ylabel is None:
        return plain
    s, left, right, xt, yt = _margins(width, box, xlabel, ylabel)
    raster = width - left - right
    if raster < AXES_MIN * width:
        return plain
    return FigureLayout(width=width, scale=s, left=left, raster=raster, axes=True, xlabel=xlabel, ylabel=ylabel,
                        xticks=tuple(xt[0]), xtick_labels=tuple(xt[1]), yticks=tuple(yt[0]), ytick_labels=tuple(yt[1]))


def layout_around(columns: int, box, xlabel: str | None, ylabel: str | None) -> FigureLayout:
    """The layout that gives an image of ``columns`` px its own width (a picture as wide as the image and its margins).

    Examples
    --------
    >>> lay = layout_around(500, (0, 100, 0, 100), "X (m)", "Y (m)")
    >>> lay.raster, lay.width == lay.left + 500 + (lay.width - lay.left - lay.raster)
    (500, True)
    """
    columns = int(columns)
    width = max(columns + 2 * PAD, MIN_WIDTH)
    if xlabel is None or ylabel is None:
        return FigureLayout(width=width, scale=font_scale(width), left=(width - columns) // 2, raster=columns, axes=False)
    for _ in range(4):  # the margins depend a little on the width (font scale, ticks): settle them
        s, left, right, xt, yt = _margins(width, box, xlabel, ylabel)
        width = max(columns + left + right, MIN_WIDTH)
    return FigureLayout(width=width, scale=s, left=width - right - columns, raster=columns, axes=True, xlabel=xlabel, ylabel=ylabel,
                        xticks=tuple(xt[0]), xtick_labels=tuple(xt[1]), yticks=tuple(yt[0]), ytick_labels=tuple(yt[1]))
