"""The job scaffold: what every file-to-file job on the tiled store does, written once.

A job (``normals``, ``don``, ``segment``, ``compress``) is a subclass of
:class:`Job` that supplies three things: its **steps** (functions of a
:class:`JobContext`, each timed under its name), its **output** (the
:class:`~patchcloud.stream.engine.export.Column` s added to the input's
records, or its own :meth:`Job.write`) and its **summary**.
:func:`run_job` does the rest, in this order:

1. the output is checked (absent, or ``overwrite``; its directory there),
   the input opened (one clear error if it is not a complete LAS/LAZ);
2. the scheduler starts (:class:`~patchcloud.stream.engine.runner.Runner`);
3. ``tile``: the input is cut into the store's tiles, or the store made
   from it before is reused (:func:`~patchcloud.stream.engine.ingest.ensure_tiled`);
4. the job's steps, each through
   :func:`~patchcloud.stream.engine.tasks.map_tiles` as it needs; a step
   marks each tile done with the hash of its *resolved* parameters
   (:func:`params_key`), so a rerun skips what is done and a change of
   parameters or calibration reruns what depends on it;
5. the output is written under a temporary name and renamed when complete;
6. the summary (times per step, peak memory), then the default store is
   removed (a store the user named is kept).

How a job runs (tile size, scheduler, workers, store, ...) is one
:class:`RunOptions`, the same for every job; what it computes is its own
options object (:class:`patchcloud.core.NormalsOptions` and friends).

Adding a job: one module in ``stream/jobs/`` with a :class:`Job` subclass
and its function (``jobs/normals.py`` is the model), one in
``stream/cli/``.

>>> RunOptions(workers=2).scheduler
'auto'
>>> RunOptions(tile_size=-1)
Traceback (most recent call last):
...
patchcloud.core.errors.PatchcloudValueError: tile size must be a positive number of metres, got -1
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


from patchcloud.core import PatchcloudValueError, options_with
from patchcloud.stream.engine.export import Column, export_columns
from patchcloud.stream.engine.ingest import check_tile_size, ensure_tiled
from patchcloud.stream.engine.runner import Runner
from patchcloud.stream.engine.tasks import map_tiles
from patchcloud.stream.io.las import LasSource, check_las_output, check_writable, open_source
from patchcloud.stream.io.las_output import LAZ_CHUNK
from patchcloud.stream.io.store import Store

__all__ = [
    "RunOptions", "Job", "JobContext", "run_job", "split_options", "params_key", "default_store_path", "write_profile",
    "time_and_memory_lines",
]


@dataclass(frozen=True)
class RunOptions:
    """How a job runs, the same for every job (not what it computes).

    Parameters
    ----------
    tile_size : float, optional
        Tile edge (metres), rounded down to a power of two; default: about a
        million points per tile over the file's footprint.
    scheduler : str
        "auto" (default: worker processes for files of 2 million points or
        more, else threads), "threads", "processes", "synchronous", or a dask
        scheduler address such as ``tcp://host:8786``.
    workers : int, optional
        Threads or processes of the local scheduler (default: the cores).
    store : str, optional
        Where the tiles and intermediate results go (a path or an fsspec URL
        the workers can reach).  Default: ``OUTPUT.store`` beside the
        output, removed after a successful run (kept with ``keep_store``);
        a given store is kept, and a rerun resumes from it.
    keep_store : bool, optional
        Keep (True) or remove (False) the store after success; default:
        keep a given store, remove the default one.
    overwrite : bool
        Replace an existing output.
    quiet : bool
        No progress bars.
    profile : str, optional
        Write the run's task stream there (JSON: every task's step, start,
        end and worker; the steps' times; the workers), for
        ``tools/bench_scale.py``'s occupancy figures or your own.
    chunk : int, optional
        Points per part of the file (what one ingest or export task reads
        and writes): a multiple of 50,000 (the LAZ chunk).  Default: about
        eight parts per worker, 100,000 to 500,000 points each
        (:func:`patchcloud.stream.engine.ingest.part_size`).  Results do not
        depend on it.
    """

    tile_size: float | None = None
    scheduler: str = "auto"
    workers: int | None = None
    store: str | None = None
    keep_store: bool | None = None
    overwrite: bool = False
    quiet: bool = False
    profile: str | None = None
    chunk: int | None = None

    def __post_init__(self) -> None:
        check_tile_size(self.tile_size)
        if self.workers is not None and (isinstance(self.workers, bool) or int(self.workers) != self.workers or self.workers < 1):
            raise PatchcloudValueError(f"workers must be at least 1, got {self.workers!r}")
        if self.chunk is not None and (
            isinstance(self.chunk, bool) or int(self.chunk) != self.chunk or self.chunk < 1 or self.chunk % LAZ_CHUNK
        ):
            raise PatchcloudValueError(f"chunk must be a positive multiple of {LAZ_CHUNK:,} points, got {self.chunk!r}")
        if not isinstance(self.scheduler, str) or not self.scheduler:
            raise PatchcloudValueError(f"scheduler must be a name or an address, got {self.scheduler!r}")


def split_options(kwargs: dict, options, kind: type, run: RunOptions | None) -> tuple[Any, RunOptions]:
    """``kind`` and :class:`RunOptions` objects from keyword arguments, for the jobs' functions.

    ``options`` (a ``kind`` or None) and ``run`` are the objects given, if
    any; a keyword argument overrides their field of that name.  An unknown
    name is an error listing the valid ones.

    >>> from patchcloud.core import CompressOptions
    >>> o, r = split_options({"max_error": 0.05, "workers": 2}, None, CompressOptions, None)
    >>> o.max_error, r.workers
    (0.05, 2)
    """
    mine = {f.name for f in dataclasses.fields(kind)}
    theirs = {f.name for f in dataclasses.fields(RunOptions)}
    unknown = sorted(set(kwargs) - mine - theirs)
    if unknown:
        raise PatchcloudValueError(
            f"unknown option{'s' if len(unknown) > 1 else ''} {', '.join(unknown)}; valid: {', '.join(sorted(mine | theirs))}"
        )
    own = options_with(kind, options, {k: v for k, v in kwargs.items() if k in mine})
    how = {k: v for k, v in kwargs.items() if k in theirs}
    return own, dataclasses.replace(run or RunOptions(), **how)


def params_key(values: dict) -> str:
    """A short hash of resolved parameters (JSON-serialisable): what a step records as "done with these".

    >>> params_key({"a": 1, "b": 2.0}) == params_key({"b": 2.0, "a": 1})
    True
    """
    return hashlib.sha256(json.dumps(values, sort_keys=True).encode()).hexdigest()[:16]


def default_store_path(output: str | os.PathLike) -> str:
    """Where a job keeps its store when none is given: beside the output.

    >>> default_store_path("out/city.laz")
    'out/city.laz.store'
    """
    return str(output) + ".store"


def time_and_memory_lines(seconds: dict[str, float], points: int, peak_memory: int, scheduler: str) -> list[str]:
    """The last two lines of a job's summary: time per step and in all, and the peak memory.

    >>> print("\\n".join(time_and_memory_lines({"tile": 1.0, "fit": 3.0}, 8_000_000, 2**30, "threads")))
      time            tile 1.0 s, fit 3.0 s; total 4.0 s (2,000,000 points/s)
      peak memory     1,024 MiB (all processes, scheduler threads)
    """
    total = sum(seconds.values())
    return [
        "  time            " + ", ".join(f"{s} {t:.1f} s" for s, t in seconds.items())
        + f"; total {total:.1f} s ({points / max(total, 1e-9):,.0f} points/s)",
        f"  peak memory     {peak_memory / 2**20:,.0f} MiB (all processes, scheduler {scheduler})",
    ]


@dataclass
class JobContext:
    """What a job's steps work with: the input, the tiled store, the scheduler, the run's options.

    ``seconds`` gets each step's wall time; ``peak_memory`` (bytes, all
    processes) is set before the summary is made; ``kept_store`` is the
    store's URL when it is kept after the job, else "".
    """

    source: LasSource
    output: Path
    store: Store
    runner: Runner
    run: RunOptions
    seconds: dict[str, float] = field(default_factory=dict)
    peak_memory: int = 0
    kept_store: str = ""

    def map_tiles(self, func: Callable, **kwargs) -> dict:
        """:func:`patchcloud.stream.engine.tasks.map_tiles` on this job's store and runner."""
        return map_tiles(func, self.store, runner=self.runner, **kwargs)


