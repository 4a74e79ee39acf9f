"""Points exactly the radius (or the clustering tolerance) apart, on a LAS file's grid, count the same whatever the
frame rounds their coordinates to: the same file with another offset gives the same DoN and segments (they differed by
up to 0.63 on the embedded tile, where points 0.5 m and 2 m apart on its 1 cm grid are common)."""

import os

import laspy
import numpy as np
import pytest

from patchcloud.core import components
from patchcloud.core.radius import radius_moments, tie_margin
from patchcloud.stream import don, segment

SAMPLE = os.path.join(os.path.dirname(__file__), "..", "data", "test_data_77055_627760_LA93_IGN69.laz")


def _lattice(step: float, origin) -> np.ndarray:
    """A 41 x 41 plane of points every ``step`` (metres), its corner at ``origin``: coordinates as a file's integers
    times its scale plus its offset give them (rounded in the frame)."""
    i, j = np.meshgrid(np.arange(41), np.arange(41), indexing="ij")
    ints = np.column_stack([i.ravel(), j.ravel(), np.zeros(i.size, dtype=np.int64)])
    return ints, ints * step + np.asarray(origin, dtype=np.float64)


@pytest.mark.parametrize("mode", ["exact", "fast"])
def test_a_ball_holds_the_grid_points_at_exactly_its_radius_whatever_the_frame(mode):
    """On a 1 cm grid, the ball of 5 cm around a point holds the 81 points (i, j) with i² + j² <= 25 (those at
    (5, 0), (3, 4), ... exactly 5 cm away included), whether the frame puts the grid at 0 or at 123456.78 m."""
    step, r = 0.01, 0.05
    ints, _ = _lattice(step, (0, 0, 0))
    centre = 20 * 41 + 20
    want = int((((ints[:, :2] - ints[centre, :2]) ** 2).sum(axis=1) <= 25).sum())
    assert want == 81
    counts = set()
    for origin in [(0.0, 0.0, 0.0), (123456.78, 6543210.91, 12.34), (0.005, 0.003, 0.0), (777777.77, 1.0, 0.0)]:
        _, pts = _lattice(step, origin)
        m = radius_moments(pts, r, mode=mode, at=np.array([centre]), origin=np.zeros(3), grid_step=step)
        counts.add(int(m[0, 0]))
    assert counts == {want}


def test_two_grid_points_exactly_the_tolerance_apart_are_linked_whatever_the_frame():
    step = 0.01
    for origin in [(0.0, 0.0, 0.0), (123456.78, 6543210.91, 12.34), (777777.77, 1.0, 0.0)]:
        pts = np.array([[0, 0, 0], [3, 4, 0], [10, 0, 0]]) * step + np.asarray(origin)  # 5 cm, then 7.3 cm apart
        assert components(pts, 0.05, grid_step=step).tolist() == [0, 0, 1], origin
    assert tie_margin(0.01) < 0.5 * ((0.0501**2) - 0.05**2) * 100  # far below a grid's next distance


def _shifted(tmp_path, dx: int, dy: int):
    """The embedded tile with its offset moved by (dx, dy) steps: the same points on the same grid."""
    las = laspy.read(SAMPLE)
    h = laspy.LasHeader(point_format=las.header.point_format, version=las.header.version)
    h.vlrs.extend(las.header.vlrs)
    h.scales = las.header.scales
    h.offsets = np.asarray(las.header.offsets) + np.array([dx, dy, 0]) * np.asarray(las.header.scales)
    moved = laspy.LasData(h)
    for name in las.point_format.dimension_names:
        if name not in ("X", "Y", "Z"):
            moved[name] = las[name]
    moved.X = np.asarray(las.X, dtype=np.int64) - dx
    moved.Y = np.asarray(las.Y, dtype=np.int64) - dy
    moved.Z = las.Z
    out = tmp_path / f"shift{dx}_{dy}.laz"
    moved.write(out)
    return out


