"""The building blocks against brute-force or hand-computed answers."""

import numpy as np
import pytest

import synthetic
from conftest import angles_deg
from patchcloud.core import PatchKind, estimate_normals
from patchcloud.core.blend import wendland
from patchcloud.core.moments import EXPONENTS, pca, point_moments, quadric_normal_equations, shift_matrices
from patchcloud.core.morton import decode, encode
from patchcloud.core.quadric import fit_nodes, implicit_value, surface_curvatures, surface_normals


def test_morton_round_trip_and_order(rng):
    ijk = rng.integers(0, 1 << 21, (1000, 3))
    assert np.array_equal(decode(encode(ijk)), ijk)
    assert encode(np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]])).tolist() == [1, 2, 4, 7]


def test_moments_match_brute_force_and_shift(rng):
    p = rng.normal(size=(300, 3))
    starts = np.array([0, 100, 250])
    M = point_moments(p, starts, chunk=64)
    for k, (lo, hi) in enumerate([(0, 100), (100, 250), (250, 300)]):
        ref = [np.sum(p[lo:hi, 0] ** a * p[lo:hi, 1] ** b * p[lo:hi, 2] ** c) for a, b, c in EXPONENTS]
        assert np.allclose(M[k], ref)
    d = np.array([0.3, -1.2, 0.7])
    q = p[:100] + d
    ref = [np.sum(q[:, 0] ** a * q[:, 1] ** b * q[:, 2] ** c) for a, b, c in EXPONENTS]
    assert np.allclose(shift_matrices(d[None])[0] @ M[0], ref)


def test_quadric_system_matches_explicit_least_squares(rng):
    p = rng.normal(size=(200, 3)) * [2.0, 1.0, 0.1]
    M = point_moments(p, np.array([0]))
    _, _, frame = pca(M)
    G, b, ww = quadric_normal_equations(M, frame, np.array([1.5]))
    u, v, w = (p @ frame[0]).T / 1.5
    phi = np.column_stack([u * u, u * v, v * v, u, v, np.ones_like(u)])
    assert np.allclose(G[0], phi.T @ phi) and np.allclose(b[0], phi.T @ w) and np.isclose(ww[0], w @ w)


def _fit_reference(M, half_edge):
    """fit_nodes as numpy computes it: pca, the normal equations, a batched solve with the same ridge."""
    mean, eig, frame = pca(M)
    G, b, ww = quadric_normal_equations(M, frame, half_edge)
    ridge = 1e-13 * np.trace(G, axis1=1, axis2=2) / 6.0 + 1e-300
    beta = np.linalg.solve(G + ridge[:, None, None] * np.eye(6), b[:, :, None])[:, :, 0]
    rss = ww - 2.0 * np.einsum("ni,ni->n", beta, b) + np.einsum("ni,nij,nj->n", beta, G, beta)
    return mean, eig, frame, beta, half_edge * np.sqrt(np.maximum(rss, 0.0) / M[:, 0])


@pytest.mark.parametrize("shape", ["bowls", "planes", "lines", "blobs"])
def test_the_compiled_fit_of_many_nodes_is_the_numpy_one(rng, shape):
    """fit_nodes (one compiled loop) against pca + quadric_normal_equations + numpy's solve: the same frames (up to the
    sign of e1, which flips e2 and the odd terms), eigenvalues, surfaces and fit errors."""
    nodes, starts, pts = 300, [], []
    for k in range(nodes):
        n = int(rng.integers(12, 200))
        uv = rng.uniform(-1, 1, (n, 2)) * rng.uniform(0.2, 2.0, 2)
        a, b, c = rng.normal(0, 0.5, 3)
        w = {"bowls": a * uv[:, 0] ** 2 + b * uv[:, 0] * uv[:, 1] + c * uv[:, 1] ** 2 + rng.normal(0, 0.01, n),
             "planes": rng.normal(0, 1e-9, n), "lines": np.zeros(n), "blobs": rng.normal(0, 0.5, n)}[shape]
        if shape == "lines":
            uv[:, 1] = 0.0
        rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        starts.append(sum(len(q) for q in pts))
        pts.append(np.column_stack([uv, w]) @ rot.T + rng.normal(0, 0.3, 3))
    M = point_moments(np.concatenate(pts), np.array(starts))
    half = rng.uniform(0.5, 2.0, nodes)
    fit = fit_nodes(M, half)
    mean, eig, frame, beta, rmse = _fit_reference(M, half)
    assert np.allclose(fit.centroid, mean, rtol=0, atol=1e-12)
    assert np.allclose(fit.eigenvalues, eig, rtol=1e-9, atol=1e-12 * eig[:, :1])
    flip = np.sign(np.einsum("ni,ni->n", fit.frame[:, :, 0], frame[:, :, 0]))  # e1 (and so e2) may point the other way
    if shape != "lines":  # (on a line e2 and e3 are any pair around it)
        assert np.allclose(fit.frame[:, :, 2], frame[:, :, 2], atol=1e-7)
        assert np.allclose(fit.frame[:, :, 0] * flip[:, None], frame[:, :, 0], atol=1e-6)
        assert np.allclose(fit.rmse, rmse, rtol=1e-6, atol=1e-7)  # (rss is a difference of sums: ~1e-8 m of noise in both)
    # the same surface: each node's own points are as far from it (fit_nodes' coefficients are at the centroid)
    for k in range(0, nodes, 7):
        p = pts[k]
        rows = np.zeros(len(p), dtype=int)
        got = implicit_value(p, fit.centroid[k][None][rows] * 0 + p.mean(axis=0), fit.frame[k][None][rows], fit.coeffs[k][None][rows])
        assert np.isclose(np.sqrt(np.mean(got ** 2)), fit.rmse[k], rtol=1e-6, atol=1e-7)
    fit_plane = fit_nodes(M, half, quadric=False)
    assert np.array_equal(fit_plane.frame, fit.frame) and np.isnan(fit_plane.rmse).all() and not fit_plane.coeffs.any()


