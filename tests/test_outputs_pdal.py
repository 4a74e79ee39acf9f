"""Outputs that PDAL reads with no options (issue 18), from a LAS 1.2 input carrying GeoTIFF keys, a WKT and extra bytes.

Every job's output (normals, don, segment, decompress) is LAS 1.4 of the
input's point format; its ExtraBytes VLR holds the input's descriptor first
(unchanged but its min and max, set to the points') and then the new
dimensions, each with a no-data value; no NaN is written; the header's
bounds, point count and counts by return (the legacy ones too) are those of
the points; the generating software and a provenance VLR name patchcloud;
every other VLR of the input is in the output byte for byte, the
GeoKeyDirectory among them (its key count written as it was: laspy would
write 5 keys for these 4 and a padding slot).

The laspy checks always run; the PDAL checks (``pdal info --stats``, a
``filters.range`` pipeline, the SRS) run where ``pdal`` is on PATH or at
``PATCHCLOUD_PDAL``, and are skipped with that reason elsewhere (CI).
"""

import json
import os
import shutil
import struct
import subprocess

import laspy
import numpy as np
import pytest

import synthetic
from patchcloud.stream import compress, decompress, don, normals, segment
from patchcloud.stream.io.las_records import PROVENANCE_USER_ID, file_records, software_version

PDAL = os.environ.get("PATCHCLOUD_PDAL") or shutil.which("pdal")
needs_pdal = pytest.mark.skipif(PDAL is None or not os.access(PDAL, os.X_OK),
                                reason="PDAL not found (put pdal on PATH or set PATCHCLOUD_PDAL to run the PDAL checks)")

#: GeoTIFF keys of EPSG:2154 (model type projected, raster pixel-is-area, projected CRS 2154, linear unit metre), then a
#: zero slot: 4 keys in 5 slots, the layout that laspy's parse-and-rewrite turned into 5 keys.
GEOKEYS = struct.pack("<24H", 1, 1, 0, 4, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, 2154, 3076, 0, 1, 9001, 0, 0, 0, 0)
#: What each job adds, and a range of PDAL's filters.range with the number of points it should keep (a function of the output).
ADDED = {
    "normals": ["NormalX", "NormalY", "NormalZ", "Curvature", "NormalMethod", "PatchId"],
    "don": ["DoN", "DoNX", "DoNY", "DoNZ"],
    "segment": ["DoN", "DoNX", "DoNY", "DoNZ", "ClusterID"],
    "decompress": ["Reconstructed"],
}
RANGES = {
    "normals": ("NormalMethod[1:4]", lambda las: len(las)),  # every point of this scene gets a normal: 1-4
    "don": ("DoN[0.1:]", lambda las: int((np.asarray(las.DoN) >= np.float32(0.1)).sum())),
    "segment": ("ClusterID[1:]", lambda las: int((np.asarray(las.ClusterID) >= 1).sum())),
    "decompress": ("Reconstructed[1:1]", lambda las: int((np.asarray(las.Reconstructed) == 1).sum())),
}


