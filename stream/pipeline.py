"""The stream's jobs: ``tile`` (ingest only) and ``normals`` (the whole pipeline), and ``info``.

``normals`` runs, each step resumable (a rerun skips what is done):

1. tile: read the input in chunks into the store's tiles, sort each tile
   by octree key (:mod:`.ingest`, :func:`.steps.sort_tile`);
2. calibrate: the global defaults (point spacing from the tiles' octree
   occupancy, the RMSE threshold from the finest cells' fits), so every
   tile uses the same parameters whatever the tiling;
3. fit: one task per tile (:func:`.steps.fit_one_tile`);
4. seams: links between the leaves on either side of every tile face,
   then one orientation for all patches (:mod:`.seams`);
5. finish: normals per tile, blended across tile faces with the
   neighbours' patch models (:func:`.steps.finish_one_tile`);
6. export (:mod:`.export`).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from patchcloud.core.errors import PatchcloudIOError, PatchcloudValueError
from patchcloud.core.morton import MAX_DEPTH
from patchcloud.core.normals import check_parameters

from . import steps
from .export import export_normals
from .ingest import bucket, make_grid
from .lasio import LasSource, open_source
from .scheduling import Runner, map_tiles
from .seams import orient_tiles
from .store import Store

__all__ = ["normals", "tile", "NormalsSummary", "default_store_path", "check_output", "open_job"]


@dataclass
class NormalsSummary:
    """What a ``normals`` run did (times in seconds, memory in bytes)."""

    input: str
    output: str
    points: int
    tiles: int
    tile_size: float
    patches_by_kind: dict[str, int]
    normals_by_method: dict[str, int]
    parameters: dict
    seconds: dict[str, float] = field(default_factory=dict)
    peak_memory: int = 0
    scheduler: str = "threads"
    store: str = ""

    def format(self) -> str:
        n = max(self.points, 1)
        m = self.normals_by_method
        k = self.patches_by_kind
        lines = [
            f"{self.input} -> {self.output}",
            f"  points          {self.points:,}",
            f"  tiles           {self.tiles:,} of {self.tile_size:g} m",
            f"  patches         {sum(k.values()):,} (surface {k['surface']:,}, edge {k['edge']:,}, sparse {k['sparse']:,})",
            f"  normals by      quadric {m['quadric'] / n:.1%}, blended {m['blended'] / n:.1%}, k-NN fallback {m['knn'] / n:.1%}",
            f"  parameters      {self.parameters['criterion']} threshold {self.parameters['threshold']:.4g}, "
            f"d_min {self.parameters['d_min']:.3g} m, spacing {self.parameters['spacing']:.3g} m, orient {self.parameters['orient']}",
            *time_and_memory_lines(self.seconds, self.points, self.peak_memory, self.scheduler),
        ]
        return "\n".join(lines)


def time_and_memory_lines(seconds: dict[str, float], points: int, peak_memory: int, scheduler: str) -> list[str]:
    """The last two lines of a job's summary: time per step and in all, and the peak memory."""
    total = sum(seconds.values())
    return [
        "  time            " + ", ".join(f"{s} {t:.1f} s" for s, t in seconds.items())
        + f"; total {total:.1f} s ({points / max(total, 1e-9):,.0f} points/s)",
        f"  peak memory     {peak_memory / 2**20:,.0f} MiB (all processes, scheduler {scheduler})",
    ]


def default_store_path(output: str | os.PathLike) -> str:
    """Where ``normals`` keeps its store when none is given: beside the output."""
    return str(output) + ".store"


def check_output(output: str | os.PathLike, overwrite: bool) -> Path:
    """``output`` as a Path, after checking it can be written: not there (or ``overwrite``), its directory there."""
    out = Path(output)
    if out.exists() and not overwrite:
        raise PatchcloudIOError(f"{out}: exists (use --overwrite to replace it)")
    if not out.parent.exists():
        raise PatchcloudIOError(f"{out}: the directory {out.parent} does not exist")
    return out


def open_job(input, output, store: str | None, keep_store: bool | None, overwrite: bool) -> tuple[Path, LasSource, str, bool]:
    """What every out-of-core job starts with: the output checked, the input opened, where the store goes and whether it stays.

    The default store is ``OUTPUT.store``, removed after success unless
    ``keep_store``; a store given is kept unless ``keep_store`` is False.
    """
    out = check_output(output, overwrite)
    src = open_source(input)
    url = store or default_store_path(out)
    return out, src, url, (store is not None) if keep_store is None else bool(keep_store)


def _params_key(d: dict) -> str:
    return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


def _validate(tile_size, **parameters) -> None:
    """The core's parameter checks, and the tile size's."""
    check_parameters(**parameters)
    if tile_size is not None and (not np.isfinite(tile_size) or tile_size <= 0):
        raise PatchcloudValueError(f"tile size must be a positive number of metres, got {tile_size!r}")


