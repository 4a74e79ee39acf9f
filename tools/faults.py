"""Fault injection on the real command line: disk full, kill -9 at each step, two runs at once, damaged stores, a
worker killed, Ctrl-C; every case checks the exit status, stderr, the files left and the output's bytes; one table.

    python tools/faults.py [--points 300000] [--tile-size 32] [--workdir DIR] [--only CLASS ...] [--results PATH]
                           [--keep]

Every case runs ``patchcloud`` (``python -m patchcloud.stream.cli``) as a process group of its own on a synthetic
city (``tools/city_las.py``, seed 0, ``--points`` points, tiles of ``--tile-size`` metres, on disk, the synchronous
scheduler unless the case says otherwise), injects its fault and checks:

- the exit status: 2 for an error, 130 for Ctrl-C, 0 for a success;
- stderr: a failure is exactly one line starting ``error: ``, no traceback; a success (``-q``) prints nothing, but
  for the note of each stale lock it takes over (``note: ...: taking over a stale lock (pid N on this host is
  dead)``) after a run killed with ``kill -9``;
- the files left: no ``*.partial``, ``*.parts``, ``*.tmp``, lock or half-written output; the default store
  ``OUT.store`` removed, or kept and named in the error line ("the store OUT.store, N MiB, is kept");
- the output's bytes: after the fault, the same command again (the resume) exits 0 and writes a file
  byte-identical to a clean run's (patchcloud's outputs are deterministic), and removes the default store.

Classes (``--only``):

``disk-full``
    the output and its default store on a tmpfs that fills: one too small for the run (it fills in the tiling, in
    the steps, in the output's write), or a large one filled up by this script when the run reaches a step (the
    tiles' sort, the fit, the seams, the finish, the output's write; or at once); ``normals`` on disk, with worker
    processes and in memory, ``don``, ``compress``, ``decompress``, ``render``.  Expected: exit 2, one line saying
    "No space left on device", no temporary file; then, the space given back, the same command resumes.  Needs
    root (``mount -t tmpfs``): skipped otherwise.
``kill-9``
    the process group killed when the store shows a step's mark (``tiles/*/zarr.json`` ``done``, the root's
    ``steps``), a step's working files, ``OUT.partial`` or the store's removal; synchronous and worker processes;
    ``normals``, ``don``, ``compress``.  The same command then takes the dead run's lock over and resumes.  And
    the state of a run killed between its output's rename and the store's record of it, made by hand.
``concurrent``
    two runs on one output (started together, or the second mid-run, with ``--overwrite``, in memory), two runs
    on one ``--store`` (the same job or another), ``patchcloud tile`` on the store of a running job: one writes,
    the other stops with one line saying it is locked; the output is a clean run's.
``corrupt-store``
    a kept ``--store`` damaged (a chunk deleted, a byte flipped, garbage or an empty file for a chunk, an array
    moved from another tile, array metadata removed, a tile removed, the index damaged, the version or format
    mark removed or altered, garbage for the root metadata), then a run to a new output from it; and stores of a
    run killed mid-way, damaged, then the same command.  Expected: exit 2 and one line saying the store is
    damaged and what to do; or, where the damage is in data the run does not read, exit 0 and the clean bytes;
    never exit 0 with other bytes.
``worker-killed``
    with ``--scheduler processes --workers 2``, one worker process (a child of the command) killed in the
    tiling, the fit, the finish or the export; both at once; one killed again and again.  Expected: exit 0 and
    the clean bytes (dask reruns the tasks), or exit 2 with one line and the store named; which is recorded.
``ctrl-c``
    SIGINT to the process group (what Ctrl-C in a terminal sends) in each step, with worker processes, in memory,
    and twice in a row: exit 130 (or killed by SIGINT, which a shell reports as 130 too), one line naming the kept
    store, no lock left; the same command resumes.

Needs Linux (``/proc``).  Case directories are removed once a case passes (``--keep`` keeps them); a failed case's
is kept for inspection, and its reproduction, stderr and reasons are printed under the table.  Exits 1 if a case
failed.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import random
import shlex
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "CLASSES", "JOBS", "KILL_POINTS", "DAMAGE", "MIDWAY", "Case", "Run", "Result", "Proc", "Lab", "Reference", "Skip", "Hung",
    "main", "run_classes", "attempt", "format_table", "error_problems", "store_note_problems", "success_problems",
    "leftover_problems", "same_bytes_problems", "disk_full", "kill_9", "concurrent", "corrupt_store", "worker_killed", "ctrl_c",
]

HERE = Path(__file__).resolve().parent
#: The command line: the installed package's CLI, run by this interpreter.
CLI = [sys.executable, "-m", "patchcloud.stream.cli"]
#: Seconds a command may take before the case is failed as hung.
TIMEOUT = 300.0
#: Seconds between two looks at a running job's store.
POLL = 0.005
#: Names no run may leave behind (beside what a case allows).
JUNK = (".partial", ".parts", ".tmp", ".lock", ".takeover")

#: job -> (subcommand and its options, output suffix, whether it runs on a store).
JOBS = {
    "normals": (["normals"], ".laz", True),
    "don": (["don"], ".laz", True),
    "compress": (["compress"], ".pcz", True),
    "decompress": (["decompress"], ".laz", False),
    "render": (["render", "--color", "elevation"], ".png", False),
}


class Skip(Exception):
    """A case that cannot run here (no tmpfs, or its trigger was never reached); the message says why."""


class Hung(Exception):
    """A command that did not end in :data:`TIMEOUT` seconds (its process group was killed)."""


@dataclass
class Run:
    """A finished command: exit status, stderr, wall seconds."""

    code: int
    err: str
    seconds: float

    @property
    def lines(self) -> list[str]:
        """stderr's non-empty lines."""
        return [ln for ln in self.err.splitlines() if ln.strip()]


@dataclass
class Result:
    """One case: its fault class, name, status ("pass", "fail", "skip"), why it failed or was skipped, what happened,
    how to reproduce it and the stderr that matters."""

    fault: str
    case: str
    status: str
    why: str = ""
    note: str = ""
    repro: str = ""
    stderr: str = ""
    seconds: float = 0.0


@dataclass
class Reference:
    """A clean run's output (its path and bytes) and the bytes its store took on disk at the end (0: no store)."""

    path: Path
    data: bytes
    store_bytes: int = 0


# -- processes ------------------------------------------------------------------------------------------------


