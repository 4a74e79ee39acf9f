"""PDAL's words with PDAL's meanings (issue 18, part 3): --classes, noise and withheld points, --keep-noise,
--always-up, --fallback-knn, and what ``patchcloud info`` says of classes and patchcloud dimensions."""

from pathlib import Path

import laspy
import numpy as np
import pytest
from click.testing import CliRunner

from patchcloud.core import PatchcloudValueError
from patchcloud.stream import RunOptions, compress, decompress, don, normals, segment
from patchcloud.stream.cli import main
from patchcloud.stream.io.point_coding import coarse_steps, coarsen, refine

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "data" / "test_data_77055_627760_LA93_IGN69.laz"
NO_PATCH = 4294967295


def write_las(path, xyz, classification, withheld=None):
    """A LAS 1.4 point format 6 file of ``xyz`` (metres, millimetre scale) with the given classes and withheld flags."""
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([650000.0, 6860000.0, 0.0])
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0] + 650000.0, xyz[:, 1] + 6860000.0, xyz[:, 2] + 40.0
    las.classification = np.asarray(classification, dtype=np.uint8)
    if withheld is not None:
        las.withheld = np.asarray(withheld, dtype=bool)
    las.intensity = np.arange(len(xyz)) % 65535
    las.write(str(path))


def ground(seed=0, side=32.0, step=0.25):
    """A jittered grid of ground points, gently sloping, 2 mm of noise."""
    g = np.arange(0.0, side, step)
    x, y = np.meshgrid(g, g)
    rng = np.random.default_rng(seed)
    x = x.ravel() + rng.uniform(-0.05, 0.05, x.size)
    y = y.ravel() + rng.uniform(-0.05, 0.05, y.size)
    z = 0.02 * x + 0.01 * y + rng.normal(0, 0.002, x.size)
    return np.column_stack([x, y, z])


def box(lo=(12.0, 12.0), size=(6.0, 6.0, 4.0), step=0.25, seed=1):
    """The walls and roof of a box standing on the ground (a building)."""
    rng = np.random.default_rng(seed)
    (x0, y0), (sx, sy, h) = lo, size
    pts = []
    u = np.arange(0.0, 1.0, step / sx)
    v = np.arange(0.0, 1.0, step / sy)
    w = np.arange(0.0, 1.0, step / h)
    for a, b in [(u, w), (v, w)]:
        A, B = np.meshgrid(a, b)
        A, B = A.ravel(), B.ravel()
        if a is u:
            pts += [np.column_stack([x0 + A * sx, np.full(A.size, y0), B * h]), np.column_stack([x0 + A * sx, np.full(A.size, y0 + sy), B * h])]
        else:
            pts += [np.column_stack([np.full(A.size, x0), y0 + A * sy, B * h]), np.column_stack([np.full(A.size, x0 + sx), y0 + A * sy, B * h])]
    A, B = np.meshgrid(u, v)
    pts.append(np.column_stack([x0 + A.ravel() * sx, y0 + B.ravel() * sy, np.full(A.size, h)]))
    p = np.concatenate(pts)
    p[:, 2] += 0.02 * p[:, 0] + 0.01 * p[:, 1]  # on the sloping ground
    return p + rng.normal(0, 0.002, p.shape)


def nrm(las):
    return np.column_stack([las.NormalX, las.NormalY, las.NormalZ])


def interleave(a, b, seed=2):
    """Rows of a and b mixed in a random order; returns the mixed rows and which came from b."""
    from_b = np.zeros(len(a) + len(b), dtype=bool)
    from_b[np.random.default_rng(seed).choice(from_b.size, len(b), replace=False)] = True
    out = np.empty((from_b.size, 3))
    out[~from_b], out[from_b] = a, b
    return out, from_b


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """Ground (class 2) with a box (class 6); the same ground alone; ground with noise above it (class 7); with
    withheld points there instead."""
    d = tmp_path_factory.mktemp("classes")
    g = ground()
    pts, is_box = interleave(g, box())
    write_las(d / "with_box.las", pts, np.where(is_box, 6, 2))
    write_las(d / "ground.las", g, np.full(len(g), 2))
    rng = np.random.default_rng(3)
    birds = np.column_stack([rng.uniform(4, 28, 60), rng.uniform(4, 28, 60), rng.uniform(0.3, 1.0, 60)])
    birds[:, 2] += 0.02 * birds[:, 0] + 0.01 * birds[:, 1]
    pts, is_bird = interleave(g, birds, seed=4)
    write_las(d / "noisy.las", pts, np.where(is_bird, 7, 2))
    write_las(d / "withheld.las", pts, np.full(len(pts), 2), withheld=is_bird)
    return d, is_box, is_bird


