"""The CRS kept byte for byte and named, and the unit of every distance (issue 18, part 2)."""

import json
import os

import laspy
import numpy as np
import pytest
from click.testing import CliRunner
from pyproj import CRS

import synthetic
from patchcloud.core import PatchcloudValueError
from patchcloud.stream import RunOptions, info, normals
from patchcloud.stream.cli import main
from patchcloud.stream.io.crs import units_of
from patchcloud.stream.io.las_records import file_records

SAMPLE = os.path.join(os.path.dirname(__file__), "..", "data", "test_data_77055_627760_LA93_IGN69.laz")
AUTZEN = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data", "lidar-autzen", "autzen_trim.laz")


def _scene(path, crs=None, evlrs=(), offset=(650000.0, 6860000.0, 40.0), scale=0.001, n=6_000):
    pts, _ = synthetic.scene(n, seed=2)
    h = laspy.LasHeader(point_format=6, version="1.4")
    h.scales, h.offsets = np.array([scale] * 3), np.array(offset)
    if crs is not None:
        h.vlrs.append(laspy.VLR("LASF_Projection", 2112, "OGC WKT", CRS.from_user_input(crs).to_wkt().encode() + b"\0"))
        h.global_encoding.wkt = True
    las = laspy.LasData(h)
    las.x, las.y, las.z = (pts[:, i] * (scale / 0.001) + offset[i] for i in range(3))
    las.evlrs = laspy.vlrs.vlrlist.VLRList(list(evlrs))
    las.write(str(path))
    return path


def test_info_names_the_crs_of_the_embedded_tile_and_of_its_store(tmp_path):
    r = CliRunner().invoke(main, ["info", SAMPLE])
    assert r.exit_code == 0 and "CRS          EPSG:2154 (RGF93 v1 / Lambert-93); units: horizontal metre (1 m)" in r.output, r.output
    assert info(SAMPLE)["crs_info"]["epsg"] == 2154
    r = CliRunner().invoke(main, ["tile", SAMPLE, str(tmp_path / "s.zarr"), "-q"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["info", str(tmp_path / "s.zarr")])
    assert "EPSG:2154 (RGF93 v1 / Lambert-93)" in r.output, r.output


@pytest.mark.skipif(not os.path.exists(AUTZEN), reason="../shared/data/lidar-autzen/autzen_trim.laz is absent")
def test_autzen_is_in_international_feet_and_its_summary_says_so(tmp_path):
    r = CliRunner().invoke(main, ["info", AUTZEN])
    assert "NAD_1983_HARN_Lambert_Conformal_Conic; units: horizontal international foot (0.3048 m)" in r.output, r.output
    out = tmp_path / "a.las"
    r = CliRunner().invoke(main, ["normals", AUTZEN, str(out), "--summary-json", str(tmp_path / "s.json")])
    assert r.exit_code == 0, r.output
    assert "units           ft (foot, 0.3048 m; from the CRS)" in r.output and " ft, spacing " in r.output
    s = json.loads((tmp_path / "s.json").read_text())
    assert s["units"] == {"symbol": "ft", "name": "foot", "metres": 0.3048, "source": "CRS"}
    # the GeoTIFF keys (21 keys in 22 slots), their parameters and the WKT, byte for byte
    ins, outs = file_records(AUTZEN)[0], file_records(out)[0]
    assert sum(r.name == "LASF_Projection" for r in ins) == 4
    assert all(r in outs for r in ins if r.name != "laszip encoded")
    assert laspy.read(str(out)).header.parse_crs().equals(laspy.open(AUTZEN).header.parse_crs())


def test_a_geographic_crs_is_one_error_naming_units_and_units_overrides_it(tmp_path):
    path = _scene(tmp_path / "geo.las", crs="EPSG:4326")
    out = tmp_path / "o.las"
    r = CliRunner().invoke(main, ["normals", str(path), str(out), "-q"])
    assert r.exit_code == 2 and r.output.count("\n") == 1, r.output
    assert "EPSG:4326 (WGS 84) is geographic" in r.output and "--units" in r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["geo.las"]  # nothing written
    r = CliRunner().invoke(main, ["normals", str(path), str(out), "--units", "m", "--summary-json", str(tmp_path / "s.json")])
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "s.json").read_text())["units"]["source"] == "--units"
    assert "units           m (metre, 1 m; from --units)" in r.output


