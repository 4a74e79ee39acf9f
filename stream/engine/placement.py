"""Where a run runs: in memory, on threads or on local worker processes, by the input's size and the options given.

One rule, read by the job (:meth:`patchcloud.stream.engine.job.RunOptions.runs_in_memory`,
:class:`patchcloud.stream.engine.runner.Runner`) and by the console script
before it imports the job, to start the workers' fork server while it
does (:func:`starts_local_processes`, :mod:`patchcloud.stream.engine.forkserver`).
It imports nothing heavy (no numba, dask or zarr).
"""

from __future__ import annotations

import os

from patchcloud.stream.io.budget import max_memory

__all__ = [
    "AUTO_PROCESSES_POINTS", "IN_MEMORY_POINTS", "IN_MEMORY_POINTS_FEW_CORES", "FEW_CORES", "IN_MEMORY_BASE",
    "IN_MEMORY_POINT_BYTES", "in_memory_points", "in_memory_by_default", "resolve_scheduler", "starts_local_processes",
]

#: From this many points on, "auto" runs worker processes (below, threads: no processes to start).
AUTO_PROCESSES_POINTS = 2_000_000
#: Inputs of at most this many points run in memory by default (:attr:`RunOptions.in_memory`): measured peak 0.97 GiB
#: (city LAZ, 2-core machine, two tiles at a time; 1.05 GiB at 4M points, 2.02 GiB at 10M:
#: tools/results/bench_small_modes-2026-11-26.txt).
IN_MEMORY_POINTS = 2_000_000
#: The same on a machine of at most :data:`FEW_CORES` cores: there worker processes do not win (2 cores, city LAZ,
#: tools/results/bench_small_modes-2026-11-26.txt: in memory 6.29 s against 10.18 s on disk at 4M points, 13.43 s
#: against 20.05 s at 10M, peak 2.02 GiB).
IN_MEMORY_POINTS_FEW_CORES = 10_000_000
FEW_CORES = 2
#: Peak memory of a run in memory: at most this much, plus :data:`IN_MEMORY_POINT_BYTES` per point (measured on the city,
#: 2M to 10M points, a step's tiles two at a time: 0.97, 1.14 and 2.01 GiB; the line 0.73 GiB + 140 B per point lies
#: above each).
IN_MEMORY_BASE = 750 << 20
IN_MEMORY_POINT_BYTES = 140


def in_memory_points(cores: int | None = None) -> int:
    """The largest input (points) that runs in memory by default on a machine of ``cores`` cores (default: this one's).

    >>> in_memory_points(2), in_memory_points(16)
    (10000000, 2000000)
    """
    cores = (os.cpu_count() or 1) if cores is None else int(cores)
    return IN_MEMORY_POINTS_FEW_CORES if cores <= FEW_CORES else IN_MEMORY_POINTS


def in_memory_by_default(points: int, scheduler: str = "auto", workers: int | None = None, store: str | None = None,
                         keep_store: bool | None = None) -> bool:
    """Whether a run of ``points`` points with these options (those of :class:`RunOptions`, ``in_memory`` not given)
    runs in memory: at most :func:`in_memory_points` points, within the memory budget, and no option that asks for a
    scheduler, workers or a store.

    >>> in_memory_by_default(60_000), in_memory_by_default(10**8), in_memory_by_default(60_000, workers=2)
    (True, False, False)
    """
    need = IN_MEMORY_BASE + IN_MEMORY_POINT_BYTES * int(points)
    return (int(points) <= in_memory_points() and store is None and not keep_store and scheduler == "auto"
            and workers is None and need <= max_memory())


def resolve_scheduler(scheduler: str, points: int | None) -> str:
    """The scheduler "auto" stands for with a file of ``points`` points; any other name as it is.

    lazrs holds the GIL for a whole call and zarr and numpy parts of a task
    hold it too, so on files of millions of points worker processes scale
    where threads do not (measured in the README); below
    :data:`AUTO_PROCESSES_POINTS`, starting processes costs more than it gains.

    >>> resolve_scheduler("auto", 10_000_000), resolve_scheduler("auto", 60_000), resolve_scheduler("threads", 10**9)
    ('processes', 'threads', 'threads')
    """
    if scheduler != "auto":
        return scheduler
    return "processes" if points is not None and points >= AUTO_PROCESSES_POINTS else "threads"


def starts_local_processes(points: int | None, scheduler: str = "auto", workers: int | None = None, store: str | None = None,
                           keep_store: bool | None = None, in_memory: bool | None = None) -> bool:
    """Whether a run of ``points`` points (None: not known) with these options starts a local cluster of worker processes.

    >>> starts_local_processes(50_000_000), starts_local_processes(60_000), starts_local_processes(None, "processes")
    (True, False, True)
    >>> starts_local_processes(50_000_000, "tcp://head:8786"), starts_local_processes(50_000_000, in_memory=True)
    (False, False)
    """
    if in_memory or scheduler not in ("auto", "processes"):
        return False
    if scheduler == "auto" and (points is None or (in_memory is None and in_memory_by_default(points, scheduler, workers, store, keep_store))):
        return False
    return resolve_scheduler(scheduler, points) == "processes"
