"""The seam pass in blocks of tiles gives the orientation of the whole cloud's spanning forest."""

import os

import numpy as np
import pytest

from test_stream import write_scene
from patchcloud.core import patch_signs
from patchcloud.stream import Runner, Store, normals
from patchcloud.stream.jobs import normals_tiles
from patchcloud.stream.jobs.seams import orient_tiles, tile_pairs


def whole_cloud_signs(store: Store, orient: str):
    """The seam pass as one maximum spanning forest over every patch of the store (the pass before blocks)."""
    tiles = store.tiles
    index = {t: k for k, t in enumerate(tiles)}
    sizes = np.array([int(store.tile_attrs(t)["fit"]["patches"]) for t in tiles])
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    rule = int(offsets[-1])
    links, agreement, score = [], [], []
    for k, t in enumerate(tiles):
        lk = store.read(t, "links").reshape(-1, 2)
        links.append(np.where(lk == sizes[k], rule, lk + offsets[k]))
        agreement.append(store.read(t, "agreement"))
        score.append(store.read(t, "score"))
    for a, b, axis in tile_pairs(tiles):
        ra, rb, ag = normals_tiles.seam_links(store.url, a, b, axis)
        links.append(np.column_stack([ra + offsets[index[a]], rb + offsets[index[b]]]))
        agreement.append(ag)
    sign, ruled = patch_signs(rule, np.concatenate(links), np.concatenate(agreement), np.concatenate(score), orient)
    return [sign[offsets[k] : offsets[k + 1]] for k in range(len(tiles))], int(ruled.sum())


@pytest.fixture(scope="module")
def kept_store(tmp_path_factory):
    d = tmp_path_factory.mktemp("seams")
    write_scene(d / "scene.las", n=40_000, seed=3)
    url = str(d / "scene.zarr")
    normals(d / "scene.las", d / "out.las", tile_size=8, scheduler="synchronous", store=url, quiet=True)
    return url


@pytest.mark.slow  # about 60 s with its store (2 cores)
@pytest.mark.parametrize("orient", ["up", "none"])  # with "none", no component is turned over by its score
def test_blocks_of_tiles_orient_as_the_whole_cloud_forest(kept_store, orient):
    store = Store.open(kept_store)
    assert len(store.tiles) >= 20
    expect, expect_ruled = whole_cloud_signs(store, orient)
    with Runner("threads", workers=2, quiet=True) as runner:
        for bits in (1, 8):  # blocks of 2 and 256 tiles a side: several levels, and one above the tiles
            counts = orient_tiles(store, runner, orient, bits=bits)
            got = [store.read(t, "sign").astype(np.float64) for t in store.tiles]
            assert counts["ruled"] == expect_ruled
            for g, e in zip(got, expect):
                assert np.array_equal(g, e)
            assert not os.path.exists(os.path.join(kept_store, "seams"))  # its working blobs are removed
