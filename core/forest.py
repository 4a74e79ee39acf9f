"""Maximum spanning forests in blocks: a block's orientation graph reduced to what its outside can see.

The orientation of a whole cloud is fixed by one maximum spanning forest
of its agreement graph (:func:`patchcloud.core.orient.spanning_forest`,
:func:`patchcloud.core.tiles.patch_signs`).  This module computes the
same forest, and the same signs, block by block, so that no process ever
holds the graph of the whole cloud:

1. :func:`reduce_forest` takes a block's nodes and links (a tile's forest,
   or the reduced forests of the blocks inside a bigger block and the
   links between them) and the block's *terminals* (the nodes that have
   links leaving the block, and the rule node).  It computes the block's
   forest and keeps only what a link from outside can change: the
   terminals, the forest's branch points between them, and one link per
   path between these *key* nodes, standing for the path's least reliable
   link (only that one can ever be dropped by a cycle through the outside,
   so the reduced link, ordered as it, behaves as the whole path).  Every
   other node is *anchored* to a key node, with its sign relative to it;
   a component with no terminal is finished in the block (its signs are
   final).  What is left is a :class:`ReducedForest` of a size set by the
   block's boundary, not its contents, and an :class:`Expansion`.
2. A bigger block reduces the union of its children's reduced forests and
   the links between the children, and so on up to one block, whose only
   terminal is the rule node.
3. :func:`expand_signs` goes back down: the key nodes' final signs give
   every node of the block its sign.

Links are ordered by reliability ``|agreement|``, ties broken by the
endpoints' ids and the sign (``tie``): a total order, so the forest is
unique and the blocks' result equals the whole graph's, whatever the
blocks.

Examples
--------
A chain 0-1-2-3 cut into blocks {0, 1} and {2, 3}; node 4 stands for the
rule (linked to 0); the link 1-2 joins the blocks:

>>> import numpy as np
>>> def links(i, j, a):
...     return forest_links(np.array(i), np.array(j), np.array(a), 0.5)
>>> na = forest_nodes(np.array([0, 1, 4]), np.zeros(3))
>>> ra, ea = reduce_forest(na, links([0, 0], [1, 4], [-0.9, 0.7]), np.isin(na.id, [1, 4]))
>>> nb = forest_nodes(np.array([2, 3]), np.zeros(2))
>>> rb, eb = reduce_forest(nb, links([2], [3], [0.8]), nb.id == 2)
>>> top = merge_nodes([ra.nodes, rb.nodes])
>>> _, et = reduce_forest(top, concat_links([ra.links, rb.links, links([1], [2], [-0.6])]), top.id == 4)
>>> s, r = expand_signs(et, np.array([1.0]), np.array([True]))  # the rule: +1
>>> expand_signs(ea, *lookup(et.id, s, r, ra.nodes.id))[0].tolist()
[1.0, -1.0, 1.0]
>>> expand_signs(eb, *lookup(et.id, s, r, rb.nodes.id))[0].tolist()
[1.0, 1.0]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

__all__ = [
    "ForestNodes",
    "ForestLinks",
    "ReducedForest",
    "Expansion",
    "forest_nodes",
    "forest_links",
    "concat_links",
    "merge_nodes",
    "link_order",
    "kruskal",
    "find_root",
    "reduce_forest",
    "expand_signs",
    "lookup",
]


@dataclass(frozen=True)
class ForestNodes:
    """Nodes of an orientation graph and what they carry (N nodes, ids sorted, unique).

    Attributes
    ----------
    id : (N,) int64
        Node ids (in the stream: patch ids over the whole cloud; the rule's node is one more than the last patch).
    score : (N,) float64
        Rule score summed over the nodes anchored to this one, each times its sign relative to it.
    low : (N,) int64
        Lowest id among the nodes anchored to this one (the root of a component with no rule).
    low_sign : (N,) float64
        Sign (+1/-1) of node ``low`` relative to this one.
    faces : (N,) uint8
        The caller's bits, carried unchanged (the stream: the tile faces the node has links across); OR-ed where ids repeat.
    """

    id: np.ndarray
    score: np.ndarray
    low: np.ndarray
    low_sign: np.ndarray
    faces: np.ndarray

    def __len__(self) -> int:
        return int(self.id.size)


@dataclass(frozen=True)
class ForestLinks:
    """Orientation links (E links).

    Attributes
    ----------
    i, j : (E,) int64
        Node ids of the two ends.
    agreement : (E,) float64
        Signed agreement: > 0 when the two ends have the same orientation; ``|agreement|`` is the reliability.
    tie : (E, 3) int64
        Order among links of equal reliability: the lower and the higher end
        id and the sign of the original link (a reduced link keeps those of
        the link it stands for).
    """

    i: np.ndarray
    j: np.ndarray
    agreement: np.ndarray
    tie: np.ndarray

    def __len__(self) -> int:
        return int(self.i.size)


@dataclass(frozen=True)
class ReducedForest:
    """A block's forest as its outside sees it: key nodes and one link per path between them."""

    nodes: ForestNodes
    links: ForestLinks


@dataclass(frozen=True)
class Expansion:
    """How a block's nodes get their signs from its key nodes' (N nodes).

    Attributes
    ----------
    id : (N,) int64
        The block's nodes, sorted.
    anchor : (N,) int64
        Row of the node's key node in :attr:`ReducedForest.nodes`, or -1 when
        the node's component has no terminal (finished in this block).
    sign : (N,) float64
        Sign relative to the key node; the final sign where ``anchor`` is -1.
    """

    id: np.ndarray
    anchor: np.ndarray
    sign: np.ndarray


def forest_nodes(ids: np.ndarray, score: np.ndarray, faces: np.ndarray | None = None) -> ForestNodes:
    """Nodes that stand for themselves alone (a tile's patches): ``low`` is the node itself.

    ``ids`` need not be sorted; they must be unique.
    """
    ids = np.asarray(ids, dtype=np.int64)
    order = np.argsort(ids, kind="stable")
    f = np.zeros(ids.size, dtype=np.uint8) if faces is None else np.asarray(faces, dtype=np.uint8)
    return ForestNodes(
        id=ids[order], score=np.asarray(score, dtype=np.float64)[order], low=ids[order].copy(),
        low_sign=np.ones(ids.size), faces=f[order],
    )


def forest_links(i: np.ndarray, j: np.ndarray, agreement: np.ndarray, min_reliability: float) -> ForestLinks:
    """Original links (not reduced ones), those below ``min_reliability`` dropped."""
    a = np.asarray(agreement, dtype=np.float64)
    keep = np.abs(a) >= min_reliability
    i = np.asarray(i, dtype=np.int64)[keep]
    j = np.asarray(j, dtype=np.int64)[keep]
    a = a[keep]
    tie = np.column_stack([np.minimum(i, j), np.maximum(i, j), np.where(a > 0, 1, -1)]).astype(np.int64)
    return ForestLinks(i=i, j=j, agreement=a, tie=tie.reshape(-1, 3))


def concat_links(parts: list[ForestLinks]) -> ForestLinks:
    """All the links of ``parts``, in that order."""
    if not parts:
        e = np.zeros(0, dtype=np.int64)
        return ForestLinks(e, e.copy(), np.zeros(0), np.zeros((0, 3), dtype=np.int64))
    return ForestLinks(
        i=np.concatenate([p.i for p in parts]), j=np.concatenate([p.j for p in parts]),
        agreement=np.concatenate([p.agreement for p in parts]), tie=np.concatenate([p.tie for p in parts]).reshape(-1, 3),
    )


def merge_nodes(parts: list[ForestNodes]) -> ForestNodes:
    """The union of node sets; a node in several (the rule's) gets its scores summed, the lowest ``low`` and its faces OR-ed."""
    ids = np.concatenate([p.id for p in parts]) if parts else np.zeros(0, dtype=np.int64)
    score = np.concatenate([p.score for p in parts]) if parts else np.zeros(0)
    low = np.concatenate([p.low for p in parts]) if parts else np.zeros(0, dtype=np.int64)
    low_sign = np.concatenate([p.low_sign for p in parts]) if parts else np.zeros(0)
    faces = np.concatenate([p.faces for p in parts]) if parts else np.zeros(0, dtype=np.uint8)
    order = np.lexsort((low, ids))
    ids, score, low, low_sign, faces = ids[order], score[order], low[order], low_sign[order], faces[order]
    first = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]]) if ids.size else np.zeros(0, dtype=np.int64)
    return ForestNodes(
        id=ids[first], score=np.add.reduceat(score, first) if ids.size else score, low=low[first],
        low_sign=low_sign[first], faces=np.bitwise_or.reduceat(faces, first) if ids.size else faces,
    )


