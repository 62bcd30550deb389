"""Reading recordings: one walk over the records in file order, and the readers built on it.

``open_recording`` maps a recording (checked to exist and start like an MCAP
file); ``Recording.messages`` walks its records in file order -- Schemas and
Channels are noted as they come, chunks decompressed on the way, the walk ends
at Data End -- and yields every message. An unfinished (crashed) file is read up
to its last complete record: ``ReadStats.truncated`` is set and the walk ends
quietly. A chunk that does not decompress (or fails its CRC check, when asked)
or whose records are garbled, and a message before its channel, are counted in
``ReadStats.malformed`` and skipped.

- ``iter_messages``: every message as a ``Message``, optionally JSON-decoded;
- ``read_payloads``: every payload by topic (the fast path of ``read_runs``);
- ``copy_messages``: every message into an ``McapWriter`` (``ordervib recover``).

Every expected failure (missing, empty, non-MCAP file) is an ``OrdervibError``
with one line.
"""

from __future__ import annotations

import hashlib
import logging
import mmap
import os
import struct
import zlib
from collections import defaultdict
from collections.abc import Generator, Iterator
from dataclasses import dataclass, field
from typing import IO, Any, NamedTuple

import orjson

from node.contract import OrdervibError
from node.mcap.format import (
    CHUNK,
    MAGIC,
    MESSAGE_BODY,
    RECORD,
    U16,
    U32,
    U64,
    Channel,
    Compression,
    Opcode,
    Schema,
)
from node.mcap.writer import SCHEMA_NAMES, McapWriter, schema_kind

Source = str | os.PathLike | IO[bytes]  # a recording's path, or a binary stream holding one
Buffer = bytes | mmap.mmap  # a recording's bytes, or a chunk's records
# one message as walked: its channel, sequence, log_time (ns), publish_time (ns), payload
RawMessage = tuple[Channel, int, int, int, bytes]

_MESSAGE, _CHUNK, _CHANNEL, _SCHEMA = int(Opcode.MESSAGE), int(Opcode.CHUNK), int(Opcode.CHANNEL), \
    int(Opcode.SCHEMA)
_END = (int(Opcode.DATA_END), int(Opcode.FOOTER))  # the summary after them repeats channels


class Message(NamedTuple):
    """One recorded message. payload: raw JSON bytes, or the decoded dict."""

    topic: str
    log_time: int
    publish_time: int
    payload: Any


@dataclass
class ReadStats:
    """What a read met: messages, malformed payloads skipped, an unfinished file; the file's
    sha256 (hex) when the read was asked for it (``read_payloads(..., sha256=True)``)."""

    messages: int = 0
    malformed: int = 0
    truncated: bool = False
    unknown_topics: set[str] = field(default_factory=set)
    sha256: str | None = None


def _string(buf: Buffer, pos: int) -> tuple[str, int]:
    """The string at pos (u32 length, UTF-8) and the position after it."""
    end = pos + U32.size + U32.unpack_from(buf, pos)[0]
    return buf[pos + U32.size:end].decode(), end


