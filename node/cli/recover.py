"""``ordervib recover``: rescue the messages of an unfinished (crashed) MCAP recording.

A node killed before ``finish()`` leaves a file without summary or footer:
``mcap.reader.make_reader`` refuses it. This command scans it linearly in file
order (``NonSeekingReader``), keeps every complete message and writes them into
a new, finished MCAP with the same topics, schemas, encodings, channel metadata,
``log_time``, ``publish_time`` and sequence numbers, in the layout conventions
of ``node.mcap.recording`` (zstd chunks of 1 MiB, chunk and message indexes).
A finished input is simply copied message by message.
"""

from __future__ import annotations

import argparse
import os
import struct
import sys
import time
from dataclasses import dataclass, field
from typing import IO

from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader
from mcap.records import Channel, Schema
from mcap.records import Message as McapMessage
from mcap.writer import CompressionType, IndexType, Writer

from node.cli.paths import check_output_file
from node.contract.errors import OrdervibError
from node.mcap.recording import LIBRARY, MAGIC, _open_checked

NAME = "recover"
HELP = "rescue the complete messages of an unfinished MCAP recording into a finished one"

CHUNK_SIZE = 1 << 20  # bytes, as node.mcap.recording.RecordingWriter


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="BROKEN.mcap", help="recording to rescue (finished or not)")
    p.add_argument("--out", required=True, metavar="FIXED.mcap", help="finished recording to write")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")


@dataclass
class RecoverReport:
    """What a recovery kept.

    messages: messages written; topics: messages per topic; first_ns/last_ns:
    smallest and largest log_time (ns, None if no message); unfinished: the input
    had no footer (or ended mid-record); bytes_in: input size (bytes).
    """

    messages: int = 0
    topics: dict[str, int] = field(default_factory=dict)
    first_ns: int | None = None
    last_ns: int | None = None
    unfinished: bool = False
    bytes_in: int = 0

    @property
    def span_s(self) -> float:
        """Time span covered by log_time, s (0 without messages)."""
        if self.first_ns is None or self.last_ns is None:
            return 0.0
        return (self.last_ns - self.first_ns) / 1e9


def _has_footer(f: IO[bytes]) -> bool:
    """True when the stream ends with the MCAP magic (a finished file)."""
    f.seek(0, os.SEEK_END)
    size = f.tell()
    if size < 2 * len(MAGIC):
        return False
    f.seek(size - len(MAGIC))
    ok = f.read(len(MAGIC)) == MAGIC
    f.seek(0)
    return ok


class _Copier:
    """Registers schemas and channels on first use, then copies messages."""

    def __init__(self, writer: Writer, report: RecoverReport) -> None:
        self.writer = writer
        self.report = report
        self.schemas: dict[int, int] = {}  # input schema id -> output schema id
        self.channels: dict[int, int] = {}  # input channel id -> output channel id

    def _schema_id(self, schema: Schema | None) -> int:
        if schema is None:  # schema id 0: no schema
            return 0
        sid = self.schemas.get(schema.id)
        if sid is None:
            sid = self.writer.register_schema(schema.name, schema.encoding, schema.data)
            self.schemas[schema.id] = sid
        return sid

    def add(self, schema: Schema | None, channel: Channel, msg: McapMessage) -> None:
        """Write one message, registering its channel (and schema) the first time."""
        cid = self.channels.get(channel.id)
        if cid is None:
            cid = self.writer.register_channel(
                channel.topic,
                channel.message_encoding,
                self._schema_id(schema),
                dict(channel.metadata or {}),
            )
            self.channels[channel.id] = cid
        self.writer.add_message(cid, msg.log_time, msg.data, msg.publish_time, msg.sequence)
        r = self.report
        r.messages += 1
        r.topics[channel.topic] = r.topics.get(channel.topic, 0) + 1
        r.first_ns = msg.log_time if r.first_ns is None else min(r.first_ns, msg.log_time)
        r.last_ns = msg.log_time if r.last_ns is None else max(r.last_ns, msg.log_time)


def recover_file(src: str | os.PathLike, dst: IO[bytes]) -> RecoverReport:
    """Copy every complete message of recording src (in file order) into a finished MCAP on dst.

    Raises OrdervibError when src is missing or not an MCAP file. dst is not closed.
    """
    report = RecoverReport()
    f = _open_checked(src)  # one-line errors for a missing or non-MCAP file
    writer = Writer(
        dst,
        chunk_size=CHUNK_SIZE,
        compression=CompressionType.ZSTD,
        index_types=IndexType.CHUNK | IndexType.MESSAGE,
    )
    writer.start(profile="", library=LIBRARY)
    copier = _Copier(writer, report)
    with f:
        report.bytes_in = os.fstat(f.fileno()).st_size
        report.unfinished = not _has_footer(f)
        it = NonSeekingReader(f, validate_crcs=True).iter_messages(log_time_order=False)
        while True:
            try:
                schema, channel, msg = next(it)
            except StopIteration:
                break
            except (McapError, struct.error, EOFError, ValueError, OSError):
                report.unfinished = True  # ended mid-record, or a corrupt tail
                break
            copier.add(schema, channel, msg)
    writer.finish()
    return report


def _check(args: argparse.Namespace) -> None:
    src, out = args.recording, args.out
    check_output_file(out, "--out")
    if os.path.exists(src) and os.path.exists(out) and os.path.samefile(src, out):
        raise OrdervibError("--out must differ from the input recording")


def _summary(r: RecoverReport, src: str, out: str, seconds: float) -> str:
    """One line: counts, span and whether the input was unfinished."""
    state = "unfinished" if r.unfinished else "finished"
    span = ""
    if r.first_ns is not None and r.last_ns is not None:
        t0 = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(r.first_ns / 1e9))
        span = f", span {r.span_s:.3f} s from {t0} UTC"
    return (
        f"recover: {state} input {src} ({r.bytes_in} bytes): {r.messages} messages on "
        f"{len(r.topics)} topics{span} -> {out} in {seconds:.2f} s"
    )


def run(args: argparse.Namespace) -> int:
    _check(args)
    start = time.perf_counter()
    part = args.out + ".part"
    try:
        with open(part, "wb") as dst:
            report = recover_file(args.recording, dst)
        os.replace(part, args.out)
    finally:
        if os.path.exists(part):
            os.remove(part)
    if not args.quiet:
        print(_summary(report, args.recording, args.out, time.perf_counter() - start))
        for topic in sorted(report.topics):
            print(f"  {report.topics[topic]:8d}  {topic}")
    if report.messages == 0:
        print("recover: warning: no complete message found", file=sys.stderr)
    return 0
