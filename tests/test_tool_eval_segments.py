"""tools/eval_segments.py: the segment scores on a hand-computed example, the readers, and the command line."""

import numpy as np
import pytest

import eval_segments as ev  # tools/ is on sys.path, see conftest.py

# 10 points, 2 classes (1, 2), 3 segments (0 = none), 3 objects.
#   index     0  1  2  3  4  5  6  7  8  9
TRUTH = [1, 1, 1, 1, 1, 1, 2, 2, 2, 2]
SEGS = [1, 1, 1, 2, 2, 0, 2, 3, 3, 0]
OBJS = [7, 7, 7, 8, 8, 8, 9, 9, 9, 9]
KEPT = [1, 1, 1, 1, 1, 0, 1, 1, 1, 0]
DEFINED = [1, 1, 1, 1, 1, 1, 1, 1, 0, 0]
# By hand:
#   segment 1 = {0, 1, 2}: classes 1 1 1 -> labelled 1
#   segment 2 = {3, 4, 6}: classes 1 1 2 -> labelled 1
#   segment 3 = {7, 8}:    classes 2 2   -> labelled 2
#   class 1: 6 points; segments labelled 1 hold 6 points (0-4, 6), 5 of class 1 -> precision 5/6, recall 5/6
#   class 2: 4 points; segments labelled 2 hold 2 points, both of class 2   -> precision 2/2, recall 2/4
#   kept: class 1 5/6, class 2 3/4; in segments: class 1 5/6, class 2 3/4; undefined: class 1 0, class 2 2/4
#   object 7 (class 1): 3/3 in segment 1 -> found
#   object 8 (class 1): 2/3 in segment 2 -> found (more than half)
#   object 9 (class 2): best 2/4 (segment 3) -> NOT found (exactly half is not more than half)
#   object recall: class 1 2/2, class 2 0/1


def test_majority_labels_by_hand():
    seg_ids, seg_class, predicted = ev.majority_labels(SEGS, TRUTH)
    assert seg_ids.tolist() == [1, 2, 3]
    assert seg_class.tolist() == [1, 1, 2]
    assert predicted.tolist() == [1, 1, 1, 1, 1, -1, 1, 2, 2, -1]


def test_majority_tie_goes_to_smallest_code():
    _, seg_class, _ = ev.majority_labels([4, 4, 4, 4], [6, 5, 6, 5])
    assert seg_class.tolist() == [5]


def test_class_scores_by_hand():
    r = ev.class_scores(TRUTH, SEGS, kept=np.array(KEPT, bool), defined=np.array(DEFINED, bool))
    assert r.classes.tolist() == [1, 2]
    assert r.points.tolist() == [6, 4]
    assert r.segments.tolist() == [2, 1]
    np.testing.assert_allclose(r.precision, [5 / 6, 1.0])
    np.testing.assert_allclose(r.recall, [5 / 6, 2 / 4])
    np.testing.assert_allclose(r.kept, [5 / 6, 3 / 4])
    np.testing.assert_allclose(r.in_segments, [5 / 6, 3 / 4])
    np.testing.assert_allclose(r.undefined, [0.0, 2 / 4])


def test_class_scores_undefined_precision_and_no_masks():
    r = ev.class_scores([1, 1, 2, 2], [0, 0, 5, 5])  # no segment is labelled 1
    assert np.isnan(r.precision[0]) and r.recall[0] == 0.0
    assert r.precision[1] == 1.0 and r.recall[1] == 1.0
    assert np.isnan(r.kept).all() and np.isnan(r.undefined).all()
    none = ev.class_scores([1, 2], [0, 0])
    assert np.isnan(none.precision).all() and (none.recall == 0).all() and (none.segments == 0).all()


