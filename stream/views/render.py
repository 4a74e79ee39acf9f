"""Pictures of LAS/LAZ files of any size: ``patchcloud render``.

The file is streamed in chunks (:func:`~patchcloud.stream.io.las.read_chunks`)
and every chunk is reduced at once to at most one point per pixel, the one
nearest the viewer (a z-buffer), so memory depends on the image, never on the
file.  The pieces are pure numpy functions, unit-tested on their own:

* :func:`view_axes` / :func:`choose_view` / :func:`make_frame`: the
  orthographic camera and the image's framing from the header bounds (no
  first pass over the points);
* :class:`ZBuffer`: the per-pixel decimation, chunk by chunk;
* :func:`colorize`, :func:`lambert`, :func:`patch_boundaries`: colours,
  shading and patch outlines of the decimated pixels.

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

from patchcloud.core import PatchcloudIOError, PatchcloudValueError

from patchcloud.stream.io.budget import check_memory
from patchcloud.stream.io.catalog import open_catalog
from patchcloud.stream.io.las import LasSource, check_not_input, laz_backend, open_source, read_chunks

__all__ = [
    "COLOR_MODES", "VIEWS", "AMBIENT", "FLAT_RATIO", "LIGHT", "BACKGROUND", "UNDEFINED", "NO_SEGMENT",
    "RenderImage", "RenderSummary", "ZBuffer", "Frame", "render", "render_array", "render_arrays", "render_figure",
    "view_axes", "choose_view", "auto_fill", "MAX_FILL", "robust_heights", "HEIGHTS", "make_frame", "fill_gaps", "colorize", "lambert", "patch_boundaries", "segment_colours",
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
    >>> choose_view((0, 0, 0), (1000, 1000, 60)), choose_view((0, 0, 0), (30, 40, 25))
    ('top', 'oblique')
    """
    ext = np.asarray(maxs, float) - np.asarray(mins, float)
    return "top" if ext[2] < FLAT_RATIO * max(ext[0], ext[1]) else "oblique"


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
    """
    width = int(width)
    if not 1 <= width <= MAX_WIDTH:
        raise PatchcloudValueError(f"width must be 1 to {MAX_WIDTH} pixels; got {width!r}")
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    u, v = corners @ R[0], corners @ R[1]
    du, dv = float(u.max() - u.min()), float(v.max() - v.min())
    if du <= 0 and dv <= 0:
        du = dv = 1.0
    pixel = max(du, 1e-9) / width
    if dv / pixel > MAX_ASPECT * width:
        pixel = dv / (MAX_ASPECT * width)
    W = max(1, int(np.ceil(du / pixel - 1e-9)))
    H = max(1, int(np.ceil(dv / pixel - 1e-9)))
    return Frame(float(u.min()), float(v.max()), float(pixel), W, H)


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


def fill_gaps(depth: np.ndarray, passes: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Close small holes: each pass, an empty pixel copies its filled 8-neighbour nearest the viewer.

    Parameters
    ----------
    depth : (H, W) depth of every pixel's point, -inf where empty.
    passes : int
        Passes (0: none); each grows the drawn points by one pixel into empty space.

    Returns
    -------
    source : (H, W) int64
        The flat pixel each pixel shows (itself for pixels with a point).
    filled : (H, W) bool
        Pixels that show a point after filling.

    Examples
    --------
    >>> d = np.full((1, 3), -np.inf); d[0, 0] = 1.0; d[0, 2] = 2.0
    >>> fill_gaps(d)[0].tolist()   # the middle pixel takes the nearer neighbour
    [[0, 2, 2]]
    """
    H, W = depth.shape
    d = np.asarray(depth, dtype=np.float64).copy()
    src = np.arange(H * W, dtype=np.int64).reshape(H, W)
    offsets = [(-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1)]
    for _ in range(int(passes)):
        empty = d == -np.inf
        if not empty.any():
            break
        best_d, best_s = d.copy(), src.copy()
        for dr, dc in offsets:  # neighbour at (r + dr, c + dc)
            nd = np.full((H, W), -np.inf)
            ns = np.zeros((H, W), dtype=np.int64)
            rs, rd = (slice(dr, None), slice(None, H - dr)) if dr >= 0 else (slice(None, H + dr), slice(-dr, None))
            cs, cd = (slice(dc, None), slice(None, W - dc)) if dc >= 0 else (slice(None, W + dc), slice(-dc, None))
            nd[rd, cd] = d[rs, cs]
            ns[rd, cd] = src[rs, cs]
            take = empty & (nd > best_d)
            best_d[take] = nd[take]
            best_s[take] = ns[take]
        d, src = best_d, best_s
    return src, d > -np.inf


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
        undefined values UNDEFINED grey.
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
    if color == "normals":
        c = (v + 1.0) / 2.0
        c[~np.isfinite(c).all(axis=1)] = UNDEFINED
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
    (left, right, bottom, top) in metres: file coordinates for the top view
    (x, y) and the side view (x or y, and z), screen coordinates about the
    box's lower corner for the oblique view.
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
    fill: int = 0
    seconds: float = 0.0

    @property
    def pixels_filled(self) -> int:
        return int(self.filled.sum())

    @property
    def axis_labels(self) -> tuple[str | None, str | None]:
        """Labels of the image axes (None for the oblique view, whose axes are not drawn)."""
        if self.view == "top":
            return "x (m)", "y (m)"
        if self.view == "side":
            return ("x (m)" if abs(self.axes[0, 0]) > 0.5 else "y (m)"), "z (m)"
        return None, None


