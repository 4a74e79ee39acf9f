"""tools/bench_runs_argsort.py: the run-by-run stable argsort against numpy's, one table, the same permutations."""

import bench_runs_argsort  # tools/ is on sys.path, see conftest.py


def test_the_table_says_the_permutations_are_numpys(tmp_path):
    out = tmp_path / "t.txt"
    assert bench_runs_argsort.main(["--points", "20000", "--repeats", "1", "--out", str(out)]) == 0
    rows = [line for line in out.read_text().splitlines() if line and not line.startswith("#")][1:]
    assert len(rows) == 3 and all(r.split()[-1] == "yes" for r in rows)
    runs = [float(r.split()[-5]) for r in rows]  # mean run length: the cells of h come in runs, random keys do not
    assert runs[0] > 2.0 and runs[2] < 1.5
