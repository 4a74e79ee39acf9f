"""Options shared by several subcommands, and the one way errors reach the user."""

from __future__ import annotations

import functools
import logging
import os
import re
import sys
import warnings
from pathlib import Path

import click

from patchcloud.core import DonOptions, PatchcloudError, os_error_line

__all__ = ["OneLineErrors", "classes", "keep_noise", "paths_argument", "out_dir", "assume_crs", "assume_crs_each", "catalog_options", "input_and_output", "check_side_files", "check_distinct", "check_json_path", "summary_json_path", "tile_size", "units", "scheduler", "scheduler_file", "workers", "store", "keep_store", "in_memory", "overwrite", "quiet", "profile", "max_memory", "reports_errors", "in_option_words", "don_options", "job_options", "report_option", "check_report", "finish_job", "run_options", "summary_json", "summary_dict", "write_summary_json", "SUMMARY_JSON_KEY"]

tile_size = click.option(
    "--tile-size", type=float, default=None, metavar="LENGTH",
    help="Edge of the tiles (in the file's horizontal unit, as every distance option: see --units), rounded down to a "
    "power of two. Default: about a million points per tile.",
)
units = click.option(
    "--units", type=click.Choice(["m", "ft", "us-ft"]), default=None,
    help="The unit of the file's coordinates, which every distance option and summary figure is in, instead of its "
    "CRS's (for a file without a CRS, where metres are assumed, or a wrong one). Default: the CRS's horizontal unit; a "
    "geographic CRS (degrees) is an error naming this option.",
)
scheduler = click.option(
    "--scheduler", default="auto", show_default=True, metavar="ADDRESS",
    help="'auto' (worker processes for files of 2 million points or more; below that in memory, or threads with --workers), "
    "'threads', 'processes' "
    "(one task per worker, each worker a core), 'synchronous', or the address of a dask.distributed scheduler, "
    "e.g. tcp://host:8786 (the workers must then reach the input, the store and the output's directory).",
)
scheduler_file = click.option(
    "--scheduler-file", default=None, metavar="JSON", type=click.Path(dir_okay=False),
    help="Run on the dask scheduler whose address this file holds (what 'dask scheduler --scheduler-file' and dask-jobqueue "
    "write; SLURM and PBS set-ups share it this way) instead of --scheduler.",
)
workers = click.option("--workers", type=int, default=None, help="Threads or processes on this machine (each uses one core). Default: the cores.")
store = click.option(
    "--store", default=None, metavar="PATH",
    help="Where the tiles and intermediate results go (a path or an fsspec URL). Default: OUT.store beside "
    "the output, removed when the job succeeds; a store given here is kept, and a rerun resumes from it.",
)
classes = click.option(
    "--classes", default=None, metavar="LIST",
    help="Only points of these ASPRS classes, e.g. 2,6 (PDAL's `where: Classification == 2`): only they are computed and "
    "used as neighbours; the others are written unchanged with the empty value (NormalMethod 0 and a zero normal, DoN 0, "
    "ClusterID 0; compress keeps them as residual points, within --max-error, with the residual points' attributes). Default: every class.",
)
keep_noise = click.option(
    "--keep-noise", is_flag=True,
    help="Keep noise (classes 7 and 18) and withheld points; by default they are left out of every neighbourhood and get "
    "the empty value, as --classes leaves points out (a noise class named in --classes is kept).",
)
keep_store = click.option("--keep-store", is_flag=True, help="Keep the default store after success.")
overwrite = click.option("--overwrite", is_flag=True, help="Replace an existing output.")
quiet = click.option("--quiet", "-q", is_flag=True, help="No progress bars or summary.")
in_memory = click.option(
    "--in-memory/--on-disk", "in_memory", default=None,
    help="Run in this process with the tiles in memory (no dask cluster, no store on disk; same results), or on a store. "
    "Default: in memory for inputs of up to 2 million points (10 million on a machine of at most 2 cores) when no --store, "
    "--keep-store, --workers or --scheduler is given.",
)


