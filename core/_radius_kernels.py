"""Compiled loops behind radius normals and Euclidean clustering (numba).

Points reach these kernels sorted by cell and, inside a cell, by their
coordinates, so every sum runs in an order fixed by the coordinates alone:
the same points give bit-identical sums whatever their input order or the
tile they were read from.  The cell keys pack integer cell indices that are
already shifted to be non-negative (see :func:`patchcloud.core.grid.CellGrid`).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ._kernels import CHUNK, eigh3_into, lower_bound, upper_bound
from .forest import find_root
from .threads import parallel_kernel

__all__ = ["ball_moments", "build_row_table", "voxel_moments", "voxel_stats", "pca_normals", "union_cells"]


@njit(cache=True, nogil=True)
def _lookup(keys, key):
    """Index of ``key`` in the sorted array ``keys``, or -1."""
    i = lower_bound(keys, key)
    if i < keys.size and keys[i] == key:
        return i
    return -1


@njit(cache=True, nogil=True)
def _add_point(acc, dx, dy, dz):
    """Add one point's offset to the count and moments ``acc`` (layout of ball_moments_exact)."""
    acc[0] += 1.0
    acc[1] += dx
    acc[2] += dy
    acc[3] += dz
    acc[4] += dx * dx
    acc[5] += dx * dy
    acc[6] += dx * dz
    acc[7] += dy * dy
    acc[8] += dy * dz
    acc[9] += dz * dz


@parallel_kernel
def voxel_moments(points, cell_start, centres, out):
    """Count and moments of every voxel's points about the voxel's centre (layout as ball_moments_exact)."""
    C = cell_start.size - 1
    for h in prange(C):
        acc = np.zeros(10)
        cx, cy, cz = centres[h, 0], centres[h, 1], centres[h, 2]
        for p in range(cell_start[h], cell_start[h + 1]):
            dx = points[p, 0] - cx
            dy = points[p, 1] - cy
            dz = points[p, 2] - cz
            _add_point(acc, dx, dy, dz)
        for t in range(10):
            out[h, t] = acc[t]


_GOLDEN = np.uint64(11400714819323198485)


@njit(cache=True, nogil=True)
def _slot(key, bits):
    return np.int64((np.uint64(key) * _GOLDEN) >> np.uint64(64 - bits))


@njit(cache=True, nogil=True)
def build_row_table(row_keys, bits):
    """Open-addressing hash table (size 2**bits) from row key to row index; -1 marks a free slot."""
    size = 1 << bits
    keys = np.full(size, -1, dtype=np.int64)
    vals = np.empty(size, dtype=np.int64)
    for r in range(row_keys.size):
        h = _slot(row_keys[r], bits)
        while keys[h] != -1:
            h = (h + 1) & (size - 1)
        keys[h] = row_keys[r]
        vals[h] = r
    return keys, vals


@njit(cache=True, nogil=True)
def _row_of(table_keys, table_vals, bits, key):
    h = _slot(key, bits)
    size = table_keys.size
    while table_keys[h] != -1:
        if table_keys[h] == key:
            return table_vals[h]
        h = (h + 1) & (size - 1)
    return -1


@njit(cache=True, nogil=True)
def _add_voxel(acc, cell_moments, h, dx, dy, dz):
    """Add all of voxel ``h`` to ``acc``: its moments about its centre shifted to the query, the centre at (dx, dy, dz)."""
    n = cell_moments[h, 0]
    s1x, s1y, s1z = cell_moments[h, 1], cell_moments[h, 2], cell_moments[h, 3]
    acc[0] += n
    acc[1] += s1x + n * dx
    acc[2] += s1y + n * dy
    acc[3] += s1z + n * dz
    acc[4] += cell_moments[h, 4] + 2.0 * s1x * dx + n * dx * dx
    acc[5] += cell_moments[h, 5] + s1x * dy + s1y * dx + n * dx * dy
    acc[6] += cell_moments[h, 6] + s1x * dz + s1z * dx + n * dx * dz
    acc[7] += cell_moments[h, 7] + 2.0 * s1y * dy + n * dy * dy
    acc[8] += cell_moments[h, 8] + s1y * dz + s1z * dy + n * dy * dz
    acc[9] += cell_moments[h, 9] + 2.0 * s1z * dz + n * dz * dz


