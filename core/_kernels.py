"""Compiled per-point loops (numba) for the two steps that visit every point.

Everything per node stays vectorised numpy.  What visits every point runs
here, where numpy's temporaries would cost five to ten times more: the
Morton keys, the finest-level moments, the evaluation of the patch quadrics
at each point, the blending across leaf faces, the k-NN fallback's PCA and
quadric, and the reordering of the outputs.  Where a numpy reference exists
(:func:`.moments.point_moments`, :func:`.morton.encode`,
:func:`.quadric.surface_normals` and ``surface_curvatures``) the tests compare
the two.  Parallel loops only ever write a row of their own, so results do
not depend on the thread count.  Compiled code is cached on disk after the
first call.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .threads import parallel_kernel

from .codes import PatchKind

__all__ = ["eval_surface_points", "blend_points", "cell_moments", "knn_pca", "bounds", "morton_keys", "unsort_outputs", "take_rows", "neighbour_signs", "shift_to_parents", "box_cell_keys", "run_starts", "rows_where", "box_cell_stats", "interpolated_pca", "eigh3", "eigh3_into", "morton_key", "cholesky_solve6", "face_votes", "CHUNK", "ROUNDING_SPREAD", "lower_bound", "upper_bound", "face_neighbour_counts", "shift_moments"]

_KIND_SURFACE = int(PatchKind.SURFACE)  # a plain int for numba
_MAX_DEPTH = 21
#: Rows per chunk of a parallel loop that allocates its scratch once per chunk.
CHUNK = 1024
#: Points whose moments about a cell of edge h leave a spread (the sum of their PCA eigenvalues) of at most this times
#: h^2 are one point (copies): the spread left is the rounding of the moments, about 1e-16 h^2, and has no shape.
ROUNDING_SPREAD = 1e-12


@njit(cache=True, nogil=True)
def _frame_coords(px, py, pz, l, centroid, frames):
    dx = px - centroid[l, 0]
    dy = py - centroid[l, 1]
    dz = pz - centroid[l, 2]
    u = frames[l, 0, 0] * dx + frames[l, 1, 0] * dy + frames[l, 2, 0] * dz
    v = frames[l, 0, 1] * dx + frames[l, 1, 1] * dy + frames[l, 2, 1] * dz
    w = frames[l, 0, 2] * dx + frames[l, 1, 2] * dy + frames[l, 2, 2] * dz
    return u, v, w


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
def _k1_direction(su, sv, k1, E, F, G, L, M, N, l, frames):
    """Unit 3D tangent of principal curvature k1 from the fundamental forms."""
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
    return tx / tn, ty / tn, tz / tn


@njit(cache=True, nogil=True)
def _spread(x):
    x = x & np.uint64(0x1FFFFF)
    x = (x | (x << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    x = (x | (x << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    x = (x | (x << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    x = (x | (x << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    x = (x | (x << np.uint64(2))) & np.uint64(0x1249249249249249)
    return x


@njit(cache=True, nogil=True)
def _compact(x):
    x = x & np.uint64(0x1249249249249249)
    x = (x | (x >> np.uint64(2))) & np.uint64(0x10C30C30C30C30C3)
    x = (x | (x >> np.uint64(4))) & np.uint64(0x100F00F00F00F00F)
    x = (x | (x >> np.uint64(8))) & np.uint64(0x1F0000FF0000FF)
    x = (x | (x >> np.uint64(16))) & np.uint64(0x1F00000000FFFF)
    x = (x | (x >> np.uint64(32))) & np.uint64(0x1FFFFF)
    return x


@njit(cache=True, nogil=True)
def shift_moments(moments, d, rows, cols, exps, binom, out):
    """``out[m]``: the moments ``moments[m]`` (35 sums of monomials) moved by ``d[m]``, from the non-zero entries of the
    shift matrix (``rows``, ``cols``, the exponents of ``d`` in each, their binomial factors)."""
    pw = np.empty((3, 5))
    for m in range(moments.shape[0]):
        for a in range(3):
            pw[a, 0] = 1.0
            for e in range(1, 5):
                pw[a, e] = pw[a, e - 1] * d[m, a]
        for j in range(out.shape[1]):
            out[m, j] = 0.0
        for t in range(rows.shape[0]):
            v = pw[0, exps[t, 0]] * pw[1, exps[t, 1]]
            v *= pw[2, exps[t, 2]]
            v *= binom[t]
            out[m, rows[t]] += v * moments[m, cols[t]]


@njit(cache=True, nogil=True)
def lower_bound(cells, key):
    """The first position of sorted ``cells`` whose value is not below ``key`` (numpy's searchsorted, left).

    Kernels use this and :func:`upper_bound`, not ``np.searchsorted``: numba's
    version lives in numba.np.arraymath, which a cached kernel calling it
    imports when it loads (0.3 s of a small run).
    """
    lo, hi = 0, cells.size
    while lo < hi:
        mid = (lo + hi) >> 1
        if cells[mid] < key:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True, nogil=True)
def upper_bound(cells, key):
    """The first position of sorted ``cells`` whose value is above ``key`` (numpy's searchsorted, right)."""
    lo, hi = 0, cells.size
    while lo < hi:
        mid = (lo + hi) >> 1
        if cells[mid] <= key:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True, nogil=True)
def face_neighbour_counts(keys, out):
    """``out[k]``: how many of the six face neighbours of the cell of Morton key ``keys[k]`` are in ``keys`` (unique,
    uint64, below 2**63): looked up in an open-addressing hash table of the keys (a binary search each took 80 ms of a
    277,573-point file's decompression)."""
    n = keys.shape[0]
    bits = 1
    while (1 << bits) < 2 * n:
        bits += 1
    size = 1 << bits
    empty = np.uint64(0xFFFFFFFFFFFFFFFF)
    table = np.full(size, empty, dtype=np.uint64)
    mask = np.uint64(size - 1)
    mult = np.uint64(0x9E3779B97F4A7C15)
    down = np.uint64(64 - bits)
    for k in range(n):
        h = (keys[k] * mult) >> down
        while table[h] != empty:
            h = (h + np.uint64(1)) & mask
        table[h] = keys[k]
    top = np.int64((1 << 21) - 1)
    three = np.uint64(3)
    first = 0  # the run of keys[k]'s siblings (one parent): keys[first:last], at most 8, around k in the sorted keys
    last = 0
    for k in range(n):
        key = keys[k]
        if k >= last:
            first = k
            last = k + 1
            while last < n and (keys[last] >> three) == (key >> three):
                last += 1
        c = np.int64(0)
        for axis in range(3):
            bit = np.uint64(1) << np.uint64(axis)
            # along each axis one face neighbour is a sibling (the other value of this axis' lowest bit): looked up in
            # the run, the other crosses the parent's face: in the hash table
            sib = key ^ bit
            for j in range(first, last):
                if keys[j] == sib:
                    c += 1
                    break
            v = np.int64(_compact(key >> np.uint64(axis)))
            w = v + 1 if key & bit else v - 1
            if w < 0 or w > top:
                continue
            rest = key & ~(np.uint64(0x1249249249249249) << np.uint64(axis))
            nk = rest | (_spread(np.uint64(w)) << np.uint64(axis))
            h = (nk * mult) >> down
            while table[h] != empty:
                if table[h] == nk:
                    c += 1
                    break
                h = (h + np.uint64(1)) & mask
        out[k] = c


@njit(cache=True, nogil=True)
def morton_key(i, j, k):
    """The Morton key (uint64) of integer cell coordinates in [0, 2**21), as :func:`.morton.encode` gives."""
    return _spread(np.uint64(i)) | (_spread(np.uint64(j)) << np.uint64(1)) | (_spread(np.uint64(k)) << np.uint64(2))


@njit(cache=True, nogil=True)
def _find_leaf(key, lo, hi):
    i = upper_bound(lo, key) - 1  # the last leaf whose first key is <= key
    if i >= 0 and key < hi[i]:
        return i
    return -1


@parallel_kernel
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
            dir1[i, 0], dir1[i, 1], dir1[i, 2] = _k1_direction(su, sv, k1, E, F, G, L, M, N, l, frames)


@parallel_kernel
def blend_points(
    local, q, start, count, level, ijk, lo_key, hi_key, lower, edge, kind, centroid, frames, coeffs, sigma3,
    nb_off, nb_lo_key, nb_hi_key, nb_edge, nb_kind, nb_centroid, nb_frames, nb_coeffs, nb_sigma3,
    normals, scalars, dir1, blended, todo,
):
    """Blend normals and (sigma3, k1, k2) of surface points across leaf faces, in place, for the points where ``todo``
    (every leaf still a neighbour).

    Mirrors :func:`patchcloud.core.blend.blend_across_faces`: within
    ``r = min(d1, d2) / 3`` of a face, the neighbour's surface value at the
    point gets the Wendland weight of ``dist / r`` (own value: weight 1),
    provided the neighbour surface passes within ``r`` of the point.

    Leaves beyond the root cube's faces come from the ``nb_*`` arrays: block
    ``d`` (rows ``nb_off[d]:nb_off[d + 1]``, sorted by key) holds the leaves
    of the equal-sized cube across face ``d`` (-x, +x, -y, +y, -z, +z), with
    keys in that cube's own octree and centroids in this cube's frame.
    """
    P = start.shape[0]
    qmax = 1 << _MAX_DEPTH
    for l in prange(P):
        if kind[l] != _KIND_SURFACE:
            continue
        h = edge[l]
        shift = _MAX_DEPTH - level[l]
        # per face (axis, side): the neighbour leaf the last point found there; the next point's is most often the same
        memo = np.full(6, -1, dtype=np.int64)
        for i in range(start[l], start[l] + count[l]):
            if not todo[i]:
                continue
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
                outside = pc < 0 or pc >= qmax
                if outside:  # across the root cube's face: the neighbour cube's leaves
                    pc = 0 if upper else qmax - 1
                c0, c1, c2 = q[i, 0], q[i, 1], q[i, 2]
                if axis == 0:
                    c0 = pc
                elif axis == 1:
                    c1 = pc
                else:
                    c2 = pc
                key = _spread(np.uint64(c0)) | (_spread(np.uint64(c1)) << np.uint64(1)) | (_spread(np.uint64(c2)) << np.uint64(2))
                face = 2 * axis + (1 if upper else 0)
                j = memo[face]
                if outside:
                    a0, a1 = nb_off[face], nb_off[face + 1]
                    if a0 == a1:
                        continue
                    if j < 0 or not (nb_lo_key[j] <= key and key < nb_hi_key[j]):  # else the leaf a search would find
                        j = _find_leaf(key, nb_lo_key[a0:a1], nb_hi_key[a0:a1])
                        if j < 0:
                            continue
                        j += a0
                        memo[face] = j
                    o_kind, o_edge, o_centroid, o_frames, o_coeffs, o_sigma3 = nb_kind, nb_edge, nb_centroid, nb_frames, nb_coeffs, nb_sigma3
                else:
                    if j < 0 or not (lo_key[j] <= key and key < hi_key[j]):
                        j = _find_leaf(key, lo_key, hi_key)
                        if j < 0:
                            continue
                        memo[face] = j
                    o_kind, o_edge, o_centroid, o_frames, o_coeffs, o_sigma3 = kind, edge, centroid, frames, coeffs, sigma3
                if o_kind[j] != _KIND_SURFACE:
                    continue
                r = min(h, o_edge[j]) / 3.0
                t = dist / r
                if t >= 1.0:
                    continue
                u, v, w = _frame_coords(px, py, pz, j, o_centroid, o_frames)
                a, b, c, d, e, f = o_coeffs[j, 0], o_coeffs[j, 1], o_coeffs[j, 2], o_coeffs[j, 3], o_coeffs[j, 4], o_coeffs[j, 5]
                gap = w - (a * u * u + b * u * v + c * v * v + d * u + e * v + f)
                if abs(gap) > r:
                    continue
                mx, my, mz, su, sv = _normal_at(u, v, j, o_frames, o_coeffs)
                if mx * normals[i, 0] + my * normals[i, 1] + mz * normals[i, 2] <= 0.0:
                    continue  # opposite orientations never blend
                wt = (1.0 - t) ** 4 * (4.0 * t + 1.0)
                k1, k2, E, F, G, L, M, N = _curvatures(su, sv, j, o_coeffs)
                nx += wt * mx
                ny += wt * my
                nz += wt * mz
                s0 += wt * o_sigma3[j]
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


@parallel_kernel
def cell_moments(local, starts, centres, out):
    """Moments (:mod:`patchcloud.core.moments`) of runs of points about their cell centres.

    ``out[k, m] = sum over the points of run k of prod_axis (p - centres[k]) ** EXPONENTS[m]``,
    the 35 monomials written out (generated from ``moments.EXPONENTS``, whose
    order they follow) so the sums stay in registers; mirrors
    :func:`patchcloud.core.moments.point_moments`.
    """
    M = starts.shape[0]
    n = local.shape[0]
    for k in prange(M):
        hi = starts[k + 1] if k + 1 < M else n
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        a3 = 0.0
        a4 = 0.0
        a5 = 0.0
        a6 = 0.0
        a7 = 0.0
        a8 = 0.0
        a9 = 0.0
        a10 = 0.0
        a11 = 0.0
        a12 = 0.0
        a13 = 0.0
        a14 = 0.0
        a15 = 0.0
        a16 = 0.0
        a17 = 0.0
        a18 = 0.0
        a19 = 0.0
        a20 = 0.0
        a21 = 0.0
        a22 = 0.0
        a23 = 0.0
        a24 = 0.0
        a25 = 0.0
        a26 = 0.0
        a27 = 0.0
        a28 = 0.0
        a29 = 0.0
        a30 = 0.0
        a31 = 0.0
        a32 = 0.0
        a33 = 0.0
        a34 = 0.0
        for i in range(starts[k], hi):
            x = local[i, 0] - centres[k, 0]
            y = local[i, 1] - centres[k, 1]
            z = local[i, 2] - centres[k, 2]
            x2, y2, z2 = x * x, y * y, z * z
            x3, y3, z3 = x2 * x, y2 * y, z2 * z
            x4, y4, z4 = x2 * x2, y2 * y2, z2 * z2
            a0 += 1.0
            a1 += x
            a2 += y
            a3 += z
            a4 += x2
            a5 += x*y
            a6 += x*z
            a7 += y2
            a8 += y*z
            a9 += z2
            a10 += x3
            a11 += x2*y
            a12 += x2*z
            a13 += x*y2
            a14 += x*y*z
            a15 += x*z2
            a16 += y3
            a17 += y2*z
            a18 += y*z2
            a19 += z3
            a20 += x4
            a21 += x3*y
            a22 += x3*z
            a23 += x2*y2
            a24 += x2*y*z
            a25 += x2*z2
            a26 += x*y3
            a27 += x*y2*z
            a28 += x*y*z2
            a29 += x*z3
            a30 += y4
            a31 += y3*z
            a32 += y2*z2
            a33 += y*z3
            a34 += z4
        out[k, 0] = a0
        out[k, 1] = a1
        out[k, 2] = a2
        out[k, 3] = a3
        out[k, 4] = a4
        out[k, 5] = a5
        out[k, 6] = a6
        out[k, 7] = a7
        out[k, 8] = a8
        out[k, 9] = a9
        out[k, 10] = a10
        out[k, 11] = a11
        out[k, 12] = a12
        out[k, 13] = a13
        out[k, 14] = a14
        out[k, 15] = a15
        out[k, 16] = a16
        out[k, 17] = a17
        out[k, 18] = a18
        out[k, 19] = a19
        out[k, 20] = a20
        out[k, 21] = a21
        out[k, 22] = a22
        out[k, 23] = a23
        out[k, 24] = a24
        out[k, 25] = a25
        out[k, 26] = a26
        out[k, 27] = a27
        out[k, 28] = a28
        out[k, 29] = a29
        out[k, 30] = a30
        out[k, 31] = a31
        out[k, 32] = a32
        out[k, 33] = a33
        out[k, 34] = a34


@njit(cache=True, nogil=True)
def cholesky_solve6(G, b):
    """Solve ``G x = b`` for a symmetric positive definite 6x6 ``G`` (overwritten)."""
    for j in range(6):
        d = G[j, j]
        for k in range(j):
            d -= G[j, k] * G[j, k]
        d = np.sqrt(d) if d > 0.0 else 1e-300
        G[j, j] = d
        for i in range(j + 1, 6):
            v = G[i, j]
            for k in range(j):
                v -= G[i, k] * G[j, k]
            G[i, j] = v / d
    x = b.copy()
    for i in range(6):
        v = x[i]
        for k in range(i):
            v -= G[i, k] * x[k]
        x[i] = v / G[i, i]
    for i in range(5, -1, -1):
        v = x[i]
        for k in range(i + 1, 6):
            v -= G[k, i] * x[k]
        x[i] = v / G[i, i]
    return x


@njit(cache=True, nogil=True)
def _plane_sign(vec):
    """-1.0 or 1.0: the sign that makes the first column of ``vec`` (the smallest eigenvalue's vector) point along (0.001, 0.01, 1)."""
    return -1.0 if vec[0, 0] * 1e-3 + vec[1, 0] * 1e-2 + vec[2, 0] < 0 else 1.0


@njit(cache=True, nogil=True)
def _plane_normal(vec):
    """The eigenvector of the smallest eigenvalue (first column of ``vec``), made to point along (0.001, 0.01, 1)."""
    e3 = vec[:, 0].copy()
    if _plane_sign(vec) < 0:
        e3 = -e3
    return e3


@njit(cache=True, nogil=True)
def eigh3(A):
    """Eigenvalues (ascending) and eigenvectors (columns) of a symmetric 3x3 matrix (:func:`eigh3_into`)."""
    w = np.empty(3)
    v = np.empty((3, 3))
    eigh3_into(A, w, v)
    return w, v


@njit(cache=True, nogil=True)
def eigh3_into(a, w, v):
    """:func:`eigh3` without allocating: reads the upper triangle of ``a`` (3, 3); writes ``w`` (3,) and ``v`` (3, 3).

    Closed form, after D. Eberly, "A Robust Eigensolver for 3 x 3
    Symmetric Matrices" (Geometric Tools, 2014): the
    matrix is scaled by its largest entry; the eigenvalues are those of the
    trigonometric solution of the characteristic cubic; the eigenvector of
    the eigenvalue farthest from the other two is the longest cross product
    of two rows of ``A - lambda I``; the other two diagonalise the 2 x 2
    restriction of ``A`` to the plane orthogonal to it (one rotation); the
    eigenvalues are the vectors' Rayleigh quotients.  0.16 us a matrix
    against 0.34 us for the cyclic Jacobi it replaces, as accurate (tested
    against LAPACK), for the loops that solve one per point: moment
    normals, k-NN and radius PCA.
    Eigenvalues ascending; a matrix with a NaN gives NaNs; a multiple of the
    identity gives the identity's columns.
    """
    a00, a01, a02, a11, a12, a22 = a[0, 0], a[0, 1], a[0, 2], a[1, 1], a[1, 2], a[2, 2]
    big = max(abs(a00), abs(a01), abs(a02), abs(a11), abs(a12), abs(a22))
    if not big > 0.0:  # zero, or NaN
        fill = 0.0 if big == 0.0 else np.nan
        for r in range(3):
            w[r] = fill
            for c in range(3):
                v[r, c] = (1.0 if r == c else 0.0) if big == 0.0 else np.nan
        return
    inv = 1.0 / big
    a00, a01, a02, a11, a12, a22 = a00 * inv, a01 * inv, a02 * inv, a11 * inv, a12 * inv, a22 * inv
    off = a01 * a01 + a02 * a02 + a12 * a12
    q = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p = np.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * off) / 6.0)
    if off == 0.0 or p < 1e-150:  # diagonal: its own eigenvalues, in order (ties: diagonal order)
        _diagonal_into(a00 * big, a11 * big, a22 * big, w, v)
        return
    c00 = b11 * b22 - a12 * a12
    c01 = a01 * b22 - a12 * a02
    c02 = a01 * a12 - b11 * a02
    half_det = (b00 * c00 - a01 * c01 + a02 * c02) / (2.0 * p * p * p)
    half_det = min(max(half_det, -1.0), 1.0)
    phi = np.arccos(half_det) / 3.0
    beta2 = 2.0 * np.cos(phi)
    beta0 = 2.0 * np.cos(phi + 2.0943951023931953)  # + 2 pi / 3
    beta1 = -(beta0 + beta2)
    l0, l1, l2 = q + p * beta0, q + p * beta1, q + p * beta2  # ascending: beta0 <= beta1 <= beta2
    if half_det >= 0.0:  # the largest is the lone one: its vector first
        e2x, e2y, e2z = _null_vector(a00 - l2, a01, a02, a11 - l2, a12, a22 - l2)
        e0x, e0y, e0z = _second_vector(a00, a01, a02, a11, a12, a22, e2x, e2y, e2z)  # the smaller of the other two
        e1x, e1y, e1z = e2y * e0z - e2z * e0y, e2z * e0x - e2x * e0z, e2x * e0y - e2y * e0x
    else:  # the smallest (a plane's normal)
        e0x, e0y, e0z = _null_vector(a00 - l0, a01, a02, a11 - l0, a12, a22 - l0)
        e1x, e1y, e1z = _second_vector(a00, a01, a02, a11, a12, a22, e0x, e0y, e0z)  # the smaller of the other two
        e2x, e2y, e2z = e0y * e1z - e0z * e1y, e0z * e1x - e0x * e1z, e0x * e1y - e0y * e1x
    # each eigenvalue again as its vector's Rayleigh quotient: the cubic's roots lose half the digits where two are
    # close (arccos near -1 or 1), the quotients of accurate vectors do not (kept in order)
    l0 = _quotient(a00, a01, a02, a11, a12, a22, e0x, e0y, e0z)
    l1 = max(_quotient(a00, a01, a02, a11, a12, a22, e1x, e1y, e1z), l0)
    l2 = max(_quotient(a00, a01, a02, a11, a12, a22, e2x, e2y, e2z), l1)
    w[0], w[1], w[2] = l0 * big, l1 * big, l2 * big
    v[0, 0], v[1, 0], v[2, 0] = e0x, e0y, e0z
    v[0, 1], v[1, 1], v[2, 1] = e1x, e1y, e1z
    v[0, 2], v[1, 2], v[2, 2] = e2x, e2y, e2z


