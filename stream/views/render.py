"""Pictures of LAS/LAZ files of any size: ``patchcloud render``.

The file is streamed in chunks (:func:`~patchcloud.stream.io.las.read_chunks`)
and every chunk is reduced at once to at most one point per pixel, the one
nearest the viewer (a z-buffer), so memory depends on the image, never on the
file.  The pieces are pure numpy functions, unit-tested on their own:

* :func:`view_axes` / :func:`choose_view` / :func:`make_frame`: the
  orthographic camera and the image's framing from the header bounds (no
  first pass over the points);
* :class:`ZBuffer`: the per-pixel decimation, chunk by chunk;
* :func:`fill_gaps` / :func:`auto_fill`: the holes between the points
  closed from the nearest drawn pixel, within 2 mean point spacings;
* :func:`colorize`, :func:`lambert`, :func:`patch_boundaries`: colours,
  shading and patch outlines of the decimated pixels;
* :func:`render_figure`: the picture, exactly as wide as asked with its
  title, axes and legend (laid out by :mod:`.layout`, the axes named and in
  the units of the file's CRS by :mod:`.units`).

Views (orthographic; screen axes u to the right, v up, depth w towards the
viewer, the visible point of a pixel being the one of largest w, ties going
to the earlier point of the file):

* ``top``: looking straight down; u = x (east), v = y (north).
* ``side``: looking horizontally across the longer horizontal side of the
  bounding box: from the south (looking north, u = x) when the x extent is
  at least the y extent, else from the east (looking west, u = y); v = z.
* ``oblique``: from the south-west (azimuth 225°, i.e. looking north-east)
  and 35° above the horizon.

Default view: ``top`` when the file's height range is less than
:data:`FLAT_RATIO` (0.5) times its larger horizontal extent (aerial tiles,
even a 50 m urban tile with 20 m of trees and roofs; streets seen by
mobile mapping), else ``oblique`` (scans of single objects, facades,
terrestrial scans).

Shading (Lambert): brightness = a + (1 - a) max(0, n'·l) with ambient
a = :data:`AMBIENT` (0.4), n' the unit normal turned towards the viewer (so
the sign of the stored normal does not matter) and l the light from the
upper left of the image and towards the viewer: l = (-0.5, 0.5, 0.7071)
in screen coordinates (u, v, w), i.e. azimuth 315°, 45° high in the top
view.  The RGB colour is multiplied by it.  Shading needs the normals
(NormalX/Y/Z): by default a file with them is shaded, one without is not.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import laspy
import numpy as np

from patchcloud.core import PatchcloudIOError, PatchcloudValueError, check_flag

from patchcloud.stream.io.budget import check_memory
from patchcloud.stream.io.catalog import open_catalog
from patchcloud.stream.io.crs import UNITS
from patchcloud.stream.io.las import LasSource, check_not_input, open_source, read_chunks, read_range
from patchcloud.stream.views.layout import MIN_WIDTH, FigureLayout, figure_layout, layout_around
from patchcloud.stream.views.units import AxisNames, axis_names

__all__ = [
    "COLOR_MODES", "NO_DATA", "VIEWS", "AMBIENT", "FLAT_RATIO", "LIGHT", "BACKGROUND", "UNDEFINED", "NO_SEGMENT",
    "RenderImage", "RenderSummary", "ZBuffer", "Frame", "render", "render_array", "render_arrays", "render_figure",
    "view_axes", "choose_view", "auto_fill", "MAX_FILL", "MIN_FILL", "FILL_SPACINGS", "FILL_LIMIT", "point_spacing",
    "view_axis_labels", "picture_crs", "WIDTH_OF", "robust_heights", "HEIGHTS", "make_frame", "fill_gaps", "colorize", "lambert", "patch_boundaries", "segment_colours",
    "patch_colours", "class_colours", "robust_range", "supported_modes", "file_dimensions",
]

#: Colour modes and the dimensions each needs (elevation needs only the coordinates).
COLOR_MODES = {
    "normals": ("NormalX", "NormalY", "NormalZ"),
    "curvature": ("Curvature",),
    "don": ("DoN",),
    "segments": ("ClusterID",),
    "patches": ("PatchId",),
    "classification": ("classification",),
    "intensity": ("intensity",),
    "elevation": (),
}
NORMAL_DIMS = COLOR_MODES["normals"]
#: Views: see the module docstring.
VIEWS = ("top", "oblique", "side")
#: Default view rule: top when z range < FLAT_RATIO * max(x range, y range).
FLAT_RATIO = 0.5
#: Ambient share of the Lambert shading.
AMBIENT = 0.4
#: Light direction in screen coordinates (u right, v up, w towards the viewer), unit length.
LIGHT = np.array([-0.5, 0.5, np.sqrt(0.5)])
#: Oblique view: azimuth the viewer looks towards (degrees from north, clockwise) and elevation above the horizon.
OBLIQUE_AZIMUTH = 45.0
OBLIQUE_ELEVATION = 35.0
#: Colour of empty pixels, of points whose value is undefined (NaN), of ClusterID 0.
BACKGROUND = (1.0, 1.0, 1.0)
UNDEFINED = (0.85, 0.85, 0.85)
NO_SEGMENT = (0.6, 0.6, 0.6)
#: Factor darkening the pixels on a patch boundary.
BOUNDARY_DARKEN = 0.5
#: Robust colour range: these percentiles of the visible pixels' values.
PERCENTILES = (2.0, 98.0)
#: Continuous colour maps (perceptually uniform).
CMAPS = {"curvature": "viridis", "don": "viridis", "elevation": "cividis", "intensity": "gray"}
#: Continuous modes whose files hold this value where there is none, shown UNDEFINED: DoN is 0 where a normal at
#: either scale is undefined (declared as its no-data value; a true 0 would need the same normal at both scales).
NO_DATA = {"don": 0.0}
#: Largest image height, in multiples of the width (a very elongated frame gets a coarser pixel instead).
MAX_ASPECT = 4

#: ASPRS standard classes (LAS 1.4 R15, table 17): name and colour.
ASPRS = {
    0: ("never classified", (0.55, 0.55, 0.55)),
    1: ("unclassified", (0.75, 0.75, 0.75)),
    2: ("ground", (0.65, 0.47, 0.28)),
    3: ("low vegetation", (0.65, 0.88, 0.45)),
    4: ("medium vegetation", (0.35, 0.72, 0.25)),
    5: ("high vegetation", (0.10, 0.45, 0.12)),
    6: ("building", (0.86, 0.25, 0.20)),
    7: ("low point (noise)", (1.00, 0.00, 1.00)),
    8: ("model key / reserved", (1.00, 1.00, 0.00)),
    9: ("water", (0.20, 0.45, 0.90)),
    10: ("rail", (0.45, 0.30, 0.45)),
    11: ("road surface", (0.30, 0.30, 0.30)),
    12: ("overlap / reserved", (0.90, 0.90, 0.55)),
    13: ("wire guard", (0.95, 0.80, 0.20)),
    14: ("wire conductor", (0.95, 0.60, 0.10)),
    15: ("transmission tower", (0.60, 0.30, 0.70)),
    16: ("wire connector", (0.80, 0.60, 0.90)),
    17: ("bridge deck", (0.55, 0.35, 0.60)),
    18: ("high noise", (1.00, 0.40, 1.00)),
}


# ---------------------------------------------------------------------------
# camera and framing


def view_axes(view: str, mins, maxs) -> np.ndarray:
    """The (3, 3) rotation whose rows are the screen axes u (right), v (up), w (towards the viewer).

    Parameters
    ----------
    view : {"top", "oblique", "side"}
    mins, maxs : (3,) bounds of the box shown (only the side view uses them: it looks across the longer side).

    Examples
    --------
    >>> view_axes("top", (0, 0, 0), (1, 1, 1)).tolist()
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    >>> view_axes("side", (0, 0, 0), (10, 2, 1))[2].tolist()   # from the south: towards the viewer is -y
    [0.0, -1.0, 0.0]
    """
    if view == "top":
        return np.eye(3)
    if view == "side":
        ext = np.asarray(maxs, float) - np.asarray(mins, float)
        az, el = (0.0, 0.0) if ext[0] >= ext[1] else (-90.0, 0.0)
    elif view == "oblique":
        az, el = OBLIQUE_AZIMUTH, OBLIQUE_ELEVATION
    else:
        raise PatchcloudValueError(f"view must be one of {', '.join(VIEWS)}; got {view!r}")
    a, e = np.radians(az), np.radians(el)
    d = np.array([np.cos(e) * np.sin(a), np.cos(e) * np.cos(a), -np.sin(e)])  # looking direction
    u = np.cross(d, [0.0, 0.0, 1.0])
    u /= np.linalg.norm(u)
    v = np.cross(u, d)
    R = np.array([u, v / np.linalg.norm(v), -d])
    R[np.abs(R) < 1e-15] = 0.0
    return R + 0.0  # no negative zeros


def choose_view(mins, maxs) -> str:
    """The default view of a box: "top" when its height is under FLAT_RATIO x its larger horizontal side, else "oblique".

    Examples
    --------
    >>> choose_view((0, 0, 0), (1000, 1000, 60)), choose_view((0, 0, 0), (30, 40, 25)), choose_view((5, 5, 5), (5, 5, 5))
    ('top', 'oblique', 'top')
    """
    ext = np.asarray(maxs, float) - np.asarray(mins, float)
    return "top" if ext[2] < FLAT_RATIO * max(ext[0], ext[1]) or not ext.any() else "oblique"


@dataclass(frozen=True)
class Frame:
    """The image: pixel (row, col) covers u in [umin + col*pixel, +pixel), v in (vmax - (row+1)*pixel, vmax - row*pixel]."""

    umin: float
    vmax: float
    pixel: float
    width: int
    height: int

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(left, right, bottom, top) in screen coordinates (metres)."""
        return (self.umin, self.umin + self.width * self.pixel, self.vmax - self.height * self.pixel, self.vmax)

    def pixels(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat pixel index (row * width + col) of screen coordinates, and which fall inside the image.

        Points exactly on the right or bottom edge go to the last column or row.
        """
        col = np.floor((u - self.umin) / self.pixel).astype(np.int64)
        row = np.floor((self.vmax - v) / self.pixel).astype(np.int64)
        col[col == self.width] = self.width - 1
        row[row == self.height] = self.height - 1
        inside = (col >= 0) & (col < self.width) & (row >= 0) & (row < self.height)
        return row * self.width + col, inside


def make_frame(R: np.ndarray, lo, hi, width: int) -> Frame:
    """The frame of ``width`` pixels that holds the box [lo, hi] (local metres) seen along ``R``; square pixels.

    The height follows the aspect ratio of the projected box, at most
    MAX_ASPECT x width (a longer frame gets larger pixels and fewer columns).

    Examples
    --------
    >>> f = make_frame(np.eye(3), (0, 0, 0), (100, 50, 10), 200)
    >>> f.width, f.height, f.pixel
    (200, 100, 0.5)
    >>> f = make_frame(np.eye(3), (5, 5, 5), (5, 5, 5), 100)  # copies of one point: a unit square around it
    >>> f.umin, f.vmax, f.width, f.height
    (4.5, 5.5, 100, 100)
    """
    width = int(width)
    if not 1 <= width <= MAX_WIDTH:
        raise PatchcloudValueError(f"width must be 1 to {MAX_WIDTH} pixels; got {width!r}")
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    u, v = corners @ R[0], corners @ R[1]
    du, dv = float(u.max() - u.min()), float(v.max() - v.min())
    u_min, v_max = float(u.min()), float(v.max())
    if du <= 0 and dv <= 0:  # one point (or copies of it): a unit square with it in the middle
        du = dv = 1.0
        u_min, v_max = u_min - 0.5, v_max + 0.5
    pixel = max(du, 1e-9) / width
    if dv / pixel > MAX_ASPECT * width:
        pixel = dv / (MAX_ASPECT * width)
    W = max(1, int(np.ceil(du / pixel - 1e-9)))
    H = max(1, int(np.ceil(dv / pixel - 1e-9)))
    return Frame(u_min, v_max, float(pixel), W, H)


# ---------------------------------------------------------------------------
# decimation


class ZBuffer:
    """The point nearest the viewer in every pixel, built chunk by chunk.

    Each pixel keeps the point of largest depth (towards the viewer); among
    equal depths the smallest input index.  That is a total order, so the
    result does not depend on how the points are split into chunks or on
    their order.

    Parameters
    ----------
    height, width : int
        Image size in pixels.
    channels : int
        Values kept per pixel (float64).

    Examples
    --------
    >>> zb = ZBuffer(1, 2, 1)
    >>> zb.add(np.array([0, 0, 1]), np.array([1.0, 3.0, 2.0]), np.array([0, 1, 2]), np.array([[10.], [11.], [12.]]))
    >>> zb.add(np.array([1]), np.array([2.0]), np.array([3]), np.array([[13.]]))   # same depth, later point: loses
    >>> zb.values[:, 0].tolist(), zb.index.tolist()
    ([11.0, 12.0], [1, 2])
    """

    def __init__(self, height: int, width: int, channels: int):
        n = int(height) * int(width)
        self.shape = (int(height), int(width))
        self.depth = np.full(n, -np.inf)
        self.index = np.full(n, -1, dtype=np.int64)
        self.values = np.full((n, int(channels)), np.nan)

    def add(self, pixel: np.ndarray, depth: np.ndarray, index: np.ndarray, values: np.ndarray) -> None:
        """Offer points (flat pixel, depth, input index, (n, channels) values) to the buffer."""
        if pixel.size == 0:
            return
        order = np.lexsort((index, -depth, pixel))
        p = pixel[order]
        first = np.empty(p.size, dtype=bool)
        first[0] = True
        np.not_equal(p[1:], p[:-1], out=first[1:])
        sel = order[first]
        p, d, i = pixel[sel], depth[sel], index[sel]
        cd, ci = self.depth[p], self.index[p]
        better = (d > cd) | ((d == cd) & ((ci < 0) | (i < ci)))
        p = p[better]
        sel = sel[better]
        self.depth[p] = d[better]
        self.index[p] = i[better]
        self.values[p] = values[sel]

    @property
    def filled(self) -> np.ndarray:
        """(H, W) bool: pixels that show a point."""
        return (self.index >= 0).reshape(self.shape)

    def channel(self, k: int) -> np.ndarray:
        """(H, W) values of channel ``k`` (NaN where empty)."""
        return self.values[:, k].reshape(self.shape)


def point_spacing(drawn: np.ndarray) -> float:
    """The mean spacing (pixels) of the points drawn in ``drawn``, over the area they cover (not the whole frame).

    The area is the cells of a coarse grid (cells about twice the spacing)
    that hold a drawn pixel, so a lake, the sky of an oblique view or a
    frame larger than the cloud do not count; the spacing is the square
    root of that area over the drawn pixels (one point each), estimated
    twice (the first time over the whole frame).  NaN when nothing is drawn.

    Examples
    --------
    >>> d = np.zeros((100, 200), bool); d[::4, :100:4] = True     # points 4 px apart over the left half
    >>> round(point_spacing(d), 2)    # 4, and a little for the cells cut by the edge of the points
    4.08
    """
    drawn = np.asarray(drawn, dtype=bool)
    n = int(drawn.sum())
    if n == 0:
        return float("nan")
    H, W = drawn.shape
    s = float(np.sqrt(H * W / n))
    for _ in range(2):
        c = max(1, int(round(2.0 * s)))
        rows = np.logical_or.reduceat(drawn, np.arange(0, H, c), axis=0)
        cells = np.logical_or.reduceat(rows, np.arange(0, W, c), axis=1)
        # cells on the last row / column may be cut short: count their real area
        hs = np.diff(np.append(np.arange(0, H, c), H))
        ws = np.diff(np.append(np.arange(0, W, c), W))
        area = float((cells * hs[:, None] * ws[None, :]).sum())
        s = float(np.sqrt(area / n))
    return s


def fill_gaps(drawn: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Close the holes between the points: every empty pixel within ``radius`` pixels of a drawn one shows the nearest.

    One Euclidean distance transform (:func:`scipy.ndimage.distance_transform_edt`)
    finds each empty pixel's nearest drawn pixel, so the gaps between scan
    lines close whatever their direction (no dashes), while an empty area
    wider than twice the radius (a lake, a courtyard, the space beside the
    cloud) stays empty farther than ``radius`` from its shore.

    Parameters
    ----------
    drawn : (H, W) bool
        Pixels a point was drawn in.
    radius : float
        Pixels (centre to centre); 0: no filling.

    Returns
    -------
    source : (H, W) int64
        The flat pixel each pixel shows (itself for drawn and empty pixels).
    filled : (H, W) bool
        Pixels that show a point after filling.

    Examples
    --------
    >>> d = np.zeros((1, 6), bool); d[0, 0] = d[0, 5] = True
    >>> src, filled = fill_gaps(d, 2)
    >>> src.tolist(), filled.tolist()   # pixels 1, 2 take the left point, 3, 4 the right one
    ([[0, 0, 0, 5, 5, 5]], [[True, True, True, True, True, True]])
    >>> fill_gaps(d, 1)[1].tolist()     # pixels 2 and 3 are 2 px from either point
    [[True, True, False, False, True, True]]
    """
    from scipy.ndimage import distance_transform_edt

    drawn = np.asarray(drawn, dtype=bool)
    H, W = drawn.shape
    source = np.arange(H * W, dtype=np.int64).reshape(H, W)
    if not radius > 0 or not drawn.any() or drawn.all():
        return source, drawn.copy()
    dist, (ri, ci) = distance_transform_edt(~drawn, return_indices=True)
    take = ~drawn & (dist <= float(radius))
    del dist
    source[take] = ri[take].astype(np.int64) * W + ci[take]
    return source, drawn | take


# ---------------------------------------------------------------------------
# colours


def robust_range(values: np.ndarray, percentiles=PERCENTILES) -> tuple[float, float]:
    """(low, high): the given percentiles of the finite values; a unit-wide range around a constant; (0, 1) for none.

    Examples
    --------
    >>> robust_range(np.arange(101.0))
    (2.0, 98.0)
    >>> robust_range(np.array([5.0, np.nan]))
    (4.5, 5.5)
    """
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return (0.0, 1.0)
    lo, hi = (float(x) for x in np.percentile(v, percentiles))
    if not hi > lo:
        return (lo - 0.5, lo + 0.5) if lo == hi else (float(v.min()), float(v.max()))
    return (lo, hi)


def _hsv_to_rgb(h, s, v):
    from matplotlib.colors import hsv_to_rgb

    return hsv_to_rgb(np.stack([h, s, v], axis=-1))


def segment_colours(ids: np.ndarray) -> np.ndarray:
    """(..., 3) colours of segment ids: tab20 without its two greys (18 colours), cycled by id; id 0 (no segment) is NO_SEGMENT grey.

    Examples
    --------
    >>> segment_colours(np.array([0, 1, 19]))[:, 0].round(3).tolist()
    [0.6, 0.122, 0.122]
    """
    from matplotlib import colormaps

    tab = np.asarray(colormaps["tab20"].colors)[:, :3]
    tab = np.delete(tab, [14, 15], axis=0)  # the greys would read as "no segment"
    ids = np.asarray(ids).astype(np.int64)
    out = tab[(np.maximum(ids, 1) - 1) % len(tab)]
    out[ids == 0] = NO_SEGMENT
    return out


def patch_colours(ids: np.ndarray) -> np.ndarray:
    """(..., 3) colours of patch ids: hue by the golden ratio (consecutive ids far apart), saturation and value hashed.

    Examples
    --------
    >>> c = patch_colours(np.array([1, 2, 1]))
    >>> bool((c[0] == c[2]).all()), bool((c[0] != c[1]).any())
    (True, True)
    """
    k = np.asarray(ids).astype(np.float64)
    h = np.mod(k * 0.6180339887498949, 1.0)
    s = 0.45 + 0.4 * np.mod(k * 0.7548776662466927, 1.0)
    v = 0.7 + 0.3 * np.mod(k * 0.5698402909980532, 1.0)
    return _hsv_to_rgb(h, s, v)


def class_colours(codes: np.ndarray) -> np.ndarray:
    """(..., 3) ASPRS colours of classification codes; codes outside the standard table get a hashed colour.

    Examples
    --------
    >>> class_colours(np.array([2, 6])).round(2).tolist()
    [[0.65, 0.47, 0.28], [0.86, 0.25, 0.2]]
    """
    codes = np.asarray(codes).astype(np.int64)
    lut = patch_colours(np.arange(256) * 7 + 3)
    for c, (_, rgb) in ASPRS.items():
        lut[c] = rgb
    return lut[np.clip(codes, 0, 255)]


def _continuous(values, cmap_name, rng):
    from matplotlib import colormaps

    lo, hi = rng
    t = np.clip((values - lo) / (hi - lo), 0.0, 1.0)
    rgb = np.asarray(colormaps[cmap_name](np.nan_to_num(t, nan=0.0)))[..., :3]
    rgb[~np.isfinite(values)] = UNDEFINED
    return rgb


def colorize(
    color: str, values: np.ndarray, filled: np.ndarray, value_range=None, drawn: np.ndarray | None = None,
) -> tuple[np.ndarray, tuple | None, list]:
    """Colours of the visible pixels.

    Parameters
    ----------
    color : str
        One of :data:`COLOR_MODES`.
    values : (H, W, 3) normals for "normals", else (H, W) values (ids, codes, metres...), NaN = undefined.
    filled : (H, W) bool
        Pixels that show a point; the others are BACKGROUND.
    value_range : (low, high), optional
        For the continuous modes (curvature, don, intensity, elevation):
        default the 2nd-98th percentiles of the finite values of the
        ``drawn`` pixels.
    drawn : (H, W) bool, optional
        The pixels a point was drawn in before gap filling (default:
        ``filled``), so that filled pixels do not weigh in the range twice.

    Returns
    -------
    rgb : (H, W, 3) float64 in [0, 1]
        normals: (n + 1) / 2; curvature, DoN: viridis; elevation: cividis;
        intensity: grey; segments: :func:`segment_colours`; patches:
        :func:`patch_colours`; classification: :func:`class_colours`;
        undefined values UNDEFINED grey: NaN, a zero normal, and DoN's
        no-data 0 (:data:`NO_DATA`), which the colour range leaves out.
    value_range : (low, high) or None
        The range mapped onto the colour map (continuous modes).
    legend : list of (label, rgb, pixels)
        Classification: one entry per class visible, most frequent first.

    Examples
    --------
    >>> rgb, rng, _ = colorize("normals", np.array([[[0.0, 0.0, 1.0]]]), np.array([[True]]))
    >>> rgb[0, 0].tolist(), rng
    ([0.5, 0.5, 1.0], None)
    """
    if color not in COLOR_MODES:
        raise PatchcloudValueError(f"color must be one of {', '.join(COLOR_MODES)}; got {color!r}")
    filled = np.asarray(filled, dtype=bool)
    H, W = filled.shape
    rgb = np.empty((H, W, 3))
    rgb[...] = BACKGROUND
    rng = None
    legend: list = []
    v = values[filled]
    if color in NO_DATA:  # the value the outputs write where there is none (README: "No NaN, and what a point ...")
        values = np.where(values == NO_DATA[color], np.nan, values)
        v = values[filled]
    if color == "normals":
        c = (v + 1.0) / 2.0
        c[~np.isfinite(c).all(axis=1) | (v == 0.0).all(axis=1)] = UNDEFINED  # (0, 0, 0): a point left out, no normal
    elif color in CMAPS:
        own = v if drawn is None else values[np.asarray(drawn, dtype=bool) & filled]
        rng = tuple(float(x) for x in value_range) if value_range is not None else robust_range(own)
        c = _continuous(v, CMAPS[color], rng)
    else:
        ok = np.isfinite(v)
        ids = np.where(ok, v, 0).astype(np.int64)
        if color == "segments":
            c = segment_colours(ids)
        elif color == "patches":
            c = patch_colours(ids)
        else:
            c = class_colours(ids)
            codes, counts = np.unique(ids[ok], return_counts=True)
            for k in np.argsort(-counts, kind="stable"):
                code = int(codes[k])
                name = ASPRS.get(code, ("other",))[0]
                legend.append((f"{code} {name}", tuple(float(x) for x in class_colours(np.array([code]))[0]), int(counts[k])))
        c[~ok] = UNDEFINED
    rgb[filled] = c
    return np.clip(rgb, 0.0, 1.0), rng, legend


def lambert(normals: np.ndarray, R: np.ndarray, ambient: float = AMBIENT, light=LIGHT) -> np.ndarray:
    """Lambert brightness a + (1 - a) max(0, n'·l) of world-frame normals seen along ``R``; 1 where a normal is undefined.

    n' is the normal turned towards the viewer (its sign in the file does not
    matter); l is ``light`` in screen coordinates (u, v, w), unit length.

    Examples
    --------
    >>> lambert(np.array([[0.0, 0.0, -1.0]]), np.eye(3)).round(4).tolist()   # facing the viewer once turned
    [0.8243]
    """
    n = np.asarray(normals, dtype=np.float64)
    screen = np.stack([n[..., 0] * R[k, 0] + n[..., 1] * R[k, 1] + n[..., 2] * R[k, 2] for k in range(3)], axis=-1)
    norm = np.sqrt((screen * screen).sum(axis=-1))
    sign = np.where(screen[..., 2] < 0, -1.0, 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = sign * (screen @ np.asarray(light, dtype=np.float64)) / norm
    b = ambient + (1.0 - ambient) * np.maximum(0.0, cos)
    return np.where(np.isfinite(b), b, 1.0)


def patch_boundaries(ids: np.ndarray, filled: np.ndarray) -> np.ndarray:
    """(H, W) bool: filled pixels with a filled 4-neighbour of another id.

    Examples
    --------
    >>> patch_boundaries(np.array([[1, 1, 2]]), np.ones((1, 3), bool)).tolist()
    [[False, True, True]]
    """
    ids = np.asarray(ids)
    filled = np.asarray(filled, dtype=bool)
    out = np.zeros(filled.shape, dtype=bool)
    for axis in (0, 1):
        a = [slice(None)] * 2
        b = [slice(None)] * 2
        a[axis], b[axis] = slice(1, None), slice(None, -1)
        a, b = tuple(a), tuple(b)
        diff = filled[a] & filled[b] & (ids[a] != ids[b])
        out[a] |= diff
        out[b] |= diff
    return out


# ---------------------------------------------------------------------------
# the file


def file_dimensions(path: str | os.PathLike) -> list[str]:
    """Names of the dimensions of a LAS/LAZ file (standard and extra bytes)."""
    try:
        with laspy.open(path) as r:
            return list(r.header.point_format.dimension_names)
    except Exception as exc:
        raise PatchcloudIOError(f"{path}: not a readable LAS/LAZ file ({exc})") from exc


def supported_modes(dims) -> list[str]:
    """The colour modes whose dimensions are all in ``dims``.

    Examples
    --------
    >>> supported_modes(["X", "Y", "Z", "intensity", "classification"])
    ['classification', 'intensity', 'elevation']
    """
    have = set(dims)
    return [m for m, need in COLOR_MODES.items() if all(d in have for d in need)]


@dataclass
class RenderImage:
    """An image of a file, before it is drawn into a figure (see :func:`render_array`).

    ``rgb`` is (H, W, 3) float64 in [0, 1], row 0 at the top; ``filled``
    the pixels that show a point (after gap filling; ``points_drawn``
    counts the points kept by the z-buffer, one per pixel, before it); ``value`` the value shown in each pixel
    ((H, W, 3) normals or (H, W) values, NaN where empty); ``extent``
    (left, right, bottom, top) in file units: file coordinates for the top view
    (x, y) and the side view (x or y, and z), screen coordinates about the
    box's lower corner for the oblique view.  ``names``: the axes' names
    and units from the file's CRS; ``layout``: the picture it was framed
    for (:func:`render_figure` draws it exactly that wide), None when the
    image was made ``width`` pixels wide itself; ``fill``: the gap-filling
    radius in pixels; ``range_given``: the colour range was asked for
    (else the 2nd-98th percentiles).
    """

    source: str
    color: str
    view: str
    shaded: bool
    rgb: np.ndarray
    filled: np.ndarray
    value: np.ndarray
    extent: tuple[float, float, float, float]
    pixel: float
    axes: np.ndarray
    point_count: int
    points_in_box: int
    points_drawn: int
    value_range: tuple[float, float] | None
    legend: list = field(default_factory=list)
    bbox: tuple[float, float, float, float] | None = None
    fill: float = 0.0
    seconds: float = 0.0
    names: AxisNames = field(default_factory=AxisNames)
    layout: FigureLayout | None = None
    range_given: bool = False

    @property
    def pixels_filled(self) -> int:
        return int(self.filled.sum())

    @property
    def axis_labels(self) -> tuple[str | None, str | None]:
        """Labels of the image axes, "Easting (m)", "Elevation (ft)"... (None for the oblique view, whose axes are not drawn)."""
        return view_axis_labels(self.view, self.axes, self.names)


def view_axis_labels(view: str, R: np.ndarray, names: AxisNames) -> tuple[str | None, str | None]:
    """The labels of the horizontal and vertical axes of a view: file axes with the CRS's names and units.

    Examples
    --------
    >>> view_axis_labels("side", view_axes("side", (0, 0, 0), (2, 10, 1)), AxisNames("Easting", "Northing", "Elevation", "m", "m"))
    ('Northing (m)', 'Elevation (m)')
    """
    if view == "top":
        return names.x, names.y
    if view == "side":
        return (names.x if abs(R[0, 0]) > 0.5 else names.y), names.z
    return None, None


@dataclass
class RenderSummary:
    """What :func:`render` drew: the PNG's size, the image's, points read from the file, inside the frame, drawn (one per pixel), pixels filled (after gap filling)."""

    input: str
    output: str
    color: str
    view: str
    shaded: bool
    width: int
    height: int
    points_read: int
    points_in_box: int
    points_drawn: int
    pixels_filled: int
    value_range: tuple[float, float] | None
    seconds: float
    image_width: int = 0
    image_height: int = 0
    pixel: float = 0.0
    unit: str = ""
    fill: float = 0.0

    def format(self) -> str:
        rng = "" if self.value_range is None else f", colour range {self.value_range[0]:.4g} .. {self.value_range[1]:.4g}"
        return (
            f"{self.input} -> {self.output}: {self.width} x {self.height} px PNG, {self.color}, {self.view} view"
            f"{', shaded' if self.shaded else ''}{rng}\n"
            f"image {self.image_width} x {self.image_height} px of {self.pixel:.4g} {self.unit}, "
            f"{self.points_read:,} points read, {self.points_in_box:,} in the frame, {self.points_drawn:,} drawn "
            f"(one per pixel), {self.pixels_filled:,} pixels filled (radius {self.fill:.3g} px), {self.seconds:.1f} s"
        )


def _check_bbox(bbox):
    if bbox is None:
        return None
    b = tuple(float(v) for v in bbox)
    if len(b) != 4 or not all(np.isfinite(b)) or not (b[2] > b[0] and b[3] > b[1]):
        raise PatchcloudValueError(f"bbox must be xmin ymin xmax ymax with xmin < xmax and ymin < ymax (file coordinates); got {bbox!r}")
    return b


#: Framing sample: windows spread over the file, points per window (all points of smaller files).
FRAME_WINDOWS, FRAME_WINDOW = 32, 1 << 15
#: An empty band of heights wider than this share of the header's height range (or than the sample's
#: 1st-99th percentile range, if larger) separates outliers from the cloud.
OUTLIER_GAP = 0.1
#: What ``heights`` may be: a frame for the heights of a sample (outliers left out), or for the header's bounds.
HEIGHTS = ("robust", "all")


def robust_heights(src: LasSource) -> tuple[float, float]:
    """Heights (file z, metres) to frame: those of a sample of the file, without the outliers an empty band cuts off.

    The sample is FRAME_WINDOWS runs of FRAME_WINDOW points spread over
    the file (the whole file when it is no larger), read by seeking, so it
    costs a fraction of a pass.  From the sample's 1st-99th percentiles
    the range grows up (and down) through the sorted sampled heights until
    an empty band wider than ``OUTLIER_GAP`` x the header's height range
    (or the percentile range, if larger): a pylon or a tree, sampled all
    the way up, stays in; a bird 500 m above a city tile, or a return 80 m
    under the ground, is cut off.  The result never exceeds the header's
    bounds.
    """
    n = src.point_count
    zs = []
    if n <= FRAME_WINDOWS * FRAME_WINDOW:
        zs = [np.asarray(pts.z, dtype=np.float64) for _, pts in read_chunks(src, 1 << 20)]
    else:
        for start in np.linspace(0, n - FRAME_WINDOW, FRAME_WINDOWS).astype(np.int64).tolist():
            zs.append(np.asarray(read_range(src, start, FRAME_WINDOW).z, dtype=np.float64))
    z = np.sort(np.concatenate(zs)) if zs else np.zeros(0)
    zmin, zmax = float(src.mins[2]), float(src.maxs[2])
    if z.size == 0:
        return zmin, zmax
    q0, q1 = np.percentile(z, [1.0, 99.0])
    gap = max(q1 - q0, OUTLIER_GAP * (zmax - zmin), 1e-9)
    up = np.concatenate([[q1], z[z > q1]])
    cut = np.flatnonzero(np.diff(up) > gap)
    top = up[cut[0]] if cut.size else up[-1]
    down = np.concatenate([[q0], z[z < q0][::-1]])
    cut = np.flatnonzero(-np.diff(down) > gap)
    bottom = down[cut[0]] if cut.size else down[-1]
    # a sample may miss the highest and lowest points of the cloud itself: a little room (none where every point was
    # read: past the cloud's own extremes, room clipped only by the header's bounds, which outliers widen, grew the
    # range by a tenth, and turned a tile with two outliers from a top view to an oblique one; bug hunt I)
    pad = 0.0 if n <= FRAME_WINDOWS * FRAME_WINDOW else 0.05 * float(top - bottom)
    return max(zmin, float(bottom) - pad), min(zmax, float(top) + pad)


#: Widest image (pixels): a picture takes about 180 bytes a pixel at its peak (6.5 GB for a square image this wide).
MAX_WIDTH = 6000
#: Bytes an image pixel takes at the picture's peak (depth, index, filled masks, the gap-filling and RGB passes, then
#: matplotlib's resampled RGBA copies and its canvas while the PNG is drawn), besides 8 per channel and picture: a
#: picture is checked against the memory budget (``--max-memory``) before its buffers are made.  Measured on
#: 2026-11-29: 1.37 GB above the process's start for an image of 8.05 million pixels (the embedded tile and
#: fusa.laz at --width 3000, elevation), 170 bytes a pixel; 96 before, which left out the drawing (review N).
PIXEL_BYTES = 176
#: Gap filling by default: empty pixels within this many point spacings of a point are filled.
FILL_SPACINGS = 2.0
#: Largest filling radius the default chooses, and the smallest (pixels).
MAX_FILL, MIN_FILL = 32.0, 1.5
#: Largest filling radius that may be asked for (pixels).
FILL_LIMIT = 64


def auto_fill(drawn: np.ndarray) -> float:
    """The default filling radius (pixels): FILL_SPACINGS x the :func:`point_spacing` of ``drawn``, from MIN_FILL to MAX_FILL.

    With points on scan lines (along-line spacing s, lines L apart) the
    farthest empty pixel is sqrt(s² + L²) / 2 from a point: under 2 mean
    spacings sqrt(s L) for lines up to 15 s apart.  Among points spread at
    random, a pixel farther than 2 mean spacings from all of them happens
    with probability exp(-4 π) < 4e-6 (at 1.5 spacings, 9e-4: holes).
    A real gap (a lake) stays empty but for a band of 2 spacings along its shore.

    Examples
    --------
    >>> d = np.zeros((400, 400), bool); d[::4, ::4] = True
    >>> auto_fill(d), auto_fill(np.ones((4, 4), bool)), auto_fill(np.zeros((4, 4), bool))
    (8.0, 2.0, 1.5)
    """
    s = point_spacing(drawn)
    if not np.isfinite(s):
        return MIN_FILL
    return float(np.clip(FILL_SPACINGS * s, MIN_FILL, MAX_FILL))


def render_array(
    input, *, color: str, view: str | None = None, bbox=None, width: int = 1600,
    shade: bool | None = None, value_range=None, fill: float | None = None, heights: str = "robust", chunk: int = 1 << 20,
    assume_crs: str | None = None, width_of: str = "image", units: str | None = None,
) -> RenderImage:
    """The picture of a LAS/LAZ file of any size, or of a catalog of them, as an RGB array, read out of core.

    Parameters
    ----------
    input : path of a LAS/LAZ/COPC file, or a catalog: several paths, a
        directory, a glob (:func:`patchcloud.stream.io.catalog.expand_inputs`),
        drawn as one cloud in one frame (the files must be in one CRS).
    color : {"normals", "curvature", "don", "segments", "patches", "classification", "intensity", "elevation"}
        What the colour shows; the file must have the dimension(s) of the
        mode (see :data:`COLOR_MODES`).
    view : {"top", "oblique", "side"}, optional
        Default: :func:`choose_view` of the framed box.
    bbox : (xmin, ymin, xmax, ymax), optional
        File coordinates (the file's CRS and units): only the points inside
        are drawn and the frame is this box (with the file's z range).
    width : int
        Width in pixels of the image (``width_of="image"``), or of the
        picture :func:`render_figure` draws of it (``"figure"``: title, axes
        and legend included; the image gets the columns they leave, see
        :func:`patchcloud.stream.views.layout.figure_layout`).  The height
        follows the aspect ratio.
    shade : bool, optional
        Lambert shading from the normals; default: when the file has NormalX/Y/Z.
    value_range : (low, high), optional
        Colour range of the continuous modes; default the 2nd-98th
        percentiles of the visible pixels' values.
    fill : float, optional
        Gap filling (:func:`fill_gaps`): every empty pixel within ``fill``
        pixels of a drawn one shows the nearest drawn one, closing the holes
        between scan lines and sparse points; 0: none.  Default
        (:func:`auto_fill`): 2 x the mean spacing in pixels of the points
        drawn, over the area they cover, from 1.5 to :data:`MAX_FILL`, so an
        aerial tile at 25 points/m² and a dense mobile scan both look like
        surfaces at any width while a lake or a courtyard wider than 4
        spacings stays empty.
    heights : {"robust", "all"}
        The heights the frame (and the default view) is chosen for.
        "robust" (default): from a sample of the file
        (:func:`robust_heights`), so noise far above or below (birds, low
        returns) neither squashes the picture nor turns an aerial tile into
        an oblique view; in the oblique and side views such points fall
        outside the picture.  "all": the header's bounds.
    chunk : int
        Points read at a time (the result does not depend on it).
    assume_crs : str, optional
        In a catalog, the CRS of files without one (as ``RunOptions.assume_crs``).
    units : {"m", "ft", "us-ft"}, optional
        The unit of the coordinates, instead of the CRS's (``--units``, as
        in the jobs): the axis labels and the pixel size say it.  Default:
        the CRS's units; "file units" for a file without a CRS.

    Returns
    -------
    RenderImage

    Raises
    ------
    PatchcloudIOError
        Not a readable LAS/LAZ file.
    PatchcloudValueError
        A bad option, or the file lacks the mode's dimension (the message
        names the file, the dimension and the modes the file supports).

    Examples
    --------
    >>> img = render_array(sample, color="classification", width=400)   # an aerial tile: seen from the top
    >>> img.rgb.shape, img.rgb.dtype, img.view
    ((400, 400, 3), dtype('float64'), 'top')
    >>> img.point_count, img.points_drawn <= img.point_count, img.shaded   # no normals in the file: no shading
    (60653, True, False)
    """
    return render_arrays(input, colors=[color], view=view, bbox=bbox, width=width, shade=shade, value_range=value_range,
                         fill=fill, heights=heights, chunk=chunk, assume_crs=assume_crs, width_of=width_of, units=units)[0]


def input_sources(input, assume_crs: str | None = None) -> tuple[list[LasSource], str]:
    """The files a picture shows, and how it names them: one file, or a catalog (several paths, a directory, a glob).

    The files of a catalog must be one cloud in one CRS (see
    :func:`patchcloud.stream.io.catalog.open_catalog`, and its ``assume_crs``).
    """
    if isinstance(input, (str, os.PathLike)) and Path(input).is_file():
        return [open_source(input)], str(input)
    cat = open_catalog(input, assume_crs)
    return list(cat.holding), cat.path


def check_modes(sources: Sequence[LasSource], colors: Sequence[str], shade: bool | None) -> bool:
    """Check every file has the dimensions of the colour modes (and the normals, to ``shade``); return whether to shade
    (``shade`` None: when every file has the normals)."""
    shade = check_flag("shade", shade, allow_none=True)
    has_normals = True
    for src in sources:
        dims = file_dimensions(src.path)
        for color in colors:
            missing = [d for d in COLOR_MODES[color] if d not in dims]
            if missing:
                raise PatchcloudValueError(
                    f"{src.path}: colour mode '{color}' needs the dimension{'s' if len(missing) > 1 else ''} {', '.join(missing)}, "
                    f"which the file does not have; this file supports: {', '.join(supported_modes(dims))}"
                )
        if not all(d in dims for d in NORMAL_DIMS):
            has_normals = False
            if shade:
                raise PatchcloudValueError(
                    f"{src.path}: shading needs the normals (NormalX, NormalY, NormalZ), which the file does not have; "
                    f"run patchcloud normals first, or render without shading"
                )
    return has_normals if shade is None else bool(shade)


def picture_crs(sources: Sequence[LasSource], assume_crs: str | None = None) -> str | None:
    """The CRS the picture's coordinates are in: the files' (a catalog has one), else ``assume_crs``, else None."""
    return next((s.crs for s in sources if s.crs), assume_crs)


#: What the ``width`` of :func:`render_array` is the width of.
WIDTH_OF = ("image", "figure")


def render_arrays(
    input, *, colors: Sequence[str], view: str | None = None, bbox=None, width: int = 1600,
    shade: bool | None = None, value_range=None, fill: float | None = None, heights: str = "robust", chunk: int = 1 << 20,
    assume_crs: str | None = None, output: str | os.PathLike | None = None, width_of: str = "image", units: str | None = None,
) -> list[RenderImage]:
    """Pictures of one file, or of a catalog as one cloud, in several colour modes, from one read (see :func:`render_array`).

    The pixels, the points drawn in them and the shading are the same in
    every picture (they depend on the view, not on the colour); each pixel
    keeps the values of every mode, so N pictures cost one pass over the
    file, not N.  ``output``: the path the caller will write the pictures
    to, refused (before the read) when it is one of the inputs.

    Returns
    -------
    list of RenderImage, in the order of ``colors``

    Examples
    --------
    >>> from patchcloud.stream import normals
    >>> _ = normals(sample, tmp / "n.laz", quiet=True)
    >>> by_normal, by_curvature = render_arrays(tmp / "n.laz", colors=["normals", "curvature"], width=400)
    >>> by_normal.color, by_curvature.color, by_normal.rgb.shape
    ('normals', 'curvature', (400, 400, 3))
    >>> bool((by_normal.filled == by_curvature.filled).all())   # the same pixels in both pictures
    True
    """
    t0 = time.perf_counter()
    if isinstance(colors, str):  # one mode's name, not its letters
        raise PatchcloudValueError(f"colors must be a list of colour modes, e.g. [{colors!r}]; got the string {colors!r}")
    colors = list(colors)
    if not colors:
        raise PatchcloudValueError(f"give at least one colour mode: {', '.join(COLOR_MODES)}")
    for color in colors:
        if color not in COLOR_MODES:
            raise PatchcloudValueError(f"color must be one of {', '.join(COLOR_MODES)}; got {color!r}")
    if view is not None and view not in VIEWS:
        raise PatchcloudValueError(f"view must be one of {', '.join(VIEWS)}; got {view!r}")
    if int(chunk) < 1:
        raise PatchcloudValueError(f"chunk must be a positive number of points; got {chunk!r}")
    if fill is not None and (isinstance(fill, bool) or not isinstance(fill, (int, float, np.integer, np.floating))
                             or not 0 <= fill <= FILL_LIMIT):
        raise PatchcloudValueError(f"fill must be a gap-filling radius in pixels from 0 (none) to {FILL_LIMIT}, "
                                   f"or left out (from the point spacing); got {fill!r}")
    if width_of not in WIDTH_OF:
        raise PatchcloudValueError(f"width_of must be one of {', '.join(WIDTH_OF)}; got {width_of!r}")
    if width_of == "figure" and not (isinstance(width, (int, np.integer)) and MIN_WIDTH <= width <= MAX_WIDTH):
        raise PatchcloudValueError(f"width must be {MIN_WIDTH} to {MAX_WIDTH} pixels for a picture (its title, axes and "
                                   f"legend included); got {width!r}")
    if heights not in HEIGHTS:
        raise PatchcloudValueError(f"heights must be one of {', '.join(HEIGHTS)}; got {heights!r}")
    if units is not None and units not in UNITS:
        raise PatchcloudValueError(f"units must be one of {', '.join(UNITS)}; got {units!r}")
    bbox = _check_bbox(bbox)
    if value_range is not None:
        low, high = (float(v) for v in value_range)
        if not (np.isfinite(low) and np.isfinite(high) and low < high):
            raise PatchcloudValueError(f"value_range must be two finite numbers, low < high; got {tuple(value_range)!r}")
        if not any(c in CMAPS for c in colors):  # a range that would change nothing is a mistake to say, not to ignore
            raise PatchcloudValueError(f"value_range sets the colour range of {', '.join(CMAPS)}; colour {', '.join(map(str, colors))} "
                                       "has none: leave it out")
    sources, name = input_sources(input, assume_crs)
    if output is not None:  # where the caller will write the picture: never one of the inputs
        check_not_input(output, [s.path for s in sources])
    shade = check_modes(sources, colors, shade)

    origin = np.min([s.mins for s in sources], axis=0).astype(np.float64)
    lo = np.zeros(3)
    hi = np.max([s.maxs for s in sources], axis=0).astype(np.float64) - origin
    if bbox is not None and not (bbox[0] <= hi[0] + origin[0] and bbox[2] >= origin[0] and bbox[1] <= hi[1] + origin[1] and bbox[3] >= origin[1]):
        raise PatchcloudValueError(
            f"{name}: the box x {bbox[0]:.10g} to {bbox[2]:.10g}, y {bbox[1]:.10g} to {bbox[3]:.10g} lies outside the input's "
            f"bounds (x {origin[0]:.10g} to {hi[0] + origin[0]:.10g}, y {origin[1]:.10g} to {hi[1] + origin[1]:.10g}): nothing to draw"
        )
    if bbox is not None:
        lo[:2] = np.asarray(bbox[:2]) - origin[:2]
        hi[:2] = np.asarray(bbox[2:]) - origin[:2]
    if heights == "robust":
        low, high = zip(*(robust_heights(s) for s in sources))
        lo[2], hi[2] = min(low) - origin[2], max(high) - origin[2]
    if view is None:
        view = choose_view(lo, hi)
    R = view_axes(view, lo, hi)
    names = axis_names(picture_crs(sources, assume_crs), units)
    layout = None
    if width_of == "figure":  # the image gets the columns the title, axes and legend leave
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        u, v = corners @ R[0], corners @ R[1]
        ou, ov = (0.0, 0.0) if view == "oblique" else (float(R[0] @ origin), float(R[1] @ origin))
        box = (u.min() + ou, u.max() + ou, v.min() + ov, v.max() + ov)
        layout = figure_layout(width, box, *view_axis_labels(view, R, names))
        width = layout.raster
    frame = make_frame(R, lo, hi, width)

    # channels kept per pixel: the normals (for the normals mode or the shading), then one per value dimension
    want_normals = shade or "normals" in colors
    nval = 3 if want_normals else 0
    value_dims: list[str] = []
    for color in colors:
        d = None if color == "normals" else (COLOR_MODES[color][0] if COLOR_MODES[color] else "z")
        if d is not None and d not in value_dims:
            value_dims.append(d)
    channels = nval + len(value_dims)
    image = f"{frame.width:,} x {frame.height:,} pixels"
    check_memory(frame.height * frame.width * (PIXEL_BYTES + 8 * channels * len(colors)),
                 f"a picture {layout.width:,} px wide (its image {image})" if layout else f"a picture of {image}")
    zb = ZBuffer(frame.height, frame.width, channels)
    in_box = 0
    astray = 0  # points outside the headers' x, y bounds (without a bbox, which the frame is made from)
    # by more than half a step: a header's bounds are rounded (sample_c.las: its max x 6e-6 below its last point's,
    # an offset that is no whole number of steps), and laspy and PDAL take such a point as inside
    slack = 0.5 * max(max(float(s.scale[0]), float(s.scale[1])) for s in sources)
    firsts = np.cumsum([0] + [s.point_count for s in sources])  # a point's index: its place in the catalog (ties: the first)
    chunks = ((int(first) + start, pts) for src, first in zip(sources, firsts) for start, pts in read_chunks(src, int(chunk)))
    for start, pts in chunks:
        x = np.asarray(pts.x, dtype=np.float64) - origin[0]
        y = np.asarray(pts.y, dtype=np.float64) - origin[1]
        z = np.asarray(pts.z, dtype=np.float64) - origin[2]
        index = np.arange(start, start + x.size, dtype=np.int64)
        sel = None
        if bbox is not None:
            sel = (x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1])
        else:
            astray += int(np.count_nonzero((x < lo[0] - slack) | (x > hi[0] + slack) | (y < lo[1] - slack) | (y > hi[1] + slack)))
        if sel is not None:
            x, y, z, index = x[sel], y[sel], z[sel], index[sel]
        u = x * R[0, 0] + y * R[0, 1] + z * R[0, 2]
        v = x * R[1, 0] + y * R[1, 1] + z * R[1, 2]
        w = x * R[2, 0] + y * R[2, 1] + z * R[2, 2]
        pixel, inside = frame.pixels(u, v)
        in_box += int(inside.sum())
        cols = []
        if want_normals:
            cols += [np.asarray(pts[d], dtype=np.float64) for d in NORMAL_DIMS]
        for d in value_dims:
            cols.append(np.asarray(pts.z, dtype=np.float64) if d == "z" else np.asarray(pts[d]).astype(np.float64))
        vals = np.column_stack(cols) if cols else np.zeros((len(pts), 0))
        if sel is not None:
            vals = vals[sel]
        zb.add(pixel[inside], w[inside], index[inside], vals[inside])
        del pts, vals, cols

    if astray:
        total = int(sum(s.point_count for s in sources))
        raise PatchcloudValueError(
            f"{name}: {astray:,} of its {total:,} points lie outside its header's bounds (x {origin[0]:.10g} to "
            f"{hi[0] + origin[0]:.10g}, y {origin[1]:.10g} to {hi[1] + origin[1]:.10g}), which frame the picture: rewrite "
            "the header (e.g. pdal translate IN OUT)"
        )
    drawn = zb.filled
    points_drawn = int(drawn.sum())
    fill = auto_fill(drawn) if fill is None else float(fill)
    source, filled = fill_gaps(drawn, fill)
    vals = zb.values[source.ravel()].reshape(zb.shape + (zb.values.shape[1],))
    del zb
    normals = vals[..., :3] if want_normals else None
    brightness = lambert(normals, R) if shade else None
    if view == "oblique":
        extent = frame.extent
    else:  # file coordinates: add the origin back on the two screen axes
        e = frame.extent
        ou = float(R[0] @ origin)
        ov = float(R[1] @ origin)
        extent = (e[0] + ou, e[1] + ou, e[2] + ov, e[3] + ov)
    images = []
    for color in colors:
        if color == "normals":
            value = normals
        else:
            d = COLOR_MODES[color][0] if COLOR_MODES[color] else "z"
            value = vals[..., nval + value_dims.index(d)]
        rgb, rng, legend = colorize(color, value, filled, value_range, drawn=drawn)
        if color == "patches":
            rgb[patch_boundaries(np.nan_to_num(value, nan=-1.0), filled)] *= BOUNDARY_DARKEN
        if brightness is not None:
            rgb[filled] *= brightness[filled][:, None]
        images.append(RenderImage(
            source=name, color=color, view=view, shaded=bool(shade), rgb=rgb, filled=filled, value=value,
            extent=extent, pixel=frame.pixel, axes=R, point_count=int(firsts[-1]), points_in_box=in_box,
            points_drawn=points_drawn, value_range=rng, legend=legend, bbox=bbox, fill=fill,
            seconds=time.perf_counter() - t0, names=names, layout=layout, range_given=value_range is not None,
        ))
    return images


#: Words for the colour modes in titles and colour bars.
MODE_NAMES = {"normals": "Normals", "curvature": "Curvature", "don": "DoN magnitude", "segments": "Segments",
              "patches": "Patches", "classification": "Classification", "intensity": "Intensity", "elevation": "Elevation"}
#: Classes listed in a legend at most.
LEGEND_MAX = 20


def _ordinal(p: float) -> str:
    """2 -> "2nd", 98 -> "98th", 2.5 -> "2.5th"."""
    if p != int(p):
        return f"{p:g}th"
    n = int(p)
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


def colour_note(img: RenderImage) -> str:
    """The sentence under a picture that says what its colours (and its empty pixels) mean.

    Examples
    --------
    >>> img = RenderImage("f.laz", "normals", "top", True, np.zeros((1, 1, 3)), np.ones((1, 1), bool), np.zeros((1, 1, 3)),
    ...                   (0, 1, 0, 1), 1.0, np.eye(3), 1, 1, 1, None, fill=2.0)
    >>> print(colour_note(img))
    Red = Normal X (east), green = Normal Y (north), blue = Normal Z (up), each (n + 1) / 2. Shaded by the normals, light from the upper left. Empty pixels within 2 px of a point show the nearest one.
    """
    parts = []
    if img.color == "normals":
        parts.append("Red = Normal X (east), green = Normal Y (north), blue = Normal Z (up), each (n + 1) / 2.")
    elif img.color == "segments":
        ids = img.value[img.filled]
        n = np.unique(ids[np.isfinite(ids) & (ids > 0)]).size
        parts.append(f"Grey: no segment (ClusterID 0); {n:,} segments visible, in 18 colours repeated.")
    elif img.color == "patches":
        ids = img.value[img.filled]
        n = np.unique(ids[np.isfinite(ids)]).size
        parts.append(f"{n:,} patches visible (PatchId), their boundaries darkened.")
    elif img.value_range is not None:
        if img.range_given:
            parts.append("Colours span the range asked for; values beyond it take the end colours.")
        else:
            parts.append(f"Colours span the {_ordinal(PERCENTILES[0])} to {_ordinal(PERCENTILES[1])} percentiles of the "
                         "points drawn; values beyond take the end colours.")
    if img.shaded:
        parts.append("Shaded by the normals, light from the upper left.")
    if img.view == "oblique":
        parts.append(f"Seen from the south-west, {OBLIQUE_ELEVATION:g}° above the horizon.")
    if img.fill > 0:
        parts.append(f"Empty pixels within {img.fill:.3g} px of a point show the nearest one.")
    return " ".join(parts)


def render_figure(img: RenderImage):
    """The picture as a matplotlib Figure on an Agg canvas, laid out in pixels: one image pixel on one figure pixel.

    Its width is ``img.layout.width`` when the image was framed for a
    picture (``width_of="figure"``, as :func:`render` does), else the
    image's width and the margins its axes need.  Top to bottom: the title
    (file, colour mode, view, points drawn of the points in the file); the
    image, its axes in file coordinates named and in the units of the
    file's CRS ("Easting (m)", "Elevation (US ft)"; the oblique view has
    none); the colour bar and its label ("Curvature", "DoN magnitude",
    "Elevation (m)") or the legend of the classes; a sentence on the
    colours.  Save it uncropped (:func:`~patchcloud.stream.views.plots.save_png`
    with ``crop=False``): the PNG is then exactly that wide.

    Examples
    --------
    >>> img = render_array(sample, color="elevation", width=600, width_of="figure")
    >>> fig = render_figure(img)
    >>> fig.canvas.get_width_height()[0], img.axis_labels
    (600, ('Easting (m)', 'Northing (m)'))
    """
    if not isinstance(img, RenderImage):
        raise PatchcloudValueError(f"img must be a RenderImage (what render_array returns), got a {type(img).__name__}")
    from matplotlib import colormaps
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    from patchcloud.stream.views.layout import (
        DPI, LABEL_PAD, PAD, TICK, TICK_PAD, axis_metrics, choose_ticks, line_height, text_size, thin_ticks, wrap_text,
    )

    H, W = img.filled.shape
    xl, yl = img.axis_labels
    lay = img.layout if img.layout is not None else layout_around(W, img.extent, xl, yl)
    s = lay.scale
    m = axis_metrics(s)
    FW = lay.width
    inner = FW - 2 * PAD
    texts: list[tuple] = []  # (x px, top px, text, points, ha)
    boxes: list[tuple] = []  # (x px, top px, w px, h px, colour)

    y = PAD
    title = (f"{Path(img.source).name}: {MODE_NAMES[img.color]}, {img.view} view{', shaded' if img.shaded else ''}\n"
             f"{img.points_drawn:,} point{'' if img.points_drawn == 1 else 's'} drawn of {img.point_count:,}")
    for line in wrap_text(title, inner, m["title_pt"]):
        texts.append((FW / 2, y, line, m["title_pt"], "center"))
        y += line_height(m["title_pt"])
    y += PAD
    if lay.axes:  # a y label longer than the image is tall reaches above it: keep it off the title
        y += max(0, int(np.ceil((text_size(yl, m["label_pt"])[0] - H) / 2)))
    ring = 1 if lay.axes else 0
    img_left = lay.left + (lay.raster - W) // 2
    img_top = y + ring
    y = img_top + H + ring + lay.axis_height() + PAD

    bar = None
    if img.value_range is not None:  # colour bar under the image, as wide as it (at least 60 % of the picture)
        span = max(W, int(0.6 * inner))
        x0 = max(PAD, img_left + W // 2 - span // 2)
        x1 = min(FW - PAD, x0 + span)
        lo, hi = img.value_range
        ticks, labels = choose_ticks(lo, hi, x1 - x0, True, m["tick_pt"])
        half = max([text_size(t, m["tick_pt"])[0] for t in labels] or [0.0]) / 2
        x0, x1 = max(x0, int(np.ceil(PAD + half))), min(x1, int(FW - PAD - half))
        ticks, labels = thin_ticks(ticks, labels, lo, hi, x1 - x0, True, m["tick_pt"])
        bar_h = max(6, int(round(14 * s)))
        bar = (x0, y, x1 - x0, bar_h, ticks, labels)
        tick_h = max([text_size(t, m["tick_pt"])[1] for t in labels] or [0.0])
        y += bar_h + int(np.ceil(m["tick_len"] + m["tick_pad"] + tick_h)) + PAD
        names = {"curvature": "Curvature", "don": "DoN magnitude", "elevation": img.names.z, "intensity": "Intensity"}
        for line in wrap_text(names[img.color], inner, m["label_pt"]):
            texts.append((FW / 2, y, line, m["label_pt"], "center"))
            y += line_height(m["label_pt"])
        y += PAD // 2
    elif img.legend:  # the classes, most frequent first, in as many columns as fit
        pt = m["note_pt"]
        sw = int(round(text_size("Ag", pt)[1] * 0.8))
        entries = [(f"{lab} ({n:,} px)", c) for lab, c, n in img.legend[:LEGEND_MAX]]
        room = inner - sw - 4
        entries = [(wrap_text(t, room, pt)[0] if text_size(t, pt)[0] > room else t, c) for t, c in entries]
        colw = sw + 4 + max(text_size(t, pt)[0] for t, _ in entries) + 14
        ncol = max(1, int((inner + 14) // colw))
        lh = line_height(pt)
        for k, (t, c) in enumerate(entries):
            r, col = divmod(k, ncol)
            x = PAD + col * colw
            top = y + r * lh
            boxes.append((x, top + (lh - sw) / 2 - 1, sw, sw, c))
            texts.append((x + sw + 4, top, t, pt, "left"))
        y += int(np.ceil(len(entries) / ncol)) * lh
        if len(img.legend) > LEGEND_MAX:
            more = f"and {len(img.legend) - LEGEND_MAX:,} more classes"
            texts.append((PAD, y, wrap_text(more, inner, pt)[0], pt, "left"))
            y += lh
        y += PAD // 2
    for line in wrap_text(colour_note(img), inner, m["note_pt"]):
        texts.append((PAD, y, line, m["note_pt"], "left"))
        y += line_height(m["note_pt"])
    FH = y + PAD

    fig = Figure(figsize=(FW / DPI, FH / DPI), dpi=DPI)
    FigureCanvasAgg(fig)
    fig.figimage(img.rgb, xo=img_left, yo=FH - img_top - H, origin="upper")
    line_w = min(0.8 * s, 72.0 / DPI)  # at most one pixel: the frame stays on its ring of pixels around the image
    if lay.axes:
        ax = fig.add_axes(((img_left - 1) / FW, (FH - img_top - H - 1) / FH, (W + 2) / FW, (H + 2) / FH))
        ax.patch.set_visible(False)
        e, p = img.extent, img.pixel
        ax.set_xlim(e[0] - p, e[1] + p)
        ax.set_ylim(e[2] - p, e[3] + p)
        ax.set_xticks(*thin_ticks(lay.xticks, lay.xtick_labels, e[0], e[1], W, True, m["tick_pt"]))
        ax.set_yticks(*thin_ticks(lay.yticks, lay.ytick_labels, e[2], e[3], H, False, m["tick_pt"]))
        ax.tick_params(labelsize=m["tick_pt"], length=TICK * s, pad=TICK_PAD * s, width=line_w)
        ax.set_xlabel(xl, fontsize=m["label_pt"], labelpad=LABEL_PAD * s)
        ax.set_ylabel(yl, fontsize=m["label_pt"], labelpad=LABEL_PAD * s)
        for sp in ax.spines.values():
            sp.set_linewidth(line_w)
    if bar is not None:
        from matplotlib.cm import ScalarMappable

        x0, top, bw, bh, ticks, labels = bar
        cax = fig.add_axes((x0 / FW, 1 - (top + bh) / FH, bw / FW, bh / FH))
        sm = ScalarMappable(norm=Normalize(*img.value_range), cmap=colormaps[CMAPS[img.color]])
        cb = fig.colorbar(sm, cax=cax, orientation="horizontal", extend="both")
        cb.set_ticks(ticks, labels=labels)
        cax.tick_params(labelsize=m["tick_pt"], length=TICK * s, pad=TICK_PAD * s, width=line_w)
        cb.outline.set_linewidth(line_w)
    for x, top, w, h, c in boxes:
        fig.add_artist(Rectangle((x / FW, 1 - (top + h) / FH), w / FW, h / FH, transform=fig.transFigure,
                                 facecolor=c, edgecolor="0.3", linewidth=line_w))
    for x, top, t, pt, ha in texts:
        fig.text(x / FW, 1 - top / FH, t, fontsize=pt, ha=ha, va="top", parse_math=False)
    return fig


def render(
    input, output: str | os.PathLike, *, color: str, view: str | None = None, bbox=None,
    width: int = 1600, shade: bool | None = None, value_range=None, fill: float | None = None, heights: str = "robust",
    chunk: int = 1 << 20, assume_crs: str | None = None, units: str | None = None,
) -> RenderSummary:
    """Write a PNG picture of a LAS/LAZ file of any size, or of a catalog of files in one frame
    (out of core; see :func:`render_array` for the options).

    The PNG is exactly ``width`` pixels wide, its title, axes and colour bar
    or legend included (see :func:`render_figure`); the image of the points
    takes the columns they leave.  It is written atomically (an existing
    file is replaced).

    Returns
    -------
    RenderSummary
        The PNG's size and the image's, points read, in the frame, drawn
        (one per filled pixel), the colour range, seconds.

    Examples
    --------
    >>> from patchcloud.stream import normals
    >>> _ = normals(sample, tmp / "n.laz", quiet=True)
    >>> s = render(tmp / "n.laz", tmp / "n.png", color="curvature", width=400)
    >>> print(s.format())   # doctest: +ELLIPSIS
    /...n.png: 400 x ... px PNG, curvature, top view, shaded, colour range ... .. ...
    image ... x ... px of ... m, 60,653 points read, 60,653 in the frame, ... drawn (one per pixel), ... pixels filled (radius ... px), ... s
    >>> from matplotlib.image import imread
    >>> imread(tmp / "n.png").shape[1::-1] == (s.width, s.height)
    True
    """
    from patchcloud.stream.views.plots import check_png_path, save_png

    t0 = time.perf_counter()
    out = check_png_path(output)
    img = render_arrays(input, colors=[color], view=view, bbox=bbox, width=width, shade=shade, value_range=value_range, fill=fill,
                        heights=heights, chunk=chunk, assume_crs=assume_crs, output=out, width_of="figure", units=units)[0]
    fig = render_figure(img)
    save_png(fig, out, crop=False)
    FW, FH = fig.canvas.get_width_height()
    H, W = img.filled.shape
    return RenderSummary(
        input=img.source, output=str(out), color=color, view=img.view, shaded=img.shaded, width=FW, height=FH,
        points_read=img.point_count, points_in_box=img.points_in_box, points_drawn=img.points_drawn,
        pixels_filled=img.pixels_filled, value_range=img.value_range, seconds=time.perf_counter() - t0,
        image_width=W, image_height=H, pixel=img.pixel, unit=img.names.horizontal, fill=img.fill,
    )
