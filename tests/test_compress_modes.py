"""The two modes of ``compress``: model mode within the budget point by point, points mode every point back exactly."""

import laspy
import numpy as np
import pytest
from click.testing import CliRunner
from conftest import ROOT, flat_las, shared_file

from patchcloud.core import PatchcloudIOError, PatchcloudValueError, dequantise_models, patch_distances
from patchcloud.stream import compress, decompress
from patchcloud.stream.cli import main
from patchcloud.stream.io import pcz
from patchcloud.stream.io.point_coding import coarse_steps, coarsen, refine

OFFSET = np.array([651000.0, 6862000.0, 0.0])
BUDGET = 0.02


def write_las(path, pts, point_format=6, seed=0, extra=True, scale=0.001):
    """``pts`` (local metres) as LAS of ``point_format`` with every dimension filled at random (and an extra dimension)."""
    rng = np.random.default_rng(seed)
    h = laspy.LasHeader(point_format=point_format, version="1.4" if point_format >= 6 else "1.3" if point_format >= 4 else "1.2")
    h.scales, h.offsets = [scale] * 3, OFFSET
    if extra:
        h.add_extra_dims([laspy.ExtraBytesParams(name="Deviation", type=np.float32),
                          laspy.ExtraBytesParams(name="Echo", type="3u2")])
    las = laspy.LasData(h)
    las.x, las.y, las.z = pts[:, 0] + OFFSET[0], pts[:, 1] + OFFSET[1], pts[:, 2]
    n = len(pts)
    for d in las.point_format.dimensions:
        if d.name in ("X", "Y", "Z"):
            continue
        t = np.dtype(d.dtype)
        shape = (n,) if d.num_elements == 1 else (n, d.num_elements)
        if d.kind == laspy.DimensionKind.BitField:
            v = rng.integers(0, 2 ** d.num_bits, n)
        elif t.kind == "f":
            v = rng.normal(size=shape).astype(t.base)
        else:
            info = np.iinfo(t.base)
            v = rng.integers(max(info.min, -1000), min(info.max, 60000), shape).astype(t.base)
        las[d.name] = v
    if point_format < 6:
        las.classification = rng.integers(0, 31, n)
    if "gps_time" in las.point_format.dimension_names:
        las.gps_time = np.sort(rng.uniform(0, 1000, n))
    las.write(path)
    return path


def noisy_scene(rng, n=30000):
    """A plane with noise of 0.6 budgets (a tenth of its points beyond the budget, but fitted within it) and a bush."""
    xy = rng.uniform(0, 20, (n, 2))
    ground = np.column_stack([xy, 0.05 * xy[:, 0] + rng.normal(0, 0.6 * BUDGET, n)])
    bush = rng.normal([14.0, 6.0, 1.0], 0.5, (3000, 3))
    return np.vstack([ground, bush])


def test_model_mode_keeps_every_point_within_the_budget_of_its_patch_or_of_its_residual_point(tmp_path):
    rng = np.random.default_rng(3)
    src = write_las(tmp_path / "n.las", noisy_scene(rng), extra=False)
    s = compress(src, tmp_path / "n.pcz", max_error=BUDGET, tile_size=8.0, quiet=True)
    las = laspy.read(src)
    X = np.column_stack([las.X, las.Y, las.Z]).astype(np.int64)
    k = coarse_steps(BUDGET, las.header.scales)
    coded = np.column_stack([refine(coarsen(X[:, a], k[a]), k[a]) for a in range(3)])
    assert np.linalg.norm((coded - X) * 0.001, axis=1).max() <= BUDGET
    with pcz.open_pcz(tmp_path / "n.pcz") as f:
        origin = np.asarray(f.attrs["grid"]["origin"])
        local = X * 0.001 + OFFSET - origin
        near = np.zeros(len(X), bool)  # within the budget of the decoded patch of the octree cell the point is in
        for t in range(len(f.tiles)):
            m = dequantise_models(f.patches(t)[0])
            lo, e = m.cell_corner(), m.edge
            inside = np.flatnonzero(np.all((local >= m.root_corner) & (local < m.root_corner + m.root_edge), axis=1))
            for c in range(len(e)):
                rows = inside[np.all((local[inside] >= lo[c]) & (local[inside] < lo[c] + e[c]), axis=1)]
                p = np.full(len(rows), m.cell_patch[c])
                near[rows[patch_distances(m, local[rows], p) <= BUDGET]] = True
        residual = np.concatenate([f.residual(t)[0] for t in range(len(f.tiles))]).astype(np.int64)
    # every point not near its patch comes back as a residual point at its coded position
    key = lambda a: a[:, 0] * 10**12 + a[:, 1] * 10**6 + a[:, 2]  # noqa: E731 (coordinates below 10**6 here)
    res_keys, res_n = np.unique(key(residual), return_counts=True)
    far = ~near
    far_keys, far_n = np.unique(key(coded[far]), return_counts=True)
    pos = np.searchsorted(res_keys, far_keys)
    assert np.all(res_keys[np.minimum(pos, len(res_keys) - 1)] == far_keys) and np.all(res_n[pos] >= far_n)
    assert far.sum() > 1500 and s.residual >= far.sum()  # the noise puts many points beyond the budget: residual
    assert s.points - s.residual > 0.3 * s.points  # the plane is modelled still