def run(*args):
    r = CliRunner().invoke(main, [str(a) for a in args])
    assert r.exit_code == 0, r.output + str(r.exception)
    return r


def test_classes_compute_only_those_classes_and_the_others_get_the_empty_value(scenes, tmp_path):
    d, is_box, _ = scenes
    run("normals", d / "with_box.las", tmp_path / "sel.las", "--classes", "2", "--tile-size", "16", "-q")
    run("normals", d / "ground.las", tmp_path / "alone.las", "--tile-size", "16", "-q")
    run("normals", d / "with_box.las", tmp_path / "all.las", "--tile-size", "16", "-q")
    sel, alone, every = (laspy.read(tmp_path / f) for f in ("sel.las", "alone.las", "all.las"))
    src = laspy.read(d / "with_box.las")
    size = src.points.array.dtype.itemsize
    assert len(sel.points) == len(is_box)  # every input point once, in order, every byte of its record
    assert np.array_equal(sel.points.array.view(np.uint8).reshape(len(is_box), -1)[:, :size],
                          src.points.array.view(np.uint8).reshape(len(is_box), size))
    # the box: no normal, the documented empty value
    assert np.all(sel.NormalMethod[is_box] == 0) and np.all(nrm(sel)[is_box] == 0)
    assert np.all(sel.Curvature[is_box] == 0) and np.all(sel.PatchId[is_box] == NO_PATCH)
    # the ground: exactly the normals of a run on the ground alone (it never saw the box)
    assert np.all(sel.NormalMethod[~is_box] > 0)
    assert np.array_equal(nrm(sel)[~is_box], nrm(alone))
    assert np.array_equal(np.asarray(sel.Curvature)[~is_box], np.asarray(alone.Curvature))
    # ... whereas with every class, the ground beside the walls sees the box
    assert not np.array_equal(nrm(every)[~is_box], nrm(alone))
    assert np.all(every.NormalMethod > 0)


def test_the_summary_and_the_store_say_what_was_left_out(scenes, tmp_path):
    d, is_box, _ = scenes
    s = normals(d / "with_box.las", tmp_path / "o.las", classes=[2], quiet=True, store=str(tmp_path / "s.zarr"))
    assert s.left_out == {"classes": int(is_box.sum()), "noise": 0, "withheld": 0}
    assert f"left out        {int(is_box.sum()):,}" in s.format() and "not of classes 2" in s.format()
    r = run("info", tmp_path / "s.zarr")
    assert "classes 2; noise (classes 7, 18) and withheld points left out" in r.output
    assert f"classes {int(is_box.sum()):,}" in r.output


def test_noise_is_left_out_by_default_and_kept_with_keep_noise(scenes, tmp_path):
    d, _, is_bird = scenes
    run("normals", d / "noisy.las", tmp_path / "default.las", "--tile-size", "16", "-q")
    run("normals", d / "noisy.las", tmp_path / "kept.las", "--tile-size", "16", "--keep-noise", "-q")
    run("normals", d / "ground.las", tmp_path / "clean.las", "--tile-size", "16", "-q")
    default, kept, clean = (laspy.read(tmp_path / f) for f in ("default.las", "kept.las", "clean.las"))
    assert np.all(default.NormalMethod[is_bird] == 0) and np.all(nrm(default)[is_bird] == 0)
    assert np.array_equal(nrm(default)[~is_bird], nrm(clean))  # the plane's normals as without the noise
    assert np.all(kept.NormalMethod > 0)  # kept: the noise points have normals, and take part in the plane's
    assert not np.array_equal(nrm(kept)[~is_bird], nrm(clean))


