"""pyproj's answers about files' CRSs kept on disk: a run on a file whose CRS was seen before imports no pyproj.

Every job reads its inputs' CRSs: laspy parses a file's CRS records with
pyproj into the WKT that :class:`~patchcloud.stream.io.las.LasSource` keeps
(:func:`header_crs`), and :func:`~patchcloud.stream.io.crs.units_of` asks
pyproj for that CRS's units, name and EPSG code
(:func:`~patchcloud.stream.io.crs.crs_description`).  pyproj's import and
these answers take 0.1-0.25 s of every run on the 2-core machine (the EPSG
search alone 0.15 s for a WKT without an authority, as Autzen's), a sixth
of a small file's whole run, and users run the same CRS again and again: a
catalog's tiles, a script over a directory of them.

So each answer is kept in one small JSON file under
``$XDG_CACHE_HOME/patchcloud/crs`` (default ``~/.cache/patchcloud/crs``),
named by a hash of the question (the file's CRS records, or a WKT) and of
what answers it: the laspy version and the pyproj installation (the place,
size and time of its ``__init__.py``, which a new pyproj or its PROJ
database changes, and ``PROJ_DATA``/``PROJ_LIB``).  A cached answer is the
answer pyproj gave: the same WKT, the same units, names and codes.  A file
is written under a temporary name and then renamed; one that cannot be read
or written is passed over (the answer is computed as without a cache).
``PATCHCLOUD_CRS_CACHE`` names another directory, or ``0`` for none.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import tempfile
from collections.abc import Callable

from .geotiff_crs import GEO_ASCII_PARAMS, GEO_DOUBLE_PARAMS, GEO_KEY_DIRECTORY, geo_keys, geotiff_crs

__all__ = ["remembered", "header_crs", "cache_dir", "CACHE_VERSION", "PROJECTION"]

#: Changed when what is kept, or how it is keyed, changes: older files are then not read.
CACHE_VERSION = 2  # 2: GeoTIFF keys read as libgeotiff reads them (geotiff_crs), not by laspy
#: The user id of a LAS file's CRS records (laspy parses every record of it).
PROJECTION = "LASF_Projection"
#: The record id of the OGC CRS WKT (GeoTIFF's: :mod:`.geotiff_crs`).
WKT_RECORD = 2112


def cache_dir() -> str | None:
    """Where the answers are kept (``PATCHCLOUD_CRS_CACHE``, else ``$XDG_CACHE_HOME/patchcloud/crs``); None: nowhere."""
    chosen = os.environ.get("PATCHCLOUD_CRS_CACHE")
    if chosen is not None:
        return None if chosen.strip() in ("", "0") else chosen
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "patchcloud", "crs")


def _answerer() -> bytes:
    """What answers the questions: the laspy version and pyproj's installation (found without importing it)."""
    import laspy

    parts = [f"v{CACHE_VERSION}", f"laspy {laspy.__version__}"]
    spec = importlib.util.find_spec("pyproj")
    origin = None if spec is None else spec.origin
    try:
        st = os.stat(origin) if origin else None
    except OSError:
        st = None
    parts.append("no pyproj" if st is None else f"pyproj {origin} {st.st_size} {st.st_mtime_ns}")
    parts += [f"{name}={os.environ.get(name, '')}" for name in ("PROJ_DATA", "PROJ_LIB")]
    return "\n".join(parts).encode()


def remembered(kind: str, question: bytes, answer: Callable[[], dict]) -> dict:
    """``answer()`` (a JSON-able dict), kept on disk for the next call with the same ``kind`` and ``question``.

    An exception ``answer()`` raises goes to the caller, and nothing is kept.

    >>> import os, tempfile
    >>> os.environ["PATCHCLOUD_CRS_CACHE"] = tempfile.mkdtemp()
    >>> calls = []
    >>> [remembered("demo", b"q", lambda: calls.append(1) or {"a": 1}) for _ in range(2)], len(calls)
    ([{'a': 1}, {'a': 1}], 1)
    >>> del os.environ["PATCHCLOUD_CRS_CACHE"]
    """
    where = cache_dir()
    if where is None:
        return answer()
    key = hashlib.sha256(b"\0".join([kind.encode(), _answerer(), question])).hexdigest()
    path = os.path.join(where, key[:2], key + ".json")
    try:
        with open(path, encoding="utf-8") as f:
            kept = json.load(f)
        if isinstance(kept, dict) and kept.get("kind") == kind and isinstance(kept.get("answer"), dict):
            return kept["answer"]
    except (OSError, ValueError):
        pass
    value = answer()
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=os.path.dirname(path), prefix=".", suffix=".tmp")
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                json.dump({"kind": kind, "answer": value}, f)
            os.replace(tmp, path)
        except BaseException:
            os.unlink(tmp)
            raise
    except OSError:  # a read-only or full cache: the answer stands, unkept
        pass
    return value


def header_crs(header) -> tuple[str | None, str | None]:
    """A LAS header's CRS as PDAL reads it: ``(WKT, None)``, ``(None, None)`` without one, or ``(None, why)``
    where its CRS records cannot be read (the error, as its type and message).

    GeoTIFF keys are read by :func:`~.geotiff_crs.geotiff_crs` (user-defined
    projections, geocentric CRSs and unit keys, which laspy's ``parse_crs``
    does not read), unless the global encoding's WKT bit says the WKT record
    holds the CRS (LAS 1.4); the WKT record is read by laspy, where there are
    no GeoTIFF keys or they define no CRS.  The question is the WKT bit and
    the header's ``LASF_Projection`` records, in order.

    >>> import laspy
    >>> header_crs(laspy.LasHeader(point_format=6, version="1.4"))
    (None, None)
    """
    records = [r for r in list(header.vlrs) + list(header.evlrs or []) if r.user_id == PROJECTION]
    if not records:
        return None, None
    data = [(r.record_id, bytes(r.record_data_bytes() if hasattr(r, "record_data_bytes") else r.record_data)) for r in records]
    wkt_first = bool(getattr(header.global_encoding, "wkt", False))
    question = b"%d;" % wkt_first + b"".join(b"%d:%d:" % (rid, len(d)) + d for rid, d in data)

    def parse() -> dict:
        crs = None
        by_id = {rid: d for rid, d in reversed(data)}  # the first record of each id
        has_wkt = any(rid == WKT_RECORD for rid, _ in data)
        if GEO_KEY_DIRECTORY in by_id and not (has_wkt and wkt_first):  # GeoTIFF keys, as libgeotiff (PDAL) reads them
            crs = geotiff_crs(geo_keys(by_id[GEO_KEY_DIRECTORY], by_id.get(GEO_DOUBLE_PARAMS), by_id.get(GEO_ASCII_PARAMS)))
        if crs is None and has_wkt:  # the WKT (the global encoding's WKT bit set, or no GeoTIFF keys): laspy reads it first
            crs = header.parse_crs()
        return {"wkt": None if crs is None else crs.to_wkt()}

    try:
        return remembered("header", question, parse).get("wkt"), None
    except Exception as exc:  # an unparsable CRS record (not kept: asked again next time): not fatal, but said wherever
        return None, f"{type(exc).__name__}: {str(exc)[:160]}"  # the CRS is (info, units, catalogs)
