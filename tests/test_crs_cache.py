"""stream.io.crs_cache: pyproj's answers about CRSs kept on disk, the same answers, and a run that then needs no pyproj."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import laspy
import pytest

from patchcloud.stream.io import crs_cache
from patchcloud.stream.io.crs import crs_description, units_of
from patchcloud.stream.io.crs_cache import header_crs, remembered

SAMPLE = Path(__file__).resolve().parents[1] / "data" / "test_data_77055_627760_LA93_IGN69.laz"
SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


@pytest.fixture
def cache(tmp_path, monkeypatch):
    where = tmp_path / "crs"
    monkeypatch.setenv("PATCHCLOUD_CRS_CACHE", str(where))
    return where


def _kept(where: Path) -> list[Path]:
    return sorted(where.rglob("*.json"))


def test_an_answer_is_computed_once_then_read_back(cache):
    calls = []

    def answer():
        calls.append(1)
        return {"unit": ["metre", 1.0], "epsg": None, "nan": float("nan")}

    first = remembered("t", b"question", answer)
    again = remembered("t", b"question", answer)
    assert len(calls) == 1 and len(_kept(cache)) == 1
    assert again["unit"] == ["metre", 1.0] and again["epsg"] is None and again["nan"] != again["nan"]  # NaN kept
    assert first["unit"] == again["unit"]
    remembered("t", b"another question", answer)
    remembered("other kind", b"question", answer)
    assert len(calls) == 3 and len(_kept(cache)) == 3
    assert not list(cache.rglob("*.tmp"))  # written under a temporary name, renamed


def test_a_new_pyproj_asks_again(cache, monkeypatch):
    calls = []
    remembered("t", b"q", lambda: calls.append(1) or {"a": 1})
    monkeypatch.setattr(crs_cache, "_answerer", lambda: b"another pyproj")
    assert remembered("t", b"q", lambda: calls.append(1) or {"a": 2}) == {"a": 2}
    assert len(calls) == 2


def test_a_damaged_or_unwritable_cache_is_passed_over(cache, tmp_path, monkeypatch):
    remembered("t", b"q", lambda: {"a": 1})
    (path,) = _kept(cache)
    path.write_text("{not json")
    assert remembered("t", b"q", lambda: {"a": 2}) == {"a": 2}  # computed again, and kept again
    assert json.loads(path.read_text())["answer"] == {"a": 2}
    blocked = tmp_path / "file"
    blocked.write_text("a file where the cache's directory would be")
    monkeypatch.setenv("PATCHCLOUD_CRS_CACHE", str(blocked / "crs"))
    assert remembered("t", b"q", lambda: {"a": 3}) == {"a": 3}


def test_an_error_is_raised_and_not_kept(cache):
    def fails():
        raise ValueError("no such CRS")

    with pytest.raises(ValueError, match="no such CRS"):
        remembered("t", b"q", fails)
    assert not _kept(cache)


def test_off(monkeypatch):
    monkeypatch.setenv("PATCHCLOUD_CRS_CACHE", "0")
    calls = []
    for _ in range(2):
        remembered("t", b"q", lambda: calls.append(1) or {"a": 1})
    assert len(calls) == 2 and crs_cache.cache_dir() is None


def _files():
    files = [SAMPLE]
    for name in ("lidar-autzen/autzen_trim.laz", "lidar-lastools/house.laz", "lidar-ign-stbarth/St_Barth_RGAF09_UTM20N_IGN_1988_SB_subset_100m.laz",
                 "tls-lone-star/lone-star.laz"):
        if (SHARED / name).is_file():
            files.append(SHARED / name)
    return files


def test_header_crs_is_the_crs_laspy_reads_with_and_without_the_cache(cache):
    """The CRS is the one laspy and pyproj give (GeoTIFF keys, WKT records, none) where laspy reads the keys as PDAL
    does, and a geocentric one where laspy took it for geographic (lone-star: GTModelType 3), read back from the cache
    the same; the description and units of that WKT too."""
    from pyproj import CRS

    for path in _files():
        header = laspy.open(path).header
        parsed = header.parse_crs()
        first = header_crs(header)
        if path.name == "lone-star.laz":  # GeoTIFF keys: geocentric (1024 = 3) on WGS 84 (2048 = 4326)
            assert CRS(first[0]).is_geocentric and CRS(first[0]).to_epsg() == 4978
        else:
            assert (first[0] is None) == (parsed is None), path
            assert parsed is None or CRS(first[0]).equals(parsed, ignore_axis_order=True), path
        expected_description = None if first[0] is None else crs_description(first[0])
        for _ in range(2):  # computed, then from the cache
            assert header_crs(header) == first, path
            if first[0] is not None:
                assert crs_description(first[0]) == expected_description
    assert len(_kept(cache)) >= 2


def test_a_description_is_read_back_in_a_new_process(cache):
    """A second process gets the EPSG label and units from the cache: the same values, pyproj not imported."""
    code = textwrap.dedent(f"""
        import sys
        from patchcloud.stream.engine.laspy_start import skip_laspy_pyproj
        skip_laspy_pyproj()
        import laspy
        from patchcloud.stream.io.crs import units_of, crs_description
        from patchcloud.stream.io.crs_cache import header_crs
        h = laspy.open({str(SAMPLE)!r}).header
        wkt, err = header_crs(h)
        u = units_of(wkt, h.mins, h.maxs)
        print(crs_description(wkt)["label"], u.symbol, u.source, err, "pyproj" in sys.modules)
    """)
    env = dict(os.environ, PATCHCLOUD_CRS_CACHE=str(cache))
    first = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    second = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert first.returncode == 0 and second.returncode == 0, first.stderr[-2000:] + second.stderr[-2000:]
    assert first.stdout.split() == ["EPSG:2154", "(RGF93", "v1", "/", "Lambert-93)", "m", "CRS", "None", "True"]
    assert second.stdout.split() == first.stdout.split()[:-1] + ["False"]


def test_an_unreadable_crs_record_is_said_each_time(cache):
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.vlrs.append(laspy.vlrs.known.WktCoordinateSystemVlr("this is not a CRS"))
    for _ in range(2):
        wkt, error = header_crs(header)
        assert wkt is None and error is not None and "crs" in error.lower(), error
    assert not _kept(cache)


def test_geographic_units_refused_from_the_cache_as_without_it(cache):
    """A cached description still refuses degrees (the error names --units)."""
    from patchcloud.core import PatchcloudValueError

    for _ in range(2):
        with pytest.raises(PatchcloudValueError, match="--units"):
            units_of("EPSG:4326", (0.0, 0.0), (1.0, 1.0), where="f.las")


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_a_second_run_on_the_same_crs_imports_no_pyproj_and_writes_the_same_file(cache, tmp_path):
    """The console script on the embedded tile: the first run asks pyproj and keeps its answers, the second imports no
    pyproj; both outputs byte for byte the same as a run without the cache (its CRS records and summary included)."""
    code = textwrap.dedent("""
        import sys
        if __name__ == "__main__":
            from patchcloud.stream.console import run
            import patchcloud.stream.cli as cli
            cli.leave = sys.exit  # (a probe: this process goes on after the command, to look at it)
            sys.argv = ["patchcloud", "normals", sys.argv[1], sys.argv[2], "-q", "--overwrite"]
            try:
                run()
            except SystemExit as e:
                assert not e.code, e.code
            print("pyproj" in sys.modules)
    """)
    seen = []
    for name, where in (("a.laz", str(cache)), ("b.laz", str(cache)), ("c.laz", "0")):
        env = dict(os.environ, PATCHCLOUD_CRS_CACHE=where)
        out = subprocess.run([sys.executable, "-c", code, str(SAMPLE), str(tmp_path / name)], capture_output=True, text=True,
                             timeout=300, env=env)
        assert out.returncode == 0, out.stderr[-3000:]
        seen.append(out.stdout.split()[-1])
    assert seen == ["True", "False", "True"]
    a, b, c = ((tmp_path / n).read_bytes() for n in ("a.laz", "b.laz", "c.laz"))
    assert a == b == c
    assert laspy.read(tmp_path / "b.laz").header.parse_crs().to_epsg() == 2154
