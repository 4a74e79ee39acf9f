"""The seam pass: one orientation for the patches of all tiles, computed in blocks of tiles on the workers.

Each tile's fit kept its orientation forest (the most reliable face
agreements inside the tile, and links to the global rule).  The seam
pass adds the links between the leaves on either side of every tile face
and takes the maximum spanning forest of it all, which orients every
patch as a single in-memory run would (:func:`patchcloud.core.tiles.patch_signs`).
No process holds that whole graph:

1. **faces**: one task per pair of face neighbours links their leaves by
   face sampling of the two patch models
   (:func:`.normals_tiles.seam_links`) and writes the links to the store;
2. **up**: one task per tile reduces the tile's forest to what its faces
   can see (:func:`patchcloud.core.forest.reduce_forest`: the patches
   linked across a face, the branch points between them, one link per
   path); then one task per block of ``2**BLOCK_BITS`` tiles a side
   reduces its children's reduced forests and the face links between
   them, and so on up to one block, whose only terminal is the rule;
3. **down**: from the top, each block's task reads its parent's final
   signs, takes those of its key nodes, gives all its nodes their final
   signs (:func:`patchcloud.core.forest.expand_signs`) and writes them for
   its children; the tiles' tasks write each patch's ``sign``.

Each task holds one block: its children's reduced forests, whose size is
set by the block's faces, not its contents.  The client holds the list of
tiles and blocks only.  Store layout: blobs (:meth:`patchcloud.stream.io.store.Store.put_blob`, one
write each, no zarr metadata), removed when the pass ends::

    seams/faces/<tile>_<axis>          (E, 3)  rows in the tile and in its +axis neighbour, agreement
    seams/L<level>/<block>_reduced     (2 + 5K + 6M,)  the block's reduced forest, what its parent reads: K, M,
                                       its K key nodes (id, score, low, low_sign, faces) and M reduced links
                                       (i, j, agreement, tie (3))
    seams/L<level>/<block>_expansion   (2 + K + 3N,)  what the block's down task reads: K, N, its key
                                       nodes' ids and its N nodes' expansion (id, anchor, sign)
    seams/L<level>/<block>_signs       (3N,)  final sign and ruled flag of the block's N nodes (id, sign, ruled),
                                       what its children read

Ids are patch ids over the whole cloud (the tile's offset plus its row),
the rule's node is the number of patches; all below 2**53, exact in float64.
"""

from __future__ import annotations

import numpy as np

from patchcloud.core import (
    MIN_RELIABILITY, ForestLinks, ForestNodes, Expansion, concat_links, expand_signs, forest_links, forest_nodes, lookup,
    merge_nodes, reduce_forest,
)

from patchcloud.stream.engine.runner import Runner
from patchcloud.stream.io.store import Store, tile_name
from patchcloud.stream.jobs import normals_tiles

__all__ = ["orient_tiles", "tile_pairs", "BLOCK_BITS", "face_links", "reduce_tile", "reduce_block", "expand_block"]

#: Blocks of the seam pass are 2**BLOCK_BITS tiles a side (4 x 4 x 4 tiles, 64 children at most).
BLOCK_BITS = 2

_AXES = np.eye(3, dtype=np.int64)


def tile_pairs(tiles: list[tuple]) -> list[tuple[tuple, tuple, int]]:
    """Pairs ``(a, b, axis)`` of tiles sharing a face, ``b`` on the +axis side of ``a``, in tile order."""
    present = set(tiles)
    pairs = []
    for t in tiles:
        for axis in range(3):
            b = list(t)
            b[axis] += 1
            b = tuple(b)
            if b in present:
                pairs.append((t, b, axis))
    return pairs


def _face_path(a: tuple, axis: int) -> str:
    return f"seams/faces/{tile_name(a)}_{axis}"


def _block_path(level: int, block: tuple) -> str:
    return f"seams/L{level}/{tile_name(block)}"


def _block_of(t, level: int, bits: int, low: tuple = (0, 0, 0)) -> tuple:
    """The block of ``2**(bits * level)`` tiles a side holding tile ``t``, counted from tile ``low`` (at most 0 on
    each axis: tiles of negative index, from points below the header's bounds, shift as a whole)."""
    return tuple((int(v) - int(lo)) >> (bits * level) for v, lo in zip(t, low))


# -- tasks -------------------------------------------------------------------
def face_links(url: str, a: tuple, b: tuple, axis: int) -> int:
    """Link the leaves of tiles ``a`` and ``b`` (``b`` next to ``a`` on +``axis``); write the links; return their number."""
    ra, rb, ag = normals_tiles.seam_links(url, a, b, axis)
    Store.open(url).put_blob(_face_path(a, axis), np.column_stack([ra, rb, ag]))
    return int(ra.size)


