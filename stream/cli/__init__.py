"""The ``patchcloud`` command line (click): one module per subcommand, shared options in :mod:`.options`."""

from __future__ import annotations

import click

from .compress import compress_command, decompress_command
from .don import don_command
from .don_scales import don_scales_command
from .info import info_command
from .normals import normals_command
from .render import render_command, render_tiles_command
from .segment import segment_command
from .tile import tile_command

__all__ = ["main"]


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="patchcloud")
@click.option("--debug", is_flag=True, default=False, help="Show the traceback of an unexpected error (a bug) instead of one line.")
def main(debug: bool) -> None:
    """Normals, curvature, Difference of Normals and segments of LiDAR point clouds of any size.

    \b
    Start with:
      patchcloud normals in.laz out.laz       normals and curvature of a LAS/LAZ file
      patchcloud don in.laz out.laz           Difference of Normals (DoN) of every point
      patchcloud segment in.laz out.laz       DoN segments (street furniture, kerbs, ...)
      patchcloud don-scales labelled.laz      which (rs, rl) separates the classes best
      patchcloud compress in.laz out.pcz      quadric patch models + residual points
      patchcloud decompress in.pcz out.laz    points back, at any density
      patchcloud info in.laz                  what a file (or a store) holds
      patchcloud render in.laz out.png        a picture (render-tiles: a store's tiles)
    """


main.add_command(normals_command)
main.add_command(don_command)
main.add_command(segment_command)
main.add_command(don_scales_command)
main.add_command(compress_command)
main.add_command(decompress_command)
main.add_command(tile_command)
main.add_command(info_command)
main.add_command(render_command)
main.add_command(render_tiles_command)
