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

from typing import NamedTuple

import numpy as np

from . import _kernels
from .forest import forest_links, kruskal, link_order
from .graph import connected_components
from .morton import MAX_DEPTH, containing, encode, key_range
from .codes import PatchKind
from .octree import Octree

__all__ = [
    "DOT_MIN", "MIN_RELIABILITY", "CREASE_COS", "CREASE_AGREEMENT", "CREASE_SPAN", "CREASE_THICKNESS", "CONCAVE_MIN_POINTS",
    "CONCAVE_SAG", "CONCAVE_DAMPING", "LeafSet", "face_neighbours", "link_agreements", "face_agreement", "crease_agreement",
    "crease_ready", "cross_face_pairs", "spanning_forest", "forest_signs", "propagate_signs", "rule_prior", "concave_damping",
    "rule_scores", "component_rule_signs", "point_rule_signs",
]

#: Smallest |cos| between the PCA normals of an edge or sparse leaf and a neighbour for them to link.
DOT_MIN = 0.9
#: Smallest |agreement| of a link for it to carry orientation.
MIN_RELIABILITY = 0.5
#: Two surface patches whose PCA normals are further apart than this (|cos| below it: 60 degrees) meet at a crease
#: (a wall's foot, a roof's ridge, the rim of a box): :func:`crease_agreement` relates them, not their quadrics.
CREASE_COS = 0.5
#: The agreement of a clear crease link: just above :data:`MIN_RELIABILITY`, below a smooth surface's links (up to 1)
#: and below the ``up`` prior of any patch that has one (|n_z| >= 0.5), so a crease orients only what nothing else
#: reaches: walls, roofs steeper than 60 degrees.  A thin sheet has two sides and a scan sees one: where a roof
#: overhangs a wall (eaves) the two meet in a T, and the crease rule, which reads it as the wall and the eaves'
#: underside, would turn a 55-degree roof plane down over its up prior (0.57) at 0.75.
CREASE_AGREEMENT = 0.55
#: A patch takes part in a crease link only when it is a thin sheet (:func:`crease_ready`): its points' spread
#: across their second direction at least this share of that along the first (not a line of points) ...
CREASE_SPAN = 0.1
#: ... and their spread along e3 at most this share of that along the second (not a blob or a cap).
CREASE_THICKNESS = 0.25
#: Under the ``up`` rule, a surface patch of at least this many times ``n_min`` points whose quadric sags more than
#: :data:`CONCAVE_SAG` times its fit RMSE over half its leaf's edge, concave as seen from above, has a weaker prior
#: (:func:`concave_damping`): the underside of a pipe or a vault.
CONCAVE_MIN_POINTS = 3
CONCAVE_SAG = 3.0
#: How fast the prior of a concave patch weakens with its bend (the quadric's ``a + c`` times the leaf's edge).
CONCAVE_DAMPING = 10.0

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


class LeafSet(NamedTuple):
    """Leaves as arrays in one coordinate frame (metres), for orientation links.

    A tile's own leaves and its neighbour's leaves are two sets in the same
    frame; :func:`link_agreements` relates rows of one to rows of the other.
    """

    lower: np.ndarray  #: (P, 3) minimum corner of every leaf cube
    edge: np.ndarray  #: (P,) leaf edge
    centroid: np.ndarray  #: (P, 3)
    frame: np.ndarray  #: (P, 3, 3) PCA axes as columns
    coeffs: np.ndarray  #: (P, 6) quadric in the frame
    rmse: np.ndarray  #: (P,) quadric fit RMSE
    kind: np.ndarray  #: (P,) PatchKind values
    count: np.ndarray  #: (P,) points
    eigenvalues: np.ndarray  #: (P, 3) covariance eigenvalues along the frame's axes (unit^2)

    @classmethod
    def of_tree(cls, tree: Octree, frames: np.ndarray, coeffs: np.ndarray) -> "LeafSet":
        """The leaves of an octree (root-corner frame) with the given frames and quadrics."""
        return cls(tree.lower, tree.leaf_edge, tree.centroid, frames, coeffs, tree.fit.rmse, tree.kind, tree.count,
                   tree.fit.eigenvalues)

    @classmethod
    def of_table(cls, table, corner) -> "LeafSet":
        """The rows of a PatchTable, shifted to the frame whose origin is ``corner``."""
        c = np.asarray(corner, dtype=np.float64)
        return cls(table.lower - c, table.edge, table.centroid - c, table.frame, table.coeffs, table.rmse, table.kind, table.count,
                   table.eigenvalues)


