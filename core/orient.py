"""Consistent orientation of patch surfaces (paper section 2.3) and global rules.

Two leaves are neighbours when their cubes share (part of) a face.  On the
shared face a grid of points is sampled; the two quadrics, seen as implicit
functions ``I(p) = w - S(u, v)``, agree in orientation when their signs agree
at most samples.  The agreements form a graph over the patches; a maximum
spanning forest (most reliable agreements first) fixes every patch's sign
relative to a root, and one global rule then orients each connected
component as a whole.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, minimum_spanning_tree

from .morton import MAX_DEPTH, encode
from .octree import Octree
from .quadric import implicit_value, surface_normals

__all__ = [
    "ORIENT_RULES", "face_neighbours", "face_agreement", "propagate_signs", "rule_prior", "component_rule_signs",
    "point_rule_signs",
]

#: Global orientation rules: towards +Z, towards a viewpoint, away from the centre, none.
ORIENT_RULES = ("up", "viewpoint", "outward", "none")

_DIRS = np.array([[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]], dtype=np.int64)


def face_neighbours(tree: Octree) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs of leaves whose cubes share a face.

    Every pair is reported once, from its smaller leaf ``i`` (or the one with
    the lower index when both have the same size), with the direction ``d``
    (an index into the six axis directions -x, +x, -y, +y, -z, +z) of the
    face of ``i`` that touches ``j``.

    Returns
    -------
    i, j, d : (E,) int64
    """
    ijk = tree.ijk
    level = tree.level
    P = level.shape[0]
    ii, jj, dd = [], [], []
    for d, step in enumerate(_DIRS):
        nb = ijk + step
        size = np.left_shift(1, level)
        ok = np.all((nb >= 0) & (nb < size[:, None]), axis=1)
        src = np.flatnonzero(ok)
        shift = (MAX_DEPTH - level[src])[:, None]
        probe = encode(np.left_shift(nb[src], shift))
        j = tree.find_leaf(probe)
        good = j >= 0
        src, j = src[good], j[good]
        # the neighbour must contain the whole same-size cell: same level or coarser
        keep = level[j] <= level[src]
        same = level[j] == level[src]
        keep &= ~same | (src < j)
        ii.append(src[keep])
        jj.append(j[keep])
        dd.append(np.full(int(keep.sum()), d))
    if P == 0:
        e = np.zeros(0, dtype=np.int64)
        return e, e, e
    return np.concatenate(ii), np.concatenate(jj), np.concatenate(dd)


def face_agreement(
    tree: Octree, frames: np.ndarray, coeffs: np.ndarray, i: np.ndarray, j: np.ndarray, d: np.ndarray, samples: int = 4
) -> np.ndarray:
    """Mean sign agreement of two patches' implicit quadrics on their shared face.

    Only samples near both surfaces vote: one closer than twice the larger
    fit RMSE to either surface says nothing (a face parallel to a noisy
    surface lies inside its noise band, where the two signs are arbitrary),
    and one farther than half the face's edge from either surface depends on
    how the quadrics extrapolate rather than on the shared surface, and one
    where the two quadrics' normals are more than 60 degrees apart or point
    the opposite way to what the signs say (the quadrics cross or fold
    there) is unreliable.  All count as 0.

    Parameters
    ----------
    frames, coeffs : per-leaf frames (P, 3, 3) and quadric coefficients (P, 6).
    i, j, d : pairs from :func:`face_neighbours`.
    samples : int
        The face of ``i`` is sampled on a ``samples x samples`` grid.

    Returns
    -------
    (E,) float64 in [-1, 1]: the sum of the votes (+1 where the two signs
    agree, -1 where they differ) over the number of voting samples, or over
    4 when fewer voted: +1 when the frames' ``e3`` agree at every voting
    sample, -1 when they are opposite at every one.
    """
    E = i.shape[0]
    if E == 0:
        return np.zeros(0)
    axis = d // 2
    upper = d % 2
    h = tree.leaf_edge[i]
    lo = tree.lower[i]
    g = (np.arange(samples) + 0.5) / samples
    gu, gv = np.meshgrid(g, g, indexing="ij")
    gu, gv = gu.ravel(), gv.ravel()
    m = gu.size
    pts = np.repeat(lo, m, axis=0)
    hh = np.repeat(h, m)
    ax = np.repeat(axis, m)
    other1 = (ax + 1) % 3
    other2 = (ax + 2) % 3
    rows = np.arange(E * m)
    pts[rows, ax] += np.repeat(upper, m) * hh
    pts[rows, other1] += np.tile(gu, E) * hh
    pts[rows, other2] += np.tile(gv, E) * hh
    cen = tree.centroid
    ri, rj = np.repeat(i, m), np.repeat(j, m)
    patch_i = (cen[ri], frames[ri], coeffs[ri])  # each side's patch, row by sample
    patch_j = (cen[rj], frames[rj], coeffs[rj])
    vi = implicit_value(pts, *patch_i)
    vj = implicit_value(pts, *patch_j)
    band = 2.0 * np.repeat(np.maximum(tree.fit.rmse[i], tree.fit.rmse[j]), m)
    reach = 0.5 * hh
    near = (np.abs(vi) > band) & (np.abs(vj) > band) & (np.abs(vi) <= reach) & (np.abs(vj) <= reach)
    # a sample also needs the two surfaces to run alike there: where the signs
    # and the directions of the two normals tell different stories, the
    # quadrics cross or fold and the sample says nothing
    ni = surface_normals(pts, *patch_i)
    nj = surface_normals(pts, *patch_j)
    dot = np.einsum("ni,ni->n", ni, nj)
    same = np.sign(vi) * np.sign(vj)
    near &= (np.abs(dot) > 0.5) & (same == np.sign(dot))
    vote = (same * near).reshape(E, m)
    voters = near.reshape(E, m).sum(axis=1)
    return vote.sum(axis=1) / np.maximum(voters, 4)


