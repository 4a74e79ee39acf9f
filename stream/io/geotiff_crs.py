"""A LAS file's GeoTIFF CRS records read as libgeotiff reads them (PDAL, GDAL, LAStools), not only their EPSG codes.

A LAS file below point format 6 usually says its CRS with GeoTIFF "geo
keys": record 34735 (the key directory), 34736 (their double values) and
34737 (their text).  laspy's ``parse_crs`` takes the projected CRS's EPSG
code (key 3072), else the geographic one's (key 2048), and nothing else;
so it took files that PDAL itself writes for a CRS without an EPSG code
(key 3072 = 32767, "user-defined", with the projection's parameters in
other keys) for their geographic base CRS, and refused them as degrees; a
geocentric file (key 1024 = 3) for a geographic one; and an EPSG code whose
linear unit key 3076 says feet for metres.  :func:`geotiff_crs` reads them
all as libgeotiff does (``GTIFGetDefn``):

- key 1024 (model): 1 projected, 2 geographic, 3 geocentric (where absent:
  projected when a projection key is there, else geographic when key 2048 is);
- projected: key 3072's EPSG code, its axis unit replaced by key 3076's
  (3077: metres per unit, for a unit of its own) where that says another;
  for 32767, the conversion named by key 3074 (an EPSG code), else built
  from key 3075 (the method) and the parameter keys 3078-3095, on the
  geodetic CRS of key 2048, else of the datum (2050), ellipsoid (2056) or
  axes (2057-2059) keys, else WGS 84 (libgeotiff's default);
- geographic: key 2048's CRS (or the geodetic CRS above);
- geocentric: a geocentric CRS of that datum, in metres (or key 2052's unit).

Vertical keys (4096-4099) are not read, as laspy did not: the horizontal
CRS is what decides a file's units and its sameness with a catalog's
others.  A projection method outside :data:`METHODS` is an error (the
caller says the records cannot be read), never a silent other CRS.
"""

from __future__ import annotations

import math
import struct

__all__ = ["geo_keys", "geotiff_crs", "GeoKeyError", "METHODS", "USER_DEFINED", "GEO_KEY_DIRECTORY", "GEO_DOUBLE_PARAMS",
           "GEO_ASCII_PARAMS"]

#: The record ids (user id ``LASF_Projection``) of GeoTIFF's key directory, its double and its ASCII parameters (their
#: TIFF tags too, which a key's location names).
GEO_KEY_DIRECTORY, GEO_DOUBLE_PARAMS, GEO_ASCII_PARAMS = 34735, 34736, 34737

#: The value of a code key that says "defined by the other keys".
USER_DEFINED = 32767
#: GeoTIFF's projection methods (key 3075, ``ProjCoordTransGeoKey``) read here, by code.
METHODS = {
    1: "Transverse Mercator", 3: "Hotine Oblique Mercator", 7: "Mercator", 8: "Lambert Conformal Conic 2SP",
    9: "Lambert Conformal Conic 1SP", 10: "Lambert Azimuthal Equal Area", 11: "Albers Equal Area", 12: "Azimuthal Equidistant",
    14: "Stereographic", 15: "Polar Stereographic", 16: "Oblique Stereographic", 17: "Equirectangular",
}
# parameter keys
_STD1, _STD2, _NAT_LON, _NAT_LAT, _FE, _FN = 3078, 3079, 3080, 3081, 3082, 3083
_FO_LON, _FO_LAT, _FO_E, _FO_N = 3084, 3085, 3086, 3087
_C_LON, _C_LAT, _C_E, _C_N = 3088, 3089, 3090, 3091
_K_NAT, _K_CENTRE, _AZIMUTH, _POLE_LON, _RECTIFIED = 3092, 3093, 3094, 3095, 3096
#: Angular units (key 2054) in degrees per unit: degree, radian, grad, arc-second, degree (supplier to define).
_ANGLES = {9102: 1.0, 9101: 180.0 / math.pi, 9105: 0.9, 9104: 1.0 / 3600.0, 9122: 1.0}


class GeoKeyError(ValueError):
    """GeoTIFF keys that do not make a CRS read here (damaged records, a method outside :data:`METHODS`)."""


