"""GeoTIFF CRS records read as libgeotiff (PDAL) reads them (stream/io/geotiff_crs.py): user-defined projections, unit
keys, geocentric and geographic models, and which record wins when a file has both GeoTIFF keys and a WKT."""

from __future__ import annotations

import struct

import laspy
import numpy as np
import pytest
from click.testing import CliRunner
from pyproj import CRS, Transformer

from patchcloud.stream.cli import main
from patchcloud.stream.io.crs import units_of
from patchcloud.stream.io.crs_cache import header_crs
from patchcloud.stream.io.geotiff_crs import GeoKeyError, geo_keys, geotiff_crs

#: The keys PDAL 2.8 writes for "+proj=tmerc +lat_0=0 +lon_0=-120 +k=0.9996 +x_0=500000 +y_0=0 +datum=NAD83 +units=ft"
#: (no EPSG code: 3072 = 32767), as read from a file it wrote.
PDAL_TMERC_FT = {1024: 1, 1025: 1, 1026: "unknown", 2048: 4269, 2049: "unknown", 2054: 9102, 2057: 6378137.0,
                 2059: 298.257222101, 3072: 32767, 3074: 32767, 3075: 1, 3076: 9002, 3080: -120.0, 3081: 0.0,
                 3082: 1640419.94750656, 3083: 0.0, 3092: 0.9996}


def _records(keys: dict) -> list:
    """The three LASF_Projection records of ``keys`` (ints in the directory, floats and tuples in the doubles, str in
    the ASCII record), as libgeotiff lays them out."""
    entries, doubles, text = [], [], ""
    for k in sorted(keys):
        v = keys[k]
        if isinstance(v, int):
            entries.append((k, 0, 1, v))
        elif isinstance(v, str):
            entries.append((k, 34737, len(v) + 1, len(text)))
            text += v + "|"
        else:
            vals = [v] if isinstance(v, float) else list(v)
            entries.append((k, 34736, len(vals), len(doubles)))
            doubles += vals
    directory = struct.pack(f"<{4 + 4 * len(entries)}H", 1, 1, 0, len(entries), *[x for e in entries for x in e])
    out = [laspy.VLR("LASF_Projection", 34735, "GeoTIFF GeoKeyDirectoryTag", directory)]
    if doubles:
        out.append(laspy.VLR("LASF_Projection", 34736, "GeoTIFF GeoDoubleParamsTag", struct.pack(f"<{len(doubles)}d", *doubles)))
    if text:
        out.append(laspy.VLR("LASF_Projection", 34737, "GeoTIFF GeoAsciiParamsTag", text.encode() + b"\0"))
    return out


def _las(path, keys: dict | None = None, wkt: str | None = None, version: str = "1.2", point_format: int = 3, wkt_bit=False):
    """A small plane of points (x, y in hundreds of thousands: lengths) with these CRS records."""
    h = laspy.LasHeader(point_format=point_format, version=version)
    h.scales, h.offsets = np.array([0.01, 0.01, 0.01]), np.array([500000.0, 4000000.0, 0.0])
    for r in _records(keys) if keys else []:
        h.vlrs.append(r)
    if wkt is not None:
        h.vlrs.append(laspy.VLR("LASF_Projection", 2112, "OGC WKT", CRS(wkt).to_wkt().encode() + b"\0"))
    h.global_encoding.wkt = wkt_bit
    las = laspy.LasData(h)
    g = np.arange(0.0, 40.0, 0.5)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    las.x, las.y, las.z = 500000.0 + x, 4000000.0 + y, 10.0 + 0.1 * x
    las.write(str(path))
    return path


def _same_projection(a: CRS, b: CRS, lonlat=(-121.3, 44.1)) -> bool:
    """Whether two projected CRSs put one point at the same place (within a millimetre of their unit)."""
    pa = Transformer.from_crs(a.geodetic_crs, a, always_xy=True).transform(*lonlat)
    pb = Transformer.from_crs(a.geodetic_crs, b, always_xy=True).transform(*lonlat)
    return bool(np.allclose(pa, pb, atol=1e-3, rtol=0))


def test_pdals_user_defined_transverse_mercator_in_feet_is_that_projection_not_its_geographic_base():
    crs = geotiff_crs(PDAL_TMERC_FT)
    expected = CRS.from_proj4("+proj=tmerc +lat_0=0 +lon_0=-120 +k=0.9996 +x_0=500000 +y_0=0 +datum=NAD83 +units=ft")
    assert crs.is_projected and _same_projection(crs, expected)
    assert units_of(crs.to_wkt(), (500000.0, 4000000.0), (500040.0, 4000040.0)).symbol == "ft"