def test_withheld_points_are_left_out_by_default_and_kept_with_keep_noise(scenes, tmp_path):
    d, _, is_bird = scenes
    s = normals(d / "withheld.las", tmp_path / "default.las", tile_size=16, quiet=True)
    assert s.left_out == {"classes": 0, "noise": 0, "withheld": int(is_bird.sum())}
    normals(d / "withheld.las", tmp_path / "kept.las", tile_size=16, keep_noise=True, quiet=True)
    run("normals", d / "ground.las", tmp_path / "clean.las", "--tile-size", "16", "-q")
    default, kept, clean = (laspy.read(tmp_path / f) for f in ("default.las", "kept.las", "clean.las"))
    assert np.all(default.NormalMethod[is_bird] == 0)
    assert np.array_equal(nrm(default)[~is_bird], nrm(clean))
    assert np.all(kept.NormalMethod > 0)


def test_a_noise_class_named_in_classes_is_kept(scenes, tmp_path):
    d, _, is_bird = scenes
    s = normals(d / "noisy.las", tmp_path / "o.las", classes="2,7", tile_size=16, quiet=True)
    assert sum(s.left_out.values()) == 0
    assert np.all(laspy.read(tmp_path / "o.las").NormalMethod > 0)


def test_a_store_is_reused_only_with_the_same_selection(scenes, tmp_path):
    d, _, is_bird = scenes
    store = str(tmp_path / "s.zarr")
    normals(d / "noisy.las", tmp_path / "a.las", tile_size=16, quiet=True, store=store)
    normals(d / "noisy.las", tmp_path / "b.las", tile_size=16, quiet=True, store=store, keep_noise=True)
    normals(d / "noisy.las", tmp_path / "c.las", tile_size=16, quiet=True, keep_noise=True)
    a, b = laspy.read(tmp_path / "a.las"), laspy.read(tmp_path / "b.las")
    assert np.all(a.NormalMethod[is_bird] == 0) and np.all(b.NormalMethod > 0)
    assert (tmp_path / "b.las").read_bytes() == (tmp_path / "c.las").read_bytes()


def test_a_store_of_another_kind_of_job_is_refused_not_tiled_again(scenes, tmp_path):
    # compress tiles every point, normals leaves noise out: compress given normals' store (or the reverse) would tile it
    # again, taking normals' tiles and records with it, though nothing new was asked (review M): one line, nothing touched
    from patchcloud.core import PatchcloudValueError
    from patchcloud.stream import Store, compress

    d, _, _ = scenes
    store = str(tmp_path / "s.zarr")
    normals(d / "noisy.las", tmp_path / "a.las", tile_size=16, quiet=True, store=store)
    before = Store.open(store).attrs["selection"]
    with pytest.raises(PatchcloudValueError, match=r"s.zarr: its tiles hold every class; noise .* left out .*compress tiles "
                                                   r"every point: one store holds one tiling"):
        compress(d / "noisy.las", tmp_path / "c.pcz", max_error=0.05, quiet=True, store=store)
    assert not (tmp_path / "c.pcz").exists() and Store.open(store).attrs["selection"] == before
    normals(d / "noisy.las", tmp_path / "a.las", tile_size=16, quiet=True, store=store)  # still its own: no --overwrite
    other = str(tmp_path / "t.zarr")
    compress(d / "noisy.las", tmp_path / "c.pcz", max_error=0.05, quiet=True, store=other, keep_store=True)
    with pytest.raises(PatchcloudValueError, match="normals tiles every class; noise"):
        normals(d / "noisy.las", tmp_path / "b.las", tile_size=16, quiet=True, store=other)
    normals(d / "noisy.las", tmp_path / "b.las", tile_size=16, quiet=True, store=other, keep_noise=True)  # the same tiles


