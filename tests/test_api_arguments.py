"""Arguments the Python API and the CLI used to accept and then ignore or misread (a sweep of 2026-11-26)."""

import struct
from pathlib import Path

import laspy
import numpy as np
import pytest
from click.testing import CliRunner
from test_stream import write_scene

from patchcloud.core import (
    PatchcloudValueError,
    difference_of_normals,
    don_magnitude,
    don_mask,
    estimate_normals,
    fit_models,
    grid_origin,
    radius_normals,
    sample_models,
)
import patchcloud
from patchcloud.stream import normals
from patchcloud.stream.cli import main

SAMPLE = Path(__file__).resolve().parents[1] / "data" / "test_data_77055_627760_LA93_IGN69.laz"


@pytest.fixture(scope="module")
def plane():
    xy = np.random.default_rng(2).uniform(0, 4, (2000, 2))
    return np.column_stack([xy, 0.1 * xy[:, 0]])


def test_at_takes_indices_or_a_mask_and_refuses_anything_else(plane):
    mask = plane[:, 0] < 1.0
    whole = radius_normals(plane, 0.5)
    assert np.array_equal(radius_normals(plane, 0.5, at=mask), whole[mask])
    assert np.array_equal(radius_normals(plane, 0.5, at=np.flatnonzero(mask)), whole[mask])
    assert np.array_equal(difference_of_normals(plane, 0.3, 1.0, at=mask), difference_of_normals(plane, 0.3, 1.0)[mask])
    for bad, words in (([2000], "got 2000"), ([-1], "got -1"), ([1.7], "type float64"), (mask[:10], "mask must hold 2000 booleans")):
        with pytest.raises(PatchcloudValueError, match=words):
            radius_normals(plane, 0.5, at=bad)
    with pytest.raises(PatchcloudValueError, match="density must be a positive finite number"):
        radius_normals(plane, 0.5, density=-5.0)


def test_options_that_would_be_ignored_are_refused(plane):
    with pytest.raises(PatchcloudValueError, match="blend must be True or False; got 'no'"):
        estimate_normals(plane, blend="no")
    with pytest.raises(PatchcloudValueError, match='viewpoint goes with orient="viewpoint", not orient=\'up\''):
        estimate_normals(plane, viewpoint=(5, 5, -100))
    down = estimate_normals(plane, orient="viewpoint", viewpoint=(2, 2, -100)).normals
    assert np.median(down[:, 2]) < -0.9
    with pytest.raises(PatchcloudValueError, match="d_min must be at most max_edge"):
        fit_models(plane, 0.01, d_min=5.0, max_edge=1.0)
    with pytest.raises(PatchcloudValueError, match="n_min must be a positive integer"):
        fit_models(plane, 0.01, n_min=0)
    with pytest.raises(PatchcloudValueError, match=r"min_sigma2 must be in \[0, 1/3\)"):
        fit_models(plane, 0.01, min_sigma2=-1.0)


def test_don_vectors_must_be_n_by_3():
    assert don_magnitude(np.array([[0.3, 0.0, 0.4]])).tolist() == [0.5]
    for bad in (np.ones((3, 2)), np.ones(3)):
        with pytest.raises(PatchcloudValueError, match=r"don must be an \(N, 3\) array"):
            don_magnitude(bad)
        with pytest.raises(PatchcloudValueError, match=r"don must be an \(N, 3\) array"):
            don_mask(bad, 0.2)


def test_file_jobs_take_paths_and_write_las_or_laz(tmp_path):
    src = tmp_path / "scene.las"
    write_scene(src, n=3000, seed=1)
    with pytest.raises(PatchcloudValueError, match="input must be the path of a LAS/LAZ file .* not a LasData"):
        normals(laspy.read(str(src)), tmp_path / "out.laz", quiet=True)
    with pytest.raises(PatchcloudValueError, match=r"out.txt: an output's name ends in .las \(LAS\) or .laz \(LAZ\)"):
        normals(src, tmp_path / "out.txt", quiet=True)
    assert not (tmp_path / "out.txt").exists()


