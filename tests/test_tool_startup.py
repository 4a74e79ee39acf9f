"""tools/process_starts.py and tools/startup_marks.py: when a command's processes start, and where a run's start-up goes."""

import subprocess
import sys
from pathlib import Path

import pytest

import process_starts  # tools/ is on sys.path, see conftest.py

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "data" / "test_data_77055_627760_LA93_IGN69.laz"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux's /proc")
def test_a_child_process_is_listed_after_its_parent():
    code = "import subprocess, sys, time; time.sleep(0.05); subprocess.run([sys.executable, '-c', 'import time; time.sleep(0.2)'])"
    status, rows = process_starts.started_processes([sys.executable, "-c", code])
    assert status == 0 and len(rows) == 2, rows
    (t0, parent, cmd0), (t1, child, cmd1) = rows
    assert t0 == 0.0 and t1 >= 0.04 and parent != child and "time.sleep(0.2)" in cmd1


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux's /proc")
def test_startup_marks_times_a_run_in_memory(tmp_path):
    run = subprocess.run([sys.executable, str(ROOT / "tools" / "startup_marks.py"), "normals", str(SAMPLE), str(tmp_path / "o.laz"),
                          "-q", "--profile", str(tmp_path / "p.json")], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    lines = run.stderr.strip().splitlines()
    marks = [line.split(None, 1)[1] for line in lines[:-1]]
    assert marks[0] == "main" and marks[-1] == "exit" and "run >" in marks and "run <" in marks, marks
    assert "cluster >" not in marks  # a 60,000-point file runs in memory: no cluster, no fork server
    times = [float(line.split()[0]) for line in lines[:-1]]
    assert times == sorted(times)
    assert lines[-1].startswith("profile: started ")