@njit(cache=True, nogil=True)
def _quotient(a00, a01, a02, a11, a12, a22, x, y, z):
    """x^T A x for the symmetric A of upper triangle ``a..`` and a unit vector x."""
    return (a00 * x * x + a11 * y * y + a22 * z * z) + 2.0 * (a01 * x * y + a02 * x * z + a12 * y * z)


@njit(cache=True, nogil=True)
def _diagonal_into(d0, d1, d2, w, v):
    """Eigen-decomposition of diag(d0, d1, d2): ascending, ties in diagonal order."""
    i0, i1, i2 = 0, 1, 2
    if d1 < d0:
        i0, i1, d0, d1 = i1, i0, d1, d0
    if d2 < d1:
        i1, i2, d1, d2 = i2, i1, d2, d1
        if d1 < d0:
            i0, i1, d0, d1 = i1, i0, d1, d0
    w[0], w[1], w[2] = d0, d1, d2
    for r in range(3):
        v[r, 0] = 1.0 if r == i0 else 0.0
        v[r, 1] = 1.0 if r == i1 else 0.0
        v[r, 2] = 1.0 if r == i2 else 0.0


@njit(cache=True, nogil=True)
def _null_vector(m00, m01, m02, m11, m12, m22):
    """Unit vector of the null space of the symmetric rank-2 matrix M: the longest cross product of two of its rows."""
    x0, y0, z0 = m01 * m12 - m02 * m11, m02 * m01 - m00 * m12, m00 * m11 - m01 * m01  # row0 x row1
    x1, y1, z1 = m01 * m22 - m02 * m12, m02 * m02 - m00 * m22, m00 * m12 - m01 * m02  # row0 x row2
    x2, y2, z2 = m11 * m22 - m12 * m12, m12 * m02 - m01 * m22, m01 * m12 - m11 * m02  # row1 x row2
    d0, d1, d2 = x0 * x0 + y0 * y0 + z0 * z0, x1 * x1 + y1 * y1 + z1 * z1, x2 * x2 + y2 * y2 + z2 * z2
    if d0 >= d1 and d0 >= d2:
        s = 1.0 / np.sqrt(d0)
        return x0 * s, y0 * s, z0 * s
    if d1 >= d2:
        s = 1.0 / np.sqrt(d1)
        return x1 * s, y1 * s, z1 * s
    s = 1.0 / np.sqrt(d2)
    return x2 * s, y2 * s, z2 * s


