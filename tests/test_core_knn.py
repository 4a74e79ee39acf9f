"""The compiled k-NN search by rings of octree cells: exact (against scipy's cKDTree), canonical order, any layout."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from patchcloud.core.knn import knn


@pytest.mark.parametrize("layout", ["uniform", "plane", "clusters and outliers", "lattice ties"])
def test_the_neighbours_are_the_exact_ones_nearest_first(layout):
    rng = np.random.default_rng(3)
    if layout == "uniform":
        p = rng.uniform(0, 10, (5000, 3))
    elif layout == "plane":
        xy = rng.uniform(0, 50, (5000, 2))
        p = np.column_stack([xy, 0.1 * xy[:, 0] + rng.normal(0, 0.01, 5000)])
    elif layout == "clusters and outliers":
        p = np.concatenate([rng.normal(0, 0.05, (3000, 3)), rng.normal(40, 0.05, (1990, 3)), rng.uniform(-500, 500, (10, 3))])
    else:  # a 1 cm lattice: many neighbours at equal distances
        p = np.stack(np.meshgrid(*[np.arange(17) * 0.01] * 3, indexing="ij"), -1).reshape(-1, 3)
    query = np.arange(0, len(p), 7)
    for k in (1, 8, 16):
        nb = knn(p, query, k)
        d = np.linalg.norm(p[nb] - p[query][:, None], axis=2)
        ref, _ = cKDTree(p).query(p[query], k=k)
        assert np.allclose(d, ref.reshape(len(query), k), rtol=0, atol=1e-12)  # the k nearest distances, nearest first
        assert np.all(nb[:, 0] == query) or layout == "lattice ties" or k == 1


def test_ties_are_broken_by_coordinates_so_the_order_of_the_points_does_not_matter():
    p = np.stack(np.meshgrid(*[np.arange(9) * 0.5] * 3, indexing="ij"), -1).reshape(-1, 3)
    perm = np.random.default_rng(0).permutation(len(p))
    inv = np.argsort(perm)
    a = knn(p, np.arange(len(p)), 12)
    b = knn(p[perm], inv, 12)  # the same points, shuffled
    assert np.array_equal(perm[b], a)
    centre = 4 * 81 + 4 * 9 + 4
    six = p[a[centre, 1:7]] - p[centre]  # the six at 0.5 m, by x, then y, then z
    assert np.array_equal(six, [[-0.5, 0, 0], [0, -0.5, 0], [0, 0, -0.5], [0, 0, 0.5], [0, 0.5, 0], [0.5, 0, 0]])


def test_fewer_points_than_k():
    p = np.array([[0.0, 0, 0], [3, 0, 0]])
    assert np.array_equal(knn(p, np.array([1]), 5), [[1, 0]])
