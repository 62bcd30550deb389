"""The engine-history state file: each bed's :class:`EngineState`, kept across node restarts.

To know an engine's shutdown time the node needs the end of its previous run, which may
have been seen by a node that has stopped since. ``ordervib run`` loads this file at start
and keeps it up to date (every ``SAVE_EVERY_S`` when something changed, and on the way
out); ``ordervib replay`` can read one (the history before the recording). JSON, written
to a temporary file beside it and moved over it (``os.replace``), so a reader or a crash
never sees half a file::

    {"format": "ordervib-engine-history", "version": 1,
     "beds": {"b1": {"last_on_t": 1767602968.9, "energy": 65697.2, "shutdown_h": 0.18,
                     "thermal": 112.73, "rate": 19458.6}}}
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path

from node.contract.documents import parse_document
from node.contract.errors import OrdervibError
from node.runtime.history import EngineState

FORMAT = "ordervib-engine-history"
VERSION = 1
SAVE_EVERY_S = 10.0


def load_engine_states(path: str | os.PathLike) -> dict[str, EngineState]:
    """Each bed's engine state; an absent file is no history ({}), a malformed one an
    OrdervibError naming the file and what is wrong."""
    p = Path(path)
    try:
        text = p.read_text()
    except FileNotFoundError:
        return {}
    except (OSError, UnicodeDecodeError) as exc:
        raise OrdervibError(f"engine state {p}: cannot be read ({exc})") from None
    doc = parse_document(text, FORMAT, VERSION, f"engine state {p}", "engine-history")
    beds = doc.get("beds")
    if not isinstance(beds, dict):
        raise OrdervibError(f"engine state {p}: 'beds' must be an object")
    out = {}
    for name, d in beds.items():
        try:
            out[str(name)] = EngineState.from_dict(d)
        except ValueError as exc:
            raise OrdervibError(f"engine state {p}: bed {name!r}: {exc}") from None
    return out


def engine_document(states: Mapping[str, EngineState]) -> dict:
    return {"format": FORMAT, "version": VERSION,
            "beds": {name: s.to_dict() for name, s in sorted(states.items())}}


def save_engine_states(path: str | os.PathLike, states: Mapping[str, EngineState]) -> None:
    """Replace the file atomically with ``states`` (OSError on failure; the old file stays)."""
    p = Path(path)
    tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "w") as f:
            json.dump(engine_document(states), f, indent=1)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, p)
    finally:
        if tmp.exists():
            tmp.unlink()


def check_engine_file(path: str | os.PathLike) -> dict[str, EngineState]:
    """Before a command opens any output: the file loads (or is absent) and its folder exists."""
    p = Path(path)
    if p.is_dir():
        raise OrdervibError(f"--engine-state {p} is a directory, not a file")
    if not p.parent.is_dir():
        raise OrdervibError(f"--engine-state {p}: folder {p.parent} does not exist")
    return load_engine_states(p)
