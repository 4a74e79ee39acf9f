"""``map_tiles(func, store, halo=...)``: the one way every per-tile step runs.

The model is xarray's ``map_blocks``: one task per tile, each given the
store's URL, the tile's index and, with ``halo``, the indices of the tiles
around it; results come back in the order of the tiles asked for, whatever
order the tasks finished in.  A task that raises records its error in its
tile's ``failed`` attribute (``patchcloud render-tiles`` shows it), cleared
when the tile later succeeds.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from itertools import product
from typing import Any

from patchcloud.stream.engine.runner import Runner
from patchcloud.stream.io.store import Store

__all__ = ["map_tiles", "tile_task"]


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
    **kwargs,
) -> dict[tuple, Any]:
    """Run ``func(store.url, ijk, **kwargs)`` for every tile, in parallel.

    Parameters
    ----------
    func : callable
        A module-level function (it may run in another process).
    store : Store
    tiles : sequence of (3,) int tuples, optional
        The tiles to run on (default: all of the store's).
    halo : int
        With ``halo >= 1``, ``func`` also gets ``neighbours=``: the store's
        tiles within ``halo`` tiles of ``ijk`` (per axis, ``ijk`` excluded).
    runner : Runner, optional
        Default: a synchronous runner.
    kwargs :
        Passed to every call.

    Returns
    -------
    dict from tile index to ``func``'s result, in the order of ``tiles``
    (the tasks are submitted largest tile first, so a step does not end
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
    runner = runner or Runner("synchronous", quiet=True)
    all_tiles = store.tiles
    todo = list(tiles) if tiles is not None else all_tiles
    present = set(all_tiles)
    calls = []
    for ijk in todo:
        kw = dict(kwargs)
        if halo:
            r = range(-halo, halo + 1)
            kw["neighbours"] = [
                (ijk[0] + a, ijk[1] + b, ijk[2] + c) for a, b, c in product(r, r, r)
                if (a, b, c) != (0, 0, 0) and (ijk[0] + a, ijk[1] + b, ijk[2] + c) in present
            ]
        calls.append(((func, store.url, ijk), kw))
    # largest tiles first, so the last tasks of the step are small ones and no worker waits long for them
    counts = dict(zip(all_tiles, store.tile_counts.tolist()))
    order = sorted(range(len(todo)), key=lambda k: (-counts.get(todo[k], 0), k))
    results = runner.map(tile_task, [calls[k] for k in order], label or getattr(func, "__name__", "tiles"))
    by_tile = dict(zip([todo[k] for k in order], results))
    return {ijk: by_tile[ijk] for ijk in todo}
