"""A catalog: several LAS/LAZ/COPC files taken as one cloud, on one integer grid, one output per input.

Users hold tiles of one survey (hundreds of 1 km² files).  A job on a
catalog treats them as the file that concatenating them would make: the
catalog's point ``i`` is point ``i - start[f]`` of file ``f``, the files in
the order of their sorted paths (so nothing depends on the order a shell or
a glob lists them).

**One grid.**  The store keeps LAS integer coordinates, so every file is
re-expressed on one grid: the finest scale of the files (per axis) and the
offset of the first file on that scale.  A file's integers ``X`` become ``X * factor + shift``
(integers, exact): this needs each file's scale to be a whole multiple of
the common scale and its offset to differ from the first file's by a whole
number of common steps; otherwise the files cannot be merged without
rounding and the catalog is refused with one error naming two files.

**Empty files.**  A file of no points (an empty tile of a survey) takes
part in nothing but the CRS check: its output is its header with the new
dimensions and no points.  A catalog whose every file is empty is refused.

**One CRS.**  CRSs are compared as CRSs (pyproj's equality, not their
bytes); two different ones are an error naming a file of each.  A file
without a CRS among files with one is an error unless ``assume_crs`` says
which CRS such files are in.

>>> factor_and_shift((0.01, 0.01, 0.01), (0.0, 0.0, 0.0), (0.001, 0.001, 0.001), (0.0, 0.0, 0.0))
((10, 10, 10), (0, 0, 0))
>>> factor_and_shift((0.001, 0.001, 0.001), (100.0, 0.0, 0.0), (0.001, 0.001, 0.001), (0.0, 0.0, 0.0))
((1, 1, 1), (100000, 0, 0))
>>> factor_and_shift((0.003, 0.001, 0.001), (0.0, 0.0, 0.0), (0.002, 0.001, 0.001), (0.0, 0.0, 0.0)) is None
True
"""

from __future__ import annotations

import functools
import glob
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from patchcloud.core import PatchcloudIOError, PatchcloudValueError

from .las import LasSource, is_copc_name, open_source

__all__ = ["Catalog", "expand_inputs", "open_catalog", "same_crs", "output_name", "output_paths", "check_out_dir", "factor_and_shift", "LAS_SUFFIXES"]

#: File name endings taken from a directory (case-insensitive).
LAS_SUFFIXES = (".las", ".laz")
_INT32 = 2**31 - 1


