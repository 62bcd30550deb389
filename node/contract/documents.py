"""ordervib's own versioned JSON files (the engine-history state, a model's kept training
runs): parsed and checked in one place, every fault a one-line ``OrdervibError``."""

from __future__ import annotations

import json
from typing import Any

from node.contract.errors import OrdervibError


def parse_document(text: str, fmt: str, version: int, where: str, kind: str,
                   version_key: str = "version") -> dict[str, Any]:
    """The JSON object in ``text`` whose ``format`` is ``fmt`` and whose ``version_key`` is
    ``version``; else an ``OrdervibError`` "<where>: ..." (``kind`` names the file's kind).

    >>> parse_document('{"format": "f", "version": 1, "x": 2}', "f", 1, "a.json", "test")["x"]
    2
    >>> parse_document('{"format": "g"}', "f", 1, "a.json", "test")
    Traceback (most recent call last):
    node.contract.errors.OrdervibError: a.json: not an ordervib test file
    """
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise OrdervibError(f"{where}: not valid JSON ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != fmt:
        raise OrdervibError(f"{where}: not an ordervib {kind} file")
    if doc.get(version_key) != version:
        raise OrdervibError(f"{where}: version {doc.get(version_key)!r} is not supported "
                            f"(this ordervib reads {version})")
    return doc
