"""The live edges: Zenoh in and out, MCAP recording. The logic is ``NodeCore``'s.

The subscriber hands its samples to a bounded FIFO inside Zenoh (``FifoChannel`` of
``queue_size``; no Python runs per message on Zenoh's side); one worker thread drains it in
batches (everything waiting, up to ``BATCH_MAX``; each message's receive time is Zenoh's
timestamp as it arrived, ``receive_ns``), runs the node logic once per batch
(``NodeCore.handle_batch``, as offline replay does), records every input it admitted,
publishes and records every output, emits the waiting slots of a bed that fell silent
(``NodeCore.flush_idle``: the alignment wait on the node's clock, ``align_wait_s`` plus
``IDLE_MARGIN_NS`` after the bed's last receipt, looked at with the intake empty; replay does
the same from the recorded receive times), flushes the recording once a second (a
killed node loses at most the last second) and publishes the beds' health in turn, at most
``HEALTH_MAX_PER_S`` a second whatever the beds (``node.live.health_rate``: once a second per bed
up to 100 beds, ``HEALTH_PER_PASS`` beds a pass at most; a bed silent for ``health_silence_s``
leaves the rotation). A transition's
analysis (``monitor/transient``) runs in a process of its own at the lowest priority
(``NodeCore(defer_transients=True)``, ``PendingTransient``, ``node.live.analyses``): its message
goes out once done, in the order the transitions ended.

Hostile and broken clients (``bench hostile``): whatever arrives, the node's state stays bounded. The
core admits a message only on a valid sensor key of a bed the ``beds`` pattern names, within
``max_beds`` beds and ``max_channels`` channels per bed; the refused are counted per reason,
never recorded, never a bed, a topic or an MCAP channel (``NodeCore.route``). A bed silent
for ``bed_expiry_s`` (receive time) is freed: its waiting samples run, a last health message
says ``expired: true``. The recording's channel table is bounded too
(``RecordingWriter.max_channels``): a topic beyond it is refused and counted, the recording
goes on. What belongs to no bed (refusals, beds tracked, silent and expired, the worker's
lag, whether the ``connect`` endpoints answer: ``node.edges.reach``) goes to the node's own
health, ``ordervib/node/<id>/health`` (``NodeHealthMessage``), once a second while it changes; its
``t`` is the beds' latest sensor time (``sensor_t``), so that the node's recording keeps one
timeline: before any sensor time it is published with ``t`` null and not recorded.

Failures (docs/deployment.md, "What the node does when things go wrong"):

- more than ``queue_size`` messages waiting (the worker behind): the node loses none; Zenoh
  holds the links back (TCP flow control) until the worker takes more, so the publishers wait
  (``BLOCK``) or drop at their side (``DROP``, counted there). Health shows it as the worker's
  lag: how long the intake has not been found empty (``worker_lag_s``). With a Python callback
  per message the node cost 48 us a message at 20 beds, 10 of them the callback thread and its
  contention with the worker (``bench live``);
- a malformed payload is counted and recorded at its receive time; it never
  reaches code that can throw;
- a recording that fails (disk full, I/O error) stops being written: the node
  goes on monitoring and publishing, every message it can no longer record is
  counted (health ``recording: false``, ``unrecorded: N``), one error line is
  logged, the unfinished file is left for ``ordervib recover``, and ``run_node``
  ends with an ``OrdervibError`` (``ordervib run`` exits non-zero);
- an engine-state save that fails (``node.edges.engine_file``) is logged once and shown in
  health (``engine_state: false``) while monitoring goes on; if the last save failed too,
  ``run_node`` ends with an ``OrdervibError``;
- outputs are published with Zenoh's ``CongestionControl.DROP``: a subscriber that stops
  reading loses live messages (after Zenoh's ``wait_before_drop``, 1 ms), it never stalls
  the node. With ``BLOCK`` one hung subscriber held the worker 5 s in ``put`` (Zenoh's
  ``wait_before_close``, then it closes that link) while inputs queued up and every other
  subscriber waited too. The recording keeps every output;
- a worker pass longer than ``STALL_S`` is logged with where its time went;
- the garbage collector: once set up (model loaded, session open), before the first message,
  ``start`` collects, freezes what lives on (``gc.freeze``: the model, the core, the session
  objects are never traversed again) and raises the first generation's threshold to
  ``GC_THRESHOLD`` (``quiet_gc``): process-wide settings, set again by each node started (harmless),
  never undone. With the defaults the demo's worker stalled 1.2 s, 1.1 s of it in the collector;
- a worker thread that dies withdraws the node's liveliness token at once;
  ``run_node``'s watchdog notices it within ``WATCHDOG_S``, stops the node and
  raises an ``OrdervibError`` naming the cause.
"""

