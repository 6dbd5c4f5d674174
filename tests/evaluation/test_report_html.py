"""``report.html`` of a study: the Markdown report as one self-contained page."""

from __future__ import annotations

import base64

import pytest

from evaluation.report import write_html

PNG = b"\x89PNG\r\n\x1a\n" + b"1" * 16


def test_html_inlines_the_figures_and_scrolls_the_tables(tmp_path):
    (tmp_path / "curves.png").write_bytes(PNG)
    md = tmp_path / "report.md"
    md.write_text("# Title\n\n| a | b |\n|---|---|\n| 1 | 2 |\n\n![ratio curves](curves.png)\n", encoding="utf-8")
    page = write_html(md, title="a study").read_text(encoding="utf-8")
    assert "<title>a study</title>" in page and "width=device-width" in page
    assert f'<img alt="ratio curves" src="data:image/png;base64,{base64.b64encode(PNG).decode()}"/>' in page
    assert "curves.png" not in page
    assert "<div class='scroll'><table>" in page and "<td>2</td>" in page


def test_html_refuses_a_missing_figure(tmp_path):
    md = tmp_path / "report.md"
    md.write_text("![gone](gone.png)\n", encoding="utf-8")
    with pytest.raises(ValueError, match="gone.png"):
        write_html(md)
