"""The report as a document: panels of blocks, rendered to one self-contained HTML page.

Every text goes through ``escape``; figures are embedded as base64 PNG (``figure_html``);
the page holds its own CSS and no script, and names no external URL, so it opens from a
file with no server and no network.

>>> p = Panel("panel-x", "I. A <title>", [Heading("yB"), Paragraph("a & b"),
...           Table(["OC", "eps_td"], [["OC3", "0.12"]])])
>>> html = render_document("Report", [p])
>>> '<section id="panel-x">' in html and "<h2>I. A &lt;title&gt;</h2>" in html
True
>>> "<p>a &amp; b</p>" in html and "<td>OC3</td>" in html and "http" not in html.lower()
True
"""

from __future__ import annotations

import base64
import html
import io
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any


def escape(text: object) -> str:
    """``text`` as HTML text (``&``, ``<``, ``>``, quotes escaped).

    >>> escape('a < b & "c"')
    'a &lt; b &amp; &quot;c&quot;'
    """
    return html.escape(str(text), quote=True)


@dataclass(frozen=True)
class Heading:
    """A sub-heading inside a panel (``<h3>``; level 4 for a finer one)."""

    text: str
    level: int = 3

    def html(self) -> str:
        n = min(max(self.level, 3), 6)
        return f"<h{n}>{escape(self.text)}</h{n}>"


@dataclass(frozen=True)
class Paragraph:
    """A paragraph of plain text; ``note`` marks it as a remark (e.g. something pending)."""

    text: str
    note: bool = False

    def html(self) -> str:
        cls = ' class="note"' if self.note else ""
        return f"<p{cls}>{escape(self.text)}</p>"


@dataclass(frozen=True)
class Table:
    """A table of text cells: header (n,), rows (each n cells), an optional caption.

    >>> Table(["a"], [["1"]], "c").html()
    '<table><caption>c</caption><thead><tr><th>a</th></tr></thead><tbody><tr><td>1</td></tr></tbody></table>'
    """

    header: Sequence[str]
    rows: Sequence[Sequence[str]]
    caption: str = ""

    def html(self) -> str:
        cap = f"<caption>{escape(self.caption)}</caption>" if self.caption else ""
        head = "".join(f"<th>{escape(h)}</th>" for h in self.header)
        body = "".join("<tr>" + "".join(f"<td>{escape(c)}</td>" for c in row) + "</tr>"
                       for row in self.rows)
        return f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


@dataclass(frozen=True)
class Figure:
    """An embedded image (``figure_html``'s ``<img>``) with a caption."""

    img: str
    caption: str = ""

    @classmethod
    def of(cls, fig: Any, caption: str = "", dpi: int = 90) -> Figure:
        """From a matplotlib Figure (closed afterwards)."""
        return cls(figure_html(fig, caption, dpi), caption)

    def html(self) -> str:
        cap = f"<figcaption>{escape(self.caption)}</figcaption>" if self.caption else ""
        return f"<figure>{self.img}{cap}</figure>"


Block = Heading | Paragraph | Table | Figure  # what a panel holds, in order


def figure_html(fig: Any, alt: str = "", dpi: int = 90) -> str:
    """A matplotlib Figure as ``<img src="data:image/png;base64,...">``; the figure is closed
    (released by pyplot when pyplot made it; a ``matplotlib.figure.Figure`` needs nothing).

    >>> from matplotlib.figure import Figure
    >>> figure_html(Figure(figsize=(1, 1)), "x").startswith('<img alt="x" src="data:image/png;base64,iVBOR')
    True
    """
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    finally:
        pyplot = sys.modules.get("matplotlib.pyplot")  # never imported here: it would pick a backend
        if pyplot is not None:
            pyplot.close(fig)
    data = base64.b64encode(buf.getvalue()).decode("ascii")
    return f'<img alt="{escape(alt)}" src="data:image/png;base64,{data}">'


@dataclass
class Panel:
    """One numbered part of the report: a stable ``id`` (``panel-...``), a title, its blocks."""

    id: str
    title: str
    blocks: list[Block] = field(default_factory=list)

    def html(self) -> str:
        inner = "\n".join(b.html() for b in self.blocks)
        return f'<section id="{escape(self.id)}">\n<h2>{escape(self.title)}</h2>\n{inner}\n</section>'


CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; margin: 0 auto;
       max-width: 1200px; padding: 1em 2em; color: #1d1d1f; background: #fff; }
h1 { font-size: 1.6em; border-bottom: 2px solid #335; padding-bottom: .2em; }
h2 { font-size: 1.3em; margin-top: 0; color: #224; }
h3 { font-size: 1.1em; margin: 1.2em 0 .4em; }
section { border: 1px solid #ccd; border-radius: 6px; padding: 1em 1.5em; margin: 1.5em 0; }
nav a { margin-right: 1.2em; }
dl.meta { display: grid; grid-template-columns: max-content auto; gap: .2em 1em; font-size: .9em; }
dl.meta dt { font-weight: 600; }
dl.meta dd { margin: 0; font-family: ui-monospace, monospace; }
table { border-collapse: collapse; font-size: .85em; margin: .5em 0 1em; }
caption { text-align: left; font-weight: 600; padding: .3em 0; }
th, td { border: 1px solid #ccd; padding: .2em .6em; text-align: right; }
th { background: #eef; }
td:first-child, th:first-child { text-align: left; }
figure { margin: .5em 0 1em; }
figure img { max-width: 100%; height: auto; }
figcaption { font-size: .85em; color: #444; }
p.note { background: #fff6d5; border-left: 4px solid #e0b000; padding: .4em .8em; }
"""


def render_document(title: str, panels: Sequence[Panel], meta: Sequence[tuple[str, str]] = ()) -> str:
    """The whole HTML page: title, a line of links to the panels, ``meta`` (label, value) pairs,
    then each panel as a ``<section id=...>``."""
    nav = " ".join(f'<a href="#{escape(p.id)}">{escape(p.title)}</a>' for p in panels)
    dl = "".join(f"<dt>{escape(k)}</dt><dd>{escape(v)}</dd>" for k, v in meta)
    body = "\n".join(p.html() for p in panels)
    return (f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
            f"<title>{escape(title)}</title>\n<style>{CSS}</style>\n</head>\n<body>\n"
            f"<h1>{escape(title)}</h1>\n<nav>{nav}</nav>\n"
            f'<dl class="meta">{dl}</dl>\n{body}\n</body>\n</html>\n')
