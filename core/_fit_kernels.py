"""The PCA plane and least-squares quadric of many octree nodes from their moments, one compiled loop.

:func:`fit_quadrics` does for each node what :func:`patchcloud.core.moments.pca`,
:func:`patchcloud.core.moments.quadric_normal_equations` and the solve of
:func:`patchcloud.core.quadric.fit_nodes` do with numpy over all nodes at
once (those stay the reference the tests hold it to): the covariance's
eigen-decomposition (:func:`patchcloud.core._kernels.eigh3_into`), the
moments turned into the node's PCA frame by contracting the symmetric
moment tensors of degrees 1 to 4 with the frame's axes, the 6 x 6 normal
equations of ``w = a u^2 + b uv + c v^2 + d u + e v + f`` solved with the
same ridge, and the coefficients moved to the centroid.  numpy spent most
of the fit's time in ``einsum`` and in batched LAPACK calls of a few
thousand 3 x 3 and 6 x 6 systems (about 0.15 s of a 2-million-point
tile's 0.43 s fit).
"""

from __future__ import annotations

import numpy as np
from numba import prange

from ._kernels import CHUNK, cholesky_solve6, eigh3_into
from .threads import parallel_kernel

__all__ = ["fit_quadrics"]

#: The basis phi = (u^2, uv, v^2, u, v, 1) of the quadric: the exponents of u, and of v.
_PHI_U = np.array([2, 1, 0, 1, 0, 0])
_PHI_V = np.array([0, 1, 2, 0, 1, 0])


