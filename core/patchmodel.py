"""Patch models of one cloud: the quadric surfaces that stand for its points, and points sampled back from them.

The anisotropic octree (criterion ``rmse`` with the error budget as its
threshold) splits the cloud into leaves whose quadric fits within the
budget; touching surface leaves that one quadric still fits within the
budget are then merged (:mod:`patchcloud.core.merge`), so a plane is one
patch and a box one patch per face.  A *patch* is a PCA frame and a
quadric; the octree *cells* it covers say where its points were: per
cell, the point count, the ``(u, v)`` box of the points in the patch's
frame and an 8 x 8 occupancy mask of that box.

Every other point is *residual*: the points of edge and sparse leaves
(vegetation, wires, isolated returns), and the points farther than
``outlier_factor`` x the budget from their patch's quadric.  So every
input point is represented either by a surface or by itself.

Sampling draws each cell's point count (or any other) uniformly over the
occupied cells of its mask and lifts each ``(u, v)`` onto its patch's
quadric.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._kernels import cell_moments, draw_on_patches
from .checks import check_budget
from .errors import PatchcloudMemoryError, PatchcloudValueError
from .merge import leaf_neighbours, merge_leaves, moment_scale, sum_moments, unique_pairs
from .octree import estimate_spacing, sort_points
from .options import NormalsOptions
from .patches import PatchKind
from .points import root_cube, validate_points
from .quadric import fit_nodes, implicit_value
from .tiles import fit_tile

__all__ = ["PatchModels", "ModelFit", "QuantisedModels", "fit_models", "sample_models", "quantise_models", "dequantise_models", "close_masks", "MASK_SIDE",
           "patch_distances"]

#: The occupancy mask of a cell is MASK_SIDE x MASK_SIDE cells over its (u, v) box (one uint64).
MASK_SIDE = 8
#: Draws per sampled point at most: a draw outside its octree cell is drawn again.
MAX_DRAWS = 8


@dataclass(frozen=True)
class PatchModels:
    """Quadric patches (P rows) and the octree cells they cover (C rows) that stand for a cloud's smooth surfaces.

    The surface of patch ``k``, in its frame, is ``w = a u^2 + b uv + c v^2
    + d u + e v + f`` (``coeffs[k]``), with ``(u, v, w) = frame[k].T @ (p -
    centroid[k])``.  Its cells are rows ``start[k]:start[k] + cells[k]`` of
    the cell arrays; the surface is kept inside each cell, where the cell's
    ``extent`` and ``mask`` say the points were.

    Attributes
    ----------
    root_corner : (3,) float64
        Minimum corner of the octree's root cube (metres, caller's frame).
    root_edge : float
        Edge of the root cube (metres).
    centroid : (P, 3) float64
        Origin of the patch frame (metres, caller's frame).
    frame : (P, 3, 3) float64
        Axes ``e1, e2, e3`` as columns (e3: the normal of the PCA plane).
    coeffs : (P, 6) float64
        Quadric coefficients ``a, b, c, d, e, f``.
    rmse : (P,) float64
        RMS distance (along e3) of the patch's points to its quadric (metres).
    cells : (P,) int64
        Number of octree cells of each patch (at least one).
    level : (C,) uint8
        Octree level of each cell.
    ijk : (C, 3) int64
        Integer coordinates of each cell at its level.
    count : (C,) int64
        Points each cell stands for.
    extent : (C, 4) float64
        ``u_min, u_max, v_min, v_max`` of the cell's points in its patch's frame (metres).
    mask : (C,) uint64
        Bit ``i * MASK_SIDE + j`` set where cell (i, j) of the extent's
        MASK_SIDE x MASK_SIDE grid (i along u) holds a point, after a
        filling of one-cell gaps (:func:`close_masks`).
    """

    root_corner: np.ndarray
    root_edge: float
    centroid: np.ndarray
    frame: np.ndarray
    coeffs: np.ndarray
    rmse: np.ndarray
    cells: np.ndarray
    level: np.ndarray
    ijk: np.ndarray
    count: np.ndarray
    extent: np.ndarray
    mask: np.ndarray

    def __len__(self) -> int:
        """The number of patches."""
        return int(self.centroid.shape[0])

    @classmethod
    def empty(cls, root_corner, root_edge: float) -> "PatchModels":
        """No patches (a cube whose points are all residual)."""
        z = np.zeros
        return cls(
            root_corner=np.asarray(root_corner, dtype=np.float64).copy(), root_edge=float(root_edge), centroid=z((0, 3)),
            frame=z((0, 3, 3)), coeffs=z((0, 6)), rmse=z(0), cells=z(0, np.int64), level=z(0, np.uint8),
            ijk=z((0, 3), np.int64), count=z(0, np.int64), extent=z((0, 4)), mask=z(0, np.uint64),
        )

    @property
    def cell_patch(self) -> np.ndarray:
        """(C,) patch of every cell."""
        return np.repeat(np.arange(len(self)), self.cells)

    @property
    def patch_count(self) -> np.ndarray:
        """(P,) points each patch stands for."""
        return np.bincount(self.cell_patch, weights=self.count, minlength=len(self)).astype(np.int64)

    @property
    def edge(self) -> np.ndarray:
        """(C,) edge of every cell (metres)."""
        return _cell_edge(self.root_edge, self.level)

    def cell_corner(self) -> np.ndarray:
        """(C, 3) minimum corner of every cell (metres, caller's frame)."""
        return self.root_corner + self.ijk * self.edge[:, None]

    def mask_bits(self) -> np.ndarray:
        """(C, MASK_SIDE**2) bool: the occupied cells of each cell's mask, bit by bit."""
        return ((self.mask[:, None] >> np.arange(MASK_SIDE * MASK_SIDE, dtype=np.uint64)) & np.uint64(1)).astype(bool)

    def occupied(self) -> np.ndarray:
        """(C,) number of occupied cells of each cell's mask."""
        return self.mask_bits().sum(axis=1).astype(np.int64)


@dataclass(frozen=True)
class ModelFit:
    """What :func:`fit_models` gives.

    Attributes
    ----------
    models : PatchModels
    patch : (N,) int64
        Patch (row of ``models``) each input point is represented by; -1 for a residual point.
    cell : (N,) int64
        Cell (row of ``models``' cell arrays) of each input point; -1 for a residual point.
    residual : (R,) int64
        Input rows of the residual points, ascending.
    error : (N,) float64
        Distance along the patch normal from each point to its quadric (metres); 0 for residual points.
    """

    models: PatchModels
    patch: np.ndarray
    cell: np.ndarray
    residual: np.ndarray
    error: np.ndarray


def _cell_edge(root_edge: float, level: np.ndarray) -> np.ndarray:
    """Edge (metres) of octree cells at ``level`` below a root cube of edge ``root_edge``."""
    return root_edge / 2.0 ** level.astype(np.float64)


def _cells(u: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    span = np.where(hi > lo, hi - lo, 1.0)
    return np.clip(np.floor((u - lo) / span * MASK_SIDE), 0, MASK_SIDE - 1).astype(np.int64)


_NOT_FIRST = np.uint64(sum(1 << (i * MASK_SIDE) for i in range(MASK_SIDE)) ^ (2**64 - 1))  # bits with j > 0
_NOT_LAST = np.uint64(sum(1 << (i * MASK_SIDE + MASK_SIDE - 1) for i in range(MASK_SIDE)) ^ (2**64 - 1))  # j < 7


def close_masks(mask: np.ndarray) -> np.ndarray:
    """Fill the one-cell gaps of 8 x 8 occupancy masks: an empty cell whose two opposite neighbours are set.

    A sparse cell sets its mask bits where its few points happen to fall;
    a lone empty mask cell between two set ones (along u or along v) is
    sampling noise, not a hole in the surface.  Wider holes, the outline
    and the empty corners of a slanted region are kept.

    Examples
    --------
    >>> import numpy as np
    >>> full = np.uint64(2**64 - 1)
    >>> one_hole = full ^ np.uint64(1 << (3 * 8 + 4))               # cell (3, 4) empty
    >>> big_hole = full ^ np.uint64(sum(1 << (i * 8 + j) for i in range(2, 5) for j in range(2, 5)))
    >>> corner = full ^ np.uint64(1)                                 # cell (0, 0) empty: an outline
    >>> close_masks(np.array([one_hole, big_hole, corner])).tolist() == [int(full), int(big_hole), int(corner)]
    True
    """
    m = np.asarray(mask, dtype=np.uint64)
    one, row = np.uint64(1), np.uint64(MASK_SIDE)
    left = (m << one) & _NOT_FIRST  # bit (i, j) set where (i, j - 1) is
    right = (m >> one) & _NOT_LAST  # where (i, j + 1) is
    below = m << row  # where (i - 1, j) is
    above = m >> row  # where (i + 1, j) is
    return m | (left & right) | (below & above)


def _starts(counts: np.ndarray) -> np.ndarray:
    return np.r_[0, np.cumsum(counts)[:-1]].astype(np.int64) if counts.size else np.zeros(0, np.int64)


def _group_fits(moments: np.ndarray, centres: np.ndarray, group: np.ndarray, G: int):
    """Centroid, frame and quadric of each group of cells, from the cells' moments about their centres."""
    gm, c = sum_moments(moments, centres, group, G)
    f = fit_nodes(gm, moment_scale(gm))
    return c + f.centroid, f.frame, f.coeffs


#: Patch sizes (points) above this rank as equal in :func:`_assign` (32 bits of its key; patch indices take 24).
_SIZE_MAX = (1 << 32) - 1


def _assign(world, leaf, nb, surf_group, g_size, g_centroid, g_frame, g_coeffs, budget, limit, chunk=1 << 18):
    """Patch of every point (sorted by leaf): see step 3 of :func:`fit_models`.

    Returns the rows of the modelled points (ascending), their patch and their signed error (metres).
    """
    L = surf_group.shape[0]
    if g_size.size >= 1 << 24:
        raise PatchcloudValueError(f"{g_size.size} patches in one tile: at most {1 << 24} (use smaller tiles)")
    # candidate patches per leaf: its own and those of the leaves touching it (``nb``; CSR over leaves)
    both = np.concatenate([nb, nb[:, ::-1], np.column_stack([np.arange(L), np.arange(L)])])
    both = both[surf_group[both[:, 1]] >= 0]
    cand = unique_pairs(np.column_stack([both[:, 0], surf_group[both[:, 1]]]), max(int(g_size.size), 1))[0]
    c_start = np.searchsorted(cand[:, 0], np.arange(L + 1))
    out_pt, out_g, out_e = [], [], []
    for lo in range(0, leaf.size, chunk):
        hi = min(lo + chunk, leaf.size)
        lf = leaf[lo:hi]
        k = c_start[lf + 1] - c_start[lf]
        pt = np.repeat(np.arange(lo, hi), k)
        g = cand[np.repeat(c_start[lf], k) + np.arange(k.sum()) - np.repeat(np.cumsum(k) - k, k), 1]
        e = implicit_value(world[pt], g_centroid[g], g_frame[g], g_coeffs[g])
        own = g == surf_group[leaf[pt]]
        # rank (lowest wins): within the budget first, then by error in steps of a quarter budget,
        # then the largest patch, then the lowest patch index; one int64 key per candidate
        good = np.abs(e) <= budget
        step = np.where(good, np.minimum(np.floor(np.abs(e) * (4.0 / budget)), 4), 7).astype(np.int64)
        key = (step << 56) | ((_SIZE_MAX - np.minimum(g_size[g].astype(np.int64), _SIZE_MAX)) << 24) | g
        has = k > 0
        seg = (np.cumsum(k) - k)[has]  # first candidate of each point that has one
        best_key = np.minimum.reduceat(key, seg) if seg.size else np.zeros(0, np.int64)
        winner = np.flatnonzero(key == np.repeat(best_key, k[has]))  # one per point: keys differ by patch
        take = good[winner]
        # no patch within the budget: the own leaf's patch within the outlier limit
        own_ok = own & (np.abs(e) <= limit)
        fallback = np.zeros(hi - lo, dtype=np.int64) - 1
        fallback[pt[own_ok] - lo] = np.flatnonzero(own_ok)
        chosen = np.full(hi - lo, -1, dtype=np.int64)
        chosen[pt[winner[take]] - lo] = winner[take]
        chosen = np.where(chosen >= 0, chosen, fallback)
        sel = chosen[chosen >= 0]
        out_pt.append(pt[sel])
        out_g.append(g[sel])
        out_e.append(e[sel])
    cat = lambda parts, dt: np.concatenate(parts) if parts else np.zeros(0, dt)  # noqa: E731
    return cat(out_pt, np.int64), cat(out_g, np.int64), cat(out_e, np.float64)


def _pull_to_majority(world, leaf, pt, pg, perr, g_centroid, g_frame, g_coeffs, budget):
    """Points of a leaf split between patches go to the leaf's majority patch when it fits them within the budget.

    Where two patches overlap, each point of a leaf would otherwise pick
    whichever is closer, splitting the leaf into several cells (each a row
    of the file) for nothing; along a real edge the other face's points do
    not fit the majority patch and stay where they are.
    """
    if pt.size == 0:
        return pg, perr
    G = int(pg.max()) + 1
    pair = leaf[pt] * G + pg
    key, n_in = np.unique(pair, return_counts=True)
    k_leaf = key // G
    # the majority patch of each leaf (most points, then lowest patch index: keys are sorted)
    o = np.lexsort((key % G, -n_in, k_leaf))
    first = np.r_[True, k_leaf[o][1:] != k_leaf[o][:-1]]
    major = np.full(int(leaf.max()) + 1, -1, dtype=np.int64)
    major[k_leaf[o][first]] = (key % G)[o][first]
    m = major[leaf[pt]]
    other = np.flatnonzero(m != pg)
    if other.size == 0:
        return pg, perr
    g = m[other]
    e = implicit_value(world[pt[other]], g_centroid[g], g_frame[g], g_coeffs[g])
    move = np.abs(e) <= budget
    pg, perr = pg.copy(), perr.copy()
    pg[other[move]] = g[move]
    perr[other[move]] = e[move]
    return pg, perr


def fit_models(
    points: np.ndarray,
    max_error: float,
    *,
    d_min: float | None = None,
    max_edge: float | None = None,
    n_min: int = 12,
    min_sigma2: float = 0.01,
    outlier_factor: float = 3.0,
    merge: bool = True,
    root: tuple[np.ndarray, float] | None = None,
) -> ModelFit:
    """Patch models of a cloud within an error budget, and its residual points.

    Parameters
    ----------
    points : (N, 3) array, or laspy.LasData
        Coordinates (metres); any order.
    max_error : float
        The error budget (metres): the octree splits a leaf until its
        quadric's fit RMSE is below it (criterion ``rmse``), down to
        ``d_min``; touching leaves merge while one quadric fits their
        points with an RMSE below it.
    d_min, max_edge, n_min, min_sigma2 :
        As :func:`patchcloud.core.estimate_normals` (defaults from the point spacing).
    outlier_factor : float
        A point farther than ``outlier_factor * max_error`` from its
        quadric is kept as a residual point.
    merge : bool
        Merge touching leaves (default); False keeps one patch per leaf.
    root : (corner, edge), optional
        The octree's root cube (a tile of the stream); default: the points' bounding cube.

    Returns
    -------
    ModelFit

    Examples
    --------
    >>> import numpy as np
    >>> xy = np.random.default_rng(0).uniform(0, 8, (20000, 2))
    >>> fit = fit_models(np.column_stack([xy, 0.05 * xy[:, 0] ** 2]), 0.01)
    >>> len(fit.models), fit.residual.size, int(fit.models.count.sum())
    (2, 0, 20000)
    """
    pts, lo, hi = validate_points(points)
    budget = check_budget(max_error)
    o = NormalsOptions(d_min=d_min, max_edge=max_edge, n_min=n_min, min_sigma2=min_sigma2)  # (checks them)
    d_min, max_edge, n_min, min_sigma2 = o.d_min, o.max_edge, o.n_min, o.min_sigma2
    if isinstance(outlier_factor, (bool, str)) or not np.isfinite(outlier_factor) or outlier_factor < 1:
        raise PatchcloudValueError(f"outlier_factor must be at least 1, got {outlier_factor!r}")
    if not isinstance(merge, (bool, np.bool_)):
        raise PatchcloudValueError(f"merge must be True or False; got {merge!r}")
    n = pts.shape[0]
    if n < n_min:
        raise PatchcloudValueError(f"the cloud has {n} points, fewer than n_min={n_min}")
    corner, edge = root_cube(lo, hi, root)
    sorted_input = sort_points(pts - corner, np.zeros(3), edge)
    spacing = estimate_spacing(sorted_input[1], edge)
    if d_min is None:
        d_min = 3.0 * spacing if spacing > 0 else edge / 2.0**21
    if max_edge is None:
        max_edge = 256.0 * spacing if spacing > 0 else np.inf
    fit = fit_tile(
        pts, corner, edge, criterion="rmse", threshold=budget, d_min=d_min, max_edge=max_edge, n_min=n_min,
        min_sigma2=min_sigma2, orient="none", spacing=spacing, sorted_input=sorted_input,
    )
    t = fit.patches
    leaf = np.repeat(np.arange(len(t)), t.count)  # leaf of each sorted point
    world = fit.local + corner
    limit = outlier_factor * budget

    # 1. the points of surface leaves within the limit of their leaf's quadric
    surface = t.kind[leaf] == PatchKind.SURFACE
    ls = leaf[surface]
    kept = surface.copy()
    kept[surface] = np.abs(implicit_value(world[surface], t.centroid[ls], t.frame[ls], t.coeffs[ls])) <= limit
    kept &= (np.bincount(leaf[kept], minlength=len(t)) >= 3)[leaf]

    # 2. cells: the leaves that keep points; their moments about their centres; groups of them
    cell_leaf, cell_n = np.unique(leaf[kept], return_counts=True)
    level, ijk = t.level[cell_leaf], t.ijk[cell_leaf]
    cell_edge = _cell_edge(edge, level)
    centres = corner + (ijk + 0.5) * cell_edge[:, None]
    cell_of = np.full(len(t), -1, dtype=np.int64)
    cell_of[cell_leaf] = np.arange(cell_leaf.size)
    kw = world[kept]
    moments = np.zeros((cell_leaf.size, 35))
    if cell_leaf.size:
        cell_moments(kw, _starts(cell_n), centres, moments)
    nb = leaf_neighbours(t.level, t.ijk)  # all leaves' touching pairs; the cells' among them
    if merge and cell_leaf.size > 1:
        both = cell_of[nb]
        group = merge_leaves(moments, centres, level, ijk, budget, pairs=both[(both >= 0).all(axis=1)])
    else:
        group = np.arange(cell_leaf.size)
    G = int(group.max()) + 1 if group.size else 0
    g_centroid, g_frame, g_coeffs = _group_fits(moments, centres, group, G) if G else (np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 6)))

    # 3. every point to a patch: of the patches of its leaf and of the leaves touching it, those
    #    within the budget, the closest (to a quarter budget), then the largest (so a leaf bent round
    #    an edge gives its points to the faces); else its own leaf's patch within the outlier limit;
    #    else residual
    surf_group = np.full(len(t), -1, dtype=np.int64)
    surf_group[cell_leaf] = group
    g_size = np.bincount(group, weights=moments[:, 0], minlength=G)
    pt, pg, perr = _assign(world, leaf, nb, surf_group, g_size, g_centroid, g_frame, g_coeffs, budget, limit)
    pg, perr = _pull_to_majority(world, leaf, pt, pg, perr, g_centroid, g_frame, g_coeffs, budget)
    # cells: (leaf, patch) pairs holding 3 points or more, of patches holding n_min points or more
    pair = leaf[pt] * max(G, 1) + pg
    key, inv, n_in = np.unique(pair, return_inverse=True, return_counts=True)
    ok = n_in[inv] >= 3
    ok &= (np.bincount(pg[ok], minlength=G) >= n_min)[pg]
    pt, pg, perr, pair = pt[ok], pg[ok], perr[ok], pair[ok]
    key = np.unique(pair)
    c_leaf, c_group = key // max(G, 1), key % max(G, 1)
    live_group = np.bincount(c_group, minlength=G) > 0
    new_group = np.cumsum(live_group) - 1
    # cells ordered by patch, then by leaf
    o = np.lexsort((c_leaf, c_group))
    c_leaf, c_group = c_leaf[o], c_group[o]
    r = np.empty(key.size, dtype=np.int64)
    r[o] = np.arange(key.size)
    r = r[np.searchsorted(key, pair)]  # cell row of each modelled point
    C = key.size
    level, ijk = t.level[c_leaf], t.ijk[c_leaf]
    uvw = np.einsum("nij,ni->nj", g_frame[pg], world[pt] - g_centroid[pg])

    # 4. per cell: count, extent and occupancy mask of its points in its patch's frame
    u, v = uvw[:, 0], uvw[:, 1]
    count = np.bincount(r, minlength=C).astype(np.int64)
    extent = np.zeros((C, 4))
    mask = np.zeros(C, dtype=np.uint64)
    if C:
        order = np.argsort(r, kind="stable")
        st = _starts(count)
        uo, vo = u[order], v[order]
        extent = np.column_stack([np.minimum.reduceat(uo, st), np.maximum.reduceat(uo, st),
                                  np.minimum.reduceat(vo, st), np.maximum.reduceat(vo, st)])
        ro = r[order]
        bit = _cells(uo, extent[ro, 0], extent[ro, 1]) * MASK_SIDE + _cells(vo, extent[ro, 2], extent[ro, 3])
        mask = close_masks(np.bitwise_or.reduceat(np.left_shift(np.uint64(1), bit.astype(np.uint64)), st))
    cg = new_group[c_group]  # patch of each cell row
    P = int(live_group.sum())
    rmse = np.sqrt(np.bincount(cg[r], weights=perr**2, minlength=P) / np.maximum(np.bincount(cg[r], minlength=P), 1))
    models = PatchModels(
        root_corner=corner.copy(), root_edge=float(edge), centroid=g_centroid[live_group], frame=g_frame[live_group],
        coeffs=g_coeffs[live_group], rmse=rmse, cells=np.bincount(cg, minlength=P).astype(np.int64),
        level=level.astype(np.uint8), ijk=ijk, count=count, extent=extent, mask=mask,
    )
    rows = fit.order[pt]  # input rows of the modelled points
    patch = np.full(n, -1, dtype=np.int64)
    cell = np.full(n, -1, dtype=np.int64)
    error = np.zeros(n)
    patch[rows] = cg[r]
    cell[rows] = r
    error[rows] = perr
    return ModelFit(models=models, patch=patch, cell=cell, residual=np.flatnonzero(patch < 0), error=error)


def sample_models(models: PatchModels, counts: np.ndarray | None = None, *, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points on the patch surfaces: ``counts[c]`` (default: the cells' own counts) per cell.

    Each point is drawn uniformly over the occupied cells of its cell's
    mask, then lifted onto its patch's quadric; a point that falls outside
    its octree cell (where the box of the cell's points overhangs the
    cell) is drawn again, up to :data:`MAX_DRAWS` times.  The same models,
    counts and seed give the same points.

    Returns
    -------
    points : (M, 3) float64
        Caller's frame (metres).
    cell : (M,) int64
        Cell of each point (``models.cell_patch[cell]`` is its patch); points come cell after cell.

    Examples
    --------
    >>> import numpy as np
    >>> xy = np.random.default_rng(0).uniform(0, 8, (20000, 2))
    >>> fit = fit_models(np.column_stack([xy, np.zeros(20000)]), 0.01)
    >>> p, k = sample_models(fit.models)
    >>> p.shape, float(np.abs(p[:, 2]).max()) < 1e-9
    ((20000, 3), True)
    """
    if not isinstance(models, PatchModels):
        raise PatchcloudValueError(f"models must be PatchModels (fit_models(...).models, or dequantise_models), got {type(models).__name__}")
    C = models.count.shape[0]
    if counts is None:
        counts = models.count
    else:
        given = np.asarray(counts)
        whole = given.dtype.kind in "iu" or (given.dtype.kind == "f" and bool(np.all(np.isfinite(given) & (given == np.round(given)))))
        if given.shape != (C,) or not whole or (given < 0).any():
            raise PatchcloudValueError(f"counts must be {C} non-negative whole numbers, one per cell")
        counts = given.astype(np.int64)
    seeds = np.asarray(seed, dtype=object).reshape(-1)
    if not seeds.size or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 0 for v in seeds):
        raise PatchcloudValueError(f"seed must be a non-negative whole number, or a sequence of them; got {seed!r}")
    rng = np.random.default_rng(seed)
    bits = models.mask_bits()
    occupied = bits.sum(axis=1)
    cell_order = np.argsort(~bits, axis=1, kind="stable")  # the occupied cells first, in index order
    edge = models.edge
    lo = models.cell_corner()
    patch = models.cell_patch
    try:
        k = np.repeat(np.arange(C), counts)
        pts = np.empty((k.size, 3))
        todo = np.arange(k.size)
    except MemoryError:
        total = int(counts.sum())
        raise PatchcloudMemoryError(f"counts ask for {total:,} points ({total * 48 / 2**30:,.1f} GiB): more than this machine holds") from None
    args = (occupied, cell_order, np.ascontiguousarray(models.extent, dtype=np.float64), patch,
            np.ascontiguousarray(models.coeffs, dtype=np.float64), np.ascontiguousarray(models.centroid, dtype=np.float64),
            np.ascontiguousarray(models.frame, dtype=np.float64), np.ascontiguousarray(lo), np.ascontiguousarray(edge, dtype=np.float64))
    for attempt in range(MAX_DRAWS):  # a draw outside its octree cell is drawn again
        r = rng.random((todo.size, 3))
        outside = np.empty(todo.size, dtype=np.bool_)
        draw_on_patches(todo, k, r, *args, MASK_SIDE, pts, outside)
        todo = todo[outside]
        if todo.size == 0:
            break
    return pts, k


#: Share of the error budget each quantised quantity may use at most (four of them: < half the budget in all).
QUANT_SHARE = 1.0 / 8.0
#: Steps of a cell's (u, v) extent: the cell edge over this (an extent only says where samples go along the surface).
EXTENT_STEPS = 64


@dataclass(frozen=True)
class QuantisedModels:
    """Patch models as integers, each quantity with a step derived from the error budget and the patch's size.

    A patch's *scale* ``E = root_edge / 2**scale`` is chosen so that every
    point of its cells lies within ``sqrt(3) E`` of its centroid.  With
    ``eps`` the budget, the steps below then keep the surface of the
    dequantised model within ``4 * QUANT_SHARE * eps`` (half the budget)
    of the fitted one over its cells: centroid ``eps/8 / (sqrt(3)/2)`` per
    axis (from the root corner), rotation vector ``eps/8 / (3 E)`` radians
    per component, ``f`` ``eps/8``, ``d, e`` ``eps/8 / (2 sqrt(3) E)``,
    ``a, b, c`` ``eps/8 / (9 E^2)``.  A cell's extent is kept in steps of
    its own edge ``/ EXTENT_STEPS``, from the projection of the cell's
    centre on the (dequantised) patch frame.

    Attributes
    ----------
    max_error : float
        The budget the steps derive from (metres).
    root_corner, root_edge, cells, level, ijk, count, mask :
        As :class:`PatchModels` (exact).
    scale : (P,) int8
        The patch's scale (see above).
    centroid : (P, 3) int64
    rotation : (P, 3) int64
        Rotation vector of the frame.
    coeffs : (P, 6) int64
    rmse : (P,) float32
    extent : (C, 4) int64
    """

    max_error: float
    root_corner: np.ndarray
    root_edge: float
    scale: np.ndarray
    centroid: np.ndarray
    rotation: np.ndarray
    coeffs: np.ndarray
    rmse: np.ndarray
    cells: np.ndarray
    level: np.ndarray
    ijk: np.ndarray
    count: np.ndarray
    extent: np.ndarray
    mask: np.ndarray

    def __len__(self) -> int:
        return int(self.scale.shape[0])


def _steps(root_edge: float, scale: np.ndarray, max_error: float) -> dict[str, np.ndarray]:
    """Quantisation steps per patch (see :class:`QuantisedModels`)."""
    E = _cell_edge(root_edge, scale)
    share = QUANT_SHARE * max_error
    quad = share / (9.0 * E * E)
    lin = share / (2.0 * np.sqrt(3.0) * E)
    return {
        "centroid": share / (np.sqrt(3.0) / 2.0),
        "rotation": share / (3.0 * E),
        "coeffs": np.column_stack([quad, quad, quad, lin, lin, np.full_like(E, share)]),
    }


def _patch_scale(models: PatchModels, margin: float) -> np.ndarray:
    """(P,) int8: the largest level whose ``sqrt(3) * edge`` reaches from each centroid (moved by up to ``margin``) to all its cells."""
    if len(models) == 0:
        return np.zeros(0, np.int8)
    lo = models.cell_corner()
    c = models.centroid[models.cell_patch]
    far = np.maximum(np.abs(lo - c), np.abs(lo + models.edge[:, None] - c))
    reach = np.zeros(len(models))
    np.maximum.at(reach, models.cell_patch, np.linalg.norm(far, axis=1))
    scale = np.floor(np.log2(np.sqrt(3.0) * models.root_edge / (reach + margin)))
    return np.clip(scale, -64, 64).astype(np.int8)


def _cell_origin(models: PatchModels) -> np.ndarray:
    """(C, 2) the (u, v) of each cell's centre in its patch's frame: the origin of its quantised extent."""
    centre = models.cell_corner() + 0.5 * models.edge[:, None]
    p = models.cell_patch
    return np.einsum("nij,ni->nj", models.frame[p][:, :, :2], centre - models.centroid[p])


def quantise_models(models: PatchModels, max_error: float) -> QuantisedModels:
    """Integers standing for ``models`` within half of ``max_error`` (metres); see :class:`QuantisedModels`.

    Examples
    --------
    >>> import numpy as np
    >>> d = np.random.default_rng(0).normal(size=(20000, 3))
    >>> fit = fit_models(d / np.linalg.norm(d, axis=1)[:, None], 0.005)
    >>> back = dequantise_models(quantise_models(fit.models, 0.005))
    >>> float(np.abs(back.coeffs - fit.models.coeffs).max()) < 0.005
    True
    """
    if not isinstance(models, PatchModels):
        raise PatchcloudValueError(f"models must be a PatchModels (fit_models(...).models), got a {type(models).__name__}")
    from scipy.spatial.transform import Rotation

    budget = check_budget(max_error)
    scale = _patch_scale(models, budget)
    st = _steps(models.root_edge, scale, budget)
    rot = Rotation.from_matrix(models.frame).as_rotvec() if len(models) else np.zeros((0, 3))
    q = QuantisedModels(
        max_error=budget, root_corner=models.root_corner.copy(), root_edge=models.root_edge, scale=scale,
        centroid=np.rint((models.centroid - models.root_corner) / st["centroid"]).astype(np.int64),
        rotation=np.rint(rot / st["rotation"][:, None]).astype(np.int64),
        coeffs=np.rint(models.coeffs / st["coeffs"]).astype(np.int64), rmse=models.rmse.astype(np.float32),
        cells=models.cells.copy(), level=models.level.copy(), ijk=models.ijk.copy(), count=models.count.copy(),
        extent=np.zeros((models.count.shape[0], 4), np.int64), mask=models.mask.copy(),
    )
    # extents from the cells' centres as the decoder will see them (dequantised frames and centroids)
    origin = _cell_origin(dequantise_models(q))
    step = models.edge[:, None] / EXTENT_STEPS
    ext = models.extent - origin[:, [0, 0, 1, 1]]
    q.extent[:] = np.column_stack([np.floor(ext[:, 0:1] / step), np.ceil(ext[:, 1:2] / step),
                                   np.floor(ext[:, 2:3] / step), np.ceil(ext[:, 3:4] / step)]).astype(np.int64)
    return q


def patch_distances(models: PatchModels, points: np.ndarray, patch: np.ndarray) -> np.ndarray:
    """(N,) float64: the distance (metres) from each point to the quadric of its patch, along the patch's third axis.

    ``|w - S(u, v)|`` in the patch's frame: at least the distance to the
    surface.  ``points`` (N, 3) in the models' frame, ``patch`` (N,) rows of
    ``models``.

    >>> import numpy as np
    >>> xy = np.random.default_rng(0).uniform(0, 8, (5000, 2))
    >>> fit = fit_models(np.column_stack([xy, np.zeros(5000)]), 0.01)
    >>> float(patch_distances(fit.models, np.array([[4.0, 4.0, 0.003]]), fit.patch[:1]).round(6)[0])
    0.003
    """
    if not isinstance(models, PatchModels):
        raise PatchcloudValueError(f"models must be a PatchModels (fit_models(...).models), got a {type(models).__name__}")
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise PatchcloudValueError(f"points must be an (N, 3) array, got shape {pts.shape}")
    p = np.asarray(patch)
    if p.shape != (pts.shape[0],) or (p.size and not np.issubdtype(p.dtype, np.integer)):
        raise PatchcloudValueError(f"patch must be ({pts.shape[0]},) whole numbers, one per point, got shape {p.shape} and type {p.dtype}")
    p = p.astype(np.int64)
    if p.size and (p.min() < 0 or p.max() >= len(models.count)):
        bad = p[(p < 0) | (p >= len(models.count))][0]
        raise PatchcloudValueError(f"patch must hold rows of the {len(models.count)} models (0 to {len(models.count) - 1}); got {bad} "
                                   "(fit_models gives -1 to residual points, which have no patch: leave them out)")
    return np.abs(implicit_value(pts, models.centroid[p], models.frame[p], models.coeffs[p]))


def dequantise_models(q: QuantisedModels) -> PatchModels:
    """The patch models a :class:`QuantisedModels` stands for."""
    if not isinstance(q, QuantisedModels):
        raise PatchcloudValueError(f"q must be a QuantisedModels (quantise_models(...)), got a {type(q).__name__}")
    from scipy.spatial.transform import Rotation

    st = _steps(q.root_edge, q.scale, q.max_error)
    frame = Rotation.from_rotvec(q.rotation * st["rotation"][:, None]).as_matrix() if len(q) else np.zeros((0, 3, 3))
    m = PatchModels(
        root_corner=q.root_corner.copy(), root_edge=q.root_edge, centroid=q.root_corner + q.centroid * st["centroid"],
        frame=frame.reshape(-1, 3, 3), coeffs=q.coeffs * st["coeffs"], rmse=q.rmse.astype(np.float64),
        cells=q.cells.copy(), level=q.level.copy(), ijk=q.ijk.copy(), count=q.count.copy(),
        extent=np.zeros((q.count.shape[0], 4)), mask=q.mask.copy(),
    )
    step = m.edge[:, None] / EXTENT_STEPS
    m.extent[:] = q.extent * step + _cell_origin(m)[:, [0, 0, 1, 1]]
    return m
