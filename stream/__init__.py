"""patchcloud.stream: normals, Difference of Normals, segments and compression of LAS/LAZ files of any size.

Files are cut into the cubic tiles of a zarr store, dask runs one task
per tile, and the results are written back as a copy of the input with
new dimensions (or a ``.pcz``).  Sub-packages, by role, data flowing one
way (files -> store -> tiles -> patch models -> results -> files):

- :mod:`~patchcloud.stream.io`: LAS/LAZ sources and writers, the zarr store, the ``.pcz`` format;
- :mod:`~patchcloud.stream.engine`: ingest and export, the scheduler, ``map_tiles``, the job scaffold;
- :mod:`~patchcloud.stream.jobs`: one module per command (``normals``, ``don``, ``segment``, ...);
- :mod:`~patchcloud.stream.views`: pictures and HTML reports;
- :mod:`~patchcloud.stream.cli`: the ``patchcloud`` command line.

>>> from patchcloud.stream import normals
>>> summary = normals(sample, tmp / "sample_normals.laz", quiet=True)
>>> print(summary.format())                                   # doctest: +ELLIPSIS
/...test_data_77055_627760_LA93_IGN69.laz -> /.../sample_normals.laz
  points          60,653
...
"""

from patchcloud.stream.engine.job import RunOptions
from patchcloud.stream.engine.runner import Runner
from patchcloud.stream.engine.tasks import map_tiles
from patchcloud.stream.io.store import Store
from patchcloud.stream.jobs.compress import CompressSummary, compress
from patchcloud.stream.jobs.decompress import DecompressSummary, decompress
from patchcloud.stream.jobs.don import DonSummary, don
from patchcloud.stream.jobs.info import format_info, info
from patchcloud.stream.jobs.normals import NormalsSummary, normals
from patchcloud.stream.jobs.segment import segment
from patchcloud.stream.jobs.tile import tile
from patchcloud.stream.views.render import RenderImage, RenderSummary, render, render_array, render_arrays
from patchcloud.stream.views.render_tiles import TilesSummary, render_tiles
from patchcloud.stream.views.report import report_compress, report_don, report_normals, write_report

__all__ = [
    # jobs: file in, file out
    "normals", "NormalsSummary", "don", "segment", "DonSummary", "compress", "CompressSummary", "decompress",
    "DecompressSummary", "tile", "info", "format_info",
    # how jobs run, and running your own per-tile function
    "RunOptions", "Runner", "map_tiles", "Store",
    # pictures and reports
    "render", "render_array", "render_arrays", "RenderImage", "RenderSummary", "render_tiles", "TilesSummary",
    "write_report", "report_normals", "report_don", "report_compress",
]