@njit(cache=True, nogil=True)
def _second_vector(a00, a01, a02, a11, a12, a22, ex, ey, ez):
    """Of the two unit eigenvectors orthogonal to the unit eigenvector ``e``, the one of the smaller eigenvalue: A
    restricted to the plane orthogonal to ``e`` is a 2 x 2 symmetric matrix, diagonalised by one rotation (exact to
    rounding, whatever the gap between its two eigenvalues)."""
    if abs(ex) > abs(ey):  # (u, v): an orthonormal basis of the plane orthogonal to e
        s = 1.0 / np.sqrt(ex * ex + ez * ez)
        ux, uy, uz = -ez * s, 0.0, ex * s
    else:
        s = 1.0 / np.sqrt(ey * ey + ez * ez)
        ux, uy, uz = 0.0, ez * s, -ey * s
    vx, vy, vz = ey * uz - ez * uy, ez * ux - ex * uz, ex * uy - ey * ux
    avx, avy, avz = a00 * vx + a01 * vy + a02 * vz, a01 * vx + a11 * vy + a12 * vz, a02 * vx + a12 * vy + a22 * vz
    m00 = _quotient(a00, a01, a02, a11, a12, a22, ux, uy, uz)
    m01 = ux * avx + uy * avy + uz * avz
    m11 = vx * avx + vy * avy + vz * avz
    if m01 == 0.0:  # diagonal already
        return (ux, uy, uz) if m00 <= m11 else (vx, vy, vz)
    # one Jacobi rotation: (c, -s) has eigenvalue m00 - t m01, (s, c) has m11 + t m01
    tau = (m11 - m00) / (2.0 * m01)
    t = (1.0 if tau >= 0.0 else -1.0) / (abs(tau) + np.sqrt(1.0 + tau * tau))
    c = 1.0 / np.sqrt(1.0 + t * t)
    sn = t * c
    if m00 - t * m01 <= m11 + t * m01:
        return c * ux - sn * vx, c * uy - sn * vy, c * uz - sn * vz
    return sn * ux + c * vx, sn * uy + c * vy, sn * uz + c * vz


