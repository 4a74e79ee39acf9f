"""``patchcloud normals``."""

from __future__ import annotations

import click

from patchcloud.core import Method, NormalsOptions

from . import options


@click.command("normals")
@options.paths_argument
@click.option("--criterion", type=click.Choice(["rmse", "sigma3"]), default=NormalsOptions.criterion, show_default=True,
              help="When an octree node is one smooth patch: quadric fit RMSE below the threshold (in the file's unit), or surface variation.")
@click.option("--threshold", type=float, default=None, help="Threshold of the criterion. Default: from the scanner noise (rmse), 0.005 (sigma3).")
@click.option("--orient", type=click.Choice(["up", "viewpoint", "outward", "none"]), default=NormalsOptions.orient, show_default=True,
              help="Which side normals point to: up (+Z, aerial and mobile LiDAR), towards --viewpoint, away from the centre, or no rule. "
              "up, outward and none orient whole groups of linked patches, so a wall or a curved surface keeps the side its neighbours "
              "give it; viewpoint turns every normal to face the viewpoint, point by point, as PDAL does.")
@click.option("--always-up", is_flag=True,
              help="PDAL's always_up (filters.normal): after orientation, flip every normal with NormalZ < 0, point by point, "
              "so NormalZ >= 0 everywhere (the principal curvatures follow). Unlike --orient up, which turns whole patch groups. "
              "Default: off (PDAL's default is on).")
@click.option("--fallback-knn", "k_fallback", type=int, default=NormalsOptions.k_fallback, show_default=True, metavar="K",
              help="Neighbours of the k-NN fallback (3 to 1000): the PCA normal of the points of edge and sparse patches that have no "
              "moment normal (NormalMethod 3; NormalMethod 4: cell moments). "
              "Not PDAL's knn, the neighbours of every normal: patchcloud's other normals come from the patches' quadrics.")
@click.option("--viewpoint", type=float, nargs=3, default=None, metavar="X Y Z",
              help="Every normal faces this point (file coordinates), point by point, as PDAL's viewpoint: it implies --orient "
              "viewpoint, and does not go with --always-up (PDAL's viewpoint overrides its always_up).")
@click.option("--no-blend", is_flag=True, help="Do not blend normals across patch faces.")
@click.option("--principal-curvatures", is_flag=True,
              help="Also write PrincipalCurvature1 >= PrincipalCurvature2 (1/unit of the file's CRS, positive where convex seen from the normal's side) "
              "and the first's direction, PrincipalDirectionX/Y/Z (0 where a point has none).")
@options.job_options
@options.catalog_options
@options.report_option
@options.reports_errors
def normals_command(paths, criterion, threshold, orient, always_up, k_fallback, viewpoint, no_blend, principal_curvatures, report, **run):
    """Normals and curvature of INPUT (LAS/LAZ/COPC, any size), written to OUTPUT.

    With --out-dir DIR every argument is an input (files, directories,
    quoted globs): the files are taken as one cloud (normals and
    orientation across their boundaries are those of the merged file) and
    each gets its output in DIR.

    OUTPUT (LAZ when its name ends in .laz) holds every input point once, in
    input order, with every original dimension unchanged, plus NormalX,
    NormalY, NormalZ, Curvature (surface variation), NormalMethod ({methods}) and
    PatchId (an input dimension of one of these names, such as PDAL's
    NormalX, takes this run's values, keeping its type).  Points left out (--classes; noise and withheld points unless
    --keep-noise) get NormalMethod 0, a zero normal, Curvature 0 and PatchId
    4294967295.  Memory depends on --tile-size, not on the file.  A run that is
    stopped can be resumed by running the same command again with --store.

    \b
    Example:
      patchcloud normals city.laz city_normals.laz
      patchcloud normals city.laz out.laz --store /data/city.zarr --scheduler tcp://head:8786
      patchcloud normals city.laz city_normals.laz --report city_normals.html
      patchcloud normals tiles/ --out-dir tiles_normals/
    """
    options.start_workers_early(paths, run, "patchcloud.stream.jobs.normals")  # before the job's imports
    from patchcloud.stream import normals

    if viewpoint:  # PDAL's meaning: a viewpoint given orients the normals towards it
        explicit = click.get_current_context().get_parameter_source("orient") != click.core.ParameterSource.DEFAULT
        if explicit and orient != "viewpoint":
            raise click.UsageError(f"--viewpoint orients the normals towards it: it goes with --orient viewpoint, not --orient {orient}")
        orient = "viewpoint"
    run = options.run_options(run)
    input, output = options.input_and_output(paths, run.out_dir, report, run.overwrite, run.profile, store=run.store)
    asked = NormalsOptions(criterion=criterion, threshold=threshold, orient=orient, viewpoint=viewpoint or None, blend=not no_blend,
                           k_fallback=k_fallback)
    summary = normals(input, output, asked, run, principal_curvatures=principal_curvatures, always_up=always_up)
    options.finish_job(summary, run.quiet, report, "report_normals")


normals_command.help = normals_command.help.replace("{methods}", Method.describe(long=True))
