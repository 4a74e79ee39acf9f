"""Ingest and export as parallel tasks: identical files whatever the workers, scheduler and parts; resume per part."""

import subprocess
import sys
import textwrap

import laspy
import lazrs
import numpy as np
import pytest
from test_stream import write_scene

from patchcloud.stream import Store, normals, segment, tile
from patchcloud.stream.engine import ingest
from patchcloud.stream.engine.export import Column, export_columns
from patchcloud.stream.engine.runner import Runner
from patchcloud.stream.io.las import open_source

N = 130_000  # about that many points: three parts of 50,000 points, the smallest part size


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("parallel")
    las = d / "scene.las"
    write_scene(las, n=N, seed=3)
    laz = d / "scene.laz"
    laspy.read(str(las)).write(str(laz))
    return las, laz


@pytest.mark.slow  # about 30 s a file format (2 cores): with the cluster tests
@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_output_bytes_do_not_depend_on_workers_scheduler_or_parts(scene, tmp_path, suffix):
    src = scene[1] if suffix == ".laz" else scene[0]
    runs = {
        "synchronous, one part": dict(scheduler="synchronous", chunk=1_000_000),
        "threads x1, parts of 50,000": dict(scheduler="threads", workers=1, chunk=50_000),
        "threads x2, default parts": dict(scheduler="threads", workers=2),
        "processes x2, parts of 100,000": dict(scheduler="processes", workers=2, chunk=100_000),
    }
    data = {}
    for name, how in runs.items():
        out = tmp_path / (name.replace(" ", "_").replace(",", "") + suffix)
        normals(src, out, tile_size=16, quiet=True, **how)
        data[name] = out.read_bytes()
    first = next(iter(data.values()))
    assert all(d == first for d in data.values()), [k for k, d in data.items() if d != first]


@pytest.mark.slow  # 10-20 s: with the slow marker, so the default suite stays under 10 minutes
def test_segment_ids_are_numbered_in_file_order_whatever_the_parts(scene, tmp_path):
    las = scene[0]
    a, b = tmp_path / "a.las", tmp_path / "b.las"
    kw = dict(r_small=0.5, r_large=2.0, threshold=0.05, tolerance=0.5, tile_size=16, quiet=True)
    segment(las, a, scheduler="synchronous", chunk=1_000_000, **kw)
    segment(las, b, scheduler="threads", workers=2, chunk=50_000, **kw)
    assert a.read_bytes() == b.read_bytes()
    ids = laspy.read(str(a)).ClusterID.astype(np.int64)
    first = ids[np.sort(np.unique(ids, return_index=True)[1])]
    first = first[first != 0]
    assert first.size > 2 and np.array_equal(first, np.arange(1, first.size + 1))  # 1, 2, ... as they first appear


def _export(src_path, out, store_url, chunk, runner):
    """Every point's intensity times two as a new float dimension, written by the parallel exporter."""
    src = open_source(src_path)
    st = ingest.ensure_tiled(src, store_url, 16.0, runner, True, chunk)[0]
    for t in st.tiles:
        rec = st.read(t, "xyz")  # sorted by octree key: put back into the tile's input order
        rank = st.read(t, "rank")
        back = np.empty_like(rec)
        back[rank] = rec
        st.write(t, "twice_x", (back[:, 0] * 2).astype(np.float64))
    cols = [Column("twice_x", ("TwiceX",), np.float64)]
    export_columns(st, str(out), cols, (("TwiceX", np.float64, "2 X"),), runner=runner)


def test_parallel_laz_reads_back_with_laspy_and_the_sequential_lazrs_decoder(scene, tmp_path):
    las_in, laz_in = scene
    out = tmp_path / "out.laz"
    with Runner("threads", 2, quiet=True) as runner:
        _export(laz_in, out, str(tmp_path / "s.zarr"), 50_000, runner)
    got = laspy.read(str(out))
    ref = laspy.read(str(las_in))
    n = len(ref.points)
    assert len(got.points) == n
    assert np.array_equal(np.asarray(got.X), np.asarray(ref.X)) and np.array_equal(np.asarray(got.intensity), np.asarray(ref.intensity))
    assert np.array_equal(np.asarray(got.TwiceX), 2.0 * np.asarray(ref.X))
    # the sequential decoder, straight from the point data, gives the same records
    h = got.header
    vlr = lazrs.LazVlr.new_for_compression(h.point_format.id, h.point_format.num_extra_bytes)  # as written
    with open(out, "rb") as f:
        f.seek(h.offset_to_point_data)
        dec = lazrs.LasZipDecompressor(f, vlr.record_data())
        raw = np.zeros(n * h.point_format.size, np.uint8)
        dec.decompress_many(raw)
    assert raw.tobytes() == got.points.array.tobytes()
    # and the point data is what laspy writes in one go with the same records
    one_go = tmp_path / "one_go.laz"
    with laspy.open(str(one_go), mode="w", header=h, do_compress=True, laz_backend=laspy.LazBackend.Lazrs) as w:
        w.write_points(got.points)
    a, b = out.read_bytes(), one_go.read_bytes()
    assert a[h.offset_to_point_data :] == b[h.offset_to_point_data :]


def test_header_statistics_are_those_of_the_points(scene, tmp_path):
    las_in, _ = scene
    out = tmp_path / "n.las"
    normals(las_in, out, tile_size=16, quiet=True, workers=2, chunk=50_000)
    las = laspy.read(str(out))
    h = las.header
    assert h.point_count == len(las.points) > 100_000
    assert np.allclose(h.mins, [las.x.min(), las.y.min(), las.z.min()]) and np.allclose(h.maxs, [las.x.max(), las.y.max(), las.z.max()])
    for st in h.vlrs.get("ExtraBytesVlr")[0].extra_bytes_structs:
        name = st.format_name()
        v = np.asarray(las.points.array[name], dtype=np.float64)
        assert st.min[0] == v.min() and st.max[0] == v.max(), name  # laspy's own writer records the first values only


