"""``patchcloud render`` and ``render-tiles``: known colours, decimation, framing, errors."""

import laspy
import numpy as np
import pytest
from click.testing import CliRunner
from matplotlib.image import imread

from patchcloud.stream.cli import main
from patchcloud.core.errors import PatchcloudValueError
from patchcloud.stream import render, render_array, render_tiles
from patchcloud.stream.views.render import render_arrays
from patchcloud.stream.views.render import (
    AMBIENT, BOUNDARY_DARKEN, LIGHT, NO_SEGMENT, ZBuffer, choose_view, class_colours, colorize, lambert,
    make_frame, patch_boundaries, patch_colours, segment_colours, view_axes,
)
from patchcloud.stream.views.render_tiles import STATE_COLOURS, tile_state
from patchcloud.stream.io.store import Store

X0, Y0 = 650000.0, 6860000.0


def write_las(path, xyz, crs=None, **dims):
    """A LAS 1.4 pf6 file of local ``xyz`` (metres, shifted by X0, Y0) with standard or extra dimensions,
    and a CRS (anything pyproj takes) when given."""
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([X0, Y0, 0.0])
    std = set(header.point_format.dimension_names)
    extra = [laspy.ExtraBytesParams(name, np.asarray(v).dtype) for name, v in dims.items() if name not in std]
    if extra:
        header.add_extra_dims(extra)
    if crs is not None:
        from pyproj import CRS

        header.add_crs(CRS.from_user_input(crs))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0] + X0, xyz[:, 1] + Y0, xyz[:, 2]
    for name, v in dims.items():
        las[name] = v
    las.write(str(path))
    return path


def grid_xy(n=200, size=10.0):
    """Points at the centres of an n x n grid over [0, size]^2, plus the two corners (so the bounds are exact)."""
    c = (np.arange(n) + 0.5) * size / n
    x, y = np.meshgrid(c, c, indexing="ij")
    xy = np.column_stack([x.ravel(), y.ravel()])
    return np.vstack([xy, [[0.0, 0.0], [size, size]]])


def normal_dims(n):
    n = np.asarray(n, dtype=np.float32)
    return dict(NormalX=n[:, 0].copy(), NormalY=n[:, 1].copy(), NormalZ=n[:, 2].copy())


# --- pure functions ---------------------------------------------------------------------------------------


def test_view_axes_are_rotations_and_the_default_view_follows_the_height_ratio():
    for view in ("top", "side", "oblique"):
        R = view_axes(view, (0, 0, 0), (10, 4, 3))
        assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
        assert R[1, 2] >= 0  # screen up never points down
    assert view_axes("side", (0, 0, 0), (2, 10, 3))[0].tolist() == [0.0, 1.0, 0.0]  # longer along y: seen from the east
    ob = view_axes("oblique", (0, 0, 0), (1, 1, 1))
    assert np.isclose(np.degrees(np.arcsin(ob[2, 2])), 35.0) and ob[2, 0] < 0 and ob[2, 1] < 0  # viewer south-west, 35 deg up
    assert choose_view((0, 0, 0), (100, 50, 49)) == "top" and choose_view((0, 0, 0), (100, 50, 51)) == "oblique"
    f = make_frame(np.eye(3), (0, 0, 0), (10, 1, 1), 10)
    assert (f.width, f.height, f.pixel) == (10, 1, 1.0)
    tall = make_frame(np.eye(3), (0, 0, 0), (1, 100, 1), 10)  # at most 4 x the width tall
    assert tall.height == 40 and tall.width == 1


def test_zbuffer_keeps_the_nearest_point_whatever_the_chunks_and_breaks_ties_by_input_order(rng):
    n = 5000
    pix = rng.integers(0, 50, n)
    depth = rng.integers(0, 4, n).astype(float)  # many equal depths: ties
    index = np.arange(n)
    vals = rng.random((n, 2))
    whole = ZBuffer(5, 10, 2)
    whole.add(pix, depth, index, vals)
    for parts in (7, 333, 4999):
        zb = ZBuffer(5, 10, 2)
        perm = rng.permutation(n)  # any order of chunks, any order within
        for part in np.array_split(perm, parts):
            zb.add(pix[part], depth[part], index[part], vals[part])
        assert np.array_equal(zb.index, whole.index) and np.array_equal(zb.values, whole.values, equal_nan=True)
    for p in range(50):  # by hand: largest depth, then smallest index
        at = np.flatnonzero(pix == p)
        if at.size:
            best = at[depth[at] == depth[at].max()].min()
            assert whole.index[p] == best
        else:
            assert whole.index[p] == -1


