"""Export: each input file again, every point once and in input order, with the results as extra dimensions.

The store's input is a catalog (one file, or several taken as one cloud):
there is one output per file.  Writing runs as tasks, one per part of a
file (the ingest's parts, each
a whole number of LAZ chunks): a task (:func:`export_part`) reads its part
of the input again; the store's index says how many of its points went
to each tile and from which row of the tile's results they start (a
tile's results are kept in input order), so the task gathers its
points' results, appends them to the records (every byte of every
original record, extra bytes included, copied as it is) and writes them:
LAS at their place in the pre-sized output, LAZ as compressed chunks
that the client stitches with one chunk table
(:mod:`patchcloud.stream.io.las_output`).  The files are byte-identical
whatever the number of workers, the scheduler or the part size.

A job declares what it adds as :class:`Column` s (see
:meth:`patchcloud.stream.engine.job.Job.columns`).  Ids that are renumbered
in order of first appearance in the catalog (``renumber``, e.g. ClusterID)
take one more pass over the parts first: each part's ids in the order they
first appear (:func:`first_seen_part`), numbered by the client in part order.

**Resume per file.**  Each output is finished (stitched, renamed) as soon
as the last of its parts is written, and recorded in the store (group
``outputs``: its path, size, modification time and :func:`output_key`).
A rerun on the same store skips every output recorded as complete with the
same key whose file is still as recorded (:func:`complete_outputs`), and
writes the others: after a crash during the export of a catalog, only the
files not yet finished are written again.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import laspy
import numpy as np

from patchcloud.core import PatchcloudIOError, PatchcloudValueError

from patchcloud.stream.engine.ingest import catalog_parts, pack_tile_keys, read_part, route_path, store_selection, tile_keys
from patchcloud.stream.engine.runner import Runner
from patchcloud.stream.io import las_output, memory_group
from patchcloud.stream.io.las import POSITION_AND_CLASS, check_writable, is_laz_name, output_header
from patchcloud.stream.io.catalog import Catalog
from patchcloud.stream.io.store import Store
from patchcloud.stream.io.renamed import partial_path, rename_into_place

__all__ = ["Column", "export_columns", "export_part", "first_seen_part", "FirstSeenIds", "output_key", "complete_outputs", "file_record",
           "output_record_name", "record_output", "same_request"]


@dataclass(frozen=True)
class Column:
    """A per-tile result array (in the tile's input order) and the output dimensions it fills.

    ``array`` is the tile array's name; ``dims`` the output dimensions, one
    per column of the array (one for a 1-D array).  ``per_tile(store, t,
    values)``, when given, turns a tile's rows into output values (``t``
    the tile's position in the store's list), e.g. to make ids global: a
    module-level function, since tasks may run in other processes.
    ``renumber``: the values are ids (0 for none), renumbered 1, 2, ... in
    the order they first appear in the file.  ``empty``: what the points
    the store's tiles leave out (:mod:`patchcloud.stream.io.classes`: not of
    the classes asked for, noise, withheld) hold, the dimensions'
    documented empty value.
    """

    array: str
    dims: tuple[str, ...]
    dtype: type
    per_tile: Callable[[Store, int, np.ndarray], np.ndarray] | None = None
    renumber: bool = False
    empty: float = 0


class FirstSeenIds:
    """Renumbers ids 1, 2, ... in the order they first appear (0 stays 0), call after call.

    Examples
    --------
    >>> f = FirstSeenIds()
    >>> f(np.array([0, 7, 3, 7])).tolist(), f(np.array([3, 9, 0])).tolist()
    ([0, 1, 2, 1], [2, 3, 0])
    """

    def __init__(self) -> None:
        self.known = np.zeros(0, dtype=np.int64)  # sorted ids seen so far
        self.number = np.zeros(0, dtype=np.int64)  # their new numbers

    def __call__(self, ids: np.ndarray) -> np.ndarray:
        ids = np.asarray(ids, dtype=np.int64)
        out = np.zeros(ids.shape, dtype=np.int64)
        nz = ids != 0
        if not nz.any():
            return out
        v = ids[nz]
        uniq, first = np.unique(v, return_index=True)
        pos = np.searchsorted(self.known, uniq)
        seen = np.zeros(uniq.size, dtype=bool)
        inside = pos < self.known.size
        seen[inside] = self.known[pos[inside]] == uniq[inside]
        new = uniq[~seen][np.argsort(first[~seen], kind="stable")]
        start = self.number.size + 1
        ids_all = np.r_[self.known, new]
        num_all = np.r_[self.number, np.arange(start, start + new.size)]
        o = np.argsort(ids_all, kind="stable")
        self.known, self.number = ids_all[o], num_all[o]
        out[nz] = self.number[np.searchsorted(self.known, v)]
        return out


def _part_values(store: Store, cat: Catalog, p: int, f: int, first: int, count: int, columns: list[Column], laz_parallel: bool,
                 selection: laspy.DecompressionSelection | None = None):
    """Part ``p``'s input records (points ``first:first + count`` of file ``f`` of ``cat``, the store's catalog) and,
    for each column, their values.  ``selection``: the fields to decode of a layered LAZ (default: all)."""
    src = cat.sources[f]
    records = read_part(store, p, src, first, count, laz_parallel, selection=selection)
    kept = np.flatnonzero(store_selection(store).mask(records))  # the points the tiles hold; the others get each column's empty value
    xyz = cat.common(f, records["X"][kept], records["Y"][kept], records["Z"][kept])
    tid = np.full(len(records), -1, dtype=np.int64)
    tid[kept] = np.searchsorted(pack_tile_keys(np.asarray(store.tiles, dtype=np.int64)), tile_keys(store.grid, xyz))
    return records, _routed_values(store, src, p, tid, columns, local=False)


def _routed_values(store: Store, src, p: int, tid: np.ndarray, columns: list[Column], local: bool) -> list[np.ndarray]:
    """For each column, the values of part ``p``'s points, each in tile ``tid`` (-1: left out, the column's empty
    value): a tile's position in the store's list, or with ``local`` among the part's own tiles (in key order)."""
    index = store.get("index/part_tile")
    lo, hi = np.searchsorted(index[:, 0], [p, p + 1])
    rows = index[lo:hi]
    starts = store.get("index/tile_start", slice(int(lo), int(hi)))
    n = len(tid)
    kept = np.flatnonzero(tid >= 0)
    t = tid[kept]
    if local:
        t = rows[:, 1][t]
    counts = np.bincount(t, minlength=len(store.tiles))
    if not np.array_equal(counts[rows[:, 1]], rows[:, 2]) or counts.sum() != rows[:, 2].sum():
        raise PatchcloudIOError(f"{src.path}: the file no longer matches the store {store.url} (part {p})")
    order = kept[np.argsort(t, kind="stable")]
    values = [np.full((n, len(col.dims)) if len(col.dims) > 1 else n, col.empty, col.dtype) for col in columns]
    tiles = store.tiles
    s = 0
    for ti, m, start in zip(rows[:, 1].tolist(), rows[:, 2].tolist(), starts.tolist()):
        dst = order[s : s + m]
        for col, v in zip(columns, values):
            got = store.read(tiles[ti], col.array, slice(start, start + m))
            v[dst] = col.per_tile(store, ti, got) if col.per_tile else got
        s += m
    return values


