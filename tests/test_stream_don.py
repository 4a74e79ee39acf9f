"""``patchcloud don`` / ``segment``: tile-wise DoN equal to the whole-cloud DoN, segments across tile faces, the CLI."""

import laspy
import numpy as np
import pytest
from click.testing import CliRunner

from patchcloud.core import difference_of_normals, segment_don
from patchcloud.core.errors import PatchcloudIOError, PatchcloudValueError
from patchcloud.stream import Store, don, segment
from patchcloud.stream.cli import main
from patchcloud.core.radius import cell_density, uses_voxels
from patchcloud.stream.jobs.don import cloud_density, default_viewpoint_of
from patchcloud.stream.io.las import open_source

OFFSET = np.array([770496.0, 6277504.0, 30.0])  # Lambert-93-sized; tile faces fall on whole metres of the local frame


def street(rng, spacing=0.1):
    """A 10 x 10 m street: ground with a 0.15 m kerb at y = 6, three poles, one of them across x = 4 and x = 8."""
    g = np.arange(0, 10, spacing)
    gx, gy = np.meshgrid(g, g)
    x, y = gx.ravel() + rng.uniform(0, spacing / 3, gx.size), gy.ravel() + rng.uniform(0, spacing / 3, gx.size)
    ground = np.column_stack([x, y, np.where(y > 6.0, 0.15, 0.0)])
    kerb_y = np.arange(0, 10, spacing / 2)
    kz = np.arange(spacing / 2, 0.15, spacing / 2)
    ky, kzz = np.meshgrid(kerb_y, kz)
    kerb = np.column_stack([ky.ravel(), np.full(ky.size, 6.0), kzz.ravel()])
    poles = []
    for cx, cy in [(8.0, 2.0), (2.5, 3.0), (4.0, 8.5)]:
        th = np.arange(0, 2 * np.pi, spacing / 0.1 / 2)
        z = np.arange(spacing, 2.5, spacing / 2)
        tt, zz = np.meshgrid(th, z)
        base = 0.15 if cy > 6 else 0.0
        poles.append(np.column_stack([cx + 0.1 * np.cos(tt.ravel()), cy + 0.1 * np.sin(tt.ravel()), base + zz.ravel()]))
    pts = np.vstack([ground, kerb, *poles])
    label = np.concatenate([np.zeros(len(ground) + len(kerb), int)] + [np.full(len(p), k + 1) for k, p in enumerate(poles)])
    perm = rng.permutation(len(pts))
    return pts[perm] + OFFSET, label[perm]


def write_las(path, pts, extra=None):
    h = laspy.LasHeader(point_format=6, version="1.4")
    h.scales = [0.001] * 3
    h.offsets = OFFSET
    las = laspy.LasData(h)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    las.intensity = np.arange(len(pts)) % 65535
    las.write(path)
    return laspy.read(path)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    rng = np.random.default_rng(7)
    pts, label = street(rng)
    path = tmp_path_factory.mktemp("don") / "street.las"
    las = write_las(path, pts)
    xyz = np.column_stack([las.X, las.Y, las.Z])  # the stored integers
    return path, xyz, label


def local_frame(path, xyz):
    """The stream's local frame, to the last bit: X * scale + (offset - origin), origin a multiple of 4096 m."""
    src = open_source(path)
    origin = np.floor(np.asarray(src.mins) / 4096.0) * 4096.0
    return xyz.astype(np.float64) * np.asarray(src.scale) + (np.asarray(src.offset) - origin), origin


def store_don(store_path, local):
    """Every point's float64 DoN as the tiles stored it, in input order."""
    st = Store.open(str(store_path), mode="r")
    T = st.grid.tile_size
    tile = np.floor(local / T).astype(np.int64)
    out = np.full(local.shape, np.inf)
    for ijk in st.tiles:
        rows = np.flatnonzero(np.all(tile == ijk, axis=1))  # the tile's points in input order
        out[rows] = st.read(ijk, "don")
    return out