@pytest.mark.parametrize("point_format", range(11))
def test_points_mode_gives_every_point_back_in_order_with_every_attribute(tmp_path, point_format):
    rng = np.random.default_rng(point_format)
    src = write_las(tmp_path / "a.las", noisy_scene(rng, 4000), point_format=point_format, seed=point_format)
    s = compress(src, tmp_path / "a.pcz", max_error=0.05, keep_points=True, quiet=True)
    assert s.mode == "points" and s.points == 7000 and s.steps == [57, 57, 57]  # floor(2 x 5 cm / (sqrt(3) x 1 mm))
    out = tmp_path / "b.laz"
    if point_format in (9, 10):  # lazrs shifts their wave packet offsets where the scanner channel changes: refused
        with pytest.raises(PatchcloudValueError, match="write LAS"):
            decompress(tmp_path / "a.pcz", out)
        assert not out.exists()
        out = tmp_path / "b.las"
    decompress(tmp_path / "a.pcz", out)
    a, b = laspy.read(src), laspy.read(out)
    assert b.point_format.id == point_format and list(b.point_format.dimension_names) == list(a.point_format.dimension_names)
    for name in a.point_format.dimension_names:
        if name not in ("X", "Y", "Z"):
            assert np.asarray(b[name]).tobytes() == np.asarray(a[name]).tobytes(), name
    d = np.sqrt((a.x - b.x) ** 2 + (a.y - b.y) ** 2 + (a.z - b.z) ** 2)
    assert 0.01 < d.max() <= 0.05
    assert np.array_equal(b.X, refine(coarsen(a.X, 57), 57))  # the coded positions, point by point, in input order


def test_points_mode_below_the_grid_is_exact_and_drop_zeroes_exactly_what_it_names(tmp_path):
    rng = np.random.default_rng(1)
    src = write_las(tmp_path / "a.las", noisy_scene(rng, 4000), scale=0.01)
    s = compress(src, tmp_path / "a.pcz", max_error=0.01, keep_points=True, drop=("GpsTime", "Echo", "user_data"), quiet=True)
    assert s.steps == [1, 1, 1] and s.dropped == ["gps_time", "Echo", "user_data"]
    decompress(tmp_path / "a.pcz", tmp_path / "b.las")
    a, b = laspy.read(src), laspy.read(tmp_path / "b.las")
    for name in a.point_format.dimension_names:
        same = np.asarray(b[name]).tobytes() == np.asarray(a[name]).tobytes()
        if name in ("gps_time", "Echo", "user_data"):
            assert not np.asarray(b[name]).any() and np.asarray(a[name]).any(), name
        else:
            assert same, name  # X, Y, Z too: the budget is below the file's 1 cm grid
    small = tmp_path / "d.pcz"
    compress(src, small, max_error=0.01, keep_points=True, quiet=True)
    assert (tmp_path / "a.pcz").stat().st_size < small.stat().st_size


