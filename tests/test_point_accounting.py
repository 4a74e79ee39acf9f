"""Exact point accounting: a LAS or LAZ whose header point count disagrees with its data is refused with the two numbers
wherever the file makes it detectable; valid files whose point data is followed by something else are accepted."""

import struct

import laspy
import numpy as np
import pytest
from click.testing import CliRunner

from patchcloud.core import PatchcloudIOError
from patchcloud.stream import normals
from patchcloud.stream.cli import main
from patchcloud.stream.io.las import open_source


def _cloud(n, point_format, version="1.4", seed=0):
    rng = np.random.default_rng(seed)
    h = laspy.LasHeader(point_format=point_format, version=version)
    h.scales, h.offsets = [0.01, 0.01, 0.01], [0, 0, 0]
    las = laspy.LasData(h)
    xy = rng.uniform(0, 40, (n, 2))
    las.x, las.y = xy[:, 0], xy[:, 1]
    las.z = 0.05 * xy[:, 0] + rng.normal(0, 0.002, n)
    las.intensity = rng.integers(0, 1000, n)
    return las


def _set_count(path, n):
    """Write ``n`` as the header's point count (the legacy field, and the 64-bit one of LAS 1.4)."""
    raw = bytearray(path.read_bytes())
    raw[107:111] = struct.pack("<I", min(n, 2**32 - 1))
    if raw[25] >= 4:
        raw[247:255] = struct.pack("<Q", n)
    path.write_bytes(bytes(raw))


@pytest.mark.parametrize("point_format", [6, 8])
@pytest.mark.parametrize("header", [999, 1003])
def test_a_layered_laz_whose_header_count_differs_from_its_chunks_is_refused(tmp_path, point_format, header):
    path = tmp_path / "x.laz"
    _cloud(1001, point_format).write(str(path))
    assert open_source(path).point_count == 1001
    _set_count(path, header)
    with pytest.raises(PatchcloudIOError, match=rf"x.laz: the header says {header:,} points but the LAZ chunk table holds 1,001$"):
        open_source(path)


def test_a_laz_of_fixed_chunks_whose_header_count_needs_fewer_chunks_is_refused(tmp_path):
    path = tmp_path / "x.laz"
    _cloud(120_000, 1, version="1.2").write(str(path))  # chunks of 50,000: 3 chunks
    _set_count(path, 40_000)
    with pytest.raises(PatchcloudIOError, match=r"the header says 40,000 points but the LAZ chunk table holds 100,001 to 150,000"):
        open_source(path)


def test_the_cli_refuses_it_in_one_line_writing_nothing(tmp_path):
    path = tmp_path / "x.laz"
    _cloud(1001, 6).write(str(path))
    _set_count(path, 999)
    r = CliRunner().invoke(main, ["normals", str(path), str(tmp_path / "out.laz")])
    assert r.exit_code == 2 and r.output.count("\n") == 1 and "999" in r.output and "1,001" in r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.laz"]


def _with_waveform_record(path, n_points, payload=1000):
    """A LAS 1.3 point format 4 file followed by an internal waveform data packet record (60-byte header and payload)."""
    las = _cloud(n_points, 4, version="1.3")
    las.write(str(path))
    raw = bytearray(path.read_bytes())
    at = len(raw)
    record = struct.pack("<H16sHQ32s", 0, b"LASF_Spec", 65535, payload, b"waveform data") + bytes(range(256)) * (payload // 256) + bytes(payload % 256)
    raw += record
    raw[6:8] = struct.pack("<H", struct.unpack("<H", bytes(raw[6:8]))[0] | 0b10)  # waveform data packets internal
    raw[227:235] = struct.pack("<Q", at)
    path.write_bytes(bytes(raw))
    return las


def test_a_las_13_with_an_internal_waveform_record_is_accepted_and_runs(tmp_path):
    path = tmp_path / "wave.las"
    las = _with_waveform_record(path, 999)
    assert open_source(path).point_count == 999
    out = tmp_path / "out.las"
    normals(path, out, quiet=True)
    back = laspy.read(str(out))
    assert len(back) == 999 and np.array_equal(back.X, las.X) and np.array_equal(back.intensity, las.intensity)
    assert np.array_equal(back.NormalZ != 0, np.ones(999, bool))
    h = back.header  # the waveform record follows the points, the header pointing at it: the descriptors stay true
    assert h.global_encoding.waveform_data_packets_internal
    raw_in, raw_out = path.read_bytes(), out.read_bytes()
    first_in = laspy.open(str(path)).header.start_of_waveform_data_packet_record
    assert raw_out[h.start_of_waveform_data_packet_record:] == raw_in[first_in:]


def test_points_past_the_header_count_before_a_waveform_record_are_still_refused(tmp_path):
    path = tmp_path / "wave.las"
    _with_waveform_record(path, 1001)
    _set_count(path, 999)
    with pytest.raises(PatchcloudIOError, match=r"the header says 999 points but the point data holds 1,001"):
        open_source(path)


def test_a_las_10_input_is_written_as_las_14_with_the_same_records(tmp_path):
    """Outputs are LAS 1.4 (issue 18): a LAS 1.0 input's outputs are LAS 1.4 of the same point format (formats 0 and 1
    are those of 1.0), with the legacy point count set, instead of the whole job running and then failing at the export."""
    from patchcloud.stream import compress, decompress

    path = tmp_path / "old.las"
    las = _cloud(3000, 1, version="1.2")
    las.write(str(path))
    raw = bytearray(path.read_bytes())
    raw[25] = 0  # version minor: LAS 1.0
    path.write_bytes(bytes(raw))
    assert str(laspy.open(str(path)).header.version) == "1.0"
    normals(path, tmp_path / "out.las", quiet=True)
    back = laspy.read(str(tmp_path / "out.las"))
    assert str(back.header.version) == "1.4" and back.header.point_format.id == 1
    assert np.array_equal(back.X, las.X) and np.array_equal(back.gps_time, las.gps_time)
    assert struct.unpack_from("<I", (tmp_path / "out.las").read_bytes(), 107)[0] == 3000  # the legacy point count
    compress(path, tmp_path / "old.pcz", max_error=0.02, quiet=True)
    decompress(tmp_path / "old.pcz", tmp_path / "back.laz")
    assert str(laspy.open(str(tmp_path / "back.laz")).header.version) == "1.4"
