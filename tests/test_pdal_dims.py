"""An input that already holds PDAL's dimensions with PDAL's types (double NormalX/Y/Z and Curvature from
filters.normal, int64 ClusterID from filters.cluster) takes this run's values in them (found by a sweep of
2026-11-27: PDAL's outputs were refused)."""

import laspy
import numpy as np
import pytest
from test_stream import write_scene

from patchcloud.core import PatchcloudValueError
from patchcloud.stream import compress, decompress, normals, segment


def with_dims(src, path, dims):
    """``src`` with extra dimensions ``dims`` ((name, numpy type), ...) holding made-up values, as PDAL writes them."""
    las = laspy.read(str(src))
    las.add_extra_dims([laspy.ExtraBytesParams(name=n, type=t) for n, t in dims])
    for i, (n, t) in enumerate(dims):
        las[n] = np.full(len(las.points), 7 + i, dtype=t)
    las.write(str(path))


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("pdaldims") / "scene.las"
    write_scene(path, n=20_000, seed=3, point_format=6, extra=False)
    return path


def test_pdal_normals_are_overwritten_in_their_double_fields(scene, tmp_path):
    src = tmp_path / "pdal.las"
    with_dims(scene, src, [("NormalX", np.float64), ("NormalY", np.float64), ("NormalZ", np.float64), ("Curvature", np.float64)])
    normals(scene, tmp_path / "plain.las", quiet=True)
    normals(src, tmp_path / "out.las", quiet=True)
    plain, out = laspy.read(str(tmp_path / "plain.las")), laspy.read(str(tmp_path / "out.las"))
    for name in ("NormalX", "NormalY", "NormalZ", "Curvature"):
        assert out.points.array.dtype[name] == np.float64, name
        assert np.array_equal(np.asarray(out[name]), np.asarray(plain[name], dtype=np.float64)), name
    assert np.array_equal(np.asarray(out.NormalMethod), np.asarray(plain.NormalMethod))
    assert sorted(out.point_format.extra_dimension_names) == sorted(plain.point_format.extra_dimension_names)


def test_pdal_cluster_ids_are_overwritten_in_their_int64_field(scene, tmp_path):
    src = tmp_path / "pdal.las"
    with_dims(scene, src, [("ClusterID", np.int64)])
    args = dict(r_small=0.5, r_large=2.0, threshold=0.02, tolerance=1.0, min_points=5, quiet=True)
    segment(scene, tmp_path / "plain.las", **args)
    segment(src, tmp_path / "out.las", **args)
    plain, out = laspy.read(str(tmp_path / "plain.las")), laspy.read(str(tmp_path / "out.las"))
    assert out.points.array.dtype["ClusterID"] == np.int64
    ids = np.asarray(plain.ClusterID)
    assert np.unique(ids).size > 3  # segments, not only 0
    assert np.array_equal(np.asarray(out.ClusterID), ids.astype(np.int64))


def test_a_dimension_too_narrow_for_the_values_is_refused_before_anything_is_written(scene, tmp_path):
    src = tmp_path / "narrow.las"
    with_dims(scene, src, [("NormalX", np.uint8)])
    with pytest.raises(PatchcloudValueError, match="NormalX of type uint8, which cannot hold"):
        normals(src, tmp_path / "out.las", quiet=True)
    assert not (tmp_path / "out.las").exists()
    # before anything runs (review K: after the whole computation, and on disk with a store kept "to resume from",
    # where the same command failed the same way), for every job and catalogs too
    from patchcloud.stream import don, segment

    for job, dim in ((normals, "NormalX"), (don, "DoN"), (segment, "ClusterID")):
        with_dims(scene, src, [(dim, np.uint8)])
        args = {} if job is normals else dict(r_small=0.5, r_large=2.0)
        with pytest.raises(PatchcloudValueError, match=f"{dim} of type uint8, which cannot hold"):
            job(src, tmp_path / "out.las", quiet=True, scheduler="synchronous", **args)  # on disk: the store is made first
        assert sorted(p.name for p in tmp_path.iterdir()) == ["narrow.las"]



def test_the_descriptors_of_a_second_extra_bytes_vlr_are_kept(tmp_path):
    """laspy reads the first ExtraBytes VLR only: the bytes the second describes were written undescribed (PDAL then
    saw no name for them); the outputs of normals and of a points-mode round trip describe them as the input did."""
    from test_odd_records import _two_blocks

    src = _two_blocks(tmp_path, 1, "in.las", n=3000)
    original = laspy.read(str(src))
    normals(src, tmp_path / "n.las", quiet=True)
    compress(src, tmp_path / "p.pcz", keep_points=True, quiet=True)
    decompress(tmp_path / "p.pcz", tmp_path / "d.las")
    for out in (tmp_path / "n.las", tmp_path / "d.las"):
        got = laspy.read(str(out))
        names = [d.name for d in got.point_format.extra_dimensions]
        assert names[0] == "TrueNormal" and names[-1] == "conf", names
        np.testing.assert_array_equal(np.asarray(got["conf"]), np.asarray(original["ExtraBytes"]).ravel())
        np.testing.assert_array_equal(np.asarray(got["TrueNormal"]), np.asarray(original["TrueNormal"]))
