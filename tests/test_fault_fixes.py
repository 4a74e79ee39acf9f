"""What tools/faults.py found, fixed: a store's attributes are written in one piece (a run killed between two writes
left a step marked done without its results, and the rerun stopped on a KeyError); a lock that cannot be written on
a full disk is not left behind; ``patchcloud tile`` locks its store as the jobs do."""

import json
import os
import re
import socket
import time
from pathlib import Path

import numpy as np
import pytest

from patchcloud.core import PatchcloudIOError
from patchcloud.stream import tile
from patchcloud.stream.io.lock import PatchcloudLockedError, RunLock, lock_path
from patchcloud.stream.io.store import Store

SAMPLE = os.path.join(os.path.dirname(__file__), "..", "data", "test_data_77055_627760_LA93_IGN69.laz")


def _count_metadata_writes(monkeypatch, suffix: str) -> list:
    """The keys ending in ``suffix`` written from now on into a store ``s.zarr``, by zarr's local store or by the store's
    direct writes (stream/io/local_zarr.py)."""
    from zarr.storage import LocalStore

    from patchcloud.stream.io import local_zarr

    written = []
    put = LocalStore.set
    write_file = local_zarr._write_file

    async def counted(self, key, value):
        if key.endswith(suffix):
            written.append(key)
        return await put(self, key, value)

    def counted_file(path, data):
        key = str(path).split("s.zarr/", 1)[-1]
        if key.endswith(suffix):
            written.append(key)
        return write_file(path, data)

    monkeypatch.setattr(LocalStore, "set", counted)
    monkeypatch.setattr(local_zarr, "_write_file", counted_file)
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


# -- a run killed while it removes its store, or between recording its output and renaming it ------------------------------


@pytest.fixture(scope="module")
def small_las(tmp_path_factory):
    from test_stream import write_scene

    path = tmp_path_factory.mktemp("kill") / "in.las"
    write_scene(path, n=8_000, seed=3, point_format=6, extra=False)
    return path


def _normals(src, out, *extra):
    from click.testing import CliRunner

    from patchcloud.stream.cli import main

    return CliRunner().invoke(main, ["normals", str(src), str(out), "--on-disk", "--scheduler", "synchronous", "-q",
                                     "--tile-size", "16", *extra])


def test_a_store_is_removed_through_a_removing_name_with_its_records_last(tmp_path, monkeypatch):
    from patchcloud.stream.io import store as store_module

    s = Store.create(str(tmp_path / "s.zarr"))
    s.write((0, 0, 0), "v", np.arange(3))
    s.set_group_attrs("outputs", **{"0": {"path": "x"}})
    removed = []
    unlink, rmtree = store_module.Path.unlink, store_module.shutil.rmtree
    monkeypatch.setattr(store_module.Path, "unlink", lambda self, **kw: (removed.append(self.name), unlink(self, **kw))[1])
    monkeypatch.setattr(store_module.shutil, "rmtree", lambda p, **kw: (removed.append(os.path.basename(p)), rmtree(p, **kw))[1])
    Store.discard(str(tmp_path / "s.zarr"))
    assert not (tmp_path / "s.zarr").exists() and not (tmp_path / "s.zarr.removing").exists()
    assert removed[0] == "s.zarr.removing"  # a leftover of an earlier removal, if any
    assert removed[-3:] == ["outputs", "zarr.json", "s.zarr.removing"] and "tiles" in removed[1:-3]


def test_a_run_killed_while_removing_its_store_is_finished_by_the_same_command(small_las, tmp_path):
    out = tmp_path / "out.las"
    assert _normals(small_las, out, "--keep-store").exit_code == 0
    clean = out.read_bytes()
    store = tmp_path / "out.las.store"
    os.replace(store, tmp_path / "out.las.store.removing")  # what Store.discard does first, then its removal, cut short
    import shutil

    shutil.rmtree(tmp_path / "out.las.store.removing" / "tiles")
    r = _normals(small_las, out)
    assert r.exit_code == 0, r.output
    assert out.read_bytes() == clean
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.las"]


