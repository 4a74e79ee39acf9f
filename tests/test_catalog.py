"""Catalogs: several files taken as one cloud give, per point, what the merged file gives; bad catalogs give one clear error."""

import json
import os

import laspy
import numpy as np
import pytest
from click.testing import CliRunner
from pyproj import CRS
from test_stream import write_scene

from patchcloud.core import PatchcloudIOError, PatchcloudValueError
from patchcloud.stream import compress, decompress, don, normals, segment
from patchcloud.stream.cli import main
from patchcloud.stream.engine.ingest import auto_tile_size, check_points_per_tile
from patchcloud.stream.io.catalog import open_catalog
from patchcloud.stream.io.crs import is_crs_record
from patchcloud.stream.io.las_records import file_records

N = 40_000
TILE = 16.0  # the 40 m scene in several tiles: file boundaries and tile faces both cut it


def _split(las, idx, path, point_format=None, scale=None, offset=None, crs=None):
    """Points ``idx`` of ``las`` as a new file (optionally another point format, scale, offset, CRS)."""
    h = laspy.LasHeader(point_format=point_format or las.header.point_format.id, version="1.4")
    h.scales = las.header.scales if scale is None else np.asarray(scale)
    h.offsets = las.header.offsets if offset is None else np.asarray(offset)
    for dim in las.point_format.extra_dimensions:
        h.add_extra_dims([laspy.ExtraBytesParams(dim.name, dim.dtype)])
    if crs is not None:
        h.add_crs(CRS.from_user_input(crs))
    out = laspy.LasData(h)
    out.x, out.y, out.z = np.asarray(las.x)[idx], np.asarray(las.y)[idx], np.asarray(las.z)[idx]
    out.intensity = np.asarray(las.intensity)[idx]
    out.write(str(path))


@pytest.fixture(scope="module")
def cut(tmp_path_factory):
    """The scene cut into 4 files by x and y (spatial boundaries, as tiles of a survey), and the merged file of them."""
    d = tmp_path_factory.mktemp("catalog")
    whole = d / "whole.las"
    write_scene(whole, n=N, seed=11)
    las = laspy.read(str(whole))
    x, y = np.asarray(las.x), np.asarray(las.y)
    q = (x > np.median(x)).astype(int) + 2 * (y > np.median(y))
    (d / "in").mkdir()
    parts = [np.flatnonzero(q == k) for k in range(4)]
    for k, idx in enumerate(parts):
        _split(las, idx, d / "in" / f"tile_{k}.las", crs="EPSG:2154")
    merged = d / "merged.las"
    _split(las, np.concatenate(parts), merged, crs="EPSG:2154")
    return d, merged


def _concat(paths):
    return np.concatenate([laspy.read(str(p)).points.array for p in paths])


def _same_records(a, b, names):
    for n in names:
        assert np.array_equal(a[n], b[n], equal_nan=a[n].dtype.kind == "f"), n


def test_catalog_normals_are_those_of_the_merged_file(cut, tmp_path):
    d, merged = cut
    s = normals(d / "in", out_dir=str(tmp_path / "out"), tile_size=TILE, quiet=True)
    assert s.points == laspy.open(str(merged)).header.point_count
    assert [f[0].rsplit("/", 1)[-1] for f in s.files] == [f"tile_{k}.las" for k in range(4)]
    ref = tmp_path / "merged_out.las"
    normals(merged, ref, tile_size=TILE, quiet=True)
    got = _concat(sorted((tmp_path / "out").iterdir()))
    want = laspy.read(str(ref)).points.array
    _same_records(got, want, ["X", "Y", "Z", "intensity", "NormalX", "NormalY", "NormalZ", "Curvature", "NormalMethod", "PatchId"])
    for k in range(4):  # each output: exactly its input's records, in input order
        a = laspy.read(str(d / "in" / f"tile_{k}.las")).points.array
        b = laspy.read(str(tmp_path / "out" / f"tile_{k}.las")).points.array
        _same_records(b, a, a.dtype.names)
        assert CRS.from_user_input(laspy.read(str(tmp_path / "out" / f"tile_{k}.las")).header.parse_crs()).to_epsg() == 2154


def test_catalog_don_and_segments_are_those_of_the_merged_file(cut, tmp_path):
    d, merged = cut
    kw = dict(r_small=0.5, r_large=2.0, tile_size=TILE, quiet=True)
    don(sorted((d / "in").glob("*.las"))[::-1], out_dir=str(tmp_path / "don"), **kw)  # any order: the catalog sorts
    don(merged, tmp_path / "don.las", **kw)
    _same_records(_concat(sorted((tmp_path / "don").iterdir())), laspy.read(str(tmp_path / "don.las")).points.array,
                  ["DoN", "DoNX", "DoNY", "DoNZ"])
    kw.update(threshold=0.1, tolerance=0.6, min_cluster=5)
    segment(str(d / "in" / "*.las"), out_dir=str(tmp_path / "seg"), **kw)
    segment(merged, tmp_path / "seg.las", **kw)
    got = _concat(sorted((tmp_path / "seg").iterdir()))
    want = laspy.read(str(tmp_path / "seg.las")).points.array
    _same_records(got, want, ["ClusterID"])
    ids = got["ClusterID"]
    assert ids.max() > 1
    # ids are one numbering over the catalog: 1, 2, ... in order of first appearance across the files
    first = ids[ids > 0][np.sort(np.unique(ids[ids > 0], return_index=True)[1])]
    assert np.array_equal(first, np.arange(1, ids.max() + 1))


def test_files_with_other_scales_offsets_and_point_formats(cut, tmp_path):
    """A file in cm with RGB (format 7) beside files in mm (format 6): one common mm grid, each output keeps its format."""
    d, _ = cut
    las = laspy.read(str(d / "whole.las"))
    x = np.asarray(las.x)
    a, b = np.flatnonzero(x <= np.median(x)), np.flatnonzero(x > np.median(x))
    # on the cm grid, offset 10 m away: exactly representable on the mm grid of the first file
    cm = np.round(np.column_stack([np.asarray(las.x)[b], np.asarray(las.y)[b], np.asarray(las.z)[b]]), 2)
    (tmp_path / "in").mkdir()
    _split(las, a, tmp_path / "in" / "a.las", crs="EPSG:2154")
    h = laspy.LasHeader(point_format=7, version="1.4")
    h.scales = np.array([0.01, 0.01, 0.01])
    h.offsets = np.asarray(las.header.offsets) + np.array([10.0, -20.0, 0.0])
    h.add_crs(CRS.from_epsg(2154))
    fb = laspy.LasData(h)
    fb.x, fb.y, fb.z = cm[:, 0], cm[:, 1], cm[:, 2]
    fb.red = np.arange(b.size) % 65535
    fb.write(str(tmp_path / "in" / "b.las"))
    cat = open_catalog(tmp_path / "in")
    assert cat.scale == (0.001, 0.001, 0.001) and cat.factor[1] == (10, 10, 10) and cat.shift[1] == (10_000, -20_000, 0)
    normals(tmp_path / "in", out_dir=str(tmp_path / "out"), tile_size=TILE, quiet=True)
    # the merged file, on the common grid
    merged = tmp_path / "merged.las"
    hm = laspy.LasHeader(point_format=6, version="1.4")
    hm.scales, hm.offsets = las.header.scales, las.header.offsets
    m = laspy.LasData(hm)
    xyz = np.vstack([np.column_stack([np.asarray(las.x)[a], np.asarray(las.y)[a], np.asarray(las.z)[a]]), cm])
    m.x, m.y, m.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    m.write(str(merged))
    normals(merged, tmp_path / "merged_out.las", tile_size=TILE, quiet=True)
    out_a, out_b = laspy.read(str(tmp_path / "out" / "a.las")), laspy.read(str(tmp_path / "out" / "b.las"))
    want = laspy.read(str(tmp_path / "merged_out.las"))
    for name in ("NormalX", "NormalY", "NormalZ", "Curvature", "NormalMethod", "PatchId"):
        assert np.array_equal(np.r_[out_a[name], out_b[name]], want[name]), name
    assert out_b.header.point_format.id == 7 and np.array_equal(out_b.red, fb.red)
    assert np.array_equal(out_b.X, fb.X) and tuple(out_b.header.scales) == (0.01, 0.01, 0.01)


