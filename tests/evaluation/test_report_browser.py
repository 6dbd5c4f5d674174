"""The HTML reports as a reader sees them: headless Chromium at desktop and phone width.

Chromium loads the twin report (``gbo twin report``), a study report
(``gbo bench``'s ``report.html``) and a leaderboard (``gbo bench suite``'s ``leaderboard.html``) at 1280 and
390 px; every image must have
loaded (``naturalWidth > 0``) and be drawn, the page must not scroll sideways,
and the tables (the twin report's error ladder) must be there. Skips when no
Chromium is installed (``make test`` installs Debian's ``chromium`` where missing).
"""

from __future__ import annotations

import numpy as np
import pytest

from agents.twin.csvio import write_csv
from evaluation.browser import DESKTOP_WIDTH, PHONE_WIDTH, find_chromium, page_check, screenshot
from evaluation.cli import main
from evaluation.leaderboard import Leaderboard, PlantTarget, write_leaderboard
from evaluation.report import write_report
from evaluation.study import parse_study
from evaluation.study_runner import run_study
from tests.support import loop_records

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(find_chromium() is None,
                                 reason="chromium is not installed (make test installs it; as root: "
                                        "apt-get install -y chromium)")]
WIDTHS = (DESKTOP_WIDTH, PHONE_WIDTH)


@pytest.fixture(scope="module")
def twin_report(tmp_path_factory):
    folder = tmp_path_factory.mktemp("twin")
    records = loop_records({"saturation": {"limit": 150.0}}, gains=np.array([[0.3, 1.0], [0.9, 1.2], [1.05, 2.0]]),
                           duration=1.0, start_index=1)
    csv = write_csv(records, folder / "sat.csv")
    assert main(["twin", "report", str(csv), "--out", str(folder / "report"), "--max-steps", "1"]) == 0
    return folder / "report" / "index.html"


@pytest.fixture(scope="module")
def study_report(tmp_path_factory):
    out = tmp_path_factory.mktemp("study")
    study = parse_study({"study": {"name": "tiny", "batches": 2, "budget": 3, "n_initial": 1, "resolution": 10},
                         "env": {"id": "gbo_envs/DCMotor-v0"}, "tuners": [{"name": "random"}],
                         "thresholds": [1.5]})
    run_study(study, out, workers=1, progress=False)
    write_report(study, out)
    return out / "report.html"


def _check_page(path, width) -> dict:
    check = page_check(path, width=width)
    assert check["innerWidth"] == width
    assert check["scrollWidth"] <= width, "the page scrolls sideways"
    assert check["images"], "no figure on the page"
    for image in check["images"]:
        assert image["naturalWidth"] > 0, f"broken image {image['alt']!r}"
        assert image["width"] > 0 and image["height"] > 0, f"figure {image['alt']!r} is not visible"
        assert image["width"] <= width
    return check


@pytest.mark.parametrize("width", WIDTHS)
def test_twin_report_in_chromium(twin_report, width, tmp_path):
    check = _check_page(twin_report, width)
    assert len(check["images"]) >= 4  # ladder, compare, two residual figures
    ladder = [table for table in check["tables"] if table["id"] == "ladder"]
    assert ladder and ladder[0]["rows"] == 3  # header, the linear model, one added effect
    assert "Error ladder" in check["headings"]
    png = screenshot(twin_report, tmp_path / "twin.png", width=width, height=1200)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("width", WIDTHS)
def test_study_report_in_chromium(study_report, width, tmp_path):
    check = _check_page(study_report, width)
    assert len(check["images"]) >= 3  # ratio curves, histogram, cost surface
    assert len(check["tables"]) >= 4 and all(table["rows"] >= 2 for table in check["tables"])
    assert "Summary per tuner" in check["headings"]
    png = screenshot(study_report, tmp_path / "study.png", width=width, height=1200)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def leaderboard(tmp_path_factory):
    import numpy as np
    import pandas as pd

    rng = np.random.default_rng(0)
    plants = [PlantTarget(f"Plant{i}-v0", 1.05, budget=35) for i in range(4)]
    rows = [{"tuner": tuner, "plant": plant.label, "seed": seed,
             "curve": np.minimum.accumulate(1.0 + rng.exponential(scale, 35)), "instant": None}
            for tuner, scale in [("my-tuner", 0.05), ("bo", 0.1), ("random", 0.4)] for plant in plants
            for seed in range(5)]
    board = Leaderboard(n_bootstrap=100).fit(pd.DataFrame(rows), plants, order=["my-tuner", "bo", "random"])
    return write_leaderboard(board, tmp_path_factory.mktemp("board"), title="Leaderboard", highlight="my-tuner")["html"]


@pytest.mark.parametrize("width", WIDTHS)
def test_leaderboard_in_chromium(leaderboard, width, tmp_path):
    check = _check_page(leaderboard, width)
    assert len(check["images"]) == 2  # the runtime ECDF over the suite and per plant
    assert len(check["tables"]) == 5 and all(table["rows"] == 4 for table in check["tables"])  # ranking, 4 plants
    assert {"Ranking", "Runtime ECDF", "Per plant"} <= set(check["headings"])
    png = screenshot(leaderboard, tmp_path / "board.png", width=width, height=1200)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
