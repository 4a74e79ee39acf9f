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


@pytest.mark.parametrize("budget", [0.002, 0.01])
def test_box_is_six_patches_that_come_back_on_the_box(rng, budget):
    p = box(rng)
    fit = fit_models(p, budget)
    m = fit.models
    # one patch per face: the leaves of a face merge, and the leaves along the edges give
    # each point to the face it lies on
    assert len(m) == 6 and fit.residual.size == 0
    normals = np.abs(m.frame[:, :, 2])
    assert np.all(normals.max(axis=1) > 1 - 1e-9)
    assert sorted(np.argmax(normals, axis=1).tolist()) == [0, 0, 1, 1, 2, 2]
    np.testing.assert_array_equal(np.sort(m.patch_count), np.sort(np.bincount(fit.patch, minlength=6)))
    assert int(m.count.sum()) == len(p) and np.all(fit.patch >= 0)
    q, _ = sample_models(m)
    assert box_distance(q).max() < 1e-9  # faces come back exact
    # and where the points were: every sample within a cell of a face point
    assert np.all((q >= -1e-9) & (q <= 4.0 + 1e-9))


def test_wider_budget_merges_more_and_keeps_its_promise(rng):
    p = sphere(rng, n=30000)
    fits = {b: fit_models(p, b) for b in (0.002, 0.01, 0.05)}
    sizes = [len(fits[b].models) for b in (0.002, 0.01, 0.05)]
    assert sizes[0] > sizes[1] > sizes[2] and sizes[2] <= 10  # a handful
    for b, fit in fits.items():
        assert np.sqrt(np.mean(fit.error[fit.patch >= 0] ** 2)) <= b
        assert np.all(fit.models.rmse <= b)
        assert fit.residual.size / len(p) < 0.01
    unmerged = fit_models(p, 0.01, merge=False)
    assert len(unmerged.models) > 1.5 * len(fits[0.01].models)


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
    kept = int(fit.models.count.sum())
    assert kept + fit.residual.size == len(p) and kept > 0.99 * len(p)
    assert double.shape[0] == 2 * kept and np.array_equal(np.bincount(k), 2 * fit.models.count)
    none, _ = sample_models(fit.models, np.zeros(fit.models.count.size, dtype=np.int64))
    assert none.shape == (0, 3)


def test_models_do_not_depend_on_input_order(rng):
    p = sphere(rng, n=20000, noise=0.001)
    perm = rng.permutation(len(p))
    a, b = fit_models(p, 0.01), fit_models(p[perm], 0.01)
    for name in ("centroid", "frame", "coeffs", "rmse", "cells", "level", "ijk", "count", "extent", "mask"):
        assert np.array_equal(getattr(a.models, name), getattr(b.models, name)), name
    assert np.array_equal(a.patch[perm], b.patch) and np.array_equal(a.cell[perm], b.cell)


@pytest.mark.parametrize("bad", [0.0, -0.01, float("nan"), "x"])
def test_bad_budget(rng, bad):
    with pytest.raises(PatchcloudValueError, match="max_error must be a positive length"):
        fit_models(rng.uniform(size=(100, 3)), bad)


def test_bad_counts(rng):
    fit = fit_models(sphere(rng, n=5000), 0.01)
    with pytest.raises(PatchcloudValueError, match="counts must be"):
        sample_models(fit.models, -fit.models.count)


def _off_surface(models, points, cell):
    """Distance along each patch's normal from points (sampled from ``cell``) to the patch's quadric (metres)."""
    patch = models.cell_patch[cell]
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
    for name in ("cells", "level", "ijk", "count", "mask"):
        assert np.array_equal(getattr(back, name), getattr(fit.models, name))
    for name in ("centroid", "rotation", "coeffs", "extent"):
        assert getattr(q, name).dtype == np.int64
    pts, k = sample_models(back, seed=1)
    off = _off_surface(fit.models, pts, k)  # dequantised samples against the fitted surfaces
    assert off.max() <= budget / 2
    # the quantised extents hold the fitted ones
    assert np.all(back.extent[:, [0, 2]] <= fit.models.extent[:, [0, 2]] + 1e-12)
    assert np.all(back.extent[:, [1, 3]] >= fit.models.extent[:, [1, 3]] - 1e-12)


