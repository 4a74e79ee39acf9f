"""Point formats 9 and 10 whose scanner channel changes: LAZ (lazrs 0.8) does not give back their wave packet fields.

An output that LAZ would corrupt is refused before anything runs (one
line, nothing written); LAS keeps every field; records whose wave packet
fields are all zero lose nothing in LAZ and are written as asked.
"""

import io

import laspy
import numpy as np
import pytest
from click.testing import CliRunner
from test_stream import write_scene

from patchcloud.core import PatchcloudValueError
from patchcloud.stream.cli import main
from patchcloud.stream.io.las import WAVE_PACKET_FIELDS, check_laz_keeps, open_source, wave_packets_break_laz


def _with_wave_packets(path, point_format=9, channels=4, waves=True, n=20_000, seed=3):
    """The synthetic scene in ``point_format``, scanner channels drawn in 0..channels-1, random wave packet fields."""
    write_scene(path, n=n, point_format=point_format, extra=False)
    las = laspy.read(str(path))
    rng = np.random.default_rng(seed)
    las.scanner_channel = rng.integers(0, channels, len(las.points))
    if waves:
        for d in WAVE_PACKET_FIELDS:
            t = las.points.array.dtype[d]
            las[d] = rng.random(len(las.points)).astype(t) if t.kind == "f" else rng.integers(0, 1 << 20, len(las.points)).astype(t)
    las.write(str(path))
    return las


def _laz_round_trip(points: laspy.PackedPointRecord) -> laspy.PackedPointRecord:
    h = laspy.LasHeader(point_format=points.point_format, version="1.4")
    las = laspy.LasData(h)
    las.points = points
    buf = io.BytesIO()
    las.write(buf, do_compress=True, laz_backend=laspy.LazBackend.Lazrs)
    buf.seek(0)
    return laspy.read(buf, laz_backend=laspy.LazBackend.Lazrs).points


@pytest.mark.parametrize("point_format", [9, 10])
@pytest.mark.parametrize("channels,waves", [(4, True), (1, True), (4, False)])
def test_the_guard_says_exactly_when_lazrs_loses_fields(tmp_path, point_format, channels, waves):
    """The guard against the measured behaviour of lazrs: when lazrs is fixed, this test says so."""
    las = _with_wave_packets(tmp_path / "w.las", point_format, channels, waves, n=3000)
    back = _laz_round_trip(las.points)
    lost = [d for d in WAVE_PACKET_FIELDS if not np.array_equal(np.asarray(back[d]), np.asarray(las.points[d]))]
    assert wave_packets_break_laz(las.points) == bool(lost) == (channels > 1 and waves), lost


def test_a_laz_output_that_would_lose_wave_packets_is_refused_before_anything_runs(tmp_path):
    src = tmp_path / "w.las"
    _with_wave_packets(src)
    out = tmp_path / "out.laz"
    r = CliRunner().invoke(main, ["normals", str(src), str(out), "-q", "--scheduler", "synchronous"])
    assert r.exit_code != 0 and r.output.count("\n") == 1, r.output
    assert "out.laz" in r.output and "w.las" in r.output and ".las" in r.output and "Traceback" not in r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w.las"]  # no output, no partial, no store
    with pytest.raises(PatchcloudValueError, match="scanner channel changes"):
        check_laz_keeps(open_source(src), out)


def test_a_las_output_keeps_every_wave_packet_field(tmp_path):
    src = tmp_path / "w.las"
    las = _with_wave_packets(src, point_format=10)
    out = tmp_path / "out.las"
    r = CliRunner().invoke(main, ["normals", str(src), str(out), "-q", "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    back = laspy.read(str(out))
    for d in (*WAVE_PACKET_FIELDS, "scanner_channel", "X", "Y", "Z"):
        assert np.array_equal(np.asarray(back[d]), np.asarray(las[d])), d
    assert np.isfinite(back.NormalZ).all()


def test_zero_wave_packet_fields_with_changing_channels_go_to_laz_unchanged(tmp_path):
    src = tmp_path / "w.las"
    las = _with_wave_packets(src, waves=False)
    out = tmp_path / "out.laz"
    r = CliRunner().invoke(main, ["normals", str(src), str(out), "-q", "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    back = laspy.read(str(out))
    for d in (*WAVE_PACKET_FIELDS, "scanner_channel"):
        assert np.array_equal(np.asarray(back[d]), np.asarray(las[d])), d
