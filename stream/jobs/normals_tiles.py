"""Per-tile steps of ``patchcloud normals``: the functions dask runs, one task per tile (or per pair of tiles).

Every step reads what it needs from the store, writes its arrays, and only
then marks the tile done for that step, so a task can be run again after a
crash or on another worker without losing or duplicating anything
(idempotent), and a rerun skips the tiles already done.  Each takes the
store's URL (not an open store), so it can run in another process.
"""

from __future__ import annotations

import numpy as np

from patchcloud.core import (
    LeafSet, Method, PatchKind, Skin, cross_face_pairs, finish_tile, fit_tile, folded, link_agreements, point_keys,
    rmse_histograms, surface_normals,
)

from patchcloud.stream.engine.job import params_key
from patchcloud.stream.io.store import Store, piece_name, piece_rows, table_to_array

__all__ = ["calibrate_tile", "fit_one_tile", "seam_links", "finish_one_tile", "finish_values", "finish_names", "mark_finished_pieces",
           "turn_up", "FINISH_ARRAYS", "PRINCIPAL_ARRAYS"]


def turn_up(normals: np.ndarray, scalars: np.ndarray, dir1: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PDAL's ``always_up``: each normal with a negative z flipped, point by point, with what depends on its side.

    Seen from the other side a surface's curvatures change sign: ``(k1,
    k2)`` (``scalars[:, 1:3]``) becomes ``(-k2, -k1)``, still ``k1 >= k2``,
    and the k1 direction becomes the old k2 direction, ``cross(n, dir1)``;
    the surface variation (``scalars[:, 0]``) does not change.  Returns new
    arrays; (N, 3), (N, 3) and (N, 3) float64 in, the same out.

    >>> n, sc, d = turn_up(np.array([[0.0, 0.6, -0.8], [0.0, 0.0, 1.0]]), np.array([[0.1, 2.0, -1.0], [0.0, 1.0, 1.0]]),
    ...                    np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]))
    >>> n.tolist(), sc.tolist(), d[0].round(2).tolist()
    ([[-0.0, -0.6, 0.8], [0.0, 0.0, 1.0]], [[0.1, 1.0, -2.0], [0.0, 1.0, 1.0]], [0.0, -0.8, -0.6])
    """
    normals, scalars, dir1 = normals.copy(), scalars.copy(), dir1.copy()
    rows = np.flatnonzero(normals[:, 2] < 0)
    n = normals[rows]
    dir1[rows] = np.cross(n, dir1[rows])
    normals[rows] = -n
    k1, k2 = scalars[rows, 1].copy(), scalars[rows, 2].copy()
    scalars[rows, 1], scalars[rows, 2] = -k2, -k1
    return normals, scalars, dir1


def calibrate_tile(url: str, ijk: tuple, d_min: float, n_min: int) -> np.ndarray:
    """The tile's share of the default threshold's histograms (:func:`patchcloud.core.rmse_histograms`).

    Cells of the absolute grid, so the sum over the tiles is the whole
    cloud's, whatever the tiling (tiles at least twice the calibration
    cells), and :func:`patchcloud.core.estimate_normals` resolves the same
    threshold on the same points.
    """
    store = Store.open(url)
    grid = store.grid
    return rmse_histograms(grid.local(store.read(ijk, "xyz")), d_min, n_min, origin=grid.origin)


def fit_one_tile(url: str, ijk: tuple, params: dict) -> dict:
    """Fit a tile's octree; store its patch table, orientation forest and skin."""
    store = Store.open(url)
    if store.tile_done(ijk, "fit"):
        return store.tile_attrs(ijk)["fit"]
    grid = store.grid
    T = grid.tile_size
    corner = grid.corner(ijk)
    xyz = store.read(ijk, "xyz")
    pts = grid.local(xyz)
    q, keys = point_keys(pts - corner, T)
    vp = params.get("viewpoint_local")
    fit = fit_tile(
        pts, corner, T, criterion=params["criterion"], threshold=params["threshold"], d_min=params["d_min"],
        max_edge=params["max_edge"], n_min=params["n_min"], min_sigma2=params["min_sigma2"], orient=params["orient"],
        viewpoint=None if vp is None else np.asarray(vp), centre=np.asarray(params["centre_local"]),
        spacing=params["spacing"], sorted_input=(np.arange(xyz.shape[0]), keys, q),
    )
    t = fit.patches
    store.write(ijk, "patches", table_to_array(t))
    store.write(ijk, "links", fit.links)
    store.write(ijk, "agreement", fit.agreement)
    store.write(ijk, "score", fit.score)
    halo = params["halo"]
    local = pts - corner
    near = np.any(local < halo, axis=1) | np.any(local >= T - halo, axis=1)
    leaf = np.repeat(np.arange(len(t), dtype=np.uint32), t.count)
    store.write(ijk, "skin", xyz[near])
    store.write(ijk, "skin_patch", leaf[near])
    kinds = np.bincount(t.kind, weights=t.count, minlength=3)
    info = dict(
        patches=len(t), kinds=np.bincount(t.kind, minlength=3).tolist(), points_by_kind=kinds.astype(np.int64).tolist(),
        skin=int(near.sum()),
    )
    store.mark_tile(ijk, "fit", fit=info)
    return info


