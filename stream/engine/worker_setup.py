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
"""

from __future__ import annotations

import signal

from patchcloud.stream.engine.allocator import tune_allocator

__all__ = ["dask_setup"]


def dask_setup(worker) -> None:
    """Called by dask in each worker process as it starts, in its main thread: ignore SIGINT, tune the allocator (see the
    module's notes)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    tune_allocator()
