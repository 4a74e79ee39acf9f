"""The seam pass: one orientation for the patches of all tiles.

Each tile's fit kept its orientation forest (the most reliable face
agreements inside the tile, and links to the global rule).  Here the
leaves on either side of every tile face are linked the same way, by face
sampling of the two patch models (:func:`.normals_tiles.seam_links`, one task per
pair of tiles); the union of the tiles' forests and these links holds the
forest of the whole cloud's graph, so one maximum spanning forest over it
(:func:`patchcloud.core.tiles.patch_signs`) orients every patch as a
single in-memory run would.  Blending across tile faces happens when each
tile is finished, from its neighbours' oriented patch models.

Memory: a few tens of bytes per patch (the forests, links and signs), not
per point.
"""

from __future__ import annotations

import numpy as np

from patchcloud.core import patch_signs

from patchcloud.stream.jobs import normals_tiles
from patchcloud.stream.engine.runner import Runner
from patchcloud.stream.io.store import Store

__all__ = ["orient_tiles", "tile_pairs"]


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


def orient_tiles(store: Store, runner: Runner, orient: str, quiet: bool = False) -> dict:
    """Orient every patch of the store consistently; write each tile's ``sign``; return counts."""
    tiles = store.tiles
    index = {t: k for k, t in enumerate(tiles)}
    sizes = np.array([int(store.tile_attrs(t)["fit"]["patches"]) for t in tiles], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    total = int(offsets[-1])
    rule = total
    links, agreement, score = [], [], []
    for k, t in enumerate(tiles):
        lk = store.read(t, "links").reshape(-1, 2)
        links.append(np.where(lk == sizes[k], rule, lk + offsets[k]))
        agreement.append(store.read(t, "agreement"))
        score.append(store.read(t, "score"))
    pairs = tile_pairs(tiles)
    calls = [((store.url, a, b, axis), {}) for a, b, axis in pairs]
    results = runner.map(normals_tiles.seam_links, calls, "seams") if calls else []
    cross = 0
    for (a, b, _), (ra, rb, ag) in zip(pairs, results):
        links.append(np.column_stack([ra + offsets[index[a]], rb + offsets[index[b]]]))
        agreement.append(ag)
        cross += ra.size
    L = np.concatenate(links) if links else np.zeros((0, 2), dtype=np.int64)
    A = np.concatenate(agreement) if agreement else np.zeros(0)
    S = np.concatenate(score) if score else np.zeros(0)
    sign, ruled = patch_signs(total, L, A, S, orient)
    for k, t in enumerate(tiles):
        store.write(t, "sign", sign[offsets[k] : offsets[k + 1]].astype(np.int8))
    store.update(patch_offsets=offsets[:-1].tolist())
    return dict(patches=total, cross_links=cross, ruled=int(ruled.sum()))
