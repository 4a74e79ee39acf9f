"""Exact pictures: a PNG exactly --width wide with everything inside it, gap filling without dashes, labels in users' words."""

import itertools

import numpy as np
import pytest
from click.testing import CliRunner
from matplotlib.image import imread
from scipy.spatial import cKDTree

from conftest import ROOT, shared_file
from patchcloud.core.errors import PatchcloudValueError
from patchcloud.stream import render, render_array
from patchcloud.stream.cli import main
from patchcloud.stream.views.render import FILL_SPACINGS, auto_fill, fill_gaps, point_spacing, render_arrays, render_figure
from test_render import X0, Y0, write_las

SAMPLE = ROOT / "data" / "test_data_77055_627760_LA93_IGN69.laz"


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    """A 40 m x 30 m block: ground with a 6 m building (classes 2 and 6), 0.2 m grid, in Lambert-93."""
    c = np.arange(0.1, 40.0, 0.2)
    x, y = np.meshgrid(c, np.arange(0.1, 30.0, 0.2), indexing="ij")
    x, y = x.ravel(), y.ravel()
    house = (x > 10) & (x < 20) & (y > 8) & (y < 18)
    z = np.where(house, 6.0, 0.02 * x)
    cls = np.where(house, 6, 2).astype(np.uint8)
    n = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (x.size, 1))
    rng = np.random.default_rng(5)
    return write_las(tmp_path_factory.mktemp("pictures") / "block.las", np.column_stack([x, y, z]), crs="EPSG:2154",
                     classification=cls, intensity=(rng.random(x.size) * 1000).astype(np.uint16), NormalX=n[:, 0].copy(),
                     NormalY=n[:, 1].copy(), NormalZ=n[:, 2].copy(), Curvature=rng.uniform(0, 0.05, x.size).astype(np.float32))


def texts(fig):
    """(text, window extent in pixels) of every visible text of ``fig``, once drawn."""
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    return [(t.get_text(), t.get_window_extent(r)) for t in fig.findobj(lambda a: type(a).__name__ == "Text")
            if t.get_visible() and t.get_text()]


def assert_all_inside_and_apart(fig):
    """Every text lies inside the figure and no two texts overlap (by more than half a pixel)."""
    W, H = fig.canvas.get_width_height()
    boxes = texts(fig)
    for t, b in boxes:
        assert b.x0 >= -0.5 and b.x1 <= W + 0.5 and b.y0 >= -0.5 and b.y1 <= H + 0.5, (t, b.bounds, (W, H))
    for (t1, b1), (t2, b2) in itertools.combinations(boxes, 2):
        ox = min(b1.x1, b2.x1) - max(b1.x0, b2.x0)
        oy = min(b1.y1, b2.y1) - max(b1.y0, b2.y0)
        assert min(ox, oy) <= 0.5, (t1, t2)


# -- exact widths -------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("width, color, view, bbox", [
    (300, "elevation", "top", None), (800, "classification", "side", None), (1601, "curvature", "oblique", None),
    (300, "classification", "top", (X0 + 1, Y0, X0 + 3, Y0 + 30)),   # 2 m x 30 m: a tall frame, narrower than the picture
    (800, "elevation", "top", (X0, Y0 + 5, X0 + 40, Y0 + 5.5)),      # 40 m x 0.5 m: a strip a few pixels high
    (64, "normals", "top", None),                                    # the narrowest: no axes, the words wrapped
])
def test_the_png_is_exactly_width_pixels_wide_with_everything_inside(block, tmp_path, width, color, view, bbox):
    out = tmp_path / "p.png"
    s = render(block, out, color=color, view=view, bbox=bbox, width=width)
    png = imread(str(out))
    assert png.shape[1] == width and (s.width, s.height) == (png.shape[1], png.shape[0])
    assert f"{width} x {png.shape[0]} px PNG" in s.format()
    assert s.image_width < width and s.image_height > 0
    img = render_arrays(block, colors=[color], view=view, bbox=bbox, width=width, width_of="figure")[0]
    assert img.rgb.shape[:2] == (s.image_height, s.image_width)
    fig = render_figure(img)
    assert fig.canvas.get_width_height() == (width, png.shape[0])
    assert_all_inside_and_apart(fig)
    # the image is in the PNG pixel for pixel, where the layout put it (inside the frame of its axes)
    lay = img.layout
    left = lay.left + (lay.raster - s.image_width) // 2
    rgb = np.floor(img.rgb * 255) / 255
    band = png[:, left:left + s.image_width, :3]
    h = s.image_height
    k = int(np.argmax(rgb.std(axis=(1, 2))))  # the image's most varied row, and the PNG's rows like it
    like = np.flatnonzero(np.all(np.abs(band - rgb[k]) < 1e-6, axis=(1, 2))) - k
    at = [t for t in like if 0 <= t and t + h <= png.shape[0] and np.allclose(band[t:t + h], rgb, atol=1e-6)]
    assert len(at) == 1  # the whole image, in one place


