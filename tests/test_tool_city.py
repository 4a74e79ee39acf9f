"""tools/city_las.py: the streaming synthetic city scan (mobile mapping + aerial)."""

import numpy as np
import pytest

laspy = pytest.importorskip("laspy")
import city_las  # tools/ is on sys.path, see conftest.py

N = 200_000
KEYS = ["x", "y", "z", "classification", "object_id", "nx", "ny", "nz", "intensity", "gps_time",
        "point_source_id", "scan_angle"]


def _stream(n, seed=0, chunk=1_000_000):
    chunks = list(city_las.iter_city_chunks(n, seed=seed, chunk=chunk))
    return chunks, {k: np.concatenate([c[k] for c in chunks]) for k in chunks[0]}


@pytest.fixture(scope="module")
def points():
    """The N-point scan, streamed in chunks that do not align with the internal blocks."""
    chunks, pts = _stream(N, chunk=70_000)
    assert [len(c["x"]) for c in chunks] == [70_000, 70_000, 60_000]
    return pts


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("city")
    out = {}
    for suffix in (".las", ".laz"):
        out[suffix] = d / ("city" + suffix)
        assert city_las.write_city(out[suffix], N, seed=0, chunk=90_000) == N
    assert not list(d.glob("*.partial"))
    return out


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_file_has_exact_count_classes_and_extra_dims(files, suffix):
    with laspy.open(files[suffix]) as f:
        assert f.header.are_points_compressed == (suffix == ".laz")
        assert f.header.point_count == N
        assert np.allclose(f.header.scales, 0.001)
        assert np.allclose(f.header.offsets, [650_000, 6_860_000, 0])
    las = laspy.read(files[suffix])
    assert len(las.points) == N
    assert {"ObjectId", "TrueNormalX", "TrueNormalY", "TrueNormalZ"} <= set(las.point_format.extra_dimension_names)
    cls = np.asarray(las.classification)
    present = set(np.unique(cls).tolist())
    assert {city_las.GROUND, city_las.BUILDING, city_las.HIGH_VEGETATION} <= present
    assert present & {city_las.POLE, city_las.CAR}  # the "other" objects
    assert present <= {2, 5, 6, 64, 65}
    n = np.column_stack([las.TrueNormalX, las.TrueNormalY, las.TrueNormalZ]).astype(np.float64)
    norm = np.linalg.norm(n, axis=1)
    defined = norm > 0
    assert np.allclose(norm[defined], 1.0, atol=1e-5)
    assert np.all(cls[~defined] == city_las.HIGH_VEGETATION)  # only foliage has no normal
    oid = np.asarray(las.ObjectId)
    assert np.all((oid == 0) == (cls == city_las.GROUND))
    assert np.all(oid[cls == city_las.BUILDING] % 4 == 1)


def test_las_and_laz_hold_the_points_of_the_stream(files, points):
    a, b = laspy.read(files[".las"]), laspy.read(files[".laz"])
    for dim in ("X", "Y", "Z", "classification", "intensity", "gps_time", "ObjectId", "TrueNormalZ"):
        assert np.array_equal(np.asarray(a[dim]), np.asarray(b[dim])), dim
    assert np.allclose(np.asarray(a.x), points["x"], atol=0.0006)
    assert np.allclose(np.asarray(a.z), points["z"], atol=0.0006)
    assert np.array_equal(np.asarray(a.ObjectId), points["object_id"])


def test_ground_on_the_road_has_an_upward_normal(points):
    x = points["x"] - city_las.ORIGIN[0]
    y = points["y"] - city_las.ORIGIN[1]
    z = points["z"] - city_las.ORIGIN[2]
    ground = points["classification"] == city_las.GROUND
    road_z = city_las.ground_height(x, y)
    w = np.minimum(np.abs(x - np.round(x / 100) * 100), np.abs(y - np.round(y / 100) * 100))
    on_road = ground & (w < city_las.HALF_ROAD - 0.3) & (np.abs(z - road_z) < 0.1)
    assert on_road.sum() > 20_000
    assert np.all(points["nz"][on_road] > 0.999)  # 2 % cross slope: 1.1 degrees
    assert np.mean(points["nz"][ground] > 0.99) > 0.97  # the rest are curb faces
    # surface points lie on their surface: ground within a few sigma of the range noise
    assert np.percentile(np.abs(z[on_road] - road_z[on_road]), 99) < 0.06