@njit(cache=True, nogil=True)
def _add_straddling(acc, cell_moments, cell_stats, h, dx, dy, dz, r, half_diag):
    """Add the part within ``r`` of the query of voxel ``h``, which the sphere cuts (centre at (dx, dy, dz) from the query).

    The voxel's points are taken as spread uniformly along u, the direction
    from the query to their centroid, over the half-width a = sqrt(3 var_u)
    (at most the half diagonal), and the sphere as the plane across u at
    distance r: the fraction (t + a) / 2a of the points lies within, t = r
    minus the centroid's distance, with its mean moved by (t - a) / 2 along
    u and its variance along u (t + a)^2 / 12 (the other directions as the
    voxel's).  Continuous in the query's position (no voxel jumps in or out
    of a ball), exact for a voxel wholly inside or outside, and equal to
    the points' own sums for a uniform spread.  ``cell_stats[h]``: the
    centroid's offset from the centre (3) and the covariance (xx, xy, xz,
    yy, yz, zz) of the voxel's points (:func:`voxel_stats`).
    """
    mx, my, mz = cell_stats[h, 0], cell_stats[h, 1], cell_stats[h, 2]
    vx, vy, vz = dx + mx, dy + my, dz + mz  # centroid, from the query
    d = np.sqrt(vx * vx + vy * vy + vz * vz)
    if d <= 0.0:
        _add_voxel(acc, cell_moments, h, dx, dy, dz)
        return
    ux, uy, uz = vx / d, vy / d, vz / d
    cxx, cxy, cxz = cell_stats[h, 3], cell_stats[h, 4], cell_stats[h, 5]
    cyy, cyz, czz = cell_stats[h, 6], cell_stats[h, 7], cell_stats[h, 8]
    var = ux * ux * cxx + uy * uy * cyy + uz * uz * czz + 2.0 * (ux * uy * cxy + ux * uz * cxz + uy * uz * cyz)
    a = min(np.sqrt(3.0 * max(var, 0.0)), half_diag)
    t = r - d
    if t >= a:
        _add_voxel(acc, cell_moments, h, dx, dy, dz)
        return
    if t <= -a:
        return
    m = cell_moments[h, 0] * (t + a) / (2.0 * a)  # the points within
    s = (t - a) / 2.0  # their mean moves by s u
    f = (t + a) * (t + a) / 12.0 - var  # their variance along u changes by f
    ex, ey, ez = vx + s * ux, vy + s * uy, vz + s * uz  # their mean, from the query
    acc[0] += m
    acc[1] += m * ex
    acc[2] += m * ey
    acc[3] += m * ez
    acc[4] += m * (cxx + f * ux * ux + ex * ex)
    acc[5] += m * (cxy + f * ux * uy + ex * ey)
    acc[6] += m * (cxz + f * ux * uz + ex * ez)
    acc[7] += m * (cyy + f * uy * uy + ey * ey)
    acc[8] += m * (cyz + f * uy * uz + ey * ez)
    acc[9] += m * (czz + f * uz * uz + ez * ez)


@parallel_kernel
def voxel_stats(moments, out):
    """Centroid offset from the centre (3) and covariance (xx, xy, xz, yy, yz, zz) of every voxel, from its moments."""
    for h in prange(moments.shape[0]):
        n = moments[h, 0]
        mx, my, mz = moments[h, 1] / n, moments[h, 2] / n, moments[h, 3] / n
        out[h, 0], out[h, 1], out[h, 2] = mx, my, mz
        out[h, 3] = moments[h, 4] / n - mx * mx
        out[h, 4] = moments[h, 5] / n - mx * my
        out[h, 5] = moments[h, 6] / n - mx * mz
        out[h, 6] = moments[h, 7] / n - my * my
        out[h, 7] = moments[h, 8] / n - my * mz
        out[h, 8] = moments[h, 9] / n - mz * mz


