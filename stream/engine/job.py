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
   removed (a store the user named is kept);
7. the dask cluster and client are closed, and the threads the run
   started stopped (:mod:`~patchcloud.stream.engine.background`).

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
patchcloud.core.errors.PatchcloudValueError: tile_size must be a positive length in the coordinates' unit, got -1
"""

from __future__ import annotations

import contextlib
import dataclasses
import numbers
import hashlib
import json
import os
import uuid
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


from patchcloud.core import PatchcloudError, PatchcloudExistsError, check_flag, PatchcloudIOError, PatchcloudNotImplementedError, PatchcloudValueError, options_with, os_error_line
from patchcloud.stream.engine.background import stops_what_it_starts
from patchcloud.stream.engine.compiling import CompileClock, announce_on_stderr, compiling_line, merge_intervals, seconds_within
from patchcloud.stream.engine.export import Column, complete_outputs, export_columns
from patchcloud.stream.engine.ingest import TILE_POINT_BYTES, NothingToResumeError, check_store_selection, check_tile_size, ensure_tiled
from patchcloud.stream.engine.placement import (FEW_CORES, IN_MEMORY_BASE, IN_MEMORY_POINT_BYTES, IN_MEMORY_POINTS,
                                                IN_MEMORY_POINTS_FEW_CORES, in_memory_by_default, in_memory_points)
from patchcloud.stream.engine.runner import Runner, check_scheduler
from patchcloud.stream.engine.tasks import map_tiles
from patchcloud.stream.io.crs import UNITS, Units, units_of
from patchcloud.stream.io.las_records import provenance_vlr
from patchcloud.stream.io.classes import REASONS, Selection
from patchcloud.stream.io.catalog import Catalog, check_out_dir, expand_inputs, open_catalog, output_paths
from patchcloud.stream.io.las import (
    CorruptPointsError, LasSource, atomic_output, check_dims_fit, check_las_output, check_laz_keeps, check_not_input, check_writable,
    open_source, same_file,
)
from patchcloud.stream.io.las_output import LAZ_CHUNK
from patchcloud.stream.io import las_output, memory_group
from patchcloud.stream.io.budget import check_memory
from patchcloud.stream.io.lock import RunLock
from patchcloud.stream.io.renamed import file_state, partial_path, renamed_here
from patchcloud.stream.io.store import PatchcloudStoreError, Store, remove_store_dir, removing_path

__all__ = [
    "IN_MEMORY_POINTS", "IN_MEMORY_POINTS_FEW_CORES", "MAX_WORKERS", "FEW_CORES", "in_memory_points", "RunOptions", "Job", "JobContext", "run_job", "split_options", "run_request", "params_key", "in_file_frame", "default_store_path", "write_profile",
    "time_and_memory_lines", "memory_scope", "file_lines", "kept_store_note", "says_what_is_kept", "catalog_units", "units_line", "units_text", "left_out_lines", "left_out_text",
]

#: The most worker processes or threads a run starts (more is a typo: each is a process started on this machine).
MAX_WORKERS = 4096


@dataclass(frozen=True)
class RunOptions:
    """How a job runs, the same for every job (not what it computes).

    Parameters
    ----------
    tile_size : float, optional
        Tile edge in the file's unit (its CRS's, or ``units``: metres, feet),
        rounded down to a power of two; default: about a million points per
        tile over the file's footprint.
    scheduler : str
        "auto" (default: worker processes for files of 2 million points or
        more; below that in memory (``in_memory``), or threads when
        ``workers`` is given), "threads", "processes", "synchronous", or a dask
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
    out_dir : str, optional
        A catalog run: the input is several files (paths, a directory, a
        glob; :func:`patchcloud.stream.io.catalog.expand_inputs`) taken as
        one cloud, and each file's output goes here under the file's name
        (``.copc.laz`` becoming ``.laz``).  Made if absent.  The default
        store is then ``OUT_DIR/patchcloud.store``.
    assume_crs : str, optional
        The CRS of the files that have none (``"EPSG:2154"``, WKT: what
        pyproj takes), which gives their unit and is written into their
        outputs; a file with another CRS is an error.  Without it a file
        without a CRS among files with one is an error (one file alone is
        taken in metres, or ``units``).
    classes : tuple of int or str, optional
        Which points take part (:mod:`patchcloud.stream.io.classes`): only
        those of these ASPRS classes ("2,6" or ``(2, 6)``) are computed and
        used as neighbours; the others are written unchanged with the new
        dimensions' empty value (NormalMethod 0 and a zero normal, DoN 0,
        ClusterID 0; ``compress`` keeps them as residual points, within its budget).
        PDAL's ``where: Classification == 2``.  Default: every class.
    keep_noise : bool
        Keep noise (classes 7 and 18) and withheld points in the
        neighbourhoods.  Default False: they are left out as above (a noise
        class listed in ``classes`` is kept).
    units : {"m", "ft", "us-ft"}, optional
        The unit of the file's coordinates, which every distance option and
        summary figure is in, instead of its CRS's (for a file without a CRS,
        or with a wrong one): see :mod:`patchcloud.stream.io.crs`.  Default:
        the CRS's horizontal unit (metres for a file without a CRS); a
        geographic CRS is an error naming this option.
    in_memory : bool, optional
        Run in this process, the tiles held in memory: no dask cluster, no
        store on disk; a step's tasks side by side on ``workers`` threads
        (default: every core), each task's kernels sequential and GIL-free,
        or, for a step of fewer tasks than threads, one task at a time with
        its kernels on every thread; the same tiles and the
        same results, byte for byte, as a run on a store.  Default (None):
        for inputs of at most :func:`in_memory_points` (2 million points;
        10 million on a machine of at most 2 cores) when neither
        ``store``, ``keep_store``, ``workers`` nor a ``scheduler`` other
        than "auto" is given, and its peak fits the memory budget.  True:
        whatever the size within the budget (memory grows with it: about
        0.73 GiB plus 140 bytes per point at the peak); False: never.
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
    out_dir: str | None = None
    assume_crs: str | None = None
    in_memory: bool | None = None
    units: str | None = None
    classes: tuple[int, ...] | None = None
    keep_noise: bool = False

    def __post_init__(self) -> None:
        for flag in ("overwrite", "quiet"):  # overwrite="no" must not replace a file
            object.__setattr__(self, flag, check_flag(flag, getattr(self, flag)))
        object.__setattr__(self, "keep_store", check_flag("keep_store", self.keep_store, allow_none=True))
        check_tile_size(self.tile_size)
        object.__setattr__(self, "classes", self.selection.classes)  # checked, as a sorted tuple
        if isinstance(self.store, os.PathLike):  # a pathlib.Path as well as a str
            object.__setattr__(self, "store", os.fspath(self.store))
        if self.store is not None and not str(self.store).strip():  # ('' ran on the default store, then kept it)
            raise PatchcloudValueError(f"store must be a path or an fsspec URL (leave it out for OUT.store, removed when the job "
                                       f"succeeds); got {self.store!r}")
        if self.units is not None and self.units not in UNITS:
            raise PatchcloudValueError(f"units must be one of {', '.join(UNITS)}; got {self.units!r}")
        if self.workers is not None and (isinstance(self.workers, bool) or not isinstance(self.workers, numbers.Real)
                                         or self.workers != int(self.workers) or self.workers < 1):
            raise PatchcloudValueError(f"workers must be a whole number of at least 1, got {self.workers!r}")
        if self.workers is not None and self.workers > MAX_WORKERS:
            raise PatchcloudValueError(f"workers must be at most {MAX_WORKERS:,}, got {self.workers!r}")
        if self.chunk is not None and (
            isinstance(self.chunk, bool) or int(self.chunk) != self.chunk or self.chunk < 1 or self.chunk % LAZ_CHUNK
        ):
            raise PatchcloudValueError(f"chunk must be a positive multiple of {LAZ_CHUNK:,} points, got {self.chunk!r}")
        check_scheduler(self.scheduler)
        if self.in_memory not in (None, True, False):
            raise PatchcloudValueError(f"in_memory must be True, False or None (by the input's size), got {self.in_memory!r}")
        if self.in_memory:
            if self.store is not None or self.keep_store:
                raise PatchcloudValueError("in_memory runs keep no store: leave out store and keep_store, or in_memory")
            if self.scheduler not in ("auto", "synchronous"):
                raise PatchcloudValueError(f"in_memory runs inline, on no scheduler: leave out scheduler ({self.scheduler!r}), or in_memory")

    @property
    def selection(self) -> Selection:
        """The points that take part (:class:`patchcloud.stream.io.classes.Selection`)."""
        return Selection(classes=self.classes, keep_noise=self.keep_noise)

    def runs_in_memory(self, points: int) -> bool:
        """Whether a run on an input of ``points`` points runs in memory (see ``in_memory``): by default only if its
        peak fits the memory budget (:mod:`patchcloud.stream.io.budget`); asked for beyond it, a PatchcloudMemoryError.

        >>> RunOptions().runs_in_memory(60_000), RunOptions().runs_in_memory(10**8), RunOptions(scheduler="threads").runs_in_memory(60_000)
        (True, False, False)
        """
        if self.in_memory:
            check_memory(IN_MEMORY_BASE + IN_MEMORY_POINT_BYTES * int(points), f"a run in memory of {int(points):,} points",
                         "--on-disk runs in bounded memory")
        if self.in_memory is not None:
            return self.in_memory
        return in_memory_by_default(points, self.scheduler, self.workers, self.store, self.keep_store)


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
    if run is not None and not isinstance(run, RunOptions):
        raise PatchcloudValueError(f"run must be a RunOptions (or give its fields as keywords: workers=2, ...), "
                                   f"got {type(run).__name__}")
    return own, dataclasses.replace(run or RunOptions(), **how)


