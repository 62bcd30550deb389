"""The report as a document: panels of blocks, rendered to one self-contained HTML page.

Every text goes through ``escape``; figures are embedded as base64 PNG with an 8-bit palette
(``figure_html``, ``paletted``), their smallest text checked against ``MIN_TEXT_PX``;
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
import logging
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

log = logging.getLogger(__name__)


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
    """A table of text cells: header (n,), rows (each n cells), an optional caption; groups:
    an optional first header row of (text, columns spanned); marks: per row, a CSS class per
    cell ("" none; e.g. ``better``, ``worse``).

    >>> Table(["a"], [["1"]], "c").html()
    '<table><caption>c</caption><thead><tr><th>a</th></tr></thead><tbody><tr><td>1</td></tr></tbody></table>'
    >>> t = Table(["a", "b"], [["1", "2"]], groups=[("", 1), ("g", 1)], marks=[["", "worse"]]).html()
    >>> t[:t.index("<tbody>")]
    '<table><thead><tr><th></th><th colspan="1">g</th></tr><tr><th>a</th><th>b</th></tr></thead>'
    >>> t[t.index("<tbody>"):]
    '<tbody><tr><td>1</td><td class="worse">2</td></tr></tbody></table>'
    """

    header: Sequence[str]
    rows: Sequence[Sequence[str]]
    caption: str = ""
    groups: Sequence[tuple[str, int]] = ()
    marks: Sequence[Sequence[str]] = ()

    def html(self) -> str:
        cap = f"<caption>{escape(self.caption)}</caption>" if self.caption else ""
        top = ""
        if self.groups:
            top = "<tr>" + "".join(f'<th colspan="{n}">{escape(g)}</th>' if g else "<th></th>" * n
                                   for g, n in self.groups) + "</tr>"
        head = "".join(f"<th>{escape(h)}</th>" for h in self.header)
        body = []
        for i, row in enumerate(self.rows):
            marks = self.marks[i] if i < len(self.marks) else ()
            cells = [f'<td class="{escape(marks[k])}">' if k < len(marks) and marks[k] else "<td>"
                     for k in range(len(row))]
            body.append("<tr>" + "".join(f"{td}{escape(c)}</td>" for td, c in zip(cells, row)) + "</tr>")
        return f"<table>{cap}<thead>{top}<tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


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


PAGE_WIDTH_PX = 1080  # a figure's width on the page (CSS px): a wider PNG is shown scaled down to it
MIN_TEXT_PX = 11.0  # the smallest text a figure should show on the page, CSS px


def text_sizes(fig: Any) -> list[float]:
    """The font sizes (pt) of the texts a drawn (saved) figure shows: visible, not empty, not on
    an axes turned off (its tick labels are never drawn).

    >>> from matplotlib.figure import Figure
    >>> fig = Figure(figsize=(2, 2))
    >>> ax = fig.subplots()
    >>> ax.set_title("t", fontsize=12); ax.tick_params(labelsize=7)
    Text(0.5, 1.0, 't')
    >>> fig.savefig(io.BytesIO(), format="png")  # drawn: the tick labels have their text
    >>> min(text_sizes(fig)), max(text_sizes(fig))
    (7.0, 12.0)
    """
    from matplotlib.text import Text

    out = []
    for t in fig.findobj(Text):
        ax = t.axes
        if not t.get_visible() or not t.get_text().strip() or (ax is not None and not ax.axison
                                                                 and t not in ax.texts and t is not ax.title):
            continue
        out.append(float(t.get_fontsize()))
    return out


def shown_text_px(fig: Any, png: bytes, dpi: float) -> float:
    """The smallest text of ``fig`` (drawn into ``png`` at ``dpi``) as the page shows it, CSS px:
    its size in pixels, scaled down as the page scales a PNG wider than ``PAGE_WIDTH_PX``
    (inf: no text)."""
    width = int.from_bytes(png[16:20], "big")  # the PNG's IHDR width
    sizes = text_sizes(fig)
    if not sizes or width <= 0:
        return float("inf")
    return min(sizes) * dpi / 72.0 * min(1.0, PAGE_WIDTH_PX / width)


def paletted(png: bytes, colours: int = 256) -> bytes:
    """``png`` with at most ``colours`` colours (an 8-bit palette, no dithering): a plot's lines
    and text keep their colours and the file is about a third; the original when that is no
    smaller.

    >>> from matplotlib.figure import Figure
    >>> fig = Figure(figsize=(3, 2)); _ = fig.subplots().plot([0, 1, 0.5])
    >>> buf = io.BytesIO(); fig.savefig(buf, format="png", dpi=90)
    >>> small = paletted(buf.getvalue())
    >>> len(small) < len(buf.getvalue()) and small[:8] == b"\\x89PNG\\r\\n\\x1a\\n"
    True
    """
    from PIL import Image

    with Image.open(io.BytesIO(png)) as im:
        rgb = im.convert("RGB")
    out = io.BytesIO()
    rgb.quantize(colors=colours, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(
        out, format="PNG", optimize=True)
    return out.getvalue() if out.tell() < len(png) else png


def figure_html(fig: Any, alt: str = "", dpi: int = 90) -> str:
    """A matplotlib Figure as ``<img src="data:image/png;base64,...">``; the figure is closed
    (released by pyplot when pyplot made it; a ``matplotlib.figure.Figure`` needs nothing).
    ``data-text-px`` holds its smallest text as the page shows it (``shown_text_px``); below
    ``MIN_TEXT_PX`` a warning is logged.

    >>> from matplotlib.figure import Figure
    >>> figure_html(Figure(figsize=(1, 1)), "x")[:70]
    '<img alt="x" data-text-px="inf" src="data:image/png;base64,iVBORw0KGgo'
    """
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
        png = buf.getvalue()
        px = shown_text_px(fig, png, dpi)
    finally:
        pyplot = sys.modules.get("matplotlib.pyplot")  # never imported here: it would pick a backend
        if pyplot is not None:
            pyplot.close(fig)
    if px < MIN_TEXT_PX:
        log.warning("report figure %r: its smallest text shows at %.1f px (under %g)", alt[:60], px,
                    MIN_TEXT_PX)
    data = base64.b64encode(paletted(png)).decode("ascii")
    return f'<img alt="{escape(alt)}" data-text-px="{px:.2f}" src="data:image/png;base64,{data}">'


@dataclass
class Panel:
    """One part of the report: a stable ``id`` (``panel-...``), a title, its blocks; folded
    (``fold``): its blocks in a closed ``<details>`` whose ``<summary>`` shows the title and
    ``gist``, a line of what it holds.

    >>> Panel("p", "T", [Paragraph("x")], gist="g").html().splitlines()[1:3]
    ['<details>', '<summary><h2>T</h2> <span class="gist">g</span></summary>']
    """

    id: str
    title: str
    blocks: list[Block] = field(default_factory=list)
    gist: str = ""
    fold: bool = True

    def html(self) -> str:
        inner = "\n".join(b.html() for b in self.blocks)
        head = f"<h2>{escape(self.title)}</h2>"
        if not self.fold:
            return f'<section id="{escape(self.id)}">\n{head}\n{inner}\n</section>'
        gist = f' <span class="gist">{escape(self.gist)}</span>' if self.gist else ""
        return (f'<section id="{escape(self.id)}">\n<details>\n<summary>{head}{gist}</summary>\n'
                f"{inner}\n</details>\n</section>")


CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; margin: 0 auto;
       max-width: 1200px; padding: 1em 2em; color: #1d1d1f; background: #fff; }
h1 { font-size: 1.6em; border-bottom: 2px solid #335; padding-bottom: .2em; }
h2 { font-size: 1.3em; margin-top: 0; color: #224; }
h3 { font-size: 1.1em; margin: 1.2em 0 .4em; }
section { border: 1px solid #ccd; border-radius: 6px; padding: .8em 1.5em; margin: 1em 0; }
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
details > summary { cursor: pointer; }
details > summary h2 { display: inline; }
details[open] > summary { margin-bottom: .8em; }
span.gist { color: #555; margin-left: .6em; }
#verdict h3 { margin: .6em 0 .2em; font-size: 1.25em; }
#verdict table { font-size: .85em; margin: .2em 0 .6em; }
#verdict caption { font-weight: normal; color: #444; }
#summary h3 { margin: .8em 0 .2em; }
#summary p { margin: .2em 0 .3em; }
#summary table { font-size: .8em; margin: .2em 0 .6em; }
#summary th, #summary td { padding: .1em .5em; }
#summary caption { font-weight: normal; color: #444; }
#summary td:nth-child(2), #summary thead tr:last-child th:nth-child(2) { text-align: left; }
td.better { background: #e1f3e1; }
td.worse { background: #fbe1dd; }
td.pass { background: #c6efc6; font-weight: 600; }
td.fail { background: #f6c1b8; font-weight: 600; }
td.alarm { background: #ffe9a8; font-weight: 600; }
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
