"""tools/normals_las.py, the in-memory main job: output content and bad input."""

import importlib.util

import numpy as np
import pytest

from conftest import ROOT

laspy = pytest.importorskip("laspy")
SAMPLE = ROOT / "data" / "test_data_77055_627760_LA93_IGN69.laz"


def _tool():
    spec = importlib.util.spec_from_file_location("normals_las", ROOT / "tools" / "normals_las.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("suffix", [".laz", ".las"])
def test_writes_every_original_dimension_plus_normals(tmp_path, suffix, capsys):
    out = tmp_path / ("out" + suffix)
    assert _tool().main([str(SAMPLE), str(out)]) == 0
    a, b = laspy.read(SAMPLE), laspy.read(out)
    assert len(b.points) == len(a.points)
    for name in a.point_format.dimension_names:
        assert np.array_equal(np.asarray(a[name]), np.asarray(b[name])), name
    n = np.column_stack([b["NormalX"], b["NormalY"], b["NormalZ"]])
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
    assert set(np.unique(b["NormalMethod"])) <= {1, 2, 3, 4}
    with laspy.open(out) as f:
        assert f.header.are_points_compressed == (suffix == ".laz")
    assert "points            60,653" in capsys.readouterr().out
    assert not list(tmp_path.glob("*.partial"))


def test_refuses_to_overwrite_without_flag(tmp_path, capsys):
    out = tmp_path / "out.laz"
    out.write_bytes(b"keep me")
    assert _tool().main([str(SAMPLE), str(out)]) == 2
    assert "exists (use --overwrite" in capsys.readouterr().err
    assert out.read_bytes() == b"keep me"


@pytest.mark.parametrize(
    "content, message",
    [(b"this is not a point cloud", "not a readable LAS/LAZ file"), (None, "no such file")],
)
def test_bad_input_gives_one_clear_line_and_no_output(tmp_path, capsys, content, message):
    src = tmp_path / "bad.laz"
    if content is not None:
        src.write_bytes(content)
    out = tmp_path / "out.laz"
    assert _tool().main([str(src), str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and str(src) in err
    assert not out.exists() and not list(tmp_path.glob("*.partial"))


def test_truncated_file_is_refused(tmp_path, capsys):
    src = tmp_path / "cut.laz"
    data = SAMPLE.read_bytes()
    src.write_bytes(data[: len(data) // 2])
    out = tmp_path / "out.laz"
    assert _tool().main([str(src), str(out)]) == 2
    assert str(src) in capsys.readouterr().err
    assert not out.exists()
