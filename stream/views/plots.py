"""Figures of patchcloud results: matplotlib, drawn off screen with the Agg canvas.

Every figure is a :class:`matplotlib.figure.Figure` with its own
:class:`~matplotlib.backends.backend_agg.FigureCanvasAgg`: no pyplot, no
global backend or rcParams, so figures can be drawn from any thread.  The
look is shared through :data:`STYLE`, :func:`new_figure` and
:func:`style_axes`; :func:`save_png` writes a figure atomically.
Colour maps are perceptually uniform (viridis).
"""

from __future__ import annotations

import os
import textwrap
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from patchcloud.core import PatchcloudIOError

from patchcloud.stream.io.las import atomic_output

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.axes import Axes

    from patchcloud.stream.jobs.don_scales import ScalesResult

__all__ = ["STYLE", "CMAP", "new_figure", "style_axes", "check_png_path", "PNG_SIGNATURE", "NOT_PICTURE_NAMES", "save_png", "scale_selection_figure", "shorten"]

#: Shared look of every figure: resolution (dots per inch) and font sizes (points).
STYLE = {"dpi": 150, "title": 10, "label": 9, "tick": 8, "annotation": 7, "suptitle": 11}

#: The colour map of continuous values (perceptually uniform).
CMAP = "viridis"


def new_figure(width: float, height: float, ncols: int = 1, *, width_ratios=None) -> tuple[Figure, list]:
    """A figure of ``width`` x ``height`` inches with ``ncols`` axes side by side, on its own Agg canvas.

    Returns
    -------
    (Figure, list of Axes)

    Examples
    --------
    >>> fig, axes = new_figure(6, 3, 2)
    >>> len(axes), type(fig.canvas).__name__
    (2, 'FigureCanvasAgg')
    """
    fig = Figure(figsize=(width, height), dpi=STYLE["dpi"], layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, ncols, squeeze=False, gridspec_kw=None if width_ratios is None else {"width_ratios": width_ratios})
    return fig, list(axes[0])


def style_axes(ax: "Axes", title: str | None = None, xlabel: str | None = None, ylabel: str | None = None) -> None:
    """Title, axis labels and tick labels in the :data:`STYLE` font sizes.

    Examples
    --------
    >>> fig, (ax,) = new_figure(3, 3)
    >>> style_axes(ax, "t", "x (m)", "y (m)")
    >>> ax.get_xlabel(), ax.title.get_fontsize()
    ('x (m)', 10.0)
    """
    if title is not None:
        ax.set_title(title, fontsize=STYLE["title"])
    if xlabel is not None:
        ax.set_xlabel(xlabel, fontsize=STYLE["label"])
    if ylabel is not None:
        ax.set_ylabel(ylabel, fontsize=STYLE["label"])
    ax.tick_params(labelsize=STYLE["tick"])


#: The first bytes of every PNG file.
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: Names a picture is not given: a point cloud's (an unquoted glob's last file would be taken as the picture).
NOT_PICTURE_NAMES = (".las", ".laz")


def check_png_path(path: str | os.PathLike) -> Path:
    """``path`` as a Path if a PNG can be written there (an existing PNG is replaced); else a PatchcloudIOError naming it.

    Refused: a directory, a missing directory, a name of a point cloud
    (:data:`NOT_PICTURE_NAMES`, any case: ``render tiles/*.laz`` unquoted
    makes the last tile the picture), a name not ending in ``.png`` (any
    case), and an existing file that is not a PNG (a store's metadata, a
    LAS file, a report): a picture replaces only a picture.  Jobs that draw after a long read call it first, so a bad
    path fails before the work.
    """
    p = Path(path)
    if p.is_dir():
        raise PatchcloudIOError(f"{p}: is a directory")
    if not p.resolve().parent.exists():
        raise PatchcloudIOError(f"{p}: the directory {p.parent} does not exist")
    if p.name.lower().endswith(NOT_PICTURE_NAMES):
        raise PatchcloudIOError(f"{p}: a LAS/LAZ name, not a picture's (a PNG is written; an unquoted glob's last file?)")
    if p.exists():
        try:
            with open(p, "rb") as f:
                head = f.read(len(PNG_SIGNATURE))
        except OSError as exc:
            raise PatchcloudIOError(f"{p}: cannot be read ({exc.strerror or exc})") from None
        if head != PNG_SIGNATURE:
            raise PatchcloudIOError(f"{p}: exists and is not a PNG (a picture replaces only a picture)")
    if p.suffix.lower() != ".png":  # PNG bytes under another picture's name (.jpg, .tif) would mislead every viewer
        raise PatchcloudIOError(f"{p}: a PNG is written: name it {p.stem}.png")
    return p


