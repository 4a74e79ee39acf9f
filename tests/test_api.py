"""The Python API (issue 18, part 5): ``import patchcloud``.

- the package: ``__version__`` from the installation (pyproject's version),
  every name of ``__all__`` the very object of ``patchcloud.core`` or
  ``patchcloud.stream``, and importing it loads neither numba, dask, zarr
  nor matplotlib;
- the array functions take a ``laspy.LasData`` as well as an (N, 3) array,
  and give the same arrays, in the file's point order; on a LasData, the
  DoN is the ``don`` file job's;
- a file job returns with nothing of its own running: no dask client, no
  thread it started, in memory and on a dask cluster, three runs in a row;
- numba's compiling is reported on its own line ("compiling kernels,
  once"), out of the steps' times: in process with a kernel never compiled
  before, and (slow) in a fresh process with an empty numba cache.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
import tomllib
from pathlib import Path

import laspy
import numba
import numpy as np
import pytest

import patchcloud
import patchcloud.core
import patchcloud.stream
from patchcloud.stream.engine.compiling import COMPILING
from patchcloud.stream.jobs import normals_tiles

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "data" / "test_data_77055_627760_LA93_IGN69.laz"


@pytest.fixture(scope="module")
def las():
    return laspy.read(SAMPLE)


# -- the package ------------------------------------------------------------------------------------------------------


def test_version_is_the_projects():
    """One version, written once (core/version.py, which pyproject.toml reads), the installed metadata's."""
    from importlib.metadata import version

    with open(ROOT / "pyproject.toml", "rb") as f:
        project = tomllib.load(f)
    assert "version" in project["project"]["dynamic"]
    assert project["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "patchcloud.core.version.__version__"}
    assert patchcloud.__version__ == version("patchcloud") == patchcloud.core.__version__


def test_import_patchcloud_is_cheap():
    code = (
        "import sys, patchcloud\n"
        "print(patchcloud.__version__)\n"
        "print(sorted(m for m in ('numba', 'dask', 'distributed', 'zarr', 'matplotlib') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split("\n")
    assert out[0] == patchcloud.__version__ and out[1] == "[]", out


def test_the_command_line_s_help_imports_no_heavy_package():
    """``patchcloud --help`` (its import and every subcommand's) loads neither laspy (0.2 s with requests and pyproj)
    nor numba, dask, zarr or matplotlib: a subcommand imports what it needs when it runs."""
    code = (
        "import sys\n"
        "from patchcloud.stream.cli import main\n"
        "try:\n    main(['--help'])\n"
        "except SystemExit as e:\n    assert not e.code, e.code\n"
        "print(sorted(m for m in ('laspy', 'numba', 'dask', 'distributed', 'zarr', 'matplotlib') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "[]", out


def test_checking_a_laz_file_imports_no_numba():
    """The checks every command makes of a LAZ input (its header, its records' sizes, the decoding of its last chunk:
    :func:`open_source`) load laspy and lazrs, not numba (0.16-0.3 s): the console script makes them before it starts
    the worker processes, and ``info`` on a header makes nothing else."""
    code = (
        "import sys\n"
        "from patchcloud.stream.io.las import open_source\n"
        f"src = open_source({str(SAMPLE)!r})\n"
        "print(src.point_count, src.compressed, 'numba' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    with laspy.open(SAMPLE) as f:
        n = f.header.point_count
    assert out == [str(n), "True", "False"], out


def test_info_on_a_las_file_imports_no_job_s_packages():
    """``patchcloud info`` on a LAS/LAZ file reads its header and records: it loads no numba, zarr, dask or matplotlib
    (what a .pcz or a store needs is imported for them only)."""
    code = (
        "import sys\n"
        "from patchcloud.stream.cli import main\n"
        "try:\n"
        f"    main(['info', {str(SAMPLE)!r}])\n"
        "except SystemExit as e:\n    assert not e.code, e.code\n"
        "print(sorted(m for m in ('numba', 'dask', 'distributed', 'zarr', 'matplotlib') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert "60,653" in out and out.strip().splitlines()[-1] == "[]", out


def test_every_name_is_core_s_or_the_stream_s_own():
    names = [n for n in patchcloud.__all__ if n != "__version__"]
    assert len(set(names)) == len(names)
    assert set(patchcloud.__all__) <= set(dir(patchcloud))
    for name in names:
        home = patchcloud.core if name in patchcloud.core.__all__ else patchcloud.stream
        assert name in home.__all__, name
        assert getattr(patchcloud, name) is getattr(home, name), name
    for name in ("estimate_normals", "difference_of_normals", "segment_don", "normals", "don", "segment", "compress",
                 "decompress", "render", "PatchcloudError"):
        assert name in patchcloud.__all__, name
    with pytest.raises(AttributeError, match="has no attribute 'nothing_here'"):
        patchcloud.nothing_here


# -- arrays: an (N, 3) array or a LasData ------------------------------------------------------------------------------


def test_a_lasdata_is_its_float64_coordinates_in_file_order(las):
    res = patchcloud.estimate_normals(las)
    ref = patchcloud.estimate_normals(np.column_stack([las.x, las.y, las.z]))
    np.testing.assert_array_equal(res.normals, ref.normals)
    np.testing.assert_array_equal(res.k1, ref.k1)
    assert res.normals.shape == (len(las.points), 3) and res.parameters.root_corner[0] > 7e5  # the file's coordinates
    r = patchcloud.radius_normals(las, 2.0)
    step = float(min(las.header.scales))  # a LasData's ties are decided on its grid; an array's, given the step
    np.testing.assert_array_equal(r, patchcloud.radius_normals(las.xyz, 2.0, grid_step=step))
    # a shuffled file: the same normals, shuffled alike (input order in, input order out)
    perm = np.random.default_rng(3).permutation(len(las.points))
    shuffled = laspy.LasData(las.header, las.points[perm])
    np.testing.assert_allclose(patchcloud.radius_normals(shuffled, 2.0), r[perm], atol=1e-9, equal_nan=True)


def test_don_of_a_lasdata_is_the_file_job_s(las, tmp_path):
    don = patchcloud.difference_of_normals(las, 1.0, 4.0)
    patchcloud.don(SAMPLE, tmp_path / "don.laz", r_small=1.0, r_large=4.0, quiet=True)
    out = laspy.read(tmp_path / "don.laz")
    written = np.column_stack([out.DoNX, out.DoNY, out.DoNZ]).astype(np.float64)
    undefined = np.isnan(don[:, 0])
    assert undefined.sum() == 91 and np.isnan(don[undefined]).all()  # 89 without the rounding rule: 2 balls collinear within 1 cm
    assert (written[undefined] == 0).all() and (np.asarray(out.DoN)[undefined] == 0).all()  # the file's empty value (README, Outputs)
    np.testing.assert_allclose(don[~undefined], written[~undefined], atol=1e-7)  # float32 in the file
    seg = patchcloud.segment_don(las, don, 0.25, 0.5, min_points=20)
    step = float(min(las.header.scales))  # a LasData's ties are decided on its grid
    np.testing.assert_array_equal(seg, patchcloud.segment_don(las.xyz, don, 0.25, 0.5, min_points=20, grid_step=step))
    assert seg.shape == (len(las.points),) and seg.max() > 10


def test_a_lasdata_without_points_and_a_wrong_argument_are_clear_errors():
    empty = laspy.create(point_format=6, file_version="1.4")
    assert patchcloud.difference_of_normals(empty, 1.0, 2.0).shape == (0, 3)
    with pytest.raises(patchcloud.PatchcloudValueError, match=r"points must have shape \(N, 3\), got \(4,\)"):
        patchcloud.estimate_normals(np.zeros(4))
    with pytest.raises(patchcloud.PatchcloudValueError, match="the cloud has no points"):
        patchcloud.estimate_normals(empty)


# -- file jobs leave nothing running -----------------------------------------------------------------------------------


def _os_threads(settle_to: int | None = None) -> int:
    """Threads of this process as the OS counts them (numba's native pool too).

    A thread just joined may still be ending in the OS: with ``settle_to``,
    wait (at most 5 s) for the count to come down to it.
    """
    def count() -> int:
        return len(os.listdir("/proc/self/task")) if os.path.isdir("/proc/self/task") else threading.active_count()

    for _ in range(50):
        if settle_to is None or count() <= settle_to:
            break
        time.sleep(0.1)
    return count()


def _thread_names(settle_to: list[str]) -> list[str]:
    """This process's Python threads by name, sorted, after waiting (at most 5 s) for them to come back to ``settle_to``:
    a daemon thread told to stop may take a moment to see it (distributed's "Profile" watcher of a closed worker looks
    every 20 ms, longer on a loaded machine)."""
    for _ in range(50):
        names = sorted(t.name for t in threading.enumerate())
        if names == settle_to:
            break
        time.sleep(0.1)
    return names


@pytest.mark.parametrize("how", [dict(in_memory=True), dict(in_memory=False, scheduler="threads", workers=2)],
                         ids=["in-memory", "dask-cluster"])
def test_a_job_run_three_times_leaves_no_thread_and_no_client(how, tmp_path):
    from distributed import default_client

    before = sorted(t.name for t in threading.enumerate())
    counts = []
    for k in range(3):
        s = patchcloud.normals(SAMPLE, tmp_path / f"n{k}.laz", quiet=True, **how)
        assert s.points == 60653 and s.scheduler == ("in memory" if how["in_memory"] else "threads")
        assert _thread_names(settle_to=before) == before, f"run {k + 1} left threads running"
        counts.append((threading.active_count(), _os_threads(settle_to=counts[0][1] if counts else None)))
        with pytest.raises(ValueError, match="No clients found"):
            default_client()
    # numba's pool (in memory) starts once per process, with the first run: no growth after it (the first count
    # may still hold a thread of run 1 that is ending in the OS, so a later count may be lower: that is no leak).
    # Numba's TBB layer (chosen where libtbb is installed) starts its workers on demand, so a later run may start
    # some that the first did not need: never more than the pool holds (seen on a 2-core machine: 6, 7, 7).
    try:
        tbb = numba.threading_layer() == "tbb"
    except ValueError:  # no parallel kernel has run in this process
        tbb = False
    slack = numba.config.NUMBA_NUM_THREADS - 1 if tbb else 0
    assert counts[1][1] <= counts[0][1] + slack and counts[2][1] <= counts[0][1] + slack, counts
    assert counts[1][0] <= counts[0][0] and counts[2][0] <= counts[0][0], counts


def test_the_other_entry_points_leave_no_thread(tmp_path):
    before = sorted(t.name for t in threading.enumerate())
    store = patchcloud.tile(SAMPLE, str(tmp_path / "s.zarr"), tile_size=64, quiet=True, scheduler="threads", workers=2)
    assert len(store.tiles) == 4
    assert _thread_names(settle_to=before) == before
    assert patchcloud.info(str(tmp_path / "s.zarr"))["kind"] == "store"
    assert _thread_names(settle_to=before) == before
    patchcloud.compress(SAMPLE, tmp_path / "c.pcz", max_error=0.05, quiet=True)
    patchcloud.decompress(tmp_path / "c.pcz", tmp_path / "back.laz")
    assert _thread_names(settle_to=before) == before


# -- numba's compiling, on its own line --------------------------------------------------------------------------------


def test_a_kernel_compiled_during_a_job_is_reported_apart(tmp_path, monkeypatch):
    fit = normals_tiles.fit_one_tile
    fresh = numba.njit(lambda x: x + 1.0)  # a new dispatcher: compiled on its first call, in this job

    def fit_after_compiling(*args, **kwargs):
        fresh(1.0)
        return fit(*args, **kwargs)

    monkeypatch.setattr(normals_tiles, "fit_one_tile", fit_after_compiling)
    first = patchcloud.normals(SAMPLE, tmp_path / "a.laz", quiet=True, in_memory=True)
    assert first.compile_seconds > 0
    assert f"  {COMPILING.replace('compiling ', 'compiling       ')}: {first.compile_seconds:.1f} s" in first.format()
    again = patchcloud.normals(SAMPLE, tmp_path / "b.laz", quiet=True, in_memory=True)  # compiled now: nothing to report
    assert again.compile_seconds == 0 and "compiling" not in again.format()


@pytest.mark.slow
def test_an_empty_numba_cache_is_reported_once_then_not(tmp_path):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    cmd = [sys.executable, "-m", "patchcloud.stream.cli", "normals", str(SAMPLE), str(tmp_path / "n.laz"), "--overwrite"]
    cold = subprocess.run(cmd, capture_output=True, text=True, env=env, check=True)
    assert "compiling       kernels, once: " in cold.stdout and f"{COMPILING} (numba" in cold.stderr, cold.stdout + cold.stderr
    assert any((tmp_path / "numba").rglob("*.nbi"))  # the kernels are in the cache now
    warm = subprocess.run(cmd, capture_output=True, text=True, env=env, check=True)
    assert "compiling" not in warm.stdout + warm.stderr, warm.stdout + warm.stderr
    assert "points/s" in warm.stdout
