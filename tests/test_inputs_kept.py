"""An input is never replaced: an output, store or report that is one of a command's inputs is one clear error, whatever --overwrite says."""

import os
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from patchcloud.stream.cli import main

SAMPLE = os.path.join(os.path.dirname(__file__), "..", "data", "test_data_77055_627760_LA93_IGN69.laz")


@pytest.fixture
def laz(tmp_path):
    p = tmp_path / "in.laz"
    shutil.copy(SAMPLE, p)
    (tmp_path / "links").mkdir()  # not in the directory the catalogs name: there it would be the same file twice
    os.symlink(p, tmp_path / "links" / "link.laz")
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
    # nor a catalog's output, named as its input in the output directory (.pcz for compress)
    ["normals", "{in}", "--out-dir", "{dir}_out", "--report", "{dir}_out/in.laz", "--overwrite"],
    ["compress", "{in}", "--out-dir", "{dir}_out", "--report", "{dir}_out/in.pcz", "--overwrite"],
    ["segment", "{in}", "--out-dir", "{dir}_out", "--summary-json", "{dir}_out/in.laz"],
])
def test_an_input_is_never_replaced(laz, tmp_path, args):
    before = laz.read_bytes()
    files = sorted(p.name for p in tmp_path.iterdir())
    args = [a.format(**{"in": str(laz), "link": str(tmp_path / "links" / "link.laz"), "dir": str(tmp_path)}) for a in args]
    Path(f"{tmp_path}_out").mkdir(exist_ok=True)  # a catalog's output directory, there (outside tmp_path)
    r = CliRunner().invoke(main, args + ["-q"])
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    said = lines[0].replace(str(tmp_path), "DIR")  # (the test's own directory name holds the word "input")
    refusals = ("input", "job's file", "an output's name ends in", "a LAS/LAZ name", "the store would be the output",
                "is not a JSON file")
    assert len(lines) == 1 and lines[0].startswith("error: ") and any(w in said for w in refusals), r.output
    assert not any(Path(f"{tmp_path}_out").iterdir())
    assert laz.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == files


def test_decompress_does_not_replace_its_pcz(laz, tmp_path):
    pcz = tmp_path / "x.pcz"
    assert CliRunner().invoke(main, ["compress", str(laz), str(pcz), "-q"]).exit_code == 0
    before = pcz.read_bytes()
    r = CliRunner().invoke(main, ["decompress", str(pcz), str(pcz), "--overwrite", "-q"])
    assert r.exit_code == 2 and "is the input" in r.output and pcz.read_bytes() == before


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_the_report_of_a_catalog_of_one_file_shows_its_output(laz, tmp_path):
    """A directory or glob that names one file is a catalog of one: its summary's output is the directory, and its
    report reads the file written in it (it tried to read the directory)."""
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["normals", str(tmp_path / "in*.laz"), "--out-dir", str(out), "--report", str(tmp_path / "r.html"), "-q"])
    assert r.exit_code == 0, r.output
    assert (out / "in.laz").is_file() and "in.laz" in (tmp_path / "r.html").read_text()


def test_a_picture_replaces_only_a_picture(laz, tmp_path):
    """render and render-tiles write a PNG: never over a LAS/LAZ name (an unquoted ``render tiles/*.laz`` makes the
    last tile the output), nor over an existing file that is not a PNG (a store's metadata, notes); a PNG is replaced."""
    other = tmp_path / "other.laz"
    shutil.copy(laz, other)
    notes = tmp_path / "notes.txt"
    notes.write_text("mine")
    store = tmp_path / "st.zarr"
    assert CliRunner().invoke(main, ["tile", str(laz), str(store), "-q"]).exit_code == 0
    meta = (store / "zarr.json").read_bytes()
    for args, says in [
        (["render", str(laz), str(other), "--color", "elevation"], "a LAS/LAZ name"),
        (["render", str(laz), str(tmp_path / "new.copc.laz"), "--color", "elevation"], "a LAS/LAZ name"),
        (["render", str(laz), str(notes), "--color", "elevation"], "exists and is not a PNG"),
        (["render-tiles", str(store), str(store / "zarr.json")], "exists and is not a PNG"),
        (["render-tiles", str(store), str(other)], "a LAS/LAZ name"),
    ]:
        r = CliRunner().invoke(main, args + ["-q"])
        assert r.exit_code == 2 and r.output.count("\n") == 1 and says in r.output, (args, r.output)
    assert other.read_bytes() == laz.read_bytes() and notes.read_text() == "mine" and (store / "zarr.json").read_bytes() == meta
    assert not (tmp_path / "new.copc.laz").exists()
    png = tmp_path / "p.png"
    for _ in range(2):  # the second run replaces the first's PNG
        r = CliRunner().invoke(main, ["render", str(laz), str(png), "--color", "elevation", "--width", "200", "-q"])
        assert r.exit_code == 0, r.output


@pytest.mark.parametrize("extra, says", [
    (["--table", "{in}"], "a LAS/LAZ name, not a table's"),
    (["--table", "{dir}/copy.txt", "--summary-json", "{in}"], "exists and is not a JSON file"),
    (["--plot", "{in}"], "a LAS/LAZ name, not a picture's"),
    (["--table", "{dir}/t.png", "--plot", "{dir}/t.png"], "--plot and --table name the same file"),
])
def test_don_scales_never_replaces_its_input_nor_writes_two_files_in_one(laz, tmp_path, extra, says):
    before = laz.read_bytes()
    files = sorted(p.name for p in tmp_path.iterdir())
    args = [a.format(**{"in": str(laz), "dir": str(tmp_path)}) for a in extra]
    r = CliRunner().invoke(main, ["don-scales", str(laz), "--radii", "0.5,2", "-q", *args])
    assert r.exit_code == 2 and r.output.count("\n") == 1 and says in r.output, r.output
    assert laz.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == files


