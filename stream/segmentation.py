"""The stream's Difference-of-Normals jobs: ``don`` (DoN per point) and ``segment`` (DoN segments).

Both run on the tiled store of :mod:`.pipeline` (the same ``tile`` step,
store, schedulers and resume rules as ``patchcloud normals``):

1. tile (shared with ``normals``; a store made by either is reused);
2. skin: each tile's points within the halo width of its faces;
3. DoN: one task per tile, over the tile plus its neighbours' skins, which
   hold every point within ``r_large`` (plus, in fast mode, half a voxel
   diagonal) of the tile: a point's DoN is the one a whole-cloud run
   computes, bit for bit, whatever the tile size;
4. (segment) cluster: components of each tile's kept points, with the
   kept points of the neighbours' skins within the tolerance;
5. (segment) merge: one union-find over all tiles' components gives
   segments that cross tile faces, sized over the whole file;
6. export: the input with DoN, DoNX, DoNY, DoNZ (and ClusterID), segment
   ids numbered 1, 2, ... in order of their first point in the file, as
   :func:`patchcloud.core.segment_don` numbers them.
"""

from __future__ import annotations

import math
import os
import shutil
import time
from dataclasses import dataclass, field

import numpy as np

from patchcloud.core.cluster import check_cluster_sizes
from patchcloud.core.don import check_scales, check_threshold
from patchcloud.core.radius import check_mode, check_radius, check_viewpoint, halo_width

from . import don_steps
from .export import Column, FirstSeenIds, export_columns
from .lasio import DON_DIMS, SEGMENT_DIMS, LasSource
from .pipeline import _ensure_tiled, _params_key, _validate, open_job, time_and_memory_lines
from .scheduling import Runner, map_tiles
from .store import Store