@parallel_kernel
def ball_moments(
    voxels, points, cell_start, cell_k, row_start, table_keys, table_vals, bits, dims, rows,
    query, qorder, qgroup_start, qblock, r2, cell_moments, cell_stats, cell_centres, half_diag, out,
):
    """Count and moments about each query point of the points within sqrt(r2) of it.

    The occupied cells are sorted by key, so the cells of one row (i, j) are
    contiguous (``row_start``; ``cell_k`` their k index) and a hash table
    finds a row in one or two probes.  Queries come grouped by block (a
    cube of cells; ``qblock`` the grid index of each group's first cell):
    a group gathers once the runs of cells that can hold a point within
    reach of its block, ``rows[t] = (a, b, c_lo, c_hi)`` offsets from the
    block's first cell, then every query of the group scans them.  The
    groups' queries are ``query[qorder[qgroup_start[g]:qgroup_start[g + 1]]]``.

    ``voxels`` False (exact): the query sums the points within reach.
    ``voxels`` True (fast): the query sums the moments of the cells
    (voxels) whose centre is within reach, shifted from the voxel centre
    to the query point; where those voxels hold at most two points each on
    average, the query sums the points within reach instead (as cheap, and
    exact).  Every choice depends only on the cells near the query and
    every sum runs in a fixed order, so a tile with its halo gives the
    whole cloud's values bit for bit.

    ``out[i]`` (query ``i``): n, sum(d) (3), sum(d d^T) (xx, xy, xz, yy, yz,
    zz), d the offset from the query point.  A query at the coordinates of the
    one before it in its group takes its sums (a pile of copies of one point
    costs one ball, not one per copy).
    """
    G = qgroup_start.size - 1
    R = rows.shape[0]
    rad = np.sqrt(r2)
    near = max(rad - half_diag, 0.0)
    near2, far2 = near * near, (rad + half_diag) * (rad + half_diag)
    for g in prange(G):
        lo_cell = np.empty(R, dtype=np.int64)
        hi_cell = np.empty(R, dtype=np.int64)
        nr = 0
        for t in range(R):
            i = qblock[g, 0] + rows[t, 0]
            j = qblock[g, 1] + rows[t, 1]
            if i < 0 or j < 0 or i >= dims[0] or j >= dims[1]:
                continue
            r = _row_of(table_keys, table_vals, bits, i * dims[1] + j)
            if r < 0:
                continue
            s, e = row_start[r], row_start[r + 1]
            klo = qblock[g, 2] + rows[t, 2]
            khi = qblock[g, 2] + rows[t, 3]
            a = s + lower_bound(cell_k[s:e], klo)
            b = s + upper_bound(cell_k[s:e], khi)
            if a < b:
                lo_cell[nr] = a
                hi_cell[nr] = b
                nr += 1
        for m in range(qgroup_start[g], qgroup_start[g + 1]):
            row = qorder[m]
            qx, qy, qz = query[row, 0], query[row, 1], query[row, 2]
            if m > qgroup_start[g]:  # a copy of the query before it (a pile of copies, side by side): the same sums
                prev = qorder[m - 1]
                if query[prev, 0] == qx and query[prev, 1] == qy and query[prev, 2] == qz:
                    for t in range(10):
                        out[row, t] = out[prev, t]
                    continue
            acc = np.zeros(10)
            exact = not voxels
            if voxels:
                used = 0
                for t in range(nr):
                    for h in range(lo_cell[t], hi_cell[t]):
                        dx = cell_centres[h, 0] - qx
                        dy = cell_centres[h, 1] - qy
                        dz = cell_centres[h, 2] - qz
                        dc2 = dx * dx + dy * dy + dz * dz
                        if dc2 > far2:  # every point of the voxel beyond the radius
                            continue
                        used += 1
                        if dc2 <= near2:  # every point within: the voxel's moments, shifted to the query
                            _add_voxel(acc, cell_moments, h, dx, dy, dz)
                        else:
                            _add_straddling(acc, cell_moments, cell_stats, h, dx, dy, dz, rad, half_diag)
                if acc[0] <= 2.0 * used:
                    exact = True
                    acc[:] = 0.0
            if exact:
                for t in range(nr):
                    for p in range(cell_start[lo_cell[t]], cell_start[hi_cell[t]]):
                        dx = points[p, 0] - qx
                        dy = points[p, 1] - qy
                        dz = points[p, 2] - qz
                        if dx * dx + dy * dy + dz * dz <= r2:
                            _add_point(acc, dx, dy, dz)
            for t in range(10):
                out[row, t] = acc[t]


