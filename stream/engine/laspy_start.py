"""laspy without ``requests``, for the processes patchcloud runs itself (the console script, its local workers).

``import laspy`` imports ``laspy.copc``, which imports ``requests`` (and
with it urllib3, charset detection, ...) for reading COPC files over HTTP:
0.024 s of every process (``python -X importtime``).  patchcloud reads
local files only (an input is a path), and ``laspy.copc`` takes a missing
``requests`` as HTTP support left out, so :func:`skip_laspy_http` hides it
while ``laspy.copc`` runs.  Like numba's BLAS probe
(:mod:`~patchcloud.stream.engine.numba_start`), only the console script
and its workers do it, not ``import patchcloud``.
"""

from __future__ import annotations

from patchcloud.stream.engine.import_hooks import hide_while_importing

__all__ = ["skip_laspy_http", "HTTP", "COPC"]

#: What laspy imports for COPC over HTTP.
HTTP = "requests"
#: The laspy module that imports it.
COPC = "laspy.copc"


def skip_laspy_http() -> bool:
    """Have ``laspy.copc``, when it is imported, go without ``requests`` (see the module's notes).

    Returns False when laspy is already imported (too late).
    """
    return hide_while_importing(COPC, HTTP)