@dataclass
class RenderSummary:
    """What :func:`render` drew: points read from the file, inside the frame, drawn (one per pixel), pixels filled (after gap filling)."""

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

    def format(self) -> str:
        rng = "" if self.value_range is None else f", colour range {self.value_range[0]:.4g} .. {self.value_range[1]:.4g}"
        return (
            f"{self.input} -> {self.output}: {self.width} x {self.height} px, {self.color}, {self.view} view{', shaded' if self.shaded else ''}{rng}\n"
            f"{self.points_read:,} points read, {self.points_in_box:,} in the frame, {self.points_drawn:,} drawn "
            f"(one per pixel), {self.pixels_filled:,} pixels filled, {self.seconds:.1f} s"
        )


def _check_bbox(bbox):
    if bbox is None:
        return None
    b = tuple(float(v) for v in bbox)
    if len(b) != 4 or not all(np.isfinite(b)) or not (b[2] > b[0] and b[3] > b[1]):
        raise PatchcloudValueError(f"bbox must be xmin ymin xmax ymax with xmin < xmax and ymin < ymax (metres); got {bbox!r}")
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
        try:
            with laspy.open(src.path, laz_backend=laz_backend()) as r:
                for start in np.linspace(0, n - FRAME_WINDOW, FRAME_WINDOWS).astype(np.int64).tolist():
                    r.seek(start)
                    zs.append(np.asarray(r.read_points(FRAME_WINDOW).z, dtype=np.float64))
        except Exception as exc:
            raise PatchcloudIOError(f"{src.path}: cannot read point data ({exc})") from exc
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
    # the sample may miss the highest and lowest points of the cloud itself: a little room
    pad = 0.05 * float(top - bottom)
    return max(zmin, float(bottom) - pad), min(zmax, float(top) + pad)


#: Widest image (pixels): the per-pixel buffers take about 100 bytes a pixel (3.6 GB for a square image this wide).
MAX_WIDTH = 6000
#: Bytes a pixel takes (depth, index, filled masks, the gap-filling and RGB passes), besides 8 per channel and picture:
#: a picture is checked against the memory budget (``--max-memory``) before its buffers are made.
PIXEL_BYTES = 96
#: Most gap-filling passes the default chooses.
MAX_FILL = 8
#: Most gap-filling passes that may be asked for (each pass widens the points by a pixel).
FILL_LIMIT = 64


def auto_fill(shape: tuple[int, int], points: int) -> int:
    """Gap-filling passes for ``points`` over an image of ``shape``: 3/4 of their mean spacing in pixels, in 1..MAX_FILL.

    (Scan lines leave gaps wider than the mean spacing; 3/4 of it closes most of them.)

    Examples
    --------
    >>> auto_fill((800, 800), 60000), auto_fill((800, 800), 5_000_000), auto_fill((800, 800), 0)
    (3, 1, 8)
    """
    spacing = np.sqrt(shape[0] * shape[1] / max(points, 1))
    return int(np.clip(np.ceil(0.75 * spacing), 1, MAX_FILL))


