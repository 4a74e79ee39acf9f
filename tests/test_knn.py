"""patchcloud.core.knn: exact k nearest neighbours against a brute-force search."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from patchcloud.core.knn import nearest_neighbours, point_grid


def brute(points, queries, k, max_distance=np.inf):
    """Every distance, sorted by (distance, index): the answer the grid must give, ties included."""
    d2 = ((queries[:, None, :] - points[None, :, :]) ** 2).sum(axis=2)
    idx = np.tile(np.arange(len(points)), (len(queries), 1))
    order = np.lexsort((idx, d2), axis=1)[:, :k]
    d2 = np.take_along_axis(d2, order, axis=1)
    out = np.where(d2 <= max_distance**2, order, -1)
    return np.where(out >= 0, np.sqrt(d2), np.inf), out


def clouds():
    rng = np.random.default_rng(7)
    yield "volume", rng.uniform(0, 20, (3000, 3))
    xy = rng.uniform(0, 30, (3000, 2))
    yield "ground, centimetre grid (many ties)", np.round(np.column_stack([xy, 0.05 * np.sin(xy[:, 0])]), 2)
    yield "integer lattice (all ties)", np.stack(np.meshgrid(np.arange(12.0), np.arange(12.0), np.arange(3.0)), -1).reshape(-1, 3)
    yield "two far blobs", np.concatenate([rng.normal(0, 0.2, (1500, 3)), rng.normal(500, 0.2, (1500, 3))])
    yield "a line", np.column_stack([np.linspace(0, 100, 2000), np.zeros(2000), np.zeros(2000)])


@pytest.mark.parametrize("name,points", list(clouds()), ids=[c[0] for c in clouds()])
@pytest.mark.parametrize("k", [1, 8, 16])
def test_the_neighbours_are_the_brute_force_ones_ties_by_index(name, points, k):
    rng = np.random.default_rng(1)
    queries = np.concatenate([points[::37], points[::53] + rng.normal(0, 0.5, (len(points[::53]), 3)),
                              [points.min(axis=0) - 3.0], points.max(axis=0) + [[40.0, -5.0, 2.0]]])  # two outside the box
    d, i = nearest_neighbours(point_grid(points, k), queries, k)
    bd, bi = brute(points, queries, k)
    assert np.array_equal(i, bi)
    assert np.allclose(d, bd, rtol=0, atol=1e-9)


def test_max_distance_leaves_empty_places_and_ids_are_the_callers():
    rng = np.random.default_rng(3)
    points = rng.uniform(0, 10, (800, 3))
    ids = np.arange(800) * 10 + 5
    queries = np.concatenate([rng.uniform(0, 10, (50, 3)), [[30.0, 30.0, 30.0]]])
    d, i = nearest_neighbours(point_grid(points, 8, ids=ids), queries, 8, max_distance=1.2)
    bd, bi = brute(points, queries, 8, max_distance=1.2)
    assert np.array_equal(i, np.where(bi >= 0, bi * 10 + 5, -1))
    assert np.array_equal(np.isinf(d), bi < 0) and (i[-1] == -1).all()
    assert np.allclose(d[bi >= 0], bd[bi >= 0])


@pytest.mark.parametrize("name,points", list(clouds()), ids=[c[0] for c in clouds()])
@pytest.mark.parametrize("max_distance", [0.15, 0.9, 4.0])
def test_a_limit_finds_every_neighbour_within_it_from_queries_near_and_far(name, points, max_distance):
    """Queries all over the box and beyond (most with nothing within the limit: the search skips them from the cells
    around at the level of the limit): the brute-force answer, ties included."""
    rng = np.random.default_rng(5)
    lo, hi = points.min(axis=0) - 2 * max_distance, points.max(axis=0) + 2 * max_distance
    queries = np.concatenate([rng.uniform(lo, hi, (400, 3)), points[::41] + rng.normal(0, max_distance, (len(points[::41]), 3))])
    for k in (1, 8):
        d, i = nearest_neighbours(point_grid(points, 8), queries, k, max_distance=max_distance)
        bd, bi = brute(points, queries, k, max_distance=max_distance)
        assert np.array_equal(i, bi)
        assert np.array_equal(np.isinf(d), bi < 0) and np.allclose(d[bi >= 0], bd[bi >= 0], rtol=0, atol=1e-9)


@pytest.mark.parametrize("name,points", list(clouds()), ids=[c[0] for c in clouds()])
@pytest.mark.parametrize("max_distance", [np.inf, 0.15, 0.9])
def test_queries_in_space_order_share_cell_lookups_and_find_the_same_neighbours(name, points, max_distance):
    """Queries sorted by Morton key, as the fallbacks ask them: runs of queries in one cell reuse the cells' ranges
    looked up for the first of them; every query still gets the brute-force answer."""
    from patchcloud.core.octree import sort_points

    lo = points.min(axis=0) - 1.0
    edge = float((points.max(axis=0) - lo).max()) + 2.0
    order, keys, _ = sort_points(points - lo, np.zeros(3), edge)
    queries = (points[order] + np.random.default_rng(2).normal(0, 0.05, points.shape))[::3]
    for k in (1, 16):
        d, i = nearest_neighbours(point_grid(points, 8), queries, k, max_distance=max_distance)
        bd, bi = brute(points, queries, k, max_distance=max_distance)
        assert np.array_equal(i, bi)
        assert np.allclose(d[bi >= 0], bd[bi >= 0], rtol=0, atol=1e-9)


def test_more_neighbours_than_points_and_degenerate_clouds():
    one = np.array([[1.0, 2.0, 3.0]])
    d, i = nearest_neighbours(point_grid(one, 4), np.array([[1.0, 2.0, 4.0]]), 4)
    assert i.tolist() == [[0, -1, -1, -1]] and d[0, 0] == 1.0 and np.isinf(d[0, 1:]).all()
    same = np.zeros((5, 3))  # every point at one place: ties by index
    assert nearest_neighbours(point_grid(same, 2), np.zeros((1, 3)), 3)[1].tolist() == [[0, 1, 2]]
    empty = point_grid(np.zeros((0, 3)), 4)
    assert nearest_neighbours(empty, one, 2)[1].tolist() == [[-1, -1]]
    with pytest.raises(ValueError, match="k must be at least 1"):
        nearest_neighbours(point_grid(one, 1), one, 0)


def test_the_answer_does_not_depend_on_the_threads():
    from patchcloud.core.threads import SEQUENTIAL_BELOW, single_threaded

    points = np.random.default_rng(5).uniform(0, 50, (SEQUENTIAL_BELOW + 5000, 3))  # the parallel kernels' size
    g = point_grid(points, 16)
    a = nearest_neighbours(g, points[::3], 16)
    with single_threaded():
        b = nearest_neighbours(g, points[::3], 16)
    assert np.array_equal(a[1], b[1]) and np.array_equal(a[0], b[0])


def test_isolated_points_and_far_queries_find_their_neighbours_through_coarser_cells():
    rng = np.random.default_rng(11)
    ground = np.column_stack([rng.uniform(0, 100, (20000, 2)), rng.normal(0, 0.01, 20000)])
    birds = np.array([[50.0, 50.0, 300.0], [0.0, 100.0, 150.0], [99.0, 1.0, 80.0]])  # far above a dense ground
    points = np.concatenate([ground, birds])
    queries = np.concatenate([birds, [[-500.0, -500.0, -500.0]], ground[::997]])
    for k in (1, 8):
        d, i = nearest_neighbours(point_grid(points, k), queries, k)
        bd, bi = brute(points, queries, k)
        assert np.array_equal(i, bi) and np.allclose(d, bd)


def test_near_queries_keeps_every_point_within_reach():
    from patchcloud.core.knn import near_queries

    rng = np.random.default_rng(2)
    points = rng.uniform(0, 100, (30000, 3))
    queries = rng.uniform(20, 60, (40, 3))
    for reach in (0.5, 3.0, 40.0):
        keep = near_queries(points, queries, reach)
        within = (((points[:, None, :] - queries[None, :, :]) ** 2).sum(axis=2) <= reach**2).any(axis=1)
        assert keep[within].all()
        assert keep.sum() < len(points) or reach == 40.0  # and it does leave the far points out
    assert not near_queries(points, queries[:0], 1.0).any()


@pytest.mark.parametrize("n_queries, reach", [(40, 2.0), (5000, 40.0)])
def test_near_queries_keeps_exactly_the_points_of_the_cells_around_the_queries(n_queries, reach):
    """Few queries far apart (the box's cells too many: cells sorted) and many close together (a mask of the box's cells).

    Kept: every point within ``reach`` of a query; none farther than a cell
    diagonal beyond the query's own cell, ``2 sqrt(3) reach``.
    """
    from patchcloud.core.knn import near_queries

    rng = np.random.default_rng(5)
    queries = rng.uniform(0, 1000.0, (n_queries, 3))
    points = np.concatenate([rng.uniform(0, 1000.0, (20000, 3)), queries + rng.normal(0, reach, queries.shape)])
    keep = near_queries(points, queries, reach)
    nearest = cKDTree(queries).query(points)[0]
    assert keep[nearest <= reach].all()
    assert not keep[nearest > 2 * np.sqrt(3) * reach].any()
    assert 0 < keep.sum() < len(points)


def test_fallback_points_far_from_every_patch_take_the_global_rule():
    """A plane (patches) and, far from it, a scatter no patch models: no patch normal within reach of the scatter.

    The scatter's dense part gets moment normals; its lone points, 40 m apart, too few for
    moments, get k-NN normals; both kinds take the global rule, point by point.
    """
    from patchcloud.core import Method, estimate_normals

    rng = np.random.default_rng(4)
    plane = np.column_stack([rng.uniform(0, 20, (20000, 2)), rng.normal(0, 0.002, 20000)])
    scatter = rng.uniform(0, 3, (300, 3)) + [200.0, 200.0, 50.0]
    lone = np.column_stack([np.arange(8) * 40.0, np.full(8, 150.0), 30.0 + 7.0 * (np.arange(8) % 3)])
    r = estimate_normals(np.concatenate([plane, scatter, lone]), orient="up")
    far = r.method[len(plane):]
    assert (far[:300] == Method.MOMENTS).any() and (far[300:] == Method.KNN).all()
    assert (r.normals[len(plane):, 2] >= 0).all()  # the rule, point by point
    assert (r.method[: len(plane)] != Method.KNN).mean() > 0.9


@pytest.mark.parametrize("max_distance", [np.inf, 0.05, 0.3])
def test_a_grid_of_sorted_points_finds_what_a_sorted_grid_finds(max_distance):
    # an octree's points indexed in their own order (no sort) and a grid built by sorting: the same neighbours, on a
    # lattice where distances tie (ties to the smaller id) and with a subset's ids (the voters of a tile)
    from patchcloud.core.knn import sorted_point_grid
    from patchcloud.core.octree import sort_points

    rng = np.random.default_rng(5)
    g = np.arange(0.0, 3.0, 0.05)
    points = np.concatenate([np.column_stack([a.ravel() for a in np.meshgrid(g, g, [1.5])]), rng.uniform(0, 3, (2000, 3))])
    order, keys, _ = sort_points(points, np.zeros(3), 4.0)
    ps = points[order]
    some = np.flatnonzero(rng.random(len(ps)) < 0.6)
    queries = np.concatenate([ps[::5], rng.uniform(-1, 5, (50, 3))])
    for k in (1, 8, 16):
        a = nearest_neighbours(sorted_point_grid(ps[some], keys[some], 4.0, k, ids=some), queries, k, max_distance=max_distance)
        b = nearest_neighbours(point_grid(ps[some], k, ids=some), queries, k, max_distance=max_distance)
        assert np.array_equal(a[1], b[1]) and np.array_equal(a[0], b[0])
