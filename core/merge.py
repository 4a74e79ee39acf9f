"""Merging adjacent octree leaves into larger quadric patches.

The anisotropic octree stops splitting as soon as a leaf's quadric fits
within the budget, so a plane or a gently curved roof ends up as many
leaves, each with its own model.  :func:`merge_leaves` joins touching
leaves whose points one quadric still fits within the budget: a box
becomes one patch per face, a plane one patch.

It works on the leaves' moments (:mod:`patchcloud.core.moments`), never on
the points: the moments of a union are the sums of the members' moments
moved to a common centre, and the joint PCA frame, quadric and RMS error
follow from them (:func:`patchcloud.core.quadric.fit_nodes`).  Merging
runs in rounds; in each round every group picks the touching group whose
union fits best, and pairs that picked each other merge (so a round's
merges are disjoint and each round is vectorised over all pairs).  The
best pair overall always merges, so every round makes progress until no
union fits.
"""

from __future__ import annotations

import numpy as np

from .moments import N_MOMENTS, shift_moments
from .quadric import fit_nodes

__all__ = ["leaf_neighbours", "unique_pairs", "merge_leaves", "shift_moments", "sum_moments", "moment_scale"]

#: The 26 offsets to the cells that touch a cell (faces, edges and corners).
_OFFSETS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1) if (i, j, k) != (0, 0, 0)],
                    dtype=np.int64)


def _level_keys(ijk: np.ndarray, level: int) -> np.ndarray:
    """One int64 per cell of ``level`` (at most 21 bits per axis)."""
    s = np.int64(1) << np.int64(level)
    return (ijk[..., 0] * s + ijk[..., 1]) * s + ijk[..., 2]


def leaf_neighbours(level: np.ndarray, ijk: np.ndarray) -> np.ndarray:
    """Pairs of octree leaves that touch (share a face, an edge or a corner).

    Parameters
    ----------
    level : (P,) integer
        Octree level of each leaf (0 is the root cube; at most 21).
    ijk : (P, 3) integer
        Integer coordinates of each leaf at its level.  The leaves must not
        overlap.

    Returns
    -------
    (K, 2) int64
        Rows ``(a, b)`` with ``a < b``, sorted, each pair once.

    Examples
    --------
    >>> import numpy as np
    >>> leaf_neighbours(np.array([1, 1, 2]), np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0]])).tolist()
    [[0, 1], [0, 2]]
    """
    level = np.asarray(level, dtype=np.int64)
    ijk = np.asarray(ijk, dtype=np.int64)
    if level.size and level.max() > 21:
        raise ValueError(f"octree levels up to 21 are supported, got {int(level.max())}")
    # every leaf probes its 26 neighbours at its own level; the leaf holding a probe
    # is at that level or coarser (a finer neighbour finds this leaf by its own probe)
    probe = ijk[:, None, :] + _OFFSETS[None, :, :]
    side = np.int64(1) << level
    inside = np.all((probe >= 0) & (probe < side[:, None, None]), axis=2)
    src, off = np.nonzero(inside)
    probe = probe[src, off]
    plevel = level[src]
    found = []
    for lv in np.unique(level).tolist():
        here = np.flatnonzero(level == lv)
        keys = _level_keys(ijk[here], lv)
        order = np.argsort(keys, kind="stable")
        keys = keys[order]
        ask = np.flatnonzero(plevel >= lv)
        k = _level_keys(probe[ask] >> (plevel[ask] - lv)[:, None], lv)
        pos = np.minimum(np.searchsorted(keys, k), max(keys.size - 1, 0))
        hit = keys[pos] == k if keys.size else np.zeros(k.size, dtype=bool)
        found.append(np.column_stack([src[ask[hit]], here[order[pos[hit]]]]))
    pairs = np.concatenate(found) if found else np.zeros((0, 2), dtype=np.int64)
    pairs = np.sort(pairs, axis=1)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    return unique_pairs(pairs, len(level))[0] if pairs.size else np.zeros((0, 2), dtype=np.int64)