@pytest.fixture(scope="module")
def outputs(tmp_path_factory):
    """A LAS 1.2 point format 3 input and each job's output of it (LAS for normals and segment, LAZ for the others)."""
    from pyproj import CRS

    d = tmp_path_factory.mktemp("pdal")
    pts, _ = synthetic.scene(12_000, seed=7)
    pts = pts + [650000.0, 6860000.0, 40.0]
    h = laspy.LasHeader(point_format=3, version="1.2")
    h.scales, h.offsets = np.array([0.001, 0.001, 0.001]), np.array([650000.0, 6860000.0, 0.0])
    h.add_extra_dims([laspy.ExtraBytesParams("Deviation", np.uint16, description="pulse deviation", no_data=[65535])])
    h.vlrs.append(laspy.VLR("LASF_Projection", 34735, "GeoTiff GeoKeyDirectoryTag", GEOKEYS))
    h.vlrs.append(laspy.VLR("LASF_Projection", 2112, "OGC WKT", CRS.from_epsg(2154).to_wkt("WKT1_GDAL").encode() + b"\0"))
    las = laspy.LasData(h)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    rng = np.random.default_rng(7)
    las.number_of_returns = rng.integers(1, 4, len(pts))
    las.return_number = np.minimum(rng.integers(1, 4, len(pts)), las.number_of_returns)
    las.gps_time = np.arange(len(pts)) * 1e-3
    las.Deviation = (np.arange(len(pts)) % 50).astype(np.uint16)
    src = d / "in.las"
    las.write(str(src))
    outs = {"normals": d / "normals.las", "don": d / "don.laz", "segment": d / "segment.las", "decompress": d / "decompress.laz"}
    run = dict(quiet=True, scheduler="synchronous")
    normals(src, outs["normals"], **run)
    don(src, outs["don"], r_small=0.5, r_large=2.0, **run)
    segment(src, outs["segment"], r_small=0.5, r_large=2.0, threshold=0.1, tolerance=0.5, min_cluster=5, **run)
    compress(src, d / "in.pcz", max_error=0.05, **run)
    decompress(d / "in.pcz", outs["decompress"])
    return src, outs


def test_the_input_is_las_12_with_a_padded_geokey_directory(outputs):
    src, _ = outputs
    assert str(laspy.open(str(src)).header.version) == "1.2"
    geokeys = [r for r in file_records(src)[0] if r.record_id == 34735]
    assert geokeys[0].data == GEOKEYS


@pytest.mark.parametrize("job", list(ADDED))
def test_the_output_is_las_14_with_described_dims_true_statistics_and_the_inputs_records(outputs, job):
    src, outs = outputs
    out = outs[job]
    las, inp = laspy.read(str(out)), laspy.read(str(src))
    h = las.header
    assert str(h.version) == "1.4" and h.point_format.id == 3  # formats 0 to 5 stay, with a LAS 1.4 header
    assert h.generating_software == f"patchcloud {software_version()}"
    # the ExtraBytes VLR: the input's descriptor first (all but its min and max as they were), then the new dimensions
    in_eb = next(r for r in file_records(src)[0] if r.record_id == 4 and r.name == "LASF_Spec").data
    out_vlrs, out_evlrs = file_records(out)
    eb = next(r for r in out_vlrs if r.record_id == 4 and r.name == "LASF_Spec").data
    assert eb[:64] == in_eb[:64] and eb[112:192] == in_eb[112:192]
    structs = h.vlrs.get("ExtraBytesVlr")[0].extra_bytes_structs
    assert [s.format_name() for s in structs] == ["Deviation", *ADDED[job]]
    for s in structs:
        v = np.asarray(las[s.format_name()], dtype=np.float64)
        assert not np.isnan(v).any(), s.format_name()
        assert s.no_data is not None and s.description, s.format_name()  # every descriptor has its no-data value
        valid = v[v != s.no_data[0]]  # the descriptor's range: of the values that are data
        assert s.min[0] == valid.min() and s.max[0] == valid.max(), s.format_name()
    # header statistics
    x, y, z = (np.asarray(las[a], dtype=np.float64) for a in ("x", "y", "z"))
    assert h.point_count == len(las) and np.allclose(h.mins, [x.min(), y.min(), z.min()], atol=1e-9)
    assert np.allclose(h.maxs, [x.max(), y.max(), z.max()], atol=1e-9)
    by_return = np.bincount(np.asarray(las.return_number), minlength=16)[1:16]
    assert np.array_equal(h.number_of_points_by_return, by_return)
    legacy = struct.unpack_from("<6I", out.read_bytes(), 107)
    assert legacy == (len(las), *by_return[:5].tolist())
    # every VLR of the input but the ExtraBytes one, byte for byte (GeoKeys with their count, WKT); then patchcloud's
    for r in file_records(src)[0]:
        if r.record_id != 4:
            assert r in out_vlrs, (r.name, r.record_id)
    prov = [r for r in out_vlrs if r.name == PROVENANCE_USER_ID]
    assert len(prov) == 1 and json.loads(prov[0].data)["job"] == job and json.loads(prov[0].data)["version"] == software_version()
    assert out_evlrs == []
    assert str(h.parse_crs().to_epsg()) == "2154"
    if job != "decompress":  # the input's records are kept, and its points
        assert len(las) == len(inp) and np.array_equal(las.X, inp.X) and np.array_equal(las.Deviation, inp.Deviation)


