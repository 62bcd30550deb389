"""A command's result on stdout: text lines and tables, or one JSON object (``--json``).

Status and progress go to stderr through ``logging`` (``node.cli.logs``); what a command
found or wrote is its result. With ``--json`` the result is one JSON object printed when the
command ends (NaN and infinities as null), never a Python repr.

>>> r = Results(as_json=True)
>>> r.table("ocs", ["OC", "eps"], [["OC1", "0.120"], ["OC2", "-"]])
>>> r.line("wrote x.csv", "out", "x.csv")
>>> r.done()
{
  "ocs": [
    {
      "OC": "OC1",
      "eps": 0.12
    },
    {
      "OC": "OC2",
      "eps": null
    }
  ],
  "out": "x.csv"
}
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Sequence
from typing import Any

from node.console.table import print_table

JSON_HELP = "print the result on stdout as one JSON object instead of text"


def add_json_option(p: argparse.ArgumentParser) -> None:
    """The ``--json`` option of a command whose result a script reads."""
    p.add_argument("--json", action="store_true", help=JSON_HELP)


def plain(value: Any) -> Any:
    """``value`` with every non-finite float as None and tuples as lists: valid JSON."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if hasattr(value, "item") and callable(value.item):  # a numpy scalar
        return plain(value.item())
    return value


def print_json(value: Any) -> None:
    """``value`` on stdout as indented JSON (``plain``)."""
    print(json.dumps(plain(value), indent=2, allow_nan=False))


def cell(text: str) -> Any:
    """A table cell as JSON takes it: a number when it reads as one, None for "-", else the text.

    >>> cell("12"), cell("0.5"), cell("-"), cell("12.5 %")
    (12, 0.5, None, '12.5 %')
    """
    if text == "-":
        return None
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


class Results:
    """A command's result: printed as it comes (text), or kept and printed by ``done`` as one
    JSON object (``as_json``), each part under its key."""

    def __init__(self, as_json: bool = False) -> None:
        self.as_json = as_json
        self.data: dict[str, Any] = {}

    def line(self, text: str, key: str | None = None, value: Any = None) -> None:
        """A line of text; as JSON, ``value`` under ``key`` (no key: the text among "notes")."""
        if not self.as_json:
            print(text)
        elif key is None:
            self.data.setdefault("notes", []).append(text)
        else:
            self.data[key] = value

    def value(self, key: str, value: Any) -> None:
        """A part of the JSON object alone (the text says it otherwise, or not at all)."""
        if self.as_json:
            self.data[key] = value

    def table(self, key: str, header: Sequence[str], rows: Sequence[Sequence[str]]) -> None:
        """A table; as JSON, a list of objects (header -> ``cell``; the first column, the row's
        name, as text) under ``key``."""
        if not self.as_json:
            print_table(header, rows)
        else:
            self.data[key] = [{h: c if j == 0 else cell(c) for j, (h, c) in enumerate(zip(header, row))}
                              for row in rows]

    def done(self) -> None:
        """As JSON: the object, printed once."""
        if self.as_json:
            print_json(self.data)
