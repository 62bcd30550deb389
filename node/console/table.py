"""Text tables of the commands' results (and of the benchmarks' Markdown reports).

>>> print_table(["OC", "eps_td"], [["OC1", "0.123"], ["OC12", "-"]])
OC    eps_td
----  ------
OC1   0.123
OC12  -
>>> print_table(["x", "y"], [["1", "22"]], markdown=True)
| x | y  |
|---|----|
| 1 | 22 |
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TextIO


def table_lines(header: Sequence[str], rows: Sequence[Sequence[str]], markdown: bool = False) -> list[str]:
    """Lines of a table, each column padded to its widest cell (header included).

    Plain: columns two spaces apart, dashes under the header, no trailing spaces.
    Markdown: ``| a | b |`` rows with a ``|---|---|`` rule.
    """
    widths = [max(len(c) for c in column) for column in zip(header, *rows)]

    def plain(cells: Sequence[str]) -> str:
        return "  ".join(c.ljust(w) for c, w in zip(cells, widths)).rstrip()

    def piped(cells: Sequence[str]) -> str:
        return "| " + " | ".join(c.ljust(w) for c, w in zip(cells, widths)) + " |"

    if markdown:
        return [piped(header), "|" + "|".join("-" * (w + 2) for w in widths) + "|", *map(piped, rows)]
    return [plain(header), "  ".join("-" * w for w in widths), *map(plain, rows)]


def print_table(header: Sequence[str], rows: Sequence[Sequence[str]], *, markdown: bool = False,
                title: str | None = None, file: TextIO | None = None) -> None:
    """Print ``table_lines`` (to stdout unless ``file``); a title comes first as ``## title``."""
    if title is not None:
        print(f"\n## {title}\n", file=file)
    for line in table_lines(header, rows, markdown):
        print(line, file=file)
