"""What each local worker process sets as it starts (stream/engine/worker_setup.py)."""

import subprocess
import sys
import textwrap


def test_a_worker_leaves_at_exit_without_the_interpreters_teardown_and_flushes_its_output():
    code = textwrap.dedent("""
        import atexit, sys
        atexit.register(lambda: print("teardown ran"))  # registered before the worker's set-up: skipped
        from patchcloud.stream.engine.worker_setup import dask_setup
        dask_setup(None)
        sys.stdout.write("buffered, no newline")  # still in the buffer at exit: exit_now flushes it
    """)
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout == "buffered, no newline"


def test_a_worker_that_dies_of_an_exception_still_leaves_with_status_1():
    code = "from patchcloud.stream.engine.worker_setup import dask_setup\ndask_setup(None)\nraise RuntimeError('boom')\n"
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 1 and "RuntimeError: boom" in run.stderr


def test_a_worker_codes_zarr_chunks_on_as_many_threads_as_it_runs_tasks():
    """zarr's own pool (os.cpu_count() + 4 threads a process) contended with the tasks of every worker process."""
    code = textwrap.dedent("""
        import zarr
        from patchcloud.stream.engine.worker_setup import dask_setup, tune_running_worker
        class Worker:
            class state:
                nthreads = 3
        dask_setup(None)
        one = (zarr.config.get("threading.max_workers"), zarr.config.get("async.concurrency"))
        tune_running_worker(Worker())
        three = (zarr.config.get("threading.max_workers"), zarr.config.get("async.concurrency"))
        import numpy as np, tempfile
        z = zarr.create_array(tempfile.mkdtemp() + "/a.zarr", shape=(10,), chunks=(5,), dtype="i4")
        z[:] = np.arange(10)
        from zarr.core import sync
        print(one, three, sync._executor._max_workers)
    """)
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "(1, 1) (3, 3) 3"


def test_the_workers_of_a_local_cluster_code_zarr_chunks_on_one_thread():
    from patchcloud.stream.engine.runner import Runner

    with Runner("processes", 2) as runner:
        runner.client.wait_for_workers(2, timeout=120)  # both registered (on a loaded machine the second may lag)
        got = runner.client.run(lambda: __import__("zarr").config.get("threading.max_workers"))
    assert sorted(got.values()) == [1, 1]
