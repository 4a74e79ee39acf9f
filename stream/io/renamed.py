"""The outputs this process renamed into place, as it left them: what a failed run in memory may remove.

A run in memory keeps no store, so when it fails nothing would resume its
outputs, and it removes the ones it had already completed (each is written
under a temporary name and renamed into place when complete), so that the
same command starts over.  It must remove only files it wrote: not a file
another program (a user, PDAL, another patchcloud run) put at an output's
path during the run.  Each rename into place records the file's state here
(:func:`rename_into_place`, which renames and records: inode, size,
modification time), and a file counts as this run's (:func:`renamed_here`)
only while it is still in that state.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

__all__ = ["rename_into_place", "renamed_here", "file_state", "partial_path"]

_renamed: dict[str, tuple] = {}
_lock = threading.Lock()


def file_state(path: str | os.PathLike) -> tuple | None:
    """(inode, size, modification time in ns) of a file, or None where there is none."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (st.st_ino, st.st_size, st.st_mtime_ns)


def _key(path: str | os.PathLike) -> str:
    return str(Path(path).resolve())


def partial_path(path: str | os.PathLike) -> Path:
    """The temporary name a file is written under until it is complete and renamed to ``path``: ``path`` + ``.partial``.

    >>> partial_path("/data/out.laz").name
    'out.laz.partial'
    """
    p = Path(path)
    return p.with_name(p.name + ".partial")


def rename_into_place(tmp: str | os.PathLike, path: str | os.PathLike) -> None:
    """Rename the complete file ``tmp`` to ``path`` (replacing what is there), and record it as this process's."""
    Path(tmp).replace(path)
    state = file_state(path)
    if state is not None:
        with _lock:
            _renamed[_key(path)] = state


def renamed_here(path: str | os.PathLike) -> bool:
    """Whether the file at ``path`` is one this process renamed into place, unchanged since.

    >>> import tempfile, os
    >>> d = tempfile.mkdtemp(); p = os.path.join(d, "out.las")
    >>> open(p + ".partial", "wb").write(b"mine"); rename_into_place(p + ".partial", p)
    4
    >>> renamed_here(p)
    True
    >>> os.remove(p); open(p, "wb").write(b"someone else's file")
    19
    >>> renamed_here(p)
    False
    """
    with _lock:
        was = _renamed.get(_key(path))
    return was is not None and file_state(path) == was
