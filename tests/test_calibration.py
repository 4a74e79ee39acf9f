"""The default RMSE threshold's calibration: cells of an absolute grid, so tiles add up and the frame does not matter."""

import numpy as np

from patchcloud.core import estimate_normals, rmse_histograms, threshold_from_histograms
from patchcloud.core.calibration import calibration_edges


def wavy_ground(n=60_000, seed=2):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 48.0, (n, 2))
    z = 0.3 * np.sin(xy[:, 0] / 3.0) + 0.02 * rng.normal(size=n)
    return np.column_stack([xy, z]) + [647168.0 + 1000.0, 6856704.0 + 2000.0, 40.0]


def test_tiles_add_up_to_the_whole_cloud_in_any_frame():
    pts = wavy_ground()
    origin = np.array([647168.0, 6856704.0, 0.0])  # a stream grid origin (a multiple of 4096 m)
    d_min = 0.9
    c0, c1, _ = calibration_edges(d_min)
    whole = rmse_histograms(pts, d_min, 12)
    assert whole[0].sum() > 50 and whole[1].sum() > 50
    local = pts - origin
    assert np.array_equal(rmse_histograms(local, d_min, 12, origin=origin), whole)
    # tiles of 8 m (a multiple of both cell edges) on the grid: their histograms add up
    tile = np.floor(local[:, :2] / 8.0).astype(np.int64)
    key = tile[:, 0] * 1000 + tile[:, 1]
    parts = [rmse_histograms(local[key == k], d_min, 12, origin=origin) for k in np.unique(key)]
    assert np.array_equal(np.sum(parts, axis=0), whole)


def test_the_threshold_is_about_twice_the_noise_and_the_in_memory_run_uses_it():
    pts = wavy_ground()
    res = estimate_normals(pts)
    p = res.parameters
    h = rmse_histograms(pts - np.asarray(p.root_corner), p.d_min, p.n_min)
    assert p.threshold == threshold_from_histograms(h, p.d_min, p.spacing)
    assert 0.02 < p.threshold < 0.06  # 2 cm noise on a gentle wave: about twice the fit RMSE


def test_cells_larger_than_the_grid_anchor_are_no_error():
    # two points far apart make d_min huge: calibration cells of 8192 m, larger than the 4096 m anchor
    pts = np.array([[0.0, 0.0, 0.0], [3000.0, 10.0, 5.0]])
    h = rmse_histograms(pts, 5000.0, 12, origin=(647168.0, 6856704.0, -4096.0))
    assert h.sum() == 0
    assert threshold_from_histograms(h, 5000.0, spacing=1.0) == 0.02  # the floor: FLOOR_FACTOR x spacing