def test_fit_recovers_an_exact_quadric():
    # on a symmetric grid the PCA frame is the xyz frame, where z is exactly a quadric
    g = np.linspace(-1, 1, 21)
    u, v = (a.ravel() for a in np.meshgrid(g, 1.5 * g))
    p = np.column_stack([u, v, 0.3 * u**2 + 0.1 * v**2 + 2.0])
    fit = fit_nodes(point_moments(p, np.array([0])), np.array([1.0]))
    assert fit.rmse[0] < 1e-7  # 0 but for the rounding of rss, a difference of sums of order 100 (m^2)
    a, b, c = fit.coeffs[0, :3] * np.sign(fit.frame[0, 2, 2])
    assert np.isclose(a * np.sign(fit.frame[0, 1, 0]) ** 2, 0.1) and np.isclose(c, 0.3) and abs(b) < 1e-9
    rows = np.zeros(len(p), dtype=int)
    assert np.max(np.abs(implicit_value(p, fit.centroid[rows], fit.frame[rows], fit.coeffs[rows]))) < 1e-9


def test_compiled_kernel_matches_numpy_reference(rng):
    p, _ = synthetic.torus(rng, 20000)
    res = estimate_normals(p, orient="outward", blend=False)
    t = res.patches
    k = res.patch.astype(np.int64)
    surf = t.kind[k] == PatchKind.SURFACE
    n_ref = surface_normals(p[surf], t.centroid[k[surf]], t.frame[k[surf]], t.coeffs[k[surf]])
    k1, k2, d1 = surface_curvatures(p[surf], t.centroid[k[surf]], t.frame[k[surf]], t.coeffs[k[surf]])
    assert np.max(angles_deg(res.normals[surf], n_ref, signed=True)) < 1e-3
    assert np.allclose(res.k1[surf], k1, atol=1e-4, rtol=1e-4)
    assert np.allclose(res.k2[surf], k2, atol=1e-4, rtol=1e-4)
    assert np.median(np.abs(np.einsum("ij,ij->i", res.dir1[surf], d1))) > 0.999


def test_wendland_weights():
    assert np.allclose(wendland(np.array([0.0, 0.5, 1.0, 1.5])), [1.0, 0.1875, 0.0, 0.0])


def test_blending_smooths_jumps_across_leaf_faces(rng):
    p, n = synthetic.sphere(rng, 60000, radius=1.0)
    sharp = estimate_normals(p, orient="outward", blend=False)
    smooth = estimate_normals(p, orient="outward", blend=True)
    assert np.array_equal(sharp.patch, smooth.patch)
    from scipy.spatial import cKDTree

    _, nb = cKDTree(p).query(p, k=2)
    cross = sharp.patch[nb[:, 0]] != sharp.patch[nb[:, 1]]
    assert cross.sum() > 100
    a, b = nb[cross, 0], nb[cross, 1]
    true_jump = angles_deg(n[a], n[b])
    excess_sharp = np.abs(angles_deg(sharp.normals[a], sharp.normals[b]) - true_jump)
    excess_smooth = np.abs(angles_deg(smooth.normals[a], smooth.normals[b]) - true_jump)
    assert np.mean(excess_smooth) < 0.5 * np.mean(excess_sharp)
    # blending trades a little accuracy inside patches for continuity across them
    assert np.median(angles_deg(smooth.normals, n)) <= np.median(angles_deg(sharp.normals, n)) + 0.1


