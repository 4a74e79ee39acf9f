"""tools/bench_voxels.py: the points a voxel holds on a hand-made plane, and the table on a small city."""

import numpy as np

import bench_voxels as bv  # tools/ is on sys.path, see conftest.py


def test_points_a_voxel_holds_on_a_plane():
    # a plane on a 0.25 m grid (16 points/m²), in one layer of cells: 0.5 m voxels (r = 2 m) hold 4 points,
    # 0.25 m voxels (r = 1 m) 1, 1.25 m voxels (r = 5 m: cells of 1 m scaled by 1.25²) 25
    g = np.arange(0.0, 20.0, 0.25) + 0.125
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    plane = np.column_stack([x, y, np.full(x.size, 0.1)])
    assert bv.voxel_points(plane, 2.0) == 4.0
    assert bv.voxel_points(plane, 1.0) == 1.0
    assert bv.voxel_points(plane, 5.0) == 25.0


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
