"""Writing recordings: ``RecordingWriter`` (the contract's layout) over ``McapWriter`` (MCAP records).

``RecordingWriter`` (docs/contract.md sections 1 and 3): one MCAP topic per key
expression, JSON payloads, ``jsonschema`` schemas of ``"type": "object"`` (one per
topic kind), ``log_time`` = round(t * 1e9).

``McapWriter`` packs message records straight into the open chunk's buffer:
mcap-python's ``Writer`` builds a record object per message (about 15 us each);
this one packs the 31-byte message record head with one ``struct`` call and
appends head and payload to a ``bytearray`` (well under 1 us). Per-chunk work
(message indexes, channel counts, time range) is done with numpy on the offsets
of the messages when the chunk closes. Layout (``node.mcap.format``):

- Magic, Header (empty profile, library ``ordervib``).
- Schema and Channel records in the data section, outside chunks, written when
  first registered (before the chunk holding their first message).
- Chunks of at most about ``chunk_size`` uncompressed bytes (zstd, level 1 by default: 7 % faster
  replay than level 3 for 4 % more bytes; lz4 or none), uncompressed CRC computed,
  each followed by its Message Index records (one per channel, ascending channel id)
  unless ``message_index=False``.
- Metadata records (``add_metadata``, e.g. what an import read), after the last chunk.
- Data End (data section CRC 0: not computed, which the spec allows).
- Summary: Schemas, Channels, Statistics, Chunk Indexes, Metadata Indexes; Summary Offsets;
  Footer with the summary CRC; closing magic.

With ``background=True`` chunks are compressed (and their CRC computed) in a
worker thread while the caller goes on adding messages; they reach the stream
in order, so the bytes are the same. ``flush()`` waits for them.

``flush()`` closes the open chunk and pushes everything to the stream, so a
killed process loses only what it wrote after its last flush; the readers of
``node.mcap.reader`` (and ``ordervib recover``) read such a file.
No wall clock goes into the file: equal inputs give equal bytes.

Channel ids are u16 (given out from 1): a recording holds at most 65,535 topics.
``RecordingWriter`` bounds its channel table (``max_channels``, at most that): a message on a
new topic beyond it is not written and counted (``refused``); the recording goes on.
"""

from __future__ import annotations

import os
import zlib
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import IO, Any, cast

import numpy as np
import orjson

from node.contract import OrdervibError, TopicKind, json_schema, log_time_ns, topic_kind
from node.mcap.format import (
    CHANNEL_U64,
    CHUNK,
    CHUNK_INDEX,
    FOOTER,
    LIBRARY,
    MAGIC,
    MESSAGE,
    MESSAGE_DTYPE,
    MESSAGE_INDEX,
    RECORD,
    SIZES,
    STATISTICS,
    SUMMARY_OFFSET,
    TIME_OFFSET,
    U16,
    U32,
    U64,
    Compression,
    Opcode,
)

MAX_CHANNELS = 0xFFFF  # channels (topics) of one MCAP file at most: u16 ids, from 1

# one JSON Schema per topic kind (contract section 2), registered once per recording
SCHEMAS: dict[TopicKind, bytes] = {kind: orjson.dumps(json_schema(kind)) for kind in TopicKind}
SCHEMA_NAMES: dict[TopicKind, str] = {kind: f"ordervib.{kind.value}" for kind in TopicKind}
# the one name the project writes per kind; readers also accept other spellings of it (the
# committed recordings say "ordervib.Sensor"): see schema_kind
_KIND_OF_NAME: dict[str, TopicKind] = {name.lower(): kind for kind, name in SCHEMA_NAMES.items()}


def schema_kind(name: str) -> TopicKind | None:
    """The topic kind a recording's schema name stands for, in the name the project writes or in
    an older spelling (the committed recordings' ``ordervib.Sensor``); None: not one of ours.

    >>> schema_kind("ordervib.sensor"), schema_kind("ordervib.Sensor"), schema_kind("foxglove.Log")
    (<TopicKind.SENSOR: 'sensor'>, <TopicKind.SENSOR: 'sensor'>, None)
    """
    return _KIND_OF_NAME.get(name.lower())

_BODY = MESSAGE.size - RECORD.size  # message record body before the payload, bytes
_HEAD_BYTES = np.dtype((np.void, MESSAGE_DTYPE.itemsize))  # a message head as one opaque item
_FIELDS: Mapping[str, tuple[Any, ...]] = MESSAGE_DTYPE.fields or {}
_CHANNEL_AT, _LOG_TIME_AT = _FIELDS["channel"][1], _FIELDS["log_time"][1]  # offsets in a message record
_BYTE8 = np.arange(8, dtype=np.int64)


