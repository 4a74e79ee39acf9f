"""Streaming generator of a synthetic city LiDAR scan (mobile mapping + aerial), any size.

    python tools/city_las.py OUT.las|OUT.laz --points N [--seed 0] [--chunk 1000000] [--point-format 6]

Writes ``N`` points (5 million, 100 million or more) to a LAS/LAZ file chunk by
chunk, so memory is bounded by the chunk size (about 100 MB plus 250 bytes per
point of the chunk: 0.3 GB with the default million), never by ``N``.  The
output goes to ``OUT.partial`` first and is renamed when complete.  From Python::

    from city_las import iter_city_chunks, write_city
    for chunk in iter_city_chunks(5_000_000, seed=0):   # dicts of numpy arrays
        ...
    write_city("city.laz", 5_000_000, seed=0)

Scene
-----
An endless, procedurally laid out city on a square street grid (coordinates in
metres, local origin at a street crossing, written with the UTM-like offset
``ORIGIN`` = (650000, 6860000, 40)):

- streets every ``PITCH`` = 100 m in x and y; each street is 20 m wide: a 13 m
  road with a 2 % cross slope (crown on the centre line) between 0.15 m curbs
  and two 3.5 m sidewalks (1 % slope); the 80 m x 80 m blocks between them are
  flat at sidewalk level (0.185 m);
- every block is a perimeter block: four rows of parcels 9-22 m wide and
  10-15 m deep along its sides around an inner courtyard; a parcel is a
  building (axis-aligned box, eave height from a per-block base of 7-24 m,
  flat roof or a gabled roof with the ridge along the street, optional 2-4.5 m
  front setback) or, now and then, a gap (a passage into the courtyard, through
  which the mobile scanner sees the far row's back walls); corner parcels are
  always flat-roofed buildings on the block edge; 1-3 trees per courtyard;
- street furniture on both sidewalks of every street segment: poles
  (vertical cylinders, radius 0.08-0.13 m, 4-8 m high, 18-28 m apart, most
  with a lamp arm and head over the road), rows of trees on about 60 % of the
  sidewalks (trunk cylinder + ellipsoidal crown of volumetric foliage) and
  cars parked along both curbs (body box with ground clearance + cabin box,
  about 4.4 x 1.8 x 1.5 m).

The layout is a pure function of ``(seed, block/street indices)`` (cached), so
the city never has to be held in memory: the objects near the part of the
trajectory being scanned are generated on demand.  The same seed gives the
same city for every ``n_points``; ``n_points`` only decides how much of it is
scanned.

Scan
----
``1 - AERIAL_SHARE`` (75 %) of the points come first, from a **mobile mapping
car** at 10 m/s driving a serpentine over the grid (first along every x-street,
turning at the ends, then along every y-street), 3 m right of the centre line.
A rotating profiler 2.5 m above the road sweeps a full circle in the vertical
plane perpendicular to the trajectory 100 times per second (profiles 0.1 m
apart); the car's roof hides +-20 deg around straight down, and the range is
limited to 80 m.  Each ray returns the first surface it meets (analytic
intersection with the road/curb/sidewalk height field, building boxes and
roofs, cylinders and boxes of the furniture; tree crowns are volumetric: a ray
entering a crown stops after an exponentially distributed free path of mean
0.6 m, or passes through).  Per internal block of 65,536 points the profiler
casts as many rays as needed and a uniform random subset of exactly 65,536
returns is kept (random dropout), so the mobile density is a constant ~3,000
points per metre of trajectory; it falls with range and shows occlusion (the
gaps behind poles, cars and trees).  The trajectory length is
``n_mobile / 3006`` m, and the grid size K (K x K blocks) the smallest whose
serpentine is long enough: a 100M-point file covers about 1.2 x 1.2 km, a
5M-point file about 0.26 x 0.26 km, at the same density.

The remaining 25 % come from an **aerial survey** (later GPS times) over the
bounding box of the trajectory plus 30 m: parallel strips along x at 500 m
above ground with 20 % overlap, scan lines across track (half angle at most
20 deg), roughly square point spacing; its density is 15-21 points/m2 from 5
million points up (lower for smaller files, whose trajectory is short).  It
sees the ground, the roofs (which the mobile scanner cannot), the crowns and
the tops of cars.

Range noise is Gaussian along the ray: 1.5 cm for the mobile scanner, 2.5 cm
for the aerial one.  Points are in acquisition order: the file order is the
scan order (``gps_time`` non-decreasing), spatially coherent like a real file.

Classes (ASPRS codes, LAS 1.4 point formats 6-10)
-------------------------------------------------
====  ====================================================================
2     ground: road, curb faces, sidewalks, courtyards
5     high vegetation: tree trunks and crowns
6     building: facades, walls and roofs
64    pole (street lights, sign posts; user-definable range 64-255)
65    car (parked)
====  ====================================================================

With point formats 1-5 (5-bit classification) poles and cars are written
as 1 (unclassified); their ``ObjectId`` still tells them apart.

Dimensions
----------
Per chunk, ``iter_city_chunks`` yields a dict of arrays, one entry per point:

- ``x``, ``y``, ``z`` (float64, metres: local coordinates + ``ORIGIN``);
- ``classification`` (uint8, the codes above);
- ``object_id`` (uint32): 0 for ground, otherwise one id per building
  (parcel), pole, tree or car, unique over the whole city and the same in the
  mobile and aerial parts (``id % 4``: 1 building, 2 pole, 3 tree, 0 car);
- ``nx``, ``ny``, ``nz`` (float32): the true unit normal of the surface hit,
  pointing out of the solid (up for the ground, towards the road for curb
  faces, radially for poles and trunks); **zero** for tree foliage, which is a
  volume and has no surface normal;
- ``intensity`` (uint16): reflectance of the material x incidence x range;
- ``gps_time`` (float64, seconds, non-decreasing);
- ``point_source_id`` (uint16): 1 for the mobile scan, 100 + strip index for
  the aerial strips;
- ``scan_angle`` (float32, degrees): the profiler angle (0 = up, +-180 =
  down) or the aerial scan angle (0 = nadir).

``write_city`` stores them as LAS fields (scale 0.001 m, offsets 650000,
6860000, 0) plus the extra-bytes dimensions ``ObjectId`` (uint32) and
``TrueNormalX``/``Y``/``Z`` (float32); point formats with RGB get a colour per
class and object.  Every point is a single return (return 1 of 1).

Determinism
-----------
The points are generated in internal blocks of ``BLOCK`` = 65,536 points,
each from its own random stream ``SeedSequence([seed, kind, block])``, so the
output depends only on ``(n_points, seed)``, not on ``chunk``, and any block
can be regenerated on its own with ``city_block``.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

__all__ = [  # noqa: RUF022 (grouped: constants, then the API)
    "BLOCK", "ORIGIN", "GROUND", "HIGH_VEGETATION", "BUILDING", "POLE", "CAR", "UNCLASSIFIED",
    "CityPlan", "city_plan", "city_block", "iter_city_chunks", "write_city", "main",
]

# ----------------------------------------------------------------------------- codes
GROUND = 2
HIGH_VEGETATION = 5
BUILDING = 6
POLE = 64
CAR = 65
UNCLASSIFIED = 1

ORIGIN = (650_000.0, 6_860_000.0, 40.0)
LAS_OFFSETS = (650_000.0, 6_860_000.0, 0.0)
LAS_SCALE = 0.001

# ----------------------------------------------------------------------------- street grid (m)
PITCH = 100.0  # street centre line spacing, x and y
HALF_ROAD = 6.5  # centre line to curb
SIDEWALK = 3.5
EDGE = HALF_ROAD + SIDEWALK  # centre line to block edge (building line)
CAMBER = 0.02  # road cross slope
CURB = 0.15
SIDEWALK_SLOPE = 0.01
INTERIOR_Z = CURB + SIDEWALK_SLOPE * SIDEWALK  # ground level inside blocks
MAX_INDEX = 1024  # grid indices -1 .. MAX_INDEX - 2 get unique object ids

# ----------------------------------------------------------------------------- internal blocks
BLOCK = 65_536

# ----------------------------------------------------------------------------- mobile scanner
PROFILES_PER_BLOCK = 218
PROFILE_SPACING = 0.1  # m between profiles (10 m/s, 100 Hz)
SPEED = 10.0
SCANNER_HEIGHT = 2.5
LANE = 3.0  # right of the centre line
RAYS = 640  # first try, rays per full turn; raised per block when too few return
BLIND = math.radians(20.0)  # hidden by the car around straight down
MOBILE_RANGE = 80.0
MOBILE_NOISE = 0.015
MOBILE_T0 = 300_000.0
MOBILE_DENSITY = BLOCK / (PROFILES_PER_BLOCK * PROFILE_SPACING)  # points per metre of trajectory

# ----------------------------------------------------------------------------- aerial scanner
AERIAL_SHARE = 0.25
FLIGHT_HEIGHT = 500.0
MAX_HALF_ANGLE = math.radians(20.0)
STRIP_OVERLAP = 0.2
AERIAL_MARGIN = 30.0
AIR_SPEED = 60.0
TURN_TIME = 90.0
AERIAL_NOISE = 0.025
AERIAL_GAP = 3_600.0  # s between the end of the drive and the flight

JITTER = 0.1  # angular jitter of a ray, in angular steps
FOLIAGE_PATH = 0.6  # mean free path in a crown (m)

# ----------------------------------------------------------------------------- object table
(C_KIND, C_X0, C_X1, C_Y0, C_Y1, C_Z0, C_Z1, C_CX, C_CY, C_CZ, C_R, C_RZ,
 C_ROOF, C_RIDGE, C_CLS, C_OID, C_REFL) = range(17)
NCOL = 17
BOX, CYL, ELL = 0, 1, 2


# ============================================================================= helpers
def _rng(seed: int, *keys: int) -> np.random.Generator:
    """Generator seeded from ``(seed, *keys)``; keys may be small negative integers."""
    return np.random.default_rng(np.random.SeedSequence([int(seed)] + [int(k) + (1 << 20) for k in keys]))


def _ground_f(w: np.ndarray | float) -> np.ndarray:
    """Ground height at distance ``w`` (m) from the nearest street centre line."""
    w = np.asarray(w, dtype=np.float64)
    return np.where(
        w <= HALF_ROAD, CAMBER * (HALF_ROAD - w),
        np.where(w <= EDGE, CURB + SIDEWALK_SLOPE * (w - HALF_ROAD), INTERIOR_Z),
    )


def _ground_fprime(w: np.ndarray) -> np.ndarray:
    """Derivative of ``_ground_f``."""
    return np.where(w <= HALF_ROAD, -CAMBER, np.where(w <= EDGE, SIDEWALK_SLOPE, 0.0))


def ground_height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Ground height (local metres, without the z offset) at local ``(x, y)``.

    The height is ``f(min(dx, dy))``, ``dx``/``dy`` the distances to the
    nearest street centre lines: road crown, curb step, sidewalk, then flat.
    """
    dx = np.abs(x - np.round(x / PITCH) * PITCH)
    dy = np.abs(y - np.round(y / PITCH) * PITCH)
    return _ground_f(np.minimum(dx, dy))


