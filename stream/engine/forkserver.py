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
import importlib.util
import multiprocessing
import os
import signal
import sys
import threading
from collections.abc import Iterator, Sequence
from pathlib import Path

__all__ = ["forked_workers", "start_server", "nanny_environ", "hold_ctrl_c", "quiet_resource_tracker", "TRACKER_QUIET", "PRELOAD", "METHOD_KEY"]

#: The modules the server imports before it forks any worker.
PRELOAD = ("patchcloud.stream.engine.worker_imports",)
#: dask's configuration key of the method its nanny starts worker processes with.
METHOD_KEY = "distributed.worker.multiprocessing-method"
#: The job's modules :func:`start_server` was given, imported by the server after :data:`PRELOAD`.
_modules: tuple[str, ...] = ()
#: Whether :func:`start_server` started the server (its thread) in this process.
_started = False


def hold_ctrl_c() -> None:
    """Block SIGINT in this thread, multiprocessing's resource tracker started first (starting it unblocks SIGINT in the
    thread that does): the processes this thread starts, and the threads it starts, inherit the block (a signal mask
    survives fork and exec), so a Ctrl-C meant for the run does not reach a worker still importing."""
    from multiprocessing import resource_tracker

    quiet_resource_tracker()
    resource_tracker.ensure_running()
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})


#: The warning option (``-W``) the resource tracker starts with (:func:`quiet_resource_tracker`).
TRACKER_QUIET = "ignore:resource_tracker:UserWarning"


def quiet_resource_tracker() -> None:
    """Have multiprocessing's resource tracker, started after this, not warn of "leaked semaphore objects".

    A worker process killed (kill -9, the kernel's OOM killer) cannot
    unregister the semaphores it made; the tracker unlinks them when the run
    ends, as it should, but warned of each (two lines of a UserWarning on
    stderr, after a run that dask had recovered and that ended well).  The
    tracker takes this process's ``-W`` options (``sys.warnoptions``).
    """
    if TRACKER_QUIET not in sys.warnoptions:
        sys.warnoptions.append(TRACKER_QUIET)


def _set_server_preload() -> None:
    """The modules the fork server imports when it starts: :data:`PRELOAD`, then those given to :func:`start_server`
    (no effect on a server already running)."""
    multiprocessing.get_context("forkserver").set_forkserver_preload([*PRELOAD, *_modules])


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
    _set_server_preload()


def start_server(modules: Sequence[str] = (), wait: bool = False) -> bool:
    """Start the fork server now, in a background thread, so that it imports :data:`PRELOAD` and ``modules`` (the job's,
    e.g. ``"patchcloud.stream.jobs.normals"``) while this process goes on.

    The console script calls it before its own imports
    (:mod:`patchcloud.stream.console`) or, failing that, before it imports
    the job (0.6 s), when the run will start local worker processes
    (:func:`~patchcloud.stream.engine.placement.starts_local_processes`);
    :func:`forked_workers` then finds the server started.  The server, like
    the workers, holds Ctrl-C back until each worker's set-up ignores it
    (:mod:`~patchcloud.stream.engine.worker_setup`).  Returns whether a
    server is started (False where ``forkserver`` does not exist); a second
    call with the same modules starts nothing more.  ``wait``: return once
    the server process runs (not once it has imported), so that this
    process's own imports do not slow its start (they take turns on the GIL
    with the starting thread's).
    """
    global _modules, _started
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return False
    if _started and _modules == tuple(modules):
        return True
    _modules, _started = tuple(modules), True
    starting = threading.Thread(target=_start, name="patchcloud-start-forkserver", daemon=True)
    starting.start()
    if wait:
        starting.join()
    return True


def _start() -> None:
    from multiprocessing import forkserver

    try:  # (dask is told to keep this preload list by forked_workers, as the cluster starts)
        nanny_environ()
        _set_server_preload()
        hold_ctrl_c()
        forkserver.ensure_running()
    except Exception:  # a server that cannot start now is started (or its error met) by the cluster's first worker
        pass


def nanny_environ() -> dict:
    """Set in this process's environment what dask's nanny sets there before it starts a worker process, and return it.

    That is ``distributed.nanny.pre-spawn-environ`` (one thread for OpenMP,
    MKL and OpenBLAS; malloc's trim threshold), each variable already set
    keeping its value, and ``PYTHONHASHSEED`` 6640 where it is unset or 0,
    so that every worker hashes strings alike (dask's nanny does the same).
    A worker forked from the fork server has the environment the server
    started with, and the server's interpreter read these as it started:
    :func:`start_server`, which starts the server before any nanny, sets
    them first.
    """
    import dask.config

    _distributed_defaults()
    wanted = dask.config.get("distributed.nanny.pre-spawn-environ", default={}) or {}
    env = {str(k): os.environ.get(str(k), str(v)) for k, v in wanted.items() if v is not None}
    if env.get("PYTHONHASHSEED", os.environ.get("PYTHONHASHSEED")) in (None, "0"):
        env["PYTHONHASHSEED"] = "6640"
    os.environ.update(env)
    return env


def _distributed_defaults() -> None:
    """dask's configuration given the defaults of dask.distributed's (its ``distributed.yaml``), as ``import
    distributed`` gives them (``distributed/config.py``), without that import (0.3 s, numpy with it) when it is not
    done yet: :func:`start_server`'s thread would hold this process's imports back."""
    if "distributed" in sys.modules:
        return
    import dask.config
    import yaml

    spec = importlib.util.find_spec("distributed")
    if spec is None or spec.origin is None:
        return
    try:
        defaults = yaml.safe_load(Path(spec.origin).with_name("distributed.yaml").read_text())
    except (OSError, yaml.YAMLError):
        return
    dask.config.update_defaults(defaults)


@contextlib.contextmanager
def forked_workers() -> Iterator[bool]:
    """Within the block, the worker processes dask's nanny starts are forked from a server that imported :data:`PRELOAD`.

    Yields whether they are (False where the ``forkserver`` method does not
    exist: spawned, as dask does by default).  A worker restarted after the
    block (one that died) is spawned.

    A forked worker has the environment the server started with, not this
    process's at the worker's start: what the workers read while they run
    and this process may change between runs (the memory budget,
    :data:`patchcloud.stream.io.budget.ENV`) goes to them through the
    nanny (the runner's ``env``).  A fork server started by other code in
    this process (there is one a process) is used as it is.
    """
    if "forkserver" not in multiprocessing.get_all_start_methods():
        yield False
        return
    import dask

    _preload()
    with dask.config.set({METHOD_KEY: "forkserver"}):
        yield True
