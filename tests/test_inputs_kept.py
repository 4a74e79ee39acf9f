"""An input is never replaced: an output, store or report that is one of a command's inputs is one clear error, whatever --overwrite says."""

import os
import shutil

import pytest
from click.testing import CliRunner

from patchcloud.stream.cli import main

SAMPLE = os.path.join(os.path.dirname(__file__), "..", "data", "test_data_77055_627760_LA93_IGN69.laz")


@pytest.fixture
def laz(tmp_path):
    p = tmp_path / "in.laz"
    shutil.copy(SAMPLE, p)
    os.symlink(p, tmp_path / "link.laz")
    return p


@pytest.mark.parametrize("args", [
    ["normals", "{in}", "{in}", "--overwrite"],
    ["normals", "{in}", "{link}", "--overwrite"],  # another name for the same file
    ["don", "{in}", "{in}", "--overwrite"],
    ["segment", "{in}", "{dir}/./in.laz", "--overwrite"],
    ["compress", "{in}", "{in}", "--overwrite"],
    ["render", "{in}", "{in}", "--color", "elevation"],
    ["render", "{in}", "{link}", "{in}", "--color", "elevation"],
    ["normals", "{in}", "{dir}/out.laz", "--store", "{in}"],
    ["normals", "{in}", "{dir}/out.laz", "--store", "{dir}/out.laz"],
    ["normals", "{in}", "{dir}/out.laz", "--report", "{in}", "--overwrite"],
    # a catalog's inputs are the files its directories and globs name
    ["normals", "{dir}", "--out-dir", "{dir}_out", "--report", "{in}", "--overwrite"],
    ["normals", "{dir}/*.laz", "--out-dir", "{dir}_out", "--report", "{in}", "--overwrite"],
    ["segment", "{dir}", "--out-dir", "{dir}_out", "--report", "{in}", "--overwrite"],
    ["compress", "{dir}", "--out-dir", "{dir}_out", "--report", "{in}", "--overwrite"],
    # the other files a run writes beside its output
    ["normals", "{in}", "{dir}/out.laz", "--summary-json", "{in}"],
    ["normals", "{in}", "{dir}/out.laz", "--summary-json", "{dir}/out.laz"],
    ["don", "{in}", "{dir}/out.laz", "--profile", "{in}"],
    ["normals", "{dir}", "--out-dir", "{dir}_out", "--summary-json", "{in}"],
])
def test_an_input_is_never_replaced(laz, tmp_path, args):
    before = laz.read_bytes()
    files = sorted(p.name for p in tmp_path.iterdir())
    args = [a.format(**{"in": str(laz), "link": str(tmp_path / "link.laz"), "dir": str(tmp_path)}) for a in args]
    r = CliRunner().invoke(main, args + ["-q"])
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and ("input" in lines[0] or "job's file" in lines[0]), r.output
    assert laz.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == files


def test_decompress_does_not_replace_its_pcz(laz, tmp_path):
    pcz = tmp_path / "x.pcz"
    assert CliRunner().invoke(main, ["compress", str(laz), str(pcz), "-q"]).exit_code == 0
    before = pcz.read_bytes()
    r = CliRunner().invoke(main, ["decompress", str(pcz), str(pcz), "--overwrite", "-q"])
    assert r.exit_code == 2 and "is the input" in r.output and pcz.read_bytes() == before


def test_the_report_of_a_catalog_of_one_file_shows_its_output(laz, tmp_path):
    """A directory or glob that names one file is a catalog of one: its summary's output is the directory, and its
    report reads the file written in it (it tried to read the directory)."""
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["normals", str(tmp_path / "in*.laz"), "--out-dir", str(out), "--report", str(tmp_path / "r.html"), "-q"])
    assert r.exit_code == 0, r.output
    assert (out / "in.laz").is_file() and "in.laz" in (tmp_path / "r.html").read_text()
