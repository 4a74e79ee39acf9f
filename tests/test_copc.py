"""COPC input, and the EVLRs (a CRS WKT among them) of LAS 1.4 inputs kept in every output."""

import laspy
import numpy as np
import pytest
from click.testing import CliRunner
from laspy.vlrs.known import WktCoordinateSystemVlr
from laspy.vlrs.vlrlist import VLRList
from test_stream import write_scene

from patchcloud.core import PatchcloudIOError, PatchcloudValueError
from patchcloud.stream import compress, decompress, normals
from patchcloud.stream.cli import main

WKT = (
    'PROJCS["RGF93 v1 / Lambert-93",GEOGCS["RGF93 v1",DATUM["Reseau_Geodesique_Francais_1993_v1",'
    'SPHEROID["GRS 1980",6378137,298.257222101]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],'
    'PROJECTION["Lambert_Conformal_Conic_2SP"],PARAMETER["latitude_of_origin",46.5],PARAMETER["central_meridian",3],'
    'PARAMETER["standard_parallel_1",49],PARAMETER["standard_parallel_2",44],PARAMETER["false_easting",700000],'
    'PARAMETER["false_northing",6600000],UNIT["metre",1],AUTHORITY["EPSG","2154"]]'
)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("copc")
    path = d / "scene.las"
    write_scene(path, n=20_000, seed=5, point_format=6, extra=False)
    return path


def write_copc(src, path):
    """``src`` (point format 6-8) as COPC with copclib: a root node of every 8th point and the rest in depth-1 octants.

    The points of a COPC file are in node order, not in ``src``'s order:
    the function returns the order in which it wrote them (indices of ``src``).
    """
    copc = pytest.importorskip("copclib", reason="copclib (the test extra) writes the COPC test file")
    las = laspy.read(str(src))
    h = las.header
    cfg = copc.CopcConfigWriter(point_format_id=h.point_format.id, scale=tuple(h.scales), offset=tuple(h.offsets), wkt=WKT)
    cfg.las_header.min = copc.Vector3(*h.mins)
    cfg.las_header.max = copc.Vector3(*h.maxs)
    cfg.copc_info.spacing = 1.0
    writer = copc.FileWriter(str(path), cfg)
    n = len(las.points)
    mid = (np.asarray(h.mins) + np.asarray(h.maxs)) / 2
    octant = (np.asarray(las.x) > mid[0]) + 2 * (np.asarray(las.y) > mid[1]) + 4 * (np.asarray(las.z) > mid[2])
    root = np.arange(n) % 8 == 0
    order = [np.flatnonzero(root)]
    nodes = [copc.VoxelKey(0, 0, 0, 0)]
    for o in range(8):
        order.append(np.flatnonzero(~root & (octant == o)))
        nodes.append(copc.VoxelKey(1, o & 1, (o >> 1) & 1, (o >> 2) & 1))
    for key, rows in zip(nodes, order):
        if rows.size:
            raw = las.points.array[rows].tobytes()
            writer.AddNode(key, copc.VectorChar(np.frombuffer(raw, np.int8)), copc.VoxelKey(0, 0, 0, 0))
    writer.Close()
    return np.concatenate(order)


@pytest.fixture(scope="module")
def copc_file(scene, tmp_path_factory):
    path = tmp_path_factory.mktemp("copcfile") / "scene.copc.laz"
    order = write_copc(scene, path)
    return path, order


def _records(path):
    las = laspy.read(str(path))
    return las.points.array


def test_copc_input_gives_a_plain_laz_with_the_same_records_and_the_crs(copc_file, scene, tmp_path):
    path, order = copc_file
    with laspy.open(str(path)) as r:
        assert any(v.user_id == "copc" for v in r.header.vlrs), "the test file is not COPC"
    out = tmp_path / "scene.laz"
    s = normals(path, out, quiet=True)
    assert s.points == len(order) == laspy.open(str(scene)).header.point_count
    got = laspy.read(str(out))
    h = got.header
    assert not any(v.user_id == "copc" for v in h.vlrs)
    assert not any(v.user_id == "copc" for v in (h.evlrs or []))
    assert h.parse_crs().to_epsg() == 2154
    # the COPC file's records, in its own order, with the normals added
    src = _records(path)
    for name in src.dtype.names:
        assert np.array_equal(got.points.array[name], src[name]), name
    # the same point in the plain file gets the same normal (the result does not depend on the input order)
    plain = tmp_path / "plain.las"
    normals(scene, plain, quiet=True)
    ref = laspy.read(str(plain))
    n_copc = np.column_stack([got.NormalX, got.NormalY, got.NormalZ])
    n_ref = np.column_stack([ref.NormalX, ref.NormalY, ref.NormalZ])[order]
    assert np.array_equal(n_copc, n_ref)