def unique_pairs(pairs: np.ndarray, base: int) -> tuple[np.ndarray, np.ndarray]:
    """The rows of ``pairs`` ((K, 2) integers, the second column in ``[0, base)``) once each, sorted, and the index of
    each one's first occurrence: numpy's ``unique(pairs, axis=0, return_index=True)``, on one int64 a row (a 1-D
    unique: ``axis=0`` sorts void views, several times slower).

    >>> unique_pairs(np.array([[2, 1], [0, 3], [2, 1], [0, 0]]), 4)
    (array([[0, 0],
           [0, 3],
           [2, 1]]), array([3, 1, 0]))
    """
    key, first = np.unique(pairs[:, 0] * np.int64(base) + pairs[:, 1], return_index=True)
    return np.column_stack([key // base, key % base]), first


def _centroid(moments: np.ndarray, centre: np.ndarray) -> np.ndarray:
    return centre + moments[:, 1:4] / moments[:, :1]


def _union(ma: np.ndarray, ca: np.ndarray, mb: np.ndarray, cb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Moments of unions of groups (about ``ca``, ``cb``), about the unions' centroids."""
    n = ma[:, :1] + mb[:, :1]
    c = (ma[:, 1:4] + ma[:, :1] * ca + mb[:, 1:4] + mb[:, :1] * cb) / n
    return shift_moments(ma, ca - c) + shift_moments(mb, cb - c), c


def sum_moments(moments: np.ndarray, centres: np.ndarray, label: np.ndarray, G: int) -> tuple[np.ndarray, np.ndarray]:
    """Moments of groups of rows (the rows with the same ``label``), each about its group's centroid.

    Parameters
    ----------
    moments : (K, 35) float64
        Moments of each row's points about ``centres``.
    centres : (K, 3) float64
    label : (K,) int64
        Group of each row, in ``0..G-1``.

    Returns
    -------
    moments : (G, 35) float64
        Zero for a group with no rows.
    centroids : (G, 3) float64
        NaN for a group with no rows.
    """
    n = np.bincount(label, weights=moments[:, 0], minlength=G)
    first = np.column_stack([np.bincount(label, weights=moments[:, i] + moments[:, 0] * centres[:, i - 1], minlength=G)
                             for i in (1, 2, 3)])
    with np.errstate(invalid="ignore", divide="ignore"):
        c = first / n[:, None]
    shifted = shift_moments(moments, centres - c[label])
    return np.stack([np.bincount(label, weights=shifted[:, i], minlength=G) for i in range(N_MOMENTS)], axis=1), c


def moment_scale(moments: np.ndarray) -> np.ndarray:
    """(M,) RMS distance of each group's points to its centroid (moments about the centroid): the fit's length unit."""
    n = np.maximum(moments[:, 0], 1.0)
    return np.sqrt(np.maximum((moments[:, 4] + moments[:, 7] + moments[:, 9]) / n, 0.0)) + 1e-12


def _stars(gm: np.ndarray, gc: np.ndarray, sink: np.ndarray, joins: np.ndarray, P: int) -> tuple[np.ndarray, np.ndarray]:
    """Moments (about their centroids) of every sink with the groups that join it; other rows unchanged."""
    hub = np.unique(sink)
    members = np.concatenate([hub, joins])
    sm, sc = sum_moments(gm[members], gc[members], np.concatenate([hub, sink]), P)
    m, c = gm.copy(), gc.copy()
    m[hub], c[hub] = sm[hub], sc[hub]
    return m, c


def _pair_cost_of(a: np.ndarray, b: np.ndarray, cost: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The cost of each pair (x, y) from the table of pairs (a, b) (either order)."""
    base = max(a.max(initial=0), b.max(initial=0), x.max(initial=0), y.max(initial=0)) + 1
    key = np.minimum(x, y) * base + np.maximum(x, y)
    table = a * base + b
    o = np.argsort(table)
    return cost[o[np.searchsorted(table[o], key)]]


def _rmse(moments: np.ndarray) -> np.ndarray:
    """RMS distance of each group's points to its quadric (moments about the centroid)."""
    return fit_nodes(moments, moment_scale(moments)).rmse


def merge_leaves(
    moments: np.ndarray, centres: np.ndarray, level: np.ndarray, ijk: np.ndarray, max_rmse: float, *,
    harm: float = 1.0, max_rounds: int = 256, pairs: np.ndarray | None = None,
) -> np.ndarray:
    """Groups of touching leaves that one quadric fits with an RMS error at most ``max_rmse``.

    Parameters
    ----------
    moments : (P, 35) float64
        Moments of each leaf's points about ``centres`` (see :mod:`patchcloud.core.moments`).
    centres : (P, 3) float64
        Centre of each leaf's cell (metres).
    level, ijk :
        The leaves' octree cells (see :func:`leaf_neighbours`).
    max_rmse : float
        Largest RMS distance (metres, along the group's PCA normal) of a
        group's points to its least-squares quadric.
    harm : float
        Two groups merge only when the union's quadric adds at most
        ``(harm * max_rmse)**2`` to the squared error per point of the
        smaller group: a leaf that bends round an edge does not tilt the
        plane of the face it touches.
    max_rounds : int
        Merging stops after this many rounds even if unions still fit.
    pairs : (K, 2) int64, optional
        The touching pairs, if the caller has them (:func:`leaf_neighbours` of ``level, ijk``).

    Returns
    -------
    (P,) int64
        Group of each leaf, numbered 0, 1, ... in order of each group's first leaf.

    Examples
    --------
    Four leaves of one plane become one group; a perpendicular leaf stays apart:

    >>> import numpy as np
    >>> from patchcloud.core import moments as mo
    >>> g = np.mgrid[0:4, 0:4].reshape(2, -1).T / 4 + 1 / 8
    >>> cells = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0), (2, 0, 0)]
    >>> pts = [np.column_stack([g + c[:2], np.full(16, 0.5)]) for c in cells[:4]]
    >>> pts.append(np.column_stack([np.full(16, 2.5), g[:, 0], g[:, 1]]))
    >>> centres = np.array(cells) + 0.5
    >>> m = np.concatenate([mo.point_moments(p - c, np.array([0])) for p, c in zip(pts, centres)])
    >>> merge_leaves(m, centres, np.full(5, 2), np.array(cells), 0.01).tolist()
    [0, 0, 0, 0, 1]
    """
    P = moments.shape[0]
    group = np.arange(P)
    if P < 2:
        return group
    pairs = leaf_neighbours(level, ijk) if pairs is None else np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    # per group: moments about the group's centroid
    gc = _centroid(moments, centres)
    gm = shift_moments(moments, centres - gc)
    g_rmse = _rmse(gm)

    def pair_costs(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """RMSE of each union, and its harm: what it adds to the squared error per point of the smaller group."""
        um, _ = _union(gm[a], gc[a], gm[b], gc[b])
        u_rmse = _rmse(um)
        n = gm[:, 0]
        return u_rmse, (um[:, 0] * u_rmse**2 - n[a] * g_rmse[a] ** 2 - n[b] * g_rmse[b] ** 2) / np.minimum(n[a], n[b])

    pair_rmse, pair_harm = pair_costs(pairs[:, 0], pairs[:, 1])
    for _ in range(max_rounds):
        if pairs.shape[0] == 0:
            break
        ok = (pair_rmse <= max_rmse) & (pair_harm <= (harm * max_rmse) ** 2)
        if not ok.any():
            break
        a, b, cost = pairs[ok, 0], pairs[ok, 1], pair_harm[ok]
        # each group's best partner (lowest cost, then lowest index)
        ends = np.concatenate([a, b])
        other = np.concatenate([b, a])
        c2 = np.concatenate([cost, cost])
        order = np.lexsort((other, c2, ends))
        first = np.r_[True, ends[order][1:] != ends[order][:-1]]
        best = np.full(P, -1)
        best[ends[order][first]] = other[order][first]
        # a group moves into its best partner when that one is bigger (then index); the
        # others are sinks and take every group that moves into them, as one star
        n = gm[:, 0]
        has = best >= 0
        moves = np.zeros(P, dtype=bool)
        moves[has] = (n[best[has]] > n[has]) | ((n[best[has]] == n[has]) & (best[has] < np.flatnonzero(has)))
        joins = np.flatnonzero(moves & ~moves[np.maximum(best, 0)])
        sink = best[joins]
        star_m, star_c = _stars(gm, gc, sink, joins, P)
        hub = np.unique(sink)
        fits = np.zeros(P, dtype=bool)
        fits[hub] = _rmse(star_m[hub]) <= max_rmse  # (each member's harm was checked against the hub alone)
        # a star that does not fit as a whole takes only its best member (which fits: it was tested)
        keep = fits[sink]
        if not keep.all():
            lone = ~keep
            jc = _pair_cost_of(a, b, cost, joins[lone], sink[lone])
            o = np.lexsort((joins[lone], jc, sink[lone]))
            s_sorted = sink[lone][o]
            top = np.r_[True, s_sorted[1:] != s_sorted[:-1]]
            chosen = np.zeros(joins.size, dtype=bool)
            chosen[np.flatnonzero(keep)] = True
            chosen[np.flatnonzero(lone)[o[top]]] = True
            joins, sink = joins[chosen], sink[chosen]
            star_m, star_c = _stars(gm, gc, sink, joins, P)
        hub = np.unique(sink)
        gm[hub], gc[hub] = star_m[hub], star_c[hub]
        g_rmse[hub] = _rmse(gm[hub])
        relabel = np.arange(P)
        relabel[joins] = sink
        group = relabel[group]
        # the pairs between the new groups; only those of a group that changed need new costs
        pairs = np.sort(relabel[pairs], axis=1)
        live = pairs[:, 0] != pairs[:, 1]
        pairs, pair_rmse, pair_harm = pairs[live], pair_rmse[live], pair_harm[live]
        pairs, idx = unique_pairs(pairs, P)
        pair_rmse, pair_harm = pair_rmse[idx], pair_harm[idx]
        changed = np.zeros(P, dtype=bool)
        changed[hub] = True
        stale = changed[pairs[:, 0]] | changed[pairs[:, 1]]
        if stale.any():
            pair_rmse[stale], pair_harm[stale] = pair_costs(pairs[stale, 0], pairs[stale, 1])
    _, first_leaf, label = np.unique(group, return_index=True, return_inverse=True)
    rank = np.empty(first_leaf.size, dtype=np.int64)
    rank[np.argsort(first_leaf, kind="stable")] = np.arange(first_leaf.size)
    return rank[label.reshape(-1)]
