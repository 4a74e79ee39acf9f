"""The patch-model file (``.pcz``): a cloud as quantised quadric patches plus residual points, in one zip.

A ``.pcz`` is a zarr (format 3) store in a single zip file (chunks
stored, not deflated: every chunk is already compressed; the JSON
metadata deflated).  No pickle
anywhere: integers, floats, JSON attributes.  Version 4 has two modes.

**Model mode** (the default: patch models, residual points within the budget)::

    zarr.json                     attrs: format "patchcloud-pcz", version, mode "model", max_error
                                  (metres), grid (origin, tile_size, scale, offset), counts, source
                                  (the input's name, point format, LAS version, bounds, CRS WKT),
                                  record_bytes, steps (3 ints), dropped (dimension names)
    header                        (H,) uint8    the input's LAS header and VLRs, as they were
    evlrs                         (E,) uint8    its extended VLRs (LAS 1.4), as they were; empty if none
    tiles/ijk                     (T, 3) int64  tile indices (tile = cube of edge tile_size from origin)
    tiles/patch_start             (T + 1,) int64 rows of each tile's patches
    tiles/cell_start              (T + 1,) int64 rows of each tile's cells
    tiles/residual_start          (T + 1,) int64 rows of each tile's residual points
    tiles/residual_byte_start     (T + 1,) int64 bytes of each tile's residual LAZ
    tiles/intensity_shift         (T,) uint8    each tile's intensities (its cells' and its residual points')
                                  are stored divided by 2**shift, rounded (stream.io.residual_points)
    patches/scale                 (P,) int8     } quantised as
    patches/centroid              (P, 3) int32  } patchcloud.core.patchmodel.QuantisedModels
    patches/rotation              (P, 3) int32  } (steps from max_error and the patch's scale)
    patches/coeffs                (P, 6) int64  }
    patches/rmse                  (P,) float32  fit RMS error (metres)
    patches/cells                 (P,) uint32   cells of each patch (a tile's cells come patch after patch)
    cells/level                   (C,) uint8    octree level in the tile (root = the tile)
    cells/ijk                     (C, 3) int32  cell at that level
    cells/count                   (C,) uint32   points the cell stands for
    cells/extent                  (C, 4) int32  (u, v) box of its points, steps of the cell edge / 1024
    cells/mask                    (C,) uint64   8 x 8 occupancy of the (u, v) extent
    cells/classification          (C,) uint8    majority class of the cell's points
    cells/intensity               (C,) uint16   mean intensity of the cell's points (divided by 2**shift)
    residual/laz                  (S,) uint8    per tile, the residual points' records as a LAZ file
                                  (lazrs: LAS records compress best with LAZ's field-wise
                                  predictive coding) in input, Morton or column order, or
                                  (version 5) as an octree block (stream.io.residual_octree,
                                  starting "PCZO"), whichever is smaller, as
                                  stream.io.residual_points codes them: X, Y, Z the input's
                                  integers divided by steps (stream.io.point_coding), the
                                  classification as it was, the intensity divided by
                                  2**shift (rounded), return 1 of 1, every other
                                  dimension (those named by dropped) zero

**Points mode** (``compress --keep-points``: every point, in input order)::

    zarr.json                     attrs: as above, mode "points", counts (blocks, points)
    header, evlrs                 as above
    blocks/point_start            (B + 1,) int64 the first input point of each block
    blocks/byte_start             (B + 1,) int64 bytes of each block's LAZ
    blocks/bounds                 (B, 6) int64  smallest and largest X, Y, Z of its points (input grid)
    points/laz                    (S,) uint8    per block, its records as a LAZ file (as residual/laz)

Records of point formats 0-3 are stored as formats 6 and 7
(:mod:`.layered`: LAZ codes those in fewer bytes) and turned back on
reading; the LAZ columns are in chunks of 4 MiB; the arrays of several
columns (patches' centroids, rotations and coefficients, cells' indices and
extents) are stored column by column (a zarr transpose codec; version 5).
Version 3 stored them
in their own format, in chunks of 64 KiB; version 2 is model mode with
exact residual points (no steps, nothing dropped).  Versions 2 to 4 have no
``tiles/intensity_shift``: their cells' mean intensities are exact, their
residual points keep their intensity and returns exactly, in input order.  Every version is read as such.

The file is reproducible: the same input and parameters give the same
bytes (entries in name order, each dated :data:`ZIP_TIME`; the input
recorded by its name, not its path, unless asked).

Reading checks the format mark and the version, and names the file in
every error (:class:`patchcloud.core.errors.PatchcloudIOError`): a file
that is not a zip, truncated, of another version or made by something else.
Nothing a file states is trusted before it is checked (:func:`open_pcz`):
every zip entry's size against the file and the memory budget
(:mod:`.budget`; a compressed entry expanding far beyond its size is a zip
bomb), every array's type, shape and chunks against this layout, every
chunk's decoded size against its chunk, the tile index against the arrays
and the counts, and the points the cells stand for against the counts;
then every read of a tile's rows is checked against the budget.
"""

from __future__ import annotations

import functools
import io
import os
import shutil
import warnings
import zipfile
from collections import Counter
from contextlib import contextmanager
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import laspy
from laspy.vlrs.vlrlist import VLRList
import numpy as np
import zarr
from zarr.codecs import BloscCodec, TransposeCodec

from patchcloud.core import PatchcloudError, PatchcloudExistsError, PatchcloudIOError, PatchcloudValueError, QuantisedModels

from .budget import check_memory
from .layered import LAYERED, from_layered, layered_size
from .renamed import partial_path, rename_into_place
from .las import check_header_sizes, check_header_values
from .las_records import stated_point_count
from .point_coding import refine
from .residual_octree import MAGIC as OCTREE_MAGIC, decode as octree_decode, records_of as octree_records
from .residual_points import fine_intensity
from .store import tile_name

__all__ = ["FORMAT", "VERSION", "READABLE", "ZIP_TIME", "TilePart", "PointsBlock", "write_pcz", "write_points_pcz", "PczFile",
           "PointsPczFile", "open_pcz", "OpenedArrays", "WHOLE_READ_BYTES"]

