"""Normals and curvature on analytic surfaces with exact answers."""

import numpy as np
import pytest

import synthetic
from conftest import angles_deg
from patchcloud.core import Method, PatchKind, estimate_normals

CRITERIA = ["rmse", "sigma3"]


@pytest.mark.parametrize("criterion", CRITERIA)
def test_plane_normals_are_exact_and_up(rng, criterion):
    p, n = synthetic.plane(rng, 20000, size=10.0, tilt=(0.2, -0.1))
    res = estimate_normals(p, criterion=criterion)
    assert res.normals.dtype == np.float32 and res.normals.shape == p.shape
    ang = angles_deg(res.normals, n, signed=True)
    assert np.max(ang) < 0.01  # noise-free plane: exact, and oriented up
    assert np.all(np.abs(res.k1) < 1e-6) and np.all(np.abs(res.k2) < 1e-6)
    assert np.all(res.curvature < 1e-9)
    assert np.all(res.method != Method.KNN)


@pytest.mark.parametrize("criterion", CRITERIA)
def test_sphere_normals_curvature_and_outward(rng, criterion):
    R = 2.0
    p, n = synthetic.sphere(rng, 40000, radius=R, centre=(3.0, -1.0, 0.5))
    res = estimate_normals(p, criterion=criterion, orient="outward")
    ang = angles_deg(res.normals, n)
    assert np.median(ang) < 1.0
    cos = np.einsum("ij,ij->i", res.normals, n)
    assert np.mean(cos > 0) >= 0.995
    H = np.median(res.mean_curvature)
    assert abs(H - 1 / R) < 0.1 / R
    assert abs(np.median(res.k1) - 1 / R) < 0.1 / R and abs(np.median(res.k2) - 1 / R) < 0.1 / R


def test_sphere_with_noise(rng):
    R = 1.0
    p, n = synthetic.sphere(rng, 40000, radius=R, noise=0.003)
    res = estimate_normals(p, orient="outward")
    ang = angles_deg(res.normals, n)
    assert np.median(ang) < 2.0
    assert np.mean(np.einsum("ij,ij->i", res.normals, n) > 0) >= 0.995
    assert abs(np.median(res.mean_curvature) - 1 / R) < 0.1 / R


def test_cylinder_principal_curvatures_and_directions(rng):
    R = 0.5
    p, n = synthetic.cylinder(rng, 30000, radius=R, height=3.0)
    res = estimate_normals(p, orient="outward")
    assert np.median(angles_deg(res.normals, n)) < 1.0
    assert abs(np.median(res.k1) - 1 / R) < 0.1 / R
    assert abs(np.median(res.k2)) < 0.05 / R
    # the direction of k1 is horizontal (around the axis), k2 along the axis
    assert np.median(np.abs(res.dir1[:, 2])) < 0.05


def test_paraboloid_curvature_at_apex(rng):
    a, b = 0.5, 0.25
    p, n = synthetic.paraboloid(rng, 40000, size=1.0, a=a, b=b)
    res = estimate_normals(p)
    assert np.median(angles_deg(res.normals, n)) < 1.0
    near = np.linalg.norm(p[:, :2], axis=1) < 0.1
    # seen from above (normals up) the bowl is concave: curvatures -2b >= ... >= -2a
    assert abs(np.median(res.k1[near]) + 2 * b) < 0.1 * 2 * b
    assert abs(np.median(res.k2[near]) + 2 * a) < 0.1 * 2 * a


@pytest.mark.parametrize("criterion", CRITERIA)
def test_torus_outward(rng, criterion):
    p, n = synthetic.torus(rng, 60000, major=2.0, minor=0.6)
    res = estimate_normals(p, criterion=criterion, orient="outward")
    assert np.median(angles_deg(res.normals, n)) < 1.0
    assert np.mean(np.einsum("ij,ij->i", res.normals, n) > 0) >= 0.995


def test_terrain_up(rng):
    xy = rng.uniform(0, 60, (50000, 2))
    z = 2.0 * np.sin(xy[:, 0] / 7.0) + 1.5 * np.cos(xy[:, 1] / 5.0)
    gx = 2.0 / 7.0 * np.cos(xy[:, 0] / 7.0)
    gy = -1.5 / 5.0 * np.sin(xy[:, 1] / 5.0)
    n = np.column_stack([-gx, -gy, np.ones_like(gx)])
    p = np.column_stack([xy, z]) + rng.normal(scale=0.01, size=(len(z), 3))
    res = estimate_normals(p)
    assert np.mean(res.normals[:, 2] > 0) >= 0.995
    assert np.median(angles_deg(res.normals, n)) < 2.0