def test_object_scores_and_recall_by_hand():
    o = ev.object_scores(OBJS, SEGS, TRUTH, defined=np.array(DEFINED, bool))
    assert o.ids.tolist() == [7, 8, 9]
    assert o.classes.tolist() == [1, 1, 2]
    assert o.points.tolist() == [3, 3, 4]
    np.testing.assert_allclose(o.best_share, [1.0, 2 / 3, 2 / 4])
    assert o.found.tolist() == [True, True, False]
    np.testing.assert_allclose(o.defined, [1.0, 1.0, 2 / 4])
    classes, objects, found, recall, median_best, measurable = ev.object_recall(o)
    assert classes.tolist() == [1, 2]
    assert objects.tolist() == [2, 1]
    assert found.tolist() == [2, 0]
    np.testing.assert_allclose(recall, [1.0, 0.0])
    np.testing.assert_allclose(median_best, [(1.0 + 2 / 3) / 2, 0.5])
    assert measurable.tolist() == [2, 0]  # object 9 is defined on exactly half its points: not more


def test_object_scores_min_points_and_ground():
    o = ev.object_scores(OBJS, SEGS, TRUTH, min_points=4)
    assert o.ids.tolist() == [9] and o.found.tolist() == [False]
    z = ev.object_scores([0, 0, 0], [1, 1, 0], [2, 2, 2])  # object id 0 = no object
    assert z.ids.size == 0
    assert ev.object_recall(z)[1].size == 0


def test_scores_do_not_depend_on_point_order():
    perm = np.random.default_rng(3).permutation(10)
    t, s, o = (np.asarray(v)[perm] for v in (TRUTH, SEGS, OBJS))
    a, b = ev.class_scores(TRUTH, SEGS), ev.class_scores(t, s)
    np.testing.assert_allclose(a.precision, b.precision)
    np.testing.assert_allclose(a.recall, b.recall)
    assert ev.object_scores(o, s, t).found.tolist() == [True, True, False]


def test_lzf_literal_and_overlapping_back_reference():
    # "a" literal, then a back reference of length 5 at distance 1 (overlapping): "aaaaaa"
    assert ev.lzf_decompress(bytes([0]) + b"a" + bytes([(3 << 5) | 0, 0]), 6) == b"aaaaaa"
    # long back reference (length code 7 plus an extra byte): 7 + 3 + 2 = 12 copies of "ab"... from distance 2
    data = bytes([1]) + b"ab" + bytes([(7 << 5) | 0, 3, 1])
    assert ev.lzf_decompress(data, 14) == b"ab" * 7
    with pytest.raises(ValueError):
        ev.lzf_decompress(bytes([0]) + b"a" + bytes([(3 << 5) | 0, 5]), 6)  # reference before the start


def _lzf_literals(raw: bytes) -> bytes:
    """A valid LZF stream made of literal runs only (at most 32 bytes each)."""
    out = bytearray()
    for i in range(0, len(raw), 32):
        part = raw[i:i + 32]
        out += bytes([len(part) - 1]) + part
    return bytes(out)


def _write_pcd(path, xyz):
    xyz = np.asarray(xyz, dtype="<f4")
    raw = np.ascontiguousarray(xyz.T).tobytes()  # column-major: all x, all y, all z
    comp = _lzf_literals(raw)
    head = ("# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\n"
            f"COUNT 1 1 1\nWIDTH {len(xyz)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(xyz)}\nDATA binary_compressed\n")
    path.write_bytes(head.encode("ascii") + np.array([len(comp), len(raw)], "<u4").tobytes() + comp)


