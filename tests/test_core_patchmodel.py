"""Patch models (patchcloud.core.patchmodel): fitting within an error budget, and sampling points back."""

import numpy as np
import pytest

from patchcloud.core import PatchcloudValueError
from patchcloud.core.patchmodel import dequantise_models, fit_models, quantise_models, sample_models


def sphere(rng, n=40000, radius=5.0, noise=0.0):
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1)[:, None] * (radius + noise * rng.normal(size=(n, 1)))


def box(rng, side=4.0, per_face=6000):
    faces = []
    for axis in range(3):
        for s in (0.0, side):
            q = rng.uniform(0, side, (per_face, 3))
            q[:, axis] = s
            faces.append(q)
    return np.vstack(faces)


def box_distance(q, side=4.0):
    inside = np.clip(q, 0, side)
    to_faces = np.minimum(inside, side - inside).min(axis=1)
    return np.linalg.norm(q - inside, axis=1) + to_faces


def test_plane_is_a_handful_of_patches_and_comes_back_on_the_plane(rng):
    xy = rng.uniform(0, 20, (30000, 2))
    p = np.column_stack([xy, 0.1 * xy[:, 0] + 3.0]) + [650000.0, 6860000.0, 0.0]  # UTM-sized
    fit = fit_models(p, 0.02)
    assert len(fit.models) <= 4 and fit.residual.size == 0
    assert int(fit.models.count.sum()) == len(p)
    q, k = sample_models(fit.models)
    assert q.shape == p.shape
    np.testing.assert_allclose(q[:, 2], 0.1 * (q[:, 0] - 650000.0) + 3.0, atol=1e-6)
    lo, hi = p.min(axis=0), p.max(axis=0)
    assert np.all((q >= lo - 1e-6) & (q <= hi + 1e-6))  # no point drawn outside the points' cells


def test_noisy_sphere_within_the_budget(rng):
    p = sphere(rng, noise=0.002)
    budget = 0.01
    fit = fit_models(p, budget)
    assert len(fit.models) < 100
    assert fit.residual.size / len(p) < 0.01
    assert np.abs(fit.error).mean() <= budget
    assert int(fit.models.count.sum()) + fit.residual.size == len(p)  # every point: a surface or itself
    q, _ = sample_models(fit.models)
    off = np.abs(np.linalg.norm(q, axis=1) - 5.0)
    assert off.mean() <= budget and np.percentile(off, 99) <= 3 * budget


def test_box_faces_come_back_on_the_box_and_edges_stay_points(rng):
    p = box(rng)
    budget = 0.01
    fit = fit_models(p, budget)
    q, _ = sample_models(fit.models)
    off = box_distance(q)
    # faces come back exact; a leaf holding a sliver of the next face bends its quadric a little
    assert np.median(off) < 1e-9 and off.mean() < budget / 10 and np.percentile(off, 99.9) < 3 * budget
    # the points along the edges, where no quadric fits, are residual: kept exactly as they were
    # (in the leaves along the edges: the smallest are 0.25 m here, a few 0.5 m)
    from_edge = np.sort(np.abs(p - np.round(p / 4.0) * 4.0), axis=1)[:, 1]
    assert fit.residual.size > 0 and np.percentile(from_edge[fit.residual], 99) < 0.25
    assert from_edge[fit.residual].max() <= 0.5
    assert np.all(fit.patch[fit.residual] == -1)
    assert int(fit.models.count.sum()) + fit.residual.size == len(p)


def test_outliers_of_a_surface_become_residual(rng):
    xy = rng.uniform(0, 10, (20000, 2))
    p = np.column_stack([xy, np.zeros(20000)])
    spikes = rng.choice(20000, 20, replace=False)
    p[spikes, 2] = 0.2  # 20 cm above a plane, with a 1 cm budget
    fit = fit_models(p, 0.01)
    assert set(spikes) <= set(fit.residual.tolist())
    assert np.abs(fit.error).max() <= 0.03


def test_sampling_any_density_and_determinism(rng):
    p = sphere(rng, n=20000)
    fit = fit_models(p, 0.01)
    q1, k1 = sample_models(fit.models, seed=3)
    q2, k2 = sample_models(fit.models, seed=3)
    assert np.array_equal(q1, q2) and np.array_equal(k1, k2)
    double, k = sample_models(fit.models, fit.models.count * 2)
    assert double.shape[0] == 2 * len(p) and np.array_equal(np.bincount(k), 2 * fit.models.count)
    none, _ = sample_models(fit.models, np.zeros(len(fit.models), dtype=np.int64))
    assert none.shape == (0, 3)


def test_models_do_not_depend_on_input_order(rng):
    p = sphere(rng, n=20000, noise=0.001)
    perm = rng.permutation(len(p))
    a, b = fit_models(p, 0.01), fit_models(p[perm], 0.01)
    for name in ("level", "ijk", "count", "centroid", "frame", "coeffs", "extent", "mask", "rmse"):
        assert np.array_equal(getattr(a.models, name), getattr(b.models, name)), name
    assert np.array_equal(a.patch[perm], b.patch)


@pytest.mark.parametrize("bad", [0.0, -0.01, float("nan"), "x"])
def test_bad_budget(rng, bad):
    with pytest.raises(PatchcloudValueError, match="max_error must be a positive number"):
        fit_models(rng.uniform(size=(100, 3)), bad)


def test_bad_counts(rng):
    fit = fit_models(sphere(rng, n=5000), 0.01)
    with pytest.raises(PatchcloudValueError, match="counts must be"):
        sample_models(fit.models, -fit.models.count)


def _off_surface(models, points, patch):
    """Distance along each patch's normal from points to the patch's quadric (metres)."""
    d = points - models.centroid[patch]
    u, v, w = np.einsum("nij,ni->nj", models.frame[patch], d).T
    c = models.coeffs[patch]
    return np.abs(w - (c[:, 0] * u * u + c[:, 1] * u * v + c[:, 2] * v * v + c[:, 3] * u + c[:, 4] * v + c[:, 5]))


@pytest.mark.parametrize("budget", [0.002, 0.01, 0.05])
def test_quantised_models_stay_within_half_the_budget(rng, budget):
    p = np.vstack([sphere(rng, n=20000, radius=3.0, noise=budget / 4), box(rng, per_face=3000) + 10.0])
    fit = fit_models(p, budget)
    q = quantise_models(fit.models, budget)
    back = dequantise_models(q)
    for name in ("level", "ijk", "count", "mask"):
        assert np.array_equal(getattr(back, name), getattr(fit.models, name))
    for name in ("centroid", "rotation", "coeffs", "extent"):
        assert getattr(q, name).dtype == np.int64
    pts, k = sample_models(back, seed=1)
    off = _off_surface(fit.models, pts, k)  # dequantised samples against the fitted surfaces
    assert off.max() <= budget / 2
    # the quantised extents hold the fitted ones
    assert np.all(back.extent[:, [0, 2]] <= fit.models.extent[:, [0, 2]] + 1e-12)
    assert np.all(back.extent[:, [1, 3]] >= fit.models.extent[:, [1, 3]] - 1e-12)
