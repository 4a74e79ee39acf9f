"""A text progress bar on standard error (redrawn in place on a terminal, one line per step otherwise)."""

from __future__ import annotations

import sys
import time

__all__ = ["Progress"]


class Progress:
    """Progress of one step of ``total`` units.

    >>> p = Progress("fit", 10, quiet=True)
    >>> p.update(10)
    >>> p.done
    10
    """

    def __init__(self, label: str, total: int, quiet: bool = False, unit: str = "") -> None:
        self.label, self.total, self.unit = label, max(int(total), 0), unit
        self.done = 0
        self.quiet = quiet
        self.tty = sys.stderr.isatty()
        self.t0 = time.perf_counter()
        self._last = 0.0
        self.elapsed = 0.0

    def update(self, n: int = 1) -> None:
        self.done += n
        now = time.perf_counter()
        if self.quiet or not self.tty or now - self._last < 0.2:
            return
        self._last = now
        self._draw(now)

    def _draw(self, now: float, end: str = "") -> None:
        frac = self.done / self.total if self.total else 1.0
        width = 30
        bar = "#" * int(frac * width)
        sys.stderr.write(f"\r{self.label:<18} [{bar:<{width}}] {frac:6.1%}  {self.done:,}/{self.total:,}{self.unit}  {now - self.t0:6.1f} s{end}")
        sys.stderr.flush()

    def close(self) -> float:
        now = time.perf_counter()
        self.elapsed = now - self.t0
        if not self.quiet:
            if self.tty:
                self._draw(now, end="\n")
            else:
                sys.stderr.write(f"{self.label:<18} {self.done:,}/{self.total:,}{self.unit} in {self.elapsed:.1f} s\n")
        return self.elapsed