def first_seen_part(url: str, p: int, f: int, first: int, count: int, columns: list[Column], laz_parallel: bool = False) -> list:
    """Task: for each column to renumber, its ids in part ``p`` in the order they first appear (0 left out).

    The points' tiles come from the part's route where the ingest recorded
    one (nothing decoded), else from the records' positions and classes.
    """
    store = Store.open(url)
    cat = store.catalog
    route = route_path(p)
    if int(store.group_attrs(route).get("points", -1)) == count:
        values = _routed_values(store, cat.sources[f], p, store.get(f"{route}/tile").astype(np.int64), columns, local=True)
    else:
        _, values = _part_values(store, cat, p, f, first, count, columns, laz_parallel, POSITION_AND_CLASS)
    out = []
    for v in values:
        v = np.asarray(v, dtype=np.int64).reshape(-1)
        uniq, at = np.unique(v[v != 0], return_index=True)
        out.append(uniq[np.argsort(at, kind="stable")])
    return out


def export_part(url: str, p: int, f: int, local: int, first: int, count: int, columns: list[Column], dims, tmp: str,
                start: int, compressed: bool, laz_parallel: bool = False):
    """Task: part ``p`` of the catalog (part ``local`` of file ``f``): its records plus the columns, written into ``tmp``.

    Returns the part's header statistics and, for LAZ, its chunk-table entries.
    """
    store = Store.open(url)
    cat = store.catalog
    src = cat.sources[f]
    header = las_output.prepare_header(output_header(src, dims, crs=cat.crs), compressed)
    # a layered LAZ input whose records the output keeps: its chunks are copied, only the new bytes coded
    layered = las_output.layered_source(src.path, header, [name for col in columns for name in col.dims])
    if layered is not None:
        routed = _export_routed(store, src, p, local, first, count, columns, header, layered, tmp)
        if routed is not None:
            return routed
    records, values = _part_values(store, cat, p, f, first, count, columns, laz_parallel, layered.selection if layered else None)
    n = len(records)
    out = laspy.PackedPointRecord.zeros(n, header.point_format)
    las_output.copy_records(records, out.array)
    stored = _stored(store, columns, values, n, out.array.dtype)
    for name, v in stored.items():
        out[name] = v
    stats = las_output.point_stats(header, out, stored)
    if layered is not None:
        rec = out.array.view(np.uint8).reshape(n, out.array.dtype.itemsize)
        at = layered.plan.at
        return stats, las_output.write_laz_part_layered(tmp, local, layered, first, rec[:, at : at + layered.plan.new_bytes],
                                                        np.asarray(out["scanner_channel"]))
    if compressed:
        return stats, las_output.write_laz_part(tmp, local, header, out, parallel=laz_parallel)
    las_output.write_las_part(tmp, start, first, out)
    return stats, None


