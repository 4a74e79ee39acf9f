"""The ``patchcloud`` console script: the workers' fork server started first, then the command line.

A run on local worker processes waits, before its first task, for one
fork server to import what the workers need (dask.distributed, numba,
zarr, laspy and patchcloud's task modules: 1.2 s on the 2-core machine,
2.1 s on the 16-core one; :mod:`patchcloud.stream.engine.forkserver`).
The command line imports click, numpy and its subcommands before it reads
the options (0.2 s here; on the 16-core machine the server started 1.0 s
after the process), so the server started only then.  Here the arguments
are looked at first, before those imports (:func:`early_job`): when they
name a job, a LAS/LAZ input whose header gives its point count, and
options with which the run will start local worker processes (the one
rule, :func:`patchcloud.stream.engine.placement.starts_local_processes`),
the server starts at once.

This quick look is a hint, nothing more: what it does not understand (a
catalog's directories and globs, ``--help``, a command that is not a job)
leaves the start to the command line as before
(:func:`patchcloud.stream.cli.options.start_workers_early`), which parses
the options for real and checks the inputs; a server started here that the
run does not use ends with the process.
"""

from __future__ import annotations

import os
import sys

__all__ = ["run", "start_early", "early_job", "JOB_MODULES"]

#: The commands that may start local worker processes: the module the fork server imports for each, and whether the
#: command runs a catalog's files one by one (its largest file decides, not their sum).
JOB_MODULES = {
    "normals": ("patchcloud.stream.jobs.normals", False),
    "don": ("patchcloud.stream.jobs.don", False),
    "segment": ("patchcloud.stream.jobs.segment", False),
    "compress": ("patchcloud.stream.jobs.compress", True),
}
#: The options :func:`early_job` reads, and whether each takes a value (the others of the command line it skips).
_READ = {"--scheduler": True, "--scheduler-file": True, "--workers": True, "--store": True, "--out-dir": True,
         "--keep-store": False, "--in-memory": False, "--on-disk": False}
_SUFFIXES = (".las", ".laz")


def run() -> None:
    """The ``patchcloud`` command: :func:`patchcloud.stream.cli.run`, after :func:`start_early`."""
    from patchcloud.stream.engine.dask_start import skip_dask_templates

    skip_dask_templates()  # before start_early imports dask (the command line's set-up would come too late)
    start_early(sys.argv[1:])
    from patchcloud.stream.cli import run as command_line

    command_line()


def start_early(argv: list[str]) -> str | None:
    """Start the fork server of the job :func:`early_job` names for ``argv``, if any, and return that job's module."""
    job = early_job(argv)
    if job is not None:
        from patchcloud.stream.engine.forkserver import start_server

        start_server([job], wait=True)  # (0.2 s: dask's configuration, the processes spawned) before the command line's imports
    return job


def early_job(argv: list[str]) -> str | None:
    """The job module whose fork server to start now for this command line (``sys.argv[1:]``), or None.

    The inputs are the arguments that name an existing LAS/LAZ file (the
    first of them without ``--out-dir``: the output may exist too); their
    point counts come from their headers.  None for anything else: another
    command, ``-h``/``--help``, a directory or glob among a catalog's
    inputs, an unreadable header, an option given twice.

    >>> early_job(["info", "x.laz"]), early_job(["normals", "--help"]), early_job([])
    (None, None, None)
    """
    if not argv or argv[0] not in JOB_MODULES:
        return None
    from patchcloud.stream.engine.placement import starts_local_processes

    job, each_file = JOB_MODULES[argv[0]]
    values: dict[str, object] = {}
    words: list[str] = []
    rest = iter(argv[1:])
    for arg in rest:
        if arg in ("-h", "--help"):
            return None
        name, eq, value = arg.partition("=")
        if name not in _READ:
            words.append(arg)  # an argument, or an option (or its value) not read here
            continue
        if name in values or (eq and not _READ[name]):
            return None
        if not _READ[name]:
            values[name] = True
        elif eq:
            values[name] = value
        else:
            values[name] = next(rest, None)
    files = [w for w in words if w.lower().endswith(_SUFFIXES) and os.path.isfile(w)]
    if values.get("--out-dir"):
        if any(not os.path.isfile(w) and not w.startswith("-") and ("*" in w or os.path.isdir(w)) for w in words):
            return None  # a directory or glob of a catalog: the command line expands it
    else:
        files = files[:1]
    counts = [_point_count(f) for f in files]
    if not counts or None in counts:
        return None
    try:
        workers = None if values.get("--workers") is None else int(str(values["--workers"]))
    except ValueError:
        return None
    scheduler = str(values.get("--scheduler") or "auto")
    if values.get("--scheduler-file") or values.get("--in-memory") and values.get("--on-disk"):
        return None
    in_memory = True if values.get("--in-memory") else False if values.get("--on-disk") else None
    points = max(counts) if each_file else sum(counts)
    if starts_local_processes(points, scheduler, workers, values.get("--store"), bool(values.get("--keep-store")) or None,
                              in_memory):
        return job
    return None


def _point_count(path: str) -> int | None:
    """The point count a LAS/LAZ file's header states (:func:`~patchcloud.stream.io.las_records.stated_point_count`),
    None where the first 375 bytes are not such a header."""
    from patchcloud.stream.io.las_records import stated_point_count

    try:
        with open(path, "rb") as f:
            head = f.read(375)
    except OSError:
        return None
    if len(head) < 227 or head[:4] != b"LASF":
        return None
    return stated_point_count(head)


if __name__ == "__main__":  # python -m patchcloud.stream.console: the patchcloud command
    run()
