"""Block-wise maximum spanning forests (patchcloud.core.forest) against the whole graph's (patch_signs)."""

from __future__ import annotations

import numpy as np
import pytest

from patchcloud.core import patch_signs
from patchcloud.core.forest import (
    concat_links, expand_signs, forest_links, forest_nodes, kruskal, link_order, lookup, merge_nodes, reduce_forest,
)
from patchcloud.core.orient import MIN_RELIABILITY, spanning_forest


def random_cloud_graph(rng, tiles=(4, 3), per_tile=(5, 40), ties=True):
    """Patches in a grid of tiles: links inside tiles, between neighbouring tiles, and to the rule's node."""
    cells = [(a, b) for a in range(tiles[0]) for b in range(tiles[1]) if rng.random() > 0.15]
    counts = rng.integers(per_tile[0], per_tile[1], len(cells))
    tile = np.repeat(np.array(cells).reshape(-1, 2), counts, axis=0)
    n = tile.shape[0]
    rule = n
    i = rng.integers(0, n, 6 * n)
    j = rng.integers(0, n, 6 * n)
    d = np.abs(tile[i] - tile[j]).sum(axis=1)
    ok = (i != j) & (d <= 1)  # same tile or face neighbours
    i, j = i[ok], j[ok]
    r = rng.random(n) < 0.5  # links to the rule
    i = np.concatenate([i, np.flatnonzero(r)])
    j = np.concatenate([j, np.full(int(r.sum()), rule)])
    if ties:  # few distinct reliabilities: many ties
        a = rng.choice([0.3, 0.5, 0.6, 0.75, 0.9, 1.0], i.size) * rng.choice([-1.0, 1.0], i.size)
    else:
        a = rng.uniform(-1, 1, i.size)
    score = rng.normal(size=n)
    return n, tile, np.column_stack([i, j]), a, score


