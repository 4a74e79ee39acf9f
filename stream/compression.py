"""``compress`` and ``decompress``: a LAS/LAZ file to a ``.pcz`` patch-model file and back, out of core.

``compress`` runs on the tiled store of :mod:`.pipeline` (a store made by
``normals``, ``don`` or ``segment`` is reused):

1. tile (shared), and every point's record bytes bucketed by tile;
2. per tile (one dask task each): :func:`patchcloud.core.fit_models` with
   the budget as the RMSE threshold, the tile as the octree's root and the
   whole file's spacing (touching leaves merged into larger patches); the
   models quantised within half the budget; the majority class and mean
   intensity of the points of each patch's octree cell; the residual
   points' coordinates and records;
3. pack: the tiles' parts into one ``.pcz`` (:mod:`.pcz`), tile after tile.

``decompress`` reads a ``.pcz`` tile by tile (or only the tiles that meet
a box), samples every patch cell by cell (its own count, a density, or a
level of detail) and writes the samples and the residual points to LAS/LAZ with
the original header and a ``Reconstructed`` dimension (1 sampled from a
patch, 0 a residual point, byte for byte as it was).
"""

from __future__ import annotations

import io
import os
import shutil
import time
from dataclasses import dataclass, field

import laspy
import numpy as np

from patchcloud.core.errors import PatchcloudValueError
from patchcloud.core.patchmodel import (
    MASK_SIDE, PatchModels, check_budget, dequantise_models, fit_models, quantise_models, sample_models,
)

from . import pcz, steps
from .ingest import bucket_records
from .lasio import LasSource, _laz_backend, atomic_output, is_laz_name
from .pipeline import _ensure_tiled, _params_key, _validate, check_output, open_job, time_and_memory_lines
from .scheduling import Runner, map_tiles
from .store import Store

__all__ = ["compress", "decompress", "CompressSummary", "DecompressSummary", "compress_tile"]

#: n_min of the compression octree (as the normals' default).
N_MIN = 12
#: Largest patch cell, in point spacings.  A patch's 8 x 8 occupancy mask then has cells of at most
#: 4 spacings, so decompression does not fill gaps in the data wider than that (with the normals'
#: 256 spacings, samples landed up to 5.7 m from any original point on a flat IGN tile).
MAX_EDGE_SPACINGS = 32.0
_PART = ("scale", "centroid", "rotation", "coeffs", "rmse", "cells", "level", "ijk", "count", "extent", "mask",
         "classification", "intensity")


@dataclass
class CompressSummary:
    """What a ``compress`` run did (sizes in bytes, times in seconds)."""

    input: str
    output: str
    points: int
    patches: int
    cells: int
    residual: int
    max_error: float
    input_bytes: int
    output_bytes: int
    mean_error: float
    seconds: dict[str, float] = field(default_factory=dict)
    peak_memory: int = 0
    scheduler: str = "threads"

    def format(self) -> str:
        n = max(self.points, 1)
        return "\n".join([
            f"{self.input} -> {self.output}",
            f"  points          {self.points:,}: {self.points - self.residual:,} on {self.patches:,} patches ({self.cells:,} octree cells) "
            f"({(self.points - self.residual) / n:.1%}), {self.residual:,} residual ({self.residual / n:.1%})",
            f"  error           budget {self.max_error:g} m; mean distance of the modelled points to their surface "
            f"{self.mean_error:.4f} m (before quantisation, which adds at most half the budget)",
            f"  size            {self.output_bytes:,} bytes, {8 * self.output_bytes / n:.2f} bits/point; input "
            f"{self.input_bytes:,} bytes ({self.input_bytes / max(self.output_bytes, 1):.1f}x larger)",
            *time_and_memory_lines(self.seconds, self.points, self.peak_memory, self.scheduler),
        ])


