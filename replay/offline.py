"""Offline replay: the node's logic over a recording, as fast as two cores allow.

The recording is read in file order (``iter_messages_fast``) in batches of
messages. Each batch goes to ``NodeCore.handle_batch`` (decode, align, predict), as in the live node,
with the messages' publish times as the receive times the live node stamped them with (a bed
silent for the alignment wait on that clock has its waiting slots emitted before its next
message, as the live node's timer did),
which reports the messages that completed monitor messages and those it refused; the
batch's recording is then written by the live node's own rule (``recording_rows``): the
inputs the node admitted, each monitor message right after the input that completed it,
exactly where a live node records it.

With ``workers=1`` (the default on a machine with two cores or more, where
``fork`` exists) the node's logic runs in one forked worker process while this
process reads the next batch and writes the previous one; the worker sees the
messages in the same order, so the output bytes are identical to
``workers=0`` (everything in this process). The output's chunks are compressed
in a thread of this process (``RecordingWriter(background=True)``), on whichever
core has room, in order: the same bytes again.
"""

from __future__ import annotations

import gc
import multiprocessing
import os
import queue
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from itertools import islice
from operator import itemgetter
from typing import Any

import numpy as np
import orjson

from node.contract import FS, OrdervibError, TopicKind, is_output_key, log_time_ns, topic_kind
from node.mcap import ReadStats, RecordingWriter, iter_messages_fast, message_time_span, recorded_topics
from node.models.bundle import Bundle, Model
from node.runtime.clock import ClockPolicy
from node.runtime.core import NodeCore, Row, recording_rows

BATCH = 4096  # messages per batch
IN_FLIGHT = 2  # batches handed to the worker and not yet written

_KEY, _LOG, _PUB, _PAYLOAD = (itemgetter(i) for i in range(4))  # fields of a Message
Encoded = tuple[str, int, bytes]  # (key, log_time ns, JSON bytes) of a monitor message
# what the logic did with a batch: (i, encoded outputs) of each message i that completed some,
# and which messages it refused ((n,) bool, or None: none was; ``Batch.refused``)
Done = tuple[list[tuple[int, list[Encoded]]], np.ndarray | None]


@dataclass
class ReplayReport:
    """What a replay did (the logic's counts come from the process that ran it)."""

    inputs: int = 0
    published: int = 0
    malformed: int = 0  # every bed's
    foreign: int = 0  # messages on keys that are no sensor keys
    seconds: float = 0.0
    truncated: bool = False
    alarm_episodes: list[dict] = field(default_factory=list)
    beds: dict[str, dict[str, Any]] = field(default_factory=dict)
    workers: int = 0
    engines: dict = field(default_factory=dict)  # each bed's engine history at the end (EngineState)
    verdicts: list[tuple[str, dict]] = field(default_factory=list)  # (key, monitor/verdict message), in order


class _Logic:
    """NodeCore plus what replay needs around it: encoded outputs and the report."""

    def __init__(self, bundle: Bundle | Model, encode: bool, engines: dict | None = None,
                 clock: ClockPolicy | None = None) -> None:
        self.core = NodeCore(bundle, engines, clock=clock)
        self.core.verdict_log = []  # (few: one per limited target at each OC switch and run end)
        self.encode = encode

    def _outputs(self, outs) -> list[Encoded]:
        if not self.encode:
            return []
        return [(key, log_time_ns(msg["t"]), orjson.dumps(msg)) for key, msg in outs]

    def batch(self, keys, payloads, recv) -> Done:
        b = self.core.handle_batch(keys, payloads, recv)
        return [(i, self._outputs(outs)) for i, outs in b.done], b.refused

    def finish(self) -> tuple[list[Encoded], dict]:
        final = self._outputs(self.core.finish())
        c = self.core
        report = {"published": c.published, "malformed": c.malformed, "foreign": c.foreign,
                  "alarm_episodes": c.alarm_log.episodes, "engines": c.engine_states(),
                  "verdicts": c.verdict_log,
                  "beds": {name: {"received": b.received, "malformed": b.malformed,
                                  "samples": b.aligner.stats.samples, "alarm_samples": b.alarm_samples,
                                  "late": b.aligner.stats.late, "duplicates": b.aligner.stats.duplicates,
                                  "missing": dict(b.aligner.stats.missing)}
                           for name, b in c.beds.items()}}
        return final, report


