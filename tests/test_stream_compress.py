"""``patchcloud compress`` / ``decompress``: LAS -> .pcz -> LAS, out of core."""

from pathlib import Path

import laspy
import numpy as np
import pytest
from click.testing import CliRunner
from laspy.vlrs.vlrlist import VLRList

from patchcloud.core.errors import PatchcloudExistsError, PatchcloudIOError, PatchcloudValueError
from patchcloud.stream import compress, decompress
from patchcloud.stream.cli import main
from patchcloud.stream.io.point_coding import coarse_steps
from patchcloud.stream.io import pcz
from patchcloud.stream.io.pcz import open_pcz

OFFSET = np.array([650000.0, 6860000.0, 0.0])
BUDGET = 0.02


def scene(rng):
    """Ground (class 2), a 4 m box-shaped building (class 6) on it, and a noisy bush (class 5): 46k points."""
    g = rng.uniform(0, 16, (30000, 2))
    g = g[~((g[:, 0] > 4) & (g[:, 0] < 8) & (g[:, 1] > 4) & (g[:, 1] < 8))]
    ground = np.column_stack([g, np.zeros(len(g))])
    walls = []
    for axis in (0, 1):
        for s in (4.0, 8.0):
            q = np.column_stack([rng.uniform(4, 8, 2000), rng.uniform(4, 8, 2000), rng.uniform(0, 4, 2000)])
            q[:, axis] = s
            walls.append(q)
    roof = np.column_stack([rng.uniform(4, 8, (3000, 2)), np.full(3000, 4.0)])
    bush = rng.normal([12.0, 12.0, 1.0], 0.6, (4000, 3))
    pts = np.vstack([ground, *walls, roof, bush])
    cls = np.concatenate([np.full(len(ground), 2), np.full(8000 + 3000, 6), np.full(4000, 5)]).astype(np.uint8)
    return pts, cls


@pytest.fixture(scope="module")
def las_file(tmp_path_factory):
    rng = np.random.default_rng(5)
    pts, cls = scene(rng)
    perm = rng.permutation(len(pts))
    pts, cls = pts[perm], cls[perm]
    h = laspy.LasHeader(point_format=6, version="1.4")
    h.scales = [0.001] * 3
    h.offsets = OFFSET
    h.add_extra_dims([laspy.ExtraBytesParams(name="Deviation", type=np.float32)])
    las = laspy.LasData(h)
    las.x, las.y, las.z = pts[:, 0] + OFFSET[0], pts[:, 1] + OFFSET[1], pts[:, 2]
    las.classification = cls
    las.intensity = rng.integers(0, 4000, len(pts))
    las.gps_time = np.sort(rng.uniform(0, 1000, len(pts)))
    las["Deviation"] = rng.normal(size=len(pts)).astype(np.float32)
    path = tmp_path_factory.mktemp("pcz") / "scene.las"
    las.write(path)
    return path


def rows(points):
    a = points.array
    return np.ascontiguousarray(a).view(np.dtype((np.void, a.dtype.itemsize)))


