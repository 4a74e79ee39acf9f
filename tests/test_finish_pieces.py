"""A big tile's finish cut into pieces that run side by side: the same values as the whole tile's task, byte for byte."""

import laspy
import numpy as np
import pytest
from test_stream import write_scene

import synthetic
from patchcloud.core import Method, finish_tile, fit_tile, patch_signs
from patchcloud.core.octree import sort_points
from patchcloud.core.points import root_cube
from patchcloud.stream import Store, normals
from patchcloud.stream.engine import tasks
from patchcloud.stream.jobs import normals as normals_job
from patchcloud.stream.jobs import normals_tiles
from patchcloud.stream.io.store import piece_name, piece_rows


def test_piece_rows_cover_every_row_once():
    for n in (0, 1, 7, 100, 1001):
        for k in (1, 2, 3, 7):
            cuts = [piece_rows(n, j, k) for j in range(k)]
            assert cuts[0][0] == 0 and cuts[-1][1] == n and all(a[1] == b[0] for a, b in zip(cuts, cuts[1:]))
            assert max(b - a for a, b in cuts) - min(b - a for a, b in cuts) <= 1
    with pytest.raises(ValueError, match="0 <= j < k"):
        piece_rows(10, 3, 3)


def test_pieces_of_a_tile_give_the_whole_tiles_values_bit_for_bit(rng):
    # a bumpy ground, a wall and scattered points: quadric, blended, moment and k-NN normals all occur
    pts, _ = synthetic.scene(40_000, seed=5)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    corner, edge = root_cube(lo, hi, None)
    local = pts - corner
    sorted_input = sort_points(local, np.zeros(3), edge)
    d_min, min_sigma2 = 0.6, 0.002
    fit = fit_tile(pts, corner, edge, criterion="rmse", threshold=0.01, d_min=d_min, max_edge=20.0, n_min=10,
                   min_sigma2=min_sigma2, orient="up", viewpoint=None, centre=pts.mean(axis=0), spacing=0.2,
                   sorted_input=sorted_input)
    sign, _ = patch_signs(len(fit.patches), fit.links, fit.agreement, fit.score, "up")
    kw = dict(d_min=d_min, min_sigma2=min_sigma2, k_fallback=8, orient="up", centre=pts.mean(axis=0))
    whole = finish_tile(fit.local, fit.patches, sign, **kw)
    methods = set(np.unique(whole.method).tolist())
    assert {Method.QUADRIC, Method.BLENDED, Method.MOMENTS} <= methods, methods
    n = len(fit.local)
    for k in (2, 3, 7):
        which = rng.integers(0, k, n)  # any split of the points, here scattered at random
        parts = [finish_tile(fit.local, fit.patches, sign, only=which == j, **kw) for j in range(k)]
        for name in ("normals", "scalars", "dir1", "method", "patch"):
            got = np.empty_like(getattr(whole, name))
            for j, part in enumerate(parts):
                got[which == j] = getattr(part, name)
            assert np.array_equal(got, getattr(whole, name)), (k, name)
    with pytest.raises(ValueError, match="only must be"):
        finish_tile(fit.local, fit.patches, sign, only=np.ones(n - 1, dtype=bool), **kw)


def test_pieces_for_cuts_only_tiles_over_a_workers_share():
    counts = {(0, 0, 0): 900, (1, 0, 0): 100, (2, 0, 0): 300, (3, 0, 0): 200}  # 1,500 points
    assert tasks.pieces_for(counts, slots=1, min_points=10) == {}
    assert tasks.pieces_for(counts, slots=5, min_points=10) == {(0, 0, 0): 3}  # share 300: 900 in 3, 300 not cut
    assert tasks.pieces_for(counts, slots=5, min_points=450) == {(0, 0, 0): 2}  # no piece under 450 points
    assert tasks.pieces_for({}, slots=4) == {}


def test_the_store_reads_an_array_written_in_pieces_as_one(tmp_path):
    store = Store.create(str(tmp_path / "s.zarr"))
    t = (0, 0, 0)
    values = np.arange(30, dtype=np.float32).reshape(10, 3)
    store.write(t, "normal", -values)  # written whole first: the pieces replace it
    for j in range(3):
        lo, hi = piece_rows(10, j, 3)
        store.write(t, piece_name("normal-run2", j, 3), values[lo:hi])
    store.mark_pieces(t, {"normal": "normal-run2"}, 3)
    assert np.array_equal(store.read(t, "normal"), values)
    for rows in (slice(0, 10), slice(2, 7), slice(3, 6), slice(5, 5), slice(9, 20)):
        assert np.array_equal(store.read(t, "normal", rows), values[rows]), rows
    store.write(t, "normal", values * 2)  # then whole again
    store.unmark_pieces(t, ["normal"])
    assert np.array_equal(store.read(t, "normal"), values * 2)


@pytest.mark.slow  # 10-20 s: with the slow marker, so the default suite stays under 10 minutes
@pytest.mark.parametrize("extra", [{}, {"principal_curvatures": True, "always_up": True}, {"in_memory": True}])
def test_a_run_with_tiles_in_pieces_writes_the_same_bytes(tmp_path, monkeypatch, extra):
    src = tmp_path / "scene.laz"
    write_scene(src, n=60_000, seed=4)
    whole, cut = tmp_path / "whole.laz", tmp_path / "cut.laz"
    normals(src, whole, tile_size=16, scheduler="synchronous", quiet=True, **extra)
    seen = []
    real = tasks.pieces_for

    def spy(counts, slots, min_points=None):
        out = real(counts, 20, min_points=2_000)  # as for 20 workers: pieces of a few thousand points, every tile cut
        seen.append(out)
        return out

    monkeypatch.setattr(normals_job, "pieces_for", spy)
    how = dict(workers=2) if extra.get("in_memory") else dict(scheduler="threads", workers=8)  # in memory: a memory:// store
    normals(src, cut, tile_size=16, quiet=True, **how, **extra)
    assert seen and len(seen[0]) >= 2 and max(seen[0].values()) >= 3, seen  # several tiles cut, in 3 or more
    assert cut.read_bytes() == whole.read_bytes()
    las = laspy.read(str(cut))
    assert (las.NormalMethod != 0).all()


