"""tools/pcl_peer.py: the PCL peer of the benchmarks computes PCL's normals and DoN (skipped without libpcl-dev)."""

import numpy as np
import pytest

import pcl_peer  # tools/ is on sys.path, see conftest.py
from patchcloud.core import difference_of_normals

exe, why = pcl_peer.pcl_program()
pytestmark = pytest.mark.skipif(exe is None, reason=why)


def _bumpy(n=6000, seed=0):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 10, (n, 2))
    return np.column_stack([xy, 0.3 * np.sin(xy[:, 0]) + 0.01 * rng.standard_normal(n)])


def test_pcl_knn_normals_of_a_tilted_plane_face_the_viewpoint():
    rng = np.random.default_rng(1)
    xy = rng.uniform(0, 10, (3000, 2))
    pts = np.column_stack([xy, 0.5 * xy[:, 0]])
    seconds, n = pcl_peer.run_pcl(pts, "knn", (16,), (5.0, 5.0, 100.0), 2)
    assert seconds > 0 and n.shape == (3000, 3)
    assert np.allclose(n, np.array([-0.5, 0.0, 1.0]) / np.sqrt(1.25), atol=1e-4)


def test_pcl_don_equals_patchcloud_exact_mode():
    pts = _bumpy()
    vp = np.array([5.0, 5.0, 50.0])
    _, don = pcl_peer.run_pcl(pts, "don", (0.5, 1.5), vp, 2)
    ours = difference_of_normals(pts, 0.5, 1.5, viewpoint=vp, mode="exact")
    ok = np.isfinite(ours).all(axis=1)
    assert ok.mean() > 0.99 and np.abs(np.linalg.norm(ours, axis=1)).max() > 0.01  # not a flat, trivial case
    assert np.allclose(don[ok], ours[ok], atol=1e-4)  # PCL computes in float32
