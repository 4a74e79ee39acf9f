"""patchcloud.stream: out-of-core LAS/LAZ ingest, zarr tiles, dask scheduling and export.

Not built yet (see the project's issues); nothing is exported so far.
"""

__all__: list[str] = []