def propagate_signs(
    n: int, i: np.ndarray, j: np.ndarray, agreement: np.ndarray, min_reliability: float, prior: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Signs of ``n`` patches from pairwise agreements and an optional prior.

    Edges whose ``|agreement|`` is below ``min_reliability`` are ignored.
    ``prior[k]`` (in [-1, 1]) is the agreement of patch ``k`` with the global
    rule; it enters as an edge to a virtual node that stands for the rule, so
    that the rule and the pairwise agreements compete on the same footing:
    a maximum spanning forest on ``|agreement|`` (most reliable first) fixes
    every sign.  Components that hold the rule node follow it; the others get
    signs relative to their lowest-index patch.

    Returns
    -------
    sign : (n,) float64 of +1/-1
    component : (n,) int64 label of every patch's component (without the rule node)
    ruled : (n,) bool, True where the sign was fixed through the rule node
    """
    if n == 0:
        return np.ones(0), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool)
    nodes = n
    if prior is not None:
        k = np.arange(n)
        i = np.concatenate([i, k])
        j = np.concatenate([j, np.full(n, n)])
        agreement = np.concatenate([agreement, prior])
        nodes = n + 1
    keep = np.abs(agreement) >= min_reliability
    i, j, a = i[keep], j[keep], agreement[keep]
    w = 2.0 - np.abs(a)  # positive: csgraph treats zeros as missing edges
    g = coo_matrix((w, (i, j)), shape=(nodes, nodes)).tocsr()
    forest = minimum_spanning_tree(g).tocoo()
    fi, fj = forest.row, forest.col
    # the sign of each forest edge (the forest may store it as (j, i))
    key = np.minimum(i, j).astype(np.int64) * nodes + np.maximum(i, j)
    order = np.argsort(key, kind="stable")
    fkey = np.minimum(fi, fj).astype(np.int64) * nodes + np.maximum(fi, fj)
    frel = np.sign(a)[order[np.searchsorted(key[order], fkey)]]
    ncomp, comp = connected_components(forest, directed=False)
    # doubled graph: node v+ is v, v- is v + nodes
    pos = frel > 0
    r = np.concatenate([fi[pos], fi[pos] + nodes, fi[~pos], fi[~pos] + nodes])
    c = np.concatenate([fj[pos], fj[pos] + nodes, fj[~pos] + nodes, fj[~pos]])
    dg = coo_matrix((np.ones(r.size), (r, c)), shape=(2 * nodes, 2 * nodes))
    _, lab = connected_components(dg, directed=False)
    root = np.full(ncomp, nodes, dtype=np.int64)
    np.minimum.at(root, comp, np.arange(nodes))
    if prior is not None:
        root[comp[n]] = n  # the rule node is the root of its component
    sign = np.where(lab[:n] == lab[root[comp[:n]]], 1.0, -1.0)
    ruled = np.zeros(n, dtype=bool)
    if prior is not None:
        ruled = comp[:n] == comp[n]
    return sign, comp[:n].astype(np.int64), ruled


def rule_prior(rule: str, normals: np.ndarray, positions: np.ndarray, viewpoint=None, centre=None) -> np.ndarray | None:
    """Agreement in [-1, 1] of each patch normal with a global rule, for :func:`propagate_signs`.

    "up": the normal's z; "viewpoint": the cosine to the direction of the
    viewpoint; "outward": 0.6 times the cosine to the direction away from
    ``centre`` (a weak prior: on a non-convex object local agreements must be
    able to overrule it); "none": no prior.
    """
    if rule == "none":
        return None
    if rule == "up":
        return normals[:, 2].copy()
    d = (np.asarray(viewpoint)[None, :] - positions) if rule == "viewpoint" else (positions - np.asarray(centre)[None, :])
    norm = np.linalg.norm(d, axis=1)
    cos = np.einsum("ni,ni->n", normals, d) / np.where(norm > 0, norm, 1.0)
    return cos if rule == "viewpoint" else 0.6 * cos


def _rule_scores(rule: str, normals: np.ndarray, positions: np.ndarray, weights: np.ndarray, viewpoint, centre) -> np.ndarray:
    if rule == "up":
        s = normals[:, 2]
    elif rule == "viewpoint":
        s = np.einsum("ni,ni->n", normals, np.asarray(viewpoint)[None, :] - positions)
    elif rule == "outward":
        s = np.einsum("ni,ni->n", normals, positions - np.asarray(centre)[None, :])
    else:
        s = np.zeros(normals.shape[0])
    return s * weights


def component_rule_signs(
    rule: str, component: np.ndarray, normals: np.ndarray, positions: np.ndarray, weights: np.ndarray, viewpoint=None, centre=None
) -> np.ndarray:
    """Sign (+1/-1) per item that makes each component follow the global rule.

    The weighted sum of the rule's score over a component decides for all of
    it: towards +Z for "up", towards ``viewpoint``, away from ``centre``
    for "outward"; "none" keeps every sign.
    """
    if component.size == 0:
        return np.ones(0)
    score = _rule_scores(rule, normals, positions, weights, viewpoint, centre)
    total = np.bincount(component, weights=score, minlength=int(component.max()) + 1)
    return np.where(total[component] < 0, -1.0, 1.0)


def point_rule_signs(rule: str, normals: np.ndarray, positions: np.ndarray, viewpoint=None, centre=None) -> np.ndarray:
    """Sign per point that makes each normal follow the global rule on its own."""
    score = _rule_scores(rule, normals, positions, np.ones(normals.shape[0]), viewpoint, centre)
    return np.where(score < 0, -1.0, 1.0)
