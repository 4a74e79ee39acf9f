"""Where a ``patchcloud`` run's start-up and end go: its main steps timed in its own process.

    python tools/startup_marks.py normals city.laz out.laz --workers 16 --profile p.json

Runs the command as the console script does (:mod:`patchcloud.stream.console`,
the fork server started first where it would be) and prints, on stderr at
the end, when the process reached each mark: the command line imported,
the fork server started, the job's modules imported, the run's start, the
local cluster's start and end, the profile written, the cluster closed,
the store removed.  Times are seconds since the process started as /proc
gives it, whose boot time is whole seconds: the offsets between marks are
exact, the first mark's may be off by up to a second.  With ``--profile``
it also prints when the run started, the workers were ready and the first
task began (tools/results/startup_16core-2026-11-28.txt).
"""

from __future__ import annotations

import atexit
import json
import os
import sys
import time

__all__ = ["main"]


def _process_start() -> float:
    """The process's start, seconds since the epoch (/proc: whole-second boot time plus clock ticks)."""
    with open("/proc/self/stat") as f:
        ticks = int(f.read().rsplit(")", 1)[1].split()[19])
    with open("/proc/stat") as f:
        boot = next(float(line.split()[1]) for line in f if line.startswith("btime"))
    return boot + ticks / os.sysconf("SC_CLK_TCK")


def main() -> None:
    start = _process_start()
    marks: list[tuple[float, str]] = []

    def mark(what: str) -> None:
        marks.append((time.time() - start, what))

    def report() -> None:
        lines = [f"{t:6.2f} {what}" for t, what in marks + [(time.time() - start, "exit")]]
        if "--profile" in sys.argv:
            try:
                with open(sys.argv[sys.argv.index("--profile") + 1]) as f:
                    p = json.load(f)
                lines.append(f"profile: started {p['started'] - start:.2f} ready {p['ready'] - start:.2f} "
                             f"first task {min(t[1] for t in p['tasks']) - start:.2f} ended {p['ended'] - start:.2f}")
            except (OSError, ValueError, KeyError, IndexError) as exc:
                lines.append(f"profile: not read ({exc})")
        sys.stderr.write("\n".join(lines) + "\n")

    atexit.register(report)
    mark("main")

    def timed(owner, name: str, label: str) -> None:
        f = getattr(owner, name)

        def wrapper(*a, **k):
            mark(label + " >")
            try:
                return f(*a, **k)
            finally:
                mark(label + " <")
        setattr(owner, name, wrapper)

    from patchcloud.stream.engine import forkserver

    first_start = forkserver.start_server

    def start_server(*a, **k):
        mark("start_server called (a second call starts nothing more)" if any("start_server" in w for _, w in marks) else "start_server called")
        return first_start(*a, **k)
    forkserver.start_server = start_server
    from patchcloud.stream import console

    console.start_early(sys.argv[1:])
    from patchcloud.stream.cli import main as command_line

    mark("command line imported")
    import patchcloud.stream.engine.job as job_module
    import patchcloud.stream.engine.runner as runner
    import patchcloud.stream.io.store as store

    timed(runner.Runner, "_start_local", "cluster")
    timed(runner.Runner, "close", "close")
    timed(job_module, "_run", "run")
    timed(job_module, "write_profile", "write profile")
    timed(store, "remove_store_dir", "remove store")
    mark("job modules imported")
    command_line(sys.argv[1:])


if __name__ == "__main__":
    main()
