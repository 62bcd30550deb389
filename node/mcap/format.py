"""The MCAP format as this package writes and reads it (https://mcap.dev/spec), in one place.

Opcodes, the magic, the fixed-size parts of the records (little-endian ``struct``
layouts), the chunk compressions and the library name written in the Header.
Every record is ``opcode (u8), body length (u64), body``; strings are ``u32 length``
then UTF-8 bytes. A file is ``MAGIC, Header, data section (Schema, Channel, Chunk,
Message Index records), Data End, summary, Summary Offsets, Footer, MAGIC``.

>>> RECORD.size, MESSAGE.size, Opcode.MESSAGE
(9, 31, <Opcode.MESSAGE: 5>)
>>> Compression("none").chunk_name, Compression.from_chunk_name("zstd")
('', <Compression.ZSTD: 'zstd'>)
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

MAGIC = b"\x89MCAP0\r\n"
LIBRARY = "ordervib"  # the Header's library field


class Opcode(enum.IntEnum):
    """Record opcodes used here."""

    HEADER = 0x01
    FOOTER = 0x02
    SCHEMA = 0x03
    CHANNEL = 0x04
    MESSAGE = 0x05
    CHUNK = 0x06
    MESSAGE_INDEX = 0x07
    CHUNK_INDEX = 0x08
    STATISTICS = 0x0B
    METADATA = 0x0C
    METADATA_INDEX = 0x0D
    SUMMARY_OFFSET = 0x0E
    DATA_END = 0x0F


U16, U32, U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
RECORD = struct.Struct("<BQ")  # opcode, body length
# a Message record's head: opcode, length, channel id, sequence, log_time (ns), publish_time (ns)
MESSAGE = struct.Struct("<BQHIQQ")
MESSAGE_BODY = struct.Struct("<HIQQ")  # the same without opcode and length
# the same head as a numpy record, for building many at once
MESSAGE_DTYPE = np.dtype([("op", "u1"), ("length", "<u8"), ("channel", "<u2"), ("sequence", "<u4"),
                          ("log_time", "<u8"), ("publish_time", "<u8")])
assert MESSAGE_DTYPE.itemsize == MESSAGE.size
# Chunk body, before its compression string: message start and end time, uncompressed size and CRC
CHUNK = struct.Struct("<QQQI")
# Chunk Index body, before its message index offsets: start and end time, chunk offset and length
CHUNK_INDEX = struct.Struct("<QQQQ")
SIZES = struct.Struct("<QQ")  # Chunk Index tail: compressed and uncompressed size
MESSAGE_INDEX = struct.Struct("<HI")  # Message Index body head: channel id, byte length of its entries
TIME_OFFSET = np.dtype("<u8")  # a Message Index entry is two of these: log_time, offset in the chunk
CHANNEL_U64 = struct.Struct("<HQ")  # one entry of a channel id -> u64 map (index offsets, counts)
# Statistics body, before its channel counts: messages, schemas, channels, attachments,
# metadata, chunks, message start and end time
STATISTICS = struct.Struct("<QHIIIIQQ")
SUMMARY_OFFSET = struct.Struct("<BQQ")  # group opcode, group start, group length
FOOTER = struct.Struct("<BQQQ")  # opcode, length, summary start, summary offset start (CRC follows)


class Compression(enum.Enum):
    """Chunk compressions; the value is the command-line name, ``chunk_name`` the file's."""

    ZSTD = "zstd"
    LZ4 = "lz4"
    NONE = "none"

    @property
    def chunk_name(self) -> str:
        """The compression string of a Chunk record (empty for none)."""
        return "" if self is Compression.NONE else self.value

    @classmethod
    def from_chunk_name(cls, name: str) -> Compression:
        """The compression of a Chunk record's string (ValueError if unknown)."""
        return cls.NONE if name == "" else cls(name)

    def compressor(self, zstd_level: int = 1) -> Callable[[bytes | bytearray], bytes]:
        """A function compressing one chunk's records."""
        if self is Compression.ZSTD:
            import zstandard

            return zstandard.ZstdCompressor(level=zstd_level).compress
        if self is Compression.LZ4:
            import lz4.frame

            return lz4.frame.compress
        return bytes

    def decompress(self, data: bytes, size: int) -> bytes:
        """A chunk's records from their compressed bytes (size: uncompressed bytes)."""
        if self is Compression.ZSTD:
            import zstandard

            return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
        if self is Compression.LZ4:
            import lz4.frame

            return lz4.frame.decompress(data)
        return data


class Schema(NamedTuple):
    """A Schema record: id, name, encoding, data."""

    id: int
    name: str
    encoding: str
    data: bytes


class Channel(NamedTuple):
    """A Channel record: id, schema id (0: none), topic, message encoding, metadata."""

    id: int
    schema_id: int
    topic: str
    message_encoding: str
    metadata: dict[str, str]