def test_grids_that_cannot_be_merged_exactly_are_refused(cut, tmp_path):
    d, _ = cut
    las = laspy.read(str(d / "in" / "tile_0.las"))
    (tmp_path / "in").mkdir()
    _split(las, np.arange(100), tmp_path / "in" / "a.las", scale=[0.003, 0.003, 0.003], crs="EPSG:2154")
    _split(las, np.arange(100, 200), tmp_path / "in" / "b.las", scale=[0.002, 0.002, 0.002], crs="EPSG:2154")
    with pytest.raises(PatchcloudValueError, match="b.las and .*a.las: .*cannot be put on one integer grid"):
        normals(tmp_path / "in", out_dir=str(tmp_path / "out"), quiet=True)
    assert not (tmp_path / "out").exists()


def test_crs_are_compared_as_crs(cut, tmp_path):
    d, _ = cut
    las = laspy.read(str(d / "in" / "tile_0.las"))
    (tmp_path / "in").mkdir()
    _split(las, np.arange(3000), tmp_path / "in" / "a.las", crs="EPSG:2154")
    _split(las, np.arange(3000, 6000), tmp_path / "in" / "b.las", crs=CRS.from_epsg(2154).to_wkt("WKT1_GDAL"))
    assert open_catalog(tmp_path / "in").crs is not None  # same CRS, other bytes
    _split(las, np.arange(6000, 9000), tmp_path / "in" / "c.las", crs="EPSG:32631")
    with pytest.raises(PatchcloudValueError, match="a.las and .*c.las: different CRSs"):
        open_catalog(tmp_path / "in")
    (tmp_path / "in" / "c.las").unlink()
    _split(las, np.arange(6000, 9000), tmp_path / "in" / "c.las")
    with pytest.raises(PatchcloudValueError, match="c.las: no CRS, while .*a.las has one; give --assume-crs"):
        open_catalog(tmp_path / "in")
    assert open_catalog(tmp_path / "in", assume_crs="EPSG:2154").crs is not None
    with pytest.raises(PatchcloudValueError, match="not the assumed one"):
        open_catalog(tmp_path / "in", assume_crs="EPSG:32631")


def _cli_fails(args, says, tmp_path):
    before = sorted(p for p in tmp_path.rglob("*"))
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and says in lines[0], r.output
    assert sorted(p for p in tmp_path.rglob("*")) == before  # nothing written


def test_bad_catalogs_give_one_clear_error_and_write_nothing(cut, tmp_path):
    d, _ = cut
    (tmp_path / "empty").mkdir()
    _cli_fails(["normals", str(tmp_path / "empty"), "--out-dir", str(tmp_path / "o")], "no LAS/LAZ file", tmp_path)
    (tmp_path / "notes.las").write_text("not a point cloud")
    _cli_fails(["normals", str(d / "in" / "tile_0.las"), str(tmp_path / "notes.las"), "--out-dir", str(tmp_path / "o")],
               "notes.las: not a LAS/LAZ file", tmp_path)
    for k in (1, 2):
        (tmp_path / f"d{k}").mkdir()
        (tmp_path / f"d{k}" / "same.las").write_bytes((d / "in" / f"tile_{k}.las").read_bytes())
    _cli_fails(["normals", str(tmp_path / "d1"), str(tmp_path / "d2"), "--out-dir", str(tmp_path / "o")],
               "two inputs would write the same output", tmp_path)
    _cli_fails(["normals", str(tmp_path / "d1"), "--out-dir", str(tmp_path / "d1" / "out")],
               "inside the input directory", tmp_path)
    _cli_fails(["normals", str(tmp_path / "d1"), str(tmp_path / "x.las")], "is a directory; for a catalog", tmp_path)
    _cli_fails(["normals", str(tmp_path / "d1" / "same.las"), str(tmp_path / "d2" / "same.las"), str(tmp_path / "x.las")],
               "give --out-dir", tmp_path)
    _cli_fails(["normals", str(tmp_path / "d1"), "--out-dir", str(tmp_path / "o"), "--report", str(tmp_path / "no" / "r.html")],
               "does not exist", tmp_path)
    _cli_fails(["compress", str(tmp_path / "d1"), "--out-dir", str(tmp_path / "o"), "--report", str(tmp_path / "no" / "r.html")],
               "does not exist", tmp_path)
    # the same file under two names, by a hard or a symbolic link (a sweep of 2026-11-27: its points were taken twice,
    # or one of the two outputs was not written)
    (tmp_path / "links").mkdir()
    os.link(d / "in" / "tile_1.las", tmp_path / "links" / "hard.las")
    os.symlink(d / "in" / "tile_1.las", tmp_path / "links" / "soft.las")
    for name in ("hard.las", "soft.las"):
        _cli_fails(["normals", str(d / "in" / "tile_1.las"), str(tmp_path / "links" / name), "--out-dir", str(tmp_path / "o")],
                   f"links/{name}: the same file under two names (give it once)", tmp_path)
    from patchcloud.stream.io.catalog import expand_inputs  # the same name twice (a directory and a glob): once

    assert expand_inputs([d / "in", str(d / "in" / "*.las")]) == expand_inputs(d / "in")


