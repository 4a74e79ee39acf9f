"""Write the committed ``.pcz`` fixture of tests/test_pcz.py: a small file of this version and what it holds.

    python tools/make_pcz_fixture.py        # writes tests/data/pcz-v{VERSION}.pcz and .npz

The ``.npz`` holds every field of every tile as the writer was given it
(numpy arrays, no pickle); the test reads the ``.pcz`` back with the
current reader and compares field by field, so a change that makes files
of this version read differently fails, whatever the fitting does later.
Run it once per format version, and commit both files.
"""

from __future__ import annotations

import sys
from pathlib import Path

import laspy
import numpy as np

from patchcloud.core.patchmodel import fit_models, quantise_models
from patchcloud.stream.io import pcz
from patchcloud.stream.io.laz_block import records_laz
from patchcloud.stream.io.residual_points import octree_block

BUDGET = 0.01
T = 4.0
#: The residual points' X, Y, Z as stored are the input's divided by these (version 3; the reader multiplies them back).
STEPS = (2, 2, 3)
DROPPED = ["gps_time"]
#: The input's point format (version 4 stores records of formats 0-3 as 6 or 7: stream.io.layered) and its record size.
POINT_FORMAT = 1
RECORD = laspy.PointFormat(POINT_FORMAT).size
#: A stand-in for the input's header: the reader reads only its point format (byte 104).
HEADER = b"LASF" + bytes(100) + bytes([POINT_FORMAT]) + bytes(270)
#: Per tile, the residual intensities are stored divided by 2**shift (version 5; the reader multiplies them back).
SHIFTS = (0, 3)
FIELDS = ("scale", "centroid", "rotation", "coeffs", "rmse", "cells", "level", "ijk", "count", "extent", "mask")


def parts(rng: np.random.Generator) -> list[pcz.TilePart]:
    """Two 4 m tiles: a tilted plane with spikes, and a box corner; residual records of random bytes (version 5: the
    second tile's as an octree, of the fields it holds)."""
    out = []
    for t, ijk in enumerate([(0, 0, 0), (1, 0, 0)]):
        corner = np.asarray(ijk, float) * T
        if t == 0:
            xy = rng.uniform(0.01, T - 0.01, (1500, 2))
            p = np.column_stack([xy, 0.1 * xy[:, 0] + 1.0])
        else:
            p = rng.uniform(0.5, 3.5, (1500, 3))
            p[np.arange(1500), rng.integers(0, 3, 1500)] = 0.5
        p = corner + p
        p[:10, 2] += 0.3  # spikes: residual
        fit = fit_models(p, BUDGET, root=(corner, T))
        q = quantise_models(fit.models, BUDGET)
        C, R = q.count.shape[0], fit.residual.size
        xyz = np.rint(p[fit.residual] / 0.001).astype("<i4")
        if t == 1 and pcz.VERSION >= 5:  # an octree block (version 5): the records it holds, class, intensity, 1 of 1
            pf = laspy.PointFormat(POINT_FORMAT)
            rec = laspy.PackedPointRecord.zeros(R, pf)
            rec["X"], rec["Y"], rec["Z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
            rec["classification"] = rng.integers(0, 32, R).astype(np.uint8)
            rec["intensity"] = rng.integers(0, 200, R).astype(np.uint16)  # levels past 126: escaped
            rec["return_number"] = rec["number_of_returns"] = np.ones(R, np.uint8)
            records = np.ascontiguousarray(rec.array).view(np.uint8).reshape(R, RECORD)
            laz = octree_block(records, pf, True)
        else:
            records = np.hstack([xyz.view(np.uint8).reshape(R, 12), rng.integers(0, 256, (R, RECORD - 12)).astype(np.uint8)])
            laz = records_laz(records, laspy.PointFormat(POINT_FORMAT), "1.2", [0.001] * 3, [0.0] * 3)
        out.append(pcz.TilePart(ijk, q, rng.integers(1, 7, C).astype(np.uint8),
                                rng.integers(0, 60000, C).astype(np.uint16), R, laz, intensity_shift=SHIFTS[t]))
        out[-1].__dict__["records"] = records
    return out


def main(folder: Path) -> None:
    ps = parts(np.random.default_rng(2026))
    grid = dict(origin=[0.0, 0.0, 0.0], tile_size=T, scale=[0.001] * 3, offset=[0.0] * 3)
    name = folder / f"pcz-v{pcz.VERSION}"
    pcz.write_pcz(name.with_suffix(".pcz"), ps, max_error=BUDGET, grid=grid, header=HEADER,
                  source={"path": "fixture.las"}, record_bytes=RECORD - 12, overwrite=True, steps=STEPS, dropped=DROPPED)
    arrays = {"steps": np.asarray(STEPS), "shifts": np.asarray(SHIFTS)}
    for t, part in enumerate(ps):
        for f in FIELDS:
            arrays[f"{t}/{f}"] = np.asarray(getattr(part.models, f))
        arrays[f"{t}/classification"] = part.classification
        arrays[f"{t}/intensity"] = part.intensity
        arrays[f"{t}/records"] = part.records
    np.savez_compressed(name.with_suffix(".npz"), **arrays)
    print(f"wrote {name}.pcz and {name}.npz")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[1] / "tests" / "data")
