"""patchcloud.stream: normals, Difference of Normals and segments of LAS/LAZ files of any size, through a tiled zarr store and dask.

>>> from patchcloud.stream import normals                    # doctest: +SKIP
>>> summary = normals("city.laz", "city_normals.laz")        # doctest: +SKIP
>>> print(summary.format())                                  # doctest: +SKIP
"""

from .compression import CompressSummary, DecompressSummary, compress, decompress
from .info import format_info, info
from .pipeline import NormalsSummary, normals, tile
from .scheduling import Runner, map_tiles
from .render import RenderImage, RenderSummary, render, render_array, render_arrays
from .render_tiles import TilesSummary, render_tiles
from .segmentation import DonSummary, don, segment
from .report import report_compress, report_don, report_normals, write_report
from .store import Store

__all__ = ["normals", "don", "segment", "DonSummary", "compress", "decompress", "CompressSummary", "DecompressSummary", "tile", "info", "format_info", "NormalsSummary", "Store", "Runner", "map_tiles", "write_report", "report_normals", "report_don", "report_compress", "render", "render_array", "render_arrays", "RenderImage", "RenderSummary", "render_tiles", "TilesSummary"]