@dataclass(frozen=True)
class Catalog:
    """Files taken as one cloud: their sources, the common grid, and how each file's integers map onto it.

    Attributes
    ----------
    sources : tuple of LasSource
        The files, sorted by path.
    scale, offset : (3,) tuples of float
        The common grid: ``x = X * scale + offset`` with ``X`` the common integers.
    factor, shift : tuple of (3,) tuples of int
        File ``f``'s integers ``X_f`` are ``X_f * factor[f] + shift[f]`` on the common grid.
    crs : str or None
        The catalog's CRS (WKT), or None when no file has one.
    names : tuple of str
        The files' paths as they were named (a link's own name, where
        ``sources`` hold the file's resolved path), in the same order; empty
        for a catalog made otherwise (then :meth:`name` is the resolved one).
    """

    sources: tuple[LasSource, ...]
    scale: tuple[float, float, float]
    offset: tuple[float, float, float]
    factor: tuple[tuple[int, int, int], ...]
    shift: tuple[tuple[int, int, int], ...]
    crs: str | None = None
    names: tuple[str, ...] = ()

    def name(self, f: int) -> str:
        """File ``f``'s path as it was named (see ``names``)."""
        return self.names[f] if len(self.names) == len(self.sources) else self.sources[f].path

    @property
    def point_count(self) -> int:
        return int(sum(s.point_count for s in self.sources))

    @property
    def starts(self) -> np.ndarray:
        """(F + 1,) int64: file ``f``'s points are the catalog's points ``starts[f]:starts[f + 1]``."""
        return np.r_[0, np.cumsum([s.point_count for s in self.sources])].astype(np.int64)

    @property
    def holding(self) -> tuple[LasSource, ...]:
        """The files that hold points (an empty file's header bounds say nothing of where the cloud is)."""
        return tuple(s for s in self.sources if s.point_count > 0) or self.sources

    @property
    def mins(self) -> tuple[float, float, float]:
        return tuple(float(min(s.mins[a] for s in self.holding)) for a in range(3))

    @property
    def maxs(self) -> tuple[float, float, float]:
        return tuple(float(max(s.maxs[a] for s in self.holding)) for a in range(3))

    @property
    def path(self) -> str:
        """The file's path for one file; for several, the first one and how many follow (for summaries and errors)."""
        if len(self.sources) == 1:
            return self.sources[0].path
        return f"{self.sources[0].path} and {len(self.sources) - 1} more file{'s' if len(self.sources) > 2 else ''}"

    def common(self, f: int, X: np.ndarray, Y: np.ndarray, Z: np.ndarray) -> np.ndarray:
        """(n, 3) int32 common-grid integers of file ``f``'s integer coordinates.

        Raises PatchcloudIOError when a point lies outside the 32-bit range of
        the common grid (a point far outside its file's header bounds).
        """
        k, d = self.factor[f], self.shift[f]
        if k == (1, 1, 1) and d == (0, 0, 0):
            return np.column_stack([X, Y, Z]).astype(np.int32, copy=False)
        out = np.column_stack([np.asarray(v, dtype=np.int64) * k[a] + d[a] for a, v in enumerate((X, Y, Z))])
        if out.size and (out.min() < -_INT32 - 1 or out.max() > _INT32):
            raise PatchcloudIOError(f"{self.sources[f].path}: points lie outside the catalog's 32-bit integer grid")
        return out.astype(np.int32)

    def same_files(self, other: dict) -> bool:
        """True when ``other`` (a :meth:`to_json` dict) is this catalog with every file unchanged."""
        theirs = other.get("sources") or []
        return len(theirs) == len(self.sources) and all(s.same_file(o) for s, o in zip(self.sources, theirs))

    def to_json(self) -> dict:
        return dict(sources=[s.to_json() for s in self.sources], scale=list(self.scale), offset=list(self.offset),
                    factor=[list(k) for k in self.factor], shift=[list(d) for d in self.shift], crs=self.crs)

    @classmethod
    def from_json(cls, d: dict) -> "Catalog":
        return cls(
            sources=tuple(LasSource.from_json(s) for s in d["sources"]), scale=tuple(d["scale"]), offset=tuple(d["offset"]),
            factor=tuple(tuple(int(v) for v in k) for k in d["factor"]), shift=tuple(tuple(int(v) for v in s) for s in d["shift"]),
            crs=d.get("crs"),
        )

    @classmethod
    def of(cls, src: LasSource) -> "Catalog":
        """The catalog of one file (its own grid)."""
        return cls(sources=(src,), scale=src.scale, offset=src.offset, factor=((1, 1, 1),), shift=((0, 0, 0),), crs=src.crs)


def factor_and_shift(scale, offset, common_scale, common_offset):
    """Integers ``(factor, shift)`` with ``X * scale + offset == (X * factor + shift) * common_scale + common_offset``
    for every integer ``X``, or None when there are none."""
    factor, shift = [], []
    for s, o, cs, co in zip(scale, offset, common_scale, common_offset):
        k = round(s / cs)
        if k < 1 or abs(k * cs - s) > 1e-9 * s:
            return None
        d = (o - co) / cs
        if abs(d - round(d)) > 1e-6:
            return None
        factor.append(int(k))
        shift.append(int(round(d)))
    return tuple(factor), tuple(shift)


def expand_inputs(inputs) -> list[Path]:
    """The LAS/LAZ files that ``inputs`` name, sorted by path, each once (the same file under two names: an error).

    ``inputs``: a path, a directory (its ``*.las`` and ``*.laz`` files, any
    case, not its sub-directories), a glob pattern (``tiles/*.laz``), or a
    list of these.  Files named explicitly are taken whatever their name
    (a file that is not LAS/LAZ is refused when opened).

    Raises
    ------
    PatchcloudIOError
        A path that does not exist and matches nothing, a directory with no
        LAS/LAZ file, or no input at all.
    """
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    found: list[Path] = []
    for item in inputs:
        p = Path(item)
        if p.is_dir():
            here = sorted(q for q in p.iterdir() if q.is_file() and q.name.lower().endswith(LAS_SUFFIXES))
            if not here:
                raise PatchcloudIOError(f"{p}: a directory with no LAS/LAZ file (*.las, *.laz)")
            found += here
        elif p.exists():
            found.append(p)
        elif glob.has_magic(str(item)):
            matched = sorted(Path(m) for m in glob.glob(str(item)) if Path(m).is_file())
            if not matched:
                raise PatchcloudIOError(f"{item}: no file matches")
            found += matched
        else:
            raise PatchcloudIOError(f"{p}: no such file")
    if not found:
        raise PatchcloudIOError("no input file given")
    # one file once, by what it is (device and inode: a symbolic or a hard link is the file it names); named twice
    # under two names, its output's name would be a guess (found by a sweep of 2026-11-27: a hard link took its points
    # twice, a symbolic one wrote only one of the two outputs asked for)
    first: dict[tuple[int, int], Path] = {}
    for q in sorted(found, key=lambda q: str(q)):
        st = q.stat()
        seen = first.setdefault((st.st_dev, st.st_ino), q)
        if seen.name != q.name:
            raise PatchcloudIOError(f"{seen} and {q}: the same file under two names (give it once)")
    # sorted by the paths as given, made absolute but not resolved: a directory of symbolic links is in its links' order,
    # as the outputs (named after them) are, not in their targets' (bug hunt F)
    return sorted(first.values(), key=lambda q: os.path.abspath(q))


