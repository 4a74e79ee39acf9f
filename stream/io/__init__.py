"""Files: LAS/LAZ sources and writers (:mod:`.las`), the tiled zarr store (:mod:`.store`), the ``.pcz`` format (:mod:`.pcz`).

Nothing here knows about jobs, scheduling or pictures.
"""