def run_request(job: "Job", run: RunOptions) -> dict:
    """What a run was asked that decides its outputs, as JSON: the job, its options as given
    (:meth:`Job.asked_parameters`), the tile size, the units and CRS assumed and the points taken part.

    Each output's record in the store keeps it; a later run on the store
    with another request finds the output not complete for it before it
    computes anything (without ``overwrite``: refused at once, the store
    untouched).  Options given as they are: an option given with the value
    its default would resolve to is another request.

    >>> from patchcloud.stream.jobs.don import DonJob
    >>> from patchcloud.core import DonOptions
    >>> run_request(DonJob(DonOptions(0.2, 2.0)), RunOptions())["options"]["r_large"]
    2.0
    """
    return json.loads(json.dumps(dict(job=job.name, options=job.asked_parameters(), tile_size=run.tile_size, units=run.units,
                                      assume_crs=run.assume_crs, selection=run.selection.to_json()), sort_keys=True, default=str))


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


def time_and_memory_lines(seconds: dict[str, float], points: int, peak_memory: int, scheduler: str, compile_seconds: float = 0.0) -> list[str]:
    """The last lines of a job's summary: numba's compiling, if any; time per step and in all; the peak memory.

    ``seconds`` leave the compiling out (:func:`_run`), so the points per
    second are the job's own; ``compile_seconds`` (a first run's) is said on
    a line of its own.

    >>> print("\\n".join(time_and_memory_lines({"tile": 1.0, "fit": 3.0}, 8_000_000, 2**30, "threads")))
      time            tile 1.0 s, fit 3.0 s; total 4.0 s (2,000,000 points/s)
      peak memory     1,024 MiB (all processes, scheduler threads)
    >>> print(time_and_memory_lines({"fit": 3.0}, 60_000, 2**30, "in memory", compile_seconds=12.5)[0])
      compiling       kernels, once: 12.5 s (numba: the first run of these kernels since installing; cached for later runs; not in the times below)
    """
    total = sum(seconds.values())
    return [
        *compiling_line(compile_seconds),
        "  time            " + ", ".join(f"{s} {t:.1f} s" for s, t in seconds.items())
        + f"; total {total:.1f} s ({points / max(total, 1e-9):,.0f} points/s)",
        f"  peak memory     {peak_memory / 2**20:,.0f} MiB {memory_scope(scheduler)}",
    ]