def save_png(fig: Figure, path: str | os.PathLike, *, crop: bool = True) -> Path:
    """Write ``fig`` as a PNG at ``path``: to ``path + ".partial"`` first, then renamed (never a half-written file).

    ``crop``: cut the PNG to what the figure draws (nothing clipped, the
    size unknown beforehand); False: the figure's own size in pixels, for
    figures laid out in pixels (``patchcloud render``).

    Raises
    ------
    PatchcloudIOError
        The directory is missing or the file cannot be written (the path named).

    Examples
    --------
    >>> import tempfile
    >>> fig, (ax,) = new_figure(2, 2)
    >>> with tempfile.TemporaryDirectory() as d:
    ...     save_png(fig, os.path.join(d, "x.png")).read_bytes()[:4] == b"\\x89PNG"
    True
    """
    p = check_png_path(path)
    if not isinstance(fig.canvas, FigureCanvasAgg):
        FigureCanvasAgg(fig)
    try:
        with atomic_output(p, overwrite=True) as f:
            if crop:
                fig.savefig(f, format="png", dpi=STYLE["dpi"], bbox_inches="tight", pad_inches=0.05)  # nothing clipped
            else:
                fig.savefig(f, format="png", dpi=STYLE["dpi"])
    except PatchcloudIOError:
        raise
    except OSError as exc:
        raise PatchcloudIOError(f"{p}: cannot write the figure ({exc})") from exc
    return p


def _wrap(label: str, width: int = 11) -> str:
    """A class label on lines of at most ``width`` characters (whole words): "5 high vegetation" on two lines."""
    return textwrap.fill(label, width=width, break_long_words=False)