def test_a_json_written_beside_the_work_replaces_only_json_and_never_a_store(laz, tmp_path):
    """--summary-json and --profile of any command (render, decompress and render-tiles were not checked at all)
    replace only a JSON file, never write into a zarr store (its metadata is JSON), and never name the --report."""
    store = tmp_path / "st.zarr"
    assert CliRunner().invoke(main, ["tile", str(laz), str(store), "-q"]).exit_code == 0
    meta = (store / "zarr.json").read_bytes()
    (tmp_path / "old.json").write_text('{"a": 1}')
    before = laz.read_bytes()
    for args, says in [
        (["render", str(laz), str(tmp_path / "p.png"), "--color", "elevation", "--summary-json", str(laz)], "is not a JSON file"),
        (["render-tiles", str(store), str(tmp_path / "t.png"), "--summary-json", str(store / "zarr.json")], "inside a zarr store"),
        (["normals", str(laz), str(tmp_path / "n.laz"), "--store", str(store), "--summary-json", str(store / "s.json")],
         "inside a zarr store"),
        (["normals", str(laz), str(tmp_path / "n.laz"), "--profile", str(laz)], "is not a JSON file"),
        (["normals", str(laz), str(tmp_path / "n.laz"), "--report", str(tmp_path / "r"), "--summary-json", str(tmp_path / "r")],
         "--report and --summary-json name the same file"),
    ]:
        r = CliRunner().invoke(main, args + ["-q"])
        assert r.exit_code == 2 and r.output.count("\n") == 1 and says in r.output, (args, r.output)
    assert laz.read_bytes() == before and (store / "zarr.json").read_bytes() == meta and not (tmp_path / "n.laz").exists()
    r = CliRunner().invoke(main, ["render", str(laz), str(tmp_path / "p.png"), "--color", "elevation", "--width", "200",
                                  "--summary-json", str(tmp_path / "old.json"), "-q"])
    assert r.exit_code == 0 and '"color": "elevation"' in (tmp_path / "old.json").read_text()  # a JSON file: replaced


def test_a_json_or_report_never_takes_the_place_of_an_output_not_yet_written_nor_of_the_store(laz, tmp_path):
    """--summary-json naming a command's output that does not exist yet (decompress, render, render --out-dir,
    render-tiles), or --summary-json, --report and --profile naming the --store directory: one error line before
    anything runs (decompress and render wrote the JSON over the output they had just written, exit 0; a store
    named so failed only after the whole job)."""
    pcz = tmp_path / "x.pcz"
    store = tmp_path / "st.zarr"
    assert CliRunner().invoke(main, ["compress", str(laz), str(pcz), "-q"]).exit_code == 0
    assert CliRunner().invoke(main, ["tile", str(laz), str(store), "-q"]).exit_code == 0
    (tmp_path / "pics").mkdir()
    files = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    for args in [
        ["decompress", str(pcz), str(tmp_path / "d.laz"), "--summary-json", str(tmp_path / "d.laz")],
        ["render", str(laz), str(tmp_path / "p.png"), "--color", "elevation", "--summary-json", str(tmp_path / "p.png")],
        ["render", str(laz), "--out-dir", str(tmp_path / "pics"), "--color", "elevation",
         "--summary-json", str(tmp_path / "pics" / "in.png")],
        ["render-tiles", str(store), str(tmp_path / "t.png"), "--summary-json", str(tmp_path / "t.png")],
        ["normals", str(laz), str(tmp_path / "n.laz"), "--store", str(tmp_path / "new.zarr"), "--summary-json",
         str(tmp_path / "new.zarr")],
        ["normals", str(laz), str(tmp_path / "n.laz"), "--store", str(tmp_path / "new.zarr"), "--profile", str(tmp_path / "new.zarr")],
        ["normals", str(laz), str(tmp_path / "n.laz"), "--store", str(tmp_path / "new.zarr"), "--report", str(tmp_path / "new.zarr")],
    ]:
        r = CliRunner().invoke(main, args + ["-q"])
        assert r.exit_code == 2 and r.output.count("\n") == 1, (args, r.output)
        assert "job's file" in r.output or "would replace" in r.output, (args, r.output)
        assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == files, args  # nothing written


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_a_json_or_report_may_go_into_the_output_directory_the_catalog_run_makes(laz, tmp_path):
    """--summary-json and --report inside an --out-dir that does not exist yet (the run makes it) are taken, whichever
    comes first on the command line (they were refused: "the directory ... does not exist"); a JSON in another missing
    directory is still refused, before anything is made."""
    for k, order in enumerate((["--out-dir", "{o}", "--summary-json", "{o}/s.json"], ["--summary-json", "{o}/s.json", "--out-dir", "{o}"])):
        o = tmp_path / f"made{k}"
        args = [a.format(o=o) for a in order]
        r = CliRunner().invoke(main, ["normals", str(laz), *args, "--report", str(o / "r.html"), "-q"])
        assert r.exit_code == 0, r.output
        assert sorted(p.name for p in o.iterdir()) == ["in.laz", "r.html", "s.json"]
    r = CliRunner().invoke(main, ["normals", str(laz), "--out-dir", str(tmp_path / "o3"), "--summary-json", str(tmp_path / "nope" / "s.json"), "-q"])
    assert r.exit_code == 2 and "directory does not exist" in r.output and not (tmp_path / "o3").exists()