@parallel_kernel
def pca_normals(moments, query, viewpoint, min_points, min_spread, normals, variation):
    """Normal (smallest principal axis) and surface variation from ball moments about the query points.

    A normal is turned to face ``viewpoint`` (dot(viewpoint - q, n) >= 0).
    Rows with fewer than ``min_points`` points, or whose points lie on a
    line or at one place (second-smallest eigenvalue below 1e-12 of the
    largest, or at most ``min_spread``: the coordinates' rounding step
    squared), are left NaN: their normal is undefined.
    """
    M = moments.shape[0]
    chunks = (M + CHUNK - 1) // CHUNK
    for chunk in prange(chunks):  # scratch allocated once per chunk of rows, not once per row
        cov = np.empty((3, 3))
        w = np.empty(3)
        v = np.empty((3, 3))
        for m in range(chunk * CHUNK, min(M, (chunk + 1) * CHUNK)):
            n = moments[m, 0]
            if n < min_points:
                for a in range(3):
                    normals[m, a] = np.nan
                variation[m] = np.nan
                continue
            mx, my, mz = moments[m, 1] / n, moments[m, 2] / n, moments[m, 3] / n
            cov[0, 0] = moments[m, 4] / n - mx * mx
            cov[0, 1] = moments[m, 5] / n - mx * my
            cov[0, 2] = moments[m, 6] / n - mx * mz
            cov[1, 1] = moments[m, 7] / n - my * my
            cov[1, 2] = moments[m, 8] / n - my * mz
            cov[2, 2] = moments[m, 9] / n - mz * mz
            cov[1, 0], cov[2, 0], cov[2, 1] = cov[0, 1], cov[0, 2], cov[1, 2]
            eigh3_into(cov, w, v)
            if not (w[1] > 1e-12 * w[2]) or w[1] <= min_spread or w[2] <= 0.0:
                for a in range(3):
                    normals[m, a] = np.nan
                variation[m] = np.nan
                continue
            nx, ny, nz = v[0, 0], v[1, 0], v[2, 0]
            s = 1.0 / np.sqrt(nx * nx + ny * ny + nz * nz)
            nx, ny, nz = nx * s, ny * s, nz * s
            if (viewpoint[0] - query[m, 0]) * nx + (viewpoint[1] - query[m, 1]) * ny + (viewpoint[2] - query[m, 2]) * nz < 0:
                nx, ny, nz = -nx, -ny, -nz
            normals[m, 0], normals[m, 1], normals[m, 2] = nx, ny, nz
            variation[m] = max(w[0], 0.0) / (w[0] + w[1] + w[2])


@njit(cache=True, nogil=True)
def union_cells(points, cell_keys, cell_start, cells, dims, offsets, tol2, parent):
    """Union-find over occupied cells: cells joined when any two of their points are within sqrt(tol2).

    Every point of a cell is within the tolerance of every other (the cell
    edge is tol / sqrt(3)), so cells stand for their points; ``offsets``
    (half of the neighbourhood) lists the cells that can hold a point
    within tolerance.  A pair of cells already in one set is not searched.
    """
    C = cell_keys.size
    for h in range(C):
        for o in range(offsets.shape[0]):
            i = cells[h, 0] + offsets[o, 0]
            j = cells[h, 1] + offsets[o, 1]
            k = cells[h, 2] + offsets[o, 2]
            if i < 0 or j < 0 or k < 0 or i >= dims[0] or j >= dims[1] or k >= dims[2]:
                continue
            g = _lookup(cell_keys, (i * dims[1] + j) * dims[2] + k)
            if g < 0:
                continue
            ra = find_root(parent, h)
            rb = find_root(parent, g)
            if ra == rb:
                continue
            joined = False
            for p in range(cell_start[h], cell_start[h + 1]):
                for q in range(cell_start[g], cell_start[g + 1]):
                    dx = points[p, 0] - points[q, 0]
                    dy = points[p, 1] - points[q, 1]
                    dz = points[p, 2] - points[q, 2]
                    if dx * dx + dy * dy + dz * dz <= tol2:
                        joined = True
                        break
                if joined:
                    break
            if joined:
                if ra < rb:
                    parent[rb] = ra
                else:
                    parent[ra] = rb
