"""tools/bench_fallback.py: the same-class ball PCA on a hand-made case, the tables, and the command line on a tiny LAS."""

import numpy as np
import pytest

import bench_fallback as bf  # tools/ is on sys.path, see conftest.py
from patchcloud.core import Method


def _two_planes():
    """A horizontal ground plane (class 2) crossed by a vertical wall x = 2.5 (class 6), plus small odd classes.

    - class 5: 4 points within 1 m of each other (each has 3 others: a reference), not coplanar with anything else;
    - class 1: 3 points (each has 2 others: no reference);
    - class 4: 1 point alone (no reference).
    """
    g = np.arange(0.0, 5.0, 0.25)
    gx, gy = np.meshgrid(g, g)
    ground = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    wy, wz = np.meshgrid(g, np.arange(-1.0, 2.0, 0.25))
    wall = np.column_stack([np.full(wy.size, 2.5), wy.ravel(), wz.ravel()])
    veg = np.array([[1.0, 1.0, 3.0], [1.3, 1.0, 3.0], [1.0, 1.3, 3.0], [1.1, 1.1, 3.0]])  # plane z = 3
    unc = np.array([[4.0, 4.0, 1.0], [4.2, 4.0, 1.0], [4.0, 4.2, 1.0]])
    lone = np.array([[0.5, 0.5, 0.5]])
    xyz = np.vstack([ground, wall, veg, unc, lone])
    cls = np.concatenate([np.full(len(ground), 2), np.full(len(wall), 6), np.full(4, 5), np.full(3, 1), [4]]).astype(np.uint8)
    return xyz, cls


@pytest.mark.parametrize("max_pairs", [bf.MAX_PAIRS, 50])  # one chunk per class, and many small chunks
def test_reference_is_each_class_own_plane(max_pairs):
    xyz, cls = _two_planes()
    ref, nb = bf.reference_normals(xyz, cls, max_pairs=max_pairs)
    ground, wall, veg = cls == 2, cls == 6, cls == 5
    # the wall crosses the ground (z from -1 to 2 at x = 2.5), yet each class sees only itself
    assert np.all(bf.angles(ref[ground], np.tile([0, 0, 1.0], (ground.sum(), 1))) < 1e-4)
    assert np.all(bf.angles(ref[wall], np.tile([1.0, 0, 0], (wall.sum(), 1))) < 1e-4)
    assert np.all(bf.angles(ref[veg], np.tile([0, 0, 1.0], (4, 1))) < 1e-4)
    assert np.allclose(np.linalg.norm(ref[ground | wall | veg], axis=1), 1.0, atol=1e-6)
    # fewer than 3 other same-class points: no reference, and the count says why
    assert np.all(np.isnan(ref[(cls == 1) | (cls == 4)]))
    assert nb[cls == 1].tolist() == [2, 2, 2] and nb[cls == 4].tolist() == [0] and nb[veg].tolist() == [3, 3, 3, 3]
    # ground uses a 2 m ball, the wall 1 m: a wall point in its middle has the 1 m disc of 0.25 m grid points
    mid = np.flatnonzero(wall & np.all(np.isclose(xyz, [2.5, 2.5, 0.5]), axis=1))
    assert nb[mid].tolist() == [np.count_nonzero(np.linalg.norm(xyz[wall] - xyz[mid], axis=1) <= 1.0) - 1]
    gmid = np.flatnonzero(ground & np.all(np.isclose(xyz, [2.5, 2.5, 0.0]), axis=1))
    assert nb[gmid].tolist() == [np.count_nonzero(np.linalg.norm(xyz[ground] - xyz[gmid], axis=1) <= 2.0) - 1]


def test_class_groups_and_method_names():
    assert bf.class_groups([2, 6, 3, 4, 5, 1, 7, 64, 17]).tolist() == [0, 1, 2, 2, 2, 3, 3, 3, 3]
    assert bf.method_name(3) == "knn" and bf.method_name(1) == "quadric" and bf.method_name(250) == "code250"