def _stored(store: Store, columns: list[Column], values: list[np.ndarray], n: int, dtype: np.dtype) -> dict[str, np.ndarray]:
    """Each new dimension's values as stored (``dtype``'s field), contiguous (its header range is read from them); ids
    renumbered where a column asks (:attr:`Column.renumber`)."""
    stored = {}
    for col, v in zip(columns, values):
        if col.renumber:
            known, number = store.get(f"export/{col.array}_ids"), store.get(f"export/{col.array}_numbers")
            w = np.asarray(v, dtype=np.int64)
            v = np.where(w != 0, number[np.clip(np.searchsorted(known, w), 0, max(known.size - 1, 0))] if known.size else 0, 0)
        for k, name in enumerate(col.dims):
            stored[name] = np.ascontiguousarray((v if len(col.dims) == 1 else v[:, k]).reshape(n), dtype=dtype[name])
    return stored


def _export_routed(store: Store, src, p: int, local: int, first: int, count: int, columns: list[Column], header: laspy.LasHeader,
                   layered: las_output.LayeredSource, tmp: str):
    """:func:`export_part` of a layered input without decoding it: from the route the ingest recorded
    (:func:`~patchcloud.stream.engine.ingest.route_path`: each point's tile, scanner channel and the records' header
    statistics), the new bytes coded beside the input's copied chunks.  None where the store has no route of the
    part (made by an older version) or it does not fit the output's header: the records are then decoded."""
    route = route_path(p)
    info = store.group_attrs(route)
    if "stats" not in info or int(info.get("points", -1)) != count:
        return None
    part_stats = las_output.PointStats.from_json(info["stats"])
    b = header.point_format.dtype()
    at, end = layered.plan.at, layered.plan.at + layered.plan.new_bytes  # the new bytes of each output record
    new_names = [name for name in b.names if at <= b.fields[name][1] < end]
    structs = las_output.extra_bytes_structs(header)
    later = structs[len(part_stats.eb_min) + len(new_names):]  # an input's second ExtraBytes VLR's (stream.io.las.assemble_header)
    if len(structs) < len(part_stats.eb_min) + len(new_names) or any(s.min_is_relevant() or s.max_is_relevant() for s in later):
        return None
    st = os.stat(src.path)
    if st.st_size != src.size or st.st_mtime_ns != src.mtime_ns:
        raise PatchcloudIOError(f"{src.path}: the file changed after it was read into the store {store.url}")
    tid = store.get(f"{route}/tile").astype(np.int64)
    values = _routed_values(store, src, p, tid, columns, local=True)
    new_dtype = np.dtype(dict(names=new_names, formats=[b.fields[n][0] for n in new_names],
                              offsets=[b.fields[n][1] - at for n in new_names], itemsize=end - at))
    stored = _stored(store, columns, values, count, b)
    new = np.zeros(count, dtype=new_dtype)
    for name, v in stored.items():
        new[name] = v
    channels = store.get(f"{route}/channel") if store.has_array(f"{route}/channel") else np.zeros(count, dtype=np.uint8)
    stats = las_output.with_new_dims(part_stats, header, stored, count)
    table = las_output.write_laz_part_layered(tmp, local, layered, first, new.view(np.uint8).reshape(count, new_dtype.itemsize), channels)
    return stats, table