@pytest.mark.parametrize("code, units", [(26910, "ft"), (2154, "m")])
def test_a_unit_key_overrides_the_epsg_codes_unit_as_libgeotiff_does(code, units):
    keys = {1024: 1, 3072: code, 3076: 9002 if units == "ft" else 9001}
    crs = geotiff_crs(keys)
    assert units_of(crs.to_wkt(), (500000.0, 4000000.0), (500040.0, 4000040.0)).symbol == units
    base = CRS.from_epsg(code)
    p = Transformer.from_crs(base.geodetic_crs, crs, always_xy=True).transform(*base.area_of_use.bounds[:2])
    q = Transformer.from_crs(base.geodetic_crs, base, always_xy=True).transform(*base.area_of_use.bounds[:2])
    factor = 0.3048 if units == "ft" else 1.0
    assert np.allclose(np.asarray(p) * factor, q, atol=1e-6, rtol=0)  # the same place, in feet


def test_lambert_93_spelled_out_in_keys_is_lambert_93():
    keys = {1024: 1, 3072: 32767, 3074: 32767, 3075: 8, 2048: 4171, 3076: 9001, 3078: 49.0, 3079: 44.0, 3084: 3.0,
            3085: 46.5, 3086: 700000.0, 3087: 6600000.0}
    assert _same_projection(geotiff_crs(keys), CRS.from_epsg(2154), lonlat=(2.35, 48.85))


def test_a_projection_named_by_its_epsg_code_on_a_user_defined_datum():
    keys = {1024: 1, 3072: 32767, 3074: 16010, 2048: 32767, 2050: 6269, 3076: 9001}  # UTM zone 10N on NAD83's datum
    assert _same_projection(geotiff_crs(keys), CRS.from_epsg(26910))


def test_geocentric_and_geographic_models():
    geocentric = geotiff_crs({1024: 3, 2048: 4326})
    assert geocentric.is_geocentric and geocentric.to_epsg() == 4978
    geographic = geotiff_crs({1024: 2, 2048: 4326})
    assert geographic.is_geographic
    assert geotiff_crs({1025: 1}) is None  # no CRS key: no CRS


def test_keys_that_make_no_crs_here_are_an_error_not_another_crs():
    with pytest.raises(GeoKeyError, match="projection method 22"):
        geotiff_crs({1024: 1, 3072: 32767, 2048: 4269, 3075: 22})
    with pytest.raises(GeoKeyError, match="says it holds 5 keys"):
        geo_keys(struct.pack("<8H", 1, 1, 0, 5, 3072, 0, 1, 2154))
    with pytest.raises(GeoKeyError, match="doubles 3 to 3 of 1"):
        geo_keys(struct.pack("<8H", 1, 1, 0, 1, 3082, 34736, 1, 3), struct.pack("<d", 1.0))


def test_the_wkt_bit_says_which_record_holds_the_crs(tmp_path):
    both = dict(keys={1024: 1, 3072: 32631}, wkt="EPSG:2154")
    h12 = laspy.open(str(_las(tmp_path / "a.las", **both))).header  # LAS 1.2, no WKT bit: GeoTIFF, as PDAL reads it
    assert CRS(header_crs(h12)[0]).to_epsg() == 32631
    h14 = laspy.open(str(_las(tmp_path / "b.las", **both, version="1.4", point_format=6, wkt_bit=True))).header
    assert CRS(header_crs(h14)[0]).to_epsg() == 2154


def test_a_run_on_pdals_user_defined_crs_is_in_feet_and_keeps_its_records(tmp_path):
    """PDAL's own output for a CRS without an EPSG code was refused as geographic (NAD83); it runs, in feet, and the
    output holds the input's GeoTIFF records as they were."""
    src = _las(tmp_path / "in.las", keys=PDAL_TMERC_FT)
    r = CliRunner().invoke(main, ["normals", str(src), str(tmp_path / "out.las")])
    assert r.exit_code == 0, r.output
    assert "ft (foot, 0.3048 m; from the CRS)" in r.output, r.output
    def projection(path):
        return [(v.record_id, v.record_data_bytes()) for v in laspy.open(str(path)).header.vlrs if v.user_id == "LASF_Projection"]
    assert projection(tmp_path / "out.las") == projection(src)
    geocentric = _las(tmp_path / "geocentric.las", keys={1024: 3, 1025: 2, 2048: 4326})
    r = CliRunner().invoke(main, ["normals", str(geocentric), str(tmp_path / "g.las")])
    assert r.exit_code == 0 and "m (metre, 1 m; from the CRS)" in r.output, r.output
