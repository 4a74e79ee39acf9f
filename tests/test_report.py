"""HTML reports (``--report``): one self-contained file, the run's numbers, angle-error and DoN histograms, the CLI."""

import base64
import importlib.util
import re

import laspy
import numpy as np
import pytest
from click.testing import CliRunner

import synthetic
from patchcloud.core.errors import PatchcloudIOError, PatchcloudValueError
from patchcloud.stream import DonSummary, compress, normals, report_compress, report_don, report_normals, segment, write_report
from patchcloud.stream.cli import main
from patchcloud.stream.views.plots import new_figure
from patchcloud.stream.views.report import (
    ReportFigure, ReportTable, check_report_path, don_histogram, figure_png, histogram_figure, normal_statistics, pcz_parts,
    pcz_tiles, segment_sizes,
)

OFFSET = np.array([650000.0, 6860000.0, 40.0])
IMG = '<img src="data:image/png;base64,'

HAVE_RENDER = importlib.util.find_spec("patchcloud.stream.views.render") is not None  # the views need it


def write_las(path, pts, *, normals_as=None, nrm=None, classification=None):
    """A LAS of ``pts`` (local metres, shifted by OFFSET), optionally with reference normals under ``normals_as`` (X, Y, Z names)."""
    h = laspy.LasHeader(point_format=6, version="1.4")
    h.scales = [0.001] * 3
    h.offsets = [OFFSET[0], OFFSET[1], 0.0]
    if normals_as:
        h.add_extra_dims([laspy.ExtraBytesParams(name=d, type=np.float32) for d in normals_as])
    las = laspy.LasData(h)
    las.x, las.y, las.z = (pts + OFFSET).T
    las.intensity = np.arange(len(pts)) % 65535
    if classification is not None:
        las.classification = classification
    if normals_as:
        for d, col in zip(normals_as, nrm.T):
            las[d] = col.astype(np.float32)
    las.write(str(path))
    return path


def rotated(n, degrees):
    """Each unit row of ``n`` turned by ``degrees`` about an axis perpendicular to it."""
    u = np.cross(n, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u, axis=1)[:, None]
    t = np.radians(degrees)
    return np.cos(t) * n + np.sin(t) * u


def scene():
    """Ground (class 2), a 3 m box-shaped building (class 6) and a noisy bush (class 5): about 20k points, 16 m square."""
    rng = np.random.default_rng(3)
    g = rng.uniform(0, 16, (14000, 2))
    g = g[~((g[:, 0] > 4) & (g[:, 0] < 7) & (g[:, 1] > 4) & (g[:, 1] < 7))]
    ground = np.column_stack([g, np.zeros(len(g))])
    walls = []
    for axis in (0, 1):
        for s in (4.0, 7.0):
            q = np.column_stack([rng.uniform(4, 7, 800), rng.uniform(4, 7, 800), rng.uniform(0, 3, 800)])
            q[:, axis] = s
            walls.append(q)
    roof = np.column_stack([rng.uniform(4, 7, (1500, 2)), np.full(1500, 3.0)])
    bush = rng.normal([12.0, 12.0, 1.0], 0.5, (2000, 3))
    pts = np.vstack([ground, *walls, roof, bush])
    cls = np.concatenate([np.full(len(ground), 2), np.full(3200 + 1500, 6), np.full(2000, 5)]).astype(np.uint8)
    perm = rng.permutation(len(pts))
    return pts[perm], cls[perm]


@pytest.fixture(scope="module")
def scene_las(tmp_path_factory):
    pts, cls = scene()
    return write_las(tmp_path_factory.mktemp("report") / "scene.las", pts, classification=cls), len(pts)


@pytest.fixture(scope="module")
def plane_xyz():
    return synthetic.plane(np.random.default_rng(1), 20000, size=10.0, tilt=(0.1, 0.2))