def output_key(store: Store, columns: list[Column], dims, provenance: laspy.VLR | None = None) -> str:
    """What an output holds, as a short hash: the dimensions added, the columns, the steps done on the store (with
    the keys of their resolved parameters) and the job's parameters as its provenance VLR states them (a DoN radius, a
    segment tolerance), so an output written after other parameters is not taken as this one."""
    what = dict(dims=[[str(d[0]), np.dtype(d[1]).str] for d in dims], columns=[[c.array, list(c.dims), c.empty] for c in columns],
                steps=store.attrs.get("steps", {}), params=store.attrs.get("params_key"), selection=store.attrs.get("selection"),
                provenance=None if provenance is None else bytes(provenance.record_data).decode("utf-8", "replace"))
    return hashlib.sha256(json.dumps(what, sort_keys=True, default=str).encode()).hexdigest()[:16]


def file_record(path: Path) -> dict:
    """What says a file is unchanged: its resolved path, size and modification time."""
    st = path.stat()
    return dict(path=str(path.resolve()), size=int(st.st_size), mtime_ns=int(st.st_mtime_ns))


def complete_outputs(store: Store, outputs, key: str | None = None, request: dict | None = None) -> list[bool]:
    """For each output (one per file of the store's catalog): whether the store records it as written completely
    (with ``key``, when given) and the file is still as it was then (same size and modification time).

    ``request``: what the run now was asked (:func:`patchcloud.stream.engine.job.run_request`), checked before it
    computes anything: an output recorded as written for another request is not complete for this one, so it is
    refused at once rather than after the computation, when its key would differ.  Outputs are recorded by path, so
    jobs that share a store keep each other's records.
    """
    recorded = store.group_attrs("outputs")
    out = []
    for o in outputs:
        p = Path(o)
        r = recorded.get(output_record_name(p))
        ok = r is not None and p.is_file() and (key is None or r.get("key") == key)
        ok = ok and (request is None or same_request(r.get("request"), request))
        out.append(bool(ok and {k: r.get(k) for k in ("path", "size", "mtime_ns")} == file_record(p)))
    return out


def same_request(recorded: dict | None, asked: dict) -> bool:
    """Whether an output recorded for the request ``recorded`` may be this run's, asked ``asked``: the same request, but
    for a tile size not given now (the run takes the store's own tiles, those the output was made on); None (recorded
    before requests were) may be.

    >>> same_request({"job": "don", "tile_size": 64.0}, {"job": "don", "tile_size": None})
    True
    >>> same_request({"job": "don", "tile_size": 64.0}, {"job": "don", "tile_size": 32.0})
    False
    """
    if recorded is None:
        return True
    if asked.get("tile_size") is None:
        recorded = {k: v for k, v in recorded.items() if k != "tile_size"}
        asked = {k: v for k, v in asked.items() if k != "tile_size"}
    return recorded == asked


def output_record_name(path: Path) -> str:
    """The name of an output's record in the store: its resolved path."""
    return str(Path(path).resolve())


def record_output(store: Store, output: Path, partial: Path, key: str, request: dict | None) -> None:
    """Record in the store that ``output`` is complete, from its finished temporary file ``partial``, before the rename
    (which keeps size and modification time): a run killed between the two finds its output complete
    (:func:`complete_outputs`), not a file it may not replace."""
    store.set_group_attrs("outputs", **{output_record_name(output): dict(
        file_record(Path(partial)), path=str(Path(output).resolve()), key=key, request=request)})