def compress_tile(url: str, ijk: tuple, params: dict) -> dict:
    """Patch models of one tile within the budget, quantised; its residual points; stored as the tile's ``pcz_*`` arrays."""
    store = Store.open(url)
    key = params["key"]
    if store.tile_done(ijk, "compress", key):
        return store.tile_attrs(ijk)["compress"]
    grid = store.grid
    T = grid.tile_size
    corner = grid.corner(ijk)
    xyz = store.read(ijk, "xyz")
    local = grid.local(xyz)
    rank = store.read(ijk, "rank").astype(np.int64)  # xyz row r is the tile's point rank[r] in input order
    in_order = store.read(ijk, "record")  # the tile's records in input order
    budget = params["max_error"]
    if xyz.shape[0] >= N_MIN:
        fit = fit_models(local, budget, d_min=params["d_min"], max_edge=params["max_edge"], n_min=N_MIN, root=(corner, T))
        models, cell, residual, err = fit.models, fit.cell, fit.residual, fit.error
    else:  # too few points for a surface: all residual
        n = xyz.shape[0]
        models, cell, residual, err = PatchModels.empty(corner, T), np.full(n, -1), np.arange(n), np.zeros(n)
    q = quantise_models(models, budget)
    pf = laspy.PointFormat(params["point_format"])
    for name in params["extra_dims"]:
        pf.add_extra_dimension(laspy.ExtraBytesParams(name=name["name"], type=np.dtype(name["type"])))
    rec = laspy.PackedPointRecord(np.ascontiguousarray(in_order).view(pf.dtype()).reshape(-1), pf)
    on = cell >= 0
    C = q.count.shape[0]
    cls = np.asarray(rec["classification"]).astype(np.int64)[rank]
    votes = np.bincount(cell[on] * 256 + cls[on], minlength=C * 256).reshape(C, 256)
    inten = np.bincount(cell[on], weights=np.asarray(rec["intensity"], dtype=np.float64)[rank][on], minlength=C)
    values = dict(
        scale=q.scale, centroid=q.centroid, rotation=q.rotation, coeffs=q.coeffs, rmse=q.rmse, cells=q.cells,
        level=q.level, ijk=q.ijk, count=q.count, extent=q.extent, mask=q.mask,
        classification=votes.argmax(axis=1).astype(np.uint8), intensity=np.rint(inten / np.maximum(q.count, 1)).astype(np.uint16),
    )
    for name in _PART:
        store.write(ijk, "pcz_" + name, values[name])
    # in input order: LAZ predicts each record from the previous one (scan order: GPS time, returns, intensity)
    laz = pcz.residual_laz(in_order[np.sort(rank[residual])], pf, params["version"], grid.scale, grid.offset)
    store.write(ijk, "pcz_residual_laz", np.frombuffer(laz, dtype=np.uint8))
    info = dict(patches=len(models), cells=C, residual=int(residual.size), points=int(xyz.shape[0]), abs_error=float(np.abs(err[on]).sum()))
    store.mark_tile(ijk, "compress", key, compress=info)
    return info


def _parts(st: Store, max_error: float):
    T = st.grid.tile_size
    for ijk in st.tiles:
        v = {name: st.read(ijk, "pcz_" + name) for name in _PART}
        q = pcz.QuantisedModels(
            max_error=max_error, root_corner=st.grid.corner(ijk), root_edge=T,
            **{name: v[name] for name in _PART if name not in ("classification", "intensity")},
        )
        yield pcz.TilePart(ijk, q, v["classification"], v["intensity"], int(st.tile_attrs(ijk)["compress"]["residual"]),
                           st.read(ijk, "pcz_residual_laz").tobytes())


def _header_bytes(src: LasSource) -> tuple[bytes, bytes]:
    """The input's header and VLRs, and its extended VLRs (LAS 1.4; after the points), as raw bytes."""
    with open(src.path, "rb") as f:
        h = laspy.LasHeader.read_from(f)
        f.seek(0)
        head = f.read(h.offset_to_point_data)
        evlrs = b""
        if h.version.minor >= 4 and h.number_of_evlrs > 0:
            f.seek(h.start_of_first_evlr)
            evlrs = f.read()
        return head, evlrs


