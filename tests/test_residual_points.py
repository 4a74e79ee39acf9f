"""Model mode's residual points (version 5): intensity on 64 levels, one return, the class, the order LAZ codes best."""

import io

import laspy
import numpy as np
import pytest

from patchcloud.core.patchmodel import fit_models, quantise_models
from patchcloud.stream.io import pcz
from patchcloud.stream.io.residual_points import (
    INTENSITY_BITS, coarse_intensity, column_order, decoded_records, fine_intensity, intensity_shift, morton_order,
    residual_block, stored_records,
)


def test_every_intensity_comes_back_within_half_a_level():
    I = np.arange(65536)
    for s in range(17):
        back = fine_intensity(coarse_intensity(I, s), s).astype(np.int64)
        assert np.abs(back - I).max() == (0 if s == 0 else min(1 << (s - 1), 32767)), s  # halves up: some move by half
        assert back.max() <= 65535 and coarse_intensity(I, s).max() <= 1 << (16 - s)


def test_the_shift_puts_the_99th_percentile_on_64_levels_whatever_a_few_bright_points_say():
    assert INTENSITY_BITS == 6
    assert intensity_shift(np.array([], dtype=np.int64)) == 0
    assert intensity_shift(np.arange(64)) == 0  # p99 = 62: 6 bits
    assert intensity_shift(np.arange(101) * 100) == 8  # p99 = 9900: 14 bits -> 8
    low = np.r_[np.full(99, 40), 65535]  # one bright point in 100: index floor(0.99 * 99) = 98 -> 40
    assert intensity_shift(low) == 0
    assert intensity_shift(np.full(10, 65535)) == 10


def records(n, pf, rng, scan=True):
    """``n`` records of ``pf``: a scan line (X rising, Y and Z smooth) or the same points shuffled; random intensity,
    returns 2 of 3, class 5, GPS time and user data set."""
    rec = laspy.PackedPointRecord.zeros(n, pf)
    x = np.arange(n) * 7
    rec["X"], rec["Y"], rec["Z"] = x, (np.sin(np.arange(n) / 50) * 500).astype(np.int32), (np.arange(n) % 97) * 3
    rec["intensity"] = rng.integers(0, 4096, n)
    rec["return_number"], rec["number_of_returns"] = np.full(n, 2, np.uint8), np.full(n, 3, np.uint8)
    rec["classification"] = np.full(n, 5, np.uint8)
    rec["gps_time"] = np.arange(n) * 1e-5
    rec["user_data"] = np.full(n, 9, np.uint8)
    rows = np.ascontiguousarray(rec.array).view(np.uint8).reshape(n, pf.size)
    return rows if scan else rows[rng.permutation(n)]