@pytest.mark.slow  # 15-20 s: with the slow marker, so the default suite stays under 10 minutes
def test_a_store_finished_in_pieces_then_whole_then_in_pieces_reads_the_last(tmp_path, monkeypatch):
    # one kept store, the finish step redone each time (always_up asked, then not): in pieces, whole, in pieces
    src = tmp_path / "scene.las"
    write_scene(src, n=20_000, seed=6)
    store = tmp_path / "kept.zarr"
    real = tasks.pieces_for
    cut = lambda counts, slots, min_points=None: real(counts, 20, min_points=2_000)  # noqa: E731
    runs = [(cut, False), (lambda counts, slots, min_points=None: {}, True), (cut, False)]
    for k, (rule, up) in enumerate(runs):
        monkeypatch.setattr(normals_job, "pieces_for", rule)
        normals(src, tmp_path / f"kept{k}.las", tile_size=16, scheduler="threads", workers=4, store=str(store), quiet=True, always_up=up)
    monkeypatch.setattr(normals_job, "pieces_for", lambda counts, slots, min_points=None: {})
    for up in (False, True):
        normals(src, tmp_path / f"fresh_{up}.las", tile_size=16, scheduler="synchronous", quiet=True, always_up=up)
    fresh = {up: (tmp_path / f"fresh_{up}.las").read_bytes() for up in (False, True)}
    assert fresh[False] != fresh[True]  # always_up turns some normals: the runs can be told apart
    assert [(tmp_path / f"kept{k}.las").read_bytes() == fresh[up] for k, (_, up) in enumerate(runs)] == [True, True, True]


def _cut_for_20_workers(monkeypatch):
    real = tasks.pieces_for
    monkeypatch.setattr(normals_job, "pieces_for", lambda counts, slots, min_points=None: real(counts, 20, min_points=2_000))


@pytest.mark.slow  # 15-20 s: with the slow marker, so the default suite stays under 10 minutes
def test_pieces_left_by_a_killed_run_are_not_taken_for_those_of_other_parameters(tmp_path, monkeypatch):
    # killed once the pieces are written (before the tile is recorded), then run with always_up, then without again:
    # the third run may reuse the first run's pieces, never the second's
    src = tmp_path / "scene.las"
    write_scene(src, n=20_000, seed=6)
    kw = dict(tile_size=16, scheduler="threads", workers=4, store=str(tmp_path / "kept.zarr"), quiet=True)
    _cut_for_20_workers(monkeypatch)

    def killed(*args, **kwargs):
        raise KeyboardInterrupt("killed after the pieces were written")

    real_mark = normals_tiles.mark_finished_pieces
    monkeypatch.setattr(normals_tiles, "mark_finished_pieces", killed)
    with pytest.raises(KeyboardInterrupt):
        normals(src, tmp_path / "a1.las", **kw)
    monkeypatch.setattr(normals_tiles, "mark_finished_pieces", real_mark)
    normals(src, tmp_path / "b.las", always_up=True, **kw)
    normals(src, tmp_path / "a3.las", **kw)
    monkeypatch.setattr(normals_job, "pieces_for", lambda counts, slots, min_points=None: {})
    for up in (False, True):
        normals(src, tmp_path / f"fresh_{up}.las", tile_size=16, scheduler="synchronous", quiet=True, always_up=up)
    assert (tmp_path / "b.las").read_bytes() == (tmp_path / "fresh_True.las").read_bytes()
    assert (tmp_path / "a3.las").read_bytes() == (tmp_path / "fresh_False.las").read_bytes()


@pytest.mark.slow  # 15-20 s: with the slow marker, so the default suite stays under 10 minutes
def test_recording_the_pieces_keeps_what_the_tasks_recorded_of_the_fit(tmp_path, monkeypatch):
    # a kept store run again with another fit parameter: the client records the tiles in pieces after the workers
    # recorded their new fit; the fit's record and its counts must survive
    src = tmp_path / "scene.las"
    write_scene(src, n=20_000, seed=6)
    kw = dict(tile_size=16, scheduler="threads", workers=4, quiet=True)
    _cut_for_20_workers(monkeypatch)
    normals(src, tmp_path / "r1.las", store=str(tmp_path / "kept.zarr"), **kw)
    again = normals(src, tmp_path / "r2.las", store=str(tmp_path / "kept.zarr"), threshold=0.05, **kw)
    st = Store.open(str(tmp_path / "kept.zarr"))
    assert [t for t in st.tiles if "fit" not in st.tile_attrs(t)["done"]] == []
    monkeypatch.setattr(normals_job, "pieces_for", lambda counts, slots, min_points=None: {})
    fresh = normals(src, tmp_path / "fresh.las", threshold=0.05, **kw)
    assert again.patches_by_kind == fresh.patches_by_kind
    assert (tmp_path / "r2.las").read_bytes() == (tmp_path / "fresh.las").read_bytes()
