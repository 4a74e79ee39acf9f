"""The patch table: one row per octree leaf, as a structure of numpy arrays.

This is what the stream keeps per tile and what the compressor stores; it
holds every leaf's octree key, point count, PCA plane and quadric.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from .codes import PatchKind
from .quadric import turn_over

__all__ = ["PatchKind", "PatchTable"]


@dataclass(frozen=True)
class PatchTable:
    """Quadric patch models of one cloud's octree leaves (P rows).

    Coordinates are in the caller's frame (the points passed to
    :func:`patchcloud.core.estimate_normals`), in metres or whatever unit the
    points use.  The surface of patch ``k`` is, in its frame,

    ``w = a u^2 + b uv + c v^2 + d u + e v + f`` with
    ``(u, v, w) = frame[k].T @ (p - centroid[k])`` and
    ``(a, b, c, d, e, f) = coeffs[k]``.

    After orientation, ``frame[k][:, 2]`` (the third column) is the side the
    normals of the patch point to.

    Attributes
    ----------
    root_corner : (3,) float64
        Minimum corner of the root cube.
    root_edge : float
        Edge of the root cube.
    level : (P,) uint8
        Octree level of the leaf (0 is the root).
    ijk : (P, 3) int64
        Integer coordinates of the leaf at its level: the leaf spans
        ``root_corner + ijk * edge`` to ``root_corner + (ijk + 1) * edge``.
    count : (P,) int64
        Points in the leaf.
    centroid : (P, 3) float64
        Centroid of the leaf's points.
    frame : (P, 3, 3) float64
        PCA axes as columns ``e1, e2, e3`` (e3: plane normal), right-handed.
    eigenvalues : (P, 3) float64
        Covariance eigenvalues ``lambda1 >= lambda2 >= lambda3`` (unit^2).
    coeffs : (P, 6) float64
        Quadric coefficients ``a, b, c, d, e, f`` in the frame.
    rmse : (P,) float64
        RMSE of the quadric fit along e3 (unit).
    kind : (P,) uint8
        :class:`PatchKind` of the leaf.

    Examples
    --------
    >>> import numpy as np
    >>> from patchcloud.core import estimate_normals
    >>> rng = np.random.default_rng(0)
    >>> xy = rng.uniform(0, 10, (5000, 2))
    >>> table = estimate_normals(np.column_stack([xy, np.zeros(5000)])).patches
    >>> bool(np.all(table.normal[table.kind == 0, 2] > 0.999))
    True
    """

    root_corner: np.ndarray
    root_edge: float
    level: np.ndarray
    ijk: np.ndarray
    count: np.ndarray
    centroid: np.ndarray
    frame: np.ndarray
    eigenvalues: np.ndarray
    coeffs: np.ndarray
    rmse: np.ndarray
    kind: np.ndarray

    def __len__(self) -> int:
        return int(self.level.shape[0])

    @property
    def edge(self) -> np.ndarray:
        """(P,) edge of every leaf cube."""
        return self.root_edge / np.exp2(self.level.astype(np.float64))

    @property
    def lower(self) -> np.ndarray:
        """(P, 3) minimum corner of every leaf cube."""
        return self.root_corner + self.ijk * self.edge[:, None]

    @property
    def normal(self) -> np.ndarray:
        """(P, 3) plane normal (e3) of every patch."""
        return self.frame[:, :, 2]

    @property
    def sigma3(self) -> np.ndarray:
        """(P,) surface variation ``lambda3 / sum(lambda)`` (paper eq. 2), in [0, 1/3]."""
        tot = self.eigenvalues.sum(axis=1)
        return np.divide(self.eigenvalues[:, 2], tot, out=np.zeros_like(tot), where=tot > 0)

    @property
    def sigma2(self) -> np.ndarray:
        """(P,) ``lambda2 / sum(lambda)`` (paper eq. 4); small for 3D curves."""
        tot = self.eigenvalues.sum(axis=1)
        return np.divide(self.eigenvalues[:, 1], tot, out=np.zeros_like(tot), where=tot > 0)

    def flipped(self, mask: np.ndarray) -> "PatchTable":
        """A copy with the patches in ``mask`` turned over.

        See :func:`patchcloud.core.quadric.turn_over`: the same surface with
        its normals reversed.
        """
        frame, coeffs = turn_over(self.frame, self.coeffs, mask)
        return replace(self, frame=frame, coeffs=coeffs)

    def take(self, index: np.ndarray) -> "PatchTable":
        """A table of the rows ``index`` (an index array or a boolean mask)."""
        values = {}
        for f in fields(self):
            v = getattr(self, f.name)
            values[f.name] = v if f.name.startswith("root_") else v[index]
        return PatchTable(**values)
