"""``normals --principal-curvatures``: k1 >= k2 and k1's direction, against analytic surfaces, at several tile sizes."""

import laspy
import numpy as np
import pytest
from click.testing import CliRunner

from patchcloud.stream import normals
from patchcloud.stream.cli import main
from patchcloud.stream.io.dims import PRINCIPAL_DIMS

OFFSET = np.array([650000.0, 6860000.0, 40.0])
R = 20.0  # the dome's radius (m): k1 = k2 = +1/R with normals up (outward)
A = 25.0  # the saddle z = (x^2 - y^2) / (2A): at the top, k1 = +1/A along y, k2 = -1/A along x


def write_surface(path, z_of, n=40_000, half=10.0, seed=0):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-half, half, (n, 2))
    pts = np.column_stack([xy, z_of(xy[:, 0], xy[:, 1])]) + OFFSET
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.0001] * 3)
    header.offsets = OFFSET
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    las.write(str(path))
    return pts - OFFSET


@pytest.fixture(scope="module")
def surfaces(tmp_path_factory):
    d = tmp_path_factory.mktemp("principal")
    dome = write_surface(d / "dome.las", lambda x, y: np.sqrt(R**2 - x**2 - y**2))
    saddle = write_surface(d / "saddle.las", lambda x, y: (x**2 - y**2) / (2 * A), seed=1)
    return d, dome, saddle


def read(path):
    las = laspy.read(str(path))
    k = np.column_stack([las.PrincipalCurvature1, las.PrincipalCurvature2]).astype(np.float64)
    d = np.column_stack([las.PrincipalDirectionX, las.PrincipalDirectionY, las.PrincipalDirectionZ]).astype(np.float64)
    n = np.column_stack([las.NormalX, las.NormalY, las.NormalZ]).astype(np.float64)
    return k, d, n, np.asarray(las.NormalMethod)


@pytest.mark.parametrize("tile_size", [4.0, 8.0, 32.0])
def test_a_dome_has_k1_equal_k2_equal_one_over_its_radius_at_every_tile_size(surfaces, tmp_path, tile_size):
    d, dome, _ = surfaces
    out = tmp_path / "dome_pc.las"
    normals(d / "dome.las", out, principal_curvatures=True, tile_size=tile_size, scheduler="synchronous", quiet=True)
    k, direction, n, method = read(out)
    assert np.isfinite(k).all() and np.isfinite(direction).all()
    assert np.all(k[:, 0] >= k[:, 1])
    quad = np.isin(method, (1, 2))
    assert quad.mean() > 0.9
    assert abs(np.median(k[quad, 0]) - 1 / R) < 0.1 / R and abs(np.median(k[quad, 1]) - 1 / R) < 0.1 / R
    set_ = np.linalg.norm(direction, axis=1) > 0
    assert np.allclose(np.linalg.norm(direction[set_], axis=1), 1, atol=1e-3)
    assert np.percentile(np.abs(np.sum(direction[set_] * n[set_], axis=1)), 99) < 1e-2  # tangent to the surface


def test_a_saddle_has_opposite_curvatures_and_k1_along_y(surfaces, tmp_path):
    d, _, saddle = surfaces
    r = CliRunner().invoke(main, ["normals", str(d / "saddle.las"), str(tmp_path / "s.las"), "--principal-curvatures",
                                  "--tile-size", "8", "--on-disk", "--scheduler", "synchronous", "-q"])
    assert r.exit_code == 0, r.output
    k, direction, n, method = read(tmp_path / "s.las")
    top = (np.linalg.norm(saddle[:, :2], axis=1) < 2.0) & np.isin(method, (1, 2))
    assert top.sum() > 500
    assert abs(np.median(k[top, 0]) - 1 / A) < 0.1 / A and abs(np.median(k[top, 1]) + 1 / A) < 0.1 / A
    assert np.median(np.abs(direction[top, 1])) > 0.99  # k1's direction: along y, where k1 != k2


def test_without_the_option_the_output_has_no_principal_dims(surfaces, tmp_path):
    d, _, _ = surfaces
    normals(d / "dome.las", tmp_path / "plain.las", quiet=True)
    dims = set(laspy.read(str(tmp_path / "plain.las")).point_format.dimension_names)
    assert "NormalX" in dims and not dims & {name for name, *_ in PRINCIPAL_DIMS}


def test_in_memory_and_on_disk_write_the_same_principal_curvatures(surfaces, tmp_path):
    d, _, _ = surfaces
    normals(d / "saddle.las", tmp_path / "mem.las", principal_curvatures=True, tile_size=8, in_memory=True, quiet=True)
    normals(d / "saddle.las", tmp_path / "disk.las", principal_curvatures=True, tile_size=8, in_memory=False,
            scheduler="synchronous", quiet=True)
    a, b = laspy.read(str(tmp_path / "mem.las")), laspy.read(str(tmp_path / "disk.las"))
    for name, *_ in PRINCIPAL_DIMS:
        assert np.array_equal(np.asarray(a[name]), np.asarray(b[name])), name


@pytest.mark.slow  # 10-20 s: with the slow marker, so the default suite stays under 10 minutes
def test_asking_for_them_on_a_kept_store_redoes_the_finish_only(surfaces, tmp_path, monkeypatch):
    from patchcloud.stream.jobs import normals_tiles

    d, _, _ = surfaces
    run = dict(tile_size=8, scheduler="synchronous", store=str(tmp_path / "s.zarr"), quiet=True)
    normals(d / "saddle.las", tmp_path / "plain.las", **run)

    def no_fit(*args, **kwargs):
        raise AssertionError("the fit does not depend on the principal curvatures")

    monkeypatch.setattr(normals_tiles, "fit_one_tile", no_fit)
    normals(d / "saddle.las", tmp_path / "kept.las", principal_curvatures=True, **run)
    monkeypatch.undo()
    normals(d / "saddle.las", tmp_path / "fresh.las", principal_curvatures=True, tile_size=8, in_memory=False,
            scheduler="synchronous", quiet=True)
    a, b = laspy.read(str(tmp_path / "kept.las")), laspy.read(str(tmp_path / "fresh.las"))
    for name, *_ in PRINCIPAL_DIMS:
        assert np.array_equal(np.asarray(a[name]), np.asarray(b[name])), name