def test_colours_of_the_categorical_modes():
    c = segment_colours(np.array([0, 1, 2, 19, 37]))
    assert tuple(c[0]) == NO_SEGMENT and np.array_equal(c[1], c[4])  # 18 colours, cycled
    assert not np.allclose(c[1:4, 0], c[1:4, 1]) or not np.allclose(c[1:4, 1], c[1:4, 2])  # no grey among them
    tab = segment_colours(np.arange(1, 19))
    assert (np.ptp(tab, axis=1) > 0.05).all()
    p = patch_colours(np.arange(1, 200))
    assert len({tuple(np.round(v, 6)) for v in p}) == 199
    assert np.allclose(class_colours(np.array([2, 6, 9])), [[0.65, 0.47, 0.28], [0.86, 0.25, 0.2], [0.2, 0.45, 0.9]])
    b = patch_boundaries(np.array([[1, 1, 2, 2], [1, 1, 2, 2]]), np.array([[1, 1, 1, 0], [1, 1, 1, 1]], bool))
    assert b.tolist() == [[False, True, True, False], [False, True, True, False]]


def test_continuous_colours_use_the_robust_range_and_grey_for_undefined():
    v = np.array([[0.0, 1.0, 2.0, np.nan]])
    rgb, rng, _ = colorize("curvature", v, np.array([[1, 1, 1, 1]], bool), value_range=(0.0, 2.0))
    from matplotlib import colormaps

    assert rng == (0.0, 2.0)
    assert np.allclose(rgb[0, :3], colormaps["viridis"]([0.0, 0.5, 1.0])[:, :3])
    assert np.allclose(rgb[0, 3], 0.85)
    _, rng, _ = colorize("curvature", np.arange(101.0)[None, :], np.ones((1, 101), bool))
    assert rng == (2.0, 98.0)


def test_lambert_is_the_formula_and_ignores_the_sign_of_the_normal():
    n = np.array([[0.3, -0.2, 0.9], [-0.3, 0.2, -0.9]])
    R = np.eye(3)
    nn = n[0] / np.linalg.norm(n[0])
    want = AMBIENT + (1 - AMBIENT) * max(0.0, float(nn @ LIGHT))
    assert np.allclose(lambert(n, R), want)
    assert np.isclose(lambert(np.array([[0.7, -0.7, 0.0]]), R)[0], AMBIENT)  # facing away from the light
    assert lambert(np.array([[np.nan, 0, 1]]), R)[0] == 1.0


# --- files ------------------------------------------------------------------------------------------------


def test_tilted_plane_top_view_is_the_normal_rgb_times_the_lambert_factor(tmp_path):
    xy = grid_xy(100)
    z = 0.3 * xy[:, 0] - 0.1 * xy[:, 1] + 40.0
    n = np.array([-0.3, 0.1, 1.0]) / np.linalg.norm([-0.3, 0.1, 1.0])
    flip = np.floor(xy[:, 0] / 0.2) % 2 == 0  # every other pixel column oriented downwards: the shading must not care
    nrm = np.where(flip[:, None], -n, n)
    path = write_las(tmp_path / "plane.las", np.column_stack([xy, z]), **normal_dims(nrm))
    img = render_array(path, color="normals", view="top", width=50, fill=0)
    assert img.view == "top" and img.shaded and img.rgb.shape == (50, 50, 3)
    assert img.filled.all()
    n32 = n.astype(np.float32).astype(np.float64)
    factor = AMBIENT + (1 - AMBIENT) * max(0.0, float(n32 @ LIGHT) / np.linalg.norm(n32))
    up = (n32 + 1) / 2 * factor
    down = (-n32 + 1) / 2 * factor
    flat = img.rgb.reshape(-1, 3)
    is_up = np.isclose(flat, up, atol=1e-9).all(axis=1)
    is_down = np.isclose(flat, down, atol=1e-9).all(axis=1)
    assert (is_up | is_down).all() and is_up.any() and is_down.any()
    assert np.array_equal(is_down.reshape(50, 50)[0], np.arange(50) % 2 == 0)
    assert np.isclose(img.extent[0], X0) and np.isclose(img.extent[3], Y0 + 10.0)


