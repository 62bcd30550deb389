"""The import map (MAP.toml): which source channel becomes which contract channel, in which
unit, on which clock; read bounded and checked whole before any file is opened.

The format is documented in ``docs/import.md``. A bad map is one ``OrdervibError`` line that
names the map and the key.

>>> m = parse_map({"bed": "cell3", "time": {"column": "Time", "start": 1767600000},
...                "channels": {"nB": {"source": "IP speed", "unit": "rad/s"},
...                             "yB": {"source": "IP 1x", "unit": "in/s", "detection": "rms"}}})
>>> m.bed, m.time.column, [c.channel for c in m.channels]
('cell3', 'Time', ['nB', 'yB'])
>>> round(m.channels[1].affine(None)[0], 6)  # in/s rms -> mm/s peak
35.921024
>>> try:
...     parse_map({"bed": "cell3", "channels": {"nX": {"source": "a"}}}, "m.toml")
... except OrdervibError as exc:
...     print(str(exc)[:50])
m.toml: [channels.nX]: not a contract channel (nA,
"""

from __future__ import annotations

import datetime as dt
import math
import os
import stat
import tomllib
from dataclasses import dataclass, field
from typing import Any

from node.contract import (
    CHANNEL_UNITS,
    PHASE_CHANNELS,
    RUN_GAP,
    SENSOR_CHANNELS,
    OrdervibError,
    is_name,
    is_phase_channel,
)
from node.contract.documents import file_kind, read_bounded
from node.ingest.units import conversion, detection_factor, same_unit

MAX_MAP_BYTES = 64 * 1024  # a map file is small text
MAX_SOURCE_CHARS = 256  # a source channel's name (or group/channel path)
MAX_SKIP_ROWS = 1000  # CSV lines before the header
MAX_RATE = 1e6  # Hz, a sample rate given in the map
FORMATS = ("mf4", "tdms", "csv")
CHANNELS: tuple[str, ...] = SENSOR_CHANNELS + PHASE_CHANNELS  # the names a map may write
TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}  # seconds per unit
DEFAULT_MAX_GAP = 1.0  # s: no value is interpolated between source samples further apart
# what a blank CSV cell means: auto (not sampled in a column that has a value every k-th row,
# k >= 2, i.e. its own rate; else null), null (a dropout, written null), not-sampled (no sample:
# the column is resampled from its other rows)
BLANKS = ("auto", "null", "not-sampled")
_TOP = {"bed", "format", "time", "channels", "csv"}
_TIME = {"column", "rate", "start", "unit", "max_gap"}
_CHANNEL = {"source", "unit", "override", "scale", "offset", "detection", "convention", "group",
            "max_gap", "blank"}
_CSV = {"delimiter", "decimal", "skip_rows", "blank"}


@dataclass(frozen=True)
class TimeSpec:
    """Where the samples' times come from.

    column: a time channel (CSV column; TDMS channel, ``group/channel`` or one in the same
    group as each source); rate: Hz, sample i at start + i / rate (instead of a column);
    start: s since the epoch added to the times (None: the file's own start, MDF4's header or
    TDMS's ``wf_start_time``; 0 for a CSV time column, whose times are then epoch seconds);
    unit: seconds per unit of the time column; max_gap: s, the widest step between two source
    samples that is interpolated over (below the contract's 60 s run gap).
    """

    column: str | None = None
    rate: float | None = None
    start: float | None = None
    unit: float = 1.0
    max_gap: float = DEFAULT_MAX_GAP


