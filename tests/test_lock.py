"""Two runs never write the same output or store at once: a lock held by a live run stops the second with one line;
a stale lock (dead pid, or no heartbeat from another host) is taken over with a note."""

import json
import os
import socket
import subprocess
import sys
import time

import laspy
import numpy as np
import pytest
from click.testing import CliRunner
from test_stream import write_scene

from patchcloud.core import PatchcloudValueError
from patchcloud.stream import normals
from patchcloud.stream.cli import main
from patchcloud.stream.io.lock import STALE, PatchcloudLockedError, RunLock, lock_path, process_start
from patchcloud.stream.jobs import normals_tiles


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("lock") / "scene.las"
    write_scene(path, n=20_000, seed=7)
    return path


def _hold(path, pid, host, age=0.0):
    lock = lock_path(path)
    lock.write_text(json.dumps(dict(pid=pid, host=host, started=time.time() - age, token="someone")))
    if age:
        os.utime(lock, (time.time() - age, time.time() - age))
    return lock


def _dead_pid():
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_a_live_runs_lock_stops_a_second_run_with_one_line_and_nothing_written(scene, tmp_path):
    out = tmp_path / "out.las"
    lock = _hold(out, os.getpid(), socket.gethostname())
    r = CliRunner().invoke(main, ["normals", str(scene), str(out), "--quiet"])
    assert r.exit_code == 2 and r.output.count("\n") == 1, r.output
    assert f"{out}: another patchcloud run (pid {os.getpid()} on {socket.gethostname()}, since " in r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.las.lock"] and lock.read_text().count("someone") == 1


def test_a_given_store_is_locked_too(scene, tmp_path):
    store = tmp_path / "s.zarr"
    _hold(store, os.getpid(), socket.gethostname())
    with pytest.raises(PatchcloudLockedError, match=r"s.zarr: another patchcloud run"):
        normals(scene, tmp_path / "out.las", store=str(store), scheduler="synchronous", quiet=True)
    assert not (tmp_path / "out.las").exists() and not store.exists()


