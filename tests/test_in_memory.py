"""Small inputs run in memory (no dask cluster, no store on disk) with the results of a run on a store, byte for byte."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from check_identical import pcz_digests
from test_stream import write_scene

from patchcloud.core import PatchcloudValueError
from patchcloud.stream import RunOptions, compress, don, normals, segment
from patchcloud.stream.engine.job import in_memory_points
from patchcloud.stream.io import memory_group
from patchcloud.stream.jobs import normals_tiles

SAMPLE = Path(__file__).resolve().parents[1] / "data" / "test_data_77055_627760_LA93_IGN69.laz"


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("mem") / "scene.las"
    write_scene(path, n=30_000, seed=5)
    return path


JOBS = {
    "normals": (normals, {}, ".laz"),
    "don": (don, {"mode": "exact", "r_small": 0.3, "r_large": 1.5}, ".las"),
    "segment": (segment, {"r_small": 0.3, "r_large": 1.5, "threshold": 0.1, "tolerance": 0.3}, ".laz"),
    "compress": (compress, {}, ".pcz"),
}


@pytest.mark.parametrize("job", sorted(JOBS))
def test_in_memory_equals_a_run_on_a_store(scene, tmp_path, job):
    func, opts, suffix = JOBS[job]
    mem, disk = tmp_path / f"mem{suffix}", tmp_path / f"disk{suffix}"
    s = func(scene, mem, tile_size=16, quiet=True, in_memory=True, workers=2, **opts)  # several tiles: seams and halos in memory too, tasks on 2 threads
    assert s.scheduler == "in memory"
    assert not list(tmp_path.glob("*.store")) and memory_group.urls() == []
    func(scene, disk, tile_size=16, quiet=True, in_memory=False, scheduler="threads", workers=2, **opts)
    if suffix == ".pcz":
        assert pcz_digests(mem) == pcz_digests(disk)
    else:
        assert mem.read_bytes() == disk.read_bytes()


def test_the_in_memory_limit_is_larger_only_where_worker_processes_cannot_win(monkeypatch):
    from patchcloud.stream.engine import job

    assert in_memory_points(1) == in_memory_points(2) == 10_000_000 and in_memory_points(3) == in_memory_points(64) == 2_000_000
    monkeypatch.setattr(job.os, "cpu_count", lambda: 16)
    assert RunOptions().runs_in_memory(2_000_000) and not RunOptions().runs_in_memory(2_000_001)
    monkeypatch.setattr(job.os, "cpu_count", lambda: 2)
    assert RunOptions().runs_in_memory(4_000_000)


def test_auto_runs_small_inputs_in_memory_unless_a_store_or_scheduler_is_asked():
    limit = in_memory_points()
    assert RunOptions().runs_in_memory(limit) and not RunOptions().runs_in_memory(limit + 1)
    assert not RunOptions(store="s.zarr").runs_in_memory(10)
    assert not RunOptions(keep_store=True).runs_in_memory(10)
    assert not RunOptions(scheduler="processes").runs_in_memory(10)
    assert not RunOptions(workers=2).runs_in_memory(10)  # workers asked for: a local cluster of them
    assert not RunOptions(in_memory=False).runs_in_memory(10)
    assert RunOptions(in_memory=True).runs_in_memory(10**7)  # asked for: beyond the default's size, within the budget


@pytest.mark.parametrize("kwargs, says", [
    (dict(in_memory=True, store="s.zarr"), "keep no store"),
    (dict(in_memory=True, keep_store=True), "keep no store"),
    (dict(in_memory=True, scheduler="threads"), "no scheduler"),
    (dict(in_memory="yes"), "True, False or None"),
])
def test_in_memory_options_that_contradict_are_one_clear_error(kwargs, says):
    with pytest.raises(PatchcloudValueError, match=says):
        RunOptions(**kwargs)


def test_a_failing_in_memory_run_leaves_nothing(scene, tmp_path, monkeypatch):
    def broken(*args, **kwargs):
        raise RuntimeError("broken tile")

    monkeypatch.setattr(normals_tiles, "finish_one_tile", broken)
    with pytest.raises(RuntimeError, match="broken tile"):
        normals(scene, tmp_path / "out.laz", quiet=True)
    assert memory_group.urls() == [] and list(tmp_path.iterdir()) == []


def test_the_cli_on_a_small_file_imports_neither_dask_zarr_nor_matplotlib(tmp_path):
    code = (
        "import sys\n"
        "from patchcloud.stream.cli import main\n"
        f"try:\n    main(['normals', {str(SAMPLE)!r}, {str(tmp_path / 'n.laz')!r}, '-q'])\n"
        "except SystemExit as e:\n    assert not e.code, e.code\n"
        "print(sorted(m for m in ('dask', 'distributed', 'zarr', 'matplotlib') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]" and (tmp_path / "n.laz").stat().st_size > 0
    np.testing.assert_equal(sorted(p.name for p in tmp_path.iterdir()), ["n.laz"])


@pytest.mark.slow  # three jobs in two processes
def test_small_runs_on_cached_kernels_import_no_numba_arraymath(tmp_path):
    """numba.np.arraymath (0.3 s, BLAS probe and all) is imported by numba's compiler, and by a cached kernel whose
    code calls one of its functions (np.searchsorted, np.iinfo, ...) as soon as it loads: the kernels of normals, don
    and segment call none, so once they are cached a small run of the console script (which loads them without
    numba's compiler set-up) does not import it."""
    code = (
        "import sys\n"
        "from patchcloud.stream.engine.numba_start import load_cached_kernels_lightly\n"
        "load_cached_kernels_lightly()\n"
        "from patchcloud.stream.cli import main\n"
        f"for job in ('normals', 'don', 'segment'):\n"
        f"    try:\n        main([job, {str(SAMPLE)!r}, {str(tmp_path)!r} + '/' + job + '.laz', '-q', '--overwrite'])\n"
        "    except SystemExit as e:\n        assert not e.code, e.code\n"
        "print('numba.np.arraymath' in sys.modules)\n"
    )
    runs = [subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600) for _ in range(2)]
    assert all(r.returncode == 0 for r in runs), runs[-1].stderr[-2000:]
    assert runs[1].stdout.split() == ["False"]  # the first run may have compiled kernels (and imported it)