def check_json_path(path: str, option: str, out_dir: str | None = None) -> None:
    """Before anything runs: a JSON file a command writes beside its work (``--summary-json``, ``--profile``) goes
    where it replaces nothing but a JSON file, and not into a zarr store (a store's metadata is JSON): a
    click.BadParameter (one error line) otherwise.  An input, an output or a store would have been lost.  Its
    directory exists, or is ``out_dir`` (a catalog's ``--out-dir``, which the run makes) in one that does."""
    p = Path(path)
    parent = p.resolve().parent
    if out_dir is not None and parent == Path(out_dir).resolve() and not parent.exists():
        parent = parent.parent  # the run makes the output directory: its own directory is where it must be writable
    if p.is_dir() or not parent.is_dir():
        raise click.BadParameter(f"{path}: is a directory, or its directory does not exist", param_hint=option)
    if p.name == "zarr.json" or (parent / "zarr.json").exists():
        raise click.BadParameter(f"{path}: inside a zarr store (a patchcloud store): it would damage it", param_hint=option)
    from patchcloud.core import PatchcloudIOError
    from patchcloud.stream.io.las import check_directory_writable

    try:  # a directory it cannot be written in: said now, not after the job
        check_directory_writable(parent, path)
    except PatchcloudIOError as exc:
        raise click.BadParameter(str(exc), param_hint=option) from None
    if p.exists() and not p.is_file():  # a device or a pipe: the write at the end is refused (after the whole job)
        raise click.BadParameter(f"{path}: exists and is not a file (a device or a pipe): {option} writes a file", param_hint=option)
    if p.exists():
        import json

        try:
            with open(p, "rb") as f:
                head = f.read(1 << 20)
            if head.strip():
                json.loads(head)
        except (OSError, ValueError):
            raise click.BadParameter(f"{path}: exists and is not a JSON file ({option} replaces only one)", param_hint=option) from None