def output_name(path: str | os.PathLike) -> str:
    """The output name of an input in ``--out-dir``: the same name, ``.copc.laz`` becoming ``.laz`` (LAS/LAZ, not COPC).

    >>> output_name("a/tile_1.laz"), output_name("b/tile_2.copc.laz"), output_name("c/T.LAS")
    ('tile_1.laz', 'tile_2.laz', 'T.LAS')
    """
    name = Path(path).name
    if is_copc_name(name):
        return name[: -len(".copc.laz")] + ".laz"
    return name


def output_paths(paths: list[Path], out_dir: str | os.PathLike, inputs=(), suffix: str | None = None) -> list[Path]:
    """Where each input's output goes in ``out_dir``; errors for two inputs with one output name or ``out_dir`` inside an input directory.

    ``inputs``: the inputs as given, to refuse an output directory inside
    a directory given as input (the outputs would mix with the inputs).
    ``suffix``: the outputs' suffix (``.pcz``, ``.png``) instead of the
    input's (:func:`output_name`).

    >>> [p.name for p in output_paths([Path("a/t1.laz"), Path("b/t2.copc.laz")], "out", suffix=".png")]
    ['t1.png', 't2.png']
    """
    out = Path(out_dir)
    names: dict[str, Path] = {}  # output name, lower case -> its input
    outs = []
    for p in paths:
        n = output_name(p) if suffix is None else str(Path(output_name(p)).with_suffix(suffix))
        if n.lower() in names:
            raise PatchcloudValueError(f"{names[n.lower()]} and {p}: two inputs would write the same output {out / n}")
        names[n.lower()] = p
        outs.append(out / n)
    o = out.resolve()
    for item in (Path(i) for i in ([inputs] if isinstance(inputs, (str, os.PathLike)) else inputs)):
        if item.is_dir():
            d = item.resolve()
            if o == d or d in o.parents:
                raise PatchcloudValueError(f"{out}: the output directory is inside the input directory {item}; choose another")
    return outs


