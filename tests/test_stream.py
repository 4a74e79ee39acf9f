"""The stream: LAS/LAZ -> tiles -> fit -> seams -> LAS/LAZ, on small multi-tile files."""

import os

import laspy
import numpy as np
import pytest
from click.testing import CliRunner
from conftest import angles_deg

import synthetic
from patchcloud.core import PatchcloudIOError, PatchcloudValueError
from patchcloud.core.octree import point_keys
from patchcloud.stream import Store, normals, tile
from patchcloud.stream.jobs import normals_tiles as stream_steps
from patchcloud.stream.cli import main

OFFSET = np.array([650000.0, 6860000.0, 40.0])  # UTM-like: the local frame must keep millimetres


def write_scene(path, n=60_000, seed=0, point_format=6, shuffle=True, extra=True):
    """A LAS/LAZ of the synthetic scene (40 m square, known normals), in shuffled input order."""
    pts, nrm = synthetic.scene(n, seed=seed)
    order = np.random.default_rng(seed).permutation(len(pts)) if shuffle else np.arange(len(pts))
    pts, nrm = pts[order] + OFFSET, nrm[order]
    header = laspy.LasHeader(point_format=point_format, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([650000.0, 6860000.0, 0.0])
    if extra:
        header.add_extra_dims([laspy.ExtraBytesParams("TrueNormal", np.float32, description="true normal", )])
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    las.intensity = np.arange(len(pts)) % 65535
    if extra:
        las.TrueNormal = nrm[:, 2].astype(np.float32)
    las.write(str(path))
    q = np.column_stack([las.x, las.y, las.z])
    return q, nrm


def read_normals(path):
    las = laspy.read(str(path))
    return las, np.column_stack([las.NormalX, las.NormalY, las.NormalZ]).astype(np.float64)


@pytest.fixture(scope="module")
def scene_las(tmp_path_factory):
    d = tmp_path_factory.mktemp("scene")
    path = d / "scene.las"
    pts, nrm = write_scene(path)
    return path, pts, nrm


@pytest.fixture(scope="module")
def reference(scene_las, tmp_path_factory):
    """A single-tile run of the scene (tile edge 64 m > the 40 m scene)."""
    path, _, _ = scene_las
    out = tmp_path_factory.mktemp("ref") / "ref.las"
    normals(path, out, tile_size=64, scheduler="synchronous", quiet=True)
    return read_normals(out)


def test_multi_tile_run_keeps_every_point_and_dimension(scene_las, tmp_path):
    path, pts, true = scene_las
    out = tmp_path / "out.laz"
    s = normals(path, out, tile_size=16, scheduler="threads", workers=2, quiet=True)
    assert s.tiles >= 9 and s.points == len(pts)
    src = laspy.read(str(path))
    las, nrm = read_normals(out)
    assert las.header.point_format.id == src.header.point_format.id
    for name in src.point_format.dimension_names:  # every original dimension, in input order
        assert np.array_equal(np.asarray(las[name]), np.asarray(src[name])), name
    assert np.allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-5)
    ang = angles_deg(nrm, true)
    assert np.median(ang) < 1.0
    ground = (np.abs(pts[:, 2] - OFFSET[2]) < 0.01) & (true[:, 2] > 0.99)
    assert np.mean(nrm[ground, 2] > 0) > 0.995
    assert set(np.unique(las.NormalMethod)) <= {1, 2, 3, 4}
    assert not (tmp_path / "out.laz.store").exists() and not (tmp_path / "out.laz.partial").exists()


@pytest.mark.slow  # about 30 s (2 cores)
def test_tile_size_does_not_change_the_result(scene_las, reference, tmp_path):
    path, _, _ = scene_las
    _, ref = reference
    for T in (8, 16):
        out = tmp_path / f"t{T}.las"
        normals(path, out, tile_size=T, scheduler="synchronous", quiet=True)
        _, nrm = read_normals(out)
        cos = np.einsum("ij,ij->i", nrm, ref)
        assert np.mean(cos > 0) > 0.998, T  # same orientation
        assert np.median(angles_deg(nrm, ref)) < 0.05, T


@pytest.mark.slow  # a local dask cluster, about 30 s (2 cores)
def test_local_cluster_gives_identical_output(scene_las, tmp_path):
    path, _, _ = scene_las
    laz = tmp_path / "scene.laz"
    laspy.read(str(path)).write(str(laz))
    for src in (path, laz):
        a, b = tmp_path / f"a{src.suffix}", tmp_path / f"b{src.suffix}"
        normals(src, a, tile_size=16, scheduler="synchronous", quiet=True)
        normals(src, b, tile_size=16, scheduler="processes", workers=2, quiet=True)  # a 2-worker LocalCluster
        la, lb = laspy.read(str(a)), laspy.read(str(b))
        assert np.array_equal(la.points.array, lb.points.array)
    assert np.array_equal(laspy.read(str(tmp_path / "a.las")).points.array, laspy.read(str(tmp_path / "a.laz")).points.array)