def test_tile_refuses_a_geographic_crs_as_the_jobs_do_and_takes_units(tmp_path):
    """``tile`` cut a file in degrees into tiles of 32 degrees without a word, and had no --units."""
    path = _scene(tmp_path / "geo.las", crs="EPSG:4326")
    store = tmp_path / "s.zarr"
    r = CliRunner().invoke(main, ["tile", str(path), str(store), "-q"])
    assert r.exit_code == 2 and r.output.count("\n") == 1 and "EPSG:4326 (WGS 84) is geographic" in r.output, r.output
    assert not store.exists()
    r = CliRunner().invoke(main, ["tile", str(path), str(store), "-q", "--units", "m"])
    assert r.exit_code == 0 and store.exists(), r.output


def test_a_store_tiled_with_units_keeps_them_for_the_jobs_on_it(tmp_path):
    """``tile --units ft`` said "tiles of 64 m" and recorded nothing: a job on the store without --units took metres
    (review N)."""
    path = _scene(tmp_path / "nocrs.las")
    store = tmp_path / "s.zarr"
    r = CliRunner().invoke(main, ["tile", str(path), str(store), "--tile-size", "16", "--units", "ft"])
    assert r.exit_code == 0 and "tiles of 16 ft" in r.output, r.output
    assert info(str(store))["unit"] == "ft"
    s = normals(path, tmp_path / "o.las", store=str(store), quiet=True)
    assert s.units["symbol"] == "ft" and s.units["source"] == "--units" and s.tile_size == 16
    s = normals(path, tmp_path / "m.las", store=str(store), units="m", quiet=True, overwrite=True)  # asked: taken
    assert s.units["symbol"] == "m"
    r = CliRunner().invoke(main, ["tile", str(path), str(store), "--tile-size", "16", "-q"])  # tiled again without: the CRS's
    assert r.exit_code == 0 and info(str(store))["unit"] == "m", r.output


def test_heights_in_another_unit_than_x_and_y_are_refused_unless_units_says(tmp_path):
    """UTM metres over NAVD88 heights in US feet ran as one unit: slopes 3.28 times too steep (review N)."""
    path = _scene(tmp_path / "mixed.las", crs="EPSG:6346+6360", offset=(500000.0, 4000000.0, 40.0))
    with pytest.raises(PatchcloudValueError, match=r"mixed.las: its CRS .* has heights in US survey foot \(0.304801 m\) and "
                                                   r"x, y in metre .*Z = Z \* 0.3048006096.*or give --units m"):
        normals(path, tmp_path / "o.las", quiet=True)
    assert not (tmp_path / "o.las").exists()
    r = CliRunner().invoke(main, ["tile", str(path), str(tmp_path / "s.zarr"), "-q"])
    assert r.exit_code == 2 and r.output.count("\n") == 1 and "heights in US survey foot" in r.output, r.output
    s = normals(path, tmp_path / "o.las", units="m", quiet=True)  # every axis taken as it is, as asked
    assert s.units["symbol"] == "m" and s.units["source"] == "--units"


def test_degrees_in_a_projected_crs_are_refused():
    with pytest.raises(PatchcloudValueError, match=r"look like degrees, not lengths of its projected CRS EPSG:2154.*--units"):
        units_of("EPSG:2154", (2.30, 48.80), (2.31, 48.81), where="x.las")
    assert units_of("EPSG:2154", (2.30, 48.80), (2.31, 48.81), "m").source == "--units"
    assert units_of("EPSG:2249", (700000.0, 2900000.0), (701000.0, 2901000.0)).symbol == "us-ft"  # Massachusetts, US survey feet
    assert units_of(None, (0.0, 0.0), (1.0, 1.0)).source == "assumed"
    with pytest.raises(PatchcloudValueError, match="units must be one of m, ft, us-ft; got 'km'"):
        RunOptions(units="km")


def test_evlrs_are_kept_byte_for_byte_and_copc_records_dropped(tmp_path):
    wkt = CRS.from_epsg(2154).to_wkt().encode() + b"\0"
    evlrs = [laspy.VLR("LASF_Projection", 2112, "OGC WKT", wkt), laspy.VLR("copc", 1000, "EPT hierarchy", bytes(32)),
             laspy.VLR("someone", 7, "their record", bytes(range(256)) * 300)]  # longer than a VLR may be
    path = _scene(tmp_path / "e.las", crs="EPSG:2154", evlrs=evlrs)
    out = tmp_path / "o.laz"
    normals(path, out, quiet=True)
    (iv, ie), (ov, oe) = file_records(path), file_records(out)
    assert [(r.name, r.record_id) for r in ie] == [("LASF_Projection", 2112), ("copc", 1000), ("someone", 7)]
    assert oe == [ie[0], ie[2]]
    assert iv[0] in ov
    assert laspy.read(str(out)).header.parse_crs().to_epsg() == 2154


