"""``normals``: normals and curvature of a LAS/LAZ file of any size.

The job's steps (each resumable: a rerun skips what is done):

1. tile (the scaffold's, shared by every job: :mod:`patchcloud.stream.engine.ingest`);
2. calibrate: the global defaults (point spacing from the tiles' octree
   occupancy, the RMSE threshold from the finest cells' fits), so every
   tile uses the same parameters whatever the tiling;
3. fit: one task per tile (:func:`.normals_tiles.fit_one_tile`);
4. seams: links between the leaves on either side of every tile face,
   then one orientation for all patches (:mod:`.seams`);
5. finish: normals per tile, blended across tile faces with the
   neighbours' patch models (:func:`.normals_tiles.finish_one_tile`); a
   tile of more than a worker's share of the points is cut into pieces
   (ranges of its input order) that run side by side, each writing its
   rows (:func:`.normals_tiles.mark_finished_pieces`);
6. export: the input plus :data:`NORMALS_DIMS`.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field

import numpy as np

from patchcloud.core import MAX_DEPTH, SKIN_HALO, Method, NormalsOptions, PatchcloudValueError, PatchKind, check_flag, threshold_from_histograms
from patchcloud.stream.engine.export import Column
from patchcloud.stream.engine.job import (
    Job, JobContext, RunOptions, file_lines, left_out_lines, params_key, run_job, split_options, time_and_memory_lines, units_line,
)
from patchcloud.stream.engine.ingest import occupancy_spacing
from patchcloud.stream.engine.tasks import map_tiles, pieces_for
from patchcloud.stream.io.dims import NO_PATCH, NORMALS_DIMS, PRINCIPAL_DIMS
from patchcloud.stream.io.store import Store
from patchcloud.stream.jobs import normals_tiles
from patchcloud.stream.jobs.seams import orient_tiles

__all__ = ["normals", "NormalsJob", "NormalsSummary", "resolve_parameters", "global_patch_ids"]


@dataclass
class NormalsSummary:
    """What a ``normals`` run did (times in seconds, memory in bytes)."""

    input: str
    output: str
    points: int
    tiles: int
    tile_size: float
    patches_by_kind: dict[str, int]
    normals_by_method: dict[str, int]
    parameters: dict
    seconds: dict[str, float] = field(default_factory=dict)
    peak_memory: int = 0
    compile_seconds: float = 0.0  # numba compiling the kernels (a first run), not in seconds
    scheduler: str = "threads"
    store: str = ""
    files: list = field(default_factory=list)  # (input, output, points) of each file of a catalog
    units: dict = field(default_factory=lambda: {"symbol": "m"})  # the file's length unit (patchcloud.stream.io.crs.Units)
    left_out: dict = field(default_factory=dict)  # points left out of every neighbourhood, by reason (stream.io.classes.REASONS)
    selection: dict | None = None  # the classes asked for and keep_noise (Selection.to_json)

    def format(self) -> str:
        n = max(self.points, 1)
        m = self.normals_by_method
        k = self.patches_by_kind
        u = self.units["symbol"]
        lines = [
            f"{self.input} -> {self.output}",
            f"  points          {self.points:,}",
            f"  tiles           {self.tiles:,} of {self.tile_size:g} {u}",
            units_line(self.units),
            f"  patches         {sum(k.values()):,} (surface {k['surface']:,}, edge {k['edge']:,}, sparse {k['sparse']:,})",
            f"  normals by      quadric {m['quadric'] / n:.1%}, blended {m['blended'] / n:.1%}, cell moments {m['moments'] / n:.1%}, "
            f"k-NN fallback {m['knn'] / n:.1%}" + (f", none {m['none']:,} (a point alone, or copies of one)" if m.get("none") else ""),
            f"  parameters      {self.parameters['criterion']} threshold {self.parameters['threshold']:.4g}, "
            f"d_min {self.parameters['d_min']:.3g} {u}, spacing {self.parameters['spacing']:.3g} {u}, orient {self.parameters['orient']}"
            + (", always up" if self.parameters.get("always_up") else "") + (f", fallback k-NN {self.parameters['k_fallback']}" if "k_fallback" in self.parameters else ""),
            *left_out_lines(self.left_out, self.selection, self.points),
            *time_and_memory_lines(self.seconds, self.points, self.peak_memory, self.scheduler, self.compile_seconds),
            *file_lines(self.files),
        ]
        return "\n".join(lines)


def resolve_parameters(store: Store, options: NormalsOptions, runner) -> dict:
    """Spacing, d_min, max_edge and threshold of the whole cloud: the options' values, or the defaults from the data.

    The defaults follow the rules of :func:`patchcloud.core.estimate_normals`,
    computed from per-tile statistics on cells of the grid's absolute
    frame, so they do not depend on the tiling: the spacing from occupied
    cells, the RMSE threshold from :func:`patchcloud.core.rmse_histograms`
    (the in-memory function anchors those cells at its root cube's corner,
    so its threshold is about, not exactly, the same).
    """
    a = store.attrs
    n = int(sum(a["tile_counts"]))
    occ = {int(k): int(v) for k, v in a["occupancy"].items()}
    spacing = occupancy_spacing(occ, n)
    T = store.grid.tile_size
    d_min, max_edge, threshold = options.d_min, options.max_edge, options.threshold
    if d_min is None:
        d_min = 3.0 * spacing if spacing > 0 else T / 2.0**MAX_DEPTH
    if max_edge is None:
        max_edge = 256.0 * spacing if spacing > 0 else float("inf")
    if threshold is None:
        if options.criterion == "sigma3":
            threshold = 0.005
        else:
            key = {"d_min": d_min, "n_min": options.n_min, "cells": "absolute, 1.5 d_min", "rmse": "1e-12 to 1e12"}
            cached = a.get("calibration")
            if cached and cached.get("key") == key:
                threshold = cached["threshold"]
            else:
                hists = map_tiles(normals_tiles.calibrate_tile, store, runner=runner, label="calibrate", small=True, d_min=d_min,
                                  n_min=options.n_min)
                threshold = threshold_from_histograms(np.sum(list(hists.values()), axis=0), d_min, spacing)
                store.update(calibration={"key": key, "threshold": threshold})
    return dict(spacing=float(spacing), d_min=float(d_min), max_edge=float(max_edge), threshold=float(threshold))


def global_patch_ids(store: Store, t: int, patch: np.ndarray) -> np.ndarray:
    """Tile ``t``'s patch ids (rows of its patch table) as ids over the whole cloud (the seam pass's offsets)."""
    return patch + int(store.attrs["patch_offsets"][t])


class NormalsJob(Job):
    """The steps of ``normals`` on the scaffold (see :mod:`patchcloud.stream.engine.job`)."""

    name = "normals"

    def __init__(self, options: NormalsOptions, principal_curvatures: bool = False, always_up: bool = False) -> None:
        principal_curvatures = check_flag("principal_curvatures", principal_curvatures)
        always_up = check_flag("always_up", always_up)
        if always_up and options.orient == "viewpoint":  # each would turn every normal its own way
            raise PatchcloudValueError("always_up turns every normal up and a viewpoint turns it towards the viewpoint: give one "
                                       "(PDAL's viewpoint overrides its always up)")
        self.options = options
        self.principal_curvatures = principal_curvatures
        self.always_up = always_up
        self.params: dict = {}
        self.origin = None  # the store grid's origin, once calibrated
        self.key = ""
        #: Whether no tile of the store can be marked fitted (finished): set by :meth:`calibrate`.
        self.none_fitted = self.none_finished = False

    def steps(self):
        return [("calibrate", self.calibrate), ("fit", self.fit), ("seams", self.seams), ("finish", self.finish)]

    def calibrate(self, ctx: JobContext) -> None:
        """Resolve the parameters; a change of them (or of the calibration) clears the steps that depend on them."""
        o, st = self.options, ctx.store
        origin = self.origin = np.asarray(st.grid.origin)
        asked = dataclasses.asdict(o)
        del asked["viewpoint"]  # the tiles get it in the store's frame
        self.params = dict(
            asked, centre_local=list(st.attrs["centroid_local"]),
            viewpoint_local=None if o.viewpoint is None else (np.asarray(o.viewpoint, dtype=float) - origin).tolist(),
            **resolve_parameters(st, o, ctx.runner),  # threshold, d_min, max_edge as resolved, and the spacing
        )
        self.params["halo"] = SKIN_HALO * self.params["d_min"]
        self.key = params_key(self.params)
        # a tile is marked fitted (finished) only after the store records the parameters (the finish's key): a store
        # without them has no tile to clear or to skip, and its tiles' records are not read (one each, in this process)
        self.none_fitted = st.attrs.get("params_key") is None
        self.none_finished = st.attrs.get("finish_key") is None
        if st.attrs.get("params_key") != self.key:
            if not self.none_fitted:
                st.clear_tile_steps(["fit", "finish"])
            self.none_fitted = self.none_finished = True
            st.mark_step("seams", None)
            st.update(params=self.params, params_key=self.key)
        # what only the finish step depends on: asking for the principal curvatures or always_up redoes that step, not the fit
        self.params["principal_curvatures"] = self.principal_curvatures
        self.params["always_up"] = self.always_up
        finish_key = params_key(self.params)
        if st.attrs.get("finish_key") != finish_key:
            if not self.none_finished:
                st.clear_tile_steps(["finish"])
            self.none_finished = True
            st.update(finish_key=finish_key)

    def parameters(self) -> dict:
        """As :meth:`Job.parameters`, the centre only where the orientation has one (``outward``)."""
        p = super().parameters()
        if p.get("orient") != "outward":
            p.pop("centre", None)
        return p

    def asked_parameters(self) -> dict:
        return dict(super().asked_parameters(), principal_curvatures=self.principal_curvatures, always_up=self.always_up)

    def fit(self, ctx: JobContext) -> None:
        todo = ctx.store.tiles if self.none_fitted else [t for t in ctx.store.tiles if not ctx.store.tile_done(t, "fit")]
        ctx.map_tiles(normals_tiles.fit_one_tile, tiles=todo, label="fit", params=self.params)

    def seams(self, ctx: JobContext) -> None:
        if ctx.store.step_done("seams") != self.key:
            orient_tiles(ctx.store, ctx.runner, self.options.orient)
            if not self.none_finished:
                ctx.store.clear_tile_steps(["finish"])
                self.none_finished = True
            ctx.store.mark_step("seams", self.key)

    def finish(self, ctx: JobContext) -> None:
        """One task per tile, a big tile cut into pieces side by side (:func:`pieces_for`): with many workers, the
        biggest tile's task would otherwise be the step's length."""
        st = ctx.store
        todo = st.tiles if self.none_finished else [t for t in st.tiles if not st.tile_done(t, "finish")]
        counts = dict(zip(st.tiles, st.tile_counts.tolist()))
        pieces = pieces_for({t: counts[t] for t in todo}, ctx.runner.slots)
        ctx.map_tiles(normals_tiles.finish_one_tile, tiles=todo, halo=1, label="finish", params=self.params, pieces=pieces)
        for t, k in pieces.items():  # every piece is written: the tile is done (a few small reads and one write each)
            normals_tiles.mark_finished_pieces(st, t, self.params, k)

    def dims(self):
        return NORMALS_DIMS + PRINCIPAL_DIMS if self.principal_curvatures else NORMALS_DIMS

    def columns(self, ctx: JobContext):
        columns = [
            Column("normal", ("NormalX", "NormalY", "NormalZ"), np.float32),
            Column("curvature", ("Curvature",), np.float32),
            Column("method", ("NormalMethod",), np.uint8),
            Column("patch", ("PatchId",), np.uint32, per_tile=global_patch_ids, empty=NO_PATCH),
        ]
        if self.principal_curvatures:
            columns += [Column("principal", tuple(d[0] for d in PRINCIPAL_DIMS[:2]), np.float32),
                        Column("direction", tuple(d[0] for d in PRINCIPAL_DIMS[2:]), np.float32)]
        return columns, self.dims()

    def summarise(self, ctx: JobContext) -> NormalsSummary:
        st = ctx.store
        kinds = np.zeros(len(PatchKind), dtype=np.int64)
        methods = np.zeros(len(Method) + 1, dtype=np.int64)
        for t in st.tiles:
            a = st.tile_attrs(t)
            kinds += np.asarray(a["fit"]["kinds"], dtype=np.int64)
            methods += np.asarray(a["finish"]["methods"], dtype=np.int64)
        return NormalsSummary(
            input=ctx.input_name, output=str(ctx.output), points=ctx.catalog.point_count, tiles=len(st.tiles),
            tile_size=st.grid.tile_size,
            patches_by_kind={k.name.lower(): int(kinds[k]) for k in PatchKind},
            normals_by_method={**{m.name.lower(): int(methods[m]) for m in Method}, "none": int(methods[0])},
            parameters=self.parameters(), seconds=ctx.seconds, peak_memory=ctx.peak_memory, compile_seconds=ctx.compile_seconds, scheduler=ctx.scheduler,
            store=ctx.kept_store, files=ctx.files, units=ctx.units.to_json(), left_out=dict(st.attrs.get("left_out", {})),
            selection=st.attrs.get("selection"),
        )


def normals(
    input, output: str | os.PathLike | None = None, options: NormalsOptions | None = None, run: RunOptions | None = None,
    *, principal_curvatures: bool = False, always_up: bool = False, **kwargs,
) -> NormalsSummary:
    """Normals and curvature of a LAS/LAZ/COPC file (or a catalog of them) of any size, written as a copy with extra dimensions.

    Parameters
    ----------
    input, output : path
        LAS, LAZ or COPC in; LAS or LAZ out (LAZ when ``output`` ends in .laz),
        every input point once, in input order, every original dimension
        unchanged, plus :data:`NORMALS_DIMS`: NormalX, NormalY, NormalZ,
        Curvature (float32), NormalMethod (uint8, :class:`patchcloud.core.Method`:
        1 quadric, 2 blended, 3 k-NN) and PatchId (uint32).  A catalog:
        ``input`` several paths, a directory or a glob, ``output`` None and
        ``out_dir`` given (see :class:`patchcloud.stream.RunOptions`): the
        files are one cloud, and each gets its output in ``out_dir``.
    options : NormalsOptions, optional
        What to compute (:class:`patchcloud.core.NormalsOptions`, the
        ``viewpoint`` in the file's coordinates); the defaults come from the
        whole cloud.
    run : RunOptions, optional
        How to run it (:class:`patchcloud.stream.RunOptions`: tile size,
        scheduler, workers, store, overwrite, quiet).
    principal_curvatures : bool
        Also write :data:`PRINCIPAL_DIMS`: PrincipalCurvature1 >= PrincipalCurvature2
        (1/unit of the file's CRS, of the fitted quadric at the point's projection, or of its
        neighbourhood's for k-NN points; positive where the surface is
        convex seen from the side the oriented normal points to) and the unit
        direction of the first (PrincipalDirectionX/Y/Z; the second is
        normal x first).  A point with none gets 0 and (0, 0, 0).
    always_up : bool
        PDAL's ``always_up`` (``filters.normal``): after orientation, every
        normal whose z is negative is flipped, point by point, so that
        NormalZ >= 0 everywhere (with it the principal curvatures and
        direction, which depend on the side: (k1, k2) becomes (-k2, -k1)).
        Unlike ``orient="up"`` (the default), which turns whole groups of
        linked patches towards +Z, so a wall or a curved surface keeps the side
        its neighbours give it.  Default False (PDAL's default is True).
    **kwargs
        Any field of either, by name (``criterion="sigma3"``, ``workers=2``),
        overriding the objects given.

    Returns
    -------
    NormalsSummary

    Raises
    ------
    PatchcloudIOError (an OSError)
        An input that is not a readable, complete LAS/LAZ file, an existing
        output without ``overwrite``, an unusable store.
    PatchcloudValueError (a ValueError)
        An invalid parameter; the message lists the valid values.

    Examples
    --------
    >>> s = normals(sample, tmp / "normals.laz", quiet=True)
    >>> s.points, sum(s.normals_by_method.values()) == s.points
    (60653, True)
    >>> import laspy
    >>> laspy.read(tmp / "normals.laz").NormalZ.dtype
    dtype('float32')
    """
    options, run = split_options(kwargs, options, NormalsOptions, run)
    return run_job(NormalsJob(options, principal_curvatures, always_up), input, output, run)