def memory_scope(scheduler: str) -> str:
    """What a peak memory figure covers, as summaries and reports say it.

    >>> memory_scope("in memory"), memory_scope("processes")
    ('(one process, in memory)', '(all processes, scheduler processes)')
    """
    return "(one process, in memory)" if scheduler == "in memory" else f"(all processes, scheduler {scheduler})"


def units_text(units: dict) -> str:
    """The unit every length of a summary is in, and where the unit came from: the summary's line and the report's row.

    >>> units_text({"symbol": "ft", "name": "foot", "metres": 0.3048, "source": "CRS"})
    'ft (foot, 0.3048 m; from the CRS): every length here and every distance option'
    """
    source = {"CRS": "from the CRS", "--units": "from --units", "assumed": "assumed: no CRS",
              "--assume-crs": "from the CRS --assume-crs gives",
              "unreadable": "assumed: its CRS record cannot be read, see patchcloud info"}.get(units.get("source"), "")
    return f"{units['symbol']} ({units.get('name', '')}, {units.get('metres', 1.0):g} m; {source}): every length here and every distance option"


def units_line(units: dict) -> str:
    """A summary's line naming the unit every length in it is in (:func:`units_text`).

    >>> units_line({"symbol": "ft", "name": "foot", "metres": 0.3048, "source": "CRS"})
    '  units           ft (foot, 0.3048 m; from the CRS): every length here and every distance option'
    """
    return f"  units           {units_text(units)}"


def left_out_text(left_out: dict, selection: dict | None, points: int, fate: str = "no value, in no neighbourhood") -> str:
    """How many points were left out of every neighbourhood, by reason, and what became of them (``fate``); "" when
    none: the summary's line and the report's row.

    >>> left_out_text({"classes": 5, "noise": 2, "withheld": 0}, {"classes": [2], "keep_noise": False}, 100)
    '7 (7.0%): 5 not of classes 2, 2 noise (class 7, 18); no value, in no neighbourhood'
    """
    total = sum(int(v) for v in left_out.values())
    if total == 0:
        return ""
    classes = (selection or {}).get("classes")
    words = {"classes": "not of classes " + ", ".join(str(c) for c in classes or []), "noise": "noise (class 7, 18)",
             "withheld": "withheld"}
    why = ", ".join(f"{int(left_out[r]):,} {words[r]}" for r in REASONS if int(left_out.get(r, 0)))
    return f"{total:,} ({total / max(points, 1):.1%}): {why}; {fate}"


def left_out_lines(left_out: dict, selection: dict | None, points: int, fate: str = "no value, in no neighbourhood") -> list[str]:
    """A summary's line on the points left out of every neighbourhood (:func:`left_out_text`); none when none.

    >>> print(left_out_lines({"classes": 5, "noise": 2, "withheld": 0}, {"classes": [2], "keep_noise": False}, 100)[0])
      left out        7 (7.0%): 5 not of classes 2, 2 noise (class 7, 18); no value, in no neighbourhood
    """
    text = left_out_text(left_out, selection, points, fate)
    return [f"  left out        {text}"] if text else []


