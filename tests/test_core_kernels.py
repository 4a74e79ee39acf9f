"""The compiled kernels against their numpy references."""

import pytest
import numpy as np

from patchcloud.core import _kernels
from patchcloud.core.fallback import knn_normals
from patchcloud.core.moments import EXPONENTS, point_moments
from patchcloud.core.morton import encode, quantize
from patchcloud.core.radius import radius_moments


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
    normals, sigma3, k1, k2, dir1, nb, defined = knn_normals(p, query, 20)
    assert defined.all()
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
def test_sorted_grid_knn_equals_whole_cloud_knn(rng, lone):
    # isolated points far from the rest force the search up to coarser cells
    p = np.concatenate([rng.uniform(0, 1, (4000, 3)), rng.uniform(2, 7.9, (lone, 3))])
    from patchcloud.core.knn import sorted_point_grid
    from patchcloud.core.octree import sort_points

    order, keys, q = sort_points(p, np.zeros(3), 8.0)
    ps = p[order]
    rank = np.argsort(order)  # where each point of p went
    query = np.sort(np.r_[rank[4000::1 if lone < 100 else 3], rank[:4000:100]])
    a = knn_normals(ps, query, 10, grids=[sorted_point_grid(ps, keys, 8.0, 10)])
    b = knn_normals(ps, query, 10)
    for x, y in zip(a, b):
        assert np.array_equal(x, y)  # neighbours nearest first, ties by index


def _tile_and_skin(p, edge):
    """A tile's points (in the cube [0, edge)^3, sorted by key) then the others as its skin, with the tile's keys."""
    from patchcloud.core.octree import sort_points

    inside = np.all((p >= 0) & (p < edge), axis=1)
    tile = p[inside]
    order, keys, _ = sort_points(tile, np.zeros(3), edge)
    return np.concatenate([tile[order], p[~inside]]), keys


@pytest.mark.parametrize("k", [3, 12])
def test_tile_and_skin_grids_find_the_whole_cloud_neighbours(rng, k):
    # a tile with its skin (the stream's k-NN fallback): the tile's grid without a sort and the skin's searched in turn,
    # on a lattice (many neighbours tie in distance: ties go to the smaller row in both searches), with isolated points
    from patchcloud.core.tiles import tile_grids

    g = np.arange(-0.5, 2.5, 0.05)
    lattice = np.column_stack([a.ravel() for a in np.meshgrid(g, g, [1.0])])
    p = np.concatenate([lattice, rng.uniform(-0.5, 2.5, (3000, 3)), [[1.0, 1.0, 1.9], [1.99, 0.5, 0.5]], [[9.0, 9.0, 9.0]]])
    p, keys = _tile_and_skin(p, 2.0)
    n = keys.size
    query = np.r_[np.arange(0, n, 7), n - 1, n - 2]
    grids = tile_grids(p, keys, 2.0, k)
    assert len(grids) == 2 and grids[0].ids.size == n
    whole = knn_normals(p, query, k)
    split = knn_normals(p, query, k, grids=grids)
    for a, b in zip(whole, split):
        assert np.array_equal(a, b)


def test_a_skin_search_that_widens_keeps_the_tile_neighbours():
    # a lone tile point whose 6 nearest are 2 tile points and 4 skin points 1.5 m off, beyond two rings of the skin's
    # fine cells: the skin's search starts again on larger cells and must keep the tile points found before it
    from patchcloud.core.knn import nearest_neighbours
    from patchcloud.core.tiles import tile_grids

    dense = np.column_stack([np.arange(200) * 0.01 + 2.2, np.zeros(200), np.zeros(200)])  # the skin: a dense line
    tile = np.array([[0.5, 0.5, 0.5], [0.52, 0.5, 0.5], [0.5, 0.53, 0.5], [0.1, 1.9, 1.9]])
    p, keys = _tile_and_skin(np.concatenate([tile, dense, [[0.5, 0.5, 2.1], [0.5, 2.1, 0.5]]]), 2.0)
    lone = int(np.flatnonzero(np.all(p == [0.5, 0.5, 0.5], axis=1))[0])
    d, i = nearest_neighbours(tile_grids(p, keys, 2.0, 4), p[[lone]], 6)
    ref = np.argsort(np.linalg.norm(p - p[lone], axis=1), kind="stable")[:6]
    assert i[0].tolist() == ref.tolist()
    assert np.sum(i[0] < keys.size) == 3  # the point itself and the two beside it, with three skin points


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


