"""The contract's MCAP layout (INTERFACE.md sections 1 and 3), in one place.

- ``RecordingWriter``: one MCAP topic per key expression, JSON payloads,
  ``jsonschema`` schemas of ``"type": "object"``, ``log_time`` = round(t * 1e9).
- ``iter_messages``: streaming reader in file order; works on unfinished files.
- ``read_runs``: fast reader returning the pass-off runs of a recording as
  time-major arrays on the 40 Hz grid, for training.

Every expected failure (missing, truncated, non-MCAP file) is an
``OrdervibError`` with one line; malformed payloads are counted and skipped.
"""

from __future__ import annotations

import math
import os
import struct
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import IO, Any, NamedTuple

import numpy as np
import orjson
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader

from node.contract import (
    FS,
    OFF_FRACTION,
    RUN_GAP,
    SENSOR_CHANNELS,
    SPEED_CHANNELS,
    OrdervibError,
    TopicKind,
    json_schema,
    log_time_ns,
    parse_sensor_key,
    topic_kind,
)
from node.mcap.fast import FastMcapWriter

MIN_RUN = 10.0  # shorter stretches of "engine on" are not runs (noise), s

MAGIC = b"\x89MCAP0\r\n"
LIBRARY = "ordervib"
# one JSON Schema per topic kind (contract section 2), registered once per recording
SCHEMAS: dict[TopicKind, bytes] = {kind: orjson.dumps(json_schema(kind)) for kind in TopicKind}
SCHEMA_NAMES: dict[TopicKind, str] = {kind: f"ordervib.{kind.value}" for kind in TopicKind}


class RecordingWriter:
    """Writes a recording: one topic per key expression, one message per sample.

    Use as a context manager, or call ``close()``. ``flush()`` closes the open
    chunk and pushes it to the file, so a crash loses nothing written before it.
    Output is deterministic: no wall clock is written anywhere. ``background=True``
    compresses the chunks in a worker thread (same bytes; for bulk writers).
    """

    def __init__(
        self,
        path: str | os.PathLike | IO[bytes],
        *,
        chunk_size: int = 1 << 20,
        compression: str = "zstd",
        message_index: bool = True,
        background: bool = False,
    ) -> None:
        if compression not in ("zstd", "lz4", "none"):
            raise OrdervibError(f"unknown compression {compression!r} (zstd, lz4, none)")
        if isinstance(path, (str, os.PathLike)):
            try:
                self._file: IO[bytes] | None = open(path, "wb")  # noqa: SIM115
            except OSError as exc:
                raise OrdervibError(f"cannot write {os.fspath(path)}: {exc.strerror}") from exc
            stream: IO[bytes] = self._file
        else:
            self._file, stream = None, path
        self._writer = FastMcapWriter(stream, chunk_size=chunk_size, compression=compression,
                                      message_index=message_index, library=LIBRARY,
                                      background=background)
        self._schemas: dict[TopicKind, int] = {}
        self._channels: dict[str, int] = {}
        self._closed = False
        self.count = 0

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def channel_id(self, key: str) -> int:
        """The MCAP channel of a key expression, registering schema and channel once."""
        cid = self._channels.get(key)
        if cid is None:
            kind = topic_kind(key)
            sid = self._schemas.get(kind)
            if sid is None:
                sid = self._writer.register_schema(SCHEMA_NAMES[kind], "jsonschema", SCHEMAS[kind])
                self._schemas[kind] = sid
            cid = self._writer.register_channel(key, "json", sid)
            self._channels[key] = cid
        return cid

    def write(
        self, key: str, t: float, payload: dict[str, Any] | bytes, publish_time_ns: int
    ) -> None:
        """Write one sample: key expression, time t (s), JSON payload, publish time (ns)."""
        if self._closed:
            raise OrdervibError("recording already closed")
        data = payload if isinstance(payload, bytes) else orjson.dumps(payload)
        cid = self._channels.get(key) or self.channel_id(key)
        self._writer.add(cid, log_time_ns(t), int(publish_time_ns), data)
        self.count += 1

    def write_ns(self, key: str, log_time_ns: int, data: bytes, publish_time_ns: int) -> None:
        """Write one message whose log_time (ns) and JSON bytes are already known (the fast path)."""
        if self._closed:
            raise OrdervibError("recording already closed")
        self._writer.add(self._channels.get(key) or self.channel_id(key), log_time_ns,
                         publish_time_ns, data)
        self.count += 1

    def write_many(self, messages: Iterable[tuple[str, int, int, bytes]]) -> None:
        """Write (key, log_time ns, publish_time ns, JSON bytes) messages, e.g. ``Message`` tuples."""
        if self._closed:
            raise OrdervibError("recording already closed")
        self.count += self._writer.add_many(messages, self._channels, self.channel_id)

    def write_columns(self, keys: Sequence[str], log_times: Sequence[int],
                      publish_times: Sequence[int], payloads: Sequence[bytes]) -> None:
        """``write_many`` given as four columns (the fastest way to write many messages)."""
        if self._closed:
            raise OrdervibError("recording already closed")
        channels = self._channels
        try:
            cids = np.fromiter(map(channels.__getitem__, keys), dtype=np.uint16, count=len(keys))
        except KeyError:
            for k in keys:  # register new keys in order of first appearance
                if k not in channels:
                    self.channel_id(k)
            cids = np.fromiter(map(channels.__getitem__, keys), dtype=np.uint16, count=len(keys))
        self._writer.add_columns(cids, log_times, publish_times, payloads)
        self.count += len(cids)

    @property
    def bytes_written(self) -> int:
        """Bytes in the file so far, not counting the open chunk."""
        return self._writer.bytes_out

    def flush(self) -> None:
        """Close the open chunk and push everything so far to the file (no fsync)."""
        if not self._closed:
            self._writer.flush()

    def close(self) -> None:
        """Write indexes and summary, then close the file (if we opened it)."""
        if self._closed:
            return
        self._closed = True
        self._writer.finish()
        if self._file is not None:
            self._file.close()


