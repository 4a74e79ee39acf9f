"""A file's CRS named for people (EPSG code or name) and its length units, which every distance option is in.

patchcloud computes in the file's coordinates: a distance given to a job
(``--tile-size``, ``--rs``, ``--tolerance``, ``--max-error`` ...) is in the
file's **horizontal unit**, and the summaries name that unit.  The unit
comes from the CRS (pyproj): metre, foot (international, 0.3048 m) or US
survey foot (1200/3937 m).  ``--units`` (``units=``) overrides it, for a
file without a CRS (metres are assumed then, and said so) or with a wrong
one.  A geographic CRS (degrees are not lengths), or a projected CRS whose
coordinates look like degrees, is one error naming ``--units``.

>>> u = units_of("EPSG:2154", (700000.0, 6600000.0), (701000.0, 6601000.0))
>>> u.symbol, u.metres, u.source
('m', 1.0, 'CRS')
>>> units_of(None, (0.0, 0.0), (10.0, 10.0), "ft").symbol
'ft'
"""

from __future__ import annotations

import copy
import functools
from dataclasses import dataclass

from patchcloud.core import PatchcloudValueError

from .crs_cache import remembered

__all__ = ["Units", "UNITS", "units_of", "crs_name", "crs_description", "CRS_RECORD_IDS", "is_crs_record", "with_crs"]


@dataclass(frozen=True)
class Units:
    """A length unit of a file's coordinates: its symbol (``m``, ``ft``, ``us-ft``), name, length in metres, and where
    it came from (``CRS``, ``--units``, or ``assumed`` for a file without a CRS)."""

    symbol: str
    name: str
    metres: float
    source: str

    def to_json(self) -> dict:
        return dict(self.__dict__)


#: The units ``--units`` takes: symbol -> (name, metres).
UNITS = {"m": ("metre", 1.0), "ft": ("foot", 0.3048), "us-ft": ("US survey foot", 1200.0 / 3937.0)}


def _crs(crs):
    from pyproj import CRS

    return crs if isinstance(crs, CRS) else CRS.from_user_input(crs)


def crs_name(crs) -> str:
    """``EPSG:CODE (name)`` when pyproj finds the CRS's EPSG code, else its name.

    >>> crs_name("EPSG:2154")
    'EPSG:2154 (RGF93 v1 / Lambert-93)'
    """
    c = _crs(crs)
    return _label(c, c.to_epsg())


def _label(c, code) -> str:
    return f"EPSG:{code} ({c.name})" if code else c.name


def _horizontal_and_vertical(c):
    """The CRS's horizontal and vertical parts (the vertical one None when it has none)."""
    if c.is_compound:
        subs = c.sub_crs_list
        return subs[0], next((s for s in subs[1:] if s.is_vertical), None)
    return c, None


def _unit(axis) -> tuple[str, float]:
    return axis.unit_name, float(axis.unit_conversion_factor)


def _symbol(name: str, factor: float) -> str | None:
    for symbol, (_, metres) in UNITS.items():
        if abs(factor - metres) < 1e-9:
            return symbol
    return None


def crs_description(crs) -> dict:
    """Name, EPSG code (or None), whether geographic, and the horizontal and vertical units (name, metres) of a CRS.

    The vertical unit is the vertical CRS's, or the horizontal one's when the CRS has no vertical part.

    >>> d = crs_description("EPSG:2154")
    >>> d["epsg"], d["horizontal_unit"], d["vertical_unit"]
    (2154, ['metre', 1.0], ['metre', 1.0])
    """
    if isinstance(crs, str):  # a file's WKT: pyproj's EPSG search takes about 60 ms for a WKT without an authority, and
        return copy.deepcopy(_described(crs))  # its import 0.06-0.09 s: the answer is kept (crs_cache)
    return _describe(_crs(crs))


@functools.lru_cache(maxsize=64)
def _described(text: str) -> dict:
    return remembered("description", text.encode(), lambda: _describe(_crs(text)))  # kept on disk too: crs_cache


def _describe(c) -> dict:
    h, v = _horizontal_and_vertical(c)
    hu = _unit(h.axis_info[0]) if h.axis_info else ("unknown", float("nan"))
    vu = _unit(v.axis_info[0]) if v is not None and v.axis_info else hu
    code = c.to_epsg()
    return {"name": c.name, "epsg": code, "label": _label(c, code), "geographic": bool(h.is_geographic),
            "horizontal_unit": [hu[0], hu[1]], "vertical_unit": [vu[0], vu[1]]}


