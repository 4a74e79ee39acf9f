"""The floors of pyproject.toml's dependencies, each ``name>=X`` as ``name==X``: what ``.ci/min-versions`` installs.

Run as a script it prints one pin a line; ``tests/test_scaffold.py`` reads the same floors through :func:`floors`.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

#: A dependency with a floor: its name (extras included, e.g. ``laspy[lazrs]``) and its oldest version.
FLOOR = re.compile(r"([A-Za-z0-9_.\-]+(?:\[[^\]]+\])?)\s*>=\s*([0-9][0-9A-Za-z.]*)")


def floors(pyproject: Path = Path(__file__).resolve().parents[1] / "pyproject.toml") -> list[tuple[str, str]]:
    """(name with extras, oldest version) of every dependency; SystemExit naming one that has no floor."""
    with open(pyproject, "rb") as f:
        deps = tomllib.load(f)["project"]["dependencies"]
    out = []
    for dep in deps:
        m = FLOOR.fullmatch(dep.strip())
        if not m:
            raise SystemExit(f"{pyproject}: {dep!r} is not of the form name>=version: say in .ci/floors.py how to pin its floor")
        out.append((m.group(1), m.group(2)))
    return out


if __name__ == "__main__":
    for name, version in floors():
        print(f"{name}=={version}")
