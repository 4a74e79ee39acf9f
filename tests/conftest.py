import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))  # the synthetic-surface generators live in tools/

SHARED = ROOT.parent / "shared" / "data"


def angles_deg(a, b, signed=False):
    """Angle between rows of a and b in degrees (sign-insensitive unless signed)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    cos = np.einsum("ij,ij->i", a, b) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    if not signed:
        cos = np.abs(cos)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(scope="module")
def small_pcz(tmp_path_factory):
    """A model-mode .pcz of a 20,000-point scene (its LAS beside it, ``scene.las``): 5 cm, tiles of 16 m."""
    from test_stream import write_scene

    from patchcloud.stream import compress

    d = tmp_path_factory.mktemp("pcz")
    write_scene(d / "scene.las", n=20_000, seed=5)
    compress(d / "scene.las", d / "scene.pcz", max_error=0.05, tile_size=16, quiet=True)
    return d / "scene.pcz"


def shared_file(rel: str) -> Path:
    path = SHARED / rel
    if not path.exists():
        pytest.skip(f"shared data file {rel} not found beside the repo (../shared/data); this test needs it")
    return path


def flat_las(point_format: int = 6, version: str = "1.4", extra=(), n: int = 2000, seed: int = 0):
    """A laspy.LasData of ``n`` points on a noisy 20 m x 20 m plane (1 cm grid, offset 0), one return each, with the
    extra-bytes dimensions ``extra`` (laspy.ExtraBytesParams) zero: for tests of what the jobs write of a file's fields."""
    import laspy

    h = laspy.LasHeader(point_format=point_format, version=version)
    h.scales, h.offsets = [0.01] * 3, [0.0] * 3
    if extra:
        h.add_extra_dims(list(extra))
    rng = np.random.default_rng(seed)
    las = laspy.LasData(h)
    las.points = laspy.ScaleAwarePointRecord.zeros(n, header=h)
    las.x, las.y, las.z = rng.uniform(0, 20, n), rng.uniform(0, 20, n), rng.normal(0, 0.01, n)
    las.return_number, las.number_of_returns = np.ones(n, int), np.ones(n, int)
    return las