FORMAT = "patchcloud-pcz"
VERSION = 5
#: The versions this reader reads: 2 (model mode only, residual points exact), 3, 4 and 5.
READABLE = (2, 3, 4, 5)
#: The date of every zip entry (the zip format's earliest), so that a ``.pcz`` does not depend on when it was written.
ZIP_TIME = (1980, 1, 1, 0, 0, 0)
#: Rows per chunk of every per-patch, per-cell and per-residual-point array.
CHUNK = 1 << 16
#: Bytes per chunk of the LAZ columns (residual/laz, points/laz; version 4): a zip entry and a Blosc header per chunk
#: cost about 120 bytes, 5 kB on a 3 MB file in chunks of 64 KiB (version 3).
LAZ_CHUNK = 1 << 22
#: Byte shuffle + Zstd at its strongest level through Blosc (measured on an IGN tile's patches:
#: 22 % smaller than zarr's default Zstd level 3; the arrays are small next to the points they replace).
CODEC = BloscCodec(cname="zstd", clevel=9, shuffle="shuffle")
#: The LAZ columns' codec.  LAZ is entropy-coded already: Blosc's Zstd at level 9 took 0.2 s a megabyte (a
#: 697,721-point file's 3.2 MB: 0.6 s) to save 0.3-2 % of it (2 % on the embedded tile); level 5 keeps most of that
#: (1.6 % there, nothing on the 697,721 points) at 0.01 s.  Still Blosc, so every reader, and the check of the size a
#: chunk states before it is read, are unchanged.
LAZ_CODEC = BloscCodec(cname="zstd", clevel=5, shuffle="noshuffle")
#: Points mode's codec when it keeps every point exactly (steps 1, nothing dropped: the input's records re-coded): there
#: the last 0.3 % is what keeps the ``.pcz`` from being larger than the input LAZ (the 697,721-point file: 37.26 bits a
#: point at level 5, 37.13 at 9, the file 37.15), so level 9 is worth its time.
LAZ_CODEC_EXACT = BloscCodec(cname="zstd", clevel=9, shuffle="noshuffle")

#: Every chunk is written, zeros too (version 5; zarr leaves out chunks of zeros by default): a chunk missing from a
#: file is damage, not zeros (a sweep of 2026-11-27 took a file without its tiles' intensity shifts for one whose
#: intensities were never shifted).
WRITE_EVERY_CHUNK = {"write_empty_chunks": True}
#: A compressed zip entry may expand to at most this many times its size, and 1 MiB in any case (a ``.pcz``'s entries
#: are stored, not compressed; a repacked one's JSON deflates about tenfold): beyond, a zip bomb.
MAX_ZIP_RATIO = 100
#: Bytes a tile's rows take in memory as they are read, per patch and per cell (the stored types, their int64 copies).
PATCH_ROW_BYTES, CELL_ROW_BYTES = 3 * (1 + 12 + 12 + 48 + 4 + 4), 3 * (1 + 12 + 4 + 16 + 8 + 1 + 2)
#: The smallest and largest tile edge a file may state (metres): beyond, its arithmetic under- or overflows.
TILE_SIZES = (2.0**-20, 2.0**24)
_STARTS = ("patch_start", "cell_start", "residual_start", "residual_byte_start")
_ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"

_PATCH_ARRAYS = (
    ("scale", np.int8, ()), ("centroid", np.int32, (3,)), ("rotation", np.int32, (3,)), ("coeffs", np.int64, (6,)),
    ("rmse", np.float32, ()), ("cells", np.uint32, ()),
)
_CELL_ARRAYS = (
    ("level", np.uint8, ()), ("ijk", np.int32, (3,)), ("count", np.uint32, ()), ("extent", np.int32, (4,)),
    ("mask", np.uint64, ()), ("classification", np.uint8, ()), ("intensity", np.uint16, ()),
)


@dataclass(frozen=True)
class TilePart:
    """One tile's share of a ``.pcz``: its quantised patches (root = the tile), their cells' attributes, its residual points.

    ``models.root_corner``/``root_edge`` must be the tile's cube;
    ``residual_laz`` is the block of the residual points' records (a LAZ
    file or, version 5, an octree block: see
    :func:`~.residual_points.residual_block`; no bytes for none), holding
    ``residual_count`` points (the name is the array's, ``residual/laz``,
    kept from version 2); its cells' and residual points' intensities are
    divided by ``2**intensity_shift``
    (:func:`~.residual_points.coarse_intensity`).
    """

    ijk: tuple[int, int, int]
    models: QuantisedModels
    classification: np.ndarray
    intensity: np.ndarray
    residual_count: int
    residual_laz: bytes
    intensity_shift: int = 0