def _string(s: str) -> bytes:
    b = s.encode()
    return U32.pack(len(b)) + b


def _record(op: int, body: bytes) -> bytes:
    """One MCAP record: opcode, u64 length, body."""
    return RECORD.pack(op, len(body)) + body


def _compression(name: str) -> Compression:
    try:
        return Compression(name)
    except ValueError:
        raise OrdervibError(f"unknown compression {name!r} (zstd, lz4, none)") from None


class McapWriter:
    """Writes one MCAP file to a binary stream. Ids are given out from 1 in registration order.

    ``add(cid, log_time, publish_time, data)`` appends one message (times in ns).
    The stream is expected to be positioned at its start (offsets are counted
    from the first byte written) and is not closed by ``finish()``.
    ``background=True``: chunks are packed (compressed, CRC) in a worker thread.
    """

    def __init__(self, stream: IO[bytes], *, chunk_size: int = 1 << 20, compression: str = "zstd",
                 message_index: bool = True, zstd_level: int = 1, background: bool = False) -> None:
        comp = _compression(compression)
        self._stream = stream
        self._pos = 0  # bytes handed to the stream so far
        self.chunk_size = chunk_size
        self._compress = comp.compressor(zstd_level)
        self._comp_name = comp.chunk_name
        self._message_index = message_index
        self._schemas: list[bytes] = []  # records, id = index + 1
        self._channels: list[bytes] = []
        self._pending = bytearray()  # records outside chunks not yet handed to the stream
        self._buf = bytearray()  # the open chunk's records
        self._offs: list[int] = []  # offset of each message record in the open chunk (add)
        self._blocks: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # add_columns: offsets,
        # channel ids and log times of its messages in the open chunk
        self._chunk_indexes: list[bytes] = []
        self._metadata: list[tuple[str, dict[str, str]]] = []  # written at finish, after the chunks
        self._counts: dict[int, int] = {}
        self.message_count = 0  # messages in closed chunks
        self._t_min: int | None = None
        self._t_max = 0
        self._finished = False
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="mcap-chunks") if background else None
        self._packing: deque[tuple[Future, tuple]] = deque()  # chunks in the worker thread, in order
        self._pending += MAGIC + _record(Opcode.HEADER, _string("") + _string(LIBRARY))

    # -- registration
    def _register(self, records: list[bytes], rec: bytes) -> int:
        records.append(rec)
        self._wait()  # after the chunks closed before it
        self._pending += rec
        return len(records)

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Write a Schema record; returns its id."""
        sid = len(self._schemas) + 1
        return self._register(self._schemas, _record(
            Opcode.SCHEMA, U16.pack(sid) + _string(name) + _string(encoding) + U32.pack(len(data)) + data))

    def register_channel(self, topic: str, message_encoding: str, schema_id: int,
                         metadata: dict[str, str] | None = None) -> int:
        """Write a Channel record; returns its id (OrdervibError beyond ``MAX_CHANNELS``)."""
        cid = len(self._channels) + 1
        if cid > MAX_CHANNELS:
            raise OrdervibError(f"an MCAP file holds {MAX_CHANNELS} channels at most (u16 ids)")
        meta = b"".join(_string(k) + _string(v) for k, v in (metadata or {}).items())
        return self._register(self._channels, _record(
            Opcode.CHANNEL, U16.pack(cid) + U16.pack(schema_id) + _string(topic)
            + _string(message_encoding) + U32.pack(len(meta)) + meta))

    def add_metadata(self, name: str, entries: dict[str, str]) -> None:
        """A Metadata record (a name and string pairs), written after the last chunk and listed in
        the summary's Metadata Index."""
        self._metadata.append((name, dict(entries)))

    # -- messages
    def add(self, cid: int, log_time: int, publish_time: int, data: bytes, sequence: int = 0) -> None:
        """Append one message record to the open chunk (closing it when full)."""
        buf = self._buf
        self._offs.append(len(buf))
        buf += MESSAGE.pack(Opcode.MESSAGE, _BODY + len(data), cid, sequence, log_time, publish_time)
        buf += data
        if len(buf) >= self.chunk_size:
            self.close_chunk()

    def add_many(self, messages: Iterable[tuple[str, int, int, bytes]], channels: dict[str, int],
                 channel_of: Callable[[str], int]) -> int:
        """Append (topic, log_time, publish_time, data) messages; ``channels`` maps topics to ids,
        ``channel_of`` registers a topic it lacks (0: none, the message is skipped). Returns the
        number of messages appended."""
        buf, offs, pack, get, limit = self._buf, self._offs, MESSAGE.pack, channels.get, self.chunk_size
        op, body = int(Opcode.MESSAGE), _BODY  # (an enum member looked up per message costs)
        n = 0
        for topic, log_time, publish_time, data in messages:
            cid = get(topic) or channel_of(topic)
            if not cid:
                continue
            offs.append(len(buf))
            buf += pack(op, body + len(data), cid, 0, log_time, publish_time)
            buf += data
            n += 1
            if len(buf) >= limit:
                self.close_chunk()
                buf, offs = self._buf, self._offs
        return n

    def add_columns(self, cids: Sequence[int] | np.ndarray, log_times: Sequence[int] | np.ndarray,
                    publish_times: Sequence[int] | np.ndarray, payloads: Sequence[bytes]) -> None:
        """Append many messages at once: record heads built with numpy, joined with the payloads."""
        n = len(payloads)
        if n == 0:
            return
        lens = np.fromiter(map(len, payloads), dtype=np.int64, count=n)
        ends = np.cumsum(lens + MESSAGE.size)
        base = len(self._buf)
        room = self.chunk_size - base
        if ends[-1] >= room and n > 1:  # close the chunk after the message that fills it
            j = int(np.searchsorted(ends, room, side="left")) + 1
            if j < n:
                self.add_columns(cids[:j], log_times[:j], publish_times[:j], payloads[:j])
                self.add_columns(cids[j:], log_times[j:], publish_times[j:], payloads[j:])
                return
        head = np.empty(n, dtype=MESSAGE_DTYPE)
        head["op"] = Opcode.MESSAGE
        head["length"] = lens + _BODY
        head["channel"] = cids
        head["sequence"] = 0
        head["log_time"] = np.asarray(log_times, dtype=np.uint64)
        head["publish_time"] = np.asarray(publish_times, dtype=np.uint64)
        records: list[bytes] = [b""] * (2 * n)
        records[::2] = cast(list[bytes], head.view(_HEAD_BYTES).tolist())  # each head as one bytes object
        records[1::2] = payloads
        self._blocks.append((ends - (lens + MESSAGE.size) + base, head["channel"], head["log_time"]))
        self._buf += b"".join(records)
        if len(self._buf) >= self.chunk_size:
            self.close_chunk()

    @property
    def bytes_out(self) -> int:
        """Bytes handed to the stream so far (the file's size after a flush)."""
        return self._pos + len(self._pending)

    def close_chunk(self) -> None:
        """Compress the open chunk and queue it, with its message indexes, for the stream."""
        if not self._offs and not self._blocks:
            return
        data = self._buf
        columns = self._index_columns()
        self._buf = bytearray()
        self._offs = []
        self._blocks = []
        if self._pool is None:
            self._queue_chunk(*self._pack(data), len(data), *columns)
            self._push()
        else:
            self._packing.append((self._pool.submit(self._pack, data), (len(data), *columns)))
            self._collect(wait=False)

    def _pack(self, data: bytearray) -> tuple[bytes, int]:
        """The compressed chunk and the CRC of its records (in the worker thread if any)."""
        return self._compress(data), zlib.crc32(data)

    def _collect(self, wait: bool) -> None:
        """Queue the chunks packed in the worker thread, in order: all of them when ``wait``,
        else those done."""
        while self._packing and (wait or self._packing[0][0].done()):
            job, columns = self._packing.popleft()
            self._queue_chunk(*job.result(), *columns)
        self._push()

    def _wait(self) -> None:
        """Queue every chunk still in the worker thread."""
        if self._packing:
            self._collect(wait=True)

    def _queue_chunk(self, comp: bytes, crc: int, size: int, offs: np.ndarray, cids: np.ndarray,
                     times: np.ndarray) -> None:
        """A packed chunk, its message indexes and its chunk index, after what is queued so far."""
        t0, t1 = int(times.min()), int(times.max())
        chunk = CHUNK.pack(t0, t1, size, crc) + _string(self._comp_name) + U64.pack(len(comp))
        chunk_start = self.bytes_out
        pending = self._pending
        pending += RECORD.pack(Opcode.CHUNK, len(chunk) + len(comp)) + chunk
        pending += comp
        chunk_len = self.bytes_out - chunk_start
        order = np.argsort(cids, kind="stable")  # a radix sort of the 16-bit ids
        ids, starts, counts = np.unique(cids[order], return_index=True, return_counts=True)
        index_offsets = bytearray()
        index_start = self.bytes_out
        for cid, a, k in zip(ids.tolist(), starts.tolist(), counts.tolist(), strict=True):
            self._counts[cid] = self._counts.get(cid, 0) + k
            if self._message_index:
                sel = order[a:a + k]
                pairs = np.empty((k, 2), dtype=TIME_OFFSET)
                pairs[:, 0] = times[sel]
                pairs[:, 1] = offs[sel]
                index_offsets += CHANNEL_U64.pack(cid, self.bytes_out)
                pending += RECORD.pack(Opcode.MESSAGE_INDEX, MESSAGE_INDEX.size + 16 * k)
                pending += MESSAGE_INDEX.pack(cid, 16 * k) + pairs.tobytes()
        index_len = self.bytes_out - index_start
        self._chunk_indexes.append(_record(
            Opcode.CHUNK_INDEX,
            CHUNK_INDEX.pack(t0, t1, chunk_start, chunk_len)
            + U32.pack(len(index_offsets)) + bytes(index_offsets) + U64.pack(index_len)
            + _string(self._comp_name) + SIZES.pack(len(comp), size)))
        self.message_count += len(offs)
        self._t_min = t0 if self._t_min is None else min(self._t_min, t0)
        self._t_max = max(self._t_max, t1)

    def _index_columns(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Offsets, channel ids (uint16) and log times of the open chunk's messages, in file order."""
        blocks = list(self._blocks)
        if self._offs:  # messages from add(): read their ids and times back from the records
            offs = np.array(self._offs, dtype=np.int64)
            raw = np.frombuffer(self._buf, dtype=np.uint8)
            cids = (raw[offs + _CHANNEL_AT].astype(np.uint16)
                    | (raw[offs + _CHANNEL_AT + 1].astype(np.uint16) << 8))
            times = np.ascontiguousarray(raw[(offs + _LOG_TIME_AT)[:, None] + _BYTE8]).view(TIME_OFFSET)
            blocks.append((offs, cids, times.ravel()))
        offs, cids, times = (np.concatenate(c) for c in zip(*blocks, strict=True))
        if self._offs and self._blocks:
            order = np.argsort(offs)
            offs, cids, times = offs[order], cids[order], times[order]
        return offs, cids, times

    def _push(self) -> None:
        if self._pending:
            self._stream.write(self._pending)
            self._pos += len(self._pending)
            self._pending = bytearray()

    def flush(self) -> None:
        """Close the open chunk and push everything to the stream (and flush it; no fsync)."""
        self.close_chunk()
        self._wait()
        self._push()
        self._stream.flush()

    def abandon(self) -> None:
        """Stop without writing anything more (the stream is left as it is); never raises."""
        self._finished = True
        self._pending = bytearray()
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)

    def finish(self) -> None:
        """Close the data section, write the summary, footer and closing magic."""
        if self._finished:
            return
        self._finished = True
        try:
            self.close_chunk()
            self._wait()
        finally:
            if self._pool is not None:
                self._pool.shutdown()
        metadata_indexes = []
        for name, entries in self._metadata:
            pairs = b"".join(_string(k) + _string(v) for k, v in entries.items())
            start = self.bytes_out
            self._pending += _record(Opcode.METADATA, _string(name) + U32.pack(len(pairs)) + pairs)
            metadata_indexes.append(_record(Opcode.METADATA_INDEX, U64.pack(start)
                                            + U64.pack(self.bytes_out - start) + _string(name)))
        self._pending += _record(Opcode.DATA_END, U32.pack(0))
        summary_start = self.bytes_out
        summary = bytearray()
        offsets = bytearray()
        counts = b"".join(CHANNEL_U64.pack(c, k) for c, k in sorted(self._counts.items()))
        stats = _record(Opcode.STATISTICS, STATISTICS.pack(
            self.message_count, len(self._schemas), len(self._channels), 0, len(self._metadata),
            len(self._chunk_indexes), self._t_min or 0, self._t_max) + U32.pack(len(counts)) + counts)
        for op, records in ((Opcode.SCHEMA, self._schemas), (Opcode.CHANNEL, self._channels),
                            (Opcode.STATISTICS, [stats]), (Opcode.CHUNK_INDEX, self._chunk_indexes),
                            (Opcode.METADATA_INDEX, metadata_indexes)):
            if records:
                start = len(summary)
                for r in records:
                    summary += r
                offsets += _record(Opcode.SUMMARY_OFFSET, SUMMARY_OFFSET.pack(
                    op, summary_start + start, len(summary) - start))
        offset_start = summary_start + len(summary)
        summary += offsets
        head = FOOTER.pack(Opcode.FOOTER, FOOTER.size - RECORD.size + U32.size, summary_start, offset_start)
        crc = zlib.crc32(head, zlib.crc32(summary))
        self._pending += summary
        self._pending += head + U32.pack(crc) + MAGIC
        self._push()
        self._stream.flush()


