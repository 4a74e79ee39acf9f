"""Invariants: frame offset, input order, degenerate clouds, bad input."""

from pathlib import Path

import numpy as np
import pytest

import synthetic
from conftest import angles_deg
from patchcloud.core import Method, PatchcloudError, PatchcloudValueError, estimate_normals


@pytest.fixture
def bumpy(rng):
    xy = rng.uniform(0, 30, (30000, 2))
    z = 0.8 * np.sin(xy[:, 0] / 3.0) * np.cos(xy[:, 1] / 4.0)
    return np.column_stack([xy, z]) + rng.normal(scale=0.005, size=(30000, 3))


def test_a_change_of_unit_by_a_power_of_two_gives_the_same_normals():
    """The embedded IGN tile in units of 1/1024 m: the same default threshold (up to its histogram's 0.25 % bins) and the
    same normals.  Its fits of more than 100 units fell outside the calibration's histogram: 0.48 times the threshold,
    12,299 normals moved by more than 1 degree."""
    laspy = pytest.importorskip("laspy")
    las = laspy.read(str(Path(__file__).resolve().parents[1] / "data" / "test_data_77055_627760_LA93_IGN69.laz"))
    p = np.column_stack([las.x, las.y, las.z])
    p -= p.min(axis=0)
    a, b = estimate_normals(p), estimate_normals(p * 1024.0)
    assert b.parameters.threshold / 1024.0 == pytest.approx(a.parameters.threshold, rel=0.005)
    assert np.array_equal(a.method, b.method)
    assert np.all(np.einsum("ij,ij->i", a.normals, b.normals) > np.cos(np.radians(0.1)))  # float32 normals: ~0.03 degree steps


def test_utm_offset_gives_the_same_normals(bumpy):
    offset = np.array([512345.678, 5234567.891, 123.4])
    a = estimate_normals(bumpy)
    b = estimate_normals(bumpy + offset)
    assert np.percentile(angles_deg(a.normals, b.normals, signed=True), 99.9) < 1e-3
    assert np.array_equal(a.patch, b.patch)
    assert np.allclose(a.patches.centroid + offset, b.patches.centroid, rtol=0, atol=1e-6)


def test_result_does_not_depend_on_input_order(bumpy, rng):
    perm = rng.permutation(len(bumpy))
    a = estimate_normals(bumpy)
    b = estimate_normals(bumpy[perm])
    for name in ("normals", "curvature", "k1", "k2", "dir1", "method", "patch"):
        assert np.array_equal(getattr(a, name)[perm], getattr(b, name)), name


def test_order_independence_with_duplicate_points(rng):
    p, _ = synthetic.sphere(rng, 5000)
    p = np.concatenate([p, p[:500], p[:100]])
    perm = rng.permutation(len(p))
    a = estimate_normals(p, orient="outward")
    b = estimate_normals(p[perm], orient="outward")
    assert np.array_equal(a.normals[perm], b.normals)


def test_all_points_identical():
    # one point, 50 times: no direction at all, so no normal (a zero vector, NormalMethod 0), not a PCA of rounding
    p = np.tile([[1.0, 2.0, 3.0]], (50, 1))
    res = estimate_normals(p)
    assert np.all(np.isfinite(res.normals))
    assert not res.normals.any() and (res.method == 0).all()


def test_collinear_points_get_perpendicular_unit_normals(rng):
    t = rng.uniform(0, 10, 2000)
    d = np.array([1.0, 2.0, 0.5]) / np.linalg.norm([1.0, 2.0, 0.5])
    p = t[:, None] * d
    res = estimate_normals(p)
    assert np.all(np.isfinite(res.normals))
    assert np.allclose(np.linalg.norm(res.normals, axis=1), 1, atol=1e-5)
    assert np.max(np.abs(res.normals @ d)) < 1e-3
    assert np.all(res.method == Method.KNN)


def test_flat_along_one_axis(rng):
    xy = rng.uniform(0, 5, (8000, 2))
    p = np.column_stack([np.full(8000, 7.0), xy])  # x constant: normals along x
    res = estimate_normals(p, orient="viewpoint", viewpoint=(100.0, 0.0, 0.0))
    assert np.all(res.normals[:, 0] > 0.9999)


def test_viewpoint_orientation(rng):
    p, _ = synthetic.plane(rng, 10000)
    res = estimate_normals(p, orient="viewpoint", viewpoint=(0.0, 0.0, -50.0))
    assert np.all(res.normals[:, 2] < -0.9999)


