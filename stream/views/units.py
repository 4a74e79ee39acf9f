"""Axis names and units of a picture, from the CRS of the file: "Easting (m)", "Northing (US ft)", "Elevation (ft)".

A projected CRS names its axes (Easting, Northing) and their unit; a
compound CRS adds the vertical one.  A LAS file with a horizontal CRS only
gives no unit for z: its heights are then taken to be in the horizontal
unit, as in practice (Autzen, in international feet, has its heights in
feet too).  A geographic CRS gives longitude and latitude in degrees; its
heights without a vertical CRS are in "file units".  A file without a CRS
says nothing: its axes are X, Y and Z in "file units".

Unit abbreviations: metre "m", international foot (0.3048 m) "ft", US
survey foot (1200/3937 m) "US ft", degree "°"; another unit by its name.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from patchcloud.stream.io.crs import UNITS

__all__ = ["AxisNames", "axis_names", "unit_abbreviation", "NO_CRS_UNIT", "LABELS"]

#: What an axis of unknown unit says.
NO_CRS_UNIT = "file units"
#: How an axis label writes each unit of :data:`patchcloud.stream.io.crs.UNITS` (the units distances may be in).
LABELS = {"m": "m", "ft": "ft", "us-ft": "US ft"}


@dataclass(frozen=True)
class AxisNames:
    """Names of the x, y and z axes of a file's coordinates and their units ("Easting", "m").

    Examples
    --------
    >>> a = AxisNames("Easting", "Northing", "Elevation", "ft", "ft")
    >>> a.x, a.z
    ('Easting (ft)', 'Elevation (ft)')
    """

    x_name: str = "X"
    y_name: str = "Y"
    z_name: str = "Z"
    horizontal: str = NO_CRS_UNIT
    vertical: str = NO_CRS_UNIT

    @property
    def x(self) -> str:
        return f"{self.x_name} ({self.horizontal})"

    @property
    def y(self) -> str:
        return f"{self.y_name} ({self.horizontal})"

    @property
    def z(self) -> str:
        return f"{self.z_name} ({self.vertical})"


def unit_abbreviation(name: str, metres: float | None) -> str:
    """The short name of a linear unit from pyproj's name and its length in metres; angular units: "°".

    Examples
    --------
    >>> unit_abbreviation("metre", 1.0), unit_abbreviation("foot", 0.3048), unit_abbreviation("US survey foot", 0.30480060960121924)
    ('m', 'ft', 'US ft')
    >>> unit_abbreviation("degree", 0.0174532925199433), unit_abbreviation("Clarke's link", 0.201166195164)
    ('°', "Clarke's link")
    """
    n = (name or "").lower()
    if "degree" in n:
        return "°"
    if metres is not None:
        for symbol, (_, value) in UNITS.items():
            if abs(float(metres) - value) <= 1e-9 * value:
                return LABELS[symbol]
    return name or NO_CRS_UNIT


def _axis(info) -> tuple[str, str]:
    return info.name, unit_abbreviation(info.unit_name, info.unit_conversion_factor)


def axis_names(crs: str | None, units: str | None = None) -> AxisNames:
    """The axis names and units of a CRS (WKT, "EPSG:2154", anything pyproj takes); X/Y/Z in file units for None.

    An unreadable CRS is treated as none (the picture is still drawn).
    ``units`` (one of :data:`patchcloud.stream.io.crs.UNITS`, ``--units``)
    overrides the CRS's units, horizontal and vertical, as it overrides them
    for every distance of a job; the axis names still come from the CRS.

    Examples
    --------
    >>> axis_names("EPSG:2154").x, axis_names("EPSG:2154").z     # Lambert-93: metres, heights in metres too
    ('Easting (m)', 'Elevation (m)')
    >>> a = axis_names("EPSG:2994")                               # NAD83(HARN) / Oregon GIC Lambert (ft)
    >>> a.y, a.z
    ('Northing (ft)', 'Elevation (ft)')
    >>> axis_names("EPSG:2249").x                                 # NAD83 / Massachusetts Mainland (ftUS)
    'Easting (US ft)'
    >>> axis_names("EPSG:2154+5720").z                            # compound: the vertical CRS's unit
    'Elevation (m)'
    >>> axis_names(None).x, axis_names(None).z
    ('X (file units)', 'Z (file units)')
    >>> axis_names(None, units="ft").x, axis_names("EPSG:2154", units="us-ft").z
    ('X (ft)', 'Elevation (US ft)')
    """
    names = _crs_axis_names(crs)
    if units is None:
        return names
    if units not in LABELS:
        raise ValueError(f"units must be one of {', '.join(LABELS)}; got {units!r}")
    return replace(names, horizontal=LABELS[units], vertical=LABELS[units])


def _crs_axis_names(crs: str | None) -> AxisNames:
    """:func:`axis_names` of the CRS alone."""
    if crs is None:
        return AxisNames()
    try:
        from pyproj import CRS

        c = CRS.from_user_input(crs)
    except Exception:  # pyproj missing or a CRS it cannot read: say nothing rather than fail the picture
        return AxisNames()
    parts = list(c.sub_crs_list) or [c]
    horizontal = next((p for p in parts if p.is_projected or p.is_geographic or p.is_geocentric), None)
    vertical = next((p for p in parts if p.is_vertical), None)
    if horizontal is None:
        return AxisNames()
    infos = list(horizontal.axis_info)
    east = next((a for a in infos if a.direction.lower() in ("east", "west")), None)
    north = next((a for a in infos if a.direction.lower() in ("north", "south")), None)
    if east is None or north is None or len(infos) < 2:
        east, north = (infos + [None, None])[:2]
    if east is None or north is None:
        return AxisNames()
    (xn, xu), (yn, _) = _axis(east), _axis(north)
    if horizontal.is_geographic:
        xn, yn = "Longitude", "Latitude"
    up = next((a for a in infos if a.direction.lower() == "up"), None)  # a 3D geographic CRS: its ellipsoidal height
    if vertical is not None and vertical.axis_info:
        zu = _axis(vertical.axis_info[0])[1]
    elif up is not None:
        zu = _axis(up)[1]
    elif horizontal.is_projected or horizontal.is_geocentric:  # (geocentric: x, y and z in one unit, lone-star's metres)
        zu = xu  # LAS practice: heights in the horizontal unit when no vertical CRS says otherwise
    else:
        zu = NO_CRS_UNIT
    return AxisNames(xn.capitalize() if xn else "X", yn.capitalize() if yn else "Y", "Elevation", xu, zu)