class Job:
    """One job on the tiled store: subclass it, give :meth:`steps`, :meth:`columns` (or :meth:`write`) and :meth:`summarise`.

    The instance holds the job's validated options and, as attributes, what
    its steps hand on to later ones (resolved parameters, per-tile counts).
    """

    #: Name of the writing step in the summary's times.
    write_step = "export"

    def steps(self) -> Sequence[tuple[str, Callable[[JobContext], None]]]:
        """The job's steps after ``tile``, in order: (name in the summary's times, function of the context)."""
        return ()

    def columns(self, ctx: JobContext) -> tuple[list[Column], Sequence[tuple]]:
        """The per-tile arrays written as new dimensions, and those dimensions (name, type, description[, no-data])."""
        raise NotImplementedError(f"{type(self).__name__} writes its output with its own write()")

    def write(self, ctx: JobContext) -> None:
        """Write the output: by default the input's records plus :meth:`columns`, under a temporary name."""
        columns, dims = self.columns(ctx)
        export_columns(ctx.store, ctx.source, str(ctx.output), columns, dims, runner=ctx.runner, overwrite=ctx.run.overwrite,
                       quiet=ctx.run.quiet)

    def summarise(self, ctx: JobContext):
        """The job's summary (a dataclass with ``format()``), made after the output is written."""
        raise NotImplementedError


