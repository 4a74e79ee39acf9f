"""The HTML report in a real headless browser: it loads with no console message, every view and table is shown,
and the screenshot holds the report's own pictures, pixel for pixel.

The browser: $PATCHCLOUD_BROWSER, else chromium, chromium-browser, google-chrome or google-chrome-stable on PATH
(.ci/run installs Debian's chromium where it is missing).  Where none can be had the test is skipped, saying so.
"""

import base64
import io
import json
import os
import re
import shutil
import subprocess

import numpy as np
import pytest
from matplotlib.image import imread

import synthetic
from patchcloud.stream import normals, report_normals
from patchcloud.stream.views.report import VIEW_WIDTH
from test_report import write_las

BROWSER = os.environ.get("PATCHCLOUD_BROWSER") or next(
    (shutil.which(b) for b in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable") if shutil.which(b)), None)
#: The window: wider than the report's column (1250 px), so its pictures are shown at their own size.
WINDOW = 1300

pytestmark = pytest.mark.skipif(
    BROWSER is None, reason="no headless browser here (set PATCHCLOUD_BROWSER, or install chromium: .ci/run installs "
    "Debian's where apt can): the HTML report is not opened in a browser")

# Loads the report in a frame of the window's width and writes, once it has loaded, what the browser made of it:
# every image (decoded? its own size, where it is shown) and every table (rows, where it is shown).
HARNESS = """<!DOCTYPE html><html><head><meta charset="utf-8"></head><body style="margin:0">
<iframe id="report" src="REPORT" style="border:0;width:WIDTHpx;height:200px"></iframe>
<script>
document.getElementById("report").addEventListener("load", function () {
  var d = this.contentDocument, out = {images: [], tables: [], height: d.documentElement.scrollHeight};
  for (var img of d.images) {
    var r = img.getBoundingClientRect();
    out.images.push({complete: img.complete, width: img.naturalWidth, height: img.naturalHeight,
                     box: [r.left, r.top, r.width, r.height]});
  }
  for (var t of d.querySelectorAll("table")) {
    var r = t.getBoundingClientRect();
    out.tables.push({rows: t.rows.length, box: [r.left, r.top, r.width, r.height]});
  }
  var pre = document.createElement("pre");
  pre.id = "result";
  pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
});
</script></body></html>"""


def run_browser(tmp_path, *args):
    """Run the headless browser; (stdout, the console's messages: page logs and uncaught errors)."""
    cmd = [BROWSER, "--headless=new", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--force-device-scale-factor=1",
           "--enable-logging=stderr", "--v=0", f"--user-data-dir={tmp_path / 'browser-profile'}", *args]
    r = subprocess.run(cmd, capture_output=True, timeout=120)
    err = r.stderr.decode(errors="replace")
    assert r.returncode == 0, err[-2000:]
    return r.stdout.decode(errors="replace"), [ln for ln in err.splitlines() if ":CONSOLE" in ln or "Uncaught" in ln]


def browse(report, tmp_path):
    """What the browser made of ``report``: the harness's record and the console's messages."""
    harness = report.parent / f"harness-{report.stem}.html"
    harness.write_text(HARNESS.replace("REPORT", report.name).replace("WIDTH", str(WINDOW)))
    out, console = run_browser(tmp_path, "--allow-file-access-from-files", "--virtual-time-budget=10000", "--dump-dom",
                               harness.resolve().as_uri())
    m = re.search(r'<pre id="result">(.*?)</pre>', out, re.S)
    assert m, "the report never finished loading in the browser"
    return json.loads(m.group(1).replace("&quot;", '"').replace("&lt;", "<").replace("&gt;", ">").replace("&amp;", "&")), console


def embedded(page):
    return [base64.b64decode(m) for m in re.findall(r'<img src="data:image/png;base64,([A-Za-z0-9+/=]+)"', page)]


def problems(seen, pngs, page):
    """What the browser did not show: images not decoded or not at their size, tables missing or empty."""
    out = []
    if len(seen["images"]) != len(pngs):
        out.append(f"{len(seen['images'])} images shown of {len(pngs)}")
    for k, (img, png) in enumerate(zip(seen["images"], pngs)):
        w, h = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")  # the PNG's IHDR
        if not img["complete"] or (img["width"], img["height"]) != (w, h):
            out.append(f"image {k}: decoded as {img['width']} x {img['height']}, the PNG is {w} x {h}")
        elif abs(img["box"][2] - (w + 2)) > 0.5:  # its own size, and a 1 px border each side
            out.append(f"image {k}: shown {img['box'][2]:g} px wide, the PNG is {w}")
    tables = [t.count("<tr>") for t in re.findall(r"<table.*?</table>", page, re.S)]
    if [t["rows"] for t in seen["tables"]] != tables:
        out.append(f"tables shown with rows {[t['rows'] for t in seen['tables']]}, the page has {tables}")
    out += [f"table {k} not shown" for k, t in enumerate(seen["tables"]) if not (t["box"][2] > 50 and t["box"][3] > 10)]
    return out


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("browser")
    pts, nrm = synthetic.plane(np.random.default_rng(1), 20000, size=10.0, tilt=(0.1, 0.2))
    path = write_las(tmp / "plane.las", pts, normals_as=("NormalX", "NormalY", "NormalZ"), nrm=nrm)
    s = normals(path, tmp / "out.las", scheduler="synchronous", quiet=True)
    return report_normals(s, tmp / "r.html")  # with its views: normals, curvature, patches


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_the_report_in_a_headless_browser_shows_every_view_and_table_and_its_pictures(report, tmp_path):
    page = report.read_text()
    pngs = embedded(page)
    assert len(pngs) == 6  # 3 views, 3 figures
    seen, console = browse(report, tmp_path)
    assert console == []  # no console message: nothing logged, no error thrown
    assert problems(seen, pngs, page) == []
    assert [img["width"] for img in seen["images"][:3]] == [VIEW_WIDTH] * 3  # the views exactly as wide as asked

    # the screenshot of the whole page holds each embedded picture, pixel for pixel, where the browser laid it out
    shot = tmp_path / "shot.png"
    _, console = run_browser(tmp_path, f"--window-size={WINDOW},{seen['height']}", f"--screenshot={shot}", report.resolve().as_uri())
    assert console == []
    screen = imread(str(shot))[..., :3]
    assert screen.shape[:2] == (seen["height"], WINDOW)
    for k, (img, png) in enumerate(zip(seen["images"], pngs)):
        want = imread(io.BytesIO(png))[..., :3]
        h, w = want.shape[:2]
        x, y = int(round(img["box"][0])) + 1, int(round(img["box"][1])) + 1  # inside the 1 px border
        errs = [np.abs(screen[y + dy:y + dy + h, x + dx:x + dx + w] - want).mean()
                for dy in (-1, 0, 1) for dx in (-1, 0, 1) if screen[y + dy:y + dy + h, x + dx:x + dx + w].shape == want.shape]
        assert errs and min(errs) < 1.0 / 255, (k, min(errs, default=None))
        other = imread(io.BytesIO(pngs[(k + 1) % len(pngs)]))[..., :3]  # and not merely any picture: not the next one
        if other.shape == want.shape:
            assert np.abs(other - want).mean() > 2.0 / 255
    for t in seen["tables"]:  # the tables' text is on the screen: not blank
        x, y, w, h = (int(round(v)) for v in t["box"])
        assert screen[y:y + h, x:x + w].std() > 0.05


@pytest.mark.slow  # over 4 s: the slow suite keeps the default one under 10 minutes
def test_a_broken_picture_is_caught(report, tmp_path):
    # the same page with one view's PNG replaced by bytes that are no picture: the browser cannot decode it, and
    # the check says so
    page = report.read_text()
    start = page.index("data:image/png;base64,") + len("data:image/png;base64,")
    junk = base64.b64encode(b"not a picture " * 40).decode()
    broken = report.parent / "broken.html"
    broken.write_text(page[:start] + junk + page[page.index('"', start):])
    seen, _ = browse(broken, tmp_path)
    found = problems(seen, embedded(page), page)
    assert len(found) == 1 and found[0].startswith("image 0: decoded as 0 x 0"), found
