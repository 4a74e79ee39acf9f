"""``patchcloud don-scales``."""

from __future__ import annotations

from pathlib import Path

import click

from patchcloud.core import PatchcloudIOError, PatchcloudValueError

from . import options

__all__ = ["don_scales_command", "parse_list"]


def parse_list(name: str, text: str | None, kind=float) -> list | None:
    """``"0.2,0.5, 1"`` as a list of ``kind``; None for None; a PatchcloudValueError naming the option otherwise.

    Examples
    --------
    >>> parse_list("--radii", "0.2, 0.5,1")
    [0.2, 0.5, 1.0]
    >>> parse_list("--classes", "2,6", int)
    [2, 6]
    """
    if text is None:
        return None
    parts = [p.strip() for p in text.split(",") if p.strip()]
    try:
        values = [kind(p) for p in parts]
    except ValueError:
        what = "whole numbers" if kind is int else "numbers"
        raise PatchcloudValueError(f"{name} must be comma-separated {what}, e.g. 0.2,0.5,1; got {text!r}") from None
    if not values:
        raise PatchcloudValueError(f"{name} must list at least one value, comma-separated; got {text!r}")
    return values


def _class_value(text: str):
    v = float(text)
    return int(v) if v.is_integer() else v


def _write_text(path: str, text: str) -> None:
    from patchcloud.stream.io.las import atomic_output  # here, not at the top: laspy is slow to import, and --help needs none

    try:
        with atomic_output(path, overwrite=True) as f:
            f.write((text + "\n").encode("utf-8"))
    except PatchcloudIOError:
        raise
    except OSError as exc:
        raise PatchcloudIOError(f"{path}: cannot write the table ({exc})") from exc


def _check_written(input: str, plot: str | None, table: str | None) -> None:
    """Before the work: the figure, the table and the --summary-json replace neither the input nor each other, the
    figure only a PNG (:func:`~patchcloud.stream.views.plots.check_png_path`), the table no LAS/LAZ name."""
    from patchcloud.stream.io.las import same_file
    from patchcloud.stream.views.plots import NOT_PICTURE_NAMES, check_png_path

    options.check_side_files([input], None, None, None, overwrite=True)  # the --summary-json
    if plot is not None:
        check_png_path(plot)
    if table is not None and Path(table).name.lower().endswith(NOT_PICTURE_NAMES):
        raise PatchcloudIOError(f"{table}: a LAS/LAZ name, not a table's (--table writes text)")
    for option, path in (("--plot", plot), ("--table", table)):
        if path is not None and same_file(input, path):
            raise PatchcloudIOError(f"{path}: {option} would replace the input")
    options.check_distinct([("--plot", plot), ("--table", table), ("--summary-json", options.summary_json_path())])


@click.command("don-scales")
@click.argument("input", type=click.Path(dir_okay=False))
@click.option("--radii", default="0.1,0.2,0.5,1,2,4", show_default=True, metavar="R1,R2,...",
              help="Radii in the file's horizontal unit, comma-separated; every pair r_s < r_l is scored.")
@click.option("--small", default=None, metavar="R1,R2,...", help="Candidate small radii (the file's unit); the large ones are --large, or else --radii.")
@click.option("--large", default=None, metavar="R1,R2,...", help="Candidate large radii (the file's unit); the small ones are --small, or else --radii.")
@click.option("--classes-from", default="classification", show_default=True, metavar="NAME",
              help="The dimension holding the classes (any dimension of the file, extra bytes included).")
@click.option("--classes", default=None, metavar="C1,C2,...", help="The class values to compare, e.g. 2,6,64. Default: every class present.")
@click.option("--sample", type=int, default=200_000, show_default=True, metavar="N",
              help="Query points, drawn with an equal share per class (seeded: same run, same result).")
@click.option("--mode", type=click.Choice(["fast", "exact"]), default="fast", show_default=True,
              help="Radius normals from voxel moments (fast) or the exact PCA of each ball.")
@click.option("--min-class-points", type=int, default=100, show_default=True, metavar="N",
              help="Fewest points of a class (and defined DoN values per pair) to compare it.")
@click.option("--min-defined", type=float, default=0.5, show_default=True, metavar="FRACTION",
              help="Smallest fraction of a class's query points with a defined DoN for the class to count at a pair.")
@click.option("--max-points", type=int, default=50_000_000, show_default=True, metavar="N",
              help="Largest file accepted: the whole file is loaded into memory.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the query draw.")
@click.option("--plot", "plot", default=None, metavar="OUT.png",
              help="The figure. Default: INPUT's stem + _don_scales.png in the current directory.")
@click.option("--no-plot", is_flag=True, help="Do not draw the figure.")
@click.option("--table", default=None, metavar="OUT.txt", help="Also write the table to this file.")
@options.units
@options.max_memory
@options.quiet
@options.summary_json
@options.reports_errors
def don_scales_command(input, radii, small, large, classes_from, classes, sample, mode, min_class_points, min_defined, max_points, seed,
                       plot, no_plot, table, units, quiet):
    """The Difference-of-Normals radii that best separate the classes of INPUT (LAS/LAZ).

    For every pair r_s < r_l of the radii, the DoN magnitude is computed at
    a stratified sample of points and summarised per class; the pairs are
    ranked by the Fisher ratio sum_c n_c (mu_c - mu)^2 / sum_c n_c sigma_c^2
    (between-class over within-class variance of |DoN|; higher separates
    better).  Prints a table (best pair marked) and writes a figure: the
    ratio over (r_s, r_l) and the per-class |DoN| at the best pair.  The
    file is loaded whole into memory (see --max-points).  An existing
    figure or table file is replaced.

    \b
    Example:
      patchcloud don-scales city.laz
      patchcloud don-scales city.laz --classes 2,6,64 --radii 0.2,0.5,1,2,4 --plot scales.png --table scales.md
      patchcloud don-scales city.laz --classes-from user_data --mode exact --sample 20000
    """
    from patchcloud.stream.jobs.don_scales import don_scales

    if plot is not None and no_plot:
        raise PatchcloudValueError("--plot and --no-plot: give one of them, not both")
    radii_v = parse_list("--radii", radii)
    small_v = parse_list("--small", small)
    large_v = parse_list("--large", large)
    classes_v = parse_list("--classes", classes, _class_value)
    from patchcloud.stream.io.catalog import output_name  # x.copc.laz: x_don_scales.png

    plot_path = None if no_plot else (plot or f"{Path(output_name(input)).stem}_don_scales.png")
    if plot_path is not None and not Path(plot_path).resolve().parent.exists():
        raise PatchcloudIOError(f"{plot_path}: the directory {Path(plot_path).parent} does not exist")
    if table is not None and not Path(table).resolve().parent.exists():
        raise PatchcloudIOError(f"{table}: the directory {Path(table).parent} does not exist")
    _check_written(input, plot_path, table)
    say = None if quiet else (lambda msg: click.echo(msg, err=True))
    result = don_scales(
        input, radii=radii_v, small=small_v, large=large_v, classes_from=classes_from, classes=classes_v, sample=sample,
        mode=mode, min_class_points=min_class_points, min_defined=min_defined, max_points=max_points, seed=seed, progress=say,
        units=units,
    )
    text = result.format()
    options.write_summary_json(result)
    if table is not None:
        _write_text(table, text)
    if plot_path is not None:
        from patchcloud.stream.views.plots import save_png, scale_selection_figure

        save_png(scale_selection_figure(result), plot_path)
    if not quiet:
        click.echo(text)
        if plot_path is not None:
            click.echo(f"\nfigure: {plot_path}")
        if table is not None:
            click.echo(f"table: {table}")
