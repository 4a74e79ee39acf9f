"""Compiled per-point loops (numba) for the two steps that visit every point.

Everything per node stays vectorised numpy; only the evaluation of the
patch quadrics at each point and the blending across leaf faces run here,
where numpy's temporaries would cost ten times more.  Each kernel mirrors a
numpy reference in :mod:`.quadric` / :mod:`.blend`, and the tests compare
them.  Compiled code is cached on disk after the first call.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

__all__ = ["eval_surface_points", "blend_points"]

_KIND_SURFACE = 0
_MAX_DEPTH = 21


@njit(cache=True, inline="always")
def _frame_coords(px, py, pz, l, centroid, frames):
    dx = px - centroid[l, 0]
    dy = py - centroid[l, 1]
    dz = pz - centroid[l, 2]
    u = frames[l, 0, 0] * dx + frames[l, 1, 0] * dy + frames[l, 2, 0] * dz
    v = frames[l, 0, 1] * dx + frames[l, 1, 1] * dy + frames[l, 2, 1] * dz
    w = frames[l, 0, 2] * dx + frames[l, 1, 2] * dy + frames[l, 2, 2] * dz
    return u, v, w


@njit(cache=True, inline="always")
def _normal_at(u, v, l, frames, coeffs):
    a, b, c, d, e = coeffs[l, 0], coeffs[l, 1], coeffs[l, 2], coeffs[l, 3], coeffs[l, 4]
    su = 2.0 * a * u + b * v + d
    sv = b * u + 2.0 * c * v + e
    inv = 1.0 / np.sqrt(1.0 + su * su + sv * sv)
    lx, ly, lz = -su * inv, -sv * inv, inv
    nx = frames[l, 0, 0] * lx + frames[l, 0, 1] * ly + frames[l, 0, 2] * lz
    ny = frames[l, 1, 0] * lx + frames[l, 1, 1] * ly + frames[l, 1, 2] * lz
    nz = frames[l, 2, 0] * lx + frames[l, 2, 1] * ly + frames[l, 2, 2] * lz
    return nx, ny, nz, su, sv


@njit(cache=True, inline="always")
def _curvatures(su, sv, l, coeffs):
    a, b, c = coeffs[l, 0], coeffs[l, 1], coeffs[l, 2]
    W = np.sqrt(1.0 + su * su + sv * sv)
    E, F, G = 1.0 + su * su, su * sv, 1.0 + sv * sv
    L, M, N = -2.0 * a / W, -b / W, -2.0 * c / W
    det1 = E * G - F * F
    H = (E * N - 2.0 * F * M + G * L) / (2.0 * det1)
    K = (L * N - M * M) / det1
    disc = H * H - K
    disc = np.sqrt(disc) if disc > 0.0 else 0.0
    return H + disc, H - disc, E, F, G, L, M, N


@njit(cache=True)
def _spread(x):
    x = x & np.uint64(0x1FFFFF)
    x = (x | (x << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    x = (x | (x << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    x = (x | (x << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    x = (x | (x << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    x = (x | (x << np.uint64(2))) & np.uint64(0x1249249249249249)
    return x


@njit(cache=True)
def _find_leaf(key, lo, hi):
    # last leaf whose first key is <= key
    a, b = 0, lo.shape[0]
    while a < b:
        m = (a + b) >> 1
        if lo[m] <= key:
            a = m + 1
        else:
            b = m
    i = a - 1
    if i >= 0 and key < hi[i]:
        return i
    return -1


@njit(cache=True, parallel=True)
def eval_surface_points(local, start, count, surface, centroid, frames, coeffs, sigma3, normals, scalars, dir1):
    """Normal, (sigma3, k1, k2) and k1 direction of every point of a surface leaf.

    Writes rows of ``normals``, ``scalars`` and ``dir1`` (sorted order) for
    the points of leaves with ``surface[l]``; mirrors
    :func:`patchcloud.core.quadric.surface_normals` and ``surface_curvatures``.
    """
    P = start.shape[0]
    for l in prange(P):
        if not surface[l]:
            continue
        for i in range(start[l], start[l] + count[l]):
            u, v, w = _frame_coords(local[i, 0], local[i, 1], local[i, 2], l, centroid, frames)
            nx, ny, nz, su, sv = _normal_at(u, v, l, frames, coeffs)
            normals[i, 0], normals[i, 1], normals[i, 2] = nx, ny, nz
            k1, k2, E, F, G, L, M, N = _curvatures(su, sv, l, coeffs)
            scalars[i, 0], scalars[i, 1], scalars[i, 2] = sigma3[l], k1, k2
            r1u, r1v = M - k1 * F, -(L - k1 * E)
            r2u, r2v = N - k1 * G, -(M - k1 * F)
            if r2u * r2u + r2v * r2v > r1u * r1u + r1v * r1v:
                du, dv = r2u, r2v
            else:
                du, dv = r1u, r1v
            nrm = np.sqrt(du * du + dv * dv)
            if nrm < 1e-12 * (abs(k1) + 1e-300) + 1e-300:
                du, dv = 1.0, 0.0
            else:
                du, dv = du / nrm, dv / nrm
            tl = su * du + sv * dv
            tx = frames[l, 0, 0] * du + frames[l, 0, 1] * dv + frames[l, 0, 2] * tl
            ty = frames[l, 1, 0] * du + frames[l, 1, 1] * dv + frames[l, 1, 2] * tl
            tz = frames[l, 2, 0] * du + frames[l, 2, 1] * dv + frames[l, 2, 2] * tl
            tn = np.sqrt(tx * tx + ty * ty + tz * tz)
            dir1[i, 0], dir1[i, 1], dir1[i, 2] = tx / tn, ty / tn, tz / tn


@njit(cache=True, parallel=True)
def blend_points(
    local, q, start, count, level, ijk, lo_key, hi_key, lower, edge, kind, centroid, frames, coeffs, sigma3,
    normals, scalars, dir1, blended,
):
    """Blend normals and (sigma3, k1, k2) of surface points across leaf faces, in place.

    Mirrors :func:`patchcloud.core.blend.blend_across_faces`: within
    ``r = min(d1, d2) / 3`` of a face, the neighbour's surface value at the
    point gets the Wendland weight of ``dist / r`` (own value: weight 1),
    provided the neighbour surface passes within ``r`` of the point.
    """
    P = start.shape[0]
    qmax = 1 << _MAX_DEPTH
    for l in prange(P):
        if kind[l] != _KIND_SURFACE:
            continue
        h = edge[l]
        shift = _MAX_DEPTH - level[l]
        for i in range(start[l], start[l] + count[l]):
            px, py, pz = local[i, 0], local[i, 1], local[i, 2]
            nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
            s0, s1, s2 = scalars[i, 0], scalars[i, 1], scalars[i, 2]
            wsum = 1.0
            hit = False
            for axis in range(3):
                lo = lower[l, axis]
                dlo = local[i, axis] - lo
                dhi = lo + h - local[i, axis]
                upper = dhi < dlo
                dist = dhi if upper else dlo
                if dist >= h / 3.0:
                    continue
                cell = ijk[l, axis]
                pc = ((cell + 1) << shift) if upper else ((cell << shift) - 1)
                if pc < 0 or pc >= qmax:
                    continue
                c0, c1, c2 = q[i, 0], q[i, 1], q[i, 2]
                if axis == 0:
                    c0 = pc
                elif axis == 1:
                    c1 = pc
                else:
                    c2 = pc
                key = _spread(np.uint64(c0)) | (_spread(np.uint64(c1)) << np.uint64(1)) | (_spread(np.uint64(c2)) << np.uint64(2))
                j = _find_leaf(key, lo_key, hi_key)
                if j < 0 or kind[j] != _KIND_SURFACE:
                    continue
                r = min(h, edge[j]) / 3.0
                t = dist / r
                if t >= 1.0:
                    continue
                u, v, w = _frame_coords(px, py, pz, j, centroid, frames)
                a, b, c, d, e, f = coeffs[j, 0], coeffs[j, 1], coeffs[j, 2], coeffs[j, 3], coeffs[j, 4], coeffs[j, 5]
                gap = w - (a * u * u + b * u * v + c * v * v + d * u + e * v + f)
                if abs(gap) > r:
                    continue
                mx, my, mz, su, sv = _normal_at(u, v, j, frames, coeffs)
                if mx * normals[i, 0] + my * normals[i, 1] + mz * normals[i, 2] <= 0.0:
                    continue  # opposite orientations never blend
                wt = (1.0 - t) ** 4 * (4.0 * t + 1.0)
                k1, k2, E, F, G, L, M, N = _curvatures(su, sv, j, coeffs)
                nx += wt * mx
                ny += wt * my
                nz += wt * mz
                s0 += wt * sigma3[j]
                s1 += wt * k1
                s2 += wt * k2
                wsum += wt
                hit = True
            if hit:
                nn = np.sqrt(nx * nx + ny * ny + nz * nz)
                nx, ny, nz = nx / nn, ny / nn, nz / nn
                normals[i, 0], normals[i, 1], normals[i, 2] = nx, ny, nz
                scalars[i, 0], scalars[i, 1], scalars[i, 2] = s0 / wsum, s1 / wsum, s2 / wsum
                # keep the k1 direction tangent to the blended normal
                tx, ty, tz = dir1[i, 0], dir1[i, 1], dir1[i, 2]
                dt = tx * nx + ty * ny + tz * nz
                tx, ty, tz = tx - dt * nx, ty - dt * ny, tz - dt * nz
                tn = np.sqrt(tx * tx + ty * ty + tz * tz)
                if tn > 0:
                    dir1[i, 0], dir1[i, 1], dir1[i, 2] = tx / tn, ty / tn, tz / tn
                blended[i] = True