def test_a_file_of_a_few_points_runs_as_one_tile(tmp_path):
    src = tmp_path / "scene.las"
    write_scene(src, n=3000, seed=1)
    las = laspy.read(str(src))
    few = laspy.LasData(las.header)
    few.points = las.points[:30].copy()
    few.write(str(tmp_path / "few.las"))
    for args in ([], ["--tile-size", "1000"]):
        r = CliRunner().invoke(main, ["normals", str(tmp_path / "few.las"), str(tmp_path / "out.las"), "-q", "--overwrite", *args])
        assert r.exit_code == 0, r.output
        assert len(laspy.read(str(tmp_path / "out.las")).points) == 30


def test_header_bounds_that_understate_the_cloud(tmp_path):
    """Zeroed header bounds (some writers leave them so): the default tile size, taken from them, would cut the cloud
    into thousands of 1 m tiles; the cloud is tiled again at the size its points give, and the normals are those of
    the file with true bounds up to rounding (the local frame's origin moves).  render, framed by them, refuses."""
    good, bad = tmp_path / "good.las", tmp_path / "bad.las"
    write_scene(good, n=60_000, seed=2, point_format=1, extra=False)
    raw = bytearray(good.read_bytes())
    struct.pack_into("<6d", raw, 179, *([0.0] * 6))  # max x, min x, max y, min y, max z, min z
    bad.write_bytes(bytes(raw))
    tiles = []
    for src in (good, bad):
        r = CliRunner().invoke(main, ["normals", str(src), str(tmp_path / f"{src.stem}_n.las")])
        assert r.exit_code == 0, r.output
        tiles.append([line for line in r.output.splitlines() if line.strip().startswith("tiles ")])
    assert tiles[0] == tiles[1] and "of 128 m" in tiles[0][0]  # (thousands of 1 m tiles before)
    a, b = laspy.read(str(tmp_path / "good_n.las")), laspy.read(str(tmp_path / "bad_n.las"))
    assert np.array_equal(a.NormalMethod, b.NormalMethod)
    assert np.allclose(np.asarray(a.NormalZ), np.asarray(b.NormalZ), atol=1e-5)
    r = CliRunner().invoke(main, ["render", str(bad), str(tmp_path / "bad.png"), "--color", "elevation"])
    assert r.exit_code == 2 and "59,932 of its 59,932 points lie outside its header's bounds (x 0 to 0, y 0 to 0)" in r.output
    assert not (tmp_path / "bad.png").exists()


def test_render_draws_a_file_whose_header_bounds_are_rounded_within_half_a_step(tmp_path):
    """PDAL's sample_c.las: its header's max x lies 6e-6 below its last point's (a step of 0.01, an offset that is no
    whole number of steps); render refused it as "1 point outside its header's bounds" (bug hunt I)."""
    src, off = tmp_path / "rounded.las", tmp_path / "off.las"
    write_scene(src, n=20_000, seed=3, point_format=1, extra=False)
    raw = bytearray(src.read_bytes())
    step = struct.unpack_from("<d", raw, 131)[0]  # the x scale
    max_x = struct.unpack_from("<d", raw, 179)[0]
    struct.pack_into("<d", raw, 179, max_x - 0.4 * step)
    src.write_bytes(bytes(raw))
    r = CliRunner().invoke(main, ["render", str(src), str(tmp_path / "r.png"), "--color", "elevation", "-q"])
    assert r.exit_code == 0 and (tmp_path / "r.png").exists(), r.output
    struct.pack_into("<d", raw, 179, max_x - 2.0 * step)  # a point a whole step beyond: outside, refused as before
    off.write_bytes(bytes(raw))
    r = CliRunner().invoke(main, ["render", str(off), str(tmp_path / "o.png"), "--color", "elevation", "-q"])
    assert r.exit_code == 2 and "lie outside its header's bounds" in r.output, r.output