def test_in_memory_and_on_disk_give_the_same_bytes_with_a_selection(scenes, tmp_path):
    d, _, _ = scenes
    for mode in (True, False):
        normals(d / "with_box.las", tmp_path / f"{mode}.laz", classes=(2,), tile_size=16, quiet=True, in_memory=mode)
    assert (tmp_path / "True.laz").read_bytes() == (tmp_path / "False.laz").read_bytes()


def test_don_and_segment_leave_the_other_classes_out(scenes, tmp_path):
    d, is_box, _ = scenes
    s = don(d / "with_box.las", tmp_path / "d.las", r_small=0.5, r_large=2.0, classes=[6], quiet=True)
    out = laspy.read(tmp_path / "d.las")
    assert np.all(np.asarray(out.DoN)[~is_box] == 0) and np.any(np.asarray(out.DoN)[is_box] > 0)
    assert s.defined <= int(is_box.sum()) and s.left_out["classes"] == int((~is_box).sum())
    segment(d / "with_box.las", tmp_path / "s.las", r_small=0.5, r_large=2.0, threshold=0.01, tolerance=0.5, min_points=5,
            classes=[6], quiet=True)
    out = laspy.read(tmp_path / "s.las")
    assert np.all(np.asarray(out.ClusterID)[~is_box] == 0) and np.any(np.asarray(out.ClusterID)[is_box] > 0)


def test_compress_models_only_the_selection_and_keeps_the_others_as_residual_points(scenes, tmp_path):
    d, is_box, _ = scenes
    s = compress(d / "with_box.las", tmp_path / "c.pcz", classes=[2], max_error=0.02, quiet=True)
    assert s.left_out == {"classes": int(is_box.sum()), "noise": 0, "withheld": 0}
    assert s.residual >= int(is_box.sum())
    decompress(tmp_path / "c.pcz", tmp_path / "back.las")
    back = laspy.read(tmp_path / "back.las")
    residual = np.asarray(back.Reconstructed) == 0
    src = laspy.read(d / "with_box.las")
    k = coarse_steps(0.02, src.header.scales)
    assert max(k) > 1  # the budget is coarser than the file's grid: the residual points are rounded to multiples of k
    box = np.column_stack([refine(coarsen(v, k[a]), k[a]) for a, v in enumerate((src.X, src.Y, src.Z))])[is_box]
    box_xyz = {tuple(r) for r in box.tolist()}
    got = {tuple(r) for r in np.column_stack([back.X, back.Y, back.Z])[residual & (np.asarray(back.classification) == 6)].tolist()}
    assert got == box_xyz  # every box point as a residual point, on the coarser grid (within the budget)
    assert np.all(np.asarray(back.classification)[~residual] == 2)  # the models are the ground's


def test_catalog_runs_apply_the_selection_to_every_file(scenes, tmp_path):
    d, _, is_bird = scenes
    cat = tmp_path / "cat"
    cat.mkdir()
    for name in ("noisy.las", "withheld.las"):
        (cat / name).write_bytes((d / name).read_bytes())
    s = normals(str(cat), out_dir=str(tmp_path / "out"), tile_size=16, quiet=True)
    assert s.left_out == {"classes": 0, "noise": int(is_bird.sum()), "withheld": int(is_bird.sum())}
    for name in ("noisy.las", "withheld.las"):
        out = laspy.read(tmp_path / "out" / name)
        assert np.all(out.NormalMethod[is_bird] == 0) and np.all(out.NormalMethod[~is_bird] > 0)


def test_always_up_flips_each_normal_to_plus_z_point_by_point(tmp_path):
    run("normals", SAMPLE, tmp_path / "d.laz", "-q", "--principal-curvatures")
    run("normals", SAMPLE, tmp_path / "u.laz", "-q", "--principal-curvatures", "--always-up")
    a, b = laspy.read(tmp_path / "d.laz"), laspy.read(tmp_path / "u.laz")
    na, nb = nrm(a), nrm(b)
    down = na[:, 2] < 0
    assert down.sum() > 100  # the default (--orient up, by patch groups) leaves some normals pointing down
    assert np.all(nb[:, 2] >= 0)
    assert np.array_equal(nb[down], -na[down]) and np.array_equal(nb[~down], na[~down])
    # the principal curvatures follow the side: (k1, k2) -> (-k2, -k1)
    k_a = np.column_stack([a.PrincipalCurvature1, a.PrincipalCurvature2])
    k_b = np.column_stack([b.PrincipalCurvature1, b.PrincipalCurvature2])
    assert np.array_equal(k_b[down], -k_a[down][:, ::-1]) and np.array_equal(k_b[~down], k_a[~down])
    assert np.array_equal(np.asarray(a.Curvature), np.asarray(b.Curvature))


