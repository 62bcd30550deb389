"""Reading the mapped channels of a test cell's file: ASAM MDF4, NI TDMS or CSV.

Each reader returns, per contract channel of the map, the source's samples as they are in
the file (``Series``: times in s since the epoch, raw values, the unit the file gives, the
samples the file declares) and whether the file ends before its own structure does
(``Source.ends_early``: npTDMS's complaint about a cut TDMS file). ``asammdf`` and ``npTDMS``
are imported only when a file of theirs is read, so the node runs without them. Every failure
(a missing file, another format, a channel the file lacks, a broken or cut MDF4 file) is one
``OrdervibError`` line naming the file, or the map for what the map lacks.
"""

from __future__ import annotations

import csv
import gc
import io
import logging
import math
import os
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from node.contract import OrdervibError
from node.contract.documents import file_kind
from node.ingest.blanks import column_samples
from node.ingest.mapping import FORMATS, ChannelMap, ImportMap
from node.ingest.mdf4_blocks import cut_at

log = logging.getLogger(__name__)

MAX_FILE_BYTES = 8 << 30  # a source file of at most 8 GiB
MAX_SAMPLES = 50_000_000  # samples of one source channel at most (400 MB as float64)
MAX_COLUMNS = 100_000  # fields of a CSV line at most
SUFFIXES = {".mf4": "mf4", ".mdf": "mf4", ".tdms": "tdms", ".csv": "csv", ".txt": "csv"}
_MDF_MAGIC, _TDMS_MAGIC = b"MDF     ", b"TDSm"
_INSTALL = "pip install 'ordervib[import]'"


@dataclass(frozen=True)
class Series:
    """One source channel as the file holds it: t (n,) s since the epoch (absolute), v (n,)
    float64 raw values (NaN for a dropout), unit the file's unit string (None: none given),
    declared the samples the file's own structure says the channel has (None: it says none),
    note how its samples were picked (a CSV column's blank cells), "" if as they are."""

    t: np.ndarray
    v: np.ndarray
    unit: str | None = None
    declared: int | None = None
    note: str = ""


@dataclass(frozen=True)
class Source:
    """What a file gave: the mapped channels' ``Series`` (contract name -> series), and why the
    file ends before its own structure does (None: it does not, as far as the reader sees)."""

    series: dict[str, Series]
    ends_early: str | None = None


def source_format(path: str, fmt: str | None) -> str:
    """The format of ``path`` (``fmt``, else by its suffix), after checking that the file is a
    regular file within the size bound whose first bytes fit that format."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise OrdervibError(f"file not found: {path}") from None
    except OSError as exc:
        raise OrdervibError(f"cannot read {path}: {exc.strerror}") from None
    if not os.path.isfile(path):
        raise OrdervibError(f"{path}: is {file_kind(st.st_mode)}, not a recording file")
    if st.st_size > MAX_FILE_BYTES:
        raise OrdervibError(f"{path}: {st.st_size} bytes, more than the {MAX_FILE_BYTES >> 30} GiB read")
    if fmt is None:
        fmt = SUFFIXES.get(os.path.splitext(path)[1].lower())
        if fmt is None:
            raise OrdervibError(f"{path}: which format? name it .mf4, .tdms or .csv, or give format "
                                f"({', '.join(FORMATS)}) in the map")
    try:
        with open(path, "rb") as f:
            head = f.read(16)
    except OSError as exc:
        raise OrdervibError(f"cannot read {path}: {exc.strerror}") from None
    if fmt == "mf4" and not (head.startswith(_MDF_MAGIC) and head[8:10] == b"4."):
        raise OrdervibError(f"{path} is not an MDF4 file (no 'MDF     4.' identification block)")
    if fmt == "tdms" and not head.startswith(_TDMS_MAGIC):
        raise OrdervibError(f"{path} is not a TDMS file (no 'TDSm' lead-in)")
    if fmt == "csv" and (head.startswith(_MDF_MAGIC) or head.startswith(_TDMS_MAGIC) or b"\0" in head):
        raise OrdervibError(f"{path} is not a CSV text file")
    return fmt


def read_source(path: str, fmt: str, imap: ImportMap) -> Source:
    """Every mapped channel's ``Series``, read from ``path``, and whether the file ends early."""
    readers: dict[str, Callable[[str, ImportMap], Source]] = {
        "mf4": _read_mf4, "tdms": _read_tdms, "csv": _read_csv}
    if fmt != "mf4" and any(cm.group is not None for cm in imap.channels):
        raise OrdervibError(f"{imap.name}: group (a channel group number) is for MDF4 files only")
    if fmt != "csv" and any(cm.blank is not None for cm in imap.channels):
        raise OrdervibError(f"{imap.name}: blank (what an empty cell means) is for CSV files only")
    return readers[fmt](path, imap)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return (text[0][:200] if text else type(exc).__name__)


