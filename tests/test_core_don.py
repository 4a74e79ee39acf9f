"""Radius normals, Difference of Normals and Euclidean clustering of one in-memory cloud (patchcloud.core)."""

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from scipy.stats import spearmanr

from patchcloud.core import (
    PatchcloudValueError,
    difference_of_normals,
    don_magnitude,
    don_mask,
    euclidean_clusters,
    radius_normals,
    segment_don,
)
from patchcloud.core.radius import halo_width, radius_moments


def brute_normals(points, radius, viewpoint, at):
    """PCA of the ball, by hand: the reference definition."""
    tree = cKDTree(points)
    out = np.full((len(at), 3), np.nan)
    for m, i in enumerate(at):
        nb = tree.query_ball_point(points[i], radius * (1 + 1e-12))
        if len(nb) < 3:
            continue
        d = points[nb] - points[i]
        w, v = np.linalg.eigh(np.cov(d.T, bias=True))
        n = v[:, 0]
        out[m] = n if np.dot(viewpoint - points[i], n) >= 0 else -n
    return out


def pole_scene(rng, spacing=0.05):
    """A 12 x 12 m ground plane with a vertical pole of radius 0.1 m and height 3 m at its centre."""
    g = np.arange(-6, 6, spacing)
    gx, gy = np.meshgrid(g, g)
    ground = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    ground[:, :2] += rng.uniform(-spacing / 4, spacing / 4, (gx.size, 2))
    theta = np.arange(0, 2 * np.pi, spacing / 0.1)
    z = np.arange(spacing, 3.0, spacing)
    tt, zz = np.meshgrid(theta, z)
    pole = np.column_stack([0.1 * np.cos(tt.ravel()), 0.1 * np.sin(tt.ravel()), zz.ravel()])
    ground = ground[np.hypot(ground[:, 0], ground[:, 1]) > 0.1]
    return np.vstack([ground, pole]), len(ground)


def test_exact_normals_equal_the_reference_pca(rng):
    p = rng.uniform(0, 3, (3000, 3)) * [1, 1, 0.2] + [650000.0, 6860000.0, 40.0]  # UTM-sized coordinates
    at = rng.choice(len(p), 200, replace=False)
    vp = np.array([650001.0, 6860001.0, 100.0])
    ours = radius_normals(p, 0.4, viewpoint=vp, at=at, mode="exact")
    ref = brute_normals(p, 0.4, vp, at)
    assert np.array_equal(np.isnan(ours), np.isnan(ref))
    ok = ~np.isnan(ref[:, 0])
    assert ok.sum() > 150
    np.testing.assert_allclose(ours[ok], ref[ok], atol=1e-9)


@pytest.mark.parametrize("mode", ["exact", "fast"])
def test_plane_gives_zero_don_and_normals_face_the_viewpoint(rng, mode):
    xy = rng.uniform(0, 10, (20000, 2))
    p = np.column_stack([xy, 0.3 * xy[:, 0] + 5.0])  # tilted plane
    d = difference_of_normals(p, 0.3, 1.5, mode=mode)
    assert np.nanmax(np.abs(d)) < 1e-9
    n = radius_normals(p, 0.5, mode=mode, viewpoint=[5, 5, 100])
    truth = np.array([-0.3, 0, 1]) / np.hypot(0.3, 1)
    np.testing.assert_allclose(n, np.broadcast_to(truth, n.shape), atol=1e-9)
    n_down = radius_normals(p, 0.5, mode=mode, viewpoint=[5, 5, -100])
    np.testing.assert_allclose(n_down, -n, atol=1e-12)


@pytest.mark.parametrize("mode", ["exact", "fast"])
def test_magnitude_lies_in_unit_interval(rng, mode):
    p = rng.normal(size=(20000, 3)) * [2, 2, 0.5]
    m = don_magnitude(difference_of_normals(p, 0.3, 1.2, mode=mode))
    ok = np.isfinite(m)
    assert ok.mean() > 0.9
    assert m[ok].min() >= 0 and m[ok].max() <= 1 + 1e-12


