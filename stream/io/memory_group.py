"""A store held in this process's memory: what small inputs run on instead of a zarr store on disk.

:class:`MemoryGroup` and :class:`MemoryArray` have the few methods of
``zarr.Group`` and ``zarr.Array`` that :class:`patchcloud.stream.Store`
uses (attributes, nested groups, arrays read, written and appended by
rows), over numpy arrays, so a job runs the same code, with the same
results, whether its store is on disk or here; without zarr's encoding,
files and event loop.  Groups are named by a URL ``memory://NAME`` and
live in this process only: only the inline (synchronous) scheduler can
use them, whose tasks may run side by side on threads: what changes the
tree of groups and arrays, and appends, hold a lock.

>>> g = create("memory://doctest")
>>> g.create_array("tiles/t+0+0+0/xyz", shape=(0, 3), dtype="int32", chunks=(4, 3))
MemoryArray(shape=(0, 3), dtype=int32)
>>> g["tiles/t+0+0+0/xyz"].append(np.ones((2, 3), dtype="int32"), axis=0)
>>> int(g["tiles/t+0+0+0"]["xyz"][...].sum())
6
>>> g.attrs.update(steps={"tile": True}); dict(g.attrs)
{'steps': {'tile': True}}
>>> drop("memory://doctest"); exists("memory://doctest")
False
"""

from __future__ import annotations

import json
import threading

import numpy as np

__all__ = ["PREFIX", "MemoryGroup", "MemoryArray", "MemoryAttrs", "is_memory_url", "create", "open_group", "exists", "drop", "urls"]

#: URLs of in-memory stores start with this.
PREFIX = "memory://"

_GROUPS: dict[str, "MemoryGroup"] = {}
_LOCK = threading.Lock()
#: Held while a group's tree of children changes or an array grows (tasks on threads write side by side).
_TREE = threading.RLock()


def is_memory_url(url) -> bool:
    """Whether ``url`` names an in-memory store (``memory://NAME``)."""
    return isinstance(url, str) and url.startswith(PREFIX)


class MemoryAttrs:
    """A group's attributes: values go in and come out as JSON copies, as they would from a file."""

    def __init__(self) -> None:
        self._values: dict = {}

    def update(self, *args, **kwargs) -> None:
        self._values.update(json.loads(json.dumps(dict(*args, **kwargs))))

    def keys(self):
        return list(self._values)

    def __iter__(self):
        return iter(list(self._values))

    def __len__(self) -> int:
        return len(self._values)

    def __contains__(self, key) -> bool:
        return key in self._values

    def __getitem__(self, key):
        return json.loads(json.dumps(self._values[key]))

    def get(self, key, default=None):
        return self[key] if key in self._values else default


class MemoryArray:
    """A numpy array read and written by rows; appending grows it geometrically (amortised copies)."""

    def __init__(self, shape: tuple, dtype, data: np.ndarray | None = None) -> None:
        if data is None:
            self._data = np.zeros(shape, dtype=dtype)
        else:  # a copy: the caller keeps its array (and may change it)
            self._data = np.array(data, dtype=dtype, copy=True)
            if self._data.shape != tuple(shape):
                raise ValueError(f"data of shape {self._data.shape} for an array of shape {tuple(shape)}")
        self._n = int(shape[0]) if len(shape) else 0

    @property
    def shape(self) -> tuple:
        return (self._n,) + self._data.shape[1:]

    @property
    def dtype(self) -> np.dtype:
        return self._data.dtype

    def __repr__(self) -> str:
        return f"MemoryArray(shape={self.shape}, dtype={self.dtype})"

    def __getitem__(self, key) -> np.ndarray:
        """A copy, as a read from a file would give (the caller may change it)."""
        return np.array(self._data[: self._n][key], copy=True)

    def __setitem__(self, key, values) -> None:
        self._data[: self._n][key] = values

    def append(self, values: np.ndarray, axis: int = 0) -> None:
        if axis != 0:
            raise ValueError("in-memory arrays append rows only (axis=0)")
        values = np.asarray(values, dtype=self.dtype)
        with _TREE:
            n = self._n + values.shape[0]
            if n > self._data.shape[0]:
                grown = np.zeros((max(n, 2 * self._data.shape[0]),) + self._data.shape[1:], dtype=self.dtype)
                grown[: self._n] = self._data[: self._n]
                self._data = grown
            self._data[self._n : n] = values
            self._n = n


