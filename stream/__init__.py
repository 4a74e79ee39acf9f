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

from patchcloud.core import lazy_exports


_SOURCES = {  # where each public name lives: imported on first use (PEP 562), so importing the package is quick
    'patchcloud.stream.engine.job': ('RunOptions',),
    'patchcloud.stream.engine.runner': ('Runner',),
    'patchcloud.stream.engine.tasks': ('map_tiles',),
    'patchcloud.stream.io.store': ('Store',),
    'patchcloud.stream.jobs.compress': ('CompressSummary', 'compress'),
    'patchcloud.stream.jobs.decompress': ('DecompressSummary', 'decompress'),
    'patchcloud.stream.jobs.don': ('DonSummary', 'don'),
    'patchcloud.stream.jobs.info': ('format_info', 'info'),
    'patchcloud.stream.jobs.normals': ('NormalsSummary', 'normals'),
    'patchcloud.stream.jobs.segment': ('segment',),
    'patchcloud.stream.jobs.tile': ('tile',),
    'patchcloud.stream.views.render': ('RenderImage', 'RenderSummary', 'render', 'render_array', 'render_arrays', 'render_figure'),
    'patchcloud.stream.views.render_tiles': ('TilesSummary', 'render_tiles'),
    'patchcloud.stream.views.report': ('report_compress', 'report_don', 'report_normals', 'write_report'),
}

__all__ = [
    # jobs: file in, file out
    "normals", "NormalsSummary", "don", "segment", "DonSummary", "compress", "CompressSummary", "decompress",
    "DecompressSummary", "tile", "info", "format_info",
    # how jobs run, and running your own per-tile function
    "RunOptions", "Runner", "map_tiles", "Store",
    # pictures and reports
    "render", "render_array", "render_arrays", "render_figure", "RenderImage", "RenderSummary", "render_tiles", "TilesSummary",
    "write_report", "report_normals", "report_don", "report_compress",
]


__getattr__, __dir__ = lazy_exports(__name__, _SOURCES, __all__)
