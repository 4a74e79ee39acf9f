"""Coordinate moments of octree nodes, up to degree 4.

A node's moments are the sums ``sum_i (x_i - c)^a (y_i - c)^b (z_i - c)^c``
over its points, for every exponent triple with ``a + b + c <= 4`` (35 of
them), taken about the node's centre ``c``.  Together they give every PCA
plane and every quadric least-squares fit of the node without visiting its
points again, and the moments of a parent are the shifted sums of its
children's: this is what lets :mod:`patchcloud.core.octree` work level by
level over all nodes at once.

Moments are kept about node *centres* (not the origin of the tile) so that
they stay well conditioned in float64 at every level.
"""

from __future__ import annotations

from math import comb

import numpy as np

from . import _kernels

__all__ = [
    "EXPONENTS",
    "N_MOMENTS",
    "point_moments",
    "cell_moments",
    "shift_matrices",
    "shift_entries",
    "shift_moments",
    "pca",
    "quadric_normal_equations",
    "TENSOR_INDEX",
]

#: Exponent triples (a, b, c) of the 35 monomials, ordered by degree.
EXPONENTS: np.ndarray = np.array(
    [(a, b, d - a - b) for d in range(5) for a in range(d, -1, -1) for b in range(d - a, -1, -1)],
    dtype=np.int64,
)
N_MOMENTS = len(EXPONENTS)
_INDEX = {tuple(e): i for i, e in enumerate(EXPONENTS.tolist())}


def _tensor_index(order: int) -> np.ndarray:
    """For a symmetric tensor of ``order`` over 3 axes: the moment index of every entry."""
    idx = np.empty((3,) * order, dtype=np.int64)
    for pos in np.ndindex(*idx.shape):
        e = [0, 0, 0]
        for axis in pos:
            e[axis] += 1
        idx[pos] = _INDEX[tuple(e)]
    return idx


_T1, _T2, _T3, _T4 = (_tensor_index(k) for k in (1, 2, 3, 4))
#: The moment index of every entry of the symmetric moment tensors of degree 2, 3 and 4: (3, 3), (3, 3, 3), (3, 3, 3, 3)
#: int64 (what :func:`patchcloud.core._fit_kernels.fit_quadrics` reads the moments through).
TENSOR_INDEX = (_T2, _T3, _T4)

# Binomial shift: (p + d)^alpha = sum_{beta <= alpha} C(alpha, beta) d^(alpha - beta) p^beta.
_pairs = [
    (i, j)
    for i, ea in enumerate(EXPONENTS.tolist())
    for j, eb in enumerate(EXPONENTS.tolist())
    if all(b <= a for a, b in zip(ea, eb))
]
_SHIFT_ROW = np.array([p[0] for p in _pairs])
_SHIFT_COL = np.array([p[1] for p in _pairs])
_SHIFT_EXP = EXPONENTS[_SHIFT_ROW] - EXPONENTS[_SHIFT_COL]
_SHIFT_BINOM = np.array(
    [
        comb(int(a), int(b)) * comb(int(c), int(d)) * comb(int(e), int(f))
        for (a, c, e), (b, d, f) in zip(EXPONENTS[_SHIFT_ROW], EXPONENTS[_SHIFT_COL])
    ],
    dtype=np.float64,
)


def point_moments(rel: np.ndarray, starts: np.ndarray, chunk: int = 1 << 18) -> np.ndarray:
    """Moments of contiguous runs of points (numpy reference of the compiled ``cell_moments``).

    Parameters
    ----------
    rel : (N, 3) float64
        Point coordinates relative to the centre of the node each belongs to (metres).
    starts : (M,) int64
        Index of the first point of each node; nodes are the runs
        ``rel[starts[k]:starts[k + 1]]`` and ``starts[0] == 0``.

    Returns
    -------
    (M, 35) float64
        Moments in the order of :data:`EXPONENTS`.
    """
    n = rel.shape[0]
    m = starts.shape[0]
    out = np.zeros((m, N_MOMENTS), dtype=np.float64)
    if n == 0:
        return out
    # Chunks of whole nodes bound the temporary memory.
    targets = np.arange(chunk, n, chunk)
    cuts = starts[np.searchsorted(starts, targets, side="right") - 1]
    cuts = np.unique(np.concatenate([[0], cuts, [n]]))
    for lo, hi in zip(cuts[:-1].tolist(), cuts[1:].tolist()):
        k0 = int(np.searchsorted(starts, lo))
        k1 = int(np.searchsorted(starts, hi))
        local = starts[k0:k1] - lo
        out[k0:k1, 0] = np.diff(np.append(local, hi - lo))
        axes = (rel[lo:hi, 0], rel[lo:hi, 1], rel[lo:hi, 2])
        values: dict[tuple[int, int, int], np.ndarray] = {}
        for i in range(1, N_MOMENTS):
            a, b, c = (int(v) for v in EXPONENTS[i])
            # build each monomial from one of degree one less
            axis = 0 if a else (1 if b else 2)
            prev = (a - (axis == 0), b - (axis == 1), c - (axis == 2))
            val = axes[axis] if sum(prev) == 0 else values[prev] * axes[axis]
            out[k0:k1, i] = np.add.reduceat(val, local)
            if a + b + c < 4:
                values[(a, b, c)] = val
    return out