def test_pole_responds_at_its_scale_and_not_at_others(rng):
    p, n_ground = pole_scene(rng)
    pole = np.arange(len(p)) >= n_ground
    mid = pole & (p[:, 2] > 1.0) & (p[:, 2] < 2.0)  # away from the pole's foot and top
    far = ~pole & (np.hypot(p[:, 0], p[:, 1]) > 3.0) & (np.abs(p[:, :2]).max(axis=1) < 4.0)
    # DoN at the points looked at only (``at``: every point is still a neighbour), so the balls of 6-8 m over the
    # whole scene are not computed at every point
    at = np.flatnonzero(mid | far)
    on_pole = mid[at]
    at_scale = don_magnitude(difference_of_normals(p, 0.2, 2.0, mode="exact", at=at))
    assert np.median(at_scale[on_pole]) > 0.5  # horizontal small-scale normal vs near-vertical large-scale one
    assert np.nanmax(at_scale[~on_pole]) < 1e-6  # the ground away from the pole is flat at both scales
    # both radii far larger than the pole: the ground dominates both balls
    large = don_magnitude(difference_of_normals(p, 6.0, 8.0, mode="exact", at=np.flatnonzero(mid)))
    assert np.nanmedian(large) < 0.1
    # both radii smaller than the pole's radius: both normals radial
    small = don_magnitude(difference_of_normals(p, 0.06, 0.09, mode="exact", at=np.flatnonzero(mid)))
    assert np.nanmedian(small) < 0.1


def test_undefined_normals_are_nan_never_zero():
    isolated = np.array([[0.0, 0, 0], [10.0, 0, 0], [10.1, 0, 0], [20, 0, 0], [20, 0.1, 0], [20, 0, 0.1]])
    n = radius_normals(isolated, 0.5)
    assert np.isnan(n[:3]).all()  # one point, two points (collinear)
    assert np.isfinite(n[3:]).all()  # three non-collinear points define a plane
    line = np.column_stack([np.linspace(0, 1, 50), np.zeros(50), np.zeros(50)])
    assert np.isnan(radius_normals(line, 0.2)).all()
    d = difference_of_normals(isolated, 0.05, 0.5)
    assert np.isnan(d).all()  # the small ball holds one point everywhere
    assert not don_mask(d, 0.0).any()


@pytest.mark.parametrize("mode", ["exact", "fast"])
def test_results_do_not_depend_on_input_order(rng, mode):
    p, _ = pole_scene(rng, spacing=0.1)
    perm = rng.permutation(len(p))
    vp = [0, 0, 50]
    a = difference_of_normals(p, 0.25, 1.0, mode=mode, viewpoint=vp)
    b = difference_of_normals(p[perm], 0.25, 1.0, mode=mode, viewpoint=vp)
    assert np.array_equal(a[perm], b, equal_nan=True)  # bit-identical


@pytest.mark.parametrize("mode", ["exact", "fast"])
def test_a_region_with_its_halo_gives_the_whole_clouds_values(rng, mode):
    """The invariant the tiled stream relies on: a box plus a halo of halo_width gives bit-identical rows."""
    p, _ = pole_scene(rng, spacing=0.08)
    p = p + [770512.0, 6277530.0, 35.0]  # Lambert-93-sized, as in the stream's frames
    vp = np.array([770512.0, 6277530.0, 80.0])
    whole = difference_of_normals(p, 0.3, 1.0, mode=mode, viewpoint=vp)
    lo, hi = np.array([770510.0, 6277529.0, 0.0]), np.array([770513.0, 6277533.0, 100.0])
    w = halo_width(1.0, mode)
    near = np.all((p >= lo - w) & (p < hi + w), axis=1)
    inside = np.flatnonzero(np.all((p[near] >= lo) & (p[near] < hi), axis=1))
    part = difference_of_normals(p[near], 0.3, 1.0, mode=mode, viewpoint=vp, at=inside)
    assert np.array_equal(part, whole[np.flatnonzero(near)[inside]], equal_nan=True)


def test_fast_mode_agrees_with_exact_mode(rng):
    p, _ = pole_scene(rng, spacing=0.05)
    p = p + rng.normal(scale=0.005, size=p.shape)
    e = don_magnitude(difference_of_normals(p, 0.2, 2.0, mode="exact"))
    f = don_magnitude(difference_of_normals(p, 0.2, 2.0, mode="fast"))
    ok = np.isfinite(e) & np.isfinite(f)
    assert ok.mean() > 0.99
    assert spearmanr(e[ok], f[ok]).statistic > 0.95
    assert np.percentile(np.abs(e - f)[ok], 95) < 0.05


