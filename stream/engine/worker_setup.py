"""Preloaded by the worker processes of a local cluster (``LocalCluster(preload=[__name__])``): what each needs set first.

A terminal's Ctrl-C reaches every process of the foreground group, the
workers too.  Each worker ignores it: the run's own process is
interrupted, says so in one line and closes the cluster, which stops the
workers, instead of every worker printing a ``KeyboardInterrupt``
traceback.

Each worker also sets its C allocator to reuse large arrays
(:func:`~patchcloud.stream.engine.allocator.tune_allocator`: dask's nanny
starts workers with a setting that maps and zeroes every array over
128 KiB afresh).

And each worker, once closed, leaves without tearing its interpreter
down (:func:`exit_now`): finalising numba's and LLVM's objects module by
module took 0.3-0.5 s at the end of every run, during which the command
waits for its workers (10M city, 2 workers: closing the cluster 0.54 s,
then 0.04 s).
"""

from __future__ import annotations

import atexit
import os
import signal
import sys

from patchcloud.stream.engine.allocator import tune_allocator
from patchcloud.stream.engine.import_hooks import after_importing
from patchcloud.stream.engine.laspy_start import skip_laspy_http, skip_laspy_pyproj
from patchcloud.stream.engine.numba_start import load_cached_kernels_lightly, skip_numba_blas_probe, skip_numba_yaml

__all__ = ["dask_setup", "exit_now", "worker_threads", "tune_running_worker"]


def exit_now() -> None:
    """Flush stdout and stderr, then end the process at once (``os._exit``): registered to run first at exit, when
    dask has closed the worker (its files, directory and connections already closed), it skips the rest of the
    interpreter's teardown.

    The status is 1 after an uncaught exception (its traceback already
    printed), else 0: the status ``sys.exit`` asked for is not known at
    exit, and dask's nanny only logs it.
    """
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # a closed stream: nothing to flush
            pass
    os._exit(1 if getattr(sys, "last_value", None) is not None else 0)


def dask_setup(worker) -> None:
    """Called by dask in each worker process as it starts, in its main thread: ignore SIGINT, tune the allocator, skip
    numba's BLAS probe and its compiler set-up for cached kernels, size lazrs' thread pool (:mod:`~patchcloud.stream.engine.numba_start`) and
    laspy's HTTP support and pyproj (:mod:`~patchcloud.stream.engine.laspy_start`), have zarr code chunks on as many threads as the
    worker runs tasks (:func:`~patchcloud.stream.io.store.limit_zarr_threads`), leave at once at exit (see the module's
    notes)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # lazrs decodes the chunks of a variable-chunk LAZ file (COPC) on rayon's pool, one thread per core unless told:
    # as many as the worker runs tasks (before any lazrs call: the pool is made at the first)
    os.environ.setdefault("RAYON_NUM_THREADS", str(worker_threads(worker)))
    tune_allocator()
    skip_numba_blas_probe()
    skip_numba_yaml()
    load_cached_kernels_lightly()
    skip_laspy_http()
    skip_laspy_pyproj()
    from patchcloud.stream.io.store import limit_zarr_threads  # after the skips: it imports laspy and numba

    n = worker_threads(worker)
    # once zarr is imported (at once if it is): a worker on a local store may never import it (stream.io.local_zarr)
    after_importing("zarr", lambda _zarr: limit_zarr_threads(n))
    atexit.register(exit_now)


def tune_running_worker(dask_worker=None) -> None:
    """What :func:`dask_setup` sets that a worker already running needs too (a worker of another cluster, reached by
    its scheduler's address, which preloads nothing of patchcloud's): zarr's threads, set by ``Client.run`` as the run
    connects.  A worker that has coded chunks before keeps the pool it made then."""
    from patchcloud.stream.io.store import limit_zarr_threads

    limit_zarr_threads(worker_threads(dask_worker))


def worker_threads(worker) -> int:
    """How many tasks a dask worker runs at once (1 without a worker: a test's, or one too old to say)."""
    state = getattr(worker, "state", None)
    n = getattr(state, "nthreads", None) or getattr(worker, "nthreads", None)
    return int(n) if n else 1