def test_the_default_store_is_locked_too(scene, tmp_path):
    """A run on disk keeps its store beside its output: another run given that store (``--store``) used to write into it
    at the same time, and the first ended in ``KeyError: 'fit'`` (bug hunt E)."""
    store = tmp_path / "out.las.store"
    _hold(store, os.getpid(), socket.gethostname())
    with pytest.raises(PatchcloudLockedError, match=r"out.las.store: another patchcloud run"):
        normals(scene, tmp_path / "out.las", in_memory=False, scheduler="synchronous", quiet=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.las.store.lock"]
    os.unlink(lock_path(store))
    normals(scene, tmp_path / "out.las", in_memory=True, scheduler="synchronous", quiet=True)  # in memory: no store
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.las"]


def _zombie():
    """A child that has ended and that its parent (this test) has not reaped: what a run killed by ``timeout -s KILL``
    is until its parent, or the init process, reaps it; os.kill(pid, 0) still finds it."""
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    for _ in range(200):
        state = open(f"/proc/{p.pid}/stat").read().rsplit(")", 1)[1].split()[0]
        if state == "Z":
            return p
        time.sleep(0.05)
    raise AssertionError("the child did not end")


@pytest.mark.parametrize("holder", ["dead pid", "zombie", "silent host", "reused pid"])
def test_a_stale_lock_is_taken_over_with_a_note_and_released_after(scene, tmp_path, capfd, holder):
    out = tmp_path / "out.las"
    child = None
    if holder == "dead pid":
        _hold(out, _dead_pid(), socket.gethostname())
    elif holder == "zombie":
        if not sys.platform.startswith("linux"):
            pytest.skip("a zombie's state is read from /proc (Linux)")
        child = _zombie()
        _hold(out, child.pid, socket.gethostname())
    elif holder == "reused pid":  # a container started again: this process has the pid of the run that took the lock
        if process_start(os.getpid()) is None:
            pytest.skip("a process's start is read from /proc (Linux)")
        _hold(out, os.getpid(), socket.gethostname(), age=time.time() - process_start(os.getpid()) + 60)
    else:
        _hold(out, 1, "another-host.example", age=STALE + 60)
    normals(scene, out, quiet=True)
    err = capfd.readouterr().err
    why = {"silent host": "no heartbeat from another-host", "reused pid": "is another process, started after the lock"}
    assert "taking over a stale lock" in err and why.get(holder, "is dead") in err
    assert len(laspy.read(str(out))) == len(laspy.read(str(scene))) and not lock_path(out).exists()
    if child is not None:
        child.wait()


def test_a_recent_lock_from_another_host_is_respected(scene, tmp_path):
    out = tmp_path / "out.las"
    _hold(out, 1, "another-host.example", age=10)
    with pytest.raises(PatchcloudLockedError, match="pid 1 on another-host.example"):
        normals(scene, out, quiet=True)


def test_a_failed_run_releases_its_lock(scene, tmp_path, monkeypatch):
    def broken(*args, **kwargs):
        raise PatchcloudValueError("a tile went wrong")

    monkeypatch.setattr(normals_tiles, "finish_one_tile", broken)
    out = tmp_path / "out.las"
    with pytest.raises(PatchcloudValueError):
        normals(scene, out, scheduler="synchronous", quiet=True)
    assert not lock_path(out).exists()


def test_locks_of_several_paths_are_all_or_nothing(tmp_path):
    _hold(tmp_path / "b", os.getpid(), socket.gethostname())
    with pytest.raises(PatchcloudLockedError):
        RunLock([tmp_path / "a", tmp_path / "b"]).acquire()
    assert not lock_path(tmp_path / "a").exists()  # the first one, taken, is given back


def test_two_concurrent_runs_on_one_output_one_writes_it_the_other_stops(scene, tmp_path):
    out = tmp_path / "out.las"
    cmd = [sys.executable, "-m", "patchcloud.stream.cli", "normals", str(scene), str(out), "--on-disk", "--scheduler", "synchronous",
           "--quiet"]
    runs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    done = [(p.wait(timeout=300), p.stderr.read()) for p in runs]
    codes = sorted(c for c, _ in done)
    assert codes == [0, 2], done
    err = next(e for c, e in done if c == 2)
    assert err.count("\n") == 1 and ("another patchcloud run" in err or "exists" in err), err
    back = laspy.read(str(out))
    assert len(back) == len(laspy.read(str(scene))) and np.all(np.isfinite(back.NormalX))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.las"]


def test_a_lock_records_the_command_line_whole_up_to_its_first_words(monkeypatch):
    from patchcloud.stream.io.lock import COMMAND_WORDS

    monkeypatch.setattr(sys, "argv", ["patchcloud", "normals", "a b.laz", "out.laz", "--tile-size", "1"])
    assert json.loads(RunLock([])._info())["command"] == "patchcloud normals 'a b.laz' out.laz --tile-size 1"
    monkeypatch.setattr(sys, "argv", ["patchcloud", "normals", *[f"t{i}.laz" for i in range(40)], "--out-dir", "o"])
    words = json.loads(RunLock([])._info())["command"].split()
    assert len(words) == COMMAND_WORDS + 1 and words[-1] == "..."


def test_a_catalog_and_a_run_on_one_of_its_outputs_exclude_each_other(scene, tmp_path):
    """A catalog run writing OUT/a.las takes OUT/a.las.lock, the lock a run writing OUT/a.las alone takes: either way
    round, the second run stops with one line naming that output, and writes nothing."""
    import shutil

    inputs = tmp_path / "in"
    inputs.mkdir()
    for name in ("a.las", "b.las"):
        shutil.copy(scene, inputs / name)
    out = tmp_path / "out"
    out.mkdir()
    lock = _hold(out / "a.las", os.getpid(), socket.gethostname())  # a run writing out/a.las alone
    with pytest.raises(PatchcloudLockedError, match=r"out/a.las: another patchcloud run"):
        normals(str(inputs), out_dir=str(out), scheduler="synchronous", quiet=True)
    assert sorted(p.name for p in out.iterdir()) == ["a.las.lock"]
    lock.unlink()
    with RunLock([out / "patchcloud", out / "a.las", out / "b.las"]):  # what a catalog run into out holds
        with pytest.raises(PatchcloudLockedError, match=r"out/b.las: another patchcloud run"):
            normals(inputs / "b.las", out / "b.las", scheduler="synchronous", quiet=True)
    assert sorted(p.name for p in out.iterdir()) == []