def link_order(links: ForestLinks) -> np.ndarray:
    """Indices of ``links``, most reliable first (ties: lower end id, higher end id, agreeing before disagreeing)."""
    t = links.tie
    return np.lexsort((-t[:, 2], t[:, 1], t[:, 0], -np.abs(links.agreement)))


@njit(cache=True, nogil=True)
def find_root(parent: np.ndarray, x: int) -> int:
    """Root of ``x`` in a union-find forest ``parent`` (compressing the path on the way)."""
    root = x
    while parent[root] != root:
        root = parent[root]
    while parent[x] != root:  # path compression
        nxt = parent[x]
        parent[x] = root
        x = nxt
    return root


@njit(cache=True, nogil=True)
def kruskal(n: int, i: np.ndarray, j: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Mask (E,) of the links of the spanning forest of ``n`` nodes taken in ``order`` (Kruskal's algorithm).

    ``i``, ``j`` are node rows in ``[0, n)``; the first links in ``order``
    are preferred (most reliable first gives the maximum spanning forest).
    """
    parent = np.arange(n)
    size = np.ones(n, dtype=np.int64)
    keep = np.zeros(i.size, dtype=np.bool_)
    for e in order:
        a = find_root(parent, i[e])
        b = find_root(parent, j[e])
        if a == b:
            continue
        if size[a] < size[b]:
            a, b = b, a
        parent[b] = a
        size[a] += size[b]
        keep[e] = True
    return keep


@njit(cache=True, nogil=True)
def _reduce(n, fi, fj, fsign, frank, terminal):
    """The forest's key nodes, reduced paths and every node's anchor (rows; see :func:`reduce_forest`).

    Returns key (n,) bool; anchor (n,) int64 (a key row, or -(1 + root)
    for a component with no terminal, ``root`` its last pruned node);
    rel (n,) float64 sign relative to the anchor; and the reduced paths:
    ends (M, 2) rows, sign (M,), bottleneck (M,) forest-link index.
    """
    m = fi.size
    deg = np.zeros(n, dtype=np.int64)
    for e in range(m):
        deg[fi[e]] += 1
        deg[fj[e]] += 1
    start = np.zeros(n + 1, dtype=np.int64)
    for v in range(n):
        start[v + 1] = start[v] + deg[v]
    nbr = np.empty(2 * m, dtype=np.int64)
    via = np.empty(2 * m, dtype=np.int64)
    fill = start[:-1].copy()
    for e in range(m):
        a, b = fi[e], fj[e]
        nbr[fill[a]] = b
        via[fill[a]] = e
        fill[a] += 1
        nbr[fill[b]] = a
        via[fill[b]] = e
        fill[b] += 1
    # 1. prune non-terminal leaves: each hangs on the neighbour left when it goes
    alive = np.ones(n, dtype=np.bool_)
    queued = np.zeros(n, dtype=np.bool_)
    cur = deg.copy()
    stack = np.empty(n, dtype=np.int64)
    top = 0
    for v in range(n):
        if not terminal[v] and cur[v] <= 1:
            stack[top] = v
            top += 1
            queued[v] = True
    pruned = np.empty(n, dtype=np.int64)
    npruned = 0
    parent = np.full(n, -1, dtype=np.int64)
    prel = np.ones(n)
    while top > 0:
        top -= 1
        v = stack[top]
        alive[v] = False
        pruned[npruned] = v
        npruned += 1
        for k in range(start[v], start[v + 1]):
            w = nbr[k]
            if alive[w]:
                parent[v] = w
                prel[v] = fsign[via[k]]
                cur[w] -= 1
                if not terminal[w] and cur[w] <= 1 and not queued[w]:
                    stack[top] = w
                    top += 1
                    queued[w] = True
                break
    # 2. key nodes: terminals and branch points of what is left
    key = np.zeros(n, dtype=np.bool_)
    for v in range(n):
        key[v] = alive[v] and (terminal[v] or cur[v] != 2)
    anchor = np.full(n, -1, dtype=np.int64)
    rel = np.ones(n)
    for v in range(n):
        if key[v]:
            anchor[v] = v
    # 3. paths between key nodes through degree-2 nodes: one reduced link each
    seen = np.zeros(m, dtype=np.bool_)
    ends = np.empty((n, 2), dtype=np.int64)
    psign = np.empty(n)
    bott = np.empty(n, dtype=np.int64)
    npaths = 0
    path_nodes = np.empty(n, dtype=np.int64)
    path_edges = np.empty(n + 1, dtype=np.int64)
    for u in range(n):
        if not key[u]:
            continue
        for k0 in range(start[u], start[u + 1]):
            e0 = via[k0]
            if seen[e0] or not alive[nbr[k0]]:
                continue
            # walk from u to the next key node
            ne = 0
            nn = 0
            prev_e = e0
            path_edges[ne] = e0
            ne += 1
            seen[e0] = True
            x = nbr[k0]
            while not key[x]:
                path_nodes[nn] = x
                nn += 1
                for k in range(start[x], start[x + 1]):
                    e = via[k]
                    if e != prev_e and alive[nbr[k]]:
                        prev_e = e
                        x = nbr[k]
                        break
                path_edges[ne] = prev_e
                ne += 1
                seen[prev_e] = True
            v = x
            b = 0
            for t in range(1, ne):
                if frank[path_edges[t]] > frank[path_edges[b]]:
                    b = t
            s = 1.0
            for t in range(ne):  # nodes before the bottleneck follow u
                if t == b:
                    break
                s *= fsign[path_edges[t]]
                anchor[path_nodes[t]] = u
                rel[path_nodes[t]] = s
            s = 1.0
            for t in range(ne - 1, b, -1):  # those after it follow v
                s *= fsign[path_edges[t]]
                anchor[path_nodes[t - 1]] = v
                rel[path_nodes[t - 1]] = s
            ptot = 1.0
            for t in range(ne):
                ptot *= fsign[path_edges[t]]
            ends[npaths, 0] = u
            ends[npaths, 1] = v
            psign[npaths] = ptot
            bott[npaths] = path_edges[b]
            npaths += 1
    # 4. pruned nodes follow the node they hang on (last pruned first)
    for t in range(npruned - 1, -1, -1):
        v = pruned[t]
        p = parent[v]
        if p < 0:
            anchor[v] = -(1 + v)  # the root of a component with no terminal
            rel[v] = 1.0
        else:
            anchor[v] = anchor[p]
            rel[v] = prel[v] * rel[p]
    return key, anchor, rel, ends[:npaths].copy(), psign[:npaths].copy(), bott[:npaths].copy()


def reduce_forest(
    nodes: ForestNodes, links: ForestLinks, terminal: np.ndarray, flip: bool = True
) -> tuple[ReducedForest, Expansion]:
    """A block's maximum spanning forest, reduced to its key nodes (see the module's docstring).

    Parameters
    ----------
    nodes : ForestNodes
        The block's nodes (every end of ``links`` must be one).
    links : ForestLinks
        The block's links: original ones and the children's reduced ones.
    terminal : (N,) bool
        Nodes with links leaving the block: they stay.  The rule's node must
        be one in every block (it is the root of its component: the caller
        gives it the sign +1 at the top).
    flip : bool
        A finished component with no rule is turned over as a whole when its
        summed score is negative (:func:`patchcloud.core.tiles.patch_signs`);
        False keeps its lowest node's sign +1.

    Returns
    -------
    ReducedForest, Expansion
    """
    n = len(nodes)
    terminal = np.asarray(terminal, dtype=bool)
    if terminal.shape != (n,):
        raise ValueError(f"terminal must have one value per node ({n}), not shape {terminal.shape}")
    li = np.searchsorted(nodes.id, links.i)
    lj = np.searchsorted(nodes.id, links.j)
    if len(links) and (li.max() >= n or lj.max() >= n or np.any(nodes.id[li] != links.i) or np.any(nodes.id[lj] != links.j)):
        raise ValueError("every link's ends must be among the nodes")
    order = link_order(links)
    rank = np.empty(len(links), dtype=np.int64)
    rank[order] = np.arange(len(links))
    keep = kruskal(n, li, lj, order)
    f = np.flatnonzero(keep)
    fsign = np.where(links.agreement[f] > 0, 1.0, -1.0)
    key, anchor, rel, ends, psign, bott = _reduce(n, li[f], lj[f], fsign, rank[f], terminal)
    keyrow = np.cumsum(key) - 1
    closed = anchor < 0
    a_row = np.where(closed, -1, keyrow[np.maximum(anchor, 0)])
    # what each key node carries: the scores and lowest node of those anchored to it
    k = int(key.sum())
    inside = np.flatnonzero(~closed)
    score = np.bincount(a_row[inside], weights=rel[inside] * nodes.score[inside], minlength=k)
    low, low_sign = _lowest(a_row[inside], nodes.low[inside], rel[inside] * nodes.low_sign[inside], k)
    sign = rel.copy()
    if closed.any():  # components with no terminal: final signs now
        c = np.flatnonzero(closed)
        root = -(anchor[c] + 1)
        roots, comp = np.unique(root, return_inverse=True)
        clow, clow_sign = _lowest(comp, nodes.low[c], rel[c] * nodes.low_sign[c], roots.size)
        s_root = clow_sign.copy()  # the lowest node's sign +1
        if flip:
            total = np.bincount(comp, weights=s_root[comp] * rel[c] * nodes.score[c], minlength=roots.size)
            s_root = np.where(total < 0, -s_root, s_root)
        sign[c] = s_root[comp] * rel[c]
    kn = np.flatnonzero(key)
    reduced_nodes = ForestNodes(id=nodes.id[kn], score=score, low=low, low_sign=low_sign, faces=nodes.faces[kn])
    orig = f[bott]
    reduced_links = ForestLinks(
        i=nodes.id[ends[:, 0]], j=nodes.id[ends[:, 1]], agreement=psign * np.abs(links.agreement[orig]),
        tie=links.tie[orig].reshape(-1, 3),
    )
    return ReducedForest(reduced_nodes, reduced_links), Expansion(id=nodes.id.copy(), anchor=a_row, sign=sign)


def _lowest(group: np.ndarray, low: np.ndarray, low_sign: np.ndarray, groups: int) -> tuple[np.ndarray, np.ndarray]:
    """Per group, the lowest ``low`` and its sign."""
    out = np.full(groups, np.iinfo(np.int64).max, dtype=np.int64)
    out_sign = np.ones(groups)
    if group.size:
        order = np.lexsort((low, group))
        g = group[order]
        first = order[np.r_[True, g[1:] != g[:-1]]]
        out[group[first]] = low[first]
        out_sign[group[first]] = low_sign[first]
    return out, out_sign


def expand_signs(expansion: Expansion, key_sign: np.ndarray, key_ruled: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Final sign and "ruled" flag of every node of a block from those of its key nodes.

    Returns
    -------
    sign : (N,) float64 +1/-1, in the order of ``expansion.id``
    ruled : (N,) bool, True where the node's component holds the rule's node
    """
    a = expansion.anchor
    inside = a >= 0
    sign = expansion.sign.copy()
    ruled = np.zeros(a.size, dtype=bool)
    if inside.any():
        sign[inside] = np.asarray(key_sign)[a[inside]] * expansion.sign[inside]
        ruled[inside] = np.asarray(key_ruled, dtype=bool)[a[inside]]
    return sign, ruled


def lookup(ids: np.ndarray, sign: np.ndarray, ruled: np.ndarray, wanted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``sign`` and ``ruled`` of the nodes ``wanted`` (a subset of the sorted ``ids``)."""
    k = np.searchsorted(ids, wanted)
    if wanted.size and (k.max() >= ids.size or np.any(ids[k] != wanted)):
        raise ValueError("lookup: some wanted nodes are not among ids")
    return sign[k], ruled[k]
