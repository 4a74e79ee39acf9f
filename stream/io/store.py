"""The zarr store that holds a cloud cut into tiles, and what has been computed on them.

Layout (zarr format 3; a local path or any fsspec URL the workers can reach;
or ``memory://NAME``, a store in this process's memory for inline runs:
:mod:`.memory_group`)::

    store/                       attrs: format, version, uid, catalog (the input files), source (the first), grid, steps done
      index/chunk_tile           (K, 3) int64: input chunk, tile, points of the chunk in the tile
      tiles/<name>/              attrs: ijk, count, done (per step)
        xyz                      (n, 3) int32  LAS integer coordinates, sorted by octree key
        rank                     (n,) uint32   position of each point among the tile's points in input order
        patches                  (P, 29) float64  the patch table (see :func:`table_to_array`)
        links, agreement, score  the tile's orientation forest (see patchcloud.core.tiles.TileFit)
        skin, skin_patch         points near the tile's faces and their patch rows
        sign                     (P,) int8    orientation of every patch after the seam pass
      seams/                     the seam pass's working blobs (see patchcloud.stream.jobs.seams), removed after it
        normal, curvature,       results in the tile's input order
        method, patch

Tiles are the cubes of a grid of edge ``tile_size`` (a power of two,
metres) anchored at ``origin`` (a multiple of :data:`ANCHOR` metres), so
every tile is a cube of one global octree whatever the tile size, and a
tile's face is an octree face.  Coordinates stay exact: the LAS integers
are stored; the float64 local frame is ``X * scale + offset - origin``.

On a local disk (a path or ``file://``) the store reads and writes these
files itself, in the same format (:mod:`.local_zarr`: zarr's 2 ms a call
was most of a small tile's task), and no process of the run imports zarr;
on other fsspec URLs, and for arrays of other codecs, zarr does.

Compression: every array on disk is stored through Blosc's LZ4 with a
byte shuffle (:func:`codec_for`), which on the 10-million-point city wrote
a smaller store than zarr's default Zstd (239 against 246 MB) and spent
less time (interleaved whole runs, 2 workers: 19.6-22.0 s against
22.7-25.2 s); stores written with another codec are read as they are.

Integrity: every array on disk carries, in its attributes, the crc32 of
each of its chunks' data, the store's ``uid`` and its own path; every read checks the
chunks it touches (:meth:`Store.read`, :meth:`Store.get`), and every blob
ends in its crc32.  A chunk altered or deleted (zarr reads a deleted chunk
as zeros), an array missing, one copied from another store or moved from
another tile or name is a
:class:`PatchcloudStoreError` naming the tile and the array, never a
silent zero.  Stores held in memory are not checked.
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import uuid
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from patchcloud.core import GRID_ANCHOR, PatchcloudIOError, PatchcloudValueError, PatchTable, cell_indices, frame_shift, local_coordinates

from . import local_zarr, memory_group
from .catalog import Catalog
from .local_zarr import BLOSC, DATA_TYPES, LocalZarr, local_root

__all__ = [
    "Store", "Grid", "ANCHOR", "FORMAT", "VERSION", "table_to_array", "array_to_table", "tile_name", "PatchcloudStoreError",
    "chunk_checksums", "codec_for", "limit_zarr_threads", "REMOVING_SUFFIX", "removing_path", "remove_store_dir", "piece_name", "piece_rows",
]

FORMAT = "patchcloud-store"
#: 2: arrays carry chunk checksums and the store's uid; 3: and their own path (an array moved to another tile is refused);
#: 4: normals of edge and sparse leaves from cell moments (NormalMethod 4), so a version-3 store's normals are not reused.
#: 5: the input's last parts cut finer (:func:`patchcloud.stream.engine.ingest.part_ranges`), so a version-4 store's
#: parts, which its index and the export follow, are not this version's.
VERSION = 5
#: What a damaged store's error tells the user to do.
START_OVER = "remove the store to start over"
#: What a store's directory holds beside its root metadata: one of them there, zarr.json not, is a damaged store.
STORE_PARTS = ("tiles", "index")
#: The grid origin is a multiple of this (metres), so grids of every power-of-two tile size up to it align (core's
#: ``root="grid"`` is the cube they are cells of).
ANCHOR = GRID_ANCHOR
#: Largest tile size (metres).
MAX_TILE = ANCHOR


class PatchcloudStoreError(PatchcloudIOError):
    """The store is damaged: an array is missing, its data is not what was written (a checksum differs, a chunk cannot be
    decoded), or it was written by another store.  The message names the store, the tile or path, and the array."""


def chunk_checksums(values: np.ndarray, rows: int) -> list[int]:
    """The crc32 of each block of ``rows`` rows of ``values`` (its chunks' data as written), in order.

    >>> chunk_checksums(np.arange(5, dtype="<i4"), 2) == [zlib.crc32(np.arange(k, min(k + 2, 5), dtype="<i4")) for k in (0, 2, 4)]
    True
    """
    v = np.ascontiguousarray(values)
    return [zlib.crc32(v[k : k + rows]) for k in range(0, v.shape[0], rows)]


@dataclass(frozen=True)
class Grid:
    """The tile grid and the local frame: ``local = (X + base) * scale + shift``, ``offset - origin`` split into whole
    steps ``base`` and a rest ``shift`` (:func:`~patchcloud.core.frame_shift`: 0 for an offset on the grid, so a point's
    local coordinates, and its tile, do not depend on the file's offset)."""

    origin: tuple[float, float, float]
    tile_size: float
    scale: tuple[float, float, float]
    offset: tuple[float, float, float]

    def local(self, xyz_int: np.ndarray) -> np.ndarray:
        """(n, 3) float64 local coordinates (metres) of LAS integer coordinates."""
        base, shift = self.frame
        return local_coordinates(xyz_int, self.scale, shift, base)

    @property
    def frame(self) -> tuple[np.ndarray, np.ndarray]:
        """``(base, shift)``, (3,) int64 and (3,) float64: ``offset - origin`` as ``base * scale + shift``
        (:func:`~patchcloud.core.frame_shift`)."""
        return frame_shift(self.offset, self.origin, self.scale)

    def tiles_of(self, xyz_int: np.ndarray) -> np.ndarray:
        """(n, 3) int64 tile indices of LAS integer coordinates: ``floor(local(xyz_int) / tile_size)``, in one pass."""
        base, shift = self.frame
        return cell_indices(xyz_int, self.scale, shift, self.tile_size, base)

    def corner(self, ijk) -> np.ndarray:
        """Local minimum corner of tile ``ijk``."""
        return np.asarray(ijk, dtype=np.float64) * self.tile_size

    def to_json(self) -> dict:
        return dict(origin=list(self.origin), tile_size=self.tile_size, scale=list(self.scale), offset=list(self.offset))

    @classmethod
    def from_json(cls, d: dict) -> "Grid":
        return cls(tuple(d["origin"]), float(d["tile_size"]), tuple(d["scale"]), tuple(d["offset"]))


def tile_name(ijk) -> str:
    """Name of tile ``ijk`` in the store, e.g. ``t+3-1+0``."""
    i, j, k = (int(v) for v in ijk)
    return f"t{i:+d}{j:+d}{k:+d}"


#: Columns of the patch table array.
_TABLE_COLS = (
    ("level", 1), ("ijk", 3), ("count", 1), ("centroid", 3), ("frame", 9), ("eigenvalues", 3), ("coeffs", 6),
    ("rmse", 1), ("kind", 1),
)


def table_to_array(t: PatchTable) -> np.ndarray:
    """The rows of a patch table as one (P, 28) float64 array (exact: integers below 2**53)."""
    P = len(t)
    cols = [np.asarray(getattr(t, name), dtype=np.float64).reshape(P, width) for name, width in _TABLE_COLS]
    return np.concatenate(cols, axis=1) if P else np.zeros((0, sum(w for _, w in _TABLE_COLS)))


def array_to_table(a: np.ndarray, corner: np.ndarray, edge: float) -> PatchTable:
    """Inverse of :func:`table_to_array`."""
    out = {}
    c = 0
    for name, width in _TABLE_COLS:
        out[name] = a[:, c : c + width]
        c += width
    P = a.shape[0]
    return PatchTable(
        root_corner=np.asarray(corner, dtype=np.float64),
        root_edge=float(edge),
        level=out["level"][:, 0].astype(np.uint8),
        ijk=out["ijk"].astype(np.int64),
        count=out["count"][:, 0].astype(np.int64),
        centroid=np.ascontiguousarray(out["centroid"]),
        frame=np.ascontiguousarray(out["frame"]).reshape(P, 3, 3),
        eigenvalues=np.ascontiguousarray(out["eigenvalues"]),
        coeffs=np.ascontiguousarray(out["coeffs"]),
        rmse=np.ascontiguousarray(out["rmse"][:, 0]),
        kind=out["kind"][:, 0].astype(np.uint8),
    )


def piece_name(name: str, j: int, k: int) -> str:
    """The array holding piece ``j`` of ``k`` of a tile's array ``name`` (its rows ``piece_rows(n, j, k)``).

    >>> piece_name("normal", 1, 3)
    'normal@1of3'
    """
    return f"{name}@{int(j)}of{int(k)}"


def piece_rows(n: int, j: int, k: int) -> tuple[int, int]:
    """Rows ``(start, stop)`` of piece ``j`` of ``k`` of ``n`` rows: ``j n // k`` to ``(j + 1) n // k``.

    >>> [piece_rows(10, j, 3) for j in range(3)]
    [(0, 3), (3, 6), (6, 10)]
    """
    if not 0 <= j < k:
        raise ValueError(f"piece must be j of k with 0 <= j < k, got {j} of {k}")
    return int(j) * int(n) // int(k), (int(j) + 1) * int(n) // int(k)


def _set_attrs(group, attrs: dict) -> None:
    """Add ``attrs`` to the attributes of ``group`` in one write of its metadata.

    zarr's ``group.attrs.update(a=..., b=...)`` writes the group's metadata
    once per key: a run killed between two of those writes would leave, say,
    a tile's step marked done without the results recorded with it, and the
    rerun would stop on the missing key.
    """
    if isinstance(group, memory_group.MemoryGroup):
        group.attrs.update(attrs)
    else:
        group.update_attributes(attrs)


def a_path(group, name: str) -> str:
    """The path (within its store) of array ``name`` of ``group``, as zarr's ``Array.path`` states it.

    >>> import zarr
    >>> a_path(zarr.open_group(zarr.storage.MemoryStore()).require_group("tiles/t+0+0+0"), "xyz")
    'tiles/t+0+0+0/xyz'
    """
    return f"{group.path}/{name}" if group.path else name


def _zarr():
    """zarr, imported on first use: runs in memory never import it."""
    import zarr

    return zarr


def _local_dir(url: str) -> Path | None:
    """The directory of a local path or ``file://`` URL, None for other URLs (fsspec's, ``memory://``)."""
    if "://" in url and not url.startswith("file://"):
        return None
    return Path(url.removeprefix("file://"))


def _occupied(url: str) -> bool:
    """Whether a local path (or ``file://`` URL) holds a file or a non-empty directory; False for other URLs."""
    p = _local_dir(url)
    return p is not None and p.exists() and (p.is_file() or any(p.iterdir()))


#: What a store being removed is renamed to first (its path plus this).
REMOVING_SUFFIX = ".removing"


def removing_path(url: str) -> str:
    """Where the local store ``url`` goes while :meth:`Store.discard` removes it."""
    return url.rstrip("/\\") + REMOVING_SUFFIX


def remove_store_dir(path: str | os.PathLike) -> None:
    """Remove a store's directory: its tiles and working arrays first, its record of the outputs and root metadata last.

    The tiles' directories are removed by a few threads side by side (the
    kernel frees each file's blocks as it unlinks it: 0.31 s for the 10M
    city's store of 239 MB, one thread).
    """
    from concurrent.futures import ThreadPoolExecutor

    p = Path(path)
    if not p.is_dir():
        return
    tiles = p / "tiles"
    if tiles.is_dir() and not tiles.is_symlink():
        dirs = [c for c in tiles.iterdir() if c.is_dir() and not c.is_symlink()]
        with ThreadPoolExecutor(max(1, min(REMOVE_THREADS, len(dirs)))) as pool:
            list(pool.map(lambda d: shutil.rmtree(d, ignore_errors=True), dirs))
    last = ("outputs", "zarr.json")
    for child in sorted(p.iterdir(), key=lambda c: (c.name in last, c.name == "zarr.json", c.name)):
        if child.is_dir() and not child.is_symlink():
            shutil.rmtree(child, ignore_errors=True)
        else:
            child.unlink(missing_ok=True)
    shutil.rmtree(p, ignore_errors=True)


#: Threads that remove a store's tiles (:func:`remove_store_dir`).
REMOVE_THREADS = 4


def limit_zarr_threads(tasks: int) -> None:
    """Have zarr (de)compress this process's chunks on ``tasks`` threads, ``tasks`` chunks at a time.

    For a process that runs ``tasks`` tasks at once, each a core's worth of
    work: a worker process of a local cluster (one), or of another cluster
    (its thread count).  zarr otherwise codes chunks on a pool of its own in
    every process (``os.cpu_count() + 4`` threads, ten chunks in flight):
    two worker processes on two cores then ran up to 12 coding threads
    beside their two tasks, which contended for the cores and each
    process's GIL (the 10M city at two workers: 15.5 s, its fit and finish
    tasks 27-41 % longer than at one worker; limited, 12.9 s, the same
    bytes).  On 16 cores the same default would put 20 threads in each of 16
    processes.  zarr makes its pool at its first read or write in the
    process: call this before (a worker's set-up does).
    """
    import zarr

    n = max(1, int(tasks))
    zarr.config.set({"threading.max_workers": n, "async.concurrency": n})


def codec_for(dtype) -> "BloscCodec":
    """The compressor of a store's arrays of ``dtype``: Blosc, LZ4 level 5, byte shuffle by the item size.

    LZ4 decodes and encodes at memory speed and the shuffle groups the
    bytes of equal weight (the coordinates' high bytes, the normals'
    exponents), so the store stays about as small as with Zstd for less
    work in every task that writes or reads it.

    >>> {k: v for k, v in codec_for(np.int32).to_dict()["configuration"].items() if k != "blocksize"}
    {'typesize': 4, 'cname': 'lz4', 'clevel': 5, 'shuffle': 'shuffle'}
    """
    from zarr.codecs import BloscCodec

    return BloscCodec(**BLOSC, typesize=np.dtype(dtype).itemsize)


class Store:
    """A tiled cloud in a zarr group (or a :class:`~.memory_group.MemoryGroup` for ``memory://`` URLs).

    Examples
    --------
    >>> import tempfile, os
    >>> s = Store.create(os.path.join(tempfile.mkdtemp(), "s.zarr"))
    >>> s.attrs["format"]
    'patchcloud-store'
    """

    #: Points per zarr chunk of per-point arrays.
    CHUNK = 1 << 16

    def __init__(self, group, url: str, root: Path | None = None, mode: str = "r+"):
        self._group = group  # None: a local store's zarr group, opened when first needed (:attr:`group`)
        self._mode = mode
        self.url = url
        self._attrs: dict | None = None
        self._groups: dict = {}
        if root is None and not isinstance(group, memory_group.MemoryGroup):
            root = local_root(group)
        #: A store on a local disk: its tiles' arrays, attributes and blobs read and written by plain file calls
        #: (:mod:`.local_zarr`: the same zarr format, without zarr's 2 ms a call); None: all through zarr.
        self._local = None if root is None else LocalZarr(root)
        #: What zarr calls the path of an array at path "p" of this group ("prefix/p" in a group below the store's root).
        self._prefix = f"{group.path}/" if getattr(group, "path", "") else ""

    @property
    def group(self):
        """The store's zarr group (or :class:`~.memory_group.MemoryGroup`); a local store's is opened on first use."""
        if self._group is None:
            self._group = _zarr().open_group(str(self._local.root), mode=self._mode)
        return self._group

    # -- opening -----------------------------------------------------------
    @classmethod
    def create(cls, url: str, overwrite: bool = False) -> "Store":
        """A new, empty store at ``url`` (replacing what is there when ``overwrite``)."""
        if not overwrite:
            cls.check_new(url)
        attrs = dict(format=FORMAT, version=VERSION, uid=uuid.uuid4().hex, steps={})
        root = _local_dir(url)
        if root is not None:  # on a local disk: its root metadata written directly (no zarr in this process)
            try:
                if overwrite:
                    remove_store_dir(root)
                elif (root / "zarr.json").exists():
                    raise FileExistsError(f"a zarr node is already at {root}")
                root.mkdir(parents=True, exist_ok=True)
                LocalZarr(root).update_group_attrs("", attrs)
            except OSError as exc:
                raise PatchcloudIOError(f"{url}: cannot create a store there ({exc})") from exc
            store = cls(None, url, root=root)
            store._attrs = attrs
            return store
        try:
            if memory_group.is_memory_url(url):
                g = memory_group.create(url, overwrite)
            else:
                g = _zarr().open_group(url, mode="w" if overwrite else "w-")
        except Exception as exc:
            raise PatchcloudIOError(f"{url}: cannot create a store there ({exc})") from exc
        _set_attrs(g, attrs)
        return cls(g, url)

    @classmethod
    def open(cls, url: str, mode: str = "r+") -> "Store":
        """An existing store; a clear error when ``url`` is not one or is of another version."""
        root = _local_dir(url)
        meta = None
        if root is not None and root.is_file():  # (zarr said "[Errno 17] File exists")
            raise PatchcloudIOError(f"{url}: not a patchcloud store (a file; a store is a directory)")
        if root is not None:  # a local store: its root metadata read directly, zarr's group opened only if needed
            try:
                meta = LocalZarr(root).meta("")
            except (OSError, ValueError):  # zarr says what is wrong with it, below
                meta = None
        if meta is not None and meta.get("node_type") == "group" and meta.get("zarr_format") == 3:
            a = dict(meta.get("attributes", {}))
            g = None
        else:
            try:
                g = memory_group.open_group(url) if memory_group.is_memory_url(url) else _zarr().open_group(url, mode=mode)
            except Exception as exc:
                raise PatchcloudIOError(f"{url}: not a patchcloud store ({exc})") from exc
            a = dict(g.attrs)
            root = None
        if a.get("format") != FORMAT:
            raise PatchcloudIOError(f"{url}: not a patchcloud store (no '{FORMAT}' format mark)")
        if a.get("version") != VERSION:
            raise PatchcloudStoreError(f"{url}: store version {a.get('version')} is not supported (this is version {VERSION}): {START_OVER}")
        store = cls(g, url, root=root if g is None else None, mode=mode)
        if g is None:  # the attributes as read at opening, as zarr's group holds them
            store._attrs = a
        return store

    @classmethod
    def check_new(cls, url: str) -> None:
        """Refuse ``url`` when something other than a patchcloud store is there: a file, or a directory (local or
        ``file://``) that is not empty but holds no readable store (its root metadata missing or damaged).

        Raises
        ------
        PatchcloudStoreError
            Naming ``url`` and saying to remove it; nothing there is touched.
        """
        if _occupied(url) and not cls.exists(url):
            root = _local_dir(url)
            if root is not None and root.is_dir() and any((root / part).exists() for part in STORE_PARTS):
                raise PatchcloudStoreError(f"{url}: a patchcloud store whose root metadata (zarr.json) is missing or damaged: "
                                           f"{START_OVER}, or give another store")
            what = "a file" if root is not None and root.is_file() else "a directory that holds no patchcloud store"
            raise PatchcloudStoreError(f"{url}: exists and is not a patchcloud store ({what}): give another store "
                                       "(nothing there is touched)")

    @classmethod
    def exists(cls, url: str) -> bool:
        if memory_group.is_memory_url(url):
            return memory_group.exists(url)
        root = _local_dir(url)
        if root is not None:  # on a local disk: its root metadata read directly
            try:
                meta = LocalZarr(root).meta("")
            except (OSError, ValueError):
                return False
            return isinstance(meta, dict) and meta.get("node_type") == "group" and meta.get("attributes", {}).get("format") == FORMAT
        try:
            g = _zarr().open_group(url, mode="r")
        except Exception:
            return False
        return dict(g.attrs).get("format") == FORMAT

    @classmethod
    def discard(cls, url: str) -> None:
        """Remove the store at ``url``: an in-memory one, or a local directory (an fsspec URL is left as it is).

        A directory is first renamed to :func:`removing_path` (at once: no
        run takes a half-removed store for a damaged one), then removed with
        its record of the outputs and its root metadata last, so that a run
        killed meanwhile leaves a directory that still says which outputs it
        completed (the next run on the same output reads it, then removes it).
        """
        if memory_group.is_memory_url(url):
            memory_group.drop(url)
        elif "://" not in url and os.path.isdir(url):
            cls.settle(url)
            gone = removing_path(url)
            shutil.rmtree(gone, ignore_errors=True)
            try:
                os.replace(url, gone)
            except OSError:
                gone = url
            remove_store_dir(gone)

    @classmethod
    def settle(cls, url: str) -> None:
        """Wait for the background removals in the store at ``url`` (:meth:`remove` with ``wait=False``) to end."""
        root = _local_dir(url)  # (None for another URL, memory:// included)
        if root is not None:
            local_zarr.settle(root)

    @property
    def in_memory(self) -> bool:
        """Whether the store is held in this process's memory (:mod:`.memory_group`)."""
        return isinstance(self._group, memory_group.MemoryGroup)

    # -- global state --------------------------------------------------------
    @property
    def attrs(self) -> dict:
        """The store's attributes (read once, then kept up to date by :meth:`update`)."""
        if self._attrs is None:
            if self._local is None:
                self._attrs = dict(self.group.attrs)
            else:
                meta = self._local.meta("")
                if meta is None:
                    raise self._damaged("root", "its metadata, zarr.json, is missing")
                self._attrs = dict(meta.get("attributes", {}))
        return self._attrs

    def update(self, **kw) -> None:
        kw = json.loads(json.dumps(kw))
        if self._local is not None:
            self._local.update_group_attrs("", kw)
        else:
            _set_attrs(self.group, kw)
        self._attrs = None

    @property
    def uid(self) -> str:
        """The store's identity, recorded by every array written into it."""
        return self.attrs.get("uid", "")

    @property
    def grid(self) -> Grid:
        return Grid.from_json(self.attrs["grid"])

    @property
    def catalog(self) -> Catalog:
        """The files the store was made from, taken as one cloud (one file: a catalog of one)."""
        return Catalog.from_json(self.attrs["catalog"])

    @property
    def tiles(self) -> list[tuple[int, int, int]]:
        """Tile indices, in the store's canonical (lexicographic) order."""
        return [tuple(t) for t in self.attrs.get("tiles", [])]

    @property
    def tile_counts(self) -> np.ndarray:
        return np.asarray(self.attrs.get("tile_counts", []), dtype=np.int64)

    def step_done(self, step: str) -> dict | None:
        return self.attrs.get("steps", {}).get(step)

    def mark_step(self, step: str, info: dict | None) -> None:
        steps = self.attrs.get("steps", {})
        if info is None:
            steps.pop(step, None)
        else:
            steps[step] = info
        self.update(steps=steps)

    # -- tiles ---------------------------------------------------------------
    def tile(self, ijk):
        name = tile_name(ijk)
        g = self._groups.get(name)
        if g is None:
            g = self.group.require_group(f"tiles/{name}")
            self._groups[name] = g
        return g

    def _tile_now(self, ijk) -> tuple:
        """Tile ``ijk``'s group opened afresh (on a local disk: its path) and its attributes as stored now (another
        process may have changed them); ``(None, {})`` for no tile."""
        where = f"tile {tile_name(ijk)}"
        if self._local is not None:
            path = f"tiles/{tile_name(ijk)}"
            try:
                attrs = self._local.group_attrs(path)
            except Exception as exc:
                raise self._damaged(where, f"unreadable attributes: {exc}") from exc
            return (None, {}) if attrs is None else (path, attrs)
        try:
            g = self.group[f"tiles/{tile_name(ijk)}"]
            return g, dict(g.attrs)
        except KeyError:
            return None, {}
        except Exception as exc:
            raise self._damaged(where, f"unreadable attributes: {exc}") from exc

    def _tile_for_attrs(self, ijk) -> tuple:
        """The group and attributes of :meth:`_tile_now`, the group created if missing, for a write of its attributes.

        zarr merges new attributes into those the group object loaded when
        it was opened and writes them all back, so a group kept from earlier
        (:meth:`tile`) would put back what it read then over what other
        processes wrote since (a step's record, its results): each write
        goes through the group opened with the attributes it changes.
        """
        g, attrs = self._tile_now(ijk)
        if g is None:
            g = f"tiles/{tile_name(ijk)}" if self._local is not None else self.tile(ijk)
        return g, attrs

    def _set_tile_attrs(self, g, now: dict, attrs: dict) -> None:
        """Add ``attrs`` to a tile's attributes ``now``, in one write: ``g`` as :meth:`_tile_for_attrs` gave it."""
        if isinstance(g, str):
            self._local.update_group_attrs(g, attrs, now)
        else:
            _set_attrs(g, attrs)

    def tile_attrs(self, ijk) -> dict:
        """The tile's attributes as stored now (another process may have changed them); {} for no tile."""
        return self._tile_now(ijk)[1]

    def tile_done(self, ijk, step: str, key=None) -> bool:
        """Step ``step`` is done on tile ``ijk`` (with ``key``, the parameters it was marked with, when given)."""
        done = self.tile_attrs(ijk).get("done", {}).get(step)
        return bool(done) if key is None else done == key

    def mark_tile(self, ijk, step: str, value=True, **attrs) -> None:
        """Mark ``step`` done on tile ``ijk``, storing ``attrs`` with it in one write."""
        g, now = self._tile_for_attrs(ijk)
        done = now.get("done", {})
        done[step] = value
        self._set_tile_attrs(g, now, dict(json.loads(json.dumps(attrs)), done=done))

    def mark_failed(self, ijk, task: str, message: str | None) -> None:
        """Record that ``task`` raised on tile ``ijk`` (``message``), or clear that record (None)."""
        g, now = self._tile_for_attrs(ijk)
        failed = dict(now.get("failed", {}))
        if message is None:
            if task not in failed:
                return
            failed.pop(task)
        else:
            failed[task] = str(message)[:2000]
        self._set_tile_attrs(g, now, dict(failed=failed))

    def clear_tile_steps(self, steps: list[str]) -> None:
        for ijk in self.tiles:
            g, now = self._tile_for_attrs(ijk)
            done = now.get("done", {})
            if any(s in done for s in steps):
                self._set_tile_attrs(g, now, dict(done={k: v for k, v in done.items() if k not in steps}))

    def write(self, ijk, name: str, values: np.ndarray, chunk: int | None = None) -> None:
        """Write (replace) array ``name`` of tile ``ijk``."""
        if not self._write_local(f"tiles/{tile_name(ijk)}/{name}", values, chunk):
            self._create(self.tile(ijk), name, values, chunk)

    def _write_local(self, path: str, values: np.ndarray, chunk: int | None) -> bool:
        """Write ``values`` as the array at ``path`` directly (:mod:`.local_zarr`) where the store is on a local disk and
        the array of a type it writes; False where zarr is to write it."""
        values = np.asarray(values)
        if self._local is None or values.dtype.name not in DATA_TYPES or values.ndim < 1:
            return False
        values = np.ascontiguousarray(values)
        rows = max(1, min(chunk or self.CHUNK, values.shape[0]))
        attributes = {"crc32": chunk_checksums(values, rows), "store": self.uid, "path": self._prefix + path}
        self._local.write_array(path, values, rows, attributes)
        return True

    def _array(self, path: str, where: str, zarr_node=None):
        """The array at ``path`` for :meth:`_checked`: read directly on a local disk, else by zarr (``zarr_node()``,
        default ``self.group[path]``); KeyError where there is none."""
        if self._local is not None:
            try:
                a = self._local.array(path)
            except Exception as exc:
                raise self._damaged(where, f"unreadable metadata: {exc}") from exc
            if a is not None:
                a.path = self._prefix + path
                return a
            if not self._local.exists(path):
                raise KeyError(path)
        return zarr_node() if zarr_node is not None else self.group[path]

    def read(self, ijk, name: str, rows: slice | None = None) -> np.ndarray:
        """Array ``name`` of tile ``ijk`` (rows ``rows`` of it, a slice of step 1), its chunks checked.

        An array written in pieces (:meth:`mark_pieces`) is read as one.

        Raises
        ------
        PatchcloudStoreError
            The array is missing, or damaged (see the module's docstring).
        """
        where = f"tile {tile_name(ijk)}"
        try:
            a = self._array(f"tiles/{tile_name(ijk)}/{name}", where, lambda: self.tile(ijk)[name])
        except KeyError:
            entry = self.tile_attrs(ijk).get("pieces", {}).get(name)
            if entry:
                stem, k = entry
                return self._read_pieces(ijk, str(stem), int(k), rows)
            raise self._damaged(where, f"array {name!r} is missing") from None
        return self._checked(a, rows, f"{where}, array {name!r}")

    def _read_pieces(self, ijk, name: str, k: int, rows: slice | None) -> np.ndarray:
        """Rows ``rows`` of tile ``ijk``'s array held in the ``k`` pieces ``piece_name(name, j, k)``, each checked."""
        where = f"tile {tile_name(ijk)}"
        arrays = []
        for j in range(k):
            try:
                arrays.append(self._array(f"tiles/{tile_name(ijk)}/{piece_name(name, j, k)}", where,
                                          lambda: self.tile(ijk)[piece_name(name, j, k)]))
            except KeyError:
                raise self._damaged(where, f"array {piece_name(name, j, k)!r} is missing") from None
        sizes = [a.shape[0] for a in arrays]
        ends = np.cumsum(sizes)
        starts = ends - sizes
        n = int(ends[-1])
        lo, hi, step = (0, n, 1) if rows is None else rows.indices(n)
        if step != 1:
            raise PatchcloudValueError(f"{self.url}: {where}: rows must be a slice of step 1, got {rows}")
        out = [self._checked(a, slice(max(lo, s) - s, min(hi, e) - s), f"{where}, array {piece_name(name, j, k)!r}")
               for j, (a, s, e) in enumerate(zip(arrays, starts.tolist(), ends.tolist())) if s < hi and e > lo]
        return np.concatenate(out) if out else self._checked(arrays[0], slice(0, 0), where)

    def mark_pieces(self, ijk, stems: dict, k: int) -> None:
        """Record that tile ``ijk``'s array ``name`` is written in ``k`` pieces of consecutive rows, the arrays
        ``piece_name(stems[name], j, k)``, for each name of ``stems``, so :meth:`read` reads each as one array; an
        array of one of those names written whole before is removed."""
        g, now = self._tile_for_attrs(ijk)
        pieces = dict(now.get("pieces", {}))
        for name, stem in stems.items():
            self.delete(ijk, name)
            pieces[name] = [str(stem), int(k)]
        self._set_tile_attrs(g, now, dict(pieces=pieces))

    def unmark_pieces(self, ijk, names) -> None:
        """Forget that tile ``ijk``'s arrays ``names`` were written in pieces (they are written whole again; the pieces
        are left)."""
        g, now = self._tile_for_attrs(ijk)
        pieces = dict(now.get("pieces", {}))
        if any(name in pieces for name in names):
            self._set_tile_attrs(g, now, dict(pieces={n: v for n, v in pieces.items() if n not in names}))

    def _damaged(self, where: str, what: str) -> PatchcloudStoreError:
        return PatchcloudStoreError(f"{self.url}: {where}: the store is damaged ({what}); {START_OVER}")

    def _create(self, group, name: str, values: np.ndarray, chunk: int | None):
        """Write ``values`` as array ``name`` of ``group`` (replacing it), by chunks of ``chunk`` rows, with its checksums."""
        values = np.ascontiguousarray(values)
        rows = max(1, min(chunk or self.CHUNK, values.shape[0]))
        chunks = (rows,) + values.shape[1:]
        if self.in_memory:  # filled as it is made: no pass writing zeros first
            group.create_array(name, shape=values.shape, dtype=values.dtype, chunks=chunks, overwrite=True, data=values)
            return
        sums = chunk_checksums(values, rows)
        a = group.create_array(name, shape=values.shape, dtype=values.dtype, chunks=chunks, overwrite=True,
                               compressors=codec_for(values.dtype), attributes={"crc32": sums, "store": self.uid, "path": a_path(group, name)})
        if values.size:
            a[...] = values

    def _checked(self, a, rows: slice | None, where: str) -> np.ndarray:
        """Rows ``rows`` of array ``a`` (all: None), after checking the crc32 of every chunk they touch."""
        if self.in_memory:
            return a[...] if rows is None else a[rows]
        attrs = a.attrs
        sums = attrs.get("crc32")
        if attrs.get("store") != self.uid or sums is None:
            raise self._damaged(where, "written by another store")
        if attrs.get("path") != a.path:
            raise self._damaged(where, f"written as {attrs.get('path')!r}, moved here")
        n = a.shape[0]
        start, stop, step = (0, n, 1) if rows is None else rows.indices(n)
        if step != 1:
            raise PatchcloudValueError(f"{self.url}: {where}: rows must be a slice of step 1, got {rows}")
        if stop <= start:
            return a[0:0]
        size = a.chunks[0]
        if len(sums) != -(-n // size):
            raise self._damaged(where, "its checksums do not match its shape")
        first, last = start // size, -(-stop // size)
        try:
            data = a[first * size : min(n, last * size)]
        except Exception as exc:
            raise self._damaged(where, f"a chunk cannot be decoded: {exc}") from exc
        for k in range(first, last):
            block = data[(k - first) * size : (k - first + 1) * size]
            if zlib.crc32(np.ascontiguousarray(block)) != sums[k]:
                raise self._damaged(where, f"rows {k * size:,} to {k * size + block.shape[0] - 1:,} differ from what was written")
        return data[start - first * size : stop - first * size]

    def has(self, ijk, name: str) -> bool:
        key = f"tiles/{tile_name(ijk)}"
        if self._local is not None:
            return self._local.exists(f"{key}/{name}")
        return key in self.group and name in self.group[key]

    def delete(self, ijk, name: str) -> None:
        if self._local is not None:
            self._local.delete(f"tiles/{tile_name(ijk)}/{name}")
            return
        g = self.tile(ijk)
        if name in g:
            del g[name]

    # -- arrays outside tiles (the ingest's parts, the export's tables) ------
    def put(self, path: str, values: np.ndarray, chunk: int | None = None) -> None:
        """Write (replace) the array at ``path`` (e.g. ``parts/000003/xyz``)."""
        if not self._write_local(path, values, chunk):
            self._create(self.group, path, values, chunk)

    def has_array(self, path: str) -> bool:
        """Whether there is an array (or group) at ``path``."""
        if self._local is not None:
            return self._local.exists(path)
        return path in self.group

    def get(self, path: str, rows: slice | None = None) -> np.ndarray:
        """The array at ``path`` (rows ``rows`` of it)."""
        try:
            a = self._array(path, f"array {path!r}")
        except KeyError:
            raise self._damaged(f"array {path!r}", "it is missing") from None
        return self._checked(a, rows, f"array {path!r}")

    def group_attrs(self, path: str) -> dict:
        """The attributes of the group at ``path`` as stored now; {} when there is none."""
        if self._local is not None:
            return self._local.group_attrs(path) or {}
        try:
            return dict(self.group[path].attrs)
        except KeyError:
            return {}

    def set_group_attrs(self, path: str, **attrs) -> None:
        """Set attributes of the group at ``path`` (made if needed)."""
        if self._local is not None:
            self._local.update_group_attrs(path, json.loads(json.dumps(attrs)))
            return
        _set_attrs(self.group.require_group(path), json.loads(json.dumps(attrs)))

    def remove(self, path: str, wait: bool = True) -> None:
        """Remove the group or array at ``path`` if there.

        With ``wait=False``, a store on a local disk removes its files on a
        thread while the caller gets on (:meth:`~.local_zarr.LocalZarr.delete`);
        :meth:`settle` waits for it.
        """
        if self._local is not None:
            self._local.delete(path, wait=wait)
            return
        if path in self.group:
            del self.group[path]

    # -- blobs: small working arrays as raw float64 bytes under one key, no zarr metadata --
    def put_blob(self, key: str, values: np.ndarray) -> None:
        """Write ``values`` (any shape, kept as flat float64) under ``key``: one store write, for the many small arrays of a pass."""
        data = np.ascontiguousarray(values, dtype="<f8").tobytes()
        if self.in_memory:
            self.group.blobs[key] = data
            return
        data += struct.pack("<Q", zlib.crc32(data))
        if self._local is not None:
            self._local.put_bytes(key, data)
            return
        from zarr.core.buffer import default_buffer_prototype
        from zarr.core.sync import sync

        sync((self.group.store_path / key).set(default_buffer_prototype().buffer.from_bytes(data)))

    def get_blob(self, key: str) -> np.ndarray:
        """The flat float64 array written under ``key`` by :meth:`put_blob`."""
        if self.in_memory:
            data = self.group.blobs.get(key)
        elif self._local is not None:
            data = self._local.get_bytes(key)
        else:
            from zarr.core.buffer import default_buffer_prototype
            from zarr.core.sync import sync

            buf = sync((self.group.store_path / key).get(prototype=default_buffer_prototype()))
            data = None if buf is None else buf.to_bytes()
        if data is None:
            raise self._damaged(f"blob {key!r}", "it is missing")
        if not self.in_memory:
            if len(data) % 8 or len(data) < 8 or struct.unpack("<Q", data[-8:])[0] != zlib.crc32(data[:-8]):
                raise self._damaged(f"blob {key!r}", "it differs from what was written")
            data = data[:-8]
        return np.frombuffer(data, dtype="<f8").astype(np.float64)

    def remove_blobs(self, prefix: str) -> None:
        """Remove every blob (and array) whose key starts with ``prefix/``."""
        if self.in_memory:
            self.group.delete_prefix(prefix)
            return
        if self._local is not None:
            self._local.remove_dir(prefix)
            return
        from zarr.core.sync import sync

        sync((self.group.store_path / prefix).delete_dir())

    def patch_table(self, ijk) -> PatchTable:
        grid = self.grid
        return array_to_table(self.read(ijk, "patches"), grid.corner(ijk), grid.tile_size)