def blockwise_signs(n, tile, links, agreement, score, flip, bits=1):
    """Signs by blocks of 2**bits x 2**bits tiles, level by level up, then down (the stream's scheme, in memory)."""
    rule = n
    ext = int(tile.max()) + 1
    top = 0
    while (ext - 1) >> (bits * top) > 0:
        top += 1

    def block(ids, level):
        t = tile[np.minimum(ids, n - 1)] >> (bits * level)
        return t[:, 0] * 100000 + t[:, 1]

    i, j = links[:, 0], links[:, 1]
    # the level at which each link joins its ends' blocks (a rule link: 0)
    joins = np.zeros(i.size, dtype=np.int64)
    for level in range(top, -1, -1):
        apart = (block(i, level) != block(j, level)) & (j != rule) & (i != rule)
        joins[apart] = np.maximum(joins[apart], level + 1)
    home = block(np.where(i == rule, j, i), 0)
    ups, exps = [], []
    nodes_by_block: dict = {}
    for level in range(top + 1):
        reduced, expansions = {}, {}
        if level == 0:
            for b in np.unique(block(np.arange(n), 0)):
                ids = np.flatnonzero(block(np.arange(n), 0) == b)
                nodes_by_block[b] = forest_nodes(np.r_[ids, rule], np.r_[score[ids], 0.0])
        else:
            children = ups[-1]
            nodes_by_block = {}
            for cb, red in children.items():
                t = np.array([[cb // 100000, cb % 100000]]) >> bits
                b = int(t[0, 0] * 100000 + t[0, 1])
                nodes_by_block.setdefault(b, []).append(red.nodes)
            nodes_by_block = {b: merge_nodes(v) for b, v in nodes_by_block.items()}
        for b, nodes in nodes_by_block.items():
            sel = joins == level
            if level == 0:
                mine = sel & (home == b)
            else:
                mine = sel & (block(i, level) == b)
            parts = [forest_links(i[mine], j[mine], agreement[mine], MIN_RELIABILITY)]
            if level:
                parts += [red.links for cb, red in ups[-1].items() if block_of_child(cb, bits) == b]
            # terminals: the rule, and nodes with links joined above this level
            out = joins > level
            ends = np.concatenate([i[out], j[out]])
            term = np.isin(nodes.id, ends) | (nodes.id == rule)
            reduced[b], expansions[b] = reduce_forest(nodes, concat_links(parts), term, flip=flip)
        ups.append(reduced)
        exps.append(expansions)
    # down
    (tb,) = ups[-1].keys()
    assert list(ups[-1][tb].nodes.id) == [rule]
    key = {tb: (np.array([1.0]), np.array([True]))}
    for level in range(top, -1, -1):
        below = {}
        for b, e in exps[level].items():
            s, r = expand_signs(e, *key[b])
            if level:
                for cb, red in ups[level - 1].items():
                    if block_of_child(cb, bits) == b:
                        below[cb] = lookup(e.id, s, r, red.nodes.id)
            else:
                below[b] = (e.id, s, r)
        key = below
    sign = np.zeros(n)
    ruled = np.zeros(n, dtype=bool)
    for ids, s, r in key.values():
        m = ids < rule
        sign[ids[m]] = s[m]
        ruled[ids[m]] = r[m]
    return sign, ruled


def block_of_child(cb, bits):
    return ((cb // 100000) >> bits) * 100000 + ((cb % 100000) >> bits)


@pytest.mark.parametrize("seed", range(12))
@pytest.mark.parametrize("orient", ["up", "none"])
def test_blockwise_signs_equal_the_whole_graph(seed, orient):
    rng = np.random.default_rng(seed)
    n, tile, links, a, score = random_cloud_graph(rng, tiles=(5, 4), ties=seed % 2 == 0)
    if orient == "none":  # no rule links
        keep = links[:, 1] != n
        links, a, score = links[keep], a[keep], np.zeros(n)
    expect, expect_ruled = patch_signs(n, links, a, score, orient)
    for bits in (1, 2):
        sign, ruled = blockwise_signs(n, tile, links, a, score, flip=orient != "none", bits=bits)
        assert np.array_equal(ruled, expect_ruled)
        assert np.array_equal(sign, expect)


def test_reduced_forest_is_small_and_keeps_terminals():
    """A path of 100 nodes between two terminals reduces to one link standing for its least reliable one."""
    n = 100
    i, j = np.arange(n - 1), np.arange(1, n)
    a = np.full(n - 1, 0.9)
    a[40] = -0.55  # the least reliable link, disagreeing
    nodes = forest_nodes(np.arange(n), np.zeros(n))
    term = np.zeros(n, dtype=bool)
    term[[0, n - 1]] = True
    red, exp = reduce_forest(nodes, forest_links(i, j, a, 0.5), term)
    assert red.nodes.id.tolist() == [0, n - 1]
    assert len(red.links) == 1
    assert red.links.agreement[0] == pytest.approx(-0.55)  # sign of the whole path, reliability of its weakest link
    assert red.links.tie[0].tolist() == [40, 41, -1]
    # nodes up to 40 follow node 0, those from 41 follow node 99, all with sign +1 relative to them
    assert exp.anchor.tolist() == [0] * 41 + [1] * 59
    assert np.all(exp.sign == 1.0)
    # the outside then decides: keeping the reduced link turns 99 over, and nodes 41.. follow it
    s, _ = expand_signs(exp, np.array([1.0, -1.0]), np.array([True, True]))
    assert s.tolist() == [1.0] * 41 + [-1.0] * 59


def test_component_without_terminal_is_finished_in_its_block():
    """A component with no terminal gets its final signs: lowest node +1, turned over when its score is negative."""
    nodes = forest_nodes(np.array([5, 7, 9]), np.array([-1.0, -1.0, 0.5]))
    links = forest_links(np.array([5, 7]), np.array([7, 9]), np.array([-0.8, 0.9]), 0.5)
    red, exp = reduce_forest(nodes, links, np.zeros(3, dtype=bool), flip=False)
    assert len(red.nodes) == 0 and np.all(exp.anchor == -1)
    assert exp.sign.tolist() == [1.0, -1.0, -1.0]  # node 5 is +1
    _, exp = reduce_forest(nodes, links, np.zeros(3, dtype=bool), flip=True)
    # score with 5 at +1: -1 + 1 - 0.5 = -0.5 < 0: turned over
    assert exp.sign.tolist() == [-1.0, 1.0, 1.0]


def test_kruskal_prefers_the_first_links_in_order():
    # a triangle: the least reliable link is left out
    i, j, a = np.array([0, 1, 0]), np.array([1, 2, 2]), np.array([0.9, -0.8, 0.6])
    links = forest_links(i, j, a, 0.5)
    keep = kruskal(3, links.i, links.j, link_order(links))
    assert keep.tolist() == [True, True, False]
    fi, fj, fa = spanning_forest(3, i, j, a, 0.5)
    assert list(zip(fi.tolist(), fj.tolist(), fa.tolist())) == [(0, 1, 0.9), (1, 2, -0.8)]


def test_merge_nodes_sums_the_rule_node():
    a = forest_nodes(np.array([1, 9]), np.array([1.0, 2.0]))
    b = forest_nodes(np.array([3, 9]), np.array([4.0, 8.0]))
    m = merge_nodes([a, b])
    assert m.id.tolist() == [1, 3, 9]
    assert m.score.tolist() == [1.0, 4.0, 10.0]