def _stat(pid: int) -> list[str] | None:
    """Fields of /proc/PID/stat after the command name (state, ppid, pgrp, ...); None when gone."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None


def _pids() -> list[int]:
    return [int(d) for d in os.listdir("/proc") if d.isdigit()]


def group_members(pgid: int) -> list[int]:
    """Live (not zombie) processes of process group ``pgid``."""
    out = []
    for pid in _pids():
        st = _stat(pid)
        if st is not None and st[0] != "Z" and int(st[2]) == pgid:
            out.append(pid)
    return out


def worker_pids(parent: int) -> list[int]:
    """The dask worker processes ``parent`` spawned (multiprocessing's ``spawn_main``), oldest first."""
    out = []
    for pid in _pids():
        st = _stat(pid)
        if st is None or int(st[1]) != parent or st[0] == "Z":
            continue
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                if b"spawn_main" in f.read():
                    out.append(pid)
        except OSError:
            continue
    return sorted(out)


class Proc:
    """A command running as a process group of its own (so that signals reach it and its workers as Ctrl-C in a
    terminal would), its stderr in a log file."""

    def __init__(self, argv: list[str], log: Path) -> None:
        self.argv = argv
        self.log = log
        self.t0 = time.monotonic()
        with open(log, "w") as err:
            self.p = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)

    @property
    def pid(self) -> int:
        return self.p.pid

    def running(self) -> bool:
        return self.p.poll() is None

    def signal(self, sig: int) -> None:
        """Send ``sig`` to the whole group."""
        try:
            os.killpg(self.p.pid, sig)
        except ProcessLookupError:
            pass

    def until(self, trigger: Callable[[], bool], timeout: float = TIMEOUT) -> bool:
        """Wait until ``trigger()`` is true (True) or the command ends (False)."""
        while self.running():
            if trigger():
                return True
            if time.monotonic() - self.t0 > timeout:
                self.signal(signal.SIGKILL)
                self.p.wait()
                raise Hung(f"no exit after {timeout:.0f} s")
            time.sleep(POLL)
        return False

    def wait(self, timeout: float = TIMEOUT) -> Run:
        """Wait for the command to end; its exit status (a signal's number negated), stderr and seconds."""
        try:
            code = self.p.wait(timeout=max(1.0, timeout - (time.monotonic() - self.t0)))
        except subprocess.TimeoutExpired:
            self.signal(signal.SIGKILL)
            self.p.wait()
            raise Hung(f"no exit after {timeout:.0f} s") from None
        return Run(code, self.log.read_text(errors="replace"), time.monotonic() - self.t0)

    def stray(self, grace: float = 10.0) -> list[int]:
        """Processes of the group still alive ``grace`` seconds after the command ended (then killed)."""
        end = time.monotonic() + grace
        while group_members(self.p.pid) and time.monotonic() < end:
            time.sleep(0.1)
        left = group_members(self.p.pid)
        self.signal(signal.SIGKILL)
        return left


# -- what a case looks at ---------------------------------------------------------------------------------------


def attrs(group: Path) -> dict:
    """The attributes of the zarr group at ``group`` as on disk now; {} when absent or being written."""
    try:
        return json.loads((group / "zarr.json").read_text()).get("attributes", {}) or {}
    except (OSError, ValueError, AttributeError):
        return {}


def step_marked(store: Path, step: str) -> Callable[[], bool]:
    """A trigger: the store's root marks ``step`` done."""
    return lambda: step in (attrs(store).get("steps") or {})


def attr_set(store: Path, name: str) -> Callable[[], bool]:
    """A trigger: the store's root has attribute ``name``."""
    return lambda: name in attrs(store)


def tiles_marked(store: Path, step: str, fraction: float) -> Callable[[], bool]:
    """A trigger: at least ``fraction`` of the store's tiles (at least one) mark ``step`` done."""

    def trigger() -> bool:
        tiles = attrs(store).get("tiles")
        if not tiles:
            return False
        try:
            done = sum(1 for d in (store / "tiles").iterdir() if (attrs(d).get("done") or {}).get(step))
        except OSError:
            return False
        return done >= max(1, math.ceil(fraction * len(tiles)))

    return trigger


def exists(path: Path) -> Callable[[], bool]:
    """A trigger: ``path`` exists."""
    return path.exists


def pcz_being_built(out: Path) -> Callable[[], bool]:
    """A trigger: the directory a ``.pcz`` is built in before it is zipped (``OUT.XXXXXXXX`` beside ``out``) exists."""
    return lambda: any(p.is_dir() and p.suffix not in (".store", ".parts") for p in out.parent.glob(out.name + ".*"))


def store_being_removed(store: Path) -> Callable[[], bool]:
    """A trigger: the run is removing its store (renamed ``STORE.removing`` first, then removed entry by entry)."""
    return Path(str(store) + ".removing").exists


def disk_bytes(path: Path) -> int:
    """Bytes ``path`` (a file or a tree) takes on disk (blocks, as a tmpfs counts them)."""
    if path.is_file():
        return path.stat().st_blocks * 512
    return sum(f.lstat().st_blocks * 512 for f in path.rglob("*")) if path.exists() else 0


def steps_done(store: Path) -> str:
    """The steps the store's root marks done, for a case's note ("no store" when none)."""
    if not store.exists():
        return "no store"
    return "store steps done: " + (", ".join(attrs(store).get("steps") or {}) or "none")


def chunk_files(array: Path) -> list[Path]:
    """The chunk files of the zarr array at ``array``, in name order."""
    return sorted(p for p in (array / "c").rglob("*") if p.is_file()) if (array / "c").exists() else []


# -- checks: each returns what is wrong, [] when nothing is --------------------------------------------------------


def error_problems(run: Run, code: int, needles: tuple[str, ...] = ()) -> list[str]:
    """A failed run: exit ``code``, stderr one line starting "error: " holding every needle (any case), no traceback."""
    bad = []
    if run.code != code and not (code == 130 and run.code == -signal.SIGINT):  # killed by SIGINT: a shell says 130 too
        bad.append(f"exit {run.code}, expected {code}")
    if "Traceback" in run.err:
        bad.append("a traceback on stderr")
    lines = run.lines
    if len(lines) != 1:
        bad.append(f"{len(lines)} lines on stderr, expected 1")
    if not lines or not lines[-1].startswith("error: "):
        bad.append("stderr's line does not start with 'error: '")
    line = lines[-1].lower() if lines else ""
    bad += [f"the line does not say {n!r}" for n in needles if n.lower() not in line]
    return bad


def store_note_problems(run: Run, store: Path) -> list[str]:
    """A failed run's default store: removed, or kept and named in its line with "is kept"."""
    line = run.lines[-1] if run.lines else ""
    if store.exists() and not (str(store) in line and "is kept" in line):
        return [f"the store {store.name} is left but the line does not name it as kept"]
    if not store.exists() and "is kept" in line:
        return [f"the line says the store is kept, but {store.name} is not there"]
    return []


def success_problems(run: Run, takeovers: int = 0) -> list[str]:
    """A successful quiet run: exit 0, nothing on stderr but the note of each stale lock it took over."""
    bad = [] if run.code == 0 else [f"exit {run.code}, expected 0"]
    notes = [ln for ln in run.lines if ln.startswith("note: ") and "taking over a stale lock" in ln and "is dead" in ln]
    other = [ln for ln in run.lines if ln not in notes]
    if other:
        bad.append(f"{len(other)} unexpected lines on stderr")
    if len(notes) != takeovers:
        bad.append(f"{len(notes)} stale-lock notes, expected {takeovers} (one per lock the killed run left)")
    return bad


