"""A damaged store is never reused silently: a deleted or altered chunk, a missing array, an array from another store,
a damaged blob or a store of another version is one PatchcloudStoreError naming the tile and the array."""

import json
import shutil
import zlib

import numpy as np
import pytest
from click.testing import CliRunner
from test_stream import write_scene

from patchcloud.core import PatchcloudIOError
from patchcloud.stream import normals
from patchcloud.stream.cli import main
from patchcloud.stream.io.store import VERSION, PatchcloudStoreError, Store, chunk_checksums


def _chunk_files(array_dir):
    return sorted(p for p in (array_dir / "c").rglob("*") if p.is_file())


def test_rows_read_back_exactly_and_only_the_touched_chunks_are_checked(tmp_path):
    s = Store.create(str(tmp_path / "s.zarr"))
    v = np.arange(30, dtype=np.int64).reshape(10, 3)
    s.write((0, 0, 0), "v", v, chunk=4)  # chunks of rows 0-3, 4-7, 8-9
    assert np.array_equal(s.read((0, 0, 0), "v"), v)
    assert np.array_equal(s.read((0, 0, 0), "v", slice(3, 9)), v[3:9])
    assert s.read((0, 0, 0), "v", slice(5, 5)).shape == (0, 3)
    files = _chunk_files(tmp_path / "s.zarr" / "tiles" / "t+0+0+0" / "v")
    assert len(files) == 3
    files[2].unlink()  # rows 8-9 now read back as zeros
    assert np.array_equal(s.read((0, 0, 0), "v", slice(0, 8)), v[:8])  # chunks 0 and 1 are intact
    with pytest.raises(PatchcloudStoreError, match=r"tile t\+0\+0\+0, array 'v': the store is damaged \(rows 8 to 9 differ"):
        s.read((0, 0, 0), "v", slice(7, 9))


def test_an_altered_byte_a_missing_array_and_a_foreign_array_are_refused(tmp_path):
    s = Store.create(str(tmp_path / "s.zarr"))
    s.put("index/x", np.arange(100, dtype=np.float64))
    f = _chunk_files(tmp_path / "s.zarr" / "index" / "x")[0]
    raw = bytearray(f.read_bytes())
    raw[len(raw) // 2] ^= 0x10
    f.write_bytes(bytes(raw))
    with pytest.raises(PatchcloudStoreError, match=r"array 'index/x': the store is damaged \((rows 0 to 99 differ|a chunk cannot be decoded)"):
        s.get("index/x")
    with pytest.raises(PatchcloudStoreError, match=r"tile t\+1-2\+0: the store is damaged \(array 'normal' is missing\); remove the store"):
        s.read((1, -2, 0), "normal")
    other = Store.create(str(tmp_path / "other.zarr"))
    other.write((0, 0, 0), "xyz", np.ones((5, 3), dtype=np.int32))
    s.write((0, 0, 0), "xyz", np.zeros((5, 3), dtype=np.int32))
    dst = tmp_path / "s.zarr" / "tiles" / "t+0+0+0" / "xyz"
    shutil.rmtree(dst)
    shutil.copytree(tmp_path / "other.zarr" / "tiles" / "t+0+0+0" / "xyz", dst)
    with pytest.raises(PatchcloudStoreError, match="written by another store"):
        Store.open(str(tmp_path / "s.zarr")).read((0, 0, 0), "xyz")


def test_a_damaged_blob_is_refused(tmp_path):
    s = Store.create(str(tmp_path / "s.zarr"))
    s.put_blob("seams/x", np.array([1.0, 2.0, 3.0]))
    assert np.array_equal(s.get_blob("seams/x"), [1.0, 2.0, 3.0])
    f = tmp_path / "s.zarr" / "seams" / "x"
    raw = bytearray(f.read_bytes())
    raw[3] ^= 1
    f.write_bytes(bytes(raw))
    with pytest.raises(PatchcloudStoreError, match=r"blob 'seams/x': the store is damaged \(it differs"):
        s.get_blob("seams/x")


def test_a_store_of_another_version_is_refused_with_what_to_do(tmp_path):
    Store.create(str(tmp_path / "s.zarr"))
    meta = tmp_path / "s.zarr" / "zarr.json"
    m = json.loads(meta.read_text())
    m["attributes"]["version"] = VERSION - 1
    meta.write_text(json.dumps(m))
    with pytest.raises(PatchcloudStoreError, match=rf"store version {VERSION - 1} is not supported .*remove the store to start over"):
        Store.open(str(tmp_path / "s.zarr"))


def test_checksums_are_those_of_each_chunk():
    v = np.arange(12, dtype="<u2").reshape(6, 2)
    assert chunk_checksums(v, 4) == [zlib.crc32(v[:4].tobytes()), zlib.crc32(v[4:].tobytes())]


@pytest.fixture(scope="module")
def kept(tmp_path_factory):
    """A finished normals run whose store was kept."""
    d = tmp_path_factory.mktemp("integrity")
    write_scene(d / "scene.las", n=20_000, seed=5)
    normals(d / "scene.las", d / "first.las", tile_size=16, scheduler="synchronous", store=str(d / "s.zarr"), quiet=True)
    return d


@pytest.mark.parametrize("damage", ["delete", "flip", "moved"])
def test_a_rerun_on_a_damaged_kept_store_stops_with_one_line_naming_the_tile(kept, tmp_path, damage):
    store = tmp_path / "s.zarr"
    shutil.copytree(kept / "s.zarr", store)
    tiles = sorted(p for p in (store / "tiles").iterdir() if (p / "normal").is_dir())
    victim = tiles[len(tiles) // 2]
    f = _chunk_files(victim / "normal")[0]
    if damage == "delete":
        f.unlink()
    elif damage == "moved":  # another tile's normals, with their own checksums, from the same store
        donor = next(t for t in tiles if t != victim)
        shutil.rmtree(victim / "normal")
        shutil.copytree(donor / "normal", victim / "normal")
    else:
        raw = bytearray(f.read_bytes())
        raw[-5] ^= 0x01
        f.write_bytes(bytes(raw))
    out = tmp_path / "again.las"
    r = CliRunner().invoke(main, ["normals", str(kept / "scene.las"), str(out), "--tile-size", "16", "--scheduler", "synchronous",
                                  "--store", str(store), "--quiet"])
    assert r.exit_code == 2, r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in r.output
    assert f"{victim.name}, array 'normal': the store is damaged" in lines[0] and "remove the store to start over" in lines[0]
    assert "resumes from it" not in lines[0]  # resuming would meet the same damage
    assert not out.exists()


def test_opening_a_file_as_a_store_says_so(tmp_path):
    """Store.open of a file (an input given as the store, say): one error saying it is a file, not zarr's
    "[Errno 17] File exists" (review J)."""
    f = tmp_path / "x.laz"
    f.write_bytes(b"LASF")
    with pytest.raises(PatchcloudIOError, match=r"x.laz: not a patchcloud store \(a file; a store is a directory\)$"):
        Store.open(str(f))
    assert f.read_bytes() == b"LASF"
