"""``map_tiles(func, store, halo=...)``: the one way every per-tile step runs.

The model is xarray's ``map_blocks``: one task per tile, each given the
store's URL, the tile's index and, with ``halo``, the indices of the tiles
around it; results come back in the order of the tiles asked for, whatever
order the tasks finished in.  A task that raises records its error in its
tile's ``failed`` attribute (``patchcloud render-tiles`` shows it), cleared
when the tile later succeeds.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from itertools import product
from typing import Any

import numpy as np

from patchcloud.core import PatchcloudValueError
from patchcloud.stream.engine.runner import Runner
from patchcloud.stream.io.store import Store

__all__ = ["map_tiles", "tile_task", "pieces_for", "PIECE_MIN_POINTS"]


def tile_task(func: Callable, url: str, ijk: tuple, **kwargs) -> Any:
    """``func(url, ijk, **kwargs)``; when it raises, the tile records the failure (``render-tiles`` shows it), then it raises."""
    name = getattr(func, "__name__", "task")
    try:
        out = func(url, ijk, **kwargs)
    except Exception as exc:
        try:
            Store.open(url).mark_failed(ijk, name, f"{type(exc).__name__}: {exc}")
        except Exception:  # the store itself is the problem: the original error says more
            pass
        raise
    st = Store.open(url)
    if name in st.tile_attrs(ijk).get("failed", {}):
        st.mark_failed(ijk, name, None)
    return out


def map_tiles(
    func: Callable,
    store: Store,
    *,
    tiles: Sequence[tuple] | None = None,
    halo: int = 0,
    runner: Runner | None = None,
    label: str | None = None,
    pieces: Mapping[tuple, int] | None = None,
    small: bool = False,
    **kwargs,
) -> dict[tuple, Any]:
    """Run ``func(store.url, ijk, **kwargs)`` for every tile, in parallel.

    Parameters
    ----------
    func : callable
        A module-level function (it may run in another process).
    store : Store, or a store's path or URL (opened)
    tiles : sequence of (3,) int tuples, optional
        The tiles to run on (default: all of the store's).
    halo : int
        With ``halo >= 1``, ``func`` also gets ``neighbours=``: the store's
        tiles within ``halo`` tiles of ``ijk`` (per axis, ``ijk`` excluded).
    runner : Runner, optional
        Default: a synchronous runner.
    pieces : mapping from tile index to int, optional
        Tiles cut into several tasks (:func:`pieces_for`): tile ``ijk`` gets
        ``pieces[ijk]`` calls, each with ``piece=(j, pieces[ijk])``, and its
        result is the list of theirs.
    small : bool
        The tasks take milliseconds each: on a dask cluster they go in
        batches, a few a worker (:meth:`Runner.map`).
    kwargs :
        Passed to every call.

    Returns
    -------
    dict from tile index to ``func``'s result, in the order of ``tiles``
    (the tasks are submitted largest first, so a step does not end
    waiting on one big tile).

    Examples
    --------
    The highest point of each tile of the embedded sample, and how many
    tiles each has around it:

    >>> from patchcloud.stream import Store, tile
    >>> store = tile(sample, str(tmp / "sample.zarr"), tile_size=64, quiet=True)
    >>> def top(url, ijk, neighbours):
    ...     st = Store.open(url)
    ...     z = st.grid.local(st.read(ijk, "xyz"))[:, 2] + st.grid.origin[2]
    ...     return round(float(z.max()), 2), len(neighbours)
    >>> result = map_tiles(top, store, halo=1)
    >>> list(result) == store.tiles, [n for _, n in result.values()]
    (True, [3, 3, 3, 3])
    """
    if isinstance(halo, bool) or not isinstance(halo, (int, np.integer)) or halo < 0:
        raise PatchcloudValueError(f"halo must be a whole number of tiles, 0 or more; got {halo!r}")
    if isinstance(store, (str, os.PathLike)):
        store = Store.open(os.fspath(store))
    elif not isinstance(store, Store):
        raise PatchcloudValueError(f"store must be a Store or a store's path or URL, got {type(store).__name__}")
    if runner is not None and not isinstance(runner, Runner):
        raise PatchcloudValueError(f"runner must be a Runner (patchcloud.stream.engine.runner.Runner(\"threads\", 4), say) or "
                                   f"None (synchronous), got {runner!r}")
    runner = runner or Runner("synchronous", quiet=True)
    all_tiles = store.tiles
    present = set(all_tiles)
    try:
        todo = [tuple(int(v) for v in t) for t in (tiles if tiles is not None else all_tiles)]
    except (TypeError, ValueError):
        raise PatchcloudValueError(f"tiles must be a list of tile indices (i, j, k) of the store, e.g. {all_tiles[:1]}; got "
                                   f"{tiles!r}") from None
    absent = [t for t in todo if t not in present]
    if absent:  # a task on it would write into the store (its failure) and find it "damaged"
        raise PatchcloudValueError(f"tiles: {absent[0]} is not a tile of the store {store.url} "
                                   f"({len(all_tiles):,} tiles, e.g. {all_tiles[0] if all_tiles else 'none'})")
    pieces = {tuple(int(v) for v in t): k for t, k in dict(pieces or {}).items()}
    stray = [t for t in pieces if t not in present]
    if stray:
        raise PatchcloudValueError(f"pieces: {stray[0]} is not a tile of the store {store.url}")
    bad = [(t, k) for t, k in pieces.items() if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1]
    if bad:  # 0 pieces ran no task for the tile, and left it out of the result
        raise PatchcloudValueError(f"pieces: tile {bad[0][0]} would be cut into {bad[0][1]!r} pieces; give a whole number of "
                                   "at least 1 per tile")
    counts = dict(zip(all_tiles, store.tile_counts.tolist()))
    calls, owner, size = [], [], []
    grid = np.asarray(all_tiles, dtype=np.int64).reshape(-1, 3)
    for ijk in todo:
        kw = dict(kwargs)
        if halo:
            kw["neighbours"] = _neighbours(ijk, int(halo), grid, present)
        k = int(pieces.get(ijk, 1))
        for j in range(k):
            calls.append(((func, store.url, ijk), dict(kw, piece=(j, k)) if ijk in pieces else kw))
            owner.append(ijk)
            size.append(counts.get(ijk, 0) / k)
    # largest first, so the last tasks of the step are small ones and no worker waits long for them
    order = sorted(range(len(calls)), key=lambda c: (-size[c], c))
    results = runner.map(tile_task, [calls[c] for c in order], label or getattr(func, "__name__", "tiles"), small=small)
    by_call = dict(zip(order, results))
    out: dict[tuple, Any] = {}
    for c, ijk in enumerate(owner):
        if ijk in pieces:
            out.setdefault(ijk, []).append(by_call[c])
        else:
            out[ijk] = by_call[c]
    return out


def _neighbours(ijk: tuple, halo: int, grid: np.ndarray, present: set) -> list[tuple]:
    """The store's tiles (``grid`` (T, 3), ``present`` the same as a set) within ``halo`` tiles of ``ijk`` per axis, ``ijk``
    excluded, in the order of the offsets (-halo, -halo, -halo) ... (halo, halo, halo): each slot looked up where there
    are fewer slots than tiles, else the tiles filtered (a halo of a thousand tiles has 8e9 slots)."""
    if (2 * halo + 1) ** 3 <= grid.shape[0]:
        r = range(-halo, halo + 1)
        return [(ijk[0] + a, ijk[1] + b, ijk[2] + c) for a, b, c in product(r, r, r)
                if (a, b, c) != (0, 0, 0) and (ijk[0] + a, ijk[1] + b, ijk[2] + c) in present]
    d = grid - np.asarray(ijk, dtype=np.int64)
    near = np.flatnonzero(np.all(np.abs(d) <= halo, axis=1) & np.any(d != 0, axis=1))
    near = near[np.lexsort((d[near, 2], d[near, 1], d[near, 0]))]
    return [tuple(int(v) for v in grid[t]) for t in near]


def pieces_for(counts: Mapping[tuple, int], slots: int, min_points: int | None = None) -> dict[tuple, int]:
    """How many tasks to cut each big tile into, for a step whose tasks can work on part of a tile.

    A tile of more than a worker's share of the points (their sum over
    ``slots`` workers) would keep one worker busy after the others are done:
    it is cut into pieces of about that share, but none smaller than
    ``min_points`` (default :data:`PIECE_MIN_POINTS`: each piece repeats the
    tile's reading and set-up).  Tiles not cut are left out.

    >>> pieces_for({(0, 0, 0): 4_000_000, (1, 0, 0): 1_000_000, (2, 0, 0): 3_000_000}, slots=4)
    {(0, 0, 0): 2, (2, 0, 0): 2}
    >>> pieces_for({(0, 0, 0): 4_000_000, (1, 0, 0): 1_000_000}, slots=1), pieces_for({(0, 0, 0): 400_000}, slots=16)
    ({}, {(0, 0, 0): 2})
    """
    total = sum(int(c) for c in counts.values())
    share = max(total / max(int(slots), 1), PIECE_MIN_POINTS if min_points is None else min_points)
    return {ijk: -(-int(c) // int(share)) for ijk, c in counts.items() if c > share}


#: The fewest points :func:`pieces_for` gives a piece of a tile.
PIECE_MIN_POINTS = 250_000
