"""Exception hierarchy shared by every patchcloud package.

Every error patchcloud raises on purpose derives from :class:`PatchcloudError`
and also from the matching built-in exception, so ``except ValueError`` keeps
working for callers who do not know patchcloud.
"""

from __future__ import annotations

__all__ = ["PatchcloudError", "PatchcloudValueError", "PatchcloudIOError", "PatchcloudExistsError", "PatchcloudNotImplementedError", "PatchcloudMemoryError", "os_error_line"]


class PatchcloudError(Exception):
    """Root of every exception raised by patchcloud."""


class PatchcloudValueError(PatchcloudError, ValueError):
    """An argument (points, parameter) is not acceptable; the message says why."""


class PatchcloudIOError(PatchcloudError, OSError):
    """A file or store cannot be read or written; the message names it."""


class PatchcloudExistsError(PatchcloudIOError, FileExistsError):
    """An output exists and ``overwrite`` (``--overwrite``) was not given; the message names it."""


class PatchcloudNotImplementedError(PatchcloudError, NotImplementedError):
    """A combination patchcloud does not handle yet (e.g. a catalog for ``compress``); the message names it."""


class PatchcloudMemoryError(PatchcloudError, MemoryError):
    """A size read from a file, or asked for by a parameter, would need more memory than the budget allows
    (``--max-memory``); nothing was allocated.  The message names the file and what it asked for."""


def os_error_line(exc: OSError) -> str:
    """``PATH: what happened`` for an OSError (its file, its system message); without a file, what happened.

    >>> os_error_line(OSError(28, "No space left on device", "/data/out.laz"))
    '/data/out.laz: No space left on device'
    """
    what = exc.strerror or str(exc) or type(exc).__name__
    return f"{exc.filename}: {what}" if exc.filename else what
