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
decompress or fail their CRC are skipped (and counted in the summary line).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import dataclass, field
from typing import IO

from node.cli.outputs import check_output, replacing
from node.mcap import McapWriter, Message, ReadStats, copy_messages, open_recording

NAME = "recover"
HELP = "rescue the complete messages of an unfinished MCAP recording into a finished one"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="BROKEN.mcap", help="recording to rescue (finished or not)")
    p.add_argument("--out", required=True, metavar="FIXED.mcap", help="finished recording to write")
    p.add_argument("--quiet", action="store_true", help="print nothing on success")


@dataclass
class RecoverReport:
    """What a recovery kept.

    messages: messages written; topics: messages per topic; first_ns/last_ns:
    smallest and largest log_time (ns, None if no message); unfinished: the input
    had no footer (or ended mid-record); bytes_in: input size (bytes); skipped:
    unreadable chunks and messages without a channel left out.
    """

    messages: int = 0
    topics: dict[str, int] = field(default_factory=dict)
    first_ns: int | None = None
    last_ns: int | None = None
    unfinished: bool = False
    bytes_in: int = 0
    skipped: int = 0

    def add(self, m: Message) -> None:
        """Count one message copied."""
        self.messages += 1
        self.topics[m.topic] = self.topics.get(m.topic, 0) + 1
        self.first_ns = m.log_time if self.first_ns is None else min(self.first_ns, m.log_time)
        self.last_ns = m.log_time if self.last_ns is None else max(self.last_ns, m.log_time)

    @property
    def span_s(self) -> float:
        """Time span covered by log_time, s (0 without messages)."""
        if self.first_ns is None or self.last_ns is None:
            return 0.0
        return (self.last_ns - self.first_ns) / 1e9


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


def _summary(r: RecoverReport, src: str, out: str, seconds: float) -> str:
    """One line: counts, span and whether the input was unfinished."""
    state = "unfinished" if r.unfinished else "finished"
    span = ""
    if r.first_ns is not None and r.last_ns is not None:
        t0 = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(r.first_ns / 1e9))
        span = f", span {r.span_s:.3f} s from {t0} UTC"
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