def shorten(text: str, most: int) -> str:
    """``text`` cut in the middle with an ellipsis when longer than ``most`` characters.

    >>> shorten("a_very_long_file_name.laz", 12)
    'a_very…e.laz'
    """
    if len(text) <= most:
        return text
    keep = most - 1
    return text[: keep - keep // 2] + "…" + text[len(text) - keep // 2:]


def _text_colour(rgba) -> str:
    """Black on light cells, white on dark ones."""
    r, g, b = rgba[:3]
    return "black" if 0.299 * r + 0.587 * g + 0.114 * b > 0.5 else "white"


def scale_selection_figure(result: "ScalesResult") -> Figure:
    """The DoN scale selection of :func:`patchcloud.stream.jobs.don_scales.don_scales` as one figure.

    Left: heat map of the Fisher ratio over (r_s, r_l) (rows r_s, columns
    r_l, metres; the value written in each cell, blank where r_s >= r_l,
    n/a on grey where fewer than two classes had enough defined values),
    the best pair outlined in red.  Right: mean ± standard
    deviation (bars) and median (diamond) of the DoN magnitude of each
    class at the best pair.

    Parameters
    ----------
    result : ScalesResult

    Returns
    -------
    Figure
        On an Agg canvas; write it with :func:`save_png`.

    Examples
    --------
    >>> from patchcloud.stream.jobs.don_scales import don_scales
    >>> r = don_scales(sample, radii=[0.5, 1, 2], classes=[2, 5], sample=1000)   # ground vs high vegetation
    >>> fig = scale_selection_figure(r)
    >>> len(fig.axes)   # heat map, per-class bars, colour bar
    3
    >>> save_png(fig, tmp / "don_scales.png").read_bytes()[:4] == b"\\x89PNG"
    True
    """
    rs_all = np.unique(result.r_small)
    rl_all = np.unique(result.r_large)
    grid = np.full((rs_all.size, rl_all.size), np.nan)
    row = np.searchsorted(rs_all, result.r_small)
    col = np.searchsorted(rl_all, result.r_large)
    grid[row, col] = result.fisher
    finite = grid[np.isfinite(grid)]
    hi = float(finite.max()) if finite.size else 1.0
    norm = Normalize(vmin=0.0, vmax=hi if hi > 0 else 1.0)

    ncls = result.classes.size
    fig, (ax, bx) = new_figure(
        max(8.0, 4.5 + 0.5 * rl_all.size + 0.7 * ncls), max(3.6, 1.2 + 0.45 * rs_all.size), 2,
        width_ratios=[max(rl_all.size, 2) + 1, max(ncls, 2) + 1],
    )
    masked = np.ma.masked_invalid(np.where(np.isinf(grid), hi, grid))
    im = ax.imshow(masked, cmap=CMAP, norm=norm, origin="lower", aspect="auto")
    cmap = im.get_cmap()
    for i, j in zip(row, col):
        v = grid[i, j]
        if np.isnan(v):  # a pair scored but without two usable classes: grey, "n/a"
            ax.add_patch(Rectangle((j - 0.5, i - 0.5), 1, 1, facecolor="0.88", edgecolor="none"))
            ax.text(j, i, "n/a", ha="center", va="center", fontsize=STYLE["annotation"], color="0.35")
            continue
        ax.text(j, i, "inf" if np.isinf(v) else f"{v:.3g}", ha="center", va="center",
                fontsize=STYLE["annotation"], color=_text_colour(cmap(norm(min(v, hi)))))
    bi, bj = row[result.best], col[result.best]
    ax.add_patch(Rectangle((bj - 0.5, bi - 0.5), 1, 1, fill=False, edgecolor="red", linewidth=2.0))
    ax.set_xticks(range(rl_all.size), [f"{v:g}" for v in rl_all])
    ax.set_yticks(range(rs_all.size), [f"{v:g}" for v in rs_all])
    rs, rl = result.best_pair
    u = result.unit
    style_axes(ax, f"Fisher ratio of |DoN| (best: {rs:g} {u}, {rl:g} {u})", f"large radius r_l ({u})", f"small radius r_s ({u})")
    cb = fig.colorbar(im, ax=ax, shrink=0.9)
    cb.set_label("between / within class variance", fontsize=STYLE["label"])
    cb.ax.tick_params(labelsize=STYLE["tick"])

    b = result.best
    x = np.arange(ncls)
    colours = cmap(np.linspace(0.0, 0.85, max(ncls, 2)))[:ncls]
    for k in range(ncls):
        if result.count[b, k] == 0:
            continue
        ax_kw = dict(color=colours[k], markersize=6)
        bx.errorbar(x[k], result.mean[b, k], yerr=result.std[b, k], fmt="o", capsize=4, linewidth=1.5, **ax_kw)
        bx.plot(x[k], result.median[b, k], "D", fillstyle="none", **ax_kw)
    bx.set_xticks(x, [f"{_wrap(lab)}\n({int(n):,})" for lab, n in zip(result.labels(), result.count[b])])
    bx.set_xlim(-0.6, ncls - 0.4)
    bx.set_ylim(-0.02, 1.02)
    bx.grid(axis="y", alpha=0.3)
    style_axes(bx, f"|DoN| per class at r_s={rs:g} {u}, r_l={rl:g} {u}", f"class ({result.classes_from}; defined points)",
               "|DoN|: mean ± std (o), median (◇)")
    name = shorten(Path(result.source).name if result.source else "points", 70)
    fig.suptitle(
        f"DoN scale selection: {name}\n{int(result.sampled.sum()):,} query points of {result.point_count:,}, "
        f"{result.mode} radius normals",
        fontsize=STYLE["suptitle"],
    )
    return fig