def file_lines(files: list[tuple[str, str, int]]) -> list[str]:
    """A catalog summary's rows, one per file: (input, output, points); nothing for one file.

    >>> print("\\n".join(file_lines([("a/t1.laz", "o/t1.laz", 1200), ("a/t2.laz", "o/t2.laz", 35)])))
      files           2
        t1.laz        1,200 points -> o/t1.laz
        t2.laz           35 points -> o/t2.laz
    """
    if len(files) < 2:
        return []
    width = max(len(Path(i).name) for i, _, _ in files)
    return [f"  files           {len(files)}"] + [
        f"    {Path(i).name:<{width}} {n:>12,} points -> {o}" for i, o, n in files
    ]


def in_file_frame(params: dict, origin) -> dict:
    """``params`` as a user reads them: ``NAME_local`` positions (the store's frame) as ``NAME`` in file coordinates
    (``origin`` added; None stays None; without an ``origin`` they keep their names), and no ``*_key`` entries
    (hashes that tell a store's steps apart).

    >>> in_file_frame({"viewpoint_local": [1.0, 2.0, 3.0], "r_small": 0.5, "don_key": "ab12"}, (1000.0, 0.0, 0.0))
    {'viewpoint': [1001.0, 2.0, 3.0], 'r_small': 0.5}
    """
    out = {}
    for name, value in params.items():
        if name.endswith("_key"):
            continue
        if name.endswith("_local") and origin is not None:
            name = name[: -len("_local")]
            if value is not None:
                value = [float(o) + float(v) for o, v in zip(origin, value)]
        out[name] = value
    return out


@dataclass
class JobContext:
    """What a job's steps work with: the input, the tiled store (None for a job that is not ``tiled``), the scheduler, the run's options.

    ``catalog`` is the input files taken as one cloud (one file: a catalog
    of one), ``source`` its first file, ``outputs`` one output per file and
    ``output`` the output (one file) or the output directory (a catalog).
    ``seconds`` gets each step's wall time, numba's compiling (a first
    run's) not counted: that is ``compile_seconds``; ``peak_memory`` (bytes, all
    processes) is set before the summary is made; ``kept_store`` is the
    store's URL when it is kept after the job, else "".
    """

    source: LasSource
    output: Path
    store: Store | None
    runner: Runner
    run: RunOptions
    catalog: Catalog | None = None
    outputs: list[Path] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    compile_seconds: float = 0.0
    peak_memory: int = 0
    kept_store: str = ""
    units: Units | None = None

    def __post_init__(self) -> None:
        if self.catalog is None:
            self.catalog = Catalog.of(self.source)
        if self.units is None:
            self.units = catalog_units(self.catalog, self.run)
        if not self.outputs:
            self.outputs = [self.output]

    @property
    def scheduler(self) -> str:
        """How the run ran, as summaries name it: the scheduler, or "in memory"."""
        if self.store is None:
            return "in memory" if self.runner.scheduler == "synchronous" else self.runner.scheduler
        return "in memory" if self.store.in_memory else self.runner.scheduler

    @property
    def input_name(self) -> str:
        """The input as summaries name it: the file, or the catalog's first file and how many follow."""
        return self.catalog.path

    @property
    def files(self) -> list[tuple[str, str, int]]:
        """(input, output, points) of every file, for a summary's per-file rows (:func:`file_lines`)."""
        return [(self.catalog.name(f), str(o), s.point_count) for f, (s, o) in enumerate(zip(self.catalog.sources, self.outputs))]

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
    #: Whether the job takes a catalog of several files (``RunOptions.out_dir``).
    catalogs = True
    #: What an output's name ends in (any case), and what that makes of it.
    output_names = {".las": "LAS", ".laz": "LAZ"}
    #: The command's name, as the outputs' provenance VLR states it.
    name = ""
    #: Whether the store's tiles hold only the points of ``RunOptions.selection`` (else every point: the job applies
    #: the selection itself, as ``compress`` does, which keeps the others as residual points).
    tiles_selection = True
    #: Whether the job works on the tiled store (else the context's ``store`` is None: the job reads the input itself,
    #: as ``compress --keep-points`` does, part by part in input order).
    tiled = True
    #: Bytes a task holds per point of its tile, beyond its process's start: the memory budget's check once tiled.
    tile_point_bytes = TILE_POINT_BYTES

    def steps(self) -> Sequence[tuple[str, Callable[[JobContext], None]]]:
        """The job's steps after ``tile``, in order: (name in the summary's times, function of the context)."""
        return ()

    def check(self, catalog: Catalog) -> None:
        """Refuse, before anything runs, parameters the input makes meaningless (a radius wider than the cloud, say):
        a PatchcloudValueError.  Nothing by default."""

    def dims(self) -> Sequence[tuple]:
        """The dimensions the output adds to the input's (name, type, description[, no-data]), known before the run:
        an input's dimension of one of these names must hold its type (checked before anything runs).  None by default."""
        return ()

    def columns(self, ctx: JobContext) -> tuple[list[Column], Sequence[tuple]]:
        """The per-tile arrays written as new dimensions, and those dimensions (name, type, description[, no-data])."""
        raise NotImplementedError(f"{type(self).__name__} writes its output with its own write()")

    def write(self, ctx: JobContext) -> None:
        """Write the output: by default the input's records plus :meth:`columns`, under a temporary name."""
        columns, dims = self.columns(ctx)
        export_columns(ctx.store, ctx.outputs, columns, dims, runner=ctx.runner, overwrite=ctx.run.overwrite, quiet=ctx.run.quiet,
                       provenance=provenance_vlr(self.name, dict(self.parameters(), units=ctx.units.symbol, **ctx.run.selection.to_json())),
                       request=run_request(self, ctx.run))

    def parameters(self) -> dict:
        """The parameters the outputs' provenance VLR and the summary state: the job's resolved ``params`` (none by
        default) as a user reads them, positions in file coordinates (:func:`in_file_frame`, with the job's
        ``origin``, the store grid's, once known)."""
        return in_file_frame(dict(getattr(self, "params", None) or {}), getattr(self, "origin", None))

    def asked_parameters(self) -> dict:
        """The job's options as given (``options``, a dataclass, when the job has one): with the run's own options,
        what :func:`run_request` records with each output."""
        options = getattr(self, "options", None)
        return dataclasses.asdict(options) if dataclasses.is_dataclass(options) else {}

    def summarise(self, ctx: JobContext):
        """The job's summary (a dataclass with ``format()``), made after the output is written."""
        raise NotImplementedError


