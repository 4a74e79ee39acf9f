"""Where numba keeps patchcloud's compiled kernels: a user cache directory, never the installed package.

By default numba caches beside the source, in the package's
``__pycache__``.  Those files are not part of the installation, so
uninstalling or reinstalling patchcloud (``pip install .`` then ``pip
install -e .``) leaves ``site-packages/patchcloud/core/`` behind, and that
stray directory then shadows the new installation.  Importing this module
(first thing ``patchcloud.core`` does, before numba is imported) points
``NUMBA_CACHE_DIR`` at ``$XDG_CACHE_HOME/patchcloud/numba`` (default
``~/.cache/patchcloud/numba``), unless the user set it or the directory
cannot be written (then numba's own default stands).
"""

from __future__ import annotations

import os

__all__ = ["cache_dir"]


def cache_dir() -> str:
    """The directory patchcloud asks numba to cache compiled kernels in."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "patchcloud", "numba")


if "NUMBA_CACHE_DIR" not in os.environ:
    _d = cache_dir()
    try:
        os.makedirs(_d, exist_ok=True)
        if os.access(_d, os.W_OK):
            os.environ["NUMBA_CACHE_DIR"] = _d
    except OSError:
        pass
