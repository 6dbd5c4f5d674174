"""Self-contained HTML pages (the twin report, the study reports): one file, figures inline, readable on a phone.

The page declares a device-width viewport; images scale to the page width and
wide tables scroll sideways inside their own box, so nothing overflows a
390 px screen.
"""

from __future__ import annotations

import base64
import html
import io

from gbo_envs.lazy_pyplot import pyplot

__all__ = ["PAGE_STYLE", "figure_to_base64", "image_tag", "page", "scrolling"]

#: Head of every HTML page: phone-width viewport, images scaled to the page, tables that scroll.
PAGE_STYLE = (
    "<meta charset='utf-8'><meta name='viewport' content='width=device-width, initial-scale=1'>"
    "<style>"
    "body{font-family:system-ui,-apple-system,'Segoe UI',Roboto,sans-serif;line-height:1.45;color:#222;"
    "max-width:1100px;margin:auto;padding:0 12px 2em}"
    "h1{font-size:1.5em;overflow-wrap:anywhere}h2{font-size:1.2em;margin-top:1.6em;border-bottom:1px solid #ddd}"
    "p,li{overflow-wrap:anywhere}"
    "figure{margin:0.8em 0}img{display:block;max-width:100%;height:auto}"
    "figcaption{font-size:0.9em;color:#555}"
    ".grid{display:grid;grid-template-columns:repeat(auto-fill,minmax(min(100%,430px),1fr));gap:4px 12px}"
    ".grid figure{margin:0}"
    ".scroll{overflow-x:auto;-webkit-overflow-scrolling:touch;margin:0.5em 0}"
    "table{border-collapse:collapse;font-size:13px;width:max-content;max-width:none}"
    "td,th{border:1px solid #ccc;padding:3px 8px;text-align:left;vertical-align:top;max-width:26em}"
    "th{background:#f3f3f3}tr:nth-child(even) td{background:#fafafa}"
    "tr.highlight td{background:#fff2c2;font-weight:600}"
    "table.wrap{width:100%}table.wrap td{max-width:none;overflow-wrap:anywhere}"
    "pre{overflow-x:auto;background:#f6f6f6;padding:8px;font-size:12px}code{font-size:0.92em}"
    "</style>"
)


def figure_to_base64(fig, dpi: int = 100) -> str:
    """PNG of a matplotlib figure as a base64 string (the figure is closed)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    pyplot().close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def image_tag(image, alt: str, caption: str = "") -> str:
    """``<figure>`` with the image inline as a base64 PNG.

    Parameters
    ----------
    image : matplotlib Figure or bytes
        A figure (rendered and closed) or the bytes of a PNG file.
    alt : str
        Text alternative of the image.
    caption : str, optional
    """
    data = base64.b64encode(image).decode("ascii") if isinstance(image, bytes) else figure_to_base64(image)
    figcaption = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
    return f'<figure><img alt="{html.escape(alt)}" src="data:image/png;base64,{data}"/>{figcaption}</figure>'


def scrolling(table_html: str) -> str:
    """``table_html`` inside a box that scrolls sideways on a narrow screen."""
    return f"<div class='scroll'>{table_html}</div>"


def page(title: str, body: str) -> str:
    """A whole HTML document with :data:`PAGE_STYLE`."""
    return (f"<!DOCTYPE html><html lang='en'><head>{PAGE_STYLE}<title>{html.escape(title)}</title></head>"
            f"<body>\n{body}\n</body></html>\n")
