"""Orientation does not depend on the tiling, k-NN fallback points included.

The scene: a noisy ground plane with tree-like blobs (points filling balls,
which no quadric fits, so their points take the k-NN fallback) centred on
the faces and corners of an 8 m tile grid.  Tiled runs must orient every
point as the single-tile run does.
"""

import laspy
import numpy as np
import orient_cases  # tools/, on the path (conftest)
import pytest

from patchcloud.core import Method
from patchcloud.stream import normals

#: (centre, radius) in metres: each blob sinks into the ground, so that orienting
#: its points by their neighbours starts from the ground and crosses tile faces
BLOBS = [((8.0, 8.0, 1.3), 1.6), ((16.0, 12.0, 1.1), 1.4), ((24.0, 24.0, 1.2), 1.5), ((16.0, 16.0, 0.9), 1.2), ((4.0, 24.0, 1.2), 1.5)]


def blob_scene(seed: int = 3) -> np.ndarray:
    """Ground 32 x 32 m (about 25 points/m^2, 1 cm noise) and five blobs of about 110 points/m^3."""
    rng = np.random.default_rng(seed)
    g = rng.uniform(0.0, 32.0, size=(25_600, 2))
    ground = np.column_stack([g, rng.normal(0.0, 0.01, len(g))])
    parts = [ground]
    for centre, r in BLOBS:
        m = int(110 * 4 / 3 * np.pi * r**3)
        d = rng.normal(size=(m, 3))
        d *= (r * rng.uniform(0, 1, m) ** (1 / 3) / np.linalg.norm(d, axis=1))[:, None]
        parts.append(np.asarray(centre) + d)
    pts = np.concatenate(parts)
    return pts[rng.permutation(len(pts))]


@pytest.fixture(scope="module")
def blob_las(tmp_path_factory):
    pts = blob_scene()
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.zeros(3)
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    path = tmp_path_factory.mktemp("blobs") / "blobs.las"
    las.write(str(path))
    return path


def run(src, out, tile_size):
    normals(src, out, tile_size=tile_size, scheduler="synchronous", quiet=True)
    las = laspy.read(str(out))
    nrm = np.column_stack([las.NormalX, las.NormalY, las.NormalZ]).astype(np.float64)
    return nrm, np.asarray(las.NormalMethod), np.column_stack([las.x, las.y, las.z])


@pytest.mark.slow  # about 50 s (2 cores)
def test_fallback_points_at_tile_faces_are_oriented_as_in_one_tile(blob_las, tmp_path):
    # fallback points: those of no patch, with moment normals (most) or k-NN normals
    ref, ref_method, xyz = run(blob_las, tmp_path / "one.las", 64.0)
    knn = ref_method >= Method.KNN
    assert (ref_method == Method.MOMENTS).sum() > 1000
    # the scene does what it is built for: many fallback points, near tile faces
    near_face = np.min(np.abs(xyz[:, :2] - 8.0 * np.round(xyz[:, :2] / 8.0)), axis=1) < 1.0
    assert (knn & near_face).sum() > 1000
    for T in (8.0, 4.0):
        nrm, method, _ = run(blob_las, tmp_path / f"t{T:g}.las", T)
        # a tiled run splits large leaves at tile faces (quadric -> blended there), and at
        # 4 m tiles (5 d_min) a few leaves at faces change between patch and k-NN: compare like with like
        assert np.sum((method >= Method.KNN) != knn) <= 0.01 * knn.sum(), T
        both = (method >= Method.KNN) == knn
        same = np.einsum("ij,ij->i", nrm, ref) > 0
        assert same[~knn & both].all(), T  # patch (quadric, blended) points: every one
        # fallback points: the bar, 99.9 % (a point whose neighbours changed method may turn)
        assert np.mean(same[knn & both]) >= 0.999, (T, int((~same[knn & both]).sum()))
        ang = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", nrm, ref), -1, 1)))
        assert np.percentile(ang[knn & both], 99) < 0.1, T


def pipe_scene(radius: float = 1.0, seed: int = 0):
    """A horizontal pipe of ``radius`` (m) along x, sampled all round, 3 m above 20 x 10 m of ground: points and each
    point's outward normal (the ground's: up)."""
    rng = np.random.default_rng(seed)
    g = np.mgrid[0:20:0.1, 0:10:0.1].reshape(2, -1).T
    ground = np.column_stack([g, np.zeros(len(g))])
    th, xs = (a.ravel() for a in np.meshgrid(np.arange(0, 2 * np.pi, 0.05 / radius), np.arange(2, 18, 0.05)))
    out = np.column_stack([np.zeros(th.size), np.cos(th), np.sin(th)])
    pipe = np.column_stack([xs, 5 + radius * out[:, 1], 3 + radius * out[:, 2]])
    pts = np.vstack([ground, pipe]) + rng.normal(0.0, 0.002, (len(ground) + len(pipe), 3))
    right = np.vstack([np.tile([0.0, 0.0, 1.0], (len(ground), 1)), out])
    return pts, right


def test_up_orients_a_pipe_outward_its_top_up_whatever_the_tiling(tmp_path):
    # the up rule cannot tell a pipe's underside from its top by its normal: the underside's patches (concave seen from
    # above) and the rough leaves along its lowest line used to decide for the whole pipe, all of it inward (top down)
    pts, right = pipe_scene()
    src = tmp_path / "pipe.las"
    write_scene(src, pts, 0.0, origin=(500000.0, 5000000.0))
    on_pipe = pts[:, 2] > 1.5
    upper = on_pipe & (right[:, 2] >= 0)
    lower = on_pipe & (right[:, 2] < 0)
    first = None
    for tile_size in (4.0, 32.0):
        nrm, _, _ = run(src, tmp_path / f"n{tile_size:g}.las", tile_size)
        good = np.einsum("ij,ij->i", nrm, right) > 0.5
        assert good[upper].mean() > 0.99 and good[lower].mean() > 0.99 and good[~on_pipe].mean() > 0.99, tile_size
        side = np.einsum("ij,ij->i", nrm, right) > 0
        first = side if first is None else first
        assert np.array_equal(side, first)  # the same side for every point at both tile sizes


