"""The job scaffold, the options objects and the codes: one definition each, used everywhere."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import click
import laspy
import numpy as np
import pytest

from patchcloud.core import (
    CompressOptions, DonOptions, Method, NormalsOptions, PatchcloudValueError, PatchKind, SegmentOptions,
    estimate_normals,
)
from patchcloud.stream import RunOptions, Store, normals
from patchcloud.stream.cli import main
from patchcloud.stream.engine.export import Column
from patchcloud.stream.engine.job import Job, JobContext, run_job, split_options
from patchcloud.stream.io.dims import NORMALS_DIMS

SAMPLE = Path(__file__).resolve().parents[1] / "data" / "test_data_77055_627760_LA93_IGN69.laz"


# --- options objects -------------------------------------------------------------------------------------------

@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: NormalsOptions(criterion="angle"), "criterion must be one of rmse, sigma3; got 'angle'"),
        (lambda: NormalsOptions(orient="down"), "orient must be one of up, viewpoint, outward, none"),
        (lambda: NormalsOptions(orient="viewpoint"), "needs a viewpoint"),
        (lambda: NormalsOptions(orient="viewpoint", viewpoint=(1, 2)), "three finite"),
        (lambda: NormalsOptions(viewpoint=(1, 2, 3)), "viewpoint goes with orient=\"viewpoint\", not orient=.up."),
        (lambda: DonOptions(mode="slow"), "mode must be one of"),
        (lambda: DonOptions(r_small=2.0, r_large=1.0), "r_small must be smaller than r_large"),
        (lambda: SegmentOptions(axis="w", axis_threshold=0.1), "axis must be one of x, y, z"),
        (lambda: SegmentOptions(threshold=1.5), r"threshold must be a DoN magnitude in \[0, 1\]"),
        (lambda: SegmentOptions(min_cluster=0), "min_points must be a whole number"),
        (lambda: CompressOptions(max_error=0), "max_error must be a positive length in the coordinates' unit"),
        (lambda: RunOptions(tile_size=0), "tile_size must be a positive length in the coordinates' unit"),
        (lambda: RunOptions(workers=0), "workers must be a whole number of at least 1"),
        (lambda: RunOptions(workers="2"), "workers must be a whole number of at least 1, got '2'"),  # (said "at least 1")
    ],
)
def test_invalid_options_are_refused_when_made(make, match):
    with pytest.raises(PatchcloudValueError, match=match):
        make()


def test_options_are_frozen_and_normalised():
    o = NormalsOptions(n_min=12.0, viewpoint=[1, 2, 3], orient="viewpoint")
    assert o.n_min == 12 and isinstance(o.n_min, int)
    assert o.viewpoint == (1.0, 2.0, 3.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        o.n_min = 3
    s = SegmentOptions(r_small=0.5, r_large=2, tolerance=1)
    assert s.don == DonOptions(r_small=0.5, r_large=2.0)


def test_unknown_option_names_list_the_valid_ones():
    with pytest.raises(PatchcloudValueError, match="unknown option knn; valid: .*k_fallback.*workers"):
        split_options({"knn": 8}, None, NormalsOptions, None)
    with pytest.raises(PatchcloudValueError, match="unknown option radius; valid: blend, criterion"):
        estimate_normals(np.zeros((20, 3)), radius=1.0)
    with pytest.raises(PatchcloudValueError, match="options must be a NormalsOptions, got DonOptions"):
        estimate_normals(np.zeros((20, 3)), DonOptions())


def test_keyword_arguments_override_the_objects_given():
    o, r = split_options({"orient": "none", "quiet": True}, NormalsOptions(criterion="sigma3"), NormalsOptions,
                         RunOptions(workers=3))
    assert (o.criterion, o.orient) == ("sigma3", "none")
    assert (r.workers, r.quiet, r.scheduler) == (3, True, "auto")


def test_options_object_and_keywords_give_identical_normals(rng):
    xy = rng.uniform(0, 10, (4000, 2))
    pts = np.column_stack([xy, np.sin(xy[:, 0])])
    a = estimate_normals(pts, NormalsOptions(criterion="sigma3", orient="outward"))
    b = estimate_normals(pts, criterion="sigma3", orient="outward")
    assert np.array_equal(a.normals, b.normals) and np.array_equal(a.curvature, b.curvature)
    assert a.parameters == b.parameters


def _defaults(command: click.Command) -> dict:
    return {p.name: p.default for p in command.params}


def test_the_command_line_takes_its_defaults_from_the_options_objects():
    commands = main.commands
    n = _defaults(commands["normals"])
    assert (n["criterion"], n["orient"], n["threshold"]) == (NormalsOptions.criterion, NormalsOptions.orient, None)
    d = _defaults(commands["don"])
    assert (d["r_small"], d["r_large"], d["mode"]) == (DonOptions.r_small, DonOptions.r_large, DonOptions.mode)
    s = _defaults(commands["segment"])
    assert (s["threshold"], s["tolerance"], s["min_points"]) == (
        SegmentOptions.threshold, SegmentOptions.tolerance, SegmentOptions.min_cluster)
    assert _defaults(commands["compress"])["max_error"] == CompressOptions.max_error


# --- codes -----------------------------------------------------------------------------------------------------

def test_codes_are_defined_once_and_written_as_documented(tmp_path):
    assert [int(m) for m in Method] == [1, 2, 3, 4] and [int(k) for k in PatchKind] == [0, 1, 2]
    assert dict((d[0], d[2]) for d in NORMALS_DIMS)["NormalMethod"] == Method.describe() == "1 quadric 2 blended 3 kNN 4 cell"
    assert len(Method.describe()) <= 32  # a LAS extra-bytes description
    out = tmp_path / "n.las"
    s = normals(SAMPLE, out, quiet=True, scheduler="synchronous")
    las = laspy.read(out)
    (dim,) = [d for d in las.point_format.extra_dimensions if d.name == "NormalMethod"]
    assert dim.description == Method.describe()
    counts = np.bincount(las.NormalMethod, minlength=4)
    assert counts[0] == 0
    assert s.normals_by_method == {**{m.name.lower(): int(counts[m]) for m in Method}, "none": 0}
    printed = {"quadric": Method.QUADRIC, "blended": Method.BLENDED, "cell moments": Method.MOMENTS, "k-NN fallback": Method.KNN}
    shares = {name: counts[code] / counts.sum() for name, code in printed.items()}  # every computed point, once
    line = next(x for x in s.format().splitlines() if "normals by" in x)
    assert line.split(None, 2)[2] == ", ".join(f"{name} {share:.1%}" for name, share in shares.items())
    assert "1 quadric patch, 2 blended across patches, 3 k-nearest-neighbour fallback" in " ".join(
        main.commands["normals"].help.split())


# --- a new job on the scaffold ---------------------------------------------------------------------------------

def tile_numbers(url: str, ijk: tuple) -> int:
    """A per-tile task: the tile's position in the store's list, for each of its points, in input order."""
    st = Store.open(url)
    n = int(st.read(ijk, "rank").shape[0])
    st.write(ijk, "tile_number", np.full(n, st.tiles.index(tuple(ijk)), dtype=np.uint32))
    return n


class TileNumberJob(Job):
    """What a newcomer writes for a new job: steps, columns, summary; the scaffold does the rest."""

    def __init__(self):
        self.counts = {}

    def steps(self):
        return [("number", self.number)]

    def number(self, ctx: JobContext) -> None:
        self.counts = ctx.map_tiles(tile_numbers, label="number")

    def columns(self, ctx):
        return [Column("tile_number", ("TileNumber",), np.uint32)], (("TileNumber", np.uint32, "tile of the point"),)

    def summarise(self, ctx):
        return dict(seconds=dict(ctx.seconds), tiles=list(ctx.store.tiles), grid=ctx.store.grid, store=ctx.kept_store)


def test_a_new_job_is_a_job_subclass_and_its_output_is_the_input_plus_its_columns(tmp_path):
    out = tmp_path / "numbered.laz"
    summary = run_job(TileNumberJob(), SAMPLE, out, RunOptions(tile_size=64, scheduler="synchronous", quiet=True))
    assert list(summary["seconds"]) == ["tile", "number", "export"]
    assert summary["store"] == "" and not Path(str(out) + ".store").exists()  # the default store is removed
    src, las = laspy.read(SAMPLE), laspy.read(out)
    n, size = len(src.points), src.point_format.size
    old = src.points.array.view(np.uint8).reshape(n, size)
    assert np.array_equal(las.points.array.view(np.uint8).reshape(n, -1)[:, :size], old)  # every input byte, in order
    tiles, grid = summary["tiles"], summary["grid"]
    # every point lies in the cube of the tile it was numbered with
    corner = np.array([grid.corner(t) for t in tiles])[las.TileNumber]
    local = np.column_stack([las.x, las.y, las.z]) - np.asarray(grid.origin)
    assert np.all((local >= corner) & (local < corner + grid.tile_size))
    assert len(tiles) == 4 and np.bincount(las.TileNumber).sum() == len(src.points)
    assert not list(tmp_path.glob("*.partial"))


def test_the_console_script_sets_the_collector_for_a_process_of_its_own():
    """``patchcloud`` (``run``) collects young objects less often and ends its process without the interpreter's
    teardown (``os._exit``); ``main`` (what CliRunner and other programs call) leaves the collector as it was and
    returns (SystemExit)."""
    import subprocess
    import sys

    probe = (
        "import gc, os, sys\n"
        "frozen = gc.get_freeze_count()\n"  # 0 on Python 3.11; 375 at start-up on 3.12.1
        "print('default', gc.get_threshold()[0])\n"  # 700 on Python 3.11 and 3.12, 2000 on 3.13
        "from patchcloud.stream.cli import main, run\n"
        "sys.argv = ['patchcloud', '--version']\n"
        "try:\n"
        "    main()\n"
        "except SystemExit as exc:\n"
        "    print('main', exc.code, gc.get_threshold()[0], gc.get_freeze_count() > frozen)\n"
        "end = os._exit\n"
        "os._exit = lambda code: (print('run', code, gc.get_threshold()[0], flush=True), end(code))\n"
        "run()\n"
        "print('not reached')\n"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout.splitlines()
    default = out.pop(0).split()[1]
    assert [line for line in out if not line.startswith("patchcloud")] == [f"main 0 {default} False", "run 0 100000"]


# --- dependencies ----------------------------------------------------------------------------------------------

#: Imported by the package but not declared, each with why that is safe.
UNDECLARED = {
    "patchcloud": "the package itself",
    "yaml": "PyYAML, a dependency of dask: read as dask reads its own configuration (stream.engine.forkserver)",
}


def test_every_package_the_code_imports_is_a_declared_dependency():
    """A package imported by core/ or stream/ is in pyproject.toml's dependencies, with a floor (``name>=X``) that
    ``.ci/min-versions`` can install: lazrs was imported directly for sessions while only laspy's extra brought it."""
    import ast
    import importlib.util
    import sys

    root = Path(__file__).resolve().parents[1]
    spec = importlib.util.spec_from_file_location("floors", root / ".ci" / "floors.py")  # what .ci/min-versions pins
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    floors = {name.split("[")[0].lower() for name, _ in module.floors(root / "pyproject.toml")}
    imported = set()
    for base in ("core", "stream"):
        for path in (root / base).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.Import):
                    imported |= {a.name.split(".")[0] for a in node.names}
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    imported.add(node.module.split(".")[0])
    third_party = {m for m in imported if m not in sys.stdlib_module_names}
    assert {"numpy", "numba", "laspy", "lazrs", "zarr", "dask"} <= third_party  # the scan finds what is there
    missing = sorted(m for m in third_party if m.lower() not in floors and m not in UNDECLARED)
    assert not missing, f"imported but not in pyproject.toml's dependencies: {missing}"
