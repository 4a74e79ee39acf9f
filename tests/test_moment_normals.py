"""Normals from cell moments interpolated at the point (patchcloud.core.moment_normals, NormalMethod 4)."""

import numpy as np
import pytest

from patchcloud.core import Method, estimate_normals
from patchcloud.core.moment_normals import MIN_POINTS, moment_normals


def brute_force(points, q, edge, votes):
    """The trilinearly weighted PCA at ``q`` over the 8 cells of ``edge`` around it, point by point."""
    cell = np.floor(points / edge).astype(np.int64)
    f = q / edge - 0.5
    base = np.floor(f).astype(np.int64)
    t = f - base
    w = np.ones(len(points))
    for a in range(3):
        lo, hi = cell[:, a] == base[a], cell[:, a] == base[a] + 1
        w *= np.where(lo, 1.0 - t[a], np.where(hi, t[a], 0.0))
    used = w > 0
    W = w.sum()
    mean = (w[:, None] * points).sum(axis=0) / W
    d = points - mean
    cov = np.einsum("n,ni,nj->ij", w, d, d) / W
    ev, vec = np.linalg.eigh(cov)
    ev = np.maximum(ev, 0.0)
    n = vec[:, 0] * (1.0 if vec[:, 0] @ [1e-3, 1e-2, 1.0] >= 0 else -1.0)
    tot = ev.sum() if ev.sum() > 0 else 1.0
    return n, ev[0] / tot, ev[1] / tot, int(used.sum()), (w[:, None] * votes).sum(axis=0)


def test_interpolated_moments_equal_a_point_by_point_weighted_pca():
    rng = np.random.default_rng(1)
    xy = rng.uniform(0, 6, (3000, 2))
    pts = np.column_stack([xy, 0.3 * xy[:, 0] + 0.1 * np.sin(3 * xy[:, 1]) + rng.normal(0, 0.05, len(xy))])
    pts = np.concatenate([pts, rng.uniform(0, 6, (500, 3))])  # clutter: flatness decides the scale
    votes = rng.normal(size=(len(pts), 3))
    voters = rng.uniform(size=len(pts)) < 0.5
    query = rng.choice(len(pts), 60, replace=False)
    h = 1.0
    res = moment_normals(pts, query, h, min_sigma2=0.01, votes=votes, voters=voters)
    for m, i in enumerate(query):
        best = None
        for edge in (0.5 * h, h):
            n, s3, s2, used, v = brute_force(pts, pts[i], edge, votes * voters[:, None])
            if used >= MIN_POINTS and s2 >= 0.01 and (best is None or s3 < best[1]):
                best = (n, s3, v, edge == h)
        assert res.defined[m] == (best is not None)
        if best is None:
            continue
        n, s3, v, coarse = best
        assert res.coarse[m] == coarse
        assert np.allclose(res.normal[m], n, atol=1e-7)
        assert res.sigma3[m] == pytest.approx(s3, abs=1e-9)
        assert np.allclose(res.votes[m], v, atol=1e-9)
        assert abs(res.dir1[m] @ res.normal[m]) < 1e-9


def test_a_plane_gives_its_normal_and_a_line_gives_none():
    rng = np.random.default_rng(2)
    xy = rng.uniform(0, 10, (5000, 2))
    n = np.array([0.2, -0.3, 1.0]) / np.linalg.norm([0.2, -0.3, 1.0])
    pts = np.column_stack([xy, -(n[0] * xy[:, 0] + n[1] * xy[:, 1]) / n[2]]) + 5.0
    line = np.column_stack([np.linspace(0, 10, 400), np.full(400, 30.0), np.full(400, 30.0)])
    res = moment_normals(np.concatenate([pts, line]), np.arange(5400), 0.8, min_sigma2=0.01)
    assert res.defined[:5000].all() and not res.defined[5000:].any()  # a 3D curve has no normal
    assert np.allclose(res.normal[:5000], n, atol=1e-9)
    assert np.all(res.sigma3[:5000] < 1e-12)