# ----------------------------------------------------------------------------- reading


class Message(NamedTuple):
    """One recorded message. payload: raw JSON bytes, or the decoded dict."""

    topic: str
    log_time: int
    publish_time: int
    payload: Any


@dataclass
class ReadStats:
    """What a read met: messages, malformed payloads skipped, an unfinished file."""

    messages: int = 0
    malformed: int = 0
    truncated: bool = False
    unknown_topics: set[str] = field(default_factory=set)


def _open_checked(path: str | os.PathLike) -> IO[bytes]:
    """Open a recording for reading, checking it exists and starts like an MCAP file."""
    name = os.fspath(path)
    try:
        f = open(name, "rb")  # noqa: SIM115
    except FileNotFoundError:
        raise OrdervibError(f"no such recording: {name}") from None
    except IsADirectoryError:
        raise OrdervibError(f"is a directory, not a recording: {name}") from None
    except OSError as exc:
        raise OrdervibError(f"cannot read {name}: {exc.strerror}") from None
    head = f.read(len(MAGIC))
    if head != MAGIC:
        f.close()
        what = "empty file" if not head else "not an MCAP file"
        raise OrdervibError(f"{what}: {name}")
    f.seek(0)
    return f


def iter_messages(
    path: str | os.PathLike, decode: bool = False, stats: ReadStats | None = None
) -> Iterator[Message]:
    """Yield every message in file order, also from an unfinished (crashed) file.

    decode=True yields the payload as a dict; a payload that is not a JSON object
    is then counted in ``stats.malformed`` and skipped. A truncated tail sets
    ``stats.truncated`` and ends the iteration quietly.
    """
    stats = stats if stats is not None else ReadStats()
    with _open_checked(path) as f:
        it = NonSeekingReader(f).iter_messages(log_time_order=False)
        while True:
            try:
                _, channel, msg = next(it)
            except StopIteration:
                return
            except (McapError, struct.error, EOFError, ValueError, OSError):
                stats.truncated = True
                return
            payload: Any = msg.data
            if decode:
                try:
                    payload = orjson.loads(msg.data)
                except orjson.JSONDecodeError:
                    payload = None
                if not isinstance(payload, dict):
                    stats.malformed += 1
                    continue
            stats.messages += 1
            yield Message(channel.topic, msg.log_time, msg.publish_time, payload)