def test_a_wkt_is_described_once_and_each_caller_gets_its_own_copy(monkeypatch, tmp_path):
    """A file's WKT is described once per process (pyproj's EPSG search costs about 60 ms for a WKT without an
    authority, and a run describes its CRS several times); the answer is the same, and a caller's changes stay its own."""
    from patchcloud.stream.io.crs import crs_description

    monkeypatch.setenv("PATCHCLOUD_CRS_CACHE", str(tmp_path / "crs"))  # an empty cache on disk (stream.io.crs_cache)
    searches = []
    search = CRS.to_epsg
    monkeypatch.setattr(CRS, "to_epsg", lambda self, *a, **k: searches.append(1) or search(self, *a, **k))
    wkt = CRS.from_epsg(2154).to_wkt().replace("Lambert-93", "Lambert-93 (this test)")  # not described before
    first = crs_description(wkt)
    assert len(searches) == 1
    first["horizontal_unit"][0] = "changed"
    again = crs_description(wkt)
    assert len(searches) == 1 and again["horizontal_unit"][0] == "metre"
    assert again == crs_description(CRS.from_wkt(wkt)) and again["epsg"] == 2154
    assert again["label"] == "EPSG:2154 (RGF93 v1 / Lambert-93 (this test))"


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_reports_and_pcz_info_state_lengths_in_the_files_unit(tmp_path):
    """A feet file's report says ft where its summary does (tiles, budget, mean error; it said m), and info of its .pcz
    states the budget and the tile size in ft."""
    src = _scene(tmp_path / "ft.las", crs="EPSG:2263")  # New York Long Island, US survey feet
    r = CliRunner().invoke(main, ["normals", str(src), str(tmp_path / "n.las"), "--report", str(tmp_path / "n.html")])
    assert r.exit_code == 0 and "tiles" in r.output, r.output
    html = (tmp_path / "n.html").read_text()
    assert " us-ft</td>" in html and " m</td>" not in html
    r = CliRunner().invoke(main, ["compress", str(src), str(tmp_path / "c.pcz"), "--max-error", "0.1", "--report", str(tmp_path / "c.html")])
    assert r.exit_code == 0, r.output
    html = (tmp_path / "c.html").read_text()
    assert "<td>0.1 us-ft</td>" in html and " m</td>" not in html and "{'" not in html  # no Python dict either
    r = CliRunner().invoke(main, ["info", str(tmp_path / "c.pcz")])
    assert "max error    0.1 us-ft" in r.output and " of " in r.output and "us-ft\n" in r.output, r.output
    r = CliRunner().invoke(main, ["tile", str(src), str(tmp_path / "st.zarr"), "-q"])
    r = CliRunner().invoke(main, ["info", str(tmp_path / "st.zarr")])
    assert r.exit_code == 0 and " us-ft (min/median/max per tile" in r.output, r.output  # a store's tiles too


def test_don_scales_names_the_files_unit_and_refuses_degrees(tmp_path):
    """don-scales' radii are in the file's unit, as every distance option: its table, best pair and summary said m for a
    feet file, and it ran on a geographic CRS every other command refuses (bug hunt I)."""
    import json

    feet = _scene(tmp_path / "ft.las", crs="EPSG:2994")  # NAD83(HARN) / Oregon GIC Lambert (ft)
    las = laspy.read(str(feet))
    las.classification = np.where(np.asarray(las.z) > np.median(np.asarray(las.z)), 6, 2).astype(np.uint8)
    las.write(str(feet))
    r = CliRunner().invoke(main, ["don-scales", str(feet), "--radii", "0.5,1,2", "--sample", "2000", "--no-plot",
                                  "--min-class-points", "10", "--summary-json", str(tmp_path / "s.json")])
    assert r.exit_code == 0, r.output
    assert "| r_s (ft) | r_l (ft) |" in r.output and " ft, Fisher ratio" in r.output and "(m)" not in r.output
    assert json.loads((tmp_path / "s.json").read_text())["unit"] == "ft"
    geo = _scene(tmp_path / "geo.las", crs="EPSG:4326")
    r = CliRunner().invoke(main, ["don-scales", str(geo), "--no-plot"])
    assert r.exit_code == 2 and "is geographic" in r.output and "--units" in r.output and r.output.count("\n") == 1, r.output


def test_a_geocentric_crs_names_its_axes_in_metres_in_pictures():
    """lone-star's CRS (geocentric WGS 84, as its GeoTIFF keys say) was labelled "file units" by render (bug hunt I)."""
    from patchcloud.stream.views.units import axis_names

    names = axis_names("EPSG:4978")
    assert (names.horizontal, names.vertical) == ("m", "m"), names
