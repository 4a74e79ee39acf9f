"""numba without its BLAS probe, for the processes patchcloud runs itself (the console script, its local workers).

When numba is imported, ``numba.np.arraymath`` checks that a BLAS is
there for ``np.dot`` and ``np.linalg`` in compiled code by importing
``scipy.linalg.cython_blas``, which imports ``scipy.linalg`` and with it
scipy's array-API layer, which makes numpy import ``numpy.testing`` and
``numpy.f2py``: 0.14 s of every run (``python -X importtime``), a fifth of
a small file's whole run.  patchcloud's kernels use neither ``np.dot`` nor
``np.linalg`` (their 3x3 eigen-solver is their own), so
:func:`skip_numba_blas_probe` makes that one import fail while
``numba.np.arraymath`` runs (numba then records "no BLAS" and moves on),
and any other import of ``scipy.linalg`` works as before.  Compiled code
in the same process that used ``np.dot`` would then be refused by numba;
so only the console script (:func:`patchcloud.stream.cli.run`) and the
workers of its local cluster do it, not ``import patchcloud``.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import sys

__all__ = ["skip_numba_blas_probe", "PROBED", "PROBING"]

#: The module numba imports to find a BLAS.
PROBED = "scipy.linalg.cython_blas"
#: The numba module that imports it, once, as it is imported.
PROBING = "numba.np.arraymath"


def skip_numba_blas_probe() -> bool:
    """Have ``numba.np.arraymath``, when it is imported, find no BLAS without importing scipy (see the module's notes).

    Returns whether it will: False when numba has already done its probe in this process.
    """
    if PROBING in sys.modules:
        return False
    if not any(isinstance(f, _SkipProbe) for f in sys.meta_path):
        sys.meta_path.insert(0, _SkipProbe())
    return True


class _SkipProbe(importlib.abc.MetaPathFinder):
    """Finds ``numba.np.arraymath`` as the path finder does, with a loader that hides :data:`PROBED` while it runs."""

    def find_spec(self, name, path=None, target=None):
        if name != PROBING:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path, target)
        if spec is not None and spec.loader is not None:
            spec.loader = _WithoutProbe(spec.loader)
        return spec


class _WithoutProbe(importlib.abc.Loader):
    """A module's own loader, run with :data:`PROBED` unimportable (``sys.modules[PROBED] = None``) for the while."""

    def __init__(self, loader) -> None:
        self.loader = loader

    def create_module(self, spec):
        return self.loader.create_module(spec)

    def exec_module(self, module) -> None:
        hide = PROBED not in sys.modules
        if hide:
            sys.modules[PROBED] = None  # an import of it now raises ImportError without importing scipy.linalg
        try:
            self.loader.exec_module(module)
        finally:
            if hide and PROBED in sys.modules and sys.modules[PROBED] is None:
                del sys.modules[PROBED]

    def __getattr__(self, name):  # get_source, get_filename, ...: the module's own loader's
        return getattr(self.loader, name)
