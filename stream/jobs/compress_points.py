"""``compress --keep-points``: every point of a LAS/LAZ file in a ``.pcz``, in input order, within the budget.

Points mode keeps every point: its position within ``max_error`` of where
it was (Euclidean, at most), every attribute bit for bit (intensity,
returns, classification, GPS time, RGB, extra bytes, waveform fields) but
those ``drop`` names, which come back as zeros.  Decompressing gives the
input's points in its order with its header and VLRs.

How (measured, ``python tools/bench_point_coding.py``): the input is cut in
parts of consecutive points, as the other jobs read it, one task each; a
task rounds each integer coordinate to a multiple ``k`` of the input's
grid (:mod:`patchcloud.stream.io.point_coding`) and codes the records in
input order as LAZ (lazrs), whose predictors follow the scan: GPS time,
returns, intensity and position from the previous points.  Positions in
the patches' frames (a quantised offset from the quadric) were tried and
were larger on every real aerial file: LAZ's scan-order prediction of
world coordinates is better than a patch's prediction of the height, and
the patch to name costs bits of its own.  No store, no tiles: memory is
a part per task.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import laspy
import numpy as np

from patchcloud.core import CompressOptions, PatchcloudValueError
from patchcloud.stream.engine.ingest import part_ranges, part_size
from patchcloud.stream.engine.job import Job, JobContext
from patchcloud.stream.io import pcz
from patchcloud.stream.io.laz_block import records_laz
from patchcloud.stream.jobs.compress import CompressSummary, pcz_source
from patchcloud.stream.io.las import LasSource, raw_header, read_range
from patchcloud.stream.io.point_coding import check_drop, coarse_records, coarse_steps, dropped_fields, refine
from patchcloud.stream.io.renamed import partial_path

__all__ = ["PointsJob", "encode_block", "blocks_folder"]


def blocks_folder(output: str | os.PathLike) -> Path:
    """Where the tasks put their blocks before they are packed: ``OUTPUT.blocks`` (the run holds OUTPUT's lock)."""
    out = Path(output)
    return out.with_name(out.name + ".blocks")


def encode_block(src: LasSource, first: int, count: int, steps, dropped, folder: str, b: int, laz_parallel: bool = False) -> dict:
    """Points ``first:first + count`` of ``src`` as a LAZ file ``folder/b.laz``: X, Y, Z divided by ``steps``, ``dropped`` zero.

    Returns the block's point count, its bytes and the bounds of its
    decoded integer coordinates (the input's grid).
    """
    pts = read_range(src, first, count, parallel=laz_parallel)
    pf = pts.point_format
    rows = coarse_records(pts.array, pf, steps, dropped)
    back = np.column_stack([refine(rows[:, 4 * a : 4 * a + 4].copy().view("<i4").ravel(), k) for a, k in enumerate(steps)])
    bounds = np.r_[back.min(axis=0), back.max(axis=0)].tolist() if len(back) else [0] * 6
    s = np.asarray(src.scale, dtype=np.float64) * np.asarray(steps)
    raw = records_laz(rows, pf, src.version, s, src.offset, parallel=laz_parallel)
    path = Path(folder) / f"{b:06d}.laz"
    tmp = partial_path(path)
    tmp.write_bytes(raw)
    tmp.replace(path)
    return dict(count=int(count), bytes=len(raw), bounds=[int(v) for v in bounds])


class PointsJob(Job):
    """``compress --keep-points`` on the scaffold: no tiles; ``encode`` (one task per part), then ``pack`` the ``.pcz``."""

    write_step = "pack"
    output_names = {".pcz": "a patch-model file"}
    catalogs = False  # a catalog is compressed file by file (stream.jobs.compress.compress_catalog)
    tiled = False
    name = "compress"

    def __init__(self, options: CompressOptions, record_source: bool = False) -> None:
        self.options = options
        self.record_source = record_source
        self.blocks: list[dict] = []
        self.steps_: tuple[int, int, int] = (1, 1, 1)
        self.dropped: tuple[str, ...] = ()
        self.counts: dict = {}

    def check(self, catalog) -> None:
        check_drop(catalog, self.options.drop)
        # a points-mode .pcz has no tiles; its reader takes budgets up to the largest tile size (pcz.TILE_SIZES)
        if self.options.max_error > pcz.TILE_SIZES[1]:
            raise PatchcloudValueError(f"{catalog.path}: --max-error {self.options.max_error:g} is larger than a .pcz "
                                       f"takes ({pcz.TILE_SIZES[1]:g} in the file's unit): give a smaller --max-error")

    def steps(self):
        return [("encode", self.encode)]

    def encode(self, ctx: JobContext) -> None:
        src, runner = ctx.source, ctx.runner
        with laspy.open(src.path) as r:
            pf = r.header.point_format
        self.dropped = dropped_fields(pf, self.options.drop, where=src.path)
        self.steps_ = coarse_steps(self.options.max_error, src.scale)
        folder = blocks_folder(ctx.output)
        shutil.rmtree(folder, ignore_errors=True)  # a killed run's
        folder.mkdir()
        # the blocks are part of the .pcz: cut by the point count (and chunk) only, never by the workers, so that the file
        # is the same bytes whatever the scheduler and the worker count (eight or more blocks, for as many tasks)
        parts = part_ranges(src.point_count, part_size(src.point_count, 1, ctx.run.chunk), taper=False)
        laz_parallel = runner.laz_parallel  # tasks in this process: lazrs may use the cores
        calls = [((src, first, count, self.steps_, self.dropped, str(folder), b), {"laz_parallel": laz_parallel})
                 for b, (first, count) in enumerate(parts)]
        try:
            self.blocks = runner.map(encode_block, calls, label="encode")
        except BaseException:  # a full disk, Ctrl-C: the blocks, which nothing resumes from, are not left behind
            shutil.rmtree(folder, ignore_errors=True)
            raise

    def write(self, ctx: JobContext) -> None:
        src, folder = ctx.source, blocks_folder(ctx.output)
        try:
            head, evlrs = raw_header(src.path)
            with laspy.open(src.path) as r:
                pf = r.header.point_format
            grid = dict(scale=list(src.scale), offset=list(src.offset))

            def blocks():
                for b, info in enumerate(self.blocks):
                    yield pcz.PointsBlock(info["count"], (folder / f"{b:06d}.laz").read_bytes(), tuple(info["bounds"]))

            self.counts = pcz.write_points_pcz(
                ctx.output, blocks(), max_error=self.options.max_error, steps=self.steps_, dropped=self.dropped, grid=grid,
                header=head, evlrs=evlrs, source=pcz_source(src, pf.id, self.record_source, ctx.units.symbol, ctx.catalog.crs), record_bytes=pf.size - 12,
                overwrite=ctx.run.overwrite,
            )
        finally:
            shutil.rmtree(folder, ignore_errors=True)

    def summarise(self, ctx: JobContext):
        n = self.counts["points"]
        return CompressSummary(
            input=ctx.source.path, output=str(ctx.output), points=n, patches=0, cells=0, residual=n,
            max_error=self.options.max_error, input_bytes=ctx.source.size, output_bytes=ctx.output.stat().st_size,
            mean_error=0.0, seconds=ctx.seconds, peak_memory=ctx.peak_memory, compile_seconds=ctx.compile_seconds,
            scheduler=ctx.scheduler, units=ctx.units.to_json(), mode="points", steps=list(self.steps_),
            dropped=list(self.dropped), scales=list(ctx.source.scale),
        )
