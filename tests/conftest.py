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


def shared_file(rel: str) -> Path:
    path = SHARED / rel
    if not path.exists():
        pytest.skip(f"shared data file {rel} not found beside the repo (../shared/data); this test needs it")
    return path