@parallel_kernel
def knn_pca(points, query, nb, normals, sigma3, k1s, k2s, dir1):
    """PCA normal, surface variation and quadric curvatures of k-neighbourhoods.

    For query ``m`` (point ``query[m]``, neighbours ``nb[m]``): the PCA frame of
    the neighbours (e3 made to point along (0.001, 0.01, 1)), the quadric
    ``w = S(u, v)`` fitted to them in that frame, and the curvatures of that
    quadric at the query point (the numpy functions of :mod:`.quadric`
    give the same curvatures for the same frame and coefficients).
    """
    M, k = nb.shape
    for m in prange(M):
        c = np.zeros(3)
        for j in range(k):
            for a in range(3):
                c[a] += points[nb[m, j], a]
        c /= k
        cov = np.zeros((3, 3))
        for j in range(k):
            for a in range(3):
                da = points[nb[m, j], a] - c[a]
                for b in range(3):
                    cov[a, b] += da * (points[nb[m, j], b] - c[b])
        cov /= k
        w, v = eigh3(cov)
        tot = w[0] + w[1] + w[2]
        sigma3[m] = max(w[0], 0.0) / tot if tot > 0 else 0.0
        frame = np.empty((1, 3, 3))
        e3 = _plane_normal(v)
        e1 = v[:, 2].copy()
        e2 = np.array([e3[1] * e1[2] - e3[2] * e1[1], e3[2] * e1[0] - e3[0] * e1[2], e3[0] * e1[1] - e3[1] * e1[0]])
        for a in range(3):
            frame[0, a, 0], frame[0, a, 1], frame[0, a, 2] = e1[a], e2[a], e3[a]
        normals[m, 0], normals[m, 1], normals[m, 2] = e3[0], e3[1], e3[2]
        # quadric in the PCA frame, scaled by the neighbourhood's extent
        s = np.sqrt(max(w[2], 1e-300))
        G = np.zeros((6, 6))
        rhs = np.zeros(6)
        phi = np.empty(6)
        for j in range(k):
            dx = points[nb[m, j], 0] - c[0]
            dy = points[nb[m, j], 1] - c[1]
            dz = points[nb[m, j], 2] - c[2]
            u = (e1[0] * dx + e1[1] * dy + e1[2] * dz) / s
            vv = (e2[0] * dx + e2[1] * dy + e2[2] * dz) / s
            ww = (e3[0] * dx + e3[1] * dy + e3[2] * dz) / s
            phi[0], phi[1], phi[2], phi[3], phi[4], phi[5] = u * u, u * vv, vv * vv, u, vv, 1.0
            for a in range(6):
                rhs[a] += phi[a] * ww
                for b in range(6):
                    G[a, b] += phi[a] * phi[b]
        tr = 0.0
        for a in range(6):
            tr += G[a, a]
        for a in range(6):
            G[a, a] += 1e-8 * tr / 6.0 + 1e-300
        beta = cholesky_solve6(G, rhs)
        coeffs = np.empty((1, 6))
        coeffs[0, 0], coeffs[0, 1], coeffs[0, 2] = beta[0] / s, beta[1] / s, beta[2] / s
        coeffs[0, 3], coeffs[0, 4], coeffs[0, 5] = beta[3], beta[4], beta[5] * s
        i = query[m]
        dx = points[i, 0] - c[0]
        dy = points[i, 1] - c[1]
        dz = points[i, 2] - c[2]
        u = e1[0] * dx + e1[1] * dy + e1[2] * dz
        vv = e2[0] * dx + e2[1] * dy + e2[2] * dz
        su = 2.0 * coeffs[0, 0] * u + coeffs[0, 1] * vv + coeffs[0, 3]
        sv = coeffs[0, 1] * u + 2.0 * coeffs[0, 2] * vv + coeffs[0, 4]
        k1, k2, E, F, G_, L, M_, N = _curvatures(su, sv, 0, coeffs)
        k1s[m], k2s[m] = k1, k2
        dir1[m, 0], dir1[m, 1], dir1[m, 2] = _k1_direction(su, sv, k1, E, F, G_, L, M_, N, 0, frame)


