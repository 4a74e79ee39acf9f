"""``tile``: ingest only, a LAS/LAZ file cut into a tiled store that later jobs start from."""

from __future__ import annotations

import os
from pathlib import Path

from patchcloud.stream.engine.ingest import ensure_tiled
from patchcloud.stream.engine.job import RunOptions, says_what_is_kept
from patchcloud.stream.engine.runner import Runner
from patchcloud.stream.io.crs import units_of
from patchcloud.stream.io.las import check_not_input, open_source
from patchcloud.stream.io.lock import RunLock
from patchcloud.stream.io.store import Store
from patchcloud.stream.engine.background import stops_what_it_starts

__all__ = ["tile"]


@stops_what_it_starts()  # no thread of the run's left running (stream.engine.background)
def tile(
    input: str | os.PathLike, store: str, *, tile_size: float | None = None, scheduler: str = "auto",
    workers: int | None = None, overwrite: bool = False, quiet: bool = False, chunk: int | None = None,
    classes=None, keep_noise: bool = False, units: str | None = None,
) -> Store:
    """Ingest only: cut ``input`` into a tiled store at ``store`` (a path or fsspec URL).

    A later job given ``store=`` starts from it (``patchcloud normals IN
    OUT --store STORE``).  The options are those of
    :class:`~patchcloud.stream.engine.job.RunOptions` (``classes`` and
    ``keep_noise``: the points the tiles hold, as the job run on the store
    must ask for them, else it tiles again; ``units``: ``--units``, the
    unit ``tile_size`` is in where the CRS does not say or says degrees, as
    every job checks it).

    Examples
    --------
    >>> s = tile(sample, str(tmp / "sample.zarr"), tile_size=64, quiet=True)
    >>> len(s.tiles), int(s.tile_counts.sum())
    (4, 60653)
    """
    run = RunOptions(tile_size=tile_size, scheduler=scheduler, workers=workers, overwrite=overwrite, quiet=quiet, chunk=chunk,
                     classes=classes, keep_noise=keep_noise, units=units)
    src = open_source(input)
    units_of(src.crs, src.mins, src.maxs, run.units, where=src.path)  # degrees are not lengths: as every job refuses them
    local = "://" not in store
    if local:
        check_not_input(store, [src.path])  # as every job refuses its input as its store
    if local:
        Path(store).parent.mkdir(parents=True, exist_ok=True)  # as zarr makes it; the store's lock goes beside it
    with RunLock([store] if local else []):  # as a job on the store does (stream.io.lock): never two writers
        if overwrite and Store.exists(store):
            Store.create(store, overwrite=True)
        else:
            Store.check_new(store)  # before any worker starts
        with says_what_is_kept(store):  # as a job says it: the store is kept, the same command resumes from it
            with Runner(run.scheduler, run.workers, quiet=run.quiet, points=src.point_count) as runner:
                s, _ = ensure_tiled(src, store, run.tile_size, runner, run.quiet, run.chunk, run.selection)
            s.update(units_asked=run.units)  # the unit the tile size was given in (None: the CRS's): the jobs on the store take it
    return s