def test_a_query_gets_the_same_answer_whatever_the_queries_before_it():
    # a curved wall queried column by column (consecutive queries one cell apart along z only, then along y), in
    # shuffled order, and one at a time: every answer is the same array, bit for bit
    rng = np.random.default_rng(4)
    y, z = rng.uniform(0, 6, 3000), rng.uniform(0, 6, 3000)
    pts = np.column_stack([0.3 + 0.05 * np.sin(y) * np.cos(z), y, z])
    by_column = np.lexsort((z, y))
    shuffled = rng.permutation(3000)
    a = moment_normals(pts, by_column, 0.5, min_sigma2=0.01)
    b = moment_normals(pts, shuffled, 0.5, min_sigma2=0.01)
    back = np.argsort(shuffled)[by_column]
    assert a.defined.sum() > 2900
    for name in ("defined", "normal", "sigma3", "dir1", "coarse"):
        assert np.array_equal(getattr(a, name), getattr(b, name)[back]), name
    for i in (0, 1500, 2999):
        one = moment_normals(pts, by_column[i : i + 1], 0.5, min_sigma2=0.01)
        assert np.array_equal(one.normal[0], a.normal[i])


def test_too_few_points_give_no_normal():
    pts = np.array([[0.1, 0.1, 0.1], [0.3, 0.2, 0.1], [0.2, 0.4, 0.3], [50.0, 50.0, 50.0]])
    res = moment_normals(pts, np.arange(4), 1.0, min_sigma2=0.01)
    assert not res.defined.any() and MIN_POINTS == 4


def test_a_tile_with_its_skin_gives_the_whole_cloud_moments():
    """Cells anchored at the corner reach at most 1.5 h beyond a point: a skin of 1.5 h is enough."""
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(0, 16, (20000, 2)), rng.uniform(0, 2, 20000)])  # a volume: every scale counts
    h = 1.0
    tile = np.all((pts[:, :2] >= 8.0) & (pts[:, :2] < 16.0), axis=1)
    skin = ~tile & np.all((pts[:, :2] >= 8.0 - 1.5 * h), axis=1)
    whole = moment_normals(pts, np.flatnonzero(tile), h, min_sigma2=0.0)
    part = pts[tile | skin]
    local = moment_normals(part, np.flatnonzero(tile[tile | skin]), h, min_sigma2=0.0)
    assert np.array_equal(whole.coarse, local.coarse)
    assert np.allclose(whole.normal, local.normal, atol=1e-9)
    short = ~tile & np.all((pts[:, :2] >= 8.0 - 0.7 * h), axis=1)  # a thinner skin changes the points at the faces
    part = pts[tile | short]
    thin = moment_normals(part, np.flatnonzero(tile[tile | short]), h, min_sigma2=0.0)
    assert not np.allclose(whole.normal, thin.normal, atol=1e-9)


def test_a_tree_on_a_noisy_plane_gets_moment_normals_not_knn():
    rng = np.random.default_rng(4)
    xy = rng.uniform(0, 30, (40000, 2))
    ground = np.column_stack([xy, rng.normal(0, 0.01, len(xy))])
    d = rng.normal(size=(3000, 3))
    crown = [15.0, 15.0, 5.0] + d * (2.5 * rng.uniform(0, 1, 3000) ** (1 / 3) / np.linalg.norm(d, axis=1))[:, None]
    trunk = np.column_stack([15.0 + rng.normal(0, 0.15, 300), 15.0 + rng.normal(0, 0.15, 300), rng.uniform(0, 3, 300)])
    res = estimate_normals(np.concatenate([ground, crown, trunk]), orient="up")
    tree = res.method[len(ground):]
    assert np.mean(tree == Method.MOMENTS) > 0.95
    assert np.mean(tree == Method.KNN) < 0.01
    assert np.mean(res.method == Method.KNN) < 0.001
    # the ground keeps its normals, right up to the trunk
    up = res.normals[: len(ground), 2]
    assert np.percentile(up, 1) > np.cos(np.radians(3.0))
    # oriented towards the ground's normals where they are not nearly perpendicular, else by the rule: up
    assert np.all(res.normals[len(ground):, 2] >= 0)