# --- fast path: a linear scan of the raw records, without per-record objects

_OP_FOOTER, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_DATA_END = 0x02, 0x04, 0x05, 0x06, 0x0F
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
_REC = struct.Struct("<BQ")


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.decompress(data)
    raise OrdervibError(f"unsupported chunk compression {compression!r}")


def _chunk_records(buf: bytes, start: int, end: int, stats: ReadStats) -> bytes | None:
    """The decompressed records of the chunk record at buf[start:end]; None (counted) if corrupt."""
    usize = _U64.unpack_from(buf, start + 16)[0]
    clen = _U32.unpack_from(buf, start + 28)[0]
    comp = buf[start + 32:start + 32 + clen].decode()
    try:
        return _decompress(comp, buf[start + 32 + clen + 8:end], usize)
    except OrdervibError:
        raise
    except Exception:  # a corrupt chunk: skip it, keep the rest
        stats.malformed += 1
        return None


def _scan(
    buf: bytes,
    topics: dict[int, str],
    sink: dict[int, list[bytes]],
    stats: ReadStats,
    pos: int = 0,
) -> bool:
    """Walk records in buf from pos, collecting message payloads per channel id into sink.

    Returns False when the data ended mid-record (an unfinished file).
    """
    n = len(buf)
    rec, u16, u32 = _REC.unpack_from, _U16.unpack_from, _U32.unpack_from
    while pos < n:
        if pos + 9 > n:
            return False
        op, length = rec(buf, pos)
        start = pos + 9
        end = start + length
        if end > n:
            return False
        if op == _OP_MESSAGE:
            cid = u16(buf, start)[0]
            lst = sink.get(cid)
            if lst is not None:
                lst.append(buf[start + 22 : end])
            elif cid not in topics:
                stats.malformed += 1  # message before its channel
        elif op == _OP_CHUNK:
            inner = _chunk_records(buf, start, end, stats)
            if inner is not None:
                try:
                    _scan(inner, topics, sink, stats)
                except (struct.error, UnicodeDecodeError):
                    stats.malformed += 1
        elif op == _OP_CHANNEL:
            cid = u16(buf, start)[0]
            tlen = u32(buf, start + 4)[0]
            topic = buf[start + 8 : start + 8 + tlen].decode()
            topics[cid] = topic
            sink.setdefault(cid, [])
        elif op == _OP_DATA_END or op == _OP_FOOTER:  # the summary section repeats channels
            return True
        pos = end
    return True


def iter_messages_fast(path: str | os.PathLike, stats: ReadStats | None = None) -> Iterator[Message]:
    """Every message in file order as raw payload bytes, by a direct record walk.

    The same messages as ``iter_messages(path)`` (also from unfinished files),
    several times faster: no per-record objects. Loads the file into memory.
    """
    stats = stats if stats is not None else ReadStats()
    with _open_checked(path) as f:
        buf = f.read()
    topics: dict[int, str] = {}
    try:
        yield from _walk(buf, len(MAGIC), topics, stats)
    except (struct.error, UnicodeDecodeError):
        stats.truncated = True


def _walk(buf: bytes, pos: int, topics: dict[int, str], stats: ReadStats) -> Iterator[Message]:
    n = len(buf)
    rec, u16, u32 = _REC.unpack_from, _U16.unpack_from, _U32.unpack_from
    msg_head = struct.Struct("<HIQQ").unpack_from
    while pos < n:
        if pos + 9 > n:
            stats.truncated = True
            return
        op, length = rec(buf, pos)
        start = pos + 9
        end = start + length
        if end > n:
            stats.truncated = True
            return
        if op == _OP_MESSAGE:
            cid, _, log_time, publish_time = msg_head(buf, start)
            topic = topics.get(cid)
            if topic is None:
                stats.malformed += 1
            else:
                stats.messages += 1
                yield Message(topic, log_time, publish_time, buf[start + 22:end])
        elif op == _OP_CHUNK:
            inner = _chunk_records(buf, start, end, stats)
            if inner is not None:
                yield from _walk(inner, 0, topics, stats)
        elif op == _OP_CHANNEL:
            cid = u16(buf, start)[0]
            tlen = u32(buf, start + 4)[0]
            topics[cid] = buf[start + 8:start + 8 + tlen].decode()
        elif op == _OP_DATA_END or op == _OP_FOOTER:
            return
        pos = end


