"""Which points of a LAS/LAZ file take part in a job: a class filter, and noise and withheld points left out.

PDAL users restrict a filter to some classes (``where: Classification ==
2``) and expect noise to stay out of every neighbourhood.  A
:class:`Selection` says which points a job computes on and uses as
neighbours; the others are written unchanged with the output
dimensions' documented empty value (``NormalMethod`` 0, a zero normal,
``DoN`` 0, ``ClusterID`` 0, ...).

- ``classes``: only points of these ASPRS classification codes (0 to
  255; point formats 0 to 5 hold 0 to 31).  Default: every class.
- Noise, ASPRS classes 7 (low noise) and 18 (high noise), and points with
  the *withheld* flag (which the LAS specification says to treat as
  deleted) are left out unless ``keep_noise``; a noise class listed in
  ``classes`` is asked for, and kept.

Each point left out is counted under one reason, the first that applies:
``classes`` (not of a class asked for), ``noise`` (class 7 or 18), then
``withheld``.

>>> s = Selection(classes=check_classes("6,2"))
>>> s.classes, s.describe()
((2, 6), 'classes 2, 6; noise (classes 7, 18) and withheld points left out')
>>> Selection(keep_noise=True).everything
True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from patchcloud.core import PatchcloudValueError

__all__ = ["Selection", "NOISE_CLASSES", "MAX_CLASS", "REASONS", "check_classes", "classification_and_withheld"]

#: ASPRS classes of noise: 7 low point (noise), 18 high noise (LAS 1.4).
NOISE_CLASSES = (7, 18)
#: The largest classification code (point formats 6 to 10; formats 0 to 5 hold 0 to 31).
MAX_CLASS = 255
#: Why a point is left out, in the order a point is counted under the first that applies.
REASONS = ("classes", "noise", "withheld")

_VALID = f"valid: classification codes 0 to {MAX_CLASS}, separated by commas, e.g. 2,6 (2 ground, 6 building)"


def check_classes(value) -> tuple[int, ...] | None:
    """``value`` (None, "2,6", or integers) as a sorted tuple of distinct class codes; a PatchcloudValueError otherwise.

    >>> check_classes("2, 6,2"), check_classes([6, 2]), check_classes(None)
    ((2, 6), (2, 6), None)
    >>> check_classes("abc")
    Traceback (most recent call last):
    ...
    patchcloud.core.errors.PatchcloudValueError: classes 'abc': 'abc' is not a class; valid: classification codes 0 to 255, separated by commas, e.g. 2,6 (2 ground, 6 building)
    >>> check_classes("300")
    Traceback (most recent call last):
    ...
    patchcloud.core.errors.PatchcloudValueError: classes '300': 300 is not a class; valid: classification codes 0 to 255, separated by commas, e.g. 2,6 (2 ground, 6 building)
    """
    if value is None:
        return None
    shown = value if isinstance(value, str) else ",".join(str(v) for v in value) if isinstance(value, (list, tuple)) else value
    if isinstance(value, str):
        items = [v.strip() for v in value.split(",")]
    elif isinstance(value, (list, tuple, np.ndarray)):
        items = list(value)
    else:
        raise PatchcloudValueError(f"classes {value!r}: give class codes as '2,6' or a list of integers; {_VALID}")
    if not items or items == [""]:
        raise PatchcloudValueError(f"classes {shown!r}: no class given; {_VALID}")
    codes = []
    for v in items:
        if isinstance(v, str):
            ok = v.isdigit()
            code = int(v) if ok else None
        else:
            ok = isinstance(v, (int, np.integer)) and not isinstance(v, bool)
            code = int(v) if ok else None
        if not ok or not 0 <= code <= MAX_CLASS:
            raise PatchcloudValueError(f"classes {shown!r}: {v!r} is not a class; {_VALID}" if not ok
                                       else f"classes {shown!r}: {code} is not a class; {_VALID}")
        codes.append(code)
    return tuple(sorted(set(codes)))


def classification_and_withheld(records: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each record's classification code (uint8) and withheld flag (bool), from laspy's raw structured array.

    Point formats 0 to 5 hold the class in bits 0-4 of ``raw_classification``
    and the withheld flag in its bit 7; formats 6 to 10 the class in
    ``classification`` and the flag in bit 2 of ``classification_flags``.
    """
    names = records.dtype.names or ()
    if "raw_classification" in names:
        raw = np.asarray(records["raw_classification"], dtype=np.uint8)
        return raw & np.uint8(31), (raw & np.uint8(0x80)) != 0
    if "classification" in names and "classification_flags" in names:
        return np.asarray(records["classification"], dtype=np.uint8), (np.asarray(records["classification_flags"]) & 4) != 0
    raise PatchcloudValueError(f"records without a classification (fields {', '.join(names)})")