def test_a_viewpoint_turns_every_normal_to_face_it_point_by_point(rng):
    """PDAL's viewpoint: each normal faces the viewpoint on its own, whatever its patch group says; on a sphere seen
    from outside, the near side outward and the far side inward, every moment and k-NN normal too."""
    p, n = synthetic.sphere(rng, 30000)
    vp = np.array([0.0, 0.0, 30.0])
    res = estimate_normals(p, orient="viewpoint", viewpoint=vp)
    facing = np.einsum("ij,ij->i", res.normals.astype(np.float64), vp - p)
    assert np.all(facing >= 0)
    view = (vp - p) / np.linalg.norm(vp - p, axis=1)[:, None]
    cos = np.einsum("ij,ij->i", n, view)  # away from the silhouette, where the side is not in doubt
    outward = np.einsum("ij,ij->i", res.normals.astype(np.float64), n) > 0
    assert outward[cos > 0.2].mean() > 0.999 and (~outward[cos < -0.2]).mean() > 0.999
    up = estimate_normals(p, orient="outward")  # the group rule, for comparison: every normal outward
    assert (np.einsum("ij,ij->i", up.normals.astype(np.float64), n) > 0).mean() > 0.999


def test_orient_none_is_consistent_on_a_sphere(rng):
    p, n = synthetic.sphere(rng, 30000)
    res = estimate_normals(p, orient="none")
    outward = np.mean(np.einsum("ij,ij->i", res.normals, n) > 0)
    assert outward >= 0.995 or outward <= 0.005


@pytest.mark.parametrize(
    "points, match",
    [
        (np.array([[0.0, 0.0, np.nan]] + [[1.0, 2.0, 3.0]] * 20), "NaN or infinite"),
        (np.array([[0.0, np.inf, 0.0]] + [[1.0, 2.0, 3.0]] * 20), "NaN or infinite"),
        (np.zeros((20, 2)), r"shape \(N, 3\)"),
        (np.zeros((20, 3, 1)), r"shape \(N, 3\)"),
        (np.zeros((20, 3), dtype=complex), "real numeric"),
        (np.array([["a", "b", "c"]] * 20), "real numeric"),
        (np.zeros((0, 3)), "the cloud has no points"),
    ],
)
def test_bad_points_raise_clear_value_errors(points, match):
    with pytest.raises(PatchcloudValueError, match=match) as info:
        estimate_normals(points)
    assert isinstance(info.value, ValueError) and isinstance(info.value, PatchcloudError)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"criterion": "angle"}, "criterion must be one of rmse, sigma3"),
        ({"orient": "down"}, "orient must be one of up, viewpoint, outward, none"),
        ({"orient": "viewpoint"}, "needs a viewpoint"),
        ({"orient": "viewpoint", "viewpoint": (1, 2)}, "three finite"),
        ({"threshold": -1.0}, "threshold must be a positive"),
        ({"d_min": 0.0}, "d_min must be a positive"),
        ({"n_min": 0}, "n_min must be a positive integer"),
        ({"k_fallback": 2.5}, "k_fallback must be a whole number from 3 to 1000"),
        ({"k_fallback": 2}, "k_fallback must be a whole number from 3 to 1000"),
        ({"k_fallback": 100_000}, "k_fallback must be a whole number from 3 to 1000"),
        ({"min_sigma2": 0.5}, "min_sigma2"),
        ({"root": ((10.0, 10.0, 10.0), 1.0)}, "outside the given root cube"),
    ],
)
def test_bad_parameters_raise(kwargs, match, rng):
    p, _ = synthetic.plane(rng, 200)
    with pytest.raises(ValueError, match=match):
        estimate_normals(p, **kwargs)


def test_integer_points_are_accepted(rng):
    p = np.column_stack([rng.integers(0, 100, (3000, 2)), np.zeros(3000, dtype=int)])
    res = estimate_normals(p)
    assert np.all(np.abs(res.normals[:, 2]) > 0.999)


def test_explicit_root_cube_aligns_leaves(rng):
    p, _ = synthetic.plane(rng, 20000, size=10.0, noise=0.002)
    root = ((-8.0, -8.0, -8.0), 16.0)
    res = estimate_normals(p, root=root)
    t = res.patches
    lo = t.lower
    # every leaf is a cell of the global grid rooted at the given cube
    cells = (lo - np.array(root[0])) / t.edge[:, None]
    assert np.allclose(cells, np.round(cells))
    assert res.parameters.root_edge == 16.0