def test_compress_of_a_catalog_is_each_file_compressed_alone(cut, tmp_path):
    from check_identical import pcz_digests
    from patchcloud.stream import decompress

    d, _ = cut
    r = CliRunner().invoke(main, ["compress", str(d / "in"), "--out-dir", str(tmp_path / "o"), "-q", "--report", str(tmp_path / "r.html")])
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == [f"tile_{k}.pcz" for k in range(4)]
    page = (tmp_path / "r.html").read_text()  # one report of the four files: totals, a table row per file
    total = sum(laspy.read(str(d / "in" / f"tile_{k}.las")).header.point_count for k in range(4))
    assert "patchcloud compress: 4 files" in page and f"{total:,}" in page
    assert all(f"<td>tile_{k}.las</td>" in page for k in range(4)) and page.count("<img") == 2  # the map, bits per file
    assert "<th>residual points</th>" in page and "kept exactly" not in page  # rounded within the budget, not exact
    alone = tmp_path / "alone.pcz"
    compress(d / "in" / "tile_2.las", alone, quiet=True)
    assert pcz_digests(alone) == pcz_digests(tmp_path / "o" / "tile_2.pcz")
    back = decompress(tmp_path / "o" / "tile_1.pcz", tmp_path / "back.las")
    assert back.residual > 0 and back.reconstructed > 0
    _cli_fails(["compress", str(d / "in"), "--out-dir", str(tmp_path / "o"), "-q"], "exists", tmp_path)  # no --overwrite
    with pytest.raises(PatchcloudIOError, match="is a directory"):
        normals(d / "in", tmp_path / "x.las", quiet=True)


def test_render_of_a_catalog_is_the_picture_of_the_merged_file(cut, tmp_path):
    from patchcloud.stream import render_array

    d, merged = cut
    whole = render_array(merged, color="elevation", width=300, heights="all")
    cat = render_array(d / "in", color="elevation", width=300, heights="all")
    assert cat.point_count == whole.point_count and cat.points_drawn == whole.points_drawn
    np.testing.assert_array_equal(cat.filled, whole.filled)
    np.testing.assert_array_equal(cat.rgb, whole.rgb)  # same frame, same point kept per pixel (ties: the first in the catalog)
    assert cat.source.endswith("tile_0.las and 3 more files")


def test_render_cli_draws_a_catalog_in_one_picture_or_one_per_file(cut, tmp_path):
    d, _ = cut
    r = CliRunner().invoke(main, ["render", str(d / "in" / "tile_0.las"), str(d / "in" / "tile_3.las"), str(tmp_path / "two.png"),
                                  "--color", "intensity", "--width", "200"])
    assert r.exit_code == 0, r.output
    assert "tile_0.las and 1 more file -> " in r.output and (tmp_path / "two.png").read_bytes()[:4] == b"\x89PNG"
    r = CliRunner().invoke(main, ["render", str(d / "in"), "--out-dir", str(tmp_path / "each"), "--color", "elevation",
                                  "--width", "200", "-q"])
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in (tmp_path / "each").iterdir()) == [f"tile_{k}.png" for k in range(4)]
    _cli_fails(["render", str(d / "in"), "--out-dir", str(tmp_path / "n"), "--color", "normals"],
               "needs the dimensions NormalX", tmp_path)


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_a_catalog_report_has_a_row_per_file_one_map_and_the_merged_run_histograms(cut, tmp_path):
    import re

    from patchcloud.stream.views.report import segment_sizes

    d, merged = cut
    opts = ["--rs", "0.3", "--rl", "1.5", "--threshold", "0.1", "--min-points", "10", "-q"]
    r = CliRunner().invoke(main, ["segment", str(d / "in"), "--out-dir", str(tmp_path / "o"), "--report", str(tmp_path / "c.html"), *opts])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["segment", str(merged), str(tmp_path / "m.las"), "--report", str(tmp_path / "m.html"), *opts])
    assert r.exit_code == 0, r.output
    cat, whole = (tmp_path / "c.html").read_text(), (tmp_path / "m.html").read_text()
    for k in range(4):
        assert f"file: tile_{k}.las" in cat
    sizes = segment_sizes([tmp_path / "o" / f"tile_{k}.las" for k in range(4)])
    np.testing.assert_array_equal(sizes, segment_sizes(tmp_path / "m.las"))  # ids span the files: sizes of the merged run
    row = r"segment size: smallest, median, largest</t[hd]><td>([^<]+)<"
    assert re.search(row, cat).group(1) == re.search(row, whole).group(1)
    assert cat.count('<img src="data:image/png;base64,') == whole.count('<img src="data:image/png;base64,')  # one map per view