def test_root_grid_gives_the_commands_normals_in_memory(tmp_path):
    """estimate_normals(points, root="grid") of a whole file: the octree of the command's tile grid, so the normals of
    `patchcloud normals` of the file (the embedded IGN tile: no noise or withheld point to leave out)."""
    from pathlib import Path

    src = Path(__file__).resolve().parents[1] / "data" / "test_data_77055_627760_LA93_IGN69.laz"
    r = CliRunner().invoke(main, ["normals", str(src), str(tmp_path / "n.laz"), "-q"])
    assert r.exit_code == 0, r.output
    las, out = laspy.read(str(src)), laspy.read(str(tmp_path / "n.laz"))
    assert not np.isin(np.asarray(las.classification), [7, 18]).any() and not np.asarray(las.withheld).any()
    res = estimate_normals(np.column_stack([las.x, las.y, las.z]), root="grid")
    cli = np.column_stack([out.NormalX, out.NormalY, out.NormalZ])
    assert np.array_equal(res.method, np.asarray(out.NormalMethod))
    assert np.abs(res.normals - cli).max() < 1e-6
    other = estimate_normals(np.column_stack([las.x, las.y, las.z]))  # the bounding cube: another octree
    assert np.mean(np.abs(other.normals - cli).max(axis=1) > 1e-3) > 0.5
    with pytest.raises(PatchcloudValueError, match="root must be \\(corner, edge\\), 'grid' or None; got 'tiles'"):
        estimate_normals(np.column_stack([las.x, las.y, las.z]), root="tiles")


def test_root_grid_holds_a_cloud_across_zero(tmp_path):
    """A cloud in a sensor's frame, across 0 on x and y (a cube at a multiple of its own edge never held it: the loop
    looking for one did not end): root="grid" starts at the grid's origin and gives the command's normals."""
    src = tmp_path / "centred.las"
    write_scene(src, n=20_000, seed=2)
    las = laspy.read(str(src))
    h = laspy.LasHeader(point_format=las.header.point_format.id, version="1.4")
    h.scales, h.offsets = las.header.scales, np.zeros(3)
    centred = laspy.LasData(h)
    centred.x, centred.y, centred.z = las.x - np.mean(las.x), las.y - np.mean(las.y), las.z
    centred.write(str(src))
    r = CliRunner().invoke(main, ["normals", str(src), str(tmp_path / "n.las"), "-q"])
    assert r.exit_code == 0, r.output
    back, out = laspy.read(str(src)), laspy.read(str(tmp_path / "n.las"))
    assert back.x.min() < 0 < back.x.max() and back.y.min() < 0 < back.y.max()
    res = estimate_normals(np.column_stack([back.x, back.y, back.z]), root="grid")
    assert np.array_equal(res.method, np.asarray(out.NormalMethod))
    assert np.abs(res.normals - np.column_stack([out.NormalX, out.NormalY, out.NormalZ])).max() < 1e-6


def test_always_up_and_a_viewpoint_are_not_both_taken(tmp_path):
    """Each turns every normal its own way (PDAL's viewpoint overrides its always_up): both asked for is one error."""
    src = tmp_path / "in.las"
    write_scene(src, n=2_000, seed=1)
    r = CliRunner().invoke(main, ["normals", str(src), str(tmp_path / "o.laz"), "--viewpoint", "0", "0", "100", "--always-up"])
    assert r.exit_code == 2 and r.output.count("\n") == 1 and "--always-up turns every normal up and a viewpoint" in r.output
    assert not (tmp_path / "o.laz").exists()


