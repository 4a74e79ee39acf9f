"""Sizes read from a file are checked against what the file can hold before anything is allocated from them; absurd
parameters are refused with the limit named; OS errors (disk full) are one line."""

import errno
import struct

import laspy
import numpy as np
import pytest
from click.testing import CliRunner
from test_stream import write_scene

from patchcloud.core import PatchcloudIOError, PatchcloudValueError
from patchcloud.stream import normals
from patchcloud.stream.cli import main
from patchcloud.stream.io import las_output
from patchcloud.stream.io.las import open_source


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("bounds") / "scene.las"
    write_scene(path, n=20_000, seed=9, point_format=6, extra=False)
    return path


def _patched(src, dst, at, fmt, value):
    raw = bytearray(src.read_bytes())
    struct.pack_into(fmt, raw, at, value)
    dst.write_bytes(bytes(raw))
    return dst


@pytest.mark.parametrize("field, at, fmt, value, said", [
    ("VLR count", 100, "<I", 1_000_000_000, r"the header says 1,000,000,000 VLRs, but the [\d,]+ bytes before the point data hold at most \d+"),
    ("point data offset", 96, "<I", 2**32 - 1, r"the header puts the point data at byte 4,294,967,295, outside the file"),
    ("header size", 94, "<H", 12, r"the header says it is 12 bytes long"),
    ("EVLR count", 243, "<I", 4_000_000_000, r"the header says 4,000,000,000 EVLRs from byte [\d,]+, but the file \([\d,]+ bytes\) holds at most \d+"),
])
def test_a_header_claiming_more_than_the_file_holds_is_one_error(scene, tmp_path, field, at, fmt, value, said):
    bad = _patched(scene, tmp_path / "bad.las", at, fmt, value)
    if field == "EVLR count":
        struct.pack_into("<Q", raw := bytearray(bad.read_bytes()), 235, len(raw) - 10)
        bad.write_bytes(bytes(raw))
    with pytest.raises(PatchcloudIOError, match=said):
        open_source(bad)
    r = CliRunner().invoke(main, ["info", str(bad)])
    assert r.exit_code == 2 and r.output.count("\n") == 1 and "Traceback" not in r.output


def test_a_vlr_or_evlr_longer_than_the_file_holds_is_one_error(tmp_path):
    import laspy
    from laspy.vlrs.vlrlist import VLRList

    h = laspy.LasHeader(point_format=6, version="1.4")
    h.vlrs.append(laspy.VLR("test", 2, "a VLR", b"y" * 50))
    las = laspy.LasData(h)
    las.x, las.y, las.z = np.arange(100.0), np.arange(100.0), np.zeros(100)
    las.evlrs = VLRList([laspy.VLR("test", 1, "an EVLR", b"x" * 100)])
    las.write(tmp_path / "ok.las")
    assert open_source(tmp_path / "ok.las").point_count == 100
    raw = (tmp_path / "ok.las").read_bytes()
    header_size, offset = struct.unpack_from("<HI", raw, 94)
    start = struct.unpack_from("<Q", raw, 235)[0]
    vlr = _patched(tmp_path / "ok.las", tmp_path / "vlr.las", header_size + 20, "<H", 60_000)
    with pytest.raises(PatchcloudIOError, match=rf"vlr.las: VLR 1 of 1 \(60,000 bytes of data\) runs past the point data at byte {offset:,}"):
        open_source(vlr)
    evlr = _patched(tmp_path / "ok.las", tmp_path / "evlr.las", start + 20, "<Q", 2**62)
    with pytest.raises(PatchcloudIOError, match=rf"EVLR 1 of 1 \([\d,]+ bytes of data\) runs past the end of the file at byte {len(raw):,}"):
        open_source(evlr)
    r = CliRunner().invoke(main, ["info", str(evlr)])
    assert r.exit_code == 2 and r.output.count("\n") == 1 and "Traceback" not in r.output


def test_a_tile_size_leaving_almost_no_points_per_tile_is_refused(scene, tmp_path):
    with pytest.raises(PatchcloudValueError, match=r"a tile size of 0.0078125 leaves about [\d.e-]+ points per tile .*at least 10 needed"):
        normals(scene, tmp_path / "out.las", tile_size=0.01, quiet=True)
    assert not (tmp_path / "out.las").exists()
    with pytest.raises(PatchcloudValueError, match=r"leaves about 0 points per tile"):  # its square underflows (it divided by 0)
        normals(scene, tmp_path / "out.las", tile_size=1e-200, quiet=True)
    assert not (tmp_path / "out.las").exists()