def seam_links(url: str, a: tuple, b: tuple, axis: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orientation links between the leaves of tiles ``a`` and ``b`` (``b`` next to ``a`` on +``axis``).

    Returns
    -------
    rows_a, rows_b : (E,) int64 patch rows in ``a`` and ``b``
    agreement : (E,) float64
    """
    store = Store.open(url, mode="r")
    A, B = store.patch_table(a), store.patch_table(b)
    corner = store.grid.corner(a)
    LA, LB = LeafSet.of_table(A, corner), LeafSet.of_table(B, corner)
    (ia, jb, da), (ib, ja, db) = cross_face_pairs(A, B, axis)
    ia, jb, x = link_agreements(LA, ia, LB, jb, da)
    ib, ja, y = link_agreements(LB, ib, LA, ja, db)
    return np.concatenate([ia, ja]), np.concatenate([jb, ib]), np.concatenate([x, y])


_FACES = [(-1, 0, 0), (1, 0, 0), (0, -1, 0), (0, 1, 0), (0, 0, -1), (0, 0, 1)]


#: The per-point arrays the finish step writes, in the order :func:`finish_values` returns them.
FINISH_ARRAYS = ("normal", "curvature", "method", "patch")
#: With the principal curvatures, these follow.
PRINCIPAL_ARRAYS = ("principal", "direction")


def finish_values(url: str, ijk: tuple, params: dict, neighbours: list[tuple], only: np.ndarray | None = None) -> list:
    """The finish step's per-point arrays (:data:`FINISH_ARRAYS`, then :data:`PRINCIPAL_ARRAYS` when asked for) of a
    tile's points in sorted order, all of them or those where ``only`` ((N,) bool, sorted order:
    :func:`patchcloud.core.finish_tile`), with the types they are written with."""
    store = Store.open(url)
    grid = store.grid
    T = grid.tile_size
    corner = grid.corner(ijk)
    local = grid.local(store.read(ijk, "xyz"))
    local -= corner  # in place: one (N, 3) array, not two
    table = store.patch_table(ijk)
    sign = store.read(ijk, "sign").astype(np.float64)
    present = {tuple(n) for n in neighbours}
    oriented: dict[tuple, object] = {}

    def oriented_table(n):
        if n not in oriented:
            oriented[n] = store.patch_table(n).flipped(store.read(n, "sign") < 0)
        return oriented[n]

    outside = []
    for step in _FACES:
        n = tuple(int(a + s) for a, s in zip(ijk, step))
        outside.append(oriented_table(n) if n in present else None)
    halo = params["halo"]
    sk_pts, sk_nrm, sk_ok = [], [], []
    for n in sorted(present):  # the skin, for moment and k-NN normals: of edge and sparse leaves, of folded surface points
        sx = store.read(n, "skin")
        if sx.shape[0] == 0:
            continue
        p = grid.local(sx)
        inside = np.all((p >= corner - halo) & (p < corner + T + halo), axis=1)
        if not inside.any():
            continue
        p = p[inside]
        rows = store.read(n, "skin_patch")[inside].astype(np.int64)
        t = oriented_table(n)
        surf = t.kind[rows] == PatchKind.SURFACE
        nrm = np.zeros_like(p)
        if surf.any():
            r = rows[surf]
            nrm[surf] = surface_normals(p[surf], t.centroid[r], t.frame[r], t.coeffs[r])
            surf[surf] = ~folded(nrm[surf], t.frame[r, :, 2])  # as finish_tile's own points: no vote where it folds
        sk_pts.append(p)
        sk_nrm.append(nrm)
        sk_ok.append(surf)
    skin = Skin(np.concatenate(sk_pts), np.concatenate(sk_nrm), np.concatenate(sk_ok)) if sk_pts else None
    vp = params.get("viewpoint_local")
    res = finish_tile(
        local, table, sign, d_min=params["d_min"], min_sigma2=params["min_sigma2"],
        k_fallback=params["k_fallback"], orient=params["orient"],
        viewpoint=None if vp is None else np.asarray(vp), centre=np.asarray(params["centre_local"]), blend=params["blend"],
        outside=outside, skin=skin, only=only,
    )
    normals, scalars, dir1 = res.normals, res.scalars, res.dir1
    if params.get("always_up"):  # PDAL's always_up: point by point, after the orientation
        normals, scalars, dir1 = turn_up(normals, scalars, dir1)
    out = [normals.astype(np.float32), scalars[:, 0].astype(np.float32), res.method.astype(np.uint8), res.patch.astype(np.uint32)]
    if params.get("principal_curvatures"):  # k1, k2 and k1's direction; 0 where a point has none (NaN-free output)
        out += [np.nan_to_num(scalars[:, 1:3], nan=0.0, posinf=0.0, neginf=0.0).astype(np.float32),
                np.nan_to_num(dir1, nan=0.0, posinf=0.0, neginf=0.0).astype(np.float32)]
    return out


def _write_finished(store: Store, ijk: tuple, params: dict, values: list) -> dict:
    """Write the finish step's arrays (sorted order, :func:`finish_values`) in the tile's input order; mark it done."""
    names = finish_names(params)
    _write_rows(store, ijk, names, values, store.read(ijk, "rank").astype(np.int64))
    store.unmark_pieces(ijk, names)  # written whole, whatever an earlier run wrote in pieces
    info = dict(methods=_method_counts(values).tolist())
    store.mark_tile(ijk, "finish", finish=info)
    return info


def _write_rows(store: Store, ijk: tuple, names, values: list, at: np.ndarray) -> None:
    """Write each of ``values`` (sorted order) as array ``names[i]`` of tile ``ijk``, its rows put at ``at``."""
    for name, v in zip(names, values):
        out = np.empty_like(v)
        out[at] = v
        store.write(ijk, name, out)


def _method_counts(values: list) -> np.ndarray:
    """Points per ``Method`` code (0 first) of the finish step's arrays (:func:`finish_values`)."""
    return np.bincount(values[2], minlength=len(Method) + 1).astype(np.int64)