@dataclass(frozen=True)
class ChannelMap:
    """One contract channel and where it comes from.

    source: the channel's name in the file (TDMS: ``channel`` or ``group/channel``); unit: its
    named unit (None: the file's, else the contract's); override: the map's unit wins over
    another one the file states (else that is an error); scale, offset: contract value =
    source x scale + offset (instead of a unit); detection: an order amplitude's (peak, rms,
    pk-pk); convention: a phase's (lag as the contract, or lead); group: the MDF4 channel
    group, for a name in several; max_gap: s, this channel's (None: the map's); blank: what
    a blank CSV cell of it means (``BLANKS``; None: the map's ``[csv] blank``).
    """

    channel: str
    source: str
    unit: str | None = None
    scale: float | None = None
    offset: float = 0.0
    detection: str = "peak"
    convention: str = "lag"
    group: int | None = None
    max_gap: float | None = None
    override: bool = False
    blank: str | None = None

    def source_unit(self, file_unit: str | None) -> str | None:
        """The unit the source's values are in: the map's, else the file's (None: the contract's,
        or ``scale`` gives the conversion). One-line error when the map names a unit and the file
        states another (by name: rpm and RPM are one unit) and the map does not say ``override``."""
        if self.scale is not None:
            return None
        file_unit = (file_unit or "").strip() or None
        if self.unit is None:
            return file_unit
        if file_unit is not None and not self.override and not same_unit(self.channel, self.unit, file_unit):
            raise OrdervibError(f"the map says unit {self.unit!r}, the file says {file_unit!r}: correct "
                                "the map, or add override = true to its [channels."
                                f"{self.channel}] if its unit is the right one")
        return self.unit

    def affine(self, file_unit: str | None) -> tuple[float, float]:
        """(scale, offset) from the source's values to the contract's unit; ``file_unit``: the
        unit the file gives the source (None or "": none). One-line error for an unknown unit,
        or for one the file contradicts (``source_unit``)."""
        if self.scale is not None:
            a, b = self.scale, self.offset
        else:
            unit = self.source_unit(file_unit) or CHANNEL_UNITS[self.channel]
            a, b = conversion(self.channel, unit.strip())
        if self.channel not in PHASE_CHANNELS and self.detection != "peak":
            k = detection_factor(self.channel, self.detection)
            a, b = a * k, b * k
        if self.convention == "lead":
            a, b = -a, -b
        return a, b


@dataclass(frozen=True)
class CsvSpec:
    """How a CSV export is laid out: one header row of names after ``skip_rows`` lines."""

    delimiter: str = ","
    decimal: str = "."
    skip_rows: int = 0
    blank: str = "auto"


@dataclass(frozen=True)
class ImportMap:
    """A whole import map: the bed written, the source format (None: by the file's suffix), the
    clock, the channels (contract order), the CSV layout and the map's own name (its path, for
    messages)."""

    bed: str
    channels: tuple[ChannelMap, ...]
    format: str | None = None
    time: TimeSpec = field(default_factory=TimeSpec)
    csv: CsvSpec = field(default_factory=CsvSpec)
    name: str = "map"