def render_array(
    input, *, color: str, view: str | None = None, bbox=None, width: int = 1600,
    shade: bool | None = None, value_range=None, fill: int | None = None, heights: str = "robust", chunk: int = 1 << 20,
    assume_crs: str | None = None,
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
        File coordinates (metres, the file's CRS): only the points inside
        are drawn and the frame is this box (with the file's z range).
    width : int
        Image width in pixels; the height follows the aspect ratio.
    shade : bool, optional
        Lambert shading from the normals; default: when the file has NormalX/Y/Z.
    value_range : (low, high), optional
        Colour range of the continuous modes; default the 2nd-98th
        percentiles of the visible pixels' values.
    fill : int, optional
        Gap filling (:func:`fill_gaps`): passes in which every empty pixel
        takes its neighbour's point nearest the viewer, closing the holes of
        sparse surfaces (each pass widens the points by one pixel); 0: none.
        Default: 3/4 of the mean point spacing in pixels (from the frame's
        pixels over the points inside it), rounded up, from 1 to :data:`MAX_FILL`,
        so an aerial tile at 25 points/m² and a dense mobile scan both look
        like surfaces at any width.
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
                         fill=fill, heights=heights, chunk=chunk, assume_crs=assume_crs)[0]


def input_sources(input, assume_crs: str | None = None) -> tuple[list[LasSource], str]:
    """The files a picture shows, and how it names them: one file, or a catalog (several paths, a directory, a glob).

    The files of a catalog must be one cloud in one CRS (see
    :func:`patchcloud.stream.io.catalog.open_catalog`, and its ``assume_crs``).
    """
    if isinstance(input, (str, os.PathLike)) and Path(input).is_file():
        return [open_source(input)], str(input)
    cat = open_catalog(input, assume_crs)
    return list(cat.sources), cat.path


def check_modes(sources: Sequence[LasSource], colors: Sequence[str], shade: bool | None) -> bool:
    """Check every file has the dimensions of the colour modes (and the normals, to ``shade``); return whether to shade
    (``shade`` None: when every file has the normals)."""
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


def render_arrays(
    input, *, colors: Sequence[str], view: str | None = None, bbox=None, width: int = 1600,
    shade: bool | None = None, value_range=None, fill: int | None = None, heights: str = "robust", chunk: int = 1 << 20,
    assume_crs: str | None = None, output: str | os.PathLike | None = None,
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
    if fill is not None and (isinstance(fill, bool) or int(fill) != fill or not 0 <= fill <= FILL_LIMIT):
        raise PatchcloudValueError(f"fill must be a number of gap-filling passes from 0 (none) to {FILL_LIMIT}, "
                                   f"or left out (from the point spacing); got {fill!r}")
    if heights not in HEIGHTS:
        raise PatchcloudValueError(f"heights must be one of {', '.join(HEIGHTS)}; got {heights!r}")
    bbox = _check_bbox(bbox)
    sources, name = input_sources(input, assume_crs)
    if output is not None:  # where the caller will write the picture: never one of the inputs
        check_not_input(output, [s.path for s in sources])
    shade = check_modes(sources, colors, shade)

    origin = np.min([s.mins for s in sources], axis=0).astype(np.float64)
    lo = np.zeros(3)
    hi = np.max([s.maxs for s in sources], axis=0).astype(np.float64) - origin
    if bbox is not None:
        lo[:2] = np.asarray(bbox[:2]) - origin[:2]
        hi[:2] = np.asarray(bbox[2:]) - origin[:2]
    if heights == "robust":
        low, high = zip(*(robust_heights(s) for s in sources))
        lo[2], hi[2] = min(low) - origin[2], max(high) - origin[2]
    if view is None:
        view = choose_view(lo, hi)
    R = view_axes(view, lo, hi)
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
    check_memory(frame.height * frame.width * (PIXEL_BYTES + 8 * channels * len(colors)),
                 f"a picture of {frame.width:,} x {frame.height:,} pixels")
    zb = ZBuffer(frame.height, frame.width, channels)
    in_box = 0
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

    points_drawn = int((zb.index >= 0).sum())
    if fill is None:
        fill = auto_fill(zb.shape, in_box)
    source, filled = fill_gaps(zb.depth.reshape(zb.shape), max(0, int(fill)))
    drawn = source == np.arange(source.size).reshape(source.shape)
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
            points_drawn=points_drawn, value_range=rng, legend=legend, bbox=bbox, fill=int(fill),
            seconds=time.perf_counter() - t0,
        ))
    return images


def render_figure(img: RenderImage):
    """The picture as a matplotlib Figure (Agg canvas): the image at about one figure pixel per image pixel, colour bar or legend beside it.

    Title: file name, colour mode, view, points drawn of points in the file.
    Top and side views have axes in metres (file coordinates); the oblique
    view hides them.
    """
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.patches import Patch

    from patchcloud.stream.views.plots import STYLE, shorten, new_figure, style_axes

    H, W = img.filled.shape
    dpi = STYLE["dpi"]
    side = 1.9 if (img.value_range is not None or img.legend) else 0.6
    fig, (ax,) = new_figure(W / dpi + side + 0.9, H / dpi + 1.1)
    ax.imshow(img.rgb, extent=img.extent, origin="upper", interpolation="nearest", aspect="equal")
    xl, yl = img.axis_labels
    name = shorten(Path(img.source).name, 60)
    what = {"don": "DoN", "segments": "segments (ClusterID)", "patches": "patches (PatchId)",
            "normals": "normals RGB = (n + 1) / 2"}.get(img.color, img.color)
    title = (f"{name}: {what}, {img.view} view{', shaded' if img.shaded else ''}\n"
             f"{img.points_drawn:,} points drawn of {img.point_count:,}")
    style_axes(ax, title, xl, yl)
    if xl is None:
        ax.set_axis_off()
    else:
        ax.ticklabel_format(useOffset=False, style="plain")
    if img.value_range is not None:
        sm = ScalarMappable(norm=Normalize(*img.value_range), cmap=colormaps[CMAPS[img.color]])
        cb = fig.colorbar(sm, ax=ax, shrink=0.8, extend="both")
        label = {"curvature": "curvature l3/(l1+l2+l3)", "don": "|DoN|", "elevation": "z (m)", "intensity": "intensity"}[img.color]
        cb.set_label(f"{label} ({PERCENTILES[0]:g}-{PERCENTILES[1]:g} percentile range)", fontsize=STYLE["label"])
        cb.ax.tick_params(labelsize=STYLE["tick"])
    elif img.legend:
        handles = [Patch(facecolor=c, edgecolor="0.3", label=f"{lab} ({n:,} px)") for lab, c, n in img.legend[:20]]
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=STYLE["annotation"], frameon=False)
    elif img.color == "segments":
        ids = img.value[img.filled]
        n = np.unique(ids[np.isfinite(ids) & (ids > 0)]).size
        handles = [Patch(facecolor=NO_SEGMENT, label="0: no segment"), Patch(facecolor="none", edgecolor="none", label=f"{n:,} segments visible")]
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=STYLE["annotation"], frameon=False)
    elif img.color == "patches":
        ids = img.value[img.filled]
        n = np.unique(ids[np.isfinite(ids)]).size
        ax.text(1.01, 1.0, f"{n:,} patches visible\nboundaries darkened", transform=ax.transAxes, va="top",
                fontsize=STYLE["annotation"])
    return fig