def write_scene(path, pts, z0, origin=(499712.0, 4997120.0)):
    """Write ``pts`` (local metres) as a LAS file: x and y shifted by ``origin``, z by ``z0``, on a 0.5 mm grid."""
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales, header.offsets = np.full(3, 0.0005), np.array([origin[0], origin[1], 0.0])
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts[:, 0] + origin[0], pts[:, 1] + origin[1], pts[:, 2] + z0
    las.write(str(path))


def scene(parts, seed=0):
    """Points (5 mm noise) and each point's outward normal, from (points, outward normal) pairs: one normal for all the
    part's points, or one per point."""
    pts = np.vstack([p for p, _ in parts])
    right = np.vstack([np.broadcast_to(np.asarray(o, float), p.shape) for p, o in parts])
    return pts + np.random.default_rng(seed).normal(0.0, 0.005, pts.shape), right


def test_up_orients_a_box_buildings_walls_outward_whatever_the_tiling(tmp_path):
    # walls face no side under the up rule: they take the side of the ground and roof they meet at creases.  A wall's
    # foot, a strip of two rows in the ground's leaf row, curled its quadric and linked the wall inward at full
    # reliability: here the -x and -y walls faced into the building, 98 % of their points, at both tile sizes
    # tools/orient_cases.py's box: a 10 x 10 x 6 m building (roof and four walls) on 30 x 30 m of ground, 0.1 m spacing
    pts, right = scene([(p, r) for _, p, r in orient_cases.box()])
    src = tmp_path / "box.las"
    write_scene(src, pts, 100.0, origin=(500000.0, 5000000.0))
    wall = np.abs(right[:, 2]) < 0.5
    first = None
    for tile_size in (8.0, 64.0):
        nrm, _, _ = run(src, tmp_path / f"b{tile_size:g}.las", tile_size)
        side = np.einsum("ij,ij->i", nrm, right) > 0
        for o in ((0, -1, 0), (0, 1, 0), (-1, 0, 0), (1, 0, 0)):
            one = np.all(right == o, axis=1)
            assert side[one].mean() > 0.97, (tile_size, o, side[one].mean())
        assert side[~wall].mean() > 0.99, tile_size
        first = side if first is None else first
        assert np.mean(side == first) > 0.999  # the same side at both tile sizes


def test_eaves_do_not_turn_a_steep_roof_down(tmp_path):
    # a 55-degree gable roof overhanging its walls by 0.6 m: roof and wall meet in a T, which the crease rule reads as
    # the wall and the eaves' underside; at an agreement of 0.75 it outranked the roof plane's up prior (0.57) and
    # turned that plane down, 98.7 % of its points (found by review)
    pts, right = scene([(p, r) for _, p, r in orient_cases.gable(eave=0.6, rise=5.0)])  # 7 x 8 m, 4 m walls
    src = tmp_path / "eave.las"
    write_scene(src, pts, 101.3)
    nrm, _, _ = run(src, tmp_path / "eave_out.las", 8.0)
    good = np.einsum("ij,ij->i", nrm, right) > 0
    for o in np.unique(right, axis=0):
        one = np.all(right == o, axis=1)
        assert good[one].mean() > 0.97, (o, good[one].mean())


def test_ground_round_a_small_building_does_not_turn_its_walls_at_any_tile_size(tmp_path):
    # a 4 x 4 x 3 m building on 24 x 24 m of ground 0.3 m below a tile face, its walls' lowest 0.4 m unseen: at 8 m
    # tiles the tile below the face held only the ground round the building, one leaf whose centroid lies inside the
    # walls, and it turned all four walls inward, at that tile size only (found by review)
    s, foot, h = 4.0, 0.4, 3.0
    x0 = y0 = 12.0 - s / 2 + 0.05
    g = orient_cases.grid(0, 24, 0, 24, 0.1)
    g = g[~((g[:, 0] > x0) & (g[:, 0] < x0 + s) & (g[:, 1] > y0) & (g[:, 1] < y0 + s))]
    r = orient_cases.grid(x0, x0 + s, y0, y0 + s, 0.1)
    w = orient_cases.grid(x0, x0 + s, foot, h, 0.1)
    pts, right = scene([
        (np.column_stack([g, np.zeros(len(g))]), (0, 0, 1)), (np.column_stack([r, np.full(len(r), h)]), (0, 0, 1)),
        (np.column_stack([w[:, 0], np.full(len(w), y0), w[:, 1]]), (0, -1, 0)),
        (np.column_stack([w[:, 0], np.full(len(w), y0 + s), w[:, 1]]), (0, 1, 0)),
        (np.column_stack([np.full(len(w), x0), w[:, 0] - x0 + y0, w[:, 1]]), (-1, 0, 0)),
        (np.column_stack([np.full(len(w), x0 + s), w[:, 0] - x0 + y0, w[:, 1]]), (1, 0, 0)),
    ])
    src = tmp_path / "ring.las"
    write_scene(src, pts, 127.7)
    wall = np.abs(right[:, 2]) < 0.5
    for tile_size in (8.0, 16.0):
        nrm, _, _ = run(src, tmp_path / f"r{tile_size:g}.las", tile_size)
        good = np.einsum("ij,ij->i", nrm, right) > 0
        assert good[wall].mean() > 0.99 and good.mean() > 0.99, (tile_size, good[wall].mean())
