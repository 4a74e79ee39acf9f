"""Exclusive locks on what a run writes (its output, its store), so two runs never write the same files at once.

A lock is a file ``PATH.lock`` created atomically (``O_CREAT | O_EXCL``)
holding the owner's pid, host, start time and a token; the owner touches
it every :data:`HEARTBEAT` seconds.  A second run finding it stops with
one line naming the owner.  A stale lock (its pid dead on this host, or
run by a process started after the lock was taken: a container started
again, its pids reused; or no heartbeat for :data:`STALE` seconds from
another host: a run killed
with ``kill -9``, a machine that went down) is taken over with a note on
stderr; two runs taking over the same stale lock are ordered by a second
file created atomically, ``PATH.lock.takeover``.  Stores at fsspec URLs
are not locked (only local paths are): give each run its own.

>>> import tempfile, os
>>> d = tempfile.mkdtemp()
>>> with RunLock([os.path.join(d, "out.laz")]):
...     os.path.exists(os.path.join(d, "out.laz.lock"))
True
>>> os.path.exists(os.path.join(d, "out.laz.lock"))
False
"""

from __future__ import annotations

import json
import os
import shlex
import socket
import sys
import threading
import time
import uuid
from pathlib import Path

from patchcloud.core import PatchcloudIOError

__all__ = ["RunLock", "PatchcloudLockedError", "lock_path", "alive", "process_start", "HEARTBEAT", "STALE", "COMMAND_WORDS"]

#: Seconds between two touches of a held lock.
HEARTBEAT = 30.0
#: A lock from another host untouched for this many seconds is stale.
STALE = 300.0
#: A takeover file older than this (seconds) was left by a run killed while taking over.
_TAKEOVER_STALE = 60.0


class PatchcloudLockedError(PatchcloudIOError):
    """Another run holds the lock on an output or a store; the message names it."""


def lock_path(path: str | os.PathLike) -> Path:
    """The lock file of ``path``: ``PATH.lock`` beside it."""
    p = Path(path).resolve()
    return p.with_name(p.name + ".lock")


def alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this host: it exists and is not a zombie (ended, its parent not yet told; under
    a container's first process that never reaps, it stays one for good).

    >>> alive(os.getpid())
    True
    """
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        pass
    try:  # Linux: the state after the name's closing parenthesis (a name may hold one too)
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):  # no /proc (macOS), or gone meanwhile: os.kill said it was there
        return True
    return state not in ("Z", "X")


#: Seconds by which a process may seem to have started after a lock it took (the boot time /proc gives is whole seconds).
_START_SLACK = 2.0


def process_start(pid: int) -> float | None:
    """When process ``pid`` started, seconds since the epoch (Linux: /proc), or None where that cannot be read.

    >>> abs(process_start(os.getpid()) - time.time()) < 1e6
    True
    """
    try:
        ticks = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19])
        with open("/proc/stat") as f:
            boot = next(float(line.split()[1]) for line in f if line.startswith("btime"))
        return boot + ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError, StopIteration):
        return None


def _read(lock: Path) -> dict | None:
    try:
        return json.loads(lock.read_text())
    except (OSError, ValueError):
        return None


def _stale(lock: Path, info: dict | None) -> str | None:
    """Why the lock at ``lock`` is stale ("pid 12 on this host is dead", ...), or None when it is held."""
    try:
        age = time.time() - lock.stat().st_mtime
    except FileNotFoundError:
        return "gone"
    if info is None:  # being written right now, or garbage
        return f"unreadable and untouched for {age:.0f} s" if age > _TAKEOVER_STALE else None
    if info.get("host") == socket.gethostname():
        pid = int(info.get("pid", -1))
        if not alive(pid):
            return f"pid {pid} on this host is dead"
        began = process_start(pid)
        if began is not None and began > float(info.get("started", 0.0)) + _START_SLACK:
            # (a container started again runs as the same pid on the same host name, and waited for its own lock)
            return f"pid {pid} on this host is another process, started after the lock was taken"
        return None
    return f"no heartbeat from {info.get('host')} for {age:.0f} s" if age > STALE else None


#: How many words of the command line a lock records (a catalog's may name hundreds of files): more are "...".
COMMAND_WORDS = 16


class RunLock:
    """Exclusive locks on ``paths`` (outputs, stores: local paths), held from :meth:`acquire` (or ``with``) to :meth:`release`."""

    def __init__(self, paths) -> None:
        self.locks = sorted({lock_path(p) for p in paths})
        self.token = uuid.uuid4().hex
        self.held: list[Path] = []
        self._stop = threading.Event()
        self._beat: threading.Thread | None = None

    def _info(self) -> str:
        return json.dumps(dict(pid=os.getpid(), host=socket.gethostname(), started=time.time(), token=self.token,
                               command=shlex.join(sys.argv[:COMMAND_WORDS]) + (" ..." if len(sys.argv) > COMMAND_WORDS else "")))

    def _create(self, lock: Path) -> bool:
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            return False
        except OSError as exc:
            raise PatchcloudIOError(f"{lock}: cannot create the run's lock ({exc.strerror})") from exc
        try:
            with os.fdopen(fd, "w") as f:
                f.write(self._info())
        except OSError as exc:  # a full disk: an empty lock left here would stop the next run for a minute
            lock.unlink(missing_ok=True)
            raise PatchcloudIOError(f"{lock}: cannot create the run's lock ({exc.strerror})") from exc
        return True

    def _take_over(self, lock: Path, info: dict | None, why: str) -> bool:
        """Replace the stale lock ``lock`` by ours, unless another run is taking it over first."""
        guard = lock.with_name(lock.name + ".takeover")
        try:
            fd = os.open(guard, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                if time.time() - guard.stat().st_mtime > _TAKEOVER_STALE:
                    guard.unlink(missing_ok=True)
            except FileNotFoundError:
                pass
            return False
        os.close(fd)
        try:
            if _read(lock) != info or _stale(lock, info) is None:  # it changed hands meanwhile
                return False
            tmp = lock.with_name(f"{lock.name}.{self.token}")
            tmp.write_text(self._info())
            os.replace(tmp, lock)
            sys.stderr.write(f"note: {lock}: taking over a stale lock ({why})\n")
            return True
        finally:
            guard.unlink(missing_ok=True)

    def _take(self, lock: Path) -> None:
        for _ in range(3):
            if self._create(lock):
                return
            info = _read(lock)
            why = _stale(lock, info)
            if why == "gone":
                continue
            if why is None:
                who = f"pid {info.get('pid')} on {info.get('host')}, since {time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(info.get('started', 0)))}" \
                    if info else "a run starting now"
                target = lock.with_name(lock.name[: -len(".lock")])
                raise PatchcloudLockedError(f"{target}: another patchcloud run ({who}) is writing it; wait for it to end "
                                            f"(or, if that run is gone, remove {lock})")
            if self._take_over(lock, info, why):
                return
        raise PatchcloudLockedError(f"{lock}: another patchcloud run took this lock at the same time; try again")

    def acquire(self) -> "RunLock":
        try:
            for lock in self.locks:
                self._take(lock)
                self.held.append(lock)
        except BaseException:
            self.release()
            raise
        self._beat = threading.Thread(target=self._heartbeat, name="patchcloud-lock", daemon=True)
        self._beat.start()
        return self

    def _heartbeat(self) -> None:
        while not self._stop.wait(HEARTBEAT):
            for lock in self.held:
                try:
                    os.utime(lock)
                except OSError:
                    pass

    def release(self) -> None:
        """Remove the locks this run holds (not one another run has taken over meanwhile)."""
        self._stop.set()
        if self._beat is not None:
            self._beat.join()
            self._beat = None
        for lock in self.held:
            if (_read(lock) or {}).get("token") == self.token:
                lock.unlink(missing_ok=True)
        self.held = []

    def __enter__(self) -> "RunLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()
