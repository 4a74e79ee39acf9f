"""``patchcloud tile``."""

from __future__ import annotations

import click

from . import options


@click.command("tile")
@click.argument("input", type=click.Path(dir_okay=False))
@click.argument("store")
@options.tile_size
@options.units
@options.classes
@options.keep_noise
@options.scheduler
@options.workers
@options.max_memory
@options.overwrite
@options.quiet
@options.reports_errors
def tile_command(input, store, tile_size, units, classes, keep_noise, scheduler, workers, overwrite, quiet):
    """Cut INPUT (LAS/LAZ) into the tiled zarr STORE (a path or fsspec URL), without computing anything.

    A later `patchcloud normals INPUT OUT --store STORE` starts from it.
    """
    from patchcloud.stream import format_info, info, tile

    s = tile(input, store, tile_size=tile_size, scheduler=scheduler, workers=workers, overwrite=overwrite, quiet=quiet,
             classes=classes, keep_noise=keep_noise, units=units)
    if not quiet:
        click.echo(format_info(info(s.url)))