def leftover_problems(directory: Path, allowed: set[str]) -> list[str]:
    """Everything in ``directory`` is in ``allowed`` (names); what else is there, temporary files first."""
    names = sorted(p.name for p in directory.iterdir()) if directory.exists() else []
    junk = [n for n in names if n.endswith(JUNK) or ".lock." in n]
    other = [n for n in names if n not in allowed and n not in junk]
    bad = [f"left behind: {', '.join(junk)}"] if junk else []
    return bad + ([f"unexpected files: {', '.join(other)}"] if other else [])


def same_bytes_problems(path: Path, ref: Reference) -> list[str]:
    """``path`` holds a clean run's bytes."""
    if not path.is_file():
        return [f"no output {path.name}"]
    data = path.read_bytes()
    if data != ref.data:
        return [f"{path.name} differs from a clean run's output ({len(data):,} bytes against {len(ref.data):,})"]
    return []


# -- the lab: input, references, commands -----------------------------------------------------------------------


class Lab:
    """The input, the clean runs' outputs and the commands of the cases, under ``workdir``."""

    def __init__(self, workdir: Path, points: int, tile_size: float, keep: bool = False) -> None:
        self.workdir = workdir
        self.made: set[Path] = set()  # what this run made once in the work directory
        self.points = points
        self.tile_size = tile_size
        self.keep = keep
        self.refs: dict[str, Reference] = {}
        workdir.mkdir(parents=True, exist_ok=True)
        self.input = workdir / f"city-{points}.laz"
        if not self.input.exists():
            subprocess.run([sys.executable, str(HERE / "city_las.py"), str(self.input), "--points", str(points)],
                           check=True, stdout=subprocess.DEVNULL)

    def argv(self, job: str, out: Path, scheduler: str | None = "synchronous", extra: tuple[str, ...] = ()) -> list[str]:
        """The command of ``job`` writing ``out``: on disk with ``scheduler`` (processes: 2 workers), or in memory
        (``scheduler`` None, the default for small inputs); quiet."""
        sub, _, on_store = JOBS[job]
        source = self.reference("compress").path if job == "decompress" else self.input
        argv = [*CLI, sub[0], str(source), str(out), *sub[1:], "-q", *extra]
        if on_store:
            argv += ["--tile-size", f"{self.tile_size:g}"]
            if scheduler is not None:
                argv += ["--on-disk", "--scheduler", scheduler] + (["--workers", "2"] if scheduler == "processes" else [])
        return argv

    def reference(self, job: str) -> Reference:
        """A clean run of ``job`` (synchronous, its store kept to measure it, then removed), made once."""
        if job not in self.refs:
            d = self.workdir / "reference" / job
            shutil.rmtree(d, ignore_errors=True)
            d.mkdir(parents=True)
            out = d / f"out{JOBS[job][1]}"
            store = Path(str(out) + ".store")
            argv = self.argv(job, out) + (["--keep-store"] if JOBS[job][2] else [])
            r = Proc(argv, self.workdir / f"reference-{job}.err").wait()
            if r.code != 0:
                raise SystemExit(f"the clean run failed: {show(argv)}\n{r.err}")
            self.refs[job] = Reference(out, out.read_bytes(), disk_bytes(store))
            shutil.rmtree(store, ignore_errors=True)
        return self.refs[job]

    def case_dir(self, fault: str, case: str) -> Path:
        """A fresh, empty directory for one case."""
        slug = "".join(c if c.isalnum() else "-" for c in case.lower()).strip("-")
        d = self.workdir / fault / slug
        _unmount_below(d)
        shutil.rmtree(d, ignore_errors=True)
        d.mkdir(parents=True)
        return d

    def start(self, argv: list[str], d: Path, name: str = "run") -> Proc:
        """Start ``argv``, its stderr in ``d``'s parent (so the case directory holds only what the run writes)."""
        return Proc(argv, d.parent / f"{d.name}.{name}.err")

    def run(self, argv: list[str], d: Path, name: str = "run") -> Run:
        """Run ``argv`` to its end."""
        return self.start(argv, d, name).wait()


def show(argv: list[str]) -> str:
    """``argv`` as a shell line, the CLI as ``patchcloud``."""
    return shlex.join(["patchcloud", *argv[len(CLI):]] if argv[: len(CLI)] == CLI else argv)


# -- tmpfs ------------------------------------------------------------------------------------------------------