class Recording:
    """A recording opened for one or more walks over its records (see the module).

    ``source``: a path (memory-mapped) or a binary stream (read whole). ``size``:
    bytes; ``finished``: it ends with the closing magic; ``schemas``/``channels``:
    the records met so far by ``messages``, by id.
    """

    def __init__(self, source: Source) -> None:
        self._map: mmap.mmap | None = None
        if isinstance(source, (str, os.PathLike)):
            self.name = os.fspath(source)
            try:
                with open(self.name, "rb") as f:
                    head = f.read(len(MAGIC))
                    if head == MAGIC:
                        self._map = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
            except FileNotFoundError:
                raise OrdervibError(f"no such recording: {self.name}") from None
            except IsADirectoryError:
                raise OrdervibError(f"is a directory, not a recording: {self.name}") from None
            except OSError as exc:
                raise OrdervibError(f"cannot read {self.name}: {exc.strerror}") from None
            buf: Buffer = self._map if self._map is not None else head
        else:
            self.name = str(getattr(source, "name", "<stream>"))
            source.seek(0)
            buf = source.read()
        if buf[:len(MAGIC)] != MAGIC:
            raise OrdervibError(f"{'empty file' if not buf else 'not an MCAP file'}: {self.name}")
        self.buf = buf
        self.size = len(buf)
        self.finished = self.size >= 2 * len(MAGIC) and buf[-len(MAGIC):] == MAGIC
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}

    def __enter__(self) -> Recording:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Unmap the file (the payloads yielded stay valid: they are copies)."""
        if self._map is not None:
            self._map.close()

    def messages(self, stats: ReadStats, check_crc: bool = False) -> Iterator[RawMessage]:
        """Every message in file order (see the module); ``check_crc``: check chunk CRCs too."""
        try:
            ended = yield from self._walk(self.buf, len(MAGIC), stats, check_crc)
        except (struct.error, UnicodeDecodeError):  # a garbled record: keep what came before
            ended = None
        if not ended:  # no Data End: an unfinished file
            stats.truncated = True

    def _walk(self, buf: Buffer, pos: int, stats: ReadStats,
              check_crc: bool) -> Generator[RawMessage, None, bool | None]:
        """The messages of the records in buf from pos. Returns True at a Data End (or Footer)
        record, False at the end of buf, None when buf ends mid-record."""
        n = len(buf)
        channels = self.channels
        head, body = RECORD.unpack_from, MESSAGE_BODY.unpack_from
        while pos < n:
            if pos + RECORD.size > n:
                return None
            op, length = head(buf, pos)
            start = pos + RECORD.size
            end = start + length
            if end > n:
                return None
            if op == _MESSAGE:
                cid, sequence, log_time, publish_time = body(buf, start)
                channel = channels.get(cid)
                if channel is None:
                    stats.malformed += 1  # a message before its channel
                else:
                    yield channel, sequence, log_time, publish_time, buf[start + MESSAGE_BODY.size:end]
            elif op == _CHUNK:
                records = _chunk_records(buf, start, end, stats, check_crc)
                if records is not None:
                    try:
                        ended = yield from self._walk(records, 0, stats, check_crc)
                    except (struct.error, UnicodeDecodeError):
                        ended = None
                    if ended is None:  # a garbled chunk: skip the rest of it, keep the file
                        stats.malformed += 1
            elif op == _CHANNEL:
                cid, sid = U16.unpack_from(buf, start)[0], U16.unpack_from(buf, start + 2)[0]
                topic, p = _string(buf, start + 4)
                encoding, p = _string(buf, p)
                meta_end = p + U32.size + U32.unpack_from(buf, p)[0]
                p += U32.size
                metadata = {}
                while p < meta_end:
                    key, p = _string(buf, p)
                    metadata[key], p = _string(buf, p)
                channels[cid] = Channel(cid, sid, topic, encoding, metadata)
            elif op == _SCHEMA:
                sid = U16.unpack_from(buf, start)[0]
                name, p = _string(buf, start + 2)
                encoding, p = _string(buf, p)
                size = U32.unpack_from(buf, p)[0]
                self.schemas[sid] = Schema(sid, name, encoding, bytes(buf[p + U32.size:p + U32.size + size]))
            elif op in _END:
                return True
            pos = end
        return False


def _chunk_records(buf: Buffer, start: int, end: int, stats: ReadStats,
                   check_crc: bool) -> bytes | None:
    """The decompressed records of the chunk record body at buf[start:end]; None (counted) if corrupt."""
    _, _, size, crc = CHUNK.unpack_from(buf, start)
    name, p = _string(buf, start + CHUNK.size)
    try:
        compression = Compression.from_chunk_name(name)
    except ValueError:
        raise OrdervibError(f"unsupported chunk compression {name!r}") from None
    try:
        records = compression.decompress(buf[p + U64.size:end], size)
    except Exception:  # a corrupt chunk: skip it, keep the rest
        records = None
    if records is None or (check_crc and crc and zlib.crc32(records) != crc):
        stats.malformed += 1
        return None
    return records


def open_recording(source: Source) -> Recording:
    """The recording at a path (or in a binary stream), checked to start like an MCAP file.

    Raises a one-line ``OrdervibError`` for a missing, unreadable, empty or non-MCAP file.
    """
    return Recording(source)


def iter_messages(source: Source, decode: bool = False, stats: ReadStats | None = None) -> Iterator[Message]:
    """Yield every message in file order, also from an unfinished (crashed) file.

    decode=True yields the payload as a dict; a payload that is not a JSON object
    is then counted in ``stats.malformed`` and skipped. A truncated tail sets
    ``stats.truncated`` and ends the iteration quietly.
    """
    stats = stats if stats is not None else ReadStats()
    new = tuple.__new__  # a Message without NamedTuple's Python-level __new__: half the cost
    with open_recording(source) as rec:
        for channel, _, log_time, publish_time, data in rec.messages(stats):
            payload: Any = data
            if decode:
                try:
                    payload = orjson.loads(data)
                except orjson.JSONDecodeError:
                    payload = None
                if not isinstance(payload, dict):
                    stats.malformed += 1
                    continue
            stats.messages += 1
            yield new(Message, (channel.topic, log_time, publish_time, payload))


def iter_messages_fast(source: Source, stats: ReadStats | None = None) -> Iterator[Message]:
    """Every message in file order as raw payload bytes: ``iter_messages(source, stats=stats)``."""
    return iter_messages(source, stats=stats)


def read_payloads(source: Source, stats: ReadStats | None = None, sha256: bool = False
                  ) -> dict[str, list[bytes]]:
    """Every message payload of a recording by topic (in channel order), in file order (no decoding).

    sha256: also hash the whole file from the same mapping into ``stats.sha256`` (one read).
    """
    stats = stats if stats is not None else ReadStats()
    sink: defaultdict[int, list[bytes]] = defaultdict(list)
    with open_recording(source) as rec:
        if sha256:
            stats.sha256 = hashlib.sha256(rec.buf).hexdigest()
        for channel, _, _, _, data in rec.messages(stats):
            sink[channel.id].append(data)
        out: dict[str, list[bytes]] = {}
        for cid, channel in rec.channels.items():
            payloads = sink.get(cid, [])
            out.setdefault(channel.topic, []).extend(payloads)
            stats.messages += len(payloads)
    return out


def copy_messages(rec: Recording, writer: McapWriter, stats: ReadStats) -> Iterator[Message]:
    """Copy every message of rec (file order, chunk CRCs checked) into writer, keeping topics,
    schemas, encodings, channel metadata, times and sequence numbers; yields each one copied.

    Schemas and channels are registered on first use (new ids from 1); ``writer`` is not finished.
    A schema of ours under an older name (``ordervib.Sensor``) is written under the one name the
    project writes for its kind (``SCHEMA_NAMES``), its content kept.
    """
    schema_ids: dict[int, int] = {0: 0}  # input schema id -> output schema id; 0: no schema
    channel_ids: dict[int, int] = {}
    for channel, sequence, log_time, publish_time, data in rec.messages(stats, check_crc=True):
        cid = channel_ids.get(channel.id)
        if cid is None:
            sid = schema_ids.get(channel.schema_id)
            if sid is None:
                schema = rec.schemas.get(channel.schema_id)
                sid = 0
                if schema is not None:
                    kind = schema_kind(schema.name)
                    name = schema.name if kind is None else SCHEMA_NAMES[kind]
                    sid = writer.register_schema(name, schema.encoding, schema.data)
                schema_ids[channel.schema_id] = sid
            cid = writer.register_channel(channel.topic, channel.message_encoding, sid, channel.metadata)
            channel_ids[channel.id] = cid
        writer.add(cid, log_time, publish_time, data, sequence)
        stats.messages += 1
        yield Message(channel.topic, log_time, publish_time, data)


def message_time_span(path: str) -> tuple[int, int] | None:
    """A finished recording's first and last message log times (ns) from its summary (the
    mcap library reads the footer only); None when it has none (an unfinished file) or no
    message, or cannot be read (the reading proper reports that)."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
    except Exception:  # noqa: BLE001 - any failure here only means: no span known
        return None
    stats = summary.statistics if summary is not None else None
    if stats is None or stats.message_count == 0:
        return None
    return int(stats.message_start_time), int(stats.message_end_time)