@pytest.mark.parametrize("mode", ["exact", "fast"])
def test_tilewise_don_equals_the_whole_cloud_whatever_the_tile_size(scene, tmp_path, mode):
    path, xyz, _ = scene
    local, origin = local_frame(path, xyz)
    vp = default_viewpoint_of(open_source(path))
    whole = difference_of_normals(local, 0.3, 1.5, viewpoint=vp - origin, mode=mode, grid_step=0.001)  # the file's grid
    assert np.isfinite(whole).all(axis=1).mean() > 0.99
    for T in (2.0, 4.0, 16.0):
        st = tmp_path / f"s{T:g}.zarr"
        don(path, tmp_path / f"d{T:g}.las", r_small=0.3, r_large=1.5, mode=mode, tile_size=T, store=str(st),
            scheduler="synchronous", quiet=True)
        tiled = store_don(st, local)
        if mode == "fast":  # the file's density, from the tiles' occupancy, is the one a whole-cloud run measures
            for edge in (0.075, 0.375):
                assert cloud_density(Store.open(str(st)), edge) == pytest.approx(cell_density(local, edge), rel=1e-12)
            assert not uses_voxels(0.3, 4, cell_density(local, 0.075)) and uses_voxels(1.5, 4, cell_density(local, 0.375))
        assert np.array_equal(np.isnan(tiled), np.isnan(whole))
        ok = np.isfinite(whole)
        assert np.abs(tiled[ok] - whole[ok]).max() <= 1e-9, T


@pytest.mark.slow  # 10-20 s: with the slow marker, so the default suite stays under 10 minutes
def test_segments_equal_the_whole_cloud_and_cross_tile_faces(scene, tmp_path):
    path, xyz, label = scene
    local, origin = local_frame(path, xyz)
    vp = default_viewpoint_of(open_source(path)) - origin
    whole = segment_don(local, difference_of_normals(local, 0.3, 1.5, viewpoint=vp, grid_step=0.001), 0.2, 0.15, min_points=30,
                        grid_step=0.001)  # the file's grid
    ids = {}
    for T in (2.0, 4.0, 16.0):
        out = tmp_path / f"seg{T:g}.laz"
        s = segment(path, out, r_small=0.3, r_large=1.5, threshold=0.2, tolerance=0.15, min_cluster=30, tile_size=T,
                    scheduler="threads" if T == 4.0 else "synchronous", workers=2, quiet=True)
        las = laspy.read(out)
        ids[T] = np.asarray(las["ClusterID"], dtype=np.int64)
        assert s.segments == whole.max()
        np.testing.assert_array_equal(las.intensity, np.arange(len(xyz)) % 65535)  # input order, dims kept
    for T, got in ids.items():
        np.testing.assert_array_equal(got, whole, err_msg=f"tile size {T}")
    # the pole at (8, 2) stands across faces of tiles of 2, 4 and 8 m: one segment, and its own
    for pole in (1, 2, 3):
        z = local[:, 2] - (OFFSET[2] - origin[2])
        on = (label == pole) & (z > 0.4) & (z < 1.2)
        found = ids[2.0][on]
        assert (found > 0).mean() > 0.5 and len(np.unique(found[found > 0])) == 1
    assert len({int(np.max(ids[2.0][label == p])) for p in (1, 2, 3)}) == 3  # three poles, three segments


def test_threshold_on_one_axis_keeps_the_kerb(scene, tmp_path):
    path, xyz, label = scene
    local, origin = local_frame(path, xyz)
    y = local[:, 1] - (OFFSET[1] - origin[1])
    out = tmp_path / "kerb.las"
    s = segment(path, out, r_small=0.15, r_large=1.0, threshold=0.05, axis="y", axis_threshold=0.05, tolerance=0.15,
                min_cluster=20, tile_size=4.0, scheduler="synchronous", quiet=True)
    las = laspy.read(out)
    seg = np.asarray(las["ClusterID"], dtype=np.int64)
    near_kerb = (label == 0) & (np.abs(y - 6.0) < 0.2)
    x = local[:, 0] - (OFFSET[0] - origin[0])
    from_poles = np.min([np.hypot(x - cx, y - cy) for cx, cy in [(8.0, 2.0), (2.5, 3.0), (4.0, 8.5)]], axis=0)
    far = (label == 0) & (np.abs(y - 6.0) > 1.5) & (from_poles > 1.5)
    assert (seg[near_kerb] > 0).mean() > 0.5
    assert (seg[far] == 0).all()
    dy = np.asarray(las["DoNY"])
    assert np.all(np.abs(dy[seg > 0]) >= 0.05 - 1e-6)
    assert s.kept is not None and s.kept > 0