def write_profile(path: str | os.PathLike, runner: Runner, seconds: dict, started: float, ready: float, ended: float) -> None:
    """Write a run's task stream as JSON: ``tasks`` [step, start, end, worker], ``steps`` (seconds), the run's times."""
    data = dict(
        scheduler=runner.scheduler, slots=runner.slots, started=started, ready=ready, ended=ended, steps=seconds,
        tasks=[list(t) for t in runner.tasks],
    )
    tmp = Path(str(path) + ".partial")
    tmp.write_text(json.dumps(data))
    tmp.replace(path)


def run_job(job: Job, input: str | os.PathLike, output: str | os.PathLike, run: RunOptions) -> Any:
    """Run ``job`` from ``input`` to ``output`` (see the module's docstring for the order of things); return its summary.

    Raises
    ------
    PatchcloudIOError (an OSError)
        An input that is not a readable, complete LAS/LAZ file, an existing
        output without ``overwrite``, an unusable store.
    PatchcloudValueError (a ValueError)
        An invalid option (the scheduler's, say).
    """
    check_las_output(output)
    out = check_writable(output, run.overwrite)
    src = open_source(input)
    url = run.store or default_store_path(out)
    keep = (run.store is not None) if run.keep_store is None else bool(run.keep_store)
    started = time.time()
    with Runner(run.scheduler, run.workers, quiet=run.quiet, points=src.point_count) as runner:
        store, tile_seconds = ensure_tiled(src, url, run.tile_size, runner, run.quiet, run.chunk)
        ctx = JobContext(source=src, output=out, store=store, runner=runner, run=run, kept_store=url if keep else "")
        ctx.seconds["tile"] = tile_seconds
        for name, step in job.steps():
            t0 = time.perf_counter()
            step(ctx)
            ctx.seconds[name] = ctx.seconds.get(name, 0.0) + time.perf_counter() - t0
        t0 = time.perf_counter()
        job.write(ctx)
        ctx.seconds[job.write_step] = time.perf_counter() - t0
        ctx.peak_memory = runner.peak_memory()
        summary = job.summarise(ctx)
        if run.profile:
            write_profile(run.profile, runner, ctx.seconds, started, runner.ready_at, time.time())
    if not keep and "://" not in url:
        shutil.rmtree(url, ignore_errors=True)
    return summary