def test_patch_table_is_consistent(rng):
    p, _ = synthetic.box(rng, 20000)
    res = estimate_normals(p, orient="outward")
    t = res.patches
    assert t.count.sum() == len(p)
    assert np.array_equal(np.bincount(res.patch, minlength=len(t)), t.count)
    # every point lies inside its leaf cube
    lo = t.lower[res.patch]
    hi = lo + t.edge[res.patch][:, None]
    assert np.all(p >= lo - 1e-9) and np.all(p <= hi + 1e-9)
    assert np.allclose(np.einsum("pij,pik->pjk", t.frame, t.frame), np.eye(3), atol=1e-9)
    assert np.allclose(np.linalg.det(t.frame), 1.0)
    assert set(np.unique(t.kind)) <= {0, 1, 2}
    assert np.all(t.eigenvalues[:, 0] >= t.eigenvalues[:, 1]) and np.all(t.eigenvalues[:, 1] >= t.eigenvalues[:, 2])


def test_flipped_patch_is_the_same_surface_reversed(rng):
    p, _ = synthetic.sphere(rng, 5000)
    t = estimate_normals(p).patches
    f = t.flipped(np.ones(len(t), dtype=bool))
    q = p[:50]
    rows = np.zeros(50, dtype=int)
    a = implicit_value(q, t.centroid[rows], t.frame[rows], t.coeffs[rows])
    b = implicit_value(q, f.centroid[rows], f.frame[rows], f.coeffs[rows])
    assert np.allclose(a, -b)
    na = surface_normals(q, t.centroid[rows], t.frame[rows], t.coeffs[rows])
    nb = surface_normals(q, f.centroid[rows], f.frame[rows], f.coeffs[rows])
    assert np.allclose(na, -nb)


def test_numba_caches_outside_the_installed_package():
    # a cache inside site-packages/patchcloud/core outlives an uninstall and shadows the next install
    import os

    import patchcloud.core
    from numba.core import config

    package = os.path.dirname(patchcloud.core.__file__)
    if os.environ.get("NUMBA_CACHE_DIR") not in (None, patchcloud.core._numba_cache.cache_dir()):
        pytest.skip("NUMBA_CACHE_DIR was set by the user")
    assert config.CACHE_DIR == patchcloud.core._numba_cache.cache_dir()
    assert not os.path.abspath(config.CACHE_DIR).startswith(os.path.abspath(package))


def test_face_neighbours_counts_the_occupied_cells_beside_each_cell():
    """Against a count by coordinates, on random cells and on cells at the edges of the key's range (no neighbour
    past 0 or 2**21 - 1)."""
    from patchcloud.core.morton import decode, encode, face_neighbours

    rng = np.random.default_rng(3)
    cube = np.stack(np.meshgrid(*[np.arange(20, 23)] * 3), axis=-1).reshape(-1, 3)  # its centre has all six
    ijk = np.unique(np.vstack([rng.integers(0, 12, (600, 3)), cube, [[0, 0, 0], [(1 << 21) - 1, 0, 5], [(1 << 21) - 2, 0, 5]]]),
                    axis=0)
    keys = np.sort(encode(ijk))
    cells = {tuple(c) for c in decode(keys).tolist()}
    want = [sum((c[0] + d[0], c[1] + d[1], c[2] + d[2]) in cells
                for d in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)))
            for c in decode(keys).tolist()]
    assert face_neighbours(keys).tolist() == want and max(want) == 6


def test_face_neighbours_refuses_keys_not_sorted_or_not_unique():
    """It finds a cell's siblings next to it in the sorted keys: unsorted keys would count wrong, silently."""
    from patchcloud.core import PatchcloudValueError
    from patchcloud.core.morton import encode, face_neighbours

    keys = np.sort(encode(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]])))
    for bad in (keys[::-1], np.r_[keys, keys[:1]]):
        with pytest.raises(PatchcloudValueError, match="keys must be sorted and unique"):
            face_neighbours(bad)
    assert face_neighbours(keys[:1]).tolist() == [0] and face_neighbours(keys[:0]).tolist() == []