from __future__ import annotations

import gc
import logging
import threading
import time
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from types import TracebackType
from typing import Any

import numpy as np
import orjson

from node import native
from node.contract import (
    HealthMessage,
    NodeHealthMessage,
    OrdervibError,
    Refused,
    health_key,
    liveliness_key,
    log_time_ns,
    log_times_ns,
    node_health_key,
    sensor_subscription,
)
from node.edges.engine_file import SAVE_EVERY_S, engine_document, load_engine_states, save_engine_states
from node.edges.reach import Reach, connect_endpoints
from node.edges.zenoh import open_session, zenoh_config
from node.live.analyses import TransientAnalyses
from node.live.health_rate import HEALTH_MAX_PER_S, HEALTH_SILENCE_MAX_S, HEALTH_SILENCE_S, HealthRotation
from node.live.intake import FairIntake
from node.mcap import RecordingWriter
from node.mcap.rotation import RotatingRecorder
from node.models.bundle import Bundle, Model
from node.runtime.clock import ClockPolicy
from node.runtime.core import MAX_BEDS, MAX_CHANNELS, NodeCore, Row, recording_rows

log = logging.getLogger(__name__)

# Messages handled at once at most: a batch's outputs go out once the whole batch is handled, so a
# bed's sample completed early in a burst waits for the rest of it. 20 beds (bench live): 4096
# gave latency p99 / max 47 / 113 ms, 128 gave 32 / 67 and 29 / 69 ms, 64 30 / 68 ms, at the same
# CPU per message (a batch's own cost, about 40 us, is 0.3 us a message at 128)
BATCH_MAX = 128
QUEUE_MAX = 10_000_000  # the intake's bound (queue_size) at most
# Behind, the worker takes up to DRAIN_MAX messages a pass from Zenoh's FIFO into the fair intake
# (node.live.intake), which holds INTAKE_MAX at most (beyond, Zenoh's FIFO holds them, then the links)
DRAIN_MAX, INTAKE_MAX = 1024, 65_536
LAG_KEPT = 4000  # latencies (per bed) the health message's percentiles are taken over
WATCHDOG_S = 0.5  # how often run_node checks the worker thread, s
# gc.set_threshold: a young collection every 50,000 net container allocations, not 700 (the
# worker holds thousands of queued tuples at once: with 700 each batch ran many collections that
# promoted them); the older generations' defaults kept
GC_THRESHOLD = (50_000, 10, 10)
STALL_S = 0.5  # a worker pass longer than this is logged as a warning with its breakdown, s
BED_EXPIRY_S = 300.0  # a bed silent this long (receive time) is freed, by default, s (--bed-expiry)
# The worker's wait for input when the intake was empty: short while messages flow, longer after
# IDLE_POLLS empty looks (a silent node wakes 200 times a second, not 1,000)
POLL_S, IDLE_POLL_S, IDLE_POLLS = 0.001, 0.005, 200
IDLE_CHECK_S = 0.05  # how often silent beds' waiting slots are looked at, s (NodeCore.flush_idle)
# Silent beds are looked at only with the intake found empty (a node behind its inputs cannot tell
# a silence), as of the time it was found so, and a message stamped on arrival but not yet in the
# intake must not count as later than a flush: a silent bed's waiting slots go out align_wait_s
# plus this after its last receipt
IDLE_MARGIN_NS = 250_000_000
SMALL_LOG = 64  # a batch's input log times in plain Python below this many messages, numpy above
# Beds' health at most this many a worker pass (a pass every 50 ms at the least; and at most
# HEALTH_MAX_PER_S a second): hundreds of beds' health in one pass held every real bed's outputs behind them
HEALTH_PER_PASS = 16


def receive_ns(stamp: Any, floor: int, now: int) -> int:
    """A sample's receive time, ns since the epoch: its Zenoh timestamp (``stamp``; None: ``now``)
    within [floor, now] (a publisher's own timestamp, or the session's clock pushed ahead by one,
    is not trusted beyond that).

    >>> from types import SimpleNamespace as S
    >>> stamp = S(get_time_as_ntp64=lambda: S(as_nanos=lambda: 1_700_000_000_500_000_000))
    >>> receive_ns(stamp, 0, 2 * 10**18), receive_ns(stamp, 0, 5), receive_ns(None, 5, 9)
    (1700000000500000000, 5, 9)
    """
    if stamp is None:
        return now
    ns: int = stamp.get_time_as_ntp64().as_nanos()
    return floor if ns < floor else now if ns > now else ns


