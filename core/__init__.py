"""patchcloud.core: normals, curvature, quadric patch models and Difference of Normals of one in-memory cloud.

Numpy arrays in, numpy arrays out; no files and no dask here.

>>> import numpy as np
>>> from patchcloud.core import estimate_normals
>>> xy = np.random.default_rng(0).uniform(0, 10, (5000, 2))
>>> res = estimate_normals(np.column_stack([xy, 0.1 * xy[:, 0]]))
>>> res.normals.shape, res.normals.dtype
((5000, 3), dtype('float32'))
"""

from . import _numba_cache  # noqa: F401  (first, before numba is imported: see its docstring)
from .cluster import euclidean_clusters
from .don import difference_of_normals, don_magnitude, don_mask, segment_don
from .errors import PatchcloudError, PatchcloudIOError, PatchcloudValueError
from .normals import Method, NormalsParameters, NormalsResult, estimate_normals
from .patches import PatchKind, PatchTable
from .patchmodel import ModelFit, PatchModels, fit_models, sample_models
from .radius import default_viewpoint, radius_normals

__all__ = [
    "estimate_normals",
    "NormalsResult",
    "NormalsParameters",
    "Method",
    "PatchTable",
    "PatchKind",
    "radius_normals",
    "default_viewpoint",
    "difference_of_normals",
    "don_magnitude",
    "don_mask",
    "segment_don",
    "euclidean_clusters",
    "fit_models",
    "sample_models",
    "PatchModels",
    "ModelFit",
    "PatchcloudError",
    "PatchcloudValueError",
    "PatchcloudIOError",
]
