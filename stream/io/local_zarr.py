"""The arrays and groups of a store on a local disk, read and written directly in zarr's format 3.

A tile's task reads and writes a few dozen small arrays and attributes.
Through zarr each of those costs about 2 ms whatever its size (the array's
metadata looked up and parsed, its chunks fetched through zarr's event
loop): 40 reads, 80 ms, for the finish of a tile whose compute takes 4 ms
(the 1M city in 8 m tiles: 1,194 tiles, 367 s on two workers, nearly all
of it the store's own overhead).  On a local disk this module does the
same reads and writes with plain file calls (0.06 ms a small array) and
the same bytes on disk:

- an array is its directory holding ``zarr.json`` (shape, data type, a
  regular chunk grid along the first axis, the ``bytes`` codec then
  ``blosc``, the attributes) and one file per chunk, ``c/K/0...``; the
  last chunk is padded to the full chunk shape with the fill value (0),
  as zarr writes it; a chunk file that is missing reads as the fill
  value, as in zarr;
- chunks are coded by numcodecs' Blosc with the configuration zarr gives
  it (:func:`patchcloud.stream.io.store.codec_for`: LZ4, level 5, byte
  shuffle, the item size), so zarr reads what is written here and this
  module reads what zarr wrote;
- a group is its directory holding ``zarr.json`` with its attributes;
- every file is written under a temporary name, then renamed (what zarr's
  local store does): a reader sees the old file or the new one, whole.

Only what patchcloud's stores hold goes this way (numeric data types,
chunks along the first axis, those two codecs); :meth:`LocalZarr.array`
returns None for anything else, and the store reads it through zarr.
"""

from __future__ import annotations

import json
import os
import shutil
import threading
import uuid
from pathlib import Path

import numpy as np

__all__ = ["LocalZarr", "LocalArray", "local_root", "settle", "DATA_TYPES", "BLOSC", "TRASH"]

#: The data types read and written directly (zarr's names are numpy's).
DATA_TYPES = ("bool", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "float32", "float64")
#: How a store codes its chunks (zarr's ``BloscCodec`` arguments, the item size aside): LZ4, level 5, byte shuffle.
#: :func:`patchcloud.stream.io.store.codec_for` makes zarr's codec from it; :func:`array_metadata` writes it.
BLOSC = {"cname": "lz4", "clevel": 5, "shuffle": "shuffle"}
#: Blosc's shuffle modes by zarr's names.
_SHUFFLE = {"noshuffle": 0, "shuffle": 1, "bitshuffle": 2}
#: The directory of a store's root where :meth:`LocalZarr.delete` moves what it removes in the background.
TRASH = ".removing"
#: The threads removing nodes in the background, by store root (:func:`settle` waits for them).
_REMOVING: dict[str, list[threading.Thread]] = {}
_REMOVING_LOCK = threading.Lock()


def local_root(group) -> Path | None:
    """The directory of a zarr group opened on a local disk store, or None (another store)."""
    try:
        from zarr.storage import LocalStore
    except ImportError:  # pragma: no cover - zarr 3 has it
        return None
    store = getattr(group, "store", None)
    if not isinstance(store, LocalStore):
        return None
    root = Path(store.root)
    return root / group.path if group.path else root


def _write_file(path: str, data: bytes) -> None:
    """Write ``data`` to ``path`` under a temporary name, then rename it (its directory made if needed)."""
    tmp = f"{path}.{uuid.uuid4().hex}.partial"
    try:
        f = open(tmp, "wb")
    except FileNotFoundError:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        f = open(tmp, "wb")
    try:
        with f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:  # nothing half-written left behind
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def _chunk_key(k: int, ndim: int) -> str:
    """The key of chunk ``k`` (along the first axis) of an array of ``ndim`` dimensions: ``c/K``, then ``/0`` a dimension.

    >>> _chunk_key(3, 1), _chunk_key(3, 2)
    ('c/3', 'c/3/0')
    """
    return "/".join(["c", str(k)] + ["0"] * (ndim - 1))


def _read_bytes(path: str) -> bytes | None:
    """The bytes of the file at ``path``, None where there is none."""
    try:
        with open(path, "rb") as f:
            return f.read()
    except (FileNotFoundError, NotADirectoryError, IsADirectoryError):
        return None


def _read_json(path: str) -> dict | None:
    data = _read_bytes(path)
    return None if data is None else json.loads(data)