def test_euclidean_clusters_equal_connected_components(rng):
    p = rng.uniform(0, 5, (4000, 3)) * [1, 1, 0.3]
    tol = 0.18
    labels = euclidean_clusters(p, tol)
    pairs = cKDTree(p).query_pairs(tol, output_type="ndarray")
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(p), len(p)))
    k, ref = connected_components(g, directed=False)
    assert labels.max() == k
    # the same partition, numbered by first point
    _, first = np.unique(ref, return_index=True)
    order = np.argsort(first)
    renumber = np.empty(k, dtype=np.int64)
    renumber[order] = np.arange(1, k + 1)
    assert np.array_equal(labels, renumber[ref])


def test_clusters_by_hand():
    chain = np.array([[0, 0, 0], [0.19, 0, 0], [0.38, 0, 0], [0.57, 0, 0.0]])  # steps of 0.19
    assert euclidean_clusters(chain, 0.2).tolist() == [1, 1, 1, 1]
    assert euclidean_clusters(chain, 0.18).tolist() == [1, 2, 3, 4]
    two = np.vstack([chain, chain + [5, 0, 0]])
    assert euclidean_clusters(two[::-1], 0.2).tolist() == [1, 1, 1, 1, 2, 2, 2, 2]
    assert euclidean_clusters(two, 0.2, min_points=5).tolist() == [0] * 8
    mixed = np.vstack([chain, [[9, 9, 9]]])
    assert euclidean_clusters(mixed, 0.2, min_points=1, max_points=3).tolist() == [0, 0, 0, 0, 1]
    assert euclidean_clusters(np.zeros((0, 3)), 0.2).tolist() == []


@pytest.mark.parametrize("mode, share", [("exact", 0.95), ("fast", 0.93)])
def test_segment_don_isolates_the_pole(rng, mode, share):
    p, n_ground = pole_scene(rng, spacing=0.05)
    d = difference_of_normals(p, 0.2, 2.0, mode=mode)
    seg = segment_don(p, d, 0.25, 0.15, min_points=50)
    pole = np.arange(len(p)) >= n_ground
    # within r_l of the ground (above, the large ball holds only the pole and both normals are radial)
    ids, counts = np.unique(seg[pole & (p[:, 2] > 0.3) & (p[:, 2] < 1.8)], return_counts=True)
    main = ids[np.argmax(counts)]
    # the pole is one segment: all of it but a band near z = 1.3 m, where the large ball's normal turns from
    # horizontal to vertical and even the exact |DoN| goes from 0.14 to 0.97 within 10 cm (fast keeps 94 %)
    assert main > 0 and counts.max() / counts.sum() > share
    assert np.mean(seg[~pole & (np.hypot(p[:, 0], p[:, 1]) > 3)] == 0) == 1.0  # far ground is none


def test_axis_threshold_selects_one_component():
    d = np.array([[0.3, 0, 0], [0, 0, 0.3], [0.2, 0, 0.2]])
    assert don_mask(d, 0.25).tolist() == [True, True, True]
    assert don_mask(d, 0.25, axis="z", axis_threshold=0.15).tolist() == [False, True, True]


@pytest.mark.parametrize(
    "call, words",
    [
        (lambda p: difference_of_normals(p, 2.0, 0.2), "r_small must be smaller"),
        (lambda p: difference_of_normals(p, 0.5, 0.5), "r_small must be smaller"),
        (lambda p: difference_of_normals(p, -0.2, 2.0), "r_small must be a positive"),
        (lambda p: radius_normals(p, 0.0), "radius must be a positive"),
        (lambda p: radius_normals(p, float("nan")), "radius must be a positive"),
        (lambda p: radius_normals(p, 1.0, mode="approx"), "mode must be one of exact, fast"),
        (lambda p: radius_normals(p, 1.0, min_points=2), "min_points must be"),
        (lambda p: radius_normals(p, 1.0, resolution=0), "resolution must be"),
        (lambda p: radius_normals(p, 1.0, viewpoint=[0, 0]), "viewpoint must be"),
        (lambda p: radius_normals(p[:, :2], 1.0), "must be an (N, 3) array"),
        (lambda p: radius_normals(np.vstack([p, [[np.nan] * 3]]), 1.0), "NaN or infinite"),
        (lambda p: don_mask(np.zeros((3, 3)), 1.5), "threshold must be a DoN magnitude in [0, 1]"),
        (lambda p: don_mask(np.zeros((3, 3)), 0.2, axis="w", axis_threshold=0.1), "axis must be one of x, y, z"),
        (lambda p: don_mask(np.zeros((3, 3)), 0.2, axis="z"), "needs an axis_threshold"),
        (lambda p: euclidean_clusters(p, -1.0), "tolerance must be a positive"),
        (lambda p: euclidean_clusters(p, 0.2, min_points=0), "min_points must be"),
        (lambda p: euclidean_clusters(p, 0.2, min_points=5, max_points=2), "max_points must be"),
        (lambda p: segment_don(p, np.zeros((2, 3)), 0.2, 0.1), "don must have the shape"),
    ],
)
def test_bad_parameters_are_named(call, words):
    p = np.random.default_rng(0).uniform(size=(50, 3))
    with pytest.raises(PatchcloudValueError, match=words.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[").replace("]", r"\]")):
        call(p)


