"""Where tasks run: a local dask cluster (threads or processes), an existing cluster, or inline.

:class:`Runner` maps a function over a list of calls and returns the
results in call order, whatever order the tasks finished in; per-tile steps
go through :func:`patchcloud.stream.engine.tasks.map_tiles`, which builds
those calls.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import resource
import socket
import threading
import time
import uuid
from collections.abc import Callable, Sequence
from typing import Any

from patchcloud.core import PatchcloudIOError, PatchcloudValueError, single_threaded

from patchcloud.stream.engine.compiling import CompileClock
from patchcloud.stream.engine.forkserver import forked_workers, hold_ctrl_c
from patchcloud.stream.engine.placement import AUTO_PROCESSES_POINTS, resolve_scheduler
from patchcloud.stream.engine.progress import Progress
from patchcloud.stream.engine.scheduler_probe import ADDRESS, probe_scheduler
from patchcloud.stream.io.budget import ENV as BUDGET_ENV

__all__ = ["Runner", "SCHEDULERS", "AUTO_PROCESSES_POINTS", "ADDRESS_SCHEMES", "resolve_scheduler", "check_scheduler", "scheduler_from_file"]

#: Named schedulers; anything else is taken as the address of a dask.distributed scheduler.
SCHEDULERS = ("auto", "threads", "processes", "synchronous")
#: The schemes of the dask.distributed scheduler addresses patchcloud takes (TLS: set dask's ``distributed.comm.tls``
#: configuration, or ``DASK_DISTRIBUTED__COMM__TLS__*`` variables, as for any dask client).
ADDRESS_SCHEMES = ("tcp", "tls", "ucx", "ws", "wss")


def check_scheduler(scheduler) -> str:
    """``scheduler`` when it is one of :data:`SCHEDULERS` or a scheduler address ``SCHEME://HOST[:PORT]`` (a scheme of
    :data:`ADDRESS_SCHEMES`) or ``HOST:PORT``; else one PatchcloudValueError saying what is taken.

    >>> check_scheduler("tls://10.0.0.1:8786"), check_scheduler("node7:8786"), check_scheduler("threads")
    ('tls://10.0.0.1:8786', 'node7:8786', 'threads')
    >>> check_scheduler("htps://node7:8786")
    Traceback (most recent call last):
    ...
    patchcloud.core.errors.PatchcloudValueError: scheduler must be one of auto, threads, processes, synchronous or a dask scheduler address SCHEME://HOST[:PORT] with SCHEME one of tcp, tls, ucx, ws, wss (or HOST:PORT); got 'htps://node7:8786'
    """
    if isinstance(scheduler, str) and scheduler in SCHEDULERS:
        return scheduler
    m = ADDRESS.match(scheduler) if isinstance(scheduler, str) else None
    ok = m is not None and (m["scheme"] in ADDRESS_SCHEMES if m["scheme"] else m["port"] is not None)
    if not ok or (m["port"] is not None and not 0 < int(m["port"]) < 65536):
        raise PatchcloudValueError(
            f"scheduler must be one of {', '.join(SCHEDULERS)} or a dask scheduler address SCHEME://HOST[:PORT] with SCHEME one of "
            f"{', '.join(ADDRESS_SCHEMES)} (or HOST:PORT); got {scheduler!r}"
        )
    return scheduler


def scheduler_from_file(path) -> str:
    """The address in a dask scheduler file (the JSON ``dask scheduler --scheduler-file`` and dask-jobqueue write).

    Raises
    ------
    PatchcloudIOError
        ``path`` cannot be read or holds no address.
    PatchcloudValueError
        The address is not one :func:`check_scheduler` takes.
    """
    try:
        with open(path) as f:
            address = json.load(f)["address"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise PatchcloudIOError(f"{path}: not a dask scheduler file with an address ({type(exc).__name__}: {exc})") from None
    return check_scheduler(address)


def _call(func: Callable, numba_threads: int, args: tuple, kwargs: dict) -> tuple[Any, tuple[float, float, str], list]:
    """Run ``func`` with numba limited to ``numba_threads`` threads (the tasks themselves run in parallel).

    With one thread, the kernels run their sequential, GIL-free versions
    (:func:`patchcloud.core.single_threaded`): tasks on threads then compute
    side by side.  Returns the result, when and where the task ran
    (start and end, seconds since the epoch; host:process:thread), and
    when, within it, numba compiled kernels (:class:`~patchcloud.stream.engine.compiling.CompileClock`).
    """
    import numba

    t0 = time.time()
    with CompileClock(this_thread=True) as clock:
        if numba_threads <= 1:
            with single_threaded():
                out = func(*args, **kwargs)
        else:
            numba.set_num_threads(max(1, min(numba_threads, numba.config.NUMBA_NUM_THREADS)))
            out = func(*args, **kwargs)
    return out, (t0, time.time(), f"{socket.gethostname()}:{os.getpid()}:{threading.get_ident()}"), clock.intervals


#: Tasks a worker gets, at least, from a step of small calls run in batches (:meth:`Runner.map` with ``small``).
SMALL_TASKS_PER_WORKER = 4


def _run_calls(func: Callable, calls: list[tuple[tuple, dict]]) -> list:
    """``[func(*args, **kwargs) for args, kwargs in calls]``: one task of a batched map."""
    return [func(*args, **kwargs) for args, kwargs in calls]


def _cpu_usage() -> dict:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return dict(user=r.ru_utime, sys=r.ru_stime, faults=r.ru_minflt)


def _peak_rss_bytes() -> int:
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024


class Runner:
    """Runs tasks on a dask scheduler.

    Parameters
    ----------
    scheduler : str
        "auto" (default: "processes" for files of
        :data:`AUTO_PROCESSES_POINTS` points or more, else "threads"),
        "threads" (an in-process dask.distributed cluster, one thread per
        worker), "processes" (a local cluster of single-threaded worker
        processes), "synchronous" (inline: one task at a time, the kernels on ``workers`` threads, default
        every core, for debugging; with ``pool``, what runs in memory), or the address of a running dask.distributed scheduler
        such as ``tcp://host:8786``.
    workers : int, optional
        Threads or processes of a local cluster (default: the cores).
    quiet : bool
        No progress bars.
    points : int, optional
        Points of the file to process (what "auto" decides on).
    pool : bool
        With the synchronous scheduler: run a step's tasks side by side on
        ``workers`` threads of this process, each with the kernels'
        sequential, GIL-free versions (what an in-memory run does), when the
        step has at least as many tasks as threads; fewer run one at a time
        with every thread in each.  The results are
        the same either way.
    """

    def __init__(self, scheduler: str = "auto", workers: int | None = None, quiet: bool = False, points: int | None = None,
                 pool: bool = False) -> None:
        self.scheduler = resolve_scheduler(check_scheduler(scheduler or "auto"), points)
        if pool and self.scheduler != "synchronous":
            raise PatchcloudValueError(f"pool runs tasks in this process: it goes with the synchronous scheduler, not {self.scheduler!r}")
        #: Whether the synchronous scheduler runs a step's tasks on a pool of ``workers`` threads (see ``pool`` above).
        self.pool = bool(pool)
        #: Every task run: (label, start, end, host:process:thread), times in seconds since the epoch.
        self.tasks: list[tuple[str, float, float, str]] = []
        #: When the tasks' numba compiled kernels, wherever they ran: (start, end), seconds since the epoch.
        self.compile_intervals: list[tuple[float, float]] = []
        self.quiet = quiet
        self._client = None
        self.cluster = None
        self._starting: threading.Thread | None = None
        self._start_error: BaseException | None = None
        #: When the workers were ready to take tasks (seconds since the epoch).
        self.ready_at = time.time()
        cores = os.cpu_count() or 1
        n = int(workers) if workers else cores
        if n < 1:
            raise PatchcloudValueError(f"workers must be at least 1, got {workers!r}")
        self.slots = n
        self._threads = n
        if self.scheduler == "synchronous":
            self.slots = n if self.pool else 1
            return
        if self.scheduler not in SCHEDULERS:  # an address (check_scheduler took it)
            from dask.distributed import Client

            probe_scheduler(self.scheduler)  # dask's client would wait for ever on a server that is not a scheduler
            try:
                self._client = Client(self.scheduler, timeout="20s")
            except Exception as exc:
                raise PatchcloudValueError(f"cannot reach the dask scheduler at {self.scheduler} ({exc})") from exc
            info = self._client.scheduler_info()
            self.slots = max(1, sum(w.get("nthreads", 1) for w in info.get("workers", {}).values()))
            from patchcloud.stream.engine.worker_setup import tune_running_worker

            try:  # zarr's threads, one per task thread (stream.io.store.limit_zarr_threads): what a local worker's set-up does
                self._client.run(tune_running_worker)
            except Exception:  # a worker that cannot (an older patchcloud, ...) keeps zarr's default
                pass
            self.ready_at = time.time()
            return
        # the local cluster starts in the background while the caller gets on (opening the input, making the store).
        # A terminal's Ctrl-C reaches every process of its foreground group, a worker too, and one that is still
        # starting (before its set-up, stream.engine.worker_setup, ignores it) would print a KeyboardInterrupt
        # traceback of its imports. So the starting thread blocks SIGINT: the threads dask starts from it (its event
        # loop's, which start the workers) inherit the block, and so do the worker processes (a signal mask survives
        # fork and exec), while this process's main thread still takes Ctrl-C and closes the cluster.
        self._starting = threading.Thread(target=self._start_local, args=(n,), name="patchcloud-start-cluster", daemon=True)
        self._starting.start()

    def _start_local(self, n: int) -> None:
        try:
            processes = self.scheduler == "processes"
            if processes:  # the worker processes start with Ctrl-C held back (see above)
                hold_ctrl_c()
            from dask.distributed import Client, LocalCluster

            with forked_workers() if processes else contextlib.nullcontext():  # the worker processes forked, not spawned
                self.cluster = LocalCluster(  # workers log nothing but critical: a task's error reaches the user as one line
                    processes=processes, n_workers=n if processes else 1, threads_per_worker=1 if processes else n,
                    dashboard_address=":0", silence_logs=logging.CRITICAL,
                    # a forked worker has the fork server's environment: the budget as it is now ("": none given)
                    **({"preload": ["patchcloud.stream.engine.worker_setup"], "env": {BUDGET_ENV: os.environ.get(BUDGET_ENV, "")}}
                       if processes else {}),
                )
            self._client = Client(self.cluster)
            self.ready_at = time.time()
        except BaseException as exc:  # handed to the first caller of .client
            self._start_error = exc

    @property
    def client(self):
        """The dask client (None for the synchronous scheduler); waits for the local cluster to be up."""
        if self._starting is not None:
            self._starting.join()
            self._starting = None
            if self._start_error is not None:
                raise PatchcloudValueError(f"cannot start a local dask cluster ({self._start_error})") from self._start_error
        return self._client

    @property
    def numba_threads(self) -> int:
        """Threads per task: ``workers`` (default: all the cores) for the synchronous scheduler, else one (each worker is a core).

        With one, tasks run the kernels' sequential, GIL-free versions and
        lazrs' sequential codec, so ``workers`` N uses N cores, no more.
        """
        return self._threads if self.scheduler == "synchronous" else 1

    @property
    def laz_parallel(self) -> bool:
        """Whether tasks decode and encode LAZ with lazrs' threads: when they run in this process (synchronous).

        lazrs holds the GIL for a whole call, so tasks on threads of one
        process code LAZ one at a time however many run: each call then
        had better use every core.  Worker processes use the sequential
        codec, so that N workers use N cores, no more.
        """
        return self.scheduler == "synchronous" and self._threads > 1

    def _pooled(self, tasks: int) -> bool:
        """Whether a step of ``tasks`` tasks runs them on the pool (one thread each), not one at a time on every thread."""
        return self.pool and self._threads > 1 and tasks >= self._threads

    def map(self, func: Callable, calls: Sequence[tuple[tuple, dict]], label: str,
            on_result: Callable[[int, Any], None] | None = None, small: bool = False) -> list:
        """``[func(*args, **kwargs) for args, kwargs in calls]``, run in parallel, results in call order.

        ``on_result(k, result)``, when given, runs in this process as each
        call ``k`` completes (in the order they complete), e.g. to finish an
        output as soon as its last part is written.

        ``small``: the calls take milliseconds each (the seam pass's), so on a
        dask cluster, where each task costs the scheduler and the worker about
        as much, the calls are dealt to :data:`SMALL_TASKS_PER_WORKER` tasks a
        worker (the same results).
        """
        if small and self.client is not None and len(calls) > SMALL_TASKS_PER_WORKER * self.slots:
            return self._map_batched(func, calls, label, on_result)
        bar = Progress(label, len(calls), quiet=self.quiet, unit=" tasks")
        results: list = [None] * len(calls)

        def took(k: int, out: tuple) -> None:  # call k's output from _call: its result, when it ran, when numba compiled
            results[k], when, compiling = out
            self.tasks.append((label, *when))
            self.compile_intervals += compiling
            bar.update()
            if on_result is not None:
                on_result(k, results[k])

        if self.client is None and self._pooled(len(calls)):
            from concurrent.futures import ThreadPoolExecutor

            pool = ThreadPoolExecutor(self._threads, thread_name_prefix="patchcloud-task")
            try:  # every task starts in call order; each result is taken in that order too
                futures = [pool.submit(_call, func, 1, args, kwargs) for args, kwargs in calls]
                for k, f in enumerate(futures):
                    took(k, f.result())
            finally:  # a failed task: the others not yet started are not started, those running finish
                pool.shutdown(wait=True, cancel_futures=True)
        elif self.client is None:
            for k, (args, kwargs) in enumerate(calls):
                took(k, _call(func, self.numba_threads, args, kwargs))
        else:
            from dask.distributed import as_completed

            step = "".join(c if c.isalnum() else "_" for c in label)
            run = uuid.uuid4().hex[:12]
            futures = [  # keys name the step and the call: patchcloud-<step>-<call>-<run>
                self.client.submit(_call, func, self.numba_threads, args, kwargs, key=f"patchcloud-{step}-{k}-{run}", retries=2)
                for k, (args, kwargs) in enumerate(calls)
            ]
            index = {f.key: k for k, f in enumerate(futures)}
            # each result is fetched by the client's event loop as its task ends (not one round trip at a time here);
            # a failed task raises its error, with its traceback, when its turn comes
            for f, out in as_completed(futures, with_results=True):
                took(index[f.key], out)
        bar.close()
        return results

    def _map_batched(self, func: Callable, calls: Sequence[tuple[tuple, dict]], label: str,
                     on_result: Callable[[int, Any], None] | None) -> list:
        """:meth:`map` of the ``calls`` dealt to :data:`SMALL_TASKS_PER_WORKER` tasks a worker in turn (task ``b``: calls
        ``b``, ``b + n``, ``b + 2 n``, ...: calls sorted largest first make even tasks); the results in call order."""
        n = SMALL_TASKS_PER_WORKER * self.slots
        batches = [((func, list(calls[b::n])), {}) for b in range(n)]
        results: list = [None] * len(calls)

        def took(b: int, outs: list) -> None:
            for j, out in enumerate(outs):
                results[b + j * n] = out
                if on_result is not None:
                    on_result(b + j * n, out)

        self.map(_run_calls, batches, label, on_result=took)
        return results

    def cpu_usage(self) -> dict:
        """CPU seconds in user and system mode and minor page faults (``user``, ``sys``, ``faults``) of this process and
        every local worker process so far (a remote cluster's workers too, when they answer)."""
        usages = [_cpu_usage(), *self._on_worker_processes(_cpu_usage)]
        return {k: sum(u[k] for u in usages) for k in usages[0]}

    def peak_memory(self) -> int:
        """Peak resident memory (bytes) summed over this process and every worker process."""
        return _peak_rss_bytes() + sum(self._on_worker_processes(_peak_rss_bytes))

    def _on_worker_processes(self, func: Callable) -> list:
        """``func()`` run on every worker process of the cluster (none with threads or none at all; none where the
        workers do not answer)."""
        if self.client is None or self.scheduler == "threads":
            return []
        try:
            return list(self.client.run(func).values())
        except Exception:
            return []

    def close(self) -> None:
        if self._starting is not None:
            self._starting.join()
            self._starting = None
        # the local scheduler runs in this process and logs, at CRITICAL, each message it can no longer send to a
        # client closed while tasks were finishing (Ctrl-C, SIGTERM, a failed task): the run's one line says it all
        quiet = logging.getLogger("distributed")
        level = quiet.level
        quiet.setLevel(logging.CRITICAL + 1)
        try:
            if self._client is not None:
                self._client.close()
            if self.cluster is not None:
                self.cluster.close()
        finally:
            quiet.setLevel(level)

    def __enter__(self) -> "Runner":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