@pytest.mark.parametrize("mode", ["exact", "fast"])
def test_the_same_points_with_another_offset_give_the_same_don_and_segments(tmp_path, mode):
    other = _shifted(tmp_path, 77_000_000, 627_700_000)
    a, b = laspy.read(SAMPLE), laspy.read(other)
    assert np.array_equal(np.asarray(a.X, dtype=np.int64), np.asarray(b.X, dtype=np.int64) + 77_000_000)  # the same grid
    assert np.array_equal(np.asarray(a.Y, dtype=np.int64), np.asarray(b.Y, dtype=np.int64) + 627_700_000)
    assert np.abs(np.asarray(a.x) - np.asarray(b.x)).max() < 1e-6  # (their coordinates round apart)
    outs = []
    for src, name in ((SAMPLE, "a"), (other, "b")):
        segment(src, tmp_path / f"{name}.laz", r_small=0.5, r_large=2.0, mode=mode, threshold=0.25, tolerance=0.5,
                min_cluster=20, quiet=True)
        outs.append(laspy.read(tmp_path / f"{name}.laz"))
    da, db = np.asarray(outs[0].DoN, dtype=np.float64), np.asarray(outs[1].DoN, dtype=np.float64)
    assert np.array_equal(da == 0, db == 0)
    assert np.abs(da - db).max() <= 1e-6  # float32 in the file; they differed by up to 0.63
    assert np.array_equal(np.asarray(outs[0].ClusterID), np.asarray(outs[1].ClusterID))


@pytest.mark.parametrize("r", [0.04, 0.05, 0.08])
def test_every_ball_on_a_grid_holds_exactly_its_grid_points_wherever_the_grid_lies_in_the_frame(r):
    """Balls around every 37th point of a 1 cm grid hold exactly the grid points within r (ties in), also where the
    grid does not start at a cell face of the frame (points a fraction of a step below the faces, which the ties'
    nudge moves into the cell above: the cells each query scans move with them)."""
    step = 0.01
    ints, _ = _lattice(step, (0, 0, 0))
    k0 = round((r / step) ** 2)
    queries = np.arange(0, ints.shape[0], 37)
    want = np.array([int((((ints[:, :2] - ints[q, :2]) ** 2).sum(axis=1) <= k0).sum()) for q in queries])
    for origin in [(0.0, 0.0, 0.0), (0.0078, 0.0079, 0.0), (0.0076, 0.0024, 0.0), (123456.7878, 6543210.9179, 0.0)]:
        _, pts = _lattice(step, origin)
        got = radius_moments(pts, r, mode="exact", at=queries, origin=np.zeros(3), grid_step=step)[:, 0]
        assert np.array_equal(got, want), origin


@pytest.mark.parametrize("on_disk", [False, True])
def test_the_same_points_with_another_offset_give_the_same_normals_bit_for_bit(tmp_path, on_disk):
    """The local frame is (X + base) * scale, one rounding of a whole number of steps from the grid's origin
    (patchcloud.core.frame_shift), so every new dimension is the same, bit for bit, whatever the offset the file was
    written with: 8 to 28 of the tile's points, on cell faces at 0.25 m of the 0.5 m grid, had other normals (up to 85
    degrees apart, 3 to 8 on the other side) with another offset; on disk, tiles of 16 m put more points on faces."""
    from patchcloud.stream import normals

    other = _shifted(tmp_path, 1_234_567, -654_321)
    opts = dict(store=str(tmp_path / "s.zarr"), tile_size=16.0, scheduler="synchronous") if on_disk else {}
    outs = []
    for src, name in ((SAMPLE, "a"), (other, "b")):
        if on_disk:
            opts["store"] = str(tmp_path / f"{name}.zarr")
        normals(src, tmp_path / f"{name}.laz", quiet=True, principal_curvatures=True, **opts)
        outs.append(laspy.read(tmp_path / f"{name}.laz"))
    new = ["NormalX", "NormalY", "NormalZ", "Curvature", "NormalMethod", "PatchId", "PrincipalCurvature1",
           "PrincipalCurvature2", "PrincipalDirectionX", "PrincipalDirectionY", "PrincipalDirectionZ"]
    assert (np.asarray(outs[0].NormalMethod) == 4).sum() > 10_000  # moment normals, whose cells decided it
    for dim in new:
        assert np.array_equal(np.asarray(outs[0][dim]), np.asarray(outs[1][dim])), dim