def _write_reduced(store: Store, path: str, nodes: ForestNodes, links: ForestLinks, exp: Expansion) -> None:
    """Two blobs for the block: its reduced forest (for its parent) and its expansion (for its own down task)."""
    reduced = [
        np.array([len(nodes), len(links)], dtype=np.float64),
        np.column_stack([nodes.id, nodes.score, nodes.low, nodes.low_sign, nodes.faces]).ravel(),
        np.column_stack([links.i, links.j, links.agreement, links.tie]).ravel(),
    ]
    store.put_blob(f"{path}_reduced", np.concatenate([p.astype(np.float64) for p in reduced]))
    expansion = [np.array([len(nodes), exp.id.size], dtype=np.float64), nodes.id, np.column_stack([exp.id, exp.anchor, exp.sign]).ravel()]
    store.put_blob(f"{path}_expansion", np.concatenate([p.astype(np.float64) for p in expansion]))


def _read_reduced(store: Store, path: str) -> tuple[ForestNodes, ForestLinks]:
    a = store.get_blob(f"{path}_reduced")
    k, m = (int(v) for v in a[:2])
    nd = a[2 : 2 + 5 * k].reshape(k, 5)
    lk = a[2 + 5 * k :].reshape(m, 6)
    nodes = ForestNodes(
        id=nd[:, 0].astype(np.int64), score=nd[:, 1].copy(), low=nd[:, 2].astype(np.int64), low_sign=nd[:, 3].copy(),
        faces=nd[:, 4].astype(np.uint8),
    )
    links = ForestLinks(i=lk[:, 0].astype(np.int64), j=lk[:, 1].astype(np.int64), agreement=lk[:, 2].copy(), tie=lk[:, 3:6].astype(np.int64))
    return nodes, links


def _read_expansion(store: Store, path: str) -> tuple[np.ndarray, Expansion]:
    """The block's key nodes' ids and its expansion."""
    a = store.get_blob(f"{path}_expansion")
    k, n = (int(v) for v in a[:2])
    ex = a[2 + k :].reshape(n, 3)
    return a[2 : 2 + k].astype(np.int64), Expansion(id=ex[:, 0].astype(np.int64), anchor=ex[:, 1].astype(np.int64), sign=ex[:, 2].copy())


def reduce_tile(url: str, ijk: tuple, offset: int, rule: int, faces: list[tuple[str, int, int]], flip: bool) -> int:
    """Reduce tile ``ijk``'s orientation forest to its key nodes (level 0 of the up pass); return their number.

    ``faces``: ``(path, column, face)`` of the face links of the tile: the
    array's path, the column holding the tile's rows (0 or 1) and the face
    (0..5: -x, +x, -y, +y, -z, +z).
    """
    store = Store.open(url)
    P = int(store.tile_attrs(ijk)["fit"]["patches"])
    lk = store.read(ijk, "links").reshape(-1, 2)
    ids = np.where(lk == P, rule, lk + offset)
    links = forest_links(ids[:, 0], ids[:, 1], store.read(ijk, "agreement"), MIN_RELIABILITY)
    bits = np.zeros(P + 1, dtype=np.uint8)
    for path, column, face in faces:
        f = store.get_blob(path).reshape(-1, 3)
        rows = f[np.abs(f[:, 2]) >= MIN_RELIABILITY, column].astype(np.int64)
        bits[rows] |= np.uint8(1 << face)
    nodes = forest_nodes(np.r_[np.arange(P) + offset, rule], np.r_[store.read(ijk, "score"), 0.0], bits)
    terminal = (nodes.faces > 0) | (nodes.id == rule)
    reduced, exp = reduce_forest(nodes, links, terminal, flip=flip)
    _write_reduced(store, _block_path(0, ijk), reduced.nodes, reduced.links, exp)
    return len(reduced.nodes)