def write_profile(path: str | os.PathLike, runner: Runner, seconds: dict, started: float, ready: float, ended: float) -> None:
    """Write a run's task stream as JSON: ``tasks`` [step, start, end, worker], ``steps`` (seconds), the run's times,
    ``cpu``: CPU seconds (``user``, ``sys``) and minor page faults of the command and its workers."""
    data = dict(
        scheduler=runner.scheduler, slots=runner.slots, started=started, ready=ready, ended=ended, steps=seconds,
        tasks=[list(t) for t in runner.tasks], cpu=runner.cpu_usage(),
    )
    with atomic_output(path, overwrite=True) as f:
        f.write(json.dumps(data).encode("utf-8"))


def _check_inputs_kept(catalog: Catalog, outs, store: str | None) -> None:
    """No output and no store may be an input, nor the store an output (one clear error instead of a lost file)."""
    inputs = [s.path for s in catalog.sources]
    for o in outs:
        check_not_input(o, inputs)
    if store is not None and "://" not in store:
        check_not_input(store, inputs)
        for o in outs:
            if same_file(store, o):
                raise PatchcloudIOError(f"{store}: the store would be the output {o}; give another --store")


def _store_url(run: RunOptions, catalog: Catalog, default_store: str) -> tuple[str, bool]:
    """The run's store: (URL, in memory)."""
    if run.runs_in_memory(catalog.point_count):
        return f"{memory_group.PREFIX}{uuid.uuid4().hex}", True
    url = run.store or default_store
    if "://" not in url:  # a local path: absolute, the same for the workers of a cluster, started in other directories
        url = os.path.abspath(url)
    return url, False


def _complete(catalog: Catalog, outs: list[Path], url: str, selection: dict | None = None,
              request: dict | None = None) -> list[bool]:
    """For each output, whether the store at ``url``, made from the same files (and, when given, with the same
    ``selection`` of points: :meth:`Selection.to_json`), records it as complete and unchanged, and, when given, written
    for the same ``request`` (:func:`run_request`; :func:`~patchcloud.stream.engine.export.complete_outputs`)."""
    if Store.exists(url):
        st = Store.open(url, mode="r")
        if (st.attrs.get("catalog") and catalog.same_files(st.attrs["catalog"])
                and (selection is None or st.attrs.get("selection") == selection)):
            return complete_outputs(st, outs, request=request)
    return [False] * len(outs)


def _writable(catalog: Catalog, outs: list[Path], url: str, in_memory: bool, overwrite: bool, ours: list[bool],
              selection: dict | None = None, request: dict | None = None) -> list[Path]:
    """Check each output can be written: absent, or ``overwrite``, or completed by an earlier run on this store for the
    same ``request`` (:func:`~patchcloud.stream.engine.export.complete_outputs`: the export then keeps it), or ``ours``
    (completed by a run killed while removing its store: written again)."""
    done = [False] * len(outs) if in_memory else _complete(catalog, outs, url, selection, request)
    return [Path(o) if d or mine else check_writable(o, overwrite) for o, d, mine in zip(outs, done, ours)]