def test_fallback_knn_changes_the_k_nn_fallback_normals_only(tmp_path):
    run("normals", SAMPLE, tmp_path / "16.laz", "-q")
    r = run("normals", SAMPLE, tmp_path / "8.laz", "--fallback-knn", "8")
    assert "fallback k-NN 8" in r.output
    a, b = laspy.read(tmp_path / "16.laz"), laspy.read(tmp_path / "8.laz")
    knn = np.asarray(a.NormalMethod) == 3
    assert np.array_equal(np.asarray(a.NormalMethod), np.asarray(b.NormalMethod))
    assert np.array_equal(nrm(a)[~knn], nrm(b)[~knn])
    assert np.mean(np.any(nrm(a)[knn] != nrm(b)[knn], axis=1)) > 0.5


def test_knn_is_not_an_option_with_another_meaning():
    r = CliRunner().invoke(main, ["normals", "--help"])
    assert "--fallback-knn" in r.output and "--knn " not in r.output and "--always-up" in r.output


@pytest.mark.parametrize("value, says", [("abc", "'abc' is not a class"), ("300", "300 is not a class"), ("2,,6", "'' is not a class")])
def test_bad_classes_are_one_error_line_listing_valid_values(value, says, tmp_path):
    r = CliRunner().invoke(main, ["normals", str(SAMPLE), str(tmp_path / "o.las"), "--classes", value])
    assert r.exit_code == 2
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"error: --classes {value}: ") and says in lines[0], r.stderr
    assert "valid: classification codes 0 to 255" in lines[0]
    assert not (tmp_path / "o.las").exists()


def test_a_selection_that_leaves_nothing_is_one_clear_error(tmp_path):
    with pytest.raises(PatchcloudValueError, match="no point left to compute on .*class 2: 22,343"):
        normals(SAMPLE, tmp_path / "o.las", classes=[9], quiet=True)
    assert not (tmp_path / "o.las").exists()
    with pytest.raises(PatchcloudValueError, match="keep_noise must be True or False"):
        RunOptions(keep_noise="yes")
    # on disk: the same command would find no point again, so the line does not say it resumes, and no store is left
    with pytest.raises(PatchcloudValueError, match="no point left to compute on") as info:
        normals(SAMPLE, tmp_path / "o.las", classes=[9], quiet=True, scheduler="synchronous")
    assert "resumes" not in str(info.value) and not (tmp_path / "o.las.store").exists()


def test_info_lists_classes_and_patchcloud_dims(scenes, tmp_path):
    d, is_box, _ = scenes
    r = run("info", d / "with_box.las")
    assert "  patchcloud   no patchcloud dimensions" in r.output
    rows = {tuple(ln.split()[-4:-1]) for ln in r.output.splitlines()}
    assert ("2", "ground", f"{int((~is_box).sum()):,}") in rows and ("6", "building", f"{int(is_box.sum()):,}") in rows
    normals(d / "with_box.las", tmp_path / "n.las", classes=[2], principal_curvatures=True, quiet=True)
    r = run("info", tmp_path / "n.las")
    assert ("patchcloud   normals: NormalX, NormalY, NormalZ, Curvature, NormalMethod, PatchId; normals --principal-curvatures: "
            "PrincipalCurvature1, PrincipalCurvature2, PrincipalDirectionX, PrincipalDirectionY, PrincipalDirectionZ") in r.output
    r = run("info", d / "withheld.las", "--json")
    assert '"withheld": 60' in r.output
