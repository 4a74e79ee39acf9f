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


@pytest.mark.parametrize("bend, surface", [(0.2, True), (2.5, False)])
def test_a_leaf_whose_quadric_folds_over_its_points_is_no_surface(rng, bend, surface):
    """A leaf's quadric must stay within 60 degrees of its frame normal at its points (slope**2 <= 3): z = bend * x**2
    over [-0.5, 0.5]**2 fits exactly, but with bend 2.5 its slope at the sides is 2.5 (68 degrees): an edge leaf, not a
    surface whose normals fold."""
    from patchcloud.core.octree import MAX_SLOPE2, build_octree

    xy = rng.uniform(-0.5, 0.5, (400, 2))
    pts = np.column_stack([xy, bend * xy[:, 0] ** 2]) + 1.0  # inside the root cube [0, 2]**3
    tree = build_octree(pts, 2.0, criterion="rmse", threshold=0.05, d_min=2.0, n_min=12, min_sigma2=0.01, spacing=0.05)
    assert tree.level.tolist() == [0] and tree.fit.rmse[0] < 0.05  # one leaf, within the threshold
    assert (4 * bend * bend * 0.25 > MAX_SLOPE2) == (not surface)
    assert tree.kind.tolist() == [PatchKind.SURFACE if surface else PatchKind.EDGE]


def test_real_ground_and_roofs_get_no_folded_quadric_normals():
    """house.laz with a threshold of 0.14 m: before the fold check 20 ground and roof points took a downward normal
    (NormalZ < -0.5) from their own folded quadric (patches of 13-17 points whose frame normal was nearly horizontal)."""
    import laspy

    from conftest import shared_file

    path = shared_file("lidar-lastools/house.laz")
    las = laspy.read(str(path))
    keep = (np.asarray(las.classification) != 7) & ~np.asarray(las.withheld, bool)
    cls = np.asarray(las.classification)[keep]
    res = estimate_normals(np.column_stack([las.x, las.y, las.z])[keep], threshold=0.14, root="grid")
    own = res.method == Method.QUADRIC
    assert own.sum() > 5000
    assert not (own & np.isin(cls, [2, 6]) & (res.normals[:, 2] < -0.5)).any()
