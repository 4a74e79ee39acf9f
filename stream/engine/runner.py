"""Where tasks run: a local dask cluster (threads or processes), an existing cluster, or inline.

:class:`Runner` maps a function over a list of calls and returns the
results in call order, whatever order the tasks finished in; per-tile steps
go through :func:`patchcloud.stream.engine.tasks.map_tiles`, which builds
those calls.
"""

from __future__ import annotations

import os
import resource
from collections.abc import Callable, Sequence
from typing import Any

from patchcloud.core import PatchcloudValueError, single_threaded

from patchcloud.stream.engine.progress import Progress

__all__ = ["Runner", "SCHEDULERS"]

#: Named schedulers; anything else is taken as the address of a dask.distributed scheduler.
SCHEDULERS = ("threads", "processes", "synchronous")


def _call(func: Callable, numba_threads: int, args: tuple, kwargs: dict) -> Any:
    """Run ``func`` with numba limited to ``numba_threads`` threads (the tasks themselves run in parallel).

    With one thread, the kernels run their sequential, GIL-free versions
    (:func:`patchcloud.core.single_threaded`): tasks on threads then compute
    side by side.
    """
    import numba

    if numba_threads <= 1:
        with single_threaded():
            return func(*args, **kwargs)
    numba.set_num_threads(max(1, min(numba_threads, numba.config.NUMBA_NUM_THREADS)))
    return func(*args, **kwargs)


def _peak_rss_bytes() -> int:
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024


class Runner:
    """Runs tasks on a dask scheduler.

    Parameters
    ----------
    scheduler : str
        "threads" (default: an in-process dask.distributed cluster, one
        thread per core), "processes" (a local cluster of one single-threaded
        worker process per core), "synchronous" (inline, for debugging), or
        the address of a running dask.distributed scheduler such as
        ``tcp://host:8786``.
    workers : int, optional
        Threads or processes of a local cluster (default: the cores).
    quiet : bool
        No progress bars.
    """

    def __init__(self, scheduler: str = "threads", workers: int | None = None, quiet: bool = False) -> None:
        self.scheduler = scheduler or "threads"
        self.quiet = quiet
        self.client = None
        self.cluster = None
        cores = os.cpu_count() or 1
        n = int(workers) if workers else cores
        if n < 1:
            raise PatchcloudValueError(f"workers must be at least 1, got {workers!r}")
        self.slots = n
        if self.scheduler == "synchronous":
            self.slots = 1
            return
        from dask.distributed import Client, LocalCluster

        if self.scheduler == "threads":
            self.cluster = LocalCluster(processes=False, n_workers=1, threads_per_worker=n, dashboard_address=":0")
        elif self.scheduler == "processes":
            self.cluster = LocalCluster(processes=True, n_workers=n, threads_per_worker=1, dashboard_address=":0")
        elif "://" in self.scheduler or ":" in self.scheduler:
            try:
                self.client = Client(self.scheduler, timeout="20s")
            except Exception as exc:
                raise PatchcloudValueError(f"cannot reach the dask scheduler at {self.scheduler} ({exc})") from exc
            info = self.client.scheduler_info()
            self.slots = max(1, sum(w.get("nthreads", 1) for w in info.get("workers", {}).values()))
            return
        else:
            raise PatchcloudValueError(
                f"scheduler must be one of {', '.join(SCHEDULERS)} or a dask scheduler address such as tcp://host:8786; got {scheduler!r}"
            )
        self.client = Client(self.cluster)

    @property
    def numba_threads(self) -> int:
        """numba threads per task: tasks run side by side, so one each when there are several slots."""
        cores = os.cpu_count() or 1
        return max(1, cores // self.slots) if self.scheduler in ("threads", "synchronous") else 1

    def map(self, func: Callable, calls: Sequence[tuple[tuple, dict]], label: str) -> list:
        """``[func(*args, **kwargs) for args, kwargs in calls]``, run in parallel, results in call order."""
        bar = Progress(label, len(calls), quiet=self.quiet, unit=" tasks")
        results: list = [None] * len(calls)
        if self.client is None:
            for k, (args, kwargs) in enumerate(calls):
                results[k] = _call(func, self.numba_threads, args, kwargs)
                bar.update()
        else:
            from dask.distributed import as_completed

            futures = [
                self.client.submit(_call, func, self.numba_threads, args, kwargs, pure=False, retries=2)
                for args, kwargs in calls
            ]
            index = {f.key: k for k, f in enumerate(futures)}
            for f in as_completed(futures):
                results[index[f.key]] = f.result()
                bar.update()
        bar.close()
        return results

    def peak_memory(self) -> int:
        """Peak resident memory (bytes) summed over this process and every worker process."""
        total = _peak_rss_bytes()
        if self.client is not None and self.scheduler != "threads":
            try:
                total += sum(self.client.run(_peak_rss_bytes).values())
            except Exception:
                pass
        return total

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()

    def __enter__(self) -> "Runner":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