def test_a_removing_store_that_does_not_record_the_output_does_not_allow_replacing_it(small_las, tmp_path):
    out = tmp_path / "out.las"
    out.write_bytes(b"someone else's file")
    (tmp_path / "out.las.store.removing").mkdir()
    r = _normals(small_las, out)
    assert r.exit_code == 2 and "exists" in r.output and out.read_bytes() == b"someone else's file"
    assert not (tmp_path / "out.las.store.removing").exists()


def test_a_run_killed_between_recording_its_output_and_renaming_it_writes_it_again(small_las, tmp_path):
    out = tmp_path / "out.las"
    assert _normals(small_las, out, "--keep-store").exit_code == 0
    clean = out.read_bytes()
    os.replace(out, tmp_path / "out.las.partial")  # the store records out.las; the rename did not happen
    r = _normals(small_las, out)
    assert r.exit_code == 0, r.output
    assert out.read_bytes() == clean
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.las"]


def test_an_output_is_recorded_before_it_is_renamed(small_las, tmp_path, monkeypatch):
    """The record holds the size and modification time the renamed file keeps."""
    out = tmp_path / "out.las"
    seen = []
    replace = type(out).replace

    def spy(self, target):
        if self.name == "out.las.partial":
            seen.append(Store.open(str(tmp_path / "out.las.store"), mode="r").group_attrs("outputs").get(str(out.resolve())))
        return replace(self, target)

    monkeypatch.setattr(type(out), "replace", spy)
    assert _normals(small_las, out, "--keep-store").exit_code == 0
    rec = [r for r in seen if r is not None]
    assert rec and rec[-1]["path"] == str(out.resolve()) and rec[-1]["size"] == out.stat().st_size
    assert rec[-1]["mtime_ns"] == out.stat().st_mtime_ns


@pytest.mark.parametrize("damage", ["removed", "garbage"])
def test_a_store_whose_root_metadata_is_gone_is_one_line_saying_remove_it(small_las, tmp_path, damage):
    out = tmp_path / "out.las"
    assert _normals(small_las, out, "--keep-store").exit_code == 0
    root = tmp_path / "out.las.store" / "zarr.json"
    if damage == "removed":
        root.unlink()
    else:
        root.write_bytes(b"\x00garbage{")
    r = _normals(small_las, tmp_path / "out2.las", "--store", str(tmp_path / "out.las.store"))
    assert r.exit_code == 2 and r.output.count("\n") == 1, r.output
    assert "a patchcloud store whose root metadata (zarr.json) is missing or damaged" in r.output
    assert "remove the store to start over" in r.output
    assert (tmp_path / "out.las.store" / "tiles").exists()  # nothing of it removed


@pytest.mark.parametrize("what", ["directory", "file"])
def test_tile_refuses_a_path_holding_something_else_and_touches_nothing(tmp_path, what):
    from patchcloud.stream.io.store import PatchcloudStoreError

    store = tmp_path / "s.zarr"
    if what == "directory":
        store.mkdir()
        (store / "notes.txt").write_text("mine")
    else:
        store.write_text("mine")
    # it is the user's: not "remove the store to start over" (review J: that told the user to remove their own files)
    what_it_is = "a file" if what == "file" else "a directory that holds no patchcloud store"
    with pytest.raises(PatchcloudStoreError, match=rf"s.zarr: exists and is not a patchcloud store \({what_it_is}\): give another "
                                                   r"store \(nothing there is touched\)$"):
        tile(SAMPLE, str(store), tile_size=64, scheduler="synchronous", quiet=True)
    assert (store / "notes.txt" if what == "directory" else store).read_text() == "mine"


def test_tile_refuses_its_input_as_its_store(tmp_path):
    """``patchcloud tile IN IN``: the input is never a store (it said the input "is not a patchcloud store: remove the
    store", review J), as every job refuses it."""
    from patchcloud.core import PatchcloudIOError

    src = tmp_path / "in.laz"
    src.write_bytes(Path(SAMPLE).read_bytes())
    with pytest.raises(PatchcloudIOError, match=r"in.laz: is the input .*in.laz; give another output \(an input is never replaced\)"):
        tile(src, str(src), tile_size=64, scheduler="synchronous", quiet=True)
    assert src.read_bytes() == Path(SAMPLE).read_bytes()