def mount_tmpfs(path: Path, size: int) -> None:
    """Mount a tmpfs of ``size`` bytes (rounded up to KiB) at ``path``; Skip where that is not allowed."""
    path.mkdir(parents=True, exist_ok=True)
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={-(-size // 1024)}k", "tmpfs", str(path)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise Skip("cannot mount a tmpfs (needs root): " + (r.stderr.strip() or f"mount exit {r.returncode}"))


def grow_tmpfs(path: Path, size: int) -> None:
    """Give the tmpfs at ``path`` ``size`` bytes."""
    subprocess.run(["mount", "-o", f"remount,size={-(-size // 1024)}k", str(path)], check=True, capture_output=True)


def unmount(path: Path) -> None:
    """Unmount ``path`` (lazily if busy)."""
    if subprocess.run(["umount", str(path)], capture_output=True).returncode != 0:
        subprocess.run(["umount", "-l", str(path)], capture_output=True)


def _unmount_below(d: Path) -> None:
    """Unmount every file system mounted at or under ``d`` (a case directory about to be removed)."""
    try:
        mounts = [line.split()[1] for line in Path("/proc/mounts").read_text().splitlines()]
    except OSError:
        return
    for m in sorted(mounts, reverse=True):
        if m == str(d) or m.startswith(str(d) + "/"):
            unmount(Path(m))


def can_mount_tmpfs(workdir: Path) -> str | None:
    """None when a tmpfs can be mounted here, else why not."""
    probe = workdir / "tmpfs-probe"
    try:
        mount_tmpfs(probe, 1 << 20)
    except Skip as exc:
        return str(exc)
    unmount(probe)
    probe.rmdir()
    return None


# -- the cases --------------------------------------------------------------------------------------------------


@dataclass
class Case:
    """One case: its name, how to reproduce it, and ``run(d)``, which plays it in the empty directory ``d`` and returns
    what is wrong ([] when nothing) and a note of what happened."""

    name: str
    repro: str
    run: Callable[[Path], tuple[list[str], str]]


def resume(lab: Lab, argv: list[str], d: Path, out: Path, ref: Reference, takeovers: int = 0) -> list[str]:
    """The same command again after a fault: exit 0, the clean bytes, nothing left in ``d`` but the output."""
    r = lab.run(argv, d, "resume")
    bad = success_problems(r, takeovers) + same_bytes_problems(out, ref) + leftover_problems(d, {out.name})
    return [f"resume: {b}" for b in bad]


def locks_left(d: Path) -> int:
    """Lock files in ``d`` (what a killed run leaves)."""
    return sum(1 for p in d.iterdir() if p.name.endswith(".lock"))


def not_reached(run: Run, ref: Reference, out: Path, what: str) -> tuple[list[str], str]:
    """A run that ended before its fault: a Skip when it succeeded with the clean bytes, else what is wrong."""
    bad = success_problems(run) + same_bytes_problems(out, ref)
    if bad:
        return [f"the run ended before {what}: " + "; ".join(bad)], ""
    raise Skip(f"the run ended before {what} ({run.seconds:.1f} s)")


def partial(out: Path) -> Path:
    """Where a job writes ``out`` before renaming it."""
    return out.with_name(out.name + ".partial")


def default_store(out: Path) -> Path:
    """The default store of a job writing ``out``."""
    return Path(str(out) + ".store")


def last_line(run: Run) -> str:
    """A run's last stderr line, shortened, for a note."""
    return run.lines[-1][:220] if run.lines else f"exit {run.code}, nothing on stderr"


# disk full


def disk_full(lab: Lab) -> list[Case]:
    """The output (and its default store) on a tmpfs that fills during the run; see the module's docstring."""
    why = can_mount_tmpfs(lab.workdir)
    if why is not None:
        raise Skip(why)
    cases = []
    for job, where, scheduler, how in (
        ("normals", "too small, fills in the tiling", "synchronous", lambda r: r.store_bytes // 10),
        ("normals", "too small, fills in the steps", "synchronous", lambda r: r.store_bytes // 2),
        ("normals", "filled as the tiles are sorted", "synchronous", lambda s, o: tiles_marked(s, "sort", 0.3)),
        ("normals", "filled in the fit", "synchronous", lambda s, o: tiles_marked(s, "fit", 0.3)),
        ("normals", "filled in the seams", "synchronous", lambda s, o: exists(s / "seams")),
        ("normals", "filled in the finish", "synchronous", lambda s, o: tiles_marked(s, "finish", 0.3)),
        ("normals", "filled in the output's write", "synchronous", lambda s, o: exists(partial(o))),
        ("normals", "filled in the output's write (processes)", "processes", lambda s, o: exists(partial(o))),
        ("normals", "too small for the output", None, lambda r: len(r.data) // 2),
        ("normals", "full from the start", "synchronous", lambda s, o: lambda: True),
        ("don", "filled in the steps", "synchronous", lambda s, o: tiles_marked(s, "don", 0.3)),
        ("don", "filled in the output's write", "synchronous", lambda s, o: exists(partial(o))),
        ("compress", "filled in the steps", "synchronous", lambda s, o: tiles_marked(s, "compress", 0.3)),
        ("compress", "filled in the output's write", "synchronous", lambda s, o: pcz_being_built(o)),
        ("decompress", "too small for the output", "synchronous", lambda r: len(r.data) // 2),
        ("render", "too small for the output", "synchronous", lambda r: len(r.data) // 2),
    ):
        name = f"{job}{' in memory' if scheduler is None else ''}: {where}"
        command = show(lab.argv(job, Path("D/OUT"), scheduler))
        if where.startswith("too small"):
            repro = f"mount -t tmpfs -o size=SIZE tmpfs D; {command}"
        else:
            repro = f"mount -t tmpfs tmpfs D; {command}; fill D {where.removeprefix('filled ')}"
        cases.append(Case(name, repro, lambda d, job=job, scheduler=scheduler, how=how, small=where.startswith("too small"):
                          _disk_full_case(lab, d, job, scheduler, how if small else None, None if small else how)))
    return cases


def _disk_full_case(lab: Lab, d: Path, job: str, scheduler: str | None, size, fill) -> tuple[list[str], str]:
    """Run ``job`` onto a tmpfs of ``size(reference)`` bytes, or a large one that is filled up when ``fill(store,
    output)`` becomes true; then give the space back and run it again."""
    mnt = d / "mnt"
    ref = lab.reference(job)
    out = mnt / ref.path.name
    store = default_store(out)
    space = size(ref) if size is not None else 4 * (ref.store_bytes + len(ref.data)) + (64 << 20)
    mount_tmpfs(mnt, space)
    try:
        argv = lab.argv(job, out, scheduler)
        p = lab.start(argv, d)
        if fill is not None and p.until(fill(store, out)):
            _fill(mnt / "filler")
        r = p.wait()
        p.stray()
        if r.code == 0:
            raise Skip(f"the disk did not fill in time ({space:,} bytes)" if fill is None else "the run ended before the disk was full")
        note = f"{steps_done(store)}; {last_line(r)}"
        bad = error_problems(r, 2, ("no space left on device",)) + store_note_problems(r, store)
        bad += leftover_problems(mnt, {store.name, "filler"})
        (mnt / "filler").unlink(missing_ok=True)
        grow_tmpfs(mnt, 4 * (ref.store_bytes + len(ref.data)) + (64 << 20))
        return bad + resume(lab, argv, mnt, out, ref, locks_left(mnt)), note
    finally:
        unmount(mnt)


def _fill(path: Path) -> None:
    """Write ``path`` until its file system is full."""
    block = b"\0" * 4096
    with open(path, "wb", buffering=0) as f:
        try:
            while True:
                f.write(block)
        except OSError:
            pass


# kill -9

#: kill -9 points: (case, job, scheduler, trigger of the store and the output).
KILL_POINTS = (
    ("tile: parts being read", "normals", "synchronous", lambda s, o: exists(s / "parts")),
    ("tile: parts read, bucketed", "normals", "synchronous", lambda s, o: step_marked(s, "bucket")),
    ("tile: half the tiles sorted", "normals", "synchronous", lambda s, o: tiles_marked(s, "sort", 0.5)),
    ("tile: done", "normals", "synchronous", lambda s, o: step_marked(s, "tile")),
    ("calibrate: done", "normals", "synchronous", lambda s, o: attr_set(s, "calibration")),
    ("fit: half the tiles", "normals", "synchronous", lambda s, o: tiles_marked(s, "fit", 0.5)),
    ("seams: working files written", "normals", "synchronous", lambda s, o: exists(s / "seams")),
    ("seams: done", "normals", "synchronous", lambda s, o: step_marked(s, "seams")),
    ("finish: half the tiles", "normals", "synchronous", lambda s, o: tiles_marked(s, "finish", 0.5)),
    ("export: OUT.partial being written", "normals", "synchronous", lambda s, o: exists(partial(o))),
    ("output written, the store being removed", "normals", "synchronous", lambda s, o: store_being_removed(s)),
    ("fit: half the tiles (processes)", "normals", "processes", lambda s, o: tiles_marked(s, "fit", 0.5)),
    ("finish: half the tiles (processes)", "normals", "processes", lambda s, o: tiles_marked(s, "finish", 0.5)),
    ("export: OUT.partial being written (processes)", "normals", "processes", lambda s, o: exists(partial(o))),
    ("don: half the tiles", "don", "synchronous", lambda s, o: tiles_marked(s, "don", 0.5)),
    ("don: OUT.partial being written", "don", "synchronous", lambda s, o: exists(partial(o))),
    ("compress: half the tiles", "compress", "synchronous", lambda s, o: tiles_marked(s, "compress", 0.5)),
    ("compress: the .pcz being built", "compress", "synchronous", lambda s, o: pcz_being_built(o)),
)


def kill_9(lab: Lab) -> list[Case]:
    """kill -9 of the process group at each step, then the same command; see the module's docstring."""
    command = show(lab.argv("normals", Path("OUT")))
    return [
        Case(name, f"{show(lab.argv(job, Path('OUT'), scheduler))}; kill -9 the process group at '{name}'; the same command",
             lambda d, job=job, scheduler=scheduler, trigger=trigger: _kill_case(lab, d, job, scheduler, trigger))
        for name, job, scheduler, trigger in KILL_POINTS
    ] + [
        Case("output recorded in the store, not yet renamed (that state made by hand)",
             f"{command} --keep-store; mv OUT OUT.partial; {command}", lambda d: _unrenamed_case(lab, d)),
    ]


def _unrenamed_case(lab: Lab, d: Path) -> tuple[list[str], str]:
    """What a run killed between the store's record of its output and the rename of OUT.partial to OUT leaves (a window
    of about a millisecond, which no trigger here hits reliably; the record comes first, so that a run killed after the
    rename finds its output complete): made by a run keeping its store, whose output is then moved back."""
    ref = lab.reference("normals")
    out = d / ref.path.name
    argv = lab.argv("normals", out)
    r = lab.run(argv + ["--keep-store"], d, "first")
    if success_problems(r) or same_bytes_problems(out, ref):
        return ["the first run failed: " + "; ".join(success_problems(r) + same_bytes_problems(out, ref))], ""
    os.replace(out, partial(out))
    return resume(lab, argv, d, out, ref), "the store records the output; OUT.partial not yet renamed"


def _kill_case(lab: Lab, d: Path, job: str, scheduler: str, trigger) -> tuple[list[str], str]:
    ref = lab.reference(job)
    out = d / ref.path.name
    argv = lab.argv(job, out, scheduler)
    p = lab.start(argv, d)
    if not p.until(trigger(default_store(out), out)):
        return not_reached(p.wait(), ref, out, "the kill")
    p.signal(signal.SIGKILL)
    killed = p.wait()
    stray = p.stray()
    note = f"killed at {killed.seconds:.1f} s, leaving {', '.join(sorted(x.name for x in d.iterdir()))}"
    bad = [f"processes left after kill -9: {stray}"] if stray else []
    return bad + resume(lab, argv, d, out, ref, locks_left(d)), note


# two runs at once

LOCKED = ("another patchcloud run",)


def concurrent(lab: Lab) -> list[Case]:
    """Two runs on one output or one store; see the module's docstring."""
    on_disk = show(lab.argv("normals", Path("OUT")))
    with_store = show(lab.argv("normals", Path("OUT"), extra=("--store", "S")))

    def same_output(d: Path, s: Path, *extra: str) -> list[str]:
        return lab.argv("normals", d / "out.laz", extra=extra)

    def other_output(job: str) -> Callable[[Path, Path], list[str]]:
        return lambda d, s: lab.argv(job, d / f"other{JOBS[job][1]}", extra=("--store", str(s)))

    def tile_command(d: Path, s: Path) -> list[str]:
        return [*CLI, "tile", str(lab.input), str(s), "--tile-size", f"{lab.tile_size / 2:g}", "--scheduler", "synchronous", "-q"]

    return [
        Case("same output, started together", f"two of: {on_disk}", lambda d: _together(lab, d, "synchronous")),
        Case("same output, started together, in memory", f"two of: {show(lab.argv('normals', Path('OUT'), None))}",
             lambda d: _together(lab, d, None)),
        Case("same output, the second mid-run", f"{on_disk}; while it fits, the same command",
             lambda d: _second_mid_run(lab, d, same_output, False)),
        Case("same output, the second mid-run with --overwrite", f"{on_disk}; while it fits, the same with --overwrite",
             lambda d: _second_mid_run(lab, d, lambda d, s: same_output(d, s, "--overwrite"), False)),
        Case("same --store, another output", f"{with_store}; while it fits, the same to OUT2",
             lambda d: _second_mid_run(lab, d, other_output("normals"), True)),
        Case("same --store, another job (don)", f"{with_store}; while it fits, patchcloud don IN OUT2 --store S",
             lambda d: _second_mid_run(lab, d, other_output("don"), True)),
        Case("patchcloud tile (other tile size) on a running job's --store",
             f"{with_store}; while it fits, patchcloud tile IN S --tile-size {lab.tile_size / 2:g}",
             lambda d: _second_mid_run(lab, d, tile_command, True)),
    ]


def _together(lab: Lab, d: Path, scheduler: str | None) -> tuple[list[str], str]:
    """Two runs of one command started together: one writes the output, the other stops with one line."""
    out = d / "out.laz"
    argv = lab.argv("normals", out, scheduler)
    procs = [lab.start(argv, d, f"run{k}") for k in (1, 2)]
    runs = [p.wait() for p in procs]
    codes = sorted(r.code for r in runs)
    bad = [] if codes == [0, 2] else [f"exit statuses {codes}, expected [0, 2]"]
    for r in runs:
        bad += success_problems(r) if r.code == 0 else error_problems(r, 2)
        if r.code == 2 and not any(n in r.err for n in ("another patchcloud run", "exists")):
            bad.append("the stopped run's line says neither that the output is locked nor that it exists")
    bad += same_bytes_problems(out, lab.reference("normals")) + leftover_problems(d, {out.name})
    return bad, last_line(next((r for r in runs if r.code != 0), runs[0]))


def _second_mid_run(lab: Lab, d: Path, second: Callable[[Path, Path], list[str]], with_store: bool) -> tuple[list[str], str]:
    """A run (with ``--store d/s.zarr`` when ``with_store``), and ``second(d, store)`` started while it fits: the second
    stops with one line naming the first; the first writes the clean bytes."""
    ref = lab.reference("normals")
    out, store = d / "out.laz", d / "s.zarr"
    first = lab.start(lab.argv("normals", out, extra=("--store", str(store)) if with_store else ()), d, "first")
    if not first.until(tiles_marked(store if with_store else default_store(out), "fit", 0.3)):
        return not_reached(first.wait(), ref, out, "the second run")
    r2 = lab.run(second(d, store), d, "second")
    r1 = first.wait()
    bad = [f"second run: {b}" for b in error_problems(r2, 2, LOCKED)]
    if f"pid {first.pid}" not in r2.err:
        bad.append(f"the second run's line does not name the first run (pid {first.pid})")
    bad += [f"first run: {b}" for b in success_problems(r1)] + same_bytes_problems(out, ref)
    return bad + leftover_problems(d, {out.name, store.name} if with_store else {out.name}), last_line(r2)


# damaged stores


def _flip(path: Path, at: int = -5) -> None:
    """Flip one bit of byte ``at`` of the file ``path``."""
    raw = bytearray(path.read_bytes())
    raw[at] ^= 0x01
    path.write_bytes(bytes(raw))


def _garbage(path: Path) -> None:
    """Random bytes in place of the file ``path`` (as long, at least 16)."""
    path.write_bytes(random.Random(0).randbytes(max(16, path.stat().st_size)))


def _set_root(store: Path, **changes) -> None:
    """Change (None: remove) attributes in the store's root ``zarr.json``."""
    meta = json.loads((store / "zarr.json").read_text())
    for k, v in changes.items():
        if v is None:
            meta["attributes"].pop(k, None)
        else:
            meta["attributes"][k] = v
    (store / "zarr.json").write_text(json.dumps(meta))


def _tiles(store: Path, array: str) -> list[Path]:
    """The store's tile groups holding ``array``, largest array first."""
    tiles = [t for t in (store / "tiles").iterdir() if (t / array / "zarr.json").exists()]
    return sorted(tiles, key=lambda t: (-json.loads((t / array / "zarr.json").read_text())["shape"][0], t.name))


def _victim(store: Path, array: str) -> Path:
    """The array ``array`` of the store's largest tile."""
    return _tiles(store, array)[0] / array


def _swap_in_larger(store: Path) -> str:
    """Replace the normals of a tile by the (larger) normals of another tile of the same store."""
    tiles = _tiles(store, "normal")
    big, small = tiles[0], tiles[len(tiles) // 2]
    shutil.rmtree(small / "normal")
    shutil.copytree(big / "normal", small / "normal")
    return f"{small.name}/normal replaced by {big.name}/normal"


def _copy_array(src: Path, dst: Path, array: str) -> str:
    """Replace ``array`` of ``dst``'s largest tile by the same tile's array in the store ``src``."""
    victim = _victim(dst, array)
    shutil.rmtree(victim)
    shutil.copytree(src / "tiles" / victim.parent.name / array, victim)
    return f"{victim.parent.name}/{array} copied from {src.name}"


#: What the line of a run on a damaged store says.
DAMAGED = ("the store is damaged", "remove the store")
#: ... on a store that is not one (no format mark, unreadable root metadata).
NOT_A_STORE = ("not a patchcloud store", "remove")

#: Damage to a finished store: (case, what is done to it, the needles of the error line, whether exit 0 with the
#: clean bytes is right too: the damage is in data a run to a new output does not read).
DAMAGE = (
    ("a chunk of a tile's normals deleted", lambda s: chunk_files(_victim(s, "normal"))[0].unlink(), DAMAGED, False),
    ("a byte flipped in a tile's curvature", lambda s: _flip(chunk_files(_victim(s, "curvature"))[0]), DAMAGED, False),
    ("a tile's patch-id chunk replaced by random bytes", lambda s: _garbage(chunk_files(_victim(s, "patch"))[0]), DAMAGED, False),
    ("a tile's method chunk emptied", lambda s: chunk_files(_victim(s, "method"))[0].write_bytes(b""), DAMAGED, False),
    ("a tile's normals array metadata removed", lambda s: (_victim(s, "normal") / "zarr.json").unlink(), DAMAGED, False),
    ("a tile's normals moved from a larger tile", _swap_in_larger, DAMAGED, False),
    ("a tile's group metadata replaced by garbage", lambda s: (_victim(s, "normal").parent / "zarr.json").write_text("{garbage"),
     DAMAGED, False),
    ("a whole tile removed", lambda s: shutil.rmtree(_victim(s, "normal").parent), DAMAGED, False),
    ("a chunk of the index deleted", lambda s: chunk_files(s / "index" / "part_tile")[0].unlink(), DAMAGED, False),
    ("a byte flipped in a tile's xyz (not read by an export)", lambda s: _flip(chunk_files(_victim(s, "xyz"))[0]), DAMAGED, True),
    ("the store's version mark removed", lambda s: _set_root(s, version=None), ("not supported", "remove the store"), False),
    ("the store's version mark altered", lambda s: _set_root(s, version=1), ("not supported", "remove the store"), False),
    ("the store's format mark removed", lambda s: _set_root(s, format=None), NOT_A_STORE, False),
    ("the store's root metadata replaced by garbage", lambda s: (s / "zarr.json").write_text("\x00garbage"), NOT_A_STORE, False),
)

#: Damage to the store of a run killed mid-way, before the same command: (case, kill trigger, damage (store, another
#: store of the same input), needles).
MIDWAY = (
    ("killed after tiling; a byte flipped in a tile's xyz", lambda s: step_marked(s, "tile"),
     lambda s, other: _flip(chunk_files(_victim(s, "xyz"))[0]), DAMAGED),
    ("killed after tiling; a tile's xyz copied from another store", lambda s: step_marked(s, "tile"),
     lambda s, other: _copy_array(other, s, "xyz"), DAMAGED),
    ("killed in the seams; a byte flipped in a tile's patches", lambda s: exists(s / "seams"),
     lambda s, other: _flip(chunk_files(_victim(s, "patches"))[0]), DAMAGED),
)


def corrupt_store(lab: Lab) -> list[Case]:
    """A damaged kept store, then a run from it; see the module's docstring."""
    kept = show(lab.argv("normals", Path("OUT"), extra=("--store", "S")))
    again = show(lab.argv("normals", Path("OUT2"), extra=("--store", "S")))
    cases = [Case(name, f"{kept}; {name}; {again}",
                  lambda d, damage=damage, needles=needles, may_pass=may_pass: _damaged_case(lab, d, damage, needles, may_pass))
             for name, damage, needles, may_pass in DAMAGE]
    return cases + [Case(name, f"{kept}; kill -9 the process group then; damage S; the same command",
                         lambda d, trigger=trigger, damage=damage, needles=needles: _midway_case(lab, d, trigger, damage, needles))
                    for name, trigger, damage, needles in MIDWAY]


def _kept_stores(lab: Lab) -> tuple[Path, Path]:
    """A finished normals run's kept store, and another store of the same input (``patchcloud tile``), made once a run
    (a store left in the work directory by an earlier version of patchcloud is not reused)."""
    base = lab.workdir / "corrupt-store" / "base"
    store, other = base / "s.zarr", base / "other.zarr"
    if base not in lab.made or not store.exists() or not other.exists():
        lab.made.add(base)
        shutil.rmtree(base, ignore_errors=True)
        base.mkdir(parents=True)
        r = lab.run(lab.argv("normals", base / "out.laz", extra=("--store", str(store))), base)
        if r.code != 0 or same_bytes_problems(base / "out.laz", lab.reference("normals")):
            raise SystemExit(f"the run making the kept store failed:\n{r.err}")
        lab.run([*CLI, "tile", str(lab.input), str(other), "--tile-size", f"{lab.tile_size:g}", "--scheduler", "synchronous",
                 "-q"], base, "other")
    return store, other


def _wrong_success(out: Path, ref: Reference) -> list[str]:
    """What an exit 0 on a damaged store wrote."""
    held = "the clean bytes" if not same_bytes_problems(out, ref) else "OTHER BYTES (silently wrong)"
    return [f"exit 0 on a damaged store, the output holding {held}"]


def _damaged_case(lab: Lab, d: Path, damage, needles: tuple[str, ...], may_pass: bool) -> tuple[list[str], str]:
    """A copy of the finished store damaged, then a run to a new output from it."""
    ref = lab.reference("normals")
    store, out = d / "s.zarr", d / "again.laz"
    shutil.copytree(_kept_stores(lab)[0], store)
    what = damage(store)
    r = lab.run(lab.argv("normals", out, extra=("--store", str(store))), d)
    note = (f"{what}; " if isinstance(what, str) else "") + last_line(r)
    if r.code == 0:
        if may_pass:
            return success_problems(r) + same_bytes_problems(out, ref) + leftover_problems(d, {out.name, store.name}), note
        return _wrong_success(out, ref), note
    bad = error_problems(r, 2, (str(store),) + needles)
    bad += ["the line says the same command resumes from a damaged store"] if "resumes from it" in r.err else []
    return bad + leftover_problems(d, {store.name}), note


def _midway_case(lab: Lab, d: Path, trigger, damage, needles: tuple[str, ...]) -> tuple[list[str], str]:
    """A run killed at ``trigger``, its store damaged, then the same command."""
    ref = lab.reference("normals")
    store, out = d / "s.zarr", d / "out.laz"
    other = _kept_stores(lab)[1]
    argv = lab.argv("normals", out, extra=("--store", str(store)))
    p = lab.start(argv, d)
    if not p.until(trigger(store)):
        return not_reached(p.wait(), ref, out, "the kill")
    p.signal(signal.SIGKILL)
    p.wait()
    what = damage(store, other)
    takeovers = locks_left(d)
    r = lab.run(argv, d, "again")
    note = (f"{what}; " if isinstance(what, str) else "") + last_line(r)
    if r.code == 0:
        return _wrong_success(out, ref), note
    notes = [ln for ln in r.lines if ln.startswith("note: ") and "taking over a stale lock" in ln]
    bad = [] if len(notes) == takeovers else [f"{len(notes)} stale-lock notes, expected {takeovers}"]
    rest = Run(r.code, "\n".join(ln for ln in r.lines if ln not in notes), r.seconds)
    return bad + error_problems(rest, 2, (str(store),) + needles) + leftover_problems(d, {store.name}), note


# a worker killed


def worker_killed(lab: Lab) -> list[Case]:
    """A worker process killed mid-run (``--scheduler processes --workers 2``); see the module's docstring."""
    command = show(lab.argv("normals", Path("OUT"), "processes"))
    return [
        Case(name, f"{command}; {what}", lambda d, trigger=trigger, kills=kills, both=both: _worker_case(lab, d, trigger, kills, both))
        for name, what, trigger, kills, both in (
            ("one worker, in the tiling", "kill -9 one worker once a tile is sorted",
             lambda s, o: tiles_marked(s, "sort", 0.1), 1, False),
            ("one worker, in the fit", "kill -9 one worker at a quarter of the tiles fitted",
             lambda s, o: tiles_marked(s, "fit", 0.25), 1, False),
            ("one worker, in the finish", "kill -9 one worker at a quarter of the tiles finished",
             lambda s, o: tiles_marked(s, "finish", 0.25), 1, False),
            ("one worker, in the export", "kill -9 one worker once OUT.partial exists", lambda s, o: exists(partial(o)), 1, False),
            ("both workers at once, in the fit", "kill -9 both workers at a quarter of the tiles fitted",
             lambda s, o: tiles_marked(s, "fit", 0.25), 1, True),
            ("a worker killed 4 times, from the fit on", "kill -9 the newest worker every second, 4 times, from the fit on",
             lambda s, o: tiles_marked(s, "fit", 0.1), 4, False),
        )
    ]


def _worker_case(lab: Lab, d: Path, trigger, kills: int, both: bool) -> tuple[list[str], str]:
    ref = lab.reference("normals")
    out = d / ref.path.name
    store = default_store(out)
    argv = lab.argv("normals", out, "processes")
    p = lab.start(argv, d)
    if not p.until(trigger(store, out)):
        return not_reached(p.wait(), ref, out, "the kill")
    killed = _kill_workers(p, kills, both)
    r = p.wait()
    stray = p.stray()
    bad = [f"processes left after the run: {stray}"] if stray else []
    if r.code == 0:
        bad += same_bytes_problems(out, ref) + leftover_problems(d, {out.name})
        bad += ["a traceback on stderr"] if "Traceback" in r.err else []
        return bad, f"{killed} worker(s) killed; exit 0 (dask reran the tasks), {len(r.lines)} dask log lines on stderr"
    bad += error_problems(r, 2) + store_note_problems(r, store) + leftover_problems(d, {store.name})
    return bad + resume(lab, argv, d, out, ref), f"{killed} worker(s) killed; exit {r.code}: {last_line(r)}"


def _kill_workers(p: Proc, kills: int, both: bool) -> int:
    """SIGKILL the newest worker of ``p`` (every worker with ``both``) ``kills`` times, a second apart, while it runs;
    how many were killed."""
    done = 0
    for k in range(kills):
        if k:
            time.sleep(1.0)
        workers = worker_pids(p.pid)
        if not p.running() or not workers:
            break
        for pid in workers if both else workers[-1:]:
            try:
                os.kill(pid, signal.SIGKILL)
                done += 1
            except ProcessLookupError:
                pass
    return done


# Ctrl-C


def ctrl_c(lab: Lab) -> list[Case]:
    """SIGINT to the process group; see the module's docstring."""

    def case(name: str, scheduler: str | None, when: str, trigger, twice: bool = False) -> Case:
        repro = f"{show(lab.argv('normals', Path('OUT'), scheduler))}; SIGINT to its process group {when}; the same command"
        return Case(name, repro, lambda d: _interrupt_case(lab, d, scheduler, trigger, twice))

    return [
        case("in the tiling", "synchronous", "once a part is read", lambda s, o: exists(s / "parts")),
        case("in the fit", "synchronous", "at half the tiles fitted", lambda s, o: tiles_marked(s, "fit", 0.5)),
        case("in the export", "synchronous", "once OUT.partial exists", lambda s, o: exists(partial(o))),
        case("twice in a row, in the finish", "synchronous", "twice, 50 ms apart, at half the tiles finished",
             lambda s, o: tiles_marked(s, "finish", 0.5), twice=True),
        case("in memory, in the steps", None, "3 s after the start", lambda s, o: after(3.0)),
        case("worker processes, in the fit", "processes", "at a quarter of the tiles fitted", lambda s, o: tiles_marked(s, "fit", 0.25)),
    ]


def _interrupt_case(lab: Lab, d: Path, scheduler: str | None, trigger, twice: bool) -> tuple[list[str], str]:
    ref = lab.reference("normals")
    out = d / ref.path.name
    store = default_store(out)
    argv = lab.argv("normals", out, scheduler)
    p = lab.start(argv, d)
    if not p.until(trigger(store, out)):
        return not_reached(p.wait(), ref, out, "Ctrl-C")
    p.signal(signal.SIGINT)
    if twice:
        time.sleep(0.05)
        p.signal(signal.SIGINT)
    r = p.wait()
    stray = p.stray()
    bad = [f"processes left after the run: {stray}"] if stray else []
    bad += error_problems(r, 130, ("interrupted",)) + store_note_problems(r, store) + leftover_problems(d, {store.name})
    note = f"exit {r.code}, {len(r.lines)} line(s): {last_line(r)}"
    return bad + resume(lab, argv, d, out, ref), note


def after(seconds: float) -> Callable[[], bool]:
    """A trigger: ``seconds`` after it is made."""
    end = time.monotonic() + seconds
    return lambda: time.monotonic() >= end


#: Fault classes: name -> (title in the table, the function listing its cases).
CLASSES: dict[str, tuple[str, Callable[[Lab], list[Case]]]] = {
    "disk-full": ("disk full", disk_full),
    "kill-9": ("kill -9 at each step", kill_9),
    "concurrent": ("two concurrent runs", concurrent),
    "corrupt-store": ("damaged store", corrupt_store),
    "worker-killed": ("a worker killed", worker_killed),
    "ctrl-c": ("Ctrl-C (SIGINT)", ctrl_c),
}


# -- running and reporting --------------------------------------------------------------------------------------


def attempt(lab: Lab, fault: str, case: Case) -> Result:
    """Run one case in a fresh directory; a Skip or a hang become its result."""
    t0 = time.perf_counter()
    d = lab.case_dir(fault, case.name)
    try:
        bad, note = case.run(d)
        status, why = ("fail", "; ".join(bad)) if bad else ("pass", "")
    except Skip as exc:
        status, why, note = "skip", str(exc), ""
    except Hung as exc:
        status, why, note = "fail", f"hung: {exc}", ""
    result = Result(fault, case.name, status, why, note, case.repro, seconds=time.perf_counter() - t0)
    if status == "fail":
        result.stderr = _stderr_of(d)
    elif not lab.keep:
        _unmount_below(d)
        shutil.rmtree(d, ignore_errors=True)
        for log in d.parent.glob(f"{d.name}.*.err"):
            log.unlink()
    return result


def _stderr_of(d: Path) -> str:
    """The stderr logs of a case's commands, each under its name."""
    parts = []
    for log in sorted(d.parent.glob(f"{d.name}.*.err")):
        text = log.read_text(errors="replace").strip()
        parts.append(f"[{log.name.split('.')[-2]}] " + (text[-1500:] if text else "(empty)"))
    return "\n".join(parts)


def run_classes(lab: Lab, names: list[str], say: Callable[[str], None] = print) -> list[Result]:
    """Run the cases of the fault classes ``names``, printing a line per case."""
    results = []
    for name in names:
        title, cases = CLASSES[name]
        say(f"{title} ({name})")
        try:
            listed = cases(lab)
        except Skip as exc:
            say(f"  skipped: {exc}")
            results.append(Result(name, "all cases", "skip", str(exc)))
            continue
        for case in listed:
            r = attempt(lab, name, case)
            results.append(r)
            detail = r.why if r.status != "pass" else r.note
            say(f"  {r.status.upper():<4}  {r.case:<58} {r.seconds:5.1f} s  {detail}")
    return results


def format_table(results: list[Result]) -> str:
    """The table: per class, cases, passed, failed, skipped; then each failed case, its reproduction and stderr."""
    rows = [f"{'class of fault':<24} {'cases':>5} {'passed':>6} {'failed':>6} {'skipped':>7}  what still fails"]
    for name, (title, _) in CLASSES.items():
        mine = [r for r in results if r.fault == name]
        if not mine:
            continue
        failed = [r for r in mine if r.status == "fail"]
        count = lambda s: sum(r.status == s for r in mine)  # noqa: E731
        rows.append(f"{title:<24} {len(mine):>5} {count('pass'):>6} {count('fail'):>6} {count('skip'):>7}  "
                    + (", ".join(r.case for r in failed) or "-"))
    total = [sum(r.status == s for r in results) for s in ("pass", "fail", "skip")]
    rows.append(f"{'all':<24} {len(results):>5} {total[0]:>6} {total[1]:>6} {total[2]:>7}")
    for r in results:
        if r.status == "fail":
            rows += ["", f"FAILED {r.fault} / {r.case}", f"  why:       {r.why}", f"  reproduce: {r.repro}"]
            rows += [f"  observed:  {r.note}"] if r.note else []
            rows += ["  stderr:"] + [f"    {ln}" for ln in r.stderr.splitlines()]
        elif r.status == "skip":
            rows += ["", f"skipped {r.fault} / {r.case}: {r.why}"]
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=int, default=300_000, help="points of the synthetic city (default 300,000)")
    ap.add_argument("--tile-size", type=float, default=32.0, help="tile edge, metres (default 32: about 30 tiles)")
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/patchcloud-faults"))
    ap.add_argument("--only", nargs="+", choices=list(CLASSES), default=None, metavar="CLASS",
                    help=f"fault classes to run: {', '.join(CLASSES)} (default: all)")
    ap.add_argument("--results", type=Path, default=None, help="also write the cases' lines and the table there")
    ap.add_argument("--keep", action="store_true", help="keep the directories of the cases that pass")
    a = ap.parse_args(argv)
    names = a.only or list(CLASSES)
    lines: list[str] = []

    def say(line: str) -> None:
        print(line, flush=True)
        lines.append(line)

    t0 = time.perf_counter()
    say(f"patchcloud fault injection: {a.points:,} points, tiles of {a.tile_size:g} m, {os.cpu_count()} cores, "
        f"{platform.platform()}, python {platform.python_version()}")
    say(f"command: {shlex.join([Path(sys.executable).name, 'tools/faults.py', *(argv if argv is not None else sys.argv[1:])])}")
    lab = Lab(a.workdir.resolve(), a.points, a.tile_size, a.keep)
    results = run_classes(lab, names, say)
    say("")
    say(format_table(results))
    say(f"\ntotal time {time.perf_counter() - t0:.0f} s")
    if a.results is not None:
        a.results.parent.mkdir(parents=True, exist_ok=True)
        a.results.write_text("\n".join(lines) + "\n")
    return 1 if any(r.status == "fail" for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