def _inputs_and_outputs(job: Job, input, output, run: RunOptions) -> tuple[Catalog, list[Path], Path, str, bool]:
    """Check what a run reads and writes before anything runs: (catalog, outputs, output or output directory, store, in memory)."""
    if run.out_dir is None:
        if output is None:
            raise PatchcloudValueError("give an output file, or out_dir (--out-dir) for a catalog of files")
        if not isinstance(input, (str, os.PathLike, list, tuple)):
            raise PatchcloudValueError(f"input must be the path of a LAS/LAZ file (or several paths, with out_dir), not a "
                                       f"{type(input).__name__}; for points in memory use patchcloud.estimate_normals and the "
                                       "other functions of patchcloud.core")
        if not isinstance(input, (str, os.PathLike)):
            raise PatchcloudValueError("several inputs make a catalog: give out_dir (--out-dir) instead of one output file")
        if Path(input).is_dir():
            raise PatchcloudIOError(f"{input}: is a directory; for a catalog of its files give --out-dir OUT (out_dir)")
        if Path(output).suffix.lower() not in job.output_names:
            kinds = " or ".join(f"{suffix} ({kind})" for suffix, kind in job.output_names.items())
            raise PatchcloudValueError(f"{output}: an output's name ends in {kinds}, any case")
        check_las_output(output)
        check_writable(output, overwrite=True)  # its directory; whether it may be replaced once the store is known
        # assume_crs: the CRS of a file without one (its units), or a check of the file's
        src = open_source(input)  # one file (a glob is not one: no such file)
        catalog = Catalog.of(src) if run.assume_crs is None else open_catalog([src.path], run.assume_crs)
        catalog_units(catalog, run)
        _check_inputs_kept(catalog, [output], run.store)
        check_laz_keeps(catalog.sources[0], output)
        url, in_memory = _store_url(run, catalog, default_store_path(output))
        return catalog, [Path(output)], Path(output), url, in_memory
    if output is not None:
        raise PatchcloudValueError(f"{output}: with out_dir (--out-dir) every argument is an input; the outputs go to {run.out_dir}")
    paths = expand_inputs(input)
    if len(paths) > 1 and not job.catalogs:
        raise PatchcloudNotImplementedError(f"{type(job).__name__.removesuffix('Job').lower()} takes one file at a time: "
                                            f"catalogs of files are not supported yet ({len(paths)} files given)")
    out_dir = check_out_dir(run.out_dir)
    outs = output_paths(paths, out_dir, input)
    catalog = open_catalog(paths, run.assume_crs)
    catalog_units(catalog, run)
    _check_inputs_kept(catalog, outs, run.store)
    for src, o in zip(catalog.sources, outs):
        check_laz_keeps(src, o)
    if run.store is not None and "://" not in run.store and Path(run.store).resolve() == out_dir.resolve():
        raise PatchcloudValueError(f"{run.store}: the store (--store) and the output directory (--out-dir) must differ")
    url, in_memory = _store_url(run, catalog, str(out_dir / "patchcloud.store"))
    return catalog, outs, out_dir, url, in_memory


def catalog_units(catalog: Catalog, run: RunOptions) -> Units:
    """The unit of the catalog's coordinates (:func:`patchcloud.stream.io.crs.units_of`; ``run.units`` overrides its CRS).

    Metres assumed for files whose CRS record cannot be read say so (source ``unreadable``), not "no CRS"; a unit of
    the CRS that ``--assume-crs`` gives files without one says so (source ``--assume-crs``), not "from the CRS"."""
    units = units_of(catalog.crs, catalog.mins, catalog.maxs, run.units, where=catalog.path)
    if units.source == "assumed" and any(s.crs_error for s in catalog.sources):
        return dataclasses.replace(units, source="unreadable")
    if units.source == "CRS" and all(s.crs is None for s in catalog.sources):  # no file has one: --assume-crs gave it
        return dataclasses.replace(units, source="--assume-crs")
    return units


def run_job(job: Job, input, output, run: RunOptions) -> Any:
    """Run ``job`` from ``input`` to ``output`` (see the module's docstring for the order of things); return its summary.

    ``input``: one file (then ``output`` is the output file), or, with
    ``run.out_dir``, one or several paths, directories or globs taken as one
    cloud (then ``output`` is None and each file's output goes to ``out_dir``).

    Raises
    ------
    PatchcloudIOError (an OSError)
        An input that is not a readable, complete LAS/LAZ file, an existing
        output without ``overwrite``, an unusable store.
    PatchcloudValueError (a ValueError)
        An invalid option (the scheduler's, say), or a catalog whose files
        are not one cloud (CRSs, grids).
    PatchcloudLockedError (a PatchcloudIOError)
        Another run is writing the same output or store
        (:mod:`patchcloud.stream.io.lock`).
    """
    with stops_what_it_starts():  # no thread of the run's left running (stream.engine.background)
        return _run_job(job, input, output, run)


