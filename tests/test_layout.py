"""The package layout rules, checked on the source (AST) of every module of ``core/`` and ``stream/``.

a. no module imports a private name (``_x``, not a dunder) of another module,
   nor uses one as ``module._x``; a private *module* may be imported only by
   the modules of its own package (its siblings);
b. ``patchcloud.core`` never imports ``patchcloud.stream``;
c. ``patchcloud.stream.io`` and ``patchcloud.stream.engine`` never import
   ``patchcloud.stream.jobs``, ``.views`` or ``.cli`` (nor the names the
   ``patchcloud.stream`` package re-exports from them);
d. ``stream/`` has at most :data:`MAX_STREAM_TOP` modules at its top besides
   ``__init__.py``;
e. no ``doctest: +SKIP`` in the sources;
f. ``patchcloud.stream`` imports from ``patchcloud.core`` itself only, and
   only names of ``patchcloud.core.__all__``;
g. the top package ``patchcloud`` (its ``__init__.py`` is in
   ``stream/patchcloud/``, pyproject's package-dir) re-exports: it defines
   no function or class, imports from ``patchcloud.core`` and
   ``patchcloud.stream`` only (the packages, names of their ``__all__``),
   and every name of its ``__all__`` but ``__version__`` is one of theirs.

Imports anywhere count: at module level, inside functions and under
``if TYPE_CHECKING:``.  Every test lists all its offenders as
``path:line: statement  (why)``.  The ``test_checker_*`` tests feed the
checker snippets with known answers, so that the rules cannot pass by
seeing nothing.
"""

from __future__ import annotations

import ast
import re
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Dotted name of each package -> its directory.
PACKAGES = {"patchcloud.core": ROOT / "core", "patchcloud.stream": ROOT / "stream", "patchcloud": ROOT / "stream" / "patchcloud"}
#: The top package's directory, inside stream/ but no part of ``patchcloud.stream``.
TOP = PACKAGES["patchcloud"]

#: The most modules ``stream/`` may hold at its top, ``__init__.py`` aside.
MAX_STREAM_TOP = 6

#: Sub-packages of the stream that may not depend on the ones above them.
LOWER = ("patchcloud.stream.io", "patchcloud.stream.engine")
UPPER = ("patchcloud.stream.jobs", "patchcloud.stream.views", "patchcloud.stream.cli")

SKIP_RE = re.compile(r"doctest:[^\n]*\+SKIP")


@dataclass(frozen=True)
class Module:
    name: str  # dotted name; a package's __init__ has the package's name
    path: str  # for messages, relative to the repository
    is_package: bool
    source: str

    @property
    def package(self) -> str:
        """The package relative imports resolve against (a package's ``__init__`` is its own)."""
        return self.name if self.is_package else self.name.rpartition(".")[0]

    @property
    def tree(self) -> ast.Module:
        return ast.parse(self.source, filename=self.path)


def discover() -> list[Module]:
    """Every ``.py`` module of the three packages, recursively (the top package's directory counted once, as itself)."""
    out = []
    for pkg, directory in PACKAGES.items():
        for path in sorted(directory.rglob("*.py")):
            rel = path.relative_to(directory)
            if "__pycache__" in rel.parts or (pkg != "patchcloud" and path.is_relative_to(TOP)):
                continue
            parts = list(rel.with_suffix("").parts)
            is_package = parts[-1] == "__init__"
            if is_package:
                parts = parts[:-1]
            name = ".".join([pkg, *parts])
            out.append(Module(name, path.relative_to(ROOT).as_posix(), is_package, path.read_text(encoding="utf-8")))
    return out


MODULES = discover()
KNOWN = frozenset(m.name for m in MODULES)


#: Names of the standard library that begin with an underscore yet are its documented, public API (the Python docs
#: describe ``os._exit`` as the way for a child process to end at once): not private names of another module.
DOCUMENTED_UNDERSCORE = frozenset({"os._exit"})


