"""tools/bench_compress.py: a smoke run of the compression benchmark on a small synthetic LAS."""

import math

import numpy as np
import pytest

laspy = pytest.importorskip("laspy")
pytest.importorskip("lazrs")
import bench_compress  # tools/ is on sys.path, see conftest.py


def _plane_and_box(path, n=20_000, seed=0):
    """A noisy ground plane (80 %) and the walls and roof of a box on it (20 %), scale 1 mm."""
    rng = np.random.default_rng(seed)
    m = int(0.8 * n)
    ground = np.column_stack([rng.uniform(0, 40, m), rng.uniform(0, 40, m), rng.normal(0, 0.003, m)])
    k = n - m
    side = rng.integers(0, 5, k)
    u, v = rng.uniform(0, 10, k), rng.uniform(0, 6, k)
    box = np.empty((k, 3))
    for s, (x, y, z) in enumerate([(u, 0 * u, v), (u, 10 + 0 * u, v), (0 * u, u, v), (10 + 0 * u, u, v), (u, v * 10 / 6, 6 + 0 * u)]):
        sel = side == s
        box[sel] = np.column_stack([x[sel], y[sel], z[sel]]) + [15, 15, 0]
    pts = np.vstack([ground, box]) + [500_000, 6_000_000, 100]
    h = laspy.LasHeader(point_format=1, version="1.2")
    h.scales, h.offsets = np.array([0.001] * 3), np.array([500_000, 6_000_000, 0])
    las = laspy.LasData(h)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    las.classification = np.r_[np.full(m, 2), np.full(k, 6)].astype(np.uint8)
    las.intensity = rng.integers(0, 4000, n).astype(np.uint16)
    las.write(path)
    return n


def test_main_writes_a_sane_table(tmp_path, capsys):
    src = tmp_path / "plane_box.las"
    n = _plane_and_box(src)
    out = tmp_path / "bench.md"
    infos = bench_compress.main(["--real", "--city-points", "0", "--files", str(src), "--max-error", "0.05",
                                 "--no-draco", "--out", str(out)])
    assert len(infos) == 1
    info = infos[0]
    assert info["points"] == n and not info["draco_curve"]
    (row,) = info["rows"]
    sz = info["sizes"]
    assert 0 < sz["laz_xyz"] < sz["laz"] < sz["las"]
    assert row["bytes"] > 0 and row["bpp"] > 0 and sz["las"] / row["bytes"] > 1  # smaller than LAS, at least
    for key in ("o2r", "r2o", "modelled"):
        assert all(math.isfinite(v) and v >= 0 for v in row[key].values()), key
    assert row["o2r"]["mean"] <= row["o2r"]["p95"] <= row["o2r"]["max"]
    assert row["d2"] <= row["d1"] and row["d2"] < 0.05  # point-to-plane within the budget on a plane and a box
    assert 0 <= row["normal_deg"] < 10
    assert row["residual_exact"] == 1.0 or np.isnan(row["residual_exact"])
    assert row["compress_s"] > 0 and row["decompress_s"] > 0
    p = row["points_mode"]  # --keep-points: every point within the budget, attributes exact, smaller than LAS
    assert p["attributes_exact"] and 0 < p["max_move"] <= 0.05 and p["bytes"] < sz["las"] and p["steps"] == [57, 57, 57]
    assert sz["laz_xyz"] < sz["laz4"] <= sz["laz"]
    text = out.read_text()
    assert "### plane_box" in text and "| 0.05 |" in text and "### Goals per input" in text and "### Goals of the two modes" in text
    speed = info["laz_speed"]  # the LAZ baselines of compress and decompress, one row per mode
    assert speed["write_s"] > 0 and speed["read_s"] > 0
    assert "### Speed against LAZ" in text and "| plane_box | 0.05 | model |" in text and "| plane_box | 0.05 | points |" in text
    assert "| max-error m | .pcz bits/pt | x LAS | x LAZ |" in capsys.readouterr().out


def test_plot_draws_a_png(tmp_path):
    pytest.importorskip("matplotlib")
    rows = [dict(budget=b, d1=2 * b, d2=b / 2, bpp=20 / (1 + 10 * b)) for b in (0.01, 0.05)]
    curve = [dict(bits=k, d1=2.0**-k * 100, d2=2.0**-k * 50, bpp=3.0 * k) for k in range(6, 14)]
    info = dict(name="x", points=1000, sizes=dict(las=30_000, laz=4_000, laz_xyz=2_000), rows=rows, draco_curve=curve)
    png = bench_compress.plot([info, dict(info, name="y", draco_curve=[])], tmp_path / "rd.png")
    assert png.read_bytes()[:4] == b"\x89PNG"
    from matplotlib.image import imread

    img = imread(png)
    assert img.shape[0] > 200 and img.shape[1] > 400 and img[..., :3].var() > 0  # drawn, not blank
    no_draco = imread(bench_compress.plot([dict(info, draco_curve=[]), dict(info, name="y", draco_curve=[])], tmp_path / "n.png"))

    def red(a):  # Draco's curve is red (its legend entry too, in both figures)
        return int(((a[..., 0] > 0.7) & (a[..., 1] < 0.3) & (a[..., 2] < 0.3)).sum())

    assert red(img) > red(no_draco) + 200  # the curve given is drawn


def test_draco_bits_and_interpolation():
    assert bench_compress.draco_bits_for(100.0, 0.05) == 10  # 100 / 2**10 <= 0.1 < 100 / 2**9
    curve = [dict(d1=1.0, d2=0.5, bpp=4.0), dict(d1=0.01, d2=0.005, bpp=16.0)]
    assert bench_compress.interp_bpp(curve, 0.1, "d1") == pytest.approx(8.0)
    assert np.isnan(bench_compress.interp_bpp(curve, 2.0, "d1"))