def test_a_tile_size_leaving_few_points_per_occupied_tile_is_refused_once_tiled_and_no_store_is_kept(tmp_path):
    """A scene 10 m tall of 6,000 points: 1 m tiles pass the footprint's check (about 10 points per tile of its 24 x 24 m),
    but the occupied tiles hold fewer than 50 points each on average: a few milliseconds a tile and a step for
    nothing (a real 57,000-point house in 2 m tiles: 46 s)."""
    rng = np.random.default_rng(3)
    las = tmp_path / "tall.las"
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales = np.array([0.001] * 3)
    data = laspy.LasData(header)
    p = rng.uniform([0, 0, 0], [24, 24, 10], (6_000, 3))
    data.x, data.y, data.z = p[:, 0], p[:, 1], p[:, 2]
    data.write(str(las))
    out = tmp_path / "out.las"
    r = CliRunner().invoke(main, ["normals", str(las), str(out), "--tile-size", "1", "--on-disk", "--scheduler", "synchronous", "-q"])
    assert r.exit_code == 2 and r.output.count("\n") == 1, r.output
    assert "a tile size of 1 (in the file's unit, a power of two) leaves" in r.output and "points per occupied tile" in r.output \
        and "--tile-size" in r.output
    assert "store" not in r.output  # nothing kept to resume from: the same command would fail again
    assert not out.exists() and not (tmp_path / "out.las.store").exists() and list(tmp_path.iterdir()) == [las]
    r = CliRunner().invoke(main, ["normals", str(las), str(out), "--tile-size", "8", "--scheduler", "synchronous", "-q"])
    assert r.exit_code == 0, r.output


def test_a_full_disk_is_one_line_naming_the_file_and_the_kept_store(scene, tmp_path, monkeypatch):
    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "out.las.partial"))

    monkeypatch.setattr(las_output, "finish", full)
    r = CliRunner().invoke(main, ["normals", str(scene), str(tmp_path / "out.las"), "--on-disk", "--scheduler", "synchronous",
                                  "--quiet"])
    assert r.exit_code == 2, r.output
    assert r.output.count("\n") == 1 and "Traceback" not in r.output
    assert r.output.startswith(f"error: {tmp_path / 'out.las.partial'}: No space left on device (the store ")
    assert not (tmp_path / "out.las").exists() and not (tmp_path / "out.las.partial").exists()


def test_a_full_disk_while_tiling_is_one_line_naming_the_file_and_the_kept_store(scene, tmp_path, monkeypatch):
    # `tile` said the store was kept for its own errors and Ctrl-C, but let an OSError through without it (a smaller
    # twin of the jobs' handling: they now share stream.engine.job.says_what_is_kept)
    from patchcloud.stream.io.store import Store

    def full(self, *args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "s.zarr" / "tiles"))

    monkeypatch.setattr(Store, "write", full)
    r = CliRunner().invoke(main, ["tile", str(scene), str(tmp_path / "s.zarr"), "--scheduler", "synchronous", "--quiet"])
    assert r.exit_code == 2 and r.output.count("\n") == 1 and "Traceback" not in r.output, r.output
    assert r.output.startswith(f"error: {tmp_path / 's.zarr' / 'tiles'}: No space left on device (the store {tmp_path / 's.zarr'}, "), r.output
    assert "is kept: the same command resumes from it" in r.output


def test_an_absurd_decompress_density_is_refused_before_writing(scene, tmp_path):
    from patchcloud.stream import compress, decompress

    compress(scene, tmp_path / "s.pcz", max_error=0.02, quiet=True)
    with pytest.raises(PatchcloudValueError, match=r"a density of 1e\+09 per square unit would sample about [\d,]+ points, more than 100 "
                                                   r"times the [\d,]+ the file stands for"):
        decompress(tmp_path / "s.pcz", tmp_path / "back.laz", density=1e9)
    assert not (tmp_path / "back.laz").exists()


def test_big_tiles_are_sampled_in_batches_of_bounded_size(scene, tmp_path, monkeypatch):
    import laspy

    from patchcloud.stream import compress, decompress
    from patchcloud.stream.jobs import decompress as module

    compress(scene, tmp_path / "s.pcz", max_error=0.02, quiet=True)
    whole = decompress(tmp_path / "s.pcz", tmp_path / "whole.las")
    monkeypatch.setattr(module, "SAMPLE_BATCH", 500)
    a = decompress(tmp_path / "s.pcz", tmp_path / "a.las")
    decompress(tmp_path / "s.pcz", tmp_path / "b.las")
    assert (a.reconstructed, a.residual) == (whole.reconstructed, whole.residual)  # every cell's count, in batches
    assert (tmp_path / "a.las").read_bytes() == (tmp_path / "b.las").read_bytes()  # and the same points every time
    w, b = laspy.read(str(tmp_path / "whole.las")), laspy.read(str(tmp_path / "a.las"))
    assert np.array_equal(np.sort(w.classification), np.sort(b.classification))  # each cell's points, in the same cells