def _lin(i: int, j: int) -> int:
    return (j + 1) * MAX_INDEX + (i + 1)


def _seg_lin(axis: int, k: int, m: int) -> int:
    return (axis * (MAX_INDEX + 1) + (k + 1)) * MAX_INDEX + (m + 1)


_NSEG = 2 * (MAX_INDEX + 1) * MAX_INDEX


def _oid(kind: int, index: int) -> int:
    """Object id: kind 0 building, 1 pole, 2 tree, 3 car."""
    return 1 + kind + 4 * index


def _row(kind: int, x0: float, x1: float, y0: float, y1: float, z0: float, z1: float, cls: int, oid: int,
         refl: float, *, cx: float = 0.0, cy: float = 0.0, cz: float = 0.0, r: float = 0.0, rz: float = 0.0,
         roof: float = 0.0, ridge: int = 0) -> list[float]:
    row = [0.0] * NCOL
    row[C_KIND], row[C_X0], row[C_X1], row[C_Y0], row[C_Y1], row[C_Z0], row[C_Z1] = kind, x0, x1, y0, y1, z0, z1
    row[C_CX], row[C_CY], row[C_CZ], row[C_R], row[C_RZ] = cx, cy, cz, r, rz
    row[C_ROOF], row[C_RIDGE], row[C_CLS], row[C_OID], row[C_REFL] = roof, ridge, cls, oid, refl
    return row


def _table(rows: list[list[float]]) -> np.ndarray:
    t = np.asarray(rows, dtype=np.float64).reshape(-1, NCOL)
    t.setflags(write=False)
    return t


def _uv_box(axis: int, u0: float, u1: float, v0: float, v1: float, z0: float, z1: float, cls: int, oid: int,
            refl: float) -> list[float]:
    """Box given in street coordinates (u along the street, v across)."""
    if axis == 0:
        return _row(BOX, u0, u1, min(v0, v1), max(v0, v1), z0, z1, cls, oid, refl)
    return _row(BOX, min(v0, v1), max(v0, v1), u0, u1, z0, z1, cls, oid, refl)


def _uv_cyl(axis: int, u: float, v: float, r: float, z0: float, z1: float, cls: int, oid: int,
            refl: float) -> list[float]:
    """Vertical cylinder given in street coordinates."""
    x, y = (u, v) if axis == 0 else (v, u)
    return _row(CYL, x - r, x + r, y - r, y + r, z0, z1, cls, oid, refl, cx=x, cy=y, r=r)


def _ell(x: float, y: float, z: float, r: float, rz: float, oid: int) -> list[float]:
    return _row(ELL, x - r, x + r, y - r, y + r, z - rz, z + rz, HIGH_VEGETATION, oid, 0.35,
                cx=x, cy=y, cz=z, r=r, rz=rz)


def _tree(rows: list, rng: np.random.Generator, x: float, y: float, ground: float, oid: int,
          crown: tuple[float, float], height: tuple[float, float]) -> None:
    """Trunk cylinder + ellipsoidal crown."""
    trunk_r = rng.uniform(0.12, 0.22)
    trunk_h = rng.uniform(*height)
    r = rng.uniform(*crown)
    rz = rng.uniform(max(crown[0], 1.8), crown[1] + 1.0)
    cz = ground + trunk_h + 0.85 * rz
    rows.append(_row(CYL, x - trunk_r, x + trunk_r, y - trunk_r, y + trunk_r, -0.5, cz, HIGH_VEGETATION, oid, 0.3,
                     cx=x, cy=y, r=trunk_r))
    rows.append(_ell(x, y, cz, r, rz, oid))


def _parcels(rng: np.random.Generator, a: float, b: float) -> list[tuple[float, float]]:
    """Split ``[a, b]`` into parcels 9-22 m wide."""
    out, u = [], a
    while b - u > 18.0:
        w = rng.uniform(9.0, 22.0)
        if b - (u + w) < 9.0:
            break
        out.append((u, u + w))
        u += w
    out.append((u, b))
    return out


