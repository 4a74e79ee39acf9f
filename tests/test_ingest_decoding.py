"""The ingest decodes of a layered LAZ (point formats 6-10) only what it routes points by; results stay the same."""

import laspy
import numpy as np
import pytest
from test_stream import write_scene

from patchcloud.core import PatchcloudIOError
from patchcloud.stream import normals
from patchcloud.stream.io.las import POSITION_AND_CLASS, open_source, read_range


@pytest.fixture(scope="module")
def noisy_laz(tmp_path_factory):
    """A format-6 LAZ of 120,000 points (3 LAZ chunks) with GPS times, intensities, noise and withheld points."""
    d = tmp_path_factory.mktemp("decoding")
    las_path, laz_path = d / "scene.las", d / "scene.laz"
    write_scene(las_path, n=120_000, seed=11)
    las = laspy.read(str(las_path))
    rng = np.random.default_rng(11)
    n = len(las.points)
    las.gps_time = np.cumsum(rng.uniform(1e-6, 1e-5, n)) + 4e8
    las.classification = rng.choice(np.array([1, 2, 6, 7, 18], np.uint8), n, p=[0.4, 0.3, 0.2, 0.05, 0.05])
    las.withheld = rng.random(n) < 0.03
    las.point_source_id = rng.integers(1, 60000, n)
    las.write(str(laz_path))
    return laz_path, las


def test_reading_position_and_class_only_gives_those_fields_exactly_and_skips_the_others(noisy_laz):
    path, las = noisy_laz
    src = open_source(str(path))
    first, count = 50_000, 60_000  # from the second LAZ chunk into the third
    part = read_range(src, first, count, selection=POSITION_AND_CLASS).array
    whole = read_range(src, first, count).array
    truth = las.points.array[first:first + count]
    for name in ("X", "Y", "Z", "bit_fields", "classification_flags", "classification"):
        assert np.array_equal(part[name], truth[name]), name
        assert np.array_equal(whole[name], truth[name]), name
    assert np.array_equal(whole["gps_time"], truth["gps_time"])
    assert not np.array_equal(part["gps_time"], truth["gps_time"])  # not decoded: the selection did skip a layer
    assert not np.array_equal(part["point_source_id"], truth["point_source_id"])


def test_an_on_disk_run_that_decodes_less_writes_the_bytes_of_a_run_that_decodes_everything(noisy_laz, tmp_path):
    path, _ = noisy_laz
    mem, disk = tmp_path / "mem.laz", tmp_path / "disk.laz"
    normals(path, mem, tile_size=16, quiet=True, in_memory=True)  # in memory, the ingest decodes whole records (kept for export)
    normals(path, disk, tile_size=16, quiet=True, in_memory=False, scheduler="synchronous")  # on disk: position and class only
    out = laspy.read(str(disk))
    assert np.count_nonzero(out.NormalMethod == 0) > 0.05 * len(out.points)  # noise and withheld points left out, as read
    assert disk.read_bytes() == mem.read_bytes()


@pytest.mark.parametrize("selection", [None, POSITION_AND_CLASS])
@pytest.mark.parametrize("first, count", [(50_000, 60_000), (100_000, None), (50_000, 50_000)])
def test_a_part_decoded_on_lazrs_threads_from_the_chunk_table_is_the_part_laspy_reads_after_a_seek(noisy_laz, selection, first, count,
                                                                                                  monkeypatch):
    path, las = noisy_laz
    src = open_source(str(path))
    count = src.point_count - first if count is None else count  # None: to the last point, in the shorter last chunk
    with monkeypatch.context() as m:  # by the chunk table: no seek (lazrs' parallel seek costs as much as decoding a part)
        m.setattr(laspy.LasReader, "seek", lambda *a: pytest.fail("seeks"))
        threads = read_range(src, first, count, parallel=True, selection=selection)
    with laspy.open(str(path), laz_backend=laspy.LazBackend.Lazrs,
                    **({} if selection is None else {"decompression_selection": selection})) as reader:
        reader.seek(first)
        seek = reader.read_points(count)
    assert type(threads) is type(seek) and len(threads) == count
    names = threads.array.dtype.names if selection is None else ("X", "Y", "Z", "bit_fields", "classification")
    for name in names:
        assert np.array_equal(threads.array[name], seek.array[name]), name
    assert np.array_equal(threads.x, las.x[first:first + count]) and np.array_equal(threads.scales, seek.scales)


def test_a_part_that_starts_inside_a_chunk_or_a_damaged_chunk_is_read_as_laspy_reads_it(noisy_laz, tmp_path):
    path, las = noisy_laz
    src = open_source(str(path))
    inside = read_range(src, 70_000, 30_000, parallel=True)  # not a chunk's first point: laspy's seek
    assert np.array_equal(inside.array, las.points.array[70_000:100_000])
    damaged = tmp_path / "damaged.laz"
    data = bytearray(path.read_bytes())
    data[len(data) // 2: len(data) // 2 + 64] = bytes(64)  # zeros in the middle of the second chunk
    damaged.write_bytes(bytes(data))
    bad = open_source(str(damaged))
    try:
        got = read_range(bad, 50_000, 50_000, parallel=True)
    except PatchcloudIOError as exc:
        assert str(damaged) in str(exc)
    else:  # lazrs decodes damaged bytes to other points without an error: then both readers give the same points
        with laspy.open(str(damaged), laz_backend=laspy.LazBackend.Lazrs) as reader:
            reader.seek(50_000)
            assert np.array_equal(got.array, reader.read_points(50_000).array)