def _pdal(*args: str, stdin: str | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([PDAL, *args], capture_output=True, text=True, input=stdin, timeout=300)


@needs_pdal
@pytest.mark.parametrize("job", list(ADDED))
def test_pdal_reads_the_new_dims_their_statistics_and_the_crs(outputs, job):
    _, outs = outputs
    out = outs[job]
    r = _pdal("info", "--stats", str(out))
    assert r.returncode == 0, r.stderr
    assert "Could not create an SRS" not in r.stderr and "rror" not in r.stderr, r.stderr
    stats = {s["name"]: s for s in json.loads(r.stdout)["stats"]["statistic"]}
    las = laspy.read(str(out))
    for name in ["Deviation", *ADDED[job]]:
        v = np.asarray(las[name], dtype=np.float64)
        s = stats[name]
        assert s["count"] == len(las), name
        assert s["minimum"] == pytest.approx(v.min(), rel=1e-6, abs=1e-9) and s["maximum"] == pytest.approx(v.max(), rel=1e-6, abs=1e-9)
        assert isinstance(s["average"], (int, float)) and s["average"] == pytest.approx(v.mean(), rel=1e-5, abs=1e-6), name
    r = _pdal("info", "--summary", str(out))
    srs = json.loads(r.stdout)["summary"]["srs"]
    assert "Lambert-93" in srs["horizontal"] and srs["units"]["horizontal"] == "metre", srs
    assert "Could not create an SRS" not in r.stderr, r.stderr


@needs_pdal
@pytest.mark.parametrize("job", list(ADDED))
def test_a_pdal_range_filter_on_the_new_dims_keeps_the_right_points(outputs, tmp_path, job):
    _, outs = outputs
    limits, expected = RANGES[job]
    kept = tmp_path / "kept.las"
    pipeline = [str(outs[job]), {"type": "filters.range", "limits": limits}, {"type": "writers.las", "filename": str(kept)}]
    r = _pdal("pipeline", "--stdin", stdin=json.dumps(pipeline))
    assert r.returncode == 0, r.stderr
    want = expected(laspy.read(str(outs[job])))
    assert want > 0 and laspy.open(str(kept)).header.point_count == want


def test_summary_json_holds_the_summarys_figures(outputs, tmp_path):
    from click.testing import CliRunner

    from patchcloud.stream.cli import main

    src, _ = outputs
    pcz = src.parent / "in.pcz"
    r = CliRunner().invoke(main, ["decompress", str(pcz), str(tmp_path / "d.laz"), "-q", "--summary-json", str(tmp_path / "d.json")])
    assert r.exit_code == 0, r.output
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["reconstructed"] + d["residual"] == laspy.open(str(tmp_path / "d.laz")).header.point_count
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.json", "d.laz"]  # no temporary file left
    r = CliRunner().invoke(main, ["normals", str(src), str(tmp_path / "n.las"), "-q", "--scheduler", "synchronous",
                                  "--summary-json", str(tmp_path / "n.json")])
    assert r.exit_code == 0, r.output
    n = json.loads((tmp_path / "n.json").read_text())
    count = laspy.open(str(src)).header.point_count
    assert n["points"] == count and sum(n["normals_by_method"].values()) == count and n["parameters"]["criterion"] == "rmse"
    r = CliRunner().invoke(main, ["normals", str(src), str(tmp_path / "m.las"), "--summary-json", str(tmp_path / "no" / "n.json")])
    assert r.exit_code == 2 and "--summary-json" in r.output and not (tmp_path / "m.las").exists()