def test_resume_after_an_interrupted_run(scene_las, tmp_path, monkeypatch):
    path, _, _ = scene_las
    full = tmp_path / "full.las"
    normals(path, full, tile_size=16, scheduler="synchronous", quiet=True)
    store = str(tmp_path / "job.zarr")
    calls = {"n": 0}
    real = stream_steps.finish_one_tile

    def dies_after_three(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] > 3:
            raise KeyboardInterrupt("killed")
        return real(*args, **kwargs)

    monkeypatch.setattr(stream_steps, "finish_one_tile", dies_after_three)
    out = tmp_path / "out.las"
    with pytest.raises(KeyboardInterrupt):
        normals(path, out, tile_size=16, scheduler="synchronous", quiet=True, store=store)
    assert not out.exists() and not (tmp_path / "out.las.partial").exists()
    st = Store.open(store)
    assert sum(st.tile_done(t, "finish") for t in st.tiles) == 3
    # the rerun skips what was done: fit runs on no tile again
    monkeypatch.setattr(stream_steps, "finish_one_tile", real)
    fits = {"n": 0}
    real_fit = stream_steps.fit_one_tile

    def counting_fit(*args, **kwargs):
        fits["n"] += 1
        return real_fit(*args, **kwargs)

    monkeypatch.setattr(stream_steps, "fit_one_tile", counting_fit)
    normals(path, out, tile_size=16, scheduler="synchronous", quiet=True, store=store)
    assert fits["n"] == 0
    assert np.array_equal(laspy.read(str(out)).points.array, laspy.read(str(full)).points.array)


@pytest.mark.slow  # about 30 s (2 cores): two runs at 4 m tiles
def test_a_store_stopped_while_tiling_keeps_its_tile_size_when_resumed_without_one(scene_las, tmp_path, monkeypatch):
    # `tile --tile-size 4` (or `normals --tile-size 4 --store S`) stopped while sorting its tiles, then `normals --store
    # S` without a tile size: the store's 4 m tiles are resumed, not replaced by tiles of the default size (review M)
    from patchcloud.stream.engine import ingest

    path, _, _ = scene_las
    full = tmp_path / "full.las"
    normals(path, full, tile_size=4, scheduler="synchronous", quiet=True)
    store = str(tmp_path / "tiles.zarr")
    real, calls = ingest.sort_tile, {"n": 0}

    def dies_after_three(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] > 3:
            raise KeyboardInterrupt("killed")
        return real(*args, **kwargs)

    monkeypatch.setattr(ingest, "sort_tile", dies_after_three)
    with pytest.raises(KeyboardInterrupt, match=r"^interrupted \(the store .*tiles.zarr, .* is kept: the same command resumes"):
        tile(path, store, tile_size=4, scheduler="synchronous", quiet=True)
    st = Store.open(store)
    assert st.grid.tile_size == 4 and not st.step_done("tile") and len(st.tiles) > ingest.FEW_TILES  # (the default would
    monkeypatch.setattr(ingest, "sort_tile", real)                                              # find 4 m too small)
    out = tmp_path / "out.las"
    normals(path, out, scheduler="synchronous", quiet=True, store=store)
    assert Store.open(store).grid.tile_size == 4
    assert np.array_equal(laspy.read(str(out)).points.array, laspy.read(str(full)).points.array)


