"""patchcloud.core.orient.face_agreement: the face sampling of two quadrics (paper 2.3), by hand and against numpy."""

import numpy as np
import pytest

from patchcloud.core.orient import LeafSet, face_agreement
from patchcloud.core.quadric import implicit_value, surface_normals

UP = np.eye(3)
DOWN = np.diag([1.0, -1.0, -1.0])  # e3 = -z (right-handed)


def leaves(lower, frames, coeffs, centroid, rmse):
    n = len(frames)
    return LeafSet(np.asarray(lower, float), np.ones(n), np.asarray(centroid, float), np.asarray(frames, float),
                   np.asarray(coeffs, float), np.asarray(rmse, float), np.zeros(n, np.uint8), np.full(n, 10), np.zeros((n, 3)))


@pytest.mark.parametrize("frame_b, expected", [(UP, 1.0), (DOWN, -1.0)])
def test_two_leaves_of_one_plane_agree_as_their_frames_do(frame_b, expected):
    # the plane z = 0.3 across the +x face of the unit cube: of the 16 samples (y, z in 1/8, 3/8, 5/8, 7/8) those at
    # z = 7/8 lie farther than half the edge from the plane and do not vote; the 12 others agree (same frames) or
    # disagree (opposite frames) everywhere
    A = leaves([[0, 0, 0]], [UP], [[0, 0, 0, 0, 0, 0]], [[0.5, 0.5, 0.3]], [0.001])
    B = leaves([[1, 0, 0]], [frame_b], [[0, 0, 0, 0, 0, 0]], [[1.5, 0.5, 0.3]], [0.001])
    assert face_agreement(A, np.array([0]), B, np.array([0]), np.array([1])).tolist() == [expected]


def test_samples_inside_the_noise_band_say_nothing():
    # an RMSE of 0.2: a sample votes only farther than 0.4 from both planes and within 0.5, i.e. z = 7/8 (0.575)... which
    # is beyond half the edge: no sample votes, and the agreement is 0 (over at least 4)
    A = leaves([[0, 0, 0]], [UP], [[0, 0, 0, 0, 0, 0]], [[0.5, 0.5, 0.3]], [0.2])
    B = leaves([[1, 0, 0]], [UP], [[0, 0, 0, 0, 0, 0]], [[1.5, 0.5, 0.3]], [0.001])
    assert face_agreement(A, np.array([0]), B, np.array([0]), np.array([1])).tolist() == [0.0]


def numpy_agreement(A, i, B, j, d, samples=4):
    """The vectorised numpy definition the compiled kernel replaced (the same operations, sample by sample)."""
    E = i.shape[0]
    axis, upper, h, lo = d // 2, d % 2, A.edge[i], A.lower[i]
    g = (np.arange(samples) + 0.5) / samples
    gu, gv = (x.ravel() for x in np.meshgrid(g, g, indexing="ij"))
    m = gu.size
    pts = np.repeat(lo, m, axis=0)
    hh, ax, rows = np.repeat(h, m), np.repeat(axis, m), np.arange(E * m)
    pts[rows, ax] += np.repeat(upper, m) * hh
    pts[rows, (ax + 1) % 3] += np.tile(gu, E) * hh
    pts[rows, (ax + 2) % 3] += np.tile(gv, E) * hh
    ri, rj = np.repeat(i, m), np.repeat(j, m)
    pi, pj = (A.centroid[ri], A.frame[ri], A.coeffs[ri]), (B.centroid[rj], B.frame[rj], B.coeffs[rj])
    vi, vj = implicit_value(pts, *pi), implicit_value(pts, *pj)
    band = 2.0 * np.repeat(np.maximum(A.rmse[i], B.rmse[j]), m)
    near = (np.abs(vi) > band) & (np.abs(vj) > band) & (np.abs(vi) <= 0.5 * hh) & (np.abs(vj) <= 0.5 * hh)
    dot = np.einsum("ni,ni->n", surface_normals(pts, *pi), surface_normals(pts, *pj))
    same = np.sign(vi) * np.sign(vj)
    near &= (np.abs(dot) > 0.5) & (same == np.sign(dot))
    return (same * near).reshape(E, m).sum(axis=1) / np.maximum(near.reshape(E, m).sum(axis=1), 4)


def test_the_kernel_gives_the_numpy_values_bit_for_bit():
    # random curved patches on random faces of cubes of several sizes: the same agreement to the last bit
    rng = np.random.default_rng(3)
    n = 400
    frames = np.linalg.qr(rng.normal(size=(n, 3, 3)))[0]
    edge = 2.0 ** rng.integers(-2, 3, n)
    lower = rng.integers(0, 8, (n, 3)) * edge[:, None]
    centroid = lower + rng.uniform(0.3, 0.7, (n, 3)) * edge[:, None]  # surfaces through the cubes, curved a little
    coeffs = rng.normal(0, 0.3, (n, 6)) / edge[:, None]
    coeffs[:, 3:] = rng.normal(0, 0.1, (n, 3)) * [1.0, 1.0, 0.0]
    A = LeafSet(lower, edge, centroid, frames, coeffs, rng.uniform(0, 0.02, n), np.zeros(n, np.uint8), np.full(n, 10), np.zeros((n, 3)))
    i, j, d = rng.integers(0, n, 3000), rng.integers(0, n, 3000), rng.integers(0, 6, 3000)
    j = np.where(rng.random(3000) < 0.5, i, j)  # half the pairs a leaf with itself: the samples agree where they vote
    got = face_agreement(A, i, A, j, d)
    assert np.array_equal(got, numpy_agreement(A, i, A, j, d))
    assert np.count_nonzero(got) > 1000 and np.count_nonzero(got < 0) > 10  # many pairs vote, some of them against


def sparse_pair(offset):
    """A sparse leaf (kind 2) at the unit cube and one across its +x face, both with e3 = +z, their centroids
    ``offset`` apart along z."""
    def one(lower, z):
        return LeafSet(np.asarray([lower], float), np.ones(1), np.asarray([[lower[0] + 0.5, 0.5, z]]), np.asarray([UP]),
                       np.zeros((1, 6)), np.full(1, 0.001), np.full(1, 2, np.uint8), np.full(1, 10), np.zeros((1, 3)))
    return one([0, 0, 0], 0.3), one([1, 0, 0], 0.3 + offset)


@pytest.mark.parametrize("offset, expected", [(0.0, 1.0), (0.45, 1.0), (0.55, 0.0), (2.0, 0.0)])
def test_rough_leaves_link_only_where_they_lie_on_one_surface(offset, expected):
    # two sparse leaves with parallel PCA normals link by their dot product only where each centroid lies within half
    # the smaller edge (0.5) of the other's plane: a pipe's underside does not link to the ground 2 m below it
    from patchcloud.core.orient import link_agreements

    A, B = sparse_pair(offset)
    _, _, a = link_agreements(A, np.array([0]), B, np.array([0]), np.array([1]))
    assert a.tolist() == [expected]


def test_a_concave_patch_has_a_weaker_up_prior_than_a_convex_one():
    from patchcloud.core.orient import concave_damping

    prior = np.array([0.99, 0.99, 0.99, 0.99])
    coeffs = np.zeros((4, 6))
    coeffs[:, 0] = [0.5, -0.5, 0.5, 0.001]  # a bowl, a dome, a bowl too few points show, an all but flat patch
    usable = np.array([True, True, False, True])
    out = concave_damping(prior, coeffs, np.full(4, 0.4), np.full(4, 0.002), usable)
    assert out[0] == pytest.approx(0.99 / 3.0) and out[1:].tolist() == [0.99, 0.99, 0.99]
