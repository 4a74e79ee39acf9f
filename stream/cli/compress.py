"""``patchcloud compress`` and ``patchcloud decompress``."""

from __future__ import annotations

import click

from patchcloud.core import CompressOptions

from . import options


@click.command("compress")
@options.paths_argument
@click.option("--max-error", type=float, default=CompressOptions.max_error, show_default=True, metavar="LENGTH",
              help="Error budget, in the file's horizontal unit (see --units): every point comes back within it, on its patch or "
              "as a residual point (its position rounded within it; model mode keeps its class, its withheld flag, its intensity "
              "on 64 levels and one return).")
@click.option("--keep-points", is_flag=True, default=False,
              help="Points mode: every point back in input order, each within --max-error of where it was, every attribute "
              "exact (default: model mode, the patch models).")
@click.option("--drop", default="", metavar="DIMS",
              help="Dimensions not kept, comma-separated (PDAL's names: GpsTime,UserData,PointSourceId,...; or laspy's): "
              "decompressed as zeros.")
@options.job_options
@click.option("--out-dir", default=None, type=click.Path(file_okay=False), metavar="DIR",
              help="Every argument is an input (files, directories of *.las/*.laz, quoted globs), each compressed on its own "
              "to DIR/NAME.pcz.")
@options.assume_crs_each
@click.option("--record-source", is_flag=True, default=False,
              help="Record the input's absolute path and modification time in the .pcz (default: its file name only, so the same "
              "input and parameters give the same bytes).")
@options.report_option
@options.reports_errors
def compress_command(paths, max_error, keep_points, drop, record_source, report, **run):
    """Compress INPUT (LAS/LAZ/COPC, any size) to OUTPUT, a .pcz of quadric patch models and residual points.

    With --out-dir DIR every argument is an input and each file is
    compressed on its own to DIR/NAME.pcz (patches do not cross files).

    Model mode (the default): smooth surfaces become quantised quadric
    patches (octree cell, point count, frame, quadric, extent); the points
    of edges, vegetation and other rough parts are kept one by one, each
    within --max-error of where it was, with its class, its withheld flag,
    its intensity on 64 levels and one return (their other dimensions
    zero).  Memory depends on
    --tile-size, not on the file.

    Points mode (--keep-points): every point, in input order, within
    --max-error, every attribute exact but those --drop names.

    \b
    Example:
      patchcloud compress city.laz city.pcz --max-error 0.02
      patchcloud compress city.laz city.pcz --report city_pcz.html
      patchcloud compress city.laz city.pcz --keep-points --max-error 0.05 --drop GpsTime
      patchcloud compress tiles/ --out-dir tiles_pcz/
      patchcloud decompress city.pcz preview.laz --lod 2
    """
    options.start_workers_early(paths, run, "patchcloud.stream.jobs.compress", each_file=True)  # before the job's imports
    from patchcloud.stream import compress

    run = options.run_options(run)
    input, output = options.input_and_output(paths, run.out_dir, report, run.overwrite, run.profile, suffix=".pcz", store=run.store)
    drop = tuple(d.strip() for d in drop.split(",") if d.strip())
    summary = compress(input, output, CompressOptions(max_error=max_error, keep_points=keep_points, drop=drop), run,
                       record_source=record_source)
    if isinstance(summary, list):  # a catalog, file by file: each file's summary, then one report of them all
        for s in summary:
            options.finish_job(s, run.quiet, None, "report_compress")
        options.write_summary_json(summary)
        if report is not None:
            options.finish_job(summary, True, report, "report_compress_catalog")
            if not run.quiet:
                click.echo(f"  report          {report}")
    else:
        options.finish_job(summary, run.quiet, report, "report_compress")


@click.command("decompress")
@click.argument("input", type=click.Path(dir_okay=False))
@click.argument("output", type=click.Path(dir_okay=False))
@click.option("--density", type=float, default=None, metavar="PER_AREA", help="Points per square unit of the file's CRS (per square metre in metres, per square foot in feet) of each patch.")
@click.option("--lod", type=int, default=None, metavar="K", help="Level of detail: each patch's point count / 4**K. Default: the count (K = 0).")
@click.option("--bbox", type=float, nargs=6, default=None, metavar="XMIN YMIN ZMIN XMAX YMAX ZMAX",
              help="Only this box (file coordinates); only the tiles that meet it are read.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the sampling.")
@options.max_memory
@options.overwrite
@options.quiet
@options.summary_json
@options.reports_errors
def decompress_command(input, output, density, lod, bbox, seed, overwrite, quiet):
    """Points of INPUT (a .pcz) written to OUTPUT (LAS/LAZ): patch samples and the residual points.

    OUTPUT has the original file's header and VLRs.  Of a model-mode .pcz,
    with a Reconstructed dimension: 1, sampled from a patch, with the
    patch's majority class and mean intensity; 0, a residual point, within
    the budget of where it was, with its class, its withheld flag, its
    intensity on 64 levels and one return.  Of a points-mode .pcz: the input's points in input
    order, each within the budget, every attribute as it was but those
    --drop named.
    """
    from patchcloud.stream import decompress

    options.check_side_files([input], output, None, None, overwrite)  # a --summary-json replaces neither
    summary = decompress(input, output, density=density, lod=lod, bbox=bbox or None, seed=seed, overwrite=overwrite)
    options.write_summary_json(summary)
    if not quiet:
        click.echo(summary.format())