def test_render_width_800_is_800_pixels_from_the_command_line(tmp_path):
    out = tmp_path / "s.png"
    r = CliRunner().invoke(main, ["render", str(SAMPLE), str(out), "--color", "classification", "--width", "800"])
    assert r.exit_code == 0, r.output
    png = imread(str(out))
    assert png.shape[1] == 800 and f"800 x {png.shape[0]} px PNG" in r.output
    r = CliRunner().invoke(main, ["render", str(SAMPLE), str(tmp_path / "t.png"), "--color", "elevation", "--width", "40"])
    assert r.exit_code == 2 and "--width must be 64 to 6000" in r.stderr and not (tmp_path / "t.png").exists()
    with pytest.raises(PatchcloudValueError, match="width must be 64 to 6000"):
        render_array(SAMPLE, color="elevation", width=7000, width_of="figure")


def test_an_image_of_its_own_width_gets_the_margins_beside_it(block):
    img = render_array(block, color="elevation", view="top", width=300)   # the image 300 px wide: the picture is wider
    assert img.rgb.shape[1] == 300 and img.layout is None
    fig = render_figure(img)
    W, _ = fig.canvas.get_width_height()
    assert W > 300 + 40
    assert_all_inside_and_apart(fig)


# -- gap filling --------------------------------------------------------------------------------------------------------
def scan(s=0.25, lines=2.5, size=60.0, lake=(32.0, 28.0, 9.0), angle=20.0):
    """An aerial scan of a flat field: points every ``s`` m along lines ``lines`` x s apart, turned ``angle`` degrees,
    over a ``size`` m square, none in the disc ``lake`` (x, y, radius) -- a real gap."""
    L = lines * s
    half = size * 0.75
    a, b = np.meshgrid(np.arange(-half, half, s), np.arange(-half, half, L), indexing="ij")
    t = np.radians(angle)
    x = size / 2 + a * np.cos(t) - b * np.sin(t)
    y = size / 2 + a * np.sin(t) + b * np.cos(t)
    keep = (x >= 0) & (x <= size) & (y >= 0) & (y <= size) & ((x - lake[0]) ** 2 + (y - lake[1]) ** 2 > lake[2] ** 2)
    return np.column_stack([x[keep], y[keep], np.zeros(keep.sum())]), np.sqrt(s * L)


def test_scan_lines_leave_no_dashes_and_a_lake_stays_empty(tmp_path):
    # 60 m at 800 px: 0.075 m pixels; points 3.3 px apart along lines 10 px apart, so most rows of pixels between the
    # lines hold no point.  k = FILL_SPACINGS = 2 mean spacings sqrt(s L) (5.8 px each).  (The filling by passes that this
    # replaced, 5 passes of 8-neighbours here, left 1,127 empty pixels within 1.25 spacings of a point: dashes.)
    xyz, spacing = scan(lines=3.0)
    path = write_las(tmp_path / "scan.las", np.vstack([xyz, [[0, 0, 0], [60, 60, 0]]]))
    img = render_array(path, color="elevation", view="top", width=800)
    H, W = img.filled.shape
    px = img.pixel
    sp = spacing / px  # the mean spacing in pixels
    assert 5.5 < sp < 6.0
    drawn_only = render_array(path, color="elevation", view="top", width=800, fill=0).filled
    assert drawn_only.mean() < 0.1  # without filling, most pixels are empty
    assert abs(point_spacing(drawn_only) / sp - 1) < 0.15 and img.fill == auto_fill(drawn_only)
    # distance (pixels) from every pixel centre to the nearest point
    cols = (xyz[:, 0] + X0 - img.extent[0]) / px
    rows = (img.extent[3] - (xyz[:, 1] + Y0)) / px
    r, c = np.mgrid[0:H, 0:W]
    d, _ = cKDTree(np.column_stack([rows, cols])).query(np.column_stack([r.ravel() + 0.5, c.ravel() + 0.5]))
    d = d.reshape(H, W)
    k = FILL_SPACINGS
    near = d <= (k - 0.25) * sp  # within k mean spacings, less the estimate's error and a pixel's width
    assert near.mean() > 0.9 and img.filled[near].all()  # no empty pixel (no dash) near a point
    far = d > (k + 0.25) * sp + 1.0
    assert far.sum() > 0.5 * np.pi * (9.0 / px - (k + 0.25) * sp - 1) ** 2  # the lake's inside...
    assert not img.filled[far].any()  # ...stays empty


