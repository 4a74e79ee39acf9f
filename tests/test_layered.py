"""Records of point formats 0-3 stored as 6 and 7 (stream.io.layered): every field where laspy reads it, and back."""

import io

import laspy
import numpy as np
import pytest

from patchcloud.stream.io import pcz
from patchcloud.stream.io.laz_block import records_laz
from patchcloud.stream.io.layered import LAYERED, from_layered, layered_format, layered_size, to_layered


def _records(pid: int, n: int, extra: int, rng) -> np.ndarray:
    """n random records of format ``pid`` with ``extra`` extra bytes: every bit pattern the format can hold."""
    return rng.integers(0, 256, (n, laspy.PointFormat(pid).size + extra)).astype(np.uint8)


def _fields(rows: np.ndarray, pid: int) -> laspy.PackedPointRecord:
    return laspy.PackedPointRecord(rows[:, : laspy.PointFormat(pid).size].copy().view(laspy.PointFormat(pid).dtype()).ravel(),
                                   laspy.PointFormat(pid))


@pytest.mark.parametrize("pid", [0, 1, 2, 3])
@pytest.mark.parametrize("extra", [0, 3])
def test_each_field_lands_where_laspy_reads_it_in_the_twin_format_and_comes_back(pid, extra, rng):
    rows = _records(pid, 2000, extra, rng)
    lay = to_layered(rows, pid)
    twin = LAYERED[pid]
    assert lay.shape == (2000, laspy.PointFormat(twin).size + extra) == (2000, layered_size(pid, rows.shape[1]))
    a, b = _fields(rows, pid), _fields(lay, twin)
    same = ["X", "Y", "Z", "intensity", "return_number", "number_of_returns", "scan_direction_flag", "edge_of_flight_line",
            "classification", "synthetic", "key_point", "withheld", "user_data", "point_source_id"]
    same += ["gps_time"] if pid in (1, 3) else []
    same += ["red", "green", "blue"] if pid in (2, 3) else []
    for name in same:  # bit for bit (random GPS times include NaNs)
        assert np.asarray(a[name]).tobytes() == np.asarray(b[name]).tobytes(), name
    assert np.array_equal(np.asarray(a["scan_angle_rank"]).astype(np.int16), np.asarray(b.array["scan_angle"]))
    for name in ["overlap", "scanner_channel"] + ([] if pid in (1, 3) else ["gps_time"]):
        assert not np.asarray(b[name]).any(), name
    assert np.array_equal(lay[:, -extra or lay.shape[1]:], rows[:, -extra or rows.shape[1]:])  # extra bytes as they were
    assert np.array_equal(from_layered(lay, pid), rows)


@pytest.mark.parametrize("byte, value, pid", [
    (14, 0x08, 1),  # a return number above 7
    (14, 0x80, 1),  # a number of returns above 7
    (15, 0x08, 1),  # overlap
    (15, 0x10, 1),  # a scanner channel
    (16, 32, 1),  # a class above 31
    (19, 0x01, 1),  # a scan angle beyond int8
    (25, 0x01, 0),  # GPS time in a format without it
])
def test_a_record_no_format_0_to_3_record_maps_to_is_refused(byte, value, pid, rng):
    lay = to_layered(_records(pid, 5, 0, rng), pid)
    lay[:, 14:20] = 0  # a valid record, then one bit set where no record of the format can
    lay[3, byte] |= value
    with pytest.raises(ValueError, match=f"record 3 holds fields point format {pid} does not have"):
        from_layered(lay, pid)


def test_formats_that_have_no_twin_are_stored_as_they_are(rng):
    for pid in (4, 5, 6, 7, 8, 9, 10):
        assert layered_format(laspy.PointFormat(pid)) is None and layered_size(pid, 100) is None
    pf = laspy.PointFormat(3)
    pf.add_extra_dimension(laspy.ExtraBytesParams("height", "f8"))
    twin = layered_format(pf)
    assert twin.id == 7 and list(twin.extra_dimension_names) == ["height"] and twin.size == 36 + 8


@pytest.mark.parametrize("pid", [0, 1, 2, 3])
def test_a_records_laz_of_format_0_to_3_is_a_layered_laz_that_reads_back(pid, rng):
    pf = laspy.PointFormat(pid)
    rows = _records(pid, 3000, 0, rng)
    raw = records_laz(rows, pf, "1.2", [0.001] * 3, [0.0] * 3)
    las = laspy.read(io.BytesIO(raw))
    assert las.header.point_format.id == LAYERED[pid] and las.header.are_points_compressed
    back = from_layered(np.ascontiguousarray(las.points.array).view(np.uint8).reshape(3000, -1), pid)
    assert np.array_equal(back, rows)
