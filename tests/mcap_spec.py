"""What contract section 3 asks of every recording the project writes, checked on its bytes
against the MCAP specification: a summary (statistics, schemas, channels, chunk indexes) and,
for every chunk, message indexes that list each of its messages (indexed readers such as
Foxglove's ``McapIndexedReader`` refuse a chunk index without them). A helper of the tests."""

from __future__ import annotations

import struct
from collections import Counter
from pathlib import Path

import lz4.frame
import zstandard
from mcap.reader import make_reader

CHUNK, MESSAGE, MESSAGE_INDEX = 0x06, 0x05, 0x07


def chunk_records(data: bytes, offset: int) -> bytes:
    """The decompressed records of the Chunk record at ``offset``."""
    op, _ = struct.unpack_from("<BQ", data, offset)
    assert op == CHUNK, f"no chunk at {offset}"
    pos = offset + 9 + 8 + 8  # start and end times
    size, _crc, n = struct.unpack_from("<QII", data, pos)
    pos += 16
    compression = data[pos:pos + n].decode()
    pos += n
    (length,) = struct.unpack_from("<Q", data, pos)
    body = data[pos + 8:pos + 8 + length]
    if compression == "zstd":
        return zstandard.ZstdDecompressor().decompress(body, max_output_size=size)
    if compression == "lz4":
        return lz4.frame.decompress(body)
    assert compression == "", compression
    return body


def _messages_in(records: bytes) -> Counter:
    """Messages per channel id in a chunk's records."""
    out: Counter = Counter()
    pos = 0
    while pos < len(records):
        op, length = struct.unpack_from("<BQ", records, pos)
        if op == MESSAGE:
            out[struct.unpack_from("<H", records, pos + 9)[0]] += 1
        pos += 9 + length
    return out


def check_indexed(path: str | Path) -> int:
    """Assert the recording at ``path`` carries its summary and complete message indexes; its
    message count."""
    data = Path(path).read_bytes()
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None, f"{path}: no summary"
    assert summary.channels and summary.schemas, f"{path}: no channels or schemas in the summary"
    assert summary.chunk_indexes or summary.statistics.message_count == 0, f"{path}: no chunk indexes"
    seen = 0
    for ci in summary.chunk_indexes:
        in_chunk = _messages_in(chunk_records(data, ci.chunk_start_offset))
        assert set(ci.message_index_offsets) == set(in_chunk), f"{path}: a chunk lacks message indexes"
        total = 0
        for cid, off in ci.message_index_offsets.items():
            op, _, rcid, rlen = struct.unpack_from("<BQHI", data, off)
            assert op == MESSAGE_INDEX and rcid == cid
            assert rlen // 16 == in_chunk[cid], f"{path}: channel {cid}'s index misses messages"
            total += 9 + 6 + rlen
        assert total == ci.message_index_length
        seen += sum(in_chunk.values())
    assert seen == summary.statistics.message_count
    return seen
