"""Per-tile steps of ``patchcloud don`` and ``patchcloud segment``: the functions dask runs, one task per tile.

As in :mod:`.normals_tiles`, each reads what it needs from the store, writes its
arrays and only then marks the tile done (with the key of the parameters
it ran with), so a task can be rerun after a crash and a rerun with the
same parameters skips it.  Everything is computed in the store's local
frame (``X * scale + offset - origin``, the same for every tile), so a
tile with its halo sees exactly the coordinates a whole-cloud run sees.

1. :func:`skin_tile`: the tile's points within the halo width of its faces
   (what its neighbours need of it);
2. :func:`don_tile`: DoN of the tile's points from the tile plus its
   neighbours' skins (radius normals need every point within ``r_large``);
   with a threshold, which points are kept;
3. :func:`cluster_tile`: Euclidean components of the kept points of the
   tile plus the kept points of the neighbours' skins within the
   tolerance; the links from the tile's components to neighbours' points;
4. :func:`merge_components` (in the client): one union-find over every
   tile's components and links gives segments across tile faces, filtered
   by their whole size.
"""

from __future__ import annotations

import numpy as np

from patchcloud.core import components, connected_components, don_magnitude, don_mask, number_by_first, radius_normals

from patchcloud.stream.io.store import Store

__all__ = ["skin_tile", "don_tile", "cluster_tile", "merge_components", "HIST_BINS"]

#: Bins of the DoN magnitude histograms kept per tile (for summaries and reports).
HIST_BINS = 50


def _halo_points(store: Store, ijk, neighbours, width: float, need_keep: bool = False):
    """Points of the neighbours' skins within ``width`` of tile ``ijk``'s box (box distance per axis).

    Returns local coordinates (K, 3), and per point its tile (K, 3) and row
    in that tile's sorted arrays (K,); with ``need_keep``, only points the
    DoN step kept.
    """
    grid = store.grid
    lo = grid.corner(ijk) - width
    hi = grid.corner(ijk) + grid.tile_size + width
    pts, tiles, rows = [], [], []
    for n in sorted(tuple(v) for v in neighbours):
        sk = store.read(n, "don_skin")
        if sk.shape[0] == 0:
            continue
        p = grid.local(sk)
        inside = np.all((p >= lo) & (p < hi), axis=1)
        r = store.read(n, "don_skin_rows").astype(np.int64)
        if need_keep:
            inside &= store.read(n, "keep")[r]
        if inside.any():
            pts.append(p[inside])
            rows.append(r[inside])
            tiles.append(np.broadcast_to(np.asarray(n, dtype=np.int64), (int(inside.sum()), 3)))
    if not pts:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
    return np.concatenate(pts), np.concatenate(tiles), np.concatenate(rows)


def _write_in_input_order(store: Store, ijk, name: str, values: np.ndarray) -> None:
    """Store rows given in the tile's sorted order as array ``name`` in the tile's input order (what export reads)."""
    rank = store.read(ijk, "rank").astype(np.int64)
    out = np.empty_like(values)
    out[rank] = values
    store.write(ijk, name, out)


def skin_tile(url: str, ijk: tuple, width: float, key: str) -> int:
    """Store the tile's points within ``width`` (metres) of its faces: ``don_skin`` and their rows ``don_skin_rows``."""
    store = Store.open(url)
    if store.tile_done(ijk, "don_skin", key):
        return int(store.tile_attrs(ijk)["don_skin_points"])
    grid = store.grid
    xyz = store.read(ijk, "xyz")
    local = grid.local(xyz) - grid.corner(ijk)
    near = np.any(local < width, axis=1) | np.any(local >= grid.tile_size - width, axis=1)
    store.write(ijk, "don_skin", xyz[near])
    store.write(ijk, "don_skin_rows", np.flatnonzero(near).astype(np.int64))
    store.mark_tile(ijk, "don_skin", key, don_skin_points=int(near.sum()))
    return int(near.sum())


def don_tile(url: str, ijk: tuple, params: dict, neighbours: list) -> dict:
    """DoN of the tile's points; stores ``don`` (input order, float64) and ``keep`` (sorted order)."""
    store = Store.open(url)
    key = params["don_key"]
    if store.tile_done(ijk, "don", key):
        return store.tile_attrs(ijk)["don"]
    grid = store.grid
    own = grid.local(store.read(ijk, "xyz"))
    halo, _, _ = _halo_points(store, ijk, neighbours, params["don_width"])
    pts = np.concatenate([own, halo])
    at = np.arange(own.shape[0])
    kw = dict(
        viewpoint=np.asarray(params["viewpoint_local"]), mode=params["mode"], resolution=params["resolution"],
        min_points=params["min_points"], at=at, origin=np.zeros(3),  # the store's frame: its origin is the grid's
        rounding=params["rounding"], grid_step=params.get("grid_step", 0.0),
    )
    n_small = radius_normals(pts, params["r_small"], density=params.get("density_small"), **kw)
    n_large = radius_normals(pts, params["r_large"], density=params.get("density_large"), **kw)
    don = (n_small - n_large) / 2.0
    mag = don_magnitude(don)
    defined = np.isfinite(mag)
    if params.get("threshold") is not None:
        keep = don_mask(don, params["threshold"], axis=params.get("axis"), axis_threshold=params.get("axis_threshold"))
    else:
        keep = np.zeros(own.shape[0], dtype=bool)
    _write_in_input_order(store, ijk, "don", don)
    store.write(ijk, "keep", keep)
    info = dict(
        points=int(own.shape[0]), halo=int(halo.shape[0]), defined=int(defined.sum()), kept=int(keep.sum()),
        hist=np.histogram(mag[defined], bins=HIST_BINS, range=(0.0, 1.0))[0].tolist(),
    )
    store.mark_tile(ijk, "don", key, don=info)
    return info


