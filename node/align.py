"""Aligning independently published channels into 40 Hz samples.

Each channel's samples arrive on their own (any order, jitter, duplicates,
dropouts). A sample of channel c at time t belongs to slot round((t - t0) fs).
A slot is emitted when every expected channel has filled it, or when data
``max_wait`` seconds newer than the slot has arrived (a bounded wait for late
channels). Decisions depend only on the order and content of the messages,
never on the wall clock, so replaying the messages in the order the node
received them reproduces its output exactly.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field

FS = 40.0
RUN_GAP = 60.0  # s without data: a new run (contract section 3)
_NAN = float("nan")


@dataclass
class AlignedSample:
    """One 40 Hz sample: slot time t (s) and the value of each channel that arrived (NaN: null)."""

    t: float
    values: dict[str, float]
    new_run: bool = False  # first sample after a gap of RUN_GAP or more


@dataclass
class AlignStats:
    samples: int = 0
    late: int = 0  # arrived after their slot was emitted
    duplicates: int = 0
    missing: Counter = field(default_factory=Counter)  # expected channel absent from a slot
    unknown: Counter = field(default_factory=Counter)  # channels not expected (ignored)


class Aligner:
    """Slots samples of ``channels`` on a 40 Hz grid anchored at the first sample of a run.

    Args:
        channels: the channels a sample is complete with.
        fs: sample rate, Hz.
        max_wait: seconds of newer data after which an incomplete slot is emitted anyway.
    """

    def __init__(self, channels: list[str], fs: float = FS, max_wait: float = 0.1) -> None:
        self.channels = list(channels)
        self._known = frozenset(self.channels)
        self._n = len(self.channels)
        self.fs = fs
        self.wait_slots = max(1, math.ceil(max_wait * fs))
        self.stats = AlignStats()
        self._t0: float | None = None
        self._next = 0  # first slot not yet emitted
        self._open: dict[int, dict[str, float]] = {}
        self._newest = -1
        self._last_t: float | None = None
        self._new_run = True
        self._emitted = False

    def push(self, channel: str, t: float, v: float | None) -> list[AlignedSample]:
        """Add one message; returns the samples that became complete (in time order)."""
        if channel not in self._known:
            self.stats.unknown[channel] += 1
            return []
        out: list[AlignedSample] = []
        last = self._last_t
        if last is not None and t - last >= RUN_GAP:
            out += self.flush()
            self._t0 = None
            self._new_run, self._emitted = True, False
        if self._t0 is None:
            self._t0, self._next, self._newest = t, 0, 0
        if last is None or t > last:
            self._last_t = t
        k = round((t - self._t0) * self.fs)
        nxt = self._next
        if k < nxt:
            if self._emitted:  # its slot is gone
                self.stats.late += 1
                return out
            self._next = nxt = k  # nothing emitted yet: the run starts earlier than its first message
        slot = self._open.get(k)
        if slot is None:
            slot = self._open[k] = {}
        elif channel in slot:
            self.stats.duplicates += 1
            return out
        slot[channel] = _NAN if v is None else float(v)
        if k > self._newest:
            self._newest = k
        # Between calls the head slot is neither complete nor expired, so only this
        # message can have made it so: test that first, then emit in order.
        if (k == nxt and len(slot) == self._n) or self._newest - nxt >= self.wait_slots:
            while True:
                head = self._open.get(self._next)
                complete = head is not None and len(head) == self._n
                expired = self._newest - self._next >= self.wait_slots
                if not (complete or expired):
                    break
                out.append(self._emit(self._next))
        return out

    def push_many(self, items: Iterable[tuple[int, str, float, float | None]]
                  ) -> list[tuple[int, list[AlignedSample]]]:
        """``push`` of each (tag, channel, t, v) in turn, with the very same effects, faster.

        Returns ``(tag, samples)`` for each message that completed samples.
        """
        known, n, wait, fs = self._known, self._n, self.wait_slots, self.fs
        opened, stats = self._open, self.stats
        get = opened.get
        done: list[tuple[int, list[AlignedSample]]] = []
        t0, nxt, newest, last = self._t0, self._next, self._newest, self._last_t
        for tag, channel, t, v in items:
            if channel not in known:
                stats.unknown[channel] += 1
                continue
            if t0 is not None and last is not None and t - last < RUN_GAP:
                k = round((t - t0) * fs)
                if k >= nxt:  # the common case, inline; anything else goes through push()
                    if t > last:
                        last = t
                    slot = get(k)
                    if slot is None:
                        slot = opened[k] = {}
                    elif channel in slot:
                        stats.duplicates += 1
                        continue
                    slot[channel] = _NAN if v is None else float(v)
                    if k > newest:
                        newest = k
                    if (k == nxt and len(slot) == n) or newest - nxt >= wait:
                        self._newest, self._last_t = newest, last
                        out = []
                        while True:
                            head = get(self._next)
                            complete = head is not None and len(head) == n
                            if not (complete or newest - self._next >= wait):
                                break
                            out.append(self._emit(self._next))
                        nxt = self._next
                        done.append((tag, out))
                    continue
            self._t0, self._next, self._newest, self._last_t = t0, nxt, newest, last
            out = self.push(channel, t, v)
            t0, nxt, newest, last = self._t0, self._next, self._newest, self._last_t
            if out:
                done.append((tag, out))
        self._t0, self._next, self._newest, self._last_t = t0, nxt, newest, last
        return done

    def _emit(self, k: int) -> AlignedSample:
        vals = self._open.pop(k, {})
        for c in self.channels:
            if c not in vals:
                self.stats.missing[c] += 1
                vals[c] = float("nan")
        self._next = k + 1
        self._emitted = True
        self.stats.samples += 1
        s = AlignedSample(self._t0 + k / self.fs, vals, self._new_run)
        self._new_run = False
        return s

    def flush(self) -> list[AlignedSample]:
        """Emit every open slot (end of stream, or before a new run)."""
        out = []
        while self._open:
            out.append(self._emit(self._next))
        return out
