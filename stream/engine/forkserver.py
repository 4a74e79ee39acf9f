"""A local cluster's worker processes forked from one server that has imported what they need.

dask's nanny starts each worker process with the ``spawn`` method (a new
interpreter, which imports everything anew) unless its configuration says
otherwise.  :func:`forked_workers` has it use ``forkserver``: the first
worker's start starts one server process, which imports
:mod:`patchcloud.stream.engine.worker_imports` (dask.distributed, numba,
zarr, laspy, patchcloud's jobs) once; each worker is then forked from it,
with those modules already imported.  A worker's start no longer costs an
interpreter's imports, nor do 16 workers' starts compete for the cores.
The processes run the same code on the same data: outputs are unchanged.

Where ``forkserver`` does not exist (Windows), workers are spawned as before.
"""

from __future__ import annotations

import contextlib
import multiprocessing
from collections.abc import Iterator

__all__ = ["forked_workers", "PRELOAD", "METHOD_KEY"]

#: The modules the server imports before it forks any worker.
PRELOAD = ("patchcloud.stream.engine.worker_imports",)
#: dask's configuration key of the method its nanny starts worker processes with.
METHOD_KEY = "distributed.worker.multiprocessing-method"


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
    import distributed.utils

    ctx = multiprocessing.get_context("forkserver")
    if hasattr(distributed.utils, "_forkserver_preload_set"):
        # dask sets its own preload list (imported in this process first, pandas included where installed) the first
        # time it makes its forkserver context, unless told it has: ours imports what a worker needs, dask's among it
        distributed.utils._forkserver_preload_set = True
    else:  # a dask that does it otherwise: its list first, then ours
        with dask.config.set({METHOD_KEY: "forkserver"}):
            distributed.utils.get_mp_context()
    ctx.set_forkserver_preload(list(PRELOAD))
    with dask.config.set({METHOD_KEY: "forkserver"}):
        yield True
