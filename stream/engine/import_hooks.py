"""Hooks on the import of one module: another module hidden while it runs, or a function called once it has run.

What the console script and its workers use to start faster
(:mod:`~patchcloud.stream.engine.numba_start`,
:mod:`~patchcloud.stream.engine.laspy_start`): each hook is a finder put
first on ``sys.meta_path`` that finds its module as the path finder does
and wraps the module's own loader.  Other imports are left alone.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import threading
from collections.abc import Callable

__all__ = ["hide_while_importing", "after_importing", "import_meanwhile"]


def hide_while_importing(module: str, hidden: str) -> bool:
    """Make ``hidden`` unimportable (``ImportError``) while ``module`` runs, when it is first imported.

    Returns False when ``module`` is already imported (too late).  An
    import of ``hidden`` at any other time works as usual.

    >>> hide_while_importing("sys", "os")  # imported long ago
    False
    """
    if module in sys.modules:
        return False
    _install(_Hook(module, hidden=hidden))
    return True


def after_importing(module: str, then: Callable) -> None:
    """Call ``then(module object)`` once ``module`` has run: at once if it is already imported, else when it is."""
    if module in sys.modules:
        then(sys.modules[module])
        return
    _install(_Hook(module, then=then))


def import_meanwhile(*modules: str) -> threading.Thread | None:
    """Import ``modules`` on a thread of their own while the caller waits on something else (None: all imported already).

    For a module the caller needs after a wait (a dask step's tasks): its
    import then costs the caller nothing.  An import of it meanwhile waits
    for this one, as imports do; an error here is left for that import to raise.

    >>> import_meanwhile("sys") is None
    True
    """
    todo = [m for m in modules if m not in sys.modules]
    if not todo:
        return None

    def run() -> None:
        for m in todo:
            try:
                importlib.import_module(m)
            except Exception:  # the caller's own import says what is wrong
                pass

    thread = threading.Thread(target=run, name="patchcloud-import", daemon=True)
    thread.start()
    return thread


def _install(hook: "_Hook") -> None:
    if not any(isinstance(f, _Hook) and (f.name, f.hidden, f.then) == (hook.name, hook.hidden, hook.then) for f in sys.meta_path):
        sys.meta_path.insert(0, hook)


class _Hook(importlib.abc.MetaPathFinder):
    """Finds ``name`` as the path finder does, with its loader wrapped in :class:`_Loader`."""

    def __init__(self, name: str, hidden: str | None = None, then: Callable | None = None) -> None:
        self.name, self.hidden, self.then = name, hidden, then

    def find_spec(self, name, path=None, target=None):
        if name != self.name:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path, target)
        if spec is not None and spec.loader is not None:
            spec.loader = _Loader(spec.loader, self.hidden, self.then)
        return spec


class _Loader(importlib.abc.Loader):
    """A module's own loader, run with ``hidden`` unimportable (``sys.modules[hidden] = None``), then ``then``."""

    def __init__(self, loader, hidden: str | None, then: Callable | None) -> None:
        self.loader, self.hidden, self.then = loader, hidden, then

    def create_module(self, spec):
        return self.loader.create_module(spec)

    def exec_module(self, module) -> None:
        hide = self.hidden is not None and self.hidden not in sys.modules
        if hide:
            sys.modules[self.hidden] = None  # an import of it now raises ImportError without running it
        try:
            self.loader.exec_module(module)
        finally:
            if hide and self.hidden in sys.modules and sys.modules[self.hidden] is None:
                del sys.modules[self.hidden]
        if self.then is not None:
            self.then(module)

    def __getattr__(self, name):  # get_source, get_filename, ...: the module's own loader's
        return getattr(self.loader, name)
