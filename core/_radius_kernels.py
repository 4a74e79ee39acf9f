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

from ._kernels import _eigh3

__all__ = ["ball_moments_exact", "ball_moments_voxels", "voxel_moments", "pca_normals", "union_cells"]


@njit(cache=True)
def _lookup(keys, key):
    """Index of ``key`` in the sorted array ``keys``, or -1."""
    i = np.searchsorted(keys, key)
    if i < keys.size and keys[i] == key:
        return i
    return -1


@njit(cache=True)
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


@njit(cache=True, parallel=True)
def ball_moments_exact(points, cell_keys, cell_start, dims, query, qcell, reach, r2, out):
    """Count and moments about each query point of the points within sqrt(r2) of it.

    ``points`` (N, 3) sorted by cell; ``cell_keys`` (C,) sorted keys of the
    occupied cells, ``cell_start`` (C + 1,); ``dims`` the grid's size in
    cells per axis; ``query`` (M, 3); ``qcell`` (M, 3) the query's cell;
    ``reach`` how many cells around the query's cell to look in.
    ``out[m]`` gets n, sum(d) (3), sum(d d^T) (xx, xy, xz, yy, yz, zz) for
    the offsets d = p - query[m] of the points with |d|^2 <= r2.
    """
    M = query.shape[0]
    for m in prange(M):
        qx, qy, qz = query[m, 0], query[m, 1], query[m, 2]
        acc = np.zeros(10)
        for a in range(-reach, reach + 1):
            i = qcell[m, 0] + a
            if i < 0 or i >= dims[0]:
                continue
            for b in range(-reach, reach + 1):
                j = qcell[m, 1] + b
                if j < 0 or j >= dims[1]:
                    continue
                for c in range(-reach, reach + 1):
                    k = qcell[m, 2] + c
                    if k < 0 or k >= dims[2]:
                        continue
                    h = _lookup(cell_keys, (i * dims[1] + j) * dims[2] + k)
                    if h < 0:
                        continue
                    for p in range(cell_start[h], cell_start[h + 1]):
                        dx = points[p, 0] - qx
                        dy = points[p, 1] - qy
                        dz = points[p, 2] - qz
                        if dx * dx + dy * dy + dz * dz <= r2:
                            _add_point(acc, dx, dy, dz)
        for t in range(10):
            out[m, t] = acc[t]


@njit(cache=True, parallel=True)
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