_KILLER = textwrap.dedent(
    """
    import os, signal, sys
    from patchcloud.stream import tile
    from patchcloud.stream.engine import ingest
    real, done = ingest.scatter_part, []
    def dies_after_two(*args, **kwargs):
        real(*args, **kwargs)
        done.append(1)
        if len(done) == 2:
            os.kill(os.getpid(), signal.SIGKILL)
    ingest.scatter_part = dies_after_two
    tile(sys.argv[1], sys.argv[2], tile_size=16, scheduler="synchronous", quiet=True, chunk=50_000)
    """
)


def test_ingest_resumes_from_the_parts_done_after_kill_9(scene, tmp_path, monkeypatch):
    las, _ = scene
    url = str(tmp_path / "killed.zarr")
    p = subprocess.run([sys.executable, "-c", _KILLER, str(las), url], capture_output=True, text=True)
    assert p.returncode == -9, p.stderr
    assert [Store.open(url).group_attrs(ingest.part_path(k)).get("done_xyz") for k in range(3)] == [True, True, None]
    read = []
    real = ingest.scatter_part

    def counting(url, p, *args, **kwargs):
        if not Store.open(url).group_attrs(ingest.part_path(p)).get("done_xyz"):
            read.append(p)
        return real(url, p, *args, **kwargs)

    monkeypatch.setattr(ingest, "scatter_part", counting)
    resumed = tile(las, url, tile_size=16, scheduler="synchronous", quiet=True, chunk=50_000)
    assert read == [2]  # only the part not done is read again
    fresh = tile(las, str(tmp_path / "fresh.zarr"), tile_size=16, scheduler="synchronous", quiet=True, chunk=50_000)
    assert resumed.tiles == fresh.tiles and "parts" not in resumed.group
    for t in fresh.tiles:
        for name in ("xyz", "rank"):
            assert np.array_equal(resumed.read(t, name), fresh.read(t, name))


def test_tiles_hold_their_points_in_input_order_whatever_the_parts(scene, tmp_path):
    las, _ = scene
    a = tile(las, str(tmp_path / "a.zarr"), tile_size=8, scheduler="synchronous", quiet=True, chunk=50_000)
    b = tile(las, str(tmp_path / "b.zarr"), tile_size=8, scheduler="synchronous", quiet=True, chunk=1_000_000)
    assert a.tiles == b.tiles and a.attrs["centroid_local"] == b.attrs["centroid_local"]
    src = laspy.read(str(las))
    xyz = np.column_stack([src.X, src.Y, src.Z])
    keys = ingest.tile_keys(a.grid, xyz)
    for k, t in enumerate(a.tiles):
        rows = a.read(t, "xyz")
        back = np.empty_like(rows)
        back[a.read(t, "rank")] = rows
        assert np.array_equal(back, xyz[keys == ingest.pack_tile_keys(np.array([t]))[0]])  # input order
        assert np.array_equal(rows, b.read(t, "xyz"))


@pytest.mark.parametrize("n, size", [(10_000_000, 500_000), (20_000_000, 200_000), (250_000, 100_000), (230_001, 100_000),
                                     (1_000_003, 1_000_000), (60_653, 100_000), (100_000, 50_000)])
def test_parts_cover_the_file_in_whole_chunks_and_end_in_one_chunk_parts(n, size):
    parts = ingest.part_ranges(n, size)
    firsts, counts = np.array(parts).T
    assert firsts[0] == 0 and np.all(firsts[1:] == firsts[:-1] + counts[:-1]) and firsts[-1] + counts[-1] == n
    assert np.all(counts[:-1] % 50_000 == 0) and np.all(counts <= size) and np.all(counts > 0)
    assert np.all(np.diff(counts) <= 0) or n == 230_001  # never growing (a remainder part at the end excepted)
    if n > 2 * size:  # the end cut finer: the last two parts of at most one chunk; whole parts before the finer ones
        full = counts == size
        assert np.all(counts[-2:] <= 50_000) and full[: full.sum()].all() and full.sum() < len(counts) - 2
    else:
        assert parts == [(f, min(size, n - f)) for f in range(0, n, size)]
    assert ingest.part_ranges(n, size, taper=False) == [(f, min(size, n - f)) for f in range(0, n, size)]


def test_only_the_last_file_of_a_catalog_ends_in_finer_parts():
    class Src:
        def __init__(self, n):
            self.point_count = n

    class Cat:
        sources = [Src(1_000_000), Src(0), Src(1_000_000)]

    parts = ingest.catalog_parts(Cat, 200_000)
    assert [c for f, _, c in parts if f == 0] == [200_000] * 5
    assert [c for f, _, c in parts if f == 2] == [200_000] * 3 + [100_000, 100_000, 50_000, 50_000, 50_000, 50_000]


def test_finer_last_parts_change_no_output_byte(tmp_path):
    las = tmp_path / "s.las"
    write_scene(las, n=230_000, seed=4)
    assert [c for _, c in ingest.part_ranges(laspy.open(str(las)).header.point_count, 100_000)][-3:] != [100_000] * 3
    a, b = tmp_path / "a.las", tmp_path / "b.las"
    normals(las, a, tile_size=16, quiet=True, scheduler="synchronous", chunk=100_000)
    normals(las, b, tile_size=16, quiet=True, scheduler="synchronous", chunk=1_000_000)
    assert a.read_bytes() == b.read_bytes()