def export_columns(
    store: Store, outputs, columns: list[Column], dims, runner: Runner | None = None, overwrite: bool = False,
    quiet: bool = False, provenance: laspy.VLR | None = None, request: dict | None = None,
) -> None:
    """Write every file of the store's catalog again, plus ``columns`` as dimensions ``dims``: one output per file.

    ``outputs``: the output of each file of ``store.catalog`` (one path for
    a store of one file), LAZ when the name ends in .laz.  ``dims`` are
    (name, numpy type, description[, no-data]) of the dimensions added, as
    :func:`patchcloud.stream.io.las.output_header` takes them.  Each output
    holds its file's records in its file's order; ids renumbered in order
    of first appearance (``renumber``) are numbered over the whole catalog,
    files in catalog order.  The tasks write ``OUTPUT.partial`` (the
    workers must reach the outputs' directory), each renamed to its output
    when its last part is written, and recorded in the store; outputs a
    previous run on this store completed (:func:`complete_outputs`) are
    kept as they are.  ``provenance``: a VLR every output carries, saying
    what made it (:func:`patchcloud.stream.io.las_records.provenance_vlr`);
    ``request``: what the run was asked, recorded with each output
    (:func:`complete_outputs`).
    """
    runner = runner or Runner("synchronous", quiet=quiet)
    cat = store.catalog
    outputs = [outputs] if isinstance(outputs, (str, os.PathLike)) else list(outputs)
    if len(outputs) != len(cat.sources):
        raise PatchcloudValueError(f"{len(cat.sources)} files in the store {store.url}, {len(outputs)} outputs given")
    key = output_key(store, columns, dims, provenance)
    done = complete_outputs(store, outputs, key)
    outs = [Path(o) if d else check_writable(o, overwrite) for o, d in zip(outputs, done)]
    if all(done):
        return
    compressed = [is_laz_name(o) for o in outs]
    headers = [las_output.prepare_header(output_header(src, dims, provenance, cat.crs), c) for src, c in zip(cat.sources, compressed)]
    parts = catalog_parts(cat, int(store.attrs["part_points"]))
    first_part = np.searchsorted([f for f, _, _ in parts], np.arange(len(cat.sources) + 1))  # a file's parts are consecutive
    laz_parallel = runner.laz_parallel  # tasks in this process: lazrs may use the cores
    tmps = [os.path.abspath(partial_path(o)) for o in outs]  # absolute: the workers write into them
    try:
        renumbered = [col for col in columns if col.renumber]
        if renumbered:
            calls = [((store.url, p, f, first, count, renumbered), {"laz_parallel": laz_parallel}) for p, (f, first, count) in enumerate(parts)]
            seen = runner.map(first_seen_part, calls, "export: ids")
            for k, col in enumerate(renumbered):
                ids = FirstSeenIds()
                for part in seen:
                    ids(part[k])
                store.put(f"export/{col.array}_ids", ids.known)
                store.put(f"export/{col.array}_numbers", ids.number)
        todo = [f for f in range(len(outs)) if not done[f]]
        starts = {f: las_output.begin(headers[f], tmps[f], cat.sources[f].point_count) for f in todo}
        calls, owner = [], []  # owner[k]: (file, part within the file) of call k
        for p, (f, first, count) in enumerate(parts):
            if not done[f]:
                local = p - int(first_part[f])
                calls.append(((store.url, p, f, local, first, count, columns, dims, tmps[f], starts[f], compressed[f]),
                              {"laz_parallel": laz_parallel}))
                owner.append((f, local))
        results: dict[int, list] = {f: [None] * int(first_part[f + 1] - first_part[f]) for f in todo}
        left = {f: len(r) for f, r in results.items()}
        stitched = {f: 0 for f in todo}  # LAZ: the parts of each file already appended to its output, a prefix

        # a store in memory records nothing a later run sees: the outputs are renamed when every one is complete, so a
        # run killed before (kill -9: no clean-up) leaves only .partial files, which the same command replaces (a
        # catalog's complete outputs, renamed one by one, were refused as "exists"; found by a sweep of 2026-11-27)
        in_memory = memory_group.is_memory_url(store.url)
        complete: list[int] = []  # in memory: the files complete, renamed after the last

        def complete_file(f: int) -> None:  # every part of file f is in: finish, record, rename
            mine = results.pop(f)
            las_output.finish(headers[f], tmps[f], starts[f], [r[0] for r in mine], [r[1] for r in mine] if compressed[f] else None,
                              source=cat.sources[f].path, stitched=stitched[f])
            record_output(store, outs[f], Path(tmps[f]), key, request)
            if not in_memory:
                rename_into_place(tmps[f], outs[f])
            else:
                complete.append(f)

        def finish(k: int, result) -> None:  # the part's file is complete once its last part is in: stitch, rename, record
            f, local = owner[k]
            results[f][local] = result
            left[f] -= 1
            if compressed[f] and left[f]:  # append the parts now in order while the others are still being written
                ready = stitched[f]
                while ready < len(results[f]) and results[f][ready] is not None:
                    ready += 1
                if ready > stitched[f]:
                    las_output.stitch(tmps[f], range(stitched[f], ready))
                    stitched[f] = ready
            if left[f] == 0:
                complete_file(f)

        for f in todo:  # a file of no points (a catalog's empty tile) has no part: its output is its header
            if left[f] == 0:
                complete_file(f)
        runner.map(export_part, calls, "export", on_result=finish)
        for f in complete:
            rename_into_place(tmps[f], outs[f])
    finally:
        for tmp in tmps:
            las_output.remove_partial(tmp)
        store.remove("export", wait=False)