@njit(cache=True, parallel=True)
def ball_moments_voxels(
    points, vox_start, vox_keys, vox_moments, vox_centres, dims, rows, query, qgroup_start, qblock, r2, out
):
    """Moments about each query point of the voxels whose centre lies within sqrt(r2) of it.

    The queries come grouped by block (a cube of voxels; ``qblock`` the
    grid index of each group's first voxel).  A group first gathers the
    occupied voxels that can hold a point within reach of its block:
    ``rows[t] = (a, b, c_lo, c_hi)`` are runs of voxel offsets from the
    block's first voxel, each found by two binary searches.  Every query of
    the group then sums the moments of the gathered voxels whose centre is
    within reach, shifted from the voxel centre to the query point: the
    cost per query is the number of voxels near it, not of points.  Where
    those voxels hold at most twice as many points as there are voxels (a
    sparse neighbourhood), summing the points themselves is as cheap, and
    the query takes the exact ball of points instead.  Both choices depend
    only on the voxels near the query, never on how the cloud was cut.
    """
    G = qgroup_start.size - 1
    K = 0
    for t in range(rows.shape[0]):
        K += rows[t, 3] - rows[t, 2] + 1
    for g in prange(G):
        cand = np.empty(K, dtype=np.int64)
        nc = 0
        for t in range(rows.shape[0]):
            i = qblock[g, 0] + rows[t, 0]
            j = qblock[g, 1] + rows[t, 1]
            if i < 0 or j < 0 or i >= dims[0] or j >= dims[1]:
                continue
            klo = max(qblock[g, 2] + rows[t, 2], 0)
            khi = min(qblock[g, 2] + rows[t, 3], dims[2] - 1)
            if klo > khi:
                continue
            row = (i * dims[1] + j) * dims[2]
            lo = np.searchsorted(vox_keys, row + klo)
            hi = np.searchsorted(vox_keys, row + khi, side="right")
            for h in range(lo, hi):
                cand[nc] = h
                nc += 1
        for m in range(qgroup_start[g], qgroup_start[g + 1]):
            acc = np.zeros(10)
            used = 0
            for t in range(nc):
                h = cand[t]
                dx = vox_centres[h, 0] - query[m, 0]
                dy = vox_centres[h, 1] - query[m, 1]
                dz = vox_centres[h, 2] - query[m, 2]
                if dx * dx + dy * dy + dz * dz > r2:
                    continue
                used += 1
                n = vox_moments[h, 0]
                s1x, s1y, s1z = vox_moments[h, 1], vox_moments[h, 2], vox_moments[h, 3]
                acc[0] += n
                acc[1] += s1x + n * dx
                acc[2] += s1y + n * dy
                acc[3] += s1z + n * dz
                acc[4] += vox_moments[h, 4] + 2.0 * s1x * dx + n * dx * dx
                acc[5] += vox_moments[h, 5] + s1x * dy + s1y * dx + n * dx * dy
                acc[6] += vox_moments[h, 6] + s1x * dz + s1z * dx + n * dx * dz
                acc[7] += vox_moments[h, 7] + 2.0 * s1y * dy + n * dy * dy
                acc[8] += vox_moments[h, 8] + s1y * dz + s1z * dy + n * dy * dz
                acc[9] += vox_moments[h, 9] + 2.0 * s1z * dz + n * dz * dz
            if acc[0] <= 2.0 * used:
                acc[:] = 0.0
                for t in range(nc):
                    h = cand[t]
                    for p in range(vox_start[h], vox_start[h + 1]):
                        dx = points[p, 0] - query[m, 0]
                        dy = points[p, 1] - query[m, 1]
                        dz = points[p, 2] - query[m, 2]
                        if dx * dx + dy * dy + dz * dz <= r2:
                            _add_point(acc, dx, dy, dz)
            for t in range(10):
                out[m, t] = acc[t]


@njit(cache=True, parallel=True)
def pca_normals(moments, query, viewpoint, min_points, normals, variation):
    """Normal (smallest principal axis) and surface variation from ball moments about the query points.

    A normal is turned to face ``viewpoint`` (dot(viewpoint - q, n) >= 0).
    Rows with fewer than ``min_points`` points, or whose points lie on a
    line or at one place (second-smallest eigenvalue below 1e-12 of the
    largest), are left NaN: their normal is undefined.
    """
    M = moments.shape[0]
    for m in prange(M):
        n = moments[m, 0]
        if n < min_points:
            for a in range(3):
                normals[m, a] = np.nan
            variation[m] = np.nan
            continue
        mx, my, mz = moments[m, 1] / n, moments[m, 2] / n, moments[m, 3] / n
        cov = np.empty((3, 3))
        cov[0, 0] = moments[m, 4] / n - mx * mx
        cov[0, 1] = moments[m, 5] / n - mx * my
        cov[0, 2] = moments[m, 6] / n - mx * mz
        cov[1, 1] = moments[m, 7] / n - my * my
        cov[1, 2] = moments[m, 8] / n - my * mz
        cov[2, 2] = moments[m, 9] / n - mz * mz
        cov[1, 0], cov[2, 0], cov[2, 1] = cov[0, 1], cov[0, 2], cov[1, 2]
        w, v = _eigh3(cov)
        if not (w[1] > 1e-12 * w[2]) or w[2] <= 0.0:
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


@njit(cache=True)
def _find(parent, a):
    root = a
    while parent[root] != root:
        root = parent[root]
    while parent[a] != root:  # path compression
        nxt = parent[a]
        parent[a] = root
        a = nxt
    return root


@njit(cache=True)
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
            ra = _find(parent, h)
            rb = _find(parent, g)
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
