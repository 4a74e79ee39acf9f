"""A local store's arrays, attributes and blobs, read and written by plain file calls (stream/io/local_zarr.py): the
same zarr format 3 that zarr itself reads and writes, in both directions."""

from __future__ import annotations

import json

import numpy as np
import pytest
import zarr

from patchcloud.stream.io.local_zarr import DATA_TYPES, LocalZarr, array_metadata
from patchcloud.stream.io.store import PatchcloudStoreError, Store, codec_for

CASES = [
    (dtype, shape, rows)
    for dtype in DATA_TYPES
    for shape, rows in [((7,), 7), ((10, 3), 4), ((0, 3), 1), ((9,), 4)]
]


def _values(dtype: str, shape: tuple) -> np.ndarray:
    rng = np.random.default_rng(7)
    if dtype == "bool":
        return rng.random(shape) < 0.5
    info = np.finfo(dtype) if dtype.startswith("float") else np.iinfo(dtype)
    lo, hi = (-1e6, 1e6) if dtype.startswith("float") else (max(info.min, -10**6), min(info.max, 10**6))
    return (rng.uniform(lo, hi, shape)).astype(dtype)


@pytest.mark.parametrize("dtype, shape, rows", CASES)
def test_an_array_written_directly_is_what_zarr_reads_and_has_zarrs_metadata(tmp_path, dtype, shape, rows):
    values = _values(dtype, shape)
    zarr.open_group(str(tmp_path), mode="w")  # the root group (a store's)
    LocalZarr(tmp_path).write_array("g/a", values, rows, {"crc32": [1, 2]})
    a = zarr.open_group(str(tmp_path), mode="r")["g/a"]
    assert a.dtype == np.dtype(dtype) and a.shape == shape and a.chunks == (rows,) + shape[1:]
    np.testing.assert_array_equal(a[...], values)
    assert dict(a.attrs) == {"crc32": [1, 2]}
    # the metadata zarr writes for the same array through the store's own codec
    z = zarr.open_group(str(tmp_path / "z"), mode="w")
    z.create_array("a", shape=shape, dtype=dtype, chunks=(rows,) + shape[1:], compressors=codec_for(np.dtype(dtype)),
                   attributes={"crc32": [1, 2]})
    theirs = json.loads((tmp_path / "z" / "a" / "zarr.json").read_text())
    ours = json.loads((tmp_path / "g" / "a" / "zarr.json").read_text())
    assert ours == theirs
    assert array_metadata(shape, np.dtype(dtype), (rows,) + shape[1:], {"crc32": [1, 2]}) == theirs


@pytest.mark.parametrize("dtype, shape, rows", CASES)
def test_an_array_zarr_wrote_is_read_directly(tmp_path, dtype, shape, rows):
    values = _values(dtype, shape)
    g = zarr.open_group(str(tmp_path), mode="w")
    a = g.create_array("t/a", shape=shape, dtype=dtype, chunks=(rows,) + shape[1:], compressors=codec_for(np.dtype(dtype)))
    if values.size:
        a[...] = values
    local = LocalZarr(tmp_path).array("t/a")
    assert local is not None and local.shape == shape and local.chunks == (rows,) + shape[1:]
    np.testing.assert_array_equal(local[0:shape[0]], values)
    if shape[0] > 2:  # rows across a chunk boundary
        np.testing.assert_array_equal(local[1:shape[0] - 1], values[1:-1])


def test_a_chunk_zarr_left_out_reads_as_zeros_as_zarr_reads_it(tmp_path):
    g = zarr.open_group(str(tmp_path), mode="w")
    a = g.create_array("a", shape=(8,), dtype="int32", chunks=(4,), compressors=codec_for(np.dtype("int32")))
    a[...] = np.r_[np.zeros(4, np.int32), np.arange(1, 5, dtype=np.int32)]  # chunk 0 all fill value: not written
    assert not (tmp_path / "a" / "c" / "0").exists()
    np.testing.assert_array_equal(LocalZarr(tmp_path).array("a")[0:8], a[...])


def test_an_array_of_another_codec_is_left_to_zarr(tmp_path):
    g = zarr.open_group(str(tmp_path), mode="w")
    g.create_array("a", shape=(4,), dtype="int32", chunks=(4,))  # zarr's default codec (zstd)
    assert LocalZarr(tmp_path).exists("a") and LocalZarr(tmp_path).array("a") is None


def test_a_smaller_array_replacing_a_larger_leaves_no_chunk_behind(tmp_path):
    zarr.open_group(str(tmp_path), mode="w")
    z = LocalZarr(tmp_path)
    z.write_array("a", np.arange(10, dtype=np.int64), 3, {})
    z.write_array("a", np.arange(2, dtype=np.int64), 3, {})
    assert sorted(p.name for p in (tmp_path / "a" / "c").iterdir()) == ["0"]
    np.testing.assert_array_equal(zarr.open_group(str(tmp_path), mode="r")["a"][...], [0, 1])


def test_group_attributes_are_merged_in_one_write_and_zarr_reads_them(tmp_path):
    zarr.open_group(str(tmp_path), mode="w")
    z = LocalZarr(tmp_path)
    z.update_group_attrs("tiles/t+0+0+0", {"count": 5, "done": {"sort": True}})
    z.update_group_attrs("tiles/t+0+0+0", {"done": {"sort": True, "fit": True}})
    assert z.group_attrs("tiles/t+0+0+0") == {"count": 5, "done": {"sort": True, "fit": True}}
    g = zarr.open_group(str(tmp_path), mode="r")
    assert dict(g["tiles/t+0+0+0"].attrs) == {"count": 5, "done": {"sort": True, "fit": True}}
    assert z.group_attrs("tiles/none") is None
    assert not list(tmp_path.rglob("*.partial"))  # every file renamed into place