@pytest.mark.parametrize("name", ["embedded", "lidar-ign-extrabytes/las_with_several_extra_byte_bloc.laz"])
def test_points_mode_on_the_files_grid_is_no_larger_than_the_input_laz(tmp_path, name):
    """At a budget below the grid the blocks are the input's records re-coded by lazrs, plus the .pcz's own arrays: the
    strongest Zstd level on the blocks (pcz.LAZ_CODEC_EXACT) is what keeps the file from growing (the 697,721-point
    extra-bytes file: 3,238,440 bytes against its 3,240,041; its blocks alone are 3,244,446 bytes at the middle
    level)."""
    src = ROOT / "data" / "test_data_77055_627760_LA93_IGN69.laz" if name == "embedded" else shared_file(name)
    s = compress(src, tmp_path / "a.pcz", max_error=0.01, keep_points=True, quiet=True)
    assert s.steps == [1, 1, 1]
    assert (tmp_path / "a.pcz").stat().st_size <= src.stat().st_size


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_points_mode_is_the_same_bytes_whatever_the_workers_and_the_scheduler(tmp_path):
    # 900,000 points: eight parts for one worker would be 150,000 points each, for two 100,000; the blocks must not follow
    rng = np.random.default_rng(4)
    src = write_las(tmp_path / "a.las", noisy_scene(rng, 900000), extra=False)
    runs = [dict(in_memory=True, workers=1), dict(in_memory=True, workers=2), dict(scheduler="threads", workers=2)]
    for k, run in enumerate(runs):
        compress(src, tmp_path / f"{k}.pcz", max_error=0.05, keep_points=True, quiet=True, **run)
    assert (tmp_path / "0.pcz").read_bytes() == (tmp_path / "1.pcz").read_bytes() == (tmp_path / "2.pcz").read_bytes()


def test_points_mode_does_not_depend_on_the_part_size_or_the_scheduler_and_reads_a_box(tmp_path):
    rng = np.random.default_rng(2)
    src = write_las(tmp_path / "a.las", noisy_scene(rng, 120000))
    compress(src, tmp_path / "one.pcz", max_error=0.05, keep_points=True, quiet=True, scheduler="synchronous")
    compress(src, tmp_path / "two.pcz", max_error=0.05, keep_points=True, quiet=True, scheduler="threads", workers=2, chunk=50000)
    again = compress(src, tmp_path / "one2.pcz", max_error=0.05, keep_points=True, quiet=True, scheduler="synchronous")
    assert (tmp_path / "one.pcz").read_bytes() == (tmp_path / "one2.pcz").read_bytes() and again.points == 123000
    with pcz.open_pcz(tmp_path / "two.pcz") as f:
        assert len(f.bounds) == 3
    decompress(tmp_path / "one.pcz", tmp_path / "one.las")
    decompress(tmp_path / "two.pcz", tmp_path / "two.las")
    a, b = laspy.read(tmp_path / "one.las"), laspy.read(tmp_path / "two.las")
    assert np.asarray(a.points.array).tobytes() == np.asarray(b.points.array).tobytes()
    box = (OFFSET[0] + 2, OFFSET[1] + 3, -5.0, OFFSET[0] + 6, OFFSET[1] + 9, 5.0)
    decompress(tmp_path / "two.pcz", tmp_path / "box.las", bbox=box)
    part = laspy.read(tmp_path / "box.las")
    inside = (a.x >= box[0]) & (a.x <= box[3]) & (a.y >= box[1]) & (a.y <= box[4]) & (a.z >= box[2]) & (a.z <= box[5])
    assert 0 < len(part.points) == int(inside.sum())
    assert np.asarray(part.points.array).tobytes() == np.asarray(a.points.array[inside]).tobytes()
    far = (OFFSET[0] - 50, OFFSET[1] - 50, -5.0, OFFSET[0] - 40, OFFSET[1] - 40, 5.0)  # outside the input: an error, no file
    with pytest.raises(PatchcloudValueError, match=r"two.pcz: the box x .* lies outside the input's bounds \(x .*\): no point to write"):
        decompress(tmp_path / "two.pcz", tmp_path / "far.las", bbox=far)
    assert not (tmp_path / "far.las").exists()