def units_of(crs, mins, maxs, override: str | None = None, where: str = "") -> Units:
    """The unit of a file's (or catalog's) coordinates, which distances are in.

    Parameters
    ----------
    crs : WKT, "EPSG:n" or None
        The file's CRS.
    mins, maxs : (2,) or (3,) sequences
        The coordinates' bounds (x, y first), to catch degrees in a projected CRS.
    override : {"m", "ft", "us-ft"}, optional
        ``--units``: taken as it is, whatever the CRS says (on every axis: a
        CRS whose heights are in another unit than its x, y is refused
        without it).
    where : str
        The file, to name in an error.

    Raises
    ------
    PatchcloudValueError
        An unknown ``override``; a geographic CRS; a projected CRS whose
        coordinates all lie within ±180 by ±90 over less than one unit (degrees,
        not lengths); a CRS whose unit is none of :data:`UNITS`.  Each
        message names ``--units``.
    """
    if override is not None:
        if override not in UNITS:
            raise PatchcloudValueError(f"units must be one of {', '.join(UNITS)}; got {override!r}")
        return Units(override, UNITS[override][0], UNITS[override][1], "--units")
    if crs is None:
        return Units("m", "metre", 1.0, "assumed")
    d = crs_description(crs)
    fix = f"reproject it to a projected CRS, or give --units {'|'.join(UNITS)} if its coordinates are lengths"
    if d["geographic"]:
        raise PatchcloudValueError(f"{where}: its CRS {d['label']} is geographic (coordinates in degrees, not lengths): {fix}")
    lo, hi = [float(v) for v in mins[:2]], [float(v) for v in maxs[:2]]
    if all(abs(v) <= 180.0 for v in (lo[0], hi[0])) and all(abs(v) <= 90.0 for v in (lo[1], hi[1])) and max(hi[0] - lo[0], hi[1] - lo[1]) < 1.0:
        raise PatchcloudValueError(f"{where}: its coordinates (x {lo[0]:g} to {hi[0]:g}, y {lo[1]:g} to {hi[1]:g}) look like degrees, "
                                   f"not lengths of its projected CRS {d['label']}: {fix}")
    name, factor = d["horizontal_unit"]
    symbol = _symbol(name, factor)
    if symbol is None:
        raise PatchcloudValueError(f"{where}: its CRS {d['label']} is in {name} ({factor:g} m), not metres or feet: give --units "
                                   f"{'|'.join(UNITS)}")
    vname, vfactor = d.get("vertical_unit") or (name, factor)
    if abs(float(vfactor) - float(factor)) > 1e-9 * float(factor):  # heights in feet over metres, say: slopes 3.28 x off
        raise PatchcloudValueError(
            f"{where}: its CRS {d['label']} has heights in {vname} ({float(vfactor):g} m) and x, y in {name} ({float(factor):g} m), "
            f"but normals, radii and errors need one unit on every axis: convert the heights to {name} (PDAL: filters.assign "
            f"with value \"Z = Z * {float(vfactor) / float(factor):.10g}\"), or give --units {symbol} to take every axis as it is"
        )
    return Units(symbol, UNITS[symbol][0], UNITS[symbol][1], "CRS")


#: The record ids of the CRS records (user id ``LASF_Projection``): OGC math transform WKT, OGC CRS WKT, and GeoTIFF's
#: key directory, double and ASCII parameters.
CRS_RECORD_IDS = (2111, 2112, 34735, 34736, 34737)


def is_crs_record(r) -> bool:
    """Whether the raw VLR or EVLR ``r`` (:class:`~patchcloud.stream.io.las_records.RawRecord`: ``name``, ``record_id``)
    is one of a CRS."""
    return r.name == "LASF_Projection" and r.record_id in CRS_RECORD_IDS


def with_crs(header, wkt: str):
    """``header`` (a ``laspy.LasHeader``, changed in place and returned) with the CRS ``wkt`` added after its VLRs, as
    LAS 1.4 asks: WKT (and the global encoding's WKT bit) for point formats 6 and up, GeoTIFF keys below (laspy's
    ``add_crs``, PDAL's choice too), or WKT where GeoTIFF keys cannot say the CRS exactly (one without an EPSG code:
    a PROJ string, a custom WKT).

    >>> import laspy
    >>> h = with_crs(laspy.LasHeader(point_format=6, version="1.4"), "EPSG:2154")
    >>> h.parse_crs().to_epsg(), h.global_encoding.wkt
    (2154, True)
    """
    from pyproj import CRS

    crs = CRS.from_user_input(wkt)
    if crs.to_epsg(min_confidence=100) is None:  # GeoTIFF keys name a CRS by its code: a near one would be another datum
        header.add_crs(crs, keep_compatibility=False)
        return header
    try:
        header.add_crs(crs)
    except Exception:  # GeoTIFF keys cannot hold this CRS: LAS 1.4 takes WKT for any point format
        header.add_crs(crs, keep_compatibility=False)
    return header
