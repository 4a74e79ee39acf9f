"""The ``patchcloud`` command line (click): one module per subcommand, shared options in :mod:`.options`."""

from __future__ import annotations

import gc
import os
import signal
import sys

import click

from patchcloud.stream.engine.dask_start import skip_dask_templates
from patchcloud.stream.engine.laspy_start import skip_laspy_http, skip_laspy_pyproj
from patchcloud.stream.engine.numba_start import load_cached_kernels_lightly, skip_numba_blas_probe, skip_numba_yaml

from .compress import compress_command, decompress_command
from .don import don_command
from .don_scales import don_scales_command
from .info import info_command
from .normals import normals_command
from .options import OneLineErrors
from .render import render_command, render_tiles_command
from .segment import segment_command
from .tile import tile_command

__all__ = ["main", "run", "leave", "install_signal_handlers", "importing", "IMPORT_WAIT"]


@click.group(cls=OneLineErrors, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="patchcloud")
@click.option("--debug", is_flag=True, default=False, help="Show the traceback of an unexpected error (a bug) instead of one line.")
def main(debug: bool) -> None:
    """Normals, curvature, Difference of Normals and segments of LiDAR point clouds of any size.

    \b
    Start with:
      patchcloud normals in.laz out.laz       normals and curvature of a LAS/LAZ file
      patchcloud don in.laz out.laz           Difference of Normals (DoN) of every point
      patchcloud segment in.laz out.laz       DoN segments (street furniture, kerbs, ...)
      patchcloud don-scales labelled.laz      which (rs, rl) separates the classes best
      patchcloud compress in.laz out.pcz      quadric patch models + residual points
      patchcloud decompress in.pcz out.laz    points back, at any density
      patchcloud info in.laz                  what a file (or a store) holds
      patchcloud render in.laz out.png        a picture (render-tiles: a store's tiles)
    """


main.add_command(normals_command)
main.add_command(don_command)
main.add_command(segment_command)
main.add_command(don_scales_command)
main.add_command(compress_command)
main.add_command(decompress_command)
main.add_command(tile_command)
main.add_command(info_command)
main.add_command(render_command)
main.add_command(render_tiles_command)


#: How long a Ctrl-C or SIGTERM that comes during an import waits, each time, for the import to end (seconds).
IMPORT_WAIT = 0.02


def importing(frame) -> bool:
    """Whether a signal handler's ``frame`` is inside an import: a frame of importlib's on its stack.

    >>> import sys
    >>> importing(sys._getframe())
    False
    """
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def _after_the_import(frame, handler) -> bool:
    """Whether the signal is put off until the import under way ends: then ``handler`` runs again (SIGALRM) in
    :data:`IMPORT_WAIT` seconds.  numba's compiled modules print the traceback of a KeyboardInterrupt raised while
    they import and turn it into an ImportError, which the command line then took for a bug (seen once in CI: a
    Ctrl-C as the workers started)."""
    if not importing(frame):
        return False
    signal.signal(signal.SIGALRM, handler)
    signal.setitimer(signal.ITIMER_REAL, IMPORT_WAIT)
    return True


def _terminated(signum, frame) -> None:
    """SIGTERM handler of the console script: the run stops as on Ctrl-C (one line, its store kept and said, its
    locks released, its workers closed, exit status 130), where Python would end at once and leave them."""
    if _after_the_import(frame, _terminated):
        return
    _cleaning_up()
    raise KeyboardInterrupt("terminated")


def _interrupted(signum, frame) -> None:
    """SIGINT handler of the console script: Ctrl-C stops the run as Python's KeyboardInterrupt does, once no import
    is under way."""
    if _after_the_import(frame, _interrupted):
        return
    _cleaning_up()
    raise KeyboardInterrupt


def install_signal_handlers() -> None:
    """The console script's handlers: SIGTERM (what SLURM, PBS, Kubernetes and systemd send) stops the run as Ctrl-C
    does, and Ctrl-C a second time is let be during the clean-up; both wait for an import under way to end."""
    signal.signal(signal.SIGTERM, _terminated)
    if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:  # a run started ignoring it (`cmd &` in a script) still does
        signal.signal(signal.SIGINT, _interrupted)


