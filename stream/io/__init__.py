"""Files: LAS/LAZ sources and writers (:mod:`.las`), the tiled zarr store (:mod:`.store`), the ``.pcz`` format (:mod:`.pcz`),
the locks of a run on its outputs (:mod:`.lock`).

Nothing here knows about jobs, scheduling or pictures.
"""
