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

The same processes load numba's cached kernels without the set-up that
only compiling needs (:func:`load_cached_kernels_lightly`).  Before loading
a kernel from its cache, numba "refreshes" its target: it imports every
module that implements Python and numpy for compiled code (``numba.np.*``,
``numba.cpython.*``, ``numba.typed``, ``numba.experimental``) and
registers their typing and lowering rules, 0.07 s of every process (the
first cached kernel's call: 0.105 s, 0.032 s without).  None of that is
used by machine code loaded from a cache; what such code links against is
numba's runtime (initialised here, as numba's refresh does) and the
symbols numba registers when its context is made, with the hash secret of
``numba.cpython.hashing`` (imported here too).  A kernel not in the cache
is compiled as before, and compiling refreshes in full.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import sys

__all__ = ["skip_numba_blas_probe", "load_cached_kernels_lightly", "PROBED", "PROBING", "CACHING"]

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


#: The numba module whose cache loads kernels.
CACHING = "numba.core.caching"


def load_cached_kernels_lightly() -> bool:
    """Have numba load cached kernels without refreshing its target first (see the module's notes).

    Takes effect when numba's cache module is imported (at once if it is
    already): numba itself is not imported here, so ``patchcloud --help``
    still starts without it.  Returns False where this numba's cache does
    not work as this expects (numba then loads as it always does).  Loaded
    kernels are the cache's machine code either way: the same results.
    """
    module = sys.modules.get(CACHING)
    if module is not None:
        return _lighten(module)
    if not any(isinstance(f, _Lighten) for f in sys.meta_path):
        sys.meta_path.insert(0, _Lighten())
    return True


def _lighten(caching) -> bool:
    """Replace ``caching.Cache.load_overload`` by one without the target's refresh; False if it is not as expected."""
    cache = getattr(caching, "Cache", None)
    if cache is None or not all(hasattr(cache, n) for n in ("load_overload", "_load_overload", "_guard_against_spurious_io_errors")):
        return False
    if getattr(cache.load_overload, "lightly", False):
        return True
    from numba.core.runtime import nrt

    def load_overload(self, sig, target_context):
        nrt.rtsys.initialize(target_context)  # numba's runtime: what loaded code calls to allocate
        import numba.cpython.hashing  # noqa: F401  its import gives the LLVM symbols of Python's hash secret
        with self._guard_against_spurious_io_errors():
            return self._load_overload(sig, target_context)

    load_overload.lightly = True
    load_overload.__doc__ = cache.load_overload.__doc__
    cache.load_overload = load_overload
    return True


class _Lighten(importlib.abc.MetaPathFinder):
    """Finds :data:`CACHING` as the path finder does, with a loader that lightens it once it has run (:func:`_lighten`)."""

    def find_spec(self, name, path=None, target=None):
        if name != CACHING:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path, target)
        if spec is not None and spec.loader is not None:
            spec.loader = _ThenLighten(spec.loader)
        return spec


class _ThenLighten(importlib.abc.Loader):
    """A module's own loader, then :func:`_lighten` on the module it made."""

    def __init__(self, loader) -> None:
        self.loader = loader

    def create_module(self, spec):
        return self.loader.create_module(spec)

    def exec_module(self, module) -> None:
        self.loader.exec_module(module)
        _lighten(module)

    def __getattr__(self, name):  # get_source, get_filename, ...: the module's own loader's
        return getattr(self.loader, name)
