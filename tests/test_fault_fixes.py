"""What tools/faults.py found, fixed: a store's attributes are written in one piece (a run killed between two writes
left a step marked done without its results, and the rerun stopped on a KeyError); a lock that cannot be written on
a full disk is not left behind; ``patchcloud tile`` locks its store as the jobs do."""

import json
import os
import socket
import time

import numpy as np
import pytest

from patchcloud.core import PatchcloudIOError
from patchcloud.stream import tile
from patchcloud.stream.io.lock import PatchcloudLockedError, RunLock, lock_path
from patchcloud.stream.io.store import Store

SAMPLE = os.path.join(os.path.dirname(__file__), "..", "data", "test_data_77055_627760_LA93_IGN69.laz")


def _count_metadata_writes(monkeypatch, suffix: str) -> list:
    """The keys ending in ``suffix`` that zarr's local store writes from now on."""
    from zarr.storage import LocalStore

    written = []
    put = LocalStore.set

    async def counted(self, key, value):
        if key.endswith(suffix):
            written.append(key)
        return await put(self, key, value)

    monkeypatch.setattr(LocalStore, "set", counted)
    return written


def test_a_tile_is_marked_done_with_its_results_in_one_write(tmp_path, monkeypatch):
    s = Store.create(str(tmp_path / "s.zarr"))
    s.write((0, 0, 0), "v", np.arange(3))
    written = _count_metadata_writes(monkeypatch, "t+0+0+0/zarr.json")
    s.mark_tile((0, 0, 0), "fit", fit={"kinds": [1, 2, 3]}, count=3)
    assert written == ["tiles/t+0+0+0/zarr.json"]
    attrs = json.loads((tmp_path / "s.zarr" / "tiles" / "t+0+0+0" / "zarr.json").read_text())["attributes"]
    assert attrs["done"] == {"fit": True} and attrs["fit"] == {"kinds": [1, 2, 3]} and attrs["count"] == 3


def test_the_store_root_is_updated_in_one_write(tmp_path, monkeypatch):
    s = Store.create(str(tmp_path / "s.zarr"))
    written = _count_metadata_writes(monkeypatch, "zarr.json")
    s.update(tiles=[[0, 0, 0]], tile_counts=[3], centroid_local=[0.0, 0.0, 0.0])
    assert written == ["zarr.json"] and s.tile_counts.tolist() == [3] and s.tiles == [(0, 0, 0)]


def test_a_lock_that_cannot_be_written_is_removed_and_named(tmp_path, monkeypatch):
    def full(self):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(RunLock, "_info", full)
    out = tmp_path / "out.laz"
    with pytest.raises(PatchcloudIOError, match=r"out.laz.lock: cannot create the run's lock \(No space left on device\)"):
        RunLock([out]).acquire()
    assert not lock_path(out).exists()


def test_tile_stops_on_a_store_another_run_holds(tmp_path):
    store = tmp_path / "s.zarr"
    lock_path(store).write_text(json.dumps(dict(pid=os.getpid(), host=socket.gethostname(), started=time.time(), token="x")))
    with pytest.raises(PatchcloudLockedError, match=r"s.zarr: another patchcloud run"):
        tile(SAMPLE, str(store), tile_size=64, scheduler="synchronous", quiet=True)
    assert not store.exists()


def test_tile_releases_its_lock_and_makes_the_store_directory(tmp_path):
    store = tmp_path / "new" / "s.zarr"
    s = tile(SAMPLE, str(store), tile_size=64, scheduler="synchronous", quiet=True)
    assert len(s.tiles) == 4 and not lock_path(store).exists()
