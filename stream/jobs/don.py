"""``don``: the Difference of Normals of every point of a LAS/LAZ file of any size.

The job's steps (each resumable), on the scaffold of :mod:`patchcloud.stream.engine.job`:

1. tile (shared with every job; a store made by any job is reused);
2. skin: each tile's points within the halo width of its faces;
3. DoN: one task per tile, over the tile plus its neighbours' skins, which
   hold every point within ``r_large`` (plus, in fast mode, half a voxel
   diagonal) of the tile: a point's DoN is the one a whole-cloud run
   computes, bit for bit, whatever the tile size;
4. export: the input plus :data:`DON_DIMS`.

``segment`` (:mod:`.segment`) is this job with two more steps.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from patchcloud.core import DonOptions, PatchcloudValueError, halo_width
from patchcloud.stream.engine.export import Column
from patchcloud.stream.engine.job import (
    Job, JobContext, RunOptions, file_lines, left_out_lines, params_key, run_job, split_options, time_and_memory_lines, units_line,
)
from patchcloud.stream.io.catalog import Catalog
from patchcloud.stream.io.dims import DON_DIMS, DON_NO_DATA
from patchcloud.stream.io.las import LasSource
from patchcloud.stream.io.store import Store
from patchcloud.stream.jobs import don_tiles

__all__ = ["don", "DonJob", "DonSummary", "default_viewpoint_of", "cloud_density", "magnitude_and_vector"]

#: Below this share of points with a DoN the summary says why and what to change.
FEW_DEFINED = 0.5


@dataclass
class DonSummary:
    """What a ``don`` or ``segment`` run did (times in seconds, memory in bytes)."""

    input: str
    output: str
    points: int
    tiles: int
    tile_size: float
    parameters: dict
    defined: int
    kept: int | None = None
    segments: int | None = None
    histogram: list[int] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    peak_memory: int = 0
    compile_seconds: float = 0.0  # numba compiling the kernels (a first run), not in seconds
    scheduler: str = "threads"
    store: str = ""
    files: list = field(default_factory=list)  # (input, output, points) of each file of a catalog
    units: dict = field(default_factory=lambda: {"symbol": "m"})  # the file's length unit (patchcloud.stream.io.crs.Units)
    left_out: dict = field(default_factory=dict)  # points left out of every neighbourhood, by reason (stream.io.classes.REASONS)
    selection: dict | None = None  # the classes asked for and keep_noise (Selection.to_json)

    def median_bin(self) -> int | None:
        """The histogram bin (of 1/50) that holds the median DoN magnitude of the points where it is defined; None for none."""
        h = np.asarray(self.histogram, dtype=np.int64)
        if h.sum() == 0:
            return None
        return int(np.searchsorted(np.cumsum(h), (h.sum() + 1) // 2))

    def median_magnitude(self) -> float:
        """Median DoN magnitude of the points where it is defined (from the histogram: the middle of its bin of 1/50)."""
        k = self.median_bin()
        return float("nan") if k is None else (k + 0.5) / len(self.histogram)

    def median_words(self) -> str:
        """:meth:`median_magnitude` as the bin that holds it, for the summary and the report: ``"0.22-0.24"``, or
        ``"below 0.02"`` for the first bin (a plane's 1e-18 is no "0.01").

        >>> flat = DonSummary("in.las", "out.las", 6, 1, 8.0, {}, 6, histogram=[5, 1] + [0] * 48)
        >>> flat.median_words(), DonSummary("in.las", "out.las", 3, 1, 8.0, {}, 3, histogram=[0] * 11 + [3] + [0] * 38).median_words()
        ('below 0.02', '0.22-0.24')
        """
        k, size = self.median_bin(), len(self.histogram)
        return f"below {1 / size:.2f}" if k == 0 else f"{k / size:.2f}-{(k + 1) / size:.2f}"

    def format(self) -> str:
        n = max(self.points, 1)
        p = self.parameters
        u = self.units["symbol"]
        lines = [
            f"{self.input} -> {self.output}",
            f"  points          {self.points:,}",
            f"  tiles           {self.tiles:,} of {self.tile_size:g} {u}",
            units_line(self.units),
            f"  scales          r_s {p['r_small']:g} {u}, r_l {p['r_large']:g} {u}, mode {p['mode']}",
            f"  DoN defined     {self.defined:,} ({self.defined / n:.1%})"
            + (f"; median magnitude {self.median_words()}" if self.defined else ""),
            *left_out_lines(self.left_out, self.selection, self.points),
        ]
        if self.points and self.defined < FEW_DEFINED * self.points:
            lines.append(f"  note            most points have no DoN: their r_s ball holds fewer than {p.get('min_points', 3)} points, "
                         f"or points of one line (a scan line); a larger --rs, a few times the point spacing, gives them one")
        if self.kept is not None:
            extra = f", |DoN_{p['axis']}| >= {p['axis_threshold']:g}" if p.get("axis") else ""
            lines.append(f"  kept            {self.kept:,} ({self.kept / n:.1%}) with magnitude >= {p['threshold']:g}{extra}")
        if self.segments is not None:
            mx = p["max_cluster"]
            lines.append(
                f"  segments        {self.segments:,} (tolerance {p['tolerance']:g} {u}, {p['min_cluster']}"
                f"{'' if mx is None else f'-{mx}'}{'+' if mx is None else ''} points)"
            )
        lines += time_and_memory_lines(self.seconds, self.points, self.peak_memory, self.scheduler, self.compile_seconds)
        lines += file_lines(self.files)
        return "\n".join(lines)


def default_viewpoint_of(src: LasSource | Catalog) -> np.ndarray:
    """The default viewpoint of a file or catalog (file coordinates): as :func:`patchcloud.core.default_viewpoint`, from the headers' bounds."""
    lo, hi = np.asarray(src.mins, dtype=np.float64), np.asarray(src.maxs, dtype=np.float64)
    ext = float(max((hi - lo).max(), 1.0))
    return np.array([(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0, hi[2] + ext])


def catalog_step(catalog: Catalog) -> float:
    """The step a catalog's coordinates are rounded to: the largest scale of its common grid (file units), the
    ``rounding`` of :func:`patchcloud.core.radius_normals` (a ball collinear up to it has no normal).

    The catalog is its merged file, written on that grid: files of coarser
    scales take its step too (their largest scale gave DoN 0 to points whose
    balls the merged file's run finds not collinear: bug hunt F)."""
    return float(max(catalog.scale))


def cloud_density(st: Store, edge: float) -> float:
    """:func:`patchcloud.core.cell_density` of the whole file, from the store's occupancy counts.

    Cells of a power-of-two edge no larger than a tile are cells of the
    tiles' octrees, so the counts add up over tiles exactly.  A cell larger
    than the tiles is scaled from the tile level as a surface's count
    scales (an estimate, the same for every tile).
    """
    occ = {int(k): int(v) for k, v in st.attrs["occupancy"].items()}
    n = int(st.tile_counts.sum())
    e = int(np.floor(np.log2(edge)))
    if e in occ:
        return n / occ[e]
    top = max(occ)
    return n / occ[top] * 4.0 ** (e - top)


def magnitude_and_vector(store: Store, t: int, v: np.ndarray) -> np.ndarray:
    """(n, 4): the DoN vectors' length, then the vectors (what the output's DoN, DoNX/Y/Z hold); :data:`DON_NO_DATA`
    in all four where the DoN is undefined (NaN in the store).

    >>> magnitude_and_vector(None, 0, np.array([[0.0, 0.6, 0.8], [np.nan, np.nan, np.nan]])).tolist()
    [[1.0, 0.0, 0.6, 0.8], [0.0, 0.0, 0.0, 0.0]]
    """
    out = np.column_stack([np.sqrt(np.einsum("ij,ij->i", v, v)), v])
    out[~np.isfinite(out).all(axis=1)] = DON_NO_DATA
    return out


class DonJob(Job):
    """The steps of ``don`` on the scaffold; :class:`patchcloud.stream.jobs.segment.SegmentJob` adds two."""

    name = "don"

    def __init__(self, options: DonOptions) -> None:
        self.options = options
        self.params: dict = {}
        self.origin = None  # the store grid's origin, once resolved
        self.width = 0.0
        self.halo = 1
        self.infos: dict = {}

    def steps(self):
        return [("skin", self.skin), ("don", self.don)]

    def check(self, catalog) -> None:
        """A radius (or, for segments, a tolerance) wider than the cloud's bounds' diagonal is refused: every ball would
        hold every point (and each tile's halo the whole cloud); so is a radius narrower than the files' coordinate
        step (the largest scale of their common grid): a ball would hold copies of its point alone.  Bounds of zero width (a header that
        does not state them) check the first only."""
        step = catalog_step(catalog)
        for name, r in (("r_small", float(self.options.r_small)), ("r_large", float(self.options.r_large))):
            if r < step:
                raise PatchcloudValueError(f"{name}={r:g} is narrower than the coordinates' step ({step:g}, the files' "
                                           "common grid's scale): a ball would hold nothing but copies of its point")
        across = float(np.linalg.norm(np.subtract(catalog.maxs, catalog.mins)))
        if across <= 0 or not np.isfinite(across):
            return
        for name, r, meaning in self.lengths():
            if r > across:
                raise PatchcloudValueError(f"{name}={r:g} is wider than the cloud ({across:,.4g} across its bounds' diagonal, "
                                           f"in its unit): {meaning}")

    def lengths(self) -> list[tuple[str, float, str]]:
        """The lengths :meth:`check` holds to the cloud's size: (parameter name, value, what one wider would mean)."""
        ball = "every ball would hold every point"
        return [("r_small", float(self.options.r_small), ball), ("r_large", float(self.options.r_large), ball)]

    def resolve(self, ctx: JobContext) -> None:
        """The resolved parameters (viewpoint in the store's frame, densities, halo) and their key."""
        o, st = self.options, ctx.store
        origin = self.origin = np.asarray(st.grid.origin)
        vp = default_viewpoint_of(ctx.catalog) if o.viewpoint is None else np.asarray(o.viewpoint, dtype=np.float64)
        self.params = dict(
            r_small=o.r_small, r_large=o.r_large, mode=o.mode, resolution=o.resolution, min_points=o.min_points,
            viewpoint_local=(vp - origin).tolist(), rounding=catalog_step(ctx.catalog),
            grid_step=float(min(st.grid.scale)), **self.selection(),  # the store's grid: ties decided on it
        )
        if o.mode == "fast":  # whether voxels pay off, from the whole file (as a whole-cloud run decides it)
            self.params["density_small"] = cloud_density(st, o.r_small / o.resolution)
            self.params["density_large"] = cloud_density(st, o.r_large / o.resolution)
        self.params["don_width"] = halo_width(o.r_large, o.mode, o.resolution)
        self.params["don_key"] = params_key(self.params)
        self.width = self.params["don_width"]

    def selection(self) -> dict:
        """Which points the DoN step marks kept (none here; ``segment`` thresholds)."""
        return dict(threshold=None, axis=None, axis_threshold=None)

    def skin(self, ctx: JobContext) -> None:
        self.resolve(ctx)
        self.halo = max(1, math.ceil(self.width / ctx.store.grid.tile_size))
        skin_key = params_key({"width": self.width})
        todo = [t for t in ctx.store.tiles if ctx.store.tile_attrs(t).get("done", {}).get("don_skin") != skin_key]
        ctx.map_tiles(don_tiles.skin_tile, tiles=todo, label="skin", width=self.width, key=skin_key)

    def don(self, ctx: JobContext) -> None:
        self.infos = ctx.map_tiles(don_tiles.don_tile, halo=self.halo, label="DoN", params=self.params)

    def dims(self):
        return DON_DIMS

    def columns(self, ctx: JobContext):
        return [Column("don", ("DoN", "DoNX", "DoNY", "DoNZ"), np.float32, per_tile=magnitude_and_vector)], self.dims()

    def summarise(self, ctx: JobContext) -> DonSummary:
        v = list(self.infos.values())
        return DonSummary(
            input=ctx.input_name, output=str(ctx.output), points=ctx.catalog.point_count, tiles=len(ctx.store.tiles),
            tile_size=ctx.store.grid.tile_size, parameters=self.parameters(),
            defined=sum(i["defined"] for i in v), histogram=np.sum([i["hist"] for i in v], axis=0).astype(int).tolist() if v else [],
            seconds=ctx.seconds, peak_memory=ctx.peak_memory, compile_seconds=ctx.compile_seconds, scheduler=ctx.scheduler, store=ctx.kept_store, files=ctx.files,
            units=ctx.units.to_json(), left_out=dict(ctx.store.attrs.get("left_out", {})), selection=ctx.store.attrs.get("selection"),
        )


def don(
    input, output: str | os.PathLike | None = None, options: DonOptions | None = None, run: RunOptions | None = None,
    **kwargs,
) -> DonSummary:
    """Difference of Normals of every point of a LAS/LAZ file of any size.

    ``output`` is the input (every point once, in input order, every
    original dimension unchanged) plus :data:`DON_DIMS`: ``DoN``
    (magnitude, in [0, 1]) and ``DoNX``, ``DoNY``, ``DoNZ`` (the vector
    ``(n_s - n_l) / 2``), float32; 0 in all four where a normal is
    undefined (fewer than ``min_points`` points in a ball, or collinear
    ones), the descriptors' no-data value (:data:`DON_NO_DATA`).

    Parameters
    ----------
    input, output : path
        LAS or LAZ in; LAS or LAZ out (LAZ when ``output`` ends in .laz).
    options : DonOptions, optional
        What to compute (:class:`patchcloud.core.DonOptions`: ``r_small``,
        ``r_large``, ``mode``, ``viewpoint`` in the file's coordinates,
        default above the middle of the file, one extent above its top).
    run : RunOptions, optional
        How to run it (:class:`patchcloud.stream.RunOptions`).
    **kwargs
        Any field of either, by name.

    Returns
    -------
    DonSummary

    Examples
    --------
    >>> s = don(sample, tmp / "don.laz", r_small=0.5, r_large=2.0, quiet=True)
    >>> s.points, 0 < s.defined <= s.points
    (60653, True)
    """
    options, run = split_options(kwargs, options, DonOptions, run)
    return run_job(DonJob(options), input, output, run)