def _scene(seed=0):
    """A small ground plane (2), a box roof and walls (6) and a scattered tree (5): a few thousand points."""
    rng = np.random.default_rng(seed)
    n = 4000
    ground = np.column_stack([rng.uniform(0, 30, n), rng.uniform(0, 30, n), rng.normal(0, 0.01, n)])
    u, v = rng.uniform(0, 8, 1500), rng.uniform(0, 5, 1500)
    roof = np.column_stack([u + 5, rng.uniform(0, 8, 1500) + 5, 5 + 0.1 * u])
    wall = np.column_stack([np.full(1500, 5.0), u + 5, v])
    tree = rng.normal([20, 20, 6], [1.5, 1.5, 2.0], (800, 3))
    xyz = np.vstack([ground, roof, wall, tree])
    cls = np.concatenate([np.full(n, 2), np.full(3000, 6), np.full(800, 5)]).astype(np.uint8)
    return xyz, cls


def test_tables_on_a_tiny_cloud():
    xyz, cls = _scene()
    normals, method, secs = bf.patchcloud_normals(xyz)
    ref, _ = bf.reference_normals(xyz, cls)
    run = dict(label="tiny.las", normals=normals, method=method, reference=ref, classes=cls, seconds=secs, ref_seconds=0.1)
    lines = bf.quality_table([run, dict(run, label="other.las"), dict(run, label="again.las", same_as="tiny.las")])
    names = [bf.method_name(c) for c in np.unique(method)]
    assert all(f"{m}%" in lines[0] and f"{m} n" in lines[0] for m in names) and "all n" in lines[0]
    # 3 groups (no "other" class here) of 3 files, then pooled, then the note on the duplicate
    assert len(lines) == 1 + 4 * 3 + 1 and sum("| ground" in ln for ln in lines) == 4
    assert lines[-4].startswith("all files") and lines[-1] == "# again.las holds the same bytes as tiny.las: counted once in 'all files'"
    assert lines[-4].split()[2] == f"{2 * len(xyz):,}"  # tiny and other, not again
    # the ground plane's normals are close to its ball PCA
    assert float(lines[1].split("|")[1].split()[-1]) < 5.0
    # a baseline in which some quadric points were k-NN: they show up as having left it
    knn = int(Method.KNN)
    base_method = method.copy()
    left = np.flatnonzero(method != knn)[:50]
    base_method[left] = knn
    base = {"tiny.las": dict(method=base_method, normals=normals, classes=cls)}
    out = bf.baseline_table([run], base)
    assert "50 left k-NN" in out[0]
    rows = [ln for ln in out if "|" in ln and not ln.startswith("file")]
    assert sum(int(r.split("|")[1].split()[1].replace(",", "")) for r in rows) == 50
    other = bf.baseline_table([run], {"tiny.las": dict(method=method[:-1], normals=normals[:-1], classes=cls[:-1])})
    assert "skipped" in other[0]


def test_command_line_save_baseline_results(tmp_path, capsys):
    laspy = pytest.importorskip("laspy")
    xyz, cls = _scene(1)
    h = laspy.LasHeader(point_format=1, version="1.2")
    h.scales, h.offsets = np.array([0.001] * 3), np.array([700_000.0, 6_600_000.0, 0.0])
    las = laspy.LasData(h)
    las.x, las.y, las.z = xyz[:, 0] + 700_000, xyz[:, 1] + 6_600_000, xyz[:, 2] + 50
    las.classification = cls
    src = tmp_path / "scene.las"
    las.write(src)
    saved, results = tmp_path / "run.npz", tmp_path / "res" / "table.txt"
    assert bf.main(["--files", str(src), "--save", str(saved)]) == 0
    runs, commit = bf.load_runs(saved)
    (label,) = runs
    assert runs[label]["normals"].shape == (len(xyz), 3) and runs[label]["classes"].tolist() == cls.tolist()
    assert bf.main(["--files", str(src), "--baseline", str(saved), "--results", str(results)]) == 0
    text = results.read_text()
    assert text.startswith("# bench_fallback") and text.splitlines()[1].startswith("# command: python tools/bench_fallback.py --files")
    assert "0 left k-NN" in text and "no point left the k-NN fallback" in text
    assert "scene" in capsys.readouterr().out


def test_missing_data_is_a_reason_not_an_error(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(bf, "SHARED", tmp_path / "nowhere")
    assert bf.main([]) == 0
    assert "no data" in capsys.readouterr().out
    assert bf.main(["--files", str(tmp_path / "absent.laz")]) == 0
    assert "no data" in capsys.readouterr().out