def _cleaning_up() -> None:
    """After a first Ctrl-C or SIGTERM the run cleans up (its workers closed, its locks released, one line said):
    another Ctrl-C then is let be, where it would cut the clean-up short (Python died of it at exit, status -2, or
    printed 12-27 lines of tracebacks of dask's and numba's threads, a sweep found); SIGTERM (``kill PID``) ends the
    process at once, should the clean-up hang (:func:`_stopped_at_once`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _stopped_at_once)


def _stopped_at_once(signum, frame) -> None:
    """SIGTERM during the clean-up: one line, exit status 130, now.  What the clean-up left (a lock, a store, an
    output's temporary name) the same command's next run takes over or removes; the workers end with this process."""
    try:
        sys.stderr.write("error: terminated during the clean-up: stopped at once (the same command cleans up after it and resumes)\n")
        sys.stderr.flush()
    finally:
        os._exit(130)


def run() -> None:
    """The ``patchcloud`` console script: :func:`main` as a process of its own.

    The process ends with its command, so its objects are of two kinds: the
    modules and compiled kernels, alive until the end, and a job's
    short-lived ones.  The garbage collector would walk the first kind
    again and again during the run (numba's kernels bring over 50,000
    objects) and once more at exit; here it collects the young objects
    less often (every 100,000 allocations, not 700).  Measured on the
    embedded 60,000-point tile, whole process: 0.87x the time (median of
    12 interleaved pairs).  Memory is held by arrays, which reference
    counting frees as before.  The process then ends without the
    interpreter's teardown (:func:`leave`; where a command raises instead,
    a bug's traceback, everything is untracked first, so the exit does not
    walk it).  Only the console script does
    this: in another program (or CliRunner) :func:`main` leaves the
    collector alone and returns.  So too numba's
    BLAS probe, which the console script skips
    (:func:`~patchcloud.stream.engine.numba_start.skip_numba_blas_probe`), numba's compiler set-up when it loads
    cached kernels, laspy's HTTP support and pyproj (:mod:`~patchcloud.stream.engine.laspy_start`) and dask's HTML
    templates (:mod:`~patchcloud.stream.engine.dask_start`).
    """
    gc.set_threshold(100_000, 50, 50)
    skip_numba_blas_probe()  # 0.14 s of scipy that numba would import for nothing (stream.engine.numba_start)
    skip_numba_yaml()  # 0.02 s of PyYAML, for a .numba_config.yaml that is not there (same module)
    load_cached_kernels_lightly()  # 0.07 s of numba's compiler set-up that a cached kernel does not need (same module)
    skip_laspy_http()  # 0.02 s of requests, for COPC over HTTP (stream.engine.laspy_start)
    skip_laspy_pyproj()  # pyproj imported where a CRS is read or written, not by laspy's import (same module)
    skip_dask_templates()  # 0.04 s of jinja2 for dask's HTML (stream.engine.dask_start)
    install_signal_handlers()
    try:
        main()
    except SystemExit as exc:  # click's standalone mode ends every command so, its status given
        leave(exc.code)
    finally:
        gc.freeze()


def leave(code) -> None:
    """End the console script's process now with ``code`` (what ``sys.exit`` takes: None, a status or a message),
    its output streams flushed, without the interpreter's teardown.

    The run has closed what it opened (its cluster, the workers' fork
    server's pipe, its locks, its store, its outputs renamed into place);
    what remains is the teardown of every module and object, numba's and
    LLVM's among them, and the exit hooks of libraries that had nothing
    left to do: 0.1-0.3 s at the end of every command, the worker
    processes' own (:func:`patchcloud.stream.engine.worker_setup.exit_now`).
    A message is written on stderr with status 1, as Python does; an
    output stream that cannot be flushed (a closed pipe: ``patchcloud info
    x.laz | head -1``) gives status 120, as Python does.  Under a profiler
    or a tracer (``python -m cProfile -m patchcloud.stream.console``,
    coverage, a debugger), which write their results at exit, the process
    ends as Python ends it (``sys.exit``).
    """
    if sys.getprofile() is not None or sys.gettrace() is not None:
        sys.exit(code)
    if code is None:
        status = 0
    elif isinstance(code, int):
        status = code
    else:
        try:
            sys.stderr.write(f"{code}\n")
        except Exception:  # no stderr to write to: the status still says it
            pass
        status = 1
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # a closed pipe, a full disk: Python's own exit would say so with 120
            if status == 0:
                status = 120
    os._exit(status)