def read_payloads(
    path: str | os.PathLike, stats: ReadStats | None = None
) -> dict[str, list[bytes]]:
    """Every message payload of a recording by topic, in file order (fast, no decoding)."""
    stats = stats if stats is not None else ReadStats()
    with _open_checked(path) as f:
        buf = f.read()
    topics: dict[int, str] = {}
    sink: dict[int, list[bytes]] = {}
    try:
        complete = _scan(buf, topics, sink, stats, len(MAGIC))
    except (struct.error, UnicodeDecodeError):  # a garbled record header: keep what came before
        complete = False
    stats.truncated = stats.truncated or not complete
    out: dict[str, list[bytes]] = {}
    for cid, payloads in sink.items():
        out.setdefault(topics[cid], []).extend(payloads)
        stats.messages += len(payloads)
    return out


def _decode_samples(payloads: list[bytes], stats: ReadStats) -> tuple[np.ndarray, np.ndarray]:
    """(t, v) arrays from sensor payloads; v NaN for null; malformed ones skipped."""
    try:
        dicts = orjson.loads(b"[" + b",".join(payloads) + b"]")
        t = np.array([d["t"] for d in dicts], dtype=float)
        v = np.array([np.nan if (x := d["v"]) is None else x for d in dicts], dtype=float)
        if len(dicts) == len(payloads):
            return t, v
    except (orjson.JSONDecodeError, KeyError, TypeError, ValueError):
        pass
    ts, vs = [], []
    for p in payloads:  # slow path: find and skip the malformed ones
        try:
            d = orjson.loads(p)
            t0 = d["t"]
            x = d["v"]
            if isinstance(t0, bool) or isinstance(x, bool):
                raise TypeError
            tf = float(t0)
            vf = math.nan if x is None else float(x)
            if not math.isfinite(tf):
                raise ValueError
        except (orjson.JSONDecodeError, KeyError, TypeError, ValueError):
            stats.malformed += 1
            continue
        ts.append(tf)
        vs.append(vf)
    return np.array(ts, dtype=float), np.array(vs, dtype=float)


@dataclass
class Run:
    """One pass-off run on the 40 Hz grid.

    t: (K,) seconds since the epoch; data: (K, len(channels)) float64, NaN where
    a sample is missing or a dropout; shutdown_before: seconds the engine was off
    before this run (None for the first run in the file).
    """

    t: np.ndarray
    data: np.ndarray
    channels: tuple[str, ...]
    bed: str
    shutdown_before: float | None

    def column(self, name: str) -> np.ndarray:
        """One channel's samples, shape (K,)."""
        return self.data[:, self.channels.index(name)]


def _order_channels(found: Sequence[str], wanted: Sequence[str] | None) -> tuple[str, ...]:
    if wanted is not None:
        return tuple(wanted)
    known = [c for c in SENSOR_CHANNELS if c in found]
    return tuple(known + sorted(c for c in found if c not in SENSOR_CHANNELS))


def _align(
    t: np.ndarray, col: np.ndarray, v: np.ndarray, n_channels: int
) -> tuple[float, np.ndarray]:
    """Snap samples (t sorted) to a 40 Hz grid: returns (t0, data (K, n_channels))."""
    k = np.rint((t - t[0]) * FS)
    t0 = t[0] + float(np.median(t - t[0] - k / FS))
    k = np.rint((t - t0) * FS).astype(np.int64)
    k -= k.min()
    data = np.full((int(k.max()) + 1, n_channels), np.nan)
    data[k, col] = v
    return t0 + k.min() / FS, data


def _ffill(x: np.ndarray) -> np.ndarray:
    """Fill NaN rows of each column with the last value before them (then the first after)."""
    out = x.copy()
    for j in range(x.shape[1]):
        col = out[:, j]
        ok = ~np.isnan(col)
        if not ok.any():
            continue
        idx = np.where(ok, np.arange(len(col)), 0)
        np.maximum.accumulate(idx, out=idx)
        first = int(np.argmax(ok))
        idx[:first] = first
        out[:, j] = col[idx]
    return out