def test_any_range_of_a_copc_file_reads_its_records(copc_file):
    """A COPC file's chunks hold as many points as its nodes (variable-size chunks): laspy's seek there gives other
    points, or zeros (found by a sweep of 2026-11-27: every part of a run after the first was garbage, exit 0)."""
    from patchcloud.stream.io.las import open_source, read_chunks, read_range

    path, order = copc_file
    ref = _records(path)
    src = open_source(path)
    n = len(ref)
    for first, count in [(0, n), (0, 10), (2_499, 1), (2_500, 7_000), (3_001, 12_345), (n - 1, 1), (n - 4_000, 4_000)]:
        assert np.array_equal(read_range(src, first, count).array, ref[first:first + count]), (first, count)
    got = np.concatenate([pts.array for _, pts in read_chunks(src, 3_000, start_chunk=2)])
    assert np.array_equal(got, ref[6_000:])
    with pytest.raises(PatchcloudIOError, match="truncated"):
        read_range(src, n - 10, 20)


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_a_copc_file_read_in_parts_gives_every_record(scene, tmp_path):
    """More points than one part (chunk=50,000: three parts, each from a node inside the file), in memory and on disk,
    with two worker processes too: the output's records are the COPC file's, every one."""
    big = tmp_path / "big.las"
    write_scene(big, n=120_000, seed=8, point_format=6, extra=False)
    path = tmp_path / "big.copc.laz"
    write_copc(big, path)
    ref = _records(path)
    normals_of = None
    for kwargs in ({}, {"in_memory": False}, {"in_memory": False, "scheduler": "processes", "workers": 2}):
        out = tmp_path / f"out{len(kwargs)}.laz"
        normals(path, out, quiet=True, chunk=50_000, **kwargs)
        got = laspy.read(str(out))
        for name in ref.dtype.names:
            assert np.array_equal(got.points.array[name], ref[name]), (kwargs, name)
        nrm = np.column_stack([got.NormalX, got.NormalY, got.NormalZ])
        assert (got.NormalMethod > 0).mean() > 0.99
        if normals_of is None:
            normals_of = nrm
        assert np.array_equal(nrm, normals_of), kwargs


def test_copc_output_name_is_refused_before_anything_is_written(copc_file, tmp_path):
    path, _ = copc_file
    out = tmp_path / "x.copc.laz"
    with pytest.raises(PatchcloudValueError, match=r"name the output x\.laz"):
        normals(path, out, quiet=True)
    assert list(tmp_path.iterdir()) == []
    r = CliRunner().invoke(main, ["normals", str(path), str(out), "-q"])
    assert r.exit_code == 2 and "not COPC" in r.output and "Traceback" not in r.output
    assert list(tmp_path.iterdir()) == []


def test_copc_compresses_and_decompresses_to_plain_laz(copc_file, tmp_path):
    path, _ = copc_file
    pcz = tmp_path / "scene.pcz"
    compress(path, pcz, quiet=True)
    back = tmp_path / "back.laz"
    decompress(pcz, back)
    h = laspy.read(str(back)).header
    assert not any(v.user_id == "copc" for v in list(h.vlrs) + list(h.evlrs or []))
    assert h.parse_crs().to_epsg() == 2154


def test_copc_info_and_render(copc_file, tmp_path):
    path, _ = copc_file
    r = CliRunner().invoke(main, ["info", str(path)])
    assert r.exit_code == 0 and "19,985" in r.output and "Lambert-93" in r.output
    png = tmp_path / "scene.png"
    r = CliRunner().invoke(main, ["render", str(path), str(png), "--colour", "elevation", "--width", "200"])
    assert r.exit_code == 0, r.output
    import matplotlib.image

    img = matplotlib.image.imread(str(png))
    assert len(np.unique(img.reshape(-1, img.shape[2]), axis=0)) > 10  # elevation colours, not a blank picture


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_evlrs_of_a_las14_input_are_kept(scene, tmp_path, suffix):
    """A WKT CRS stored as an EVLR (as many LAS 1.4 writers do) is in the output, after the points."""
    las = laspy.read(str(scene))
    las.header.evlrs = VLRList([WktCoordinateSystemVlr(WKT)])
    src = tmp_path / "evlr.las"
    las.write(str(src))
    with laspy.open(str(src)) as r:
        assert r.header.number_of_evlrs == 1 and not r.header.vlrs.get("WktCoordinateSystemVlr")
    out = tmp_path / f"out{suffix}"
    normals(src, out, workers=2, scheduler="threads", chunk=50_000, quiet=True)
    got = laspy.read(str(out))
    assert got.header.number_of_evlrs == 1
    assert got.header.parse_crs().to_epsg() == 2154
    assert np.array_equal(got.points.array["X"], las.points.array["X"])
    assert np.isfinite(got.NormalZ).all()