__all__ = ["don", "segment", "DonSummary", "default_viewpoint_of"]


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
    scheduler: str = "threads"
    store: str = ""

    def median_magnitude(self) -> float:
        """Median DoN magnitude of the points where it is defined (from the histogram: to 1/50)."""
        h = np.asarray(self.histogram, dtype=np.int64)
        if h.sum() == 0:
            return float("nan")
        k = int(np.searchsorted(np.cumsum(h), (h.sum() + 1) // 2))
        return (k + 0.5) / h.size

    def format(self) -> str:
        n = max(self.points, 1)
        p = self.parameters
        lines = [
            f"{self.input} -> {self.output}",
            f"  points          {self.points:,}",
            f"  tiles           {self.tiles:,} of {self.tile_size:g} m",
            f"  scales          r_s {p['r_small']:g} m, r_l {p['r_large']:g} m, mode {p['mode']}",
            f"  DoN defined     {self.defined:,} ({self.defined / n:.1%}); median magnitude {self.median_magnitude():.2f}",
        ]
        if self.kept is not None:
            extra = f", |DoN_{p['axis']}| >= {p['axis_threshold']:g}" if p.get("axis") else ""
            lines.append(f"  kept            {self.kept:,} ({self.kept / n:.1%}) with magnitude >= {p['threshold']:g}{extra}")
        if self.segments is not None:
            mx = p["max_cluster"]
            lines.append(
                f"  segments        {self.segments:,} (tolerance {p['tolerance']:g} m, {p['min_cluster']}"
                f"{'' if mx is None else f'-{mx}'}{'+' if mx is None else ''} points)"
            )
        lines += time_and_memory_lines(self.seconds, self.points, self.peak_memory, self.scheduler)
        return "\n".join(lines)


def default_viewpoint_of(src: LasSource) -> np.ndarray:
    """The default viewpoint of a file (its coordinates): as :func:`patchcloud.core.default_viewpoint`, from the header's bounds."""
    lo, hi = np.asarray(src.mins, dtype=np.float64), np.asarray(src.maxs, dtype=np.float64)
    ext = float(max((hi - lo).max(), 1.0))
    return np.array([(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0, hi[2] + ext])


def _check(r_small, r_large, mode, resolution, min_points, viewpoint) -> None:
    check_scales(r_small, r_large)
    check_mode(mode, resolution, min_points)
    if viewpoint is not None:
        check_viewpoint(viewpoint)


def _run(
    input, output, *, segmenting: bool, r_small, r_large, mode, resolution, min_points, viewpoint, threshold=None,
    axis=None, axis_threshold=None, tolerance=None, min_cluster=1, max_cluster=None, tile_size, scheduler, workers,
    store, keep_store, overwrite, quiet, chunk,
) -> DonSummary:
    _validate(tile_size, criterion="rmse", orient="up")
    _check(r_small, r_large, mode, resolution, min_points, viewpoint)
    if segmenting:
        check_threshold(threshold, axis, axis_threshold)
        check_radius("tolerance", tolerance)
        min_cluster, max_cluster = check_cluster_sizes(min_cluster, max_cluster)
    out, src, url, keep_store = open_job(input, output, store, keep_store, overwrite)
    seconds: dict[str, float] = {}
    with Runner(scheduler, workers, quiet=quiet) as runner:
        st, seconds["tile"] = _ensure_tiled(src, url, tile_size, runner, quiet, chunk)
        origin = np.asarray(st.grid.origin)
        vp = default_viewpoint_of(src) if viewpoint is None else np.asarray(viewpoint, dtype=np.float64)
        params = dict(
            r_small=float(r_small), r_large=float(r_large), mode=mode, resolution=int(resolution), min_points=int(min_points),
            viewpoint_local=(vp - origin).tolist(), threshold=None if threshold is None else float(threshold), axis=axis,
            axis_threshold=None if axis_threshold is None else float(axis_threshold),
        )
        if mode == "fast":  # whether voxels pay off, from the whole file (as a whole-cloud run decides it)
            params["density_small"] = _density(st, params["r_small"] / params["resolution"])
            params["density_large"] = _density(st, params["r_large"] / params["resolution"])
        params["don_width"] = halo_width(params["r_large"], mode, params["resolution"])
        params["don_key"] = _params_key(params)
        width = params["don_width"]
        if segmenting:
            params.update(tolerance=float(tolerance), min_cluster=min_cluster, max_cluster=max_cluster)
            params["cluster_key"] = _params_key({"don": params["don_key"], "tolerance": params["tolerance"]})
            width = max(width, params["tolerance"] * (1 + 1e-9))
        halo = max(1, math.ceil(width / st.grid.tile_size))

        t0 = time.perf_counter()
        skin_key = _params_key({"width": width})
        todo = [t for t in st.tiles if st.tile_attrs(t).get("done", {}).get("don_skin") != skin_key]
        map_tiles(don_steps.skin_tile, st, tiles=todo, runner=runner, label="skin", width=width, key=skin_key)
        seconds["skin"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        infos = map_tiles(don_steps.don_tile, st, halo=halo, runner=runner, label="DoN", params=params)
        seconds["don"] = time.perf_counter() - t0

        n_segments = None
        if segmenting:
            t0 = time.perf_counter()
            map_tiles(don_steps.cluster_tile, st, halo=halo, runner=runner, label="cluster", params=params)
            n_segments = don_steps.merge_components(st, min_cluster, max_cluster)
            seconds["cluster"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        _export(st, src, str(out), segmenting, overwrite, quiet)
        seconds["export"] = time.perf_counter() - t0
        peak = runner.peak_memory()
    if not keep_store and "://" not in url:
        shutil.rmtree(url, ignore_errors=True)
    v = list(infos.values())
    return DonSummary(
        input=src.path, output=str(out), points=src.point_count, tiles=len(st.tiles), tile_size=st.grid.tile_size,
        parameters={k: params[k] for k in params if not k.endswith("_key")}, defined=sum(i["defined"] for i in v),
        kept=sum(i["kept"] for i in v) if segmenting else None, segments=n_segments,
        histogram=np.sum([i["hist"] for i in v], axis=0).astype(int).tolist() if v else [],
        seconds=seconds, peak_memory=peak, scheduler=scheduler, store=url if keep_store else "",
    )


def _density(st: Store, edge: float) -> float:
    """:func:`patchcloud.core.radius.cell_density` of the whole file, from the store's occupancy counts.

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


def _export(st: Store, src: LasSource, output: str, segmenting: bool, overwrite: bool, quiet: bool) -> None:
    def magnitude_and_vector(t, v):
        return np.column_stack([np.sqrt(np.einsum("ij,ij->i", v, v)), v])

    columns = [Column("don", ("DoN", "DoNX", "DoNY", "DoNZ"), np.float32, per_tile=magnitude_and_vector)]
    dims = DON_DIMS
    if segmenting:
        tiles = st.tiles
        maps: dict[int, np.ndarray] = {}

        def segment_of(t, comp):
            if t not in maps:
                maps[t] = np.r_[0, st.read(tiles[t], "comp_map")]  # comp -1 (not kept) -> 0
            return maps[t][comp.astype(np.int64) + 1]

        columns.append(Column("comp", ("ClusterID",), np.uint64, per_tile=segment_of, per_chunk=FirstSeenIds()))
        dims = SEGMENT_DIMS
    export_columns(st, src, output, columns, dims, overwrite=overwrite, quiet=quiet)


_COMMON_DOC = """r_small, r_large : float
        Support radii of the two normals (metres), ``r_small < r_large``.
    mode : {"fast", "exact"}
        Radius normals from voxel moments (default: cost independent of the
        points per ball) or by PCA of every point in the ball (the
        reference, PCL's definition); see :func:`patchcloud.core.radius_normals`.
    viewpoint : (3,) array, optional
        Both normals face it (the file's coordinates).  Default: above the
        middle of the file's bounding box, one extent above its top.
    resolution, min_points :
        As :func:`patchcloud.core.radius_normals`.
    tile_size, scheduler, workers, store, keep_store, overwrite, quiet :
        As :func:`patchcloud.stream.normals`.
"""


def don(
    input: str | os.PathLike, output: str | os.PathLike, *, r_small: float = 0.2, r_large: float = 2.0, mode: str = "fast",
    viewpoint=None, resolution: int = 4, min_points: int = 3, tile_size: float | None = None, scheduler: str = "threads",
    workers: int | None = None, store: str | None = None, keep_store: bool | None = None, overwrite: bool = False,
    quiet: bool = False, chunk: int = 1 << 20,
) -> DonSummary:
    """Difference of Normals of every point of a LAS/LAZ file of any size.

    ``output`` is the input (every point once, in input order, every
    original dimension unchanged) plus ``DoN`` (magnitude, in [0, 1]) and
    ``DoNX``, ``DoNY``, ``DoNZ`` (the vector ``(n_s - n_l) / 2``), float32;
    NaN where a normal is undefined (fewer than ``min_points`` points in a
    ball, or collinear ones).

    Parameters
    ----------
    input, output : path
        LAS or LAZ in; LAS or LAZ out (LAZ when ``output`` ends in .laz).
    {common}
    Returns
    -------
    DonSummary

    Examples
    --------
    >>> from patchcloud.stream import don                              # doctest: +SKIP
    >>> print(don("street.laz", "street_don.laz", r_small=0.2, r_large=2.0).format())  # doctest: +SKIP
    """
    return _run(
        input, output, segmenting=False, r_small=r_small, r_large=r_large, mode=mode, resolution=resolution,
        min_points=min_points, viewpoint=viewpoint, tile_size=tile_size, scheduler=scheduler, workers=workers, store=store,
        keep_store=keep_store, overwrite=overwrite, quiet=quiet, chunk=chunk,
    )


def segment(
    input: str | os.PathLike, output: str | os.PathLike, *, r_small: float = 0.2, r_large: float = 2.0,
    threshold: float = 0.25, tolerance: float = 0.2, min_cluster: int = 50, max_cluster: int | None = None,
    axis: str | None = None, axis_threshold: float | None = None, mode: str = "fast", viewpoint=None,
    resolution: int = 4, min_points: int = 3, tile_size: float | None = None, scheduler: str = "threads",
    workers: int | None = None, store: str | None = None, keep_store: bool | None = None, overwrite: bool = False,
    quiet: bool = False, chunk: int = 1 << 20,
) -> DonSummary:
    """DoN segments of a LAS/LAZ file of any size: threshold the DoN magnitude, cluster the points kept.

    ``output`` is the input plus the dimensions of :func:`don` and
    ``ClusterID`` (uint64, PDAL's name): 1, 2, ... in order of each
    segment's first point in the file, 0 for points in no segment.
    Segments that cross tile faces get one id.

    Parameters
    ----------
    input, output : path
    threshold : float
        Smallest DoN magnitude of a point kept, in [0, 1].
    tolerance : float
        Largest gap (metres) between two points of one segment.
    min_cluster, max_cluster : int
        Segments of fewer or more points (over the whole file) get 0.
    axis, axis_threshold :
        Also require ``|DoN_axis| >= axis_threshold`` (axis "x", "y" or "z";
        e.g. "z" for kerbs).
    {common}
    Returns
    -------
    DonSummary
    """
    return _run(
        input, output, segmenting=True, r_small=r_small, r_large=r_large, mode=mode, resolution=resolution,
        min_points=min_points, viewpoint=viewpoint, threshold=threshold, axis=axis, axis_threshold=axis_threshold,
        tolerance=tolerance, min_cluster=min_cluster, max_cluster=max_cluster, tile_size=tile_size, scheduler=scheduler,
        workers=workers, store=store, keep_store=keep_store, overwrite=overwrite, quiet=quiet, chunk=chunk,
    )


don.__doc__ = don.__doc__.replace("{common}", _COMMON_DOC.strip("\n"))
segment.__doc__ = segment.__doc__.replace("{common}", _COMMON_DOC.strip("\n"))
