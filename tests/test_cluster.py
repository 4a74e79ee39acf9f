"""A real dask cluster from the dask command line, one worker killed mid-run: the output is still byte-identical.

The run's working directory is not the workers': its output and store, named relative to it, are found by the
workers (they were taken relative to the workers' own directory: "not a patchcloud store", review J).
"""

import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from patchcloud.stream import normals

pytestmark = pytest.mark.slow

SAMPLE = Path(__file__).resolve().parents[1] / "data" / "test_data_77055_627760_LA93_IGN69.laz"
HERE = Path(__file__).resolve().parent


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for_workers(address: str, n: int, timeout: float = 60.0) -> None:
    from dask.distributed import Client

    with Client(address, timeout="30s") as c:
        c.wait_for_workers(n, timeout=timeout)


@pytest.mark.parametrize("step", ["finish", "export"])
def test_killed_worker_leaves_the_output_byte_identical(tmp_path, step):
    """A worker killed after its second task of ``step``.  Killed during the export, its parts whose results the client
    had already taken (and appended to the LAZ) are computed again, their fragments written again: they were appended
    twice, an unreadable file from a run that said it succeeded (found by a review of 2026-11-28)."""
    dask = Path(sys.executable).with_name("dask")
    if not dask.exists():
        pytest.skip(f"no dask command beside {sys.executable}")
    source, options = SAMPLE, {"tile_size": 32}
    if step == "export":  # enough export parts (one LAZ chunk each) that the client has appended some when one dies
        import city_las

        source = tmp_path / "city.laz"
        city_las.write_city(source, 400_000, seed=3)
        options = {"chunk": 50_000}
    ref = tmp_path / "ref.laz"
    normals(source, ref, scheduler="synchronous", quiet=True, **options)
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = dict(os.environ, PYTHONPATH=str(HERE) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    procs = [subprocess.Popen([str(dask), "scheduler", "--host", "127.0.0.1", "--port", str(port), "--dashboard-address", ":0"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)]
    mark = tmp_path / "killed"
    try:
        for k in range(2):
            wenv = dict(env, PATCHCLOUD_KILL_STEP=step, PATCHCLOUD_KILL_AFTER="2", PATCHCLOUD_KILL_MARK=str(mark)) if k == 0 else env
            procs.append(subprocess.Popen(
                [str(dask), "worker", address, "--nthreads", "1", "--nworkers", "1", "--preload", "cluster_killer",
                 "--preload", "patchcloud.stream.engine.allocator", "--host", "127.0.0.1", "--dashboard-address", ":0", "--name", f"w{k}"],
                env=wenv, cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
            ))
        _wait_for_workers(address, 2)
        client = tmp_path / "client"  # the run's directory, not the workers': its relative paths are made absolute
        client.mkdir()
        out = client / "out.laz"
        run = f"from patchcloud.stream import normals; normals({str(source)!r}, 'out.laz', scheduler={address!r}, quiet=True, **{options!r})"
        p = subprocess.run([sys.executable, "-c", run], capture_output=True, text=True, timeout=600, cwd=client)
        assert p.returncode == 0, p.stderr[-3000:]
        assert mark.exists(), "the worker was not killed: the test did not test anything"
        assert procs[1].poll() is not None  # the killed worker's nanny is gone too
        assert out.read_bytes() == ref.read_bytes()
    finally:
        for p in procs:
            try:
                os.killpg(p.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            p.wait()
