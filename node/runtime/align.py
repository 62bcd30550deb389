"""Aligning independently published channels into 40 Hz samples.

Each channel's samples arrive on their own (any order, jitter, duplicates,
dropouts), each channel at its own clock phase within the period. A sample of
channel c at time t belongs to slot round(t fs - phi_c) of the absolute grid (slot k
is the time k / fs), phi_c the channel's phase as estimated from its own earlier
samples of the run (``node.contract.slotting``, the rule training shares).
A slot is emitted when every expected channel has filled it, or when data
``max_wait`` seconds newer than the slot has arrived (a bounded wait for late
channels); a run's first slot only by the wait (the first message to arrive need
not be the earliest), so reorderings within the wait change nothing. Decisions
depend only on the order and content of the messages, never on the wall clock, so
replaying the messages in the order the node received them reproduces its output
exactly.

In front of the slots stands the bed's clock guard (``node.runtime.clock``): a sample far
from the time the aligner has reached is held apart until other channels confirm its clock,
or dropped and counted; a confirmed clock that went back restarts the aligner as a new run.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import compress, repeat

import numpy as np
from mypy_extensions import mypyc_attr

from node.contract import FS, RUN_GAP
from node.contract.slotting import ChannelPhase
from node.models.config import RuntimeConfig
from node.runtime.clock import ClockGuard, ClockPolicy

_NAN = float("nan")
# Fewer messages of one bed than this go to push one by one: numpy's fixed cost per call
# (about 100 us a batch) is more than the 1.4 us a message of ``push``.
# (study: docs/tuning.md#small_batch)
SMALL_BATCH = 256


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
    late_by_channel: Counter = field(default_factory=Counter)  # the same, per channel
    duplicates: int = 0
    missing: Counter = field(default_factory=Counter)  # expected channel absent from a slot
    unknown: Counter = field(default_factory=Counter)  # channels not expected (ignored)


@mypyc_attr(allow_interpreted_subclasses=True)  # the tests' plainly written reference (node.native)
class Aligner:
    """Slots samples of ``channels`` on the absolute 40 Hz grid, each channel by its own phase.

    ``push`` is the rule, one message at a time; ``push_columns`` gives the very same
    results for a batch of messages, computed at once where it can.

    Args:
        channels: the channels a sample is complete with.
        fs: sample rate, Hz.
        max_wait: seconds of newer data after which an incomplete slot is emitted anyway
            (``RuntimeConfig.align_wait_s``).
        clock: the clock guard's policy (``ClockPolicy``; default its defaults).

    >>> a = Aligner(["nB", "yB"], max_wait=0.1)
    >>> a.push("nB", 100.025, 4001.0), a.push("nB", 100.0, 4000.0)  # any order
    ([], [])
    >>> a.push("yB", 100.011, 2.5), a.push("yB", 100.0365, None)  # yB samples 11 ms after nB
    ([], [])
    >>> [(s.t, s.values) for s in a.push("nB", 100.1, 4004.0)]  # a run's first slot waits 0.1 s
    [(100.0, {'nB': 4000.0, 'yB': 2.5}), (100.025, {'nB': 4001.0, 'yB': nan})]
    >>> round(a.phase_ms()["yB"], 1)  # yB's clock phase, ms (to 6 us)
    11.0
    >>> a.push("nB", 100.05, 4002.0), a.push("yB", 100.061, 3.0)  # then a slot goes out when complete
    ([], [AlignedSample(t=100.05, values={'nB': 4002.0, 'yB': 3.0}, new_run=False)])
    >>> a.push("yB", 100.086, 4.0), a.push("yB", 100.111, 5.0)  # slot 4003 lacks nB: it waits...
    ([], [])
    >>> [s.values for s in a.push("nB", 100.175, 4007.0)]  # ...until data 0.1 s newer came
    [{'yB': 4.0, 'nB': nan}, {'nB': 4004.0, 'yB': 5.0}]
    >>> a.stats.missing
    Counter({'nB': 1})
    """

    def __init__(self, channels: list[str], fs: float = FS,
                 max_wait: float = RuntimeConfig.align_wait_s, clock: ClockPolicy | None = None) -> None:
        self.channels = list(channels)
        self._known = frozenset(self.channels)
        self._n = len(self.channels)
        self._code = {c: i for i, c in enumerate(self.channels)}
        self.fs = fs
        self.wait_slots = max(1, math.ceil(max_wait * fs))
        self.stats = AlignStats()
        self._phase: dict[str, ChannelPhase] = {}  # each channel's, this run
        self._started = False  # a run is under way
        self._next = 0  # first slot not yet emitted
        self._open: dict[int, dict[str, float]] = {}
        self._newest = -1
        self._last_t: float | None = None
        self._new_run = True
        self._emitted = False
        self.guard = ClockGuard(clock or ClockPolicy(), self._n)
        self._jump = self.guard.max_jump

    @property
    def clock(self) -> float | None:
        """The bed's clock: the newest sensor time taken (None before the first), s."""
        return self._last_t

    def push(self, channel: str, t: float, v: float | None) -> list[AlignedSample]:
        """Add one message of ``channel`` (time t, s; value v, None or NaN: null); returns the
        samples it completes, in time order."""
        if channel not in self._known:
            self.stats.unknown[channel] += 1
            return []
        last = self._last_t
        if last is None or self.guard.pending or not -self._jump <= t - last <= self._jump:
            return self._guarded(channel, t, v)
        self.guard.taken += 1
        return self._push(channel, t, v)

    def _guarded(self, channel: str, t: float, v: float | None, received: int | None = None
                 ) -> list[AlignedSample]:
        """A message through the clock guard: taken, held, or confirming a new clock (received:
        the node's receipt time, ns, None: not known)."""
        take, confirmed = self.guard.offer(channel, t, v, self._last_t, received)
        if take:
            return self._push(channel, t, v)
        if confirmed is None:
            return []
        out: list[AlignedSample] = []
        if self._last_t is not None and confirmed.newest < self._last_t - self._jump:
            out += self.restart()  # the clock went back: a new run on it
        for c, ti, vi in confirmed.samples:
            out += self._push(c, ti, vi)
        return out

    def restart(self) -> list[AlignedSample]:
        """Emit every open slot and start a new run at the next message taken, as if first."""
        out = self.flush()
        self._phase.clear()
        self._started, self._new_run, self._emitted = False, True, False
        self._last_t, self._newest = None, -1
        return out

    def end(self) -> list[AlignedSample]:
        """End of stream: every open slot emitted; samples still held are dropped (counted)."""
        self.guard.drop_all()
        return self.flush()

    def _push(self, channel: str, t: float, v: float | None) -> list[AlignedSample]:
        """``push`` of a known channel's message the clock guard took."""
        last = self._last_t
        if last is not None and t - last >= RUN_GAP:  # a new run, on a new grid
            out = self.flush()
            self._phase.clear()
            self._started, self._new_run, self._emitted = False, True, False
        else:
            out = []
        phase = self._phase.get(channel)
        if phase is None:
            phase = self._phase[channel] = ChannelPhase(self.fs)
        k = phase.slot(t)  # round(t fs - phi), phi before this sample
        if not self._started:
            self._started, self._next, self._newest = True, k, k
        if self._last_t is None or t > self._last_t:  # max(last, t)
            self._last_t = t
        if k < self._next:
            if self._emitted or self._newest - k >= self.wait_slots:  # its slot is gone (or expired)
                self.stats.late += 1
                self.stats.late_by_channel[channel] += 1
                return out
            self._next = k  # nothing emitted yet: the run starts earlier than its first message
        opened = self._open
        slot = opened.get(k)
        if slot is None:
            slot = opened[k] = {}
        elif channel in slot:
            self.stats.duplicates += 1
            return out
        slot[channel] = _NAN if v is None else float(v)
        if k > self._newest:
            self._newest = k
        # emit in order every slot complete (every channel in) or expired (a run's first slot is
        # known once the wait has passed)
        n, wait = self._n, self.wait_slots
        while ((self._emitted and len(opened.get(self._next, ())) == n)
               or self._newest - self._next >= wait):
            out.append(self._emit(self._next))
        return out

    def push_columns(self, channels: Sequence[str], t: np.ndarray, v: np.ndarray,
                     received: Sequence[int] | None = None) -> list[tuple[int, list[AlignedSample]]]:
        """``push(channels[i], t[i], v[i])`` for every i in turn, with the very same effects.

        t: (n,) finite times, s; v: (n,) values (NaN: null); received: (n,) the node's receipt
        times, ns, for the clock guard (None: not known). Returns ``(i, samples)`` for each
        message i that completed samples. Inside a run that has emitted already, where no
        message of the batch can start a new run (the common case), the batch is aligned at
        once with numpy; otherwise, and for a few messages, message by message.

        No rounding question arises: ``ChannelPhase.slots`` gives each message the very
        phase ``push`` would (the estimate moves only at the end of a block of a channel's
        samples, and block sums are exact integers), so the slots are bit-identical.
        """
        n, last = len(t), self._last_t
        if (n < SMALL_BATCH or not self._emitted or last is None or self.guard.pending
                or float(t.max()) - last >= RUN_GAP or len(self._code) != self._n):
            return self._one_by_one(channels, t, v, received)
        ci = np.fromiter(map(self._code.get, channels, repeat(-1)), dtype=np.int64, count=n)
        at = np.flatnonzero(ci >= 0)  # the messages of known channels
        if len(at):
            before = np.maximum.accumulate(np.concatenate(([last], t[at])))[:-1]  # the bed's clock
            if (np.abs(t[at] - before) > self._jump).any():  # one far from it: the guard decides
                return self._one_by_one(channels, t, v, received)
        if (ci < 0).any():
            self.stats.unknown.update(compress(channels, (ci < 0).tolist()))
        if not len(at):
            return []
        self.guard.taken += len(at)
        t, v, code = t[at], v[at], ci[at]
        k = np.empty(len(t), dtype=np.int64)
        by_channel = np.argsort(code, kind="stable")  # each channel's messages, in arrival order
        cuts = np.searchsorted(code[by_channel], np.arange(self._n + 1)).tolist()
        for j, name in enumerate(self.channels):
            if cuts[j] == cuts[j + 1]:
                continue
            mine = by_channel[cuts[j]:cuts[j + 1]]
            phase = self._phase.get(name)
            if phase is None:
                phase = self._phase[name] = ChannelPhase(self.fs)
            k[mine] = phase.slots(t[mine])  # round(t fs - phi), phi before each message
        newest = np.maximum.accumulate(np.maximum(k, self._newest))  # after each message
        taken, emit_at = self._plan(k, code, newest)
        self._fill(k[taken], code[taken], v[taken])
        self._newest = int(newest[-1])
        self._last_t = max(last, float(t.max()))
        done: list[tuple[int, list[AlignedSample]]] = []
        for tag in at[emit_at].tolist():  # the message after which each next slot is emitted
            if done and done[-1][0] == tag:
                done[-1][1].append(self._emit(self._next))
            else:
                done.append((tag, [self._emit(self._next)]))
        return done

    def _one_by_one(self, channels: Sequence[str], t: np.ndarray, v: np.ndarray,
                    received: Sequence[int] | None) -> list[tuple[int, list[AlignedSample]]]:
        return self.push_list(channels, t.tolist(), v.tolist(), received)

    def push_list(self, channels: Sequence[str], t: Sequence[float], v: Sequence[float | None],
                  received: Sequence[int] | None = None) -> list[tuple[int, list[AlignedSample]]]:
        """``push(channels[i], t[i], v[i])`` for every i in turn, as Python lists (a few messages:
        no numpy call); ``(i, samples)`` for each message i that completed samples; received:
        as ``push_columns``'.

        The messages of channels not expected are counted at once and skipped (``push`` does
        nothing else with them); the others go through ``push``'s very steps."""
        known = self._known
        at: list[int] = []
        unknown = self.stats.unknown
        for i, c in enumerate(channels):
            if c in known:
                at.append(i)
            else:
                unknown[c] += 1
        out: list[tuple[int, list[AlignedSample]]] = []
        guard, jump, push = self.guard, self._jump, self._push
        phases, opened, stats, n, wait = self._phase, self._open, self.stats, self._n, self.wait_slots
        taken = 0
        for i in at:
            c, ti = channels[i], t[i]
            last = self._last_t
            if last is None or guard.pending or not -jump <= ti - last <= jump:
                guard.taken += taken
                taken = 0
                got = self._guarded(c, ti, v[i], None if received is None else received[i])
                if got:
                    out.append((i, got))
                continue
            taken += 1
            phase = phases.get(c)
            if phase is None or ti - last >= RUN_GAP:  # a channel's first, or a new run: push's steps
                got = push(c, ti, v[i])
                if got:
                    out.append((i, got))
                continue
            # push's very steps (``_push``) inside a run under way (a clock is set: it has started)
            k = phase.slot(ti)
            if ti > last:
                self._last_t = ti
            nxt = self._next
            if k < nxt:
                if self._emitted or self._newest - k >= wait:  # its slot is gone (or expired)
                    stats.late += 1
                    stats.late_by_channel[c] += 1
                    continue
                self._next = nxt = k
            slot = opened.get(k)
            if slot is None:
                slot = opened[k] = {}
            elif c in slot:
                stats.duplicates += 1
                continue
            vi = v[i]
            slot[c] = _NAN if vi is None else float(vi)
            if k > self._newest:
                self._newest = k
            # the head slot (nxt) stood incomplete and unexpired after the last message: only a
            # message into it can complete it, only a newer slot expire it
            if (k == nxt and self._emitted and len(slot) == n) or self._newest - nxt >= wait:
                got = []
                while ((self._emitted and len(opened.get(self._next, ())) == n)
                       or self._newest - self._next >= wait):
                    got.append(self._emit(self._next))
                out.append((i, got))
        guard.taken += taken
        return out

    def _plan(self, k: np.ndarray, c: np.ndarray, newest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """What ``push`` would do with messages of slots k and channel codes c (no new run among
        them, the run has emitted): which messages enter their slot (neither late nor duplicate;
        late and duplicates are counted), and after which message each next slot is emitted."""
        m, nxt, n = len(k), self._next, self._n
        key = k * n + c
        first = np.zeros(m, dtype=bool)
        first[np.unique(key, return_index=True)[1]] = True  # first message of its slot and channel
        held = [s * n + self._code[ch] for s, slot in self._open.items() for ch in slot]
        if held:
            first &= ~np.isin(key, held)  # already in its open slot
        # slot s = nxt + i completes with the message bringing its last missing channel (complete[i])
        # and expires with the first message whose slot is s + wait or later (expire[i])
        span = max(int(k.max()), *self._open, nxt - 1) - nxt + 1
        need = np.full(span, n, dtype=np.int64)
        for s, slot in self._open.items():
            if nxt <= s < nxt + span:
                need[s - nxt] -= len(slot)
        cand = np.flatnonzero(first & (k >= nxt))  # in arrival order
        order = cand[np.argsort(k[cand], kind="stable")]  # by slot, then arrival
        slot_of = k[order] - nxt
        rank = np.arange(len(order)) - np.searchsorted(slot_of, slot_of, side="left")
        complete = np.where(need > 0, m, -1)
        last_one = rank == need[slot_of] - 1
        complete[slot_of[last_one]] = order[last_one]
        expire = np.searchsorted(newest, np.arange(nxt, nxt + span) + self.wait_slots, side="left")
        emitted = np.maximum.accumulate(np.minimum(complete, expire))  # slots go out in order
        emit_at = emitted[:np.searchsorted(emitted, m, side="left")]
        rel = k - nxt
        late = rel < 0  # its slot went out before it arrived
        gone = ~late & (rel < len(emit_at))
        late[gone] = emit_at[rel[gone]] < np.flatnonzero(gone)
        self.stats.late += int(late.sum())
        if late.any():
            codes, counts = np.unique(c[late], return_counts=True)
            self.stats.late_by_channel.update(
                dict(zip(map(self.channels.__getitem__, codes.tolist()), counts.tolist(), strict=True)))
        self.stats.duplicates += int((~late & ~first).sum())
        return first & ~late, emit_at

    def _fill(self, k: np.ndarray, c: np.ndarray, v: np.ndarray) -> None:
        """Add the values v of channel codes c to their open slots k, in arrival order."""
        if not len(k):
            return
        order = np.argsort(k, kind="stable")
        k = k[order]
        names = list(map(self.channels.__getitem__, c[order].tolist()))
        values = v[order].tolist()
        slots, starts = np.unique(k, return_index=True)
        ends = [*starts[1:].tolist(), len(k)]
        opened = self._open
        for s, a, b in zip(slots.tolist(), starts.tolist(), ends, strict=True):
            slot = opened.get(s)
            if slot is None:
                slot = opened[s] = {}
            slot.update(zip(names[a:b], values[a:b]))

    def _emit(self, k: int) -> AlignedSample:
        vals = self._open.pop(k, {})
        if len(vals) < self._n:  # else every channel is there
            for c in self.channels:
                if c not in vals:
                    self.stats.missing[c] += 1
                    vals[c] = float("nan")
        self._next = k + 1
        self._emitted = True
        self.stats.samples += 1
        s = AlignedSample(k / self.fs, vals, self._new_run)
        self._new_run = False
        return s

    def phase_ms(self) -> dict[str, float]:
        """Each channel's estimated clock phase in this run, ms after its slot's time."""
        return {c: p.phase_ms for c, p in self._phase.items() if p.phase_ms is not None}

    def flush(self) -> list[AlignedSample]:
        """Emit every open slot (end of stream, or before a new run)."""
        out = []
        while self._open:
            out.append(self._emit(self._next))
        return out
