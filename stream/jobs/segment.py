"""``segment``: DoN segments of a LAS/LAZ file of any size, numbered across tile faces.

The ``don`` job (:mod:`.don`) with a threshold on the DoN, then two steps:

4. cluster: components of each tile's kept points, with the kept points
   of the neighbours' skins within the tolerance;
5. merge: one union-find over all tiles' components gives segments that
   cross tile faces, sized over the whole file;

and an export that adds ``ClusterID``: 1, 2, ... in order of each
segment's first point in the file, as :func:`patchcloud.core.segment_don`
numbers them.
"""

from __future__ import annotations

import os

import numpy as np

from patchcloud.core import SegmentOptions
from patchcloud.stream.engine.export import Column
from patchcloud.stream.engine.job import JobContext, RunOptions, params_key, run_job, split_options
from patchcloud.stream.io.dims import SEGMENT_DIMS
from patchcloud.stream.io.store import Store
from patchcloud.stream.jobs import don_tiles
from patchcloud.stream.jobs.don import DonJob, DonSummary

__all__ = ["segment", "SegmentJob", "segment_of"]


def segment_of(store: Store, t: int, comp: np.ndarray) -> np.ndarray:
    """Tile ``t``'s component ids as segment ids over the whole cloud (0: no segment)."""
    return np.r_[0, store.read(store.tiles[t], "comp_map")][comp.astype(np.int64) + 1]  # comp -1 (not kept) -> 0


class SegmentJob(DonJob):
    """``don``'s steps with a threshold, then cluster and merge."""

    options: SegmentOptions
    name = "segment"

    def __init__(self, options: SegmentOptions) -> None:
        super().__init__(options)
        self.segments = 0

    def steps(self):
        return [*super().steps(), ("cluster", self.cluster)]

    def lengths(self) -> list[tuple[str, float, str]]:
        """The radii and the tolerance: a tolerance wider than the cloud makes one segment of it all."""
        return [*super().lengths(), ("tolerance", float(self.options.tolerance), "the points kept would all be one segment")]

    def selection(self) -> dict:
        o = self.options
        return dict(threshold=o.threshold, axis=o.axis, axis_threshold=o.axis_threshold)

    def resolve(self, ctx: JobContext) -> None:
        super().resolve(ctx)
        o = self.options
        self.params.update(tolerance=o.tolerance, min_cluster=o.min_cluster, max_cluster=o.max_cluster)
        self.params["cluster_key"] = params_key({"don": self.params["don_key"], "tolerance": o.tolerance})
        self.width = max(self.width, o.tolerance * (1 + 1e-9))

    def cluster(self, ctx: JobContext) -> None:
        ctx.map_tiles(don_tiles.cluster_tile, halo=self.halo, label="cluster", params=self.params)
        self.segments = don_tiles.merge_components(ctx.store, self.options.min_cluster, self.options.max_cluster)

    def dims(self):
        return SEGMENT_DIMS

    def columns(self, ctx: JobContext):
        columns, _ = super().columns(ctx)
        columns.append(Column("comp", ("ClusterID",), np.uint64, per_tile=segment_of, renumber=True))
        return columns, self.dims()

    def summarise(self, ctx: JobContext) -> DonSummary:
        s = super().summarise(ctx)
        s.kept = sum(i["kept"] for i in self.infos.values())
        s.segments = self.segments
        return s


def segment(
    input, output: str | os.PathLike | None = None, options: SegmentOptions | None = None, run: RunOptions | None = None,
    **kwargs,
) -> DonSummary:
    """DoN segments of a LAS/LAZ file of any size: threshold the DoN magnitude, cluster the points kept.

    ``output`` is the input plus :data:`SEGMENT_DIMS`: the dimensions of
    :func:`patchcloud.stream.don` and ``ClusterID`` (uint64, PDAL's name):
    1, 2, ... in order of each segment's first point in the file, 0 for
    points in no segment.  Segments that cross tile faces get one id.

    Parameters
    ----------
    input, output : path
    options : SegmentOptions, optional
        What to compute (:class:`patchcloud.core.SegmentOptions`: the DoN's
        scales, ``threshold``, ``tolerance``, ``min_cluster``,
        ``max_cluster``, ``axis``, ``axis_threshold``).
    run : RunOptions, optional
        How to run it (:class:`patchcloud.stream.RunOptions`).
    **kwargs
        Any field of either, by name.

    Returns
    -------
    DonSummary

    Examples
    --------
    >>> s = segment(sample, tmp / "seg.laz", r_small=0.5, r_large=2.0, threshold=0.2, tolerance=1.0, quiet=True)
    >>> s.segments > 0, s.kept <= s.points
    (True, True)
    """
    options, run = split_options(kwargs, options, SegmentOptions, run)
    return run_job(SegmentJob(options), input, output, run)