def test_don_dims_and_undefined_points(tmp_path):
    rng = np.random.default_rng(3)
    g = np.arange(0, 6, 0.2)
    gx, gy = np.meshgrid(g, g)
    plane = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    lonely = np.array([[3.0, 3.0, 40.0]])  # nothing within r_s: undefined
    pts = np.vstack([plane, lonely])[rng.permutation(len(plane) + 1)] + OFFSET
    path = tmp_path / "p.las"
    write_las(path, pts)
    # 2 m tiles: the lonely point is a tile of its own, with nothing kept and no neighbour
    s = don(path, tmp_path / "o.las", r_small=0.5, r_large=1.5, tile_size=2.0, scheduler="synchronous", quiet=True)
    assert s.tiles == 10
    las = laspy.read(tmp_path / "o.las")
    m = np.asarray(las["DoN"])
    lonely_row = np.argmax(las.z)
    undefined = [las[d][lonely_row] for d in ("DoN", "DoNX", "DoNY", "DoNZ")]
    assert undefined == [0.0] * 4  # undefined: 0 in all four, the declared no-data value; no NaN in the file
    assert not np.isnan(np.column_stack([las[d] for d in ("DoN", "DoNX", "DoNY", "DoNZ")])).any()
    others = np.delete(np.arange(len(m)), lonely_row)
    assert np.max(np.abs(m[others])) < 1e-6  # a plane: zero
    assert s.defined == len(pts) - 1
    structs = [e for v in las.header.vlrs if hasattr(v, "extra_bytes_structs") for e in v.extra_bytes_structs]
    declared = {e.name.decode(): e.no_data for e in structs}
    assert all(declared[d][0] == 0.0 for d in ("DoN", "DoNX", "DoNY", "DoNZ"))
    g = segment(path, tmp_path / "g.las", r_small=0.5, r_large=1.5, threshold=0.1, tolerance=0.3, min_cluster=1,
                tile_size=2.0, scheduler="synchronous", quiet=True)
    assert g.kept == 0 and g.segments == 0
    assert not np.asarray(laspy.read(tmp_path / "g.las")["ClusterID"]).any()


@pytest.mark.slow  # 7 s
def test_resume_reuses_the_store(scene, tmp_path):
    path, _, _ = scene
    st = tmp_path / "keep.zarr"
    kw = dict(r_small=0.3, r_large=1.5, threshold=0.2, tolerance=0.15, min_cluster=30, tile_size=4.0, store=str(st),
              scheduler="synchronous", quiet=True)
    segment(path, tmp_path / "a.las", **kw)
    s = Store.open(str(st))
    marks = {t: s.tile_attrs(t)["done"]["don"] for t in s.tiles}
    for t in s.tiles:  # a rerun must not recompute a finished tile: poison one array and see it survive
        s.write(t, "keep", s.read(t, "keep"))
    first = s.tiles[0]
    s.write(first, "don", np.full_like(s.read(first, "don"), 0.5))
    segment(path, tmp_path / "b.las", **kw)
    assert np.all(Store.open(str(st)).read(first, "don") == 0.5)
    assert {t: Store.open(str(st)).tile_attrs(t)["done"]["don"] for t in s.tiles} == marks
    segment(path, tmp_path / "c.las", **{**kw, "r_large": 1.6})  # new parameters: recomputed
    assert not np.all(Store.open(str(st)).read(first, "don") == 0.5)


def test_cli_don_and_segment(scene, tmp_path):
    path, xyz, _ = scene
    r = CliRunner().invoke(main, ["segment", str(path), str(tmp_path / "s.laz"), "--rs", "0.3", "--rl", "1.5",
                                  "--threshold", "0.2", "--tolerance", "0.15", "--min-points", "30", "--mode", "fast",
                                  "--scheduler", "synchronous", "--tile-size", "4"])
    assert r.exit_code == 0, r.output
    assert "segments" in r.output
    las = laspy.read(tmp_path / "s.laz")
    assert {"DoN", "DoNX", "DoNY", "DoNZ", "ClusterID"} <= set(las.point_format.extra_dimension_names)
    assert np.asarray(las["ClusterID"]).max() >= 3
    r = CliRunner().invoke(main, ["don", str(path), str(tmp_path / "d.las"), "--scheduler", "synchronous", "-q"])
    assert r.exit_code == 0, r.output
    m = np.asarray(laspy.read(tmp_path / "d.las")["DoN"])
    assert np.nanmax(m) <= 1 and np.nanmin(m) >= 0


