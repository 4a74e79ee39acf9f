"""Write real ``.pcz`` files of an older format version with the patchcloud that wrote that version, and what it decoded.

    git worktree add /tmp/v2 5649a68          # the commit before the format's next version (see VERSIONS)
    python tools/make_old_pcz.py /tmp/v2 tests/data/old-pcz

For a patchcloud checkout at ``CHECKOUT`` (its ``core/`` and ``stream/``),
this writes, into ``FOLDER``: the small synthetic input (:func:`scene`,
made here, the same bytes whatever the version), its ``.pcz`` in model mode
and, where that version has it, points mode (``compress --keep-points``),
both at :data:`BUDGET`, by that checkout's ``compress``; then decompresses
each with that checkout's ``decompress`` and records, in
``pcz-vN.json``, digests of the decoded points' arrays (X, Y, Z,
classification, intensity, return numbers and, points mode, GPS time) and
their count.  tests/test_pcz.py decompresses the committed files with the
current patchcloud and compares: a version-N file decodes to the points
the version that wrote it decoded.  (tools/make_pcz_fixture.py writes a
file of the current version field by field; its header is a stand-in, so
only this one's files go through ``decompress`` whole.)
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import laspy
import numpy as np

#: The commit that last wrote each older version (the one before the next version's commit).
VERSIONS = {2: "5649a68", 3: "c8a4137", 4: "083a899"}
#: The error budget of the fixtures (metres).
BUDGET = 0.02
#: The arrays digested, per mode.
FIELDS = {"model": ("X", "Y", "Z", "classification", "intensity", "return_number", "number_of_returns"),
          "points": ("X", "Y", "Z", "classification", "intensity", "return_number", "number_of_returns", "gps_time")}


def scene(path: Path) -> Path:
    """A 12 x 12 m tilted roof beside flat ground, a few bushes: 4,000 points, point format 1, centimetre steps."""
    rng = np.random.default_rng(20261128)
    n = 4000
    x, y = rng.uniform(0.0, 12.0, n), rng.uniform(0.0, 12.0, n)
    roof = x > 6.0
    z = np.where(roof, 3.0 + 0.4 * (x - 6.0), 0.02 * y) + rng.normal(0.0, 0.003, n)
    bush = rng.random(n) < 0.08
    z[bush] += rng.uniform(0.1, 1.5, bush.sum())
    h = laspy.LasHeader(point_format=1, version="1.2")
    h.scales, h.offsets = np.array([0.001, 0.001, 0.001]), np.array([600000.0, 5000000.0, 0.0])
    las = laspy.LasData(h)
    las.x, las.y, las.z = 600000.0 + x, 5000000.0 + y, 100.0 + z
    las.classification = np.where(bush, 3, np.where(roof, 6, 2)).astype(np.uint8)
    las.intensity = rng.integers(0, 4000, n).astype(np.uint16)
    las.return_number = np.ones(n, np.uint8)
    las.number_of_returns = np.ones(n, np.uint8)
    las.gps_time = np.sort(rng.uniform(1.0e5, 1.0e5 + 60.0, n))
    las.write(str(path))
    return path


def digests(path: Path, mode: str) -> dict:
    """The decoded file's point count and a SHA-256 of each of :data:`FIELDS`' arrays (little-endian bytes)."""
    las = laspy.read(str(path))
    out = {"points": int(las.header.point_count)}
    for f in FIELDS[mode]:
        out[f] = hashlib.sha256(np.ascontiguousarray(np.asarray(las[f])).astype(np.asarray(las[f]).dtype.newbyteorder("<")).tobytes()).hexdigest()
    return out


def _package(checkout: Path, into: Path) -> Path:
    """A ``patchcloud`` package folder for ``checkout`` (as pip's editable install maps it), importable from ``into``."""
    pkg = into / "patchcloud"
    pkg.mkdir(parents=True)
    for f in (checkout / "stream" / "patchcloud").iterdir():
        if f.is_file():
            shutil.copy(f, pkg / f.name)
    (pkg / "core").symlink_to(checkout / "core")
    (pkg / "stream").symlink_to(checkout / "stream")
    return into


def _run(path_entry: Path, *args: str) -> None:
    env = dict(os.environ, PYTHONPATH=str(path_entry), PATCHCLOUD_CRS_CACHE="0")
    subprocess.run([sys.executable, "-m", "patchcloud.stream.cli", *args], check=True, env=env)  # (older ones have no console)


def main(checkout: Path, folder: Path) -> None:
    version = int(next(line.split("=")[1] for line in (checkout / "stream" / "io" / "pcz.py").read_text().splitlines()
                       if line.startswith("VERSION =")))
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        entry = _package(checkout, tmp / "path")
        src = scene(tmp / "scene.las")
        record = {"version": version, "budget": BUDGET, "files": {}}
        modes = ["model"] + (["points"] if version >= 3 else [])
        for mode in modes:
            name = f"pcz-v{version}-{mode}.pcz"
            _run(entry, "compress", str(src), str(folder / name), "--max-error", str(BUDGET), "--units", "m", "--overwrite", "-q",
                 *(["--keep-points"] if mode == "points" else []))
            _run(entry, "decompress", str(folder / name), str(tmp / f"{mode}.las"), "-q")
            record["files"][name] = dict(mode=mode, **digests(tmp / f"{mode}.las", mode))
        (folder / f"pcz-v{version}.json").write_text(json.dumps(record, indent=1) + "\n")
    print(f"wrote version {version}: {', '.join(record['files'])}")


if __name__ == "__main__":
    main(Path(sys.argv[1]).resolve(), Path(sys.argv[2]))