@pytest.mark.parametrize("call, error, words", [
    (lambda p: estimate_normals(p, root=((np.nan, 0, 0), 100.0)), PatchcloudValueError, "root corner must be three finite coordinates"),
    (lambda p: estimate_normals(p, root=5.0), PatchcloudValueError, "root must be (corner, edge), 'grid' or None; got 5.0"),
    (lambda p: fit_models(p, 0.01, root=((0, np.inf, 0), 100.0)), PatchcloudValueError, "root corner must be three finite"),
    (lambda p: grid_origin(p[:, :2]), PatchcloudValueError, "points must be an (N, 3) array, got shape (400, 2)"),
    (lambda p: grid_origin(p[:, 0]), PatchcloudValueError, "points must be an (N, 3) array, got shape (400,)"),
    (lambda p: grid_origin(np.vstack([p, [np.nan] * 3])), PatchcloudValueError, "points holds NaN or infinite coordinates"),
    (lambda p: don_mask(np.zeros((4, 3)), "0.2"), PatchcloudValueError, "threshold must be a DoN magnitude in [0, 1] (a number); got '0.2'"),
    (lambda p: sample_models(p), PatchcloudValueError, "models must be PatchModels"),
])
def test_bad_arguments_of_the_api_are_one_clear_error(call, error, words):
    p = np.random.default_rng(0).uniform(0, 10, (400, 3))
    with pytest.raises(error, match=words.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[").replace("]", r"\]")):
        call(p)
    assert grid_origin(np.zeros((0, 3))).tolist() == [0.0, 0.0, 0.0]  # no points: the origin


def test_sample_models_takes_whole_counts_and_seeds_and_says_when_memory_cannot_hold_them():
    from patchcloud.core import PatchcloudMemoryError

    xy = np.random.default_rng(0).uniform(0, 8, (20000, 2))
    m = fit_models(np.column_stack([xy, np.zeros(20000)]), 0.01).models
    C = len(m.count)
    assert sample_models(m, np.full(C, 3.0))[0].shape == (3 * C, 3)  # whole numbers as floats are whole numbers
    for bad in (np.full(C, 2.5), np.full(C, -1), np.full(C + 1, 2)):
        with pytest.raises(PatchcloudValueError, match=f"counts must be {C} non-negative whole numbers"):
            sample_models(m, bad)
    for seed in (-1, 1.5, "x", [1, -2]):
        with pytest.raises(PatchcloudValueError, match="seed must be a non-negative whole number"):
            sample_models(m, seed=seed)
    with pytest.raises(PatchcloudMemoryError, match=r"counts ask for [\d,]+ points"):
        sample_models(m, np.full(C, 10**13))


def test_values_a_sweep_found_accepted_are_one_line_before_anything_runs(tmp_path):
    """Bug hunt I: --max-memory 1e400 was a traceback (an int of infinity); --summary-json /dev/null ran the whole job,
    wrote its output, then failed; --store '' ran on the default store and kept it; --workers 1e20 was taken."""
    src = tmp_path / "in.las"
    write_scene(src, n=2_000, seed=5, point_format=1, extra=False)
    out = tmp_path / "out.las"
    for extra, says in [
        (["--max-memory", "1e400"], "a size must be below 8 EiB"),
        (["--max-memory", "1e300TB"], "a size must be below 8 EiB"),
        (["--summary-json", "/dev/null"], "exists and is not a file (a device or a pipe)"),
        (["--store", ""], "store must be a path or an fsspec URL"),
        (["--workers", "99999999999999999999"], "workers must be at most 4,096"),
    ]:
        r = CliRunner().invoke(main, ["normals", str(src), str(out), "-q", *extra])
        assert r.exit_code == 2 and says in r.output and r.output.count("\n") == 1, (extra, r.output)
        assert sorted(p.name for p in tmp_path.iterdir()) == ["in.las"], extra  # nothing written, no store


def test_huge_values_are_one_line_without_numpys_overflow_warnings(tmp_path):
    """compress --max-error 1e308 said "--tile-size of at least inf" after two RuntimeWarnings; --viewpoint 1e308 ran
    with four (bug hunt I)."""
    src = tmp_path / "in.las"
    write_scene(src, n=2_000, seed=5, point_format=1, extra=False)
    for args, says in [
        (["compress", str(src), str(tmp_path / "o.pcz"), "--max-error", "1e308"], "is larger than the tiles"),
        (["normals", str(src), str(tmp_path / "o.las"), "--viewpoint", "1e308", "1e308", "1e308"], "--viewpoint must lie within"),
    ]:
        r = CliRunner().invoke(main, [*args, "-q"])
        assert r.exit_code == 2 and says in r.output and r.output.count("\n") == 1 and "inf" not in r.output, r.output
        assert sorted(p.name for p in tmp_path.iterdir()) == ["in.las"]