@pytest.mark.parametrize(
    "args, words",
    [
        # the Python API's parameter names said as the options the user typed
        (["--rs", "2", "--rl", "0.2"], "--rs must be smaller than --rl; got --rs 2, --rl 0.2 (in the coordinates' unit)"),
        (["--rs", "-0.2"], "--rs must be a positive length"),
        (["--threshold", "1.5"], "--threshold must be a DoN magnitude in [0, 1]"),
        (["--tolerance", "0"], "--tolerance must be a positive length"),
        (["--min-points", "0"], "--min-points must be"),
        (["--min-points", str(2**63)], "at most 9223372036854775807"),
        (["--max-points", str(2**63)], "--max-points must be a whole number of points, at most 9223372036854775807"),
        (["--min-points", "100", "--max-points", "10"], "no smaller than --min-points (100), or not given; got 10"),
        (["--axis-threshold", "0.2"], "--axis-threshold needs an axis"),
        (["--tile-size", "-4"], "--tile-size must be a positive"),
        # wider than the cloud: every ball the whole cloud (it took minutes and gigabytes, then hours)
        (["--rl", "1e9"], "--rl 1e+09 is wider than the cloud"),
        (["--tolerance", "1e6"], "--tolerance 1e+06 is wider than the cloud"),
        # narrower than the file's step (0.001): copies of the point alone (5e-301 said "density must be ... 0.0")
        (["--rs", "0.5e-300"], "--rs 5e-301 is narrower than the coordinates' step (0.001, the files' common grid's scale)"),
    ],
)
def test_cli_bad_parameters(scene, tmp_path, args, words):
    path, _, _ = scene
    out = tmp_path / "x.las"
    r = CliRunner().invoke(main, ["segment", str(path), str(out), "--scheduler", "synchronous", "-q", *args])
    assert r.exit_code == 2
    assert r.output.strip().startswith("error:") and words in r.output
    assert not out.exists() and not (tmp_path / "x.las.partial").exists() and not (tmp_path / "x.las.store").exists()


def test_cli_bad_files(tmp_path, scene):
    path, _, _ = scene
    bad = tmp_path / "bad.las"
    bad.write_bytes(b"not a las file at all" * 20)
    r = CliRunner().invoke(main, ["don", str(bad), str(tmp_path / "o.las"), "-q"])
    assert r.exit_code == 2 and str(bad) in r.output and r.output.count("\n") == 1
    (tmp_path / "exists.las").write_bytes(b"x")
    r = CliRunner().invoke(main, ["don", str(path), str(tmp_path / "exists.las"), "-q"])
    assert r.exit_code == 2 and "exists" in r.output
    with pytest.raises(PatchcloudIOError, match="no such file"):
        don(tmp_path / "missing.las", tmp_path / "o2.las", quiet=True)
    with pytest.raises(PatchcloudValueError, match="mode must be one of exact, fast"):
        don(path, tmp_path / "o3.las", mode="approximate", quiet=True)


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_worker_processes_give_identical_files(scene, tmp_path):
    path, _, _ = scene
    kw = dict(r_small=0.3, r_large=1.5, threshold=0.2, tolerance=0.15, min_cluster=30, tile_size=4.0, quiet=True)
    segment(path, tmp_path / "a.las", scheduler="synchronous", **kw)
    segment(path, tmp_path / "b.las", scheduler="processes", workers=2, **kw)
    assert (tmp_path / "a.las").read_bytes() == (tmp_path / "b.las").read_bytes()