@pytest.mark.parametrize("args, says", [
    (["normals", "IN", "OUT", "--orient", "bad"], "error: Invalid value for '--orient': 'bad' is not one of"),
    (["normals", "IN", "OUT", "--bogus"], "error: No such option '--bogus' (`patchcloud normals --help` for help)"),
    (["nrmals"], "error: No such command 'nrmals'"),
    (["--bogus"], "error: No such option '--bogus' (`patchcloud --help` for help)"),
    (["normals"], "error: Missing argument"),
    (["don", "IN", "OUT", "--rs", "abc"], "error: Invalid value for '--rs': 'abc' is not a valid float"),
    (["normals", "IN", "OUT", "--viewpoint", "1", "2", "3", "--orient", "up"], "error: --viewpoint orients the normals"),
    (["render", "IN", "OUT"], "error: Missing option '--color' / '--colour'. Choose from: normals, curvature, don,"),
])
def test_usage_errors_are_one_line_with_exit_2(args, says, tmp_path):
    """What click refuses itself (an unknown option or command, a value of the wrong kind, a missing argument) is one
    line too, naming the command's help, where click prints four (usage, hint, blank, ``Error:``)."""
    from click.testing import CliRunner

    from patchcloud.stream.cli import main

    args = [str(tmp_path / "in.las") if a == "IN" else str(tmp_path / "out.las") if a == "OUT" else a for a in args]
    r = CliRunner().invoke(main, args, prog_name="patchcloud")
    # click's own words as of 8.3 ("No such option '--bogus'"); click 8.2, which pyproject.toml allows, says "No such option: --bogus"
    output = re.sub(r"No such option: (--\S+)", r"No such option '\1'", r.output)
    assert r.exit_code == 2 and output.count("\n") == 1 and output.startswith(says), r.output
    assert not (tmp_path / "out.las").exists()


def test_a_kept_store_holds_no_fragments_nor_trash_after_a_run(small_las, tmp_path):
    """The parts' fragments and the export's arrays, removed in the background, are gone when the run returns."""
    from patchcloud.stream.io.local_zarr import TRASH

    store = tmp_path / "s.zarr"
    res = _normals(small_las, tmp_path / "o.las", "--store", str(store), "--keep-store")
    assert res.exit_code == 0, res.output
    assert (store / "tiles").is_dir()
    assert not (store / "parts").exists() and not (store / "export").exists() and not (store / TRASH).exists()


@pytest.mark.parametrize("where", ["store", "memory"])
def test_a_fragment_written_as_an_interrupted_export_ends_is_removed_with_the_rest(tmp_path, monkeypatch, where):
    """Ctrl-C during the export: a task still running may write a LAZ fragment into OUT.partial.parts while the export
    removes it, which left the directory and the fragment (review J, once); the run removes what is left of its partial
    outputs once its workers are gone."""
    from patchcloud.stream import normals
    from patchcloud.stream.engine.runner import Runner
    from patchcloud.stream.io import las_output
    from patchcloud.stream.io.renamed import partial_path

    out = tmp_path / "out.laz"
    close = Runner.close

    def late_fragment_then_close(self):
        d = las_output.fragments_dir(partial_path(out))
        d.mkdir(exist_ok=True)
        (d / "000003.tmp").write_bytes(b"a task's late part")
        close(self)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt("stopped")

    monkeypatch.setattr(Runner, "close", late_fragment_then_close)
    monkeypatch.setattr(las_output, "finish", interrupted)
    run = {"store": str(tmp_path / "s.zarr"), "scheduler": "synchronous"} if where == "store" else {}  # else in memory
    with pytest.raises(KeyboardInterrupt):
        normals(SAMPLE, out, quiet=True, **run)
    assert sorted(p.name for p in tmp_path.iterdir()) == (["s.zarr"] if where == "store" else [])