@pytest.mark.parametrize("call, says", [
    # each one a bare numpy, dataclasses or AttributeError traceback before (review J of 2026-11-28)
    (lambda p: __import__("patchcloud.core", fromlist=["x"]).estimate_normals(p, threshold="0.1"),
     "threshold must be a positive finite number, got '0.1'"),
    (lambda p: __import__("patchcloud.core", fromlist=["x"]).estimate_normals(p, n_min="12"), "n_min must be a positive integer, got '12'"),
    (lambda p: __import__("patchcloud.core", fromlist=["x"]).don_magnitude("x"), "don must be an (N, 3) array of DoN vectors (numbers)"),
    (lambda p: __import__("patchcloud.core", fromlist=["x"]).fit_models(p, 0.05, merge=1), "merge must be True or False; got 1"),
    (lambda p: __import__("patchcloud.core", fromlist=["x"]).radius_normals(p, 1.0, grid_step=-1),
     "grid_step must be a finite length of at least 0"),
])
def test_arguments_of_the_wrong_kind_are_one_clear_error(call, says):
    p = np.random.default_rng(0).uniform(0, 10, (500, 3))
    with pytest.raises(PatchcloudValueError) as e:
        call(p)
    assert says in str(e.value)


def test_stream_arguments_of_the_wrong_kind_are_one_clear_error(tmp_path):
    from patchcloud.stream import decompress, map_tiles, normals, tile

    sample = Path(__file__).resolve().parents[1] / "data" / "test_data_77055_627760_LA93_IGN69.laz"
    with pytest.raises(PatchcloudValueError, match="run must be a RunOptions .*got dict"):
        normals(sample, tmp_path / "o.laz", run={"workers": 1})
    with pytest.raises(PatchcloudValueError, match="seed must be a whole number from 0 to 2\\*\\*62 - 1; got 'a'"):
        decompress(tmp_path / "x.pcz", tmp_path / "o.laz", seed="a")
    with pytest.raises(PatchcloudValueError, match="store must be a Store or a store's path or URL, got int"):
        map_tiles(len, 3)
    store = tile(sample, str(tmp_path / "s.zarr"), tile_size=64, quiet=True)
    by_path = map_tiles(_tile_points, str(tmp_path / "s.zarr"))  # a store's path is opened
    assert by_path == map_tiles(_tile_points, store) and sum(by_path.values()) == 60653


def _tile_points(url, ijk):
    from patchcloud.stream import Store

    return int(Store.open(url).tile_counts[Store.open(url).tiles.index(ijk)])


@pytest.mark.parametrize("call, says", [
    (lambda tmp: patchcloud.normals(SAMPLE, tmp / "victim.las", overwrite="no", quiet=True), "overwrite must be True or False, got 'no'"),
    (lambda tmp: patchcloud.normals(SAMPLE, tmp / "o.las", principal_curvatures="no", quiet=True), "principal_curvatures must be"),
    (lambda tmp: patchcloud.normals(SAMPLE, tmp / "o.las", always_up="no", quiet=True), "always_up must be"),
    (lambda tmp: patchcloud.normals(SAMPLE, tmp / "o.las", keep_store="no", quiet=True), "keep_store must be True, False or None"),
    (lambda tmp: patchcloud.normals(SAMPLE, tmp / "o.las", quiet="no"), "quiet must be True or False"),
    (lambda tmp: patchcloud.render(SAMPLE, tmp / "o.png", color="elevation", shade="no"), "shade must be True, False or None"),
])
def test_flags_take_booleans_only(call, says, tmp_path):
    # a truthy string was taken as True: overwrite="no" replaced the file it named (review N)
    victim = tmp_path / "victim.las"
    victim.write_bytes(b"keep me")
    with pytest.raises(PatchcloudValueError, match=says):
        call(tmp_path)
    assert victim.read_bytes() == b"keep me" and not (tmp_path / "o.las").exists() and not (tmp_path / "o.png").exists()


