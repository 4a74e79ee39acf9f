"""``patchcloud segment``."""

from __future__ import annotations

import click

from patchcloud.core import SegmentOptions

from . import options


@click.command("segment")
@options.paths_argument
@options.don_options
@click.option("--threshold", type=float, default=SegmentOptions.threshold, show_default=True, help="Smallest DoN magnitude (0 to 1) of a point kept.")
@click.option("--axis", type=click.Choice(["x", "y", "z"]), default=None,
              help="Also require |DoN| along this axis >= --axis-threshold (e.g. z for kerbs).")
@click.option("--axis-threshold", type=float, default=None, help="With --axis: smallest |DoN| along it.")
@click.option("--tolerance", type=float, default=SegmentOptions.tolerance, show_default=True, metavar="LENGTH",
              help="Largest gap between two points of one segment, in the file's horizontal unit (see --units).")
@click.option("--min-points", type=int, default=SegmentOptions.min_cluster, show_default=True, help="Smaller segments are dropped (ClusterID 0).")
@click.option("--max-points", type=int, default=None, help="Larger segments are dropped (ClusterID 0). Default: no limit.")
@options.job_options
@options.catalog_options
@options.report_option
@options.reports_errors
def segment_command(
    paths, r_small, r_large, mode, viewpoint, threshold, axis, axis_threshold, tolerance, min_points, max_points, report, **run,
):
    """DoN segments of INPUT (LAS/LAZ/COPC, any size), written to OUTPUT.

    With --out-dir DIR every argument is an input, the files are taken as
    one cloud (a segment crossing two files has one ClusterID, ids unique
    across the catalog), and each gets its output in DIR.

    Points whose DoN magnitude is at least --threshold are kept, and kept
    points closer than --tolerance are joined into segments (Euclidean
    clustering).  OUTPUT holds the input points as they are, plus DoN,
    DoNX, DoNY, DoNZ and ClusterID (uint64): 1, 2, ... in order of each
    segment's first point in the file, 0 for no segment (and for the
    points left out: --classes; noise and withheld points unless
    --keep-noise).  Segments that cross tile faces get one id.  An input
    dimension of one of these names (PDAL's int64 ClusterID) takes this
    run's values, keeping its type.

    \b
    Example:
      patchcloud segment street.laz segments.laz --rs 0.2 --rl 2.0 --threshold 0.25 --tolerance 0.2 --min-points 50
    """
    options.start_workers_early(paths, run, "patchcloud.stream.jobs.segment")  # before the job's imports
    from patchcloud.stream import segment

    run = options.run_options(run)
    input, output = options.input_and_output(paths, run.out_dir, report, run.overwrite, run.profile, store=run.store)

    asked = SegmentOptions(
        r_small=r_small, r_large=r_large, mode=mode, viewpoint=viewpoint or None, threshold=threshold, tolerance=tolerance,
        min_cluster=min_points, max_cluster=max_points, axis=axis, axis_threshold=axis_threshold,
    )
    summary = segment(input, output, asked, run)
    options.finish_job(summary, run.quiet, report, "report_don")