def test_points_a_voxel_holds_on_a_plane():
    # a plane on a 0.25 m grid (16 points/m²), in one layer of cells: 0.5 m voxels (r = 2 m) hold 4 points,
    # 0.25 m voxels (r = 1 m) 1, 1.25 m voxels (r = 5 m: cells of 1 m scaled by 1.25²) 25
    from patchcloud.core.radius import cell_density, voxel_points

    g = np.arange(0.0, 20.0, 0.25) + 0.125
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    plane = np.column_stack([x, y, np.full(x.size, 0.1)])
    for r, expected in ((2.0, 4.0), (1.0, 1.0), (5.0, 25.0)):
        assert voxel_points(r, 4, cell_density(plane, r / 4)) == expected


def test_fast_mode_sums_points_up_to_five_a_voxel(rng):
    """About 4.5 points a voxel (a plane of 18 points/m², r = 2 m, voxels of 0.5 m): the points are faster to sum than
    the voxels there (measured: 1.7-2x at 3.6-4.9 points a voxel), so fast mode takes the exact ball, bit for bit."""
    from patchcloud.core.radius import VOXEL_MIN_POINTS, cell_density, uses_voxels

    p = np.column_stack([rng.uniform(0, 20, (7200, 2)), 0.25 + rng.normal(0, 0.01, 7200)])  # in one layer of cells
    per_voxel = cell_density(p, 0.5)
    assert 3.0 < per_voxel < VOXEL_MIN_POINTS == 5.0
    assert not uses_voxels(2.0, 4, per_voxel)
    assert np.array_equal(radius_normals(p, 2.0, mode="fast"), radius_normals(p, 2.0, mode="exact"), equal_nan=True)


def test_fast_mode_sums_points_where_voxels_would_not_pay(rng):
    """Sparse for the radius (about one point per voxel): fast mode takes the exact ball, bit for bit."""
    p = rng.uniform(0, 20, (20000, 3)) * [1, 1, 0.05]
    from patchcloud.core.radius import cell_density, uses_voxels

    assert not uses_voxels(0.3, 4, cell_density(p, 0.075))
    assert np.array_equal(radius_normals(p, 0.3, mode="fast"), radius_normals(p, 0.3, mode="exact"), equal_nan=True)
    assert uses_voxels(3.0, 4, cell_density(p, 0.75))
    assert not np.array_equal(radius_normals(p, 3.0, mode="fast"), radius_normals(p, 3.0, mode="exact"), equal_nan=True)


def _wavy(rng, n=60_000, size=12.0):
    """A wavy surface (z = 0.4 sin x cos 0.7y) with a step of 0.5 m across x = 6: DoN varies at every scale."""
    xy = rng.uniform(0, size, (n, 2))
    z = 0.4 * np.sin(xy[:, 0]) * np.cos(0.7 * xy[:, 1]) + 0.5 * (xy[:, 0] > size / 2)
    return np.column_stack([xy, z])


def test_fast_ball_counts_match_exact_on_a_dense_plane(rng):
    """Voxels the sphere cuts count the share of their points within it (a voxel centre test is off by up to 9 % here)."""
    xy = rng.uniform(0, 20, (200_000, 2))
    p = np.column_stack([xy, rng.uniform(0, 0.01, len(xy))])
    at = np.flatnonzero((np.abs(xy - 10) < 8).all(axis=1))[::500]
    e = radius_moments(p, 1.0, mode="exact", at=at)
    f = radius_moments(p, 1.0, mode="fast", at=at)
    assert np.abs(f[:, 0] / e[:, 0] - 1).max() < 0.03
    assert np.abs(f[:, 1:4] / f[:, :1] - e[:, 1:4] / e[:, :1]).max() < 0.03  # mean offset, metres (radius 1 m)