@parallel_kernel
def fit_quadrics(moments, half_edge, t2, t3, t4, quadric, mean, eig, frame, coeffs, rmse):
    """PCA and (where ``quadric``) quadric of every node from its moments about its centre (see the module's notes).

    Writes ``mean`` (M, 3) (centroid relative to the node centre), ``eig``
    (M, 3) descending and clipped at 0, ``frame`` (M, 3, 3) with the axes
    ``e1, e2, e3`` as columns (``e3`` along (0.001, 0.01, 1), ``e2 = e3 x e1``),
    and with ``quadric``: ``coeffs`` (M, 6), in the frame at the centroid
    (metres), and ``rmse`` (M,) of the fit along ``e3``.
    """
    M = moments.shape[0]
    chunks = (M + CHUNK - 1) // CHUNK
    for chunk in prange(chunks):
        cov = np.empty((3, 3))
        w = np.empty(3)
        vec = np.empty((3, 3))
        e = np.empty((3, 3))  # rows: e1, e2, e3
        T4 = np.empty((3, 3, 3, 3))
        T3 = np.empty((3, 3, 3))
        A4 = np.empty((2, 3, 3, 3))  # T4 . e1, T4 . e2
        A3 = np.empty((2, 3, 3))
        G = np.empty((6, 6))
        Gr = np.empty((6, 6))
        rhs = np.empty(6)
        uv = np.empty((5, 5))  # sum u^i v^j, scaled
        w3 = np.empty(3)  # sum w u^2, w uv, w v^2, scaled
        r2 = np.empty((3, 3))  # second moments in the frame, scaled (upper triangle)
        r1 = np.empty(3)
        for m in range(chunk * CHUNK, min(M, (chunk + 1) * CHUNK)):
            n = moments[m, 0]
            mx, my, mz = moments[m, 1] / n, moments[m, 2] / n, moments[m, 3] / n
            mean[m, 0], mean[m, 1], mean[m, 2] = mx, my, mz
            for a in range(3):
                for b in range(3):
                    cov[a, b] = moments[m, t2[a, b]] / n - mean[m, a] * mean[m, b]
            eigh3_into(cov, w, vec)
            eig[m, 0], eig[m, 1], eig[m, 2] = max(w[2], 0.0), max(w[1], 0.0), max(w[0], 0.0)
            sgn = -1.0 if vec[0, 0] * 1e-3 + vec[1, 0] * 1e-2 + vec[2, 0] < 0 else 1.0
            for a in range(3):
                e[0, a] = vec[a, 2]
                e[2, a] = sgn * vec[a, 0]
            e[1, 0] = e[2, 1] * e[0, 2] - e[2, 2] * e[0, 1]
            e[1, 1] = e[2, 2] * e[0, 0] - e[2, 0] * e[0, 2]
            e[1, 2] = e[2, 0] * e[0, 1] - e[2, 1] * e[0, 0]
            for a in range(3):
                for c in range(3):
                    frame[m, a, c] = e[c, a]
            if not quadric:
                continue
            # the moment tensors of degree 3 and 4 contracted with e1 (and e2) axis by axis
            for a in range(3):
                for b in range(3):
                    for c in range(3):
                        T3[a, b, c] = moments[m, t3[a, b, c]]
                        for d in range(3):
                            T4[a, b, c, d] = moments[m, t4[a, b, c, d]]
            for f in range(2):
                for a in range(3):
                    for b in range(3):
                        for c in range(3):
                            A4[f, a, b, c] = T4[a, b, c, 0] * e[f, 0] + T4[a, b, c, 1] * e[f, 1] + T4[a, b, c, 2] * e[f, 2]
                        A3[f, a, b] = T3[a, b, 0] * e[f, 0] + T3[a, b, 1] * e[f, 1] + T3[a, b, 2] * e[f, 2]
            s = half_edge[m]
            # degree 4: u^i v^(4-i) = A4[0 or 1] contracted with the axes (the tensor is symmetric: any order)
            for i in range(5):  # i factors e1, 4 - i factors e2
                f0 = 0 if i >= 1 else 1  # the first contraction (A4's), then three more
                k1 = i - 1 if i >= 1 else 0  # e1 factors left
                tot = 0.0
                for a in range(3):
                    for b in range(3):
                        for c in range(3):
                            # factors for a, b, c: e1 for the first k1 of them, e2 for the rest
                            fa = e[0, a] if k1 >= 1 else e[1, a]
                            fb = e[0, b] if k1 >= 2 else e[1, b]
                            fc = e[0, c] if k1 >= 3 else e[1, c]
                            tot += A4[f0, a, b, c] * fa * fb * fc
                uv[i, 4 - i] = tot / (s * s * s * s)
            for i in range(4):  # degree 3: i factors e1, 3 - i factors e2
                f0 = 0 if i >= 1 else 1
                k1 = i - 1 if i >= 1 else 0
                tot = 0.0
                for a in range(3):
                    for b in range(3):
                        fa = e[0, a] if k1 >= 1 else e[1, a]
                        fb = e[0, b] if k1 >= 2 else e[1, b]
                        tot += A3[f0, a, b] * fa * fb
                uv[i, 3 - i] = tot / (s * s * s)
            # w u^i v^(2-i) (degree 3), degree 2 and 1 in the frame
            for i in range(3):  # i factors e1
                f0 = 0 if i >= 1 else 1
                tot = 0.0
                for a in range(3):
                    for b in range(3):
                        fa = (e[0, a] if i == 2 else e[1, a])
                        tot += A3[f0, a, b] * fa * e[2, b]
                w3[2 - i] = tot / (s * s * s)
            for p in range(3):
                for q in range(p, 3):
                    tot = 0.0
                    for a in range(3):
                        for b in range(3):
                            tot += e[p, a] * moments[m, t2[a, b]] * e[q, b]
                    r2[p, q] = tot / (s * s)
            for p in range(3):
                r1[p] = (e[p, 0] * moments[m, 1] + e[p, 1] * moments[m, 2] + e[p, 2] * moments[m, 3]) / s
            uv[0, 0] = n
            uv[1, 0], uv[0, 1] = r1[0], r1[1]
            uv[2, 0], uv[1, 1], uv[0, 2] = r2[0, 0], r2[0, 1], r2[1, 1]
            # phi = (u^2, uv, v^2, u, v, 1): exponents of u and v
            for k in range(6):
                for l in range(6):
                    G[k, l] = uv[_PHI_U[k] + _PHI_U[l], _PHI_V[k] + _PHI_V[l]]
            rhs[0], rhs[1], rhs[2] = w3[0], w3[1], w3[2]  # w u^2, w uv, w v^2
            rhs[3], rhs[4], rhs[5] = r2[0, 2], r2[1, 2], r1[2]  # w u, w v, w
            ww = r2[2, 2]
            # a tiny ridge keeps a node whose points lie on a line solvable: 1e-13 of the mean diagonal
            ridge = 1e-13 * (G[0, 0] + G[1, 1] + G[2, 2] + G[3, 3] + G[4, 4] + G[5, 5]) / 6.0 + 1e-300
            for k in range(6):
                for l in range(6):
                    Gr[k, l] = G[k, l] + (ridge if k == l else 0.0)
            beta = cholesky_solve6(Gr, rhs)
            rss = ww
            for k in range(6):
                rss -= 2.0 * beta[k] * rhs[k]
                for l in range(6):
                    rss += beta[k] * G[k, l] * beta[l]
            rmse[m] = s * np.sqrt(max(rss, 0.0) / max(n, 1.0))
            a_, b_, c_ = beta[0] / s, beta[1] / s, beta[2] / s
            d_, e_, f_ = beta[3], beta[4], beta[5] * s
            u0 = e[0, 0] * mx + e[0, 1] * my + e[0, 2] * mz
            v0 = e[1, 0] * mx + e[1, 1] * my + e[1, 2] * mz
            w0 = e[2, 0] * mx + e[2, 1] * my + e[2, 2] * mz
            coeffs[m, 0], coeffs[m, 1], coeffs[m, 2] = a_, b_, c_
            coeffs[m, 3] = d_ + 2.0 * a_ * u0 + b_ * v0
            coeffs[m, 4] = e_ + b_ * u0 + 2.0 * c_ * v0
            coeffs[m, 5] = a_ * u0 * u0 + b_ * u0 * v0 + c_ * v0 * v0 + d_ * u0 + e_ * v0 + f_ - w0