def link_agreements(
    A: LeafSet, i: np.ndarray, B: LeafSet, j: np.ndarray, d: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orientation agreement of face-neighbour leaves ``A[i]`` and ``B[j]``.

    Between two surface patches: :func:`face_agreement` (face sampling of the
    two quadrics, paper 2.3), or :func:`crease_agreement` where their PCA
    normals are more than 60 degrees apart (:data:`CREASE_COS`): there the
    quadrics extrapolate across a crease, and a strip's quadric (a wall's
    foot in the ground's leaf row) curls to whichever side its few rows
    happen to give.  Between a surface and an edge or sparse leaf,
    or two of those: the dot product of their PCA normals when the two are
    nearly parallel (``|cos| >= DOT_MIN``) and lie on one surface (each
    centroid within half the smaller leaf's edge of the other's PCA plane),
    else 0, so groups of patches separated by a sharp feature or a sparse
    spot still propagate their orientation through it, but two parallel
    surfaces apart (the underside of a pipe over the ground, a roof over a
    terrace) do not link.  Leaves with fewer than 3 points take no part.

    Returns
    -------
    i, j, agreement : the usable pairs and their agreements in [-1, 1].
    """
    keep = (A.count[i] >= 3) & (B.count[j] >= 3)
    i, j, d = i[keep], j[keep], d[keep]
    both = (A.kind[i] == PatchKind.SURFACE) & (B.kind[j] == PatchKind.SURFACE)
    agreement = np.einsum("ni,ni->n", A.frame[i, :, 2], B.frame[j, :, 2])
    # a PCA normal of a sharp or sparse spot is rough: trust only nearly parallel ones
    agreement[~both & (np.abs(agreement) < DOT_MIN)] = 0.0
    gap = B.centroid[j] - A.centroid[i]
    reach = 0.5 * np.minimum(A.edge[i], B.edge[j])
    apart = (np.abs(np.einsum("ni,ni->n", gap, A.frame[i, :, 2])) > reach) | (np.abs(np.einsum("ni,ni->n", gap, B.frame[j, :, 2])) > reach)
    agreement[~both & apart] = 0.0
    crease = both & (np.abs(agreement) < CREASE_COS)
    smooth = both & ~crease
    agreement[smooth] = face_agreement(A, i[smooth], B, j[smooth], d[smooth])
    agreement[crease] = crease_agreement(A, i[crease], B, j[crease])
    return i, j, agreement


def crease_ready(eigenvalues: np.ndarray) -> np.ndarray:
    """Which patches are thin sheets of points, whose PCA plane a crease link (:func:`crease_agreement`) can use.

    A line of points (a scan line, a row along a wall's foot) fits any plane
    through it, so its ``e3`` is any direction across the line; a blob or a
    strongly curved cap has no plane.  A sheet spreads along its second axis
    at least :data:`CREASE_SPAN` times as far as along its first, and along
    ``e3`` at most :data:`CREASE_THICKNESS` times as far as along its second.

    Parameters
    ----------
    eigenvalues : (P, 3) float64
        Covariance eigenvalues, largest first (unit^2).

    Returns
    -------
    (P,) bool

    >>> crease_ready(np.array([[1.0, 0.5, 1e-4], [1.0, 1e-4, 1e-5], [1.0, 0.5, 0.2]])).tolist()
    [True, False, False]
    """
    ev = np.maximum(np.asarray(eigenvalues, dtype=np.float64), 0.0)
    return (ev[:, 1] >= CREASE_SPAN**2 * ev[:, 0]) & (ev[:, 2] <= CREASE_THICKNESS**2 * ev[:, 1])


def crease_agreement(A: LeafSet, i: np.ndarray, B: LeafSet, j: np.ndarray) -> np.ndarray:
    """Orientation agreement of two patches that meet at a crease: a convex or concave edge.

    Where two surfaces meet at an edge, each lies on one side of the
    other's plane, and normals that both point out of the solid (or both
    into it) put the other patch's centroid on the same side: in front of
    both (a concave edge: a wall's foot and the ground beside it) or behind
    both (a convex one: a roof's ridge, the rim of a box).  So the frames'
    ``e3`` agree as they are when ``e3_A . (c_B - c_A)`` and ``e3_B . (c_A -
    c_B)`` have the same sign.  The rule holds only where each patch lies
    clearly on one side of the other's plane: its centroid off that plane by
    more than its points' spread across it (standard deviation) plus three
    times the plane's fit RMSE (an 8 m leaf of ground round a small building,
    its centroid inside the walls, says nothing of them), only for thin
    sheets of points (:func:`crease_ready`), and only for patches that face
    each other across the crease: their centroids
    no further apart along the line where the two planes meet than either
    lies off the other's plane (ground beside a building's corner lies
    behind the next wall's plane without meeting that wall).  A patch that
    crosses the other's plane (a fence on ground that goes on past it) says
    nothing.

    Parameters
    ----------
    A, i, B, j : the pairs' leaves ``A[i]`` and ``B[j]`` (:class:`LeafSet`, one frame).

    Returns
    -------
    (E,) float64: ``+CREASE_AGREEMENT`` where the frames agree as they are,
    ``-CREASE_AGREEMENT`` where one must turn, 0 where the rule says nothing.

    Examples
    --------
    The foot of a wall facing +x and the ground beside it facing +z agree;
    the same wall facing -x does not:

    >>> def leaves(centroid, e3, spread):
    ...     frame = np.zeros((1, 3, 3)); frame[0, :, 2] = e3; frame[0, :, :2] = np.eye(3)[:, [k for k in range(3) if not e3[k]]]
    ...     return LeafSet(np.zeros((1, 3)), np.ones(1), np.array([centroid], float), frame, np.zeros((1, 6)),
    ...                    np.full(1, 0.005), np.zeros(1, np.uint8), np.full(1, 20), np.array([spread], float))
    >>> ground = leaves([0.3, 0.5, 0.0], [0, 0, 1], [0.02, 0.02, 0.0])
    >>> wall = leaves([0.0, 0.5, 0.1], [1, 0, 0], [0.02, 0.003, 0.0])   # spread 0.05 in z: 0.1 above the ground
    >>> crease_agreement(ground, np.array([0]), wall, np.array([0])).tolist()
    [0.55]
    >>> crease_agreement(ground, np.array([0]), wall._replace(frame=-wall.frame), np.array([0])).tolist()
    [-0.55]
    """
    gap = B.centroid[j] - A.centroid[i]
    na, nb = A.frame[i, :, 2], B.frame[j, :, 2]
    sa = np.einsum("ni,ni->n", gap, na)  # B's centroid, in front of A's plane when > 0
    sb = -np.einsum("ni,ni->n", gap, nb)  # A's centroid, in front of B's plane when > 0
    clear = (np.abs(sa) > _spread_along(B, j, na) + 3.0 * A.rmse[i]) & (np.abs(sb) > _spread_along(A, i, nb) + 3.0 * B.rmse[j])
    # the two face each other across their crease: their centroids no further apart along the crease line than
    # across it (the ground beside a building's corner lies behind the next wall's plane without meeting that wall)
    t = np.cross(na, nb)
    length = np.linalg.norm(t, axis=1)
    along = np.abs(np.einsum("ni,ni->n", gap, t)) / np.where(length > 0, length, 1.0)
    clear &= length > 0  # e3s at a crease are far from parallel; a frame without an e3 says nothing
    clear &= along <= np.minimum(np.abs(sa), np.abs(sb))
    clear &= crease_ready(A.eigenvalues[i]) & crease_ready(B.eigenvalues[j])
    return np.where(clear, np.where(sa * sb > 0, CREASE_AGREEMENT, -CREASE_AGREEMENT), 0.0)


def _spread_along(S: LeafSet, rows: np.ndarray, n: np.ndarray) -> np.ndarray:
    """The standard deviation of the points of leaves ``S[rows]`` along unit directions ``n`` (E, 3): the square root of
    the sum over their axes k of lambda_k (e_k . n)^2."""
    return np.sqrt(np.einsum("nk,nk->n", np.maximum(S.eigenvalues[rows], 0.0), np.einsum("nik,ni->nk", S.frame[rows], n) ** 2))


def face_agreement(A: LeafSet, i: np.ndarray, B: LeafSet, j: np.ndarray, d: np.ndarray, samples: int = 4) -> np.ndarray:
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
    A, i, B, j : the pairs' leaves ``A[i]`` (the smaller, or equal) and ``B[j]``.
    d : (E,) int
        Face of ``A[i]`` that touches ``B[j]`` (index into -x, +x, -y, +y, -z, +z).
    samples : int
        The face of ``A[i]`` is sampled on a ``samples x samples`` grid.

    Returns
    -------
    (E,) float64 in [-1, 1]: the sum of the votes (+1 where the two signs
    agree, -1 where they differ) over the number of voting samples, or over
    4 when fewer voted: +1 when the frames' ``e3`` agree at every voting
    sample, -1 when they are opposite at every one.
    """
    E = i.shape[0]
    out = np.zeros(E)
    if E == 0:
        return out
    g = (np.arange(samples) + 0.5) / samples
    c = np.ascontiguousarray
    _kernels.face_votes(
        c(A.lower, dtype=np.float64), c(A.edge, dtype=np.float64), c(A.centroid, dtype=np.float64), c(A.frame, dtype=np.float64),
        c(A.coeffs, dtype=np.float64), c(A.rmse, dtype=np.float64), c(i, dtype=np.int64), c(B.centroid, dtype=np.float64),
        c(B.frame, dtype=np.float64), c(B.coeffs, dtype=np.float64), c(B.rmse, dtype=np.float64), c(j, dtype=np.int64),
        c(d, dtype=np.int64), g, out,
    )
    return out


def cross_face_pairs(A, B, axis: int) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Leaves of two adjacent equal-sized root cubes that share part of their common face.

    ``A`` and ``B`` are PatchTables (or anything with ``level`` and ``ijk``)
    of two cubes of the same edge, ``B`` next to ``A`` on the +``axis`` side.
    As :func:`face_neighbours` inside one cube, every pair is reported once,
    from its smaller leaf (from ``A`` when both have the same size).

    Returns
    -------
    (ia, jb, da) : pairs reported from ``A``: rows of A, rows of B, face of A (+axis)
    (ib, ja, db) : pairs reported from ``B``: rows of B, rows of A, face of B (-axis)
    """
    ab = _probe_across(A, B, axis, upper=True)
    ba = _probe_across(B, A, axis, upper=False)
    ib, ja, db = ba
    strict = np.asarray(A.level)[ja] < np.asarray(B.level)[ib]  # equal sizes were reported from A
    return ab, (ib[strict], ja[strict], db[strict])


def _probe_across(S, T, axis: int, upper: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Leaves of ``S`` on its ``upper`` face along ``axis`` and the leaf of ``T`` across, when as large or larger."""
    level = np.asarray(S.level).astype(np.int64)
    ijk = np.asarray(S.ijk).astype(np.int64)
    last = np.left_shift(1, level) - 1
    src = np.flatnonzero(ijk[:, axis] == (last if upper else 0))
    probe = ijk[src].copy()
    probe[:, axis] = 0 if upper else last[src]
    shift = (MAX_DEPTH - level[src])[:, None]
    keys = encode(np.left_shift(probe, shift))
    t_level = np.asarray(T.level).astype(np.int64)
    lo, hi = key_range(encode(np.asarray(T.ijk).astype(np.int64)), t_level)
    order = np.argsort(lo, kind="stable")
    pos = containing(lo[order], hi[order], keys)
    j = order[np.maximum(pos, 0)]
    ok = (pos >= 0) & (t_level[j] <= level[src])
    d = 2 * axis + (1 if upper else 0)
    return src[ok], j[ok], np.full(int(ok.sum()), d, dtype=np.int64)


def spanning_forest(
    nodes: int, i: np.ndarray, j: np.ndarray, agreement: np.ndarray, min_reliability: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Maximum spanning forest of an agreement graph, most reliable links first.

    Links whose ``|agreement|`` is below ``min_reliability`` are dropped.
    Ties are broken by the ends' ids (:func:`patchcloud.core.forest.link_order`),
    so the forest is unique: the one the stream computes block by block
    (:mod:`patchcloud.core.forest`).
    Because a link left out of the forest of a subgraph is the least
    reliable on a cycle, it is left out of the forest of any larger graph
    too: the forest of a whole cloud is the forest of the union of its
    tiles' forests and the links between tiles.

    Returns
    -------
    fi, fj, fa : (F,) the forest's links and their agreements.
    """
    links = forest_links(i, j, agreement, min_reliability)
    keep = kruskal(nodes, links.i, links.j, link_order(links))
    fi, fj, fa = links.i[keep], links.j[keep], links.agreement[keep]
    srt = np.argsort(np.minimum(fi, fj) * nodes + np.maximum(fi, fj), kind="stable")  # a canonical order
    return fi[srt], fj[srt], fa[srt]


def forest_signs(
    n: int, fi: np.ndarray, fj: np.ndarray, fa: np.ndarray, rule_node: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Signs of ``n`` patches fixed by a spanning forest's links.

    With ``rule_node``, node ``n`` stands for the global rule: the
    component that holds it follows it; the other components get signs
    relative to their lowest-index patch.

    Returns
    -------
    sign : (n,) float64 of +1/-1
    component : (n,) int64 label of every patch's component (without the rule node)
    ruled : (n,) bool, True where the sign was fixed through the rule node
    """
    nodes = n + 1 if rule_node else n
    if n == 0:
        return np.ones(0), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool)
    ncomp, comp = connected_components(nodes, fi, fj)
    # doubled graph: node v+ is v, v- is v + nodes
    pos = fa > 0
    r = np.concatenate([fi[pos], fi[pos] + nodes, fi[~pos], fi[~pos] + nodes])
    c = np.concatenate([fj[pos], fj[pos] + nodes, fj[~pos] + nodes, fj[~pos]])
    _, lab = connected_components(2 * nodes, r, c)
    root = np.full(ncomp, nodes, dtype=np.int64)
    np.minimum.at(root, comp, np.arange(nodes))
    if rule_node:
        root[comp[n]] = n  # the rule node is the root of its component
    sign = np.where(lab[:n] == lab[root[comp[:n]]], 1.0, -1.0)
    ruled = comp[:n] == comp[n] if rule_node else np.zeros(n, dtype=bool)
    return sign, comp[:n].astype(np.int64), ruled


def propagate_signs(
    n: int, i: np.ndarray, j: np.ndarray, agreement: np.ndarray, min_reliability: float, prior: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Signs of ``n`` patches from pairwise agreements and an optional prior.

    Links whose ``|agreement|`` is below ``min_reliability`` are ignored.
    ``prior[k]`` (in [-1, 1]) is the agreement of patch ``k`` with the global
    rule; it enters as a link to a virtual node that stands for the rule, so
    that the rule and the pairwise agreements compete on the same footing:
    a maximum spanning forest on ``|agreement|`` (most reliable first) fixes
    every sign (:func:`spanning_forest`, :func:`forest_signs`).

    Returns
    -------
    sign, component, ruled : see :func:`forest_signs`.
    """
    nodes = n
    if prior is not None:
        k = np.arange(n)
        i = np.concatenate([i, k])
        j = np.concatenate([j, np.full(n, n)])
        agreement = np.concatenate([agreement, prior])
        nodes = n + 1
    fi, fj, fa = spanning_forest(nodes, i, j, agreement, min_reliability)
    return forest_signs(n, fi, fj, fa, rule_node=prior is not None)


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


def concave_damping(prior: np.ndarray, coeffs: np.ndarray, edge: np.ndarray, rmse: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """The ``up`` rule's ``prior`` weakened where a patch is clearly concave seen from the side the rule picks.

    A horizontal patch on the underside of a pipe, a vault or a tank faces
    up into the object under the rule alone, as strongly as the patch on
    its top faces up out of it; when both are linked into one group, the
    stronger prior decides for the whole group.  The top of such an object
    is convex seen from above, its underside concave: so the prior of a
    patch whose quadric (``coeffs`` (P, 6), ``w = a u^2 + b uv + c v^2 +
    ...`` in its frame) curves towards the side the rule picks, with a sag
    ``(a + c) (edge / 2)^2`` above :data:`CONCAVE_SAG` times its fit
    ``rmse`` (not noise), is divided by ``1 + CONCAVE_DAMPING (a + c) edge``.
    Only where ``usable`` (surface patches with enough points to show a
    curvature).  Flat ground and roofs keep their priors.

    >>> prior = np.array([1.0, 1.0, -1.0])  # e3 up, up, down
    >>> coeffs = np.array([[0.5, 0, 0, 0, 0, 0], [-0.5, 0, 0, 0, 0, 0], [-0.5, 0, 0, 0, 0, 0]])  # bowl, dome, bowl seen from below
    >>> concave_damping(prior, coeffs, np.full(3, 0.4), np.full(3, 0.001), np.ones(3, bool)).round(3).tolist()
    [0.333, 1.0, -0.333]
    """
    side = np.where(prior < 0, -1.0, 1.0)
    curving = (coeffs[:, 0] + coeffs[:, 2]) * side  # > 0: the surface bends towards the rule's side (concave from there)
    sag = curving * (0.5 * edge) ** 2
    bend = np.where(usable & (sag > CONCAVE_SAG * rmse), curving * edge, 0.0)
    return prior / (1.0 + CONCAVE_DAMPING * bend)


def rule_scores(rule: str, normals: np.ndarray, positions: np.ndarray, weights: np.ndarray, viewpoint=None, centre=None) -> np.ndarray:
    """Weighted score of each normal under a global rule: positive when it follows the rule.

    "up": ``n_z``; "viewpoint": ``n . (viewpoint - p)``; "outward":
    ``n . (p - centre)``; "none": 0.  Summed over a component by
    :func:`component_rule_signs`; a turned patch's score changes sign.
    """
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
    score = rule_scores(rule, normals, positions, weights, viewpoint, centre)
    total = np.bincount(component, weights=score, minlength=int(component.max()) + 1)
    return np.where(total[component] < 0, -1.0, 1.0)


def point_rule_signs(rule: str, normals: np.ndarray, positions: np.ndarray, viewpoint=None, centre=None) -> np.ndarray:
    """Sign per point that makes each normal follow the global rule on its own."""
    score = rule_scores(rule, normals, positions, np.ones(normals.shape[0]), viewpoint, centre)
    return np.where(score < 0, -1.0, 1.0)