# ============================================================================= layout
@lru_cache(maxsize=1024)
def _block_objects(seed: int, i: int, j: int) -> np.ndarray:
    """Buildings and courtyard trees of the city block whose south-west street crossing is (i, j)."""
    rng = _rng(seed, 1, i, j)
    side = PITCH - 2 * EDGE
    xe, ye = i * PITCH + EDGE, j * PITCH + EDGE
    d = rng.uniform(10.0, 15.0, 4)  # row depths: south, north, west, east
    base = rng.uniform(7.0, 24.0)
    gable_p = 0.6 if base < 13.0 else 0.25
    lin = _lin(i, j)
    z0 = -1.0
    rows: list[list[float]] = []
    spans = [(xe, xe + side), (xe, xe + side), (ye + d[0], ye + side - d[1]), (ye + d[0], ye + side - d[1])]
    for r in range(4):
        parcels = _parcels(rng, *spans[r])
        for q, (pa, pb) in enumerate(parcels):
            end = q == 0 or q == len(parcels) - 1
            if not end and rng.random() < 0.1:
                continue  # a gap: passage into the courtyard
            setback = 0.0 if end or rng.random() < 0.7 else rng.uniform(2.0, 4.5)
            h = INTERIOR_Z + base * rng.uniform(0.75, 1.25)
            roof = 0.0 if (end and r < 2) or rng.random() > gable_p else rng.uniform(2.0, 4.5)
            refl = rng.uniform(0.3, 0.6)
            oid = _oid(0, lin * 64 + r * 16 + q)
            if r == 0:
                box = (pa, pb, ye + setback, ye + d[0])
            elif r == 1:
                box = (pa, pb, ye + side - d[1], ye + side - setback)
            elif r == 2:
                box = (xe + setback, xe + d[2], pa, pb)
            else:
                box = (xe + side - d[3], xe + side - setback, pa, pb)
            rows.append(_row(BOX, *box, z0, h, BUILDING, oid, refl, roof=roof, ridge=0 if r < 2 else 1))
    # courtyard trees
    cx0, cx1 = xe + d[2] + 4.0, xe + side - d[3] - 4.0
    cy0, cy1 = ye + d[0] + 4.0, ye + side - d[1] - 4.0
    for q in range(int(rng.integers(1, 4))):
        r = 4.5
        x, y = rng.uniform(cx0 + r, cx1 - r), rng.uniform(cy0 + r, cy1 - r)
        _tree(rows, rng, x, y, INTERIOR_Z, _oid(2, _NSEG * 64 + lin * 16 + q), crown=(2.5, 4.5), height=(2.0, 3.5))
    return _table(rows)


