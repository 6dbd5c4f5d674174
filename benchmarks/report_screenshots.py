"""Screenshots of the twin report and a study report in headless Chromium, at desktop and phone width.

Usage: ``python benchmarks/report_screenshots.py [--out docs/screenshots] [--work DIR]``.

1. The bundled workbench data (``examples/data/dc_rig.csv``: four experiments of
   DCMotorRig-v0, every 5th sample of its 2 ms records), then ``gbo twin report
   --max-steps 1 --y-unit rad/s --u-unit V``.
2. ``gbo bench smoke`` (random search and BO, 4 batches of 8 experiments).
3. Each page (``index.html``, ``report.html``) checked with
   :func:`evaluation.browser.page_check` (no broken image, no sideways scroll of
   the page) and photographed at 1280 and 390 px width:
   ``OUT/twin_report_{desktop,phone}.png``, ``OUT/study_report_{desktop,phone}.png``.

Prints one JSON object: the files written and the check of each page.
Needs Chromium (``make test`` installs Debian's ``chromium`` where missing).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import warnings
from pathlib import Path

from evaluation.browser import DESKTOP_WIDTH, PHONE_WIDTH, page_check, screenshot
from evaluation.cli import main as gbo

#: Window size of each screenshot, in CSS px.
SIZES = {"desktop": (DESKTOP_WIDTH, 2200), "phone": (PHONE_WIDTH, 2400)}
#: the bundled workbench data
RIG_CSV = Path(__file__).resolve().parents[1] / "examples" / "data" / "dc_rig.csv"


def twin_csv(path: Path) -> Path:
    """The bundled workbench data, copied to ``path`` (``examples/data/make_dc_rig.py`` writes it)."""
    return Path(shutil.copyfile(RIG_CSV, path))


def photograph(page: Path, name: str, out: Path) -> dict:
    """Check ``page`` and screenshot it at each of :data:`SIZES`; returns the checks and files."""
    result = {}
    for label, (width, height) in SIZES.items():
        check = page_check(page, width=width)
        broken = [image["alt"] for image in check["images"] if image["naturalWidth"] == 0]
        png = screenshot(page, out / f"{name}_{label}.png", width=width, height=height)
        _shrink(png)
        result[label] = {"file": str(png), "images": len(check["images"]), "broken_images": broken,
                         "tables": len(check["tables"]), "page_width": check["scrollWidth"],
                         "window_width": check["innerWidth"]}
    return result


def _shrink(png: Path) -> None:
    """Store the screenshot with a 256-colour palette (a quarter of the bytes; the pages are mostly flat colour)."""
    from PIL import Image

    with Image.open(png) as image:
        small = image.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT)
    small.save(png, optimize=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/screenshots"), help="folder of the PNGs")
    parser.add_argument("--work", type=Path, default=None, help="folder of the reports (default: a temporary one)")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore")
    work = args.work or Path(tempfile.mkdtemp(prefix="gbo-screenshots-"))
    work.mkdir(parents=True, exist_ok=True)
    twin_csv(work / "rig.csv")
    here = Path.cwd()
    os.chdir(work)  # the report names its data as given: rig.csv
    try:
        status = gbo(["twin", "report", "rig.csv", "--out", "twin", "--max-steps", "1", "--y-unit", "rad/s",
                      "--u-unit", "V", "--quiet"])
    finally:
        os.chdir(here)
    if status != 0:
        return 1
    if gbo(["bench", "smoke", "--out", str(work / "smoke"), "--workers", "1", "--quiet"]) != 0:
        return 1
    summary = {"twin_report": photograph(work / "twin" / "index.html", "twin_report", args.out),
               "study_report": photograph(work / "smoke" / "report.html", "study_report", args.out)}
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