def render(
    input, output: str | os.PathLike, *, color: str, view: str | None = None, bbox=None,
    width: int = 1600, shade: bool | None = None, value_range=None, fill: int | None = None, heights: str = "robust",
    chunk: int = 1 << 20, assume_crs: str | None = None,
) -> RenderSummary:
    """Write a PNG picture of a LAS/LAZ file of any size, or of a catalog of files in one frame
    (out of core; see :func:`render_array` for the options).

    The PNG is written atomically (an existing file is replaced).

    Returns
    -------
    RenderSummary
        Points read, in the frame, drawn (one per filled pixel), the colour range, seconds.

    Examples
    --------
    >>> from patchcloud.stream import normals
    >>> _ = normals(sample, tmp / "n.laz", quiet=True)
    >>> s = render(tmp / "n.laz", tmp / "n.png", color="curvature", width=400)
    >>> print(s.format())   # doctest: +ELLIPSIS
    /...n.png: 400 x 400 px, curvature, top view, shaded, colour range ... .. ...
    60,653 points read, 60,653 in the frame, ... drawn (one per pixel), ... pixels filled, ... s
    >>> (tmp / "n.png").read_bytes()[:4] == b"\\x89PNG"
    True
    """
    from patchcloud.stream.views.plots import check_png_path, save_png

    t0 = time.perf_counter()
    out = check_png_path(output)
    img = render_arrays(input, colors=[color], view=view, bbox=bbox, width=width, shade=shade, value_range=value_range, fill=fill,
                        heights=heights, chunk=chunk, assume_crs=assume_crs, output=out)[0]
    save_png(render_figure(img), out)
    H, W = img.filled.shape
    return RenderSummary(
        input=img.source, output=str(out), color=color, view=img.view, shaded=img.shaded, width=W, height=H,
        points_read=img.point_count, points_in_box=img.points_in_box, points_drawn=img.points_drawn,
        pixels_filled=img.pixels_filled, value_range=img.value_range, seconds=time.perf_counter() - t0,
    )