def _profile_path(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    """--profile's callback: :func:`check_json_path` before anything runs."""
    if value is not None:
        check_json_path(value, "--profile", ctx.params.get("out_dir"))
    return value


profile = click.option(
    "--profile", type=click.Path(dir_okay=False), default=None, metavar="PATH", callback=_profile_path,
    help="Write the run's task stream there (JSON: each task's step, start, end and worker), e.g. for tools/bench_scale.py.",
)


def _set_max_memory(ctx: click.Context, param: click.Parameter, value: str | None) -> None:
    """--max-memory's callback: set the budget for this command (and the workers it starts), restored when it ends."""
    if value is None:
        return
    from patchcloud.core import PatchcloudValueError
    from patchcloud.stream.io.budget import ENV, set_max_memory

    before = os.environ.get(ENV)
    try:
        set_max_memory(value)
    except PatchcloudValueError as exc:
        if ctx.get_parameter_source(param.name) == click.core.ParameterSource.ENVIRONMENT:  # not typed: say where it is
            raise click.UsageError(f"{ENV} (the environment, for --max-memory): {exc}") from None
        raise click.BadParameter(str(exc)) from None
    ctx.call_on_close(lambda: os.environ.__setitem__(ENV, before) if before is not None else os.environ.pop(ENV, None))


max_memory = click.option(
    "--max-memory", default=None, metavar="SIZE", envvar="PATCHCLOUD_MAX_MEMORY", expose_value=False, callback=_set_max_memory,
    help="Memory budget of each process (e.g. 8GiB, 4GB): sizes read from a file and allocations asked for by a parameter are "
    "checked against it before anything is allocated. Default: half the machine's memory. Also PATCHCLOUD_MAX_MEMORY.",
)
report_option = click.option(
    "--report", type=click.Path(dir_okay=False), default=None, metavar="PATH",
    help="Also write an HTML report of the run (summary, views, histograms): one self-contained file, images "
    "embedded, that opens in a browser without a server. Checked before the job runs; replaced only with --overwrite.",
)


#: Where click's context keeps the --summary-json path of the running command.
SUMMARY_JSON_KEY = "patchcloud.summary_json"


def summary_json_path() -> str | None:
    """The running command's --summary-json, or None (none given, or no command running)."""
    ctx = click.get_current_context(silent=True)
    return None if ctx is None else ctx.find_root().meta.get(SUMMARY_JSON_KEY) or ctx.meta.get(SUMMARY_JSON_KEY)


def _summary_json_path(ctx: click.Context, param: click.Parameter, value: str | None) -> None:
    """--summary-json's callback: check its directory exists before anything runs, and keep the path for the end."""
    if value is None:
        return
    check_json_path(value, "--summary-json", ctx.params.get("out_dir"))
    ctx.meta[SUMMARY_JSON_KEY] = value


summary_json = click.option(
    "--summary-json", default=None, metavar="PATH", type=click.Path(dir_okay=False), expose_value=False,
    callback=_summary_json_path,
    help="Also write the summary's figures as one JSON object there (for batch pipelines; lengths in the file's "
    "horizontal unit, which normals, don, segment and compress name in 'units' and render in 'unit'); replaced when it "
    "exists, written under a temporary name and renamed.",
)


def summary_dict(summary) -> dict | list:
    """A summary (a dataclass, or a list of them) as JSON values: numpy numbers as numbers, NaN and infinities as null.

    >>> from dataclasses import dataclass
    >>> @dataclass
    ... class S:
    ...     points: int
    ...     ratio: float
    >>> summary_dict(S(3, float("nan")))
    {'points': 3, 'ratio': None}
    """
    import dataclasses
    import math

    import numpy as np

    def clean(v):
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return {f.name: clean(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, dict):
            return {str(k): clean(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        if isinstance(v, np.ndarray):
            return clean(v.tolist())
        if isinstance(v, np.generic):
            return clean(v.item())
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, (str, int, float, bool)) or v is None:
            return v
        return str(v)

    return clean(summary)


def write_summary_json(summary) -> None:
    """Write ``summary`` (:func:`summary_dict`) where the running command's --summary-json says, if it says: under a
    temporary name, then renamed."""
    import json

    from patchcloud.stream.io.las import atomic_output

    path = summary_json_path()
    if path is None:
        return
    text = json.dumps(summary_dict(summary), indent=2, sort_keys=True, allow_nan=False) + "\n"
    with atomic_output(path, overwrite=True) as f:
        f.write(text.encode("utf-8"))


#: INPUT OUTPUT, or INPUT... with --out-dir (a catalog): see :func:`input_and_output`.
paths_argument = click.argument("paths", nargs=-1, required=True, metavar="INPUT... [OUTPUT]", type=click.Path())


out_dir = click.option(
    "--out-dir", default=None, type=click.Path(file_okay=False), metavar="DIR", is_eager=True,  # before --summary-json's check
    # (which takes a JSON file in the output directory the run will make)
    help="Every argument is an input (files, directories of *.las/*.laz, quoted globs), taken as one cloud; "
    "each file's output goes to DIR under its name (.copc.laz becomes .laz; render writes DIR/NAME.png).",
)


assume_crs = click.option(
    "--assume-crs", default=None, metavar="CRS",
    help="The CRS of files that have none (e.g. EPSG:2154), which gives their unit and is written into their outputs; a "
    "file with another CRS is an error. Without it a file without a CRS among files with one is an error.",
)


#: --assume-crs of a job that runs a catalog file by file (compress): each file keeps its own CRS.
assume_crs_each = click.option(
    "--assume-crs", default=None, metavar="CRS",
    help="The CRS of files that have none (e.g. EPSG:2154), which gives their unit and is kept for their decompression; a "
    "file with another CRS is an error. Each file of a catalog is compressed on its own, in its own CRS (files of "
    "different CRSs, or without one, are taken).",
)


def catalog_options(func):
    """--out-dir and --assume-crs: the options of a job that takes a catalog of files."""
    for option in reversed([out_dir, assume_crs]):
        func = option(func)
    return func


def input_and_output(paths: tuple[str, ...], out_dir: str | None, report: str | None, overwrite: bool, profile: str | None = None,
                     suffix: str | None = None, store: str | None = None):
    """The job function's ``input`` and ``output`` from the command's arguments (``IN OUT``, or inputs and ``--out-dir``),
    after checking the files written beside the output (``--report``, ``--summary-json``, ``--profile``) can be
    written and replace none of the job's files (:func:`check_side_files`; ``store``: the ``--store`` given, one of
    them).  ``suffix``: a catalog's outputs' (``.pcz``), if not the inputs' own."""
    from patchcloud.core import PatchcloudValueError

    if out_dir is not None:
        check_side_files(paths, None, report, profile, overwrite, out_dir=out_dir, suffix=suffix, store=store)
        return list(paths), None
    if len(paths) == 1:
        raise PatchcloudValueError(f"{paths[0]}: give an OUTPUT file after it, or --out-dir DIR")
    if len(paths) > 2:
        raise PatchcloudValueError(f"{len(paths)} paths given: for a catalog of files give --out-dir DIR (every argument is then an input)")
    check_side_files(paths[:1], paths[1], report, profile, overwrite, store=store)
    return paths[0], paths[1]


def check_side_files(inputs, output: str | None, report: str | None, profile: str | None, overwrite: bool,
                     out_dir: str | None = None, suffix: str | None = None, store: str | None = None) -> None:
    """Before a job runs: ``--report`` can be written (:func:`check_report`), and neither it, the ``--summary-json``
    of the running command nor ``--profile`` is one of the job's files: an input (every file a directory or glob of
    ``inputs`` names), the output, a catalog's output in ``out_dir`` (named as the input, or with ``suffix``), or the
    ``store`` (a ``--store`` directory, made or not yet; an fsspec URL is left to the job).  A PatchcloudIOError (one
    error line) if not; ``--overwrite`` changes nothing."""
    from patchcloud.core import PatchcloudError, PatchcloudIOError
    from patchcloud.stream.io.catalog import expand_inputs, output_paths
    from patchcloud.stream.io.las import same_file

    try:
        found = expand_inputs(list(inputs))
    except PatchcloudIOError:  # the job says what is wrong with its inputs, in its own words
        found = [Path(i) for i in inputs]
    files = [str(f) for f in found]
    outputs = [] if output is None else [str(output)]
    if out_dir is not None:
        try:
            outputs = [str(o) for o in output_paths(found, out_dir, suffix=suffix)]
        except PatchcloudError:  # two inputs of one output name: the job says so
            pass
    job_files = files + outputs + ([str(store)] if store is not None and "://" not in str(store) else [])
    check_report(report, overwrite, *job_files, out_dir=out_dir)
    summary = summary_json_path()
    check_distinct([("--report", report), ("--summary-json", summary), ("--profile", profile)])
    for option, path in (("--summary-json", summary), ("--profile", profile)):
        if path is None:
            continue
        for f in job_files:
            if same_file(f, path):
                raise PatchcloudIOError(f"{path}: {option} would replace the job's file {f}")


def check_distinct(written) -> None:
    """Before a job runs: the files a command writes (``written``: (option, path or None) pairs) are distinct, or a
    PatchcloudIOError naming the two options (the later one would replace the earlier)."""
    from patchcloud.core import PatchcloudIOError
    from patchcloud.stream.io.las import same_file

    given = [(option, path) for option, path in written if path is not None]
    for k, (option, path) in enumerate(given):
        for other, there in given[k + 1:]:
            if same_file(path, there):
                raise PatchcloudIOError(f"{path}: {option} and {other} name the same file")


def check_report(report: str | None, overwrite: bool, *job_files: str, out_dir: str | None = None) -> None:
    """Before a job runs: the ``--report`` path can be written (a PatchcloudIOError, hence one error line, if not); in
    ``out_dir`` too (a catalog's, which the job makes)."""
    if report is not None:
        from patchcloud.stream.views.report import check_report_path

        check_report_path(report, overwrite=overwrite, others=job_files, made=out_dir)


def finish_job(summary, quiet: bool, report: str | None, write_report: str) -> None:
    """After a job: print its summary (unless ``quiet``) and write its ``--report`` with ``write_report(summary, path)``,
    the name of a function of :mod:`patchcloud.stream.views.report` (imported only then: matplotlib is slow to import);
    and its --summary-json (:func:`write_summary_json`)."""
    write_summary_json(summary)
    if not quiet:
        click.echo(summary.format())
    if report is not None:
        from patchcloud.stream.views import report as reports

        getattr(reports, write_report)(summary, report)
        if not quiet:
            click.echo(f"  report          {report}")


def start_workers_early(paths: tuple[str, ...], values: dict, job: str, each_file: bool = False) -> None:
    """Start the fork server of the run's local worker processes now, while this process imports the job (0.6 s), when
    the run will start them (:func:`patchcloud.stream.engine.placement.starts_local_processes`: the options ``values``
    of :func:`job_options` and the inputs' point counts, read from their headers); it imports the job's module ``job``
    too (e.g. ``"patchcloud.stream.jobs.normals"``).  ``each_file``: a catalog's files are runs of their own
    (``compress``), so its largest file decides, not their sum.  Anything wrong with the inputs or
    options is left to the job to report: then nothing is started here."""
    from patchcloud.stream.engine.placement import starts_local_processes

    scheduler = values.get("scheduler") or "auto"
    if values.get("scheduler_file") or scheduler not in ("auto", "processes"):
        return
    points = None
    if scheduler == "auto":
        from patchcloud.stream.io.catalog import expand_inputs
        from patchcloud.stream.io.las import open_source

        try:  # the job's own checks (a crafted header's counts are refused, not parsed for minutes)
            counts = [open_source(path, allow_empty=True).point_count
                      for path in expand_inputs(list(paths if values.get("out_dir") else paths[:1]))]
        except Exception:  # the job says what is wrong with its inputs
            return
        points = max(counts, default=0) if each_file else sum(counts)
    if starts_local_processes(points, scheduler, values.get("workers"), values.get("store"), values.get("keep_store") or None,
                              values.get("in_memory")):
        from patchcloud.stream.engine.forkserver import start_server

        start_server([job])


def run_options(values: dict):
    """The :class:`patchcloud.stream.RunOptions` of the options :func:`job_options` (and :func:`catalog_options`) add,
    ``values`` by their names (a command's ``**run``; ``--keep-store`` absent: the default rule)."""
    from patchcloud.stream import RunOptions

    from patchcloud.core import PatchcloudValueError
    from patchcloud.stream.engine.runner import scheduler_from_file

    values = dict(values)
    path = values.pop("scheduler_file", None)
    if path is not None:
        if values.get("scheduler", "auto") != "auto":
            raise PatchcloudValueError("give --scheduler or --scheduler-file, not both")
        values["scheduler"] = scheduler_from_file(path)
    return RunOptions(**dict(values, keep_store=values.get("keep_store") or None))



def job_options(func):
    """The options every out-of-core job shares, named as the fields of RunOptions (a command takes them as ``**run``:
    :func:`run_options`): --classes, --keep-noise, --tile-size, --scheduler, --scheduler-file, --workers, --store, --keep-store,
    --in-memory, --overwrite, -q, --profile, --units, --summary-json; and --max-memory (which sets the budget,
    :mod:`patchcloud.stream.io.budget`)."""
    for option in reversed([classes, keep_noise, tile_size, scheduler, scheduler_file, workers, store, keep_store, in_memory, overwrite,
                            quiet, profile, units, summary_json, max_memory]):
        func = option(func)
    return func


def don_options(func):
    """The options of the Difference of Normals: --rs, --rl, --mode, --viewpoint."""
    for option in reversed([
        click.option("--rs", "r_small", type=float, default=DonOptions.r_small, show_default=True, metavar="LENGTH",
                     help="Small support radius, in the file's horizontal unit (see --units)."),
        click.option("--rl", "r_large", type=float, default=DonOptions.r_large, show_default=True, metavar="LENGTH",
                     help="Large support radius, in the file's horizontal unit (see --units)."),
        click.option("--mode", type=click.Choice(["exact", "fast"]), default=DonOptions.mode, show_default=True,
                     help="Radius normals by PCA of every point in the ball (exact, PCL's definition) or from voxel moments (fast)."),
        click.option("--viewpoint", type=float, nargs=3, default=None, metavar="X Y Z",
                     help="Both normals face it (file coordinates). Default: above the middle of the file, one extent above its top."),
    ]):
        func = option(func)
    return func


def in_option_words(message: str, command: click.Command | None) -> str:
    """An error ``message`` of the Python API in the words of ``command``'s options: a parameter named as in Python
    becomes its option (``r_small`` anywhere, ``threshold must``, ``r_small=2 m``, ``orient="viewpoint"`` become
    ``--rs``, ``--threshold must``, ``--rs 2 m``, ``--orient viewpoint``), and Python's None "not given".

    >>> cmd = click.Command("don", params=[click.Option(["--rs", "r_small"], type=float), click.Option(["--rl", "r_large"]),
    ...                                     click.Option(["--orient"]), click.Option(["--viewpoint"])])
    >>> in_option_words('r_small must be smaller than r_large; got r_small=2, r_large=0.5', cmd)
    '--rs must be smaller than --rl; got --rs 2, --rl 0.5'
    >>> in_option_words('orient="viewpoint" needs a viewpoint (x, y, z), or None', cmd)
    '--orient viewpoint needs a viewpoint (x, y, z), or not given'
    >>> in_option_words("orient 'sideways': not a rule", cmd)
    '--orient sideways: not a rule'
    >>> in_option_words("for a smaller ball give --rs R (r_small)", cmd)
    'for a smaller ball give --rs R'
    >>> run = click.Command("normals", params=[click.Option(["--store"]), click.Option(["--keep-store", "keep_store"]),
    ...                                        click.Option(["--scheduler"]), click.Option(["--in-memory", "in_memory"])])
    >>> in_option_words("in_memory runs keep no store: leave out store and keep_store, or in_memory", run)
    '--in-memory runs keep no store: leave out --store and --keep-store, or --in-memory'
    >>> in_option_words("in_memory runs inline, on no scheduler: leave out scheduler ('processes'), or in_memory", run)
    '--in-memory runs inline, on no scheduler: leave out --scheduler processes, or --in-memory'
    """
    options = {}
    for param in getattr(command, "params", ()):
        longest = max((o for o in getattr(param, "opts", ()) if o.startswith("--")), key=len, default=None)
        if isinstance(param, click.Option) and param.name and longest:
            options[param.name] = longest
    if not options:
        return message
    names = "|".join(re.escape(n) for n in sorted(options, key=len, reverse=True))
    # a name opening a sentence that says what it must be or needs (not "the store is ..."), name="value", name=value,
    # and a Python name (with an underscore) anywhere
    subject = re.compile(rf"(^|[:;] )({names})(?= must| needs)")
    message = subject.sub(lambda m: m.group(1) + options[m.group(2)], message)
    # a message opening with the name and the value given in quotes: "classes 'abc': ..." is "--classes abc: ..."
    quoted = re.compile(rf"^({names}) '([^']*)'(?=[: ])")
    message = quoted.sub(lambda m: f"{options[m.group(1)]} {m.group(2)}", message)
    # what to leave out: "leave out store and keep_store", "leave out scheduler ('processes')"
    leave = re.compile(rf"(?<=leave out )({names})(?: \('([^']*)'\))?(?: and ({names}))?(?![\w-])")
    message = leave.sub(lambda m: options[m.group(1)] + (f" {m.group(2)}" if m.group(2) is not None else "")
                        + (f" and {options[m.group(3)]}" if m.group(3) else ""), message)
    pattern = re.compile(rf'(?<![\w-])({names})(="([^"]*)"|=)|(?<![\w-])(\w+_\w+)(?![\w-])')

    def word(m: re.Match) -> str:
        if m.group(4) is not None:  # a name with an underscore: an option's only if one has it
            return options.get(m.group(4), m.group(4))
        option, rest = options[m.group(1)], m.group(2)
        if rest.startswith('="'):
            return f"{option} {m.group(3)}"
        return f"{option} "

    message = re.sub(r"\bor None\b", "or not given", pattern.sub(word, message))
    # "give --out-dir OUT (out_dir)" named the option twice once out_dir became --out-dir
    return re.sub(r"(--[\w-]+)((?: [A-Z_]+)?) \(\1\)", r"\1\2", message)


class OneLineErrors(click.Group):
    """A click group whose usage errors (an unknown option, a value click refuses, a missing argument) are one line,
    ``error: MESSAGE (`COMMAND --help` for help)``, exit status 2, like every other failure; click's own form is
    four lines (the usage, a hint, a blank line and ``Error: ...``).  Other errors are click's, unchanged."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        try:
            return super().main(args, prog_name, complete_var, standalone_mode=True, **extra)
        except _UsageLine as exc:
            click.echo(f"error: {exc.line}", err=True)
            sys.exit(exc.exit_code)

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except click.UsageError as exc:
            raise _one_line(exc) from None

    def parse_args(self, ctx, args):
        try:
            return super().parse_args(ctx, args)
        except click.UsageError as exc:
            raise _one_line(exc) from None


def _one_line(exc: click.UsageError) -> Exception:
    """The error to raise for ``exc``: itself where it is help asked for by giving no arguments, else a _UsageLine."""
    if isinstance(exc, getattr(click.exceptions, "NoArgsIsHelpError", ())):
        return exc
    return _UsageLine(exc)


class _UsageLine(Exception):
    """A click usage error carried past click's own handler to :meth:`OneLineErrors.main`, as one line."""

    def __init__(self, exc: click.UsageError) -> None:
        path = exc.ctx.command_path if exc.ctx is not None else "patchcloud"
        message = " ".join(exc.format_message().split())  # click's lists of choices span lines
        self.line = f"{message.rstrip('.')} (`{path} --help` for help)"
        self.exit_code = exc.exit_code
        super().__init__(self.line)


def reports_errors(func):
    """Turn a PatchcloudError (bad file, bad parameter) or an OSError (disk full, permission, read-only file system)
    into one line on stderr and exit status 2, Ctrl-C into one line and 130; any other exception (a bug, raised here
    or in a worker) into one line and 2 as well, unless ``patchcloud --debug`` asks for its traceback."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except PatchcloudError as exc:
            ctx = click.get_current_context(silent=True)
            try:
                line = in_option_words(str(exc), ctx.command if ctx is not None else None)
            except Exception:  # (the message as it is, rather than a second error)
                line = str(exc)
            click.echo(f"error: {line}", err=True)
            sys.exit(2)
        except OSError as exc:
            click.echo(f"error: {os_error_line(exc)}", err=True)
            sys.exit(2)
        except (click.exceptions.Exit, click.exceptions.Abort, click.ClickException):
            raise
        except Exception as exc:  # a bug, here or in a worker: one line unless --debug
            ctx = click.get_current_context(silent=True)
            if ctx is not None and ctx.find_root().params.get("debug"):
                raise
            click.echo(f"error: internal error: {type(exc).__name__}: {str(exc)[:500]} (a bug in patchcloud: "
                       "`patchcloud --debug ...` shows the traceback; please report it)", err=True)
            sys.exit(2)
        except KeyboardInterrupt as exc:
            click.echo(f"error: {str(exc) or 'interrupted'}", err=True)
            # zarr's event loop may still hold tasks and coroutines the interrupt cut short: asyncio would log each
            # one at exit, and Python warn of each coroutine never awaited
            logging.getLogger("asyncio").setLevel(logging.CRITICAL)
            warnings.simplefilter("ignore")
            sys.exit(130)

    return wrapper