def test_the_top_plane_wins_and_results_do_not_depend_on_the_chunk_size(tmp_path, rng):
    xy = grid_xy(60, 6.0)
    n = len(xy)
    low = np.column_stack([xy, np.zeros(n)])
    high = np.column_stack([xy, np.full(n, 5.0)])
    noise = np.column_stack([rng.random((3000, 2)) * 6.0, rng.random(3000) * 4.0])  # between the two
    dup = np.repeat(noise[:50], 2, axis=0)  # exact duplicates: ties broken by input order
    xyz = np.vstack([low[: n // 2], high, noise, dup, low[n // 2:]])
    cls = np.concatenate([np.full(n // 2, 2), np.full(n, 6), np.full(3000, 1), np.tile([3, 4], 50), np.full(n - n // 2, 2)])
    path = write_las(tmp_path / "stack.las", xyz, classification=cls.astype(np.uint8), intensity=np.arange(len(xyz)) % 60000)
    img = render_array(path, color="classification", view="top", width=60, fill=0)
    assert img.filled.all() and not img.shaded
    assert (img.value == 6).all()
    assert np.allclose(img.rgb, class_colours(np.array([6]))[0])
    assert img.legend[0][0] == "6 building"
    for color, view in (("classification", "side"), ("intensity", "oblique"), ("elevation", "top")):
        a = render_array(path, color=color, view=view, width=80, chunk=1000)
        b = render_array(path, color=color, view=view, width=80, chunk=10**6)
        assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.value, b.value, equal_nan=True)
        assert a.points_drawn == b.points_drawn and a.value_range == b.value_range
    side = render_array(path, color="classification", view="side", width=60, fill=0)  # both planes seen edge-on
    assert side.axis_labels == ("X (file units)", "Z (file units)")  # no CRS: no unit claimed
    top_row = side.value[0][side.filled[0]]
    bottom_row = side.value[-1][side.filled[-1]]
    assert (top_row == 6).all() and (bottom_row == 2).all()


def test_bbox_restricts_the_points_and_is_the_frame(tmp_path):
    xy = grid_xy(200)
    cls = np.where(xy[:, 0] < 5, 2, 6).astype(np.uint8) + (xy[:, 1] > 7).astype(np.uint8)
    path = write_las(tmp_path / "bbox.las", np.column_stack([xy, np.ones(len(xy))]), classification=cls)
    full = render_array(path, color="classification", view="top", width=100, fill=0)
    part = render_array(path, color="classification", view="top", width=50, bbox=(X0, Y0, X0 + 5.0, Y0 + 10.0), fill=0)
    assert full.rgb.shape == (100, 100, 3) and part.rgb.shape == (100, 50, 3)
    assert np.array_equal(part.rgb, full.rgb[:, :50]) and np.array_equal(part.value, full.value[:, :50], equal_nan=True)
    inside = (xy[:, 0] <= 5.0)
    assert part.points_in_box == int(inside.sum())
    assert not (part.value == 6).any() and (full.value == 6).any()
    # a bbox over part of the file in the oblique view: the points outside it are not drawn
    ob = render_array(path, color="classification", view="oblique", width=80, bbox=(X0 + 6, Y0, X0 + 10, Y0 + 10))
    assert set(np.unique(ob.value[ob.filled])) <= {6.0, 7.0}
    with pytest.raises(PatchcloudValueError, match="bbox"):
        render_array(path, color="classification", bbox=(X0 + 5, Y0, X0, Y0 + 1))
    with pytest.raises(PatchcloudValueError, match=r"bbox.las: the box x .* lies outside the input's bounds .*: nothing to draw"):
        render_array(path, color="classification", bbox=(X0 - 10, Y0 - 10, X0 - 5, Y0 - 5))
    for bad in ((1.0, 1.0), (5.0, 1.0), (0.0, float("nan"))):  # a range of nothing, upside down, not a number
        with pytest.raises(PatchcloudValueError, match="value_range must be two finite numbers, low < high"):
            render_array(path, color="elevation", value_range=bad)


def test_segment_zero_is_grey_and_patch_boundaries_are_darkened(tmp_path):
    xy = grid_xy(100)
    seg = np.where(xy[:, 0] < 5, 0, 3).astype(np.uint64)
    patch = np.where(xy[:, 0] < 5, 11, 12).astype(np.uint32)
    path = write_las(tmp_path / "seg.las", np.column_stack([xy, np.zeros(len(xy))]), ClusterID=seg, PatchId=patch)
    img = render_array(path, color="segments", view="top", width=50, fill=0)
    assert np.allclose(img.rgb[:, :25], NO_SEGMENT) and np.allclose(img.rgb[:, 25:], segment_colours(np.array([3]))[0])
    p = render_array(path, color="patches", view="top", width=50, fill=0)
    c11, c12 = patch_colours(np.array([11, 12]))
    assert np.allclose(p.rgb[:, 24], c11 * BOUNDARY_DARKEN) and np.allclose(p.rgb[:, 25], c12 * BOUNDARY_DARKEN)
    assert np.allclose(p.rgb[:, :24], c11) and np.allclose(p.rgb[:, 26:], c12)


def test_render_writes_a_png_and_the_cli_reports_a_missing_dimension(tmp_path):
    xy = grid_xy(40)
    path = write_las(tmp_path / "raw.las", np.column_stack([xy, xy[:, 0] * 0.1]), classification=np.full(len(xy), 2, np.uint8))
    out = tmp_path / "raw.png"
    s = render(path, out, color="elevation", width=120)
    assert out.read_bytes()[:4] == b"\x89PNG" and s.width == 120 and s.view == "top" and not s.shaded
    assert s.points_read == len(xy) and s.points_drawn <= s.pixels_filled
    assert np.isclose(s.value_range[0], 0.02, atol=0.02) and np.isclose(s.value_range[1], 0.98, atol=0.02)
    png = imread(str(out))
    assert png.shape[1] == 120 and png.shape[0] == s.height
    bad = tmp_path / "bad.png"
    r = CliRunner().invoke(main, ["render", str(path), str(bad), "--color", "patches"])
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:")
    assert "raw.las" in lines[0] and "PatchId" in lines[0] and "supports: classification, intensity, elevation" in lines[0]
    assert not bad.exists() and not (tmp_path / "bad.png.partial").exists()
    r = CliRunner().invoke(main, ["render", str(path), str(bad), "--color", "elevation", "--shade"])
    assert r.exit_code == 2 and "NormalX" in r.stderr and not bad.exists()
    r = CliRunner().invoke(main, ["render", str(tmp_path / "nope.las"), str(bad), "--color", "elevation"])
    assert r.exit_code == 2 and "nope.las" in r.stderr and not bad.exists()
    r = CliRunner().invoke(main, ["render", str(path), str(bad), "--color", "classification", "--range", "0", "1"])
    assert r.exit_code == 2 and not bad.exists(), r.output  # a colour range that would change nothing: said, not ignored
    assert r.stderr.strip().splitlines() == ["error: --range sets the colour range of curvature, don, elevation, intensity; "
                                             "colour classification has none: leave it out"], r.stderr
    r = CliRunner().invoke(main, ["render", str(path), str(out), "--color", "classification", "--view", "side", "--width", "90"])
    assert r.exit_code == 0, r.output
    assert "90 x" in r.output and "side view" in r.output


def test_render_tiles_shows_pending_and_done_columns(tmp_path):
    xy = grid_xy(100, 16.0)
    path = write_las(tmp_path / "t.las", np.column_stack([xy, np.zeros(len(xy))]))
    url = str(tmp_path / "t.zarr")
    r = CliRunner().invoke(main, ["tile", str(path), url, "--tile-size", "4", "--scheduler", "synchronous", "-q"])
    assert r.exit_code == 0, r.output
    st = Store.open(url)
    ts = tile_state(url)
    assert ts.step == "sort" and ts.counts()["done"] == len(ts.columns) and ts.points.sum() == len(xy)
    ts = tile_state(url, "fit")
    ncol = len(ts.columns)
    assert ncol >= 4 and ts.counts() == {"failed": 0, "done": 0, "partly done": 0, "pending": ncol}
    st.mark_tile(st.tiles[0], "records")  # a job's own bookkeeping step (compress') is not the default one to show
    assert tile_state(url).step == "sort"
    first = st.tiles[0]
    st.mark_tile(first, "fit", fit={"patches": 7})
    out = tmp_path / "tiles.png"
    s = render_tiles(url, out, step="fit", by="patches")
    assert (s.done, s.pending, s.partly_done, s.tiles_done, s.patches) == (1, ncol - 1, 0, 1, 7)
    assert s.points == len(xy)
    png = imread(str(out))[..., :3]
    def count(rgb):
        return int((np.abs(png - np.asarray(rgb)).max(axis=2) < 0.02).sum())
    done_px, pending_px = count(STATE_COLOURS["done"]), count(STATE_COLOURS["pending"])
    assert done_px > 0 and pending_px > (ncol - 2) * done_px  # about one square per column
    r = CliRunner().invoke(main, ["render-tiles", url, str(out)])
    assert r.exit_code == 0 and "step fit: 1 of" in r.output  # default: the last step any tile reached
    r = CliRunner().invoke(main, ["render-tiles", url, str(tmp_path / "x.png"), "--step", "nonsense"])
    assert r.exit_code == 2 and "nonsense" in r.stderr and not (tmp_path / "x.png").exists()
    r = CliRunner().invoke(main, ["render-tiles", str(path), str(tmp_path / "x.png")])
    assert r.exit_code == 2 and "not a patchcloud store" in r.stderr


def _fails_on_the_first_tile(url, ijk, first):
    if tuple(ijk) == tuple(first):
        raise RuntimeError("disk full (a test)")
    Store.open(url).mark_tile(ijk, "fit", fit={"patches": 1})


def _succeeds(url, ijk, first):
    Store.open(url).mark_tile(ijk, "fit", fit={"patches": 1})


def test_render_tiles_shows_a_failed_tile_until_it_succeeds(tmp_path):
    from patchcloud.stream import map_tiles

    xy = grid_xy(100, 16.0)
    path = write_las(tmp_path / "t.las", np.column_stack([xy, np.zeros(len(xy))]))
    url = str(tmp_path / "t.zarr")
    assert CliRunner().invoke(main, ["tile", str(path), url, "--tile-size", "4", "-q"]).exit_code == 0
    st = Store.open(url)
    first = st.tiles[0]
    with pytest.raises(RuntimeError, match="disk full"):
        map_tiles(_fails_on_the_first_tile, st, first=first)
    ts = tile_state(url, "fit")
    assert ts.counts()["failed"] == 1 and ts.errors == [(first, "_fails_on_the_first_tile", "RuntimeError: disk full (a test)")]
    s = render_tiles(url, tmp_path / "tiles.png", step="fit")
    assert s.failed == 1 and "disk full" in s.format()
    png = imread(str(tmp_path / "tiles.png"))[..., :3]
    assert int((np.abs(png - np.asarray(STATE_COLOURS["failed"])).max(axis=2) < 0.02).sum()) > 0
    map_tiles(_succeeds, st, first=first)  # a rerun that works
    assert tile_state(url, "fit").counts()["failed"] == 0


def test_colour_range_counts_drawn_pixels_only():
    # one bright point drawn among dark ones; gap filling copies the dark ones far more often:
    # the range comes from the drawn pixels, each once
    values = np.array([[0.0, 0.0, 0.0, 0.0, 1.0]])
    filled = np.ones((1, 5), dtype=bool)
    drawn = np.array([[True, False, False, False, True]])
    _, rng_drawn, _ = colorize("elevation", values, filled, drawn=drawn)
    _, rng_all, _ = colorize("elevation", values, filled)
    assert rng_drawn[1] > 0.9 and rng_all[1] < rng_drawn[1]


def test_several_colours_from_one_read_equal_one_colour_at_a_time(tmp_path):
    xy = grid_xy(60, 6.0)
    n = len(xy)
    rng = np.random.default_rng(3)
    n3 = np.tile(np.array([-0.196, 0.0, 0.981], dtype=np.float32), (n, 1))
    path = write_las(tmp_path / "m.las", np.column_stack([xy, 0.2 * xy[:, 0]]), NormalX=n3[:, 0].copy(),
                     NormalY=n3[:, 1].copy(), NormalZ=n3[:, 2].copy(), Curvature=rng.uniform(0, 0.1, n).astype(np.float32),
                     classification=rng.integers(1, 7, n).astype(np.uint8))
    colours = ["normals", "curvature", "elevation", "classification"]
    together = render_arrays(path, colors=colours, width=120, chunk=1000)
    for img, colour in zip(together, colours):
        alone = render_array(path, color=colour, width=120)
        assert img.color == colour and np.array_equal(img.rgb, alone.rgb) and img.value_range == alone.value_range


def test_outliers_far_above_do_not_spoil_the_framing(tmp_path):
    # an aerial-like 40 m tile, 3 m high, with three "birds" 500 m up and one low return 80 m down
    xy = grid_xy(80, 40.0)
    z = 0.05 * xy[:, 0]
    xyz = np.vstack([np.column_stack([xy, z]), [[10.0, 10.0, 500.0], [20.0, 20.0, 510.0], [30.0, 5.0, 505.0], [5, 5, -80.0]]])
    path = write_las(tmp_path / "o.las", xyz)
    robust = render_array(path, color="elevation", width=200)
    everything = render_array(path, color="elevation", width=200, heights="all")
    assert robust.view == "top" and everything.view == "oblique"  # the 590 m of outliers made the tile look tall
    assert robust.value_range[1] < 3.0  # the colours span the tile, not the birds (2nd-98th percentiles)
    side = render_array(path, color="elevation", width=200, view="side")
    assert side.rgb.shape[0] < 40 and side.points_in_box == len(xy)  # a flat strip, not a 590 m tall frame; birds outside
    tall = render_array(path, color="elevation", width=200, view="side", heights="all")
    assert tall.rgb.shape[0] > 10 * side.rgb.shape[0] and tall.points_in_box == len(xyz)
    with pytest.raises(PatchcloudValueError, match="heights must be one of robust, all"):
        render_array(path, color="elevation", heights="some")
    for bad in (-1, 65, "2", True):
        with pytest.raises(PatchcloudValueError, match="fill must be a gap-filling radius in pixels from 0"):
            render_array(path, color="elevation", fill=bad)


def test_undefined_don_and_left_out_normals_show_the_undefined_grey():
    """The outputs hold DoN 0 where it is undefined, and normal (0, 0, 0) for a point left out (their declared no-data):
    the picture shows them UNDEFINED grey, not the colour map's low end, and the colour range leaves them out."""
    from patchcloud.stream.views.render import UNDEFINED, colorize

    don = np.array([[0.0, 0.1, 0.2, 0.3]])
    filled = np.ones_like(don, dtype=bool)
    rgb, rng, _ = colorize("don", don, filled)
    assert rgb[0, 0].tolist() == list(UNDEFINED)
    assert all(rgb[0, i].tolist() != list(UNDEFINED) for i in (1, 2, 3))
    assert rng[0] >= 0.1  # the 2nd percentile of 0.1, 0.2, 0.3, not of the zeros
    normals = np.array([[[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]])
    rgb, _, _ = colorize("normals", normals, np.ones((1, 2), dtype=bool))
    assert rgb[0, 0].tolist() == list(UNDEFINED) and rgb[0, 1].tolist() == [0.5, 0.5, 1.0]
    rgb, _, _ = colorize("curvature", don, filled)  # a curvature of 0 is a plane's: coloured
    assert rgb[0, 0].tolist() != list(UNDEFINED)


def test_a_picture_named_other_than_png_is_refused_before_anything_is_drawn(tmp_path):
    """PNG bytes under a .jpg name mislead every viewer: one line, nothing written."""
    src = tmp_path / "in.las"
    write_las(src, np.random.default_rng(0).uniform(0, 10, (500, 3)))
    out = tmp_path / "out.jpg"
    r = CliRunner().invoke(main, ["render", str(src), str(out), "--color", "elevation", "-q"])
    assert r.exit_code == 2 and r.output.count("\n") == 1 and "out.jpg: a PNG is written: name it out.png" in r.output, r.output
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["in.las"]


def test_two_outliers_do_not_turn_a_tile_read_whole_into_an_oblique_view(tmp_path):
    """A tile 50 m wide whose points span 23.5 m of height (under half its width: a top view), with a bird 500 m up and
    a return 80 m down: the view stays the top one.  The framing's room past the heights it found, clipped only by the
    header's bounds, which the outliers widen, grew the range by a tenth (bug hunt I)."""
    import json

    rng = np.random.default_rng(11)
    n = 20_000
    x, y = rng.uniform(0.0, 50.0, n), rng.uniform(0.0, 50.0, n)
    z = np.where(x > 25.0, 23.5 * (x - 25.0) / 25.0, 0.0) + rng.normal(0.0, 0.02, n)
    views = []
    for name, outliers in (("clean", False), ("birds", True)):
        zz = z.copy()
        if outliers:
            zz[100], zz[200] = 500.0, -80.0
        h = laspy.LasHeader(point_format=1, version="1.2")
        h.scales, h.offsets = np.array([0.01, 0.01, 0.01]), np.array([700000.0, 6600000.0, 0.0])
        las = laspy.LasData(h)
        las.x, las.y, las.z = 700000.0 + x, 6600000.0 + y, zz
        las.classification = np.full(n, 2, np.uint8)
        las.write(str(tmp_path / f"{name}.las"))
        r = CliRunner().invoke(main, ["render", str(tmp_path / f"{name}.las"), str(tmp_path / f"{name}.png"), "--color",
                                      "classification", "-q", "--summary-json", str(tmp_path / f"{name}.json")])
        assert r.exit_code == 0, r.output
        views.append(json.loads((tmp_path / f"{name}.json").read_text())["view"])
    assert views == ["top", "top"]