def _ensure_tiled(src: LasSource, url: str, tile_size: float | None, runner: Runner, quiet: bool, chunk: int) -> tuple[Store, float]:
    """The store of ``src`` tiled at ``tile_size``: reused when complete and made from the same file, else made anew."""
    grid = make_grid(src, tile_size)
    t0 = time.perf_counter()
    if Store.exists(url):
        store = Store.open(url)
        a = store.attrs
        same = a.get("source") and src.same_file(a["source"]) and a.get("grid") == grid.to_json()
        if same and store.step_done("tile"):
            return store, 0.0
        if not (same and store.step_done("bucket")):  # else only the sort was interrupted: finish it below
            store = Store.create(url, overwrite=True)
    else:
        store = Store.create(url)
    if not store.step_done("bucket"):
        store.update(source=src.to_json(), grid=grid.to_json())
        bucket(store, src, grid, chunk=chunk, quiet=quiet)
        store.mark_step("bucket", {"chunk": chunk})
    occ = map_tiles(steps.sort_tile, store, runner=runner, label="tile: sort")
    log_t = int(round(np.log2(grid.tile_size)))
    total: dict[int, int] = {}
    for o in occ.values():
        for lev, count in enumerate(o):
            total[log_t - lev] = total.get(log_t - lev, 0) + int(count)
    store.update(occupancy={str(k): v for k, v in total.items()})
    store.mark_step("tile", {"tile_size": grid.tile_size})
    return store, time.perf_counter() - t0


def tile(
    input: str | os.PathLike, store: str, *, tile_size: float | None = None, scheduler: str = "threads",
    workers: int | None = None, overwrite: bool = False, quiet: bool = False, chunk: int = 1 << 20,
) -> Store:
    """Ingest only: cut ``input`` into a tiled store at ``store`` (a path or fsspec URL).

    Examples
    --------
    >>> from patchcloud.stream import tile   # doctest: +SKIP
    >>> tile("city.laz", "city.zarr", tile_size=64)   # doctest: +SKIP
    """
    _validate(tile_size, criterion="rmse", orient="up")
    src = open_source(input)
    if Store.exists(store) and overwrite:
        Store.create(store, overwrite=True)
    elif not Store.exists(store) and _exists_nonempty(store):
        raise PatchcloudIOError(f"{store}: exists and is not a patchcloud store")
    with Runner(scheduler, workers, quiet=quiet) as runner:
        s, _ = _ensure_tiled(src, store, tile_size, runner, quiet, chunk)
    return s


def _exists_nonempty(url: str) -> bool:
    if "://" in url and not url.startswith("file://"):
        return False
    p = Path(url.removeprefix("file://"))
    return p.exists() and (p.is_file() or any(p.iterdir()))


def _calibrate(store: Store, runner: Runner, criterion: str, threshold, d_min, max_edge, n_min: int) -> dict:
    """Spacing, d_min, max_edge and threshold for the whole cloud (resolved defaults)."""
    a = store.attrs
    n = int(sum(a["tile_counts"]))
    occ = {int(k): int(v) for k, v in a["occupancy"].items()}
    spacing = steps.occupancy_spacing(occ, n)
    T = store.grid.tile_size
    if d_min is None:
        d_min = 3.0 * spacing if spacing > 0 else T / 2.0**MAX_DEPTH
    if max_edge is None:
        max_edge = 256.0 * spacing if spacing > 0 else float("inf")
    if threshold is None:
        if criterion == "sigma3":
            threshold = 0.005
        else:
            key = {"d_min": d_min, "n_min": n_min}
            cached = a.get("calibration")
            if cached and cached.get("key") == key:
                threshold = cached["threshold"]
            else:
                hists = map_tiles(steps.calibrate_tile, store, runner=runner, label="calibrate", d_min=d_min, n_min=n_min)
                threshold = steps.threshold_from_histogram(np.sum(list(hists.values()), axis=0), spacing)
                store.update(calibration={"key": key, "threshold": threshold})
    return dict(spacing=float(spacing), d_min=float(d_min), max_edge=float(max_edge), threshold=float(threshold))