@pytest.mark.parametrize("point_format", [1, 6])
def test_stored_records_keep_class_and_coded_intensity_one_return_and_drop_the_rest(point_format, rng):
    pf = laspy.PointFormat(point_format)
    rows = records(500, pf, rng)
    dropped = ("gps_time", "user_data")
    stored, shift = stored_records(rows, pf, (3, 3, 3), dropped)
    assert shift == 6  # p99 below 4096: 12 bits -> 6
    s = laspy.PackedPointRecord(stored.view(pf.dtype()).ravel(), pf)
    o = laspy.PackedPointRecord(rows.view(pf.dtype()).ravel(), pf)
    assert np.array_equal(s["X"], (np.asarray(o["X"]) + 1) // 3)  # round(X / 3), halves up
    assert np.array_equal(s["intensity"], (np.asarray(o["intensity"]).astype(np.int64) + 32) >> 6)
    assert set(np.asarray(s["return_number"])) == set(np.asarray(s["number_of_returns"])) == {1}
    assert set(np.asarray(s["classification"])) == {5}
    assert not np.asarray(s["gps_time"]).any() and not np.asarray(s["user_data"]).any()
    back = laspy.PackedPointRecord(decoded_records(rows, pf, (3, 3, 3), dropped, shift).view(pf.dtype()).ravel(), pf)
    assert np.array_equal(back["X"], (np.asarray(o["X"]) + 1) // 3 * 3)
    assert np.abs(np.asarray(back["intensity"]).astype(int) - np.asarray(o["intensity"])).max() <= 32


@pytest.mark.parametrize("scan", [True, False])
def test_the_block_is_in_the_order_laz_codes_in_fewer_bytes(scan, rng):
    """A scan line codes best in input order; the same points shuffled, in Morton or column order: the block holds
    whichever is smallest, and reads back as the stored records in that order."""
    pf = laspy.PointFormat(6)
    rows = records(6000, pf, rng, scan=scan)
    laz = residual_block(rows, pf, "1.4", (1, 1, 1), ("gps_time",), [0.01] * 3, [0.0] * 3, 4)
    stored, _ = stored_records(rows, pf, (1, 1, 1), ("gps_time",), 4)
    orders = [np.arange(len(rows)), morton_order(stored), column_order(stored)]
    sizes = [len(pcz_laz(stored[o], pf)) for o in orders]
    best = int(np.argmin(sizes))
    assert len(laz) == sizes[best] and (best == 0) == scan  # input order for the scan line, not for the shuffled points
    assert sizes[0] > 1.2 * sizes[best] if not scan else min(sizes[1:]) > sizes[0]
    got = np.ascontiguousarray(laspy.read(io.BytesIO(laz)).points.array).view(np.uint8).reshape(len(rows), -1)
    assert np.array_equal(got, stored[orders[best]])


def pcz_laz(rows, pf):
    from patchcloud.stream.io.laz_block import records_laz

    return records_laz(rows, pf, "1.4", [0.01] * 3, [0.0] * 3)


def test_morton_order_groups_points_cell_by_cell():
    xyz = np.array([[3, 3, 3], [0, 0, 0], [1, 0, 0], [2, 2, 2], [0, 1, 0]], dtype="<i4")
    rows = np.hstack([xyz.view(np.uint8).reshape(5, 12), np.zeros((5, 8), np.uint8)])
    assert morton_order(rows).tolist() == [1, 2, 4, 3, 0]  # keys 0, 1, 2, 56, 63


def test_a_written_file_gives_back_the_decoded_records(tmp_path, rng):
    """write_pcz of a part made by residual_block, read back: the records decoded_records says, as a set, and the cells'
    intensities multiplied back."""
    pf = laspy.PointFormat(1)
    corner = np.zeros(3)
    p = np.column_stack([rng.uniform(0.01, 7.99, (3000, 2)), np.zeros(3000)])
    q = quantise_models(fit_models(p, 0.01, root=(corner, 8.0)).models, 0.01)
    rows = records(800, pf, rng, scan=False)
    shift = 6
    laz = residual_block(rows, pf, "1.2", (2, 2, 2), ("gps_time",), [0.001] * 3, [0.0] * 3, shift)
    C = q.count.shape[0]
    cells = rng.integers(0, 1 << 10, C).astype(np.uint16)  # the cells' mean intensities as stored: divided by 2**6
    part = pcz.TilePart((0, 0, 0), q, np.ones(C, np.uint8), cells, 800, laz, intensity_shift=shift)
    header = b"LASF" + bytes(100) + bytes([1]) + bytes(270)
    grid = dict(origin=[0.0] * 3, tile_size=8.0, scale=[0.001] * 3, offset=[0.0] * 3)
    pcz.write_pcz(tmp_path / "r.pcz", [part], max_error=0.01, grid=grid, header=header, source={"path": "x.las"},
                  record_bytes=pf.size - 12, steps=(2, 2, 2), dropped=("gps_time",))
    with pcz.open_pcz(tmp_path / "r.pcz") as f:
        assert f.intensity_shift.tolist() == [shift]
        xyz, rec = f.residual(0)
        assert np.array_equal(f.patches(0)[2], np.minimum(cells.astype(np.int64) * 64, 65535))
    got = np.hstack([xyz.view(np.uint8).reshape(-1, 12), rec])
    want = decoded_records(rows, pf, (2, 2, 2), ("gps_time",), shift)
    v = np.dtype((np.void, pf.size))
    assert sorted(got.view(v).ravel().tolist()) == sorted(want.view(v).ravel().tolist())