#: The metadata of stores' roots last read in this process, by path: ((inode, size, mtime), parsed JSON).  A root's
#: attributes list every tile (tens of kilobytes) and every task reads them; a file replaced (:func:`_write_file`) has
#: another inode, so an entry is used only while the file it was read from is there unchanged.
_ROOTS: dict[str, tuple[tuple, dict]] = {}


def _read_root_json(path: str) -> dict | None:
    """:func:`_read_json` of a store's root metadata, parsed once per version of the file in this process (a copy)."""
    try:
        f = open(path, "rb")
    except (FileNotFoundError, NotADirectoryError):
        return None
    with f:
        st = os.fstat(f.fileno())  # of the file opened: the key and the bytes are of one version
        key = (st.st_ino, st.st_size, st.st_mtime_ns)
        hit = _ROOTS.get(path)
        if hit is None or hit[0] != key:
            m = json.loads(f.read())
            if len(_ROOTS) > 64:
                _ROOTS.clear()
            _ROOTS[path] = hit = (key, m)
    return _copy(hit[1])


def _copy(m: dict) -> dict:
    """A copy of parsed metadata deep enough that a caller changing its attributes leaves the cached one as it was."""
    out = dict(m)
    if isinstance(m.get("attributes"), dict):
        out["attributes"] = {k: (v.copy() if isinstance(v, (dict, list)) else v) for k, v in m["attributes"].items()}
    return out


def _blosc(configuration: dict):
    """numcodecs' Blosc as zarr configures it (a numcodecs before 0.16 takes the item size from the array coded)."""
    from numcodecs import Blosc

    kw = dict(cname=configuration["cname"], clevel=int(configuration["clevel"]), shuffle=_SHUFFLE[configuration["shuffle"]],
              blocksize=int(configuration.get("blocksize", 0)))
    try:
        return Blosc(**kw, typesize=configuration.get("typesize"))
    except TypeError:
        return Blosc(**kw)


def array_metadata(shape: tuple, dtype: np.dtype, chunks: tuple, attributes: dict) -> dict:
    """The ``zarr.json`` of an array as zarr 3 writes it for ``create_array(..., compressors=codec_for(dtype))``.

    >>> m = array_metadata((5, 3), np.dtype("int32"), (5, 3), {"crc32": [1]})
    >>> m["codecs"][0], m["codecs"][1]["configuration"]["typesize"], m["fill_value"]
    ({'name': 'bytes', 'configuration': {'endian': 'little'}}, 4, 0)
    """
    dtype = np.dtype(dtype)
    fill = False if dtype.kind == "b" else (0.0 if dtype.kind == "f" else 0)
    # zarr names no byte order for one-byte types
    raw = {"name": "bytes"} if dtype.itemsize == 1 else {"name": "bytes", "configuration": {"endian": "little"}}
    return {
        "shape": list(shape),
        "data_type": dtype.name,
        "chunk_grid": {"name": "regular", "configuration": {"chunk_shape": list(chunks)}},
        "chunk_key_encoding": {"name": "default", "configuration": {"separator": "/"}},
        "fill_value": fill,
        "codecs": [
            raw,
            {"name": "blosc", "configuration": {"typesize": dtype.itemsize, **BLOSC, "blocksize": 0}},
        ],
        "attributes": attributes,
        "zarr_format": 3,
        "node_type": "array",
        "storage_transformers": [],
    }


GROUP_METADATA = {"attributes": {}, "zarr_format": 3, "node_type": "group"}


class LocalArray:
    """An array of a local store as :meth:`patchcloud.stream.io.store.Store` reads it: ``shape``, ``chunks``, ``attrs``,
    ``path`` and rows by a slice of step 1 (``a[i:j]``), as a zarr array has them."""

    def __init__(self, directory: str, path: str, meta: dict) -> None:
        self.directory = directory
        self.path = path
        self.shape = tuple(int(v) for v in meta["shape"])
        self.chunks = tuple(int(v) for v in meta["chunk_grid"]["configuration"]["chunk_shape"])
        self.dtype = np.dtype(meta["data_type"])
        self.attrs = meta.get("attributes", {})
        self._codec = _blosc(meta["codecs"][1]["configuration"])

    def _chunk(self, k: int) -> np.ndarray:
        """Chunk ``k`` (its rows within the array, unpadded): the fill value where its file is missing."""
        size = self.chunks[0]
        rows = min(size, self.shape[0] - k * size)
        raw = _read_bytes(f"{self.directory}/{_chunk_key(k, len(self.shape))}")
        if raw is None:
            return np.zeros((rows,) + self.shape[1:], dtype=self.dtype)
        out = np.frombuffer(self._codec.decode(raw), dtype=self.dtype.newbyteorder("<")).reshape(self.chunks)
        return out[:rows].astype(self.dtype, copy=False)

    def __getitem__(self, rows: slice) -> np.ndarray:
        start, stop, step = rows.indices(self.shape[0])
        if step != 1:
            raise ValueError(f"rows must be a slice of step 1, got {rows}")
        if stop <= start:
            return np.zeros((0,) + self.shape[1:], dtype=self.dtype)
        size = self.chunks[0]
        first, last = start // size, -(-stop // size)
        parts = [self._chunk(k) for k in range(first, last)]
        data = parts[0] if len(parts) == 1 else np.concatenate(parts)
        out = data[start - first * size : stop - first * size]
        return out if out.flags.writeable else out.copy()