def check_out_dir(out_dir: str | os.PathLike) -> Path:
    """``out_dir`` as a Path once it can hold the outputs: a directory, or absent with its parent there (the caller makes
    it once everything else is checked, so an error leaves nothing behind)."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise PatchcloudIOError(f"{out}: exists and is not a directory")
    if not out.parent.is_dir():
        raise PatchcloudIOError(f"{out}: the directory {out.parent} does not exist")
    return out


def same_crs(a: str, b: str) -> bool:
    """Whether two CRSs (WKT) are one: the same text, equal to pyproj (axis order aside), or both naming the same
    authority code (IGN's tiles say "RGF93 v1 / Lambert-93" or "RGF93 / Lambert-93", both EPSG:2154, by the
    version of the software that wrote them)."""
    if a == b:
        return True
    ca, cb = _parsed_crs(a), _parsed_crs(b)
    if ca == cb or ca.equals(cb, ignore_axis_order=True):
        return True
    ida, idb = ca.to_json_dict().get("id"), cb.to_json_dict().get("id")
    return isinstance(ida, dict) and ida == idb and "code" in ida


@functools.lru_cache(maxsize=64)
def _parsed_crs(wkt: str):
    from pyproj import CRS

    return CRS.from_wkt(wkt)


def open_catalog(inputs, assume_crs: str | None = None) -> Catalog:
    """Open every file ``inputs`` name (:func:`expand_inputs`) and check they make one cloud.

    Parameters
    ----------
    inputs : path, glob, directory or list of them
    assume_crs : str, optional
        The CRS of the files that have none (anything pyproj takes:
        ``"EPSG:2154"``, WKT); without it, a file without a CRS among files
        with one is an error.

    Raises
    ------
    PatchcloudIOError
        A file that is not a complete LAS/LAZ (see :func:`open_source`), or
        every file empty (one empty file among others is taken: see above).
    PatchcloudValueError
        Different CRSs, a missing CRS, or grids that cannot be merged exactly;
        the message names the files.
    """
    paths = expand_inputs(inputs)
    sources = [open_source(p, allow_empty=len(paths) > 1) for p in paths]
    holding = [s for s in sources if s.point_count > 0]
    if not holding:
        others = f"the {len(sources) - 1} other files" if len(sources) > 2 else "the other file"
        raise PatchcloudIOError(f"{sources[0].path} and {others}: every file holds no points")
    crs = _catalog_crs(sources, assume_crs)
    scale = tuple(min(s.scale[a] for s in holding) for a in range(3))
    # per axis, the first file on the finest grid of that axis (files may have their finest step on different axes)
    refs = [next(s for s in holding if s.scale[a] == scale[a]) for a in range(3)]
    offset = tuple(refs[a].offset[a] for a in range(3))
    ref = refs[0]
    factor, shift = [], []
    for s in sources:
        if s.point_count == 0:  # no integers to put on the grid (whatever its header's scale and bounds)
            factor.append((1, 1, 1))
            shift.append((0, 0, 0))
            continue
        fs = factor_and_shift(s.scale, s.offset, scale, offset)
        if fs is None:
            raise PatchcloudValueError(
                f"{ref.path} and {s.path}: their scales {ref.scale} and {s.scale} and offsets "
                f"{ref.offset} and {s.offset} cannot be put on one integer grid exactly (each scale a whole "
                f"multiple of the finest, offsets a whole number of steps apart)"
            )
        for lo, hi, a in ((s.mins, s.maxs, a) for a in range(3)):
            for v in (lo[a], hi[a]):
                if abs((v - offset[a]) / scale[a]) > _INT32:
                    raise PatchcloudValueError(
                        f"{s.path}: its coordinates do not fit the 32-bit integer grid of scale {scale} and offset {offset} "
                        f"shared with {ref.path}"
                    )
        factor.append(fs[0])
        shift.append(fs[1])
    return Catalog(sources=tuple(sources), scale=scale, offset=offset, factor=tuple(factor), shift=tuple(shift), crs=crs,
                   names=tuple(str(p) for p in paths))


def _catalog_crs(sources: list[LasSource], assume_crs: str | None) -> str | None:
    """The one CRS of the files (WKT) or None; an error naming two files that differ, or a file without one."""
    assumed = None
    if assume_crs is not None:
        from pyproj import CRS
        from pyproj.exceptions import CRSError

        try:
            parsed = CRS.from_user_input(assume_crs)
        except CRSError as exc:
            raise PatchcloudValueError(f"assume_crs: not a CRS pyproj knows: {assume_crs!r} ({exc})") from exc
        if not (parsed.is_projected or parsed.is_geocentric):  # what the files' x, y, z are in: lengths, not degrees
            kind = "geographic (degrees are not lengths)" if parsed.is_geographic else "a vertical CRS alone (nothing of x and y)"
            raise PatchcloudValueError(
                f"assume_crs {assume_crs!r} is {kind}: give the projected CRS the files' coordinates are in (a compound "
                f"one, e.g. EPSG:2154+5720, for their heights too), or reproject them first (PDAL's filters.reprojection)"
            )
        assumed = parsed.to_wkt()
    first: LasSource | None = None
    distinct: dict[str, LasSource] = {}  # each CRS text once, with the first file that has it
    for s in sources:
        if s.crs is None:
            continue
        if first is None:
            first = s
        distinct.setdefault(s.crs, s)
    texts = list(distinct)
    for i, a in enumerate(texts):  # every pair (whatever the files' order: "the same" need not be transitive)
        for b in texts[i + 1:]:
            if not same_crs(a, b):
                raise PatchcloudValueError(f"{distinct[a].path} and {distinct[b].path}: different CRSs; a catalog is in one CRS")
    if assumed is not None and first is not None and not same_crs(assumed, first.crs):
        raise PatchcloudValueError(f"{first.path}: its CRS is not the assumed one ({assume_crs})")
    missing = [s for s in sources if s.crs is None]
    if missing and first is not None and assumed is None:
        what = f"its CRS record cannot be read ({missing[0].crs_error})" if missing[0].crs_error else "no CRS"
        raise PatchcloudValueError(
            f"{missing[0].path}: {what}, while {first.path} has one; give --assume-crs (assume_crs) to say which CRS files without one are in"
        )
    if first is not None:
        return first.crs
    return assumed