def test_points_mode_bad_requests_and_damaged_files_are_one_line(tmp_path):
    rng = np.random.default_rng(4)
    src = write_las(tmp_path / "a.las", noisy_scene(rng, 2000))
    for mode in (["--keep-points"], []):  # refused before anything runs: no store left for a typo
        r = CliRunner().invoke(main, ["compress", str(src), str(tmp_path / "x.pcz"), *mode, "--drop", "Colour"])
        assert r.exit_code != 0 and "cannot drop 'Colour'" in r.output and "GpsTime" in r.output
        assert "is kept" not in r.output and sorted(p.name for p in tmp_path.iterdir()) == ["a.las"]
    with pytest.raises(PatchcloudValueError, match="drop must be dimension names"):
        compress(src, tmp_path / "x.pcz", keep_points=True, drop=(3,))
    compress(src, tmp_path / "a.pcz", keep_points=True, quiet=True)
    r = CliRunner().invoke(main, ["decompress", str(tmp_path / "a.pcz"), str(tmp_path / "b.las"), "--lod", "1"])
    assert r.exit_code != 0 and "holds every point (compress --keep-points)" in r.output and not (tmp_path / "b.las").exists()
    raw = (tmp_path / "a.pcz").read_bytes()
    (tmp_path / "cut.pcz").write_bytes(raw[: len(raw) // 2])
    r = CliRunner().invoke(main, ["decompress", str(tmp_path / "cut.pcz"), str(tmp_path / "c.las")])
    assert r.exit_code != 0 and "cut.pcz" in r.output and "Traceback" not in r.output and not (tmp_path / "c.las").exists()
    r = CliRunner().invoke(main, ["info", str(tmp_path / "a.pcz")])
    assert r.exit_code == 0 and "points mode" in r.output and "every one in input order" in r.output


def test_a_block_whose_laz_disagrees_with_the_index_is_refused(tmp_path):
    rng = np.random.default_rng(5)
    src = write_las(tmp_path / "a.las", noisy_scene(rng, 2000))
    compress(src, tmp_path / "a.pcz", keep_points=True, quiet=True)
    with pcz.open_pcz(tmp_path / "a.pcz") as f:
        f.attrs["record_bytes"] += 1
        with pytest.raises(PatchcloudIOError, match="block 0: its LAZ header says 5,000 points of"):
            f.block(0)


def test_drop_stores_a_zero_of_a_scaled_extra_dimension_that_cannot_hold_a_scaled_zero(tmp_path):
    """A uint8 extra dimension of offset 100 and scale 0.5 cannot hold the value 0 (stored -200): --drop stores 0 (the
    value 100), in points mode as in model mode, where it was an internal error."""
    las = flat_las(extra=[laspy.ExtraBytesParams("s8", "u1", scales=np.array([0.5]), offsets=np.array([100.0]))])
    las.points.array["s8"] = np.random.default_rng(0).integers(1, 255, len(las.points))
    src = tmp_path / "s8.las"
    las.write(src)
    for keep in (True, False):
        compress(src, tmp_path / f"{keep}.pcz", max_error=0.05, keep_points=keep, drop=("s8",), quiet=True)
        decompress(tmp_path / f"{keep}.pcz", tmp_path / f"{keep}.las")
        back = laspy.read(tmp_path / f"{keep}.las")
        assert not np.asarray(back.points.array["s8"]).any() and np.all(np.asarray(back["s8"]) == 100.0), keep


def test_points_at_the_ends_of_las_32_bit_range_come_back_within_the_budget(tmp_path):
    """X = 2^31 - 1 and X = -2^31 are LAS coordinates: rounded to multiples of k steps (k = 57 at 5 cm on a 1 mm grid)
    they lie beyond the range, and decompress called the .pcz compress had just written damaged, in both modes.  Now
    they come back at the range's end, within the budget, and every point of points mode within it."""
    rng = np.random.default_rng(0)
    n = 2000
    for name, edge in (("hi", 2**31 - 1), ("lo", -(2**31))):
        h = laspy.LasHeader(point_format=6, version="1.4")
        h.scales, h.offsets = [0.001] * 3, [0.0] * 3
        las = laspy.LasData(h)
        las.points = laspy.ScaleAwarePointRecord.zeros(n, header=h)
        sign = -1 if edge > 0 else 1
        X = edge + sign * rng.integers(0, 20000, n)
        X[:3] = edge
        las.X, las.Y, las.Z = X, rng.integers(0, 20000, n), rng.integers(0, 100, n)
        las.return_number, las.number_of_returns = np.ones(n, int), np.ones(n, int)
        src = tmp_path / f"{name}.las"
        las.write(src)
        for keep in (True, False):
            pcz = tmp_path / f"{name}{keep}.pcz"
            compress(src, pcz, max_error=0.05, keep_points=keep, quiet=True)
            decompress(pcz, tmp_path / f"{name}{keep}.las")
            back = laspy.read(tmp_path / f"{name}{keep}.las")
            assert len(back.points) >= n // 2, (name, keep)
            if keep:
                d = np.sqrt((back.x - las.x) ** 2 + (back.y - las.y) ** 2 + (back.z - las.z) ** 2)
                assert d.max() <= 0.05 and np.any(np.asarray(back.X) == edge), (name, keep)


def _with_internal_waveforms(path, point_format: int, version: str, n: int = 2000) -> None:
    """A LAS file of point format 4 or 9 whose wave packets lie in its internal waveform data packet record (LAS 1.3:
    after the points, the header pointing at it; LAS 1.4: its first EVLR), 64 random bytes a point."""
    import struct

    las = flat_las(point_format, version, n=n)
    las.header.vlrs.append(laspy.VLR(user_id="LASF_Spec", record_id=101, description="wf desc",
                                     record_data=struct.pack("<BBIIdd", 8, 0, 64, 100, 1.0, 0.0)))
    rng = np.random.default_rng(0)
    las.wavepacket_index, las.wavepacket_offset, las.wavepacket_size = np.ones(n, int), 60 + np.arange(n) * 64, np.full(n, 64)
    las.write(path)
    b = bytearray(path.read_bytes())
    w = len(b)
    data = rng.integers(0, 255, n * 64, dtype=np.uint8).tobytes()
    b += struct.pack("<H16sHQ32s", 0, b"LASF_Spec", 65535, len(data), b"waveform data") + data
    struct.pack_into("<Q", b, 227, w)  # start_of_waveform_data_packet_record
    if version == "1.4":
        struct.pack_into("<QI", b, 235, w, 1)  # its first EVLR
    struct.pack_into("<H", b, 6, struct.unpack_from("<H", b, 6)[0] | 2)  # global encoding: waveform data internal
    path.write_bytes(bytes(b))


def _waves(path) -> tuple[int, list[bytes]]:
    import struct

    b = path.read_bytes()
    at = struct.unpack_from("<Q", b, 227)[0]
    las = laspy.read(path)
    return at, [b[at + o : at + o + s] for o, s in zip(np.asarray(las.wavepacket_offset), np.asarray(las.wavepacket_size))]


@pytest.mark.parametrize("point_format, version", [(4, "1.3"), (9, "1.4")])
def test_internal_waveforms_come_back_in_points_mode_and_are_left_out_in_model_mode(tmp_path, point_format, version):
    """Points mode gives back the internal waveform data packet record (a LAS 1.3 input's as the LAS 1.4 output's first
    EVLR), the header pointing at it, so every point's wave packet is its bytes (a 1.3 input's record was lost and a
    1.4 input's pointed at by the input's offset); model mode's points keep no wave packet: no record, no pointer."""
    src = tmp_path / "wf.las"
    _with_internal_waveforms(src, point_format, version)
    at, want = _waves(src)
    assert at > 0 and len(set(want)) > 1000
    compress(src, tmp_path / "p.pcz", max_error=0.05, keep_points=True, quiet=True)
    decompress(tmp_path / "p.pcz", tmp_path / "p.las")
    at, got = _waves(tmp_path / "p.las")
    back = laspy.read(tmp_path / "p.las")
    assert at > 0 and back.header.global_encoding.waveform_data_packets_internal and got == want
    compress(src, tmp_path / "m.pcz", max_error=0.05, quiet=True)
    decompress(tmp_path / "m.pcz", tmp_path / "m.las")
    model = laspy.read(tmp_path / "m.las")
    assert model.header.start_of_waveform_data_packet_record == 0
    assert not model.header.global_encoding.waveform_data_packets_internal
    assert not any(v.record_id == 65535 for v in model.header.evlrs)
    assert (tmp_path / "m.pcz").stat().st_size < 64 * 2000  # the waveforms are not in it


def test_points_mode_stopped_while_encoding_leaves_no_blocks(tmp_path, monkeypatch):
    """A full disk or Ctrl-C during the encoding left OUT.pcz.blocks behind (3 MB on a full disk: bug hunt E)."""
    import os

    from patchcloud.stream.jobs import compress_points

    (tmp_path / "in").mkdir()
    src = write_las(tmp_path / "in" / "a.las", noisy_scene(np.random.default_rng(1), 4000))

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(compress_points, "encode_block", full)
    with pytest.raises(OSError, match="No space left"):
        compress(src, tmp_path / "a.pcz", max_error=0.05, keep_points=True, quiet=True, scheduler="synchronous")
    assert sorted(os.listdir(tmp_path)) == ["in"]


def test_points_mode_refuses_the_run_options_it_would_not_use(tmp_path):
    """--keep-points codes the records in input order with no store and no tiles: --tile-size, --store, --keep-store,
    --classes and --keep-noise were taken and did nothing (an asked-for store not there afterwards); now one line names
    them and nothing is written.  --workers and --scheduler run its blocks, and stay."""
    src = ROOT / "data" / "test_data_77055_627760_LA93_IGN69.laz"
    out = tmp_path / "kp.pcz"
    r = CliRunner().invoke(main, ["compress", str(src), str(out), "--keep-points", "--tile-size", "16", "--store",
                                  str(tmp_path / "st.zarr"), "--keep-store", "--classes", "2", "-q"])
    assert r.exit_code == 2 and r.output.count("\n") == 1, r.output
    assert "--tile-size, store (--store), --keep-store, classes (--classes) would do nothing; leave them out" in r.output
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(PatchcloudValueError, match=r"keep_noise \(--keep-noise\) would do nothing; leave it out"):
        compress(src, out, keep_points=True, keep_noise=True, quiet=True)
    r = CliRunner().invoke(main, ["compress", str(src), str(out), "--keep-points", "--workers", "2", "-q"])
    assert r.exit_code == 0 and out.exists(), r.output


@pytest.mark.parametrize("point_format, version", [(1, "1.2"), (6, "1.4")])
def test_model_mode_keeps_the_withheld_flag_of_its_residual_points(tmp_path, point_format, version):
    """Withheld points (the LAS specification: treat as deleted) are in no model and come back as residual points: they
    came back with the flag zero, ordinary ground; now each keeps it, within the budget of where it was."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(9)
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales, header.offsets = np.array([0.01] * 3), np.array([500000.0, 4000000.0, 0.0])
    data = laspy.LasData(header)
    xy = rng.uniform(0, 50, (5000, 2))
    data.x, data.y, data.z = 500000 + xy[:, 0], 4000000 + xy[:, 1], 10 + 0.1 * xy[:, 0]
    data.classification = np.full(5000, 2, np.uint8)
    withheld = np.zeros(5000, bool)
    withheld[::3] = True
    data.withheld = withheld
    data.write(str(tmp_path / "w.las"))
    s = compress(tmp_path / "w.las", tmp_path / "w.pcz", max_error=0.05, quiet=True)
    assert "withheld flag" in s.format() and s.residual >= withheld.sum()
    decompress(tmp_path / "w.pcz", tmp_path / "back.las")
    back = laspy.read(str(tmp_path / "back.las"))
    got = np.asarray(back.withheld, bool)
    assert len(back) == 5000 and got.sum() == withheld.sum()
    dist, _ = cKDTree(np.column_stack([data.x, data.y, data.z])[withheld]).query(np.column_stack([back.x, back.y, back.z])[got])
    assert dist.max() <= 0.05


def test_a_summary_with_no_point_modelled_gives_no_mean_distance(tmp_path):
    """Every point noise (class 7): in no model, so the summary says so instead of "mean distance ... 0.0000"."""
    data = flat_las(point_format=6)
    data.classification = np.full(len(data), 7, np.uint8)
    data.write(str(tmp_path / "noise.las"))
    s = compress(tmp_path / "noise.las", tmp_path / "n.pcz", max_error=0.05, quiet=True)
    assert s.residual == s.points == len(data)
    assert "no point modelled" in s.format() and "mean distance" not in s.format()
