"""``ordervib recover``: rescue the messages of an unfinished (crashed) MCAP recording.

A node killed before ``finish()`` leaves a file without summary or footer:
``mcap.reader.make_reader`` refuses it. This command walks it in file order
(``node.mcap.copy_messages``), keeps every complete message and writes them into
a new, finished MCAP with the same topics, schemas, encodings, channel metadata,
``log_time``, ``publish_time`` and sequence numbers, in the layout of
``node.mcap.McapWriter`` (zstd chunks of 1 MiB, chunk and message indexes). A schema of
ours under an older name (``ordervib.Sensor``) gets the one name written today
(``node.mcap.SCHEMA_NAMES``), its content kept.
A finished input is simply copied message by message. Chunks that do not
decompress or fail their CRC are skipped (and counted in the summary line). The summary's span
is that of the beds' data (``testbed/<bed>/...``); other topics reaching outside it (an older
node's own health, stamped on its clock) are named apart.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import dataclass, field
from typing import IO

from node.cli.outputs import check_output, replacing
from node.contract import bed_of
from node.mcap import McapWriter, Message, ReadStats, copy_messages, open_recording

NAME = "recover"
HELP = "rescue the complete messages of an unfinished MCAP recording into a finished one"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="BROKEN.mcap", help="recording to rescue (finished or not)")
    p.add_argument("--out", required=True, metavar="FIXED.mcap", help="finished recording to write")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")


def _widened(span: tuple[int, int] | None, t: int) -> tuple[int, int]:
    """``span`` (first, last) widened to hold ``t``."""
    if span is None:
        return t, t
    return (t, span[1]) if t < span[0] else (span[0], t) if t > span[1] else span


@dataclass
class RecoverReport:
    """What a recovery kept.

    messages: messages written; topics: messages per topic; first_ns/last_ns:
    smallest and largest log_time of the beds' data (``testbed/<bed>/...`` topics; of every
    message when there is none), ns, None if no message; other_ns: the smallest and largest
    log_time of the other topics (a node's own health), None if none; unfinished: the input
    had no footer (or ended mid-record); bytes_in: input size (bytes); skipped:
    unreadable chunks and messages without a channel left out.
    """

    messages: int = 0
    topics: dict[str, int] = field(default_factory=dict)
    data_ns: tuple[int, int] | None = None
    other_ns: tuple[int, int] | None = None
    unfinished: bool = False
    bytes_in: int = 0
    skipped: int = 0

    def add(self, m: Message) -> None:
        """Count one message copied."""
        self.messages += 1
        n = self.topics.get(m.topic)
        self.topics[m.topic] = 1 if n is None else n + 1
        t = m.log_time
        if bed_of(m.topic) is not None:
            self.data_ns = _widened(self.data_ns, t)
        else:
            self.other_ns = _widened(self.other_ns, t)

    @property
    def first_ns(self) -> int | None:
        span = self.data_ns or self.other_ns
        return None if span is None else span[0]

    @property
    def last_ns(self) -> int | None:
        span = self.data_ns or self.other_ns
        return None if span is None else span[1]

    @property
    def span_s(self) -> float:
        """Time span covered by the data's log_time, s (0 without messages)."""
        if self.first_ns is None or self.last_ns is None:
            return 0.0
        return (self.last_ns - self.first_ns) / 1e9

    @property
    def outside(self) -> tuple[int, int] | None:
        """The other topics' log_time range (ns) when it reaches outside the data's, else None
        (a node's health on its own clock, as nodes recorded it before it took the sensor clock)."""
        data, other = self.data_ns, self.other_ns
        if data is None or other is None or (data[0] <= other[0] and other[1] <= data[1]):
            return None
        return other


def recover_file(src: str | os.PathLike, dst: IO[bytes]) -> RecoverReport:
    """Copy every complete message of recording src (in file order) into a finished MCAP on dst.

    Raises OrdervibError when src is missing or not an MCAP file. dst is not closed.
    """
    report = RecoverReport()
    stats = ReadStats()
    with open_recording(src) as rec:  # one-line errors for a missing or non-MCAP file
        report.bytes_in = rec.size
        writer = McapWriter(dst)
        for m in copy_messages(rec, writer, stats):
            report.add(m)
        writer.finish()
        report.unfinished = stats.truncated or not rec.finished
    report.skipped = stats.malformed
    return report


def _check(args: argparse.Namespace) -> None:
    check_output(args.out, "--out", inputs=[args.recording])


def _utc(ns: int) -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(ns / 1e9))


def _summary(r: RecoverReport, src: str, out: str, seconds: float) -> str:
    """One line: counts, span and whether the input was unfinished."""
    state = "unfinished" if r.unfinished else "finished"
    span = ""
    if r.first_ns is not None and r.last_ns is not None:
        span = f", span {r.span_s:.3f} s from {_utc(r.first_ns)} UTC"
    if r.outside is not None:
        a, b = r.outside
        span += f" (the beds' data; other topics from {_utc(a)} to {_utc(b)} UTC, outside it)"
    if r.skipped:
        span += f", {r.skipped} unreadable records skipped"
    return (
        f"recover: {state} input {src} ({r.bytes_in} bytes): {r.messages} messages on "
        f"{len(r.topics)} topics{span} -> {out} in {seconds:.2f} s"
    )


def run(args: argparse.Namespace) -> int:
    _check(args)
    start = time.perf_counter()
    with replacing(args.out) as part, open(part, "wb") as dst:
        report = recover_file(args.recording, dst)
    if not args.quiet:
        print(_summary(report, args.recording, args.out, time.perf_counter() - start))
        for topic in sorted(report.topics):
            print(f"  {report.topics[topic]:8d}  {topic}")
    if report.messages == 0:
        print("recover: warning: no complete message found", file=sys.stderr)
    return 0
