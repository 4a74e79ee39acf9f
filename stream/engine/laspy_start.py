"""laspy without ``requests`` or ``pyproj`` at import, for the processes patchcloud runs itself (the console script, its local workers).

``import laspy`` imports ``laspy.copc``, which imports ``requests`` (and
with it urllib3, charset detection, ...) for reading COPC files over HTTP:
0.024 s of every process (``python -X importtime``).  patchcloud reads
local files only (an input is a path), and ``laspy.copc`` takes a missing
``requests`` as HTTP support left out, so :func:`skip_laspy_http` hides it
while ``laspy.copc`` runs.

``import laspy`` also imports ``pyproj`` (0.06-0.09 s on the 2-core
machine, on the path of every worker's start: the fork server imports
laspy before any worker can be forked), from ``laspy.vlrs.geotiff``, which
names it in a type annotation only; laspy's functions that read or write a
CRS import it themselves when called.  :func:`skip_laspy_pyproj` hides it
while ``laspy.vlrs.geotiff`` runs, so a process imports pyproj when it
first reads or writes a CRS (the console script, for the run's summary and
output header), or never (a worker).  Like numba's BLAS probe
(:mod:`~patchcloud.stream.engine.numba_start`), only the console script
and its workers do these, not ``import patchcloud``.
"""

from __future__ import annotations

from patchcloud.stream.engine.import_hooks import hide_while_importing

__all__ = ["skip_laspy_http", "skip_laspy_pyproj", "HTTP", "COPC", "CRS_LIBRARY", "GEOTIFF"]

#: What laspy imports for COPC over HTTP.
HTTP = "requests"
#: The laspy module that imports it.
COPC = "laspy.copc"
#: What laspy imports at its import for a type annotation (and imports again where it uses it).
CRS_LIBRARY = "pyproj"
#: The laspy module that imports it at its import.
GEOTIFF = "laspy.vlrs.geotiff"


def skip_laspy_http() -> bool:
    """Have ``laspy.copc``, when it is imported, go without ``requests`` (see the module's notes).

    Returns False when laspy is already imported (too late).
    """
    return hide_while_importing(COPC, HTTP)


def skip_laspy_pyproj() -> bool:
    """Have ``laspy.vlrs.geotiff``, when it is imported, go without ``pyproj`` (see the module's notes).

    Returns False when laspy is already imported (too late).  ``pyproj``
    is imported as before by whatever uses it later (laspy's
    ``LasHeader.parse_crs`` and ``add_crs``, patchcloud's CRS checks).
    """
    return hide_while_importing(GEOTIFF, CRS_LIBRARY)