def images(page):
    """The PNG bytes of every embedded image of ``page``."""
    return [base64.b64decode(m) for m in re.findall(r'<img src="data:image/png;base64,([A-Za-z0-9+/=]+)"', page)]


def assert_self_contained(page):
    assert "http://" not in page and "https://" not in page and 'src="file' not in page
    assert "<script" not in page.lower() and "<link" not in page.lower()
    for png in images(page):
        assert png[:8] == b"\x89PNG\r\n\x1a\n"


# -- the page ---------------------------------------------------------------------------------------------------------
def test_write_report_is_one_self_contained_escaped_file(tmp_path):
    fig, (ax,) = new_figure(3, 2)
    ax.plot([0, 1], [0, 1])
    path = write_report(
        tmp_path / "r.html", title="run <1>", summary_rows=[("points", "1,234,567"), ("note", "a < b & c")],
        figures=[ReportFigure(figure_png(fig), "first <figure>"), (fig, "second")], notes=["<script>alert(1)</script>"],
        tables=[ReportTable("Tiles", ("tile", "points"), (("0 0 0", "12"),))],
    )
    page = path.read_text(encoding="utf-8")
    assert page.count(IMG) == 2 and len(images(page)) == 2
    assert_self_contained(page)
    assert "<td>1,234,567</td>" in page and "a &lt; b &amp; c" in page and "&lt;script&gt;alert(1)&lt;/script&gt;" in page
    assert "<title>run &lt;1&gt;</title>" in page and "first &lt;figure&gt;" in page
    assert [p.name for p in tmp_path.iterdir()] == ["r.html"]  # no .partial left
    with pytest.raises(PatchcloudIOError, match="exists"):
        write_report(path, title="x", summary_rows=[], overwrite=False)
    with pytest.raises(PatchcloudValueError, match="PNG"):
        write_report(tmp_path / "s.html", title="x", summary_rows=[], figures=[(b"GIF89a", "not a png")])
    with pytest.raises(PatchcloudIOError, match="does not exist"):
        write_report(tmp_path / "missing" / "r.html", title="x", summary_rows=[])
    assert not (tmp_path / "s.html").exists()


def test_check_report_path(tmp_path):
    assert check_report_path(tmp_path / "r.html") == tmp_path / "r.html"
    with pytest.raises(PatchcloudIOError, match="does not exist"):
        check_report_path(tmp_path / "no" / "r.html")
    with pytest.raises(PatchcloudIOError, match="is a directory"):
        check_report_path(tmp_path)
    (tmp_path / "r.html").write_text("old")
    with pytest.raises(PatchcloudIOError, match="exists"):
        check_report_path(tmp_path / "r.html")
    check_report_path(tmp_path / "r.html", overwrite=True)
    with pytest.raises(PatchcloudIOError, match="replace the job's file"):
        check_report_path(tmp_path / "out.las", others=[tmp_path / "in.las", tmp_path / "out.las"])


# -- the histograms' data -------------------------------------------------------------------------------------------
def test_don_histogram_bars_are_the_summary_histogram():
    counts = [0] * 50
    counts[0], counts[3], counts[49] = 700, 20, 5
    s = DonSummary("in.las", "out.las", points=800, tiles=1, tile_size=8.0, parameters={}, defined=725, histogram=counts)
    h = don_histogram(s)
    assert h.counts.tolist() == counts and h.total == 725
    assert np.allclose(h.edges, np.arange(51) / 50)
    fig = histogram_figure(h, title="t", xlabel="x")
    bars = fig.axes[0].patches
    assert [b.get_height() for b in bars] == counts and np.allclose([b.get_x() for b in bars], h.edges[:-1])


