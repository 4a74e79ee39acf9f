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
