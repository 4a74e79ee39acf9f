"""Outputs written under a temporary name held with a lock: two runs at once on one output never write into the same
file, and neither removes the other's temporary file (stream/io/las.py: atomic_output)."""

import fcntl
import os

import pytest
from click.testing import CliRunner

from patchcloud.core import PatchcloudExistsError, PatchcloudIOError
from patchcloud.stream.cli import main
from patchcloud.stream.io.las import atomic_output


def test_a_second_writer_of_the_same_output_is_refused_while_the_first_writes(tmp_path):
    p = tmp_path / "out.laz"
    with atomic_output(p, overwrite=False) as f:
        f.write(b"first")
        with pytest.raises(PatchcloudIOError, match="another run is writing it now"):
            with atomic_output(p, overwrite=True):
                pass
        f.write(b" run")
    assert p.read_bytes() == b"first run" and sorted(os.listdir(tmp_path)) == ["out.laz"]


def test_a_temporary_file_left_by_a_killed_run_is_taken_over(tmp_path):
    p = tmp_path / "out.laz"
    (tmp_path / "out.laz.partial").write_bytes(b"half of a killed run's file, longer than the new one")
    with atomic_output(p, overwrite=False) as f:
        f.write(b"whole")
    assert p.read_bytes() == b"whole" and sorted(os.listdir(tmp_path)) == ["out.laz"]


def test_without_overwrite_a_file_another_run_put_there_meanwhile_is_kept(tmp_path):
    p = tmp_path / "out.laz"
    with pytest.raises(PatchcloudExistsError, match="another run wrote it meanwhile"):
        with atomic_output(p, overwrite=False) as f:
            f.write(b"mine")
            p.write_bytes(b"theirs")
    assert p.read_bytes() == b"theirs" and sorted(os.listdir(tmp_path)) == ["out.laz"]


def test_a_failed_run_removes_its_own_temporary_file_and_no_other(tmp_path):
    p = tmp_path / "out.laz"
    with pytest.raises(RuntimeError):
        with atomic_output(p, overwrite=False) as f:
            f.write(b"mine")
            raise RuntimeError("failed")
    assert os.listdir(tmp_path) == []
    with pytest.raises(RuntimeError):
        with atomic_output(p, overwrite=False):
            os.unlink(tmp_path / "out.laz.partial")  # (as if renamed away, and another run made its own)
            (tmp_path / "out.laz.partial").write_bytes(b"another run's")
            raise RuntimeError("failed")
    assert (tmp_path / "out.laz.partial").read_bytes() == b"another run's"


def test_decompress_refuses_an_output_another_run_is_writing(small_pcz, tmp_path):
    """Two ``decompress`` runs at once on one output wrote into the same temporary file: a damaged LAZ, one of them
    exiting 0 (bug hunt E).  The second now says so in one line, and the first run's file is left alone."""
    partial = tmp_path / "out.laz.partial"
    fd = os.open(partial, os.O_RDWR | os.O_CREAT)
    try:
        os.write(fd, b"the other run's bytes")
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # what a run writing out.laz holds
        r = CliRunner().invoke(main, ["decompress", str(small_pcz), str(tmp_path / "out.laz"), "-q"])
        assert (r.exit_code, r.output) == (2, f"error: {tmp_path / 'out.laz'}: another run is writing it now (its temporary "
                                              "file out.laz.partial is locked)\n")
        assert partial.read_bytes() == b"the other run's bytes" and not (tmp_path / "out.laz").exists()
        os.close(fd)
        fd = -1
        r = CliRunner().invoke(main, ["decompress", str(small_pcz), str(tmp_path / "out.laz"), "-q"])  # that run gone: taken over
        assert r.exit_code == 0 and sorted(os.listdir(tmp_path)) == ["out.laz"]
    finally:
        if fd >= 0:
            os.close(fd)


def _limited(limit_bytes):
    import resource

    def set_limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))
    return set_limit


@pytest.mark.parametrize("command", ["decompress", "normals"])
def test_a_write_past_the_room_left_names_the_output_and_leaves_nothing(small_pcz, tmp_path, command):
    """A disk full, a quota or ``ulimit -f`` while writing the output: one line naming that output (it named the
    store, which may be on another disk, or nothing at all: bug hunt E), exit status 2, no file left."""
    import subprocess
    import sys

    src = small_pcz if command == "decompress" else small_pcz.with_name("scene.las")
    out = tmp_path / "out.las"
    args = [sys.executable, "-m", "patchcloud.stream.console", command, str(src), str(out), "-q"]
    if command == "normals":
        args += ["--in-memory", "--tile-size", "16"]
    r = subprocess.run(args, capture_output=True, text=True, timeout=600, preexec_fn=_limited(256 * 1024))
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert r.stderr.startswith(f"error: {out}") and "File too large" in r.stderr, r.stderr
    assert os.listdir(tmp_path) == []
