"""The .pcz patch-model file: written tile by tile, read back field by field, and refused when it is not one."""

import io
import zipfile

import laspy
import numpy as np
import pytest

from patchcloud.core.errors import PatchcloudIOError
from patchcloud.core.patchmodel import dequantise_models, fit_models, quantise_models, sample_models
from patchcloud.stream.io import pcz
from patchcloud.stream.io.laz_block import records_laz

BUDGET = 0.01
T = 8.0


def parts(rng, record_bytes=18):
    """Two 8 m tiles: a tilted plane with a few spikes, and a sphere cap; residual records of random bytes."""
    out = []
    for t, ijk in enumerate([(0, 0, 0), (1, 0, 0)]):
        corner = np.asarray(ijk, float) * T
        xy = rng.uniform(0.01, T - 0.01, (6000, 2))
        z = 0.1 * xy[:, 0] + 1.0 if t == 0 else 4.0 - 0.05 * ((xy[:, 0] - 4) ** 2 + (xy[:, 1] - 4) ** 2)
        p = corner + np.column_stack([xy, z])
        p[:25, 2] += 0.5  # spikes: residual
        fit = fit_models(p, BUDGET, root=(corner, T))
        q = quantise_models(fit.models, BUDGET)
        C, R = q.count.shape[0], fit.residual.size
        xyz = np.rint(p[fit.residual] / 0.001).astype("<i4")
        records = np.hstack([xyz.view(np.uint8).reshape(R, 12), rng.integers(0, 256, (R, record_bytes)).astype(np.uint8)])
        laz = records_laz(records, laspy.PointFormat(6), "1.4", [0.001] * 3, [0.0] * 3)
        out.append(pcz.TilePart(ijk, q, rng.integers(1, 7, C).astype(np.uint8), rng.integers(0, 60000, C).astype(np.uint16),
                                R, laz))
        out[-1].__dict__["records"] = records  # what the file must give back (a test-only note on the frozen part)
    return out


#: A stand-in for the input's header: only its point format (byte 104) is read, to tell how the records are stored.
HEADER = b"LASF" + bytes(100) + bytes([6]) + bytes(270)


def write(tmp_path, rng, name="c.pcz", **kw):
    ps = parts(rng)
    grid = dict(origin=[0.0, 0.0, 0.0], tile_size=T, scale=[0.001] * 3, offset=[0.0] * 3)
    counts = pcz.write_pcz(tmp_path / name, ps, max_error=BUDGET, grid=grid, header=HEADER,
                           source={"path": "x.las"}, record_bytes=18, **kw)
    return ps, counts


def test_written_file_reads_back_field_by_field(tmp_path, rng, monkeypatch):
    monkeypatch.setattr(pcz, "CHUNK", 64)  # several chunks per array, flushed across tiles
    monkeypatch.setattr(pcz, "LAZ_CHUNK", 64)  # the residual LAZ bytes too
    ps, counts = write(tmp_path, rng)
    assert counts["points"] == 12000 and counts["residual"] >= 50
    with pcz.open_pcz(tmp_path / "c.pcz") as f:
        assert f.max_error == BUDGET and f.header_bytes[:4] == b"LASF"
        assert [tuple(t) for t in f.tiles] == [(0, 0, 0), (1, 0, 0)]
        for t, part in enumerate(ps):
            m, cls, inten = f.patches(t)
            assert len(m) >= 1 and m.count.shape[0] >= len(m)
            for name in ("scale", "centroid", "rotation", "coeffs", "rmse", "cells", "level", "ijk", "count", "extent", "mask"):
                assert np.array_equal(getattr(m, name), getattr(part.models, name)), name
            assert np.array_equal(m.root_corner, part.models.root_corner) and m.root_edge == part.models.root_edge
            assert np.array_equal(cls, part.classification) and np.array_equal(inten, part.intensity)
            xyz, rec = f.residual(t)
            assert np.array_equal(xyz.view(np.uint8).reshape(-1, 12), part.records[:, :12])
            assert np.array_equal(rec, part.records[:, 12:])  # byte for byte through LAZ
        # a region: only the second tile
        assert f.tiles_in([9.0, 1.0, 0.0], [10.0, 2.0, 5.0]).tolist() == [1]
        # the models sample back within the budget of the surfaces they came from
        m, _, _ = f.patches(0)
        q, _ = sample_models(dequantise_models(m))
        assert np.abs(q[:, 2] - (0.1 * q[:, 0] + 1.0)).max() <= BUDGET / 2
    names = zipfile.ZipFile(tmp_path / "c.pcz").namelist()
    assert len(names) == len(set(names))  # every entry once
    assert not any(p.name.endswith(".partial") or p.is_dir() for p in tmp_path.iterdir())


