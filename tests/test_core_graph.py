"""patchcloud.core.connected_components: scipy's components and numbering, on random and hand-made graphs."""

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components as scipy_components

from patchcloud.core import connected_components


@pytest.mark.parametrize("n, edges, seed", [(1, 0, 0), (50, 0, 1), (200, 150, 2), (1000, 990, 3), (5000, 20000, 4)])
def test_components_and_their_numbering_are_scipys(n, edges, seed):
    rng = np.random.default_rng(seed)
    a, b = rng.integers(0, n, edges), rng.integers(0, n, edges)
    count, labels = connected_components(n, a, b)
    want_count, want = scipy_components(coo_matrix((np.ones(edges), (a, b)), shape=(n, n)), directed=False)
    assert count == want_count
    np.testing.assert_array_equal(labels, want)


def test_a_chain_given_backwards_is_one_component():
    n = 10_000
    count, labels = connected_components(n, np.arange(n - 1)[::-1] + 1, np.arange(n - 1)[::-1])
    assert count == 1 and not labels.any()


def test_edges_outside_the_nodes_are_refused():
    with pytest.raises(ValueError, match="nodes 0..2"):
        connected_components(3, np.array([0]), np.array([3]))