def coded(src, k, shift):
    """(N, L) uint8: what model mode gives back of each point of ``src`` were it residual in a tile of intensity ``shift``:
    X, Y, Z rounded to multiples ``k`` of the file's grid, the class, the intensity rounded to a multiple of 2**shift
    (at most 65535), return 1 of 1, every other byte zero."""
    want = laspy.PackedPointRecord.zeros(len(src.points), src.point_format)
    want["classification"] = src.points["classification"]
    I = np.asarray(src.points["intensity"], dtype=np.int64)
    want["intensity"] = np.minimum(((I + (1 << shift >> 1)) >> shift) << shift, 65535)
    want["return_number"] = want["number_of_returns"] = np.ones(len(src.points), np.uint8)
    for a, name in enumerate("XYZ"):
        X = np.asarray(src.points[name], dtype=np.int64)
        want[name] = (X + k[a] // 2) // k[a] * k[a]
    return np.ascontiguousarray(want.array.view(np.uint8).reshape(len(src.points), -1))


def test_round_trip(las_file, tmp_path):
    src = laspy.read(las_file)
    s = compress(las_file, tmp_path / "s.pcz", max_error=BUDGET, tile_size=8.0, scheduler="synchronous", quiet=True)
    assert s.points == len(src.points) and 0 < s.residual < s.points and s.patches > 0
    # a handful of patches: ground, four walls and a roof, cut by the 8 m tiles (the box stands on 4 of them)
    assert s.patches <= 14
    assert s.mean_error <= BUDGET
    d = decompress(tmp_path / "s.pcz", tmp_path / "back.laz")
    out = laspy.read(tmp_path / "back.laz")
    assert len(out.points) == len(src.points)  # every point: a sample of its patch or itself
    rec = np.asarray(out["Reconstructed"])
    assert int((rec == 0).sum()) == s.residual == d.residual
    # residual points come back as records of input points with X, Y, Z rounded to multiples k of the file's grid
    # (within the budget), their class, their intensity on 64 levels of their tile's, one return, every other byte zero
    L = src.points.array.dtype.itemsize
    back = np.ascontiguousarray(out.points.array.view(np.uint8).reshape(len(out.points), -1)[rec == 0, :L])
    k = coarse_steps(BUDGET, src.header.scales)
    assert k == (23, 23, 23)  # the file's grid is 1 mm: 2.3 cm steps, 2 cm at most from each point
    with open_pcz(tmp_path / "s.pcz") as f:
        shifts = set(f.intensity_shift.tolist())
    # intensities of 0-4000 (12 bits) on 64 levels: multiples of 2**6 (a tile of a few dim points: finer)
    assert 6 in shifts and min(shifts) >= 1
    # sampled points carry their cell's mean intensity on the tile's 64 levels (means of uniform 0-4000: about 2000)
    sampled = np.asarray(out.intensity)[rec == 1].astype(np.int64)
    assert np.all(sampled % (1 << min(shifts)) == 0) and abs(sampled.mean() - np.asarray(src.intensity).mean()) < 64
    v = np.dtype((np.void, L))
    orig = np.concatenate([coded(src, k, sh) for sh in shifts])
    assert np.isin(back.view(v).ravel(), orig.view(v).ravel()).all()
    mine = laspy.PackedPointRecord(back.view(src.point_format.dtype()).ravel(), src.point_format)
    assert set(np.asarray(mine["return_number"])) == set(np.asarray(mine["number_of_returns"])) == {1}  # one return each
    assert {5, 6} <= set(np.asarray(mine["classification"]).tolist())  # the bush's class and the box edges', not zeros
    # the bush is residual; the sampled points lie on the ground, the walls and the roof
    xyz = np.column_stack([out.x, out.y, out.z]) - OFFSET
    s_xyz = xyz[rec == 1]
    ground = np.abs(s_xyz[:, 2])
    roof = np.abs(s_xyz[:, 2] - 4.0)
    walls = np.min(np.abs(s_xyz[:, :2, None] - np.array([4.0, 8.0])).reshape(-1, 4), axis=1)
    inside_box = np.all((s_xyz[:, :2] >= 4 - BUDGET) & (s_xyz[:, :2] <= 8 + BUDGET), axis=1)
    dist = np.where(inside_box, np.minimum(roof, walls), ground)
    assert dist.mean() <= BUDGET and np.percentile(dist, 95) <= 2 * BUDGET
    cls = np.asarray(out.classification)
    assert np.mean(cls[rec == 1][(s_xyz[:, 2] < 0.05) & ~inside_box] == 2) > 0.99  # patches carry their majority class
    assert np.mean(rec[cls == 5] == 0) > 0.9  # the bush (a volume, 0.6 m of scatter) stays points


def test_levels_of_detail_density_and_region(las_file, tmp_path):
    compress(las_file, tmp_path / "s.pcz", max_error=BUDGET, tile_size=8.0, scheduler="synchronous", quiet=True)
    full = decompress(tmp_path / "s.pcz", tmp_path / "full.las")
    lod1 = decompress(tmp_path / "s.pcz", tmp_path / "lod1.las", lod=1)
    assert lod1.residual == full.residual
    assert 0.2 < lod1.reconstructed / full.reconstructed < 0.3
    dense = decompress(tmp_path / "s.pcz", tmp_path / "dense.las", density=400.0)
    assert dense.reconstructed > full.reconstructed  # the scene has about 100 points per square metre
    box = (OFFSET[0] + 0, OFFSET[1] + 0, -1.0, OFFSET[0] + 3.0, OFFSET[1] + 3.0, 10.0)
    decompress(tmp_path / "s.pcz", tmp_path / "part.las", bbox=box)
    las = laspy.read(tmp_path / "part.las")
    assert 0 < len(las.points) < 0.1 * (full.reconstructed + full.residual)
    assert np.all((las.x >= box[0]) & (las.x <= box[3]) & (las.y >= box[1]) & (las.y <= box[4]))
    again = decompress(tmp_path / "s.pcz", tmp_path / "full2.las")
    assert (tmp_path / "full.las").read_bytes() == (tmp_path / "full2.las").read_bytes() and again.residual == full.residual


def test_cli_and_bad_input(las_file, tmp_path):
    r = CliRunner().invoke(main, ["compress", str(las_file), str(tmp_path / "c.pcz"), "--max-error", "0.05",
                                  "--scheduler", "synchronous", "--tile-size", "8"])
    assert r.exit_code == 0, r.output
    assert "bits/point" in r.output
    tiles = [line for line in r.output.splitlines() if line.strip().startswith("tiles ")]  # as normals' summary says it
    assert len(tiles) == 1 and tiles[0].split()[1:] == [str(len(compress_store_tiles(las_file))), "of", "8", "m"], tiles
    r = CliRunner().invoke(main, ["decompress", str(tmp_path / "c.pcz"), str(tmp_path / "c.laz"), "--lod", "1", "-q"])
    assert r.exit_code == 0 and (tmp_path / "c.laz").exists()
    r = CliRunner().invoke(main, ["decompress", str(las_file), str(tmp_path / "x.las")])
    assert r.exit_code == 2 and r.output.startswith("error:") and "not a patchcloud .pcz" in r.output
    assert not (tmp_path / "x.las").exists()
    r = CliRunner().invoke(main, ["compress", str(las_file), str(tmp_path / "y.pcz"), "--max-error", "-1", "-q"])
    assert r.exit_code == 2 and "--max-error must be a positive length" in r.output
    assert not (tmp_path / "y.pcz").exists() and not (tmp_path / "y.pcz.store").exists()
    with pytest.raises(PatchcloudValueError, match="density=10.0 and lod=1: give one of them, not both"):
        decompress(tmp_path / "c.pcz", tmp_path / "z.las", density=10.0, lod=1)
    with pytest.raises(PatchcloudValueError, match="bbox must be"):
        decompress(tmp_path / "c.pcz", tmp_path / "z.las", bbox=(1, 1, 1, 0, 0, 0))
    with pytest.raises(PatchcloudIOError, match="exists"):
        decompress(tmp_path / "c.pcz", tmp_path / "c.laz")


def test_info_describes_a_pcz(las_file, tmp_path):
    compress(las_file, tmp_path / "s.pcz", max_error=BUDGET, tile_size=8.0, scheduler="synchronous", quiet=True)
    r = CliRunner().invoke(main, ["info", str(tmp_path / "s.pcz")])
    assert r.exit_code == 0 and f"patchcloud .pcz version {pcz.VERSION} (model mode)" in r.output and "residual" in r.output
    whole = (tmp_path / "s.pcz").read_bytes()
    (tmp_path / "cut.pcz").write_bytes(whole[: len(whole) // 2])  # no zip directory left: still a .pcz, truncated
    (tmp_path / "cut.bin").write_bytes(whole[: len(whole) // 2])  # whatever its name
    for name in ("cut.pcz", "cut.bin"):
        r = CliRunner().invoke(main, ["info", str(tmp_path / name)])
        assert r.exit_code == 2 and "not a patchcloud .pcz file (not a zip archive; truncated?)" in r.output, r.output


@pytest.mark.parametrize("drop", ["NumberOfReturns", "ReturnNumber", "Intensity,Classification"])
def test_what_model_mode_keeps_of_a_residual_point_is_what_it_says(las_file, tmp_path, drop):
    """Either return field dropped drops both (return 1 of 0 is no point); the summary and info say what is kept and
    what is zero, and the decompressed residual points are so (found by a sweep of 2026-11-27: 'one return' said of
    points of return 1 of 0)."""
    s = compress(las_file, tmp_path / "s.pcz", max_error=BUDGET, tile_size=8.0, scheduler="synchronous", quiet=True,
                 drop=drop.split(","))
    returns = "NumberOfReturns" in drop or "ReturnNumber" in drop
    assert ({"return_number", "number_of_returns"} <= set(s.dropped)) == returns
    text = s.format()
    info = CliRunner().invoke(main, ["info", str(tmp_path / "s.pcz")]).output
    assert ("return 1 of 1" in text) == ("return 1 of 1" in info) == (not returns)
    assert ("class exact" in text) == ("class exact" in info) == ("Classification" not in drop)
    decompress(tmp_path / "s.pcz", tmp_path / "back.las")
    out = laspy.read(tmp_path / "back.las")
    res = np.asarray(out["Reconstructed"]) == 0
    assert res.sum() == s.residual > 0
    rn, nr = np.asarray(out.return_number)[res], np.asarray(out.number_of_returns)[res]
    assert set(rn) == set(nr) == ({0} if returns else {1})
    for points in (res, ~res):  # the residual points' own, and the cells' that the sampled points carry
        assert (set(np.asarray(out.intensity)[points]) == {0}) == ("Intensity" in drop)
        assert (set(np.asarray(out.classification)[points]) == {0}) == ("Classification" in drop)


def test_header_vlrs_and_extended_vlrs_survive(tmp_path):
    rng = np.random.default_rng(1)
    xy = rng.uniform(0, 10, (5000, 2))
    h = laspy.LasHeader(point_format=6, version="1.4")
    h.scales, h.offsets = [0.001] * 3, OFFSET
    h.vlrs.append(laspy.VLR(user_id="patchcloud-test", record_id=7, description="a VLR", record_data=b"vlr bytes"))
    las = laspy.LasData(h)
    las.x, las.y, las.z = xy[:, 0] + OFFSET[0], xy[:, 1] + OFFSET[1], 0.05 * xy[:, 0]
    las.evlrs = VLRList([laspy.VLR(user_id="patchcloud-test", record_id=8, description="an EVLR", record_data=b"e" * 70000)])
    las.write(tmp_path / "e.las")
    compress(tmp_path / "e.las", tmp_path / "e.pcz", max_error=0.01, scheduler="synchronous", quiet=True)
    decompress(tmp_path / "e.pcz", tmp_path / "back.las")
    with laspy.open(tmp_path / "back.las") as r:
        back = r.read()
    assert [(v.user_id, v.record_id, bytes(v.record_data)) for v in back.header.vlrs if v.user_id == "patchcloud-test"] == [
        ("patchcloud-test", 7, b"vlr bytes")]
    assert [(v.user_id, v.record_id, bytes(v.record_data)) for v in back.evlrs] == [("patchcloud-test", 8, b"e" * 70000)]
    assert len(back.points) == 5000


def test_the_same_input_gives_the_same_pcz_bytes_wherever_and_whenever_it_is(tmp_path):
    """Reproducible .pcz: entries dated ZIP_TIME in name order; the input recorded by its name, its path only when asked."""
    import os
    import shutil
    import time
    import zipfile

    import zarr
    from test_stream import write_scene
    from zarr.storage import ZipStore

    from patchcloud.stream.io.pcz import ZIP_TIME

    a = tmp_path / "a" / "scene.las"
    a.parent.mkdir()
    write_scene(a, n=20_000, seed=11)
    b = tmp_path / "b" / "scene.las"
    b.parent.mkdir()
    shutil.copyfile(a, b)
    os.utime(b, (time.time() - 3600, time.time() - 3600))
    compress(a, tmp_path / "one.pcz", max_error=0.02, quiet=True)
    time.sleep(2.1)  # another zip time stamp, were it the clock's
    compress(b, tmp_path / "two.pcz", max_error=0.02, scheduler="synchronous", quiet=True)
    assert (tmp_path / "one.pcz").read_bytes() == (tmp_path / "two.pcz").read_bytes()
    with zipfile.ZipFile(tmp_path / "one.pcz") as z:
        names = [i.filename for i in z.infolist()]
        assert names == sorted(names) and {i.date_time for i in z.infolist()} == {ZIP_TIME}
    src = dict(zarr.open_group(ZipStore(str(tmp_path / "one.pcz"), mode="r"), mode="r").attrs)["source"]
    assert src["path"] == "scene.las" and "mtime_ns" not in src
    compress(a, tmp_path / "three.pcz", max_error=0.02, quiet=True, record_source=True)
    src = dict(zarr.open_group(ZipStore(str(tmp_path / "three.pcz"), mode="r"), mode="r").attrs)["source"]
    assert src["path"] == str(a.resolve()) and src["mtime_ns"] == a.stat().st_mtime_ns


def test_sampled_points_stay_within_the_inputs_bounds_and_are_single_returns(tmp_path):
    """The embedded IGN tile, cut at the file's border: at 20 cm, mask cells of its edge patches reached up to 0.35 m
    past it, and sampled points were written there, with return number 0, which LAS does not allow (a sweep of
    2026-11-26)."""
    from pathlib import Path

    src = Path(__file__).resolve().parents[1] / "data" / "test_data_77055_627760_LA93_IGN69.laz"
    compress(src, tmp_path / "t.pcz", max_error=0.2, quiet=True)
    decompress(tmp_path / "t.pcz", tmp_path / "t.las")
    inp, out = laspy.open(str(src)).header, laspy.read(str(tmp_path / "t.las"))
    sampled = np.asarray(out.Reconstructed) == 1
    assert sampled.sum() > 10_000
    xyz = np.column_stack([out.x, out.y, out.z])[sampled]
    assert np.all(xyz >= np.asarray(inp.mins) - 1e-9) and np.all(xyz <= np.asarray(inp.maxs) + 1e-9)
    assert np.all(np.asarray(out.return_number)[sampled] == 1) and np.all(np.asarray(out.number_of_returns)[sampled] == 1)
    assert int(np.sum(out.header.number_of_points_by_return)) == len(out.points)


def test_a_box_gets_the_residual_points_rounded_past_their_tiles_face(las_file, tmp_path):
    """A residual point's coded position is rounded (moved by up to the budget) and may cross its tile's face: a box
    beyond the face, not meeting that tile, still gets it, as the whole file's decompression puts it there."""
    T, e = 4.0, 0.5  # a coarse budget: rounding to ~0.58 m moves many bush points across x = 12, the bush's middle
    compress(las_file, tmp_path / "c.pcz", max_error=e, tile_size=T, scheduler="synchronous", quiet=True)
    decompress(tmp_path / "c.pcz", tmp_path / "full.las")
    full = laspy.read(tmp_path / "full.las")
    fx = np.asarray(full.x) - OFFSET[0]
    residual = np.asarray(full.Reconstructed) == 0
    for face in (4.0, 8.0, 12.0):
        for lo, hi in ((face + 1e-6, face + 0.3), (face - 0.3, face - 1e-6)):  # on one side: it meets one tile only
            box = (OFFSET[0] + lo, OFFSET[1] - 1, -10.0, OFFSET[0] + hi, OFFSET[1] + 20, 20.0)
            decompress(tmp_path / "c.pcz", tmp_path / "box.las", bbox=box, overwrite=True)
            part = laspy.read(tmp_path / "box.las")
            want = residual & (fx >= lo) & (fx <= hi)
            got = np.asarray(part.Reconstructed) == 0
            assert got.sum() == want.sum(), (face, lo, hi)
    assert decompress(tmp_path / "c.pcz", tmp_path / "lod.las", lod=40).reconstructed > 0  # past MAX_LOD: one point a cell


def test_sampled_points_outside_their_tile_or_not_finite_are_a_damaged_file():
    from patchcloud.stream.jobs.decompress import TILE_SLACK, check_in_tile

    ijk, t = np.array([1, 0, 2]), 8.0  # the tile [8, 16] x [0, 8] x [16, 24]
    inside = np.array([[8.0, 0.0, 16.0], [16.0, 8.0, 24.0], [12.0, 4.0, 20.0]])
    check_in_tile("x.pcz", inside, ijk, t)
    check_in_tile("x.pcz", inside[:0], ijk, t)
    check_in_tile("x.pcz", inside - TILE_SLACK * t * 0.99, ijk, t)  # within the slack
    for bad in ([np.nan, 4.0, 20.0], [12.0, -TILE_SLACK * t * 1.01, 20.0], [12.0, 4.0, np.inf]):
        with pytest.raises(PatchcloudIOError, match=r"x.pcz: damaged .pcz file \(tile t\+1\+0\+2's patches put 2 points outside it\)"):
            check_in_tile("x.pcz", np.vstack([inside, [bad, bad]]), ijk, t)


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_a_budget_up_to_the_tile_size_round_trips_and_a_larger_one_is_refused_before_any_work(tmp_path):
    """--max-error as large as the tiles writes a .pcz that decompresses, every point within the budget of the
    surfaces (decompress took a budget of half the tile size for damage); larger, the reader would refuse the file:
    one error line naming both options, nothing written (it wrote the .pcz and said it was fine)."""
    import os

    sample = os.path.join(os.path.dirname(__file__), "..", "data", "test_data_77055_627760_LA93_IGN69.laz")
    for tile, budget in ((8, 4.0), (8, 8.0)):
        p = tmp_path / f"t{tile}-{budget:g}.pcz"
        r = CliRunner().invoke(main, ["compress", sample, str(p), "--tile-size", str(tile), "--max-error", str(budget), "-q"])
        assert r.exit_code == 0, r.output
        r = CliRunner().invoke(main, ["decompress", str(p), str(tmp_path / f"d{tile}-{budget:g}.laz"), "-q"])
        assert r.exit_code == 0, r.output
        assert laspy.read(tmp_path / f"d{tile}-{budget:g}.laz").header.point_count > 0
    before = sorted(tmp_path.iterdir())
    for args, says in [(["--tile-size", "8", "--max-error", "8.5"], "--tile-size of at least 16"),
                       (["--max-error", "1000"], "--max-error 1000 is larger than the tiles")]:
        r = CliRunner().invoke(main, ["compress", sample, str(tmp_path / "x.pcz"), *args, "-q"])
        assert r.exit_code == 2 and r.output.count("\n") == 1 and says in r.output, r.output
        assert sorted(tmp_path.iterdir()) == before


def test_a_pcz_renamed_into_place_before_its_store_was_removed_is_the_same_commands_to_finish(las_file, tmp_path):
    """A single-file ``compress`` killed between renaming its ``.pcz`` into place and removing its store: the same
    command said the ``.pcz`` exists and left the store (bug hunt E).  Kept here by ``keep_store`` (what the killed
    run leaves): the same command without it finishes, the same bytes, and removes the store."""
    out = tmp_path / "c.pcz"
    kw = dict(max_error=0.05, tile_size=16, quiet=True, in_memory=False)
    compress(las_file, out, keep_store=True, **kw)
    first = out.read_bytes()
    assert (tmp_path / "c.pcz.store").is_dir()
    compress(las_file, out, **kw)
    assert out.read_bytes() == first and sorted(p.name for p in tmp_path.iterdir()) == ["c.pcz"]
    with pytest.raises(PatchcloudExistsError):  # a .pcz the store does not record is still not replaced
        compress(las_file, out, **kw)


def compress_store_tiles(path) -> list:
    """The tiles of ``path`` cut in 8 m tiles (what compress's summary counts)."""
    from patchcloud.stream import tile

    return tile(path, str(Path(path).with_suffix(".tiles.zarr")), tile_size=8, scheduler="synchronous", quiet=True, overwrite=True).tiles
