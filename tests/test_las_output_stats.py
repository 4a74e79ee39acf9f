"""Header statistics of written points: the extra-bytes ranges leave out no-data and NaN values, whether they are read
from the records or from the columns as they were set."""

import laspy
import numpy as np

from patchcloud.stream.io import las_output


def _points(n=1000):
    h = laspy.LasHeader(point_format=6, version="1.4")
    h.add_extra_dims([laspy.ExtraBytesParams("Curvature", np.float32, no_data=[-1.0]),
                      laspy.ExtraBytesParams("Deviation", np.uint16, no_data=[65535]),
                      laspy.ExtraBytesParams("Plain", np.int32)])
    rng = np.random.default_rng(5)
    pts = laspy.PackedPointRecord.zeros(n, h.point_format)
    curv = rng.uniform(0.1, 0.4, n).astype(np.float32)
    curv[:5], curv[5] = np.nan, -1.0  # NaN and no-data: not in the range
    dev = rng.integers(10, 900, n).astype(np.uint16)
    dev[7] = 65535
    plain = rng.integers(-50, 50, n).astype(np.int32)
    for name, v in (("Curvature", curv), ("Deviation", dev), ("Plain", plain)):
        pts[name] = v
    return h, pts, dict(Curvature=curv, Deviation=dev, Plain=plain)


def test_extra_bytes_ranges_leave_out_no_data_and_nan():
    h, pts, cols = _points()
    st = las_output.point_stats(h, pts)
    lo = [np.frombuffer(b, dtype=d)[0] for b, d in zip(st.eb_min, ("<f8", "<u8", "<i8"))]
    hi = [np.frombuffer(b, dtype=d)[0] for b, d in zip(st.eb_max, ("<f8", "<u8", "<i8"))]
    c = cols["Curvature"][6:]
    assert lo[0] == np.float64(c.min()) and hi[0] == np.float64(c.max())
    d = np.delete(cols["Deviation"], 7)
    assert (lo[1], hi[1]) == (d.min(), d.max())
    assert (lo[2], hi[2]) == (cols["Plain"].min(), cols["Plain"].max())


def test_ranges_from_the_columns_as_set_equal_ranges_from_the_records():
    h, pts, cols = _points()
    ref = las_output.point_stats(h, pts)
    for given in (cols, {"Plain": cols["Plain"]}):
        st = las_output.point_stats(h, pts, given)
        assert (st.eb_min, st.eb_max, st.count, st.gps) == (ref.eb_min, ref.eb_max, ref.count, ref.gps)
        assert np.array_equal(st.mins, ref.mins) and np.array_equal(st.maxs, ref.maxs)
    wrong = dict(cols, Plain=cols["Plain"] + 1)  # the ranges do come from the columns given
    assert las_output.point_stats(h, pts, wrong).eb_max[2] != ref.eb_max[2]


def _laz_parts(tmp_path, name, n_parts=4, per=2 * las_output.LAZ_CHUNK):
    """A LAZ written in ``n_parts`` parts of whole LAZ chunks by write_laz_part: (header, tmp path, start, stats, tables,
    all points)."""
    h = laspy.LasHeader(point_format=6, version="1.4")
    h.scales, h.offsets = np.array([0.01, 0.01, 0.01]), np.zeros(3)
    header = las_output.prepare_header(h, compressed=True)
    rng = np.random.default_rng(9)
    pts = laspy.PackedPointRecord.zeros(n_parts * per, header.point_format)
    pts["X"], pts["Y"], pts["Z"] = (rng.integers(0, 10**6, n_parts * per) for _ in range(3))
    pts["intensity"] = rng.integers(0, 2**16, n_parts * per)
    tmp = tmp_path / name
    start = las_output.begin(header, tmp, len(pts))
    stats, tables = [], []
    for k in range(n_parts):
        part = laspy.PackedPointRecord(pts.array[k * per:(k + 1) * per].copy(), header.point_format)
        stats.append(las_output.point_stats(header, part))
        tables.append(las_output.write_laz_part(tmp, k, header, part))
    return header, tmp, start, stats, tables, pts


def test_laz_parts_stitched_as_they_come_give_the_bytes_of_parts_stitched_at_the_end(tmp_path):
    header, at_end, start, stats, tables, pts = _laz_parts(tmp_path, "end.laz.partial")
    las_output.finish(header, at_end, start, stats, tables)
    header, early, start, stats, tables, _ = _laz_parts(tmp_path, "early.laz.partial")
    las_output.stitch(early, range(0, 1))
    las_output.stitch(early, range(1, 3))  # the first three parts in, the last one left to finish
    assert not (las_output.fragments_dir(early) / "000001").exists()
    las_output.finish(header, early, start, stats, tables, stitched=3)
    assert early.read_bytes() == at_end.read_bytes()
    back = laspy.read(str(early))
    assert np.array_equal(back.points.array, pts.array)


def test_a_part_written_again_after_it_was_stitched_is_not_stitched_twice(tmp_path):
    """On a cluster, a worker lost after its export task's result was in has the task run again, which writes the
    part's fragment a second time, after the client appended and removed the first: the output holds each part once
    (every fragment still there was appended: two parts twice, an unreadable LAZ and a run that said it succeeded)."""
    header, at_end, start, stats, tables, pts = _laz_parts(tmp_path, "end.laz.partial")
    las_output.finish(header, at_end, start, stats, tables)
    header, again, start, stats, tables, _ = _laz_parts(tmp_path, "again.laz.partial")
    las_output.stitch(again, range(0, 3))
    per = len(pts) // len(tables)
    for k in (1, 2):  # the reruns of parts 1 and 2, after they were stitched: the same bytes again
        part = laspy.PackedPointRecord(pts.array[k * per:(k + 1) * per].copy(), header.point_format)
        assert las_output.write_laz_part(again, k, header, part) == tables[k]
    las_output.finish(header, again, start, stats, tables, stitched=3)
    assert again.read_bytes() == at_end.read_bytes()
    assert np.array_equal(laspy.read(str(again)).points.array, pts.array)