def geo_keys(directory: bytes, doubles: bytes | None = None, ascii: bytes | None = None) -> dict[int, object]:
    """The keys of a GeoKeyDirectory record (34735) with their values: an int (a code), a float or a tuple of floats
    (from the GeoDoubleParams record, 34736), or a str (from GeoAsciiParams, 34737).

    >>> import struct
    >>> d = struct.pack("<8H", 1, 1, 0, 1, 3072, 0, 1, 2154)
    >>> geo_keys(d)
    {3072: 2154}
    """
    if len(directory) < 8 or len(directory) % 2:
        raise GeoKeyError(f"a GeoKeyDirectory record of {len(directory)} bytes (whole 16-bit values, at least 4 of them)")
    shorts = struct.unpack(f"<{len(directory) // 2}H", directory)
    count = shorts[3]
    if 4 + 4 * count > len(shorts):
        raise GeoKeyError(f"a GeoKeyDirectory record of {len(shorts)} values says it holds {count} keys")
    values = [] if not doubles else list(struct.unpack(f"<{len(doubles) // 8}d", doubles[: len(doubles) // 8 * 8]))
    text = (ascii or b"").decode("latin-1")
    keys: dict[int, object] = {}
    for k in range(count):
        key, where, n, value = shorts[4 + 4 * k : 8 + 4 * k]
        if where == 0:
            keys[key] = int(value)
        elif where == GEO_DOUBLE_PARAMS:
            if value + n > len(values) or n == 0:
                raise GeoKeyError(f"geo key {key} takes doubles {value} to {value + n - 1} of {len(values)}")
            keys[key] = float(values[value]) if n == 1 else tuple(values[value : value + n])
        elif where == GEO_ASCII_PARAMS:
            if value + n > len(text):
                raise GeoKeyError(f"geo key {key} takes characters {value} to {value + n - 1} of {len(text)}")
            keys[key] = text[value : value + n].rstrip("|\x00")
        else:
            raise GeoKeyError(f"geo key {key} is in TIFF tag {where}, not in this file's records")
    return keys


def _code(keys: dict, key: int) -> int | None:
    """Key ``key``'s EPSG code, or None where it is absent, 0 or user-defined."""
    v = keys.get(key)
    return v if isinstance(v, int) and 0 < v < USER_DEFINED else None


def _linear_unit(keys: dict, code_key: int, size_key: int):
    """(name, metres per unit) of the linear unit keys, or None where absent."""
    code, size = keys.get(code_key), keys.get(size_key)
    if code is None and size is None:
        return None
    if isinstance(code, int) and 0 < code < USER_DEFINED:
        from pyproj.database import get_units_map

        for name, unit in get_units_map(auth_name="EPSG", category="linear").items():
            if int(unit.code) == code:
                return name, float(unit.conv_factor)
        raise GeoKeyError(f"geo key {code_key}: {code} is no EPSG linear unit")
    if isinstance(size, float) and size > 0:
        return "unit", size
    raise GeoKeyError(f"geo key {code_key} says a unit of its own ({code}) without its size (key {size_key})")


def _unit_json(name: str, metres: float):
    return "metre" if abs(metres - 1.0) < 1e-12 else {"type": "LinearUnit", "name": name, "conversion_factor": metres}


def _geodetic(keys: dict):
    """The geodetic (geographic 2D) CRS of the keys (see the module's notes)."""
    from pyproj import CRS
    from pyproj.crs import GeographicCRS
    from pyproj.crs.datum import CustomDatum, CustomEllipsoid, Ellipsoid
    from pyproj.crs.datum import Datum

    code = _code(keys, 2048)
    if code is not None:
        return CRS.from_epsg(code)
    datum = _code(keys, 2050)
    if datum is not None:
        return GeographicCRS(name="unnamed", datum=Datum.from_epsg(datum))
    ellipsoid = _code(keys, 2056)
    if ellipsoid is not None:
        return GeographicCRS(name="unnamed", datum=CustomDatum(ellipsoid=Ellipsoid.from_epsg(ellipsoid)))
    a = keys.get(2057)
    if isinstance(a, float):
        b, rf = keys.get(2058), keys.get(2059)
        axes = {"inverse_flattening": rf} if isinstance(rf, float) and rf > 0 else {"semi_minor_axis": b if isinstance(b, float) else a}
        return GeographicCRS(name="unnamed", datum=CustomDatum(ellipsoid=CustomEllipsoid(semi_major_axis=a, **axes)))
    return CRS.from_epsg(4326)


def _parameters(keys: dict, method: int, unit: tuple[str, float]):
    """The pyproj conversion of GeoTIFF method ``method`` from the parameter keys (angles in degrees, lengths in metres)."""
    from pyproj.crs import coordinate_operation as co

    degrees = _ANGLES.get(keys.get(2054, 9102))
    if degrees is None:
        raise GeoKeyError(f"geo key 2054: angular unit {keys.get(2054)} is not read here")
    metres = unit[1]

    def angle(*ks, default=0.0):
        for k in ks:
            if isinstance(keys.get(k), float):
                return keys[k] * degrees
        return default

    def length(*ks):
        for k in ks:
            if isinstance(keys.get(k), float):
                return keys[k] * metres
        return 0.0

    def scale(*ks):
        for k in ks:
            if isinstance(keys.get(k), float):
                return keys[k]
        return 1.0

    fe, fn = length(_FE, _FO_E, _C_E), length(_FN, _FO_N, _C_N)
    if method == 1:
        return co.TransverseMercatorConversion(angle(_NAT_LAT, _C_LAT), angle(_NAT_LON, _C_LON), fe, fn, scale(_K_NAT, _K_CENTRE))
    if method == 3:
        azimuth = angle(_AZIMUTH)
        return co.HotineObliqueMercatorBConversion(
            latitude_projection_centre=angle(_C_LAT, _NAT_LAT), longitude_projection_centre=angle(_C_LON, _NAT_LON),
            azimuth_projection_centre=azimuth, angle_from_rectified_to_skew_grid=angle(_RECTIFIED, default=azimuth),
            scale_factor_projection_centre=scale(_K_CENTRE, _K_NAT), easting_projection_centre=length(_C_E, _FE),
            northing_projection_centre=length(_C_N, _FN))
    if method == 7:
        if isinstance(keys.get(_STD1), float):
            return co.MercatorBConversion(angle(_STD1), angle(_NAT_LON, _C_LON), fe, fn)
        return co.MercatorAConversion(angle(_NAT_LAT), angle(_NAT_LON, _C_LON), fe, fn, scale(_K_NAT, _K_CENTRE))
    if method == 8:
        return co.LambertConformalConic2SPConversion(
            angle(_STD1), angle(_STD2), angle(_FO_LAT, _NAT_LAT), angle(_FO_LON, _NAT_LON), length(_FO_E, _FE), length(_FO_N, _FN))
    if method == 9:
        return co.LambertConformalConic1SPConversion(angle(_NAT_LAT), angle(_NAT_LON, _FO_LON), fe, fn, scale(_K_NAT, _K_CENTRE))
    if method == 10:
        return co.LambertAzimuthalEqualAreaConversion(angle(_C_LAT, _NAT_LAT), angle(_C_LON, _NAT_LON), fe, fn)
    if method == 11:
        return co.AlbersEqualAreaConversion(
            angle(_STD1), angle(_STD2), angle(_NAT_LAT, _FO_LAT, _C_LAT), angle(_NAT_LON, _FO_LON, _C_LON), fe, fn)
    if method == 12:
        return co.AzimuthalEquidistantConversion(angle(_C_LAT, _NAT_LAT), angle(_C_LON, _NAT_LON), fe, fn)
    if method == 14:
        return co.StereographicConversion(angle(_C_LAT, _NAT_LAT), angle(_C_LON, _NAT_LON), fe, fn, scale(_K_NAT, _K_CENTRE))
    if method == 15:
        lat = angle(_NAT_LAT)
        lon = angle(_POLE_LON, _NAT_LON)
        if abs(abs(lat) - 90.0) < 1e-9:
            return co.PolarStereographicAConversion(lat, lon, fe, fn, scale(_K_NAT, _K_CENTRE))
        return co.PolarStereographicBConversion(lat, lon, fe, fn)
    if method == 16:
        from pyproj.crs import CoordinateOperation

        return CoordinateOperation.from_json_dict({
            "type": "Conversion", "name": "unnamed", "method": {"name": "Oblique Stereographic", "id": {"authority": "EPSG", "code": 9809}},
            "parameters": [
                {"name": "Latitude of natural origin", "value": angle(_NAT_LAT, _C_LAT), "unit": "degree", "id": {"authority": "EPSG", "code": 8801}},
                {"name": "Longitude of natural origin", "value": angle(_NAT_LON, _C_LON), "unit": "degree", "id": {"authority": "EPSG", "code": 8802}},
                {"name": "Scale factor at natural origin", "value": scale(_K_NAT, _K_CENTRE), "unit": "unity", "id": {"authority": "EPSG", "code": 8805}},
                {"name": "False easting", "value": fe, "unit": "metre", "id": {"authority": "EPSG", "code": 8806}},
                {"name": "False northing", "value": fn, "unit": "metre", "id": {"authority": "EPSG", "code": 8807}},
            ],
        })
    if method == 17:
        return co.EquidistantCylindricalConversion(latitude_first_parallel=angle(_STD1, _NAT_LAT), longitude_natural_origin=angle(_NAT_LON, _C_LON),
                                                   false_easting=fe, false_northing=fn)
    raise GeoKeyError(f"geo key 3075: projection method {method} is not read here (only {', '.join(map(str, METHODS))})")


def _with_axis_unit(crs, unit: tuple[str, float]):
    """``crs`` (projected or geocentric) with every axis in ``unit`` (name, metres)."""
    from pyproj import CRS

    d = crs.to_json_dict()
    d.pop("id", None)  # another unit: no longer the CRS the code names
    for axis in d["coordinate_system"]["axis"]:
        axis["unit"] = _unit_json(*unit)
    return CRS.from_json_dict(d)


def _projected(keys: dict):
    from pyproj import CRS
    from pyproj.crs import CoordinateOperation, ProjectedCRS

    unit = _linear_unit(keys, 3076, 3077)
    code = _code(keys, 3072)
    if code is not None:
        crs = CRS.from_epsg(code)
        if not crs.is_projected:
            raise GeoKeyError(f"geo key 3072: EPSG:{code} is not a projected CRS")
        if unit is not None and abs(float(crs.axis_info[0].unit_conversion_factor) - unit[1]) > 1e-12 * unit[1]:
            crs = _with_axis_unit(crs, unit)
        return crs
    unit = unit or ("metre", 1.0)
    projection = _code(keys, 3074)
    if projection is not None:
        try:
            conversion = CoordinateOperation.from_epsg(projection)
        except Exception as exc:
            raise GeoKeyError(f"geo key 3074: EPSG:{projection} is no projection pyproj knows ({exc})") from None
    else:
        method = keys.get(3075)
        if not isinstance(method, int):
            raise GeoKeyError("projected CRS without an EPSG code (key 3072), projection code (3074) or method (3075)")
        conversion = _parameters(keys, method, unit)
    name = keys.get(3073) or keys.get(1026) or "unnamed"
    crs = ProjectedCRS(conversion=conversion, geodetic_crs=_geodetic(keys), name=str(name))
    return _with_axis_unit(crs, unit) if abs(unit[1] - 1.0) > 1e-12 else crs


def _geocentric(keys: dict):
    from pyproj import CRS

    base = _geodetic(keys).to_json_dict()
    unit = _unit_json(*(_linear_unit(keys, 2052, 2053) or ("metre", 1.0)))
    d = {"type": "GeodeticCRS", "name": str(keys.get(1026) or f"geocentric ({base.get('name', 'unnamed')})")}
    d.update({k: base[k] for k in ("datum", "datum_ensemble") if k in base})  # WGS 84's is an ensemble
    d["coordinate_system"] = {"subtype": "Cartesian", "axis": [
        {"name": f"Geocentric {a}", "abbreviation": a, "direction": f"geocentric{a}", "unit": unit} for a in "XYZ"]}
    return CRS.from_json_dict(d)


def geotiff_crs(keys: dict):
    """The pyproj CRS that GeoTIFF ``keys`` (:func:`geo_keys`) define, or None where they define none.

    Raises
    ------
    GeoKeyError
        Keys that make no CRS read here (see the module's notes).

    Examples
    --------
    A transverse Mercator in US survey feet on NAD83, without an EPSG code (as PDAL writes one):

    >>> keys = {1024: 1, 3072: 32767, 2048: 4269, 3075: 1, 3076: 9003, 3080: -120.0, 3081: 0.0, 3082: 1640416.6667,
    ...         3083: 0.0, 3092: 0.9996}
    >>> crs = geotiff_crs(keys)
    >>> crs.is_projected, crs.axis_info[0].unit_name, round(crs.axis_info[0].unit_conversion_factor, 7)
    (True, 'US survey foot', 0.3048006)
    """
    model = keys.get(1024)
    if model not in (None, 1, 2, 3):
        raise GeoKeyError(f"geo key 1024: model type {model} (1 projected, 2 geographic, 3 geocentric)")
    if model == 3:
        return _geocentric(keys)
    projected = any(k in keys for k in (3072, 3074, 3075))
    if model == 1 or (model is None and projected):
        return _projected(keys)
    if model == 2 or any(k in keys for k in (2048, 2050, 2056, 2057)):
        return _geodetic(keys)
    return None
