"""Look at an HTML report in headless Chromium: a screenshot, and what the page holds after it loaded.

:func:`page_check` loads a copy of the page with a small script appended that,
after the ``load`` event, writes into the DOM what a reader would see: each
image's natural size (0 for a broken image) and drawn size, the tables, and
whether the page is wider than the window; ``--dump-dom`` then returns it.
Debian's ``chromium`` package provides the browser (``make test`` installs it
where missing).
"""

from __future__ import annotations

import html
import json
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

__all__ = ["DESKTOP_WIDTH", "PHONE_WIDTH", "find_chromium", "page_check", "screenshot"]

#: Window widths of the checks, in CSS px.
DESKTOP_WIDTH = 1280
PHONE_WIDTH = 390
_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
          "--disable-background-networking", "--disable-component-update", "--disable-sync",
          "--hide-scrollbars", "--virtual-time-budget=10000")
_CHECK_ID = "gbo-page-check"
_CHECK_SCRIPT = """<script>
window.addEventListener("load", function () {
  var images = Array.from(document.images).map(function (img) {
    var box = img.getBoundingClientRect();
    return {alt: img.alt, naturalWidth: img.naturalWidth, naturalHeight: img.naturalHeight,
            width: box.width, height: box.height, complete: img.complete};
  });
  var tables = Array.from(document.querySelectorAll("table")).map(function (t) {
    return {id: t.id, rows: t.rows.length, width: t.getBoundingClientRect().width};
  });
  var result = {images: images, tables: tables, innerWidth: window.innerWidth,
                scrollWidth: document.documentElement.scrollWidth,
                headings: Array.from(document.querySelectorAll("h1, h2")).map(function (h) { return h.textContent; })};
  window.parent.postMessage(JSON.stringify(result), "*");
});
</script>"""
#: Page that shows the report in a frame of the asked width (headless Chromium keeps its window >= 500 px wide)
#: and writes the frame's check result into its own DOM.
_FRAME = """<!DOCTYPE html><html><head><meta charset="utf-8"><style>body{margin:0;background:#fff}
iframe{border:0;display:block}</style></head><body>
<iframe src="%s" width="%d" height="%d"></iframe>
<script>window.addEventListener("message", function (event) {
  var out = document.createElement("pre"); out.id = "%s"; out.textContent = event.data;
  document.body.appendChild(out);
});</script></body></html>"""
_MIN_WINDOW = 500


def find_chromium() -> str | None:
    """Path of a Chromium executable (``chromium``, ``chromium-browser``, ``google-chrome``), or None."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


def _run(args: list[str], timeout: float) -> str:
    browser = find_chromium()
    if browser is None:
        raise FileNotFoundError("chromium: not found on PATH; install it (Debian: apt-get install chromium)")
    with tempfile.TemporaryDirectory(prefix="gbo-chromium-") as profile:
        done = subprocess.run([browser, *_FLAGS, f"--user-data-dir={profile}", *args], capture_output=True,
                              text=True, timeout=timeout, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"chromium exited with {done.returncode}: {done.stderr[-2000:]}")
    return done.stdout


def _framed(folder: Path, page: Path, width: int, height: int) -> Path:
    """A page in ``folder`` that shows ``page`` in a ``width`` x ``height`` frame."""
    frame = folder / "frame.html"
    frame.write_text(_FRAME % (page.resolve().as_uri(), width, height, _CHECK_ID), encoding="utf-8")
    return frame


def _window(width: int, height: int) -> str:
    return f"--window-size={max(int(width), _MIN_WINDOW)},{int(height)}"


def screenshot(html_path: str | Path, png_path: str | Path, width: int = DESKTOP_WIDTH, height: int = 2400,
               timeout: float = 120.0) -> Path:
    """PNG of the page as Chromium draws it in a ``width`` x ``height`` window (CSS px).

    Parameters
    ----------
    html_path : str or Path
        The page.
    png_path : str or Path
        Where to write the screenshot (folders created).
    width, height : int
        Window size in CSS px; the screenshot shows the top ``height`` px of the page.
    timeout : float
        Seconds before Chromium is given up.
    """
    from PIL import Image

    png = Path(png_path).resolve()
    png.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="gbo-page-") as folder:
        frame = _framed(Path(folder), Path(html_path), int(width), int(height))
        _run([f"--screenshot={png}", _window(width, height), frame.as_uri()], timeout)
    if not png.is_file():
        raise RuntimeError(f"chromium wrote no screenshot to {png}")
    with Image.open(png) as image:
        cropped = image.crop((0, 0, int(width), int(height)))
    cropped.save(png)
    return png


def page_check(html_path: str | Path, width: int = DESKTOP_WIDTH, height: int = 900, timeout: float = 120.0) -> dict:
    """What the page holds after it loaded in a ``width`` px window.

    Returns
    -------
    dict
        ``images``: per ``<img>`` its ``alt``, ``naturalWidth``/``naturalHeight``
        (0 when broken) and drawn ``width``/``height`` (CSS px); ``tables``: per
        ``<table>`` its ``id``, number of rows and drawn width; ``innerWidth``
        and ``scrollWidth`` of the page (larger: the page scrolls sideways);
        ``headings``: text of the ``h1``/``h2``.
    """
    source = Path(html_path).read_text(encoding="utf-8")
    checked = source.replace("</body>", _CHECK_SCRIPT + "</body>") if "</body>" in source else source + _CHECK_SCRIPT
    with tempfile.TemporaryDirectory(prefix="gbo-page-") as folder:
        copy = Path(folder) / "page.html"
        copy.write_text(checked, encoding="utf-8")
        frame = _framed(Path(folder), copy, int(width), int(height))
        dom = _run(["--dump-dom", _window(width, height), frame.as_uri()], timeout)
    match = re.search(rf'<pre id="{_CHECK_ID}">(.*?)</pre>', dom, flags=re.S)
    if match is None:
        raise RuntimeError("chromium: the page never fired its load event (no check result in the DOM)")
    return json.loads(html.unescape(match.group(1)))
