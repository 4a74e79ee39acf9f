"""A local cluster's worker processes forked from one server that has imported what they need.

dask's nanny starts each worker process with the ``spawn`` method (a new
interpreter, which imports everything anew) unless its configuration says
otherwise.  :func:`forked_workers` has it use ``forkserver``: the first
worker's start (or the console script, earlier: :func:`start_server`)
starts one server process, which imports
:mod:`patchcloud.stream.engine.worker_imports` (dask.distributed, numba,
zarr, laspy, patchcloud's engine; the job's own module when the console
script names it) once; each worker is then forked from it, with those
modules already imported.  A worker's start no longer costs an
interpreter's imports, nor do 16 workers' starts compete for the cores.
The processes run the same code on the same data: outputs are unchanged.

Where ``forkserver`` does not exist (Windows), workers are spawned as before.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import signal
import threading
from collections.abc import Iterator, Sequence

__all__ = ["forked_workers", "start_server", "PRELOAD", "METHOD_KEY"]

#: The modules the server imports before it forks any worker.
PRELOAD = ("patchcloud.stream.engine.worker_imports",)
#: dask's configuration key of the method its nanny starts worker processes with.
METHOD_KEY = "distributed.worker.multiprocessing-method"
#: Whether :func:`start_server` has set the server's preload list (with the job's modules) in this process.
_early = False


def _preload() -> None:
    """Have the fork server import :data:`PRELOAD` when it starts, and dask leave that list as it is (see below)."""
    import distributed.utils

    if hasattr(distributed.utils, "_forkserver_preload_set"):
        # dask sets its own preload list (imported in this process first, pandas included where installed) the first
        # time it makes its forkserver context, unless told it has: ours imports what a worker needs, dask's among it
        distributed.utils._forkserver_preload_set = True
    else:  # a dask that does it otherwise: its list first, then ours
        import dask

        with dask.config.set({METHOD_KEY: "forkserver"}):
            distributed.utils.get_mp_context()
    if not _early:  # (the list start_server gave, with the job's modules, stays)
        multiprocessing.get_context("forkserver").set_forkserver_preload(list(PRELOAD))


def start_server(modules: Sequence[str] = ()) -> bool:
    """Start the fork server now, in a background thread, so that it imports :data:`PRELOAD` and ``modules`` (the job's,
    e.g. ``"patchcloud.stream.jobs.normals"``) while this process goes on.

    The console script calls it before it imports the job (0.6 s), when
    the run will start local worker processes
    (:func:`~patchcloud.stream.engine.placement.starts_local_processes`);
    :func:`forked_workers` then finds the server started.  The server, like
    the workers, holds Ctrl-C back until each worker's set-up ignores it
    (:mod:`~patchcloud.stream.engine.worker_setup`).  Returns whether it
    starts one (False where ``forkserver`` does not exist).
    """
    global _early
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return False
    _early = True
    threading.Thread(target=_start, args=(tuple(modules),), name="patchcloud-start-forkserver", daemon=True).start()
    return True


def _start(modules: tuple[str, ...]) -> None:
    from multiprocessing import forkserver, resource_tracker

    try:  # (dask is told to keep this preload list by forked_workers, as the cluster starts)
        multiprocessing.get_context("forkserver").set_forkserver_preload([*PRELOAD, *modules])
        resource_tracker.ensure_running()  # first: starting it unblocks SIGINT in the thread that does
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        forkserver.ensure_running()
    except Exception:  # a server that cannot start now is started (or its error met) by the cluster's first worker
        pass


@contextlib.contextmanager
def forked_workers() -> Iterator[bool]:
    """Within the block, the worker processes dask's nanny starts are forked from a server that imported :data:`PRELOAD`.

    Yields whether they are (False where the ``forkserver`` method does not
    exist: spawned, as dask does by default).  A worker restarted after the
    block (one that died) is spawned.
    """
    if "forkserver" not in multiprocessing.get_all_start_methods():
        yield False
        return
    import dask

    _preload()
    with dask.config.set({METHOD_KEY: "forkserver"}):
        yield True
