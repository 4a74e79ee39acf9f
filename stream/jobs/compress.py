"""``compress``: a LAS/LAZ file of any size to a ``.pcz`` of quadric patch models and residual points.

The job's steps, on the scaffold of :mod:`patchcloud.stream.engine.job` (a
store made by ``normals``, ``don`` or ``segment`` is reused):

1. tile (shared), then ``records``: every point's record bytes bucketed by tile;
2. ``fit``, per tile (one dask task each): :func:`patchcloud.core.fit_models` with
   the budget as the RMSE threshold, the tile as the octree's root and the
   whole file's spacing (touching leaves merged into larger patches); the
   models quantised within half the budget; the majority class and mean
   intensity of the points of each patch's octree cell (the tile's
   intensities on 64 levels); the residual points' coordinates and records
   (:mod:`patchcloud.stream.io.residual_points`);
3. ``pack`` (the job's write): the tiles' parts into one ``.pcz``
   (:mod:`patchcloud.stream.io.pcz`), tile after tile.

``decompress`` (:mod:`.decompress`) reads it back.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import laspy
import numpy as np

from patchcloud.core import (
    CompressOptions, PatchcloudValueError, PatchModels, QuantisedModels, dequantise_models, fit_models, patch_distances, quantise_models,
)
from patchcloud.stream.engine.export import complete_outputs, file_record, record_output
from patchcloud.stream.engine.ingest import bucket_records, make_grid, occupancy_spacing
from patchcloud.stream.engine.job import (
    Job, JobContext, RunOptions, catalog_units, left_out_lines, params_key, run_job, run_request, split_options, time_and_memory_lines,
)
from patchcloud.stream.io.classes import REASONS, Selection
from patchcloud.stream.io import pcz
from patchcloud.stream.io.catalog import Catalog, check_out_dir, expand_inputs, open_catalog, output_paths
from patchcloud.stream.io.las import LasSource, atomic_output, check_not_input, check_writable, open_source, raw_header
from patchcloud.stream.io.point_coding import check_drop, coarse_steps, dropped_fields
from patchcloud.stream.io.residual_points import (
    CODING, KEPT, coarse_intensity, intensity_shift, kept_words, residual_block, residual_dropped,
)
from patchcloud.stream.io.store import Store

__all__ = ["compress", "compress_catalog", "CATALOG_RECORD", "CompressJob", "CompressSummary", "compress_tile", "pcz_source", "check_budget_fits_tiles", "check_points_mode_run", "POINTS_MODE_UNUSED", "extra_dim", "point_format", "RESIDUAL_KEPT"]

#: n_min of the compression octree (as the normals' default).
N_MIN = 12
#: Largest patch cell, in point spacings.  A patch's 8 x 8 occupancy mask then has cells of at most
#: 4 spacings, so decompression does not fill gaps in the data wider than that (with the normals'
#: 256 spacings, samples landed up to 5.7 m from any original point on a flat IGN tile).
MAX_EDGE_SPACINGS = 32.0
#: What a model-mode ``.pcz`` keeps of each residual point besides its position (:mod:`patchcloud.stream.io.residual_points`):
#: its class, its intensity (on 64 levels) and its returns (as return 1 of 1, as the sampled points); the other dimensions
#: are zero.
RESIDUAL_KEPT = KEPT
_PART = ("scale", "centroid", "rotation", "coeffs", "rmse", "cells", "level", "ijk", "count", "extent", "mask",
         "classification", "intensity")


@dataclass
class CompressSummary:
    """What a ``compress`` run did (sizes in bytes, times in seconds)."""

    input: str
    output: str
    points: int
    patches: int
    cells: int
    residual: int
    max_error: float
    input_bytes: int
    output_bytes: int
    mean_error: float
    seconds: dict[str, float] = field(default_factory=dict)
    peak_memory: int = 0
    compile_seconds: float = 0.0  # numba compiling the kernels (a first run), not in seconds
    scheduler: str = "threads"
    units: dict = field(default_factory=lambda: {"symbol": "m"})  # the file's length unit (patchcloud.stream.io.crs.Units)
    left_out: dict = field(default_factory=dict)  # points left out of the models, by reason (stream.io.classes.REASONS)
    selection: dict | None = None  # the classes asked for and keep_noise (Selection.to_json)
    mode: str = "model"  # or "points" (--keep-points)
    steps: list = field(default_factory=lambda: [1, 1, 1])  # the multiples of the input's integers kept (stream.io.point_coding)
    dropped: list = field(default_factory=list)  # dimensions written as zeros (of the residual points, in model mode)
    scales: list = field(default_factory=lambda: [1.0, 1.0, 1.0])  # the input's scales (a step's length is steps x scales)
    tiles: int = 0  # the store's tiles, of tile_size (model mode; 0: none, points mode)
    tile_size: float = 0.0

    def _position_line(self, who: str) -> str:
        u = self.units["symbol"]
        if list(self.steps) == [1, 1, 1]:
            return f"  positions       {who} exact (the budget is below the file's resolution)"
        grid = " x ".join(f"{k * s:g}" for k, s in zip(self.steps, self.scales))
        return (f"  positions       {who} within {self.max_error:g} {u} (on a grid of {grid} {u}: "
                f"{', '.join(map(str, self.steps))} x the file's)")

    def format(self) -> str:
        n = max(self.points, 1)
        u = self.units["symbol"]
        dropped = ", ".join(self.dropped) or "none"
        size = (f"  size            {self.output_bytes:,} bytes, {8 * self.output_bytes / n:.2f} bits/point; input "
                f"{self.input_bytes:,} bytes ({self.input_bytes / max(self.output_bytes, 1):.2f}x larger)")
        if self.mode == "points":
            return "\n".join([
                f"{self.input} -> {self.output}",
                f"  points          {self.points:,}, every one kept in input order; attributes exact, dropped: {dropped}",
                self._position_line("every point"), size,
                *time_and_memory_lines(self.seconds, self.points, self.peak_memory, self.scheduler, self.compile_seconds),
            ])
        return "\n".join([
            f"{self.input} -> {self.output}",
            f"  points          {self.points:,}: {self.points - self.residual:,} on {self.patches:,} patches ({self.cells:,} octree cells) "
            f"({(self.points - self.residual) / n:.1%}), {self.residual:,} residual ({self.residual / n:.1%})",
            *([f"  tiles           {self.tiles:,} of {self.tile_size:g} {u}"] if self.tiles else []),
            f"  error           budget {self.max_error:g} {u}; "
            + (f"mean distance of the modelled points to their surface {self.mean_error:.4f} {u} (before quantisation, which "
               f"adds at most half the budget)" if self.points > self.residual else "no point modelled"),
            self._position_line("residual points"),
            f"  residual dims   {kept_words(self.dropped)}; zero: {dropped}",
            size,
            *left_out_lines(self.left_out, self.selection, self.points, "in no model, kept as residual points"),
            *time_and_memory_lines(self.seconds, self.points, self.peak_memory, self.scheduler, self.compile_seconds),
        ])


def extra_dim(d) -> dict:
    """One extra dimension of a laspy point format (its ``DimensionInfo``), as JSON: name, element type, count, description."""
    t = np.dtype(d.dtype)
    return {"name": d.name, "type": t.base.str, "count": int(d.num_elements), "description": d.description}


def point_format(id: int, extra_dims: list[dict]) -> laspy.PointFormat:
    """The point format ``id`` with the ``extra_dims`` (:func:`extra_dim`'s) in order: the input records' layout."""
    pf = laspy.PointFormat(id)
    for d in extra_dims:
        t = np.dtype(d["type"]) if d["count"] == 1 else np.dtype((d["type"], (d["count"],)))
        pf.add_extra_dimension(laspy.ExtraBytesParams(name=d["name"], type=t, description=d["description"]))
    return pf


def compress_tile(url: str, ijk: tuple, params: dict) -> dict:
    """Patch models of one tile within the budget, quantised; its residual points; stored as the tile's ``pcz_*`` arrays."""
    store = Store.open(url)
    key = params["key"]
    if store.tile_done(ijk, "compress", key):
        return store.tile_attrs(ijk)["compress"]
    grid = store.grid
    T = grid.tile_size
    corner = grid.corner(ijk)
    xyz = store.read(ijk, "xyz")
    local = grid.local(xyz)
    rank = store.read(ijk, "rank").astype(np.int64)  # xyz row r is the tile's point rank[r] in input order
    in_order = store.read(ijk, "record")  # the tile's records in input order
    pf = point_format(params["point_format"], params["extra_dims"])
    rec = laspy.PackedPointRecord(np.ascontiguousarray(in_order).view(pf.dtype()).reshape(-1), pf)
    # the points of the run's selection (stream.io.classes): only they are modelled; the others are residual points
    why = Selection.from_json(params["selection"]).reasons(rec.array)[rank]
    takes = np.flatnonzero(why == 0)
    budget = params["max_error"]
    n = xyz.shape[0]
    if takes.size >= N_MIN:
        fit = fit_models(local if takes.size == n else local[takes], budget, d_min=params["d_min"], max_edge=params["max_edge"],
                         n_min=N_MIN, root=(corner, T))
        models = fit.models
        cell, err = np.full(n, -1, dtype=np.asarray(fit.cell).dtype), np.zeros(n, dtype=np.asarray(fit.error).dtype)
        cell[takes], err[takes] = fit.cell, fit.error
        residual = np.sort(np.r_[takes[fit.residual], np.flatnonzero(why != 0)])
    else:  # too few points for a surface: all residual
        models, cell, residual, err = PatchModels.empty(corner, T), np.full(n, -1), np.arange(n), np.zeros(n)
    q = quantise_models(models, budget)
    # the bound, point by point: a modelled point farther than the budget from its decoded patch is a residual point
    on = np.flatnonzero(cell >= 0)
    if on.size:
        patch = models.cell_patch[cell[on]]
        far = on[patch_distances(dequantise_models(q), local[on], patch) > budget]
        cell[far] = -1
        residual = np.union1d(residual, far)
        q = dataclasses.replace(q, count=np.bincount(cell[cell >= 0], minlength=q.count.shape[0]).astype(q.count.dtype))
    on = cell >= 0
    C = q.count.shape[0]
    cls = np.asarray(rec["classification"]).astype(np.int64)[rank]
    votes = np.bincount(cell[on] * 256 + cls[on], minlength=C * 256).reshape(C, 256)
    inten = np.bincount(cell[on], weights=np.asarray(rec["intensity"], dtype=np.float64)[rank][on], minlength=C)
    shift = intensity_shift(rec["intensity"])  # the tile's intensities, its cells' means and its residual points', on 64 levels
    values = dict(
        scale=q.scale, centroid=q.centroid, rotation=q.rotation, coeffs=q.coeffs, rmse=q.rmse, cells=q.cells,
        level=q.level, ijk=q.ijk, count=q.count, extent=q.extent, mask=q.mask,
        classification=votes.argmax(axis=1).astype(np.uint8), intensity=coarse_intensity(np.rint(inten / np.maximum(q.count, 1)), shift),
    )
    for name in ("classification", "intensity"):  # --drop: the cells' too (their samples carry zeros)
        if name in params["dropped"]:
            values[name] = np.zeros_like(values[name])
    for name in _PART:
        store.write(ijk, "pcz_" + name, values[name])
    laz = residual_block(in_order[np.sort(rank[residual])], pf, params["version"], params["steps"], params["dropped"],
                         grid.scale, grid.offset, shift)
    store.write(ijk, "pcz_residual_laz", np.frombuffer(laz, dtype=np.uint8))
    info = dict(patches=len(models), cells=C, residual=int(residual.size), intensity_shift=shift, points=int(xyz.shape[0]),
                abs_error=float(np.abs(err[on]).sum()), left_out=np.bincount(why, minlength=len(REASONS) + 1)[1:].tolist())
    store.mark_tile(ijk, "compress", key, compress=info)
    return info


def _parts(st: Store, max_error: float):
    T = st.grid.tile_size
    for ijk in st.tiles:
        v = {name: st.read(ijk, "pcz_" + name) for name in _PART}
        q = QuantisedModels(
            max_error=max_error, root_corner=st.grid.corner(ijk), root_edge=T,
            **{name: v[name] for name in _PART if name not in ("classification", "intensity")},
        )
        info = st.tile_attrs(ijk)["compress"]
        yield pcz.TilePart(ijk, q, v["classification"], v["intensity"], int(info["residual"]), st.read(ijk, "pcz_residual_laz").tobytes(),
                           int(info["intensity_shift"]))


class CompressJob(Job):
    """The steps of ``compress`` on the scaffold; its write packs the ``.pcz``."""

    write_step = "pack"
    output_names = {".pcz": "a patch-model file"}
    catalogs = False  # a catalog is compressed file by file: compress_catalog
    tiles_selection = False  # every point is tiled: compress_tile models the selection's, the others are residual points
    #: the fits, the merge, the quantised models and the residual coding of a tile at once: 885 bytes a point measured
    #: (fusa.laz, one tile of 262,764 points, 222 MiB above the process's start; review N), not normals' 300
    tile_point_bytes = 900

    def __init__(self, options: CompressOptions, record_source: bool = False, tile_size: float | None = None) -> None:
        self.options = options
        self.record_source = record_source
        self.tile_size = tile_size  # the run's (None: the default), for the check of the budget against the tiles
        self.params: dict = {}
        self.infos: dict = {}
        self.counts: dict = {}
        self.point_format: laspy.PointFormat | None = None

    def steps(self):
        return [("records", self.records), ("fit", self.fit)]

    def check(self, catalog) -> None:
        check_drop(catalog, self.options.drop)
        check_budget_fits_tiles(self.options.max_error, make_grid(catalog, self.tile_size).tile_size, catalog.path)

    def records(self, ctx: JobContext) -> None:
        st = ctx.store
        if not st.step_done("records"):
            bucket_records(st, ctx.runner)
            st.mark_step("records", {"part_points": int(st.attrs["part_points"])})

    def fit(self, ctx: JobContext) -> None:
        st, src = ctx.store, ctx.source
        check_budget_fits_tiles(self.options.max_error, st.grid.tile_size, src.path)  # a store resumed: its own tiles
        occ = {int(k): int(v) for k, v in st.attrs["occupancy"].items()}
        spacing = occupancy_spacing(occ, int(st.tile_counts.sum()))
        with laspy.open(src.path) as r:
            pf = r.header.point_format
        self.params = dict(
            max_error=self.options.max_error, d_min=3.0 * spacing if spacing > 0 else st.grid.tile_size / 2.0**21,
            max_edge=MAX_EDGE_SPACINGS * spacing if spacing > 0 else float("inf"), point_format=pf.id, version=src.version,
            extra_dims=[extra_dim(d) for d in pf.extra_dimensions], selection=ctx.run.selection.to_json(),
            steps=list(coarse_steps(self.options.max_error, st.grid.scale)),
            dropped=list(residual_dropped(pf, dropped_fields(pf, self.options.drop, where=src.path))),
            residual_coding=CODING,
        )
        self.params["key"] = params_key(self.params)
        self.infos = ctx.map_tiles(compress_tile, label="compress", params=self.params)
        self.point_format = pf

    def write(self, ctx: JobContext) -> None:
        st, src, pf, budget = ctx.store, ctx.source, self.point_format, self.options.max_error
        head, evlrs = raw_header(src.path, waveforms=False)  # no point of model mode keeps a wave packet
        out, key, request = Path(ctx.output), self.params["key"], run_request(self, ctx.run)

        def record(partial: Path) -> None:  # as the export records its outputs: a .pcz recorded complete is written
            record_output(st, out, partial, key, request)  # again by the same command (the same bytes), not refused

        again = complete_outputs(st, [out], key=key)[0]
        self.counts = pcz.write_pcz(
            out, _parts(st, budget), max_error=budget, grid=st.grid.to_json(), header=head, evlrs=evlrs,
            source=pcz_source(src, pf.id, self.record_source, ctx.units.symbol, ctx.catalog.crs), record_bytes=pf.size - 12,
            overwrite=ctx.run.overwrite or again, steps=self.params["steps"], dropped=self.params["dropped"], before_rename=record,
        )

    def summarise(self, ctx: JobContext) -> CompressSummary:
        counts, v = self.counts, list(self.infos.values())
        modelled = counts["points"] - counts["residual"]
        return CompressSummary(
            input=ctx.source.path, output=str(ctx.output), points=counts["points"], patches=counts["patches"],
            cells=counts["cells"], residual=counts["residual"], max_error=self.options.max_error,
            input_bytes=ctx.source.size, output_bytes=ctx.output.stat().st_size,
            mean_error=sum(i["abs_error"] for i in v) / max(modelled, 1), seconds=ctx.seconds,
            peak_memory=ctx.peak_memory, compile_seconds=ctx.compile_seconds, scheduler=ctx.scheduler, units=ctx.units.to_json(),
            left_out=dict(zip(REASONS, np.sum([i.get("left_out", [0] * len(REASONS)) for i in v], axis=0).astype(int).tolist()))
            if v else {}, selection=ctx.run.selection.to_json(), steps=list(self.params["steps"]),
            dropped=list(self.params["dropped"]), scales=list(ctx.store.grid.scale),
            tiles=len(ctx.store.tiles), tile_size=float(ctx.store.grid.tile_size),
        )


def check_budget_fits_tiles(max_error: float, tile_size: float, where: str = "") -> None:
    """Refuse an error budget larger than the tiles (what a ``.pcz`` can hold: its reader refuses the file), before any
    work: a PatchcloudValueError naming both options.

    >>> check_budget_fits_tiles(0.05, 64.0)
    >>> check_budget_fits_tiles(100.0, 64.0, "a.laz")
    Traceback (most recent call last):
    ...
    patchcloud.core.errors.PatchcloudValueError: a.laz: --max-error 100 is larger than the tiles (64): give a smaller --max-error, or --tile-size of at least 128
    """
    if max_error > tile_size:
        exp = math.ceil(math.log2(max_error))
        fits = exp <= math.log2(pcz.TILE_SIZES[1])  # (1e308: no tile a .pcz takes is that big)
        bigger = f", or --tile-size of at least {2.0 ** exp:g}" if fits else ""
        raise PatchcloudValueError(f"{where}: --max-error {max_error:g} is larger than the tiles ({tile_size:g}): give a smaller "
                                   f"--max-error{bigger}")


def pcz_source(src: LasSource, point_format: int, record_source: bool = False, units: str | None = None,
               assumed_crs: str | None = None) -> dict:
    """What a ``.pcz`` records of its input: its header's description, its file name and the symbol of its length unit
    (``units``: what ``max_error`` and the tile size are in); with ``record_source`` its absolute path and modification
    time too (which make the ``.pcz`` depend on where and when the input was); ``assumed_crs`` (WKT), the CRS
    ``--assume-crs`` gave an input without one, which ``decompress`` writes into its output."""
    d = dict(src.to_json(), point_format=point_format)
    if units is not None:
        d["units"] = units
    if assumed_crs is not None and src.crs is None:
        d["assumed_crs"] = assumed_crs
    if not record_source:
        d["path"] = Path(src.path).name
        d.pop("mtime_ns")
    return d


def compress(
    input, output: str | os.PathLike | None = None, options: CompressOptions | None = None, run: RunOptions | None = None,
    record_source: bool = False, **kwargs,
) -> CompressSummary | list[CompressSummary]:
    """Compress a LAS/LAZ file of any size to a ``.pcz`` of quadric patch models and residual points.

    Parameters
    ----------
    input : path
        LAS, LAZ or COPC.  A catalog: ``input`` several paths, a directory
        or a glob, ``output`` None and ``out_dir`` given: each file is
        compressed on its own to ``out_dir``/NAME.pcz
        (:func:`compress_catalog`), and the result is a list of summaries.
    output : path
        The ``.pcz`` (see :mod:`patchcloud.stream.io.pcz`).
    options : CompressOptions, optional
        What to compute (:class:`patchcloud.core.CompressOptions`): the
        error budget ``max_error`` (metres).  Patches are split until their
        quadric fits their points with an RMS error below it; points farther
        than 3 times it from their patch's surface, and the points of edge
        and sparse leaves, are kept as residual points, exactly.  Quantising
        the models adds at most half the budget.
    run : RunOptions, optional
        How to run it (:class:`patchcloud.stream.RunOptions`).
    record_source : bool
        Record the input's absolute path and modification time in the
        ``.pcz``.  Default: its file name only, so that the same input and
        parameters give the same bytes wherever the input is.
    **kwargs
        Any field of either, by name.

    Returns
    -------
    CompressSummary, or a list of them (a catalog)

    Examples
    --------
    >>> s = compress(sample, tmp / "sample.pcz", max_error=0.05, quiet=True)
    >>> s.points, s.patches > 0, s.output_bytes < s.input_bytes
    (60653, True, True)
    """
    options, run = split_options(kwargs, options, CompressOptions, run)
    if options.keep_points:
        check_points_mode_run(run)
    if run.out_dir is not None:
        if output is not None:
            raise PatchcloudValueError(f"{output}: with out_dir (--out-dir) every argument is an input; the outputs go to {run.out_dir}")
        return compress_catalog(input, options, run, record_source)
    return run_job(_job(options, record_source, run.tile_size), input, output, run)


#: What points mode does not use of a run's options (it codes every record of the file in input order, in blocks of
#: records, with no store and no tiles): each option's name and flag, and the value that means "not given".
POINTS_MODE_UNUSED = (("tile_size", "--tile-size", None), ("store", "--store", None), ("keep_store", "--keep-store", None),
                      ("classes", "--classes", None), ("keep_noise", "--keep-noise", False))


def check_points_mode_run(run: RunOptions) -> None:
    """Refuse run options that points mode (``keep_points``, ``--keep-points``) would take and not use.

    >>> check_points_mode_run(RunOptions(overwrite=True))
    >>> check_points_mode_run(RunOptions(tile_size=16.0, keep_store=True))
    Traceback (most recent call last):
    ...
    patchcloud.core.errors.PatchcloudValueError: keep_points (--keep-points) codes every point in input order, with no store and no tiles: tile_size (--tile-size), keep_store (--keep-store) would do nothing; leave them out
    """
    given = [f"{name} ({flag})" for name, flag, unset in POINTS_MODE_UNUSED if getattr(run, name) != unset]
    if given:
        raise PatchcloudValueError(
            "keep_points (--keep-points) codes every point in input order, with no store and no tiles: "
            f"{', '.join(given)} would do nothing; leave {'it' if len(given) == 1 else 'them'} out")


def _job(options: CompressOptions, record_source: bool, tile_size: float | None = None) -> Job:
    """The job ``options`` ask for: model mode (:class:`CompressJob`, on tiles of ``tile_size``: the run's) or points
    mode (:class:`~.compress_points.PointsJob`)."""
    if options.keep_points:
        from patchcloud.stream.jobs.compress_points import PointsJob  # it builds on this module

        return PointsJob(options, record_source)
    return CompressJob(options, record_source, tile_size)


#: A catalog's compression records each ``.pcz`` it finishes here, in the output directory, until the last is written.
CATALOG_RECORD = "patchcloud-compress.json"


def compress_catalog(inputs, options: CompressOptions, run: RunOptions, record_source: bool = False) -> list[CompressSummary]:
    """Compress every file ``inputs`` name (paths, directories, globs) to ``run.out_dir``/NAME.pcz, file by file.

    Each ``.pcz`` is that of the file compressed alone (patches do not
    cross files, so each decompresses to its own file's points); every
    input and output is checked before the first is written.  Each file
    finished is recorded in ``OUT_DIR/``:data:`CATALOG_RECORD` (its input,
    its ``.pcz``, the parameters, its summary), removed when the last is
    written: a run stopped part way (Ctrl-C, a failure, kill -9) is resumed
    by the same command, which keeps the ``.pcz`` recorded complete whose
    files are unchanged and writes the others (a file is recorded as
    started before it is written, so one in place but not yet recorded
    complete is replaced, not refused).
    """
    paths = expand_inputs(inputs)
    out_dir = check_out_dir(run.out_dir)
    outs = output_paths(paths, out_dir, inputs, suffix=".pcz")
    for p in paths:  # each file as its own run will take it (its CRS, the assumed one, its units, the job's own checks:
        # --drop's names, the budget), before any is written
        one_file = open_catalog([p], run.assume_crs) if run.assume_crs is not None else Catalog.of(open_source(p))
        catalog_units(one_file, run)
        _job(options, record_source, run.tile_size).check(one_file)
    for o in outs:
        check_not_input(o, paths)
    # what the run was asked (the same request kept outputs record), the source recording and the parts read
    key = params_key(dict(run_request(_job(options, record_source), run), record_source=record_source, chunk=run.chunk))
    record_path = out_dir / CATALOG_RECORD
    record = _read_record(record_path)
    done = [_finished(record.get(o.name), key, p, o) for p, o in zip(paths, outs)]
    ours = [_started(record.get(o.name), key, p) for p, o in zip(paths, outs)]  # a run stopped while writing it
    if out_dir.exists():
        outs = [o if d else check_writable(o, run.overwrite or w) for o, d, w in zip(outs, done, ours)]
    made = not out_dir.exists()
    out_dir.mkdir(exist_ok=True)
    one = dataclasses.replace(run, out_dir=None)
    summaries = []
    try:
        for p, o, d, w in zip(paths, outs, done, ours):
            if d:  # finished by a run stopped later: kept as it is
                summaries.append(CompressSummary(**record[o.name]["summary"]))
                continue
            # recorded as started first: a .pcz in place but not yet recorded (stopped between the two) is this run's
            record[o.name] = dict(key=key, input=file_record(Path(p)), started=True)
            _write_record(record_path, record)
            s = run_job(_job(options, record_source, one.tile_size), p, o, dataclasses.replace(one, overwrite=one.overwrite or w))
            record[o.name] = dict(key=key, input=file_record(Path(p)), output=file_record(Path(o)), summary=dataclasses.asdict(s))
            _write_record(record_path, record)
            summaries.append(s)
    except BaseException:
        if made:  # refused before anything was written there (a tile size, say): no empty directory left
            try:
                if not any(o.exists() for o in outs):
                    record_path.unlink(missing_ok=True)
                out_dir.rmdir()
            except OSError:  # not empty: a .pcz or the record is in it
                pass
        raise
    record_path.unlink(missing_ok=True)  # every file written: nothing left to resume
    return summaries


def _finished(entry: dict | None, key: str, source, output) -> bool:
    """Whether a catalog's record ``entry`` says ``output`` was written complete from ``source`` with these parameters,
    both files unchanged since."""
    if not entry or entry.get("key") != key or not Path(output).is_file() or not Path(source).is_file():
        return False
    return entry.get("input") == file_record(Path(source)) and entry.get("output") == file_record(Path(output))


def _started(entry: dict | None, key: str, source) -> bool:
    """Whether a catalog's record ``entry`` says a run with these parameters started writing its output from
    ``source`` (unchanged since) and stopped before recording it written: an output there is that run's."""
    return bool(entry) and bool(entry.get("started")) and entry.get("key") == key and Path(source).is_file() and (
        entry.get("input") == file_record(Path(source)))


def _read_record(path: Path) -> dict:
    """A catalog's record (:data:`CATALOG_RECORD`), or nothing where there is none or it cannot be read (then nothing
    is resumed: the outputs there are refused unless ``overwrite``)."""
    import json

    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _write_record(path: Path, record: dict) -> None:
    """Write a catalog's record under a temporary name, then rename it (:func:`~patchcloud.stream.io.las.atomic_output`)."""
    import json

    with atomic_output(path, overwrite=True) as f:
        f.write(json.dumps(record, sort_keys=True, default=lambda v: v.item() if hasattr(v, "item") else str(v)).encode())