def _stop_at_the_third_output(monkeypatch):
    """Make the export stop (Ctrl-C) as it finishes its third output file; returns the real finish, to put back."""
    from patchcloud.stream.io import las_output

    finish, calls = las_output.finish, []

    def stop_at_the_third(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt("stopped")
        return finish(*args, **kwargs)

    monkeypatch.setattr(las_output, "finish", stop_at_the_third)
    return finish


def test_a_catalog_stopped_during_its_export_resumes_per_file(cut, tmp_path, monkeypatch):
    import os

    from patchcloud.stream.io import las_output

    d, _ = cut
    clean, out, store = tmp_path / "clean", tmp_path / "out", str(tmp_path / "s.zarr")
    normals(d / "in", out_dir=str(clean), tile_size=TILE, quiet=True)
    finish = _stop_at_the_third_output(monkeypatch)
    with pytest.raises(KeyboardInterrupt):
        normals(d / "in", out_dir=str(out), tile_size=TILE, quiet=True, store=store, scheduler="synchronous")
    monkeypatch.setattr(las_output, "finish", finish)
    assert sorted(p.name for p in out.iterdir() if p.suffix == ".las") == ["tile_0.las", "tile_1.las"]  # no .partial either
    assert not list(out.glob("*.partial"))
    first = {k: (out / f"tile_{k}.las").stat().st_mtime_ns for k in (0, 1)}
    normals(d / "in", out_dir=str(out), tile_size=TILE, quiet=True, store=store, scheduler="synchronous")  # no overwrite needed
    assert {k: (out / f"tile_{k}.las").stat().st_mtime_ns for k in (0, 1)} == first  # kept, not written again
    for k in range(4):
        assert (out / f"tile_{k}.las").read_bytes() == (clean / f"tile_{k}.las").read_bytes(), k
    os.utime(out / "tile_1.las", ns=(first[1] + 10**9, first[1] + 10**9))  # touched since: no longer the store's output
    with pytest.raises(PatchcloudIOError, match="tile_1.las: exists"):
        normals(d / "in", out_dir=str(out), tile_size=TILE, quiet=True, store=store, scheduler="synchronous")


#: The CRS of an IGN tile written by older software: "RGF93 / Lambert-93", the flattening rounded, EPSG:2154.
OLD_IGN_WKT = (
    'PROJCRS["RGF93 / Lambert-93",BASEGEOGCRS["RGF93",DATUM["Reseau Geodesique Francais 1993",ELLIPSOID["GRS 1980",'
    '6378137,298.2572221,LENGTHUNIT["metre",1]]],PRIMEM["Greenwich",0,ANGLEUNIT["degree",0.0174532925199433]],'
    'ID["EPSG",4171]],CONVERSION["Lambert-93",METHOD["Lambert Conic Conformal (2SP)",ID["EPSG",9802]],'
    'PARAMETER["Latitude of false origin",46.5,ANGLEUNIT["degree",0.0174532925199433]],PARAMETER["Longitude of false '
    'origin",3,ANGLEUNIT["degree",0.0174532925199433]],PARAMETER["Latitude of 1st standard parallel",49,ANGLEUNIT['
    '"degree",0.0174532925199433]],PARAMETER["Latitude of 2nd standard parallel",44,ANGLEUNIT["degree",'
    '0.0174532925199433]],PARAMETER["Easting at false origin",700000,LENGTHUNIT["metre",1]],PARAMETER["Northing at '
    'false origin",6600000,LENGTHUNIT["metre",1]]],CS[Cartesian,2],AXIS["easting (X)",east,ORDER[1],LENGTHUNIT['
    '"metre",1]],AXIS["northing (Y)",north,ORDER[2],LENGTHUNIT["metre",1]],ID["EPSG",2154]]'
)

#: The same CRS as a newer GDAL writes it from GeoTIFF keys (an "unnamed" conversion): pyproj finds it equal to
#: EPSG:2154, and OLD_IGN_WKT too, but not the two to each other.
NEW_IGN_WKT = (
    'PROJCRS["RGF93 v1 / Lambert-93",BASEGEOGCRS["RGF93 v1",DATUM["Reseau Geodesique Francais 1993 v1",ELLIPSOID['
    '"GRS 1980",6378137,298.257222101,LENGTHUNIT["metre",1]]],PRIMEM["Greenwich",0,ANGLEUNIT["degree",'
    '0.0174532925199433]],ID["EPSG",4171]],CONVERSION["unnamed",METHOD["Lambert Conic Conformal (2SP)",ID["EPSG",'
    '9802]],PARAMETER["Latitude of false origin",46.5,ANGLEUNIT["degree",0.0174532925199433],ID["EPSG",8821]],'
    'PARAMETER["Longitude of false origin",3,ANGLEUNIT["degree",0.0174532925199433],ID["EPSG",8822]],PARAMETER['
    '"Latitude of 1st standard parallel",49,ANGLEUNIT["degree",0.0174532925199433],ID["EPSG",8823]],PARAMETER['
    '"Latitude of 2nd standard parallel",44,ANGLEUNIT["degree",0.0174532925199433],ID["EPSG",8824]],PARAMETER['
    '"Easting at false origin",700000,LENGTHUNIT["metre",1],ID["EPSG",8826]],PARAMETER["Northing at false origin",'
    '6600000,LENGTHUNIT["metre",1],ID["EPSG",8827]]],CS[Cartesian,2],AXIS["easting",east,ORDER[1],LENGTHUNIT["metre",'
    '1]],AXIS["northing",north,ORDER[2],LENGTHUNIT["metre",1]],ID["EPSG",2154]]'
)


@pytest.mark.parametrize("old_first", [True, False])
def test_one_crs_written_by_two_versions_is_one_crs_whatever_the_order(cut, tmp_path, old_first):
    """IGN's tiles say "RGF93 v1 / Lambert-93" or "RGF93 / Lambert-93" (a rounded flattening), both EPSG:2154: one CRS
    (found by a sweep of 2026-11-27: refused as different CRSs, or not, by the files' order)."""
    d, _ = cut
    las = laspy.read(str(d / "in" / "tile_0.las"))
    (tmp_path / "in").mkdir()
    names = ["a.las", "b.las"] if old_first else ["b.las", "a.las"]
    _split(las, np.arange(3000), tmp_path / "in" / names[0], crs=OLD_IGN_WKT)
    _split(las, np.arange(3000, 6000), tmp_path / "in" / names[1], crs=NEW_IGN_WKT)
    _split(las, np.arange(6000, 7000), tmp_path / "in" / "m.las", crs="EPSG:2154")
    # (pyproj 3.7 with PROJ 9.5 says these two WKTs differ; pyproj 3.8 with PROJ 9.8 finds them equal: either way one CRS here)
    assert CRS.from_wkt(open_catalog(tmp_path / "in").crs).to_epsg() == 2154
    _split(las, np.arange(7000, 9000), tmp_path / "in" / "c.las", crs="EPSG:27572")  # another Lambert, another code
    with pytest.raises(PatchcloudValueError, match="different CRSs"):
        open_catalog(tmp_path / "in")


def test_a_failed_catalog_run_leaves_no_output_directory_and_assume_crs_holds_for_one_file(cut, tmp_path):
    """A run refused after its checks (a tile size too small, the store given as the output directory) leaves no empty
    --out-dir behind; --assume-crs gives one file without a CRS its unit, refuses a file of another CRS, and a
    missing CRS in a catalog is said with the option named once."""
    d, _ = cut
    _cli_fails(["normals", str(d / "in"), "--out-dir", str(tmp_path / "o"), "--tile-size", "0.05"], "--tile-size", tmp_path)
    _cli_fails(["normals", str(d / "in"), "--out-dir", str(tmp_path / "o"), "--store", str(tmp_path / "o")],
               "the store (--store) and the output directory (--out-dir) must differ", tmp_path)
    las = laspy.read(str(d / "in" / "tile_0.las"))
    _split(las, np.arange(3000), tmp_path / "none.las")
    _split(las, np.arange(3000), tmp_path / "utm.las", crs="EPSG:32631")
    r = CliRunner().invoke(main, ["normals", str(tmp_path / "none.las"), str(tmp_path / "o.las"), "--assume-crs", "EPSG:2263"])
    assert r.exit_code == 0 and "units           us-ft (US survey foot" in r.output, r.output
    assert "from the CRS --assume-crs gives" in r.output, r.output  # not "from the CRS": the file has none
    out = laspy.read(str(tmp_path / "o.las"))  # the output says the CRS the run took (as PDAL's a_srs), in WKT for format 6+
    assert out.header.parse_crs().to_epsg() == 2263 and out.header.global_encoding.wkt
    assert np.array_equal(out.points.array["X"], las.points.array["X"][:3000])
    _cli_fails(["normals", str(tmp_path / "utm.las"), str(tmp_path / "u.las"), "--assume-crs", "EPSG:2154"],
               "its CRS is not the assumed one", tmp_path)
    _cli_fails(["normals", str(tmp_path / "utm.las"), str(tmp_path / "none.las"), "--out-dir", str(tmp_path / "o")],
               "has one; give --assume-crs to say which CRS", tmp_path)


def test_info_of_a_catalogs_store_counts_every_file(cut, tmp_path):
    d, merged = cut
    st = tmp_path / "st.zarr"
    normals(d / "in", out_dir=str(tmp_path / "out"), tile_size=TILE, store=str(st), quiet=True)
    r = CliRunner().invoke(main, ["info", str(st)])
    n = laspy.open(str(merged)).header.point_count
    assert r.exit_code == 0 and f"source       4 files, tile_0.las to tile_3.las ({n:,} points)" in r.output, r.output
    shares = [float(ln.split()[-1].rstrip("%")) for ln in r.output.splitlines() if ln.rstrip().endswith("%")]
    assert shares and abs(sum(shares) - 100.0) < 0.5, r.output  # of the catalog's points, not the first file's


def test_a_compressed_catalog_stopped_part_way_resumes_per_file(cut, tmp_path, monkeypatch):
    """compress DIR --out-dir: stopped after its first file, the same command keeps that .pcz (unchanged: recorded
    complete, same parameters, same files) and writes the others, each the bytes of a clean run; with other
    parameters the kept .pcz is refused unless --overwrite, and the record is gone once every file is written."""
    from patchcloud.stream import compress
    from patchcloud.stream.jobs import compress as compress_module

    d, _ = cut
    clean = tmp_path / "clean"
    compress(d / "in", out_dir=str(clean), max_error=0.05, tile_size=TILE, quiet=True)
    real, calls = compress_module.run_job, []

    def stops_at_the_second(*args, **kwargs):
        calls.append(args[2])
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    out = tmp_path / "out"
    monkeypatch.setattr(compress_module, "run_job", stops_at_the_second)
    with pytest.raises(KeyboardInterrupt):
        compress(d / "in", out_dir=str(out), max_error=0.05, tile_size=TILE, quiet=True)
    monkeypatch.setattr(compress_module, "run_job", real)
    first = out / "tile_0.pcz"
    stamp = first.stat().st_mtime_ns
    assert (out / compress_module.CATALOG_RECORD).is_file()
    with pytest.raises(PatchcloudIOError, match="tile_0.pcz: exists"):  # other parameters: not this run's file
        compress(d / "in", out_dir=str(out), max_error=0.1, tile_size=TILE, quiet=True)
    summaries = compress(d / "in", out_dir=str(out), max_error=0.05, tile_size=TILE, quiet=True)
    assert first.stat().st_mtime_ns == stamp and [s.points for s in summaries][0] > 0
    assert not (out / compress_module.CATALOG_RECORD).exists()
    for k in range(4):
        assert (out / f"tile_{k}.pcz").read_bytes() == (clean / f"tile_{k}.pcz").read_bytes()


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_a_compressed_catalog_killed_between_a_pcz_and_its_record_resumes(cut, tmp_path, monkeypatch):
    """A .pcz renamed into place whose completion the record does not hold yet (a kill -9 between the two) is this
    run's: the same command replaces it without --overwrite, and every .pcz is a clean run's (found by a sweep of
    2026-11-27: the rerun said "exists")."""
    from patchcloud.stream import compress
    from patchcloud.stream.jobs import compress as compress_module

    d, _ = cut
    clean, out = tmp_path / "clean", tmp_path / "out"
    compress(d / "in", out_dir=str(clean), max_error=0.05, tile_size=TILE, quiet=True)
    real = compress_module._write_record

    def killed_before_recording_a_finished_file(path, record):
        if any("summary" in e for e in record.values()):
            raise KeyboardInterrupt  # (as kill -9 would stop it: no clean-up of the .pcz)
        real(path, record)

    monkeypatch.setattr(compress_module, "_write_record", killed_before_recording_a_finished_file)
    with pytest.raises(KeyboardInterrupt):
        compress(d / "in", out_dir=str(out), max_error=0.05, tile_size=TILE, quiet=True)
    monkeypatch.setattr(compress_module, "_write_record", real)
    assert (out / "tile_0.pcz").is_file()  # in place, not recorded complete
    compress(d / "in", out_dir=str(out), max_error=0.05, tile_size=TILE, quiet=True)
    for k in range(4):
        assert (out / f"tile_{k}.pcz").read_bytes() == (clean / f"tile_{k}.pcz").read_bytes()


def test_a_catalog_stopped_in_memory_leaves_no_output_and_starts_over(cut, tmp_path, monkeypatch):
    """In memory there is no store to resume from: a catalog stopped after two of its four outputs were complete has
    renamed none of them into place (the renames wait for the last: a kill -9 leaves only .partial files), and the
    same command then runs whole without --overwrite (it found two outputs "exists")."""
    from patchcloud.stream.io import las_output

    d, _ = cut
    clean, out = tmp_path / "clean", tmp_path / "out"
    normals(d / "in", out_dir=str(clean), tile_size=TILE, quiet=True)
    finish = _stop_at_the_third_output(monkeypatch)
    with pytest.raises(KeyboardInterrupt):
        normals(d / "in", out_dir=str(out), tile_size=TILE, quiet=True, in_memory=True)
    monkeypatch.setattr(las_output, "finish", finish)
    assert not out.exists()  # the directory it made, empty again, too
    normals(d / "in", out_dir=str(out), tile_size=TILE, quiet=True, in_memory=True)
    for k in range(4):
        assert (out / f"tile_{k}.las").read_bytes() == (clean / f"tile_{k}.las").read_bytes(), k


def test_review_fixes_glob_with_assume_crs_render_out_dir_and_compress_out_dir(cut, tmp_path):
    """The one-file form takes one file, --assume-crs or not (a glob ran as a catalog, then failed); render --out-dir
    checks every picture's path before it draws the first; a refused catalog compress leaves no --out-dir."""
    import os

    d, _ = cut
    _cli_fails(["normals", str(d / "in" / "tile_[01].las"), str(tmp_path / "o.las"), "--assume-crs", "EPSG:2154"],
               "no such file", tmp_path)
    pics = tmp_path / "pics"
    pics.mkdir()
    (pics / "tile_1.png").write_text("notes")
    _cli_fails(["render", str(d / "in"), "--out-dir", str(pics), "--color", "elevation"], "is not a PNG", tmp_path)
    assert sorted(os.listdir(pics)) == ["tile_1.png"]
    _cli_fails(["compress", str(d / "in"), "--out-dir", str(tmp_path / "nd"), "--tile-size", "0.05"], "--tile-size", tmp_path)


def test_a_catalog_in_memory_renames_no_output_before_the_last_is_complete(cut, tmp_path, monkeypatch):
    """What a kill -9 would find (no clean-up runs then): as the third of four outputs is finished, the two before are
    still .partial files, none in place, so the same command is not refused by a killed run's outputs."""
    from patchcloud.stream.io import las_output

    d, _ = cut
    out = tmp_path / "out"
    finish, seen = las_output.finish, []

    def look_at_the_third(*args, **kwargs):
        seen.append(sorted(p.name for p in out.iterdir()))
        return finish(*args, **kwargs)

    monkeypatch.setattr(las_output, "finish", look_at_the_third)
    normals(d / "in", out_dir=str(out), tile_size=TILE, quiet=True, in_memory=True)
    assert len(seen) == 4 and not [n for n in seen[2] if n.endswith(".las")], seen[2]  # tile_*.las.partial only
    assert sorted(p.name for p in out.iterdir()) == [f"tile_{k}.las" for k in range(4)]


def test_a_run_in_memory_removes_only_the_outputs_it_wrote(cut, tmp_path, monkeypatch):
    """What a failed run in memory removes is what it wrote (the files not as they were), whatever the failure (an
    OSError too); an output it did not touch stays, even one dated in the future."""
    import os

    from patchcloud.stream.io import las_output

    d, _ = cut
    out = tmp_path / "out"
    out.mkdir()
    future = out / "tile_3.las"
    future.write_bytes(b"kept")
    os.utime(future, ns=(4_000_000_000 * 10**9, 4_000_000_000 * 10**9))
    finish, calls = las_output.finish, []

    def full_disk_at_the_second(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise OSError(28, "No space left on device", str(out / "tile_1.las"))
        return finish(*args, **kwargs)

    monkeypatch.setattr(las_output, "finish", full_disk_at_the_second)
    with pytest.raises(PatchcloudIOError, match="tile_1.las: No space left on device"):  # none renamed yet: none removed
        normals(d / "in", out_dir=str(out), tile_size=TILE, quiet=True, in_memory=True, overwrite=True)
    assert sorted(p.name for p in out.iterdir()) == ["tile_3.las"] and future.read_bytes() == b"kept"


def test_info_on_a_missing_path_says_no_such_file_as_every_command(tmp_path):
    r = CliRunner().invoke(main, ["info", str(tmp_path / "nope.laz")])
    assert r.exit_code == 2 and r.output == f"error: {tmp_path / 'nope.laz'}: no such file\n", r.output
    (tmp_path / "x.txt").write_text("hello")
    r = CliRunner().invoke(main, ["info", str(tmp_path / "x.txt")])
    assert r.exit_code == 2 and "x.txt: not a LAS/LAZ file (no 'LASF' signature)" in r.output, r.output
    (tmp_path / "d").mkdir()
    r = CliRunner().invoke(main, ["info", str(tmp_path / "d")])
    assert r.exit_code == 2 and "neither a LAS/LAZ file nor a patchcloud store" in r.output, r.output


def test_assumed_crs_is_written_into_the_outputs_of_files_without_one(cut, tmp_path):
    """--assume-crs: each output of a file without a CRS carries the assumed one (GeoTIFF keys for point formats 0 to 5,
    WKT for 6 and up, as PDAL writes them); a file with its own CRS keeps its records as they were."""
    d, _ = cut
    las = laspy.read(str(d / "in" / "tile_0.las"))
    (tmp_path / "in").mkdir()
    _split(las, np.arange(3000), tmp_path / "in" / "a.las", crs="EPSG:2154")
    _split(las, np.arange(3000, 6000), tmp_path / "in" / "b.las", point_format=1)
    _split(las, np.arange(6000, 9000), tmp_path / "in" / "c.las", point_format=6)
    normals(tmp_path / "in", out_dir=str(tmp_path / "out"), assume_crs="EPSG:2154", quiet=True)
    a, b, c = (laspy.read(str(tmp_path / "out" / f"{k}.las")).header for k in "abc")
    assert [h.parse_crs().to_epsg() for h in (a, b, c)] == [2154, 2154, 2154]
    assert b.vlrs.get("GeoKeyDirectoryVlr") and not b.vlrs.get("WktCoordinateSystemVlr") and not b.global_encoding.wkt
    assert c.vlrs.get("WktCoordinateSystemVlr") and c.global_encoding.wkt
    def crs_records(path):  # its own CRS records, byte for byte
        return [(r.record_id, r.data) for r in file_records(path)[0] if is_crs_record(r)]

    assert crs_records(tmp_path / "out" / "a.las") == crs_records(tmp_path / "in" / "a.las") != []
    # compress keeps it for decompress (both modes); without --assume-crs there is none
    compress(tmp_path / "in" / "b.las", tmp_path / "b.pcz", assume_crs="EPSG:2154", quiet=True)
    compress(tmp_path / "in" / "c.las", tmp_path / "c.pcz", keep_points=True, assume_crs="EPSG:2154", quiet=True)
    compress(tmp_path / "in" / "c.las", tmp_path / "n.pcz", quiet=True)
    for k in "bcn":
        decompress(tmp_path / f"{k}.pcz", tmp_path / f"{k}.las")
    got = [laspy.read(str(tmp_path / f"{k}.las")).header.parse_crs() for k in "bcn"]
    assert [c.to_epsg() for c in got[:2]] == [2154, 2154] and got[2] is None
    # a CRS without an EPSG code is written as WKT whatever the point format (GeoTIFF keys would name a near one,
    # another datum), the same CRS back; degrees and heights alone are refused before anything is written
    lcc = "+proj=lcc +lat_0=41.75 +lon_0=-120.5 +lat_1=43 +lat_2=45.5 +x_0=400000 +y_0=0 +ellps=GRS80 +units=ft +no_defs"
    assert CRS(lcc).to_epsg() == 2992 and CRS(lcc).to_epsg(min_confidence=100) is None  # near EPSG:2992 (NAD83), not it
    normals(tmp_path / "in" / "b.las", tmp_path / "b_lcc.las", assume_crs=lcc, quiet=True)
    h = laspy.read(str(tmp_path / "b_lcc.las")).header
    assert h.vlrs.get("WktCoordinateSystemVlr") and not h.vlrs.get("GeoKeyDirectoryVlr") and h.parse_crs() == CRS(lcc)
    # compress takes files one by one but checks them all first: a file of another CRS leaves nothing written
    (tmp_path / "two").mkdir()
    for k, name in (("b", "a"), ("a", "b")):  # the file without a CRS first, which the assumed CRS would take
        (tmp_path / "two" / f"{name}.las").write_bytes((tmp_path / "in" / f"{k}.las").read_bytes())
    r = CliRunner().invoke(main, ["compress", str(tmp_path / "two"), "--out-dir", str(tmp_path / "pcz"), "--assume-crs", "EPSG:32631"])
    assert r.exit_code == 2 and "b.las: its CRS is not the assumed one" in r.stderr and not (tmp_path / "pcz").exists(), r.stderr
    for bad, says in (("EPSG:4326", "geographic"), ("EPSG:5720", "a vertical CRS alone")):
        r = CliRunner().invoke(main, ["normals", str(tmp_path / "in" / "b.las"), str(tmp_path / "bad.las"), "--assume-crs", bad])
        assert r.exit_code == 2 and f"--assume-crs {bad} is {says}" in r.stderr and not (tmp_path / "bad.las").exists(), r.stderr
        r = CliRunner().invoke(main, ["normals", str(tmp_path / "in" / "b.las"), str(tmp_path / "bad.las"), "--assume-crs", bad,
                                      "--units", "m"])
        assert r.exit_code == 2 and says in r.stderr, r.stderr


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_files_far_apart_get_the_tile_size_of_their_density(cut, tmp_path):
    """Two tiles of a survey 300 km apart: the default tile size and the --tile-size check see the files' boxes, not
    the catalog's box (mostly empty), so the catalog gets the tiles its files would get alone (the box made the default
    tiles 1,000x larger, each file one tile, and refused a tile size fine for each file)."""
    d, _ = cut
    las = laspy.read(str(d / "in" / "tile_0.las"))
    (tmp_path / "in").mkdir()
    _split(las, np.arange(len(las.x)), tmp_path / "in" / "a.las", crs="EPSG:2154")
    far = laspy.read(str(tmp_path / "in" / "a.las"))
    far.x = np.asarray(far.x) + 300_000.0
    far.write(str(tmp_path / "in" / "b.las"))
    one, two = open_catalog(tmp_path / "in" / "a.las"), open_catalog(tmp_path / "in")
    assert two.maxs[0] - two.mins[0] > 300_000
    assert auto_tile_size(two) == auto_tile_size(one) == 128.0  # the box: 4,096 (MAX_TILE)
    check_points_per_tile(one, 1.0)
    check_points_per_tile(two, 1.0)  # the box would leave 0.0007 points per tile
    s = normals(tmp_path / "in", out_dir=str(tmp_path / "out"), tile_size=4.0, quiet=True)
    assert s.points == 2 * len(las.x)


def _empty(path, crs="EPSG:2154", point_format=6):
    h = laspy.LasHeader(point_format=point_format, version="1.4")
    h.scales = np.array([0.05, 0.05, 0.05])  # not on the others' grid: an empty file's scale does not matter
    if crs is not None:
        h.add_crs(CRS.from_user_input(crs))
    laspy.LasData(h).write(str(path))


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_empty_files_of_a_catalog_get_empty_outputs_and_change_nothing_else(cut, tmp_path):
    """Empty tiles (no points; their header bounds 0) among a survey's: each gets an output of its header with the new
    dimensions and no points, LAS and LAZ; the other outputs are those of the catalog without them, byte for byte
    (the zero bounds neither widen the grid nor the tile size); info describes one; a catalog of only empty files is
    one error."""
    d, _ = cut
    (tmp_path / "in").mkdir()
    for k in range(4):
        (tmp_path / "in" / f"tile_{k}.las").write_bytes((d / "in" / f"tile_{k}.las").read_bytes())
    normals(tmp_path / "in", out_dir=str(tmp_path / "ref"), quiet=True)
    _empty(tmp_path / "in" / "empty_a.las")
    _empty(tmp_path / "in" / "empty_b.laz", point_format=1)
    _empty(tmp_path / "empty_c.laz", point_format=8)  # and one that ends with its header (no chunk table), as PDAL reads
    raw = (tmp_path / "empty_c.laz").read_bytes()
    (tmp_path / "in" / "empty_c.laz").write_bytes(raw[: laspy.open(str(tmp_path / "empty_c.laz")).header.offset_to_point_data])
    with_empty, without = open_catalog(tmp_path / "in"), open_catalog(sorted((tmp_path / "in").glob("tile_*.las")))
    assert (with_empty.mins, with_empty.maxs, auto_tile_size(with_empty)) == (without.mins, without.maxs, auto_tile_size(without))
    s = normals(tmp_path / "in", out_dir=str(tmp_path / "out"), quiet=True)
    assert sorted(p.name for p in (tmp_path / "out").iterdir() if p.suffix in (".las", ".laz")) == [
        "empty_a.las", "empty_b.laz", "empty_c.laz", "tile_0.las", "tile_1.las", "tile_2.las", "tile_3.las"]
    n = sum(laspy.open(str(d / "in" / f"tile_{k}.las")).header.point_count for k in range(4))
    assert s.points == n
    for k in range(4):
        a = laspy.read(str(tmp_path / "ref" / f"tile_{k}.las")).points.array
        b = laspy.read(str(tmp_path / "out" / f"tile_{k}.las")).points.array
        _same_records(b, a, a.dtype.names)
    for name in ("empty_a.las", "empty_b.laz", "empty_c.laz"):
        e = laspy.read(str(tmp_path / "out" / name))
        assert e.header.point_count == 0 and len(e.points) == 0
        assert {"NormalX", "NormalY", "NormalZ", "Curvature", "NormalMethod", "PatchId"} <= set(e.point_format.extra_dimension_names)
        assert e.header.parse_crs().to_epsg() == 2154
    seg = segment(tmp_path / "in", out_dir=str(tmp_path / "seg"), quiet=True)
    assert laspy.read(str(tmp_path / "seg" / "empty_b.laz")).header.point_count == 0 and seg.points == n
    for job in ("normals", "don"):  # the report reads the empty outputs too
        r = CliRunner().invoke(main, [job, str(tmp_path / "in"), "--out-dir", str(tmp_path / job), "-q", "--report", str(tmp_path / f"{job}.html")])
        assert r.exit_code == 0 and (tmp_path / f"{job}.html").stat().st_size > 0, r.output
        assert laspy.read(str(tmp_path / job / "empty_a.las")).header.point_count == 0
    r = CliRunner().invoke(main, ["render", str(tmp_path / "in"), "--out-dir", str(tmp_path / "png"), "--width", "120", "--color", "elevation"])
    assert r.exit_code == 0 and f"{tmp_path / 'in' / 'empty_a.las'}: no points, no picture" in r.output, r.output
    assert sorted(p.name for p in (tmp_path / "png").iterdir()) == [f"tile_{k}.png" for k in range(4)]
    r = CliRunner().invoke(main, ["info", str(tmp_path / "in" / "empty_a.las")])
    assert r.exit_code == 0 and "points       0" in r.output and "bounds       none (no points)" in r.output, r.output
    r = CliRunner().invoke(main, ["info", str(tmp_path / "in" / "empty_a.las"), "--json"])
    d = json.loads(r.output)
    assert r.exit_code == 0 and d["point_count"] == 0 and d["mins"] is None and d["maxs"] is None, r.output
    (tmp_path / "none").mkdir()
    _empty(tmp_path / "none" / "a.las")
    _empty(tmp_path / "none" / "b.las")
    with pytest.raises(PatchcloudIOError, match=r"a.las and the other file: every file holds no points"):
        normals(tmp_path / "none", out_dir=str(tmp_path / "o2"), quiet=True)
    with pytest.raises(PatchcloudIOError, match=r"a.las: the file holds no points"):  # one file: nothing to compute
        normals(tmp_path / "none" / "a.las", tmp_path / "o3.las", quiet=True)


def test_a_crs_record_that_cannot_be_read_is_said_not_taken_for_none(cut, tmp_path):
    """A LASF_Projection WKT record that is not WKT: info says it is unreadable, a run says its metres are assumed for
    that reason, a catalog with a file of another CRS names it; --assume-crs replaces it in the output."""
    d, _ = cut
    las = laspy.read(str(d / "in" / "tile_0.las"))
    (tmp_path / "in").mkdir()
    _split(las, np.arange(3000), tmp_path / "in" / "a.las", crs="EPSG:2154")
    _split(las, np.arange(3000, 6000), tmp_path / "in" / "b.las", point_format=6)
    b = laspy.read(str(tmp_path / "in" / "b.las"))
    b.header.vlrs.append(laspy.VLR("LASF_Projection", 2112, "OGC WKT", b"THIS IS NOT WKT[garbage]\0"))
    b.header.global_encoding.wkt = True
    b.write(str(tmp_path / "in" / "b.las"))
    r = CliRunner().invoke(main, ["info", str(tmp_path / "in" / "b.las")])
    assert r.exit_code == 0 and "CRS          unreadable: its CRS record (CRSError" in r.output, r.output
    r = CliRunner().invoke(main, ["normals", str(tmp_path / "in" / "b.las"), str(tmp_path / "b_out.las")])
    assert r.exit_code == 0 and "assumed: its CRS record cannot be read" in r.output, r.output
    r = CliRunner().invoke(main, ["normals", str(tmp_path / "in"), "--out-dir", str(tmp_path / "out")])
    assert r.exit_code == 2 and "b.las: its CRS record cannot be read (CRSError" in r.stderr and "a.las has one" in r.stderr
    normals(tmp_path / "in", out_dir=str(tmp_path / "out"), assume_crs="EPSG:2154", quiet=True)
    assert laspy.read(str(tmp_path / "out" / "b.las")).header.parse_crs().to_epsg() == 2154


def test_a_laz_that_says_no_points_but_holds_chunks_is_refused(cut, tmp_path):
    """Empty files are taken in a catalog, but a LAZ whose header counts 0 points over chunks of points is damaged: one
    error naming what its chunk table holds (taken as empty, its points would be lost without a word)."""
    d, _ = cut
    laspy.read(str(d / "in" / "tile_0.las")).write(str(tmp_path / "z.laz"))
    raw = bytearray((tmp_path / "z.laz").read_bytes())
    n = laspy.open(str(tmp_path / "z.laz")).header.point_count
    raw[107:111] = bytes(4)  # the legacy count
    raw[247:255] = bytes(8)  # LAS 1.4's count
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "z.laz").write_bytes(bytes(raw))
    (tmp_path / "in" / "tile_1.las").write_bytes((d / "in" / "tile_1.las").read_bytes())
    with pytest.raises(PatchcloudIOError, match=rf"z.laz: the header says 0 points but the LAZ chunk table holds {n:,}"):
        open_catalog(tmp_path / "in")


def _write(path, xyz, scale, offset=(0.0, 0.0, 0.0)):
    h = laspy.LasHeader(point_format=6, version="1.4")
    h.scales, h.offsets = np.asarray(scale, dtype=np.float64), np.asarray(offset, dtype=np.float64)
    h.add_crs(CRS.from_epsg(2154))
    out = laspy.LasData(h)
    out.x, out.y, out.z = xyz.T
    out.write(str(path))


def test_don_of_files_of_two_scales_is_the_merged_files(tmp_path):
    """A plane in cm beside a 5 mm wide strip in mm: the catalog's balls were collinear to 1 cm (the coarser file's
    step), so every strip point had DoN 0, where the merged file (on the mm grid) has values (bug hunt F)."""
    rng = np.random.default_rng(0)
    x, y = np.meshgrid(np.arange(0, 10, 0.1), np.arange(0, 10, 0.1))
    a = np.round(np.c_[x.ravel(), y.ravel(), np.zeros(x.size)], 2)
    t = np.arange(0, 10, 0.02)
    b = np.round(np.c_[30 + t, 5.0 + rng.integers(0, 6, t.size) * 0.001, 1 + 0.1 * t], 3)
    (tmp_path / "in").mkdir()
    _write(tmp_path / "in" / "a.las", a, [0.01] * 3)
    _write(tmp_path / "in" / "b.las", b, [0.001] * 3)
    _write(tmp_path / "merged.las", np.r_[a, b], [0.001] * 3)
    kw = dict(mode="exact", r_small=0.2, r_large=1.0, quiet=True)
    don(tmp_path / "in", out_dir=str(tmp_path / "out"), **kw)
    don(tmp_path / "merged.las", tmp_path / "merged_don.las", **kw)
    got = np.r_[laspy.read(str(tmp_path / "out" / "a.las"))["DoN"], laspy.read(str(tmp_path / "out" / "b.las"))["DoN"]]
    want = np.asarray(laspy.read(str(tmp_path / "merged_don.las"))["DoN"])
    assert np.count_nonzero(want[a.shape[0]:]) > 100 and np.array_equal(got, want)


def test_files_whose_finest_scale_is_on_other_axes_share_one_grid(tmp_path):
    """mm in x beside mm in z: the common grid is mm in x and z, cm in y (it was a StopIteration: bug hunt F)."""
    rng = np.random.default_rng(1)
    p = np.round(rng.uniform(0, 20, (3000, 3)) * [1, 1, 0.1], 2)
    (tmp_path / "in").mkdir()
    _write(tmp_path / "in" / "a.las", p[:1500], [0.001, 0.01, 0.01], offset=(0.0, 0.0, 5.0))
    _write(tmp_path / "in" / "b.las", p[1500:], [0.01, 0.01, 0.001], offset=(1.0, 0.0, 0.0))
    cat = open_catalog(tmp_path / "in")
    assert cat.scale == (0.001, 0.01, 0.001) and cat.offset == (0.0, 0.0, 0.0)
    assert cat.factor == ((1, 1, 10), (10, 1, 1)) and cat.shift == ((0, 0, 5000), (1000, 0, 0))
    normals(tmp_path / "in", out_dir=str(tmp_path / "out"), tile_size=TILE, quiet=True)
    assert len(laspy.read(str(tmp_path / "out" / "b.las"))) == 1500


def test_a_directory_of_links_is_in_the_order_of_the_links_names(cut, tmp_path):
    """Links t0..t3 to tile_3..tile_0: the catalog is t0, t1, t2, t3 (it was their targets' order: bug hunt F)."""
    d, _ = cut
    (tmp_path / "links").mkdir()
    for k in range(4):
        os.symlink(d / "in" / f"tile_{3 - k}.las", tmp_path / "links" / f"t{k}.las")
    cat = open_catalog(tmp_path / "links")
    # (a source's path is its file's, resolved: what a store records of it)
    assert [os.path.basename(s.path) for s in cat.sources] == ["tile_3.las", "tile_2.las", "tile_1.las", "tile_0.las"]


def test_a_catalog_of_links_is_listed_by_the_links_names(cut, tmp_path):
    """Links in the input directory (to files named otherwise): the outputs and the summary's per-file rows take the
    links' names, the ones the user sees (the rows named the files the links point to)."""
    d, _ = cut
    (tmp_path / "links").mkdir()
    for k, name in enumerate(("north.las", "south.las")):
        os.symlink(d / "in" / f"tile_{k}.las", tmp_path / "links" / name)
    s = normals(tmp_path / "links", out_dir=str(tmp_path / "out"), tile_size=TILE, quiet=True)
    assert [os.path.basename(i) for i, _, _ in s.files] == ["north.las", "south.las"]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["north.las", "south.las"]
    r = CliRunner().invoke(main, ["normals", str(tmp_path / "links"), "--out-dir", str(tmp_path / "out2"), "--tile-size", str(TILE)])
    assert r.exit_code == 0, r.output
    rows = [line.split()[0] for line in r.output.splitlines() if " points -> " in line]
    assert rows == ["north.las", "south.las"]