def test_angle_errors_of_a_plane_with_true_reference_normals_are_all_below_one_degree(plane_xyz, tmp_path):
    pts, nrm = plane_xyz
    path = write_las(tmp_path / "plane.las", pts, normals_as=("NormalX", "NormalY", "NormalZ"), nrm=nrm)
    s = normals(path, tmp_path / "out.las", scheduler="synchronous", quiet=True)
    st = normal_statistics(s.output, s.input, chunk=6000)  # several chunks of both files
    assert st.reference.startswith("NormalX/NormalY/NormalZ of the input")
    assert st.angles.total == len(pts) and st.angles.counts[0] == len(pts)  # every point in [0, 1) degrees
    assert st.curvature.total == len(pts)
    page = report_normals(s, tmp_path / "r.html", views=False).read_text()
    assert "20,000" in page and "angle error: mean" in page and page.count(IMG) == 3  # angles, curvature, methods
    assert_self_contained(page)


@pytest.mark.parametrize("degrees, bins", [(10.5, [10]), (10.0, [9, 10])])
def test_angle_errors_of_reference_normals_turned_by_ten_degrees_fall_in_the_ten_degree_bin(plane_xyz, tmp_path, degrees, bins):
    """TrueNormalX/Y/Z (as the synthetic city writes them) turned by 10.5 degrees: all in [10, 11); by 10: within rounding of 10."""
    pts, nrm = plane_xyz
    path = write_las(tmp_path / "plane.las", pts, normals_as=("TrueNormalX", "TrueNormalY", "TrueNormalZ"), nrm=rotated(nrm, degrees))
    s = normals(path, tmp_path / "out.las", scheduler="synchronous", quiet=True)
    st = normal_statistics(s.output, s.input)
    assert st.reference.startswith("TrueNormalX/TrueNormalY/TrueNormalZ")
    assert st.angles.counts[bins].sum() == len(pts) == st.angles.total
    assert abs(st.mean_angle - degrees) < 0.05


def test_without_reference_normals_the_report_says_so(scene_las, tmp_path):
    path, n = scene_las
    s = normals(path, tmp_path / "out.las", scheduler="synchronous", quiet=True)
    st = normal_statistics(s.output, s.input)
    assert st.angles is None and st.reference is None and st.curvature.total == n
    page = report_normals(s, tmp_path / "r.html", views=False).read_text()
    assert "no reference normals" in page and f"{n:,}" in page and page.count(IMG) == 2  # curvature, methods
    assert "<th>units</th><td>m (metre, 1 m; assumed: no CRS): every length here" in page  # (review N: no unit said)


def test_zero_reference_normals_are_not_compared(plane_xyz, tmp_path):
    pts, nrm = plane_xyz
    path = write_las(tmp_path / "plane.las", pts, normals_as=("TrueNormalX", "TrueNormalY", "TrueNormalZ"), nrm=0 * nrm)
    s = normals(path, tmp_path / "out.las", scheduler="synchronous", quiet=True)
    st = normal_statistics(s.output, s.input)
    assert st.angles.total == 0 and np.isnan(st.mean_angle)
    page = report_normals(s, tmp_path / "r.html", views=False).read_text()
    assert "are all zero or not finite" in page and page.count(IMG) == 2


def test_segment_sizes_are_counted_over_chunks(tmp_path):
    ids = np.array([0, 1, 1, 2, 2, 2, 0, 4, 2, 1], dtype=np.uint64)
    pts = np.column_stack([np.arange(ids.size, dtype=float), np.zeros(ids.size), np.zeros(ids.size)])
    h = laspy.LasHeader(point_format=6, version="1.4")
    h.scales, h.offsets = [0.001] * 3, [0.0] * 3
    h.add_extra_dims([laspy.ExtraBytesParams(name="ClusterID", type=np.uint64)])
    las = laspy.LasData(h)
    las.x, las.y, las.z = pts.T
    las["ClusterID"] = ids
    las.write(str(tmp_path / "s.las"))
    assert segment_sizes(tmp_path / "s.las", chunk=3).tolist() == [3, 4, 0, 1]
    with pytest.raises(PatchcloudIOError, match="no ClusterID"):
        segment_sizes(write_las(tmp_path / "plain.las", pts))