def test_box_sharp_edges_every_point_has_a_normal(rng):
    p, n = synthetic.box(rng, 40000, size=(2.0, 3.0, 1.5))
    res = estimate_normals(p, orient="outward")
    assert np.all(np.isfinite(res.normals))
    assert np.allclose(np.linalg.norm(res.normals, axis=1), 1.0, atol=1e-5)
    ang = angles_deg(res.normals, n)
    assert np.median(ang) < 1.0
    # points along the sharp edges live in edge leaves and get moment normals
    assert np.any(res.method == Method.MOMENTS)
    assert np.any(res.patches.kind == PatchKind.EDGE)
    # away from the edges the faces are exact
    half = np.array([1.0, 1.5, 0.75])
    inner = np.sum(np.abs(np.abs(p) - half) < 0.15, axis=1) <= 1
    assert np.percentile(ang[inner], 99) < 1.0
    assert np.mean(np.einsum("ij,ij->i", res.normals, n) > 0) >= 0.99


def test_noisy_plane(rng):
    p, n = synthetic.plane(rng, 30000, size=20.0, noise=0.01)
    res = estimate_normals(p)
    assert np.median(angles_deg(res.normals, n)) < 1.0
    assert np.all(res.normals[:, 2] > 0)


def test_principal_curvatures_stay_ordered_for_every_method(rng):
    # a box: edge points get moment normals, about half of which are turned by orientation
    p, _ = synthetic.box(rng, 30000, size=(2.0, 3.0, 1.5), noise=0.002)
    res = estimate_normals(p, orient="outward")
    assert np.any(res.method == Method.MOMENTS)
    assert np.all(res.k1 >= res.k2)
    # dir1 is tangent: orthogonal to the normal
    assert np.max(np.abs(np.einsum("ij,ij->i", res.dir1, res.normals))) < 1e-3


@pytest.mark.parametrize("bend", [0.2, 2.5])
def test_points_where_the_quadric_folds_get_moment_normals(rng, bend):
    """z = bend * x**2 over [-0.5, 0.5]**2 in one leaf, its quadric exact: its normal is within 60 degrees of the frame
    normal (z) where |slope| = 2 bend |x| <= sqrt(3); beyond (bend 2.5: |x| > 0.346) the quadric folds over the points
    and they get moment normals (or k-NN ones), the others keep the quadric's, exact."""
    from patchcloud.core.tiles import FOLD_MIN_COS

    xy = rng.uniform(-0.5, 0.5, (4000, 2))
    pts = np.column_stack([xy, bend * xy[:, 0] ** 2])
    res = estimate_normals(pts, d_min=4.0, threshold=0.05, blend=False, root=((-2.0, -2.0, -2.0), 4.0))
    assert len(res.patches.count) == 1 and res.patches.kind[0] == PatchKind.SURFACE  # one leaf, a surface
    slope, limit = 2 * bend * np.abs(xy[:, 0]), np.sqrt(1 / FOLD_MIN_COS**2 - 1)  # (the PCA frame is z to within a degree)
    steep = slope > limit
    assert steep.any() == (bend > 1)
    sure = np.abs(slope - limit) > 0.05
    np.testing.assert_array_equal((res.method == Method.QUADRIC)[sure], ~steep[sure])
    if bend < 1:  # the gentle one: its quadric exact, every normal
        exact = np.column_stack([-2 * bend * xy[:, 0], np.zeros(len(xy)), np.ones(len(xy))])
        assert np.max(angles_deg(res.normals, exact / np.linalg.norm(exact, axis=1)[:, None])) < 0.05


def test_real_ground_gets_no_folded_quadric_normals():
    """house.laz with a threshold of 0.14 m: 53 ground points took a downward normal (NormalZ < -0.5), 20 of them from
    their own folded quadric (patches of 13-17 points whose frame normal was nearly horizontal), the others oriented by
    those; now none."""
    import laspy

    from conftest import shared_file

    las = laspy.read(str(shared_file("lidar-lastools/house.laz")))
    keep = (np.asarray(las.classification) != 7) & ~np.asarray(las.withheld, bool)
    cls = np.asarray(las.classification)[keep]
    res = estimate_normals(np.column_stack([las.x, las.y, las.z])[keep], threshold=0.14, root="grid")
    assert (res.method == Method.QUADRIC).sum() > 5000 and (cls == 2).sum() > 10000
    assert not ((cls == 2) & (res.normals[:, 2] < -0.5)).any()
