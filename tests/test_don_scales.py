"""DoN scale selection (patchcloud.stream.jobs.don_scales, the don-scales command, its figure) on a synthetic labelled scene."""

import laspy
import numpy as np
import pytest
from click.testing import CliRunner
from matplotlib.image import imread

from patchcloud.core import PatchcloudIOError, PatchcloudValueError, difference_of_normals, don_magnitude
from patchcloud.stream.cli.don_scales import don_scales_command
from patchcloud.stream.views.plots import save_png, scale_selection_figure
from patchcloud.stream.jobs.don_scales import don_scales, fisher_ratio, scale_pairs, select_scales, stratified_sample

OFFSET = np.array([650000.0, 6860000.0, 30.0])
POLES = [(4, 4), (4, 12), (10, 6), (12, 14), (6, 22), (14, 24)]
POLE_HEIGHT = 1.5
SAMPLE = 6000


def scene(rng):
    """Ground (class 2) 30 x 30 m at 0.15 m, a building (class 6) 8 x 8 x 5 m, six poles (class 64) of radius 0.1 m, 1.5 m tall.

    The poles are the one class whose DoN depends on the pair: a ball smaller
    than the pole sees a cylinder (horizontal normal), one that reaches well
    beyond it sees mostly ground (vertical normal), so poles respond when
    r_s <= 1 m < 2 m <= r_l, and not at all when both radii exceed the pole.
    """
    s = 0.15
    g = np.arange(0, 30, s)
    gx, gy = np.meshgrid(g, g)
    ground = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    ground[:, :2] += rng.uniform(-s / 4, s / 4, (gx.size, 2))
    lo, hi, h = 18.0, 26.0, 5.0
    ground = ground[~((ground[:, 0] > lo) & (ground[:, 0] < hi) & (ground[:, 1] > lo) & (ground[:, 1] < hi))]
    a = np.arange(lo, hi, s)
    ra, rb = np.meshgrid(a, a)
    wa, wz = np.meshgrid(a, np.arange(s, h, s))
    wa, wz = wa.ravel(), wz.ravel()
    building = np.vstack([
        np.column_stack([ra.ravel(), rb.ravel(), np.full(ra.size, h)]),
        np.column_stack([wa, np.full(wa.size, lo), wz]), np.column_stack([wa, np.full(wa.size, hi), wz]),
        np.column_stack([np.full(wa.size, lo), wa, wz]), np.column_stack([np.full(wa.size, hi), wa, wz]),
    ])
    t, z = np.meshgrid(np.arange(0, 2 * np.pi, 0.5), np.arange(0.05, POLE_HEIGHT, 0.05))
    poles = []
    for cx, cy in POLES:
        poles.append(np.column_stack([cx + 0.1 * np.cos(t.ravel()), cy + 0.1 * np.sin(t.ravel()), z.ravel()]))
        ground = ground[np.hypot(ground[:, 0] - cx, ground[:, 1] - cy) > 0.1]
    poles = np.vstack(poles)
    pts = np.vstack([ground, building, poles]) + rng.normal(0, 0.005, (len(ground) + len(building) + len(poles), 3))
    cls = np.repeat(np.array([2, 6, 64], dtype=np.uint8), [len(ground), len(building), len(poles)])
    return pts, cls


def write_las(path, pts, cls):
    header = laspy.LasHeader(point_format=6, version="1.4")  # 8-bit classification: class 64
    header.scales = [0.001, 0.001, 0.001]
    header.offsets = OFFSET
    las = laspy.LasData(header)
    las.x, las.y, las.z = (pts + OFFSET).T
    las.classification = cls
    las.user_data = (cls == 64).astype(np.uint8)  # a second class dimension: pole or not
    las.write(path)


@pytest.fixture(scope="module")
def labelled(tmp_path_factory):
    path = tmp_path_factory.mktemp("don_scales") / "labelled.laz"
    pts, cls = scene(np.random.default_rng(7))
    write_las(path, pts, cls)
    return path


