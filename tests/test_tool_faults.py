"""tools/faults.py: the fault-injection script runs its cases on the real command line and reports its table.

Slow (``pytest -m slow``, run by .ci/run after the default suite): two of its quicker classes, two runs at once and a
worker killed, about a minute and a half on two cores.
"""

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_concurrent_runs_and_killed_workers_pass(tmp_path):
    work, results = tmp_path / "work", tmp_path / "faults.txt"
    cmd = [sys.executable, str(ROOT / "tools" / "faults.py"), "--only", "concurrent", "worker-killed", "--workdir", str(work),
           "--results", str(results)]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-2000:]
    table = results.read_text()
    for title in ("two concurrent runs", "a worker killed"):
        row = re.search(rf"^{title}\s+(\d+)\s+(\d+)\s+(\d+)\s+(\d+)", table, re.M)
        assert row is not None, table
        cases, passed, failed, skipped = (int(v) for v in row.groups())
        assert cases >= 6 and failed == 0 and passed + skipped == cases and passed >= cases - 1, table
    for fault in ("concurrent", "worker-killed"):
        assert not list((work / fault).iterdir())  # a case that passes leaves nothing behind