def cell_moments(local: np.ndarray, starts: np.ndarray, centres: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Moments of contiguous runs of points about their cells' centres (compiled).

    The compiled counterpart of :func:`point_moments`, which the tests
    compare it with: one parallel pass over the points, each run's sums
    accumulated in its own order, so the result does not depend on the
    thread count.

    Parameters
    ----------
    local : (N, 3) float64
        Points, C-ordered, sorted so that each cell's points are one run.
    starts : (M,) int64
        Index of the first point of each run; run ``k`` is
        ``local[starts[k]:starts[k + 1]]`` (the last one ends at ``N``) and
        ``starts[0] == 0``.
    centres : (M, 3) float64
        The centre of each run's cell, in the coordinates of ``local``.
    out : (M, 35) float64, optional
        Where to write the moments (every entry is overwritten); default: a
        new array.

    Returns
    -------
    (M, 35) float64
        ``out``: row ``k`` holds the moments of run ``k`` about ``centres[k]``,
        in the order of :data:`EXPONENTS`.

    Examples
    --------
    >>> import numpy as np
    >>> pts = np.random.default_rng(0).uniform(0, 2, (1000, 3))
    >>> pts = pts[np.argsort(pts[:, 0] >= 1, kind="stable")]
    >>> starts = np.array([0, int(np.count_nonzero(pts[:, 0] < 1))])
    >>> centres = np.array([[0.5, 1.0, 1.0], [1.5, 1.0, 1.0]])
    >>> m = cell_moments(pts, starts, centres)
    >>> m.shape, m[:, 0].tolist() == [starts[1], 1000 - starts[1]]
    ((2, 35), True)
    >>> rel = pts - np.repeat(centres, np.diff(np.r_[starts, 1000]), axis=0)
    >>> bool(np.allclose(m, point_moments(rel, starts)))
    True
    """
    if out is None:
        out = np.empty((starts.shape[0], N_MOMENTS), dtype=np.float64)
    _kernels.cell_moments(local, starts, centres, out)
    return out


def shift_entries(d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The non-zero entries of :func:`shift_matrices`: ``rows`` (T,), ``cols`` (T,), values (K, T)."""
    d = np.asarray(d, dtype=np.float64)
    pw = np.ones((d.shape[0], 3, 5))  # d_axis ** 0..4 by products (no pow)
    for e in range(1, 5):
        pw[:, :, e] = pw[:, :, e - 1] * d
    vals = pw[:, 0, _SHIFT_EXP[:, 0]] * pw[:, 1, _SHIFT_EXP[:, 1]]
    vals *= pw[:, 2, _SHIFT_EXP[:, 2]]
    vals *= _SHIFT_BINOM
    return _SHIFT_ROW, _SHIFT_COL, vals


def shift_moments(moments: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Moments about ``c`` (M, 35) moved to ``c - d``: the sums of ``(p - c + d)^e`` (a compiled loop over the
    non-zero entries of :func:`shift_matrices`).

    Parameters
    ----------
    moments : (M, 35) float64
    d : (M, 3) float64
        Old centre minus new centre (metres).

    Examples
    --------
    >>> import numpy as np
    >>> p = np.random.default_rng(0).normal(size=(50, 3))
    >>> m = point_moments(p, np.array([0]))
    >>> moved = shift_moments(m, np.array([[0.5, -1.0, 2.0]]))
    >>> bool(np.allclose(moved, point_moments(p + [0.5, -1.0, 2.0], np.array([0]))))
    True
    """
    moments = np.ascontiguousarray(moments, dtype=np.float64)
    out = np.empty_like(moments)
    _kernels.shift_moments(moments, np.ascontiguousarray(d, dtype=np.float64), _SHIFT_ROW, _SHIFT_COL, _SHIFT_EXP,
                           _SHIFT_BINOM, out)
    return out


def shift_matrices(d: np.ndarray) -> np.ndarray:
    """Matrices that move moments by a translation.

    If ``M`` holds moments about centre ``c`` then ``S @ M`` holds the moments
    about ``c - d`` (that is, of the coordinates ``p + d``).

    Parameters
    ----------
    d : (K, 3) float64
        Translations in metres.

    Returns
    -------
    (K, 35, 35) float64
    """
    rows, cols, vals = shift_entries(d)
    out = np.zeros((vals.shape[0], N_MOMENTS, N_MOMENTS))
    out[:, rows, cols] = vals
    return out


def pca(moments: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centroid, eigenvalues and frame of every node's points.

    Parameters
    ----------
    moments : (M, 35) float64
        Moments about the node centres; nodes must hold at least one point.

    Returns
    -------
    mean : (M, 3) float64
        Centroid relative to the node centre (metres).
    eigenvalues : (M, 3) float64
        Covariance eigenvalues, descending ``lambda1 >= lambda2 >= lambda3`` (m^2).
    frame : (M, 3, 3) float64
        Right-handed orthonormal frame with the eigenvectors as *columns*
        ``e1, e2, e3``; ``e3`` (the plane normal) has a non-negative
        component along (0.001, 0.01, 1) so the choice is deterministic.
    """
    n = moments[:, 0]
    mean = moments[:, 1:4] / n[:, None]
    cov = moments[:, _T2] / n[:, None, None] - mean[:, :, None] * mean[:, None, :]
    w, v = np.linalg.eigh(cov)
    eig = np.maximum(w[:, ::-1], 0.0)
    e1 = v[:, :, 2]
    e3 = v[:, :, 0]
    s = np.where(e3 @ np.array([1e-3, 1e-2, 1.0]) < 0, -1.0, 1.0)
    e3 = e3 * s[:, None]
    e2 = np.cross(e3, e1)
    frame = np.stack([e1, e2, e3], axis=2)
    return mean, eig, frame


def _contract(t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Contract the last axis of a batch of tensors with a batch of vectors."""
    return np.einsum("n...i,ni->n...", t, v)


def quadric_normal_equations(
    moments: np.ndarray, frame: np.ndarray, scale: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares system of the quadric ``w = a u^2 + b uv + c v^2 + d u + e v + f``.

    The coordinates are ``(u, v, w) = frame.T @ (p - centre) / scale``, that is
    the node's PCA frame with its origin at the node centre, scaled to be of
    order one.

    Parameters
    ----------
    moments : (M, 35) float64
        Moments about the node centres.
    frame : (M, 3, 3) float64
        Orthonormal frames, axes as columns (from :func:`pca`).
    scale : (M,) float64
        Length unit of the scaled coordinates (metres), e.g. half the node edge.

    Returns
    -------
    G : (M, 6, 6) float64
        ``sum phi phi^T`` with ``phi = (u^2, uv, v^2, u, v, 1)``.
    b : (M, 6) float64
        ``sum w phi``.
    ww : (M,) float64
        ``sum w^2``.
    """
    e1, e2, e3 = frame[:, :, 0], frame[:, :, 1], frame[:, :, 2]
    t4 = moments[:, _T4]
    t3 = moments[:, _T3]
    t2 = moments[:, _T2]
    t1 = moments[:, _T1]
    # degree 4: u^i v^j, i + j = 4
    a4, b4 = _contract(t4, e1), _contract(t4, e2)
    aa4, ab4, bb4 = _contract(a4, e1), _contract(a4, e2), _contract(b4, e2)
    aaa4, aab4 = _contract(aa4, e1), _contract(aa4, e2)
    abb4, bbb4 = _contract(ab4, e2), _contract(bb4, e2)
    dot = lambda p, q: np.einsum("ni,ni->n", p, q)  # noqa: E731
    m4 = [dot(aaa4, e1), dot(aaa4, e2), dot(aab4, e2), dot(abb4, e2), dot(bbb4, e2)]
    # degree 3: u^i v^j and w u^i v^j
    a3, b3 = _contract(t3, e1), _contract(t3, e2)
    aa3, ab3, bb3 = _contract(a3, e1), _contract(a3, e2), _contract(b3, e2)
    m3 = [dot(aa3, e1), dot(aa3, e2), dot(ab3, e2), dot(bb3, e2)]
    w3 = [dot(aa3, e3), dot(ab3, e3), dot(bb3, e3)]
    # degree 2 and 1
    r2 = np.einsum("nai,nab,nbj->nij", frame, t2, frame)
    r1 = np.einsum("nai,na->ni", frame, t1)
    n = moments[:, 0]
    s = scale
    s2, s3, s4 = s * s, s * s * s, s * s * s * s
    # uv[i][j] = sum u^i v^j (scaled)
    uv = {
        (0, 0): n,
        (1, 0): r1[:, 0] / s, (0, 1): r1[:, 1] / s,
        (2, 0): r2[:, 0, 0] / s2, (1, 1): r2[:, 0, 1] / s2, (0, 2): r2[:, 1, 1] / s2,
        (3, 0): m3[0] / s3, (2, 1): m3[1] / s3, (1, 2): m3[2] / s3, (0, 3): m3[3] / s3,
        (4, 0): m4[0] / s4, (3, 1): m4[1] / s4, (2, 2): m4[2] / s4,
        (1, 3): m4[3] / s4, (0, 4): m4[4] / s4,
    }
    wuv = {
        (0, 0): r1[:, 2] / s,
        (1, 0): r2[:, 0, 2] / s2, (0, 1): r2[:, 1, 2] / s2,
        (2, 0): w3[0] / s3, (1, 1): w3[1] / s3, (0, 2): w3[2] / s3,
    }
    ww = r2[:, 2, 2] / s2
    phi = [(2, 0), (1, 1), (0, 2), (1, 0), (0, 1), (0, 0)]
    G = np.empty((moments.shape[0], 6, 6))
    for k, (ik, jk) in enumerate(phi):
        for m, (im, jm) in enumerate(phi):
            G[:, k, m] = uv[(ik + im, jk + jm)]
    b = np.stack([wuv[p] for p in phi], axis=1)
    return G, b, ww