def test_patch_model_functions_check_their_arguments(plane):
    # a residual point's patch -1 indexed the last model silently; wrong lengths and types were numpy's or Python's errors
    from patchcloud.core import dequantise_models, patch_distances, quantise_models

    fit = fit_models(plane, 0.01)
    with pytest.raises(PatchcloudValueError, match=r"patch must hold rows of the \d+ models .*got -1 \(fit_models gives -1"):
        patch_distances(fit.models, plane, np.full(len(plane), -1))
    with pytest.raises(PatchcloudValueError, match=r"patch must be \(2000,\) whole numbers"):
        patch_distances(fit.models, plane, fit.patch[:5])
    with pytest.raises(PatchcloudValueError, match="models must be a PatchModels"):
        quantise_models("models", 0.01)
    with pytest.raises(PatchcloudValueError, match="q must be a QuantisedModels"):
        dequantise_models(fit.models)


def test_map_tiles_and_render_arrays_check_their_arguments(tmp_path):
    # pieces={tile: 0} dropped the tile from the result; runner="threads" was an AttributeError; colors="elevation" was
    # read letter by letter (review N)
    from patchcloud.stream import map_tiles, tile
    from patchcloud.stream.views.render import render_arrays

    store = tile(SAMPLE, str(tmp_path / "s.zarr"), tile_size=64, quiet=True)
    with pytest.raises(PatchcloudValueError, match=r"pieces: tile \(\d+, \d+, \d+\) would be cut into 0 pieces"):
        map_tiles(lambda url, ijk: 1, store, pieces={store.tiles[0]: 0})
    with pytest.raises(PatchcloudValueError, match=r"pieces: \(99, 99, 99\) is not a tile of the store"):
        map_tiles(lambda url, ijk: 1, store, pieces={(99, 99, 99): 2})
    with pytest.raises(PatchcloudValueError, match="tiles must be a list of tile indices"):
        map_tiles(lambda url, ijk: 1, store, tiles=5)
    with pytest.raises(PatchcloudValueError, match="runner must be a Runner"):
        map_tiles(lambda url, ijk: 1, store, runner="threads")
    with pytest.raises(PatchcloudValueError, match=r"colors must be a list of colour modes, e.g. \['elevation'\]"):
        render_arrays(SAMPLE, colors="elevation")


@pytest.mark.parametrize("call", [
    lambda p: radius_normals(p, "1"),
    lambda p: fit_models(p, "0.1"),
    lambda p: difference_of_normals(p, "0.2", 1.0),
])
def test_lengths_given_as_strings_are_refused_as_elsewhere(plane, call):
    # radius_normals(P, "1") and fit_models(P, "0.1") were taken, check_positive refused "1" elsewhere (review N)
    with pytest.raises(PatchcloudValueError, match=r"must be a positive length in the coordinates' unit, got '"):
        call(plane)


def test_report_info_and_options_helpers_refuse_wrong_arguments_in_one_line(tmp_path):
    # each raised a raw KeyError, AttributeError or TypeError from deep inside (review N)
    from patchcloud.core import options_with
    from patchcloud.stream import format_info
    from patchcloud.stream.views.render import render_figure
    from patchcloud.stream.views.report import report_compress, report_don, report_normals, write_report

    cases = [
        (lambda: format_info({"path": "x"}), "format_info takes the dictionary info"),
        (lambda: write_report(tmp_path / "r.html", title=None, summary_rows=[]), "title must be a str, got None"),
        (lambda: report_normals("x", tmp_path / "r.html"), "summary must be a NormalsSummary .*got a str"),
        (lambda: report_don("x", tmp_path / "r.html"), "summary must be a DonSummary"),
        (lambda: report_compress("x", tmp_path / "r.html"), "summary must be a CompressSummary"),
        (lambda: render_figure("x"), "img must be a RenderImage"),
        (lambda: options_with(int, None, {}), "kind must be one of NormalsOptions, DonOptions, SegmentOptions, CompressOptions"),
    ]
    for call, says in cases:
        with pytest.raises(PatchcloudValueError, match=says):
            call()
    assert not (tmp_path / "r.html").exists()