def test_copies_of_a_point_get_the_answer_each_would_get_alone(rng):
    """Piles of copies (a sorted cloud holds them side by side): each copy's neighbours and normal are searched once
    per pile, and are those of the copy searched on its own; piles of fewer copies than k, of more, and copies apart."""
    plane = np.column_stack([rng.uniform(0, 10, (3000, 2)), 0.01 * rng.normal(size=3000)])
    piles = [np.repeat([[5.0, 5.0, 0.0]], 6, axis=0), np.repeat([[2.0, 7.0, 3.0]], 40, axis=0)]
    pts = np.concatenate([plane[:1500], piles[0], piles[1], plane[1500:], piles[1][:3]])
    query = np.arange(len(pts))
    k = 16
    got = knn_normals(pts, query, k)
    for i in np.r_[1495:1560, len(pts) - 4:len(pts)]:  # the piles and the points around them, one call each
        alone = knn_normals(pts, np.array([i]), k)
        for a, b in zip(got, alone):
            assert np.array_equal(a[i], b[0]), i
    assert not got[6][1506:1546].any() and got[6][1500:1506].all()  # 40 copies: no direction; 6 copies and a plane: one


def test_copies_of_a_query_get_the_ball_each_would_get_alone(rng):
    plane = np.column_stack([rng.uniform(0, 10, (3000, 2)), 0.01 * rng.normal(size=3000)])
    column = np.column_stack([np.full(20, 7.0), np.full(20, 3.0), np.linspace(0, 0.5, 20)])  # x and y alike, z not
    pts = np.concatenate([plane[:1500], np.repeat([[5.0, 5.0, 0.05]], 50, axis=0), column, plane[1500:]])
    for mode in ("exact", "fast"):
        m = radius_moments(pts, 0.5, mode=mode)
        for i in range(1490, 1580):
            assert np.array_equal(m[i], radius_moments(pts, 0.5, mode=mode, at=np.array([i]))[0]), (mode, i)