def reduce_block(
    url: str, level: int, block: tuple, children: list[tuple], pairs: list[tuple[str, int, int]],
    tiles: list[tuple], offsets: list[int], rule: int, bits: int, flip: bool,
) -> int:
    """Reduce a block of level ``level`` from its children's reduced forests and the face links between them.

    ``pairs``: ``(path, offset_a, offset_b)`` of the face links joined at
    this level; ``tiles``, ``offsets``: the block's tiles in store order and
    their first patch ids (to know which face of which tile a node is on).
    Returns the number of key nodes kept.
    """
    store = Store.open(url)
    parts = [_read_reduced(store, _block_path(level - 1, c)) for c in children]
    nodes = merge_nodes([p[0] for p in parts])
    cross = []
    for path, oa, ob in pairs:
        f = store.get_blob(path).reshape(-1, 3)
        cross.append(forest_links(f[:, 0].astype(np.int64) + oa, f[:, 1].astype(np.int64) + ob, f[:, 2], MIN_RELIABILITY))
    links = concat_links([p[1] for p in parts] + cross)
    # a node is a terminal when one of its faces with links leads out of the block
    tiles_arr = np.asarray(tiles, dtype=np.int64).reshape(-1, 3)
    row = np.searchsorted(np.asarray(offsets, dtype=np.int64), nodes.id, side="right") - 1
    patch = nodes.id != rule
    terminal = ~patch
    block_arr = np.asarray(block, dtype=np.int64)
    for face in range(6):
        has = patch & ((nodes.faces >> face) & 1).astype(bool)
        if not has.any():
            continue
        step = _AXES[face // 2] * (1 if face % 2 else -1)
        across = (tiles_arr[row[has]] + step) >> (bits * level)
        terminal[np.flatnonzero(has)[np.any(across != block_arr, axis=1)]] = True
    reduced, exp = reduce_forest(nodes, links, terminal, flip=flip)
    _write_reduced(store, _block_path(level, block), reduced.nodes, reduced.links, exp)
    return len(reduced.nodes)


def expand_block(url: str, level: int, block: tuple, parent: tuple | None) -> int:
    """Final signs of a block's nodes from its parent's (a tile: its patches' ``sign``); written for its children.

    ``parent``: the block above it, None for the top block (whose only key
    node is the rule's, +1).  Returns the number of the tile's patches whose
    sign came through the rule (level 0), else 0.
    """
    store = Store.open(url)
    path = _block_path(level, block)
    key_ids, exp = _read_expansion(store, path)
    if parent is None:
        key_sign, key_ruled = np.ones(key_ids.size), np.ones(key_ids.size, dtype=bool)
    else:
        above = store.get_blob(f"{_block_path(level + 1, parent)}_signs").reshape(-1, 3)
        key_sign, key_ruled = lookup(above[:, 0].astype(np.int64), above[:, 1], above[:, 2] > 0, key_ids)
    sign, ruled = expand_signs(exp, key_sign, key_ruled)
    if level == 0:
        patch = slice(0, exp.id.size - 1)  # the rule's node is the last (the largest id)
        store.write(block, "sign", sign[patch].astype(np.int8))
        return int(ruled[patch].sum())
    store.put_blob(f"{path}_signs", np.column_stack([exp.id, sign, ruled]))
    return 0


# -- the pass ----------------------------------------------------------------
def orient_tiles(store: Store, runner: Runner, orient: str, bits: int = BLOCK_BITS) -> dict:
    """Orient every patch of the store consistently; write each tile's ``sign``; return counts.

    ``bits``: blocks are ``2**bits`` tiles a side.
    """
    tiles = store.tiles
    sizes = np.array([int(store.tile_attrs(t)["fit"]["patches"]) for t in tiles], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    rule = int(offsets[-1])
    offset_of = {t: int(offsets[k]) for k, t in enumerate(tiles)}
    flip = orient != "none"
    store.remove_blobs("seams")
    url = store.url
    # 1. face links
    pairs = tile_pairs(tiles)
    counts = runner.map(face_links, [((url, a, b, axis), {}) for a, b, axis in pairs], "seams: faces", small=True) if pairs else []
    # 2. up: tiles, then blocks of 2**bits a side, until one block holds every tile
    low = tuple(min(0, min(int(t[k]) for t in tiles)) for k in range(3))
    top = 0
    while len({_block_of(t, top, bits, low) for t in tiles}) > 1:
        top += 1
    faces: dict[tuple, list] = {t: [] for t in tiles}
    for a, b, axis in pairs:
        faces[a].append((_face_path(a, axis), 0, 2 * axis + 1))
        faces[b].append((_face_path(a, axis), 1, 2 * axis))
    calls = [((url, t, offset_of[t], rule, faces[t], flip), {}) for t in tiles]
    runner.map(reduce_tile, calls, "seams: tiles", small=True)
    for level in range(1, top + 1):
        blocks: dict[tuple, dict] = {}
        for t in tiles:
            b = blocks.setdefault(_block_of(t, level, bits, low), dict(children=set(), pairs=[], tiles=[]))
            b["children"].add(t if level == 1 else _block_of(t, level - 1, bits, low))  # a tile's own name at level 0
            b["tiles"].append(t)
        for a, b_, axis in pairs:
            if _block_of(a, level - 1, bits, low) != _block_of(b_, level - 1, bits, low) and _block_of(a, level, bits, low) == _block_of(b_, level, bits, low):
                blocks[_block_of(a, level, bits, low)]["pairs"].append((_face_path(a, axis), offset_of[a], offset_of[b_]))
        calls = [
            ((url, level, k, sorted(v["children"]), v["pairs"], v["tiles"], [offset_of[t] for t in v["tiles"]], rule, bits, flip), {})
            for k, v in sorted(blocks.items())
        ]
        runner.map(reduce_block, calls, f"seams: level {level}", small=True)
    # 3. down: each block reads its parent's signs
    def parent(b: tuple, level: int) -> tuple | None:
        if level == top:
            return None
        return _block_of(b, 1, bits, low) if level == 0 else tuple(v >> bits for v in b)

    for level in range(top, 0, -1):
        calls = [((url, level, b, parent(b, level)), {}) for b in sorted({_block_of(t, level, bits, low) for t in tiles})]
        runner.map(expand_block, calls, f"seams: down {level}", small=True)
    ruled = runner.map(expand_block, [((url, 0, t, parent(t, 0)), {}) for t in tiles], "seams: signs", small=True)
    store.remove_blobs("seams")
    store.update(patch_offsets=offsets[:-1].tolist())
    return dict(patches=rule, cross_links=int(sum(counts)), ruled=int(sum(ruled)), levels=top + 1)