def test_refuses_what_it_cannot_read(tmp_path, rng, monkeypatch):
    with pytest.raises(PatchcloudIOError, match="no such file"):
        pcz.open_pcz(tmp_path / "none.pcz")
    (tmp_path / "text.pcz").write_text("hello")
    with pytest.raises(PatchcloudIOError, match="not a zip archive"):
        pcz.open_pcz(tmp_path / "text.pcz")
    write(tmp_path, rng)
    data = (tmp_path / "c.pcz").read_bytes()
    (tmp_path / "cut.pcz").write_bytes(data[: len(data) // 2])
    with pytest.raises(PatchcloudIOError, match="cut.pcz"):
        pcz.open_pcz(tmp_path / "cut.pcz")
    with zipfile.ZipFile(tmp_path / "other.pcz", "w") as z:
        z.writestr("zarr.json", '{"zarr_format": 3, "node_type": "group", "attributes": {"format": "something"}}')
    with pytest.raises(PatchcloudIOError, match="no 'patchcloud-pcz' format mark"):
        pcz.open_pcz(tmp_path / "other.pcz")
    now = pcz.VERSION
    monkeypatch.setattr(pcz, "VERSION", now + 1)
    write(tmp_path, rng, name="next.pcz")
    monkeypatch.setattr(pcz, "VERSION", now)
    with pytest.raises(PatchcloudIOError, match=f"version {now + 1} is not supported"):
        pcz.open_pcz(tmp_path / "next.pcz")


@pytest.mark.parametrize("entry", ["tiles/intensity_shift/c/0", "cells/classification/c/0", "patches/centroid/c/0/0"])
def test_a_chunk_missing_is_damage_not_zeros(tmp_path, rng, entry):
    """Version 5 writes every chunk, zeros too: a file without one is refused (zarr would read zeros: every intensity
    unshifted, every class 0; found by a sweep of 2026-11-27)."""
    write(tmp_path, rng)
    with zipfile.ZipFile(tmp_path / "c.pcz") as z, zipfile.ZipFile(tmp_path / "cut.pcz", "w") as out:
        assert entry in z.namelist()
        for e in z.infolist():
            if e.filename != entry:
                out.writestr(e, z.read(e.filename))
    with pytest.raises(PatchcloudIOError, match=f"cut.pcz: damaged .pcz file \\(chunk {entry} is missing\\)"):
        pcz.open_pcz(tmp_path / "cut.pcz")


def test_never_overwrites_unasked(tmp_path, rng):
    write(tmp_path, rng)
    with pytest.raises(PatchcloudIOError, match="exists"):
        write(tmp_path, rng)
    write(tmp_path, rng, overwrite=True)


@pytest.mark.parametrize("version", [2, 3, 4, 5])
def test_a_committed_file_of_each_readable_version_reads_back_field_by_field(version):
    """tests/data/pcz-v{N}.pcz was written by tools/make_pcz_fixture.py at version N; the .npz holds what it was given.
    Version 3 stores the residual points' X, Y, Z divided by its steps; version 2 has none (exact).  Version 4's
    input is of point format 1, its records stored as format 6 (stream.io.layered); 2 and 3 hold format 6 records.
    Version 5 stores the second tile's intensities (its cells' and residual points') divided by 2**3: they come back
    multiplied (at most 65535)."""
    from pathlib import Path

    assert pcz.VERSION == 5 and pcz.READABLE == (2, 3, 4, 5)
    data = Path(__file__).parent / "data"
    expected = np.load(data / f"pcz-v{version}.npz", allow_pickle=False)
    steps = expected["steps"] if version >= 3 else np.ones(3, int)
    fields = ("scale", "centroid", "rotation", "coeffs", "rmse", "cells", "level", "ijk", "count", "extent", "mask")
    with pcz.open_pcz(data / f"pcz-v{version}.pcz") as f:
        assert f.attrs["version"] == version and f.max_error == 0.01 and f.tile_size == 4.0
        assert f.steps == tuple(steps) and f.dropped == (["gps_time"] if version >= 3 else [])
        assert [tuple(t) for t in f.tiles] == [(0, 0, 0), (1, 0, 0)]
        stored = f.root["residual/laz"][:400].tobytes()  # the first tile's LAZ header: its point format
        assert stored[:4] == b"LASF" and stored[104] & 0x3F == 6 and f.input_format_id == (1 if version >= 4 else 0)
        for t in range(2):
            m, cls, inten = f.patches(t)
            for name in fields:
                assert np.array_equal(getattr(m, name), expected[f"{t}/{name}"]), (t, name)
            shift = int(expected["shifts"][t]) if version >= 5 else 0
            want_inten = np.minimum(expected[f"{t}/intensity"].astype(np.int64) << shift, 65535)
            assert np.array_equal(cls, expected[f"{t}/classification"]) and np.array_equal(inten, want_inten)
            xyz, rec = f.residual(t)
            records = expected[f"{t}/records"]
            stored = records[:, :12].copy().view("<i4").reshape(-1, 3)
            want = records[:, 12:].copy()
            if version >= 5:
                I = np.minimum(want[:, :2].copy().view("<u2").ravel().astype(np.int64) << shift, 65535)
                want[:, :2] = I.astype("<u2")[:, None].view(np.uint8)
                assert f.intensity_shift.tolist() == [0, 3] and (shift == 0 or not np.array_equal(want, records[:, 12:]))
            if version >= 5 and t == 1:  # an octree block: its points come back in Morton order
                assert f.root["residual/laz"][int(f.residual_byte_start[1]):][:4].tobytes() == b"PCZO"
                v = np.dtype((np.void, records.shape[1]))
                got = np.hstack([(xyz // steps).astype("<i4").view(np.uint8).reshape(-1, 12), rec])
                want = np.hstack([records[:, :12], want])
                assert sorted(got.view(v).ravel().tolist()) == sorted(want.view(v).ravel().tolist())
                assert np.array_equal(xyz % steps, np.zeros_like(xyz))
                continue
            assert np.array_equal(xyz, stored * steps) and np.array_equal(rec, want)
        # the plane tile samples back on its plane
        q, _ = sample_models(dequantise_models(f.patches(0)[0]))
        assert len(q) > 1000 and np.abs(q[:, 2] - (0.1 * q[:, 0] + 1.0)).max() <= 0.005


def test_a_tile_whose_residual_disagrees_with_the_index_is_named_as_the_store_names_it():
    from pathlib import Path

    with pcz.open_pcz(Path(__file__).parent / "data" / "pcz-v2.pcz") as f:
        t = next(k for k in range(len(f.tiles)) if f.residual(k)[0].shape[0])
        f.attrs["record_bytes"] += 1  # as a crafted header would say
        with pytest.raises(PatchcloudIOError, match=r"tile t\+[01]\+0\+0: their LAZ header says \d+ points of \d+ bytes, the index says"):
            f.residual(t)


@pytest.mark.parametrize("point_format", [1, 6])
def test_records_laz_is_the_same_bytes_with_lazrs_threads(point_format, rng):
    """The parallel coder (a run of one task at a time) writes the bytes of the sequential one, so a .pcz does not depend
    on how it was run; and the records read back as given (formats 0-3 pass through their layered twins)."""
    pf = laspy.PointFormat(point_format)
    n = 120_000  # more than two LAZ chunks of 50,000 points
    records = np.zeros(n, pf.dtype())
    records["X"], records["Y"] = np.cumsum(rng.integers(-20, 21, (2, n)), axis=1)
    records["Z"] = rng.integers(0, 3000, n)
    records["intensity"] = rng.integers(0, 65535, n)
    rows = records.view(np.uint8).reshape(n, pf.size)
    args = (rows, pf, "1.4" if point_format >= 6 else "1.2", [0.01, 0.01, 0.01], [0.0, 0.0, 0.0])
    one, many = records_laz(*args), records_laz(*args, parallel=True)
    assert one == many
    back = laspy.read(io.BytesIO(many))
    for name in ("X", "Y", "Z", "intensity"):
        assert np.array_equal(np.asarray(back[name]), records[name])
