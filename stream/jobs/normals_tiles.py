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
    FLOOR_FACTOR, MAX_DEPTH, NOISE_FACTOR, LeafSet, PatchKind, Skin, cell_moments, cross_face_pairs, decode, finish_tile,
    fit_nodes, fit_tile, link_agreements, max_level_for, point_keys, surface_normals,
)

from patchcloud.stream.io.store import Store, table_to_array

__all__ = ["calibrate_tile", "threshold_from_histogram", "fit_one_tile", "seam_links", "finish_one_tile", "RMSE_BINS"]

#: log10 bin edges of the fit-RMSE histograms (metres) behind the default threshold: 0.25 % wide.
RMSE_BINS = np.linspace(-7.0, 2.0, 9 * 400 + 1)
#: Finest cells used for the default threshold: those whose hash falls in 1 of this many.
CALIBRATION_STRIDE = 8


def calibrate_tile(url: str, ijk: tuple, d_min: float, n_min: int) -> np.ndarray:
    """Histogram (over :data:`RMSE_BINS`) of the quadric-fit RMSE of the finest cells of a tile.

    The cells are those of edge ``d_min`` rounded as the octree does, with
    at least ``n_min`` points, and one in :data:`CALIBRATION_STRIDE` of them
    chosen by a hash of their absolute position: the same cells whatever
    the tiling, so the median over all tiles, like the in-memory default
    (``patchcloud.core.estimate_normals``' default threshold), measures the scanner
    noise of the whole cloud.
    """
    store = Store.open(url)
    grid = store.grid
    T = grid.tile_size
    local = grid.local(store.read(ijk, "xyz")) - grid.corner(ijk)
    _, keys = point_keys(local, T)
    level = max_level_for(T, d_min)
    c = keys >> np.uint64(3 * (MAX_DEPTH - level))
    starts = np.flatnonzero(np.r_[True, c[1:] != c[:-1]])
    counts = np.diff(np.r_[starts, c.size])
    cells = decode(c[starts])
    absolute = cells + np.asarray(ijk, dtype=np.int64) * (1 << level)
    h = (absolute * np.array([73856093, 19349663, 83492791])).sum(axis=1)
    keep = (counts >= n_min) & (np.mod(h, CALIBRATION_STRIDE) == 0)
    hist = np.zeros(RMSE_BINS.size - 1, dtype=np.int64)
    if not keep.any():
        return hist
    edge = T / 2.0**level
    centres = (cells + 0.5) * edge
    moments = np.empty((starts.size, 35))
    cell_moments(local, starts, centres, moments)
    fit = fit_nodes(moments[keep], np.full(int(keep.sum()), edge / 2.0))
    rmse = np.maximum(fit.rmse, 10.0 ** RMSE_BINS[0])
    hist += np.histogram(np.log10(rmse), bins=RMSE_BINS)[0]
    return hist


def threshold_from_histogram(hist: np.ndarray, spacing: float) -> float:
    """The default RMSE threshold (metres): NOISE_FACTOR x the histogram's median, at least FLOOR_FACTOR x spacing."""
    total = int(hist.sum())
    noise = 0.0
    if total:
        k = int(np.searchsorted(np.cumsum(hist), (total + 1) // 2))
        noise = float(10.0 ** (0.5 * (RMSE_BINS[k] + RMSE_BINS[k + 1])))
    return max(NOISE_FACTOR * noise, FLOOR_FACTOR * spacing)


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


def finish_one_tile(url: str, ijk: tuple, params: dict, neighbours: list[tuple]) -> dict:
    """Final normals and curvature of a tile's points, blended and oriented across tile faces."""
    store = Store.open(url)
    if store.tile_done(ijk, "finish"):
        return store.tile_attrs(ijk)["finish"]
    grid = store.grid
    T = grid.tile_size
    corner = grid.corner(ijk)
    xyz = store.read(ijk, "xyz")
    local = grid.local(xyz) - corner
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
    needs_knn = bool(np.any(table.kind != PatchKind.SURFACE))  # only k-NN normals look at the skin
    for n in sorted(present) if needs_knn else []:
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
        sk_pts.append(p)
        sk_nrm.append(nrm)
        sk_ok.append(surf)
    skin = Skin(np.concatenate(sk_pts), np.concatenate(sk_nrm), np.concatenate(sk_ok)) if sk_pts else None
    vp = params.get("viewpoint_local")
    res = finish_tile(
        local, table, sign, d_min=params["d_min"], k_fallback=params["k_fallback"], orient=params["orient"],
        viewpoint=None if vp is None else np.asarray(vp), centre=np.asarray(params["centre_local"]), blend=params["blend"],
        outside=outside, skin=skin,
    )
    rank = store.read(ijk, "rank").astype(np.int64)
    n = rank.shape[0]
    out_n = np.empty((n, 3), np.float32)
    out_c = np.empty(n, np.float32)
    out_m = np.empty(n, np.uint8)
    out_p = np.empty(n, np.uint32)
    out_n[rank] = res.normals
    out_c[rank] = res.scalars[:, 0]
    out_m[rank] = res.method
    out_p[rank] = res.patch
    store.write(ijk, "normal", out_n)
    store.write(ijk, "curvature", out_c)
    store.write(ijk, "method", out_m)
    store.write(ijk, "patch", out_p)
    if params.get("principal_curvatures"):  # k1, k2 and k1's direction; 0 where a point has none (NaN-free output)
        out_k = np.empty((n, 2), np.float32)
        out_d = np.empty((n, 3), np.float32)
        out_k[rank] = np.nan_to_num(res.scalars[:, 1:3], nan=0.0, posinf=0.0, neginf=0.0)
        out_d[rank] = np.nan_to_num(res.dir1, nan=0.0, posinf=0.0, neginf=0.0)
        store.write(ijk, "principal", out_k)
        store.write(ijk, "direction", out_d)
    info = dict(methods=np.bincount(res.method, minlength=4).tolist())
    store.mark_tile(ijk, "finish", finish=info)
    return info
