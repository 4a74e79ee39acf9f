"""Residual points as an octree block (.pcz version 5): exact round trips, the choice against LAZ, damage refused."""

import laspy
import numpy as np
import pytest

from patchcloud.core.errors import PatchcloudIOError
from patchcloud.stream.io import pcz
from patchcloud.stream.io.range_coder import decode_tree, decoder, encode_tree, encoder, finish, new_trees
from patchcloud.stream.io.residual_octree import MAGIC, OctreePoints, decode, encode, records_of
from patchcloud.stream.io.residual_points import octree_block, residual_block, stored_records


def same_points(xyz, cls, inten, back):
    """The decoded points are the given ones, as a multiset (the block keeps Morton order, not the input's)."""
    a = np.column_stack([xyz, cls, inten]).astype(np.int64)
    b = np.column_stack([back.xyz, back.classification, back.intensity]).astype(np.int64)
    return np.array_equal(a[np.lexsort(a.T[::-1])], b[np.lexsort(b.T[::-1])])


@pytest.mark.parametrize("case", ["random", "plane", "one", "identical", "empty", "escapes", "negative"])
def test_round_trip(case, rng):
    n = {"one": 1, "empty": 0, "identical": 40}.get(case, 3000)
    if case == "plane":
        xyz = np.column_stack([rng.integers(0, 2000, (n, 2)), np.full(n, 7)])
    elif case in ("identical", "one"):
        xyz = np.tile([[5, -3, 1 << 20]], (n, 1))
    elif case == "negative":
        xyz = rng.integers(-(1 << 20), 1 << 20, (n, 3))
    else:
        xyz = rng.integers(0, 500, (n, 3))
    if case == "escapes":  # 20 points on one position (past 15 repeats), levels past 126 (escaped to 16 bits)
        xyz[:20] = xyz[0]
    cls = rng.integers(0, 256, n)
    inten = rng.integers(0, 64, n)
    if case == "escapes":
        inten[::7] = rng.integers(127, 65536, len(inten[::7]))
    block = encode(xyz, cls, inten, single_return=case != "one")
    assert block[:4] == MAGIC
    back = decode(block, "t")
    assert len(back.xyz) == n and back.single_return == (case != "one")
    assert same_points(xyz, cls, inten, back)


def test_a_span_beyond_21_bits_is_left_to_laz():
    assert encode(np.array([[0, 0, 0], [1 << 21, 0, 0]]), np.zeros(2), np.zeros(2), True) is None
    assert encode(np.array([[0, 0, 0], [(1 << 21) - 1, 0, 0]]), np.zeros(2), np.zeros(2), True) is not None


def test_points_on_a_surface_cost_fewer_bits_than_points_in_a_volume(rng):
    """The occupancy contexts (occupied neighbours) pay where points fill neighbouring nodes: 20,000 points on a plane
    of 1000 x 1000 steps take well under the 3 x 10 bits a point of their raw positions, and fewer than the same count
    scattered through a 1000-step cube."""
    n = 20_000
    plane = np.column_stack([rng.integers(0, 1000, (n, 2)), np.zeros(n, np.int64)])
    cube = rng.integers(0, 1000, (n, 3))
    z = np.zeros(n)
    bits = [8 * len(encode(p, z, z, True)) / n for p in (plane, cube)]
    assert bits[0] < 0.6 * bits[1] and bits[0] < 8


