"""A write that fails for want of room (a full disk, a quota, ``ulimit -f``) named by the file it was writing.

``f.write(...)`` and ``os.pwrite`` raise an OSError without a file name, so
the one line a failed run prints could not say which file filled its disk,
and the run named its store, which may sit on another disk.  The writers of
outputs wrap their writes in :func:`naming_failed_writes`.
"""

from __future__ import annotations

import errno
import os
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["naming_failed_writes", "ROOM_ERRNOS"]

#: The errors of a write that found no room: no space left, a quota exceeded, a file larger than allowed.
ROOM_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


@contextmanager
def naming_failed_writes(path: str | os.PathLike) -> Iterator[None]:
    """Within the block, an OSError of :data:`ROOM_ERRNOS` without a file name is raised again naming ``path``.

    >>> try:
    ...     with naming_failed_writes("/data/out.laz"):
    ...         raise OSError(errno.ENOSPC, "No space left on device")
    ... except OSError as exc:
    ...     print(exc.filename, exc.strerror)
    /data/out.laz No space left on device
    """
    try:
        yield
    except OSError as exc:
        if exc.filename is None and exc.errno in ROOM_ERRNOS:
            raise OSError(exc.errno, exc.strerror, os.fspath(path)) from exc
        raise
