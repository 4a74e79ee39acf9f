"""Blending of normals and curvatures across leaf faces (paper section 2.4).

Within ``r = min(d1, d2) / 3`` of a face shared by two leaves of edges
``d1`` and ``d2``, a point's value is the weighted mean of its own patch's
value (weight 1) and of each neighbouring patch's value at the same point
(weight ``wendland(dist / r)``, paper eq. 7, with the distance relative to
``r`` so the weight falls to 0 at ``r``).  At the face both sides weigh the
same, so the blended field is continuous across it.  A neighbouring surface
takes part only where it passes within ``r`` of the point, so unrelated
surfaces that happen to share a node face (a wall above a road) do not bleed
into each other, nor do two patches whose normals point to opposite sides
at the point.  Values blended: the normal (renormalised), the surface
variation and the principal curvatures; the k1 direction is re-projected on
the blended tangent plane.
"""

from __future__ import annotations

import numpy as np

from typing import Sequence

from . import _kernels
from .morton import encode, key_range
from .octree import Octree
from .patches import PatchTable

__all__ = ["wendland", "blend_across_faces"]


def wendland(t: np.ndarray) -> np.ndarray:
    """Wendland C2 weight ``(1 - t)^4 (4 t + 1)`` for ``t`` in [0, 1], 0 beyond.

    Examples
    --------
    >>> wendland(np.array([0.0, 0.5, 1.0, 2.0]))
    array([1.    , 0.1875, 0.    , 0.    ])
    """
    t = np.clip(np.asarray(t, dtype=np.float64), 0.0, 1.0)
    return (1.0 - t) ** 4 * (4.0 * t + 1.0)


def blend_across_faces(
    tree: Octree,
    frames: np.ndarray,
    coeffs: np.ndarray,
    normals: np.ndarray,
    scalars: np.ndarray,
    dir1: np.ndarray,
    outside: Sequence[PatchTable | None] | None = None,
    corner: np.ndarray | None = None,
    only: np.ndarray | None = None,
) -> np.ndarray:
    """Blend the values of the points of surface leaves, in place.

    Parameters
    ----------
    tree : Octree
    frames, coeffs : (P, 3, 3), (P, 6)
        Oriented patch frames and quadrics (centroid origin).
    normals, scalars, dir1 : (N, 3) float64, sorted order
        Own-patch normals, (surface variation, k1, k2) and k1 directions;
        rows of points outside surface leaves are left as they are.
    outside : sequence of six PatchTable or None, optional
        Oriented patch tables of the equal-sized cubes across the root cube's
        faces -x, +x, -y, +y, -z, +z (a tile's neighbours); None where there
        is none.  Their leaves blend with this cube's leaves across the face
        exactly as leaves inside the cube do.
    corner : (3,) float64
        The root cube's minimum corner in the tables' coordinates (needed
        with ``outside``).
    only : (N,) bool, optional
        Blend only the points where True, sorted order (default: every
        point); each point's value is the same either way.

    Returns
    -------
    (N,) bool: True where at least one neighbouring surface contributed.
    """
    lo_key, hi_key = key_range(tree.cell, tree.level)
    nb = _pack_outside(outside, corner)
    blended = np.zeros(tree.local.shape[0], dtype=np.bool_)
    todo = np.ones(tree.local.shape[0], dtype=np.bool_) if only is None else np.ascontiguousarray(only, dtype=np.bool_)
    _kernels.blend_points(
        tree.local, tree.q, tree.start, tree.count, tree.level, tree.ijk, lo_key, hi_key, tree.lower,
        tree.leaf_edge, tree.kind, tree.centroid, frames, coeffs, tree.fit.sigma3, *nb,
        normals, scalars, dir1, blended, todo,
    )
    return blended


def _pack_outside(outside, corner) -> tuple:
    """The six neighbour tables as the kernel's concatenated ``nb_*`` arrays."""
    tables = list(outside) if outside is not None else [None] * 6
    if len(tables) != 6:
        raise ValueError(f"outside must hold 6 tables (-x, +x, -y, +y, -z, +z), got {len(tables)}")
    off = np.zeros(7, dtype=np.int64)
    parts: list[tuple] = []
    for d, t in enumerate(tables):
        if t is None or len(t) == 0:
            off[d + 1] = off[d]
            continue
        lo, hi = key_range(encode(t.ijk), t.level)
        order = np.argsort(lo, kind="stable")
        parts.append((lo[order], hi[order], t.edge[order], t.kind[order], t.centroid[order] - np.asarray(corner), t.frame[order], t.coeffs[order], t.sigma3[order]))
        off[d + 1] = off[d] + len(t)
    if not parts:
        return (off, np.zeros(0, np.uint64), np.zeros(0, np.uint64), np.zeros(0), np.zeros(0, np.uint8), np.zeros((0, 3)),
                np.zeros((0, 3, 3)), np.zeros((0, 6)), np.zeros(0))
    cols = [np.ascontiguousarray(np.concatenate(c)) for c in zip(*parts)]
    return (off, *cols)