def finish_names(params: dict) -> tuple[str, ...]:
    """The arrays the finish step writes with these parameters."""
    return FINISH_ARRAYS + (PRINCIPAL_ARRAYS if params.get("principal_curvatures") else ())


def _piece_stem(name: str, params: dict) -> str:
    """The stem of the pieces of array ``name`` written with these parameters (:func:`piece_name`): a run with other
    parameters writes other arrays, so a piece recorded as done is one of this run's parameters."""
    return f"{name}-{params_key(params)}"


def _piece_done_name(params: dict, j: int, k: int) -> str:
    """The array that says piece ``j`` of ``k`` is written with these parameters: its method counts."""
    return piece_name(_piece_stem("finish", params), j, k)


def finish_one_tile(url: str, ijk: tuple, params: dict, neighbours: list[tuple], piece: tuple[int, int] | None = None) -> dict:
    """Final normals and curvature of a tile's points, blended and oriented across tile faces.

    With ``piece=(j, k)``, only piece ``j`` of ``k``: the points of rows
    ``piece_rows(n, j, k)`` of the tile's input order, written as pieces of
    the arrays (:func:`patchcloud.stream.io.store.piece_name`) that
    :func:`mark_finished_pieces` then records as the tile's.  A big tile's
    pieces run side by side; each point gets the same values as from the
    whole tile's task.  Returns the method counts (of the piece).
    """
    store = Store.open(url)
    if store.tile_done(ijk, "finish"):
        return store.tile_attrs(ijk)["finish"]
    if piece is None:
        return _write_finished(store, ijk, params, finish_values(url, ijk, params, neighbours))
    j, k = piece
    done = _piece_done_name(params, j, k)
    if store.has(ijk, done):
        return dict(methods=store.read(ijk, done).tolist())
    rank = store.read(ijk, "rank").astype(np.int64)
    lo, hi = piece_rows(rank.size, j, k)
    only = (rank >= lo) & (rank < hi)
    values = finish_values(url, ijk, params, neighbours, only)
    _write_rows(store, ijk, [piece_name(_piece_stem(name, params), j, k) for name in finish_names(params)], values, rank[only] - lo)
    counts = _method_counts(values)
    store.write(ijk, done, counts)  # last: the piece is complete
    return dict(methods=counts.tolist())


def mark_finished_pieces(store: Store, ijk: tuple, params: dict, k: int) -> dict:
    """Once every piece of tile ``ijk`` is written (:func:`finish_one_tile` with ``piece``): record its arrays as
    ``k`` pieces and the tile's finish step as done (one writer: the client, after the step), with the method counts."""
    counts = sum(np.asarray(store.read(ijk, _piece_done_name(params, j, k)), dtype=np.int64) for j in range(k))
    store.mark_pieces(ijk, {name: _piece_stem(name, params) for name in finish_names(params)}, k)
    info = dict(methods=counts.tolist())
    store.mark_tile(ijk, "finish", finish=info)
    for j in range(k):  # a later run that redoes the step redoes every piece
        store.delete(ijk, _piece_done_name(params, j, k))
    return info