def _kept_run(scene, tmp_path, job):
    """A run of ``job`` on the scene with a kept store: (input, output, its keyword arguments, the output's bytes)."""
    path, _, _ = scene
    out = tmp_path / "out.las"
    kw = dict(r_small=0.3, r_large=1.5, tile_size=4.0, store=str(tmp_path / "keep.zarr"), scheduler="synchronous", quiet=True)
    if job is segment:
        kw.update(threshold=0.2, tolerance=0.15, min_cluster=30)
    job(path, out, **kw)
    return path, out, kw, out.read_bytes()


@pytest.mark.parametrize("job, change", [(don, {"r_small": 0.4}), pytest.param(segment, {"tolerance": 0.3}, marks=pytest.mark.slow),
                                         pytest.param(segment, {"threshold": 0.3}, marks=pytest.mark.slow)])  # segment: 8-10 s each
def test_a_kept_store_never_passes_an_output_of_other_parameters_as_this_runs(scene, tmp_path, job, change):
    """The same output and store, other parameters: the output the first run wrote is not taken as done (it was, with
    the store's record of it matching): without --overwrite one error line, with it the new values, as a fresh run's."""
    path, out, kw, first = _kept_run(scene, tmp_path, job)
    with pytest.raises(PatchcloudIOError, match="exists .*--overwrite"):
        job(path, out, **{**kw, **change})
    assert out.read_bytes() == first
    job(path, out, **{**kw, **change}, overwrite=True)
    fresh = tmp_path / "fresh.las"
    job(path, fresh, **{**kw, **change, "store": None})
    assert out.read_bytes() != first and out.read_bytes() == fresh.read_bytes()


@pytest.mark.parametrize("job, change", [(don, {"r_large": 1.2}), (segment, {"min_cluster": 40})])
def test_a_kept_output_of_other_parameters_is_refused_before_the_computation(scene, tmp_path, monkeypatch, job, change):
    """Other values of the options given: the kept output is refused before any DoN is computed (it used to be refused
    only by the export, after the whole computation); the same options resume without recomputing and keep it."""
    from patchcloud.stream.jobs import don_tiles

    path, out, kw, first = _kept_run(scene, tmp_path, job)
    calls = []
    real = don_tiles.don_tile
    monkeypatch.setattr(don_tiles, "don_tile", lambda *a, **k: calls.append(1) or real(*a, **k))
    with pytest.raises(PatchcloudIOError, match="exists .*--overwrite"):
        job(path, out, **{**kw, **change})
    with pytest.raises(PatchcloudIOError, match="exists .*--overwrite"):
        job(path, out, **kw, viewpoint=(0.0, 0.0, 30.0))
    with pytest.raises(PatchcloudIOError, match="exists .*--overwrite"):
        job(path, out, **{**kw, "tile_size": 8.0})
    assert calls == [] and out.read_bytes() == first
    job(path, out, **kw)  # the same options: the output kept as it is
    assert out.read_bytes() == first


def test_a_kept_normals_output_of_another_threshold_is_refused_before_the_fit(tmp_path, monkeypatch):
    from patchcloud.stream import normals
    from patchcloud.stream.jobs import normals_tiles

    path = tmp_path / "s.las"
    write_las(path, street(np.random.default_rng(4))[0][:20000])
    st, out = tmp_path / "keep.zarr", tmp_path / "out.las"
    kw = dict(tile_size=4.0, store=str(st), scheduler="synchronous", quiet=True)
    normals(path, out, **kw)
    first = out.read_bytes()
    calls = []
    real = normals_tiles.fit_one_tile
    monkeypatch.setattr(normals_tiles, "fit_one_tile", lambda *a, **k: calls.append(1) or real(*a, **k))
    with pytest.raises(PatchcloudIOError, match="exists"):
        normals(path, out, **kw, threshold=0.05)
    with pytest.raises(PatchcloudIOError, match="exists"):
        normals(path, out, **kw, criterion="sigma3")
    with pytest.raises(PatchcloudIOError, match="exists"):
        normals(path, out, **kw, viewpoint=(0.0, 0.0, 50.0), orient="viewpoint")
    with pytest.raises(PatchcloudIOError, match="exists"):
        normals(path, out, **{**kw, "tile_size": 8.0})  # the store is not tiled again, and the first command still keeps it
    assert calls == [] and out.read_bytes() == first
    normals(path, out, **kw)
    normals(path, out, **{**kw, "tile_size": None})  # no tile size: the store's own tiles, those the output was made on
    assert calls == [] and out.read_bytes() == first
    # made with a threshold, rerun without: the threshold would come from the data (another value), refused at once too
    other = tmp_path / "other.las"
    normals(path, other, **kw, threshold=0.05)
    with pytest.raises(PatchcloudIOError, match="exists"):
        normals(path, other, **kw)
    assert calls.count(1) == len(Store.open(str(st)).tiles)  # the fit of the threshold 0.05 run only