@contextmanager
def _quiet_unraisable() -> Iterator[None]:
    """No "Exception ignored in ..." dump on stderr from a library's finalizer in this block:
    a failed read ends in one line."""
    hook = sys.unraisablehook
    sys.unraisablehook = lambda _: None
    try:
        yield
        gc.collect()
    finally:
        sys.unraisablehook = hook


def _floats(x: Any, where: str) -> np.ndarray:
    try:
        v = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise OrdervibError(f"{where}: not a numeric channel") from None
    if v.ndim != 1:
        raise OrdervibError(f"{where}: not a channel of scalars (shape {v.shape})")
    v = v.copy()
    v[~np.isfinite(v)] = np.nan  # an infinity is no value either: a dropout
    return v


def _check_count(n: int, where: str) -> None:
    if n > MAX_SAMPLES:
        raise OrdervibError(f"{where}: {n} samples, more than the {MAX_SAMPLES} read per channel")


# -- ASAM MDF4 (asammdf)
def _read_mf4(path: str, imap: ImportMap) -> Source:
    if imap.time.column is not None or imap.time.rate is not None:
        raise OrdervibError(f"{imap.name}: an MDF4 file carries its own time (each channel group's "
                            "master): give no [time] column or rate for it")
    try:
        from asammdf import MDF
    except ImportError:
        raise OrdervibError(f"reading MDF4 needs asammdf: {_INSTALL}") from None
    cut = cut_at(path, os.path.getsize(path))
    if cut is not None:  # asammdf reads no part of it (not even with --allow-partial)
        raise OrdervibError(f"{path}: not a readable MDF4 file: it ends early, {cut} (no part of a "
                            "cut MDF4 file can be read)")
    failure = None
    with _quiet_unraisable():  # a half-built MDF object complains from its __del__
        try:
            mdf = MDF(path)
        except Exception as exc:  # a third-party parser on a broken file raises anything
            failure = _first_line(exc)
    if failure is not None:
        raise OrdervibError(f"{path}: not a readable MDF4 file ({failure})")
    out: dict[str, Series] = {}
    try:
        start = imap.time.start if imap.time.start is not None else _mf4_start(mdf.header, path)
        for cm in imap.channels:
            out[cm.channel] = _mf4_series(mdf, path, cm, start)
    finally:
        mdf.close()
    return Source(out)


def _mf4_start(header: Any, path: str) -> float:
    """The MDF4 header's start time, s since the epoch (from its UTC nanoseconds); one line when the
    file keeps a local time without its zone (the flag MDF4 allows), which no reader can place."""
    start = header.start_time
    if start.tzinfo is None:
        raise OrdervibError(f"{path}: its start time {start:%Y-%m-%d %H:%M:%S} is a local time without "
                            f"zone: give [time] start = {start:%Y-%m-%dT%H:%M:%S}+HH:MM (its zone) "
                            "in the map")
    abs_ns = getattr(header, "abs_time", None)
    return abs_ns * 1e-9 if isinstance(abs_ns, int) else float(start.timestamp())


def _mf4_series(mdf: Any, path: str, cm: ChannelMap, start: float) -> Series:
    where = f"{path}: channel {cm.source!r} (for {cm.channel})"
    entries = list(mdf.channels_db.get(cm.source, ()))
    if not entries:
        raise OrdervibError(f"{path}: no channel {cm.source!r} (mapped to {cm.channel})")
    if cm.group is not None:
        entries = [e for e in entries if e[0] == cm.group]
        if not entries:
            raise OrdervibError(f"{where}: not in channel group {cm.group}")
    if len(entries) > 1:
        groups = ", ".join(str(g) for g, _ in entries)
        raise OrdervibError(f"{where}: in channel groups {groups}: give group in the map")
    group, index = entries[0]
    declared = int(mdf.groups[group].channel_group.cycles_nr)
    _check_count(declared, where)
    try:
        sig = mdf.get(cm.source, group=group, index=index)
    except Exception as exc:  # a third-party parser on a broken file raises anything
        raise OrdervibError(f"{where}: unreadable ({_first_line(exc)})") from None
    unit = sig.unit if isinstance(sig.unit, str) else None
    return Series(t=start + np.asarray(sig.timestamps, dtype=np.float64), v=_floats(sig.samples, where),
                  unit=unit or None, declared=declared)