def load_map(path: str | os.PathLike) -> ImportMap:
    """Read and check MAP.toml (at most 64 KiB); one-line ``OrdervibError`` for a bad one."""
    name = os.fspath(path)
    try:
        mode = os.stat(name).st_mode
    except FileNotFoundError:
        raise OrdervibError(f"map file not found: {name}") from None
    except OSError as exc:
        raise OrdervibError(f"map {name}: cannot be read ({exc.strerror})") from None
    if stat.S_ISDIR(mode):
        raise OrdervibError(f"map {name}: is {file_kind(mode)}, not a map file (MAP.toml)")
    try:  # a regular file of at most 64 KiB (a FIFO or a device is refused without waiting)
        raw = read_bounded(name, f"map {name}", MAX_MAP_BYTES)
    except FileNotFoundError:
        raise OrdervibError(f"map file not found: {name}") from None
    try:
        doc = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise OrdervibError(f"{name}: not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise OrdervibError(f"{name}: not valid TOML ({exc})") from None
    return parse_map(doc, name)


def _fail(where: str, what: str) -> OrdervibError:
    return OrdervibError(f"{where}: {what}")


def _keys(d: Any, allowed: set[str], where: str) -> dict[str, Any]:
    if not isinstance(d, dict):
        raise _fail(where, "must be a table")
    unknown = sorted(set(d) - allowed)
    if unknown:
        raise _fail(where, f"unknown key {unknown[0]!r} (known: {', '.join(sorted(allowed))})")
    return d


def _number(d: dict[str, Any], key: str, where: str, lo: float, hi: float,
            open_lo: bool = False) -> float | None:
    if key not in d:
        return None
    x = d[key]
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(float(x)):
        raise _fail(where, f"{key} must be a finite number, got {x!r}")
    x = float(x)
    if not (lo < x if open_lo else lo <= x) or x > hi:
        raise _fail(where, f"{key} must be {'>' if open_lo else '>='} {lo:g} and <= {hi:g}, got {x:g}")
    return x


def _text(d: dict[str, Any], key: str, where: str, choices: tuple[str, ...] | None = None,
          max_chars: int = MAX_SOURCE_CHARS) -> str | None:
    if key not in d:
        return None
    x = d[key]
    if not isinstance(x, str) or len(x) > max_chars:
        raise _fail(where, f"{key} must be a string of at most {max_chars} characters")
    if choices is not None and x not in choices:
        raise _fail(where, f"{key} must be one of {', '.join(choices)}, got {x!r}")
    return x


def _start(x: Any, where: str) -> float:
    """The time origin: epoch seconds, or a date-time with its zone (TOML or ISO 8601 text)."""
    if isinstance(x, str):
        try:
            x = dt.datetime.fromisoformat(x)
        except ValueError:
            raise _fail(where, f"start {x!r} is no ISO 8601 date-time") from None
    if isinstance(x, dt.datetime):
        if x.tzinfo is None:
            raise _fail(where, "start needs its zone (e.g. 2026-01-05T08:00:00Z): a local time is ambiguous")
        return x.timestamp()
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not (0 <= float(x) < 1e11):
        raise _fail(where, f"start must be s since the epoch or a date-time with zone, got {x!r}")
    return float(x)


def _time(d: Any, where: str) -> TimeSpec:
    d = _keys(d, _TIME, where)
    column = _text(d, "column", where)
    rate = _number(d, "rate", where, 0.0, MAX_RATE, open_lo=True)
    if column is not None and rate is not None:
        raise _fail(where, "give column or rate, not both")
    unit = _text(d, "unit", where, tuple(TIME_UNITS)) or "s"
    gap = _number(d, "max_gap", where, 0.0, RUN_GAP, open_lo=True)
    if gap is not None and gap >= RUN_GAP:
        raise _fail(where, f"max_gap must be below the contract's run gap of {RUN_GAP:g} s")
    return TimeSpec(column=column or None, rate=rate,
                    start=None if "start" not in d else _start(d["start"], where),
                    unit=TIME_UNITS[unit], max_gap=DEFAULT_MAX_GAP if gap is None else gap)


def _channel(name: str, d: Any, where: str) -> ChannelMap:
    if name not in CHANNELS:
        raise _fail(where, f"not a contract channel ({', '.join(CHANNELS)})")
    d = _keys(d, _CHANNEL, where)
    source = _text(d, "source", where)
    if not source:
        raise _fail(where, "source (the channel's name in the file) is missing")
    unit = _text(d, "unit", where, max_chars=32)
    scale = _number(d, "scale", where, -1e12, 1e12)
    offset = _number(d, "offset", where, -1e12, 1e12)
    if unit is not None and (scale is not None or offset is not None):
        raise _fail(where, "give unit, or scale and offset, not both")
    if offset is not None and scale is None:
        raise _fail(where, "offset needs scale")
    if scale == 0.0:
        raise _fail(where, "scale must not be 0")
    detection = _text(d, "detection", where, ("peak", "rms", "pk-pk"))
    if detection is not None:
        try:  # an order amplitude's only
            detection_factor(name, detection)
        except OrdervibError as exc:
            raise _fail(where, str(exc)) from None
    convention = _text(d, "convention", where, ("lag", "lead"))
    if convention is not None and not is_phase_channel(name):
        raise _fail(where, "convention (lag or lead) is for the phase channels only")
    group = d.get("group")
    if group is not None and (isinstance(group, bool) or not isinstance(group, int)
                              or not 0 <= group < 65536):
        raise _fail(where, f"group must be an MDF4 channel group number (0, 1, ...), got {group!r}")
    gap = _number(d, "max_gap", where, 0.0, RUN_GAP, open_lo=True)
    if gap is not None and gap >= RUN_GAP:
        raise _fail(where, f"max_gap must be below the contract's run gap of {RUN_GAP:g} s")
    override = d.get("override", False)
    if not isinstance(override, bool):
        raise _fail(where, f"override must be true or false, got {override!r}")
    if override and unit is None:
        raise _fail(where, "override (the map's unit over the file's) needs unit")
    blank = _text(d, "blank", where, BLANKS)
    cm = ChannelMap(channel=name, source=source, unit=unit, scale=scale, offset=offset or 0.0,
                    detection=detection or "peak", convention=convention or "lag", group=group,
                    max_gap=gap, override=override, blank=blank)
    if unit is not None:
        try:  # a unit the table does not know: refused with the map, before any file
            cm.affine(None)
        except OrdervibError as exc:
            raise _fail(where, str(exc)) from None
    return cm


def _csv(d: Any, where: str) -> CsvSpec:
    d = _keys(d, _CSV, where)
    delimiter = _text(d, "delimiter", where, max_chars=1) or ","
    if delimiter in "\r\n\"" or not delimiter:
        raise _fail(where, f"delimiter must be one character, not a quote or line end, got {delimiter!r}")
    decimal = _text(d, "decimal", where, (".", ",")) or "."
    if decimal == delimiter:
        raise _fail(where, "decimal and delimiter must differ")
    skip = d.get("skip_rows", 0)
    if isinstance(skip, bool) or not isinstance(skip, int) or not 0 <= skip <= MAX_SKIP_ROWS:
        raise _fail(where, f"skip_rows must be an integer in [0, {MAX_SKIP_ROWS}], got {skip!r}")
    return CsvSpec(delimiter=delimiter, decimal=decimal, skip_rows=skip,
                   blank=_text(d, "blank", where, BLANKS) or "auto")


def parse_map(doc: dict[str, Any], name: str = "map") -> ImportMap:
    """An ``ImportMap`` from a parsed TOML document; one-line ``OrdervibError`` naming ``name``
    and the key for anything out of its rule."""
    doc = _keys(doc, _TOP, name)
    bed = doc.get("bed")
    if not isinstance(bed, str) or not is_name(bed):
        raise _fail(name, f"bed must be a name of letters, digits, '_', '-' or '.' (1-64), got {bed!r}")
    fmt = _text(doc, "format", name, FORMATS)
    time = _time(doc.get("time", {}), f"{name}: [time]")
    chans = doc.get("channels")
    if not isinstance(chans, dict) or not chans:
        raise _fail(name, "[channels] must hold one table per contract channel written, e.g. "
                          "[channels.nB] source = \"IP speed\"")
    if len(chans) > len(CHANNELS):
        raise _fail(name, f"[channels] holds {len(chans)} tables, more than the {len(CHANNELS)} "
                          "contract channels")
    parsed = {k: _channel(k, v, f"{name}: [channels.{k}]") for k, v in chans.items()}
    channels = tuple(parsed[c] for c in CHANNELS if c in parsed)
    if any(c.group is not None for c in channels) and fmt not in (None, "mf4"):
        raise _fail(name, "group is for MDF4 files only")
    if any(c.blank is not None for c in channels) and fmt not in (None, "csv"):
        raise _fail(name, "blank (what an empty cell means) is for CSV files only")
    return ImportMap(bed=bed, channels=channels, format=fmt, time=time,
                     csv=_csv(doc.get("csv", {}), f"{name}: [csv]"), name=name)