def _run_job(job: Job, input, output, run: RunOptions) -> Any:
    """run_job, within :func:`~patchcloud.stream.engine.background.stops_what_it_starts`."""
    catalog, outs, out, url, in_memory = _inputs_and_outputs(job, input, output, run)
    job.check(catalog)
    if job.dims():  # an input dimension too narrow for them, before anything runs (it came after the whole run: review K)
        for src in catalog.sources:
            check_dims_fit(src, job.dims())
    made = run.out_dir is not None and not out.exists()  # a catalog's output directory, made for this run
    if made:
        out.mkdir()
    # a catalog: OUT_DIR/patchcloud.lock, and each output's own lock, the one a run on that file alone takes
    locked = [out] if run.out_dir is None else [out / "patchcloud", *outs]
    if not in_memory and "://" not in url:  # the store too, given or not: another run may be given it as its --store
        locked.append(url)
    try:
        with RunLock(locked):  # then whether the outputs may be written: a killed run's leftovers are this run's to judge
            held = _named_store_attrs(run, catalog, url, in_memory)
            if held is not None:  # the user's --store, of these files: its unit, and whether its tiles are this job's
                run = _store_units(run, held)
                if job.tiled:
                    check_store_selection(held, url, _tiles_selection(job, run), run.selection,
                                          job.name or type(job).__name__.removesuffix("Job").lower())
            ours = _left_complete(catalog, outs, url, in_memory)
            outs = _writable(catalog, outs, url, in_memory, run.overwrite, ours, _tiles_selection(job, run).to_json(),
                             run_request(job, run))
            if any(ours):  # written by a run killed while removing its store: written again, the same bytes
                run = dataclasses.replace(run, overwrite=True)
            return _run_locked(job, catalog, outs, out, url, in_memory, run)
    except BaseException:
        if made:  # a run that failed before writing anything there leaves no empty directory behind
            try:
                out.rmdir()
            except OSError:  # not empty: an output or a kept store is in it
                pass
        raise


def _named_store_attrs(run: RunOptions, catalog: Catalog, url: str, in_memory: bool) -> dict | None:
    """The attributes of the store the run names (``--store``) where it exists and holds these files, else None."""
    if run.store is None or in_memory or not Store.exists(url):
        return None
    a = Store.open(url).attrs
    return a if a.get("catalog") and catalog.same_files(a["catalog"]) else None


def _store_units(run: RunOptions, held: dict) -> RunOptions:
    """``run`` with the ``--units`` that ``tile --units`` recorded in its store (attributes ``held``), for a run on that
    store that gives none: its tile size and every length are in that unit, as the tiling's were."""
    if run.units is None and held.get("units_asked"):
        return dataclasses.replace(run, units=held["units_asked"])
    return run


def _tiles_selection(job: Job, run: RunOptions) -> Selection:
    """The points the job's store tiles: the run's selection, or every point for a job that selects itself."""
    return run.selection if job.tiles_selection else Selection(keep_noise=True)


def _left_complete(catalog: Catalog, outs: list[Path], url: str, in_memory: bool) -> list[bool]:
    """For each output, whether a run killed while removing its store (:meth:`Store.discard`) had completed it, by that
    store's record; the rest of that store is removed.  All False when there is no such store."""
    left = removing_path(url)
    if in_memory or "://" in url or not os.path.isdir(left):
        return [False] * len(outs)
    try:
        return _complete(catalog, outs, left)
    except PatchcloudError:  # its record already removed, or unreadable: it proves nothing
        return [False] * len(outs)
    finally:
        remove_store_dir(left)


def _run_locked(job: Job, catalog: Catalog, outs: list[Path], out: Path, url: str, in_memory: bool, run: RunOptions) -> Any:
    """run_job once its outputs and store are checked and locked."""
    if in_memory:
        before = [file_state(o) for o in outs]
        try:
            return _run_cleaned(job, catalog, outs, out, url, False, dataclasses.replace(run, scheduler="synchronous"))
        except KeyboardInterrupt:
            raise KeyboardInterrupt(f"interrupted{_remove_written(outs, before)}") from None
        except PatchcloudError as exc:
            raise type(exc)(f"{exc}{_remove_written(outs, before)}") from exc
        except OSError as exc:  # disk full, permission: named, as on disk (in memory, only the outputs are written)
            line = os_error_line(exc) if exc.filename else f"{out}: {os_error_line(exc)}"
            raise PatchcloudIOError(f"{line}{_remove_written(outs, before)}") from exc
        except BaseException:  # a bug: its traceback as it is, the outputs removed all the same
            _remove_written(outs, before)
            raise
        finally:
            Store.discard(url)
    keep = (run.store is not None) if run.keep_store is None else bool(run.keep_store)
    with says_what_is_kept(url, keep):
        summary = _run_cleaned(job, catalog, outs, out, url, keep, run)
    if not keep:
        Store.discard(url)
    return summary


@contextlib.contextmanager
def says_what_is_kept(url: str, keep: bool = True):
    """A run on the store ``url`` that fails or is stopped says, in its one line, that the store is kept and the same
    command resumes from it (:func:`kept_store_note`); an OSError (disk full, permission) becomes a PatchcloudIOError
    naming its file.  Where nothing would resume (no points, too small tiles, point data that cannot be decoded: the
    same command would fail again, or read the file anew) the store is removed unless ``keep``, and a damaged store
    (PatchcloudStoreError) says what to do itself.  The jobs' runs and ``tile`` share it."""
    try:
        yield
    except PatchcloudStoreError:
        raise
    except (NothingToResumeError, CorruptPointsError):
        if not keep:
            Store.discard(url)
        raise
    except PatchcloudError as exc:  # (an output that exists: the same command resumes once it says --overwrite)
        raise type(exc)(f"{exc}{kept_store_note(url, overwrite=isinstance(exc, PatchcloudExistsError))}") from exc
    except OSError as exc:  # disk full, permission, read-only file system: named, and the store said
        line = os_error_line(exc) if exc.filename else f"{url}: {os_error_line(exc)}"
        raise PatchcloudIOError(f"{line}{kept_store_note(url)}") from exc
    except KeyboardInterrupt:
        raise KeyboardInterrupt(f"interrupted{kept_store_note(url)}") from None


