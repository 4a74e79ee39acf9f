"""Self-contained HTML reports of a run: the summary table, rendered views and histograms, in one file.

A report is one HTML file that opens in a browser with no server and no
network: inline CSS, no script, every image embedded as a
``data:image/png;base64,...`` URI.  :func:`write_report` writes any such
page; :func:`report_normals`, :func:`report_don` and :func:`report_compress`
write the report of a ``normals``, ``don``/``segment`` or ``compress`` run
from its summary:

- normals: the summary; views of the output coloured by normal, curvature
  and patch; the histogram of the angle between the output normals and the
  reference normals the input carries (``TrueNormalX/Y/Z``, or
  ``NormalX/Y/Z``), or a note that it has none; the histogram of the
  curvature and the points per normal method;
- don / segment: the summary; views of the output coloured by DoN (and by
  segment); the histogram of the DoN magnitudes (the run's own 50 bins);
  for segment, the histogram of the segment sizes;
- compress: the summary; views of the input (elevation, classification);
  bits per point by part of the ``.pcz`` (patches, residual points, index);
  the error budget beside the mean error; the table of tiles (patches,
  points on patches, residual points and bytes).

Every statistic that reads a file reads it in chunks of fixed size into
fixed-size accumulators: memory does not grow with the file.

>>> from patchcloud.stream import normals, report_normals
>>> page = report_normals(normals(sample, tmp / "out.laz", quiet=True), tmp / "out.html")
>>> page.name, "data:image/png;base64," in page.read_text()   # one file, its images inline
('out.html', True)
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import io
import os
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING

import laspy
import numpy as np
from matplotlib.figure import Figure

from patchcloud.core import PatchcloudError, PatchcloudExistsError, PatchcloudIOError, PatchcloudValueError

from patchcloud.stream.engine.job import left_out_text, memory_scope, units_text
from patchcloud.stream.io.las import atomic_output, open_source, read_chunks, same_file
from patchcloud.stream.views.plots import CMAP, STYLE, new_figure, style_axes

if TYPE_CHECKING:  # pragma: no cover
    from patchcloud.stream.jobs.compress import CompressSummary
    from patchcloud.stream.jobs.normals import NormalsSummary
    from patchcloud.stream.jobs.don import DonSummary

__all__ = [
    "ReportFigure", "ReportTable", "Histogram", "NormalStatistics", "write_report", "check_report_path", "figure_png",
    "report_normals", "report_don", "report_compress", "report_compress_catalog", "normals_rows", "don_rows", "compress_rows", "units_rows",
    "normal_statistics", "don_histogram", "segment_sizes", "segment_size_histogram", "pcz_parts", "pcz_tiles",
    "histogram_figure", "render_html", "REFERENCE_DIMS",
]

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: Reference normals looked for in a ``normals`` input, in this order (the synthetic city writes TrueNormal*).
REFERENCE_DIMS = (("TrueNormalX", "TrueNormalY", "TrueNormalZ"), ("NormalX", "NormalY", "NormalZ"))
#: Largest surface variation l3 / (l1 + l2 + l3) (three equal eigenvalues).
CURVATURE_MAX = 1.0 / 3.0
#: Rows of the per-tile table of a compress report at most (the largest tiles by points).
MAX_TILE_ROWS = 200
#: Width (pixels) of the rendered views' pictures (title, axes and colour bar included).
VIEW_WIDTH = 1200


# --------------------------------------------------------------------------------------------------------------------
# The page
# --------------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ReportFigure:
    """One image of a report: PNG bytes and a caption (plain text)."""

    png: bytes
    caption: str
    section: str = "Figures"


@dataclass(frozen=True)
class ReportTable:
    """A table of a report: a caption, column headings and rows of plain text cells."""

    caption: str
    columns: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]


@dataclass(frozen=True)
class Histogram:
    """Counts in bins: ``counts[i]`` values fell in ``[edges[i], edges[i + 1])`` (the last bin closed)."""

    edges: np.ndarray
    counts: np.ndarray

    @property
    def total(self) -> int:
        return int(self.counts.sum())

    def quantile(self, q: float) -> float:
        """The ``q`` quantile, to one bin: the middle of the bin that holds it (NaN when empty)."""
        n = self.total
        if n == 0:
            return float("nan")
        k = int(np.searchsorted(np.cumsum(self.counts), q * n))
        k = min(k, self.counts.size - 1)
        return float((self.edges[k] + self.edges[k + 1]) / 2)


def figure_png(fig: Figure) -> bytes:
    """``fig`` as PNG bytes (the :data:`~patchcloud.stream.views.plots.STYLE` resolution).

    Examples
    --------
    >>> fig, (ax,) = new_figure(2, 2)
    >>> figure_png(fig)[:4] == b"\\x89PNG"
    True
    """
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=STYLE["dpi"])
    return buf.getvalue()


def check_report_path(path: str | os.PathLike, *, overwrite: bool = False, others: Sequence[str | os.PathLike] = (),
                      made: str | os.PathLike | None = None) -> Path:
    """``path`` as a Path after checking a report can be written there, before a job runs.

    Parameters
    ----------
    path : path
        Where the report goes.
    overwrite : bool
        Replace an existing file (as the job's ``--overwrite``).
    others : paths
        The job's input and output: the report must be neither.
    made : path, optional
        A directory the job makes (a catalog's ``--out-dir``): the report
        may go in it, if it can be made.

    Raises
    ------
    PatchcloudIOError
        A directory, an existing file without ``overwrite``, a missing or
        read-only directory, or the job's input or output.
    """
    p = Path(path)
    if p.is_dir():
        raise PatchcloudIOError(f"{p}: is a directory, not a report file")
    where = p.parent
    if made is not None and not where.exists() and where.resolve() == Path(made).resolve():
        where = where.parent  # the job makes it there: where it is made must exist and be writable
    if not where.exists():
        raise PatchcloudIOError(f"{p}: the directory {where} does not exist")
    if not os.access(where, os.W_OK):
        raise PatchcloudIOError(f"{p}: the directory {where} is not writable")
    for o in others:
        if same_file(o, p):
            raise PatchcloudIOError(f"{p}: the report would replace the job's file {o}")
    if p.exists() and not overwrite:
        raise PatchcloudExistsError(f"{p}: exists (use --overwrite to replace it)")
    return p


_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,Helvetica,Arial,sans-serif;margin:2em auto;max-width:1250px;
padding:0 1em;color:#222;background:#fff;line-height:1.4}
h1{font-size:1.5em;margin-bottom:.2em}h2{font-size:1.2em;margin-top:1.6em;border-bottom:1px solid #ccc;padding-bottom:.2em}
p.meta{color:#666;margin-top:0}
table{border-collapse:collapse;margin:.5em 0;font-size:.92em}
th,td{border:1px solid #ddd;padding:.25em .6em;text-align:left;vertical-align:top}
th{background:#f3f3f3}td.num{text-align:right;font-variant-numeric:tabular-nums}
table.summary th{width:14em}
figure{margin:1em 0;padding:0}figure img{max-width:100%;height:auto;border:1px solid #eee}
figcaption{color:#444;font-size:.92em;margin-top:.3em}
ul.notes li{margin:.2em 0}
"""


def _img(png: bytes) -> str:
    if not isinstance(png, (bytes, bytearray)) or not bytes(png[:8]) == PNG_SIGNATURE:
        raise PatchcloudValueError("a report figure must be PNG bytes")
    return "data:image/png;base64," + base64.b64encode(bytes(png)).decode("ascii")


def _is_number(text: str) -> bool:
    t = text.replace(",", "").replace("%", "").replace(" ", "")
    try:
        float(t)
    except ValueError:
        return False
    return True


def render_html(
    *, title: str, summary_rows: Sequence[tuple[str, str]], figures: Sequence[ReportFigure | tuple[bytes | Figure, str]] = (),
    notes: Sequence[str] = (), tables: Sequence[ReportTable] = (),
) -> str:
    """The report page as a string (see :func:`write_report`)."""
    e = html.escape
    from patchcloud.core import __version__

    made_by = f"patchcloud {__version__}"
    when = _dt.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z").strip()
    out = [
        "<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">', f"<title>{e(title)}</title>",
        f"<style>{_CSS}</style>", "</head>", "<body>", f"<h1>{e(title)}</h1>", f'<p class="meta">{e(made_by)}, {e(when)}</p>',
        "<h2>Summary</h2>", '<table class="summary">',
    ]
    for key, value in summary_rows:
        out.append(f"<tr><th>{e(str(key))}</th><td>{e(str(value))}</td></tr>")
    out.append("</table>")
    if notes:
        out.append('<ul class="notes">' + "".join(f"<li>{e(str(n))}</li>" for n in notes) + "</ul>")
    section = None
    for f in figures:
        if not isinstance(f, ReportFigure):
            img, caption = f
            f = ReportFigure(figure_png(img) if isinstance(img, Figure) else img, caption)
        if f.section != section:
            section = f.section
            out.append(f"<h2>{e(section)}</h2>")
        out.append(f'<figure><img src="{_img(f.png)}" alt="{e(f.caption)}"><figcaption>{e(f.caption)}</figcaption></figure>')
    for t in tables:
        out.append(f"<h2>{e(t.caption)}</h2>")
        out.append("<table><tr>" + "".join(f"<th>{e(c)}</th>" for c in t.columns) + "</tr>")
        for row in t.rows:
            cells = "".join(f'<td class="num">{e(c)}</td>' if _is_number(c) else f"<td>{e(c)}</td>" for c in row)
            out.append(f"<tr>{cells}</tr>")
        out.append("</table>")
    out += ["</body>", "</html>", ""]
    return "\n".join(out)


def write_report(
    path: str | os.PathLike, *, title: str, summary_rows: Sequence[tuple[str, str]],
    figures: Sequence[ReportFigure | tuple[bytes | Figure, str]] = (), notes: Sequence[str] = (),
    tables: Sequence[ReportTable] = (), overwrite: bool = True,
) -> Path:
    """Write one self-contained HTML page: a title, a summary table, notes, figures and tables.

    No script and no external reference: the CSS is inline and every image
    a ``data:image/png;base64`` URI, so the file opens in any browser
    without a server or a network.  Every text is HTML-escaped.  The file
    is written to ``path + ".partial"`` and renamed when complete.

    Parameters
    ----------
    path : path
        The HTML file.
    title : str
    summary_rows : sequence of (str, str)
        The rows of the summary table: name, value (already formatted).
    figures : sequence of ReportFigure, or of (PNG bytes or matplotlib Figure, caption)
        In order; a :class:`ReportFigure`'s ``section`` starts a new heading
        when it changes.
    notes : sequence of str
        Sentences under the summary (what is missing and why, ...).
    tables : sequence of ReportTable
        After the figures.
    overwrite : bool
        Replace an existing file (default True: the caller checked with
        :func:`check_report_path` before its job).

    Returns
    -------
    Path

    Raises
    ------
    PatchcloudIOError
        The directory is missing, or the file exists and not ``overwrite``.
    PatchcloudValueError
        A figure that is neither PNG bytes nor a Figure.

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as d:
    ...     p = write_report(os.path.join(d, "r.html"), title="Run", summary_rows=[("points", "1,000")])
    ...     "<td>1,000</td>" in p.read_text()
    True
    """
    if not isinstance(title, str):
        raise PatchcloudValueError(f"title must be a str, got {title!r}")
    page = render_html(title=title, summary_rows=summary_rows, figures=figures, notes=notes, tables=tables)
    p = Path(path)
    if p.is_dir():
        raise PatchcloudIOError(f"{p}: is a directory, not a report file")
    try:
        with atomic_output(p, overwrite=overwrite) as f:
            f.write(page.encode("utf-8"))
    except PatchcloudIOError:
        raise
    except OSError as exc:
        raise PatchcloudIOError(f"{p}: cannot write the report ({exc})") from exc
    return p


# --------------------------------------------------------------------------------------------------------------------
# Summary rows, from the summaries' fields
# --------------------------------------------------------------------------------------------------------------------
def _n(v: int) -> str:
    return f"{int(v):,}"


def _share(v: int, n: int) -> str:
    return f"{int(v):,} ({int(v) / max(int(n), 1):.1%})"


def _value(v) -> str:
    if v is None:
        return "none"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, (list, tuple)):
        return ", ".join(_value(x) for x in v)
    if isinstance(v, dict):  # units, points left out, the selection: "key value" pairs, not a Python repr
        return "; ".join(f"{str(k).replace('_', ' ')} {_value(x)}" for k, x in v.items()) or "none"
    return str(v)


def _half_count(v: float) -> str:
    """The median of counts (a whole number or a half): ``42``, ``42.5``, ``1,234,567.5``.

    >>> _half_count(42.0), _half_count(42.5), _half_count(1234567.5)
    ('42', '42.5', '1,234,567.5')
    """
    return f"{int(v):,}" if v.is_integer() else f"{v:,.1f}"


def _count_or_value(v) -> str:
    """A count with thousands separators (``1,592``), anything else as :func:`_value` writes it.

    >>> _count_or_value(1592), _count_or_value(np.int64(20000)), _count_or_value(True), _count_or_value([1, 1, 1])
    ('1,592', '20,000', 'yes', '1, 1, 1')
    """
    return _n(v) if isinstance(v, (int, np.integer)) and not isinstance(v, bool) else _value(v)


def run_files(summary) -> tuple[list[str], list[str]]:
    """The inputs and outputs of a run: one each, or a catalog's files (``summary.files``: (input, output, points))."""
    files = getattr(summary, "files", None) or []
    if files:  # a catalog's, even of one file (its summary's output is then the directory)
        return [i for i, _, _ in files], [o for _, o, _ in files]
    return [summary.input], [summary.output]


def file_rows(summary) -> list[tuple[str, str]]:
    """One summary row per file of a catalog run (none for one file).

    >>> from patchcloud.stream import NormalsSummary
    >>> s = NormalsSummary("a/t1.las and 1 more file", "o", 3, 1, 8.0, {}, {}, {}, files=[("a/t1.las", "o/t1.las", 2), ("a/t2.las", "o/t2.las", 1)])
    >>> file_rows(s)
    [('files', '2'), ('file: t1.las', '2 points -> o/t1.las'), ('file: t2.las', '1 points -> o/t2.las')]
    """
    files = getattr(summary, "files", None) or []
    if len(files) < 2:
        return []
    return [("files", _n(len(files)))] + [(f"file: {Path(i).name}", f"{_n(n)} points -> {o}") for i, o, n in files]


def _check_summary(summary, kind: str, field: str) -> None:
    """Refuse, in one line, a ``summary`` that is not the job's summary (a :class:`{kind}`, which has ``field``)."""
    if not hasattr(summary, field) or not hasattr(summary, "format"):
        raise PatchcloudValueError(f"summary must be a {kind} (what the job returns), got a {type(summary).__name__}")


def _unit(summary) -> str:
    """The symbol of the unit a summary's lengths are in (``m``, ``ft``, ``us-ft``; ``m`` for a summary without one)."""
    return (getattr(summary, "units", None) or {}).get("symbol", "m")


def units_rows(summary) -> list[tuple[str, str]]:
    """The report's row naming the unit every length in it is in (:func:`units_text`, as the summary's line); none without one.

    >>> from patchcloud.stream import NormalsSummary
    >>> s = NormalsSummary("in.las", "out.las", 1, 1, 64.0, {}, {}, {}, units={"symbol": "ft", "name": "foot", "metres": 0.3048, "source": "CRS"})
    >>> units_rows(s)
    [('units', 'ft (foot, 0.3048 m; from the CRS): every length here and every distance option')]
    """
    units = getattr(summary, "units", None)
    return [("units", units_text(units))] if units else []


def left_out_rows(summary, fate: str = "no value, in no neighbourhood") -> list[tuple[str, str]]:
    """The summary's row on the points left out (by ``--classes``, noise, withheld: by reason, and what became of them)
    and the selection asked for; none where no point was left out.

    >>> from patchcloud.stream import NormalsSummary
    >>> s = NormalsSummary("in.las", "out.las", 100, 1, 64.0, {}, {}, {}, left_out={"classes": 5, "noise": 2, "withheld": 0},
    ...                    selection={"classes": [2], "keep_noise": False})
    >>> left_out_rows(s)[0]
    ('left out', '7 (7.0%): 5 not of classes 2, 2 noise (class 7, 18); no value, in no neighbourhood')
    """
    text = left_out_text(getattr(summary, "left_out", None) or {}, getattr(summary, "selection", None), summary.points, fate)
    if not text:
        return []
    rows = [("left out", text)]
    if getattr(summary, "selection", None):
        rows.append(("selection", _value(summary.selection)))
    return rows


def _left_out_total(summary) -> int:
    return sum(int(v) for v in (getattr(summary, "left_out", None) or {}).values())


def _job_rows(seconds: dict[str, float], points: int, peak_memory: int, scheduler: str | None, store: str | None) -> list[tuple[str, str]]:
    total = sum(seconds.values())
    rows = [(f"time: {step}", f"{t:.2f} s") for step, t in seconds.items()]
    rows.append(("time: total", f"{total:.2f} s ({points / max(total, 1e-9):,.0f} points/s)"))
    where = f" {memory_scope(scheduler)}" if scheduler else ""  # as the summary says it
    rows.append(("peak memory", f"{peak_memory / 2**20:,.0f} MiB{where}"))
    if store:
        rows.append(("store (kept)", store))
    return rows


def normals_rows(summary: "NormalsSummary") -> list[tuple[str, str]]:
    """The summary table of a ``normals`` run: every field of its :class:`NormalsSummary`, formatted.

    Examples
    --------
    >>> from patchcloud.stream import NormalsSummary
    >>> s = NormalsSummary("in.las", "out.las", 1234567, 4, 64.0, dict(surface=5, edge=1, sparse=0),
    ...                    dict(quadric=1000000, blended=200000, knn=34567), dict(criterion="rmse"), {"fit": 2.0})
    >>> dict(normals_rows(s))["points"]
    '1,234,567'
    """
    s = summary
    k, m = s.patches_by_kind, s.normals_by_method
    rows = [
        ("input", s.input), ("output", s.output), ("points", _n(s.points)), ("tiles", f"{s.tiles:,} of {s.tile_size:g} {_unit(s)}"),
        *units_rows(s), ("patches", f"{sum(k.values()):,}: " + ", ".join(f"{name} {v:,}" for name, v in k.items())),
    ]
    rows += [(f"normals: {name}", _share(v, s.points)) for name, v in m.items()]
    rows += left_out_rows(s)
    rows += [(f"parameter: {name}", _value(v)) for name, v in s.parameters.items()]
    return rows + _job_rows(s.seconds, s.points, s.peak_memory, s.scheduler, s.store) + file_rows(s)


def don_rows(summary: "DonSummary") -> list[tuple[str, str]]:
    """The summary table of a ``don`` or ``segment`` run: every field of its :class:`DonSummary`, formatted."""
    s = summary
    rows = [
        ("input", s.input), ("output", s.output), ("points", _n(s.points)), ("tiles", f"{s.tiles:,} of {s.tile_size:g} {_unit(s)}"),
        *units_rows(s), ("DoN defined", _share(s.defined, s.points)),
        ("median DoN magnitude", s.median_words() if s.defined else "none (no DoN defined)"),
    ]
    if s.kept is not None:
        rows.append(("kept (above the threshold)", _share(s.kept, s.points)))
    if s.segments is not None:
        rows.append(("segments", _n(s.segments)))
    rows += left_out_rows(s)
    rows += [(f"parameter: {name}", _value(v)) for name, v in s.parameters.items()]
    return rows + _job_rows(s.seconds, s.points, s.peak_memory, s.scheduler, s.store) + file_rows(s)


def compress_rows(summary: "CompressSummary") -> list[tuple[str, str]]:
    """The summary table of a ``compress`` run: every field of its :class:`CompressSummary`, formatted."""
    s = summary
    n = max(s.points, 1)
    rows = [
        ("input", s.input), ("output", s.output), ("points", _n(s.points)), *units_rows(s),
        ("points on patches", _share(s.points - s.residual, s.points)), ("patches", _n(s.patches)),
        ("residual points", _share(s.residual, s.points)),
        *([("tiles", f"{s.tiles:,} of {s.tile_size:g} {_unit(s)}")] if s.tiles else []),
        ("error budget", f"{s.max_error:g} {_unit(s)}"),
        ("mean error of the modelled points", f"{s.mean_error:.4f} {_unit(s)} (before quantisation, which adds at most half the budget)"
         if s.points > s.residual else "none modelled (every point kept as it is, within the budget)"),
        ("input size", f"{s.input_bytes:,} bytes ({8 * s.input_bytes / n:.2f} bits/point)"),
        ("output size", f"{s.output_bytes:,} bytes ({8 * s.output_bytes / n:.2f} bits/point)"),
        ("compression ratio", f"{s.input_bytes / max(s.output_bytes, 1):.2f}"),
    ]
    known = {f.name for f in fields(s)} - {"input", "output", "points", "patches", "residual", "max_error", "input_bytes",
                                           "output_bytes", "mean_error", "seconds", "peak_memory", "tiles", "tile_size", "units"}
    rows += [(name.replace("_", " "), _count_or_value(getattr(s, name))) for name in sorted(known)]  # fields added later
    return rows + _job_rows(s.seconds, s.points, s.peak_memory, None, None)


# --------------------------------------------------------------------------------------------------------------------
# Statistics read from the files, in chunks
# --------------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class NormalStatistics:
    """What a ``normals`` output says beyond its summary.

    Attributes
    ----------
    curvature : Histogram
        Surface variation of every point with a finite one, 50 bins over [0, 1/3].
    angles : Histogram or None
        Unoriented angle (degrees, ``arccos |n . m|``) between each output
        normal and the input's reference normal, 1-degree bins over [0, 90];
        None when the input has no reference normals.
    reference : str or None
        Which dimensions held the reference normals, and of which file.
    mean_angle : float
        Mean angle (degrees) over the points compared (NaN when none).
    """

    curvature: Histogram
    angles: Histogram | None
    reference: str | None
    mean_angle: float = float("nan")


def _dims(path: str) -> set[str]:
    with laspy.open(path) as r:
        return set(r.header.point_format.dimension_names)


def _unit_rows(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows of ``n`` scaled to unit length, and which rows could be (finite, nonzero)."""
    length = np.sqrt(np.einsum("ij,ij->i", n, n))
    ok = np.isfinite(length) & (length > 1e-12)
    return n / np.where(ok, length, 1.0)[:, None], ok


def normal_statistics(
    output: str | os.PathLike, input: str | os.PathLike | None = None, *, angle_bins: int = 90, curvature_bins: int = 50,
    chunk: int = 1 << 20,
) -> NormalStatistics:
    """Curvature histogram of a ``normals`` output and, where the input carries reference normals, the angle errors.

    The reference normals are the input's ``TrueNormalX/Y/Z`` (read from the
    output, which copies every input dimension) or else its
    ``NormalX/Y/Z`` (read from the input, since the output's are the new
    ones).  Points whose reference is zero or not finite are not compared;
    points without a normal (``NormalMethod`` 0) are in neither histogram.
    Both files are read in chunks of ``chunk`` points into fixed bins: the
    memory does not depend on the file.

    Parameters
    ----------
    output : path
        A LAS/LAZ written by ``patchcloud normals`` (NormalX/Y/Z, Curvature).
    input : path, optional
        Its input, where the reference normals are looked for.
    angle_bins : int
        Bins over [0, 90] degrees.
    curvature_bins : int
        Bins over [0, 1/3].
    chunk : int
        Points per read.

    Returns
    -------
    NormalStatistics

    Raises
    ------
    PatchcloudIOError
        A file that cannot be read, an output without normals, or an input
        whose point count differs from the output's.
    """
    out_src = open_source(output, allow_empty=True)  # (a catalog's empty tile: no point in any bin)
    out_dims = _dims(out_src.path)
    if not {"NormalX", "NormalY", "NormalZ", "Curvature"} <= out_dims:
        raise PatchcloudIOError(f"{out_src.path}: no NormalX/Y/Z and Curvature (not a patchcloud normals output)")
    in_src = None
    ref_dims: tuple[str, str, str] | None = None
    reference = None
    ref_in_output = False
    if input is not None:
        in_src = open_source(input, allow_empty=True)
        in_dims = _dims(in_src.path)
        for dims in REFERENCE_DIMS:
            if set(dims) <= in_dims:
                ref_dims = dims
                break
        if ref_dims is not None:
            if in_src.point_count != out_src.point_count:
                raise PatchcloudIOError(f"{out_src.path}: holds {out_src.point_count:,} points, its input {in_src.point_count:,}")
            ref_in_output = ref_dims[0] != "NormalX" and set(ref_dims) <= out_dims
            reference = f"{'/'.join(ref_dims)} of the input ({Path(in_src.path).name})"

    curv_edges = np.linspace(0.0, CURVATURE_MAX, curvature_bins + 1)
    curv = np.zeros(curvature_bins, dtype=np.int64)
    ang_edges = np.linspace(0.0, 90.0, angle_bins + 1)
    ang = np.zeros(angle_bins, dtype=np.int64)
    angle_sum = 0.0
    ref_chunks = read_chunks(in_src, chunk) if (ref_dims is not None and not ref_in_output) else None
    for _, rec in read_chunks(out_src, chunk):
        c = np.asarray(rec["Curvature"], dtype=np.float64)
        if "NormalMethod" in out_dims:  # points without a normal (NormalMethod 0: left out by --classes, noise) hold 0
            c = c[np.asarray(rec["NormalMethod"]) > 0]
        c = c[np.isfinite(c)]
        curv += np.histogram(np.clip(c, 0.0, CURVATURE_MAX), bins=curv_edges)[0]
        if ref_dims is None:
            continue
        n = np.column_stack([np.asarray(rec[d], dtype=np.float64) for d in ("NormalX", "NormalY", "NormalZ")])
        ref_rec = rec if ref_chunks is None else next(ref_chunks)[1]
        m = np.column_stack([np.asarray(ref_rec[d], dtype=np.float64) for d in ref_dims])
        n, ok_n = _unit_rows(n)
        m, ok_m = _unit_rows(m)
        ok = ok_n & ok_m
        cos = np.abs(np.einsum("ij,ij->i", n[ok], m[ok]))
        a = np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))
        ang += np.histogram(a, bins=ang_edges)[0]
        angle_sum += float(a.sum())
    if ref_chunks is not None:
        ref_chunks.close()
    angles = Histogram(ang_edges, ang) if ref_dims is not None else None
    mean = angle_sum / angles.total if angles is not None and angles.total else float("nan")
    return NormalStatistics(Histogram(curv_edges, curv), angles, reference, mean)


def merge_statistics(parts: Sequence[NormalStatistics]) -> NormalStatistics:
    """The statistics of a catalog from those of its files (same bins): counts added, the mean angle weighted by them."""
    first = parts[0]
    curv = Histogram(first.curvature.edges, np.sum([p.curvature.counts for p in parts], axis=0))
    with_angles = [p for p in parts if p.angles is not None]
    if not with_angles:
        return NormalStatistics(curv, None, first.reference, float("nan"))
    angles = Histogram(with_angles[0].angles.edges, np.sum([p.angles.counts for p in with_angles], axis=0))
    total = sum(p.angles.total for p in with_angles if p.angles.total)
    mean = sum(p.mean_angle * p.angles.total for p in with_angles if p.angles.total) / total if total else float("nan")
    reference = with_angles[0].reference if len(with_angles) == len(parts) else f"{with_angles[0].reference} ({len(with_angles)} of {len(parts)} files)"
    return NormalStatistics(curv, angles, reference, mean)


def don_histogram(summary: "DonSummary") -> Histogram:
    """The DoN magnitude histogram of a run (its own bins over [0, 1], from :attr:`DonSummary.histogram`).

    Examples
    --------
    >>> from patchcloud.stream import DonSummary
    >>> h = don_histogram(DonSummary("a", "b", 10, 1, 8.0, {}, 9, histogram=[4, 5]))
    >>> h.edges.tolist(), h.counts.tolist()
    ([0.0, 0.5, 1.0], [4, 5])
    """
    counts = np.asarray(summary.histogram, dtype=np.int64)
    return Histogram(np.linspace(0.0, 1.0, counts.size + 1), counts)


def segment_sizes(output, *, chunk: int = 1 << 20) -> np.ndarray:
    """Points of each segment of a ``segment`` output, or of a catalog's outputs (a list: ids span the files), read in chunks.

    Memory: one integer per segment, none per point.

    Returns
    -------
    (S,) int64
        ``sizes[i]`` points carry ClusterID ``i + 1``.
    """
    sources = [open_source(p, allow_empty=True) for p in ([output] if isinstance(output, (str, os.PathLike)) else output)]
    for src in sources:
        if "ClusterID" not in _dims(src.path):
            raise PatchcloudIOError(f"{src.path}: no ClusterID (not a patchcloud segment output)")
    sizes = np.zeros(0, dtype=np.int64)
    for _, rec in (c for src in sources for c in read_chunks(src, chunk)):
        ids = np.asarray(rec["ClusterID"], dtype=np.int64)
        b = np.bincount(ids)
        if b.size > sizes.size:
            sizes = np.concatenate([sizes, np.zeros(b.size - sizes.size, np.int64)])
        sizes[: b.size] += b
    return sizes[1:]


def pcz_parts(path: str | os.PathLike) -> dict[str, int]:
    """Bytes of each part of a ``.pcz`` (its zip entries, added up): patch models, residual points, index and header.

    The patch models are the ``patches/`` entries (and ``cells/``, where
    the file keeps the patches' octree cells apart); each entry counts its
    data and its local zip header; the rest of the file is the zip's
    central directory.

    Returns
    -------
    dict
        ``{"patch models": ..., "residual points": ..., "index and header": ..., "zip directory": ...}`` (bytes),
        adding up to the file's size; a points-mode file's (``--keep-points``) points are ``"points"``.
    """
    p = Path(path)
    try:
        with zipfile.ZipFile(p) as z:
            infos = z.infolist()
    except (OSError, zipfile.BadZipFile) as exc:
        raise PatchcloudIOError(f"{p}: not a readable .pcz file ({exc})") from exc
    parts = {"patch models": 0, "residual points": 0, "points": 0, "index and header": 0}
    for i in infos:
        top = i.filename.split("/", 1)[0]
        key = "patch models" if top in ("patches", "cells") else "residual points" if top == "residual" else \
            "points" if top == "points" else "index and header"
        parts[key] += i.compress_size + 30 + len(i.filename.encode()) + len(i.extra)  # data + its local header
    parts["zip directory"] = max(p.stat().st_size - sum(parts.values()), 0)
    return {k: v for k, v in parts.items() if v or k != "points"}  # "points": a points-mode file's (--keep-points)


def _sum_by_slices(values, start: np.ndarray, step: int = 1 << 20) -> np.ndarray:
    """``out[t] = values[start[t]:start[t + 1]].sum()`` for every t; ``values`` (a zarr array) read ``step`` rows at a time."""
    start = np.asarray(start, dtype=np.int64)
    out = np.zeros(start.size - 1, dtype=np.int64)
    end = int(start[-1])
    for a in range(0, end, step):
        b = min(a + step, end)
        c = np.concatenate([[0], np.cumsum(np.asarray(values[a:b], dtype=np.int64))])
        out += c[np.clip(start[1:], a, b) - a] - c[np.clip(start[:-1], a, b) - a]
    return out


def pcz_tiles(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Per tile of a ``.pcz``: its index, patches, points on patches, residual points and residual bytes.

    Reads the index and the point counts of the patches (or of their
    cells, where the file keeps them), one slice at a time; not the points.

    Returns
    -------
    dict of arrays, one row per tile
        ``ijk`` (T, 3), ``patches``, ``patch_points``, ``residual``, ``residual_bytes`` (T,).
    """
    from patchcloud.stream.io.pcz import open_pcz

    with open_pcz(path) as f:
        ps = np.asarray(f.patch_start, dtype=np.int64)
        cell_start = getattr(f, "cell_start", None)
        if cell_start is not None:  # counts per cell, a tile's cells in a row
            on = _sum_by_slices(f.root["cells/count"], cell_start)
        else:
            on = _sum_by_slices(f.root["patches/count"], ps)
        return dict(ijk=np.asarray(f.tiles), patches=np.diff(ps), patch_points=on,
                    residual=np.diff(np.asarray(f.residual_start, dtype=np.int64)),
                    residual_bytes=np.diff(np.asarray(f.residual_byte_start, dtype=np.int64)))


# --------------------------------------------------------------------------------------------------------------------
# Figures
# --------------------------------------------------------------------------------------------------------------------
def histogram_figure(
    h: Histogram, *, title: str, xlabel: str, ylabel: str = "points", log: bool | None = None, logx: bool = False,
) -> Figure:
    """Bars of ``h``: one bar per bin, its height the bin's count.

    The count axis is logarithmic when ``log``, or by default when the
    nonzero counts span more than 100x; the value axis when ``logx``.
    """
    fig, (ax,) = new_figure(7.0, 3.2)
    widths = np.diff(h.edges)
    ax.bar(h.edges[:-1], h.counts, width=widths, align="edge", color="#3b6ea5", edgecolor="white", linewidth=0.3)
    pos = h.counts[h.counts > 0]
    if log is None:
        log = bool(pos.size and pos.max() / pos.min() > 100)
    if log and pos.size:
        ax.set_yscale("log")
    if logx:
        ax.set_xscale("log")
    ax.set_xlim(h.edges[0], h.edges[-1])
    ax.grid(axis="y", alpha=0.3)
    style_axes(ax, title, xlabel, ylabel + (" (log scale)" if log and pos.size else ""))
    return fig


def _bars_figure(labels: Sequence[str], values: Sequence[float], *, title: str, xlabel: str, fmt: str) -> Figure:
    """Horizontal bars, each with its value written beside it."""
    fig, (ax,) = new_figure(7.0, 0.9 + 0.45 * len(labels))
    y = np.arange(len(labels))
    import matplotlib

    colours = matplotlib.colormaps[CMAP](np.linspace(0.15, 0.75, max(len(labels), 2)))[: len(labels)]
    ax.barh(y, values, color=colours)
    ax.set_yticks(y, list(labels))
    ax.invert_yaxis()
    top = max(max(values, default=0.0), 1e-12)
    ax.set_xlim(0, top * 1.3)
    for yi, v in zip(y, values):
        ax.text(v + top * 0.01, yi, fmt.format(v), va="center", fontsize=STYLE["annotation"])
    style_axes(ax, title, xlabel)
    return fig


def segment_size_histogram(sizes: np.ndarray) -> Histogram:
    """Segments by size, in bins of a quarter of a power of ten (points per segment)."""
    if sizes.size == 0:
        return Histogram(np.array([1.0, 10.0]), np.zeros(1, np.int64))
    lo = np.floor(np.log10(max(int(sizes.min()), 1)) * 4) / 4
    hi = np.ceil(np.log10(int(sizes.max()) + 1) * 4) / 4
    edges = 10.0 ** np.arange(lo, max(hi, lo + 0.25) + 1e-9, 0.25)
    return Histogram(edges, np.histogram(sizes, bins=edges)[0])


# --------------------------------------------------------------------------------------------------------------------
# Views (patchcloud.stream.views.render)
# --------------------------------------------------------------------------------------------------------------------
def _views(paths: list[str], colours: Sequence[tuple[str, str]], width: int) -> tuple[list[ReportFigure], list[str]]:
    """PNG views of ``paths`` (LAS/LAZ; several: a catalog in one map), one per colour, from one read
    (:func:`patchcloud.stream.views.render.render_arrays`).

    A colour the file has no dimension for, or views that cannot be drawn
    (a PatchcloudError), become notes instead.
    """
    from patchcloud.stream.views.render import file_dimensions, render_arrays, render_figure, supported_modes

    notes = []
    try:
        can = set.intersection(*(set(supported_modes(file_dimensions(p))) for p in paths))
    except PatchcloudError as exc:
        return [], [f"No views: {exc}"]
    wanted = [(c, cap) for c, cap in colours if c in can]
    name = paths[0] if len(paths) == 1 else "the outputs"
    notes += [f"No view coloured by {c}: {name} has no dimension for it." for c, _ in colours if c not in can]
    if not wanted:
        return [], notes
    try:
        images = render_arrays(paths[0] if len(paths) == 1 else paths, colors=[c for c, _ in wanted], width=width,
                               width_of="figure")
    except PatchcloudError as exc:
        return [], notes + [f"The views could not be drawn: {exc}"]
    figures = [ReportFigure(figure_png(render_figure(img)), caption, "Views") for img, (_, caption) in zip(images, wanted)]
    return figures, notes


# --------------------------------------------------------------------------------------------------------------------
# The three reports
# --------------------------------------------------------------------------------------------------------------------
def report_normals(
    summary: "NormalsSummary", path: str | os.PathLike, *, views: bool = True, view_width: int = VIEW_WIDTH,
    chunk: int = 1 << 20,
) -> Path:
    """The HTML report of a ``normals`` run (see :func:`write_report`).

    Parameters
    ----------
    summary : NormalsSummary
        The run's; its ``input`` and ``output`` are read (in chunks).
    path : path
        The HTML file (replaced if there).
    views : bool
        Render the output coloured by normal, curvature and patch.
    view_width : int
        Width of the views (pixels).
    chunk : int
        Points per read.

    Returns
    -------
    Path
    """
    _check_summary(summary, "NormalsSummary", "normals_by_method")
    inputs, outputs = run_files(summary)
    stats = merge_statistics([normal_statistics(o, i, chunk=chunk) for i, o in zip(inputs, outputs)])
    rows = normals_rows(summary)
    notes: list[str] = []
    figures: list[ReportFigure] = []
    if views:
        f, n = _views(outputs, [
            ("normals", "Output coloured by normal direction."),
            ("curvature", "Output coloured by curvature (surface variation)."),
            ("patches", "Output coloured by patch."),
        ], view_width)
        figures += f
        notes += n
    if stats.angles is not None and stats.angles.total:
        a = stats.angles
        rows += [
            ("reference normals", stats.reference or ""),
            ("angle error: points compared", _n(a.total)),
            ("angle error: mean", f"{stats.mean_angle:.2f}°"),
            ("angle error: median", f"{a.quantile(0.5):.1f}° (to 1°)"),
            ("angle error: 95th percentile", f"{a.quantile(0.95):.1f}° (to 1°)"),
            ("angle error: under 5°", f"{a.counts[a.edges[1:] <= 5.0].sum() / max(a.total, 1):.1%}"),
        ]
        figures.append(ReportFigure(figure_png(histogram_figure(
            a, title="Angle between the output normals and the reference normals", xlabel="angle (degrees, unoriented)")),
            f"Unoriented angle arccos|n·m| between each output normal n and the reference normal m ({stats.reference}), "
            f"in 1° bins; {a.total:,} points compared.", "Histograms"))
    elif stats.angles is not None:
        notes.append(f"The input's reference normals ({stats.reference}) are all zero or not finite: no angle errors to show.")
    else:
        notes.append("The input carries no reference normals (TrueNormalX/Y/Z or NormalX/Y/Z): no angle errors to show.")
    figures.append(ReportFigure(figure_png(histogram_figure(
        stats.curvature, title="Curvature (surface variation)", xlabel="Curvature λ3 / (λ1 + λ2 + λ3)")),
        f"Curvature of the {stats.curvature.total:,} points with one, {stats.curvature.counts.size} bins over [0, 1/3].",
        "Histograms"))
    m = summary.normals_by_method
    figures.append(ReportFigure(figure_png(_bars_figure(
        list(m), [v / max(summary.points, 1) * 100 for v in m.values()], title="Points by normal method",
        xlabel="share of the points (%)", fmt="{:.1f} %")),
        "Where each normal came from: a quadric patch, blended across patch faces, the PCA of the octree cells' moments "
        "around the point (for points no patch models), or the k-nearest-neighbour fallback.",
        "Histograms"))
    return write_report(path, title=f"patchcloud normals: {Path(summary.input).name}", summary_rows=rows, figures=figures, notes=notes)


def report_don(
    summary: "DonSummary", path: str | os.PathLike, *, views: bool = True, view_width: int = VIEW_WIDTH, chunk: int = 1 << 20,
) -> Path:
    """The HTML report of a ``don`` or ``segment`` run (a segment run has ``summary.segments`` set).

    Views of the output coloured by DoN (and by segment); the DoN magnitude
    histogram of the summary; for segment, the segment sizes (the output's
    ClusterID read in chunks).  Parameters as :func:`report_normals`.
    """
    _check_summary(summary, "DonSummary", "histogram")
    segmenting = summary.segments is not None
    rows = don_rows(summary)
    notes: list[str] = []
    figures: list[ReportFigure] = []
    if views:
        colours = ([("segments", "Output coloured by segment (grey: no segment).")] if segmenting else []) + [
            ("don", "Output coloured by DoN magnitude.")]
        f, n = _views(run_files(summary)[1], colours, view_width)
        figures += f
        notes += n
    h = don_histogram(summary)
    if h.total:
        figures.append(ReportFigure(figure_png(histogram_figure(h, title="DoN magnitude", xlabel="DoN magnitude (0 to 1)")),
                                    f"DoN magnitude of the {h.total:,} points where it is defined, {h.counts.size} bins over [0, 1].",
                                    "Histograms"))
    else:
        notes.append("No point has a defined DoN: no histogram.")
    undefined = summary.points - summary.defined - _left_out_total(summary)  # the points left out have none either
    if undefined:
        notes.append(f"{undefined:,} points have no DoN (fewer than {summary.parameters.get('min_points', 3)} points, or only "
                     "collinear ones, in a ball): they are not in the histogram.")
    if segmenting:
        sizes = segment_sizes(run_files(summary)[1], chunk=chunk)
        if sizes.size:
            rows += [("segment size: smallest, median, largest",
                      f"{int(sizes.min()):,}, {_half_count(float(np.median(sizes)))}, {int(sizes.max()):,} points")]
            figures.append(ReportFigure(figure_png(histogram_figure(
                segment_size_histogram(sizes), title="Segment sizes", xlabel="points per segment (log scale)",
                ylabel="segments", log=False, logx=True)),
                f"Points per segment, {sizes.size:,} segments, bins of a quarter of a power of ten.", "Histograms"))
    kind = "segment" if segmenting else "don"
    return write_report(path, title=f"patchcloud {kind}: {Path(summary.input).name}", summary_rows=rows, figures=figures, notes=notes)


def report_compress(
    summary: "CompressSummary", path: str | os.PathLike, *, views: bool = True, view_width: int = VIEW_WIDTH,
    max_tile_rows: int = MAX_TILE_ROWS,
) -> Path:
    """The HTML report of a ``compress`` run.

    Views of the input (a ``.pcz`` is not a point file) by elevation and by
    classification; bits per point by part of the ``.pcz``; the error
    budget beside the mean error; the table of the tiles (the
    ``max_tile_rows`` largest, by points).  Parameters as :func:`report_normals`.
    The list of summaries ``compress`` returns for a catalog (``out_dir``)
    gets the catalog's report (:func:`report_compress_catalog`).
    """
    if isinstance(summary, (list, tuple)):
        return report_compress_catalog(summary, path, views=views, view_width=view_width)
    _check_summary(summary, "CompressSummary", "residual")
    s = summary
    rows = compress_rows(s)
    notes: list[str] = []
    figures: list[ReportFigure] = []
    if views:
        f, n = _views([s.input], [("elevation", "Input coloured by elevation."),
                                ("classification", "Input coloured by classification.")], view_width)
        figures += f
        notes += n
    parts = pcz_parts(s.output)
    n = max(s.points, 1)
    rows += [(f"size: {name}", f"{b:,} bytes ({8 * b / n:.3f} bits/point)") for name, b in parts.items()]
    figures.append(ReportFigure(figure_png(_bars_figure(
        list(parts), [8 * b / n for b in parts.values()], title=f"Bits per point by part ({8 * s.output_bytes / n:.2f} in all)",
        xlabel="bits per input point", fmt="{:.3f}")),
        "Bytes of each part of the .pcz (its zip entries with their headers) times 8, over the points of the input.", "Figures"))
    if s.mode == "points":  # no patches, no tiles
        return write_report(path, title=f"patchcloud compress --keep-points: {Path(s.input).name}", summary_rows=rows,
                            figures=figures, notes=notes)
    figures.append(ReportFigure(figure_png(_bars_figure(
        ["error budget", "mean error, modelled points", "quantisation, at most"],
        [s.max_error, s.mean_error, s.max_error / 2], title=f"Errors ({_unit(s)})", xlabel=_unit(s), fmt="{:.4f} " + _unit(s))),
        "The budget the patches fit within (RMS), the mean distance of the modelled points to their patch's surface "
        "before quantisation, and the most quantising the models adds.", "Figures"))
    t = pcz_tiles(s.output)
    total = t["patch_points"] + t["residual"]
    order = np.argsort(-total, kind="stable")[:max_tile_rows]
    table_rows = tuple(
        (" ".join(str(int(v)) for v in t["ijk"][i]), f"{int(total[i]):,}", f"{int(t['patches'][i]):,}",
         f"{int(t['patch_points'][i]) / max(int(total[i]), 1):.1%}", f"{int(t['residual'][i]):,}", f"{int(t['residual_bytes'][i]):,}")
        for i in order
    )
    caption = "Tiles" + (f" (the {len(order):,} largest of {len(total):,}, by points)" if len(order) < len(total) else "")
    tables = [ReportTable(caption, ("tile i j k", "points", "patches", "on patches", "residual points", "residual LAZ bytes"), table_rows)]
    return write_report(path, title=f"patchcloud compress: {Path(s.input).name}", summary_rows=rows, figures=figures,
                        notes=notes, tables=tables)


def report_compress_catalog(
    summaries: Sequence["CompressSummary"], path: str | os.PathLike, *, views: bool = True, view_width: int = VIEW_WIDTH,
) -> Path:
    """The HTML report of a ``compress --out-dir`` run: a catalog compressed file by file.

    The totals (points, patches, residual, bytes in and out, bits per
    point), a view of all the inputs as one map (by elevation), the bits
    per point of each file, and the table of the files (each with its own
    figures).  Parameters as :func:`report_compress`.
    """
    if not summaries:
        raise PatchcloudValueError("a catalog report needs the summary of at least one file")
    points = sum(s.points for s in summaries)
    n = max(points, 1)
    residual = sum(s.residual for s in summaries)
    bytes_in, bytes_out = sum(s.input_bytes for s in summaries), sum(s.output_bytes for s in summaries)
    seconds: dict[str, float] = {}
    for s in summaries:
        for step, t in s.seconds.items():
            seconds[step] = seconds.get(step, 0.0) + t
    rows = [
        ("files", _n(len(summaries))), ("points", _n(points)), ("points on patches", _share(points - residual, points)),
        ("patches", _n(sum(s.patches for s in summaries))), ("residual points", _share(residual, points)),
        ("error budget", ", ".join(sorted({f"{s.max_error:g} {_unit(s)}" for s in summaries}))),
        ("mean error of the modelled points", f"{sum(s.mean_error * (s.points - s.residual) for s in summaries) / max(points - residual, 1):.4f} "
         f"{_unit(summaries[0])} (before quantisation, which adds at most half the budget)"),
        ("input size", f"{bytes_in:,} bytes ({8 * bytes_in / n:.2f} bits/point)"),
        ("output size", f"{bytes_out:,} bytes ({8 * bytes_out / n:.2f} bits/point)"),
        ("compression ratio", f"{bytes_in / max(bytes_out, 1):.2f}"),
    ] + _job_rows(seconds, points, max(s.peak_memory for s in summaries), None, None)
    figures: list[ReportFigure] = []
    notes: list[str] = []
    if views:
        f, notes = _views([s.input for s in summaries], [("elevation", "The inputs, as one map, coloured by elevation.")], view_width)
        figures += f
    names = [Path(s.input).name for s in summaries]
    figures.append(ReportFigure(figure_png(_bars_figure(
        names, [8 * s.output_bytes / max(s.points, 1) for s in summaries], title="Bits per point by file",
        xlabel="bits per input point", fmt="{:.2f}")), "Each .pcz's bytes times 8, over its input's points.", "Figures"))
    table_rows = tuple(
        (Path(s.input).name, Path(s.output).name, f"{s.points:,}", f"{(s.points - s.residual) / max(s.points, 1):.1%}",
         f"{s.patches:,}", f"{s.output_bytes:,}", f"{8 * s.output_bytes / max(s.points, 1):.2f}", f"{s.mean_error:.4f}")
        for s in summaries
    )
    tables = [ReportTable("Files", ("input", "output", "points", "on patches", "patches", "bytes", "bits/point", f"mean error ({_unit(summaries[0])})"),
                          table_rows)]
    return write_report(path, title=f"patchcloud compress: {len(summaries)} files", summary_rows=rows, figures=figures,
                        notes=notes, tables=tables)