def test_a_leaf_is_split_between_patches_only_where_its_majority_patch_does_not_fit(rng):
    from patchcloud.core.quadric import implicit_value

    p = sphere(rng, n=30000, noise=0.001)
    budget = 0.01
    fit = fit_models(p, budget)
    m = fit.models
    leaf = np.unique(np.column_stack([m.level, m.ijk]), axis=0, return_inverse=True)[1].ravel()  # leaf of each cell
    patch = m.cell_patch
    assert leaf.max() + 1 < m.count.size  # some leaves are split: the check below is not empty
    # the majority cell of each leaf: most points, then the lowest patch
    order = np.lexsort((patch, -m.count, leaf))
    first = np.unique(leaf[order], return_index=True)[1]
    major = patch[order][first]  # leaf k's majority patch (leaves numbered 0.. by np.unique)
    on = fit.cell >= 0
    others = np.flatnonzero(on)[patch[fit.cell[on]] != major[leaf[fit.cell[on]]]]
    g = major[leaf[fit.cell[others]]]
    off = np.abs(implicit_value(p[others], m.centroid[g], m.frame[g], m.coeffs[g]))
    assert others.size > 0 and np.all(off > budget)


def _sample_models_numpy(models, seed=0):
    """sample_models as it was written in numpy (before its draws were compiled), the frame turned by explicit sums in
    axis order (numpy's einsum summed them in another order: 1e-16 m apart, the same LAS integers): the reference."""
    from patchcloud.core.patchmodel import MASK_SIDE, MAX_DRAWS

    C = models.count.shape[0]
    k = np.repeat(np.arange(C), models.count)
    rng = np.random.default_rng(seed)
    bits = models.mask_bits()
    occupied = bits.sum(axis=1)
    cell_order = np.argsort(~bits, axis=1, kind="stable")
    edge, lo, patch = models.edge, models.cell_corner(), models.cell_patch
    pts = np.empty((k.size, 3))
    todo = np.arange(k.size)
    for _ in range(MAX_DRAWS):
        kk = k[todo]
        pk = patch[kk]
        r = rng.random((todo.size, 3))
        pick = np.minimum((r[:, 0] * occupied[kk]).astype(np.int64), np.maximum(occupied[kk] - 1, 0))
        cell = cell_order[kk, pick]
        e = models.extent[kk]
        u = e[:, 0] + (cell // MASK_SIDE + r[:, 1]) * (e[:, 1] - e[:, 0]) / MASK_SIDE
        v = e[:, 2] + (cell % MASK_SIDE + r[:, 2]) * (e[:, 3] - e[:, 2]) / MASK_SIDE
        c = models.coeffs[pk]
        w = c[:, 0] * u * u + c[:, 1] * u * v + c[:, 2] * v * v + c[:, 3] * u + c[:, 4] * v + c[:, 5]
        f = models.frame[pk]
        pts[todo] = models.centroid[pk] + (f[:, :, 0] * u[:, None] + f[:, :, 1] * v[:, None] + f[:, :, 2] * w[:, None])
        outside = np.any((pts[todo] < lo[kk]) | (pts[todo] > lo[kk] + edge[kk, None]), axis=1)
        todo = todo[outside]
        if todo.size == 0:
            break
    return pts, k


@pytest.mark.parametrize("seed", [0, 7])
def test_compiled_draws_are_the_numpy_definition_bit_for_bit(rng, seed):
    p = np.vstack([sphere(rng, n=20000, noise=0.003), box(rng, per_face=3000) + 20.0])
    models = dequantise_models(quantise_models(fit_models(p, 0.01).models, 0.01))
    got, k = sample_models(models, seed=seed)
    want, k0 = _sample_models_numpy(models, seed=seed)
    assert np.array_equal(k, k0) and np.array_equal(got, want)
