"""Where a run's wall time goes, from its task stream (``patchcloud ... --profile P.json``): one table.

    python tools/task_stream.py P.json [P2.json ...]

For each profile it prints the time from the run's start to its workers
being ready (the local cluster's start), every span of 0.05 s or more
during which no task runs (between which steps), and for each step (the
task labels: ``tile: read``, ``fit``, ``finish``, ...) its span, its
summed task time, that time over the workers (``ideal``: the span were the
tasks spread evenly) and its longest task.  Times in seconds from the
workers being ready.
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
from pathlib import Path


def no_task_spans(profile: dict, least: float = 0.05) -> list[tuple[str, float]]:
    """(between which steps, seconds) for each span of at least ``least`` seconds with no task running, the cluster's
    start first.

    >>> p = dict(started=0.0, ready=1.0, ended=5.0, tasks=[["a", 1.0, 2.0, "w"], ["b", 2.5, 4.0, "w"]])
    >>> no_task_spans(p)
    [('cluster start', 1.0), ('a -> b', 0.5), ('b -> end', 1.0)]
    """
    events = sorted([(t[1], 1, t[0]) for t in profile["tasks"]] + [(t[2], -1, t[0]) for t in profile["tasks"]])
    spans = [("cluster start", profile["ready"] - profile["started"])]
    running, last, name = 0, profile["ready"], "start"
    for when, change, label in events:
        if running == 0 and when - last >= least:
            spans.append((f"{name} -> {label}", when - last))
        running += change
        if running == 0:
            last, name = when, label
    if profile["ended"] - last >= least:
        spans.append((f"{name} -> end", profile["ended"] - last))
    return spans


def step_rows(profile: dict) -> list[tuple]:
    """(label, tasks, first start, last end, span, summed time, ideal, longest) per task label, in order of start;
    times in seconds from ``ready``."""
    slots = max(int(profile.get("slots", 1)), 1)
    by = collections.defaultdict(list)
    for label, a, b, _ in profile["tasks"]:
        by[label].append((a - profile["ready"], b - profile["ready"]))
    rows = []
    for label, v in sorted(by.items(), key=lambda kv: min(a for a, _ in kv[1])):
        a, b = min(x for x, _ in v), max(y for _, y in v)
        work = sum(y - x for x, y in v)
        rows.append((label, len(v), a, b, b - a, work, work / slots, max(y - x for x, y in v)))
    return rows


def report(path: str | Path) -> str:
    p = json.loads(Path(path).read_text())
    lines = [f"# {path}: scheduler {p.get('scheduler')}, {p.get('slots')} workers, run {p['ended'] - p['started']:.2f} s "
             f"(start to workers ready {p['ready'] - p['started']:.2f} s)"]
    spans = no_task_spans(p)
    lines += [f"  no task {what:<34} {s:6.2f}" for what, s in spans]
    lines.append(f"  no task in all {sum(s for _, s in spans):24.2f}")
    lines.append(f"  {'step':<16} {'tasks':>5} {'from':>6} {'to':>6} {'span':>6} {'summed':>7} {'ideal':>6} {'longest':>7}")
    for label, n, a, b, span, work, ideal, longest in step_rows(p):
        lines.append(f"  {label:<16} {n:>5} {a:6.2f} {b:6.2f} {span:6.2f} {work:7.2f} {ideal:6.2f} {longest:7.2f}")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("profiles", nargs="+")
    a = ap.parse_args(argv)
    print("\n\n".join(report(p) for p in a.profiles))
    return 0


if __name__ == "__main__":
    sys.exit(main())
