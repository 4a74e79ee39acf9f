"""Local worker processes forked from one fork server (stream/engine/forkserver.py), started early by the console script
when the run will start them (stream/cli/options.py: start_workers_early; stream/engine/placement.py)."""

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from patchcloud.stream.cli import options
from patchcloud.stream.engine import forkserver
from patchcloud.stream.engine.placement import starts_local_processes

JOB = "patchcloud.stream.jobs.normals"
SAMPLE = str(Path(__file__).resolve().parents[1] / "data" / "test_data_77055_627760_LA93_IGN69.laz")


def test_workers_are_forked_from_one_server_that_imported_what_they_need():
    code = textwrap.dedent("""
        import os, sys
        from patchcloud.stream.engine.runner import Runner
        if __name__ == "__main__":
            with Runner("processes", 2, quiet=True) as r:
                ppid = r.client.run(os.getppid)
                had = r.client.run(lambda: sorted(m for m in ("numba", "zarr", "laspy", "patchcloud.stream.engine.ingest") if m in sys.modules))
                print(len(ppid), len(set(ppid.values())), os.getpid() in ppid.values(), sorted(set(map(tuple, had.values()))))
    """)
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    # two workers, one parent (the server), not this process; each has the modules the server imported, and not zarr,
    # which a local store does without (stream/io/local_zarr.py)
    assert run.stdout.strip() == "2 1 False [('laspy', 'numba', 'patchcloud.stream.engine.ingest')]", run.stdout


@pytest.mark.parametrize("early", [False, True])
def test_forked_workers_have_the_environment_dask_gives_its_workers(early):
    """One thread for OpenMP/MKL/OpenBLAS and one string hash for every worker, whether the server was started early (by the
    console script, before any nanny set them) or by the cluster's first worker."""
    code = textwrap.dedent(f"""
        import os
        from patchcloud.stream.engine import forkserver
        from patchcloud.stream.engine.runner import Runner
        if __name__ == "__main__":
            for k in ("PYTHONHASHSEED", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
                os.environ.pop(k, None)
            if {early}:
                forkserver.start_server(["patchcloud.stream.jobs.normals"])
            with Runner("processes", 2, quiet=True) as r:
                got = r.client.run(lambda: (os.environ.get("OPENBLAS_NUM_THREADS"), os.environ.get("OMP_NUM_THREADS"), hash("patchcloud")))
                print(sorted(set(got.values())))
    """)
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    seeded = subprocess.run([sys.executable, "-c", "print(hash('patchcloud'))"], capture_output=True, text=True,
                            env={**__import__("os").environ, "PYTHONHASHSEED": "6640"}).stdout.strip()
    assert run.stdout.strip() == f"[('1', '1', {seeded})]", run.stdout


def test_placement_starts_processes_exactly_when_the_runner_would():
    assert starts_local_processes(None, "processes")
    assert starts_local_processes(50_000_000, "auto") and starts_local_processes(3_000_000, "auto", workers=4)
    assert not starts_local_processes(1_000_000, "auto", workers=4)  # threads below 2 million points
    assert not starts_local_processes(60_000, "auto")  # in memory
    assert not starts_local_processes(50_000_000, "threads") and not starts_local_processes(50_000_000, "synchronous")
    assert not starts_local_processes(50_000_000, "tcp://127.0.0.1:8786")
    assert not starts_local_processes(50_000_000, "auto", in_memory=True)


@pytest.fixture
def started(monkeypatch):
    calls = []
    monkeypatch.setattr(forkserver, "start_server", lambda modules: calls.append(list(modules)) or True)
    return calls


def test_the_console_script_starts_the_server_only_for_runs_on_local_processes(started, tmp_path):
    out = str(tmp_path / "o.las")
    options.start_workers_early((SAMPLE, out), {"scheduler": "auto"}, JOB)  # 60,000 points: in memory
    options.start_workers_early((SAMPLE, out), {"scheduler": "threads", "workers": 2}, JOB)
    options.start_workers_early((SAMPLE, out), {"scheduler": "tcp://127.0.0.1:8786"}, JOB)
    options.start_workers_early((str(tmp_path / "absent.las"), out), {"scheduler": "auto", "workers": 2}, JOB)  # the job says it
    assert started == []
    options.start_workers_early((SAMPLE, out), {"scheduler": "processes"}, JOB)
    options.start_workers_early((SAMPLE, out), {"scheduler": "auto", "in_memory": False}, JOB)  # threads below 2M points
    assert started == [[JOB]]


def test_a_catalog_compressed_file_by_file_is_judged_by_its_largest_file(started, tmp_path, monkeypatch):
    """compress runs each file of a catalog on its own: 60,000-point files in memory, however many there are."""
    import shutil

    from patchcloud.stream.engine import placement

    for k in range(3):
        shutil.copy(SAMPLE, tmp_path / f"t{k}.laz")
    monkeypatch.setattr(placement, "in_memory_points", lambda cores=None: 100_000)  # the three together: 181,959 points
    run = {"scheduler": "auto", "out_dir": str(tmp_path / "out")}
    monkeypatch.setattr(placement, "AUTO_PROCESSES_POINTS", 150_000)
    options.start_workers_early((str(tmp_path),), run, JOB, each_file=True)  # each file in memory
    assert started == []
    options.start_workers_early((str(tmp_path),), run, JOB)  # as one cloud: on worker processes
    assert started == [[JOB]]


def test_workers_of_each_run_have_the_memory_budget_of_that_run():
    """The fork server lives as long as the process and its workers have its environment: the budget, which a Python
    caller may change between runs, goes to them through the nanny."""
    code = textwrap.dedent("""
        from patchcloud.stream.engine.runner import Runner
        from patchcloud.stream.io.budget import max_memory, set_max_memory
        if __name__ == "__main__":
            seen = []
            for size in ("1GiB", "3GiB", None):
                set_max_memory(size)
                with Runner("processes", 2, quiet=True) as r:
                    seen.append(sorted(set(r.client.run(max_memory).values())) == [max_memory()])
            print(seen, max_memory() != 3 << 30)
    """)
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.strip() == "[True, True, True] True", run.stdout


def test_the_resource_tracker_cleans_up_a_killed_workers_semaphores_without_a_warning():
    """A worker killed (kill -9) leaves its semaphores to the tracker, which warned of them after a run that dask had
    recovered: two lines of UserWarning on stderr.  Control: without quiet_resource_tracker it still warns."""
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent("""
        import sys
        import multiprocessing, os
        from multiprocessing import resource_tracker
        from patchcloud.stream.engine.forkserver import quiet_resource_tracker
        if sys.argv[1] == "quiet":
            quiet_resource_tracker()
        resource_tracker.ensure_running()
        lock = multiprocessing.get_context("forkserver").Lock()  # a named semaphore, registered with the tracker
        os._exit(0)  # as a killed process: never unregistered
    """)
    said = {}
    for mode in ("quiet", "loud"):
        run = subprocess.run([sys.executable, "-c", code, mode], capture_output=True, text=True, timeout=60)
        assert run.returncode == 0, run.stderr
        said[mode] = run.stderr
    assert "leaked semaphore" in said["loud"]  # the control: what a run printed
    assert said["quiet"] == ""
