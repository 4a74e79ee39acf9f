"""The console script's first look at its arguments (stream/console.py): it starts the workers' fork server before its
imports exactly when the command line would start it later (stream/cli/options.py: start_workers_early), or leaves it
to the command line."""

import shutil
import tomllib
from pathlib import Path

import laspy
import numpy as np
import pytest

from patchcloud.stream import console
from patchcloud.stream.cli import main, options
from patchcloud.stream.engine import forkserver, placement

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = str(ROOT / "data" / "test_data_77055_627760_LA93_IGN69.laz")


def cli_decision(argv, monkeypatch):
    """The job module whose server the command line would start for ``argv``, or None (its options parsed by click)."""
    started = []
    monkeypatch.setattr(forkserver, "start_server", lambda modules: started.append(list(modules)) or True)
    command = main.commands[argv[0]]
    params = command.make_context(argv[0], list(argv[1:])).params
    job, each_file = console.JOB_MODULES[argv[0]]
    options.start_workers_early(tuple(params["paths"]), params, job, each_file=each_file)
    return started[0][0] if started else None


@pytest.fixture
def small_is_big(monkeypatch):
    """The 60,653-point sample taken for a big file: worker processes from 50,000 points, in memory up to 40,000."""
    monkeypatch.setattr(placement, "AUTO_PROCESSES_POINTS", 50_000)
    monkeypatch.setattr(placement, "in_memory_points", lambda cores=None: 40_000)


@pytest.mark.parametrize("extra, expected", [
    ([], "patchcloud.stream.jobs.normals"),
    (["--scheduler", "processes"], "patchcloud.stream.jobs.normals"),
    (["--scheduler=processes", "--workers", "3"], "patchcloud.stream.jobs.normals"),
    (["--workers", "2", "--tile-size", "64", "--classes", "2,6"], "patchcloud.stream.jobs.normals"),
    (["--scheduler", "threads"], None),
    (["--scheduler", "synchronous"], None),
    (["--in-memory"], None),
    (["--on-disk", "--keep-store"], "patchcloud.stream.jobs.normals"),
    (["--scheduler", "tcp://127.0.0.1:8786"], None),
])
def test_a_big_input_starts_the_server_as_the_command_line_would(extra, expected, small_is_big, tmp_path, monkeypatch):
    argv = ["normals", SAMPLE, str(tmp_path / "o.laz"), *extra]
    assert console.early_job(argv) == expected
    assert cli_decision(argv, monkeypatch) == expected


@pytest.mark.parametrize("extra", [[], ["--workers", "2"], ["--scheduler", "threads"]])
def test_a_small_input_starts_no_server(extra, tmp_path, monkeypatch):
    argv = ["normals", SAMPLE, str(tmp_path / "o.laz"), *extra]
    assert console.early_job(argv) is None
    assert cli_decision(argv, monkeypatch) is None
    assert console.early_job(["normals", SAMPLE, str(tmp_path / "o.laz"), "--scheduler", "processes"]) == console.JOB_MODULES["normals"][0]


def test_a_catalog_counts_its_files_together_or_one_by_one(small_is_big, tmp_path, monkeypatch):
    """normals takes a catalog's files as one cloud (their sum decides); compress runs them one by one (the largest)."""
    monkeypatch.setattr(placement, "AUTO_PROCESSES_POINTS", 100_000)
    files = []
    for k in range(2):
        shutil.copy(SAMPLE, tmp_path / f"t{k}.laz")
        files.append(str(tmp_path / f"t{k}.laz"))
    out = str(tmp_path / "out")
    for argv, expected in [(["normals", *files, "--out-dir", out], "patchcloud.stream.jobs.normals"),
                           (["compress", *files, "--out-dir", out], None),
                           (["compress", files[0], str(tmp_path / "o.pcz"), "--scheduler", "processes"], "patchcloud.stream.jobs.compress")]:
        assert console.early_job(argv) == expected, argv
        assert cli_decision(argv, monkeypatch) == expected, argv


