"""``patchcloud don``."""

from __future__ import annotations

import click

from patchcloud.core import DonOptions

from . import options


@click.command("don")
@options.paths_argument
@options.don_options
@options.job_options
@options.catalog_options
@options.report_option
@options.reports_errors
def don_command(paths, r_small, r_large, mode, viewpoint, report, **run):
    """Difference of Normals of INPUT (LAS/LAZ/COPC, any size), written to OUTPUT.

    With --out-dir DIR every argument is an input, the files are taken as
    one cloud, and each gets its output in DIR.

    DoN = (n(p, rs) - n(p, rl)) / 2, with n(p, r) the PCA normal of the
    points within r of p, both facing the viewpoint.  OUTPUT (LAZ when its
    name ends in .laz) holds every input point once, in input order, every
    original dimension unchanged, plus DoN (the magnitude, 0 to 1) and
    DoNX, DoNY, DoNZ (float32; an input dimension of one of these names takes
    this run's values); 0 in all four where a ball holds too few
    points for a normal, and for the points left out (--classes; noise and
    withheld points unless --keep-noise), which are in no ball.  Memory
    depends on --tile-size, not on the file.

    \b
    Example:
      patchcloud don street.laz street_don.laz --rs 0.2 --rl 2.0 --report street_don.html
    """
    options.start_workers_early(paths, run, "patchcloud.stream.jobs.don")  # before the job's imports
    from patchcloud.stream import don

    run = options.run_options(run)
    input, output = options.input_and_output(paths, run.out_dir, report, run.overwrite, run.profile, store=run.store)
    asked = DonOptions(r_small=r_small, r_large=r_large, mode=mode, viewpoint=viewpoint or None)
    summary = don(input, output, asked, run)
    options.finish_job(summary, run.quiet, report, "report_don")
