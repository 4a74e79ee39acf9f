"""One tile of a larger cloud: the two halves of the normals pipeline.

:func:`patchcloud.core.estimate_normals` runs on one cloud in memory; the
stream runs the same steps on the tiles of a cloud that does not fit, and
both go through this module, so a one-tile stream run and an in-memory run
are the same computation:

1. :func:`fit_tile` builds the tile's octree (a subtree of the global
   octree when the tile is one of its cubes), fits every leaf, and reduces
   the tile's orientation graph (face agreements between its leaves, plus a
   link from every patch to a virtual node standing for the global rule) to
   its maximum spanning forest.  What it keeps, a :class:`TileFit`, is small:
   the patch table (not yet oriented) and the forest.
2. :func:`patch_signs` turns the forests of all tiles, plus the links
   between leaves of neighbouring tiles (:func:`patchcloud.core.orient.cross_face_pairs`),
   into one sign per patch.  Because a link left out of a tile's forest is
   the least reliable on a cycle inside the tile, the result is the one the
   whole cloud's graph would give.
3. :func:`finish_tile` evaluates every point of the tile on its oriented
   patch, blends across leaf faces, including the faces shared with the
   neighbouring tiles (from their patch tables, not their points), and gives
   the points of edge and sparse leaves a k-NN normal, searching also among
   the "skin" points of the neighbouring tiles (those within a halo of the
   shared faces).

All coordinates are in the caller's frame (for the stream: metres relative
to the store's origin); tile-local computations subtract the tile corner.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from . import _kernels
from .blend import blend_across_faces
from .moment_normals import moment_normals
from .fallback import knn_normals
from .knn import PointGrid, nearest_neighbours, point_grid, sorted_point_grid
from .morton import encode
from .codes import Method, PatchKind
from .octree import Octree, build_octree, max_level_for, point_keys, sort_points
from .orient import (
    MIN_RELIABILITY,
    LeafSet,
    face_neighbours,
    forest_signs,
    link_agreements,
    point_rule_signs,
    rule_prior,
    concave_damping,
    CONCAVE_MIN_POINTS,
    rule_scores,
    spanning_forest,
)
from .patches import PatchTable
from .quadric import NodeFit, turn_over

__all__ = ["SKIN_HALO", "SIGN_REACH", "FOLD_MIN_COS", "folded", "TileFit", "TileNormals", "Skin", "fit_tile", "patch_signs", "finish_tile"]

#: Width of a tile's skin, in ``d_min``: the points of the neighbouring tiles
#: within this distance of its faces.  A moment normal's cells reach less
#: than ``3 d_min`` beyond its point (:mod:`patchcloud.core.moment_normals`),
#: and the sign of a moment or k-NN normal comes from patch normals no
#: farther than :data:`SIGN_REACH` from it (:func:`finish_tile`), so that a
#: tiled run gives them as a run on the whole cloud does.
SKIN_HALO = 3.0
#: How far (in ``d_min``) a patch normal may lie from a point and still orient its moment or k-NN normal.
SIGN_REACH = 2.0
#: How many of the nearest patch normals within reach orient a moment normal that its own cells' do not.
SIGN_VOTERS = 16
#: Smallest |cos| between a moment normal and the patch normals summed around it for them to orient it:
#: nearly perpendicular to them (a vertical normal in a bush above the ground), a small change of the
#: patches (another tiling splits them at its faces) would turn it, so the next rule decides.
SIGN_MIN_COS = 0.2
#: A surface point whose quadric normal is within this cosine of its patch's frame normal (60 degrees: the limit the
#: orientation's face samples trust too) has that quadric normal; beyond it, where the quadric folds over the points,
#: a moment normal (:func:`folded`).
FOLD_MIN_COS = 0.5


@dataclass(frozen=True)
class TileFit:
    """What fitting one tile keeps (P patches, N points).

    Attributes
    ----------
    patches : PatchTable
        The leaves' patch models as fitted: frames not yet oriented.
    links : (F, 2) int64
        The tile's orientation forest: pairs of patch rows; row ``P`` is the
        virtual node of the global rule.
    agreement : (F,) float64
        Agreement in [-1, 1] of each link (+1: the two ``e3`` agree).
    score : (P,) float64
        Each patch's score under the global rule as fitted (point count
        times the rule's measure; see :func:`patchcloud.core.orient.rule_scores`),
        for components that no link ties to the rule.
    order : (N,) int64
        Sorting order of the points: ``order[k]`` is the input row of the
        k-th point of the patches' runs (patch ``p`` owns sorted points
        ``cumsum(count)[p-1]:cumsum(count)[p]``).
    local : (N, 3) float64
        The sorted points relative to the tile corner (metres).
    threshold : float
        The uniformity threshold used.
    """

    patches: PatchTable
    links: np.ndarray
    agreement: np.ndarray
    score: np.ndarray
    order: np.ndarray
    local: np.ndarray
    threshold: float


@dataclass(frozen=True)
class Skin:
    """Points of neighbouring tiles near this tile's faces, for k-NN searches (S points).

    Attributes
    ----------
    points : (S, 3) float64, caller's frame
    normals : (S, 3) float64
        Their oriented normals where known (points of surface patches: the
        normal of their patch's quadric, not blended), else zeros.
    oriented : (S,) bool
        Where ``normals`` holds an oriented normal.
    """

    points: np.ndarray
    normals: np.ndarray
    oriented: np.ndarray

    @classmethod
    def empty(cls) -> "Skin":
        return cls(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, dtype=bool))


@dataclass(frozen=True)
class TileNormals:
    """Per-point results of one tile in sorted order (N points), and its oriented patches.

    ``normals`` (N, 3), ``scalars`` (N, 3) = (surface variation, k1, k2),
    ``dir1`` (N, 3), all float64; ``method`` (N,) uint8; ``patch`` (N,) int64
    row of the point's patch; ``patches`` oriented.
    """

    normals: np.ndarray
    scalars: np.ndarray
    dir1: np.ndarray
    method: np.ndarray
    patch: np.ndarray
    patches: PatchTable


def fit_tile(
    points: np.ndarray,
    corner: np.ndarray,
    edge: float,
    *,
    criterion: str,
    threshold: float | None,
    d_min: float,
    max_edge: float,
    n_min: int,
    min_sigma2: float,
    orient: str,
    viewpoint: np.ndarray | None = None,
    centre: np.ndarray | None = None,
    spacing: float = 0.0,
    sorted_input: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> TileFit:
    """Octree, patch fits and orientation forest of the points of one root cube.

    Parameters
    ----------
    points : (N, 3) float64
        Points inside the cube ``corner`` .. ``corner + edge`` (caller's frame, metres).
    corner : (3,) float64
    edge : float
    criterion, threshold, d_min, max_edge, n_min, min_sigma2 :
        As :func:`patchcloud.core.estimate_normals`, resolved (``threshold``
        may be None for the rmse criterion: then from this cube's points).
    orient : {"up", "viewpoint", "outward", "none"}
    viewpoint, centre : (3,) float64, optional
        Viewpoint (``orient="viewpoint"``) and the cloud's centre
        (``orient="outward"``), caller's frame.
    spacing : float
        Point spacing (metres), for the default threshold's floor.
    sorted_input : tuple, optional
        ``sort_points(points - corner, zeros(3), edge)`` when the caller has it.

    Returns
    -------
    TileFit
    """
    corner = np.asarray(corner, dtype=np.float64)
    local = points - corner
    if sorted_input is None:
        sorted_input = sort_points(local, np.zeros(3), edge)
    tree = build_octree(
        local, edge, criterion=criterion, threshold=threshold, d_min=d_min, n_min=n_min,
        min_sigma2=min_sigma2, spacing=spacing, max_edge=max_edge, sorted_input=sorted_input,
    )
    frames, coeffs = tree.fit.frame, tree.fit.coeffs
    P = tree.level.shape[0]
    leaves = LeafSet.of_tree(tree, frames, coeffs)
    i, j, d = face_neighbours(tree)
    i, j, a = link_agreements(leaves, i, leaves, j, d)
    usable = tree.count >= 3
    vp = None if viewpoint is None else np.asarray(viewpoint, dtype=np.float64) - corner
    ctr = None if centre is None else np.asarray(centre, dtype=np.float64) - corner
    e3 = frames[:, :, 2] * usable[:, None]
    prior = rule_prior(orient, e3, tree.centroid, vp, ctr)
    surface = tree.kind == PatchKind.SURFACE
    if prior is not None:  # the rule sees surface patches only: an edge or sparse leaf's PCA normal is rough
        prior = np.where(surface, prior, 0.0)
    if orient == "up":
        prior = concave_damping(prior, coeffs, tree.leaf_edge, tree.fit.rmse, surface & (tree.count >= CONCAVE_MIN_POINTS * n_min))
    if prior is not None:
        i = np.concatenate([i, np.arange(P)])
        j = np.concatenate([j, np.full(P, P)])
        a = np.concatenate([a, prior])
    fi, fj, fa = spanning_forest(P + 1, i, j, a, MIN_RELIABILITY)
    score = rule_scores(orient, frames[:, :, 2], tree.centroid, (tree.count * usable).astype(np.float64), vp, ctr)
    table = PatchTable(
        root_corner=corner.copy(),
        root_edge=float(edge),
        level=tree.level.astype(np.uint8),
        ijk=tree.ijk,
        count=tree.count,
        centroid=tree.centroid + corner,
        frame=frames,
        eigenvalues=tree.fit.eigenvalues,
        coeffs=coeffs,
        rmse=tree.fit.rmse,
        kind=tree.kind,
    )
    return TileFit(
        patches=table, links=np.column_stack([fi, fj]).astype(np.int64), agreement=fa, score=score,
        order=tree.order, local=tree.local, threshold=tree.threshold,
    )


def patch_signs(
    n: int, links: np.ndarray, agreement: np.ndarray, score: np.ndarray, orient: str
) -> tuple[np.ndarray, np.ndarray]:
    """Sign (+1/-1) of each of ``n`` patches from orientation links.

    ``links`` (E, 2) are pairs of patch indices, index ``n`` being the
    global rule's node, with their ``agreement``; they may be one tile's
    forest, or the union of several tiles' forests (indices offset) and the
    links between tiles.  The maximum spanning forest of the links fixes the
    signs (most reliable first); components that no link ties to the rule
    follow the rule as a whole (the sign of the sum of their ``score``).

    Returns
    -------
    sign : (n,) float64
    ruled : (n,) bool, True where the sign came through a chain of links to the rule
    """
    links = np.asarray(links, dtype=np.int64).reshape(-1, 2)
    fi, fj, fa = spanning_forest(n + 1, links[:, 0], links[:, 1], agreement, MIN_RELIABILITY)
    sign, comp, ruled = forest_signs(n, fi, fj, fa, rule_node=True)
    if orient != "none" and n and not ruled.all():
        total = np.bincount(comp, weights=np.where(ruled, 0.0, score * sign), minlength=int(comp.max()) + 1)
        sign = np.where(~ruled & (total[comp] < 0), -sign, sign)
    return sign, ruled


def _tree_of(local: np.ndarray, table: PatchTable, corner: np.ndarray, edge: float, max_level: int) -> Octree:
    """The octree of sorted tile points whose leaves are ``table``'s rows (nothing refitted)."""
    n = local.shape[0]
    q, keys = point_keys(local, edge)
    level = table.level.astype(np.int64)
    count = table.count.astype(np.int64)
    start = np.cumsum(count) - count
    h = edge / np.exp2(level)
    centre = (table.ijk + 0.5) * h[:, None]
    fit = NodeFit(
        count=count.astype(np.float64), centroid=table.centroid - corner - centre, eigenvalues=table.eigenvalues,
        frame=table.frame, coeffs=table.coeffs, rmse=table.rmse,
    )
    return Octree(
        edge=float(edge), max_level=max_level, order=np.arange(n), local=local, q=q, keys=keys, level=level,
        cell=encode(table.ijk), start=start, count=count, fit=fit, kind=table.kind, threshold=float("nan"),
    )


def folded(normals: np.ndarray, frame_normals: np.ndarray) -> np.ndarray:
    """Points whose quadric normal (``normals``, (N, 3)) is farther than ``acos(FOLD_MIN_COS)`` from their patch's frame
    normal (``frame_normals``, (N, 3); either side): there the patch's quadric folds over the points.

    A few points in a blob (a bush, a ledge) can fit a sharply bent quadric
    within the RMSE threshold over an almost arbitrary PCA plane; the
    quadric then turns its points' normals up to 90 degrees from the
    frame normal that the orientation sees (real ground and roofs pointing
    down).  :func:`finish_tile` gives such points moment normals, and the
    orientation of moment and k-NN normals takes no vote from them, in a
    tile as in its neighbours' skins.

    >>> folded(np.array([[0.0, 0.0, 1.0], [0.8, 0.0, 0.6], [0.9, 0.0, -0.436]]), np.array([[0.0, 0.0, -1.0]] * 3)).tolist()
    [False, False, True]
    """
    return np.abs(np.einsum("ij,ij->i", normals, frame_normals)) < FOLD_MIN_COS


def finish_tile(
    local: np.ndarray,
    patches: PatchTable,
    sign: np.ndarray,
    *,
    d_min: float,
    min_sigma2: float,
    k_fallback: int,
    orient: str,
    viewpoint: np.ndarray | None = None,
    centre: np.ndarray | None = None,
    blend: bool = True,
    outside: list[PatchTable | None] | None = None,
    skin: Skin | None = None,
    only: np.ndarray | None = None,
) -> TileNormals:
    """Normals, curvatures and methods of every point of one tile (or of some of them), sorted order.

    Parameters
    ----------
    local : (N, 3) float64
        The tile's points sorted as by :func:`fit_tile`, relative to the tile corner.
    patches : PatchTable
        The tile's patch table as fitted (:attr:`TileFit.patches`).
    sign : (P,) float64
        +1/-1 per patch (:func:`patch_signs`).
    d_min, min_sigma2, k_fallback, orient, blend :
        As :func:`patchcloud.core.estimate_normals`, resolved.
    viewpoint, centre : (3,) float64, optional
        Caller's frame.
    outside : list of six PatchTable or None, optional
        The oriented patch tables of the tiles across faces -x, +x, -y, +y,
        -z, +z (caller's frame), for blending across the tile's faces.
    skin : Skin, optional
        Neighbouring tiles' points within ``SKIN_HALO * d_min`` of this
        tile's faces, for the normals of edge and sparse points.
    only : (N,) bool, optional
        Only the points where True (sorted order).  Each of them gets the
        same values as in a call on the whole tile, so a big tile can be
        finished in pieces side by side (default: every point).

    Returns
    -------
    TileNormals
        Of the points asked for, in sorted order (the patch table is the
        tile's, whole).

    Notes
    -----
    The points of edge and sparse leaves get, where it is defined, the
    normal of the cell moments interpolated at the point
    (:mod:`patchcloud.core.moment_normals`, ``Method.MOMENTS``); the others
    a k-NN normal (``Method.KNN``).  Both are oriented by patch normals only
    (the quadric normals of surface points, before blending), in this
    order: a moment normal towards the patch normals summed with the
    moments' weights, a k-NN normal towards the sum of those among its k
    neighbours; else towards the sum of the nearest patch normals (at most
    :data:`SIGN_VOTERS` for a moment normal, k for a k-NN one) within
    ``SIGN_REACH * d_min`` of the point; else by the global rule on its own.  Every step looks no farther
    than the skin reaches, and no such normal depends on another's sign, so
    a point gets the same sign in a tiled run as in a run on the whole
    cloud (unless a k-NN point's k-th neighbour lies beyond the skin, where
    its neighbours differ).
    """
    corner = np.asarray(patches.root_corner, dtype=np.float64)
    edge = float(patches.root_edge)
    tree = _tree_of(local, patches, corner, edge, max_level_for(edge, d_min))
    frames, coeffs = turn_over(patches.frame, patches.coeffs, np.asarray(sign) < 0)
    oriented = PatchTable(**{**patches.__dict__, "frame": frames, "coeffs": coeffs})
    n = local.shape[0]
    if only is not None:
        only = np.asarray(only)
        if only.dtype != np.bool_ or only.shape != (n,):
            raise ValueError(f"only must be a ({n},) bool array (one per point), got {only.dtype} {only.shape}")
    todo = np.ones(n, dtype=np.bool_) if only is None else np.ascontiguousarray(only)
    surface = tree.kind == PatchKind.SURFACE
    normals = np.zeros((n, 3))
    scalars = np.zeros((n, 3))
    dir1 = np.zeros((n, 3))
    _kernels.eval_surface_points(
        tree.local, tree.start, tree.count, surface, tree.centroid, frames, coeffs, tree.fit.sigma3, normals, scalars, dir1
    )
    method = np.repeat(np.where(surface, Method.QUADRIC, 0).astype(np.uint8), tree.count)
    leaf = tree.point_leaf()
    fold = np.flatnonzero(method != 0)
    fold = fold[folded(normals[fold], frames[leaf[fold], :, 2])]  # their quadric folds: moment normals, below
    method[fold] = 0
    voters = method != 0  # surface points: their patch normals (before blending) orient the others
    if skin is not None and skin.points.shape[0]:
        skin = Skin(skin.points - corner, skin.normals, skin.oriented)
    else:
        skin = None
    # the points the fallbacks see: the tile's, then the skin's; their votes, written once (no copy of the tile's first)
    if skin is None:
        points, votes_all, voters_all = tree.local, (normals.copy() if fold.size or not surface.all() else normals), voters
    else:
        points = np.concatenate([tree.local, skin.points])
        votes_all = np.empty_like(points)
        votes_all[:n], votes_all[n:] = normals, skin.normals
        voters_all = np.concatenate([voters, skin.oriented])
    if blend:
        was = blend_across_faces(tree, frames, coeffs, normals, scalars, dir1, outside=outside, corner=corner, only=only)
        method[was] = Method.BLENDED
    method[fold] = 0
    normals[fold], scalars[fold], dir1[fold] = 0.0, 0.0, 0.0  # (a point no fallback gives a normal has none)
    vp = None if viewpoint is None else np.asarray(viewpoint, dtype=np.float64) - corner
    ctr = None if centre is None else np.asarray(centre, dtype=np.float64) - corner
    orienting = _Orienting(points, votes_all, voters_all, SIGN_REACH * d_min, orient, tree.local, tree.keys, edge, vp, ctr)
    _moment_fallback(tree, normals, scalars, dir1, method, points, min_sigma2, orienting, todo)
    _fallback(tree, normals, scalars, dir1, method, points, k_fallback, orienting, todo)
    if orient == "viewpoint" and vp is not None:  # PDAL's viewpoint: at the end, every normal faces it, point by point
        rows = np.flatnonzero(method > 0)
        facing = np.einsum("ij,ij->i", normals[rows], vp - tree.local[rows])
        _turn(normals, scalars, dir1, rows, np.where(facing < 0, -1.0, 1.0))
    if only is None:
        return TileNormals(normals, scalars, dir1, method, leaf, oriented)
    return TileNormals(normals[only], scalars[only], dir1[only], method[only], leaf[only], oriented)


@dataclass(frozen=True)
class _Orienting:
    """What orients the fallback normals of one tile: patch normals near them, then the global rule.

    ``points`` are the tile's sorted points then the skin's; ``votes`` their
    oriented patch normals where ``voters``; ``reach`` (metres) how far a
    patch normal may lie from a point and still orient it; ``local`` the
    tile's points, for the rule, ``keys`` their Morton keys in the tile's
    cube of ``edge``.
    """

    points: np.ndarray
    votes: np.ndarray
    voters: np.ndarray
    reach: float
    orient: str
    local: np.ndarray
    keys: np.ndarray
    edge: float
    viewpoint: np.ndarray | None
    centre: np.ndarray | None

    @cached_property
    def voter_grids(self) -> list[PointGrid]:
        """The search index of the voters (ids: their rows of ``points``), built once: the tile's in their sorted order, the skin's."""
        return tile_grids(self.points, self.keys, self.edge, SIGN_VOTERS, self.voters)

    def finish(self, normals, scalars, dir1, rows, nrm, sign, k: int, min_cos: float = 0.0) -> None:
        """Turn the normals of ``rows`` (``nrm``), in place: by ``sign`` where it is not 0, else towards the nearest patch normals, else by the rule."""
        todo = sign == 0
        if todo.any() and self.voters.any():
            sign[todo] = _nearby_signs(self.voter_grids, self.votes, self.points[rows[todo]], nrm[todo], k, self.reach, min_cos)
        done = sign != 0
        _turn(normals, scalars, dir1, rows[done], sign[done])
        rest = rows[~done]  # the global rule, point by point
        if rest.size and self.orient != "none":
            _turn(normals, scalars, dir1, rest, point_rule_signs(self.orient, normals[rest], self.local[rest], self.viewpoint, self.centre))


def _moment_fallback(tree: Octree, normals, scalars, dir1, method, points, min_sigma2, orienting: _Orienting, todo) -> None:
    """Moment normals for the points of edge and sparse leaves where ``todo``, where defined, oriented, in place."""
    query = np.flatnonzero((method == 0) & todo)
    if query.size == 0:
        return
    mn = moment_normals(points, query, tree.edge / 2.0**tree.max_level, min_sigma2=min_sigma2, votes=orienting.votes,
                        voters=orienting.voters)
    ok = np.flatnonzero(mn.defined)
    if ok.size == 0:
        return
    rows = query[ok]
    nrm = mn.normal[ok]
    normals[rows] = nrm
    scalars[rows] = np.column_stack([mn.sigma3[ok], np.zeros(ok.size), np.zeros(ok.size)])
    dir1[rows] = mn.dir1[ok]
    method[rows] = Method.MOMENTS
    # towards the patch normals weighed with the moments, where they are not nearly perpendicular to it
    sign = _agreeing_signs(mn.votes[ok], nrm, SIGN_MIN_COS)
    orienting.finish(normals, scalars, dir1, rows, nrm, sign, SIGN_VOTERS, SIGN_MIN_COS)


def _fallback(tree: Octree, normals, scalars, dir1, method, points, k, orienting: _Orienting, todo) -> None:
    """k-NN PCA normals for the points where ``todo`` still without one, oriented by patch normals near them, in place.

    The neighbours are among all of ``points`` (the tile's sorted points,
    then the skin's), searched in the octree's order (:func:`tile_grids`).
    """
    query = np.flatnonzero((method == 0) & todo)
    if query.size == 0:
        return
    nrm, s3, k1, k2, t1, nb, defined = knn_normals(points, query, k, grids=tile_grids(points, tree.keys, tree.edge, k))
    # coincident neighbours (duplicates): no direction, no normal (NormalMethod 0, zeros), and nothing to orient
    query, nrm, s3, k1, k2, t1, nb = (a[defined] for a in (query, nrm, s3, k1, k2, t1, nb))
    if query.size == 0:
        return
    normals[query] = nrm
    scalars[query] = np.column_stack([s3, k1, k2])
    # the quadric's k1 direction lies in the quadric's tangent plane at the point;
    # keep it tangent to the PCA normal that is reported
    t = t1 - np.einsum("ni,ni->n", t1, nrm)[:, None] * nrm
    length = np.linalg.norm(t, axis=1)
    flat = length < 1e-9  # k1 direction along the normal: any tangent will do
    t[flat] = np.cross(nrm[flat], np.where(np.abs(nrm[flat, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]]))
    dir1[query] = t / np.linalg.norm(t, axis=1)[:, None]
    method[query] = Method.KNN
    # towards the patch normals among the point's k neighbours
    sign = np.zeros(query.size)
    _kernels.neighbour_signs(nrm, nb, orienting.votes, orienting.voters, sign)
    orienting.finish(normals, scalars, dir1, query, nrm, sign, k)


def _agreeing_signs(total: np.ndarray, nrm: np.ndarray, min_cos: float = 0.0) -> np.ndarray:
    """+1/-1 turning each normal ``nrm`` towards ``total``; 0 where ``total`` is zero or within ``acos(min_cos)`` of perpendicular to it."""
    dot = np.einsum("ij,ij->i", total, nrm)
    length = np.sqrt(np.einsum("ij,ij->i", total, total))
    return np.where((length > 0) & (np.abs(dot) >= min_cos * length), np.where(dot < 0, -1.0, 1.0), 0.0)


def _nearby_signs(grids: list[PointGrid], votes, where, nrm, k: int, reach: float, min_cos: float = 0.0) -> np.ndarray:
    """+1/-1 turning each normal ``nrm`` towards the sum of the nearest (at most ``k``) voters' normals within ``reach`` of ``where``.

    ``grids`` index the voters (:func:`tile_grids`).  0 where there is
    none, or where their sum is within ``acos(min_cos)`` of perpendicular
    to the normal.
    """
    kk = int(min(k, sum(g.ids.size for g in grids)))
    if kk == 0:
        return np.zeros(where.shape[0])
    _, idx = nearest_neighbours(grids, where, kk, max_distance=reach)
    total = np.empty((where.shape[0], 3))
    _kernels.summed_votes(np.ascontiguousarray(votes, dtype=np.float64), idx, total)  # idx: rows of votes, -1 where none
    return _agreeing_signs(total, nrm, min_cos)


def tile_grids(points: np.ndarray, keys: np.ndarray, edge: float, k: int, where: np.ndarray | None = None) -> list[PointGrid]:
    """The k-NN search index of a tile's points then its skin's (of those ``where``, default all), ids their rows.

    ``points`` (N + S, 3) are the tile's N points, sorted by their Morton
    ``keys`` (N,) in the tile's cube of ``edge``, then S skin points: the
    tile's are indexed in their order, without a sort
    (:func:`~patchcloud.core.knn.sorted_point_grid`), the skin's by
    :func:`~patchcloud.core.knn.point_grid`.  The neighbours found are
    those of one grid over all of them.
    """
    n = keys.shape[0]
    if where is None:  # the tile's points as they are (views: no copy)
        grids = [sorted_point_grid(points[:n], keys, edge, k)]
    else:
        own = np.flatnonzero(where[:n])
        grids = [sorted_point_grid(_kernels.rows_where(np.ascontiguousarray(where[:n]), points), keys[own], edge, k, ids=own)]
    skin = np.arange(n, points.shape[0]) if where is None else n + np.flatnonzero(where[n:])
    if skin.size:
        grids.append(point_grid(points[skin], k, ids=skin))
    return grids


def _turn(normals: np.ndarray, scalars: np.ndarray, dir1: np.ndarray, rows: np.ndarray, sign: np.ndarray) -> None:
    """Turn the normals of ``rows`` where ``sign`` is -1, in place, with what depends on their side.

    Seen from the other side a surface's curvatures change sign, so
    ``(k1, k2)`` becomes ``(-k2, -k1)`` (still ``k1 >= k2``) and the k1
    direction becomes the old k2 direction, ``cross(n, dir1)``.
    """
    rows = rows[sign < 0]
    n, d = normals[rows], dir1[rows]
    dir1[rows] = np.cross(n, d)
    normals[rows] = -n
    k1, k2 = scalars[rows, 1].copy(), scalars[rows, 2].copy()
    scalars[rows, 1], scalars[rows, 2] = -k2, -k1