@dataclass
class LiveStats:
    received: int = 0
    overflow: int = 0  # lost in the node: none (a full intake holds Zenoh's links back); health "dropped"
    published: int = 0
    expired: int = 0  # beds freed after a silence
    unrecorded: int = 0  # messages not in the recording because it failed
    recording_error: str | None = None  # why the recording stopped, if it did
    engine_file_error: str | None = None  # why the engine state was last not saved, if so
    worker_error: str | None = None  # why the worker thread died, if it did


def quiet_gc() -> None:
    """Before a node takes messages: collect what is garbage now, freeze what is left (never
    traversed again: the loaded model, the core, the session) and raise the young generation's
    threshold (``GC_THRESHOLD``). Process-wide; calling it again (another node) is harmless."""
    gc.collect()
    gc.freeze()
    gc.set_threshold(*GC_THRESHOLD)


class LiveNode:
    """Subscribes to every test bed's sensors, predicts, publishes, records.

    A context manager: ``with LiveNode(...) as node:`` starts it and stops it (draining
    the queue, finishing the recording) on the way out. ``record`` is a path or a
    recorder with ``RecordingWriter``'s write/flush/close (e.g. ``RotatingRecorder``).

    >>> LiveStats().recording_error is None
    True
    """

    def __init__(self, bundle: Bundle | Model, record: str | RecordingWriter | RotatingRecorder,
                 listen: list[str] | None = None,
                 connect: list[str] | None = None, config_file: str | None = None,
                 queue_size: int = 1_000_000, engine_file: str | None = None, beds: str = "*",
                 max_beds: int = MAX_BEDS, max_channels: int = MAX_CHANNELS,
                 bed_expiry_s: float = BED_EXPIRY_S, clock: ClockPolicy | None = None,
                 health_silence_s: float = HEALTH_SILENCE_S) -> None:
        self.subscription = sensor_subscription(beds)  # ValueError for a bad pattern, before any I/O
        if not bed_expiry_s > 0:
            raise ValueError(f"bed_expiry_s must be > 0, got {bed_expiry_s}")
        if not 0 < health_silence_s <= HEALTH_SILENCE_MAX_S:  # NaN too
            raise ValueError(f"health_silence_s must be in (0, {HEALTH_SILENCE_MAX_S:g}], "
                             f"got {health_silence_s}")
        self.beds = beds  # the beds this node serves (a key-expression chunk, see sensor_subscription)
        self.bed_expiry_s = bed_expiry_s
        self.health_silence_s = health_silence_s  # a bed silent this long leaves the health rotation, s
        self.engine_file = engine_file  # each bed's engine history (node.edges.engine_file)
        self.core = NodeCore(bundle, load_engine_states(engine_file) if engine_file else None,
                             beds=beds, max_beds=max_beds, max_channels=max_channels, clock=clock,
                             defer_transients=True)
        self._analyses = TransientAnalyses()  # the transitions', in a process (started on demand)
        self._engine_saved: dict = {}  # what the file holds now
        self._engine_next = 0.0  # monotonic time of the next save
        self.writer = RecordingWriter(record) if isinstance(record, str) else record
        self.conf = zenoh_config(listen, connect, config_file)
        self.reach = Reach(connect_endpoints(self.conf), time.monotonic())  # restarted by start()
        # each sample stamped by the session's clock as it arrives (Zenoh's HLC, in its receive
        # path): the receive time, though the worker takes it later from the intake
        self.conf.insert_json5("timestamping/enabled", '{"router": true, "peer": true, "client": true}')
        if not 1 <= queue_size <= QUEUE_MAX:
            raise ValueError(f"queue_size must be 1-{QUEUE_MAX}, got {queue_size}")
        self.queue_size = queue_size  # messages the intake holds at most
        self._behind = True  # the last drain left messages waiting (or none ran yet)
        self._last_empty_ns = time.time_ns()  # when a drain last found the intake empty, ns
        self._empty_polls = 0  # drains in a row that found nothing
        self._fair = FairIntake()  # messages taken from Zenoh's FIFO while behind, not yet handled
        self.stats = LiveStats()
        self.token: Any = None
        self._stop = threading.Event()
        self._lag: dict[str, deque[float]] = {}  # bed -> receive-to-publish latencies, ms
        self._lag_max: dict[str, float] = {}  # bed -> the largest latency since its last health, ms
        self._last_recv: dict[str, int] = {}  # bed -> receive time of its newest message, ns
        self._node_health: dict = {}  # the last node health published, less its clock
        self._name = str(record)  # a path, or a recorder that names its file(s)
        self._written = 0  # messages the recorder took
        self._flushed = 0  # of them, those taken before its last successful flush
        self._spent = dict.fromkeys(("core", "put", "flush", "gc"), 0.0)  # s, this pass
        self._gc_start = 0.0
        self._cpu_mark = (0.0, 0)  # the worker's thread CPU time (s) and messages taken at its last tick
        self._cpu_us: float | None = None  # worker CPU per message over the last interval with any, us
        self._rotation = HealthRotation(HEALTH_MAX_PER_S)  # beds whose health is still to go out, the rate
        self._silent = 0  # beds tracked but out of the rotation (silent for health_silence_s)
        self._in_rotation = 0  # beds in the rotation at the last tick
        self.sensor_t: float | None = None  # the beds' latest sensor time, s (node health's t)

    @property
    def recording(self) -> bool:
        """Whether the recording is still being written."""
        return self.stats.recording_error is None

    def __enter__(self) -> LiveNode:
        self.start()
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    def start(self) -> None:
        import zenoh
        # see the module: never BLOCK on a subscriber
        self.attach(open_session(self.conf), zenoh.Encoding.APPLICATION_JSON, zenoh.CongestionControl.DROP)
        self.reach = Reach(self.reach.endpoints, time.monotonic())
        self.token = self.session.liveliness().declare_token(liveliness_key(str(self.session.zid())))
        quiet_gc()  # set up: what lives on is frozen before the first message
        intake: Any = zenoh.handlers.FifoChannel(self.queue_size)  # full: Zenoh holds the links back
        self.sub = self.session.declare_subscriber(self.subscription, intake)
        self.thread = threading.Thread(target=self._work, name="ordervib-node", daemon=True)
        self.thread.start()

    def attach(self, session: Any, encoding: Any = None, congestion: Any = None) -> None:
        """Publish on ``session`` (its ``put(key, bytes, encoding=, congestion_control=)``) with
        ``encoding`` and ``congestion`` control, without subscribing or starting the worker:
        ``start`` attaches a Zenoh session so; a benchmark or a test attaches a stand-in and drives
        ``handle_batch`` and ``publish`` itself."""
        self.session = session
        self._json = encoding
        self._congestion = congestion

    # -- recording: a failure stops it, never the node
    def _record_many(self, messages: Iterable[Row], n: int) -> None:
        """n (key, log time ns, receive time ns, payload) messages at once."""
        if self.stats.recording_error is None:
            try:
                self.writer.write_many(messages)  # may close a full chunk (compress, write)
                self._written += n
                return
            except Exception as exc:  # noqa: BLE001 - any recorder failure: go on without it
                self._recording_failed(exc)
        self.stats.unrecorded += n

    def _flush(self) -> None:
        if self.stats.recording_error is None:
            try:
                self.writer.flush()
                self._flushed = self._written
            except Exception as exc:  # noqa: BLE001
                self._recording_failed(exc)

    def _recording_failed(self, exc: BaseException) -> None:
        """The recorder failed: what it took since its last flush counts as lost, nothing more
        is written; the unfinished file is left as it is (``ordervib recover`` reads it)."""
        lost = self._written - self._flushed
        self.stats.recording_error = f"{type(exc).__name__}: {exc}"
        self.stats.unrecorded += lost
        log.error("recording to %s failed (%s); monitoring goes on unrecorded, %d messages lost so far",
                  self._name, self.stats.recording_error, lost)
        abandon = getattr(self.writer, "abandon", None)
        if abandon is not None:
            abandon()

    def _publish(self, key: str, msg: dict | Any) -> None:
        self.publish(((key, msg),))

    def publish(self, outs: Sequence[tuple[str, dict | Any]]) -> None:
        """Publish (key, message) outputs in turn, then record them (in the same order), each
        stamped with its publish time."""
        rows = self._send(outs)
        self._record_many(rows, len(rows))

    def _send(self, outs: Sequence[tuple[str, dict | Any]]) -> list[Row]:
        """Publish (key, message) outputs in turn; their rows for the recording, each stamped
        with its publish time (``_record_many``'s rows); a message whose ``t`` is None (the node's
        health before any sensor time) has none: the recording keeps the sensor clock's timeline.

        Each goes by ``Session.put``: no publisher is declared per key. Every key a session
        declares is a node of Zenoh's key tree, which its receive threads walk for each message on
        a key they have not resolved before (a wildcard key above all): with a publisher declared
        per topic of the 256 beds a flood fills, Zenoh's receive threads took 34 % of a core in the
        hostile soak, against 5 % without (docs/deployment.md). An undeclared put costs
        about 1 us more in this thread."""
        put_key, dumps, clock, wall = self.session.put, orjson.dumps, time.perf_counter, time.time_ns
        log_ns = log_time_ns
        enc, congestion = self._json, self._congestion
        rows = []
        put = 0.0
        for key, msg in outs:
            data = dumps(msg)
            t0 = clock()
            # waits at most Zenoh's wait_before_drop for a congested subscriber
            put_key(key, data, encoding=enc, congestion_control=congestion)
            put += clock() - t0
            t = msg["t"]
            if t is not None:  # (the node's health before any sensor time: published, not recorded)
                rows.append((key, log_ns(t), wall(), data))
        self._spent["put"] += put
        self.stats.published += len(outs)
        return rows

    def _drain(self) -> list[tuple[str, bytes, int]]:
        """The messages to handle now (at most ``BATCH_MAX``), each as (key, payload, receive time
        ns); none waiting: sleeps ``POLL_S`` (``IDLE_POLL_S`` once ``IDLE_POLLS`` looks found nothing).

        Keeping up (all that waited fits in a batch), they come in the order they arrived. Behind,
        the worker takes up to ``DRAIN_MAX`` more from Zenoh's FIFO into the fair intake (at most
        ``INTAKE_MAX`` held) and the batch comes from it, bed by bed, oldest first, a bed with a
        backlog after the others (``node.live.intake``): its catching up does not delay them.

        A message's receive time is its Zenoh timestamp (the session's clock as it arrived; see
        ``receive_ns``), within [the last time the intake was found empty, now]: a pass of the
        worker that takes long makes no silence of the beds whose messages waited meanwhile."""
        now, fair = time.time_ns(), self._fair
        out: list[tuple[str, bytes, int]] = []
        emptied = self._pull(out, BATCH_MAX if not fair else min(DRAIN_MAX, INTAKE_MAX - len(fair)), now)
        if fair or not emptied:  # behind: more from the FIFO, the batch from the fair intake
            if not fair:
                emptied = self._pull(out, DRAIN_MAX - len(out), now)
            fair.extend(out)
            out = fair.take(BATCH_MAX)
        self._behind = not emptied or bool(fair)  # more wait
        if not self._behind:
            self._last_empty_ns = time.time_ns()
        if out:
            self._empty_polls = 0
        else:
            self._empty_polls += 1
            time.sleep(POLL_S if self._empty_polls < IDLE_POLLS else IDLE_POLL_S)
        return out

    def _pull(self, out: list[tuple[str, bytes, int]], n: int, now: int) -> bool:
        """Up to n messages from Zenoh's FIFO appended to ``out`` (``_drain``'s tuples); whether
        the FIFO was found empty."""
        take, append, floor = self.sub.try_recv, out.append, self._last_empty_ns
        for _ in range(n):
            sample = take()
            if sample is None:
                return True
            append((str(sample.key_expr), sample.payload.to_bytes(),
                    receive_ns(sample.timestamp, floor, now)))
        return False

    def _bed(self, key: str) -> str | None:
        """The bed of an admitted sensor key, None for any other key (the core's one parse)."""
        route = self.core.known(key)
        return route[0] if route else None

    def handle_batch(self, batch: Sequence[tuple[str, bytes, int]]) -> None:
        """One batch of messages (key, payload, receive time ns), as the worker takes them: the
        node's logic over it, each admitted input recorded, then the outputs it completed published
        and recorded (``recording_rows``); refused inputs are counted by the core, nothing more."""
        keys, payloads, recv = zip(*batch, strict=True)
        self.stats.received += len(batch)
        t0 = time.perf_counter()
        result = self.core.handle_batch(keys, payloads, recv)
        self._spent["core"] += time.perf_counter() - t0
        last = self._last_recv
        for bed, r in result.newest.items():  # each bed's newest receipt
            if r > last.get(bed, 0):
                last[bed] = r
        # each input's log time (ns) as log_time_ns takes it; a malformed one at its receive time
        if len(batch) < SMALL_LOG:  # (log_time_ns of each, as log_times_ns gives them)
            log_ns = [round((x if x == x else r / 1e9) * 1e9) for x, r in zip(result.t.tolist(), recv)]
        else:
            log_ns = log_times_ns(np.where(np.isnan(result.t), np.array(recv) / 1e9, result.t)).tolist()

        def publish(i: int, outs: Sequence[tuple[str, dict | Any]]) -> list[Row]:
            """The outputs input i completed, published now; their latency noted on its bed."""
            rows = self._send(outs)
            lag = (time.time_ns() - recv[i]) / 1e6
            bed = self._bed(keys[i]) or ""
            lags = self._lag.get(bed)
            if lags is None:
                lags = self._lag[bed] = deque(maxlen=LAG_KEPT)
            lags.append(lag)
            if lag > self._lag_max.get(bed, 0.0):
                self._lag_max[bed] = lag
            return rows

        # the batch's recording, written at once
        rows = recording_rows(list(zip(keys, log_ns, recv, payloads)), result.done, result.refused, publish)
        if rows:
            self._record_many(rows, len(rows))

    def _on_gc(self, phase: str, info: dict) -> None:  # gc.callbacks: time the collections
        if phase == "start":
            self._gc_start = time.perf_counter()
        else:
            self._spent["gc"] += time.perf_counter() - self._gc_start

    def _work(self) -> None:
        gc.callbacks.append(self._on_gc)
        self._cpu_mark = (time.thread_time(), self.stats.received)  # this thread's clock
        try:
            next_tick = time.monotonic() + 1.0
            next_idle = time.monotonic()
            while not (self._stop.is_set() and not self._behind):
                t0 = time.perf_counter()
                spent = self._spent = dict.fromkeys(self._spent, 0.0)
                batch = self._drain()
                if batch:
                    self.handle_batch(batch)
                if self._rotation.due:
                    self._publish_health(HEALTH_PER_PASS)
                self._publish_analysed()
                if time.monotonic() >= next_idle:
                    now = None if self._behind else self._last_empty_ns  # behind, a silence is not known
                    if now is not None:  # (every message received before now is handled)
                        next_idle = time.monotonic() + IDLE_CHECK_S
                        self.publish(self.core.flush_idle(now, IDLE_MARGIN_NS))
                if time.monotonic() >= next_tick:
                    next_tick = max(next_tick + 1.0, time.monotonic())  # no burst after a long batch
                    self._tick()
                took = time.perf_counter() - t0
                if took > STALL_S:  # where the time went (gc overlaps the others)
                    rest = took - spent["core"] - spent["put"] - spent["flush"]
                    log.warning("worker stalled %.2f s over %d messages (%s, recording and rest %.2f s)",
                                took, len(batch), ", ".join(f"{k} {v:.2f} s" for k, v in spent.items()), rest)
            self._publish_health(len(self._rotation.due))  # this rotation's last ones, within the rate
            self._publish_analysed(wait=True)  # every transition before the stream's end first
            self.publish(self.core.finish())
            self._publish_analysed(wait=True)  # the runs' last ones
        except BaseException as exc:  # the node is dead: say so at once, never look alive
            self.stats.worker_error = f"{type(exc).__name__}: {exc}"
            log.debug("the worker thread died", exc_info=True)
            self._withdraw()
        finally:
            self._analyses.close()
            gc.callbacks.remove(self._on_gc)

    def _withdraw(self) -> None:
        """Undeclare the liveliness token (once)."""
        token, self.token = self.token, None
        if token is not None:
            try:
                token.undeclare()
            except Exception:  # noqa: BLE001 - the session may be gone already
                pass

    @property
    def unrecorded(self) -> int:
        """Messages not in the recording: since it failed, or refused by its channel table."""
        return self.stats.unrecorded + self.writer.refused

    def health(self, bed: str, wall: float) -> HealthMessage:
        """``bed``'s health message: the core's counters, with this node's clock, staleness,
        latency and recording state (docs/deployment.md, "Health and liveliness"); ``dropped``
        is 0: the node loses no message (see the module)."""
        lags = sorted(self._lag.get(bed, ()))
        lag = (lags[len(lags) // 2], lags[int(0.99 * (len(lags) - 1))]) if lags else (None, None)
        msg = self.core.health(bed, wall, 0, lag)
        last = self._last_recv.get(bed)
        msg["staleness"] = None if last is None else round(wall - last / 1e9, 6)
        msg["lag_ms_max"] = self._lag_max.pop(bed, None)
        msg["recording"] = self.recording
        msg["unrecorded"] = self.unrecorded
        msg["engine_state"] = None if self.engine_file is None else self.stats.engine_file_error is None
        msg["node"] = self.node_id
        msg["beds"] = self.beds
        return msg

    @property
    def node_id(self) -> str:
        """The node's Zenoh id ("" before it started)."""
        session = getattr(self, "session", None)
        return str(session.zid()) if session is not None else ""

    def node_health(self, wall: float) -> NodeHealthMessage:
        """The node's own health: what belongs to no bed (``NodeHealthMessage``); ``t`` the beds'
        latest sensor time (``sensor_t``, None before any), ``wall`` the node's clock."""
        refused = {r.value: self.core.refused[r.value] for r in Refused}
        refused[Refused.RECORDING.value] = self.writer.refused
        reach = self.reach
        return {"t": self.sensor_t, "wall": wall, "node": self.node_id, "beds": self.beds,
                "received": self.stats.received, "dropped": self.stats.overflow, "refused": refused,
                "tracked": len(self.core.beds), "max_beds": self.core.max_beds,
                "max_channels": self.core.max_channels, "expired": self.stats.expired,
                "silent": self._silent, "health_every_s": self._rotation.period_s(self._in_rotation),
                "recording": self.recording, "unrecorded": self.unrecorded,
                "cpu_us_per_message": self._cpu_us, "worker_lag_s": self._worker_lag(),
                "clock": self.core.clock.settings(), "connected": reach.connected,
                "routers": reach.routers, "peers": reach.peers}

    def _worker_lag(self) -> float:
        """How long ago the worker last found the intake empty, s: at least the wait of any message
        waiting now (a worker that keeps up finds it empty every pass, a few ms apart)."""
        return round(max(0, time.time_ns() - self._last_empty_ns) / 1e9, 6)

    def _measure_cpu(self) -> None:
        """In the worker: its CPU time per message taken since the last call (kept as it was
        when none was taken). ``time.thread_time``: the worker is the node's one thread that
        must keep up (it also takes the messages from Zenoh's FIFO); process time would add Zenoh's
        own threads and anything else running in the process (tests, a second node)."""
        cpu, taken = time.thread_time(), self.stats.received
        last_cpu, last_taken = self._cpu_mark
        self._cpu_mark = (cpu, taken)
        if taken > last_taken:
            self._cpu_us = round((cpu - last_cpu) / (taken - last_taken) * 1e6, 1)

    def _tick(self) -> None:
        """Once a second: silent beds expired, the beds' health in turn (``node.live.health_rate``),
        the node's own when it changed, and the recording flushed."""
        self._measure_cpu()
        wall = time.time()
        self._expire(wall)
        self._publish_health(len(self._rotation.due))  # the rotation's left-overs first, within the rate
        self._rotate()
        self._publish_health(HEALTH_PER_PASS)
        info = getattr(getattr(self, "session", None), "info", None)  # (a stand-in session has none)
        if info is not None:
            self.reach.check(info, time.monotonic())
        node = self.node_health(wall)
        counters = {k: v for k, v in node.items() if k not in ("t", "wall")}
        if counters != self._node_health:
            self._node_health = counters
            self._publish(node_health_key(node["node"]), node)  # (no sensor time yet: not recorded)
        t0 = time.perf_counter()
        self._flush()
        if time.monotonic() >= self._engine_next:
            self._engine_next = time.monotonic() + SAVE_EVERY_S
            self._save_engines()
        self._spent["flush"] += time.perf_counter() - t0

    def _submit_analyses(self) -> None:
        """The transitions the core left unanalysed (``NodeCore.pending``) to their process."""
        pending = self.core.pending
        for key, tr in pending:
            self._analyses.submit(key, tr)
        pending.clear()

    def _publish_analysed(self, wait: bool = False) -> None:
        """The analysed transitions' messages, in the order they ended, as far as they are done
        (``wait``: all, waiting for them). An analysis that failed fails the worker, as it would
        have inline."""
        self._submit_analyses()
        outs = [self.core.resolved(key, msg) for key, msg in self._analyses.done(wait)]
        if outs:
            self.publish(outs)

    def _rotate(self) -> None:
        """At a tick: the beds' latest sensor time, the beds out of the health rotation (silent
        for ``health_silence_s``) counted, and, the last rotation done, the next one queued: each
        bed with a sensor time heard from within the silence (a bed of malformed messages has
        no time)."""
        timed = [(bed, state.latest_t) for bed, state in self.core.beds.items() if state.latest_t is not None]
        if timed:
            self.sensor_t = max(t for _, t in timed)
        now, silence, last = time.time_ns(), int(self.health_silence_s * 1e9), self._last_recv
        rotation = [bed for bed, _ in timed if now - last.get(bed, now) <= silence]
        self._silent = len(timed) - len(rotation)
        self._in_rotation = len(rotation)
        self._rotation.refill(rotation)

    def _publish_health(self, n: int) -> None:
        """The health of the next ``n`` beds of the rotation (``_tick``), each still tracked, as
        far as the rate allows."""
        beds = self.core.beds
        outs = [(health_key(bed), self.health(bed, time.time()))
                for bed in self._rotation.take(n, time.monotonic())
                if bed in beds]  # (not expired since the tick)
        if outs:
            self.publish(outs)
            self._rotation.note(len(outs), time.monotonic())

    def _expire(self, wall: float) -> None:
        """Free the beds silent (receive time) for ``bed_expiry_s``: their waiting samples run and
        go out, a last health message says ``expired: true`` (within the health rate: a bed whose
        last health finds no room waits for a later tick)."""
        now = time.time_ns()
        silence = int(self.bed_expiry_s * 1e9)
        room = self._rotation.room(time.monotonic())
        gone: list[str] = []
        silent = [name for name in self.core.beds if now - self._last_recv.setdefault(name, now) > silence]
        for name in silent:
            if self.core.beds[name].latest_t is not None:
                if room <= 0:
                    continue  # its last health: at a later tick
                room -= 1
            gone.append(name)
        for name in gone:
            for key, msg in self.core.flush_bed(name):
                self._publish(key, msg)
            state = self.core.beds[name]
            if state.latest_t is not None:
                last = self.health(name, wall)
                last["expired"] = True
                self._publish(health_key(name), last)
                self._rotation.note(1, time.monotonic())
            self.core.forget(name)
            for per_bed in (self._lag, self._lag_max, self._last_recv):
                per_bed.pop(name, None)
        if gone:
            self.stats.expired += len(gone)
            log.info("%d bed(s) silent for %g s expired, their state freed: %s%s", len(gone),
                     self.bed_expiry_s, ", ".join(gone[:5]), ", ..." if len(gone) > 5 else "")

    def _save_engines(self) -> None:
        """Each bed's engine history to its file, when it changed; a failure is logged (once), shown
        in health and, if the last save fails, ends ``run_node`` with an error; never fatal here."""
        if self.engine_file is None:
            return
        states = self.core.engine_states()
        doc = engine_document(states)
        if doc == self._engine_saved:
            return
        try:
            save_engine_states(self.engine_file, states)
            self._engine_saved = doc
            self.stats.engine_file_error = None
        except OSError as exc:
            if self.stats.engine_file_error is None:
                log.error("engine state %s not saved (%s); monitoring goes on", self.engine_file, exc)
            self.stats.engine_file_error = f"{type(exc).__name__}: {exc}"

    def stop(self) -> None:
        """Stop receiving, drain the intake, finish the recording (unless it failed), close the session."""
        self._stop.set()
        try:
            self.sub.undeclare()
        except Exception:  # noqa: BLE001 - the session may be gone already
            pass
        self.thread.join()
        self._withdraw()
        self._save_engines()
        if self.recording:
            try:
                self.writer.close()
            except Exception as exc:  # noqa: BLE001
                self._recording_failed(exc)
        self.session.close()


def run_node(bundle: Bundle | Model, record: str | RecordingWriter | RotatingRecorder,
             listen: list[str] | None, connect: list[str] | None, config_file: str | None,
             duration: float | None, engine_file: str | None = None, beds: str = "*",
             max_beds: int = MAX_BEDS, max_channels: int = MAX_CHANNELS,
             bed_expiry_s: float = BED_EXPIRY_S, clock: ClockPolicy | None = None,
             health_silence_s: float = HEALTH_SILENCE_S) -> LiveStats:
    """The node until SIGINT, SIGTERM or ``duration`` seconds; status lines are logged, the
    closing counts returned (``ordervib run`` prints them: its result).

    Raises ``OrdervibError`` (one line) when the worker thread died (the watchdog stops
    the node within ``WATCHDOG_S``) or when the recording failed.
    """
    import signal
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    deadline = None if duration is None else time.monotonic() + duration
    with LiveNode(bundle, record, listen, connect, config_file, engine_file=engine_file, beds=beds,
                  max_beds=max_beds, max_channels=max_channels, bed_expiry_s=bed_expiry_s,
                  clock=clock, health_silence_s=health_silence_s) as node:
        where = ", ".join(listen or connect or []) or f"the endpoints of {config_file}"
        log.info("ordervib node on %s, serving beds %s; recording to %s; per-sample modules %s; Ctrl-C stops",
                 where, beds, record, native.state())
        while node.thread.is_alive():  # the watchdog
            wait = WATCHDOG_S if deadline is None else min(WATCHDOG_S, deadline - time.monotonic())
            if stop.wait(max(0.0, wait)) or (deadline is not None and time.monotonic() >= deadline):
                break
    s = node.stats
    if s.worker_error is not None:
        raise OrdervibError(f"the node's worker thread died ({s.worker_error}) after {s.received} "
                            f"messages; liveliness token withdrawn")
    if s.engine_file_error is not None and s.recording_error is None:
        raise OrdervibError(f"engine state {engine_file} not saved ({s.engine_file_error}): what the "
                            f"node learnt of the engines since its last save is lost; monitoring went on "
                            f"({s.received} received, {s.published} published), {record} finished")
    if s.recording_error is not None:
        raise OrdervibError(f"the recording {record} failed ({s.recording_error}): {s.unrecorded} "
                            f"messages unrecorded; monitoring went on ({s.received} received, "
                            f"{s.published} published)")
    return s