@njit(cache=True, nogil=True)
def bounds(points):
    """Per-axis minimum and maximum of finite points, and whether all are finite."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    finite = True
    for i in range(points.shape[0]):
        for a in range(3):
            v = points[i, a]
            if not np.isfinite(v):
                finite = False
            else:
                if v < lo[a]:
                    lo[a] = v
                if v > hi[a]:
                    hi[a] = v
    return lo, hi, finite


@parallel_kernel
def morton_keys(points, corner, edge, q, keys):
    """Integer coordinates at depth 21 and Morton keys of ``points - corner`` in a cube of ``edge``.

    Mirrors :func:`patchcloud.core.morton.quantize` and :func:`~patchcloud.core.morton.encode`.
    """
    n = 1 << _MAX_DEPTH
    scale = n / edge
    for i in prange(points.shape[0]):
        key = np.uint64(0)
        for a in range(3):
            c = np.int64(np.floor((points[i, a] - corner[a]) * scale))
            if c < 0:
                c = 0
            elif c > n - 1:
                c = n - 1
            q[i, a] = c
            key |= _spread(np.uint64(c)) << np.uint64(a)
        keys[i] = key


@parallel_kernel
def unsort_outputs(order, normals, scalars, dir1, method, patch, o_normals, o_curv, o_k1, o_k2, o_dir1, o_method, o_patch):
    """Per-point results from sorted order back to input order (``out[order[i]] = value[i]``)."""
    for i in prange(order.shape[0]):
        j = order[i]
        for a in range(3):
            o_normals[j, a] = normals[i, a]
            o_dir1[j, a] = dir1[i, a]
        o_curv[j] = scalars[i, 0]
        o_k1[j] = scalars[i, 1]
        o_k2[j] = scalars[i, 2]
        o_method[j] = method[i]
        o_patch[j] = patch[i]


@parallel_kernel
def take_rows(values, order):
    """``values[order]`` for a 2-D array, in parallel."""
    out = np.empty((order.shape[0], values.shape[1]), dtype=values.dtype)
    for i in prange(order.shape[0]):
        for j in range(values.shape[1]):
            out[i, j] = values[order[i], j]
    return out


@parallel_kernel
def neighbour_signs(nrm, nb, normals, oriented, sign):
    """Sign that turns each query normal ``nrm[m]`` towards the sum of its oriented neighbours' normals.

    ``nb[m]`` are the rows of ``normals`` next to query ``m``; ``sign[m]`` is
    +1/-1 where at least one of them is ``oriented`` (and their sum is not
    zero), 0 otherwise.
    """
    for m in prange(nrm.shape[0]):
        sign[m] = 0.0
        rx, ry, rz = 0.0, 0.0, 0.0
        for j in range(nb.shape[1]):
            o = nb[m, j]
            if oriented[o]:
                rx += normals[o, 0]
                ry += normals[o, 1]
                rz += normals[o, 2]
        if rx * rx + ry * ry + rz * rz > 0.0:
            dot = nrm[m, 0] * rx + nrm[m, 1] * ry + nrm[m, 2] * rz
            sign[m] = -1.0 if dot < 0.0 else 1.0


@njit(cache=True, nogil=True)
def _bit_length(x):
    """Number of bits of the uint64 ``x`` (0 for 0): six halvings, not a loop over the bits."""
    n = 0
    if x >> np.uint64(32) != 0:
        x >>= np.uint64(32)
        n += 32
    if x >> np.uint64(16) != 0:
        x >>= np.uint64(16)
        n += 16
    if x >> np.uint64(8) != 0:
        x >>= np.uint64(8)
        n += 8
    if x >> np.uint64(4) != 0:
        x >>= np.uint64(4)
        n += 4
    if x >> np.uint64(2) != 0:
        x >>= np.uint64(2)
        n += 2
    if x >> np.uint64(1) != 0:
        x >>= np.uint64(1)
        n += 1
    return n + 1 if x != 0 else n


@njit(cache=True, nogil=True)
def first_split_levels(keys, depth, counts):
    """``counts[l]``: how many neighbours in the sorted Morton ``keys`` (``depth`` levels) first differ at level ``l``.

    Two keys first differ at level ``depth - t``, where ``t`` is the 3-bit
    group of their highest differing bit (level 0 for a group beyond ``depth``).
    """
    for i in range(1, keys.shape[0]):
        x = keys[i] ^ keys[i - 1]
        if x == 0:
            continue
        counts[max(depth - (_bit_length(x) - 1) // 3, 0)] += 1


@parallel_kernel
def hashed_cell_picks(points, origin, edge, hash3, stride, out):
    """``out[i]``: whether point ``i``'s cell ``c = floor((p + origin) / edge)`` has ``(c . hash3) mod stride == 0``."""
    for i in prange(points.shape[0]):
        h = 0
        for a in range(3):
            h += np.int64(np.floor((points[i, a] + origin[a]) / edge)) * hash3[a]
        out[i] = h % stride == 0


@parallel_kernel
def summed_votes(votes, idx, total):
    """``total[m]``: the sum of ``votes[idx[m, j]]`` over the ``j`` where ``idx[m, j] >= 0``, in order of ``j``."""
    for m in prange(idx.shape[0]):
        tx, ty, tz = 0.0, 0.0, 0.0
        for j in range(idx.shape[1]):
            o = idx[m, j]
            if o >= 0:
                tx += votes[o, 0]
                ty += votes[o, 1]
                tz += votes[o, 2]
        total[m, 0], total[m, 1], total[m, 2] = tx, ty, tz