def _split_on(data: np.ndarray, speed_cols: list[int], tops: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) row ranges where the engine is on (some speed >= 5 % of its maximum).

    A dropout of a speed holds its last value, so it cannot fake a shutdown.
    """
    if not speed_cols:
        return [(0, len(data))]
    speeds = _ffill(data[:, speed_cols])
    off = np.all((speeds < OFF_FRACTION * tops) | np.isnan(speeds), axis=1)
    off &= ~np.all(np.isnan(speeds), axis=1)  # no speed at all: not known to be off
    on = np.concatenate([[False], ~off, [False]])
    edges = np.flatnonzero(np.diff(on.astype(np.int8)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def read_runs(
    path: str | os.PathLike,
    channels: Sequence[str] | None = None,
    stats: ReadStats | None = None,
) -> list[Run]:
    """The pass-off runs of a recording's sensor streams, in time order.

    channels: the columns wanted (default: every sensor channel found, contract
    order first). Runs are split at gaps >= 60 s and where every shaft speed is
    below 5 % of its maximum over the file; those off samples are dropped.
    shutdown_before = first "on" sample of the run - (last "on" sample of the
    previous run + 1/40 s). Several beds in one file give separate runs.
    """
    stats = stats if stats is not None else ReadStats()
    by_topic = read_payloads(path, stats)
    per_bed: dict[str, dict[str, list[bytes]]] = {}
    for topic, payloads in by_topic.items():
        parsed = parse_sensor_key(topic)
        if parsed is None:
            stats.unknown_topics.add(topic)
            continue
        per_bed.setdefault(parsed[0], {}).setdefault(parsed[1], []).extend(payloads)
    runs: list[Run] = []
    for bed in sorted(per_bed):
        runs += _bed_runs(bed, per_bed[bed], channels, stats)
    runs.sort(key=lambda r: r.t[0])
    return runs


def _bed_runs(
    bed: str,
    streams: dict[str, list[bytes]],
    wanted: Sequence[str] | None,
    stats: ReadStats,
) -> list[Run]:
    names = _order_channels(list(streams), wanted)
    col_of = {c: j for j, c in enumerate(names)}
    ts, vs, cs = [], [], []
    speed_names = [c for c in SPEED_CHANNELS if c in streams]
    extra = [c for c in speed_names if c not in col_of]
    for j, c in enumerate(list(names) + extra):  # speeds needed for splitting even if unwanted
        if c not in streams:
            continue
        t, v = _decode_samples(streams[c], stats)
        ts.append(t)
        vs.append(v)
        cs.append(np.full(len(t), j, dtype=np.int64))
    if not ts:
        return []
    t, v, col = np.concatenate(ts), np.concatenate(vs), np.concatenate(cs)
    if not len(t):
        return []
    width = len(names) + len(extra)
    all_names = list(names) + extra
    speed_cols = [all_names.index(c) for c in speed_names]
    tops = np.array([np.nanmax(v[col == j]) if np.any(col == j) else np.nan for j in speed_cols])
    tops = np.where(np.isfinite(tops) & (tops > 0), tops, np.inf)

    order = np.argsort(t, kind="stable")
    t, v, col = t[order], v[order], col[order]
    cuts = np.flatnonzero(np.diff(t) >= RUN_GAP) + 1
    runs: list[Run] = []
    last_on_end: float | None = None
    for a, b in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [len(t)]]), strict=True):
        t0, data = _align(t[a:b], col[a:b], v[a:b], width)
        for r0, r1 in _split_on(data, speed_cols, tops[: len(speed_cols)]):
            if (r1 - r0) / FS < MIN_RUN:
                continue
            start = t0 + r0 / FS
            shutdown = None if last_on_end is None else start - last_on_end
            runs.append(
                Run(
                    t=start + np.arange(r1 - r0) / FS,
                    data=np.ascontiguousarray(data[r0:r1, : len(names)]),
                    channels=names,
                    bed=bed,
                    shutdown_before=shutdown,
                )
            )
            last_on_end = t0 + r1 / FS
    return runs
