"""The engine-history state file: each bed's :class:`EngineState`, kept across node restarts.

To know an engine's shutdown time the node needs the end of its previous run, which may
have been seen by a node that has stopped since. ``ordervib run`` loads this file at start
and keeps it up to date (every ``SAVE_EVERY_S`` when something changed, and on the way
out); ``ordervib replay`` can read one (the history before the recording). JSON, written
to a temporary file beside it and moved over it (``os.replace``), so a reader or a crash
never sees half a file. The file keeps its mode (a read-only one stays read-only); only a
regular file is read or replaced: a FIFO, a device or a folder is refused in one line before
the node starts (reading a FIFO would wait for a writer forever), as is a file that cannot be
replaced (immutable, a read-only folder). A save that fails while the node runs shows in its
health (``engine_state: false``) and in ``ordervib run``'s exit status::

    {"format": "ordervib-engine-history", "version": 1,
     "beds": {"b1": {"last_on_t": 1767602968.9, "energy": 65697.2, "shutdown_h": 0.18,
                     "thermal": 112.73, "rate": 19458.6}}}
"""

from __future__ import annotations

import json
import os
import stat
from collections.abc import Mapping
from pathlib import Path

from node.contract.documents import file_kind, parse_document, read_document
from node.contract.errors import OrdervibError
from node.runtime.history import EngineState

FORMAT = "ordervib-engine-history"
VERSION = 1
SAVE_EVERY_S = 10.0
MAX_BYTES = 1 << 20  # the file: about 200 bytes a bed


def load_engine_states(path: str | os.PathLike) -> dict[str, EngineState]:
    """Each bed's engine state; an absent file is no history ({}), a malformed one an
    OrdervibError naming the file and what is wrong."""
    p = Path(path)
    try:
        text = read_document(p, f"engine state {p}", MAX_BYTES)  # a regular file only: no FIFO wait
    except FileNotFoundError:
        return {}
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


def load_given_engine_states(path: str, option: str = "--engine-state") -> dict[str, EngineState]:
    """``load_engine_states`` of a file a command is given as input: it must exist (one line)."""
    if not os.path.exists(path):  # (a FIFO or a folder: refused by the loader, in one line)
        raise OrdervibError(f"{option} {path}: no such file")
    return load_engine_states(path)


def engine_document(states: Mapping[str, EngineState]) -> dict:
    return {"format": FORMAT, "version": VERSION,
            "beds": {name: s.to_dict() for name, s in sorted(states.items())}}


def save_engine_states(path: str | os.PathLike, states: Mapping[str, EngineState]) -> None:
    """Replace the file atomically with ``states``, keeping its mode (OSError on failure, or
    when the path is not a regular file; the old file stays)."""
    p = Path(path)
    try:
        old: os.stat_result | None = os.stat(p)
    except FileNotFoundError:
        old = None
    if old is not None and not stat.S_ISREG(old.st_mode):
        raise OSError(f"{p} is {file_kind(old.st_mode)}, not a regular file: not replaced")
    tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "w") as f:
            json.dump(engine_document(states), f, indent=1)
            f.flush()
            if old is not None:  # the file's mode, not the umask's (a read-only one stays so)
                os.fchmod(f.fileno(), stat.S_IMODE(old.st_mode))
            os.fsync(f.fileno())
        os.replace(tmp, p)
    finally:
        if tmp.exists():
            tmp.unlink()


def check_engine_file(path: str | os.PathLike) -> dict[str, EngineState]:
    """Before a command opens any output: the file is a regular one and loads (or is absent),
    its folder exists, and it can be saved: an existing file is saved again with what it holds
    (an immutable one fails here), a new one is tried in its folder (and removed)."""
    p = Path(path)
    if p.is_dir():
        raise OrdervibError(f"--engine-state {p} is a directory, not a file")
    if not p.parent.is_dir():
        raise OrdervibError(f"--engine-state {p}: folder {p.parent} does not exist")
    states = load_engine_states(p)
    try:
        if p.exists():
            save_engine_states(p, states)
        else:
            tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
            tmp.touch()
            tmp.unlink()
    except OSError as exc:
        raise OrdervibError(f"--engine-state {p} cannot be saved ({exc.strerror or exc})") from None
    return states