class LocalZarr:
    """The nodes of one zarr group on a local disk (``root``: its directory), by path within it.

    Examples
    --------
    >>> import tempfile
    >>> z = LocalZarr(Path(tempfile.mkdtemp()))
    >>> z.write_array("tiles/t+0+0+0/rank", np.arange(5, dtype=np.uint32), 4, {"crc32": []})
    >>> z.array("tiles/t+0+0+0/rank")[1:5]
    array([1, 2, 3, 4], dtype=uint32)
    >>> z.update_group_attrs("tiles/t+0+0+0", {"count": 5}); z.group_attrs("tiles/t+0+0+0")
    {'count': 5}
    """

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = os.fspath(root)
        self._groups: set[str] = set()

    def _path(self, path: str, *more: str) -> str:
        return "/".join([self.root, *(p for p in (path, *more) if p)])

    # -- nodes -----------------------------------------------------------------
    def meta(self, path: str) -> dict | None:
        """The ``zarr.json`` of the node at ``path``, or None where there is none."""
        if not path:
            return _read_root_json(self._path("", "zarr.json"))
        return _read_json(self._path(path, "zarr.json"))

    def exists(self, path: str) -> bool:
        return os.path.isfile(self._path(path, "zarr.json"))

    def delete(self, path: str, wait: bool = True) -> None:
        """Remove the node at ``path`` (array or group, with what it holds) if there.

        With ``wait=False`` the node is renamed into the root's :data:`TRASH`
        directory (at once: it is gone from the store) and its files are
        unlinked on a thread, while the caller gets on (the fragments of a
        10M-point file's parts are 240 MB: unlinking them took 0.1-0.3 s
        between two steps, with the workers idle).  :func:`settle` waits for
        that thread and empties the trash, a killed run's too.
        """
        if not path:
            return
        where = self._path(path)
        if wait or not os.path.lexists(where):
            shutil.rmtree(where, ignore_errors=True)
            return
        trash = self._path(TRASH)
        gone = f"{trash}/{path.replace('/', '+')}-{uuid.uuid4().hex}"
        try:
            os.makedirs(trash, exist_ok=True)
            os.replace(where, gone)
        except OSError:  # (a file system that cannot rename it): removed here and now
            shutil.rmtree(where, ignore_errors=True)
            return
        self._groups = {g for g in self._groups if g != path and not g.startswith(path + "/")}
        thread = threading.Thread(target=shutil.rmtree, args=(gone,), kwargs=dict(ignore_errors=True), name="patchcloud-remove",
                                  daemon=True)
        with _REMOVING_LOCK:
            _REMOVING.setdefault(os.path.abspath(self.root), []).append(thread)
        thread.start()

    # -- groups ----------------------------------------------------------------
    def ensure_group(self, path: str) -> None:
        """Make the group at ``path`` and the groups above it where they are missing (no attributes)."""
        if path in self._groups:
            return
        parts = [p for p in path.split("/") if p]
        for k in range(1, len(parts) + 1):
            sub = "/".join(parts[:k])
            if sub not in self._groups and not self.exists(sub):
                _write_file(self._path(sub, "zarr.json"), json.dumps(GROUP_METADATA).encode())
            self._groups.add(sub)

    def group_attrs(self, path: str) -> dict | None:
        """The attributes of the group at ``path``, or None where there is no group."""
        m = self.meta(path)
        return None if m is None or m.get("node_type") != "group" else dict(m.get("attributes", {}))

    def update_group_attrs(self, path: str, attrs: dict, now: dict | None = None) -> None:
        """Add ``attrs`` to those of the group at ``path`` (``now``: its attributes as just read, else read here), in one
        write of its metadata; the group made where missing."""
        m = self.meta(path)
        if m is None or m.get("node_type") != "group":
            self.ensure_group(path)
            m = dict(GROUP_METADATA)
        current = dict(m.get("attributes", {})) if now is None else dict(now)
        m = dict(m, attributes={**current, **attrs})
        _write_file(self._path(path, "zarr.json"), json.dumps(m).encode())

    # -- arrays ----------------------------------------------------------------
    def array(self, path: str) -> LocalArray | None:
        """The array at ``path`` if this module reads it (see the module's notes), else None (missing, or for zarr)."""
        m = self.meta(path)
        if m is None or not readable(m):
            return None
        return LocalArray(self._path(path), path, m)

    def write_array(self, path: str, values: np.ndarray, rows: int, attributes: dict) -> None:
        """Write ``values`` as the array at ``path`` (replacing what is there), in chunks of ``rows`` rows along the first
        axis, its metadata holding ``attributes``; the groups above it made where missing."""
        values = np.ascontiguousarray(values)
        if values.dtype.name not in DATA_TYPES or values.ndim < 1:
            raise ValueError(f"{path}: cannot write a {values.dtype} array of {values.ndim} dimensions directly")
        values = values.astype(values.dtype.newbyteorder("<"), copy=False)
        directory = self._path(path)
        parent = path.rsplit("/", 1)[0] if "/" in path else ""
        if parent:
            self.ensure_group(parent)
        if os.path.isdir(directory):
            shutil.rmtree(directory, ignore_errors=True)  # no chunk of a larger array left behind
        chunks = (rows,) + values.shape[1:]
        meta = array_metadata(values.shape, values.dtype, chunks, attributes)
        codec = _blosc(meta["codecs"][1]["configuration"])
        for k in range(-(-values.shape[0] // rows)):  # (_write_file makes each chunk's directory)
            block = values[k * rows : (k + 1) * rows]
            if block.shape[0] < rows:  # the last chunk padded with the fill value, as zarr writes it
                block = np.concatenate([block, np.zeros((rows - block.shape[0],) + block.shape[1:], dtype=block.dtype)])
            _write_file(f"{directory}/{_chunk_key(k, values.ndim)}", codec.encode(np.ascontiguousarray(block)))
        _write_file(f"{directory}/zarr.json", json.dumps(meta).encode())

    # -- raw bytes (the store's blobs) -------------------------------------------
    def put_bytes(self, key: str, data: bytes) -> None:
        _write_file(self._path(key), data)

    def get_bytes(self, key: str) -> bytes | None:
        return _read_bytes(self._path(key))

    def remove_dir(self, prefix: str) -> None:
        if prefix:
            shutil.rmtree(self._path(prefix), ignore_errors=True)


def settle(root: str | os.PathLike) -> None:
    """Wait for the background removals of the store at ``root`` (:meth:`LocalZarr.delete` with ``wait=False``), then
    remove its :data:`TRASH` directory: what they left, or what a run killed meanwhile left."""
    key = os.path.abspath(os.fspath(root))
    with _REMOVING_LOCK:
        threads = _REMOVING.pop(key, [])
    for t in threads:
        t.join()
    trash = os.path.join(key, TRASH)
    if os.path.isdir(trash):
        shutil.rmtree(trash, ignore_errors=True)


def readable(meta: dict) -> bool:
    """Whether an array's ``zarr.json`` is one :class:`LocalArray` reads: a numeric type, a regular grid chunked along
    the first axis only, little-endian ``bytes`` then ``blosc``, the default chunk keys with "/", fill value 0."""
    try:
        if meta.get("node_type") != "array" or meta.get("zarr_format") != 3 or meta.get("data_type") not in DATA_TYPES:
            return False
        shape, grid = meta["shape"], meta["chunk_grid"]
        if grid.get("name") != "regular" or len(shape) < 1:
            return False
        chunks = grid["configuration"]["chunk_shape"]
        if len(chunks) != len(shape) or list(chunks[1:]) != list(shape[1:]) or chunks[0] < 1:
            return False
        keys = meta["chunk_key_encoding"]
        if keys.get("name") != "default" or keys.get("configuration", {}).get("separator", "/") != "/":
            return False
        codecs = meta["codecs"]
        if len(codecs) != 2 or codecs[0].get("name") != "bytes" or codecs[1].get("name") != "blosc":
            return False
        if codecs[0].get("configuration", {}).get("endian", "little") != "little":
            return False
        if codecs[1]["configuration"].get("shuffle") not in _SHUFFLE or meta.get("storage_transformers"):
            return False
        return meta.get("fill_value") in (0, 0.0, False)
    except (KeyError, TypeError, AttributeError):
        return False
