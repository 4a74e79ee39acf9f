"""The dimensions patchcloud's jobs add to the LAS/LAZ files they write: PDAL's names, types, descriptions, no-data values.

Each is ``(name, numpy type, description, no-data value)``, written as an
extra-bytes dimension (:func:`patchcloud.stream.io.las.output_header`).
They live here, apart from the jobs, so that what only reads them
(``patchcloud info``, which names a file's patchcloud dimensions) loads no
job, and no numba.

>>> [d[0] for d in SEGMENT_DIMS]
['DoN', 'DoNX', 'DoNY', 'DoNZ', 'ClusterID']
"""

from __future__ import annotations

import numpy as np

from patchcloud.core import Method

__all__ = ["NO_PATCH", "NORMALS_DIMS", "PRINCIPAL_DIMS", "DON_NO_DATA", "DON_DIMS", "SEGMENT_DIMS", "DECOMPRESS_DIMS"]

#: The PatchId of a point without a normal (left out by the class selection: :mod:`patchcloud.stream.io.classes`).
NO_PATCH = int(np.iinfo(np.uint32).max)
#: Extra-bytes dimensions ``patchcloud normals`` adds.  Every point the run computes on has a normal (NormalMethod 1
#: to 3); a point left out (not of the classes asked for, noise, withheld) has none: NormalMethod 0, a zero normal,
#: Curvature 0 and PatchId :data:`NO_PATCH`, the no-data values (NaN is never written; a unit normal is never
#: (0, 0, 0), so NormalMethod 0 is what tells such a point).
NORMALS_DIMS = (
    ("NormalX", np.float32, "unit normal x, 0 none", 0.0),
    ("NormalY", np.float32, "unit normal y, 0 none", 0.0),
    ("NormalZ", np.float32, "unit normal z, 0 none", 0.0),
    ("Curvature", np.float32, "surface variation l3/(l1+l2+l3)", 0.0),
    ("NormalMethod", np.uint8, Method.describe(), 0),
    ("PatchId", np.uint32, "patchcloud patch id", NO_PATCH),
)
#: What ``principal_curvatures`` adds (1/unit of the file, signed w.r.t. the oriented normal; 0 and (0, 0, 0) where the
#: point has none, their no-data value).
PRINCIPAL_DIMS = (
    ("PrincipalCurvature1", np.float32, "k1>=k2 1/unit +convex, 0 none", 0.0),
    ("PrincipalCurvature2", np.float32, "k2<=k1 1/unit +convex, 0 none", 0.0),
    ("PrincipalDirectionX", np.float32, "unit direction of k1 x, 0 none", 0.0),
    ("PrincipalDirectionY", np.float32, "unit direction of k1 y, 0 none", 0.0),
    ("PrincipalDirectionZ", np.float32, "unit direction of k1 z, 0 none", 0.0),
)
#: The value the DoN dimensions hold where the DoN is undefined, and their descriptors' no-data value: 0 (no NaN in
#: the file, so PDAL's statistics run; PDAL does not apply no-data values).
DON_NO_DATA = 0.0
#: Dimensions ``patchcloud don`` adds (no-data value :data:`DON_NO_DATA`).
DON_DIMS = (
    ("DoN", np.float32, "DoN |n_s - n_l|/2, 0 none", DON_NO_DATA),
    ("DoNX", np.float32, "DoN vector x, 0 none", DON_NO_DATA),
    ("DoNY", np.float32, "DoN vector y, 0 none", DON_NO_DATA),
    ("DoNZ", np.float32, "DoN vector z, 0 none", DON_NO_DATA),
)
#: Dimensions ``patchcloud segment`` adds: the DoN and PDAL's cluster id (0 = no segment).
SEGMENT_DIMS = DON_DIMS + (("ClusterID", np.uint64, "DoN segment id, 0 = none", 0),)
#: The dimension ``decompress`` adds: every point has it (its no-data value, 255, is never written).
DECOMPRESS_DIMS = (("Reconstructed", np.uint8, "1 from a patch, 0 residual", 255),)
