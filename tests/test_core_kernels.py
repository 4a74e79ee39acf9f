"""The compiled kernels against their numpy references."""

import pytest
import numpy as np

from patchcloud.core import _kernels
from patchcloud.core.fallback import knn_normals
from patchcloud.core.moments import EXPONENTS, point_moments
from patchcloud.core.morton import encode, quantize


def test_cell_moments_match_numpy(rng):
    p = rng.normal(size=(5000, 3))
    starts = np.array([0, 7, 1000, 1001, 4000])
    centres = rng.normal(size=(5, 3))
    counts = np.diff(np.r_[starts, 5000])
    ref = point_moments(p - np.repeat(centres, counts, axis=0), starts)
    out = np.empty((5, len(EXPONENTS)))
    _kernels.cell_moments(p, starts, centres, out)
    assert np.allclose(out, ref, rtol=1e-12, atol=1e-9)


def test_box_cell_stats_equal_the_cell_moments_and_run_sums_bit_for_bit(rng):
    # points in cells of 0.5 m keyed row-major in a box; some points outside it
    p = rng.uniform(-1.0, 3.0, (4000, 3))
    w = rng.normal(size=(4000, 3))
    edge, lo, span = 0.5, np.array([-1, -2, 0]), np.array([6, 7, 5])
    keys = np.empty(4000, dtype=np.int64)
    _kernels.box_cell_keys(p, edge, lo, span, keys)
    inside = np.flatnonzero(keys >= 0)
    assert 0 < inside.size < 4000
    order = np.argsort(keys[inside], kind="stable")
    rows, keys = inside[order], keys[inside][order]
    starts = _kernels.run_starts(keys)
    assert np.array_equal(starts, np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]]))
    ckeys = keys[starts]
    cxyz = np.stack([ckeys // (span[1] * span[2]), (ckeys // span[2]) % span[1], ckeys % span[2]], axis=1) + lo
    assert np.array_equal(np.floor(p[rows[starts]] / edge).astype(np.int64), cxyz)  # each run is its cell
    cmom, cvotes = np.empty((starts.size, 10)), np.empty((starts.size, 3))
    voters = rng.random(4000) < 0.7  # votes counted where voters only
    _kernels.box_cell_stats(p, w, voters, rows, starts, ckeys, edge, lo, span, cmom, cvotes)
    ref = np.empty((starts.size, len(EXPONENTS)))
    _kernels.cell_moments(p[rows], starts, (cxyz + 0.5) * edge, ref)
    ref = ref[:, :10]
    ref_votes = np.zeros((starts.size, 3))
    for c, (lo_, hi_) in enumerate(zip(starts, np.r_[starts[1:], rows.size])):
        for i in rows[lo_:hi_]:  # in order, one addition at a time, as the kernel sums
            ref_votes[c] += w[i] if voters[i] else 0.0
    assert np.array_equal(cmom, ref) and np.array_equal(cvotes, ref_votes)
    assert _kernels.run_starts(np.zeros(0, dtype=np.int64)).size == 0


def test_morton_keys_match_numpy(rng):
    p = rng.uniform(-5, 5, (10000, 3))
    corner, edge = np.array([-5.0, -5.0, -5.0]), 10.0
    q = np.empty((10000, 3), dtype=np.int64)
    keys = np.empty(10000, dtype=np.uint64)
    _kernels.morton_keys(p, corner, edge, q, keys)
    assert np.array_equal(q, quantize(p - corner, edge))
    assert np.array_equal(keys, encode(q))


def test_knn_pca_matches_a_direct_pca(rng):
    # a noisy paraboloid: compare with numpy PCA of the same neighbourhoods
    xy = rng.uniform(-1, 1, (3000, 2))
    p = np.column_stack([xy, 0.3 * xy[:, 0] ** 2 + 0.001 * rng.normal(size=3000)])
    query = np.arange(0, 3000, 7)
    normals, sigma3, k1, k2, dir1, nb = knn_normals(p, query, 20)
    from scipy.spatial import cKDTree

    _, ref_nb = cKDTree(p).query(p[query], k=20)
    assert np.array_equal(np.sort(nb, axis=1), np.sort(ref_nb, axis=1))
    q = p[ref_nb] - p[ref_nb].mean(axis=1)[:, None, :]
    w, v = np.linalg.eigh(np.einsum("mki,mkj->mij", q, q) / 20)
    assert np.allclose(np.abs(np.einsum("ij,ij->i", normals, v[:, :, 0])), 1.0, atol=1e-9)
    assert np.allclose(sigma3, w[:, 0] / w.sum(axis=1), atol=1e-12)
    # the neighbourhood quadric sees the paraboloid's curvature 2a = 0.6 along x
    assert abs(np.median(np.maximum(np.abs(k1), np.abs(k2))) - 0.6) < 0.1


@pytest.mark.parametrize("lone", [3, 1500])
def test_grid_knn_equals_whole_cloud_knn(rng, lone):
    # isolated points far from the rest force the widening search (1,500: more than the cells around them are searched for)
    p = np.concatenate([rng.uniform(0, 1, (4000, 3)), rng.uniform(2, 7.9, (lone, 3))])
    from patchcloud.core.octree import sort_points

    order, keys, q = sort_points(p, np.zeros(3), 8.0)
    ps = p[order]
    rank = np.argsort(order)  # where each point of p went
    # the lone points (every third of the 1,500) and some of the dense ones: at most a tenth of the cloud, or
    # knn_normals searches the whole cloud and the grid is not used
    query = np.sort(np.r_[rank[4000::1 if lone < 100 else 3], rank[:4000:100]])
    assert query.size <= len(ps) // 10
    a = knn_normals(ps, query, 10, grid=(q, keys, 5, 8.0 / 32))[5]
    b = knn_normals(ps, query, 10)[5]
    assert np.array_equal(a, b)  # nearest first, ties by index


@pytest.mark.parametrize("near", [0.02, 0.3, 5.0])
def test_knn_near_the_queries_equals_whole_cloud_knn(rng, near):
    # a few queries among many points (the k-NN fallback of a tile with its skin), some isolated so the search widens,
    # points on a grid so that many neighbours tie in distance (ties go to the smaller index in both searches)
    g = np.arange(0.0, 2.0, 0.02)
    flat = np.column_stack([a.ravel() for a in np.meshgrid(g, g, [0.0])])
    p = np.concatenate([flat, rng.uniform(0, 2, (5000, 3)), rng.uniform(5, 6, (3, 3)), [[40.0, 40.0, 40.0]]])
    query = np.r_[np.arange(0, 10000, 997), 7000, len(p) - 4, len(p) - 1]
    whole = knn_normals(p, query, 12)
    near_only = knn_normals(p, query, 12, near=near)
    for a, b in zip(whole, near_only):
        assert np.array_equal(a, b)


def test_knn_near_the_queries_widens_past_a_nearer_looking_corner():
    # the query's 12th neighbour (0.35 m along x) lies outside the box searched first (0.3 m each way), while a farther
    # point (0.50 m, on the box's diagonal) lies inside it: the search must widen, not take the diagonal point
    p = np.array([[0.001 * i, 0.0, 0.0] for i in range(11)] + [[0.35, 0.0, 0.0], [0.29, 0.29, 0.29]]
                 + [[3.0 + 0.01 * i, 3.0, 3.0] for i in range(200)])
    nb = knn_normals(p, np.array([0]), 12, near=0.3)[5]
    assert sorted(nb[0].tolist()) == list(range(12))


def test_level_occupancy_counts_the_distinct_cells_of_every_level(rng):
    from patchcloud.core import MAX_DEPTH, level_occupancy, sort_points

    # a spread cloud, duplicates, and one far point (keys that differ in the top level only)
    pts = np.concatenate([rng.uniform(0, 3, (5000, 3)), np.repeat(rng.uniform(0, 1, (50, 3)), 4, axis=0), [[127.0, 127.0, 127.0]]])
    _, keys, _ = sort_points(pts, np.zeros(3), 128.0)
    want = [np.unique(keys >> np.uint64(3 * (MAX_DEPTH - lev))).size for lev in range(MAX_DEPTH + 1)]
    assert level_occupancy(keys) == want and want[0] == 1 and want[1] == 2


def test_local_frame_kernels_equal_the_numpy_expressions_bit_for_bit(rng):
    from patchcloud.core import cell_indices, local_coordinates

    xyz = rng.integers(-2**31, 2**31 - 1, (20000, 3)).astype(np.int32)
    scale, shift = np.array([0.001, 0.01, 0.0003]), np.array([123456.7, -5e6, 33.3])
    ref = xyz.astype(np.float64) * scale + shift
    assert np.array_equal(local_coordinates(xyz, scale, shift), ref)
    assert np.array_equal(cell_indices(xyz, scale, shift, 64.0), np.floor(ref / 64.0).astype(np.int64))


@pytest.mark.parametrize("shape", ["random", "plane", "round plane", "line", "exact plane", "sphere", "huge", "tiny"])
def test_eigh3_matches_lapack_on_every_shape_of_covariance(rng, shape):
    """The closed-form 3x3 solver against numpy's LAPACK: eigenvalues to 1e-13 of the largest, vectors spanning the
    same lines where eigenvalues are apart, an orthonormal frame, A = V diag(w) V^T."""
    from patchcloud.core._kernels import eigh3

    n = 2000
    rot = np.linalg.qr(rng.normal(size=(n, 3, 3)))[0]
    lam = {
        "random": rng.uniform(0, 1, (n, 3)),
        "plane": np.c_[rng.uniform(1e-9, 1e-3, n), rng.uniform(0.5, 1, n), rng.uniform(0.5, 1, n)],
        "round plane": np.c_[rng.uniform(0, 1e-6, n), np.ones(n), 1 + rng.uniform(0, 1e-9, n)],  # two nearly equal
        "line": np.c_[rng.uniform(0, 1e-4, n), rng.uniform(0, 1e-4, n), np.ones(n)],
        "exact plane": np.c_[np.zeros(n), rng.uniform(0.5, 1, n), rng.uniform(0.5, 1, n)],
        "sphere": np.ones((n, 3)),
        "huge": rng.uniform(0, 1, (n, 3)) * 1e12,
        "tiny": rng.uniform(0, 1, (n, 3)) * 1e-24,
    }[shape]
    A = np.einsum("nij,nj,nkj->nik", rot, lam, rot)
    A = (A + A.transpose(0, 2, 1)) / 2
    w0, v0 = np.linalg.eigh(A)
    scale = np.abs(w0).max(axis=1)
    for a, ew, ev, s in zip(A, w0, v0, scale):
        w, v = eigh3(a)
        assert np.all(np.diff(w) >= 0)
        assert np.abs(w - ew).max() <= 1e-13 * s
        assert np.allclose(v.T @ v, np.eye(3), atol=1e-13)
        assert np.abs(v @ np.diag(w) @ v.T - a).max() <= 1e-13 * s
        for j in range(3):  # a vector is defined where its eigenvalue stands apart from the others
            apart = min([abs(ew[j] - ew[i]) for i in range(3) if i != j]) > 1e-6 * s
            if apart:
                assert abs(abs(v[:, j] @ ev[:, j]) - 1.0) < 1e-12


def test_eigh3_of_a_diagonal_zero_or_nan_matrix():
    from patchcloud.core._kernels import eigh3

    w, v = eigh3(np.diag([3.0, 1.0, 2.0]))
    assert w.tolist() == [1.0, 2.0, 3.0] and v.tolist() == [[0, 0, 1], [1, 0, 0], [0, 1, 0]]
    w, v = eigh3(np.diag([2.0, 2.0, 1.0]))  # ties in diagonal order
    assert w.tolist() == [1.0, 2.0, 2.0] and v.tolist() == [[0, 1, 0], [0, 0, 1], [1, 0, 0]]
    w, v = eigh3(np.zeros((3, 3)))
    assert w.tolist() == [0.0, 0.0, 0.0] and v.tolist() == np.eye(3).tolist()
    w, v = eigh3(np.full((3, 3), np.nan))
    assert np.isnan(w).all() and np.isnan(v).all()
