"""Names the doctests of ``patchcloud.core`` and ``patchcloud.stream`` may use.

- ``sample``: path of the embedded IGN LiDAR HD sample (60k points, data/README.md);
- ``tmp``: a fresh temporary directory (a :class:`pathlib.Path`) for the example's outputs.
"""

from pathlib import Path

import pytest

SAMPLE = Path(__file__).resolve().parent / "data" / "test_data_77055_627760_LA93_IGN69.laz"


@pytest.fixture(autouse=True)
def _doctest_names(doctest_namespace, tmp_path):
    doctest_namespace["sample"] = str(SAMPLE)
    doctest_namespace["tmp"] = tmp_path


def _alias_packages() -> None:
    """Make pytest's doctest collection of ``core/x.py`` and ``stream/y/z.py`` find the installed modules.

    pytest names a collected file after its directories (``core.octree``,
    ``stream.jobs.normals``), which would import every module a second time
    under that name, beside ``patchcloud.core.octree``: two copies of every
    class (an error raised by one is not the other's), and numba kernels
    cached under a module name that does not exist outside pytest.  Each
    module of the two packages is imported once, by its real name, and
    registered under pytest's name too.  ``stream/patchcloud/`` is the top
    package ``patchcloud`` itself (pyproject's package-dir), not a
    sub-package of the stream: pytest's ``stream.patchcloud`` is ``patchcloud``.
    """
    import importlib
    import pkgutil
    import sys

    top = importlib.import_module("patchcloud")
    sys.modules.setdefault("stream.patchcloud", top)

    def walk(package, short: str) -> None:
        sys.modules.setdefault(short, package)
        for info in pkgutil.iter_modules(package.__path__, prefix=package.__name__ + "."):
            if info.name == "patchcloud.stream.patchcloud":
                continue
            module = importlib.import_module(info.name)
            alias = short + info.name[len(package.__name__):]
            if info.ispkg:
                walk(module, alias)
            else:
                sys.modules.setdefault(alias, module)

    for short in ("core", "stream"):
        walk(importlib.import_module(f"patchcloud.{short}"), short)


_alias_packages()