@pytest.mark.slow  # 10 s
def test_jobs_sharing_a_store_keep_each_others_outputs(scene, tmp_path):
    """normals, then don, then segment on one kept store: each rerun keeps its own output (the records are by path;
    the don run used to replace the normals run's record, and its rerun refused its own output as existing)."""
    from patchcloud.stream import normals

    path, _, _ = scene
    st = str(tmp_path / "shared.zarr")
    kw = dict(tile_size=4.0, store=st, scheduler="synchronous", quiet=True)
    dkw = dict(r_small=0.3, r_large=1.5)
    outs = {"n": tmp_path / "n.las", "d": tmp_path / "d.las", "g": tmp_path / "g.las"}
    normals(path, outs["n"], **kw)
    don(path, outs["d"], **kw, **dkw)
    segment(path, outs["g"], **kw, **dkw, threshold=0.2, tolerance=0.15, min_cluster=30)
    before = {k: o.read_bytes() for k, o in outs.items()}
    normals(path, outs["n"], **kw)
    don(path, outs["d"], **kw, **dkw)
    segment(path, outs["g"], **kw, **dkw, threshold=0.2, tolerance=0.15, min_cluster=30)
    assert {k: o.read_bytes() for k, o in outs.items()} == before


def test_a_halo_wider_than_the_grid_finds_the_same_neighbours_at_once(tmp_path):
    """map_tiles' neighbours within a halo of a thousand tiles (8e9 slots) are the store's other tiles, found by
    filtering the tiles, in the order of the offsets, as a halo that just covers the grid gives them."""
    from patchcloud.stream import map_tiles, tile

    path = tmp_path / "s.las"
    write_las(path, street(np.random.default_rng(3))[0][:20000])
    st = tmp_path / "st.zarr"
    tile(path, str(st), tile_size=4.0, quiet=True)
    store = Store.open(str(st))

    def neighbours_of(url, ijk, neighbours=()):
        return list(neighbours)

    small = map_tiles(neighbours_of, store, halo=max(np.ptp(np.asarray(store.tiles), axis=0)) + 1)
    huge = map_tiles(neighbours_of, store, halo=1000)
    assert small == huge and all(len(v) == len(store.tiles) - 1 for v in huge.values())


def test_the_api_on_the_files_own_coordinates_gives_the_commands_dons(scene, tmp_path):
    """difference_of_normals on the file's coordinates (projected, 650 km east) lays fast mode's voxels where the
    command does (from the grid origin, a multiple of 4096 m), with radii whose voxels do not divide 4096 m
    (1.25 / 4 and 3 / 4 m): the command's DoN within a float32 ulp (bit for bit in the store's frame, tested above; it
    differed on 99.9 % of a St-Barth crop's points, by up to 0.33, when the voxels were laid from the frame's zero)."""
    path, _, _ = scene
    out = tmp_path / "d.las"
    kw = dict(r_small=1.25, r_large=3.0, mode="fast")
    don(path, out, tile_size=4.0, scheduler="synchronous", quiet=True, **kw)
    las = laspy.read(str(path))
    pts = np.column_stack([las.x, las.y, las.z])
    got = laspy.read(str(out))
    vp = default_viewpoint_of(open_source(path))
    d = difference_of_normals(pts, kw["r_small"], kw["r_large"], mode="fast", viewpoint=vp, grid_step=0.001)  # the file's grid
    ref = np.nan_to_num(np.column_stack([np.sqrt((d * d).sum(1)), d])).astype(np.float32)
    mine = np.column_stack([got.DoN, got.DoNX, got.DoNY, got.DoNZ])
    assert np.abs(mine - ref).max() <= 1e-7  # the file's coordinates round apart from the store's frame's: a float32 ulp
    other = difference_of_normals(pts, kw["r_small"], kw["r_large"], mode="fast", viewpoint=vp, origin=np.zeros(3), grid_step=0.001)
    assert np.nanmax(np.abs(other - d)) > 1e-3  # voxels laid from elsewhere: another (close) answer