def _scene(rng):
    """A 12 m x 12 m ground plane (5 cm grid, jittered) with two poles (radius 0.1 m, 4 m high) and a box."""
    g = np.arange(0, 12, 0.05)
    gx, gy = np.meshgrid(g, g)
    ground = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)]) + rng.normal(0, 0.002, (gx.size, 3))
    parts, cls, oid = [ground], [np.full(len(ground), 2)], [np.zeros(len(ground), int)]
    ang, z = np.meshgrid(np.linspace(0, 2 * np.pi, 24, endpoint=False), np.arange(0.02, 4, 0.03))
    for k, (cx, cy) in enumerate([(3.0, 3.0), (9.0, 8.0)]):
        parts.append(np.column_stack([cx + 0.1 * np.cos(ang.ravel()), cy + 0.1 * np.sin(ang.ravel()), z.ravel()]))
        cls.append(np.full(ang.size, 64))
        oid.append(np.full(ang.size, 2 + 4 * k))
    u, w = np.meshgrid(np.arange(0, 1.5, 0.04), np.arange(0.05, 1.0, 0.04))
    box = np.concatenate([np.column_stack([6 + u.ravel(), np.full(u.size, 3.0), w.ravel()]),
                          np.column_stack([6 + u.ravel(), np.full(u.size, 4.0), w.ravel()])])
    parts.append(box)
    cls.append(np.full(len(box), 65))
    oid.append(np.full(len(box), 4))
    return np.concatenate(parts), np.concatenate(cls), np.concatenate(oid)


def test_main_on_las_with_object_ids(tmp_path, rng):
    laspy = pytest.importorskip("laspy")
    xyz, cls, oid = _scene(rng)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.add_extra_dim(laspy.ExtraBytesParams(name="ObjectId", type=np.uint32))
    header.offsets = [500000.0, 5400000.0, 100.0]
    header.scales = [0.001, 0.001, 0.001]
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0] + 500000.0, xyz[:, 1] + 5400000.0, xyz[:, 2] + 100.0
    las.classification = cls.astype(np.uint8)
    las.ObjectId = oid.astype(np.uint32)
    f = tmp_path / "scene.las"
    las.write(str(f))

    out = tmp_path / "report.txt"
    assert ev.main([str(f), "--rs", "0.2", "--rl", "1.0", "--tolerance", "0.15", "--min-points", "30",
                    "--out", str(out)]) == 0
    text = out.read_text()
    assert "parameters: rs=0.2 m, rl=1 m, threshold=0.25, tolerance=0.15 m, min_points=30" in text
    assert "Definitions:" in text and "## scene.las" in text
    assert "| 64 IGN other above-ground |" in text  # a LAS file gets ASPRS/IGN names
    assert "| object class | objects (>= 30 pts) |" in text
    # both poles stand alone on a plane: found
    pole_row = [ln for ln in text.splitlines() if ln.startswith("| 64 ") and "%" in ln][-1]
    assert pole_row.split("|")[2].strip() == "2" and pole_row.split("|")[5].strip() == "100.0 %"

    # --append adds a second report
    assert ev.main([str(f), "--rs", "0.2", "--rl", "1.0", "--out", str(out), "--append"]) == 0
    assert out.read_text().count("## scene.las") == 2


def test_main_on_isprs_pcd_pair(tmp_path, rng):
    xyz, cls, _ = _scene(rng)
    xyz = (xyz + [512000.0, 5403000.0, 300.0]).astype(np.float32)
    _write_pcd(tmp_path / "samp99-utm.pcd", xyz)
    _write_pcd(tmp_path / "samp99-utm-ground.pcd", xyz[cls == 2][::-1])  # any order
    cloud = ev.load(tmp_path / "samp99-utm.pcd")
    assert cloud.truth.tolist() == np.where(cls == 2, 2, 1).tolist()
    assert cloud.object_ids is None and cloud.points.min() == 0.0
    out = tmp_path / "r.txt"
    assert ev.main([str(tmp_path / "samp99-utm.pcd"), "--rs", "0.2", "--rl", "1.0", "--out", str(out)]) == 0
    text = out.read_text()
    assert "| 1 non-ground |" in text and "| 2 ground |" in text and "object recall: n/a" in text


def test_main_on_tiny_city(tmp_path):
    pytest.importorskip("laspy")
    out = tmp_path / "city.txt"
    assert ev.main(["--city", "20000", "--out", str(out)]) == 0
    text = out.read_text()
    assert "## synthetic city, first 20,000 points (seed 0)" in text
    assert "| 2 ground | 16,716 |" in text  # the generator is deterministic
    assert "| object class |" in text and "| 6 building |" in text


def test_main_needs_an_input():
    with pytest.raises(SystemExit):
        ev.main([])