@parallel_kernel
def shift_to_parents(moments, gstart, octant, coef, out):
    """Sum children's moments into their parents, each shifted to the parent centre.

    ``out[p] = sum over children c of p of S[octant[c]] @ moments[c]`` where
    the shift matrices ``S[o]`` are given by their non-zero entries
    ``S[o][rows[t], cols[t]] = coef[o, t]``, ``rows, cols, coef =``
    :func:`.moments.shift_entries` (see :func:`.moments.shift_matrices`);
    children of parent ``p`` are ``gstart[p]:gstart[p + 1]``.  The 210
    entries are written out (in ``shift_entries``' order, so each sum adds the
    same terms in the same order as a loop over them: the same bits, tested),
    which keeps the 35 sums in registers: 3-4 times faster than the loop.
    """
    P = gstart.shape[0]
    n = moments.shape[0]
    for p in prange(P):
        hi = gstart[p + 1] if p + 1 < P else n
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        a3 = 0.0
        a4 = 0.0
        a5 = 0.0
        a6 = 0.0
        a7 = 0.0
        a8 = 0.0
        a9 = 0.0
        a10 = 0.0
        a11 = 0.0
        a12 = 0.0
        a13 = 0.0
        a14 = 0.0
        a15 = 0.0
        a16 = 0.0
        a17 = 0.0
        a18 = 0.0
        a19 = 0.0
        a20 = 0.0
        a21 = 0.0
        a22 = 0.0
        a23 = 0.0
        a24 = 0.0
        a25 = 0.0
        a26 = 0.0
        a27 = 0.0
        a28 = 0.0
        a29 = 0.0
        a30 = 0.0
        a31 = 0.0
        a32 = 0.0
        a33 = 0.0
        a34 = 0.0
        for c in range(gstart[p], hi):
            o = octant[c]
            m0 = moments[c, 0]
            m1 = moments[c, 1]
            m2 = moments[c, 2]
            m3 = moments[c, 3]
            m4 = moments[c, 4]
            m5 = moments[c, 5]
            m6 = moments[c, 6]
            m7 = moments[c, 7]
            m8 = moments[c, 8]
            m9 = moments[c, 9]
            m10 = moments[c, 10]
            m11 = moments[c, 11]
            m12 = moments[c, 12]
            m13 = moments[c, 13]
            m14 = moments[c, 14]
            m15 = moments[c, 15]
            m16 = moments[c, 16]
            m17 = moments[c, 17]
            m18 = moments[c, 18]
            m19 = moments[c, 19]
            m20 = moments[c, 20]
            m21 = moments[c, 21]
            m22 = moments[c, 22]
            m23 = moments[c, 23]
            m24 = moments[c, 24]
            m25 = moments[c, 25]
            m26 = moments[c, 26]
            m27 = moments[c, 27]
            m28 = moments[c, 28]
            m29 = moments[c, 29]
            m30 = moments[c, 30]
            m31 = moments[c, 31]
            m32 = moments[c, 32]
            m33 = moments[c, 33]
            m34 = moments[c, 34]
            a0 += coef[o, 0] * m0
            a1 += coef[o, 1] * m0
            a1 += coef[o, 2] * m1
            a2 += coef[o, 3] * m0
            a2 += coef[o, 4] * m2
            a3 += coef[o, 5] * m0
            a3 += coef[o, 6] * m3
            a4 += coef[o, 7] * m0
            a4 += coef[o, 8] * m1
            a4 += coef[o, 9] * m4
            a5 += coef[o, 10] * m0
            a5 += coef[o, 11] * m1
            a5 += coef[o, 12] * m2
            a5 += coef[o, 13] * m5
            a6 += coef[o, 14] * m0
            a6 += coef[o, 15] * m1
            a6 += coef[o, 16] * m3
            a6 += coef[o, 17] * m6
            a7 += coef[o, 18] * m0
            a7 += coef[o, 19] * m2
            a7 += coef[o, 20] * m7
            a8 += coef[o, 21] * m0
            a8 += coef[o, 22] * m2
            a8 += coef[o, 23] * m3
            a8 += coef[o, 24] * m8
            a9 += coef[o, 25] * m0
            a9 += coef[o, 26] * m3
            a9 += coef[o, 27] * m9
            a10 += coef[o, 28] * m0
            a10 += coef[o, 29] * m1
            a10 += coef[o, 30] * m4
            a10 += coef[o, 31] * m10
            a11 += coef[o, 32] * m0
            a11 += coef[o, 33] * m1
            a11 += coef[o, 34] * m2
            a11 += coef[o, 35] * m4
            a11 += coef[o, 36] * m5
            a11 += coef[o, 37] * m11
            a12 += coef[o, 38] * m0
            a12 += coef[o, 39] * m1
            a12 += coef[o, 40] * m3
            a12 += coef[o, 41] * m4
            a12 += coef[o, 42] * m6
            a12 += coef[o, 43] * m12
            a13 += coef[o, 44] * m0
            a13 += coef[o, 45] * m1
            a13 += coef[o, 46] * m2
            a13 += coef[o, 47] * m5
            a13 += coef[o, 48] * m7
            a13 += coef[o, 49] * m13
            a14 += coef[o, 50] * m0
            a14 += coef[o, 51] * m1
            a14 += coef[o, 52] * m2
            a14 += coef[o, 53] * m3
            a14 += coef[o, 54] * m5
            a14 += coef[o, 55] * m6
            a14 += coef[o, 56] * m8
            a14 += coef[o, 57] * m14
            a15 += coef[o, 58] * m0
            a15 += coef[o, 59] * m1
            a15 += coef[o, 60] * m3
            a15 += coef[o, 61] * m6
            a15 += coef[o, 62] * m9
            a15 += coef[o, 63] * m15
            a16 += coef[o, 64] * m0
            a16 += coef[o, 65] * m2
            a16 += coef[o, 66] * m7
            a16 += coef[o, 67] * m16
            a17 += coef[o, 68] * m0
            a17 += coef[o, 69] * m2
            a17 += coef[o, 70] * m3
            a17 += coef[o, 71] * m7
            a17 += coef[o, 72] * m8
            a17 += coef[o, 73] * m17
            a18 += coef[o, 74] * m0
            a18 += coef[o, 75] * m2
            a18 += coef[o, 76] * m3
            a18 += coef[o, 77] * m8
            a18 += coef[o, 78] * m9
            a18 += coef[o, 79] * m18
            a19 += coef[o, 80] * m0
            a19 += coef[o, 81] * m3
            a19 += coef[o, 82] * m9
            a19 += coef[o, 83] * m19
            a20 += coef[o, 84] * m0
            a20 += coef[o, 85] * m1
            a20 += coef[o, 86] * m4
            a20 += coef[o, 87] * m10
            a20 += coef[o, 88] * m20
            a21 += coef[o, 89] * m0
            a21 += coef[o, 90] * m1
            a21 += coef[o, 91] * m2
            a21 += coef[o, 92] * m4
            a21 += coef[o, 93] * m5
            a21 += coef[o, 94] * m10
            a21 += coef[o, 95] * m11
            a21 += coef[o, 96] * m21
            a22 += coef[o, 97] * m0
            a22 += coef[o, 98] * m1
            a22 += coef[o, 99] * m3
            a22 += coef[o, 100] * m4
            a22 += coef[o, 101] * m6
            a22 += coef[o, 102] * m10
            a22 += coef[o, 103] * m12
            a22 += coef[o, 104] * m22
            a23 += coef[o, 105] * m0
            a23 += coef[o, 106] * m1
            a23 += coef[o, 107] * m2
            a23 += coef[o, 108] * m4
            a23 += coef[o, 109] * m5
            a23 += coef[o, 110] * m7
            a23 += coef[o, 111] * m11
            a23 += coef[o, 112] * m13
            a23 += coef[o, 113] * m23
            a24 += coef[o, 114] * m0
            a24 += coef[o, 115] * m1
            a24 += coef[o, 116] * m2
            a24 += coef[o, 117] * m3
            a24 += coef[o, 118] * m4
            a24 += coef[o, 119] * m5
            a24 += coef[o, 120] * m6
            a24 += coef[o, 121] * m8
            a24 += coef[o, 122] * m11
            a24 += coef[o, 123] * m12
            a24 += coef[o, 124] * m14
            a24 += coef[o, 125] * m24
            a25 += coef[o, 126] * m0
            a25 += coef[o, 127] * m1
            a25 += coef[o, 128] * m3
            a25 += coef[o, 129] * m4
            a25 += coef[o, 130] * m6
            a25 += coef[o, 131] * m9
            a25 += coef[o, 132] * m12
            a25 += coef[o, 133] * m15
            a25 += coef[o, 134] * m25
            a26 += coef[o, 135] * m0
            a26 += coef[o, 136] * m1
            a26 += coef[o, 137] * m2
            a26 += coef[o, 138] * m5
            a26 += coef[o, 139] * m7
            a26 += coef[o, 140] * m13
            a26 += coef[o, 141] * m16
            a26 += coef[o, 142] * m26
            a27 += coef[o, 143] * m0
            a27 += coef[o, 144] * m1
            a27 += coef[o, 145] * m2
            a27 += coef[o, 146] * m3
            a27 += coef[o, 147] * m5
            a27 += coef[o, 148] * m6
            a27 += coef[o, 149] * m7
            a27 += coef[o, 150] * m8
            a27 += coef[o, 151] * m13
            a27 += coef[o, 152] * m14
            a27 += coef[o, 153] * m17
            a27 += coef[o, 154] * m27
            a28 += coef[o, 155] * m0
            a28 += coef[o, 156] * m1
            a28 += coef[o, 157] * m2
            a28 += coef[o, 158] * m3
            a28 += coef[o, 159] * m5
            a28 += coef[o, 160] * m6
            a28 += coef[o, 161] * m8
            a28 += coef[o, 162] * m9
            a28 += coef[o, 163] * m14
            a28 += coef[o, 164] * m15
            a28 += coef[o, 165] * m18
            a28 += coef[o, 166] * m28
            a29 += coef[o, 167] * m0
            a29 += coef[o, 168] * m1
            a29 += coef[o, 169] * m3
            a29 += coef[o, 170] * m6
            a29 += coef[o, 171] * m9
            a29 += coef[o, 172] * m15
            a29 += coef[o, 173] * m19
            a29 += coef[o, 174] * m29
            a30 += coef[o, 175] * m0
            a30 += coef[o, 176] * m2
            a30 += coef[o, 177] * m7
            a30 += coef[o, 178] * m16
            a30 += coef[o, 179] * m30
            a31 += coef[o, 180] * m0
            a31 += coef[o, 181] * m2
            a31 += coef[o, 182] * m3
            a31 += coef[o, 183] * m7
            a31 += coef[o, 184] * m8
            a31 += coef[o, 185] * m16
            a31 += coef[o, 186] * m17
            a31 += coef[o, 187] * m31
            a32 += coef[o, 188] * m0
            a32 += coef[o, 189] * m2
            a32 += coef[o, 190] * m3
            a32 += coef[o, 191] * m7
            a32 += coef[o, 192] * m8
            a32 += coef[o, 193] * m9
            a32 += coef[o, 194] * m17
            a32 += coef[o, 195] * m18
            a32 += coef[o, 196] * m32
            a33 += coef[o, 197] * m0
            a33 += coef[o, 198] * m2
            a33 += coef[o, 199] * m3
            a33 += coef[o, 200] * m8
            a33 += coef[o, 201] * m9
            a33 += coef[o, 202] * m18
            a33 += coef[o, 203] * m19
            a33 += coef[o, 204] * m33
            a34 += coef[o, 205] * m0
            a34 += coef[o, 206] * m3
            a34 += coef[o, 207] * m9
            a34 += coef[o, 208] * m19
            a34 += coef[o, 209] * m34
        out[p, 0] = a0
        out[p, 1] = a1
        out[p, 2] = a2
        out[p, 3] = a3
        out[p, 4] = a4
        out[p, 5] = a5
        out[p, 6] = a6
        out[p, 7] = a7
        out[p, 8] = a8
        out[p, 9] = a9
        out[p, 10] = a10
        out[p, 11] = a11
        out[p, 12] = a12
        out[p, 13] = a13
        out[p, 14] = a14
        out[p, 15] = a15
        out[p, 16] = a16
        out[p, 17] = a17
        out[p, 18] = a18
        out[p, 19] = a19
        out[p, 20] = a20
        out[p, 21] = a21
        out[p, 22] = a22
        out[p, 23] = a23
        out[p, 24] = a24
        out[p, 25] = a25
        out[p, 26] = a26
        out[p, 27] = a27
        out[p, 28] = a28
        out[p, 29] = a29
        out[p, 30] = a30
        out[p, 31] = a31
        out[p, 32] = a32
        out[p, 33] = a33
        out[p, 34] = a34


