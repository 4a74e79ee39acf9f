"""The background threads a run starts in this process, stopped before it returns: a job leaves nothing running.

A run on a store on disk, or on a dask cluster, starts threads that its
libraries keep for the life of the process, idle, once their work is done:

- zarr's event loop (thread ``zarr_io``) and that loop's default executor
  (``asyncio_0``, ``asyncio_1``, ...: zarr reads and writes local files
  there), and zarr's own pool (``zarr_pool_*``) when its ``threading.max_workers``
  is set;
- dask.distributed's offload thread (``Dask-Offload_0``), on which its
  scheduler builds task graphs and its comms (de)serialise messages.

The dask cluster and client themselves are closed by
:meth:`patchcloud.stream.engine.runner.Runner.close`.  :func:`stops_what_it_starts`
stops those of the threads above that were not running when the run began
(a process that had them before, its own zarr arrays or dask client, say,
keeps them); the libraries start them again when next needed.  numba's
thread pool (a job in memory runs its kernels on it) is started once per
process and cannot be stopped: it is not counted.

>>> import threading, zarr
>>> before = sorted(t.name for t in threading.enumerate())
>>> with stops_what_it_starts():
...     z = zarr.create_array(zarr.storage.MemoryStore(), shape=(4,), dtype="int32")  # zarr's loop runs
...     z[:] = 7
>>> sorted(t.name for t in threading.enumerate()) == before
True
"""

from __future__ import annotations

import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from collections.abc import Iterator

__all__ = ["stops_what_it_starts", "background_threads"]

#: How long (seconds) a stopping thread is waited for: an idle one stops at once.
JOIN_SECONDS = 10.0


def background_threads() -> list[str]:
    """Names of the running threads of this process other than the caller's, sorted.

    >>> isinstance(background_threads(), list)
    True
    """
    me = threading.current_thread()
    return sorted(t.name for t in threading.enumerate() if t is not me)


def _zarr_loop():
    """zarr's event loop and its thread, if zarr has started them in this process; else (None, None)."""
    sync = sys.modules.get("zarr.core.sync")
    if sync is None or not hasattr(sync, "loop") or not hasattr(sync, "iothread"):
        return None, None
    return sync.loop[0], sync.iothread[0]


def _offload_executor():
    """dask.distributed's offload executor, if distributed is imported (None otherwise)."""
    utils = sys.modules.get("distributed.utils")
    executor = getattr(utils, "_offload_executor", None)  # distributed's own name; absent in a version without it
    return executor if isinstance(executor, ThreadPoolExecutor) else None


def _offload_running() -> bool:
    return any(t.name.startswith("Dask-Offload") for t in threading.enumerate())


def _stop_zarr(loop, thread) -> None:
    """Stop zarr's event loop, the executors its threads belong to, and its thread; zarr makes new ones when next used."""
    import asyncio  # zarr, which made the loop, has imported it (a run in memory imports neither)

    sync = sys.modules["zarr.core.sync"]
    if loop.is_running():
        try:  # the loop's default executor: the asyncio_N threads
            asyncio.run_coroutine_threadsafe(loop.shutdown_default_executor(), loop).result(JOIN_SECONDS)
        except Exception:  # a loop that is stopping or busy: stopped below all the same
            pass
        loop.call_soon_threadsafe(loop.stop)
    if thread is not None:
        thread.join(JOIN_SECONDS)
    cleanup = getattr(sync, "cleanup_resources", None)  # zarr's own exit handler: its pool, the loop closed, forgotten
    if cleanup is not None and not (thread is not None and thread.is_alive()):
        cleanup()


def _stop_offload(executor: ThreadPoolExecutor) -> None:
    """Give distributed a fresh offload executor (it starts a thread on first use only) and stop the old one's thread."""
    sys.modules["distributed.utils"]._offload_executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="Dask-Offload")
    executor.shutdown(wait=True)


@contextmanager
def stops_what_it_starts() -> Iterator[None]:
    """Within it, a run; on leaving it (returning or raising), the threads of the module's list that the run started are stopped.

    Not when interrupted (Ctrl-C, ``SystemExit``): the process is ending, and
    zarr's tasks the interrupt cut short are not waited for.
    """
    zarr_before = _zarr_loop()[0] is not None
    offload_before = _offload_running()
    interrupted = False
    try:
        yield
    except (KeyboardInterrupt, SystemExit):
        interrupted = True
        raise
    finally:
        if not interrupted:
            _stop_started(zarr_before, offload_before)


def _stop_started(zarr_before: bool, offload_before: bool) -> None:
    """Stop zarr's loop and dask's offload thread, each unless it was running before the run."""
    loop, thread = _zarr_loop()
    if loop is not None and not zarr_before:
        _stop_zarr(loop, thread)
    executor = _offload_executor()
    if executor is not None and not offload_before and _offload_running():
        _stop_offload(executor)
