"""``patchcloud render`` and ``patchcloud render-tiles``."""

from __future__ import annotations

import click

from patchcloud.core import PatchcloudIOError, PatchcloudValueError

from . import options

__all__ = ["render_command", "render_tiles_command"]

_MODES = ["normals", "curvature", "don", "segments", "patches", "classification", "intensity", "elevation"]


@click.command("render")
@options.paths_argument
@click.option("--color", "--colour", "color", type=click.Choice(_MODES), required=True,
              help="What the colours show: normals (RGB = (n+1)/2), curvature, don (|DoN|), segments (ClusterID), "
              "patches (PatchId, boundaries darkened), classification (ASPRS colours), intensity, elevation.")
@click.option("--view", type=click.Choice(["top", "oblique", "side"]), default=None,
              help="Orthographic view. Default: top when the height range is under 0.5 x the larger horizontal "
              "extent (aerial, street scans), else oblique (from the south-west, 35 degrees up).")
@click.option("--bbox", type=float, nargs=4, default=None, metavar="XMIN YMIN XMAX YMAX",
              help="Draw only this box (file coordinates, in the file's units); it is the frame.")
@click.option("--width", type=int, default=1600, show_default=True, metavar="PIXELS",
              help="Width of the PNG, its title, axes and colour bar or legend included (64 to 6000); the height follows "
              "the framing.")
@click.option("--shade/--no-shade", default=None,
              help="Lambert shading from the normals. Default: shade when the file has NormalX/Y/Z.")
@click.option("--range", "value_range", type=float, nargs=2, default=None, metavar="LOW HIGH",
              help="Colour range of curvature, don, intensity, elevation. Default: 2nd-98th percentile of the drawn points.")
@click.option("--fill", type=float, default=None, metavar="PIXELS",
              help="Close holes: an empty pixel within this many pixels of a point shows the nearest point (0: none). "
              "Default: 2 x the mean point spacing in pixels (over the area the points cover), 1.5 to 32.")
@click.option("--heights", type=click.Choice(["robust", "all"]), default="robust", show_default=True,
              help="robust: frame the heights of a sample of the file, so noise far above or below (birds, low "
              "returns) does not squash the picture; all: frame the header's bounds.")
@click.option("--units", type=click.Choice(["m", "ft", "us-ft"]), default=None,
              help="The unit of the file's coordinates on the axes and in the summary, instead of its CRS's (a file without "
              "a CRS, or a wrong one; as in the jobs). Default: the CRS's units, \"file units\" without a CRS.")
@options.catalog_options
@options.max_memory
@options.quiet
@options.summary_json
@options.reports_errors
def render_command(paths, color, view, bbox, width, shade, value_range, fill, heights, units, out_dir, assume_crs, quiet):
    """A PNG picture of INPUT (LAS/LAZ/COPC, any size) in OUTPUT.

    Several inputs (files, directories, quoted globs) before OUTPUT are
    drawn as one cloud in one picture, a map of the catalog; with --out-dir
    DIR every argument is an input and each file gets its own picture,
    DIR/NAME.png.

    The files are read in chunks and decimated to the point nearest the
    viewer in every pixel, so memory depends on the image, not the files.
    An existing OUTPUT is replaced.

    \b
    Example:
      patchcloud render city_normals.laz city.png --color normals
      patchcloud render city_segments.laz seg.png --color segments --view oblique --width 2400
      patchcloud render city.laz z.png --color elevation --bbox 650000 6860000 650100 6860100
      patchcloud render tiles/ catalog.png --color elevation
      patchcloud render tiles_normals/ --out-dir pictures/ --color normals
    """
    from patchcloud.stream.io.catalog import check_out_dir, expand_inputs, output_paths
    from patchcloud.stream.io.las import check_not_input, open_source
    from patchcloud.stream.views.plots import check_png_path
    from patchcloud.stream.views.render import check_modes, render

    from patchcloud.stream.views.layout import MIN_WIDTH
    from patchcloud.stream.views.render import MAX_WIDTH

    if not MIN_WIDTH <= width <= MAX_WIDTH:
        raise PatchcloudValueError(f"--width must be {MIN_WIDTH} to {MAX_WIDTH} pixels (the PNG, title and legend included); "
                                   f"got {width}")
    if out_dir is None:
        if len(paths) < 2:
            raise PatchcloudValueError(f"{paths[0]}: give an OUTPUT picture after it, or --out-dir DIR")
        jobs = [(list(paths[:-1]) if len(paths) > 2 else paths[0], paths[-1])]
        options.check_side_files(paths[:-1], paths[-1], None, None, True)  # a --summary-json replaces neither
    else:
        options.check_side_files(paths, None, None, None, True, out_dir=out_dir, suffix=".png")  # one picture per file: every file checked before the first is drawn (render checks one job itself)
        inputs = expand_inputs(list(paths))
        directory = check_out_dir(out_dir)
        jobs = list(zip(inputs, output_paths(inputs, directory, list(paths), suffix=".png")))
        opened = {input: open_source(input, allow_empty=True) for input in inputs}  # each file is drawn alone
        empty = [input for input in inputs if opened[input].point_count == 0]
        if len(empty) == len(inputs):
            raise PatchcloudIOError(f"{empty[0]}: the file holds no points" + (", nor do the others" if len(empty) > 1 else ""))
        jobs = [(input, output) for input, output in jobs if input not in empty]  # nothing to draw: said below, no picture
        for input, output in jobs:
            check_modes([opened[input]], [color], shade)
            check_not_input(output, [opened[input].path])
            if directory.exists():
                check_png_path(output)  # an existing file there that is not a PNG: refused before the first is drawn
        directory.mkdir(exist_ok=True)
        if not quiet:
            for input in empty:
                click.echo(f"{input}: no points, no picture")
    summaries = []
    for input, output in jobs:
        s = render(input, output, color=color, view=view, bbox=bbox, width=width, shade=shade, value_range=value_range, fill=fill,
                   heights=heights, assume_crs=assume_crs, units=units)
        summaries.append(s)
        if not quiet:
            click.echo(s.format())
    options.write_summary_json(summaries[0] if out_dir is None else summaries)


@click.command("render-tiles")
@click.argument("store")
@click.argument("output", type=click.Path(dir_okay=False))
@click.option("--by", type=click.Choice(["points", "patches"]), default="points", show_default=True,
              help="What the second panel shows per column of tiles.")
@click.option("--step", default=None, metavar="NAME",
              help="The step whose state is shown: sort, fit, finish (normals), don_skin, don, cluster (don, segment), "
              "compress. Default: the last of them any tile reached.")
@options.max_memory
@options.quiet
@options.summary_json
@options.reports_errors
def render_tiles_command(store, output, by, step, quiet):
    """A PNG of the tile grid of STORE from above: which tiles are done, partly done, pending or failed, and points per tile.

    Tiles stacked in z are one column: done only if all its tiles are.  A
    tile whose task failed (the store records its error until the task
    succeeds) is failed, in red, and the summary lists the errors.
    """
    from patchcloud.stream.views.render_tiles import render_tiles

    options.check_side_files([store], output, None, None, True)  # a --summary-json replaces neither
    s = render_tiles(store, output, by=by, step=step)
    options.write_summary_json(s)
    if not quiet:
        click.echo(s.format())