def compress(
    input: str | os.PathLike, output: str | os.PathLike, *, max_error: float = 0.02, tile_size: float | None = None,
    scheduler: str = "threads", workers: int | None = None, store: str | None = None, keep_store: bool | None = None,
    overwrite: bool = False, quiet: bool = False, chunk: int = 1 << 20,
) -> CompressSummary:
    """Compress a LAS/LAZ file of any size to a ``.pcz`` of quadric patch models and residual points.

    Parameters
    ----------
    input : path
        LAS or LAZ.
    output : path
        The ``.pcz`` (see :mod:`patchcloud.stream.pcz`).
    max_error : float
        The error budget (metres): patches are split until their quadric
        fits their points with an RMS error below it; points farther than 3
        times it from their patch's surface, and the points of edge and
        sparse leaves, are kept as residual points, exactly.  Quantising the
        models adds at most half the budget.
    tile_size, scheduler, workers, store, keep_store, overwrite, quiet :
        As :func:`patchcloud.stream.normals`.

    Returns
    -------
    CompressSummary
    """
    _validate(tile_size, criterion="rmse", orient="up")
    budget = check_budget(max_error)
    out, src, url, keep_store = open_job(input, output, store, keep_store, overwrite)
    seconds: dict[str, float] = {}
    with Runner(scheduler, workers, quiet=quiet) as runner:
        st, seconds["tile"] = _ensure_tiled(src, url, tile_size, runner, quiet, chunk)
        t0 = time.perf_counter()
        if not st.step_done("records"):
            for t in st.tiles:
                st.delete(t, "record")
            bucket_records(st, src, chunk=chunk, quiet=quiet)
            st.mark_step("records", {"chunk": chunk})
        seconds["records"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        occ = {int(k): int(v) for k, v in st.attrs["occupancy"].items()}
        spacing = steps.occupancy_spacing(occ, int(st.tile_counts.sum()))
        with laspy.open(src.path) as r:
            pf = r.header.point_format
        params = dict(
            max_error=budget, d_min=3.0 * spacing if spacing > 0 else st.grid.tile_size / 2.0**21,
            max_edge=MAX_EDGE_SPACINGS * spacing if spacing > 0 else float("inf"), point_format=pf.id, version=src.version,
            extra_dims=[{"name": d.name, "type": np.dtype(d.dtype).str} for d in pf.extra_dimensions],
        )
        params["key"] = _params_key(params)
        infos = map_tiles(compress_tile, st, runner=runner, label="compress", params=params)
        seconds["fit"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        grid = st.grid.to_json()
        head, evlrs = _header_bytes(src)
        source = dict(src.to_json(), point_format=pf.id)
        counts = pcz.write_pcz(
            out, _parts(st, budget), max_error=budget, grid=grid, header=head, evlrs=evlrs, source=source,
            record_bytes=pf.size - 12, overwrite=overwrite,
        )
        seconds["pack"] = time.perf_counter() - t0
        peak = runner.peak_memory()
    if not keep_store and "://" not in url:
        shutil.rmtree(url, ignore_errors=True)
    v = list(infos.values())
    modelled = counts["points"] - counts["residual"]
    return CompressSummary(
        input=src.path, output=str(out), points=counts["points"], patches=counts["patches"], cells=counts["cells"],
        residual=counts["residual"],
        max_error=budget, input_bytes=src.size, output_bytes=out.stat().st_size,
        mean_error=sum(i["abs_error"] for i in v) / max(modelled, 1), seconds=seconds, peak_memory=peak, scheduler=scheduler,
    )


@dataclass
class DecompressSummary:
    """What a ``decompress`` run wrote."""

    input: str
    output: str
    reconstructed: int
    residual: int
    seconds: float

    def format(self) -> str:
        return (f"{self.input} -> {self.output}\n  points          {self.reconstructed + self.residual:,}: "
                f"{self.reconstructed:,} sampled from patches, {self.residual:,} residual\n  time            {self.seconds:.1f} s")


def _counts(models, density: float | None, lod: int | None) -> np.ndarray:
    """Points to sample per cell: its own count, ``density`` per square metre of its occupied extent, or count / 4**lod."""
    if density is not None:
        e = models.extent
        area = (e[:, 1] - e[:, 0]) * (e[:, 3] - e[:, 2]) * models.occupied() / MASK_SIDE**2
        return np.maximum(np.rint(area * density), 1).astype(np.int64)
    if lod is not None:
        return np.maximum(models.count // 4**lod, 1).astype(np.int64)
    return models.count.astype(np.int64)


def decompress(
    input: str | os.PathLike, output: str | os.PathLike, *, density: float | None = None, lod: int | None = None,
    bbox=None, seed: int = 0, overwrite: bool = False,
) -> DecompressSummary:
    """Points of a ``.pcz``, written to LAS/LAZ: samples of every patch and the residual points as they were.

    Parameters
    ----------
    input : path
        A ``.pcz`` written by :func:`compress`.
    output : path
        LAS or LAZ (by its name), with the input file's header and VLRs and
        a ``Reconstructed`` dimension (uint8: 1 sampled from a patch, 0 a
        residual point).  Sampled points carry the majority class and
        mean intensity of their patch's points in their octree cell; their other dimensions are 0.
    density : float, optional
        Points per square metre of each cell's occupied extent.
    lod : int, optional
        Level of detail: each cell's own count divided by ``4**lod`` (at
        least one point); 0 (the default, with no density) is the count.
    bbox : (xmin, ymin, zmin, xmax, ymax, zmax), optional
        Only this box (the file's coordinates): only the tiles that meet it
        are read, and only points inside it are written.
    seed : int
        Seed of the sampling (the same seed, the same points).

    Returns
    -------
    DecompressSummary
    """
    if density is not None and lod is not None:
        raise PatchcloudValueError("give density or lod, not both")
    if density is not None and (not np.isfinite(density) or density <= 0):
        raise PatchcloudValueError(f"density must be a positive number of points per square metre, got {density!r}")
    if lod is not None and (not isinstance(lod, (int, np.integer)) or lod < 0):
        raise PatchcloudValueError(f"lod must be a whole number, at least 0; got {lod!r}")
    box = None
    if bbox is not None:
        box = np.asarray(bbox, dtype=np.float64).reshape(-1)
        if box.shape != (6,) or not np.isfinite(box).all() or np.any(box[:3] > box[3:]):
            raise PatchcloudValueError(f"bbox must be xmin ymin zmin xmax ymax zmax with each min <= max; got {bbox!r}")
    check_output(output, overwrite)
    t0 = time.perf_counter()
    with pcz.open_pcz(input) as f:
        header = laspy.LasHeader.read_from(io.BytesIO(f.header_bytes), read_evlrs=False)
        evlrs = f.evlrs(header.number_of_evlrs if header.version.minor >= 4 else 0)
        header.vlrs = [v for v in header.vlrs if v.user_id != "laszip encoded"]
        header.add_extra_dims([laspy.ExtraBytesParams(name="Reconstructed", type=np.uint8, description="1 from a patch, 0 residual")])
        g = f.attrs["grid"]
        origin, scale, offset = (np.asarray(g[k], dtype=np.float64) for k in ("origin", "scale", "offset"))
        tiles = range(len(f.tiles)) if box is None else f.tiles_in(box[:3] - origin, box[3:] - origin)
        L = header.point_format.size
        n_rec = n_res = 0
        with atomic_output(output, overwrite) as out:
            with laspy.open(out, mode="w", header=header, do_compress=is_laz_name(output), closefd=False,
                            laz_backend=_laz_backend()) as writer:
                for t in tiles:
                    q, cls, inten = f.patches(int(t))
                    models = dequantise_models(q)
                    pts, k = sample_models(models, _counts(models, density, lod), seed=seed + int(t))
                    xyz = np.rint((pts + origin - offset) / scale).astype(np.int64)
                    rxyz, rrec = f.residual(int(t))
                    sampled = laspy.PackedPointRecord.zeros(len(xyz), header.point_format)
                    sampled["X"], sampled["Y"], sampled["Z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
                    sampled["classification"] = cls[k]
                    sampled["intensity"] = inten[k]
                    sampled["Reconstructed"] = np.ones(len(xyz), np.uint8)
                    resid = laspy.PackedPointRecord.zeros(len(rxyz), header.point_format)
                    raw = resid.array.view(np.uint8).reshape(len(rxyz), L)
                    raw[:, :12] = rxyz.astype("<i4").view(np.uint8).reshape(len(rxyz), 12)
                    raw[:, 12 : 12 + rrec.shape[1]] = rrec
                    for rec, is_res in ((sampled, False), (resid, True)):
                        if box is not None and len(rec):
                            p = np.column_stack([rec["X"], rec["Y"], rec["Z"]]) * scale + offset
                            inside = np.all((p >= box[:3]) & (p <= box[3:]), axis=1)
                            rec = laspy.PackedPointRecord(rec.array[inside], header.point_format)
                        if len(rec):
                            writer.write_points(rec)
                        if is_res:
                            n_res += len(rec)
                        else:
                            n_rec += len(rec)
                if evlrs:
                    writer.write_evlrs(evlrs)
    return DecompressSummary(input=str(input), output=str(output), reconstructed=n_rec, residual=n_res,
                             seconds=time.perf_counter() - t0)