def _run_cleaned(job: Job, catalog: Catalog, outs: list[Path], out: Path, url: str, keep: bool, run: RunOptions) -> Any:
    """:func:`_run`; when it fails or is stopped, what is left of its outputs' partial files once its workers are gone.

    The export removes them as it stops, but a task still running then (a
    worker finishes the task it is in) may write a LAZ fragment into the
    fragments' directory while it is being removed, which leaves the
    directory and that fragment (seen once by review J after a Ctrl-C): by
    the time :func:`_run` returns, its cluster is closed and nothing writes
    any more.
    """
    try:
        return _run(job, catalog, outs, out, url, keep, run)
    except BaseException:
        for o in outs:
            las_output.remove_partial(partial_path(o))
        raise


def _remove_written(outs: list[Path], before: list) -> str:
    """Remove the outputs a run in memory wrote before it stopped (the files that are not as they were, ``before`` their
    :func:`~patchcloud.stream.io.renamed.file_state`, and that this process renamed into place, unchanged since:
    :func:`~patchcloud.stream.io.renamed.renamed_here`; a file another program wrote there meanwhile is left): with no
    store, nothing would resume them, and the same command then starts over without --overwrite.  What to say of it."""
    gone = []
    for o, was in zip(outs, before):
        now = file_state(o)
        if now is None or now == was or not renamed_here(o):
            continue
        try:
            o.unlink()
            gone.append(o)
        except OSError:  # left as it is
            pass
    if not gone:
        return ""
    return f" (run in memory, so nothing resumes: the {len(gone)} output(s) it had written are removed; the same command starts over)"


def kept_store_note(url: str, overwrite: bool = False) -> str:
    """What a failed or interrupted run says of its store: where it is, how big, and that the same command (with
    ``--overwrite`` where ``overwrite``: an output exists) resumes from it."""
    if "://" in url or not Store.exists(url):
        return ""
    size = sum(f.stat().st_size for f in Path(url).rglob("*") if f.is_file())
    again = "the same command with --overwrite" if overwrite else "the same command"
    return f" (the store {url}, {size / 2**20:,.0f} MiB, is kept: {again} resumes from it; remove it to start over)"


def _run(job: Job, catalog: Catalog, outs: list[Path], out: Path, url: str, keep: bool, run: RunOptions) -> Any:
    """Tile, run the steps, write the outputs: run_job once what is read and written is checked and the store chosen.

    numba's compiling (a first run's) is timed apart (:mod:`~patchcloud.stream.engine.compiling`):
    taken out of each step's time, it is the context's ``compile_seconds``.
    """
    started = time.time()
    windows: dict[str, list[tuple[float, float]]] = {}  # each step's wall-clock spans
    with CompileClock(announce=None if run.quiet else announce_on_stderr) as clock, \
            Runner(run.scheduler, run.workers, quiet=run.quiet, points=catalog.point_count, pool=memory_group.is_memory_url(url)) as runner:
        w0 = time.time()
        store, tile_seconds = None, None
        if job.tiled:
            store, tile_seconds = ensure_tiled(catalog, url, run.tile_size, runner, run.quiet, run.chunk, _tiles_selection(job, run),
                                               job.tile_point_bytes)
            windows["tile"] = [(w0, time.time())]
        ctx = JobContext(source=catalog.holding[0], output=out, store=store, runner=runner, run=run, catalog=catalog, outputs=outs,
                         kept_store=url if keep else "")
        if tile_seconds is not None:
            ctx.seconds["tile"] = tile_seconds
        for name, step in job.steps():
            t0, w0 = time.perf_counter(), time.time()
            step(ctx)
            ctx.seconds[name] = ctx.seconds.get(name, 0.0) + time.perf_counter() - t0
            windows.setdefault(name, []).append((w0, time.time()))
        t0, w0 = time.perf_counter(), time.time()
        job.write(ctx)
        Store.settle(url)  # the working arrays removed in the background (the parts' fragments, the export's) are gone
        ctx.seconds[job.write_step] = time.perf_counter() - t0
        windows[job.write_step] = [(w0, time.time())]
        compiling = merge_intervals(clock.intervals + runner.compile_intervals)
        for name, spans in windows.items():
            ctx.seconds[name] = max(0.0, ctx.seconds[name] - sum(seconds_within(compiling, a, b) for a, b in spans))
        ctx.compile_seconds = sum(b - a for a, b in compiling)
        ctx.peak_memory = runner.peak_memory()
        summary = job.summarise(ctx)
        if run.profile:
            write_profile(run.profile, runner, ctx.seconds, started, runner.ready_at, time.time())
    return summary