def test_what_the_first_look_does_not_understand_is_left_to_the_command_line(small_is_big, tmp_path, monkeypatch):
    """A directory of a catalog, help, a command that is not a job, an input that is no LAS file, an option twice: no
    early start (the command line decides, as before)."""
    (tmp_path / "cat").mkdir()
    shutil.copy(SAMPLE, tmp_path / "cat" / "t.laz")
    out = str(tmp_path / "o.laz")
    not_las = tmp_path / "x.laz"
    not_las.write_bytes(b"not a LAS file at all")
    for argv in (["normals", str(tmp_path / "cat"), "--out-dir", str(tmp_path / "out")],
                 ["normals", str(tmp_path / "cat" / "*.laz"), "--out-dir", str(tmp_path / "out")],
                 ["normals", SAMPLE, out, "--help"], ["normals", "-h"], ["info", SAMPLE], ["render", SAMPLE, "o.png"],
                 ["normals", str(not_las), out], ["normals", str(tmp_path / "absent.laz"), out],
                 ["normals", SAMPLE, out, "--workers", "2", "--workers", "3"], ["normals", SAMPLE, out, "--workers", "two"],
                 ["normals", SAMPLE, out, "--in-memory", "--on-disk"], []):
        assert console.early_job(argv) is None, argv
    # the command line, which expands the catalog, starts it
    assert cli_decision(["normals", str(tmp_path / "cat"), "--out-dir", str(tmp_path / "out")], monkeypatch) == "patchcloud.stream.jobs.normals"


@pytest.mark.parametrize("version, fmt", [("1.2", 3), ("1.4", 6), ("1.4", 1)])
def test_the_point_count_read_from_the_header_is_laspy_s(version, fmt, tmp_path):
    las = laspy.create(point_format=fmt, file_version=version)
    las.x, las.y, las.z = (np.arange(1234.0),) * 3
    path = tmp_path / f"p{fmt}.las"
    las.write(path)
    with laspy.open(path) as f:
        assert console._point_count(str(path)) == f.header.point_count == 1234


def test_the_point_count_of_every_real_file_is_laspy_s():
    data = ROOT.parent / "shared" / "data"
    files = sorted(p for p in data.rglob("*") if p.suffix.lower() in (".las", ".laz")) if data.is_dir() else []
    files.append(Path(SAMPLE))
    for p in files:
        with laspy.open(p) as f:
            assert console._point_count(str(p)) == f.header.point_count, p


def test_the_patchcloud_command_is_the_console_script():
    with open(ROOT / "pyproject.toml", "rb") as f:
        scripts = tomllib.load(f)["project"]["scripts"]
    assert scripts["patchcloud"] == "patchcloud.stream.console:run"


def _leave_in_a_process(body: str):
    import subprocess
    import sys

    code = f"import atexit, sys\natexit.register(lambda: print('teardown', flush=True))\nfrom patchcloud.stream.cli import leave\n{body}\n"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("body, status, out, err", [
    ("print('summary', end=''); leave(None)", 0, "summary", ""),
    ("sys.stderr.write('error: x\\n'); leave(2)", 2, "", "error: x\n"),
    ("leave('a message')", 1, "", "a message\n"),
    ("print('partial'); leave(130)", 130, "partial\n", ""),
])
def test_the_console_script_leaves_with_its_status_its_output_flushed_and_no_teardown(body, status, out, err):
    r = _leave_in_a_process(body)
    assert (r.returncode, r.stdout, r.stderr) == (status, out, err)  # no "teardown": the exit hooks did not run


def test_under_a_profiler_the_console_script_leaves_as_python_does():
    r = _leave_in_a_process("sys.setprofile(lambda *a: None)\nprint('summary', end=''); leave(3)")
    assert (r.returncode, r.stdout) == (3, "summaryteardown\n")  # the exit hooks ran (a profiler writes its results there)


def test_the_console_script_leaves_with_120_when_its_output_cannot_be_flushed():
    r = _leave_in_a_process("import os\nr, w = os.pipe(); os.close(r); sys.stdout = open(w, 'w')\nprint('lost'); leave(0)")
    assert r.returncode == 120


def test_the_console_script_runs_a_job_to_the_end_and_says_so(tmp_path):
    import subprocess
    import sys

    out = tmp_path / "n.laz"
    r = subprocess.run([sys.executable, "-m", "patchcloud.stream.console", "normals", SAMPLE, str(out)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[0].endswith(f"-> {out}") and "peak memory" in r.stdout.splitlines()[-1]
    assert laspy.read(out).header.point_count == 60_653
    r = subprocess.run([sys.executable, "-m", "patchcloud.stream.console", "normals", str(tmp_path / "none.laz"), str(out)],
                       capture_output=True, text=True, timeout=600)
    assert (r.returncode, r.stdout, r.stderr.count("\n")) == (2, "", 1) and "no such file" in r.stderr