@dataclass(frozen=True)
class Selection:
    """Which points take part in a job (see the module's docstring).

    Parameters
    ----------
    classes : tuple of int, optional
        Only points of these classes; None: every class.
    keep_noise : bool
        Keep noise (classes 7 and 18) and withheld points; by default they
        are left out.
    """

    classes: tuple[int, ...] | None = None
    keep_noise: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "classes", check_classes(self.classes))
        if self.keep_noise not in (True, False):
            raise PatchcloudValueError(f"keep_noise must be True or False, got {self.keep_noise!r}")
        object.__setattr__(self, "keep_noise", bool(self.keep_noise))

    @property
    def everything(self) -> bool:
        """Whether every point takes part (no class filter, noise and withheld points kept)."""
        return self.classes is None and self.keep_noise

    def to_json(self) -> dict:
        """What a store records of the selection its tiles were made with.

        >>> Selection(classes=(2,)).to_json()
        {'classes': [2], 'keep_noise': False}
        """
        return {"classes": None if self.classes is None else list(self.classes), "keep_noise": self.keep_noise}

    @classmethod
    def from_json(cls, d: dict | None) -> "Selection":
        """The selection a store records; a store that records none holds every point."""
        if d is None:
            return cls(keep_noise=True)
        return cls(classes=None if d.get("classes") is None else tuple(d["classes"]), keep_noise=bool(d.get("keep_noise")))

    def describe(self) -> str:
        """The selection in words, as summaries say it.

        >>> Selection().describe(), Selection(keep_noise=True).describe()
        ('every class; noise (classes 7, 18) and withheld points left out', 'every point')
        """
        if self.everything:
            return "every point"
        what = "every class" if self.classes is None else "classes " + ", ".join(str(c) for c in self.classes)
        noise = [c for c in NOISE_CLASSES if self.classes is None or c not in self.classes]
        if self.keep_noise:
            return what
        if not noise:
            return f"{what}; withheld points left out"
        return f"{what}; noise (classes {', '.join(str(c) for c in noise)}) and withheld points left out"

    def reasons(self, records: np.ndarray) -> np.ndarray:
        """(n,) uint8: 0 for each record that takes part, else 1 + its reason's position in :data:`REASONS`.

        >>> import laspy
        >>> las = laspy.create(point_format=6, file_version="1.4")
        >>> las.x = las.y = las.z = np.zeros(4)
        >>> las.classification = np.array([2, 6, 7, 2]); las.withheld = np.array([0, 0, 0, 1], bool)
        >>> Selection(classes=(2,)).reasons(las.points.array).tolist()
        [0, 1, 1, 3]
        """
        cls, withheld = classification_and_withheld(records)
        out = np.zeros(cls.shape[0], dtype=np.uint8)
        if not self.keep_noise:
            out[withheld] = 3
            noise = [c for c in NOISE_CLASSES if self.classes is None or c not in self.classes]
            out[np.isin(cls, noise)] = 2
        if self.classes is not None:
            out[~np.isin(cls, self.classes)] = 1
        return out

    def mask(self, records: np.ndarray) -> np.ndarray:
        """(n,) bool: the records that take part."""
        if self.everything:
            return np.ones(len(records), dtype=bool)
        return self.reasons(records) == 0