def test_map_tiles_refuses_a_tile_not_in_the_store_and_a_negative_halo(tmp_path):
    """A tile the store does not hold is an argument error, and the store is left as it was (a task on it wrote its
    failure into the store, which then read as damaged); a negative halo is refused, not taken as none."""
    from patchcloud.stream import map_tiles, tile

    path = tmp_path / "s.las"
    write_las(path, street(np.random.default_rng(3))[0][:5000])
    st = tmp_path / "st.zarr"
    store = tile(path, str(st), tile_size=4.0, quiet=True)
    before = sorted(p.name for p in (st / "tiles").iterdir())

    def count(url, ijk, neighbours=()):
        return len(neighbours)

    with pytest.raises(PatchcloudValueError, match=r"tiles: \(99, 99, 99\) is not a tile of the store"):
        map_tiles(count, store, tiles=[(99, 99, 99)])
    assert sorted(p.name for p in (st / "tiles").iterdir()) == before
    with pytest.raises(PatchcloudValueError, match="halo must be a whole number of tiles, 0 or more; got -1"):
        map_tiles(count, store, halo=-1)


def test_a_line_stored_to_1_cm_has_no_don_and_no_segment(tmp_path):
    """Its balls hold points of one line, up to the file's rounding: no plane, so no normal and no DoN (0 in the file),
    and no segment (before: DoN up to 0.996 and 18 segments of 5 points or more)."""
    h = laspy.LasHeader(point_format=6, version="1.4")
    h.scales, h.offsets = [0.01] * 3, list(OFFSET)
    las = laspy.LasData(h)
    t = np.linspace(0, 50, 500)
    las.x, las.y, las.z = OFFSET[0] + 0.8 * t, OFFSET[1] + 0.6 * t, OFFSET[2] + 0.05 * t
    las.write(tmp_path / "line.las")
    summary = don(tmp_path / "line.las", tmp_path / "don.las", r_small=0.2, r_large=2.0, quiet=True)
    assert not np.asarray(laspy.read(tmp_path / "don.las").DoN).any()
    text = summary.format()  # no "median magnitude nan"; what to change, said
    assert "  DoN defined     0 (0.0%)\n" in text and "nan" not in text
    assert "note            most points have no DoN: their r_s ball holds fewer than 3 points, or points of one line" in text
    segment(tmp_path / "line.las", tmp_path / "seg.las", r_small=0.2, r_large=2.0, threshold=0.25, min_points=5, quiet=True)
    assert not np.asarray(laspy.read(tmp_path / "seg.las").ClusterID).any()


def test_summaries_and_provenance_state_positions_in_file_coordinates(scene, tmp_path):
    """The viewpoint and centre a user reads (summary, provenance VLR) are in the file's coordinates, not the store's
    local frame; no internal keys."""
    import json

    from patchcloud.stream import normals

    path, _, _ = scene
    vp = (770500.0, 6277505.0, 60.0)
    s = don(path, tmp_path / "d.las", r_small=0.3, r_large=1.5, viewpoint=vp, quiet=True)
    assert s.parameters["viewpoint"] == pytest.approx(vp, abs=1e-9)
    assert not [k for k in s.parameters if k.endswith(("_local", "_key"))]
    vlr = next(v for v in laspy.read(tmp_path / "d.las").header.vlrs if v.user_id == "patchcloud")
    stated = json.loads(vlr.record_data)["parameters"]
    assert stated["viewpoint"] == pytest.approx(vp, abs=1e-9) and "viewpoint_local" not in stated
    up = normals(path, tmp_path / "n.las", quiet=True)
    assert "centre" not in up.parameters and "centre_local" not in up.parameters  # the up rule has no centre
    out = normals(path, tmp_path / "o.las", orient="outward", quiet=True)
    xyz = np.column_stack([laspy.read(path).x, laspy.read(path).y, laspy.read(path).z])
    assert out.parameters["centre"] == pytest.approx(xyz.mean(axis=0), abs=1e-6)