def normals(
    input: str | os.PathLike,
    output: str | os.PathLike,
    *,
    tile_size: float | None = None,
    criterion: str = "rmse",
    orient: str = "up",
    viewpoint=None,
    threshold: float | None = None,
    d_min: float | None = None,
    max_edge: float | None = None,
    n_min: int = 12,
    min_sigma2: float = 0.01,
    k_fallback: int = 16,
    blend: bool = True,
    scheduler: str = "threads",
    workers: int | None = None,
    store: str | None = None,
    keep_store: bool | None = None,
    overwrite: bool = False,
    quiet: bool = False,
    chunk: int = 1 << 20,
) -> NormalsSummary:
    """Normals and curvature of a LAS/LAZ file of any size, written as a copy of it with extra dimensions.

    Parameters
    ----------
    input, output : path
        LAS or LAZ in; LAS or LAZ out (LAZ when ``output`` ends in .laz), every
        input point once, in input order, every original dimension unchanged,
        plus NormalX, NormalY, NormalZ, Curvature (float32), NormalMethod
        (uint8: 1 quadric, 2 blended, 3 k-NN) and PatchId (uint32).
    tile_size : float, optional
        Tile edge (metres), rounded down to a power of two; default: about a
        million points per tile over the file's footprint.
    criterion, orient, viewpoint, threshold, d_min, max_edge, n_min, min_sigma2, k_fallback, blend :
        As :func:`patchcloud.core.estimate_normals` (``viewpoint`` in the
        file's coordinates); the defaults come from the whole cloud.
    scheduler : str
        "threads" (default), "processes", "synchronous", or a dask scheduler
        address such as ``tcp://host:8786``.
    workers : int, optional
        Threads or processes of the local scheduler (default: the cores).
    store : str, optional
        Where the tiles and intermediate results go (a path or an fsspec URL
        the workers can reach).  Default: ``OUTPUT.store`` beside the
        output, removed after a successful run (kept with ``keep_store``);
        a given store is kept.
    overwrite : bool
        Replace an existing output.
    quiet : bool
        No progress bars.

    Returns
    -------
    NormalsSummary

    Raises
    ------
    PatchcloudIOError (an OSError)
        An input that is not a readable, complete LAS/LAZ file, an existing
        output without ``overwrite``, an unusable store.
    PatchcloudValueError (a ValueError)
        An invalid parameter.
    """
    _validate(
        tile_size, criterion=criterion, orient=orient, viewpoint=viewpoint, threshold=threshold, d_min=d_min,
        max_edge=max_edge, n_min=n_min, min_sigma2=min_sigma2, k_fallback=k_fallback,
    )
    out, src, url, keep_store = open_job(input, output, store, keep_store, overwrite)
    seconds: dict[str, float] = {}
    with Runner(scheduler, workers, quiet=quiet) as runner:
        st, seconds["tile"] = _ensure_tiled(src, url, tile_size, runner, quiet, chunk)
        t0 = time.perf_counter()
        cal = _calibrate(st, runner, criterion, threshold, d_min, max_edge, n_min)
        origin = np.asarray(st.grid.origin)
        params = dict(
            criterion=criterion, n_min=int(n_min), min_sigma2=float(min_sigma2), k_fallback=int(k_fallback), orient=orient,
            blend=bool(blend), centre_local=list(st.attrs["centroid_local"]),
            viewpoint_local=None if viewpoint is None else (np.asarray(viewpoint, dtype=float) - origin).tolist(),
            halo=2.0 * cal["d_min"], **cal,
        )
        key = _params_key(params)
        if st.attrs.get("params_key") != key:
            st.clear_tile_steps(["fit", "finish"])
            st.mark_step("seams", None)
            st.update(params=params, params_key=key)
        seconds["calibrate"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        todo = [t for t in st.tiles if not st.tile_done(t, "fit")]
        map_tiles(steps.fit_one_tile, st, tiles=todo, runner=runner, label="fit", params=params)
        seconds["fit"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        if st.step_done("seams") != key:
            orient_tiles(st, runner, orient, quiet=quiet)
            st.clear_tile_steps(["finish"])
            st.mark_step("seams", key)
        seconds["seams"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        todo = [t for t in st.tiles if not st.tile_done(t, "finish")]
        map_tiles(steps.finish_one_tile, st, tiles=todo, halo=1, runner=runner, label="finish", params=params)
        seconds["finish"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        export_normals(st, src, str(out), overwrite=overwrite, quiet=quiet)
        seconds["export"] = time.perf_counter() - t0
        peak = runner.peak_memory()
        summary = _summary(st, src, str(out), params, seconds, peak, scheduler)
    if not keep_store and "://" not in url:
        shutil.rmtree(url, ignore_errors=True)
    summary.store = "" if not keep_store else url
    return summary


def _summary(st: Store, src: LasSource, output: str, params: dict, seconds: dict, peak: int, scheduler: str) -> NormalsSummary:
    kinds = np.zeros(3, dtype=np.int64)
    methods = np.zeros(4, dtype=np.int64)
    for t in st.tiles:
        a = st.tile_attrs(t)
        kinds += np.asarray(a["fit"]["kinds"], dtype=np.int64)
        methods += np.asarray(a["finish"]["methods"], dtype=np.int64)
    return NormalsSummary(
        input=src.path, output=output, points=src.point_count, tiles=len(st.tiles), tile_size=st.grid.tile_size,
        patches_by_kind=dict(surface=int(kinds[0]), edge=int(kinds[1]), sparse=int(kinds[2])),
        normals_by_method=dict(quadric=int(methods[1]), blended=int(methods[2]), knn=int(methods[3])),
        parameters=params, seconds=seconds, peak_memory=peak, scheduler=scheduler,
    )