@lru_cache(maxsize=2048)
def _street_objects(seed: int, axis: int, k: int, m: int) -> np.ndarray:
    """Poles, trees and parked cars of one street segment.

    The street runs along x (``axis`` 0, centre line y = k * PITCH) or y
    (``axis`` 1, x = k * PITCH); segment ``m`` lies between the crossings m and m + 1.
    """
    rng = _rng(seed, 2, axis, k, m)
    vc = k * PITCH
    u_lo, u_hi = m * PITCH + EDGE + 1.0, (m + 1) * PITCH - EDGE - 1.0
    seg = _seg_lin(axis, k, m)
    rows: list[list[float]] = []
    n_pole = n_tree = n_car = 0
    for side in (-1.0, 1.0):
        # poles near the curb, most with a lamp arm over the road
        spacing = rng.uniform(18.0, 28.0)
        pole_u = np.arange(u_lo + rng.uniform(1.0, spacing), u_hi, spacing)
        v = vc + side * (HALF_ROAD + 0.45)
        g = CURB + SIDEWALK_SLOPE * 0.45
        for u in pole_u:
            oid = _oid(1, seg * 64 + n_pole)
            n_pole += 1
            r, top = rng.uniform(0.08, 0.13), g + rng.uniform(4.0, 8.0)
            rows.append(_uv_cyl(axis, u, v, r, -0.5, top, POLE, oid, 0.5))
            if rng.random() < 0.6:
                arm = rng.uniform(1.2, 2.2)
                ve = v - side * arm
                rows.append(_uv_box(axis, u - 0.05, u + 0.05, v, ve, top - 0.45, top - 0.35, POLE, oid, 0.5))
                rows.append(_uv_box(axis, u - 0.25, u + 0.25, ve - 0.15, ve + 0.15, top - 0.6, top - 0.45,
                                    POLE, oid, 0.6))
        # a row of trees on some sidewalks
        if rng.random() < 0.6:
            spacing = rng.uniform(8.0, 12.0)
            v = vc + side * (HALF_ROAD + 1.4)
            g = CURB + SIDEWALK_SLOPE * 1.4
            for u in np.arange(u_lo + rng.uniform(0.5, spacing), u_hi - 0.5, spacing):
                if pole_u.size and np.min(np.abs(pole_u - u)) < 3.0:
                    continue
                x, y = (u, v) if axis == 0 else (v, u)
                _tree(rows, rng, x, y, g, _oid(2, seg * 64 + n_tree), crown=(1.6, 2.3), height=(2.6, 3.6))
                n_tree += 1
        # cars parked along the curb
        slot = 5.8
        vcar = vc + side * (HALF_ROAD - 1.15)
        g = CAMBER * 1.15
        for q in range(int((u_hi - u_lo) // slot)):
            if rng.random() > 0.6:
                continue
            oid = _oid(3, seg * 64 + n_car)
            n_car += 1
            uc = u_lo + (q + 0.5) * slot + rng.uniform(-0.4, 0.4)
            length, width = rng.uniform(3.9, 4.9), rng.uniform(1.7, 1.9)
            body, roof = g + rng.uniform(0.9, 1.05), g + rng.uniform(1.4, 1.65)
            refl = rng.uniform(0.2, 0.7)
            rows.append(_uv_box(axis, uc - length / 2, uc + length / 2, vcar - width / 2, vcar + width / 2,
                                g + 0.25, body, CAR, oid, refl))
            front, rear = rng.uniform(1.0, 1.4), rng.uniform(0.4, 0.8)
            if rng.random() < 0.5:
                front, rear = rear, front
            rows.append(_uv_box(axis, uc - length / 2 + rear, uc + length / 2 - front, vcar - width / 2 + 0.1,
                                vcar + width / 2 - 0.1, body, roof, CAR, oid, refl))
    return _table(rows)


_EMPTY = _table([])


def _objects_in(seed: int, xa: float, xb: float, ya: float, yb: float) -> np.ndarray:
    """Every object whose bounding box meets the local rectangle [xa, xb] x [ya, yb]."""
    parts = [_EMPTY]
    bi = range(math.floor(xa / PITCH), math.floor(xb / PITCH) + 1)
    bj = range(math.floor(ya / PITCH), math.floor(yb / PITCH) + 1)
    for i in bi:
        for j in bj:
            parts.append(_block_objects(seed, i, j))
    reach = EDGE + 3.0
    for k in range(math.ceil((ya - reach) / PITCH), math.floor((yb + reach) / PITCH) + 1):
        for m in bi:
            parts.append(_street_objects(seed, 0, k, m))
    for k in range(math.ceil((xa - reach) / PITCH), math.floor((xb + reach) / PITCH) + 1):
        for m in bj:
            parts.append(_street_objects(seed, 1, k, m))
    t = np.concatenate(parts)
    keep = (t[:, C_X1] >= xa) & (t[:, C_X0] <= xb) & (t[:, C_Y1] >= ya) & (t[:, C_Y0] <= yb)
    return t[keep]


# ============================================================================= trajectory
def _leg_ends(leg: np.ndarray, grid: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Centre-line start (ax, ay) and end (bx, by) of serpentine legs.

    Phase 0 drives the K + 1 x-streets (rows) joined by 100 m connectors on the
    y-streets at the ends; phase 1 then drives the K + 1 y-streets the same way.
    Each phase has 2K + 1 legs.
    """
    K, P = grid, PITCH
    leg = np.asarray(leg, dtype=np.int64)
    phase = np.minimum(leg // (2 * K + 1), 1)
    lam = leg - phase * (2 * K + 1)
    q = lam // 2
    conn = (lam % 2) == 1
    even = (q % 2) == 0
    # phase 0: rows along x
    sx = np.where(even, 0.0, K * P)
    ex = K * P - sx
    ax0 = np.where(conn, ex, sx)
    bx0 = ex
    ay0 = q * P
    by0 = np.where(conn, (q + 1) * P, q * P)
    # phase 1: columns along y, starting where phase 0 ended
    flip = K % 2 == 0
    col = np.where(flip, K - q, q) * P
    col_next = np.where(flip, K - q - 1, q + 1) * P
    sy = np.where(even, K * P, 0.0)
    ey = K * P - sy
    ax1 = col
    bx1 = np.where(conn, col_next, col)
    ay1 = np.where(conn, ey, sy)
    by1 = ey
    one = phase == 1
    return (np.where(one, ax1, ax0).astype(np.float64), np.where(one, ay1, ay0).astype(np.float64),
            np.where(one, bx1, bx0).astype(np.float64), np.where(one, by1, by0).astype(np.float64))


def _leg_normals(leg: np.ndarray, grid: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Unit direction (dx, dy) and right-hand normal of legs."""
    ax, ay, bx, by = _leg_ends(leg, grid)
    n = np.hypot(bx - ax, by - ay)
    dx, dy = (bx - ax) / n, (by - ay) / n
    return dx, dy, dy, -dx


def _leg_of(s: np.ndarray, grid: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Leg index, distance into the leg and centre-line leg length at arc length ``s``."""
    K, P = grid, PITCH
    l1 = K * (K + 2) * P
    phase = np.minimum(np.floor(s / l1), 1).astype(np.int64)
    sl = s - phase * l1
    period = (K + 1) * P
    q = np.floor(sl / period).astype(np.int64)
    r = sl - q * period
    main = r < K * P
    lam = 2 * q + (~main)
    s_in = np.where(main, r, r - K * P)
    length = np.where(main, K * P, P)
    return phase * (2 * K + 1) + lam, s_in, length


def _trajectory(s: np.ndarray, grid: int) -> dict[str, np.ndarray]:
    """Scanner position on the lane-offset serpentine at centre-line arc length ``s``."""
    leg, s_in, length = _leg_of(np.asarray(s, dtype=np.float64), grid)
    ax, ay, bx, by = _leg_ends(leg, grid)
    dx, dy, nx, ny = _leg_normals(leg, grid)
    _, _, pnx, pny = _leg_normals(np.maximum(leg - 1, 0), grid)
    first = leg == 0
    pnx, pny = np.where(first, 0.0, pnx), np.where(first, 0.0, pny)
    _, _, qnx, qny = _leg_normals(leg + 1, grid)
    sx, sy = ax + LANE * (nx + pnx), ay + LANE * (ny + pny)
    ex, ey = bx + LANE * (nx + qnx), by + LANE * (ny + qny)
    f = s_in / length
    return {
        "leg": leg, "x": sx + f * (ex - sx), "y": sy + f * (ey - sy),
        "along_x": np.abs(dx) > 0.5, "dir": np.where(np.abs(dx) > 0.5, np.sign(dx), np.sign(dy)),
        "scale": np.hypot(ex - sx, ey - sy) / length,
    }


# ============================================================================= plan
@dataclass(frozen=True)
class CityPlan:
    """Everything derived from ``n_points`` alone (no randomness).

    Attributes
    ----------
    n_points, n_mobile, n_aerial : int
        Total points and the split between the mobile and the aerial scan.
    grid : int
        K: the serpentine covers a K x K block grid (local 0 .. K * PITCH).
    trajectory_length : float
        Metres of trajectory scanned by the mobile part.
    mobile_blocks, aerial_blocks : int
        Internal blocks (``BLOCK`` points, the last of each part shorter).
    region : tuple of float
        Local (x0, x1, y0, y1) covered by the aerial strips.
    strips, lines_per_strip, points_per_line : int
        Aerial strip layout.
    strip_width, line_spacing, half_angle : float
        Strip centre spacing (m), along-track line spacing (m), scan half angle (rad).
    aerial_t0 : float
        GPS time of the first aerial line.
    """

    n_points: int
    n_mobile: int
    n_aerial: int
    grid: int
    trajectory_length: float
    mobile_blocks: int
    aerial_blocks: int
    region: tuple[float, float, float, float]
    strips: int
    lines_per_strip: int
    points_per_line: int
    strip_width: float
    line_spacing: float
    half_angle: float
    aerial_t0: float

    @property
    def blocks(self) -> int:
        """Number of internal blocks."""
        return self.mobile_blocks + self.aerial_blocks


def city_plan(n_points: int) -> CityPlan:
    """Scan plan for ``n_points``: trajectory length, grid size, aerial strips.

    Parameters
    ----------
    n_points : int
        Total number of points (>= 0).

    Returns
    -------
    CityPlan
    """
    n_points = int(n_points)
    if n_points < 0:
        raise ValueError("n_points must be >= 0")
    n_aerial = round(AERIAL_SHARE * n_points)
    n_mobile = n_points - n_aerial
    length = n_mobile / MOBILE_DENSITY
    block_len = PROFILES_PER_BLOCK * PROFILE_SPACING
    grid = 1
    while 2 * grid * (grid + 2) * PITCH < length + block_len + 1.0:
        grid += 1
    if grid > MAX_INDEX - 10:
        raise ValueError(f"{n_points} points need a {grid} x {grid} grid; at most {MAX_INDEX - 10} supported")
    # bounding box of the driven trajectory
    last, _, _ = _leg_of(np.array([length]), grid)
    legs = np.arange(int(last[0]) + 1)
    s_starts = []
    for lg in legs:  # few hundred legs at most for 10^9 points
        s_starts.append(_leg_start_s(int(lg), grid))
    pts = _trajectory(np.array(s_starts + [length]), grid)
    x0, x1 = float(pts["x"].min()) - AERIAL_MARGIN, float(pts["x"].max()) + AERIAL_MARGIN
    y0, y1 = float(pts["y"].min()) - AERIAL_MARGIN, float(pts["y"].max()) + AERIAL_MARGIN
    # aerial strips along x
    max_width = 2 * FLIGHT_HEIGHT * math.tan(MAX_HALF_ANGLE) / (1 + STRIP_OVERLAP)
    strips = max(1, math.ceil((y1 - y0) / max_width))
    width = (y1 - y0) / strips
    half_angle = math.atan(0.5 * (1 + STRIP_OVERLAP) * width / FLIGHT_HEIGHT)
    swath = (1 + STRIP_OVERLAP) * width
    if n_aerial > 0:
        ppl = max(8, round(math.sqrt(n_aerial * swath / (strips * (x1 - x0)))))
        n_lines = math.ceil(n_aerial / ppl)
        lps = math.ceil(n_lines / strips)
    else:
        ppl, lps = 8, 1
    spacing = (x1 - x0) / lps
    t_end = MOBILE_T0 + (length + block_len) / SPEED
    return CityPlan(
        n_points=n_points, n_mobile=n_mobile, n_aerial=n_aerial, grid=grid, trajectory_length=length,
        mobile_blocks=math.ceil(n_mobile / BLOCK), aerial_blocks=math.ceil(n_aerial / BLOCK),
        region=(x0, x1, y0, y1), strips=strips, lines_per_strip=lps, points_per_line=ppl,
        strip_width=width, line_spacing=spacing, half_angle=half_angle, aerial_t0=t_end + AERIAL_GAP,
    )


def _leg_start_s(leg: int, grid: int) -> float:
    """Centre-line arc length where ``leg`` starts."""
    K, P = grid, PITCH
    phase, lam = divmod(leg, 2 * K + 1)
    q, conn = divmod(lam, 2)
    return phase * K * (K + 2) * P + q * (K + 1) * P + conn * K * P


# ============================================================================= ray casting
def _ground_hit(c: np.ndarray, ov: np.ndarray, oz: np.ndarray, dv: np.ndarray, dz: np.ndarray,
                vc: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """First intersection of rays (in the plane ``c``) with the ground height field.

    Along a profile plane at ``c`` the ground is ``f(min(dc, w))`` with ``dc``
    the distance of the plane to the nearest street parallel to it and ``w =
    |v - vc|``: linear pieces in ``w`` (road, sidewalk, interior, all cut at
    ``dc``), a constant tail beyond ``dc`` and the curb step at ``HALF_ROAD``.
    Each piece is intersected on both sides of ``vc`` and the nearest valid
    hit kept.  Returns ``t`` (inf where none) and the normal ``(nc, nv, nz)``
    in plane coordinates, and a road flag.
    """
    cs = np.round(c / PITCH) * PITCH
    dc = np.abs(c - cs)
    sgn_c = np.where(c >= cs, 1.0, -1.0)
    n = c.shape[0]
    best = np.full(n, np.inf)
    pid = np.full(n, -1, dtype=np.int8)
    eps = 1e-9
    pieces = (  # (w0, w1, a, b): z = a + b w on [w0, w1]
        (0.0, HALF_ROAD, CAMBER * HALF_ROAD, -CAMBER),
        (HALF_ROAD, EDGE, CURB - SIDEWALK_SLOPE * HALF_ROAD, SIDEWALK_SLOPE),
        (EDGE, np.inf, INTERIOR_Z, 0.0),
    )
    f_dc = _ground_f(dc)
    with np.errstate(divide="ignore", invalid="ignore"):
        for si, sg in enumerate((-1.0, 1.0)):
            e = sg * (ov - vc)
            qv = sg * dv
            for k, (w0, w1, a, b) in enumerate(pieces):
                t = (a + b * e - oz) / (dz - b * qv)
                w = e + t * qv
                ok = (t > 1e-6) & (w >= w0 - eps) & (w <= np.minimum(w1, dc) + eps) & (t < best)
                best = np.where(ok, t, best)
                pid = np.where(ok, si * 5 + k, pid)
            t = (f_dc - oz) / dz  # tail
            ok = (t > 1e-6) & (e + t * qv >= dc - eps) & (t < best)
            best = np.where(ok, t, best)
            pid = np.where(ok, si * 5 + 3, pid)
            t = (HALF_ROAD - e) / qv  # curb face
            z = oz + t * dz
            ok = (t > 1e-6) & (dc > HALF_ROAD) & (z >= -eps) & (z <= CURB + eps) & (t < best)
            best = np.where(ok, t, best)
            pid = np.where(ok, si * 5 + 4, pid)
    # normals
    side = np.where(pid >= 5, 1.0, -1.0)
    k = pid % 5
    slope = np.choose(np.clip(k, 0, 4), [-CAMBER, SIDEWALK_SLOPE, 0.0, 0.0, 0.0])
    nc = np.zeros(n)
    nv = -slope * side
    nz = np.ones(n)
    tail = k == 3
    nc = np.where(tail, -_ground_fprime(dc) * sgn_c, nc)
    nv = np.where(tail, 0.0, nv)
    curb = k == 4
    nv = np.where(curb, -side, nv)
    nz = np.where(curb, 0.0, nz)
    norm = np.sqrt(nc * nc + nv * nv + nz * nz)
    road = (k == 0) | (tail & (dc <= HALF_ROAD))
    return best, nc / norm, nv / norm, nz / norm, road


def _cast(axis: int, c_p: np.ndarray, shift_p: np.ndarray, ov_p: np.ndarray, oz_p: np.ndarray, theta0: float,
          dtheta: float, n_rays: int, objects: np.ndarray, rmax: float, wrap: bool, vc_mode: str,
          rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Cast ``n_rays`` rays in each of the vertical profile planes of one group.

    Profile ``p`` lies in the plane ``x = c`` (``axis`` 0, in-plane
    coordinate v = y) or ``y = c`` (``axis`` 1, v = x); its origin is
    ``(ov_p, oz_p)`` in the plane.  Ray ``k`` points at angle ``theta0 + (k +
    0.5 + jitter) * dtheta`` from straight down, towards +v; the plane
    advances by ``shift_p`` over the sweep (the scanner moves while it turns),
    so each ray has its own ``c``.  Candidate (ray, object) pairs come from
    the angular extent of each object's bounding rectangle seen from the
    origin; the nearest hit among the ground and the candidates wins.

    Returns
    -------
    dict
        Per ray (``P * n_rays``, profile-major): ``t`` (inf for no return),
        ``c``, ``dv``, ``dz``, ``ov``, ``oz``, ``frac`` (position in the
        sweep, 0..1), normals ``nc``, ``nv``, ``nz``, ``cls``, ``oid``, ``refl``.
    """
    P = c_p.shape[0]
    jit = rng.uniform(-JITTER, JITTER, (P, n_rays))
    kk = np.arange(n_rays) + 0.5 + jit
    frac = (kk / n_rays).ravel()
    theta = (theta0 + kk * dtheta).ravel()
    c = (c_p[:, None] + shift_p[:, None] * (kk / n_rays - 0.5)).ravel()
    dv = np.sin(theta)
    dv = np.where(np.abs(dv) < 1e-12, 1e-12, dv)
    dz = -np.cos(theta)
    ov = np.repeat(ov_p, n_rays)
    oz = np.repeat(oz_p, n_rays)
    n = c.shape[0]

    # ---- ground
    t_best = np.full(n, np.inf)
    nc = np.zeros(n)
    nv = np.zeros(n)
    nz = np.zeros(n)
    down = np.flatnonzero(dz < -1e-9)
    if vc_mode == "origin":
        vref = ov[down]
    else:  # near-vertical rays: street nearest to where the ray lands
        vref = ov[down] + dv[down] * (oz[down] - INTERIOR_Z) / -dz[down]
    vc = np.round(vref / PITCH) * PITCH
    tg, gnc, gnv, gnz, road = _ground_hit(c[down], ov[down], oz[down], dv[down], dz[down], vc)
    if vc_mode != "origin":  # guarantee a return (numerical corner cases)
        miss = ~np.isfinite(tg)
        tg[miss] = (INTERIOR_Z - oz[down][miss]) / dz[down][miss]
        gnz[miss] = 1.0
    t_best[down] = tg
    nc[down], nv[down], nz[down] = gnc, gnv, gnz
    cls = np.full(n, GROUND, dtype=np.uint8)
    oid = np.zeros(n, dtype=np.uint32)
    refl = np.full(n, 0.32)
    refl[down[road]] = 0.18

    # ---- candidate pairs
    if objects.shape[0]:
        if axis == 0:
            oc0, oc1, ov0, ov1 = (objects[:, C_X0], objects[:, C_X1], objects[:, C_Y0], objects[:, C_Y1])
            occ, ovc = objects[:, C_CX], objects[:, C_CY]
        else:
            oc0, oc1, ov0, ov1 = (objects[:, C_Y0], objects[:, C_Y1], objects[:, C_X0], objects[:, C_X1])
            occ, ovc = objects[:, C_CY], objects[:, C_CX]
        kind = objects[:, C_KIND]
        ridge_c = objects[:, C_RIDGE] == axis  # ridge along c: tent across v
        roof = objects[:, C_ROOF]
        otop = objects[:, C_Z1] + roof
        margin = 0.5 * np.abs(shift_p).max() + 1e-6
        cut = (c_p[:, None] >= oc0[None, :] - margin) & (c_p[:, None] <= oc1[None, :] + margin)
        pi, oi = np.nonzero(cut)
        if pi.size:
            pov, poz = ov_p[pi], oz_p[pi]
            cv = (ov0[oi] - pov, ov1[oi] - pov, ov0[oi] - pov, ov1[oi] - pov)
            cz = (objects[oi, C_Z0] - poz, objects[oi, C_Z0] - poz, otop[oi] - poz, otop[oi] - poz)
            ang = np.arctan2(np.stack(cv), -np.stack(cz))
            if wrap:
                ang %= 2 * np.pi
            amin, amax = ang.min(axis=0), ang.max(axis=0)
            inside = (np.stack(cv[:2]).prod(axis=0) <= 0) & (np.stack(cz[1:3]).prod(axis=0) <= 0)
            k0 = np.ceil((amin - theta0) / dtheta - 0.5 - JITTER).astype(np.int64)
            k1 = np.floor((amax - theta0) / dtheta - 0.5 + JITTER).astype(np.int64)
            k0 = np.where(inside, 0, np.clip(k0, 0, n_rays))
            k1 = np.where(inside, n_rays - 1, np.clip(k1, -1, n_rays - 1))
            cnt = np.maximum(k1 - k0 + 1, 0)
            total = int(cnt.sum())
            if total:
                first = np.repeat(pi * n_rays + k0 - (np.cumsum(cnt) - cnt), cnt)
                ray = first + np.arange(total)
                ob = np.repeat(oi, cnt)
                _hit_objects(ray, ob, kind, c, ov, oz, dv, dz, oc0, oc1, ov0, ov1, occ, ovc, objects, roof,
                             ridge_c, t_best, nc, nv, nz, cls, oid, refl, rng)
    t_best[t_best > rmax] = np.inf
    return {"t": t_best, "c": c, "dv": dv, "dz": dz, "ov": ov, "oz": oz, "frac": frac, "theta": theta,
            "nc": nc, "nv": nv, "nz": nz, "cls": cls, "oid": oid, "refl": refl}


def _hit_objects(ray: np.ndarray, ob: np.ndarray, kind: np.ndarray, c: np.ndarray, ov: np.ndarray,
                 oz: np.ndarray, dv: np.ndarray, dz: np.ndarray, oc0: np.ndarray, oc1: np.ndarray,
                 ov0: np.ndarray, ov1: np.ndarray, occ: np.ndarray, ovc: np.ndarray, objects: np.ndarray,
                 roof: np.ndarray, ridge_c: np.ndarray, t_best: np.ndarray, nc: np.ndarray, nv: np.ndarray,
                 nz: np.ndarray, cls: np.ndarray, oid: np.ndarray, refl: np.ndarray,
                 rng: np.random.Generator) -> None:
    """Intersect candidate (ray, object) pairs and update the per-ray nearest hit in place.

    ``ray`` and ``ob`` index the rays (arrays ``c`` .. ``dz``) and the objects
    (their extents in plane coordinates ``oc0`` .. ``ovc`` and the table
    ``objects``).  Boxes and cylinders are rectangles in the plane (slab
    test; gabled roofs add two sloped segments or a raised top), crowns are
    ellipses entered for an exponential free path.  ``t_best`` and the
    attribute arrays are updated where an object is nearer than the ground.
    """
    ts, rs, os_, ncs, nvs, nzs = [], [], [], [], [], []
    inf = np.inf
    with np.errstate(divide="ignore", invalid="ignore"):
        # ---------------- boxes and cylinders: rectangles in the plane
        sel = np.flatnonzero(kind[ob] != ELL)
        if sel.size:
            r, o = ray[sel], ob[sel]
            cr, orv, orz, drv, drz = c[r], ov[r], oz[r], dv[r], dz[r]
            cyl = kind[o] == CYL
            rad = objects[o, C_R]
            h2 = rad * rad - (cr - occ[o]) ** 2
            h = np.sqrt(np.maximum(h2, 0.0))
            v0 = np.where(cyl, ovc[o] - h, ov0[o])
            v1 = np.where(cyl, ovc[o] + h, ov1[o])
            inside_c = np.where(cyl, h2 > 0, (cr >= oc0[o]) & (cr <= oc1[o]))
            rf = roof[o]
            tent = (rf > 0) & ridge_c[o]
            raised = (rf > 0) & ~ridge_c[o]
            cm, hc = 0.5 * (oc0[o] + oc1[o]), 0.5 * (oc1[o] - oc0[o])
            z0 = objects[o, C_Z0]
            z1 = objects[o, C_Z1] + np.where(raised, rf * (1 - np.abs(cr - cm) / hc), 0.0)
            inv = 1.0 / drv
            ta, tb = (v0 - orv) * inv, (v1 - orv) * inv
            tnv, tfv = np.minimum(ta, tb), np.maximum(ta, tb)
            inz = 1.0 / drz
            ta, tb = (z0 - orz) * inz, (z1 - orz) * inz
            tnz, tfz = np.minimum(ta, tb), np.maximum(ta, tb)
            tn = np.maximum(tnv, tnz)
            hit = inside_c & (tn <= np.minimum(tfv, tfz)) & (tn > 1e-6)
            t = np.where(hit, tn, inf)
            wall = tnv >= tnz
            # wall normals: -sign(dv) along v (cylinders: radial), top/bottom: -sign(dz)
            sv = -np.sign(drv)
            n_c = np.where(wall & cyl, (cr - occ[o]) / np.where(rad > 0, rad, 1.0), 0.0)
            n_v = np.where(wall, np.where(cyl, sv * h / np.where(rad > 0, rad, 1.0), sv), 0.0)
            n_z = np.where(wall, 0.0, -np.sign(drz))
            # raised roof top (ridge along v): slopes across c
            top = ~wall & raised & (drz < 0)
            slope_c = -rf / np.where(hc > 0, hc, 1.0) * np.sign(cr - cm)
            nn = np.sqrt(1 + slope_c * slope_c)
            n_c = np.where(top, -slope_c / nn, n_c)
            n_z = np.where(top, 1.0 / nn, n_z)
            # tent roof (ridge along c): two slopes across v
            if tent.any():
                hv = 0.5 * (v1 - v0)
                vm = 0.5 * (v0 + v1)
                s_ = rf / np.where(hv > 0, hv, 1.0)
                tl = (z1 + s_ * (orv - v0) - orz) / (drz - s_ * drv)
                vl = orv + tl * drv
                okl = tent & inside_c & (tl > 1e-6) & (vl >= v0) & (vl <= vm) & (tl < t)
                nn = np.sqrt(1 + s_ * s_)
                t = np.where(okl, tl, t)
                n_c = np.where(okl, 0.0, n_c)
                n_v = np.where(okl, -s_ / nn, n_v)
                n_z = np.where(okl, 1.0 / nn, n_z)
                tr = (z1 + s_ * (v1 - orv) - orz) / (drz + s_ * drv)
                vr = orv + tr * drv
                okr = tent & inside_c & (tr > 1e-6) & (vr >= vm) & (vr <= v1) & (tr < t)
                t = np.where(okr, tr, t)
                n_c = np.where(okr, 0.0, n_c)
                n_v = np.where(okr, s_ / nn, n_v)
                n_z = np.where(okr, 1.0 / nn, n_z)
            f = np.isfinite(t)
            ts.append(t[f]); rs.append(r[f]); os_.append(o[f])
            ncs.append(n_c[f]); nvs.append(n_v[f]); nzs.append(n_z[f])
        # ---------------- crowns: volumetric ellipsoids
        sel = np.flatnonzero(kind[ob] == ELL)
        if sel.size:
            r, o = ray[sel], ob[sel]
            cr, orv, orz, drv, drz = c[r], ov[r], oz[r], dv[r], dz[r]
            k2 = 1.0 - ((cr - occ[o]) / objects[o, C_R]) ** 2
            kk = np.sqrt(np.maximum(k2, 1e-12))
            A, B = objects[o, C_R] * kk, objects[o, C_RZ] * kk
            pv, pz = (orv - ovc[o]) / A, (orz - objects[o, C_CZ]) / B
            qv, qz = drv / A, drz / B
            a = qv * qv + qz * qz
            b = pv * qv + pz * qz
            cc = pv * pv + pz * pz - 1.0
            disc = b * b - a * cc
            sq = np.sqrt(np.maximum(disc, 0.0))
            t_in = np.maximum((-b - sq) / a, 1e-6)
            t_out = (-b + sq) / a
            t = t_in + rng.exponential(FOLIAGE_PATH, t_in.shape[0])
            ok = (k2 > 0) & (disc > 0) & (t < t_out)
            t = np.where(ok, t, inf)
            f = np.isfinite(t)
            z = np.zeros(int(f.sum()))
            ts.append(t[f]); rs.append(r[f]); os_.append(o[f]); ncs.append(z); nvs.append(z); nzs.append(z)
    if not ts:
        return
    t = np.concatenate(ts)
    r = np.concatenate(rs)
    o = np.concatenate(os_)
    np.minimum.at(t_best, r, t)
    win = t == t_best[r]
    r, o = r[win], o[win]
    nc[r] = np.concatenate(ncs)[win]
    nv[r] = np.concatenate(nvs)[win]
    nz[r] = np.concatenate(nzs)[win]
    cls[r] = objects[o, C_CLS].astype(np.uint8)
    oid[r] = objects[o, C_OID].astype(np.uint32)
    refl[r] = objects[o, C_REFL]


# ============================================================================= blocks
def _points(res: dict[str, np.ndarray], idx: np.ndarray, axis: int, noise: float, rng: np.random.Generator,
            range_scale: float) -> dict[str, np.ndarray]:
    """World coordinates, normals and intensity of the returns ``idx`` of one cast."""
    t = res["t"][idx]
    t = t + rng.normal(0.0, noise, t.shape[0])
    dv, dz = res["dv"][idx], res["dz"][idx]
    pc = res["c"][idx]
    pv = res["ov"][idx] + t * dv
    pz = res["oz"][idx] + t * dz
    nc, nv, nz = res["nc"][idx], res["nv"][idx], res["nz"][idx]
    if axis == 0:
        x, y, nx, ny = pc, pv, nc, nv
    else:
        x, y, nx, ny = pv, pc, nv, nc
    cos = np.abs(nv * dv + nz * dz)
    cos = np.where((nc == 0) & (nv == 0) & (nz == 0), 0.5, cos)
    atten = 1.0 / (1.0 + t / range_scale) if np.isfinite(range_scale) else 0.8
    inten = res["refl"][idx] * (0.3 + 0.7 * cos) * atten * 60_000.0 * rng.uniform(0.9, 1.1, t.shape[0])
    return {
        "x": x + ORIGIN[0], "y": y + ORIGIN[1], "z": pz + ORIGIN[2],
        "classification": res["cls"][idx], "object_id": res["oid"][idx],
        "nx": nx.astype(np.float32), "ny": ny.astype(np.float32), "nz": nz.astype(np.float32),
        "intensity": np.clip(inten, 0, 65_535).astype(np.uint16),
    }


def _concat(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    if len(parts) == 1:
        return parts[0]
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _mobile_block(plan: CityPlan, seed: int, b: int) -> dict[str, np.ndarray]:
    need = min(BLOCK, plan.n_mobile - b * BLOCK)
    g = b * PROFILES_PER_BLOCK + np.arange(PROFILES_PER_BLOCK)
    s = (g + 0.5) * PROFILE_SPACING
    tr = _trajectory(s, plan.grid)
    cuts = np.flatnonzero(np.diff(tr["leg"])) + 1
    groups = []
    for sl in np.split(np.arange(PROFILES_PER_BLOCK), cuts):
        along_x = bool(tr["along_x"][sl[0]])
        axis = 0 if along_x else 1
        c_p = (tr["x"] if along_x else tr["y"])[sl]
        ov_p = (tr["y"] if along_x else tr["x"])[sl]
        shift = tr["dir"][sl] * tr["scale"][sl] * PROFILE_SPACING
        lo, hi = c_p.min() - 1.0, c_p.max() + 1.0
        va, vb = ov_p.min() - MOBILE_RANGE, ov_p.max() + MOBILE_RANGE
        box = (lo, hi, va, vb) if axis == 0 else (va, vb, lo, hi)
        groups.append((sl, axis, c_p, ov_p, shift, _objects_in(seed, *box)))
    oz = SCANNER_HEIGHT + CAMBER * (HALF_ROAD - LANE)
    rays, attempt = RAYS, 0
    while True:
        rng = _rng(seed, 10, b, attempt)
        dtheta = 2 * np.pi / rays
        k_lo = math.ceil(BLIND / dtheta)
        n_rays = rays - 2 * k_lo
        casts = []
        for sl, axis, c_p, ov_p, shift, objs in groups:
            res = _cast(axis, c_p, shift, ov_p, np.full(sl.size, oz), k_lo * dtheta, dtheta, n_rays, objs,
                        MOBILE_RANGE, True, "origin", rng)
            hits = np.flatnonzero(np.isfinite(res["t"]))
            casts.append((sl, axis, res, hits))
        total = sum(h.size for *_, h in casts)
        if total >= BLOCK:
            break
        rays = int(math.ceil(rays * BLOCK / max(total, 1) * 1.1 / 8.0) * 8)
        attempt += 1
    # keep a uniform random subset of exactly BLOCK returns, in scan order
    keep = np.zeros(total, dtype=bool)
    keep[np.argpartition(rng.random(total), BLOCK - 1)[:BLOCK]] = True
    parts, pos = [], 0
    for sl, axis, res, hits in casts:
        mine = hits[keep[pos:pos + hits.size]]
        pos += hits.size
        prof = sl[mine // n_rays]
        pts = _points(res, mine, axis, MOBILE_NOISE, rng, 40.0)
        frac = res["frac"][mine]
        pts["gps_time"] = MOBILE_T0 + (s[prof] + (frac - 0.5) * PROFILE_SPACING) / SPEED
        pts["point_source_id"] = np.ones(mine.size, dtype=np.uint16)
        pts["scan_angle"] = (np.degrees(res["theta"][mine]) - 180.0).astype(np.float32)
        parts.append(pts)
    out = _concat(parts)
    if need < BLOCK:
        out = {k: v[:need] for k, v in out.items()}
    return out


def _aerial_block(plan: CityPlan, seed: int, ba: int) -> dict[str, np.ndarray]:
    i0 = ba * BLOCK
    i1 = min(i0 + BLOCK, plan.n_aerial)
    ppl, lps = plan.points_per_line, plan.lines_per_strip
    l0, l1 = i0 // ppl, (i1 - 1) // ppl + 1
    lines = np.arange(l0, l1)
    strip, q = lines // lps, lines % lps
    direction = np.where(strip % 2 == 0, 1.0, -1.0)
    x0, x1, y0, _ = plan.region
    c_p = np.where(direction > 0, x0 + (q + 0.5) * plan.line_spacing, x1 - (q + 0.5) * plan.line_spacing)
    ov_p = y0 + (strip + 0.5) * plan.strip_width
    oz_p = np.full(lines.size, FLIGHT_HEIGHT)
    shift = direction * plan.line_spacing
    rng = _rng(seed, 20, ba)
    half = plan.half_angle
    parts = []
    for st in np.unique(strip):  # a block may straddle two strips
        sel = np.flatnonzero(strip == st)
        reach = FLIGHT_HEIGHT * math.tan(half) + 2.0
        ya, yb = ov_p[sel[0]] - reach, ov_p[sel[0]] + reach
        xa, xb = c_p[sel].min() - plan.line_spacing, c_p[sel].max() + plan.line_spacing
        objs = _objects_in(seed, xa, xb, ya, yb)
        res = _cast(0, c_p[sel], shift[sel], ov_p[sel], oz_p[sel], -half, 2 * half / ppl, ppl, objs, np.inf,
                    False, "landing", rng)
        first = lines[sel[0]] * ppl
        lo = max(i0 - first, 0)
        hi = min(i1 - first, sel.size * ppl)
        idx = np.arange(lo, hi)
        pts = _points(res, idx, 0, AERIAL_NOISE, rng, np.inf)
        ln = lines[sel][idx // ppl]
        lq = ln % lps
        rate = AIR_SPEED / plan.line_spacing
        strip_time = lps / rate + TURN_TIME
        pts["gps_time"] = plan.aerial_t0 + st * strip_time + (lq + res["frac"][idx]) / rate
        pts["point_source_id"] = np.full(idx.size, 100 + st, dtype=np.uint16)
        pts["scan_angle"] = np.degrees(res["theta"][idx]).astype(np.float32)
        parts.append(pts)
    return _concat(parts)


def city_block(n_points: int, seed: int, index: int, plan: CityPlan | None = None) -> dict[str, np.ndarray]:
    """Points of internal block ``index`` (``BLOCK`` points, fewer for the last of each part).

    Parameters
    ----------
    n_points : int
        Total number of points of the scan.
    seed : int
        City and scan seed (>= 0).
    index : int
        Block index, ``0 <= index < city_plan(n_points).blocks``; the mobile
        blocks come first.
    plan : CityPlan, optional
        ``city_plan(n_points)``, to save recomputing it.

    Returns
    -------
    dict of str to ndarray
        See the module docstring for the keys.
    """
    plan = plan or city_plan(n_points)
    if not 0 <= index < plan.blocks:
        raise IndexError(f"block {index} out of range 0..{plan.blocks - 1}")
    if index < plan.mobile_blocks:
        return _mobile_block(plan, int(seed), index)
    return _aerial_block(plan, int(seed), index - plan.mobile_blocks)


def iter_city_chunks(n_points: int, seed: int = 0, chunk: int = 1_000_000) -> Iterator[dict[str, np.ndarray]]:
    """Stream the scan as chunks of ``chunk`` points (the last one shorter).

    Parameters
    ----------
    n_points : int
        Total number of points; exactly this many are yielded.
    seed : int, default 0
        City and scan seed (>= 0).
    chunk : int, default 1_000_000
        Points per yielded chunk.  Does not change the points, only how they
        are cut.

    Yields
    ------
    dict of str to ndarray
        ``x``, ``y``, ``z`` (float64), ``classification`` (uint8),
        ``object_id`` (uint32), ``nx``, ``ny``, ``nz`` (float32),
        ``intensity`` (uint16), ``gps_time`` (float64),
        ``point_source_id`` (uint16), ``scan_angle`` (float32, degrees).
    """
    if seed < 0:
        raise ValueError("seed must be >= 0")
    if chunk < 1:
        raise ValueError("chunk must be >= 1")
    plan = city_plan(n_points)
    buf: list[dict[str, np.ndarray]] = []
    size = 0
    for b in range(plan.blocks):
        blk = city_block(n_points, seed, b, plan)
        buf.append(blk)
        size += blk["x"].shape[0]
        if size >= chunk:
            data = _concat(buf)
            start = 0
            while size - start >= chunk:
                yield {k: v[start:start + chunk] for k, v in data.items()}
                start += chunk
            buf = [{k: v[start:] for k, v in data.items()}] if start < size else []
            size -= start
    if size:
        yield _concat(buf)


# ============================================================================= LAS output
_PALETTE = {GROUND: (150, 145, 135), HIGH_VEGETATION: (60, 140, 50), BUILDING: (200, 180, 150),
            POLE: (90, 90, 100), CAR: (170, 40, 40), UNCLASSIFIED: (170, 40, 40)}


def _colours(cls: np.ndarray, oid: np.ndarray, intensity: np.ndarray) -> tuple[np.ndarray, ...]:
    """16-bit RGB: a base colour per class, varied per object and shaded by intensity."""
    lut = np.zeros((256, 3))
    for k, rgb in _PALETTE.items():
        lut[k] = rgb
    base = lut[cls]
    h = (oid.astype(np.uint64) * np.uint64(2654435761)) % np.uint64(1000)
    vary = np.where(oid > 0, 0.7 + 0.6 * (h.astype(np.float64) / 1000.0), 1.0)
    shade = 0.6 + 0.4 * np.minimum(intensity / 30_000.0, 1.0)
    rgb = np.clip(base * (vary * shade)[:, None], 0, 255) * 256
    return tuple(rgb[:, i].astype(np.uint16) for i in range(3))


def write_city(path: str | os.PathLike, n_points: int, seed: int = 0, chunk: int = 1_000_000,
               point_format: int = 6) -> int:
    """Write the scan to a LAS (``.las``) or LAZ (``.laz``) file, chunk by chunk.

    The file is written to ``path + ".partial"`` and renamed when complete
    (the partial file is removed on error).  Scale 0.001 m, offsets
    (650000, 6860000, 0); extra-bytes dimensions ``ObjectId`` (uint32) and
    ``TrueNormalX``/``Y``/``Z`` (float32).

    Parameters
    ----------
    path : str or PathLike
        Output file; compressed when the suffix is ``.laz``.
    n_points : int
        Number of points.
    seed : int, default 0
        City and scan seed.
    chunk : int, default 1_000_000
        Points generated and written at a time (bounds the memory).
    point_format : int, default 6
        LAS point format with GPS time (1, 3-10); written as LAS 1.4.

    Returns
    -------
    int
        Number of points written.
    """
    import laspy

    path = Path(path)
    header = laspy.LasHeader(point_format=point_format, version="1.4")
    if "gps_time" not in header.point_format.dimension_names:
        raise ValueError(f"point format {point_format} has no GPS time; use 1 or 3-10")
    header.scales = np.array([LAS_SCALE] * 3)
    header.offsets = np.array(LAS_OFFSETS)
    header.generating_software = "patchcloud tools/city_las.py"
    header.add_extra_dims([
        laspy.ExtraBytesParams(name="ObjectId", type=np.uint32, description="object id, 0 = ground"),
        laspy.ExtraBytesParams(name="TrueNormalX", type=np.float32, description="true normal x"),
        laspy.ExtraBytesParams(name="TrueNormalY", type=np.float32, description="true normal y"),
        laspy.ExtraBytesParams(name="TrueNormalZ", type=np.float32, description="true normal z"),
    ])
    names = set(header.point_format.dimension_names)
    wide_classes = point_format >= 6
    rgb = "red" in names
    compress = path.suffix.lower() == ".laz"
    tmp = path.with_name(path.name + ".partial")
    written = 0
    try:
        with laspy.open(tmp, mode="w", header=header, do_compress=compress) as writer:
            for ch in iter_city_chunks(n_points, seed, chunk):
                m = ch["x"].shape[0]
                rec = laspy.ScaleAwarePointRecord.zeros(m, header=header)
                rec.x, rec.y, rec.z = ch["x"], ch["y"], ch["z"]
                cls = ch["classification"]
                if not wide_classes:
                    cls = np.where(cls > 31, UNCLASSIFIED, cls).astype(np.uint8)
                rec.classification = cls
                rec.intensity = ch["intensity"]
                rec.gps_time = ch["gps_time"]
                rec.return_number = np.ones(m, dtype=np.uint8)
                rec.number_of_returns = np.ones(m, dtype=np.uint8)
                rec.point_source_id = ch["point_source_id"]
                if "scan_angle" in names:
                    rec.scan_angle = np.round(np.clip(ch["scan_angle"], -180, 180) / 0.006).astype(np.int16)
                else:
                    rec.scan_angle_rank = np.clip(np.round(ch["scan_angle"]), -90, 90).astype(np.int8)
                if rgb:
                    rec.red, rec.green, rec.blue = _colours(ch["classification"], ch["object_id"], ch["intensity"])
                rec["ObjectId"] = ch["object_id"]
                rec["TrueNormalX"], rec["TrueNormalY"], rec["TrueNormalZ"] = ch["nx"], ch["ny"], ch["nz"]
                writer.write_points(rec)
                written += m
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return written


# ============================================================================= CLI
def main(argv: list[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("output", type=Path, help="OUT.las or OUT.laz")
    ap.add_argument("--points", type=int, required=True, help="number of points")
    ap.add_argument("--seed", type=int, default=0, help="city and scan seed (default 0)")
    ap.add_argument("--chunk", type=int, default=1_000_000, help="points per chunk (default 1000000)")
    ap.add_argument("--point-format", type=int, default=6, choices=[1, 3, 4, 5, 6, 7, 8, 9, 10],
                    help="LAS point format with GPS time (default 6)")
    a = ap.parse_args(argv)
    if a.points < 0 or a.seed < 0 or a.chunk < 1:
        ap.error("--points and --seed must be >= 0, --chunk >= 1")
    t0 = time.perf_counter()
    try:
        n = write_city(a.output, a.points, a.seed, a.chunk, a.point_format)
    except (ValueError, OSError) as exc:
        print(f"error: {a.output}: {exc}", file=sys.stderr)
        return 2
    dt = time.perf_counter() - t0
    import laspy

    with laspy.open(a.output) as f:
        lo, hi = f.header.mins, f.header.maxs
    size = a.output.stat().st_size
    print(f"{a.output}: {n:,} points, x {lo[0]:.2f}..{hi[0]:.2f}, y {lo[1]:.2f}..{hi[1]:.2f}, "
          f"z {lo[2]:.2f}..{hi[2]:.2f}, {dt:.1f} s ({n / max(dt, 1e-9):,.0f} points/s), {size:,} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