def is_private(name: str) -> bool:
    """``_x`` is private; dunders (``__all__``, ``__future__``) are not."""
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def under(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def resolve(mod: Module, node: ast.ImportFrom) -> str:
    """The absolute name of the module ``from <...> import`` reads from."""
    if not node.level:
        return node.module or ""
    parts = mod.package.split(".")
    if node.level - 1 > len(parts) - 1:
        raise ValueError(f"{mod.path}:{node.lineno}: relative import beyond the top package")
    base = parts[: len(parts) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


@dataclass(frozen=True)
class Edge:
    """One imported module or name: ``target`` is what the statement makes the importer depend on."""

    line: int
    text: str  # the statement (or expression) as written, on one line
    source: str  # the module read from (``from`` imports) or imported
    name: str | None  # the imported name of a ``from`` import, None for ``import x``
    target: str  # source.name when that is a known module, else source (for import x: x)


def edges(mod: Module, known=KNOWN) -> list[Edge]:
    """Every import of the module, ``from __future__`` aside, resolved."""
    out = []
    for node in ast.walk(mod.tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                out.append(Edge(node.lineno, _one_line(node), a.name, None, a.name))
        elif isinstance(node, ast.ImportFrom):
            src = resolve(mod, node)
            if src == "__future__":
                continue
            for a in node.names:
                full = f"{src}.{a.name}"
                line = getattr(a, "lineno", node.lineno)
                out.append(Edge(line, _one_line(node), src, a.name, full if full in known else src))
        elif isinstance(node, ast.Call) and _dynamic_import(node):
            out.append(Edge(node.lineno, _one_line(node), node.args[0].value, None, node.args[0].value))
    return sorted(out, key=lambda e: e.line)


def _dynamic_import(node: ast.Call) -> bool:
    f = node.func
    fname = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else None
    return (
        fname in ("import_module", "__import__")
        and bool(node.args)
        and isinstance(node.args[0], ast.Constant)
        and isinstance(node.args[0].value, str)
    )


def _one_line(node: ast.AST) -> str:
    return " ".join(ast.unparse(node).split())


def _report(mod: Module, line: int, text: str, why: str) -> str:
    return f"{mod.path}:{line}: {text}  ({why})"


def _private_module_problem(mod: Module, target: str) -> str | None:
    """Why importing module ``target`` from ``mod`` breaks rule (a), or None.

    Every private component of ``target`` is a private module whose parent
    package must be the importer's own package.
    """
    parts = target.split(".")
    for i, p in enumerate(parts):
        if is_private(p):
            parent = ".".join(parts[:i])
            if mod.package != parent:
                return f"private module {'.'.join(parts[: i + 1])} used outside its package {parent}"
    return None


def _module_aliases(mod: Module, known) -> dict[str, str]:
    """Names an import binds to a module: local name -> module."""
    out = {}
    for node in ast.walk(mod.tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.asname:
                    out[a.asname] = a.name
                else:
                    top = a.name.split(".")[0]
                    out[top] = top
        elif isinstance(node, ast.ImportFrom):
            src = resolve(mod, node)
            for a in node.names:
                full = f"{src}.{a.name}"
                if full in known:
                    out[a.asname or a.name] = full
    return out


def _chain(node: ast.Attribute) -> list[str] | None:
    """``a.b.c`` -> ["a", "b", "c"]; None unless the chain starts at a plain name."""
    parts = []
    cur: ast.AST = node
    while isinstance(cur, ast.Attribute):
        parts.append(cur.attr)
        cur = cur.value
    if not isinstance(cur, ast.Name):
        return None
    parts.append(cur.id)
    return parts[::-1]


def private_violations(mod: Module, known=KNOWN) -> list[str]:
    """Rule (a) for one module."""
    out = []
    for e in edges(mod, known):
        problem = _private_module_problem(mod, e.source)
        if problem:
            out.append(_report(mod, e.line, e.text, problem))
            continue
        if e.name is None or not is_private(e.name):
            continue
        if e.target != e.source:  # the name is a module: a private module
            problem = _private_module_problem(mod, e.target)
            if problem:
                out.append(_report(mod, e.line, e.text, problem))
        else:
            out.append(_report(mod, e.line, e.text, f"private name {e.name} of {e.source}"))
    aliases = _module_aliases(mod, known)
    seen = set()
    for node in sorted(ast.walk(mod.tree), key=lambda n: (getattr(n, "lineno", 0), getattr(n, "col_offset", 0))):
        if not isinstance(node, ast.Attribute):
            continue
        chain = _chain(node)
        if chain is None or chain[0] not in aliases or id(node) in seen:
            continue
        # only the outermost attribute of a chain is judged (inner ones are its prefixes)
        cur = node.value
        while isinstance(cur, ast.Attribute):
            seen.add(id(cur))
            cur = cur.value
        prefix = aliases[chain[0]]
        for attr in chain[1:]:
            full = f"{prefix}.{attr}"
            if is_private(attr) and full not in DOCUMENTED_UNDERSCORE:
                if full in known:
                    problem = _private_module_problem(mod, full)
                    if problem:
                        out.append(_report(mod, node.lineno, _one_line(node), problem))
                else:
                    out.append(_report(mod, node.lineno, _one_line(node), f"private name {attr} of module {prefix}"))
                break
            if full not in known:
                break  # past the modules: an attribute of an object, not of a module
            prefix = full
    return out


def core_to_stream_violations(mod: Module, known=KNOWN) -> list[str]:
    """Rule (b) for one module of patchcloud.core."""
    return [
        _report(mod, e.line, e.text, "patchcloud.core imports patchcloud.stream")
        for e in edges(mod, known)
        if under(e.target, "patchcloud.stream") or under(e.source, "patchcloud.stream")
    ]


def lower_to_upper_violations(mod: Module, known=KNOWN) -> list[str]:
    """Rule (c) for one module of patchcloud.stream.io or .engine."""
    out = []
    for e in edges(mod, known):
        hit = next((u for u in UPPER if under(e.target, u)), None)
        if hit:
            out.append(_report(mod, e.line, e.text, f"{mod.name} imports {hit}"))
        elif e.target == "patchcloud.stream":
            # a name of the stream package itself: its __init__ re-exports the jobs and views
            out.append(_report(mod, e.line, e.text, f"{mod.name} imports the patchcloud.stream package (it re-exports jobs/views)"))
    return out


def skip_violations(mod: Module) -> list[str]:
    """Rule (e) for one module."""
    return [
        _report(mod, i, line.strip(), "doctest: +SKIP")
        for i, line in enumerate(mod.source.splitlines(), 1)
        if SKIP_RE.search(line)
    ]


def literal(package: str, name: str):
    """The literal value a package's ``__init__.py`` assigns to ``name``, read without importing it."""
    tree = ast.parse((PACKAGES[package] / "__init__.py").read_text(encoding="utf-8"))
    for node in tree.body:
        targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
        if any(isinstance(t, ast.Name) and t.id == name for t in targets):
            return ast.literal_eval(node.value)
    raise AssertionError(f"{package}'s __init__.py has no literal {name}")


def core_all() -> frozenset[str]:
    """``patchcloud.core.__all__``, read from core/__init__.py without importing it."""
    return frozenset(literal("patchcloud.core", "__all__"))


def top_violations(mod: Module, exported: dict[str, frozenset[str]], known=KNOWN) -> list[str]:
    """Rule (g) for the top package: ``exported`` maps each package it may import from to that package's ``__all__``."""
    out = []
    for e in edges(mod, known):
        if not under(e.source, "patchcloud") and not under(e.target, "patchcloud"):
            continue
        if e.source not in exported or e.name is None:
            out.append(_report(mod, e.line, e.text, "the top package imports from patchcloud.core and patchcloud.stream only"))
        elif e.name not in exported[e.source]:
            out.append(_report(mod, e.line, e.text, f"{e.name} is not in {e.source}.__all__"))
    for node in ast.walk(mod.tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            out.append(_report(mod, node.lineno, f"{type(node).__name__} {node.name}", "the top package re-exports, it defines nothing"))
    return out


def core_interface_violations(mod: Module, exported: frozenset[str], known=KNOWN) -> list[str]:
    """Rule (f) for one module of patchcloud.stream."""
    out = []
    for e in edges(mod, known):
        if not (under(e.source, "patchcloud.core") or under(e.target, "patchcloud.core")):
            continue
        if e.name is None:
            out.append(_report(mod, e.line, e.text, "use `from patchcloud.core import ...`"))
        elif e.source != "patchcloud.core":
            out.append(_report(mod, e.line, e.text, f"imports from {e.source}, not from patchcloud.core"))
        elif e.name != "*" and e.name not in exported:
            out.append(_report(mod, e.line, e.text, f"{e.name} is not in patchcloud.core.__all__"))
    return out


def _fail(rule: str, found: list[str], what: str = "import(s)") -> None:
    found = list(dict.fromkeys(found))  # one line per statement and reason (a statement may import several names)
    if found:
        pytest.fail(f"{rule}: {len(found)} offending {what}\n" + "\n".join(found), pytrace=False)


def _in(prefix: str) -> list[Module]:
    return [m for m in MODULES if under(m.name, prefix)]


# -- the rules on the real tree ------------------------------------------------------------------------------------


def test_tree_is_found():
    names = {m.name for m in MODULES}
    assert {"patchcloud", "patchcloud.core", "patchcloud.core.normals", "patchcloud.core._kernels", "patchcloud.stream"} <= names
    assert "patchcloud.stream.patchcloud" not in names  # stream/patchcloud/ is the top package, not a part of the stream
    assert any(m.name.startswith("patchcloud.stream.") for m in MODULES)


def test_no_cross_module_private_import():
    _fail("(a) private names and private modules used across modules", [v for m in MODULES for v in private_violations(m)])


def test_core_never_imports_stream():
    _fail("(b) patchcloud.core imports patchcloud.stream", [v for m in _in("patchcloud.core") for v in core_to_stream_violations(m)])


def test_stream_io_and_engine_do_not_import_jobs_views_cli():
    found = [v for p in LOWER for m in _in(p) for v in lower_to_upper_violations(m)]
    _fail("(c) stream.io / stream.engine import stream.jobs / .views / .cli", found)


def test_stream_top_is_small():
    top = sorted(p.name for p in PACKAGES["patchcloud.stream"].glob("*.py") if p.name != "__init__.py")
    assert len(top) <= MAX_STREAM_TOP, f"(d) stream/ has {len(top)} modules at its top (at most {MAX_STREAM_TOP}): {top}"


def test_no_skipped_doctests():
    _fail("(e) doctest: +SKIP", [v for m in MODULES for v in skip_violations(m)], "line(s)")


def test_stream_uses_only_the_core_interface():
    exported = core_all()
    found = [v for m in _in("patchcloud.stream") for v in core_interface_violations(m, exported)]
    _fail("(f) patchcloud.stream imports from patchcloud.core other than names of patchcloud.core.__all__", found)


def test_the_top_package_only_re_exports():
    (top,) = [m for m in MODULES if m.name == "patchcloud"]
    exported = {p: frozenset(literal(p, "__all__")) for p in ("patchcloud.core", "patchcloud.stream")}
    _fail("(g) the top package patchcloud", top_violations(top, exported))
    sources = literal("patchcloud", "_SOURCES")
    assert set(sources) == set(exported), sources
    wrong = [f"{n} (from {p})" for p, names in sources.items() for n in names if n not in exported[p]]
    assert not wrong, f"(g) re-exported names missing from their package's __all__: {wrong}"
    public = set(literal("patchcloud", "__all__")) - {"__version__"}
    assert public == {n for names in sources.values() for n in names}, "(g) the top package's __all__ and its sources differ"


def test_checker_top_package():
    exported = {"patchcloud.core": frozenset({"estimate_normals", "lazy_exports"}), "patchcloud.stream": frozenset({"normals"})}
    top = lambda src: top_violations(snippet("patchcloud", src, is_package=True), exported, SNIPPET_KNOWN)  # noqa: E731
    assert top("from patchcloud.core import lazy_exports\nfrom importlib.metadata import version\n") == []
    (v,) = top("from patchcloud.core.normals import estimate_normals\n")
    assert "imports from patchcloud.core and patchcloud.stream only" in v
    (v,) = top("from patchcloud.stream import Store\n")
    assert "Store is not in patchcloud.stream.__all__" in v
    (v,) = top("def estimate_normals(points):\n    return points\n")
    assert "FunctionDef estimate_normals" in v and "defines nothing" in v


def test_core_all_names_exist():
    import patchcloud.core

    missing = [n for n in patchcloud.core.__all__ if not hasattr(patchcloud.core, n)]
    assert not missing, f"patchcloud.core.__all__ names missing from the package: {missing}"
    assert len(set(patchcloud.core.__all__)) == len(patchcloud.core.__all__), "duplicates in patchcloud.core.__all__"


# -- the checker on snippets with known answers --------------------------------------------------------------------

SNIPPET_KNOWN = frozenset(
    {
        "patchcloud.core", "patchcloud.core._kernels", "patchcloud.core.normals", "patchcloud.core.octree",
        "patchcloud.core.moments", "patchcloud.core.sub", "patchcloud.core.sub._inner",
        "patchcloud.stream", "patchcloud.stream.io", "patchcloud.stream.io.las", "patchcloud.stream.io.store",
        "patchcloud.stream.engine", "patchcloud.stream.engine.runner",
        "patchcloud.stream.jobs", "patchcloud.stream.jobs.normals", "patchcloud.stream.views", "patchcloud.stream.cli",
    }
)


def snippet(name: str, source: str, is_package: bool = False) -> Module:
    return Module(name, f"<{name}>", is_package, source)


def private(name: str, source: str, is_package: bool = False) -> list[str]:
    return private_violations(snippet(name, source, is_package), SNIPPET_KNOWN)


def test_checker_private_modules_serve_their_siblings_only():
    assert private("patchcloud.core.octree", "from . import _kernels\n_kernels.take_rows(a, b)\n") == []
    assert private("patchcloud.core.octree", "from ._kernels import cell_moments\n") == []
    assert private("patchcloud.core.octree", "import patchcloud.core._kernels as k\nk.bounds(a)\n") == []
    assert private("patchcloud.core", "from . import _kernels\n", is_package=True) == []  # __init__ is its package
    assert private("patchcloud.core.octree", "from __future__ import annotations\nfrom .x import __version__\n") == []
    (v,) = private("patchcloud.stream.jobs.x", "from patchcloud.core import _kernels\n")
    assert v.startswith("<patchcloud.stream.jobs.x>:1: from patchcloud.core import _kernels")
    assert "private module patchcloud.core._kernels" in v
    assert len(private("patchcloud.stream.jobs.x", "from patchcloud.core._kernels import cell_moments\n")) == 1
    assert len(private("patchcloud.stream.jobs.x", "import patchcloud.core._kernels\n")) == 1
    assert len(private("patchcloud.stream.jobs.x", "def f():\n    from ...core import _kernels\n")) == 1
    # a sub-package is another package: core's private modules do not serve it
    assert len(private("patchcloud.core.sub.y", "from .. import _kernels\n")) == 1
    assert private("patchcloud.core.sub.y", "from . import _inner\n") == []
    assert len(private("patchcloud.core.octree", "from .sub import _inner\n")) == 1


def test_checker_private_names():
    multi = "from .normals import (\n    a,\n    _b,\n)\n"
    (v,) = private("patchcloud.core.patchmodel", multi)
    assert v.startswith("<patchcloud.core.patchmodel>:3: from .normals import a, _b")
    assert "private name _b of patchcloud.core.normals" in v
    (v,) = private("patchcloud.core._radius_kernels", "from ._kernels import _eigh3\n")
    assert "private name _eigh3 of patchcloud.core._kernels" in v
    assert len(private("patchcloud.stream.jobs.x", "from patchcloud.core.octree import _Level as L\n")) == 1
    assert len(private("patchcloud.core.octree", "from numpy.linalg import _umath_linalg\n")) == 1


def test_checker_private_attributes_of_modules():
    src = "from . import _kernels\nfrom . import moments as mo\n\ndef f(x):\n    _kernels.bounds(x)\n    return _kernels._eigh3(x), mo._INDEX\n"
    found = private("patchcloud.core.blend", src)
    assert len(found) == 2, found
    assert found[0].startswith("<patchcloud.core.blend>:6: _kernels._eigh3") and "private name _eigh3" in found[0]
    assert "private name _INDEX of module patchcloud.core.moments" in found[1]
    src = "import patchcloud.core\npatchcloud.core.octree._occupied(k, 3)\npatchcloud.core.normals.estimate_normals\n"
    (v,) = private("patchcloud.stream.jobs.x", src)
    assert "private name _occupied of module patchcloud.core.octree" in v
    src = "import patchcloud.core\npatchcloud.core._kernels.bounds(x)\n"
    (v,) = private("patchcloud.stream.jobs.x", src)
    assert "private module patchcloud.core._kernels" in v
    # attributes of objects, and private names of the module itself, are not the rule's business
    assert private("patchcloud.core.octree", "from .octree import Octree\nOctree.edge._x\nself._x\n_own()\n") == []
    # the standard library's documented os._exit is public; its other underscored names are not
    assert private("patchcloud.stream.engine.x", "import os\nos._exit(0)\n") == []
    (v,) = private("patchcloud.stream.engine.x", "import os\nimport sys\nos._exit(0)\nsys._getframe()\n")
    assert "private name _getframe of module sys" in v


def test_checker_core_never_imports_stream():
    def check(src):
        return core_to_stream_violations(snippet("patchcloud.core.x", src), SNIPPET_KNOWN)

    assert len(check("from patchcloud.stream.io import store\n")) == 1
    assert len(check("import patchcloud.stream\n")) == 1
    assert len(check("def f():\n    from ..stream import io\n")) == 1
    assert len(check("import importlib\nimportlib.import_module('patchcloud.stream.io.las')\n")) == 1
    assert check("from .octree import Octree\nimport numpy as np\n") == []


def test_checker_io_and_engine_stay_below_jobs():
    def check(name, src):
        return lower_to_upper_violations(snippet(name, src), SNIPPET_KNOWN)

    assert len(check("patchcloud.stream.io.las", "from patchcloud.stream.jobs import normals\n")) == 1
    assert len(check("patchcloud.stream.io.las", "from ..jobs.normals import open_job\n")) == 1
    assert len(check("patchcloud.stream.engine.runner", "if TYPE_CHECKING:\n    from ..views.report import X\n")) == 1
    assert len(check("patchcloud.stream.engine.runner", "from patchcloud.stream import cli\n")) == 1
    assert len(check("patchcloud.stream.engine.runner", "from patchcloud.stream import Store\n")) == 1
    assert check("patchcloud.stream.engine.runner", "from patchcloud.stream.io.store import Store\nfrom ..io import las\n") == []


def test_checker_skip():
    (v,) = skip_violations(snippet("patchcloud.core.x", '"""\n>>> f()  # doctest: +ELLIPSIS, +SKIP\n"""\n'))
    assert v.startswith("<patchcloud.core.x>:2:")
    assert skip_violations(snippet("patchcloud.core.x", '""">>> f()  # doctest: +ELLIPSIS\n"""\n')) == []


def test_checker_core_interface():
    exported = frozenset({"estimate_normals", "sort_points"})

    def check(src):
        return core_interface_violations(snippet("patchcloud.stream.jobs.x", src), exported, SNIPPET_KNOWN)

    assert check("from patchcloud.core import estimate_normals, sort_points\nimport numpy as np\n") == []
    assert len(check("from patchcloud.core.octree import sort_points\n")) == 1
    assert len(check("from patchcloud.core import _kernels\n")) == 1
    assert len(check("from patchcloud.core import (\n    sort_points,\n    max_level_for,\n)\n")) == 1
    assert len(check("import patchcloud.core.octree\n")) == 1
    assert len(check("from ...core import octree\n")) == 1
    assert len(check("from patchcloud.core.errors import PatchcloudIOError\n")) == 1
