"""When each process of a command's tree started, in seconds after the command (Linux: /proc; 10 ms ticks).

    python tools/process_starts.py patchcloud normals city.laz out.laz --workers 16

Starts the command, polls /proc every 5 ms until it ends, and prints one
line per process that descends from it: seconds after the command's own
start, the process id and its command line.  For a run on worker processes
the lines show when the fork server started and when each worker was forked
from it (tools/results/startup_16core-2026-11-28.txt).  The poll itself
takes some of a core: compare runs made with it, not with runs made without.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

__all__ = ["started_processes", "main"]


def _stat(pid: str) -> tuple[int, int] | None:
    """(parent pid, start time in clock ticks since boot) of a process, None where it is gone."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return int(fields[1]), int(fields[19])


def _cmdline(pid: str) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode(errors="replace").strip()
    except OSError:
        return "?"


def started_processes(argv: list[str], poll: float = 0.005) -> tuple[int, list[tuple[float, int, str]]]:
    """Run ``argv``; return its exit status and (seconds after its start, pid, command line) of it and every process
    descending from it that lived at least one poll, in the order they started."""
    proc = subprocess.Popen(argv)
    seen: dict[str, tuple[tuple[int, int], str]] = {}
    began = None  # the command's start (ticks): what started before it is not read again
    while True:
        for name in os.listdir("/proc"):
            if not name.isdigit() or (began is not None and name in seen and seen[name][0][1] < began):
                continue
            st = _stat(name)
            if st is None:
                continue
            if name not in seen:
                seen[name] = (st, _cmdline(name))
                if name == str(proc.pid):
                    began = st[1]
            elif seen[name][0][1] == st[1]:  # the same process: its command line read again, as it may have changed
                cmd = _cmdline(name)  # since (a child read between its fork and its exec shows its parent's, or none)
                if cmd and cmd != "?":
                    seen[name] = (seen[name][0], cmd)
        if proc.poll() is not None:
            break
        time.sleep(poll)
    root = str(proc.pid)
    if root not in seen:
        return proc.returncode, []
    ticks = os.sysconf("SC_CLK_TCK")
    base = seen[root][0][1]
    tree, out = {root}, []
    for pid, ((ppid, start), cmd) in sorted(seen.items(), key=lambda kv: (kv[1][0][1], int(kv[0]))):
        if str(ppid) in tree:
            tree.add(pid)
        if pid in tree:
            out.append(((start - base) / ticks, int(pid), cmd))
    return proc.returncode, out


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv:
        print(__doc__)
        return 2
    code, rows = started_processes(argv)
    for t, pid, cmd in rows:
        print(f"{t:6.2f} {pid:>7} {cmd[:120]}")
    return code


if __name__ == "__main__":
    sys.exit(main())