def test_fast_don_agrees_with_exact_and_hardly_depends_on_the_origin(rng):
    p = _wavy(rng)
    vp = np.array([6.0, 6.0, 50.0])
    inner = (np.abs(p[:, :2] - 6) < 4.5).all(axis=1)
    ex = don_magnitude(difference_of_normals(p, 0.4, 1.5, viewpoint=vp, mode="exact"))[inner]
    fast = don_magnitude(difference_of_normals(p, 0.4, 1.5, viewpoint=vp, mode="fast"))[inner]
    shift = np.array([0.377, 0.613, 0.131]) * 1.5  # not a multiple of any voxel edge
    moved = don_magnitude(difference_of_normals(p + shift, 0.4, 1.5, viewpoint=vp + shift, mode="fast"))[inner]
    assert np.abs(ex).max() > 0.15  # the step and the waves give DoN worth comparing
    assert np.percentile(np.abs(fast - ex), 99) < 0.01  # a voxel centre test: 0.016
    assert np.percentile(np.abs(moved - fast), 99) < 0.01  # a voxel centre test: 0.023


@pytest.mark.parametrize("mode", ["exact", "fast"])
def test_a_line_rounded_to_its_step_is_still_a_line(rng, mode):
    """Points of a line stored to 1 cm lie up to half a step off it: their balls get a plane the rounding turned at
    will, unless the step is known (a LAS file's scale); then they are collinear, as without rounding."""
    t = np.sort(rng.uniform(0, 10, 400))
    line = np.round(np.column_stack([3.0 + 0.8 * t, 1.0 + 0.6 * t, 2.0 + 0.05 * t]), 2)
    assert np.isfinite(radius_normals(line, 0.3, mode=mode, rounding=0.0)).all(axis=1).mean() > 0.9  # the old answer
    assert np.isnan(radius_normals(line, 0.3, mode=mode, rounding=0.01)).all()
    plane = np.round(np.column_stack([rng.uniform(0, 10, (10000, 2)), np.zeros(10000)]) @ [[1, 0, 0.2], [0, 1, 0.1], [0, 0, 1]], 2)
    n = radius_normals(plane, 0.3, mode=mode, rounding=0.01)  # a plane keeps its normals: it spreads far more than 1 cm
    assert np.isfinite(n).all() and np.abs(n @ ([-0.2, -0.1, 1] / np.linalg.norm([-0.2, -0.1, 1]))).min() > 0.99


def test_the_rounding_of_a_lasdata_is_its_scale():
    import laspy

    h = laspy.LasHeader(point_format=6, version="1.4")
    h.scales, h.offsets = [0.01, 0.01, 0.001], [0.0, 0.0, 0.0]
    las = laspy.LasData(h)
    t = np.linspace(0, 10, 400)
    las.x, las.y, las.z = 3.0 + 0.8 * t, 1.0 + 0.6 * t, 2.0 + 0.05 * t
    assert np.isnan(radius_normals(las, 0.3)).all()  # the largest scale, 0.01
    assert np.isfinite(radius_normals(las, 0.3, rounding=0.0)).all(axis=1).mean() > 0.9
    assert np.isnan(difference_of_normals(las, 0.3, 1.0)).all()


@pytest.mark.parametrize("call, words", [
    (lambda p: radius_normals(p, 1.0, rounding=-0.01), "rounding must be a finite length of at least 0"),
    (lambda p: difference_of_normals(p, 0.5, 1.0, rounding=float("nan")), "rounding must be a finite length of at least 0"),
    (lambda p: radius_normals(p, 1.0, origin=[np.nan, 0, 0]), "origin must be three finite coordinates"),
    (lambda p: radius_normals(p.astype(complex), 1.0), "points must be real numbers, got dtype complex128"),
])
def test_bad_rounding_origin_and_complex_points_are_named(rng, call, words):
    with pytest.raises(PatchcloudValueError, match=words):
        call(rng.uniform(0, 5, (100, 3)))
