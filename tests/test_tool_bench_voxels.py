"""tools/bench_voxels.py: the table on a small city."""

import bench_voxels as bv  # tools/ is on sys.path, see conftest.py


def test_the_table_on_a_small_city(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(bv, "REAL", {})
    out = tmp_path / "t.txt"
    monkeypatch.setattr("sys.argv", ["bench_voxels.py", "--city-points", "20000", "--radii", "2", "--out", str(out)])
    bv.main()
    rows = [line.split() for line in out.read_text().splitlines() if line.startswith("city-")]
    assert len(rows) == 1 and rows[0][0] == "city-20k" and rows[0][2] == "2"
    chosen = rows[0][7]
    per_voxel = float(rows[0][3])
    assert chosen == ("voxels" if per_voxel > bv.VOXEL_MIN_POINTS else "points")
