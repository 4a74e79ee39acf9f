"""A layered LAZ input's chunks copied into the output, only the new extra bytes coded: the bytes lazrs writes."""

import io
from pathlib import Path

import laspy
import lazrs
import numpy as np
import pytest
from test_stream import write_scene

from patchcloud.core import PatchcloudIOError
from patchcloud.stream import normals
from patchcloud.stream.io import las_output, laz_layers


def _chunks(data: bytes, vlr) -> list[bytes]:
    """The compressed chunks of what ``lazrs.compress_points`` returned."""
    table = lazrs.read_chunk_table(io.BytesIO(data), vlr)
    out, at = [], 8
    for _, size in table:
        out.append(data[at:at + size])
        at += size
    return out


@pytest.mark.parametrize("pf, m, k, channels, tail", [(6, 0, 21, 1, 0), (6, 16, 21, 4, 0), (7, 3, 5, 2, 0), (8, 0, 24, 3, 0),
                                                      (6, 16, 21, 4, 1), (8, 3, 5, 2, 3)])
def test_a_chunk_with_new_extra_bytes_is_the_one_lazrs_codes_from_the_whole_records(pf, m, k, channels, tail):
    # tail: the input's last extra bytes, which the output moves after the new ones (undescribed bytes)
    rng = np.random.default_rng(pf * 100 + k)
    n = 120_000  # 3 chunks, the last one short
    size = laspy.PointFormat(pf).size + m
    rec = rng.integers(0, 256, (n, size), dtype=np.uint8)
    ch = np.repeat(rng.integers(0, channels, n // 97 + 1), 97)[:n].astype(np.uint8)  # runs of scanner channels
    rec[:, 15] = (rec[:, 15] & 0xCF) | (ch << 4)
    new = rng.integers(0, 256, (n, k), dtype=np.uint8)
    new[:, 0] = 7  # a byte that never changes: no layer
    new[:, 1] = (np.arange(n) // 1000).astype(np.uint8)  # one that seldom does
    new[:, 2] = rng.choice(np.array([0, 255], np.uint8), n)  # the last symbol of the model, often
    vin, vout = lazrs.LazVlr.new_for_compression(pf, m), lazrs.LazVlr.new_for_compression(pf, m + k)
    lp = laz_layers.plan(vin.record_data(), vout.record_data(), size, size + k, tail)
    assert lp == laz_layers.LayeredPlan(in_size=size, in_layers=9 + {6: 0, 7: 1, 8: 2}[pf] + m, new_bytes=k, chunk=50_000, tail=tail)
    copied = _chunks(bytes(lazrs.compress_points(vin, rec.ravel(), False)), vin)
    out = np.concatenate([rec[:, : size - tail], new, rec[:, size - tail :]], axis=1)
    whole = _chunks(bytes(lazrs.compress_points(vout, out.ravel(), False)), vout)
    assert len(copied) == len(whole) == 3
    for c, (a, b) in enumerate(zip(copied, whole)):
        s = slice(c * 50_000, (c + 1) * 50_000)
        assert laz_layers.extend_chunk(a, lp, new[s], ch[s]) == b, c


def test_the_contexts_follow_lazrs_rule_for_scanner_channels():
    # the first point's channel, then a point's channel where it changes, 0 where it does not
    assert laz_layers.byte_contexts(np.array([2, 2, 3, 3, 0, 1, 1], np.uint8)).tolist() == [2, 0, 3, 0, 0, 1, 0]


def test_only_a_layered_input_whose_records_the_output_extends_is_copied():
    v = lambda pf, m: lazrs.LazVlr.new_for_compression(pf, m).record_data()  # noqa: E731
    assert laz_layers.plan(v(6, 0), v(6, 21), 30, 51) is not None
    assert laz_layers.plan(v(1, 0), v(1, 21), 28, 49) is None  # point-wise LAZ (formats 0-5): no layers
    assert laz_layers.plan(v(6, 0), v(7, 21), 30, 57) is None  # a field added in the middle
    assert laz_layers.plan(v(6, 4), v(6, 4), 34, 34) is None  # nothing added
    assert laz_layers.plan(v(6, 4), v(6, 25), 34, 55, tail=4) is not None  # the input's 4 extra bytes moved after the new
    assert laz_layers.plan(v(6, 4), v(6, 25), 34, 55, tail=5) is None  # a point field moved
    assert laz_layers.plan(v(6, 0)[:20], v(6, 21), 30, 51) is None  # a damaged VLR: coded whole, where it is reported
    assert laz_layers.plan(v(6, 0)[:-1], v(6, 21), 30, 51) is None
    other = bytearray(v(6, 0))
    other[12:16] = (10_000).to_bytes(4, "little")  # another chunk size
    assert laz_layers.plan(bytes(other), v(6, 21), 30, 51) is None
    other[12:16] = (0xFFFFFFFF).to_bytes(4, "little")  # variable chunks (COPC)
    assert laz_layers.plan(bytes(other), v(6, 21), 30, 51) is None


@pytest.fixture(scope="module")
def channels_laz(tmp_path_factory):
    """A format-7 LAZ of 120,000 points (3 chunks) with colours, GPS times, two scanner channels, noise and withheld
    points, and 2 extra bytes of its own."""
    d = tmp_path_factory.mktemp("layers")
    las_path, laz_path = d / "scene.las", d / "scene.laz"
    write_scene(las_path, n=120_000, seed=5)
    src = laspy.read(str(las_path))
    las = laspy.LasData(laspy.LasHeader(point_format=7, version="1.4"))
    las.header.scales, las.header.offsets = src.header.scales, src.header.offsets
    las.header.add_extra_dim(laspy.ExtraBytesParams("Amplitude", "u2"))
    las.points = laspy.ScaleAwarePointRecord.zeros(len(src.points), header=las.header)
    las.X, las.Y, las.Z = src.X, src.Y, src.Z
    rng = np.random.default_rng(5)
    n = len(las.points)
    las.gps_time = np.cumsum(rng.uniform(1e-6, 1e-5, n)) + 4e8
    las.red, las.green, las.blue = (rng.integers(0, 65535, n) for _ in range(3))
    las.scanner_channel = (np.arange(n) // 7_000) % 2
    las.number_of_returns = rng.integers(1, 5, n)
    las.return_number = np.minimum(rng.integers(1, 5, n), las.number_of_returns)  # the header counts points by return
    las.classification = rng.choice(np.array([1, 2, 6, 7], np.uint8), n, p=[0.4, 0.3, 0.25, 0.05])
    las.withheld = rng.random(n) < 0.02
    las.Amplitude = rng.integers(0, 4000, n)
    las.write(str(laz_path))
    return laz_path


@pytest.mark.parametrize("in_memory", [pytest.param(False, marks=pytest.mark.slow), True])  # on disk 12-16 s: slow
def test_a_run_that_copies_the_input_chunks_writes_the_bytes_of_one_that_codes_every_record(channels_laz, tmp_path, monkeypatch,
                                                                                           in_memory):
    copied, whole = tmp_path / "copied.laz", tmp_path / "whole.laz"
    taken = []
    real = las_output.layered_source

    def spy(*args, **kwargs):
        out = real(*args, **kwargs)
        taken.append(out is not None)
        return out

    # on disk: one thread, so the sequential decoder, which decodes only the selection, as worker processes do
    run = dict(in_memory=True, scheduler="synchronous") if in_memory else dict(in_memory=False, scheduler="threads", workers=1)
    monkeypatch.setattr(las_output, "layered_source", spy)
    normals(channels_laz, copied, tile_size=16, quiet=True, **run)
    assert taken and all(taken)  # every part copied its chunks
    monkeypatch.setattr(las_output, "layered_source", lambda *a, **k: None)
    normals(channels_laz, whole, tile_size=16, quiet=True, **run)
    assert copied.read_bytes() == whole.read_bytes()
    out, src = laspy.read(str(copied)), laspy.read(str(channels_laz))
    for name in ("X", "Y", "Z", "gps_time", "red", "scanner_channel", "classification", "withheld", "Amplitude"):
        assert np.array_equal(out[name], src[name]), name
    assert np.count_nonzero(out.NormalMethod) > 0.9 * len(out.points)


def test_a_chunk_that_is_not_what_the_chunk_table_says_is_one_error_naming_the_file(channels_laz, tmp_path):
    h = las_output.prepare_header(laspy.open(str(channels_laz)).header, True)
    h.add_extra_dim(laspy.ExtraBytesParams("NormalX", "f4"))
    h = las_output.prepare_header(h, True)
    source = las_output.layered_source(channels_laz, h, ["NormalX"])
    assert source is not None
    bad = las_output.LayeredSource(source.path, source.plan, source.chunks + np.array([[1, 0]]), source.selection)  # each chunk a byte off
    tmp = tmp_path / "out.laz"
    las_output.fragments_dir(tmp).mkdir()
    with pytest.raises(PatchcloudIOError, match="scene.laz: corrupt LAZ chunk 0"):
        las_output.write_laz_part_layered(tmp, 0, bad, 0, np.zeros((50_000, 4), np.uint8), np.zeros(50_000, np.uint8))
    assert not list(las_output.fragments_dir(tmp).iterdir())  # nothing half-written


def test_an_input_that_already_holds_some_of_the_new_dims_is_coded_whole_and_right(channels_laz, tmp_path, monkeypatch):
    # a normal already in the input: the output overwrites it inside the input's record, so no chunk can be copied
    las = laspy.read(str(channels_laz))
    las.add_extra_dim(laspy.ExtraBytesParams("NormalX", "f4"))
    las.NormalX = np.full(len(las.points), 7.0, np.float32)
    src = tmp_path / "with_normal.laz"
    las.write(str(src))
    taken = []
    real = las_output.layered_source

    def spy(path, header, new_dims):
        out = real(path, header, new_dims)
        if "NormalX" in new_dims:  # the export's calls (the ingest asks with a dimension of its own)
            taken.append(out)
        return out

    monkeypatch.setattr(las_output, "layered_source", spy)
    out = tmp_path / "out.laz"
    normals(src, out, tile_size=16, quiet=True, scheduler="synchronous")
    assert taken and all(t is None for t in taken)
    got = laspy.read(str(out))
    assert np.array_equal(got.Amplitude, las.Amplitude) and np.array_equal(got.gps_time, las.gps_time)
    assert np.count_nonzero(got.NormalX == 7.0) < 0.1 * len(got.points)  # written over


def test_a_header_that_counts_fewer_points_than_the_last_chunk_holds_is_read_whole(channels_laz, tmp_path):
    raw = bytearray(channels_laz.read_bytes())
    h = laspy.open(str(channels_laz)).header
    src = tmp_path / "short.laz"
    raw[247:255] = (h.point_count - 5).to_bytes(8, "little")  # LAS 1.4 point count: 5 fewer than the data holds
    src.write_bytes(bytes(raw))
    assert laspy.open(str(src)).header.point_count == h.point_count - 5
    out_h = las_output.prepare_header(laspy.open(str(src)).header, True)
    out_h.add_extra_dim(laspy.ExtraBytesParams("NormalX", "f4"))
    out_h = las_output.prepare_header(out_h, True)
    assert las_output.layered_source(src, out_h, ["NormalX"]) is None
    assert las_output.layered_source(channels_laz, out_h, ["NormalX"]) is not None


def test_the_export_takes_its_points_tiles_from_the_ingest_and_decodes_nothing(channels_laz, tmp_path, monkeypatch):
    from patchcloud.stream.engine import ingest
    from patchcloud.stream.io.store import Store

    calls = []
    real = ingest.read_range
    monkeypatch.setattr(ingest, "read_range", lambda *a, **k: calls.append(a[1:3]) or real(*a, **k))
    routed, store = tmp_path / "routed.laz", tmp_path / "kept.zarr"
    normals(channels_laz, routed, tile_size=16, quiet=True, in_memory=False, scheduler="threads", workers=1, store=store, keep_store=True)
    parts = sorted(calls)  # the ingest's parts, each read once; the export read none
    assert len(parts) == len(set(parts)) >= 2 and sum(c for _, c in parts) == laspy.open(str(channels_laz)).header.point_count
    # the same store without the routes (as an older version made it): the export decodes the records, same bytes
    Store.open(str(store)).remove("routes")
    decoded = tmp_path / "decoded.laz"
    normals(channels_laz, decoded, tile_size=16, quiet=True, in_memory=False, scheduler="threads", workers=1, store=store, keep_store=True)
    assert sorted(calls[len(parts):]) == parts  # the store was complete: only the export read, each part once
    assert routed.read_bytes() == decoded.read_bytes()


@pytest.mark.slow  # 10-20 s: with the slow marker, so the default suite stays under 10 minutes
def test_the_ingest_records_routes_of_layered_laz_only(channels_laz, tmp_path):
    from patchcloud.stream.io.store import Store

    las = tmp_path / "scene.las"
    laspy.read(str(channels_laz)).write(str(las))
    for src, routed in ((channels_laz, True), (las, False)):
        store = tmp_path / f"{src.suffix[1:]}.zarr"
        normals(src, tmp_path / f"out{src.suffix}", tile_size=16, quiet=True, scheduler="threads", workers=1, store=store, keep_store=True)
        assert Store.open(str(store)).has_array("routes") == routed, src


def test_a_real_single_channel_file_without_extra_bytes_is_copied_to_the_same_bytes(tmp_path, monkeypatch):
    # the embedded IGN LiDAR HD tile: point format 8, one scanner channel (no channel array), no extra bytes of its own
    src = Path(__file__).resolve().parents[1] / "data" / "test_data_77055_627760_LA93_IGN69.laz"
    run = dict(tile_size=64, quiet=True, in_memory=False, scheduler="threads", workers=1)
    copied, whole = tmp_path / "copied.laz", tmp_path / "whole.laz"
    normals(src, copied, **run)
    monkeypatch.setattr(las_output, "layered_source", lambda *a, **k: None)
    normals(src, whole, **run)
    assert copied.read_bytes() == whole.read_bytes()
    assert laspy.open(str(copied)).header.number_of_points_by_return[0] > 0


def test_routes_are_recorded_where_an_output_can_copy_the_chunks_only():
    from conftest import shared_file

    from patchcloud.stream.engine.ingest import routes_pay
    from patchcloud.stream.io.catalog import open_catalog

    embedded = Path(__file__).resolve().parents[1] / "data" / "test_data_77055_627760_LA93_IGN69.laz"
    assert routes_pay(open_catalog([embedded]).sources[0])  # format 8, chunks of 50,000
    # format 8 too, and an output moves its second extra-bytes block (undescribed to laspy) after the new dimensions:
    # their layers too are moved, not coded again
    moved = shared_file("lidar-ign-extrabytes/las_with_several_extra_byte_bloc.laz")
    assert routes_pay(open_catalog([moved]).sources[0])
    assert not routes_pay(open_catalog([shared_file("lidar-lastools/fusa.laz")]).sources[0])  # format 1: point-wise LAZ


@pytest.mark.slow  # 15-20 s: with the slow marker, so the default suite stays under 10 minutes
def test_segment_numbers_its_clusters_from_the_routes_and_writes_the_bytes_of_a_run_that_decodes(channels_laz, tmp_path,
                                                                                                  monkeypatch):
    from patchcloud.stream import segment
    from patchcloud.stream.engine import ingest

    calls = []
    real = ingest.read_range
    monkeypatch.setattr(ingest, "read_range", lambda *a, **k: calls.append(a[1:3]) or real(*a, **k))
    run = dict(r_small=0.5, r_large=2.0, threshold=0.1, tolerance=0.5, min_cluster=5, tile_size=16, quiet=True, in_memory=False,
               scheduler="threads", workers=1)
    routed, decoded = tmp_path / "routed.laz", tmp_path / "decoded.laz"
    segment(channels_laz, routed, **run)
    assert len(calls) == len(set(calls))  # each part read once, by the ingest: neither the numbering nor the export decodes
    monkeypatch.setattr(ingest, "routes_pay", lambda src: False)  # no routes: both read the records again
    segment(channels_laz, decoded, **run)
    assert len(calls) == 4 * len(set(calls[: len(calls) // 4]))
    assert routed.read_bytes() == decoded.read_bytes()
    assert np.asarray(laspy.read(str(routed)).ClusterID).max() > 1
