"""Markdown reports: their tables, and each as one self-contained HTML page beside it.

The study reports (:mod:`evaluation.report`), the comparison tables (:mod:`evaluation.comparison`) and the
leaderboard (:mod:`evaluation.leaderboard`) are written as Markdown, to be read on GitHub;
:func:`write_html` renders one as a page with its figures inline and tables that scroll on a phone
(:mod:`agents.html_page`).
"""

from __future__ import annotations

import html
import math
import re
from pathlib import Path

import numpy as np
from markdown_it import MarkdownIt

from agents.html_page import image_tag, page, scrolling
from gbo_envs.atomic_write import atomic_write

__all__ = ["markdown_table", "write_html"]


def markdown_table(headers: list[str], rows: list[list]) -> str:
    """A GitHub Markdown table; floats to 4 significant digits (one decimal from 1000), NaN/None as a dash."""
    def cell(value) -> str:
        if value is None or (isinstance(value, float) and math.isnan(value)):
            return "—"
        if isinstance(value, (float, np.floating)):
            return f"{value:.4g}" if abs(value) < 1e3 else f"{value:.1f}"
        return str(value).replace("|", "\\|")

    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def write_html(markdown_path: Path | str, title: str = "", highlight: str | None = None) -> Path:
    """Write the Markdown report as one self-contained HTML page beside it (``report.html``).

    Images linked relatively are inlined as base64 PNG; every table scrolls
    sideways inside its own box on a narrow screen.

    Parameters
    ----------
    markdown_path : Path or str
        The ``report.md`` of a study.
    title : str, optional
        Title of the page (default: the file's folder name).
    highlight : str, optional
        A name written in bold (``**name**``) at the start of a table cell: the rows holding it get the
        class ``highlight`` (shaded, :data:`agents.html_page.PAGE_STYLE`).

    Returns
    -------
    Path
        The ``.html`` file.
    """
    markdown_path = Path(markdown_path)
    body = MarkdownIt("commonmark").enable("table").render(markdown_path.read_text(encoding="utf-8"))

    def inline(match: re.Match) -> str:
        src, alt = html.unescape(match.group(1)), html.unescape(match.group(2))
        image = markdown_path.parent / src
        if "://" in src or not image.is_file():
            raise ValueError(f"{markdown_path}: image {src!r} is not a file beside the report")
        return image_tag(image.read_bytes(), alt)

    body = re.sub(r'<p><img src="([^"]*)" alt="([^"]*)" /></p>', inline, body)
    if highlight:
        bold = re.escape(f"<td><strong>{html.escape(highlight)}</strong>")
        body = re.sub(rf"<tr>(?=(?:(?!</tr>).)*{bold})", "<tr class='highlight'>", body, flags=re.S)
    body = re.sub(r"<table>.*?</table>", lambda m: scrolling(m.group(0)), body, flags=re.S)
    path = markdown_path.with_suffix(".html")
    with atomic_write(path) as handle:
        handle.write(page(title or markdown_path.parent.name, body))
    return path
