"""tools/bench_scale.py: the occupancy figures and the two speed-up bounds, on hand-made task streams."""

import pytest

import bench_scale  # tools/ is on sys.path, see conftest.py


def _profile(tasks, ended, slots=1):
    """A ``--profile`` of a run that started at 0 s: tasks as (label, start, end)."""
    return dict(slots=slots, started=0.0, ended=ended, tasks=[[label, s, e, "host:1:1"] for label, s, e in tasks])


# one worker: fit 4 + 1 + 1 s, then finish 2 + 2 s, and 0.5 s of the client's own at the end
ONE_WORKER = _profile([("fit", 0, 4), ("fit", 4, 5), ("fit", 5, 6), ("finish", 6, 8), ("finish", 8, 10)], ended=10.5)


def test_occupancy_of_one_worker_is_the_client_time():
    occ = bench_scale.occupancy(ONE_WORKER)
    assert occ["client_s"] == pytest.approx(0.5) and occ["work"] == pytest.approx(10.0) and occ["longest"] == pytest.approx(4.0)
    assert occ["idle"] == pytest.approx(0.5 / 10.5)


def test_the_list_bound_keeps_a_step_as_long_as_its_longest_task():
    # 2 workers: fit {4} | {1, 1} -> 4 s, finish {2} | {2} -> 2 s: (0.5 + 10) / (0.5 + 6)
    assert bench_scale.list_bound(ONE_WORKER, points=1000, n=2) == pytest.approx(10.5 / 6.5)
    # more workers cannot shorten a step below its longest task; Amdahl's bound, splitting everything, keeps rising
    assert bench_scale.list_bound(ONE_WORKER, points=1000, n=16, pieces=False) == pytest.approx(10.5 / 6.5)
    assert bench_scale.amdahl(0.5, 10.0, 2) == pytest.approx(10.5 / 5.5)
    assert bench_scale.amdahl(0.5, 10.0, 16) == pytest.approx(10.5 / (0.5 + 10 / 16))


def test_the_list_bound_recuts_the_parts_of_the_input_for_the_workers():
    # 4 export parts of 1 s at one worker; 2M points on 16 workers are cut into parts of 100,000 points (part_size):
    # 20 parts of 0.2 s, dealt 16 then 4: 0.4 s
    profile = _profile([("export", k, k + 1) for k in range(4)], ended=4.0)
    assert bench_scale.list_bound(profile, points=2_000_000, n=16) == pytest.approx(4.0 / 0.4)


def test_the_list_bound_models_the_finish_pieces_of_big_tiles():
    # finish 6 + 1 + 1 s on 4 workers: share 2 s, so the 6 s tile is cut in 3 pieces of 6 (f + (1 - f) / 3) s
    f = bench_scale.PIECE_OVERHEAD
    assert bench_scale.cut_into_pieces([6.0, 1.0, 1.0], 4) == pytest.approx([6 * (f + (1 - f) / 3)] * 3 + [1.0, 1.0])
    assert bench_scale.cut_into_pieces([1.0, 1.0], 2) == [1.0, 1.0]  # nothing over a worker's share: nothing cut
    profile = _profile([("finish", 0, 6), ("finish", 6, 7), ("finish", 7, 8)], ended=8.0)
    # 4 workers: pieces 3.0, 3.0, 3.0 | 1 then 1 on the fourth: the longest piece
    assert bench_scale.list_bound(profile, points=10**9, n=4) == pytest.approx(8.0 / (6 * (f + (1 - f) / 3)))
    assert bench_scale.list_bound(profile, points=10**9, n=4, pieces=False) == pytest.approx(8.0 / 6.0)
    # 1,000,000 points: no piece under 250,000 points, a quarter of the step's 8 s: the 6 s tile in 3 all the same
    assert bench_scale.list_bound(profile, points=1_000_000, n=4) == pytest.approx(8.0 / (6 * (f + (1 - f) / 3)))
    # 500,000 points: pieces of at least half the step (4 s): the 6 s tile in 2
    assert bench_scale.list_bound(profile, points=500_000, n=4) == pytest.approx(8.0 / (6 * (f + (1 - f) / 2)))
    assert bench_scale.cut_into_pieces([6.0, 1.0, 1.0], 4, min_share=7.0) == [6.0, 1.0, 1.0]