def test_don_and_compress_reports(scene_las, tmp_path):
    path, n = scene_las
    s = segment(path, tmp_path / "seg.las", r_small=0.3, r_large=1.5, threshold=0.1, tolerance=0.3, min_cluster=10,
                scheduler="synchronous", quiet=True)
    page = report_don(s, tmp_path / "seg.html", views=False).read_text()
    assert f"<td>{n:,}</td>" in page and f"<td>{s.segments:,}</td>" in page and page.count(IMG) == 2  # DoN, sizes
    assert f"{s.defined:,} ({s.defined / n:.1%})" in page and "<th>units</th><td>m (" in page
    assert_self_contained(page)
    assert segment_sizes(s.output).size == s.segments

    c = compress(path, tmp_path / "c.pcz", max_error=0.02, tile_size=8, scheduler="synchronous", quiet=True)
    parts = pcz_parts(c.output)
    assert sum(parts.values()) == c.output_bytes
    t = pcz_tiles(c.output)
    assert len(t["ijk"]) > 1 and t["patches"].sum() == c.patches and t["residual"].sum() == c.residual
    assert (t["patch_points"] + t["residual"]).sum() == n
    page = report_compress(c, tmp_path / "c.html", views=False).read_text()
    assert f"<td>{n:,}</td>" in page and f"<td>{c.output_bytes:,} bytes" in page and page.count(IMG) == 2
    assert "<th>units</th><td>m (" in page and "{&#x27;symbol&#x27;" not in page and "{'symbol'" not in page  # not the raw dict
    assert page.count("<tr>") >= len(t["ijk"]) + 1  # one row per tile, plus the summary's
    assert_self_contained(page)


# -- the command line -----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("command, extra, views", [
    ("normals", [], 3), ("don", ["--rs", "0.3", "--rl", "1.5"], 1),
    ("segment", ["--rs", "0.3", "--rl", "1.5", "--threshold", "0.1", "--min-points", "10"], 2),
    ("compress", ["--max-error", "0.02"], 2),
])
def test_cli_report(scene_las, tmp_path, command, extra, views):
    path, n = scene_las
    out = tmp_path / ("out.pcz" if command == "compress" else "out.las")
    report = tmp_path / "r.html"
    r = CliRunner().invoke(main, [command, str(path), str(out), "--scheduler", "synchronous", "--report", str(report), *extra])
    assert r.exit_code == 0, r.output
    assert f"report          {report}" in r.output
    page = report.read_text()
    assert f"<td>{n:,}</td>" in page
    assert_self_contained(page)
    figures = {"normals": 2, "don": 1, "segment": 2, "compress": 2}[command]
    assert page.count(IMG) == figures + (views if HAVE_RENDER else 0)


@pytest.mark.parametrize("command", ["normals", "don", "segment", "compress"])
def test_cli_report_in_a_missing_directory_is_refused_before_the_job(scene_las, tmp_path, command):
    path, _ = scene_las
    out = tmp_path / "out.las"
    r = CliRunner().invoke(main, [command, str(path), str(out), "--scheduler", "synchronous", "-q",
                                  "--report", str(tmp_path / "missing" / "r.html")])
    assert r.exit_code == 2
    assert r.output.startswith("error:") and r.output.count("\n") == 1 and "does not exist" in r.output
    assert list(tmp_path.iterdir()) == []  # no output, no store, no .partial


def test_cli_existing_report_needs_overwrite(scene_las, tmp_path):
    path, _ = scene_las
    (tmp_path / "r.html").write_text("old")
    r = CliRunner().invoke(main, ["don", str(path), str(tmp_path / "o.las"), "-q", "--report", str(tmp_path / "r.html")])
    assert r.exit_code == 2 and "exists" in r.output and not (tmp_path / "o.las").exists()
    assert (tmp_path / "r.html").read_text() == "old"


