"""Imported once by the fork server of a local cluster, so that every worker process forked from it has it already.

A local cluster's worker processes were started with ``spawn``: each a new
interpreter that imported dask.distributed, numpy, numba, zarr, laspy and
patchcloud's task modules itself, 1.5-2 s of CPU each.  On 16 cores the
16 workers did it all at once, and their start took 3.3 s of a 13.5 s run
of a 20M-point LAZ (the tools/results/bench_scale_16core-*.txt runs).
With the ``forkserver`` method (:func:`patchcloud.stream.engine.forkserver.forked_workers`)
one server process imports this module, then forks each worker from
itself: the imports are done once, and each worker starts in a few
milliseconds.

The server does here what the console script and
:mod:`~patchcloud.stream.engine.worker_setup` do before their imports
(numba's BLAS probe, laspy's HTTP support and pyproj, dask's HTML
templates skipped, numba's cache loaded lightly), so the forked workers are the processes they would have been.
Nothing here starts a thread: a process is forked from the server.  The
job's own modules (``patchcloud.stream.jobs.normals``, ...) are named by
the console script, which knows the job
(:func:`patchcloud.stream.engine.forkserver.start_server`); otherwise each
worker imports them at its first task (0.1 s).
"""

from __future__ import annotations

from patchcloud.stream.engine.dask_start import skip_dask_templates
from patchcloud.stream.engine.laspy_start import skip_laspy_http, skip_laspy_pyproj
from patchcloud.stream.engine.numba_start import load_cached_kernels_lightly, skip_numba_blas_probe, skip_numba_yaml

skip_numba_blas_probe()
skip_numba_yaml()
load_cached_kernels_lightly()
skip_laspy_http()
skip_laspy_pyproj()
skip_dask_templates()

import distributed.nanny  # noqa: E402,F401  what a worker process runs
import distributed.worker  # noqa: E402,F401
import lazrs  # noqa: E402,F401
import numba  # noqa: E402,F401

# not zarr (0.2-0.6 s of the server's imports, before any worker can start): a store on a local disk is read and
# written without it (patchcloud.stream.io.local_zarr); the tasks that need it (compress's .pcz, a store on another
# URL) import it, and the job's module named by the console script (compress) brings it here too

import patchcloud.stream.engine.export  # noqa: E402,F401  the engine's tasks (and the kernels they use)
import patchcloud.stream.engine.ingest  # noqa: E402,F401
import patchcloud.stream.engine.job  # noqa: E402,F401
import patchcloud.stream.engine.tasks  # noqa: E402,F401
import patchcloud.stream.engine.worker_setup  # noqa: E402,F401  the workers' preload

__all__: list[str] = []