class _InProcess:
    workers = 0

    def __init__(self, bundle: Bundle | Model, encode: bool, engines: dict | None = None,
                 clock: ClockPolicy | None = None) -> None:
        self.logic = _Logic(bundle, encode, engines, clock)
        self.done: deque = deque()

    def submit(self, keys, payloads, recv) -> None:
        self.done.append(self.logic.batch(keys, payloads, recv))

    def result(self):
        return self.done.popleft()

    def finish(self):
        return self.logic.finish()

    def close(self) -> None:
        pass


def _serve(bundle: Bundle | Model, encode: bool, engines: dict | None, clock: ClockPolicy | None,
           tasks, results) -> None:
    """The worker process: batches in, encoded outputs out, in order; None ends."""
    gc.disable()
    try:
        logic = _Logic(bundle, encode, engines, clock)
        while (task := tasks.get()) is not None:
            results.put(("batch", logic.batch(*task)))
        results.put(("finish", logic.finish()))
    except BaseException as exc:  # noqa: BLE001 - reported to the parent, which raises
        results.put(("error", f"{type(exc).__name__}: {exc}"))


class _Forked:
    """The logic in one forked worker process; results come back in submission order."""

    workers = 1

    def __init__(self, bundle: Bundle | Model, encode: bool, engines: dict | None = None,
                 clock: ClockPolicy | None = None) -> None:
        self.finished = False
        ctx = multiprocessing.get_context("fork")
        self.tasks, self.results = ctx.Queue(), ctx.Queue()
        self.proc = ctx.Process(target=_serve, name="ordervib-replay", daemon=True,
                                args=(bundle, encode, engines, clock, self.tasks, self.results))
        self.proc.start()

    def submit(self, keys, payloads, recv) -> None:
        self.tasks.put((keys, payloads, recv))

    def _get(self, kind: str):
        while True:
            try:
                got, value = self.results.get(timeout=0.5)
            except queue.Empty:
                if not self.proc.is_alive():
                    raise OrdervibError(f"the replay worker died (exit code {self.proc.exitcode})") from None
                continue
            if got == "error":
                raise OrdervibError(f"replay worker: {value}")
            assert got == kind, (got, kind)
            return value

    def result(self):
        return self._get("batch")

    def finish(self):
        self.tasks.put(None)
        value = self._get("finish")
        self.finished = True
        return value

    def close(self) -> None:
        """Wait for a finished worker; stop one that is not (an error on this side)."""
        if self.finished:
            self.proc.join(timeout=10)
        if self.proc.is_alive():
            self.proc.kill()
        self.proc.join()
        for q in (self.tasks, self.results):
            q.cancel_join_thread()  # batches nobody will read must not hold up the exit
            q.close()


def default_workers() -> int:
    """1 (logic in a worker process) with two cores or more and ``fork``; else 0.

    ``fork`` keeps the start cheap (the worker inherits the loaded model and modules).
    """
    ok = ("fork" in multiprocessing.get_all_start_methods() and (os.cpu_count() or 1) >= 2
          and not multiprocessing.current_process().daemon)  # a daemon may not have children
    return 1 if ok else 0