# -- NI TDMS (npTDMS)
def _read_tdms(path: str, imap: ImportMap) -> Source:
    try:
        from nptdms import TdmsFile
    except ImportError:
        raise OrdervibError(f"reading TDMS needs npTDMS: {_INSTALL}") from None
    out: dict[str, Series] = {}
    with _library_warnings("nptdms") as said:
        try:
            try:
                f = TdmsFile.open(path)
            except Exception as exc:  # a third-party parser on a broken file raises anything
                raise OrdervibError(f"{path}: not a readable TDMS file ({_first_line(exc)})") from None
            with f:
                for cm in imap.channels:
                    out[cm.channel] = _tdms_series(f, path, cm, imap)
        except OrdervibError as exc:
            if said:  # what the library noticed first (a cut file) tells more
                raise OrdervibError(f"{exc} (npTDMS: {said[0]})") from None
            raise
    for text in said:
        log.debug("%s: npTDMS: %s", path, text)
    return Source(out, ends_early=f"npTDMS: {said[0].split(',')[0]}" if said else None)


@contextmanager
def _library_warnings(name: str) -> Iterator[list[str]]:
    """The warnings of library logger ``name`` in this block, collected (first line each) instead
    of shown: the caller says them in its own line."""
    said: list[str] = []

    class _Collect(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            said.append(_first_line(Exception(record.getMessage())))

    handler = _Collect(logging.WARNING)
    names = [n for n in list(logging.root.manager.loggerDict) if n == name or n.startswith(name + ".")]
    loggers = [logging.getLogger(n) for n in names or [name]]  # npTDMS: a handler per module's logger
    saved = [(lg, lg.handlers[:], lg.propagate) for lg in loggers]
    for lg in loggers:
        lg.handlers, lg.propagate = [handler], False
    try:
        yield said
    finally:
        for lg, handlers, propagate in saved:
            lg.handlers, lg.propagate = handlers, propagate


def _tdms_channel(f: Any, path: str, name: str, group: Any = None) -> tuple[Any, Any]:
    """(group, channel) of ``name``: ``group/channel``, or a channel name found in one group
    (``group`` first, when given)."""
    groups = f.groups()
    for g in groups:
        if name.startswith(g.name + "/"):
            rest = name[len(g.name) + 1:]
            for c in g.channels():
                if c.name == rest:
                    return g, c
    if group is not None:
        for c in group.channels():
            if c.name == name:
                return group, c
    found = [(g, c) for g in groups for c in g.channels() if c.name == name]
    if not found:
        raise OrdervibError(f"{path}: no channel {name!r}")
    if len(found) > 1:
        where = ", ".join(g.name for g, _ in found)
        raise OrdervibError(f"{path}: channel {name!r} is in groups {where}: give it as group/channel")
    return found[0]


def _epoch(x: Any) -> float:
    """A TDMS timestamp (numpy datetime64, UTC) in s since the epoch."""
    ns = int(np.datetime64(x, "ns").astype(np.int64))
    return ns * 1e-9


def _tdms_series(f: Any, path: str, cm: ChannelMap, imap: ImportMap) -> Series:
    try:
        group, chan = _tdms_channel(f, path, cm.source)
    except OrdervibError as exc:
        raise OrdervibError(f"{exc} (mapped to {cm.channel})") from None
    where = f"{path}: channel {cm.source!r} (for {cm.channel})"
    n = len(chan)
    _check_count(n, where)
    try:
        v = _floats(chan[:], where)
        tm = imap.time
        if tm.column is not None:
            _, tchan = _tdms_channel(f, path, tm.column, group)
            tv = _floats(tchan[:], f"{path}: time channel {tm.column!r}")
            if len(tv) != n:
                raise OrdervibError(f"{where}: {n} samples, its time channel {tm.column!r} {len(tv)}")
            t = tv * tm.unit + (tm.start or 0.0)
        elif tm.rate is not None:
            if tm.start is None:
                raise OrdervibError(f"{imap.name}: [time] rate needs start (the time of the first sample)")
            t = tm.start + np.arange(n) / tm.rate
        else:
            props = chan.properties
            inc = props.get("wf_increment")
            if inc is None or not (isinstance(inc, (int, float)) and inc > 0):
                raise OrdervibError(f"{where}: no waveform timing (wf_increment): give [time] column "
                                    "or rate in the map")
            if tm.start is not None:
                start = tm.start
            elif "wf_start_time" in props:
                start = _epoch(props["wf_start_time"])
            else:
                raise OrdervibError(f"{where}: no wf_start_time: give [time] start in the map")
            start += float(props.get("wf_start_offset", 0.0))
            t = np.asarray(start + np.arange(n) * float(inc), dtype=np.float64)
    except OrdervibError:
        raise
    except Exception as exc:  # a third-party parser on a broken file raises anything
        raise OrdervibError(f"{where}: unreadable ({_first_line(exc)})") from None
    unit = chan.properties.get("unit_string")
    return Series(t=t, v=v, unit=unit if isinstance(unit, str) and unit else None)


# -- CSV
def _read_csv(path: str, imap: ImportMap) -> Source:
    tm = imap.time
    if tm.column is None and tm.rate is None:
        raise OrdervibError(f"{imap.name}: a CSV file needs [time] column (the time column's name) or "
                            "rate in the map")
    if tm.rate is not None and tm.start is None:
        raise OrdervibError(f"{imap.name}: [time] rate needs start (the time of the first row)")
    try:
        raw = open(path, encoding="utf-8-sig", newline="")  # noqa: SIM115
    except OSError as exc:
        raise OrdervibError(f"cannot read {path}: {exc.strerror}") from None
    with raw:
        try:
            return Source(_csv_columns(raw, path, imap))
        except UnicodeDecodeError:
            raise OrdervibError(f"{path}: not UTF-8 text") from None
        except csv.Error as exc:
            raise OrdervibError(f"{path}: not a CSV file ({_first_line(exc)})") from None


def _csv_columns(raw: io.TextIOBase, path: str, imap: ImportMap) -> dict[str, Series]:
    tm, spec = imap.time, imap.csv
    for _ in range(spec.skip_rows):
        raw.readline()
    csv.field_size_limit(1 << 20)
    rows = csv.reader(raw, delimiter=spec.delimiter)
    header = next(rows, None)
    if not header:
        raise OrdervibError(f"{path}: no header row (line {spec.skip_rows + 1})")
    if len(header) > MAX_COLUMNS:
        raise OrdervibError(f"{path}: {len(header)} columns, more than {MAX_COLUMNS}")
    names = [h.strip() for h in header]
    wanted = [cm.source for cm in imap.channels] + ([tm.column] if tm.column else [])
    index = {}
    for name in wanted:
        if name not in names:
            shown = ", ".join(repr(n) for n in names[:8]) + (", ..." if len(names) > 8 else "")
            whom = next((f"mapped to {cm.channel}" for cm in imap.channels if cm.source == name),
                        "[time] column")
            raise OrdervibError(f"{path}: no column {name!r} ({whom}); the header has {shown}")
        if names.count(name) > 1:
            raise OrdervibError(f"{path}: column {name!r} appears {names.count(name)} times in the header")
        index[name] = names.index(name)
    cols = sorted(set(index.values()))
    cells: list[list[str]] = [[] for _ in cols]
    width = max(cols) + 1
    line = spec.skip_rows + 1
    for row in rows:
        line += 1
        if not row or (len(row) == 1 and not row[0].strip()):
            continue  # a blank line
        if len(row) < width:
            raise OrdervibError(f"{path}: line {line} has {len(row)} fields, the header {len(names)}")
        for out, c in zip(cells, cols, strict=True):
            out.append(row[c])
        if len(cells[0]) > MAX_SAMPLES:
            raise OrdervibError(f"{path}: more than {MAX_SAMPLES} rows")
    values = {c: _csv_floats(col, spec.decimal, path, names[c]) for c, col in zip(cols, cells, strict=True)}
    n = len(cells[0])
    if tm.column is not None:
        t = values[index[tm.column]][0] * tm.unit + (tm.start or 0.0)
    else:
        assert tm.rate is not None and tm.start is not None
        t = tm.start + np.arange(n) / tm.rate
    series: dict[str, Series] = {}
    for cm in imap.channels:
        v, blank = values[index[cm.source]]
        picked, note, warn = column_samples(blank, cm.blank or spec.blank)
        if note:
            log.log(logging.WARNING if warn else logging.INFO, "%s: column %r (for %s): %s", path,
                    cm.source, cm.channel, note)
        if picked is not None:
            series[cm.channel] = Series(t=t[picked], v=v[picked], note=note)
        else:
            series[cm.channel] = Series(t=t, v=v, note="" if warn else note)
    return series


def _csv_floats(col: list[str], decimal: str, path: str, name: str) -> tuple[np.ndarray, np.ndarray]:
    """One CSV column as float64 (an empty cell, or nan, NaN) and its blank cells (bool); one-line
    error naming the first cell that is no number."""
    strs = [s.strip() or "nan" for s in col]
    blank = np.fromiter((not s.strip() for s in col), dtype=bool, count=len(col))
    if decimal == ",":
        strs = [s.replace(",", ".") for s in strs]
    try:
        v = np.array(strs, dtype=np.float64)
    except ValueError:
        for i, s in enumerate(strs):
            try:
                float(s)
            except ValueError:
                raise OrdervibError(
                    f"{path}: column {name!r}, data row {i + 1}: {s[:40]!r} is no number") from None
        raise
    v[~np.isfinite(v)] = math.nan
    return np.asarray(v, dtype=np.float64), blank