def test_chunk_size_does_not_change_the_points(points):
    _, other = _stream(N, chunk=1_000_000)
    for k in KEYS:
        assert np.array_equal(points[k], other[k]), k


def test_a_block_regenerates_on_its_own(points):
    plan = city_las.city_plan(N)
    b = plan.mobile_blocks  # first aerial block; the last mobile block is a short one
    blk = city_las.city_block(N, 0, b)
    start = plan.n_mobile
    assert len(blk["x"]) == plan.n_aerial
    assert np.array_equal(blk["x"], points["x"][start:start + len(blk["x"])])
    blk = city_las.city_block(N, 0, 1)
    assert np.array_equal(blk["gps_time"], points["gps_time"][city_las.BLOCK:2 * city_las.BLOCK])


def test_points_are_in_scan_order(points):
    t = points["gps_time"]
    assert np.all(np.diff(t) >= 0)
    src = points["point_source_id"]
    mobile = src == 1
    assert mobile.sum() == N - round(city_las.AERIAL_SHARE * N)
    assert np.all(mobile[: mobile.sum()]) and np.all(src[mobile.sum():] >= 100)  # the drive, then the flight
    # spatially coherent: consecutive mobile points are close (same or next profile)
    step = np.hypot(np.diff(points["x"][mobile]), np.diff(points["y"][mobile]))
    assert np.median(step) < 5.0


def test_roofs_come_from_the_air_and_facades_from_the_street(points):
    b = points["classification"] == city_las.BUILDING
    mobile = points["point_source_id"] == 1
    assert np.all(np.abs(points["nz"][b & mobile]) < 0.01)  # the street sees walls only
    roofs = b & ~mobile & (points["nz"] > 0.5)
    assert roofs.sum() > 1000


@pytest.mark.parametrize("n", [0, 1, 12_345, city_las.BLOCK + 1])
def test_exact_count_for_any_size(n):
    got = sum(len(c["x"]) for c in city_las.iter_city_chunks(n, seed=3, chunk=5_000))
    assert got == n


def test_city_grows_with_the_point_count_at_the_same_density():
    small, big = city_las.city_plan(5_000_000), city_las.city_plan(100_000_000)
    assert big.trajectory_length == pytest.approx(20 * small.trajectory_length)
    assert big.grid > small.grid

    def area(p):
        x0, x1, y0, y1 = p.region
        return (x1 - x0) * (y1 - y0)

    assert big.n_aerial / area(big) == pytest.approx(small.n_aerial / area(small), rel=0.3)


def test_seed_changes_the_city():
    a = city_las.city_block(N, 0, 0)
    b = city_las.city_block(N, 1, 0)
    assert len(a["x"]) == len(b["x"]) and not np.array_equal(a["z"], b["z"])


def test_cli_writes_laz_and_prints_a_summary(tmp_path, capsys):
    out = tmp_path / "c.laz"
    assert city_las.main([str(out), "--points", "30000", "--chunk", "7000"]) == 0
    line = capsys.readouterr().out.strip()
    assert "30,000 points" in line and "bytes" in line and line.count("\n") == 0
    assert len(laspy.read(out).points) == 30_000
    assert not list(tmp_path.glob("*.partial"))


def test_failed_write_leaves_no_file(tmp_path, monkeypatch):
    monkeypatch.setattr(city_las, "iter_city_chunks", _failing_after_first_chunk(city_las.iter_city_chunks))
    out = tmp_path / "c.las"
    with pytest.raises(RuntimeError, match="disk on fire"):
        city_las.write_city(out, 20_000, chunk=5_000)
    assert not out.exists() and not list(tmp_path.glob("*.partial"))


def _failing_after_first_chunk(gen):
    def wrapped(*args, **kwargs):
        it = gen(*args, **kwargs)
        yield next(it)
        raise RuntimeError("disk on fire")

    return wrapped