class _Column:
    """Rows appended to one array of a zarr group, written one whole chunk at a time."""

    def __init__(self, group: zarr.Group, name: str, dtype, tail: tuple[int, ...], chunk: int | None = None,
                 codec: BloscCodec = CODEC):
        self.chunk = CHUNK if chunk is None else chunk  # read when called: tests make chunks small
        # rows of several values are stored column by column (version 5): 6-35 % smaller under Blosc's shuffle
        filters = [TransposeCodec(order=(1, 0))] if len(tail) == 1 else []
        self.array = group.create_array(name, shape=(0,) + tail, dtype=dtype, chunks=(self.chunk,) + tail, compressors=[codec],
                                        filters=filters, config=WRITE_EVERY_CHUNK)
        self.buffer: list[np.ndarray] = []
        self.held = 0
        self.dtype = np.dtype(dtype)
        self.tail = tail

    def add(self, rows: np.ndarray) -> None:
        rows = np.asarray(rows)
        if rows.shape[1:] != self.tail:
            raise PatchcloudValueError(f"{self.array.path}: rows of shape {rows.shape[1:]} given, {self.tail} expected")
        if rows.size and (np.issubdtype(self.dtype, np.integer)):
            info = np.iinfo(self.dtype)
            if rows.min() < info.min or rows.max() > info.max:
                raise PatchcloudValueError(f"{self.array.path}: values beyond {self.dtype} (a quantisation step too small for the cell?)")
        self.buffer.append(rows.astype(self.dtype, copy=False))
        self.held += rows.shape[0]
        if self.held >= self.chunk:
            self._flush(final=False)

    def _flush(self, final: bool) -> None:
        data = np.concatenate(self.buffer) if self.buffer else np.zeros((0,) + self.tail, self.dtype)
        whole = data.shape[0] if final else (data.shape[0] // self.chunk) * self.chunk
        if whole:
            n = self.array.shape[0]
            self.array.resize((n + whole,) + self.tail)
            self.array[n : n + whole] = data[:whole]
        rest = data[whole:]
        self.buffer = [rest] if rest.shape[0] else []
        self.held = rest.shape[0]

    def close(self) -> None:
        self._flush(final=True)


@contextmanager
def _building(path: str | os.PathLike, overwrite: bool, before_rename: Callable[[Path], None] | None = None):
    """A zarr group to fill, zipped to ``path`` when the ``with`` block ends without error.

    The store is built in the directory ``path + ".build"`` (one a killed
    run left is removed first: callers hold the output's lock) and zipped
    to ``path + ".partial"``, which is renamed to ``path`` when complete;
    ``before_rename(partial)``, when given, is called just before (to record
    the file as complete: a rename keeps its size and modification time).
    """
    out = Path(path)
    if out.exists() and not overwrite:
        raise PatchcloudExistsError(f"{out}: exists (use --overwrite to replace it)")
    if not out.parent.exists():
        raise PatchcloudIOError(f"{out}: the directory {out.parent} does not exist")
    work = out.with_name(out.name + ".build")  # a fixed name (the run holds OUT's lock): a killed run's is removed here
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir()
    tmp = partial_path(out)
    try:
        yield zarr.open_group(str(work / "store"), mode="w")
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as z:
            base = work / "store"
            for f in sorted(base.rglob("*")):  # in name order, with a fixed time: the same models give the same bytes
                if f.is_file():
                    entry = zipfile.ZipInfo(f.relative_to(base).as_posix(), date_time=ZIP_TIME)
                    entry.external_attr = 0o644 << 16
                    if f.name == "zarr.json":  # metadata deflates about fivefold; chunks are compressed already
                        entry.compress_type = zipfile.ZIP_DEFLATED
                    with open(f, "rb") as src, z.open(entry, "w", force_zip64=True) as dst:
                        shutil.copyfileobj(src, dst, 1 << 22)
        if before_rename is not None:
            before_rename(tmp)
        rename_into_place(tmp, out)
    finally:
        shutil.rmtree(work, ignore_errors=True)
        if tmp.exists():
            tmp.unlink()


def write_pcz(
    path: str | os.PathLike, parts: Iterable[TilePart], *, max_error: float, grid: dict, header: bytes, source: dict,
    record_bytes: int, evlrs: bytes = b"", overwrite: bool = False, steps=(1, 1, 1), dropped=(),
    before_rename: Callable[[Path], None] | None = None,
) -> dict:
    """Write a model-mode ``.pcz`` from tile parts, in the order given; memory: a chunk per array, not the file.

    ``steps``: the multiples of the input's integer coordinates the residual
    points' are rounded to (:mod:`.point_coding`; 1 exact); ``dropped``:
    their dimensions written as zeros.  Written under a temporary name,
    renamed when complete (``before_rename``: see :func:`_building`).  Returns the file's counts (tiles, patches,
    residual points, points).
    """
    with _building(path, overwrite, before_rename) as root:
        residual = root.require_group("residual")
        cols = {name: _Column(root.require_group(group), name, dt, tail)
                for group, arrays in (("patches", _PATCH_ARRAYS), ("cells", _CELL_ARRAYS)) for name, dt, tail in arrays}
        laz = _Column(residual, "laz", np.uint8, (), chunk=LAZ_CHUNK, codec=LAZ_CODEC)
        tiles, pstart, cstart, rstart, bstart, shifts = [], [0], [0], [0], [0], []
        points = 0
        for part in parts:
            m = part.models
            if m.max_error != max_error:
                raise PatchcloudValueError(f"tile {part.ijk}: quantised for max_error {m.max_error}, the file says {max_error}")
            C = m.count.shape[0]
            if int(m.cells.sum()) != C or part.classification.shape != (C,) or part.intensity.shape != (C,):
                raise PatchcloudValueError(f"tile {part.ijk}: {C} cells, {int(m.cells.sum())} named by the patches, "
                                           f"{part.classification.shape[0]} classes and {part.intensity.shape[0]} intensities")
            values = dict(
                scale=m.scale, centroid=m.centroid, rotation=m.rotation, coeffs=m.coeffs, rmse=m.rmse, cells=m.cells,
                level=m.level, ijk=m.ijk, count=m.count, extent=m.extent, mask=m.mask,
                classification=part.classification, intensity=part.intensity,
            )
            for name, col in cols.items():
                col.add(values[name])
            laz.add(np.frombuffer(part.residual_laz, dtype=np.uint8))
            tiles.append(part.ijk)
            shifts.append(int(part.intensity_shift))
            pstart.append(pstart[-1] + len(m))
            cstart.append(cstart[-1] + m.count.shape[0])
            rstart.append(rstart[-1] + int(part.residual_count))
            bstart.append(bstart[-1] + len(part.residual_laz))
            points += int(m.count.sum()) + int(part.residual_count)
        for col in [*cols.values(), laz]:
            col.close()
        t = root.require_group("tiles")
        t.create_array("ijk", data=np.asarray(tiles, dtype=np.int64).reshape(-1, 3), config=WRITE_EVERY_CHUNK)
        t.create_array("patch_start", data=np.asarray(pstart, dtype=np.int64), config=WRITE_EVERY_CHUNK)
        t.create_array("cell_start", data=np.asarray(cstart, dtype=np.int64), config=WRITE_EVERY_CHUNK)
        t.create_array("residual_start", data=np.asarray(rstart, dtype=np.int64), config=WRITE_EVERY_CHUNK)
        t.create_array("residual_byte_start", data=np.asarray(bstart, dtype=np.int64), config=WRITE_EVERY_CHUNK)
        t.create_array("intensity_shift", data=np.asarray(shifts, dtype=np.uint8), config=WRITE_EVERY_CHUNK)
        root.create_array("header", data=np.frombuffer(header, dtype=np.uint8), config=WRITE_EVERY_CHUNK)
        root.create_array("evlrs", data=np.frombuffer(evlrs, dtype=np.uint8), config=WRITE_EVERY_CHUNK)
        counts = dict(tiles=len(tiles), patches=pstart[-1], cells=cstart[-1], residual=rstart[-1], points=points)
        root.attrs.update(
            format=FORMAT, version=VERSION, mode="model", max_error=float(max_error), grid=grid, source=source, counts=counts,
            record_bytes=int(record_bytes), steps=[int(k) for k in steps], dropped=list(dropped),
        )
    return counts


@dataclass(frozen=True)
class PointsBlock:
    """A run of consecutive input points of a points-mode ``.pcz``: a LAZ file of their records (see :func:`write_points_pcz`).

    ``bounds``: the smallest and largest decoded integer X, Y, Z (the input's
    grid), 6 integers.
    """

    count: int
    laz: bytes
    bounds: tuple[int, int, int, int, int, int]


def write_points_pcz(
    path: str | os.PathLike, blocks: Iterable[PointsBlock], *, max_error: float, steps, dropped, grid: dict, header: bytes,
    source: dict, record_bytes: int, evlrs: bytes = b"", overwrite: bool = False,
) -> dict:
    """Write a points-mode ``.pcz`` (``compress --keep-points``) from its blocks, in input order.

    Each block is a LAZ file of consecutive input records whose X, Y, Z are
    the input's integers divided by ``steps`` (:mod:`.point_coding`) and
    whose ``dropped`` dimensions are zero; everything else is the input's
    bytes.  Returns the file's counts (blocks, points).  The blocks' bytes
    go through :data:`LAZ_CODEC`, or :data:`LAZ_CODEC_EXACT` when every
    step is 1 and nothing is dropped.
    """
    with _building(path, overwrite) as root:
        exact = all(int(k) == 1 for k in steps) and not dropped
        laz = _Column(root.require_group("points"), "laz", np.uint8, (), chunk=LAZ_CHUNK,
                      codec=LAZ_CODEC_EXACT if exact else LAZ_CODEC)
        pstart, bstart, bounds = [0], [0], []
        for b in blocks:
            laz.add(np.frombuffer(b.laz, dtype=np.uint8))
            pstart.append(pstart[-1] + int(b.count))
            bstart.append(bstart[-1] + len(b.laz))
            bounds.append([int(v) for v in b.bounds])
        laz.close()
        g = root.require_group("blocks")
        g.create_array("point_start", data=np.asarray(pstart, dtype=np.int64), config=WRITE_EVERY_CHUNK)
        g.create_array("byte_start", data=np.asarray(bstart, dtype=np.int64), config=WRITE_EVERY_CHUNK)
        g.create_array("bounds", data=np.asarray(bounds, dtype=np.int64).reshape(-1, 6), config=WRITE_EVERY_CHUNK)
        root.create_array("header", data=np.frombuffer(header, dtype=np.uint8), config=WRITE_EVERY_CHUNK)
        root.create_array("evlrs", data=np.frombuffer(evlrs, dtype=np.uint8), config=WRITE_EVERY_CHUNK)
        counts = dict(blocks=len(bounds), points=pstart[-1])
        root.attrs.update(
            format=FORMAT, version=VERSION, mode="points", max_error=float(max_error), grid=grid, source=source, counts=counts,
            record_bytes=int(record_bytes), steps=[int(k) for k in steps], dropped=list(dropped),
        )
    return counts


def _refined(path, xyz: np.ndarray, steps, where: str) -> np.ndarray:
    """(n, 3) int32: stored X, Y, Z (multiples ``steps`` of the input's integers) back on the input's grid; beyond int32: damaged."""
    if tuple(steps) == (1, 1, 1):
        return xyz
    k = np.asarray(steps, dtype=np.int64)
    far = xyz.astype(np.int64) * k  # a coded point lies at most k / 2 steps beyond LAS's range (refine brings it back)
    if far.size and (far.min() < -(2**31) - k.max() or far.max() >= 2**31 + k.max()):
        raise PatchcloudIOError(f"{path}: damaged .pcz file ({where}'s coordinates lie beyond what LAS coordinates can hold)")
    return np.column_stack([refine(xyz[:, a], int(steps[a])) for a in range(3)]).astype(np.int32)


#: An array of at most this many bytes is read whole at its first read, and its rows then come from memory: a tile's
#: patches and cells are a dozen small reads, each a round trip through zarr's event loop (about 1 ms).
WHOLE_READ_BYTES = 16 * 2**20


class OpenedArrays:
    """A zarr group whose arrays are opened once each (their metadata read once): what the checks of :func:`open_pcz`
    and every later read share.  ``attrs`` as the group's."""

    def __init__(self, group: zarr.Group) -> None:
        self.group = group
        self.attrs = group.attrs
        try:  # every array's metadata in one go (zarr reads them side by side); a damaged one is found by name later
            with warnings.catch_warnings():  # zarr warns of an entry that is not an array or group: said by name later
                warnings.simplefilter("ignore")
                self._opened: dict[str, zarr.Array] = {k: v for k, v in group.members(max_depth=None) if isinstance(v, zarr.Array)}
        except Exception:
            self._opened = {}

    def __getitem__(self, name: str):
        a = self._opened.get(name)
        if a is None:
            a = self._opened[name] = self.group[name]
        return a


class _OpenPcz:
    """What both modes of an open ``.pcz`` share: its attributes, the input's header and EVLRs, and its stored records."""

    def __init__(self, path: str, root: OpenedArrays, store) -> None:
        self.path = path
        self.root = root
        self._store = store
        self.attrs = dict(root.attrs)
        self._whole: dict[str, np.ndarray] = {}  # small arrays, read whole once (WHOLE_READ_BYTES)

    # -- what the file says -------------------------------------------------
    @property
    def max_error(self) -> float:
        return float(self.attrs["max_error"])

    @property
    def header_bytes(self) -> bytes:
        return bytes(self._read("header"))

    def _read(self, name: str, rows: slice | None = None) -> np.ndarray:
        """Rows of array ``name`` (all of it by default); a chunk that cannot be decoded is a PatchcloudIOError naming it."""
        try:
            if name in self._whole:
                return self._whole[name] if rows is None else self._whole[name][rows]
            a = self.root[name]
            if rows is not None and a.nbytes <= WHOLE_READ_BYTES:
                self._whole[name] = a[...]
                return self._whole[name][rows]
            return a[...] if rows is None else a[rows]
        except Exception as exc:
            raise PatchcloudIOError(f"{self.path}: damaged .pcz file (array {name} cannot be read: {exc})") from exc

    def las_header(self) -> laspy.LasHeader:
        """The input's LAS header and VLRs (its sizes checked before laspy parses them; a PatchcloudIOError if damaged)."""
        raw = self.header_bytes
        check_header_sizes(f"{self.path}: the input's header", raw[:375], len(raw), evlrs=False)
        try:
            header = laspy.LasHeader.read_from(io.BytesIO(raw), read_evlrs=False)
        except Exception as exc:
            raise PatchcloudIOError(f"{self.path}: the input's LAS header cannot be read ({exc})") from exc
        check_header_values(f"{self.path}: the input's header", header)
        if header.point_format.size != int(self.attrs["record_bytes"]) + 12:
            raise PatchcloudIOError(f"{self.path}: the input's header has point records of {header.point_format.size} bytes, "
                                    f"the file says {int(self.attrs['record_bytes']) + 12}")
        return header

    @functools.cached_property
    def input_format_id(self) -> int:
        """The input's point format (its header's byte 104; -1 if the header is shorter)."""
        raw = self.header_bytes
        return raw[104] & 0x3F if len(raw) > 104 else -1

    def evlr_bytes(self, count: int, stored: bool = False) -> bytes:
        """The bytes of the input's ``count`` extended VLRs (LAS 1.4), as they were; empty when it had none.
        ``stored``: whatever bytes the file holds, however many records they are."""
        raw = bytes(self._read("evlrs")) if count or stored else b""
        if count * 60 > len(raw):
            raise PatchcloudIOError(f"{self.path}: the input's header says {count:,} extended VLRs, the file holds {len(raw):,} bytes of them")
        return raw

    def evlrs(self, count: int) -> "VLRList":
        """The input's ``count`` extended VLRs (LAS 1.4), parsed; an empty list when it had none."""
        raw = bytes(self._read("evlrs")) if count else b""
        if not raw:
            return VLRList()
        if count * 60 > len(raw):
            raise PatchcloudIOError(f"{self.path}: the input's header says {count:,} extended VLRs, the file holds {len(raw):,} bytes of them")
        try:
            return VLRList(VLRList.read_from(io.BytesIO(raw), count, extended=True))
        except Exception as exc:
            raise PatchcloudIOError(f"{self.path}: the extended VLRs cannot be read ({exc})") from exc

    @property
    def steps(self) -> tuple[int, int, int]:
        """The multiples of the input's integers the residual points' X, Y, Z were rounded to (version 2: exact, 1)."""
        return tuple(self.attrs.get("steps", (1, 1, 1)))

    @property
    def dropped(self) -> list[str]:
        """The residual points' dimensions written as zeros (version 2: none)."""
        return list(self.attrs.get("dropped", ()))

    def _records(self, array: str, s: slice, n: int, what: str, pronoun: str) -> tuple[np.ndarray, np.ndarray]:
        """Bytes ``s`` of ``array``, a LAS/LAZ file of ``n`` records (checked against the index and the
        memory budget): X, Y, Z on the input's grid (n, 3) int32 (:func:`_refined`) and the rest of the records (n, B) uint8."""
        B = int(self.attrs["record_bytes"])
        name = f"{self.path}: {what}"
        check_memory(3 * n * (B + 12) + (s.stop - s.start), f"{name} ({n:,} points)")
        raw = self._read(array, s).tobytes()
        if self.attrs["version"] >= 5 and raw[:4] == OCTREE_MAGIC:  # an octree of residual points (residual_octree)
            rows = self._octree_rows(raw, n, B + 12, name)
        else:
            rows = self._laz_rows(raw, n, B + 12, name, pronoun)
        if rows.shape != (n, B + 12):
            raise PatchcloudIOError(f"{name}: {rows.shape[0]} points of {rows.shape[1]} bytes, the index says {n} of {B + 12}")
        xyz = _refined(self.path, rows[:, :12].copy().view("<i4").reshape(n, 3), self.steps, what)
        return xyz, rows[:, 12:].copy()

    def _octree_rows(self, raw: bytes, n: int, size: int, name: str) -> np.ndarray:
        """The (n, size) records of an octree block (:mod:`.residual_octree`)."""
        points = octree_decode(raw, name)
        if len(points.xyz) != n:
            raise PatchcloudIOError(f"{name}: {len(points.xyz):,} coded points, the index says {n:,}")
        if self.input_format_id < 0:
            raise PatchcloudIOError(f"{name}: the input's header has no point format")
        return octree_records(points, self.input_format_id, size)

    def _laz_rows(self, raw: bytes, n: int, size: int, name: str, pronoun: str) -> np.ndarray:
        """The records of a LAS/LAZ block, checked against the index (formats 0-3 back from their layered twins)."""
        check_header_sizes(name, raw[:375], len(raw))
        said, record = stated_point_count(raw), int.from_bytes(raw[105:107], "little")
        pid = self.input_format_id  # records of formats 0-3 are stored as 6 or 7 (version 4; version 3: as they were)
        layered = self.attrs["version"] >= 4 and raw[104] & 0x3F == LAYERED.get(pid)
        stored = layered_size(pid, size) if layered else size
        if said != n or record != stored:
            raise PatchcloudIOError(f"{name}: {pronoun} LAZ header says {said:,} points of {record} bytes, the index says {n:,} of {stored}")
        try:
            las = laspy.read(io.BytesIO(raw))
        except Exception as exc:
            raise PatchcloudIOError(f"{name} cannot be read ({exc})") from exc
        rows = np.ascontiguousarray(las.points.array).view(np.uint8).reshape(len(las.points), -1)
        if layered:
            try:
                rows = from_layered(rows, pid)
            except ValueError as exc:
                raise PatchcloudIOError(f"{name}: damaged ({exc})") from exc
        return rows

    def close(self) -> None:
        self._store.close()

    def __enter__(self) -> "_OpenPcz":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class PczFile(_OpenPcz):
    """An open model-mode ``.pcz`` (see :func:`open_pcz`): its attributes, and its patches and residual points by tile or region."""

    def __init__(self, path: str, root: OpenedArrays, store, largest_cell: int = 0) -> None:
        super().__init__(path, root, store)
        #: The most points one cell stands for.
        self.largest_cell = largest_cell
        self.tiles = root["tiles/ijk"][...]
        self.patch_start = root["tiles/patch_start"][...]
        self.cell_start = root["tiles/cell_start"][...]
        self.residual_start = root["tiles/residual_start"][...]
        self.residual_byte_start = root["tiles/residual_byte_start"][...]
        #: Per tile, the intensities of its cells and residual points are stored divided by 2**shift (version 5; before,
        #: exact: 0).
        self.intensity_shift = (root["tiles/intensity_shift"][...].astype(np.int64) if self.attrs["version"] >= 5
                               else np.zeros(len(self.tiles), np.int64))

    @property
    def tile_size(self) -> float:
        return float(self.attrs["grid"]["tile_size"])

    def tiles_in(self, lo, hi) -> np.ndarray:
        """Positions of the tiles whose cube meets the box ``lo``..``hi`` (the grid's local frame, metres)."""
        T = self.tile_size
        a = self.tiles * T
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        return np.flatnonzero(np.all((a <= hi) & (a + T >= lo), axis=1))

    # -- contents -------------------------------------------------------------
    def patches(self, t: int) -> tuple[QuantisedModels, np.ndarray, np.ndarray]:
        """Tile ``t``'s quantised models (root = the tile), and its cells' classification and mean intensity."""
        s = slice(int(self.patch_start[t]), int(self.patch_start[t + 1]))
        c = slice(int(self.cell_start[t]), int(self.cell_start[t + 1]))
        check_memory((s.stop - s.start) * PATCH_ROW_BYTES + (c.stop - c.start) * CELL_ROW_BYTES,
                     f"{self.path}: tile {tile_name(self.tiles[t])}'s {s.stop - s.start:,} patches and {c.stop - c.start:,} cells")
        v = {name: self._read(f"patches/{name}", s) for name, _, _ in _PATCH_ARRAYS}
        v.update({name: self._read(f"cells/{name}", c) for name, _, _ in _CELL_ARRAYS})
        T = self.tile_size
        m = QuantisedModels(
            max_error=self.max_error, root_corner=self.tiles[t] * T, root_edge=T, scale=v["scale"],
            centroid=v["centroid"].astype(np.int64), rotation=v["rotation"].astype(np.int64),
            coeffs=v["coeffs"].astype(np.int64), rmse=v["rmse"], cells=v["cells"].astype(np.int64), level=v["level"],
            ijk=v["ijk"].astype(np.int64), count=v["count"].astype(np.int64), extent=v["extent"].astype(np.int64),
            mask=v["mask"],
        )
        if int(m.cells.sum()) != m.count.shape[0]:
            raise PatchcloudIOError(f"{self.path}: tile {tile_name(self.tiles[t])}: its patches name {int(m.cells.sum())} cells, "
                                    f"the index says {m.count.shape[0]}")
        return m, v["classification"], fine_intensity(v["intensity"], int(self.intensity_shift[t]))

    def residual(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """Tile ``t``'s residual points: LAS integer xyz (R, 3) int32 and the rest of their records (R, B) uint8."""
        s = slice(int(self.residual_byte_start[t]), int(self.residual_byte_start[t + 1]))
        n = int(self.residual_start[t + 1] - self.residual_start[t])
        if n == 0:
            B = int(self.attrs["record_bytes"])
            return np.zeros((0, 3), np.int32), np.zeros((0, B), np.uint8)
        xyz, rec = self._records("residual/laz", s, n, f"the residual points of tile {tile_name(self.tiles[t])}", "their")
        if self.intensity_shift[t]:  # intensity: a record's first two bytes after X, Y, Z, in every point format
            rec[:, :2] = fine_intensity(rec[:, :2].copy().view("<u2").ravel(), int(self.intensity_shift[t])).astype("<u2")[:, None].view(np.uint8)
        return xyz, rec


class PointsPczFile(_OpenPcz):
    """An open points-mode ``.pcz`` (``compress --keep-points``; see :func:`open_pcz`): every input point, block by block."""

    def __init__(self, path: str, root: OpenedArrays, store) -> None:
        super().__init__(path, root, store)
        self.point_start = root["blocks/point_start"][...]
        self.byte_start = root["blocks/byte_start"][...]
        self.bounds = root["blocks/bounds"][...]

    def blocks_in(self, lo, hi) -> np.ndarray:
        """Positions of the blocks whose points' bounds meet the box ``lo``..``hi`` (integers of the input's grid)."""
        lo, hi = np.asarray(lo), np.asarray(hi)
        b = self.bounds
        return np.flatnonzero(np.all((b[:, :3] <= hi) & (b[:, 3:] >= lo), axis=1))

    def block(self, b: int) -> tuple[np.ndarray, np.ndarray]:
        """Block ``b``'s points in input order: X, Y, Z on the input's grid (n, 3) int32, the rest of their records (n, B) uint8."""
        s = slice(int(self.byte_start[b]), int(self.byte_start[b + 1]))
        return self._records("points/laz", s, int(self.point_start[b + 1] - self.point_start[b]), f"block {b}", "its")


def open_pcz(path: str | os.PathLike) -> PczFile | PointsPczFile:
    """Open a ``.pcz`` for reading; a PatchcloudIOError naming the file when it is not one this version reads.

    Everything the file states is checked before it is used (see the module's
    notes): a damaged or crafted file is one error naming it and what is
    wrong, and no size it states is allocated beyond the memory budget
    (a :class:`patchcloud.core.PatchcloudMemoryError`).
    """
    from zarr.storage import ZipStore

    p = Path(path)
    if not p.exists():
        raise PatchcloudIOError(f"{p}: no such file")
    if not zipfile.is_zipfile(p):
        raise PatchcloudIOError(f"{p}: not a patchcloud .pcz file (not a zip archive; truncated?)")
    try:
        with zipfile.ZipFile(p) as z:
            _check_entries(p, z)
            bad = z.testzip()
            if bad is not None:
                raise PatchcloudIOError(f"{p}: damaged .pcz file (entry {bad} fails its checksum)")
            chunks = {e.filename: _chunk_head(z, e) for e in z.infolist() if "/c/" in e.filename}
        store = ZipStore(str(p), mode="r")
        root = OpenedArrays(zarr.open_group(store, mode="r"))
        a = dict(root.attrs)
    except PatchcloudError:
        raise
    except Exception as exc:
        raise PatchcloudIOError(f"{p}: not a readable .pcz file ({exc})") from exc
    try:
        if a.get("format") != FORMAT:
            raise PatchcloudIOError(f"{p}: not a patchcloud .pcz file (no '{FORMAT}' format mark)")
        if a.get("version") not in READABLE:
            raise PatchcloudIOError(f"{p}: .pcz version {a.get('version')!r} is not supported (this patchcloud reads versions "
                                    f"{', '.join(map(str, READABLE))}; install the patchcloud that wrote it to decompress it)")
        mode = a.get("mode", "model") if a["version"] >= 3 else "model"
        if mode not in ("model", "points"):
            raise PatchcloudIOError(f"{p}: damaged .pcz file (mode {mode!r}, not model or points)")
        counts = _check_attrs(p, a, mode)
        if mode == "points":
            _check_points_arrays(p, root, chunks, counts)
            return PointsPczFile(str(p), root, store)
        largest = _check_arrays(p, root, chunks, counts)
        return PczFile(str(p), root, store, largest)
    except PatchcloudError:
        store.close()
        raise
    except Exception as exc:
        store.close()
        raise PatchcloudIOError(f"{p}: incomplete .pcz file ({exc})") from exc


def _check_entries(p: Path, z: zipfile.ZipFile) -> None:
    """Every zip entry's sizes against the file, :data:`MAX_ZIP_RATIO` and the memory budget, before any is read."""
    size = p.stat().st_size
    twice = sorted(n for n, k in Counter(e.filename for e in z.infolist()).items() if k > 1)
    if twice:
        raise PatchcloudIOError(f"{p}: damaged .pcz file (entries {', '.join(twice[:3])} appear more than once)")
    for e in z.infolist():
        if e.compress_size > size or (e.compress_type == zipfile.ZIP_STORED and e.file_size != e.compress_size):
            raise PatchcloudIOError(f"{p}: damaged .pcz file (entry {e.filename} claims {e.file_size:,} bytes, "
                                    f"{e.compress_size:,} stored, in a file of {size:,})")
        if e.file_size > max(MAX_ZIP_RATIO * e.compress_size, 1 << 20):
            raise PatchcloudIOError(f"{p}: entry {e.filename} expands from {e.compress_size:,} to {e.file_size:,} bytes "
                                    f"(more than {MAX_ZIP_RATIO} times: a zip bomb?)")
        check_memory(e.file_size, f"{p}: entry {e.filename}")


def _chunk_head(z: zipfile.ZipFile, entry: zipfile.ZipInfo) -> int | None:
    """The size a chunk entry says it decodes to (its Blosc or Zstd header), None when it does not say."""
    with z.open(entry) as f:
        head = f.read(32)
    return _decoded_size(head)


def _decoded_size(head: bytes) -> int | None:
    """The decoded size a Zstd frame header or a Blosc header states; None for neither, or a Zstd frame without it.

    >>> import numcodecs
    >>> _decoded_size(numcodecs.Zstd().encode(bytes(1000))), _decoded_size(numcodecs.Blosc().encode(bytes(300)))
    (1000, 300)
    """
    if head[:4] == _ZSTD_MAGIC and len(head) >= 6:
        d = head[4]
        single = (d >> 5) & 1
        pos = 5 + (0 if single else 1) + (0, 1, 2, 4)[d & 3]
        n = (single, 2, 4, 8)[d >> 6]
        if n == 0 or len(head) < pos + n:
            return None
        return int.from_bytes(head[pos:pos + n], "little") + (256 if n == 2 else 0)
    if len(head) >= 16 and head[0] in (1, 2):  # Blosc 1: version, versionlz, flags, typesize, nbytes (u32), ...
        return int.from_bytes(head[4:8], "little")
    return None


def _check_attrs(p: Path, a: dict, mode: str = "model") -> dict:
    """The file's attributes, checked (finite, positive where they must be); returns its counts."""
    try:
        g = a["grid"]
        keys = ("scale", "offset") if mode == "points" else ("origin", "scale", "offset")  # points mode has no tiles
        size = [] if mode == "points" else [g["tile_size"]]
        numbers = [a["max_error"], *size, *(v for k in keys for v in g[k])]
        if not all(type(v) in (int, float) for v in numbers):
            raise TypeError(f"max_error and grid: {numbers!r} are not all numbers")
        max_error, tile_size = float(a["max_error"]), float(size[0]) if size else TILE_SIZES[1]
        vectors = [np.asarray(g[k], dtype=np.float64).reshape(3) for k in keys]
        names = ("blocks", "points") if mode == "points" else ("tiles", "patches", "cells", "residual", "points")
        counts = {k: a["counts"][k] for k in names}
        record = a["record_bytes"]
        source = a["source"]
        steps = a.get("steps", [1, 1, 1])
        dropped = a.get("dropped", [])
    except (KeyError, TypeError, ValueError) as exc:
        raise PatchcloudIOError(f"{p}: incomplete .pcz file (attribute {exc} missing or malformed)") from exc
    if not (np.isfinite(max_error) and 0 < max_error <= tile_size and TILE_SIZES[0] <= tile_size <= TILE_SIZES[1]
            and all(np.isfinite(v).all() for v in vectors) and (vectors[-2] > 0).all()):
        raise PatchcloudIOError(f"{p}: damaged .pcz file (max error {max_error!r}, tile size {tile_size!r}, grid {g!r})")
    if not all(type(v) is int and v >= 0 for v in counts.values()) or type(record) is not int or not 0 <= record <= 65535 - 12:
        raise PatchcloudIOError(f"{p}: damaged .pcz file (counts {counts!r}, record bytes {record!r})")
    if (not isinstance(source, dict) or not isinstance(source.get("path", ""), str)
            or not (type(source.get("point_count", 0)) is int and source.get("point_count", 0) >= 0)):
        raise PatchcloudIOError(f"{p}: damaged .pcz file (source {source!r})")
    if (not isinstance(steps, list) or len(steps) != 3 or not all(type(k) is int and 1 <= k <= 1 << 30 for k in steps)
            or not isinstance(dropped, list) or not all(isinstance(d, str) for d in dropped)):
        raise PatchcloudIOError(f"{p}: damaged .pcz file (steps {steps!r}, dropped {dropped!r})")
    return counts


def _check_points_arrays(p: Path, root: OpenedArrays, chunks: dict[str, int | None], counts: dict) -> None:
    """A points-mode file's arrays against its layout and counts."""
    B = counts["blocks"]
    laz = _array(p, root, "points/laz", np.uint8, (), None, chunks)
    for name, total, what in (("point_start", counts["points"], "points"), ("byte_start", laz.shape[0], "bytes")):
        s = _array(p, root, f"blocks/{name}", np.int64, (), B + 1, chunks)[...]
        if s[0] != 0 or np.any(np.diff(s) < 0) or int(s[-1]) != total:
            raise PatchcloudIOError(f"{p}: damaged .pcz file (blocks/{name} does not rise from 0 to the file's {total:,} {what})")
    _array(p, root, "blocks/bounds", np.int64, (6,), B, chunks)
    for name in ("header", "evlrs"):
        _array(p, root, name, np.uint8, (), None, chunks)


def _check_arrays(p: Path, root: OpenedArrays, chunks: dict[str, int | None], counts: dict) -> int:
    """Every array's type, shape and chunks against the layout, the tile index against them and the counts; returns
    the most points a cell stands for."""
    T = counts["tiles"]
    rows = {"patches": counts["patches"], "cells": counts["cells"]}
    _array(p, root, "tiles/ijk", np.int64, (3,), T, chunks)
    starts = {}
    for name in _STARTS:
        s = _array(p, root, f"tiles/{name}", np.int64, (), T + 1, chunks)[...]
        if s[0] != 0 or np.any(np.diff(s) < 0):
            raise PatchcloudIOError(f"{p}: damaged .pcz file (tiles/{name} does not rise from 0)")
        starts[name] = s
    for group, arrays in (("patches", _PATCH_ARRAYS), ("cells", _CELL_ARRAYS)):
        for name, dtype, tail in arrays:
            _array(p, root, f"{group}/{name}", dtype, tail, rows[group], chunks)
    if root.attrs["version"] >= 5:
        shift = _array(p, root, "tiles/intensity_shift", np.uint8, (), T, chunks)[...]
        if shift.size and int(shift.max()) > 16:
            raise PatchcloudIOError(f"{p}: damaged .pcz file (a tile's intensities shifted by {int(shift.max())} bits, "
                                    "beyond their 16)")
    laz = _array(p, root, "residual/laz", np.uint8, (), None, chunks)
    for name, n, what in (("patch_start", counts["patches"], "patches"), ("cell_start", counts["cells"], "cells"),
                          ("residual_start", counts["residual"], "residual points"),
                          ("residual_byte_start", laz.shape[0], "residual bytes")):
        if int(starts[name][-1]) != n:
            raise PatchcloudIOError(f"{p}: damaged .pcz file (the tile index ends at {int(starts[name][-1]):,} {what}, "
                                    f"the file holds {n:,})")
    for name in ("header", "evlrs"):
        _array(p, root, name, np.uint8, (), None, chunks)
    C = counts["cells"]
    check_memory(4 * (C + counts["patches"]), f"{p}: the counts of its {C:,} cells")
    named = int(root["patches/cells"][...].sum(dtype=np.int64))
    cell_counts = root["cells/count"][...]
    stood = int(cell_counts.sum(dtype=np.int64))
    if named != C or stood + counts["residual"] != counts["points"]:
        raise PatchcloudIOError(f"{p}: damaged .pcz file (its patches name {named:,} cells of {C:,}; its cells stand for "
                                f"{stood:,} points and its residual {counts['residual']:,}, the counts say {counts['points']:,})")
    return int(cell_counts.max()) if C else 0


def _array(p: Path, root: OpenedArrays, name: str, dtype, tail: tuple, rows: int | None, chunks: dict) -> zarr.Array:
    """Array ``name``, checked: its type, its shape (``rows`` rows if given, of shape ``tail``), codecs and chunks."""
    try:
        a = root[name]
    except KeyError:
        raise PatchcloudIOError(f"{p}: incomplete .pcz file (no {name} array)") from None
    ok = isinstance(a, zarr.Array) and a.dtype == np.dtype(dtype) and a.shape[1:] == tail and len(a.shape) == 1 + len(tail)
    if not ok or (rows is not None and a.shape[0] != rows):
        raise PatchcloudIOError(f"{p}: damaged .pcz file (array {name} is {getattr(a, 'dtype', '?')} of shape "
                                f"{getattr(a, 'shape', '?')}, not {np.dtype(dtype)} of {'N' if rows is None else rows} rows of {tail})")
    m = a.metadata
    codecs = [type(c).__name__ for c in m.codecs]
    enc = m.chunk_key_encoding
    columns = codecs == ["TransposeCodec", "BytesCodec", "BloscCodec"] and len(tail) == 1 and tuple(m.codecs[0].order) == (1, 0)
    if ((codecs not in (["BytesCodec", "BloscCodec"], ["BytesCodec", "ZstdCodec"]) and not columns) or m.storage_transformers
            or type(enc).__name__ != "DefaultChunkKeyEncoding" or enc.separator != "/" or a.chunks[1:] != tail):
        raise PatchcloudIOError(f"{p}: damaged .pcz file (array {name}: codecs {codecs}, chunks {a.chunks}: not this layout)")
    whole = int(np.prod(a.chunks)) * a.dtype.itemsize
    check_memory(whole, f"{p}: a chunk of {name}")
    if name.startswith(("tiles/", "blocks/")):  # read whole as the file opens
        check_memory(int(np.prod(a.shape)) * a.dtype.itemsize, f"{p}: {name}")
    if root.attrs.get("version", 0) >= 5 and a.shape[0]:  # every chunk is written: one missing is damage
        tail_keys = "/0" * len(tail)
        for i in range(-(-a.shape[0] // a.chunks[0])):
            if f"{name}/c/{i}{tail_keys}" not in chunks:
                raise PatchcloudIOError(f"{p}: damaged .pcz file (chunk {name}/c/{i}{tail_keys} is missing)")
    prefix = f"{name}/c/"
    for key, size in chunks.items():
        if key.startswith(prefix) and size != whole:
            raise PatchcloudIOError(f"{p}: damaged .pcz file (chunk {key} decodes to "
                                    f"{'an unstated size' if size is None else f'{size:,} bytes'}, its array's chunks to {whole:,})")
    return a