def test_a_local_store_goes_the_direct_way_and_keeps_zarrs_format(tmp_path):
    url = str(tmp_path / "s.zarr")
    Store.create(url).update(tiles=[[0, 0, 0]], tile_counts=[3])
    s = Store.open(url)
    assert s._local is not None and s._group is None  # nothing opened through zarr yet
    xyz = np.arange(9, dtype=np.int32).reshape(3, 3)
    s.write((0, 0, 0), "xyz", xyz)
    s.mark_tile((0, 0, 0), "sort", count=3)
    s.put_blob("seams/x", np.array([1.5, 2.5]))
    np.testing.assert_array_equal(s.read((0, 0, 0), "xyz"), xyz)
    np.testing.assert_array_equal(s.get_blob("seams/x"), [1.5, 2.5])
    # the same store through zarr: the array, its checksums and the tile's record are there
    g = zarr.open_group(url, mode="r")
    a = g["tiles/t+0+0+0/xyz"]
    np.testing.assert_array_equal(a[...], xyz)
    assert a.attrs["path"] == "tiles/t+0+0+0/xyz" and a.attrs["store"] == s.uid
    assert g["tiles/t+0+0+0"].attrs["done"] == {"sort": True}
    # and a store written through zarr is read the direct way
    zs = Store(zarr.open_group(url, mode="r+"), url)
    zs._local = None
    zs.write((0, 0, 0), "rank", np.array([2, 0, 1], dtype=np.uint32))
    np.testing.assert_array_equal(Store.open(url).read((0, 0, 0), "rank"), [2, 0, 1])


def test_the_root_attributes_read_again_once_another_process_changes_them(tmp_path):
    url = str(tmp_path / "s.zarr")
    Store.create(url).update(tiles=[[0, 0, 0]])
    assert Store.open(url).tiles == [(0, 0, 0)]
    Store.open(url).update(tiles=[[0, 0, 0], [1, 0, 0]])  # what another process does: the cached root is stale
    assert Store.open(url).tiles == [(0, 0, 0), (1, 0, 0)]
    s = Store.open(url)
    s.attrs["tiles"].append([9, 9, 9])  # a caller changing what it got leaves the next reader's copy alone
    assert Store.open(url).tiles == [(0, 0, 0), (1, 0, 0)]


def test_a_damaged_chunk_read_directly_is_a_store_error(tmp_path):
    url = str(tmp_path / "s.zarr")
    Store.create(url).update(tiles=[[0, 0, 0]])
    s = Store.open(url)
    s.write((0, 0, 0), "xyz", np.arange(30, dtype=np.int32).reshape(10, 3))
    chunk = tmp_path / "s.zarr" / "tiles" / "t+0+0+0" / "xyz" / "c" / "0" / "0"
    chunk.write_bytes(b"not blosc")
    with pytest.raises(PatchcloudStoreError, match="xyz"):
        Store.open(url).read((0, 0, 0), "xyz")
    chunk.unlink()  # a deleted chunk reads as zeros, which its checksum refuses
    with pytest.raises(PatchcloudStoreError, match="differ from what was written"):
        Store.open(url).read((0, 0, 0), "xyz")


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_a_run_on_a_local_store_imports_zarr_in_no_process(tmp_path):
    """The client and its workers read and write a local store without zarr (0.2-0.6 s of each process's start)."""
    import subprocess
    import sys
    import textwrap
    from pathlib import Path

    sample = Path(__file__).resolve().parents[1] / "data" / "test_data_77055_627760_LA93_IGN69.laz"
    code = textwrap.dedent(f"""
        import sys
        import patchcloud
        from patchcloud.stream.engine.runner import Runner
        if __name__ == "__main__":
            patchcloud.normals({str(sample)!r}, {str(tmp_path / "out.laz")!r}, scheduler="processes", workers=2,
                               store={str(tmp_path / "s.zarr")!r}, quiet=True)
            with Runner("processes", 1, quiet=True) as r:
                worker = list(r.client.run(lambda: "zarr" in sys.modules).values())
            print("zarr" in sys.modules, worker)
    """)
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.strip() == "False [False]"
    assert zarr.open_group(str(tmp_path / "s.zarr"), mode="r").attrs["format"] == "patchcloud-store"  # zarr reads it


def test_a_node_removed_in_the_background_is_gone_at_once_and_its_files_once_settled(tmp_path):
    """``delete(wait=False)`` takes the node out of the store before it returns; :func:`settle` waits for its files."""
    from patchcloud.stream.io.local_zarr import TRASH, settle

    z = LocalZarr(tmp_path)
    z.write_array("parts/000000/xyz", np.arange(30.0).reshape(10, 3), 4, {})
    z.write_array("keep/a", np.arange(3), 3, {})
    z.delete("parts", wait=False)
    assert not z.exists("parts/000000/xyz") and not (tmp_path / "parts").exists()
    z.write_array("parts/000000/xyz", np.ones((2, 3)), 2, {})  # the name is free again: a new node, not the old one's files
    settle(tmp_path)
    assert not (tmp_path / TRASH).exists()
    np.testing.assert_array_equal(z.array("parts/000000/xyz")[0:2], np.ones((2, 3)))
    np.testing.assert_array_equal(z.array("keep/a")[0:3], np.arange(3))
    # what a run killed during a removal left in the trash goes with the next settle
    (tmp_path / TRASH / "parts-0123").mkdir(parents=True)
    (tmp_path / TRASH / "parts-0123" / "c").write_bytes(b"x")
    settle(tmp_path)
    assert not (tmp_path / TRASH).exists()