@pytest.mark.parametrize("fmt", [0, 1, 2, 3, 6, 7, 8])
def test_every_dimension_round_trips(fmt, tmp_path):
    rng = np.random.default_rng(fmt)
    n = 3000
    xy = rng.uniform(0, 20, (n, 2))
    header = laspy.LasHeader(point_format=fmt, version="1.2" if fmt < 6 else "1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([500000.0, 5000000.0, 0.0])
    header.add_extra_dims([laspy.ExtraBytesParams("Reflectance", np.float64), laspy.ExtraBytesParams("Tag", np.uint16)])
    las = laspy.LasData(header, points=laspy.PackedPointRecord.zeros(n, header.point_format))
    raw = las.points.array.view(np.uint8).reshape(n, -1)
    raw[:] = rng.integers(0, 256, raw.shape, dtype=np.uint8)  # every bit of every field random
    las.x, las.y, las.z = xy[:, 0] + 500000, xy[:, 1] + 5000000, 0.05 * xy[:, 0]
    src = tmp_path / "in.las"
    las.write(str(src))
    out = tmp_path / "out.las"
    # random bits make about half the points withheld or noise: kept, so that every point gets a normal
    normals(src, out, tile_size=8, scheduler="synchronous", quiet=True, keep_noise=True)
    a, b = laspy.read(str(src)), laspy.read(str(out))
    assert b.header.point_format.id == fmt
    size = a.points.array.dtype.itemsize
    ra = a.points.array.view(np.uint8).reshape(n, size)
    rb = b.points.array.view(np.uint8).reshape(n, b.points.array.dtype.itemsize)[:, :size]
    assert np.array_equal(ra, rb)  # every byte of every original point record
    assert np.mean(np.asarray(b.NormalZ) > 0.99) > 0.99


def test_tile_and_info_commands(scene_las, tmp_path):
    path, pts, _ = scene_las
    r = CliRunner().invoke(main, ["tile", str(path), str(tmp_path / "s.zarr"), "--tile-size", "16", "-q"])
    assert r.exit_code == 0, r.output
    st = Store.open(str(tmp_path / "s.zarr"))
    assert sum(st.tile_counts) == len(pts) and st.grid.tile_size == 16
    total = 0
    grid = st.grid
    for t in st.tiles:  # sorted by octree key within each tile, and the rank is a permutation
        rank = st.read(t, "rank")
        assert np.array_equal(np.sort(rank), np.arange(rank.size))
        _, keys = point_keys(grid.local(st.read(t, "xyz")) - grid.corner(t), grid.tile_size)
        assert np.all(keys[1:] >= keys[:-1])
        total += rank.size
    assert total == len(pts)
    r = CliRunner().invoke(main, ["info", str(tmp_path / "s.zarr")])
    assert r.exit_code == 0 and "tiles of 16 m" in r.output and "sort" in r.output
    r = CliRunner().invoke(main, ["info", str(path)])
    assert r.exit_code == 0 and f"{len(pts):,}" in r.output
    # a job on that store without --tile-size works on its tiles (it re-tiled at the default size, silently)
    before = {t: st.read(t, "rank").tobytes() for t in st.tiles}
    s = normals(path, tmp_path / "n.las", store=str(tmp_path / "s.zarr"), quiet=True)
    assert s.tile_size == 16
    again = Store.open(str(tmp_path / "s.zarr"))
    assert {t: again.read(t, "rank").tobytes() for t in again.tiles} == before


def _expect_error(args, fragment, tmp_path):
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and fragment in lines[0], r.stderr
    return lines[0]


def test_bad_inputs_give_one_clear_error_and_no_output(scene_las, tmp_path):
    path, _, _ = scene_las
    out = tmp_path / "out.las"
    data = path.read_bytes()
    cases = {
        "text.las": (b"hello, not a point cloud\n" * 10, "not a LAS/LAZ file"),
        "empty.las": (b"", "not a LAS/LAZ file"),
        "truncated.las": (data[: len(data) // 2], "truncated"),
    }
    # a header that promises more points than the data holds, and one that promises fewer
    more = bytearray(data)
    hdr = laspy.read(str(path)).header
    n = hdr.point_count
    more[247:255] = int(n + 10).to_bytes(8, "little")  # LAS 1.4 64-bit point count
    cases["more.las"] = (bytes(more), "truncated")
    fewer = bytearray(data)
    fewer[247:255] = int(n - 100).to_bytes(8, "little")
    cases["fewer.las"] = (bytes(fewer), "point data holds")
    for name, (content, fragment) in cases.items():
        bad = tmp_path / name
        bad.write_bytes(content)
        line = _expect_error(["normals", str(bad), str(out), "-q"], fragment, tmp_path)
        assert name in line
        assert not out.exists() and not (tmp_path / "out.las.partial").exists() and not (tmp_path / "out.las.store").exists()
    zero = tmp_path / "zero.las"
    laspy.LasData(laspy.LasHeader(point_format=6, version="1.4")).write(str(zero))
    _expect_error(["normals", str(zero), str(out), "-q"], "holds no points", tmp_path)
    _expect_error(["normals", str(tmp_path / "missing.las"), str(out), "-q"], "no such file", tmp_path)
    out.write_bytes(b"keep me")
    _expect_error(["normals", str(path), str(out), "-q"], "exists (use --overwrite", tmp_path)
    assert out.read_bytes() == b"keep me"
    _expect_error(["normals", str(path), str(tmp_path / "o2.las"), "--orient", "viewpoint", "-q"], "viewpoint", tmp_path)
    _expect_error(["normals", str(path), str(tmp_path / "o2.las"), "--scheduler", "nonsense", "-q"], "scheduler must be one of", tmp_path)


def test_python_api_errors_are_specific(scene_las, tmp_path):
    path, _, _ = scene_las
    with pytest.raises(PatchcloudIOError) as e:
        normals(tmp_path / "missing.las", tmp_path / "o.las")
    assert isinstance(e.value, OSError)
    with pytest.raises(PatchcloudValueError):
        normals(path, tmp_path / "o.las", criterion="bogus")
    with pytest.raises(PatchcloudValueError):
        tile(path, str(tmp_path / "s.zarr"), tile_size=-1)
    assert not os.path.exists(tmp_path / "o.las")


def test_cli_viewpoint_orients_as_pdals_does_and_bad_options_are_named_as_typed(scene_las, tmp_path):
    """--viewpoint alone orients the normals towards it (PDAL's viewpoint); with another --orient it is an error; the
    Python API's parameter names reach the user as the options they typed."""
    from click.testing import CliRunner

    from patchcloud.stream.cli import main

    path, pts, _ = scene_las
    run = ["--scheduler", "synchronous", "-q"]
    below = [str(v) for v in (pts.mean(axis=0) - [0, 0, 1000])]  # under the scene: ground normals point down
    r = CliRunner().invoke(main, ["normals", str(path), str(tmp_path / "a.las"), "--viewpoint", *below, *run])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["normals", str(path), str(tmp_path / "b.las"), "--viewpoint", *below, "--orient", "viewpoint", *run])
    assert r.exit_code == 0, r.output
    a, b = read_normals(tmp_path / "a.las")[1], read_normals(tmp_path / "b.las")[1]
    assert np.array_equal(a, b) and np.median(a[:, 2]) < -0.9
    for args, words in ((["--viewpoint", *below, "--orient", "up"], "goes with --orient viewpoint, not --orient up"),
                        (["--orient", "viewpoint"], "--orient viewpoint needs a viewpoint"),
                        (["--fallback-knn", "100000"], "--fallback-knn must be a whole number from 3 to 1000; got 100000")):
        r = CliRunner().invoke(main, ["normals", str(path), str(tmp_path / "c.las"), *args, *run])
        assert r.exit_code == 2 and words in r.output, r.output
        assert not (tmp_path / "c.las").exists()


@pytest.mark.parametrize("change", ["z", "class"])
def test_a_kept_store_is_not_reused_for_an_input_rewritten_in_place(scene_las, tmp_path, change):
    """Same name, same size, same modification time (``touch -r``, ``cp -p``, a coarse file system), other records:
    the store is tiled again, so the output is the new file's, as a run without the store gives."""
    path, _, _ = scene_las
    src = tmp_path / "in.las"
    src.write_bytes(path.read_bytes())
    store = str(tmp_path / "job.zarr")
    normals(src, tmp_path / "first.las", store=store, keep_store=True, scheduler="synchronous", quiet=True)
    stat = os.stat(src)
    las = laspy.read(src)
    if change == "z":  # the header's bounds change too
        las.z = las.z + 0.5 * (las.x - las.x.min())
    else:  # the header stays as it was: only the records differ
        las.classification = np.where(np.arange(len(las.points)) % 7 == 0, 7, las.classification)  # noise: left out
    las.write(src)
    assert os.stat(src).st_size == stat.st_size
    os.utime(src, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    normals(src, tmp_path / "again.las", store=store, keep_store=True, scheduler="synchronous", quiet=True)
    normals(src, tmp_path / "fresh.las", scheduler="synchronous", quiet=True)
    again, fresh = laspy.read(tmp_path / "again.las"), laspy.read(tmp_path / "fresh.las")
    assert np.array_equal(again.points.array, fresh.points.array)
    assert not np.array_equal(again.points.array, laspy.read(tmp_path / "first.las").points.array)


def test_a_store_recorded_before_the_fingerprint_is_still_its_inputs(scene_las, tmp_path):
    """Stores made before 2026-11-27 record no fingerprint: their input is compared on every other field, so a kept
    store is reused and a finished command still keeps its output (a sweep found them all re-tiled, and the rerun of a
    finished command refused its own output)."""
    import json

    path, _, _ = scene_las
    store = str(tmp_path / "job.zarr")
    out = tmp_path / "out.las"
    normals(path, out, store=store, keep_store=True, scheduler="synchronous", quiet=True)
    meta = tmp_path / "job.zarr" / "zarr.json"
    doc = json.loads(meta.read_text())
    attrs = doc["attributes"]
    for src in attrs["catalog"]["sources"] + ([attrs["source"]] if isinstance(attrs.get("source"), dict) else []):
        src.pop("fingerprint")  # as a store written before the fingerprint
    meta.write_text(json.dumps(doc))
    before = out.stat().st_mtime_ns
    normals(path, out, store=store, keep_store=True, scheduler="synchronous", quiet=True)  # kept: not refused, not rewritten
    assert out.stat().st_mtime_ns == before
    from patchcloud.stream.io.las import LasSource, open_source

    old = json.loads(json.dumps(open_source(path).to_json()))  # as a store gives it back
    old.pop("fingerprint")
    assert open_source(path).same_file(old) and LasSource.from_json(old).fingerprint == 0
