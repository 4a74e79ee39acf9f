"""One module per command: ``tile``, ``normals``, ``don``, ``segment``, ``compress``, ``decompress``, ``info``, ``don_scales``.

A job module declares a :class:`patchcloud.stream.engine.job.Job` (its
steps, its output columns, its summary) and the function users call; its
per-tile tasks live beside it (``normals_tiles``, ``seams``, ``don_tiles``).
"""