def test_damaged_blocks_are_refused_naming_them(rng):
    xyz = rng.integers(0, 300, (500, 3))
    block = encode(xyz, np.full(500, 2), rng.integers(0, 64, 500), True)
    with pytest.raises(PatchcloudIOError, match="tile x: .*end early|tile x: damaged"):
        decode(block[: len(block) // 2], "tile x")
    with pytest.raises(PatchcloudIOError, match="tile x: coded points of 10 bytes"):
        decode(block[:10], "tile x")
    bomb = bytearray(block)
    bomb[6:10] = (1 << 31).to_bytes(4, "little")  # claims 2**31 points
    with pytest.raises(PatchcloudIOError, match="cannot hold"):
        decode(bytes(bomb), "tile x")
    other = bytearray(block)
    other[:4] = b"XXXX"
    with pytest.raises(PatchcloudIOError, match="damaged coded points"):
        decode(bytes(other), "tile x")


def test_records_of_fills_the_point_format(rng):
    for pid in (1, 6, 8):
        pf = laspy.PointFormat(pid)
        p = OctreePoints(np.array([[1, 2, 3]]), np.array([6], np.uint8), np.array([900]), True)
        rows = records_of(p, pid, pf.size + 4)  # 4 bytes of extra dimensions: zero
        rec = laspy.PackedPointRecord(np.ascontiguousarray(rows[:, : pf.size]).view(pf.dtype()).ravel(), pf)
        assert (rec["X"][0], rec["Y"][0], rec["Z"][0], rec["classification"][0], rec["intensity"][0]) == (1, 2, 3, 6, 900)
        assert rec["return_number"][0] == rec["number_of_returns"][0] == 1 and not rows[:, pf.size:].any()
    with pytest.raises(PatchcloudIOError, match="class 40 in point format 1"):
        records_of(OctreePoints(np.zeros((1, 3), np.int64), np.array([40], np.uint8), np.zeros(1, np.int64), True), 1, 28)


def cloud(n, pf, rng, user_data=0):
    """Records of ``n`` points shuffled on a gently curved surface: class 2 or 6, intensity, GPS time, user data."""
    rec = laspy.PackedPointRecord.zeros(n, pf)
    xy = rng.integers(0, 20000, (n, 2))
    rec["X"], rec["Y"] = xy[:, 0], xy[:, 1]
    rec["Z"] = (xy[:, 0] ** 2 // 40000).astype(np.int32)
    rec["classification"] = rng.choice(np.array([2, 6], np.uint8), n)
    rec["intensity"] = rng.integers(0, 4000, n)
    rec["gps_time"] = rng.uniform(0, 1, n)
    rec["user_data"] = np.full(n, user_data, np.uint8)
    return np.ascontiguousarray(rec.array).view(np.uint8).reshape(n, pf.size)


def test_the_octree_is_chosen_where_smaller_and_only_where_it_gives_the_records_back(rng):
    pf = laspy.PointFormat(1)
    rows = cloud(8000, pf, rng)
    dropped = ("gps_time", "user_data", "scan_angle_rank", "point_source_id")
    block = residual_block(rows, pf, "1.2", (4, 4, 4), dropped, [0.001] * 3, [0.0] * 3, 6)
    assert block[:4] == MAGIC  # shuffled points on a surface: the octree beats LAZ in every order
    stored, _ = stored_records(rows, pf, (4, 4, 4), dropped, 6)
    assert octree_block(stored, pf, True) == block
    # a dimension the octree does not hold (user data kept and not zero): no octree, LAZ
    kept = cloud(8000, pf, rng, user_data=9)
    assert octree_block(stored_records(kept, pf, (4, 4, 4), dropped[:1], 6)[0], pf, True) is None
    assert residual_block(kept, pf, "1.2", (4, 4, 4), dropped[:1], [0.001] * 3, [0.0] * 3, 6)[:4] == b"LASF"


def test_a_file_with_octree_blocks_reads_back_and_refuses_a_damaged_one(tmp_path, rng):
    from patchcloud.core.patchmodel import fit_models, quantise_models

    pf = laspy.PointFormat(1)
    rows = cloud(3000, pf, rng)
    dropped = ("gps_time", "user_data", "scan_angle_rank", "point_source_id")
    block = residual_block(rows, pf, "1.2", (2, 2, 2), dropped, [0.001] * 3, [0.0] * 3, 6)
    assert block[:4] == MAGIC
    p = np.column_stack([rng.uniform(0.01, 7.99, (2000, 2)), np.zeros(2000)])
    q = quantise_models(fit_models(p, 0.01, root=(np.zeros(3), 8.0)).models, 0.01)
    C = q.count.shape[0]
    part = pcz.TilePart((0, 0, 0), q, np.ones(C, np.uint8), np.zeros(C, np.uint16), 3000, block, intensity_shift=6)
    header = b"LASF" + bytes(100) + bytes([1]) + bytes(270)
    grid = dict(origin=[0.0] * 3, tile_size=8.0, scale=[0.001] * 3, offset=[0.0] * 3)
    pcz.write_pcz(tmp_path / "o.pcz", [part], max_error=0.01, grid=grid, header=header, source={"path": "x.las"},
                  record_bytes=pf.size - 12, steps=(2, 2, 2), dropped=dropped)
    with pcz.open_pcz(tmp_path / "o.pcz") as f:
        xyz, rec = f.residual(0)
    got = np.hstack([xyz.view(np.uint8).reshape(-1, 12), rec])
    o = laspy.PackedPointRecord(rows.view(pf.dtype()).ravel(), pf)
    g = laspy.PackedPointRecord(np.ascontiguousarray(got).view(pf.dtype()).ravel(), pf)
    want = np.column_stack([(np.asarray(o[a], dtype=np.int64) + 1) // 2 * 2 for a in "XYZ"]
                           + [np.asarray(o["classification"]), (np.asarray(o["intensity"], dtype=np.int64) + 32) >> 6 << 6])
    have = np.column_stack([np.asarray(g[a], dtype=np.int64) for a in "XYZ"] + [np.asarray(g["classification"]),
                                                                                  np.asarray(g["intensity"])])
    assert np.array_equal(want[np.lexsort(want.T[::-1])], have[np.lexsort(have.T[::-1])])
    assert set(np.asarray(g["return_number"])) == {1} and not np.asarray(g["gps_time"]).any()
    # the block cut short inside the file: one error naming the file and the tile
    import shutil
    import zipfile

    import zarr

    work = tmp_path / "w"
    with zipfile.ZipFile(tmp_path / "o.pcz") as z:
        z.extractall(work)
    g2 = zarr.open_group(str(work), mode="r+")
    raw = g2["residual/laz"][...]
    raw[len(raw) // 2:] = 0
    g2["residual/laz"][...] = raw
    bad = tmp_path / "bad.pcz"
    with zipfile.ZipFile(bad, "w") as z:
        for f in sorted(work.rglob("*")):
            if f.is_file():
                z.write(f, f.relative_to(work).as_posix())
    shutil.rmtree(work)
    with pcz.open_pcz(bad) as f, pytest.raises(PatchcloudIOError, match=r"bad\.pcz: the residual points of tile"):
        f.residual(0)


def test_the_range_coder_codes_near_the_entropy(rng):
    """Symbols of a skewed source: the adaptive coder's bits within 5 % (and 64 bytes) of the entropy; decoded back."""
    p = np.array([0.7, 0.2, 0.05, 0.05])
    sym = rng.choice(4, 50_000, p=p)
    st, out = encoder(16)
    data = finish(st, encode_tree(st, out, new_trees(1, 2), np.zeros(len(sym), np.int64), sym, 2))
    H = -(p * np.log2(p)).sum() * len(sym) / 8
    assert len(data) <= 1.05 * H + 64
    assert np.array_equal(decode_tree(decoder(data), data, new_trees(1, 2), np.zeros(len(sym), np.int64), 2), sym)


def test_children_are_the_occupancy_bits_in_order_and_a_damaged_level_is_none(rng):
    from patchcloud.stream.io.residual_octree import child_keys

    nodes = np.sort(rng.choice(10_000, 300, replace=False)).astype(np.uint64)
    occ = rng.integers(1, 256, 300)
    bits = ((occ[:, None] >> np.arange(8)) & 1).astype(bool)
    parent, child = np.nonzero(bits)  # the numpy definition it replaced
    want = (nodes[parent] << np.uint64(3)) | child.astype(np.uint64)
    assert np.array_equal(child_keys(nodes, occ, 10**6), want) and np.all(np.diff(want.astype(np.int64)) > 0)
    assert child_keys(nodes, np.where(np.arange(300) == 7, 0, occ), 10**6) is None  # an empty node
    assert child_keys(nodes, np.where(np.arange(300) == 7, 256, occ), 10**6) is None  # not a byte
    assert child_keys(nodes, occ, len(want) - 1) is None  # more positions than the header says