def test_a_don_report_without_any_defined_don_says_none_not_nan():
    from patchcloud.stream.jobs.don import DonSummary
    from patchcloud.stream.views.report import don_rows

    s = DonSummary(input="in.las", output="out.las", points=500, tiles=1, tile_size=64.0,
                   parameters=dict(r_small=0.2, r_large=2.0, mode="fast"), defined=0, histogram=[0] * 50)
    rows = dict(don_rows(s))
    assert rows["median DoN magnitude"] == "none (no DoN defined)" and rows["DoN defined"] == "0 (0.0%)"
    assert "nan" not in " ".join(v for _, v in don_rows(s))


def test_reports_count_the_points_left_out_and_tell_them_from_undefined_don(scene_las, tmp_path):
    """With --classes 2,6 the bush (class 5) is left out: the normals and DoN reports have the summary's "left out" row
    (they had none, and their tables added up to the selected points only), and the DoN report's note counts only the
    selected points without a DoN (it gave every left-out point the reason "fewer than 3 points in a ball")."""
    from patchcloud.stream import don

    path, n = scene_las
    bush = int((laspy.read(path).classification == 5).sum())
    s = normals(path, tmp_path / "n.las", classes=(2, 6), scheduler="synchronous", quiet=True)
    page = report_normals(s, tmp_path / "n.html", views=False).read_text()
    assert f"<th>left out</th><td>{bush:,} ({bush / n:.1%}): {bush:,} not of classes 2, 6" in page
    d = don(path, tmp_path / "d.las", r_small=0.3, r_large=1.5, classes=(2, 6), scheduler="synchronous", quiet=True)
    page = report_don(d, tmp_path / "d.html", views=False).read_text()
    assert f"<th>left out</th><td>{bush:,} (" in page
    undefined = n - d.defined - bush
    assert (f"{undefined:,} points have no DoN" in page) == (undefined > 0)
    assert f"{n - d.defined:,} points have no DoN" not in page


def test_report_compress_of_a_catalogs_summaries_is_the_catalogs_report(scene_las, tmp_path):
    """compress of a catalog (out_dir) returns a list of summaries: report_compress takes it and writes the catalog's
    report (it raised AttributeError: 'list' object has no attribute 'points'), with its counts as thousands."""
    import shutil

    path, n = scene_las
    (tmp_path / "in").mkdir()
    for name in ("a.las", "b.las"):
        shutil.copy(path, tmp_path / "in" / name)
    summaries = compress(tmp_path / "in", out_dir=tmp_path / "o", max_error=0.02, scheduler="synchronous", quiet=True)
    page = report_compress(summaries, tmp_path / "c.html", views=False).read_text()
    assert "patchcloud compress: 2 files" in page and f"<td>{2 * n:,}</td>" in page and "kept exactly" not in page
    single = report_compress(summaries[0], tmp_path / "one.html", views=False).read_text()
    assert f"<th>cells</th><td>{summaries[0].cells:,}</td>" in single


def test_a_points_mode_report_says_no_point_is_modelled():
    """compress --keep-points models no point: its report said 'mean error of the modelled points 0.0000 m' (bug hunt I)."""
    from patchcloud.stream.jobs.compress import CompressSummary
    from patchcloud.stream.views.report import compress_rows

    base = dict(input="a.las", output="a.pcz", points=100, patches=0, cells=0, residual=100, max_error=0.02, mean_error=0.0,
                input_bytes=1000, output_bytes=500, seconds={}, peak_memory=0)
    known = {f for f in CompressSummary.__dataclass_fields__}
    rows = dict(compress_rows(CompressSummary(**{k: v for k, v in base.items() if k in known})))
    assert rows["mean error of the modelled points"].startswith("none modelled")
    modelled = dict(compress_rows(CompressSummary(**{k: v for k, v in {**base, "residual": 40, "mean_error": 0.004}.items() if k in known})))
    assert modelled["mean error of the modelled points"].startswith("0.0040")
