"""Worker processes reuse large arrays' memory instead of mapping and zeroing it afresh (stream/engine/allocator.py).

The measure is the page faults of making and filling the same 2 MiB array
again and again: with dask's nanny setting (``MALLOC_TRIM_THRESHOLD_=65536``,
which fixes glibc's mmap threshold at 128 KiB) every array is new memory
from the kernel, 512 faults each; with the tuned allocator the heap's
memory is reused and the faults stop.
"""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import textwrap

import pytest

from patchcloud.stream.engine.runner import Runner

glibc = pytest.mark.skipif(  # (importing this module must not tune the allocator: the probe's process imports it)
    not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc",
    reason="the allocator is tuned on glibc only (this C library is not glibc)",
)

ROUNDS = 200
PAGES = (2 * 2**20) // 4096  # a 2 MiB array: below numpy's 4 MiB huge-page advice, above glibc's fixed 128 KiB


def fault_probe(rounds: int = ROUNDS) -> int:
    """Page faults of making, filling and freeing a 2 MiB array ``rounds`` times (after one warm-up round)."""
    import resource

    import numpy as np

    def once():
        a = np.empty(2 * 2**20 // 8)
        a.fill(1.0)
        return float(a[-1])

    once()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(rounds):
        once()
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before


def _faults_in_fresh_process(tune: bool) -> int:
    code = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {os.path.dirname(__file__)!r})
        from test_allocator import fault_probe
        if {tune!r}:
            from patchcloud.stream.engine.allocator import tune_allocator
            assert tune_allocator()
        print(fault_probe())
    """)
    env = dict(os.environ, MALLOC_TRIM_THRESHOLD_="65536")  # what dask's nanny gives its workers
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return int(out.stdout.strip())


@glibc
def test_a_tuned_process_reuses_large_arrays_memory():
    untuned = _faults_in_fresh_process(tune=False)
    tuned = _faults_in_fresh_process(tune=True)
    assert untuned > 0.9 * ROUNDS * PAGES, untuned  # the test can fail: with dask's setting each array faults anew
    assert tuned < 0.02 * ROUNDS * PAGES, tuned


@glibc
@pytest.mark.slow  # starts a local cluster of worker processes (a few seconds)
def test_local_cluster_workers_run_with_the_tuned_allocator():
    with Runner("processes", workers=1, quiet=True) as runner:
        faults = list(runner.client.run(fault_probe).values())
    assert len(faults) == 1 and faults[0] < 0.02 * ROUNDS * PAGES, faults