def _write_batch(writer: RecordingWriter, batch: Sequence[Row], done: Done) -> None:
    """The batch's recording (``recording_rows``, the live node's rule): its inputs as recorded
    (key, log time, publish time, payload) but those the logic refused, each completing input
    followed by its monitor messages, stamped as published when that input arrived (its log
    time). Written as columns (``write_columns``: the fastest way)."""
    outputs, refused = done

    def stamp(i: int, outs: Sequence[Encoded]) -> list[Row]:
        log_i = batch[i][1]
        return [(key, log, log_i, data) for key, log, data in outs]

    rows = recording_rows(batch, outputs, refused, stamp)
    if rows:
        keys, logs, pubs, payloads = zip(*rows, strict=True)
        writer.write_columns(keys, _u64(logs, len(rows)), _u64(pubs, len(rows)), payloads)


def _u64(values: Iterable[int], n: int) -> np.ndarray:
    """n integers (nanoseconds) as an array, for the writer."""
    return np.fromiter(values, dtype=np.uint64, count=n)


CLOCK_SCAN = 200_000  # messages a node's first health message is looked for in (20 beds: ~12 s)


def recorded_clock(recording: str) -> ClockPolicy | None:
    """The clock guard the node that wrote ``recording`` ran with: from its first own health
    message (``ordervib/node/<id>/health``, field ``clock``) among the first ``CLOCK_SCAN``
    messages; None when there is none (a test bed's recording, an older node's). A malformed
    one is an ``OrdervibError`` (one line)."""
    topics = recorded_topics(recording)
    if topics is not None and not any(topic_kind(t) is TopicKind.NODE_HEALTH for t in topics):
        return None  # a finished recording without a node's health: nothing to look for
    for m in islice(iter_messages_fast(recording, ReadStats()), CLOCK_SCAN):
        if topic_kind(m.topic) is not TopicKind.NODE_HEALTH:
            continue
        try:
            settings = orjson.loads(m.payload).get("clock")
            return None if settings is None else ClockPolicy.from_settings(settings)
        except (orjson.JSONDecodeError, AttributeError, ValueError) as exc:
            raise OrdervibError(f"{recording}: the node's clock settings in {m.topic}: {exc}") from None
    return None


def replay(recording: str, bundle: Bundle | Model, out: str | None, workers: int | None = None,
           engines: dict | None = None,
           progress: Callable[[float, int], None] | None = None) -> ReplayReport:
    """Run the node over every sensor message of ``recording``; write ``out`` if given.

    engines: each bed's engine history before the recording (``node.runtime.history``;
    default: derived from the recording alone, its first run taken as a cold start).
    progress: called after each batch with the fraction of the recording's time span read
    (when its summary tells the span) and the messages read. The beds' clock guard is the one
    the recording's node said it ran with (``recorded_clock``), else the default."""
    workers = default_workers() if workers is None else workers
    stats = ReadStats()
    gc_was_on = gc.isenabled()
    gc.disable()  # no reference cycles are made here; collections would only cost time
    t0 = time.perf_counter()
    clock = recorded_clock(recording)
    engine = (_Forked if workers > 0 else _InProcess)(bundle, out is not None, engines, clock)
    writer = None
    n_in = 0
    try:
        writer = RecordingWriter(out, background=True) if out else None  # chunks packed in a thread
        flight: deque = deque()  # the batches handed over and not yet written

        def submit(batch: list, keys: list[str]) -> None:
            payloads = list(map(_PAYLOAD, batch))
            n = len(batch)
            recv = _u64(map(_PUB, batch), n)  # receive times: the alignment wait on the node's clock
            engine.submit(keys, payloads, recv)
            flight.append(batch if writer else None)
            while len(flight) > IN_FLIGHT:
                drain()

        def drain() -> None:
            done = engine.result()
            b = flight.popleft()
            if writer:
                _write_batch(writer, b, done)

        span = message_time_span(recording) if progress is not None else None
        messages = iter_messages_fast(recording, stats=stats)
        while batch := list(islice(messages, BATCH)):
            keys = list(map(_KEY, batch))
            if any(map(is_output_key, set(keys))):
                # a node's own recording: recompute its monitor messages, do not copy them
                batch = [m for m in batch if not is_output_key(m[0])]
                keys = list(map(_KEY, batch))
            n_in += len(batch)
            if batch:
                submit(batch, keys)
                if progress is not None and span is not None:
                    progress(min(1.0, (_LOG(batch[-1]) - span[0]) / max(span[1] - span[0], 1)), n_in)
        while flight:
            drain()
        if progress is not None and span is not None:
            progress(1.0, n_in)
        final, rep = engine.finish()
        if writer:
            writer.write_many([(key, log, log, data) for key, log, data in final])
    finally:
        engine.close()
        if writer:
            writer.close()
        if gc_was_on:
            gc.enable()
    return ReplayReport(inputs=n_in, seconds=time.perf_counter() - t0, truncated=stats.truncated,
                        workers=engine.workers, **rep)