@pytest.fixture(scope="module")
def result(labelled):
    return don_scales(labelled, sample=SAMPLE)


def local_points(path):
    """The command's local coordinates: X * scale + (offset - min), float64."""
    las = laspy.read(path)
    h = las.header
    xyz = np.column_stack([las.X, las.Y, las.Z]).astype(np.float64) * h.scales + (h.offsets - h.mins)
    return xyz, np.asarray(las.classification)


def test_the_best_pair_is_the_pole_scale(result):
    assert result.classes.tolist() == [2, 6, 64]
    assert result.sampled.tolist() == [SAMPLE // 3] * 3  # stratified: an equal share per class
    assert result.pairs.shape == (15, 2) and (result.r_small < result.r_large).all()
    rs, rl = result.best_pair
    assert rs <= 1.0 and rl >= 2.0, result.format()  # small ball within the 1.5 m pole, large one beyond it
    beyond = result.r_small >= 2.0  # both radii exceed the poles' size
    assert result.best_fisher > 2.0 * np.nanmax(result.fisher[beyond])
    assert result.best_fisher == np.nanmax(result.fisher)
    j = result.classes.tolist().index(64)
    assert result.mean[result.best, j] > 0.5  # poles respond at the best pair ...
    assert result.mean[beyond, j].max() < 0.15  # ... and not when both radii exceed them
    assert result.mean[result.best, 0] < 0.1  # ground hardly at all
    # r_s = 0.1 m is below the ground spacing: mostly undefined, so not scored
    assert np.isnan(result.fisher[result.r_small == 0.1]).all()


def test_statistics_are_the_cores_don_and_the_stated_ratio(labelled, result):
    pts, cls = local_points(labelled)
    at = stratified_sample(cls, result.classes, SAMPLE, seed=0)
    rs, rl = result.best_pair
    mag = don_magnitude(difference_of_normals(pts, rs, rl, mode="fast", at=at, grid_step=0.001))  # the file's grid
    for j, c in enumerate(result.classes):
        m = mag[cls[at] == c]
        assert result.count[result.best, j] == np.isfinite(m).sum()
        np.testing.assert_allclose(result.mean[result.best, j], np.nanmean(m), rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(result.std[result.best, j], np.nanstd(m), rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(result.median[result.best, j], np.nanmedian(m), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(result.best_fisher, fisher_ratio(mag, cls[at]), rtol=1e-9)
    n, mu_c, sd = result.count[result.best], result.mean[result.best], result.std[result.best]
    mu = (n * mu_c).sum() / n.sum()
    np.testing.assert_allclose(result.best_fisher, (n * (mu_c - mu) ** 2).sum() / (n * sd**2).sum(), rtol=1e-12)


def test_deterministic_subset_and_other_dimension(labelled, result):
    again = don_scales(labelled, sample=SAMPLE)
    for name in ("fisher", "mean", "std", "median", "count"):
        np.testing.assert_array_equal(getattr(again, name), getattr(result, name))
    sub = don_scales(labelled, classes=[2, 64], radii=[0.5, 1, 2, 4], sample=4000)
    assert sub.classes.tolist() == [2, 64] and sub.excluded == (6,)
    assert sub.best_pair[1] >= 2.0
    by_flag = don_scales(labelled, classes_from="user_data", radii=[0.5, 1, 2, 4], sample=4000)
    assert by_flag.classes.tolist() == [0, 1] and by_flag.best_pair[1] >= 2.0
    text = by_flag.format()
    assert "user_data" in text and "**<-**" in text


def test_arguments_are_checked_first(labelled, tmp_path):
    with pytest.raises(PatchcloudValueError, match="at least two distinct"):
        don_scales(labelled, radii=[1.0])
    with pytest.raises(PatchcloudValueError, match="positive lengths in the file"):
        don_scales(labelled, radii=[0.5, -1])
    with pytest.raises(PatchcloudValueError, match="no pair"):
        scale_pairs(small=[2, 3], large=[1])
    with pytest.raises(PatchcloudValueError, match="classification, "):
        don_scales(labelled, classes_from="label")  # names the file's dimensions
    with pytest.raises(PatchcloudValueError, match="fewer than two classes"):
        don_scales(labelled, classes=[2])
    with pytest.raises(PatchcloudValueError, match="not in 'classification'.*64 "):
        don_scales(labelled, classes=[2, 9])
    with pytest.raises(PatchcloudValueError, match="max_points"):
        don_scales(labelled, max_points=1000)
    with pytest.raises(PatchcloudValueError, match="mode must be one of exact, fast"):
        don_scales(labelled, mode="approx")
    bad = tmp_path / "notes.laz"
    bad.write_text("not a point cloud")
    with pytest.raises(PatchcloudIOError, match="notes.laz"):
        don_scales(bad)
    pts = np.random.default_rng(0).uniform(0, 5, (500, 3))
    with pytest.raises(PatchcloudValueError, match="fewer than two classes"):
        select_scales(pts, np.repeat([1, 2], [450, 50]))


def test_figure_is_drawn(result, tmp_path):
    fig = scale_selection_figure(result)
    assert len(fig.axes) == 3  # heat map, per-class panel, colour bar
    out = save_png(fig, tmp_path / "f.png")
    assert not (tmp_path / "f.png.partial").exists()
    img = imread(out)
    assert img.shape[0] > 300 and img.shape[1] > 800 and img[..., :3].var() > 0


def test_command(labelled, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    run = CliRunner().invoke(don_scales_command, [str(labelled), "--sample", str(SAMPLE), "--table", "scales.md"])
    assert run.exit_code == 0, run.output
    assert "**<-**" in run.stdout and "best pair: r_s =" in run.stdout and "Fisher" in run.stdout
    assert (tmp_path / "scales.md").read_text().strip() in run.stdout
    png = tmp_path / "labelled_don_scales.png"  # the default: INPUT's stem, in the current directory
    img = imread(png)
    assert img[..., :3].var() > 0
    quiet = CliRunner().invoke(
        don_scales_command, [str(labelled), "--radii", "0.5,1,2,4", "--classes", "2,64", "--plot", "q.png", "-q"]
    )
    assert quiet.exit_code == 0 and quiet.stdout == "" and (tmp_path / "q.png").exists()


@pytest.mark.parametrize(
    "args, expect",
    [
        (["--classes-from", "label"], "no dimension 'label'"),
        (["--radii", "0.5"], "at least two distinct"),
        (["--radii", "0.5,x"], "--radii must be comma-separated numbers"),
        (["--classes", "2,7"], "class 7 low point (noise) not in 'classification'"),
        (["--plot", "a.png", "--no-plot"], "--plot and --no-plot: give one of them, not both"),
    ],
)
def test_command_errors(labelled, tmp_path, args, expect):
    run = CliRunner().invoke(don_scales_command, [str(labelled), "--plot", str(tmp_path / "x.png"), *args])
    assert run.exit_code == 2
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and expect in lines[0], run.stderr
    assert not (tmp_path / "x.png").exists()


def test_command_rejects_a_file_that_is_not_las(tmp_path):
    bad = tmp_path / "readme.laz"
    bad.write_text("hello")
    run = CliRunner().invoke(don_scales_command, [str(bad), "--no-plot"])
    assert run.exit_code == 2
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and str(bad) in lines[0]


def test_classes_whose_don_is_alike_at_every_pair_are_said_not_to_separate():
    """Two classes on one plane: every DoN is defined and 0, so no pair separates them (it said no DoN was defined)."""
    from patchcloud.core import PatchcloudValueError
    from patchcloud.stream.jobs.don_scales import select_scales

    xy = np.random.default_rng(4).uniform(0, 20, (20000, 2))
    pts = np.column_stack([xy, np.full(20000, 10.0)])
    labels = np.where(xy[:, 0] < 10, 2, 6)
    with pytest.raises(PatchcloudValueError, match=r"no pair of radii separates the classes: at every pair their DoN magnitudes are alike"):
        select_scales(pts, labels, radii=[0.5, 1, 2], mode="exact")