def _meet(barrier, k):
    barrier.wait(timeout=20)  # both tasks must be running at once to get past this
    return k * k


def _fail_first(k):
    if k == 0:
        raise ValueError("task 0 failed")
    return k


def test_an_in_process_pool_runs_a_steps_tasks_side_by_side_with_results_in_call_order():
    import threading

    from patchcloud.core.threads import in_single_threaded
    from patchcloud.stream.engine.runner import Runner

    with Runner("synchronous", workers=2, pool=True, quiet=True) as r:
        assert r.slots == 2 and r.laz_parallel
        barrier = threading.Barrier(2)
        assert r.map(_meet, [((barrier, k), {}) for k in range(4)], "meet") == [0, 1, 4, 9]
        assert r.map(in_single_threaded, [((), {}), ((), {})], "pooled") == [True, True]  # kernels: sequential versions
        assert r.map(in_single_threaded, [((), {})], "alone") == [False]  # one task: every thread in it
        with pytest.raises(ValueError, match="task 0 failed"):
            r.map(_fail_first, [((k,), {}) for k in range(3)], "fails")
    with Runner("synchronous", workers=2, quiet=True) as r:  # without the pool: one task at a time
        assert r.slots == 1
        assert r.map(in_single_threaded, [((), {}), ((), {})], "inline") == [False, False]
    with pytest.raises(PatchcloudValueError, match="synchronous"):
        Runner("threads", workers=2, pool=True)


def test_a_memory_group_built_from_many_threads_at_once_loses_nothing():
    import threading
    from concurrent.futures import ThreadPoolExecutor

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # threads switch often: an unguarded check-then-create loses groups (about 1 in 200 here)
    try:
        for _ in range(3):
            g = memory_group.MemoryGroup()
            start = threading.Barrier(8)

            def write(k):
                start.wait(timeout=20)
                for j in range(300):  # every thread makes the same new groups on the way
                    g.create_array(f"parts/{j:03d}/x/t{k}", shape=(1,), dtype="int64")[...] = k * 1000 + j
                    g.require_group(f"tiles/{j:03d}/y").attrs.update({f"t{k}": j})

            with ThreadPoolExecutor(8) as ex:
                list(ex.map(write, range(8)))
            assert all(int(g[f"parts/{j:03d}/x/t{k}"][0]) == k * 1000 + j for j in range(300) for k in range(8))
            assert all(dict(g[f"tiles/{j:03d}/y"].attrs) == {f"t{k}": j for k in range(8)} for j in range(300))
    finally:
        sys.setswitchinterval(interval)


def test_a_failing_in_memory_run_removes_only_the_outputs_it_wrote(scene, tmp_path, monkeypatch):
    """A run in memory that fails after renaming its output into place removes it (nothing would resume it); a file
    another program put at the output's path during the run is that program's, and stays (it was removed, with the
    message that the run had written it)."""
    from patchcloud.stream.jobs.normals import NormalsJob

    out = tmp_path / "out.laz"

    def fails_after_writing(self, ctx):
        from patchcloud.core import PatchcloudIOError

        raise PatchcloudIOError("summary broken")

    monkeypatch.setattr(NormalsJob, "summarise", fails_after_writing)
    with pytest.raises(Exception, match="summary broken.*1 output\\(s\\) it had written are removed"):
        normals(scene, out, quiet=True)
    assert list(tmp_path.iterdir()) == []
    monkeypatch.undo()

    def someone_else_writes_the_output(*args, **kwargs):
        out.write_bytes(b"another program's file")  # written at the output's path while the run is on
        raise RuntimeError("broken tile")

    monkeypatch.setattr(normals_tiles, "finish_one_tile", someone_else_writes_the_output)
    with pytest.raises(RuntimeError, match="broken tile") as e:
        normals(scene, out, quiet=True)
    assert "removed" not in str(e.value)
    assert out.read_bytes() == b"another program's file" and list(tmp_path.iterdir()) == [out]