def test_fill_gaps_takes_the_nearest_drawn_pixel_within_the_radius():
    drawn = np.zeros((5, 7), bool)
    drawn[0, 0] = drawn[4, 6] = True
    src, filled = fill_gaps(drawn, 2.0)
    d0 = np.hypot(*np.mgrid[0:5, 0:7])  # distance to (0, 0)
    d1 = np.hypot(*(np.mgrid[0:5, 0:7] - np.array([4, 6])[:, None, None]))
    assert np.array_equal(filled, (d0 <= 2) | (d1 <= 2))
    assert (src[d0 <= 2] == 0).all() and (src[d1 <= 2] == 4 * 7 + 6).all()
    assert np.array_equal(fill_gaps(drawn, 0)[1], drawn)
    assert (fill_gaps(drawn, 0)[0] == np.arange(35).reshape(5, 7)).all()


# -- labels ---------------------------------------------------------------------------------------------------------------
def test_labels_are_words_and_units_come_from_the_crs(block, tmp_path):
    words = {"elevation": "Elevation (m)", "curvature": "Curvature", "intensity": "Intensity"}
    for color, label in words.items():
        img = render_array(block, color=color, view="top", width=600, width_of="figure")
        assert img.axis_labels == ("Easting (m)", "Northing (m)")
        shown = [t for t, _ in texts(render_figure(img))]
        assert label in shown and "Easting (m)" in shown and "Northing (m)" in shown
        assert not any(t in shown for t in ("x (m)", "y (m)", "z (m)", "|DoN|"))
    side = render_array(block, color="classification", view="side", width=600, width_of="figure")
    assert side.axis_labels == ("Easting (m)", "Elevation (m)")
    normals = " ".join(t for t, _ in texts(render_figure(render_array(block, color="normals", width=600, width_of="figure"))))
    assert "Normal X" in normals and "Normal Z" in normals
    xyz = np.column_stack([np.arange(100.0) % 10, np.arange(100.0) // 10, np.zeros(100)])
    don = np.linspace(0, 0.5, 100).astype(np.float32)
    for crs, x, z in (("EPSG:2994", "Easting (ft)", "Elevation (ft)"),       # NAD83(HARN) / Oregon GIC Lambert (ft)
                      ("EPSG:2249", "Easting (US ft)", "Elevation (US ft)"),  # NAD83 / Massachusetts Mainland (ftUS)
                      ("EPSG:2154+5720", "Easting (m)", "Elevation (m)"),     # compound: Lambert-93 + NGF-IGN69 height
                      (None, "X (file units)", "Z (file units)")):
        path = write_las(tmp_path / "c.las", xyz, crs=crs, DoN=don)
        img = render_array(path, color="don", view="side", width=400, width_of="figure")
        assert img.axis_labels == (x, z)
        shown = [t for t, _ in texts(render_figure(img))]
        assert x in shown and z in shown and "DoN magnitude" in shown


def test_autzen_in_international_feet_is_labelled_in_feet(tmp_path):
    path = shared_file("lidar-autzen/autzen_trim.laz")
    s = render(path, tmp_path / "a.png", color="elevation", width=500)
    assert s.unit == "ft" and " ft," in s.format()
    img = render_array(path, color="elevation", width=500, width_of="figure")
    assert img.axis_labels == ("Easting (ft)", "Northing (ft)")
    assert "Elevation (ft)" in [t for t, _ in texts(render_figure(img))]


def test_units_override_the_crs_on_the_axes_as_in_the_jobs(tmp_path):
    xyz = np.column_stack([np.arange(100.0) % 10, np.arange(100.0) // 10, np.arange(100.0) / 50])
    path = write_las(tmp_path / "c.las", xyz, crs=None)
    img = render_array(path, color="elevation", view="side", width=400, width_of="figure", units="ft")
    assert img.axis_labels == ("X (ft)", "Z (ft)")
    img = render_array(write_las(tmp_path / "l93.las", xyz, crs="EPSG:2154"), color="elevation", view="top", width=400,
                       width_of="figure", units="us-ft")  # a wrong CRS unit: names from the CRS, unit from --units
    assert img.axis_labels == ("Easting (US ft)", "Northing (US ft)")
    out = tmp_path / "c.png"
    r = CliRunner().invoke(main, ["render", str(path), str(out), "--color", "elevation", "--units", "ft", "--width", "300"])
    assert r.exit_code == 0, r.output
    assert " ft," in r.output and imread(out).shape[1] == 300
    with pytest.raises(PatchcloudValueError, match="units must be one of m, ft, us-ft"):
        render_array(path, color="elevation", units="yd")
    r = CliRunner().invoke(main, ["render", str(path), str(out), "--color", "elevation", "--units", "yd"])
    assert r.exit_code == 2 and "'yd' is not one of" in r.output
