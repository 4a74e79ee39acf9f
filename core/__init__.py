"""patchcloud.core: normals, curvature, quadric patch models and Difference of Normals of one in-memory cloud.

Numpy arrays in, numpy arrays out; no files and no dask here.

``__all__`` has two groups: the user API, then the tile interface, the
lower-level pieces :mod:`patchcloud.stream` builds its per-tile steps from.
The stream imports from ``patchcloud.core`` only, and only names of
``__all__``; the submodules' other names may change without notice.

>>> import numpy as np
>>> from patchcloud.core import estimate_normals
>>> xy = np.random.default_rng(0).uniform(0, 10, (5000, 2))
>>> res = estimate_normals(np.column_stack([xy, 0.1 * xy[:, 0]]))
>>> res.normals.shape, res.normals.dtype
((5000, 3), dtype('float32'))
"""

from . import _numba_cache  # noqa: F401  (first, before numba is imported: see its docstring)
from .lazy import lazy_exports

_SOURCES = {  # where each public name lives: imported on first use (PEP 562), so importing the package is quick
    '.graph': ('connected_components',),
    '.cluster': ('components', 'euclidean_clusters', 'number_by_first'),
    '.don': ('difference_of_normals', 'don_magnitude', 'don_mask', 'segment_don'),
    '.errors': ('PatchcloudError', 'PatchcloudExistsError', 'PatchcloudIOError', 'PatchcloudMemoryError', 'PatchcloudNotImplementedError', 'PatchcloudValueError', 'os_error_line'),
    '.moments': ('cell_moments',),
    '.morton': ('MAX_DEPTH', 'decode', 'encode', 'face_neighbours'),
    '.frame': ('cell_indices', 'frame_shift', 'local_coordinates'),
    '.points': ('GRID_ANCHOR',),
    '.codes': ('Method', 'PatchKind'),
    '.normals': ('NormalsParameters', 'NormalsResult', 'estimate_normals'),
    '.options': ('CompressOptions', 'DonOptions', 'NormalsOptions', 'SegmentOptions', 'options_with'),
    '.octree': ('level_occupancy', 'max_level_for', 'point_keys', 'sort_points'),
    '.calibration': ('rmse_histograms', 'threshold_from_histograms'),
    '.forest': ('Expansion', 'ForestLinks', 'ForestNodes', 'concat_links', 'expand_signs', 'forest_links', 'forest_nodes', 'lookup', 'merge_nodes', 'reduce_forest'),
    '.orient': ('MIN_RELIABILITY', 'LeafSet', 'cross_face_pairs', 'link_agreements'),
    '.patches': ('PatchTable',),
    '.patchmodel': ('MASK_SIDE', 'ModelFit', 'PatchModels', 'QuantisedModels', 'dequantise_models', 'fit_models', 'patch_distances', 'quantise_models', 'sample_models'),
    '.quadric': ('fit_nodes', 'surface_normals'),
    '.checks': ('MODES', 'check_rounding', 'check_flag'),
    '.radius': ('check_grid_step', 'check_points', 'coordinate_step', 'default_viewpoint', 'grid_origin', 'grid_step_of', 'halo_width', 'radius_normals'),
    '.threads': ('single_threaded',),
    '.version': ('__version__',),
    '.tiles': ('SKIN_HALO', 'FOLD_MIN_COS', 'Skin', 'finish_tile', 'fit_tile', 'folded', 'patch_signs'),
}

__all__ = [
    # the user API
    "__version__",
    "estimate_normals",
    "NormalsResult",
    "NormalsParameters",
    "NormalsOptions",
    "DonOptions",
    "SegmentOptions",
    "CompressOptions",
    "options_with",
    "Method",
    "PatchTable",
    "PatchKind",
    "radius_normals",
    "grid_origin",
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
    "PatchcloudExistsError",
    "PatchcloudNotImplementedError",
    "PatchcloudMemoryError",
    "os_error_line",
    # the tile interface: what patchcloud.stream uses (besides names of the user API above)
    # .morton
    "MAX_DEPTH",
    "decode",
    "encode",
    "face_neighbours",
    # .frame
    "local_coordinates",
    "cell_indices",
    "frame_shift",
    "GRID_ANCHOR",
    # .octree
    "level_occupancy",
    "max_level_for",
    "point_keys",
    "sort_points",
    # .moments
    "cell_moments",
    # .calibration
    "rmse_histograms",
    "threshold_from_histograms",
    # .quadric
    "fit_nodes",
    "surface_normals",
    # .graph
    "connected_components",
    # .orient
    "MIN_RELIABILITY",
    "LeafSet",
    "cross_face_pairs",
    "link_agreements",
    # .tiles
    "SKIN_HALO",
    "FOLD_MIN_COS",
    "folded",
    "Skin",
    "fit_tile",
    "finish_tile",
    "patch_signs",
    # .forest (the seam pass, block by block)
    "ForestNodes",
    "ForestLinks",
    "Expansion",
    "forest_nodes",
    "forest_links",
    "concat_links",
    "merge_nodes",
    "reduce_forest",
    "expand_signs",
    "lookup",
    # .radius
    "MODES",
    "check_points",
    "check_rounding",
    "check_flag",
    "check_grid_step",
    "coordinate_step",
    "grid_step_of",
    "halo_width",
    # .cluster
    "components",
    "number_by_first",
    # .patchmodel
    "MASK_SIDE",
    "QuantisedModels",
    "quantise_models",
    "dequantise_models",
    "patch_distances",
    # .threads
    "single_threaded",
    # .lazy
    "lazy_exports",
]


__getattr__, __dir__ = lazy_exports(__name__, _SOURCES, __all__)