def recorded_topics(path: str) -> set[str] | None:
    """A finished recording's topics from its summary (its Channel records); None when it has
    no summary (an unfinished file) or cannot be read (the reading proper reports that)."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
    except Exception:  # noqa: BLE001 - any failure here only means: not known
        return None
    return None if summary is None else {c.topic for c in summary.channels.values()}


ENGINE_RECORD = "ordervib"  # the metadata record naming a recording's engine (docs/contract.md section 3)


def recorded_engine(path: str) -> dict[str, str]:
    """A finished recording's ``ordervib`` metadata record (``engine``, and ``bed`` and ``date``
    where known), read through its summary's metadata index; {} when it has none, no summary (an
    unfinished file) or cannot be read (the reading proper reports that)."""
    from mcap.reader import make_reader
    from mcap.records import Metadata

    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            if summary is None or not any(m.name == ENGINE_RECORD for m in summary.metadata_indexes):
                return {}
            for record in reader.iter_metadata():
                if isinstance(record, Metadata) and record.name == ENGINE_RECORD:
                    return {str(k): str(v) for k, v in record.metadata.items()}
    except Exception:  # noqa: BLE001 - any failure here only means: not known
        return {}
    return {}


def warn_unfinished(logger: logging.Logger, path: str, read: str) -> None:
    """Say that recording ``path`` is unfinished (no footer) and what was read of it: the one
    warning every reader of a recording gives for an unfinished file."""
    logger.warning("%s is unfinished (no footer: its writer was stopped or killed): read %s, up to "
                   "its last complete record; `ordervib recover` writes a finished copy", path, read)
