"""Packages whose public names are imported on first use (PEP 562), so that importing the package is quick.

``patchcloud.core`` and ``patchcloud.stream`` both use it: the command
line then starts without importing numba, dask or zarr until a name that
needs them is used.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable

__all__ = ["lazy_exports"]


def lazy_exports(package: str, sources: dict[str, tuple[str, ...]], public: list[str]) -> tuple[Callable, Callable]:
    """The module ``__getattr__`` and ``__dir__`` of ``package``, which imports each public name from its module on first use.

    ``sources`` maps a module (absolute, or relative to ``package``) to the
    names it provides; ``public`` is the package's ``__all__``.  A name is
    kept in the package's namespace once imported.

    Examples
    --------
    In a package's ``__init__.py``::

        __getattr__, __dir__ = lazy_exports(__name__, {".normals": ("estimate_normals",)}, __all__)
    """
    where = {name: module for module, names in sources.items() for name in names}
    namespace = sys.modules[package].__dict__

    def __getattr__(name: str):
        """Import the public name ``name`` from its module on first use."""
        module = where.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module, package), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(public))

    return __getattr__, __dir__