@parallel_kernel
def box_cell_keys(points, edge, lo, span, keys):
    """Key of each point's cell of edge ``edge`` (anchored at the origin) in the box of cells ``lo`` to ``lo + span - 1``: ``-1`` outside.

    A cell ``c`` (integer coordinates) has key ``((c - lo) . (span1 span2, span2, 1))``.
    """
    for i in prange(points.shape[0]):
        c0 = int(np.floor(points[i, 0] / edge)) - lo[0]
        c1 = int(np.floor(points[i, 1] / edge)) - lo[1]
        c2 = int(np.floor(points[i, 2] / edge)) - lo[2]
        if 0 <= c0 < span[0] and 0 <= c1 < span[1] and 0 <= c2 < span[2]:
            keys[i] = (c0 * span[1] + c1) * span[2] + c2
        else:
            keys[i] = -1


@njit(cache=True, nogil=True)
def rows_where(where, values):
    """``values[:M][where]`` for (N, 3) ``values`` and an (M,) bool ``where``, M <= N, in one compiled pass (numpy's
    boolean or fancy indexing of an (N, 3) array is several times slower)."""
    m = 0
    for i in range(where.shape[0]):
        if where[i]:
            m += 1
    out = np.empty((m, 3), dtype=values.dtype)
    j = 0
    for i in range(where.shape[0]):
        if where[i]:
            out[j, 0], out[j, 1], out[j, 2] = values[i, 0], values[i, 1], values[i, 2]
            j += 1
    return out


@njit(cache=True, nogil=True)
def run_starts(keys, shift=0):
    """Index of the first row of each run of equal ``keys >> shift`` in the sorted integer ``keys`` (empty for no keys):
    with a shift, the runs of the cells that hold Morton keys, without the shifted copy."""
    n = keys.shape[0]
    runs = 0
    for i in range(n):
        if i == 0 or (keys[i] >> shift) != (keys[i - 1] >> shift):
            runs += 1
    out = np.empty(runs, dtype=np.int64)
    r = 0
    for i in range(n):
        if i == 0 or (keys[i] >> shift) != (keys[i - 1] >> shift):
            out[r] = i
            r += 1
    return out


