"""dask without its HTML templates, for the processes patchcloud runs itself (the console script, its local workers).

``import distributed`` imports ``dask.widgets``, which imports ``jinja2``
and loads its template environment to draw dask objects as HTML in a
notebook: 0.04 s of every process that imports dask.distributed (``python
-X importtime``), on the path of every worker's start (the fork server
imports dask.distributed before any worker can be forked).  No process of a
``patchcloud`` command draws HTML, and ``dask.widgets`` takes a missing
``jinja2`` as the diagnostics left out (its functions then raise
ImportError when called), so :func:`skip_dask_templates` hides ``jinja2``
while ``dask.widgets`` runs.  Another import of ``jinja2`` (bokeh's
dashboard, where it is installed) works as before.  Like the other skips
(:mod:`~patchcloud.stream.engine.laspy_start`), only the console script
and its workers do it, not ``import patchcloud``.
"""

from __future__ import annotations

from patchcloud.stream.engine.import_hooks import hide_while_importing

__all__ = ["skip_dask_templates", "TEMPLATES", "WIDGETS"]

#: What dask imports for its HTML templates.
TEMPLATES = "jinja2"
#: The dask module that imports it.
WIDGETS = "dask.widgets"


def skip_dask_templates() -> bool:
    """Have ``dask.widgets``, when it is imported, go without ``jinja2`` (see the module's notes).

    Returns False when ``dask.widgets`` is already imported (too late).
    """
    return hide_while_importing(WIDGETS, TEMPLATES)
