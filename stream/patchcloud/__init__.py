"""patchcloud: normals, curvature, Difference of Normals and patch-model compression of point clouds.

Two kinds of functions, every one of them :mod:`patchcloud.core`'s or
:mod:`patchcloud.stream`'s own, re-exported here (the same objects):

- **arrays** (:mod:`patchcloud.core`): one cloud in memory, an (N, 3)
  array of coordinates or a ``laspy.LasData``, in; arrays, in the input's
  point order, out: :func:`estimate_normals` (normals, curvature,
  principal curvatures), :func:`radius_normals`,
  :func:`difference_of_normals`, :func:`segment_don`,
  :func:`euclidean_clusters`, :func:`fit_models` and :func:`sample_models`;
- **files** (:mod:`patchcloud.stream`): LAS/LAZ of any size in, a file
  out, as the ``patchcloud`` command's subcommands: :func:`normals`,
  :func:`don`, :func:`segment`, :func:`compress`, :func:`decompress`,
  :func:`tile`, :func:`info`, :func:`render`.  A job returns with nothing
  of its own left running: its dask cluster and client closed, the threads
  it started (zarr's, dask's) stopped.

Names are imported on first use, so ``import patchcloud`` loads neither
numba's kernels nor dask, zarr or matplotlib.

Examples
--------
>>> import laspy, patchcloud
>>> las = laspy.read(sample)
>>> res = patchcloud.estimate_normals(las)
>>> res.normals.shape, res.k1.shape, res.normals.dtype
((60653, 3), (60653,), dtype('float32'))
>>> don = patchcloud.difference_of_normals(las, 1.0, 4.0)
>>> seg = patchcloud.segment_don(las, don, 0.25, 0.5, min_points=20)
>>> seg.shape, int(seg.max()) > 0
((60653,), True)
>>> s = patchcloud.normals(sample, tmp / "normals.laz", quiet=True)
>>> s.points
60653
>>> from importlib.metadata import version
>>> patchcloud.__version__ == version("patchcloud")
True
"""

from patchcloud.core import __version__, lazy_exports

_SOURCES = {  # where each name lives: the package that re-exports it, imported on first use (PEP 562)
    "patchcloud.core": (
        "estimate_normals", "NormalsResult", "NormalsOptions", "radius_normals", "default_viewpoint", "difference_of_normals",
        "don_magnitude", "don_mask", "segment_don", "euclidean_clusters", "DonOptions", "SegmentOptions", "CompressOptions",
        "fit_models", "sample_models", "PatchModels", "ModelFit", "Method", "PatchKind",
        "PatchcloudError", "PatchcloudValueError", "PatchcloudIOError", "PatchcloudMemoryError", "PatchcloudNotImplementedError",
    ),
    "patchcloud.stream": ("normals", "don", "segment", "compress", "decompress", "tile", "info", "render", "RunOptions"),
}

__all__ = [
    "__version__",
    # arrays: one cloud in memory
    "estimate_normals", "NormalsResult", "NormalsOptions", "radius_normals", "default_viewpoint",
    "difference_of_normals", "don_magnitude", "don_mask", "segment_don", "euclidean_clusters", "DonOptions", "SegmentOptions",
    "fit_models", "sample_models", "PatchModels", "ModelFit", "CompressOptions", "Method", "PatchKind",
    # files: LAS/LAZ of any size
    "normals", "don", "segment", "compress", "decompress", "tile", "info", "render", "RunOptions",
    # errors
    "PatchcloudError", "PatchcloudValueError", "PatchcloudIOError", "PatchcloudMemoryError", "PatchcloudNotImplementedError",
]


__getattr__, __dir__ = lazy_exports(__name__, _SOURCES, __all__)
