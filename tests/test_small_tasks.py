"""Small tasks in batches on a dask cluster (Runner.map with small=True): the same results, in call order, fewer tasks."""

from patchcloud.stream.engine.runner import SMALL_TASKS_PER_WORKER, Runner


def square_plus(x, plus=0):
    return x * x + plus


def test_small_calls_go_in_batches_a_few_a_worker_with_the_same_results_in_order():
    calls = [((k,), {"plus": k % 3}) for k in range(50)]
    seen = []
    with Runner("threads", 2, quiet=True) as r:
        out = r.map(square_plus, calls, "small", on_result=lambda k, v: seen.append((k, v)), small=True)
        assert out == [k * k + k % 3 for k in range(50)]
        assert sorted(seen) == list(enumerate(out))  # every call's result handed over once
        assert len(r.tasks) == SMALL_TASKS_PER_WORKER * 2  # 8 tasks for 50 calls
        few = r.map(square_plus, calls[:5], "few", small=True)  # no more calls than tasks: one task each
        assert few == out[:5] and len(r.tasks) == SMALL_TASKS_PER_WORKER * 2 + 5
        assert r.map(square_plus, calls, "big") == out and len(r.tasks) == SMALL_TASKS_PER_WORKER * 2 + 55


def test_without_a_cluster_small_changes_nothing():
    r = Runner("synchronous", quiet=True)
    assert r.map(square_plus, [((k,), {}) for k in range(20)], "small", small=True) == [k * k for k in range(20)]
    assert len(r.tasks) == 20