class MemoryGroup:
    """Nested groups and arrays by ``/``-separated paths, with attributes; and raw blobs by key (at the root)."""

    def __init__(self) -> None:
        self.attrs = MemoryAttrs()
        self._children: dict[str, MemoryGroup | MemoryArray] = {}
        self.blobs: dict[str, bytes] = {}

    def _walk(self, path: str, make: bool) -> tuple["MemoryGroup", str]:
        """The group holding the last part of ``path`` (made on the way when ``make``: callers hold the lock), and that part."""
        parts = [p for p in path.split("/") if p]
        if not parts:
            raise KeyError(path)
        g = self
        for p in parts[:-1]:
            child = g._children.get(p)
            if child is None:
                if not make:
                    raise KeyError(path)
                child = g._children[p] = MemoryGroup()
            if not isinstance(child, MemoryGroup):
                raise KeyError(path)
            g = child
        return g, parts[-1]

    def __getitem__(self, path: str):
        g, name = self._walk(path, make=False)
        if name not in g._children:
            raise KeyError(path)
        return g._children[name]

    def __contains__(self, path: str) -> bool:
        try:
            self[path]
        except KeyError:
            return False
        return True

    def __delitem__(self, path: str) -> None:
        with _TREE:
            g, name = self._walk(path, make=False)
            del g._children[name]

    def require_group(self, path: str) -> "MemoryGroup":
        with _TREE:
            g, name = self._walk(path, make=True)
            child = g._children.get(name)
            if child is None:
                child = g._children[name] = MemoryGroup()
        if not isinstance(child, MemoryGroup):
            raise TypeError(f"{path} is an array, not a group")
        return child

    def create_array(self, path: str, *, shape: tuple, dtype, chunks=None, overwrite: bool = False, data=None) -> MemoryArray:
        """A new array at ``path``: of zeros, or a copy of ``data`` (of that shape and dtype) made in one pass.

        ``chunks`` is accepted for zarr's signature and unused.
        """
        a = MemoryArray(tuple(shape), dtype, data)
        with _TREE:
            g, name = self._walk(path, make=True)
            if name in g._children and not overwrite:
                raise FileExistsError(f"{path} exists")
            g._children[name] = a
        return a

    def delete_prefix(self, prefix: str) -> None:
        """Remove the blobs under ``prefix/`` (and a group or array there)."""
        with _TREE:
            for key in [k for k in self.blobs if k.startswith(prefix.rstrip("/") + "/")]:
                del self.blobs[key]
            if prefix in self:
                del self[prefix]


def create(url: str, overwrite: bool = False) -> MemoryGroup:
    """A new, empty group named ``url``; FileExistsError when there is one and not ``overwrite``."""
    with _LOCK:
        if url in _GROUPS and not overwrite:
            raise FileExistsError(f"{url} exists")
        g = _GROUPS[url] = MemoryGroup()
    return g


def open_group(url: str) -> MemoryGroup:
    """The group named ``url``; FileNotFoundError when there is none in this process."""
    g = _GROUPS.get(url)
    if g is None:
        raise FileNotFoundError(f"no in-memory store {url} in this process")
    return g


def exists(url: str) -> bool:
    return url in _GROUPS


def urls() -> list[str]:
    """The in-memory stores of this process (a finished run leaves none)."""
    return sorted(_GROUPS)


def drop(url: str) -> None:
    """Forget the group named ``url`` (its memory is freed); nothing if there is none."""
    with _LOCK:
        _GROUPS.pop(url, None)
