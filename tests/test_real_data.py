"""Real scans: the embedded IGN sample (always) and ../shared/data (skipped when absent)."""

from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, angles_deg, shared_file
from patchcloud.core import Method, estimate_normals

SAMPLE = ROOT / "data" / "test_data_77055_627760_LA93_IGN69.laz"


def _read_las(path: Path):
    laspy = pytest.importorskip("laspy")
    las = laspy.read(path)
    return np.column_stack([las.x, las.y, las.z]).astype(np.float64), np.asarray(las.classification)


def test_embedded_ign_sample_ground_and_roofs_point_up():
    xyz, cls = _read_las(SAMPLE)
    res = estimate_normals(xyz)  # Lambert-93 coordinates, ~6.3e6 m
    assert np.all(np.isfinite(res.normals))
    ground = cls == 2
    assert np.median(res.normals[ground, 2]) > 0.98
    assert np.mean(res.normals[ground, 2] > 0) > 0.99
    # building points are roofs and walls: the roofs (not vertical) point up
    roof = (cls == 6) & (np.abs(res.normals[:, 2]) > 0.3)
    assert np.mean(res.normals[roof, 2] > 0) > 0.97
    assert set(np.unique(res.method)) <= set(Method)


def test_embedded_sample_utm_scale_offset_invariance():
    xyz, _ = _read_las(SAMPLE)
    a = estimate_normals(xyz)
    b = estimate_normals(xyz - xyz.min(axis=0))
    assert np.percentile(angles_deg(a.normals, b.normals, signed=True), 99) < 0.01


def test_bunny_reconstruction_against_mesh_normals():
    import sys

    sys.path.insert(0, str(ROOT / "tools"))
    from plyio import read_ply, vertex_normals

    v, f = read_ply(shared_file("mesh-stanford-bunny/reconstruction/bun_zipper.ply"))
    xyz = np.column_stack([v["x"], v["y"], v["z"]])
    ref = vertex_normals(xyz, f)
    ok = np.linalg.norm(ref, axis=1) > 0.5
    xyz, ref = xyz[ok], ref[ok]
    res = estimate_normals(xyz, orient="outward")
    ang = angles_deg(res.normals, ref)
    assert np.median(ang) < 3.0  # point-wise k-NN PCA (k=30) gets 2.6 degrees here
    assert np.mean(np.einsum("ij,ij->i", res.normals, ref) > 0) > 0.95


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_the_six_real_ign_tiles_as_a_catalog_are_the_merged_file(tmp_path):
    """The real 6-tile IGN LiDAR HD catalog of ../shared/data: per point, the normals of a run on the merged file."""
    laspy = pytest.importorskip("laspy")
    from patchcloud.stream import normals

    first = shared_file("lidar-ign-lidarhd-tiles/test_data_77050_627755_LA93_IGN69.laz")
    tiles = sorted(first.parent.glob("*.laz"))
    assert len(tiles) == 6
    parts = [laspy.read(p) for p in tiles]
    merged = laspy.LasData(parts[0].header.copy())
    merged.points = laspy.ScaleAwarePointRecord(
        np.concatenate([p.points.array for p in parts]), parts[0].header.point_format, parts[0].header.scales,
        parts[0].header.offsets)
    assert all(np.array_equal(p.header.scales, parts[0].header.scales) and np.array_equal(p.header.offsets, parts[0].header.offsets)
               for p in parts)  # one grid already: the merged file is the concatenation of the records
    merged.write(tmp_path / "merged.laz")
    whole = normals(tmp_path / "merged.laz", tmp_path / "merged_normals.laz", quiet=True)
    cat = normals(first.parent, out_dir=str(tmp_path / "out"), quiet=True)
    assert cat.points == whole.points == sum(len(p.points) for p in parts)
    ref = laspy.read(tmp_path / "merged_normals.laz")
    start = 0
    for p in tiles:
        got = laspy.read(tmp_path / "out" / p.name)
        n = len(got.points)
        for dim in ("NormalX", "NormalY", "NormalZ", "Curvature", "NormalMethod", "PatchId"):
            np.testing.assert_array_equal(np.asarray(got[dim]), np.asarray(ref[dim])[start : start + n], err_msg=f"{p.name} {dim}")
        start += n
