"""How jobs run: ingest (:mod:`.ingest`) and export (:mod:`.export`) between files and the store,
the scheduler (:mod:`.runner`), per-tile tasks (:mod:`.tasks`: ``map_tiles``), progress bars
(:mod:`.progress`), numba's first-run compiling timed apart (:mod:`.compiling`), the threads a run
started stopped when it returns (:mod:`.background`) and the job scaffold (:mod:`.job`: ``Job``,
``RunOptions``, ``run_job``).

It uses :mod:`patchcloud.stream.io` and nothing above it (no jobs, no views).
"""
