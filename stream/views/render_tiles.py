"""The tile grid of a store, seen from above: ``patchcloud render-tiles``.

Left panel: every column of tiles (the tiles stacked in z at one (i, j))
as a square in file coordinates, coloured by its state at one step:
*failed* (a tile of the column has not done the step and records a task
that raised: :func:`patchcloud.stream.map_tiles` writes the error into the
tile's ``failed`` attribute, and clears it when the task later succeeds),
*done* (every tile of the column has the step done), *partly done* (some
of them) or *pending* (none).  Right panel: the points (or the patches)
per column, on a perceptual colour map.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import numpy as np

from patchcloud.core import PatchcloudIOError, PatchcloudValueError

from patchcloud.stream.io.store import Store

__all__ = ["TILE_STEPS", "STATE_COLOURS", "TileState", "TilesSummary", "tile_state", "tiles_figure", "render_tiles"]

#: Per-tile steps in the order the jobs run them (normals: sort, fit, finish; don/segment: don_skin, don, cluster; compress).
TILE_STEPS = ("sort", "fit", "finish", "don_skin", "don", "cluster", "compress")
#: Colours of the column states.
STATE_COLOURS = {"failed": (0.84, 0.15, 0.16), "done": (0.20, 0.63, 0.17), "partly done": (1.00, 0.60, 0.00),
                 "pending": (0.80, 0.80, 0.80)}


@dataclass
class TileState:
    """Per column of tiles (i, j): state at ``step`` and points / patches.

    ``columns`` (C, 2) tile indices i, j; ``corner`` (C, 2) the file
    coordinates (the units of ``crs``, the store's CRS as WKT or None) of each column's south-west corner; ``tiles``,
    ``done`` tiles per column and how many have the step done; ``points``
    and ``patches`` (-1 where a tile of the column has no fitted patch
    table) per column; ``failed`` the tiles per column that have not done
    the step and record a failed task; ``errors`` (tile, task, message)
    of those tiles.
    """

    url: str
    step: str
    steps: list
    tile_size: float
    columns: np.ndarray
    corner: np.ndarray
    tiles: np.ndarray
    done: np.ndarray
    points: np.ndarray
    patches: np.ndarray
    failed: np.ndarray
    errors: list
    crs: str | None = None

    @property
    def state(self) -> np.ndarray:
        """(C,) "failed", "done", "partly done" or "pending"."""
        s = np.where(self.done == self.tiles, "done", np.where(self.done > 0, "partly done", "pending"))
        return np.where(self.failed > 0, "failed", s)

    def counts(self) -> dict[str, int]:
        """Columns per state."""
        s = self.state
        return {k: int((s == k).sum()) for k in STATE_COLOURS}


def _patches_of(attrs: dict) -> int:
    for key in ("fit", "compress"):
        info = attrs.get(key)
        if isinstance(info, dict) and "patches" in info:
            return int(info["patches"])
    return -1


def tile_state(store: Store | str, step: str | None = None) -> TileState:
    """The state of every column of tiles of ``store`` at ``step`` (default: the last of TILE_STEPS any tile reached).

    Raises
    ------
    PatchcloudIOError
        Not a patchcloud store.
    PatchcloudValueError
        The store holds no tiles yet, or ``step`` is not a step of any of its tiles.
    """
    st = store if isinstance(store, Store) else Store.open(str(store), mode="r")
    tiles = st.tiles
    if not tiles:
        raise PatchcloudValueError(f"{st.url}: the store holds no tiles yet (its tiling did not finish)")
    counts = st.tile_counts
    attrs = [st.tile_attrs(t) for t in tiles]
    seen: list[str] = []
    for a in attrs:
        for k, v in a.get("done", {}).items():
            if v and k not in seen:
                seen.append(k)
    known = [s for s in TILE_STEPS if s in seen]
    steps = known + sorted(s for s in seen if s not in TILE_STEPS)
    if step is None:  # the last of the steps a job's tiles go through (not a job's own bookkeeping, e.g. compress' records)
        step = known[-1] if known else (steps[-1] if steps else "sort")
    elif step not in TILE_STEPS and step not in seen:
        raise PatchcloudValueError(
            f"{st.url}: no tile has a step {step!r}; steps: {', '.join(TILE_STEPS)} (done on some tile: {', '.join(steps) or 'none'})"
        )
    ijk = np.asarray(tiles, dtype=np.int64).reshape(-1, 3)
    done = np.array([bool(a.get("done", {}).get(step)) for a in attrs])
    failed = np.array([bool(a.get("failed")) for a in attrs]) & ~done
    errors = [(t, task, msg) for t, a, f in zip(tiles, attrs, failed) if f for task, msg in a["failed"].items()]
    patches = np.array([_patches_of(a) for a in attrs], dtype=np.int64)
    cols, inv = np.unique(ijk[:, :2], axis=0, return_inverse=True)
    inv = inv.ravel()
    C = cols.shape[0]
    n_tiles = np.bincount(inv, minlength=C)
    n_done = np.bincount(inv, weights=done, minlength=C).astype(np.int64)
    pts = np.bincount(inv, weights=counts[: len(tiles)] if counts.size >= len(tiles) else None, minlength=C).astype(np.int64)
    pat = np.bincount(inv, weights=np.maximum(patches, 0), minlength=C).astype(np.int64)
    missing = np.bincount(inv, weights=patches < 0, minlength=C) > 0
    pat[missing] = -1
    g = st.grid
    corner = cols * g.tile_size + np.asarray(g.origin[:2])
    n_failed = np.bincount(inv, weights=failed, minlength=C).astype(np.int64)
    try:
        crs = st.catalog.crs
    except (KeyError, TypeError, ValueError):  # a store without its catalog's record: no CRS to name the axes by
        crs = None
    return TileState(st.url, step, steps, g.tile_size, cols, corner, n_tiles, n_done, pts, pat, n_failed, errors, crs)


@dataclass
class TilesSummary:
    """What :func:`render_tiles` drew: columns per state, tiles, points, patches."""

    store: str
    output: str
    step: str
    by: str
    columns: int
    tiles: int
    tiles_done: int
    done: int
    partly_done: int
    pending: int
    points: int
    patches: int | None
    seconds: float
    failed: int = 0
    errors: list = field(default_factory=list)

    def format(self) -> str:
        pat = "" if self.patches is None else f", {self.patches:,} patches"
        lines = [
            f"{self.output}: step {self.step}: {self.tiles_done:,} of {self.tiles:,} tiles done; columns: {self.failed:,} failed, "
            f"{self.done:,} done, {self.partly_done:,} partly done, {self.pending:,} pending; {self.points:,} points{pat}, "
            f"{self.seconds:.1f} s"
        ]
        lines += [f"  failed: tile {tuple(int(v) for v in t)} in {task}: {msg}" for t, task, msg in self.errors[:20]]
        if len(self.errors) > 20:
            lines.append(f"  ... and {len(self.errors) - 20:,} more failed tiles")
        return "\n".join(lines)


def tiles_figure(ts: TileState, by: str = "points"):
    """The two panels (state, points or patches per column) as a Figure on an Agg canvas."""
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.collections import PatchCollection
    from matplotlib.colors import LogNorm, Normalize
    from matplotlib.patches import Patch, Rectangle

    from patchcloud.stream.views.plots import CMAP, STYLE, shorten, new_figure, style_axes
    from patchcloud.stream.views.units import axis_names

    names = axis_names(ts.crs)

    T = ts.tile_size
    x0, y0 = ts.corner.min(axis=0)
    x1, y1 = ts.corner.max(axis=0) + T
    aspect = (y1 - y0) / max(x1 - x0, 1e-9)
    w = 4.6
    fig, (ax, bx) = new_figure(2 * w + 2.6, min(max(w * aspect + 1.2, 3.2), 14.0), 2)
    state = ts.state

    def squares(colours, axes):
        rects = [Rectangle((cx, cy), T, T) for cx, cy in ts.corner]
        pc = PatchCollection(rects, facecolor=colours, edgecolor="white", linewidth=0.6 if len(rects) < 2000 else 0.0)
        axes.add_collection(pc)
        axes.set_xlim(x0 - 0.02 * T, x1 + 0.02 * T)
        axes.set_ylim(y0 - 0.02 * T, y1 + 0.02 * T)
        axes.set_aspect("equal")
        axes.ticklabel_format(useOffset=False, style="plain")
        axes.tick_params(axis="x", labelrotation=30)

    squares([STATE_COLOURS[s] for s in state], ax)
    counts = ts.counts()
    handles = [Patch(facecolor=c, label=f"{k}: {counts[k]:,}") for k, c in STATE_COLOURS.items()]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=STYLE["annotation"], frameon=False,
              title="columns", title_fontsize=STYLE["annotation"])
    style_axes(ax, f"state at step '{ts.step}' ({int(ts.done.sum()):,} of {int(ts.tiles.sum()):,} tiles done)", names.x, names.y)

    values = ts.points if by == "points" else ts.patches
    known = values >= 0
    v = values[known].astype(np.float64)
    pos = v[v > 0]
    cmap = colormaps[CMAP]
    if pos.size and pos.max() > 10 * pos.min():
        norm = LogNorm(vmin=pos.min(), vmax=pos.max())
    else:
        norm = Normalize(vmin=0.0, vmax=max(float(v.max()) if v.size else 1.0, 1.0))
    colours = np.tile(np.array([0.8, 0.8, 0.8, 1.0]), (values.size, 1))
    if v.size:
        colours[known] = cmap(norm(np.maximum(v, norm.vmin if isinstance(norm, LogNorm) else v)))
    squares(colours, bx)
    if values.size <= 100:  # few columns: write the numbers in them
        for (cx, cy), val, rgba in zip(ts.corner, values, colours):
            light = 0.299 * rgba[0] + 0.587 * rgba[1] + 0.114 * rgba[2] > 0.5
            bx.text(cx + T / 2, cy + T / 2, "?" if val < 0 else f"{int(val):,}", ha="center", va="center",
                    fontsize=STYLE["annotation"], color="black" if light else "white")
    cb = fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=bx, shrink=0.8)
    cb.set_label(f"{by} per column", fontsize=STYLE["label"])
    cb.ax.tick_params(labelsize=STYLE["tick"])
    total = int(v.sum())
    extra = "" if known.all() else f"; grey: no patch table ({int((~known).sum()):,})"
    style_axes(bx, f"{by} per column ({total:,} in all{extra})", names.x, None)
    fig.suptitle(f"tiles of {shorten(ts.url, 70)}: {len(ts.tiles):,} columns of tiles {T:g} {names.horizontal} wide", fontsize=STYLE["suptitle"])
    return fig


def render_tiles(store: str | os.PathLike, output: str | os.PathLike, *, by: str = "points", step: str | None = None) -> TilesSummary:
    """Write a PNG of the tile grid of ``store`` seen from above: state of every column at ``step``, and points (or patches) per column.

    Parameters
    ----------
    store : path or URL of a patchcloud store (``patchcloud tile``, ``normals --keep-store``...).
    output : the PNG (written atomically; an existing file is replaced).
    by : {"points", "patches"}
        What the second panel shows; patches come from the tiles' fit (or compress) step.
    step : str, optional
        One of :data:`TILE_STEPS`; default the last of them that any tile reached.

    Returns
    -------
    TilesSummary

    Raises
    ------
    PatchcloudIOError
        Not a store, or the PNG cannot be written.
    PatchcloudValueError
        A bad ``by`` or ``step``, no tiles, or ``by="patches"`` on a store whose tiles have no patch table.

    Examples
    --------
    >>> from patchcloud.stream import normals
    >>> _ = normals(sample, tmp / "n.laz", store=str(tmp / "s.zarr"), quiet=True)   # keeps its store
    >>> s = render_tiles(tmp / "s.zarr", tmp / "tiles.png", by="patches")
    >>> s.step, s.columns, s.done, s.failed, s.points, s.patches > 0
    ('finish', 2, 2, 0, 60653, True)
    >>> print(s.format())   # doctest: +ELLIPSIS
    /...tiles.png: step finish: 2 of 2 tiles done; columns: 0 failed, 2 done, 0 partly done, 0 pending; 60,653 points, ... patches, ... s
    """
    from patchcloud.stream.views.plots import check_png_path, save_png

    t0 = time.perf_counter()
    if by not in ("points", "patches"):
        raise PatchcloudValueError(f"by must be 'points' or 'patches'; got {by!r}")
    out = check_png_path(output)
    if not Store.exists(str(store)):
        raise PatchcloudIOError(f"{store}: not a patchcloud store")
    ts = tile_state(str(store), step)
    if by == "patches" and (ts.patches < 0).all():
        raise PatchcloudValueError(f"{store}: no tile has a patch table yet (run patchcloud normals with --store first); use --by points")
    save_png(tiles_figure(ts, by), out)
    c = ts.counts()
    return TilesSummary(
        store=str(store), output=str(out), step=ts.step, by=by, columns=len(ts.tiles), tiles=int(ts.tiles.sum()),
        tiles_done=int(ts.done.sum()), done=c["done"], partly_done=c["partly done"], pending=c["pending"], failed=c["failed"],
        errors=ts.errors,
        points=int(ts.points.sum()), patches=None if (ts.patches < 0).all() else int(ts.patches[ts.patches >= 0].sum()),
        seconds=time.perf_counter() - t0,
    )
