"""The codes patchcloud writes into its outputs, defined once: how a point got its normal, what a leaf holds.

``NormalMethod`` (a LAS dimension of ``patchcloud normals``) holds a
:class:`Method`; a patch table's ``kind`` column holds a :class:`PatchKind`.
The README and the command line's help quote :meth:`Method.describe`.

>>> Method.describe()
'1 quadric 2 blended 3 kNN 4 cell'
>>> int(PatchKind.SURFACE), [k.name.lower() for k in PatchKind]
(0, ['surface', 'edge', 'sparse'])
"""

from __future__ import annotations

from enum import IntEnum

__all__ = ["Method", "PatchKind"]


class Method(IntEnum):
    """Which computation gave a point its normal (the ``NormalMethod`` dimension).

    0 (not a member) is a point without a normal: left out of every
    neighbourhood (noise, ``--classes``), or whose k nearest neighbours are
    all one point (duplicates), which say nothing of a direction
    (:func:`patchcloud.core.fallback.knn_normals`); its normal is zero.
    """

    #: The quadric of the point's own patch, at the point's projection.
    QUADRIC = 1
    #: The own quadric blended with neighbouring patches' (near a leaf face).
    BLENDED = 2
    #: PCA of the k nearest neighbours (points of edge and sparse leaves without a moment normal).
    KNN = 3
    #: PCA of the moments of the point's finest octree cell, or of its 3 x 3 x 3 block
    #: (points of edge and sparse leaves; :mod:`patchcloud.core.cell_normals`).
    MOMENTS = 4

    @classmethod
    def describe(cls, long: bool = False) -> str:
        """The codes in one line: short (the LAS dimension's description) or long (the help's)."""
        if long:
            words = {cls.QUADRIC: "quadric patch", cls.BLENDED: "blended across patches", cls.KNN: "k-nearest-neighbour fallback",
                     cls.MOMENTS: "cell moments"}
            return ", ".join(f"{m.value} {words[m]}" for m in cls)
        words = {cls.QUADRIC: "quadric", cls.BLENDED: "blended", cls.KNN: "kNN", cls.MOMENTS: "cell"}
        return " ".join(f"{m.value} {words[m]}" for m in cls)


class PatchKind(IntEnum):
    """What an octree leaf holds (a patch table's ``kind``)."""

    #: A smooth piece of surface, modelled by its quadric.
    SURFACE = 0
    #: A sharp feature or a 3D curve (paper eq. 4); no surface model.
    EDGE = 1
    #: Fewer than ``n_min`` points; no surface model.
    SPARSE = 2
