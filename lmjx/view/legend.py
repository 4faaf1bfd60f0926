"""What makes a view's page readable alone: its title, what it shows, and a legend of its
colours (`style.SWATCHES`), as HTML: a box in the served page's side panel (`add_legend`) and
an overlay in the top left corner of an HTML export (`page_overlay`, with the page's
`<title>`: `Page`).  Nothing here draws the 3D scene."""

from __future__ import annotations

import html
from dataclasses import dataclass, field
from typing import Any

from lmjx.view import style

OVERLAY_ID = "lmjx-legend"  # the export's overlay element


@dataclass(frozen=True)
class Page:
    """A view's title, lines saying what it shows, and the legend's entries (keys of
    `style.SWATCHES`, in order)."""

    title: str
    lines: tuple[str, ...] = ()
    legend: tuple[str, ...] = field(default=())


def _swatch(key: str) -> str:
    s = style.SWATCHES[key]
    gradient = "linear-gradient(90deg, rgb(0,255,255), rgb(255,0,255))"  # the edges' colour scale
    paint = gradient if key == "edges" else s.css
    box = (f"display:inline-block;width:14px;height:14px;margin-right:6px;vertical-align:-2px;"
           f"border:1px solid rgba(0,0,0,0.35);border-radius:2px;background:{paint}")  # fmt: skip
    return (f'<div style="margin:2px 0;white-space:nowrap"><span style="{box}"></span><b>{html.escape(s.name)}</b>'
            f' <span style="opacity:0.75">{html.escape(s.meaning)}</span></div>')  # fmt: skip


def legend_html(keys: tuple[str, ...]) -> str:
    """The legend's entries as HTML (a coloured square, the name, what it is, per line)."""
    return "".join(_swatch(k) for k in keys)


def add_legend(server: Any, page: Page) -> Any:
    """The served page's legend, in the GUI panel (a folder, open), below its title."""
    gui = server.gui
    with gui.add_folder("Legend", expand_by_default=True):
        return gui.add_html(f'<div style="font-size:12px;padding:0 8px">{legend_html(page.legend)}</div>')


def page_overlay(page: Page) -> str:
    """The export's overlay: the title, its lines and the legend, in a box in the top left."""
    box = ("position:fixed;left:12px;top:12px;z-index:1000;max-width:460px;padding:10px 12px;"
           "background:rgba(255,255,255,0.92);color:#222;border-radius:6px;box-shadow:0 1px 6px rgba(0,0,0,0.25);"
           "font:12px/1.35 system-ui,-apple-system,'Segoe UI',Roboto,sans-serif;pointer-events:none")  # fmt: skip
    lines = "".join(f'<div style="opacity:0.85">{html.escape(x)}</div>' for x in page.lines)
    return (f'<div id="{OVERLAY_ID}" style="{box}"><div style="font-size:15px;font-weight:600;margin-bottom:2px">'
            f"{html.escape(page.title)}</div>{lines}"
            f'<div style="margin-top:6px">{legend_html(page.legend)}</div></div>')  # fmt: skip


def with_page(document: str, page: Page) -> str:
    """An HTML export (`<html>` with a `<title>` and a `<body>`) with the page's title and
    overlay."""
    title = f"<title>{html.escape(page.title)} - lmjx view</title>"
    start, end = document.find("<title>"), document.find("</title>")
    if 0 <= start < end:
        document = document[:start] + title + document[end + len("</title>") :]
    else:
        head = document.index("</head>")
        document = document[:head] + title + document[head:]
    at = document.rindex("</body>")
    return document[:at] + page_overlay(page) + document[at:]
