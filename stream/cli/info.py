"""``patchcloud info``."""

from __future__ import annotations

import json

import click

from . import options


@click.command("info")
@click.argument("path")
@click.option("--json", "as_json", is_flag=True, help="Print the description as JSON.")
@options.max_memory
@options.reports_errors
def info_command(path, as_json):
    """What PATH holds: a LAS/LAZ file (points, bounds, dimensions, CRS) or a store (tiles, steps done)."""
    from patchcloud.stream import format_info, info

    d = info(path)
    click.echo(json.dumps(d, indent=2) if as_json else format_info(d))
