"""Recordings: the contract's MCAP layout (docs/contract.md sections 1 and 3), written and read here.

- ``format``: opcodes, magic, record layouts, compressions (the only place they are written);
- ``writer``: ``RecordingWriter`` (one topic per key expression, JSON payloads) over ``McapWriter``;
- ``reader``: one walk over the records in file order (``open_recording``), and ``iter_messages``,
  ``iter_messages_fast``, ``read_payloads`` and ``copy_messages`` on it; ``message_time_span``
  from a finished file's summary (progress); ``recorded_engine``, its ``ordervib`` metadata
  record (the engine, bed and date); ``warn_unfinished``, the warning for an unfinished file;
- ``rotation``: ``RotatingRecorder``, a recording split into successive files.
"""

from node.mcap.format import LIBRARY, MAGIC, Channel, Compression, Opcode, Schema
from node.mcap.reader import (
    Message,
    ReadStats,
    Recording,
    copy_messages,
    iter_messages,
    iter_messages_fast,
    message_time_span,
    open_recording,
    read_payloads,
    recorded_engine,
    recorded_topics,
    warn_unfinished,
)
from node.mcap.rotation import RotatingRecorder, rotated_path
from node.mcap.writer import SCHEMA_NAMES, McapWriter, RecordingWriter, schema_kind

__all__ = [
    "LIBRARY", "MAGIC", "Channel", "Compression", "Opcode", "Schema", "Message", "ReadStats", "Recording",
    "copy_messages", "iter_messages", "iter_messages_fast", "message_time_span", "open_recording",
    "recorded_engine", "recorded_topics", "read_payloads", "warn_unfinished",
    "RotatingRecorder", "rotated_path", "McapWriter", "RecordingWriter", "SCHEMA_NAMES", "schema_kind",
]