def test_the_legacy_counts_of_a_format_0_to_5_output_hold_points_of_returns_6_and_7(tmp_path):
    """A LAS 1.2 input of point format 1 whose pulses have up to 7 returns (LAStools' house.laz has them), written as
    LAS 1.4 by a job: the legacy point count is the point count and the five legacy counts by return those of returns
    1 to 5, as PDAL writes them (they were all 0, and a reader of those fields saw an empty file)."""
    import struct

    from patchcloud.stream import normals

    rng = np.random.default_rng(3)
    n = 3000
    h = laspy.LasHeader(point_format=1, version="1.2")
    h.scales, h.offsets = [0.01] * 3, [0.0] * 3
    las = laspy.LasData(h)
    xy = rng.uniform(0, 20, (n, 2))
    las.x, las.y, las.z = xy[:, 0], xy[:, 1], 0.02 * xy[:, 0]
    returns = rng.integers(1, 8, n)  # 1 to 7
    las.return_number = returns
    las.number_of_returns = np.full(n, 7)
    src = tmp_path / "in.las"
    las.write(src)
    out = tmp_path / "out.las"
    normals(str(src), str(out), quiet=True)
    by = np.bincount(returns, minlength=8)[1:]
    assert by[5:].sum() > 0
    legacy = struct.unpack_from("<6I", out.read_bytes(), 107)
    assert legacy == (n, *by[:5].tolist())
    assert laspy.read(out).header.point_count == n


def test_the_inputs_creation_date_is_kept_as_written_even_day_0(tmp_path):
    """The embedded IGN tile says day 0 of 2023 (every IGN LiDAR HD tile has a day 0): laspy reads it as 31 December
    2022 and wrote day 365 of 2022.  normals (in memory and on worker processes), and decompress of both .pcz modes,
    keep the two numbers as the input has them."""
    import os
    import struct

    from patchcloud.stream import compress, decompress, normals

    sample = os.path.join(os.path.dirname(__file__), "..", "data", "test_data_77055_627760_LA93_IGN69.laz")

    def date(path):
        with open(path, "rb") as f:
            return struct.unpack_from("<HH", f.read(94), 90)

    assert date(sample) == (0, 2023)
    outs = [tmp_path / "n.laz", tmp_path / "p.las"]
    normals(sample, outs[0], quiet=True)
    normals(sample, outs[1], quiet=True, scheduler="processes", workers=1)
    for keep in (False, True):
        pcz = tmp_path / f"c{keep}.pcz"
        compress(sample, pcz, keep_points=keep, quiet=True)
        outs.append(tmp_path / f"d{keep}.laz")
        decompress(pcz, outs[-1])
    assert [date(o) for o in outs] == [(0, 2023)] * 4


def _laspy_stats(header, points):
    """The reference: laspy's own ``grow`` over the records (without the extra bytes, whose ranges it gets wrong)."""
    from copy import deepcopy

    h = deepcopy(header)
    try:
        h.vlrs.pop(h.vlrs.index("ExtraBytesVlr"))
    except ValueError:
        pass
    h.partial_reset()
    h.grow(points)
    return h


def test_bounds_gps_and_counts_by_return_are_laspys_bit_for_bit():
    """point_stats computes what laspy's LasHeader.grow computes (bounds from the integer extremes, the GPS range, the
    counts by return), for point formats with 3-bit and 4-bit return numbers, returns 0 and above the header's slots,
    negative integers and a negative offset."""
    rng = np.random.default_rng(11)
    for fmt, version in ((1, "1.2"), (3, "1.2"), (6, "1.4"), (8, "1.4")):
        h = laspy.LasHeader(point_format=fmt, version=version)
        h.scales, h.offsets = np.array([0.01, 0.001, 0.0025]), np.array([-512345.67, 6.2e6, -12.5])
        n = 5000
        pts = laspy.PackedPointRecord.zeros(n, h.point_format)
        for name in ("X", "Y", "Z"):
            pts[name] = rng.integers(-(2**31), 2**31 - 1, n, dtype=np.int64).astype(np.int32)
        pts["gps_time"] = rng.normal(3e8, 1e6, n)
        top = 7 if fmt < 6 else 15
        returns = rng.integers(0, top + 1, n)
        pts["return_number"] = returns
        ref = _laspy_stats(h, pts)
        st = las_output.point_stats(h, pts)
        assert np.array_equal(st.mins, np.asarray(ref.mins)) and np.array_equal(st.maxs, np.asarray(ref.maxs))
        assert st.gps == (float(ref.min_gps_time), float(ref.max_gps_time))
        assert np.array_equal(st.by_return, np.asarray(ref.number_of_points_by_return, dtype=np.uint64))
        assert st.count == n and st.by_return.sum() == np.count_nonzero((returns >= 1) & (returns <= 15))


def test_an_all_nan_or_all_no_data_column_keeps_the_empty_range():
    h, pts, cols = _points(50)
    curv = np.full(50, np.nan, dtype=np.float32)
    curv[::2] = -1.0  # no-data or NaN everywhere
    pts["Curvature"] = curv
    st = las_output.point_stats(h, pts)
    assert np.frombuffer(st.eb_min[0], dtype="<f8")[0] == np.finfo(np.float64).max
    assert np.frombuffer(st.eb_max[0], dtype="<f8")[0] == np.finfo(np.float64).min