def test_result_does_not_depend_on_thread_count(rng):
    numba = pytest.importorskip("numba")
    from patchcloud.core.threads import SEQUENTIAL_BELOW, single_threaded

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("only one thread available: nothing to compare")
    n = 2 * SEQUENTIAL_BELOW  # big enough for the kernels' parallel versions (smaller calls run sequentially)
    xy = rng.uniform(0, 60, (n, 2))
    cloud = np.column_stack([xy, 0.8 * np.sin(xy[:, 0] / 3.0) * np.cos(xy[:, 1] / 4.0)]) + rng.normal(scale=0.005, size=(n, 3))
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        a = estimate_normals(cloud)
        numba.set_num_threads(2)
        b = estimate_normals(cloud)
    finally:
        numba.set_num_threads(before)
    with single_threaded():  # the sequential versions
        c = estimate_normals(cloud)
    for name in ("normals", "curvature", "k1", "k2", "dir1", "method", "patch"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
        assert np.array_equal(getattr(a, name), getattr(c, name)), name


def test_coincident_neighbours_get_no_normal():
    """Neighbours that are all one point (duplicates) say nothing of a direction: no normal (NormalMethod 0, zeros), the
    same wherever the cloud lies; before, each got an arbitrary unit vector (a PCA of rounding noise), and a shift of the
    cloud changed it.  (Collinear points still get normals perpendicular to their line: the test above.)"""
    for where in ([1.0, 2.0, 3.0], [650000.1, 6860000.3, 100.7]):
        same = estimate_normals(np.repeat([where], 100, axis=0))  # 100 copies of one point
        assert (same.method == 0).all() and not same.normals.any() and not same.curvature.any()
    three = np.repeat([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]], 20, axis=0)  # each point's 16 nearest: its own copies
    for shift in ([0.0, 0, 0], [650000.0, 6860000.0, 100.0]):
        r = estimate_normals(three + shift)
        assert (r.method == 0).all() and not r.normals.any()


@pytest.mark.parametrize("n", [3, 5, 11])
def test_a_cloud_smaller_than_a_patch_gets_normals(n):
    """Fewer points than n_min (no patch can be fitted): the moment or k-NN normals of the plane, as the command gives a
    file of so few points (the function used to refuse them)."""
    xy = np.random.default_rng(n).uniform(0, 10, (n, 2))
    r = estimate_normals(np.column_stack([xy, 0.5 * xy[:, 0]]))
    assert (r.method > 0).all()
    assert np.allclose(np.abs(r.normals @ np.array([-0.5, 0.0, 1.0]) / np.hypot(0.5, 1.0)), 1.0, atol=1e-6)


def test_a_sigma3_threshold_of_a_third_or_more_is_refused():
    # a surface variation is at most 1/3: such a threshold passes every leaf, whatever its shape (a sweep ran it silently)
    pts = np.random.default_rng(0).uniform(0, 10, (500, 3))
    for t in (1 / 3, 0.34, 5.0):
        with pytest.raises(PatchcloudValueError, match="below 1/3 with criterion sigma3"):
            estimate_normals(pts, criterion="sigma3", threshold=t)
    assert estimate_normals(pts, criterion="sigma3", threshold=0.3).normals.shape == (500, 3)


def test_a_las_tile_shifted_by_whole_metres_gives_the_same_results():
    """The embedded IGN tile (points on a 1 cm grid, many exactly on cell faces) and the same points with its UTM
    offset taken off (an exact shift in float64): the bounding cube's corner is the points' minimum minus a margin of
    few bits, so every point's offset from it is the same and so is every result (131 normals were more than 1 degree
    apart, the spacing 0.3136 against 0.3135, when the cube was centred on the box)."""
    import os

    import laspy

    las = laspy.read(os.path.join(os.path.dirname(__file__), "..", "data", "test_data_77055_627760_LA93_IGN69.laz"))
    p = np.column_stack([las.x, las.y, las.z])
    a = estimate_normals(p)
    for shift in ([-770000.0, -6270000.0, 0.0], [-770048.0, -6266880.0, -16.0]):
        b = estimate_normals(p + np.array(shift))
        exact = p.astype(np.longdouble) + np.array(shift, dtype=np.longdouble)  # 64-bit mantissas on x86: the exact sums
        assert np.array_equal((p + np.array(shift)).astype(np.longdouble), exact)  # the shift is exact
        assert (a.parameters.spacing, a.parameters.threshold) == (b.parameters.spacing, b.parameters.threshold)
        for name in ("method", "patch"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        for name in ("normals", "curvature", "k1", "k2", "dir1"):  # the patches' centroids go through each frame
            assert np.abs(getattr(a, name) - getattr(b, name)).max() <= 1e-6, name