def test_an_unexpected_error_is_one_line_unless_debug(scene, tmp_path, monkeypatch):
    from patchcloud.stream.jobs import normals_tiles

    def bug(*args, **kwargs):
        raise RuntimeError("boom")

    monkeypatch.setattr(normals_tiles, "finish_one_tile", bug)
    args = ["normals", str(scene), str(tmp_path / "out.las"), "--scheduler", "synchronous", "--quiet"]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2 and r.output.count("\n") == 1, r.output
    assert r.output.startswith("error: internal error: RuntimeError: boom (a bug in patchcloud: `patchcloud --debug ...`")
    r = CliRunner().invoke(main, ["--debug", *args])
    assert isinstance(r.exception, RuntimeError) and str(r.exception).startswith("boom")


def test_a_full_disk_in_memory_names_the_output_even_when_the_error_names_no_file(scene, tmp_path, monkeypatch):
    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")  # as a write() on an open file raises it: no file name

    monkeypatch.setattr(las_output, "finish", full)
    r = CliRunner().invoke(main, ["normals", str(scene), str(tmp_path / "out.las"), "--in-memory", "--quiet"])
    assert r.exit_code == 2 and r.output.count("\n") == 1, r.output
    assert r.output.startswith(f"error: {tmp_path / 'out.las'}: No space left on device"), r.output
    assert not (tmp_path / "out.las").exists() and not (tmp_path / "out.las.partial").exists()


def test_point_data_that_cannot_be_decoded_leaves_no_store_and_offers_no_resume(tmp_path):
    """A LAZ whose first chunk fails to decode (one byte flipped; its last chunk, which opening it checks, is sound) is
    one line naming the file and the points, exit 2; the run's store is removed, not offered for resuming (a rerun
    reads the file anew)."""
    write_scene(tmp_path / "scene.las", n=120_000, seed=9, point_format=6, extra=False)
    laspy.read(str(tmp_path / "scene.las")).write(str(tmp_path / "good.laz"))
    raw = bytearray((tmp_path / "good.laz").read_bytes())
    raw[len(raw) // 10] ^= 0xFF  # in the first of its three chunks of 50,000 points
    (tmp_path / "bad.laz").write_bytes(bytes(raw))
    for how in (["--scheduler", "synchronous"], ["--scheduler", "processes", "--workers", "2"]):
        r = CliRunner().invoke(main, ["normals", str(tmp_path / "bad.laz"), str(tmp_path / "out.laz"), "--on-disk", "-q", *how])
        assert r.exit_code == 2 and r.output.count("\n") == 1, r.output
        assert "bad.laz: corrupt or truncated point data in points 0 to " in r.output, r.output
        assert "store" not in r.output and sorted(p.name for p in tmp_path.iterdir()) == ["bad.laz", "good.laz", "scene.las"]


def test_a_file_too_sparse_for_the_largest_tiles_runs_in_them(tmp_path):
    """5,000 points over 100 km hold 8 points per occupied tile of 4,096 m, the largest: no larger size to ask for, so
    the file runs in those tiles (it was refused with "give a larger --tile-size, or leave it out", the size left out)."""
    rng = np.random.default_rng(5)
    las = tmp_path / "sparse.las"
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = np.array([0.01] * 3), np.array([600000.0, 6000000.0, 0.0])
    data = laspy.LasData(header)
    xy = rng.uniform(0, 100_000, (5_000, 2))
    data.x, data.y, data.z = 600000 + xy[:, 0], 6000000 + xy[:, 1], 100 + 0.001 * xy[:, 0]
    data.write(str(las))
    for extra in ([], ["--on-disk", "--scheduler", "synchronous"]):
        out = tmp_path / f"out{len(extra)}.las"
        r = CliRunner().invoke(main, ["normals", str(las), str(out), "-q", *extra])
        assert r.exit_code == 0, r.output
        got = laspy.read(str(out))
        assert len(got) == 5_000 and np.isfinite(got.NormalZ).all()
