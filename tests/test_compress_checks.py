"""compress / decompress checks found by bug hunt H: a catalog's per-file checks before any output, a points-mode budget
its own reader takes, and a --bbox just beyond the input's bounds where decoded points lie."""

from __future__ import annotations

import laspy
import numpy as np
from click.testing import CliRunner

from patchcloud.stream.cli import main


def _las(path, extra: bool = False, n: int = 400, seed: int = 0):
    h = laspy.LasHeader(point_format=1, version="1.2")
    h.scales, h.offsets = np.array([0.01, 0.01, 0.01]), np.zeros(3)
    if extra:
        h.add_extra_dim(laspy.ExtraBytesParams(name="foo", type=np.uint8))
    las = laspy.LasData(h)
    rng = np.random.default_rng(seed)
    las.x, las.y = rng.uniform(0.0, 20.0, n), rng.uniform(0.01, 20.0, n)
    las.z = 0.05 * np.asarray(las.x)
    las.intensity = rng.integers(0, 1000, n)
    if extra:
        las.foo = rng.integers(0, 255, n)
    las.write(str(path))
    return path


def _run(args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_a_catalog_refuses_a_drop_name_one_file_lacks_before_writing_any_output(tmp_path):
    (tmp_path / "in").mkdir()
    _las(tmp_path / "in" / "a.las", extra=True)
    _las(tmp_path / "in" / "b.las", seed=1)
    for mode in ([], ["--keep-points"]):
        r = _run(["compress", tmp_path / "in", "--out-dir", tmp_path / "out", "--drop", "foo", "-q", "--units", "m", *mode])
        assert r.exit_code == 2 and "b.las: cannot drop 'foo'" in r.output, r.output
        assert not (tmp_path / "out").exists()  # not a.pcz, nor the catalog's record


def test_points_mode_refuses_a_budget_its_reader_would_refuse(tmp_path):
    src = _las(tmp_path / "a.las")
    r = _run(["compress", src, tmp_path / "a.pcz", "--keep-points", "--max-error", "2e7", "--units", "m", "-q"])
    assert r.exit_code == 2 and "--max-error 2e+07 is larger than a .pcz takes" in r.output, r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.las"]
    r = _run(["compress", src, tmp_path / "b.pcz", "--keep-points", "--max-error", "1e6", "--units", "m", "-q"])
    assert r.exit_code == 0, r.output
    assert _run(["decompress", tmp_path / "b.pcz", tmp_path / "b.las", "-q"]).exit_code == 0


def test_a_box_beyond_the_inputs_bounds_by_less_than_the_budget_gets_the_points_decoded_there(tmp_path):
    """Points mode rounds positions to a step within --max-error: some decode below the input's smallest y."""
    src = _las(tmp_path / "a.las", n=2000)
    assert _run(["compress", src, tmp_path / "a.pcz", "--keep-points", "--max-error", "0.5", "--units", "m", "-q"]).exit_code == 0
    assert _run(["decompress", tmp_path / "a.pcz", tmp_path / "all.las", "-q"]).exit_code == 0
    whole = laspy.read(str(tmp_path / "all.las"))
    low = float(laspy.open(str(src)).header.mins[1])
    below = np.asarray(whole.y) < low
    assert below.any()  # the case this is about
    box = [-1.0, low - 0.4, -10.0, 30.0, low - 1e-6, 10.0]  # wholly below the input's bounds, within the budget
    r = _run(["decompress", tmp_path / "a.pcz", tmp_path / "box.las", "--bbox", *box, "-q"])
    assert r.exit_code == 0, r.output
    assert laspy.read(str(tmp_path / "box.las")).header.point_count == int(np.count_nonzero(np.asarray(whole.y) <= low - 1e-6))
    r = _run(["decompress", tmp_path / "a.pcz", tmp_path / "far.las", "--bbox", -1.0, low - 2.0, -10.0, 30.0, low - 0.6, 10.0, "-q"])
    assert r.exit_code == 2 and "lies outside the input's bounds" in r.output, r.output