@parallel_kernel
def box_cell_stats(points, votes, voters, rows, starts, ckeys, edge, lo, span, cmom, cvotes):
    """Second-order moments and summed vectors of the cells of :func:`box_cell_keys`, points gathered by ``rows``.

    Cell ``c`` holds ``points[rows[starts[c]:starts[c + 1]]]`` and has key
    ``ckeys[c]``; ``cmom[c]`` gets the count, first and second moments
    about the cell's centre (the first 10 columns of :func:`cell_moments`,
    the same sums in the same order), ``cvotes[c]`` the sum of
    ``votes`` over the same rows where ``voters``, in the same order (the
    sum of ``where(voters, votes, 0)`` bit for bit: a zero added changes
    no sum).
    """
    C = starts.shape[0]
    n = rows.shape[0]
    s12 = span[1] * span[2]
    for c in prange(C):
        hi = starts[c + 1] if c + 1 < C else n
        key = ckeys[c]
        cx = (np.float64(key // s12 + lo[0]) + 0.5) * edge
        cy = (np.float64((key // span[2]) % span[1] + lo[1]) + 0.5) * edge
        cz = (np.float64(key % span[2] + lo[2]) + 0.5) * edge
        a0 = a1 = a2 = a3 = a4 = a5 = a6 = a7 = a8 = a9 = 0.0  # count, first moments, second moments
        v0 = v1 = v2 = 0.0
        for i in range(starts[c], hi):
            r = rows[i]
            x = points[r, 0] - cx
            y = points[r, 1] - cy
            z = points[r, 2] - cz
            a0 += 1.0
            a1 += x
            a2 += y
            a3 += z
            a4 += x * x
            a5 += x * y
            a6 += x * z
            a7 += y * y
            a8 += y * z
            a9 += z * z
            if voters[r]:
                v0 += votes[r, 0]
                v1 += votes[r, 1]
                v2 += votes[r, 2]
        cmom[c, 0] = a0
        cmom[c, 1] = a1
        cmom[c, 2] = a2
        cmom[c, 3] = a3
        cmom[c, 4] = a4
        cmom[c, 5] = a5
        cmom[c, 6] = a6
        cmom[c, 7] = a7
        cmom[c, 8] = a8
        cmom[c, 9] = a9
        cvotes[c, 0] = v0
        cvotes[c, 1] = v1
        cvotes[c, 2] = v2


@njit(cache=True, nogil=True)
def _cells_at(ckeys, c0, c1, c2, span, at):
    """Rows in the sorted ``ckeys`` of the 8 cells ``(c0, c1, c2) + (o & 1, o >> 1 & 1, o >> 2 & 1)`` (-1 where absent).

    The cells are relative to ``lo`` (:func:`interpolated_pca`); two cells
    one apart along the last axis have consecutive keys, so 4 searches find 8.
    """
    C = ckeys.shape[0]
    for o in range(4):
        key = ((c0 + (o & 1)) * span[1] + (c1 + (o >> 1))) * span[2] + c2
        pos = lower_bound(ckeys, key)
        at[o] = pos if pos < C and ckeys[pos] == key else -1
        nxt = pos + 1 if at[o] >= 0 else pos  # where key + 1 is, if anywhere
        at[o + 4] = nxt if nxt < C and ckeys[nxt] == key + 1 else -1


@parallel_kernel
def interpolated_pca(queries, h, lo, span, ckeys, cmom, cvotes, normals, sigma2, sigma3, dir1, votes, count):
    """PCA of cell moments interpolated at each query point (:mod:`patchcloud.core.moment_normals`).

    The cells have edge ``h`` and are anchored at the origin; cell ``c``
    (integer coordinates) has key ``((c - lo) . (span1 span2, span2, 1))``
    in the sorted ``ckeys``, moments ``cmom`` (count, the 3 first and the 6
    second moments about its centre, in the order of
    :data:`patchcloud.core.moments.EXPONENTS`) and summed votes ``cvotes``.
    For query ``m`` the 8 cells whose centres surround it weigh trilinearly;
    their moments, moved to the corner their centres share (once for the
    queries that share the 8 cells), are summed with these weights; the
    covariance does not depend on the point the moments are taken about.
    Writes the PCA normal (e3 made to point along (0.001, 0.01, 1)),
    ``lambda2 / sum`` and ``lambda3 / sum``, the first axis, the weighted
    votes and the points of the cells of non-zero weight.
    """
    M = queries.shape[0]
    chunks = (M + CHUNK - 1) // CHUNK
    for chunk in prange(chunks):  # scratch allocated once per chunk of queries, not once per query
        s = np.empty(3)
        Q = np.empty(6)  # (xx, xy, xz, yy, yz, zz)
        v = np.empty(3)
        cov = np.empty((3, 3))
        ev = np.empty(3)
        vec = np.empty((3, 3))
        at = np.empty(8, dtype=np.int64)  # the 8 cells' rows in ckeys (-1: empty), kept while the base cell stays
        # the 8 cells' moments about the corner their centres share, (b + 1) h: count, first, second (as Q)
        cn = np.zeros(8)
        cs = np.zeros((8, 3))
        cq = np.zeros((8, 6))
        p0, p1, p2 = np.inf, np.inf, np.inf
        for m in range(chunk * CHUNK, min(M, (chunk + 1) * CHUNK)):
            f0 = queries[m, 0] / h - 0.5
            f1 = queries[m, 1] / h - 0.5
            f2 = queries[m, 2] / h - 0.5
            b0, b1, b2 = np.floor(f0), np.floor(f1), np.floor(f2)
            t0, t1, t2 = f0 - b0, f1 - b1, f2 - b2
            if b0 != p0 or b1 != p1 or b2 != p2:  # queries come in space order: most share the last one's cells
                p0, p1, p2 = b0, b1, b2
                _cells_at(ckeys, int(b0) - lo[0], int(b1) - lo[1], int(b2) - lo[2], span, at)
                for o in range(8):  # a cell's moments about its centre c, moved to the corner: p - corner = (p - c) + d
                    pos = at[o]
                    if pos < 0:
                        continue
                    d0 = ((o & 1) - 0.5) * h
                    d1 = (((o >> 1) & 1) - 0.5) * h
                    d2 = (((o >> 2) & 1) - 0.5) * h
                    n = cmom[pos, 0]
                    x, y, z = cmom[pos, 1], cmom[pos, 2], cmom[pos, 3]
                    cn[o] = n
                    cs[o, 0], cs[o, 1], cs[o, 2] = x + n * d0, y + n * d1, z + n * d2
                    cq[o, 0] = cmom[pos, 4] + 2.0 * d0 * x + n * d0 * d0
                    cq[o, 1] = cmom[pos, 5] + d0 * y + x * d1 + n * d0 * d1
                    cq[o, 2] = cmom[pos, 6] + d0 * z + x * d2 + n * d0 * d2
                    cq[o, 3] = cmom[pos, 7] + 2.0 * d1 * y + n * d1 * d1
                    cq[o, 4] = cmom[pos, 8] + d1 * z + y * d2 + n * d1 * d2
                    cq[o, 5] = cmom[pos, 9] + 2.0 * d2 * z + n * d2 * d2
            W = 0.0
            for a in range(3):
                s[a] = 0.0
                v[a] = 0.0
            for a in range(6):
                Q[a] = 0.0
            n_all = 0.0
            for o in range(8):
                pos = at[o]
                if pos < 0:
                    continue
                w = (t0 if o & 1 else 1.0 - t0) * (t1 if (o >> 1) & 1 else 1.0 - t1) * (t2 if (o >> 2) & 1 else 1.0 - t2)
                if w <= 0.0:
                    continue
                n_all += cn[o]
                W += w * cn[o]
                for a in range(3):
                    s[a] += w * cs[o, a]
                    v[a] += w * cvotes[pos, a]
                for a in range(6):
                    Q[a] += w * cq[o, a]
            count[m] = n_all
            votes[m, 0], votes[m, 1], votes[m, 2] = v[0], v[1], v[2]
            if W <= 0.0:
                normals[m, 0], normals[m, 1], normals[m, 2] = 0.0, 0.0, 0.0
                sigma2[m] = 0.0
                sigma3[m] = 0.0
                dir1[m, 0], dir1[m, 1], dir1[m, 2] = 0.0, 0.0, 0.0
                continue
            # the covariance does not depend on the point the moments are taken about
            mx, my, mz = s[0] / W, s[1] / W, s[2] / W
            cov[0, 0] = Q[0] / W - mx * mx
            cov[0, 1] = Q[1] / W - mx * my
            cov[0, 2] = Q[2] / W - mx * mz
            cov[1, 1] = Q[3] / W - my * my
            cov[1, 2] = Q[4] / W - my * mz
            cov[2, 2] = Q[5] / W - mz * mz
            eigh3_into(cov, ev, vec)
            l0, l1, l2 = max(ev[0], 0.0), max(ev[1], 0.0), max(ev[2], 0.0)
            tot = l0 + l1 + l2
            sigma3[m] = l0 / tot if tot > 0 else 0.0
            sigma2[m] = l1 / tot if tot > ROUNDING_SPREAD * h * h else 0.0  # coincident points: no shape
            sgn = _plane_sign(vec)
            normals[m, 0], normals[m, 1], normals[m, 2] = sgn * vec[0, 0], sgn * vec[1, 0], sgn * vec[2, 0]
            dir1[m, 0], dir1[m, 1], dir1[m, 2] = vec[0, 2], vec[1, 2], vec[2, 2]


@njit(cache=True, nogil=True)
def _face_step(k, axis, o1, upper, gs, gt, h):
    """What a face sample adds to coordinate ``k`` of its cube's low corner: the face's offset, or a grid step."""
    if k == axis:
        return upper * h
    if k == o1:
        return gs * h
    return gt * h


@parallel_kernel
def face_votes(lower, edge, a_centroid, a_frames, a_coeffs, a_rmse, i, b_centroid, b_frames, b_coeffs, b_rmse, j, d, g, out):
    """:func:`patchcloud.core.orient.face_agreement` of the pairs ``(i[e], j[e])``, written to ``out[e]``.

    The face ``d[e]`` of leaf ``i[e]`` (cube ``lower``, ``edge``) is sampled
    at ``g[s] x g[t]``; each side's patch is ``centroid``, ``frames``,
    ``coeffs`` and ``rmse`` at its row.  The same operations in the same
    order as the numpy version, so the same values bit for bit.
    """
    m = g.shape[0]
    for e in prange(i.shape[0]):
        li, lj = i[e], j[e]
        axis = d[e] // 2
        upper = d[e] % 2
        h = edge[li]
        o1 = (axis + 1) % 3
        o2 = (axis + 2) % 3
        band = 2.0 * max(a_rmse[li], b_rmse[lj])
        reach = 0.5 * h
        votes = 0.0
        voters = 0
        for s in range(m):
            for t in range(m):
                px = lower[li, 0] + _face_step(0, axis, o1, upper, g[s], g[t], h)
                py = lower[li, 1] + _face_step(1, axis, o1, upper, g[s], g[t], h)
                pz = lower[li, 2] + _face_step(2, axis, o1, upper, g[s], g[t], h)
                ui, vi_, wi = _frame_coords(px, py, pz, li, a_centroid, a_frames)
                uj, vj_, wj = _frame_coords(px, py, pz, lj, b_centroid, b_frames)
                vi = wi - (a_coeffs[li, 0] * ui * ui + a_coeffs[li, 1] * ui * vi_ + a_coeffs[li, 2] * vi_ * vi_
                           + a_coeffs[li, 3] * ui + a_coeffs[li, 4] * vi_ + a_coeffs[li, 5])
                vj = wj - (b_coeffs[lj, 0] * uj * uj + b_coeffs[lj, 1] * uj * vj_ + b_coeffs[lj, 2] * vj_ * vj_
                           + b_coeffs[lj, 3] * uj + b_coeffs[lj, 4] * vj_ + b_coeffs[lj, 5])
                if not (abs(vi) > band and abs(vj) > band and abs(vi) <= reach and abs(vj) <= reach):
                    continue
                nix, niy, niz, _, _ = _normal_at(ui, vi_, li, a_frames, a_coeffs)
                njx, njy, njz, _, _ = _normal_at(uj, vj_, lj, b_frames, b_coeffs)
                dot = nix * njx + niy * njy + niz * njz
                same = (1.0 if vi > 0 else -1.0) * (1.0 if vj > 0 else -1.0)
                if abs(dot) > 0.5 and same == (1.0 if dot > 0 else -1.0):
                    votes += same
                    voters += 1
        out[e] = votes / max(voters, 4)


@parallel_kernel
def draw_on_patches(todo, k, r, occupied, cell_order, extent, patch, coeffs, centroid, frame, lo, edge, side, pts, outside):
    """One draw of :func:`patchcloud.core.patchmodel.sample_models` for the points ``todo``, written to ``pts[todo]``.

    Point ``t`` of cell ``k[t]`` takes the uniform numbers ``r[i]`` (i its
    row of ``todo``): ``r[i, 0]`` picks one of the cell's ``occupied``
    mask cells (``cell_order``: the occupied first), ``r[i, 1:]`` a place
    in it, within the cell's ``extent`` (u0, u1, v0, v1) of ``side`` x
    ``side`` mask cells; the place is lifted onto the patch's quadric and
    turned to the caller's frame.  ``outside[i]``: the point left its
    octree cell (corner ``lo``, ``edge``).  The same arithmetic, in the
    same order, as the numpy it replaces, but for the frame's sums, taken
    in axis order here (numpy's einsum took another: up to 1e-14 m apart,
    the same LAS integers on the files measured).
    """
    for i in prange(todo.shape[0]):
        t = todo[i]
        kk = k[t]
        pk = patch[kk]
        occ = occupied[kk]
        pick = min(np.int64(r[i, 0] * occ), max(occ - 1, 0))
        cell = cell_order[kk, pick]
        e0, e1, e2, e3 = extent[kk, 0], extent[kk, 1], extent[kk, 2], extent[kk, 3]
        u = e0 + (cell // side + r[i, 1]) * (e1 - e0) / side
        v = e2 + (cell % side + r[i, 2]) * (e3 - e2) / side
        c = coeffs[pk]
        w = c[0] * u * u + c[1] * u * v + c[2] * v * v + c[3] * u + c[4] * v + c[5]
        out = False
        for a in range(3):
            p = centroid[pk, a] + (frame[pk, a, 0] * u + frame[pk, a, 1] * v + frame[pk, a, 2] * w)
            pts[t, a] = p
            if p < lo[kk, a] or p > lo[kk, a] + edge[kk]:
                out = True
        outside[i] = out