@dataclass
class NodeAlarms:
    """The node's alarm episodes over recordings (``node_alarms``).

    episodes: ``EpisodeLog`` dicts {"key", "start", "end", "reason"}; samples: every bed's
    samples; per_file: (recording, its episodes, its samples) in the order given; carried: the
    engine history went on from one recording to the next (else each started cold); verdicts:
    the node's ``monitor/verdict`` messages (key, message), in order (none: the model has no
    limits).

    >>> NodeAlarms([{"key": "k", "start": 0.0, "end": 1.0, "reason": "step"}], 144000).line()
    'node alarms (ordervib replay): 1 episode(s) in 60.0 min of data = 1.00 per hour; by rule: step 1'
    """

    episodes: list[dict]
    samples: int
    per_file: list[tuple[str, int, int]] = field(default_factory=list)
    carried: bool = False
    verdicts: list[tuple[str, dict]] = field(default_factory=list)

    @property
    def hours(self) -> float:
        return self.samples / FS / 3600.0

    def by_reason(self) -> Counter:
        return Counter(e["reason"] for e in self.episodes)

    def line(self) -> str:
        """One line: episodes, data span, rate per hour, episodes by rule."""
        by_rule = ", ".join(f"{k} {v}" for k, v in sorted(self.by_reason().items())) or "none"
        rate = len(self.episodes) / self.hours if self.hours else 0.0
        return (f"node alarms (ordervib replay): {len(self.episodes)} episode(s) in "
                f"{self.hours * 60:.1f} min of data = {rate:.2f} per hour; by rule: {by_rule}")


def node_alarms(recordings: list[str], model: Bundle | Model, workers: int | None = None,
                carry: bool = False) -> NodeAlarms:
    """Replay the node over each recording (no output file) and gather its alarm episodes and
    its verdict messages.

    carry: each recording starts with the engine histories the previous one ended with (one
    engine's recordings in time order, as a live node's state file carries them); else each
    starts from a cold engine."""
    out = NodeAlarms([], 0, carried=carry)
    engines: dict | None = None
    for rec in recordings:
        r = replay(rec, model, None, workers, engines if carry else None)
        engines = r.engines
        samples = sum(b["samples"] for b in r.beds.values())
        out.episodes += r.alarm_episodes
        out.verdicts += r.verdicts
        out.samples += samples
        out.per_file.append((rec, len(r.alarm_episodes), samples))
    return out


def replay_model_file(recording: str, model: str, out: str | None = None, workers: int | None = None,
                      engine_state: str | None = None,
                      progress: Callable[[float, int], None] | None = None) -> ReplayReport:
    """``replay`` with the model folder ``model`` and, optionally, each bed's engine history from
    a live node's state file ``engine_state`` (read only; default: the recording's first run is
    a cold start)."""
    from node.models.bundle import load_model

    bundle = load_model(model)
    engines = None
    if engine_state is not None:
        from node.edges.engine_file import load_given_engine_states
        engines = load_given_engine_states(engine_state)
    return replay(recording, bundle, out, workers, engines, progress)