def cluster_tile(url: str, ijk: tuple, params: dict, neighbours: list) -> dict:
    """Components of the tile's kept points (with the kept points of the neighbours' skins within tolerance).

    Stores ``comp`` (input order, int32, -1 for points not kept),
    ``comp_size`` (points of the tile in each component), ``skin_comp``
    (the component of each skin row, for the neighbours' links) and
    ``seg_links`` (C, tile i, j, k, row): this tile's component C holds a
    point within tolerance of that row of that neighbour.
    """
    store = Store.open(url)
    key = params["cluster_key"]
    if store.tile_done(ijk, "cluster", key):
        return store.tile_attrs(ijk)["cluster"]
    grid = store.grid
    own = grid.local(store.read(ijk, "xyz"))
    keep = store.read(ijk, "keep")
    kept = np.flatnonzero(keep)
    halo, h_tile, h_row = _halo_points(store, ijk, neighbours, params["tolerance"] * (1 + 1e-9), need_keep=True)
    comp_all = components(np.concatenate([own[kept], halo]), params["tolerance"], params.get("grid_step", 0.0)) if kept.size + halo.shape[0] else np.zeros(0, np.int64)
    k = kept.size
    own_comp = number_by_first(comp_all[:k])  # 0.. over the tile's own components
    n_comp = int(own_comp.max()) + 1 if k else 0
    to_own = np.full(int(comp_all.max()) + 1 if comp_all.size else 0, -1, dtype=np.int64)
    to_own[comp_all[:k]] = own_comp
    hc = to_own[comp_all[k:]] if halo.shape[0] else np.zeros(0, np.int64)
    linked = hc >= 0
    links = np.column_stack([hc[linked], h_tile[linked], h_row[linked]]).astype(np.int64) if linked.any() else np.zeros((0, 5), np.int64)
    comp_sorted = np.full(own.shape[0], -1, dtype=np.int32)
    comp_sorted[kept] = own_comp
    _write_in_input_order(store, ijk, "comp", comp_sorted)
    store.write(ijk, "comp_size", np.bincount(own_comp, minlength=n_comp).astype(np.int64))
    store.write(ijk, "skin_comp", comp_sorted[store.read(ijk, "don_skin_rows").astype(np.int64)])
    store.write(ijk, "seg_links", links)
    info = dict(components=n_comp, links=int(links.shape[0]))
    store.mark_tile(ijk, "cluster", key, cluster=info)
    return info


def merge_components(store: Store, min_points: int, max_points: int | None) -> int:
    """Join the tiles' components into segments across tile faces; store each tile's ``comp_map``.

    ``comp_map[c]`` is the segment of the tile's component ``c`` (a
    provisional id, numbered afresh in file order at export), 0 when the
    whole segment has fewer than ``min_points`` or more than ``max_points``
    points.  Memory: a few numbers per component and link, not per point.

    Returns the number of segments.
    """
    tiles = store.tiles
    where = {t: k for k, t in enumerate(tiles)}
    sizes = [store.read(t, "comp_size") for t in tiles]
    offset = np.r_[0, np.cumsum([s.size for s in sizes])].astype(np.int64)
    total = int(offset[-1])
    a_parts, b_parts = [], []
    skin: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
    for k, t in enumerate(tiles):
        links = store.read(t, "seg_links")
        if links.shape[0] == 0:
            continue
        nb = links[:, 1:4]
        for n in {tuple(int(v) for v in row) for row in np.unique(nb, axis=0)}:
            sel = np.all(nb == n, axis=1)
            if n not in skin:
                skin[n] = (store.read(n, "don_skin_rows").astype(np.int64), store.read(n, "skin_comp").astype(np.int64))
            rows, comp = skin[n]
            cn = comp[np.searchsorted(rows, links[sel, 4])]
            a_parts.append(offset[k] + links[sel, 0])
            b_parts.append(offset[where[n]] + cn)
    if total == 0:
        for t in tiles:
            store.write(t, "comp_map", np.zeros(0, np.int64))
        return 0
    a = np.concatenate(a_parts) if a_parts else np.zeros(0, np.int64)
    b = np.concatenate(b_parts) if b_parts else np.zeros(0, np.int64)
    _, label = connected_components(total, a, b)
    size = np.bincount(label, weights=np.concatenate(sizes).astype(np.float64))
    ok = size >= min_points
    if max_points is not None:
        ok &= size <= max_points
    seg = np.where(ok[label], label + 1, 0).astype(np.int64)
    for k, t in enumerate(tiles):
        store.write(t, "comp_map", seg[offset[k] : offset[k + 1]])
    return int(ok.sum())
