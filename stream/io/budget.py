"""The memory budget (``--max-memory``): what a size read from a file, or asked for by a parameter, may make a process allocate.

Every size a file states (a ``.pcz``'s arrays, tiles and cells, a residual
block's point count, ...) and every allocation a parameter drives (a
picture's pixels, an in-memory run's points, a batch of sampled points) is
checked against this budget *before* anything is allocated, so that a small
crafted file or one absurd parameter ends in one error line instead of
driving the machine out of memory.

The budget is a number of bytes per process.  Default: half the memory
of the machine (of its cgroup, when that is lower), the share a run leaves
to the rest of the machine.  ``patchcloud ... --max-memory 4GiB`` or the
environment variable ``PATCHCLOUD_MAX_MEMORY`` (read by every process of a
run, dask workers included) sets it; :func:`set_max_memory` from Python.
"""

from __future__ import annotations

import functools
import math
import os
import re

from patchcloud.core import PatchcloudMemoryError, PatchcloudValueError

__all__ = ["ENV", "DEFAULT_SHARE", "parse_size", "format_size", "machine_memory", "max_memory", "set_max_memory", "check_memory"]

#: The environment variable holding the budget (bytes, or a size such as ``4GiB``).
ENV = "PATCHCLOUD_MAX_MEMORY"
#: The default budget, as a share of the machine's memory.
DEFAULT_SHARE = 0.5
#: Smallest budget accepted: less cannot run anything (the interpreter and its libraries take about as much).
MIN_BUDGET = 64 << 20

_UNITS = {"": 1, "b": 1, "k": 10**3, "kb": 10**3, "m": 10**6, "mb": 10**6, "g": 10**9, "gb": 10**9, "t": 10**12, "tb": 10**12,
          "kib": 1 << 10, "mib": 1 << 20, "gib": 1 << 30, "tib": 1 << 40}


def parse_size(text) -> int:
    """Bytes of a size given as a number of bytes or with a unit (kB, MB, GB, TB: powers of 1000; KiB, MiB, GiB, TiB: of 1024).

    >>> parse_size("4GiB"), parse_size("1.5 GB"), parse_size(2048), parse_size("512M")
    (4294967296, 1500000000, 2048, 512000000)
    """
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        value, unit = float(text), ""
    else:
        m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][0-9]+)?)\s*([A-Za-z]*)\s*", str(text))
        if m is None or m.group(2).lower() not in _UNITS:
            raise PatchcloudValueError(f"a size must be bytes, or a number with a unit such as 4GiB, 8GB or 512MiB (units: {', '.join(sorted(u for u in _UNITS if u))}); "
                                       f"got {text!r}")
        value, unit = float(m.group(1)), m.group(2).lower()
    nbytes = value * _UNITS[unit]
    if not math.isfinite(nbytes) or nbytes >= 2.0**63:  # (1e400, 1e300TB: no memory is that large)
        raise PatchcloudValueError(f"a size must be below 8 EiB (2**63 bytes); got {text!r}")
    return int(nbytes)


def _budget(size) -> int:
    """Bytes of a budget given as for :func:`parse_size`, at least :data:`MIN_BUDGET`."""
    nbytes = parse_size(size)
    if nbytes < MIN_BUDGET:
        raise PatchcloudValueError(f"max memory must be at least {format_size(MIN_BUDGET)}; got {size!r}")
    return nbytes


def format_size(nbytes: int) -> str:
    """A size for people: ``"1.5 GiB"``, ``"64 MiB"``, ``"12 KiB"``, ``"80 B"``.

    >>> format_size(3 << 29), format_size(64 << 20), format_size(80)
    ('1.5 GiB', '64 MiB', '80 B')
    """
    for unit, shift in (("TiB", 40), ("GiB", 30), ("MiB", 20), ("KiB", 10)):
        if nbytes >= 1 << shift:
            return f"{nbytes / (1 << shift):.3g} {unit}"
    return f"{int(nbytes)} B"


@functools.lru_cache(maxsize=1)
def machine_memory() -> int:
    """Bytes of memory this process's machine has: physical memory, or its cgroup's limit when lower (read once a
    process: every check of the budget asks)."""
    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    for path in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            with open(path) as f:
                limit = f.read().strip()
        except OSError:
            continue
        if limit.isdigit():
            total = min(total, int(limit))
    return int(total)


def max_memory() -> int:
    """The budget in bytes: ``PATCHCLOUD_MAX_MEMORY`` if set, else :data:`DEFAULT_SHARE` of :func:`machine_memory`."""
    value = os.environ.get(ENV)
    if value:
        return _budget(value)
    return int(DEFAULT_SHARE * machine_memory())


def set_max_memory(size) -> int:
    """Set the budget of this process and of the processes it starts afterwards (dask workers); returns it in bytes.

    ``size``: bytes, or a string such as ``"4GiB"`` (:func:`parse_size`); None restores the default.
    """
    if size is None:
        os.environ.pop(ENV, None)
        return max_memory()
    nbytes = _budget(size)
    os.environ[ENV] = str(nbytes)
    return nbytes


def check_memory(nbytes: int, what: str, hint: str = "") -> None:
    """Refuse to allocate ``nbytes`` for ``what`` (a phrase naming the file and the thing) beyond the budget.

    ``hint``: what else the user can do, said after how to raise the budget.

    Raises
    ------
    PatchcloudMemoryError
        ``WHAT would need SIZE, more than the memory budget of SIZE (--max-memory ...)``.

    Examples
    --------
    >>> check_memory(1000, "a test")
    >>> check_memory(1 << 62, "f.pcz: tile 0_0_0's cells")   # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    patchcloud.core.errors.PatchcloudMemoryError: f.pcz: tile 0_0_0's cells would need 4.19e+06 TiB, more than the memory budget ...
    """
    budget = max_memory()
    if nbytes > budget:
        raise PatchcloudMemoryError(f"{what} would need {format_size(nbytes)}, more than the memory budget of {format_size(budget)} "
                                    f"(--max-memory or {ENV} sets it{'; ' + hint if hint else ''})")