class _OutputFile:
    """A file to write, opened at once or at its first write (deferred); "xb" mode if exclusive."""

    def __init__(self, path: str | os.PathLike, deferred: bool, exclusive: bool) -> None:
        self.path = os.fspath(path)
        self.mode = "xb" if exclusive else "wb"
        self._f: IO[bytes] | None = None
        if not deferred:
            self._open()

    def _open(self) -> IO[bytes]:
        if self._f is None:
            try:
                self._f = open(self.path, self.mode)  # noqa: SIM115
            except FileExistsError:
                raise OrdervibError(f"{self.path} exists: not overwritten") from None
            except OSError as exc:
                raise OrdervibError(f"cannot write {self.path}: {exc.strerror}") from exc
        return self._f

    def write(self, data: bytes | bytearray) -> int:
        return self._open().write(data)

    def flush(self) -> None:
        if self._f is not None:
            self._f.flush()

    def close(self) -> None:
        if self._f is not None:
            self._f.close()


class RecordingWriter:
    """Writes a recording: one topic per key expression, one message per sample.

    Use as a context manager, or call ``close()``. ``flush()`` closes the open
    chunk and pushes it to the file, so a crash loses nothing written before it.
    Output is deterministic: no wall clock is written anywhere. ``background=True``
    compresses the chunks in a worker thread (same bytes; for bulk writers). ``max_channels``
    bounds the topics (at most ``MAX_CHANNELS``, MCAP's u16 ids): a message on a new topic
    beyond it is skipped and counted in ``refused``, never an error.
    ``path`` may be a binary stream (not closed by ``close()``). For a file path,
    ``deferred=True`` creates the file only when the first bytes go out (the first
    ``flush()`` or ``close()``), and ``exclusive=True`` never opens an existing file
    (one-line ``OrdervibError``): the live node checks its session before it touches a file.

    >>> import io
    >>> from node.mcap import iter_messages
    >>> buf = io.BytesIO()
    >>> with RecordingWriter(buf) as w:
    ...     w.write("testbed/bed1/sensor/nB", 1767600000.0, {"t": 1767600000.0, "v": 2.5}, 7)
    ...     w.write_ns("testbed/bed1/sensor/nB", 1767600000025000000, b'{"t":1767600000.025,"v":null}', 8)
    >>> w.count, w.bytes_written == len(buf.getvalue())
    (2, True)
    >>> for m in iter_messages(buf, decode=True):
    ...     print(m.topic, m.log_time, m.publish_time, m.payload["v"])
    testbed/bed1/sensor/nB 1767600000000000000 7 2.5
    testbed/bed1/sensor/nB 1767600000025000000 8 None
    """

    def __init__(
        self,
        path: str | os.PathLike | IO[bytes],
        *,
        chunk_size: int = 1 << 20,
        compression: str = "zstd",
        message_index: bool = True,
        background: bool = False,
        deferred: bool = False,
        exclusive: bool = False,
        max_channels: int = MAX_CHANNELS,
    ) -> None:
        _compression(compression)  # before creating the file
        if not 1 <= max_channels <= MAX_CHANNELS:
            raise OrdervibError(f"max_channels must be within 1 and {MAX_CHANNELS}, got {max_channels}")
        self.max_channels = max_channels
        self.refused = 0  # messages not written: their topic was new with the channel table full
        if isinstance(path, (str, os.PathLike)):
            self._file: _OutputFile | None = _OutputFile(path, deferred, exclusive)
            stream = cast(IO[bytes], self._file)
        else:
            self._file, stream = None, path
        self._writer = McapWriter(stream, chunk_size=chunk_size, compression=compression,
                                  message_index=message_index, background=background)
        self._schemas: dict[TopicKind, int] = {}
        self._channels: dict[str, int] = {}
        self._closed = False
        self.count = 0

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __str__(self) -> str:
        return self._file.path if self._file is not None else "a stream"

    def channel_id(self, key: str) -> int:
        """The MCAP channel of a key expression, registering schema and channel once; 0 when it
        is new and the recording holds ``max_channels`` channels already."""
        cid = self._channels.get(key)
        if cid is None:
            if len(self._channels) >= self.max_channels:
                return 0
            kind = topic_kind(key)
            sid = self._schemas.get(kind)
            if sid is None:
                sid = self._writer.register_schema(SCHEMA_NAMES[kind], "jsonschema", SCHEMAS[kind])
                self._schemas[kind] = sid
            cid = self._writer.register_channel(key, "json", sid)
            self._channels[key] = cid
        return cid

    def _open(self) -> McapWriter:
        if self._closed:
            raise OrdervibError("recording already closed")
        return self._writer

    def write(
        self, key: str, t: float, payload: dict[str, Any] | bytes, publish_time_ns: int
    ) -> None:
        """Write one sample: key expression, time t (s), JSON payload, publish time (ns)."""
        data = payload if isinstance(payload, bytes) else orjson.dumps(payload)
        self.write_ns(key, log_time_ns(t), data, int(publish_time_ns))

    def write_ns(self, key: str, log_time_ns: int, data: bytes, publish_time_ns: int) -> None:
        """Write one message whose log_time (ns) and JSON bytes are already known (the fast path)."""
        writer = self._open()
        cid = self._channels.get(key) or self._channel_or_refuse(key)
        if cid:
            writer.add(cid, log_time_ns, publish_time_ns, data)
            self.count += 1

    def _channel_or_refuse(self, key: str) -> int:
        """``channel_id``, counting the message refused when it is 0."""
        cid = self.channel_id(key)
        if not cid:
            self.refused += 1
        return cid

    def write_many(self, messages: Iterable[tuple[str, int, int, bytes]]) -> None:
        """Write (key, log_time ns, publish_time ns, JSON bytes) messages, e.g. ``Message`` tuples."""
        self.count += self._open().add_many(messages, self._channels, self._channel_or_refuse)

    def write_columns(self, keys: Sequence[str], log_times: Sequence[int] | np.ndarray,
                      publish_times: Sequence[int] | np.ndarray, payloads: Sequence[bytes]) -> None:
        """``write_many`` given as four columns (the fastest way to write many messages)."""
        writer = self._open()
        channels = self._channels
        try:
            cids = np.fromiter(map(channels.__getitem__, keys), dtype=np.uint16, count=len(keys))
        except KeyError:
            for k in keys:  # register new keys in order of first appearance
                if k not in channels:
                    self.channel_id(k)
            cids = np.fromiter((channels.get(k, 0) for k in keys), dtype=np.uint16, count=len(keys))
            if not cids.all():  # topics beyond the channel table: skipped, counted
                kept = np.flatnonzero(cids)
                self.refused += len(cids) - len(kept)
                cids, log_times, publish_times = (np.asarray(c)[kept]
                                                  for c in (cids, log_times, publish_times))
                payloads = [payloads[i] for i in kept.tolist()]
        writer.add_columns(cids, log_times, publish_times, payloads)
        self.count += len(cids)

    def add_metadata(self, name: str, entries: dict[str, str]) -> None:
        """A Metadata record (``name``, string pairs) in the recording, after its last chunk."""
        self._open().add_metadata(name, entries)

    @property
    def bytes_written(self) -> int:
        """Bytes in the file so far, not counting the open chunk."""
        return self._writer.bytes_out

    def flush(self) -> None:
        """Close the open chunk and push everything so far to the file (no fsync)."""
        if not self._closed:
            self._writer.flush()

    def abandon(self) -> None:
        """After a failed write or flush: close the file as it is, unfinished (no summary; what
        reached the disk before the failure is readable, e.g. by ``ordervib recover``). Never raises."""
        self._closed = True
        self._writer.abandon()
        if self._file is not None:
            try:
                self._file.close()
            except OSError:  # the buffered bytes cannot be written either
                pass

    def close(self) -> None:
        """Write indexes and summary, then close the file (if we opened it)."""
        if self._closed:
            return
        self._closed = True
        self._writer.finish()
        if self._file is not None:
            self._file.close()
