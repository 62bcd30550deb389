"""A recording split into successive files by size or by time (``ordervib run --rotate-*``).

``RotatingRecorder("node.mcap", max_mb=..., max_minutes=...)`` writes
``node.0000.mcap``, ``node.0001.mcap``, ... (the path's ``.mcap`` suffix, if
any, goes after the four-digit number; numbers grow past 9999 if need be).
Each file is a complete MCAP recording of its own: schemas and channels are
registered again in every file, and a file is finished (summary, footer) when
the next one starts. Rotation happens only between two messages, before the
message that finds the current file due:

- size: its bytes on disk (closed chunks; the live node closes one every second)
  have reached ``max_mb`` MB (10**6 bytes);
- time: the message's publish time (the receive time, in the live node) is
  ``max_minutes`` or more after the publish time of the file's first message.

No message is lost or duplicated: the files read in number order hold every
message written, in the order written. Rotation decisions depend only on what
was written, never on the wall clock, so the same messages give the same files.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from typing import Any

from node.contract.errors import OrdervibError
from node.mcap.writer import RecordingWriter


def rotated_path(path: str | os.PathLike, n: int) -> str:
    """The n-th file of a rotated recording: node.mcap -> node.0003.mcap."""
    p = os.fspath(path)
    stem, ext = (p[:-5], ".mcap") if p.endswith(".mcap") else (p, ".mcap")
    return f"{stem}.{n:04d}{ext}"


class RotatingRecorder:
    """``RecordingWriter``'s interface (write, write_ns, write_many, flush, close, count) over
    successive files; ``paths`` lists the files begun so far."""

    def __init__(self, path: str | os.PathLike, *, max_mb: float | None = None,
                 max_minutes: float | None = None, **writer_options: Any) -> None:
        if max_mb is not None and max_mb <= 0:
            raise OrdervibError("--rotate-mb must be > 0")
        if max_minutes is not None and max_minutes <= 0:
            raise OrdervibError("--rotate-minutes must be > 0")
        self.path = os.fspath(path)
        self.max_bytes = None if max_mb is None else int(max_mb * 1e6)
        self.max_ns = None if max_minutes is None else int(max_minutes * 60e9)
        self._options = writer_options
        self.paths: list[str] = []
        self.count = 0
        self._refused = 0  # the finished files' refused messages (RecordingWriter.refused)
        self._closed = False
        self._first_pub: int | None = None
        self._writer = self._open()

    def _open(self) -> RecordingWriter:
        path = rotated_path(self.path, len(self.paths))
        w = RecordingWriter(path, **self._options)
        self.paths.append(path)
        self._first_pub = None
        return w

    def __enter__(self) -> RotatingRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __str__(self) -> str:
        return f"{rotated_path(self.path, 0)}, {rotated_path(self.path, 1)}, ... (rotating)"

    @property
    def refused(self) -> int:
        """Messages not written, every file: new topics with its channel table full."""
        return self._refused + self._writer.refused

    @property
    def current(self) -> str:
        """The file being written."""
        return self.paths[-1]

    def _due(self, publish_time_ns: int) -> bool:
        w = self._writer
        if w.count == 0:
            return False  # never an empty file
        if self.max_bytes is not None and w.bytes_written >= self.max_bytes:
            return True
        return (self.max_ns is not None and self._first_pub is not None
                and publish_time_ns - self._first_pub >= self.max_ns)

    def _before(self, publish_time_ns: int) -> RecordingWriter:
        if self._closed:
            raise OrdervibError("recording already closed")
        if self._due(publish_time_ns):
            self._writer.close()
            self._refused += self._writer.refused
            self._writer = self._open()
        if self._first_pub is None:
            self._first_pub = publish_time_ns
        self.count += 1
        return self._writer

    def write(self, key: str, t: float, payload: dict[str, Any] | bytes, publish_time_ns: int) -> None:
        """As ``RecordingWriter.write``; may first finish this file and begin the next."""
        self._before(int(publish_time_ns)).write(key, t, payload, publish_time_ns)

    def write_ns(self, key: str, log_time_ns: int, data: bytes, publish_time_ns: int) -> None:
        self._before(publish_time_ns).write_ns(key, log_time_ns, data, publish_time_ns)

    def write_many(self, messages: Iterable[tuple[str, int, int, bytes]]) -> None:
        for key, log_time, publish_time, data in messages:
            self.write_ns(key, log_time, data, publish_time)

    def flush(self) -> None:
        if not self._closed:
            self._writer.flush()

    def abandon(self) -> None:
        """After a failure: leave the current file unfinished (``RecordingWriter.abandon``)."""
        if not self._closed:
            self._closed = True
            self._writer.abandon()

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._writer.close()