@pytest.mark.parametrize("threads", [1, 2, 3, 5])
def test_stable_argsort_is_numpys_stable_argsort_ties_included(rng, threads):
    from patchcloud.core.argsort import MIN_PARALLEL, stable_argsort

    n = 2 * MIN_PARALLEL + 12345
    cases = [
        rng.integers(0, 50, n),  # ties everywhere: the stable order of equal keys is the input order
        rng.integers(-2**62, 2**62, n),
        np.sort(rng.integers(0, 2**63, n, dtype=np.uint64))[::-1].copy(),  # descending runs
        np.repeat(rng.integers(0, 2**40, n // 8, dtype=np.uint64), 8),
        rng.integers(0, 1000, MIN_PARALLEL - 1),  # too few keys to cut
    ]
    for keys in cases:
        got = stable_argsort(keys, threads=threads)
        assert got.dtype == np.int64 and np.array_equal(got, np.argsort(keys, kind="stable"))


@pytest.mark.parametrize("threads", [1, 2])
def test_keys_in_runs_sort_run_by_run_as_numpys_stable_argsort(rng, threads):
    """Keys in runs of equal values (cells of points in space order) are sorted run by run; equal keys in runs far
    apart keep their input order (the stable sort's permutation, element for element)."""
    from patchcloud.core.argsort import MIN_PARALLEL, MIN_RUN, MIN_RUNS_SORT, stable_argsort

    def in_runs(values, mean):
        lengths = rng.integers(1, 2 * mean, values.size)
        return np.repeat(values, lengths)

    n = 3 * MIN_RUNS_SORT
    cases = [
        in_runs(rng.integers(0, 40, n // 4), 4),  # few values: the same key in many runs far apart
        in_runs(rng.integers(-2**62, 2**62, n // 6), 6),
        in_runs(rng.integers(0, 2**64 - 1, n // 3, dtype=np.uint64), MIN_RUN),
        in_runs(rng.integers(-3, 3, n // 10, dtype=np.int32), 10),
        np.full(n, 7, dtype=np.int64),  # one run
        in_runs(rng.integers(0, 9, 300), 10)[:MIN_RUNS_SORT - 1],  # too few keys: one numpy sort
        np.repeat(rng.integers(0, 2**40, n // 2), 2)[::-1].copy(),
        in_runs(rng.integers(0, 2**62, MIN_PARALLEL + 10_000), 4),  # so many runs that their keys are sorted in parts
    ]
    for keys in cases:
        got = stable_argsort(keys, threads=threads)
        assert got.dtype == np.int64 and np.array_equal(got, np.argsort(keys, kind="stable"))


def test_rows_where_and_shifted_runs_equal_numpy(rng):
    pts = rng.normal(size=(5000, 3))
    keys = np.sort(rng.integers(0, 2**63, 5000, dtype=np.uint64))
    where = rng.random(4000) < 0.3  # rows past the mask are left out
    assert np.array_equal(_kernels.rows_where(where, pts), pts[np.flatnonzero(where)])
    assert _kernels.rows_where(where[:0], pts).shape == (0, 3)
    for shift in (0, 3, 30, 60, 63):
        c = keys >> np.uint64(shift)
        assert np.array_equal(_kernels.run_starts(keys, shift), np.flatnonzero(np.r_[True, c[1:] != c[:-1]]))
    assert _kernels.run_starts(keys[:0], 3).size == 0
    signed = np.sort(rng.integers(-2**40, 2**40, 3000))
    assert np.array_equal(_kernels.run_starts(signed, 8), np.flatnonzero(np.r_[True, (signed >> 8)[1:] != (signed >> 8)[:-1]]))


@pytest.mark.parametrize("spread", [5.0, 5e4])  # a small box: one mask of its cells; a wide one: the sorted wanted cells
def test_near_queries_keeps_the_points_in_the_27_cells_around_each_query(rng, spread):
    from patchcloud.core.knn import near_queries

    pts = rng.uniform(0, spread, (20000, 3))
    q = np.concatenate([rng.uniform(0, spread, (100, 3)), pts[:50] + 1e-9])
    reach = 0.7
    keep = near_queries(pts, q, reach)
    lo = q.min(axis=0) - reach
    dims = np.floor((q.max(axis=0) + reach - lo) / reach).astype(np.int64) + 1
    cell = lambda p: np.minimum(np.floor((p - lo) / reach).astype(np.int64), dims - 1)  # noqa: E731
    inside = np.all((pts >= lo) & (pts <= q.max(axis=0) + reach), axis=1)
    near = np.all(np.abs(cell(pts)[:, None, :] - cell(q)[None, :, :]) <= 1, axis=2).any(axis=1) & inside
    assert np.array_equal(keep, near) and keep[:50].all()
    assert np.linalg.norm(pts[~keep][:, None, :] - q[None, :, :], axis=2).min() > reach  # a superset of the points within reach


def test_shift_to_parents_equals_the_loop_over_the_shift_entries_bit_for_bit(rng):
    from patchcloud.core.moments import shift_entries

    # children of 40 parents (1 to 8 each), their octants, moments of a cloud's scale
    counts = rng.integers(1, 9, 40)
    gstart = np.r_[0, np.cumsum(counts)[:-1]].astype(np.int64)
    octant = rng.integers(0, 8, counts.sum()).astype(np.int64)
    moments = rng.normal(size=(counts.sum(), len(EXPONENTS))) * 10.0 ** rng.integers(-3, 4, (1, len(EXPONENTS)))
    bits = np.array([[(o >> a) & 1 for a in range(3)] for o in range(8)], dtype=np.float64)
    rows, cols, coef = shift_entries((2.0 * bits - 1.0) * 0.37)
    ref = np.zeros((40, len(EXPONENTS)))
    for p in range(40):  # the definition: the entries' terms added one by one, in their order
        for c in range(gstart[p], gstart[p] + counts[p]):
            for t in range(rows.size):
                ref[p, rows[t]] += coef[octant[c], t] * moments[c, cols[t]]
    out = np.empty_like(ref)
    _kernels.shift_to_parents(moments, gstart, octant, coef, out)
    assert np.array_equal(out, ref)


def test_small_calls_run_the_sequential_kernel():
    """A parallel kernel called on arrays of fewer than SEQUENTIAL_BELOW rows runs its sequential version (no numba
    threads started for milliseconds of work); at that size and above, the parallel one, with the same results."""
    from numba import prange

    from patchcloud.core.threads import SEQUENTIAL_BELOW, parallel_kernel

    def doubled(values, out):
        for i in prange(values.shape[0]):
            out[i] = 2.0 * values[i]

    kernel = parallel_kernel(doubled)
    small = np.arange(SEQUENTIAL_BELOW - 1, dtype=np.float64)
    out = np.empty_like(small)
    kernel(small, out)
    assert np.array_equal(out, 2.0 * small)
    assert kernel.sequential.signatures and not kernel.parallel.signatures
    big = np.arange(SEQUENTIAL_BELOW, dtype=np.float64)
    out = np.empty_like(big)
    kernel(big, out)
    assert np.array_equal(out, 2.0 * big) and kernel.parallel.signatures
