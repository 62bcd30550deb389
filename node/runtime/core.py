"""Messages in, messages out: the node's logic over every test bed, without I/O.

``NodeCore.handle_batch(keys, payloads)`` takes sensor messages as they arrived (key
expressions and raw JSON bytes), decodes them by the contract's payload rule
(``node.contract.decode_samples``), aligns each bed's (``Aligner.push_columns``; a bed's few
messages of a live batch ``Aligner.push_list``, the same steps without numpy) and
runs each bed's ``MonitorPipeline`` of each target of the model (one aligner per bed over
the channels every target needs; the OC message once per bed, from the first target's
pipeline: the targets share schedule and settings, so one OC detector per bed serves them all,
stepped once per sample by the first); it returns
each message's decoded time and the monitor messages each message completed. ``handle`` is
a batch of one. Malformed payloads are counted (per bed) and skipped; channels no model needs
are ignored. The live node and offline replay both drive this class, through ``handle_batch``,
and record what it did by one rule, ``recording_rows``.

Admission (``route``, the one parse and cache of input keys): a message is taken only on a
sensor key by the contract's name rule (``parse_sensor_key``), of a bed the ``beds`` pattern
admits, while the node tracks fewer than ``max_beds`` beds (or the bed already), and on one of
the bed's first ``max_channels`` channels (the model's channels always count among them). Any
other message is refused: counted per reason (``Refused``; node-wide in ``refused``, and on its
bed where it has one), and nothing else: no bed, no state, no cache entry. So the state, the
cache of keys and the topics a node records are bounded whatever arrives. A bed's state is freed
by ``forget`` (the live node's expiry of silent beds); its engine history is kept if it is known.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import compress
from types import MappingProxyType
from typing import NamedTuple, TypeVar

import numpy as np

from node.contract import (
    Flag,
    HealthMessage,
    Refused,
    bed_matcher,
    bed_of,
    decode_samples,
    monitor_key,
    oc_key,
    parse_sensor_key,
    sensor_key,
    transient_key,
    verdict_key,
)
from node.contract.payload import decode_list
from node.models.bundle import Bundle, Model, as_model
from node.models.forecast import MIN_RUNS
from node.runtime.alarms import EpisodeLog
from node.runtime.align import SMALL_BATCH, AlignedSample, Aligner
from node.runtime.clock import ClockPolicy
from node.runtime.history import HISTORY_CHANNELS, EngineState
from node.runtime.pipeline import MonitorPipeline
from node.runtime.transient_watch import PendingTransient

Output = tuple[str, dict]  # (key expression, JSON-ready message)
Route = tuple[str, str]  # (bed, channel) of an admitted sensor key
Row = tuple[str, int, int, bytes]  # a recorded message: key, log time ns, publish time ns, JSON bytes

log = logging.getLogger(__name__)

MAX_BEDS = 256  # beds tracked at once at most, by default (ordervib run --max-beds)
MAX_CHANNELS = 64  # channels of a bed at most, by default, the model's among them (--max-channels)


class Batch(NamedTuple):
    """What ``NodeCore.handle_batch`` did with a batch of n messages."""

    t: np.ndarray  # (n,) each payload's sensor time, s; NaN where malformed
    done: list[tuple[int, list[Output]]]  # (i, outputs) of each message i that completed outputs
    refused: np.ndarray | None = None  # (n,) True where the message was refused; None: none was
    # each bed's newest receive time (ns) among its admitted messages, malformed ones too
    # (empty when no receive times were given)
    newest: Mapping[str, int] = MappingProxyType({})


Out = TypeVar("Out")  # what a message completed: outputs, or their encoded form


def recording_order(n: int, done: Iterable[tuple[int, Sequence[Out]]]
                    ) -> Iterator[tuple[int, int, Sequence[Out]]]:
    """The order in which a node records a batch of n messages and what they completed: steps
    (start, stop, outputs), the messages [start, stop) and then the outputs message stop - 1
    completed (none in a last step of the messages after the last that completed any).

    done: (i, outputs) in message order, as ``Batch.done``. The live node and offline replay
    both write their recordings in this order, so they write the same bytes.

    >>> list(recording_order(5, [(1, ["a", "b"]), (3, ["c"])]))
    [(0, 2, ['a', 'b']), (2, 4, ['c']), (4, 5, ())]
    >>> list(recording_order(2, [(1, ["a"])]))
    [(0, 2, ['a'])]
    """
    start = 0
    for i, outs in done:
        yield start, i + 1, outs
        start = i + 1
    if start < n:
        yield start, n, ()


def recording_rows(inputs: Sequence[Row], done: Iterable[tuple[int, Sequence[Out]]],
                   refused: np.ndarray | None,
                   outputs: Callable[[int, Sequence[Out]], Iterable[Row]]) -> list[Row]:
    """A batch's recording, the one rule of the live node and offline replay: the batch's inputs
    in arrival order, each refused one left out (never recorded), and right after each input i
    that completed outputs the rows ``outputs(i, outs)`` gives them (``recording_order``).

    inputs: the batch's n messages as rows; done: (i, outputs) in message order, as
    ``Batch.done``; refused: ``Batch.refused`` ((n,) bool, or None: none was). ``outputs``
    stamps the outputs: log time their ``t`` (``log_time_ns``), publish time the moment the live
    node published them, or, offline, the log time of the input that completed them.

    >>> rows = [("a", 1, 1, b""), ("bad*key", 2, 2, b""), ("b", 3, 3, b"")]
    >>> def stamp(i, outs):
    ...     return [(key, 9, rows[i][1], b"") for key in outs]
    >>> [(r[0], r[2]) for r in recording_rows(rows, [(0, ["m"]), (2, ["n"])], None, stamp)]
    [('a', 1), ('m', 1), ('bad*key', 2), ('b', 3), ('n', 3)]
    >>> [r[0] for r in recording_rows(rows, [(2, ["n"])], np.array([False, True, False]), stamp)]
    ['a', 'b', 'n']
    """
    keep = None if refused is None else (~refused).tolist()
    out: list[Row] = []
    for start, stop, outs in recording_order(len(inputs), done):
        if stop > start:  # the inputs up to the one that completed these outputs
            out += inputs[start:stop] if keep is None else compress(inputs[start:stop], keep[start:stop])
        if outs:
            out += outputs(stop - 1, outs)
    return out


@dataclass
class Bed:
    """One test bed: its aligner, a pipeline per target (in the model's order) and its monitor
    keys, and its counters (``aligner.stats`` holds samples, late, duplicates and missing per
    channel)."""

    aligner: Aligner
    pipelines: list[MonitorPipeline]
    keys: list[str]  # monitor key of each pipeline's target
    needed: frozenset[str]  # the channels its pipelines need
    extra: set[str] = field(default_factory=set)  # the other channels it was admitted with
    refused: Counter[str] = field(default_factory=Counter)  # its messages refused, per reason
    received: int = 0  # messages on its sensor keys
    malformed: int = 0  # of them, payloads that break the payload rule
    alarm_samples: int = 0  # alarm messages, every target
    latest_t: float | None = None  # its clock: the newest sensor time its aligner took (else seen), s
    last_recv: int | None = None  # the newest receive time of its well-formed messages, ns

    @property
    def pipeline(self) -> MonitorPipeline:
        """The first target's pipeline (its OC detector and engine history are the bed's)."""
        return self.pipelines[0]


class NodeCore:
    """The logic of the node over every bed, created on the bed's first admitted message.

    model: a one-target ``Bundle`` or a ``Model`` of several targets (``monitor/<target>``
    each, every aligned sample in the model's target order, after the bed's OC message).

    >>> from node.contract.schedule import OperatingCondition, Schedule
    >>> core = NodeCore(Bundle("wdmd", "yB", Schedule((OperatingCondition("A", 4000.0),)), []))
    >>> core.handle("testbed/b1/sensor/nB", b'{"t": 100.0, "v": 4000.0}')
    []
    >>> core.handle("testbed/b1/sensor/yB", b'{"t": 100.011, "v": 2.5}')  # completes a sample...
    []
    >>> out = core.handle("testbed/b1/sensor/nB", b'{"t": 100.25, "v": 4000.0}')  # ...a run's first
    >>> [(key, msg["flag"].value) for key, msg in out]  # goes out after 0.25 s of data (the wait)
    [('testbed/b1/monitor/yB', 'no-model')]
    >>> core.handle("testbed/b1/sensor/yB", b'{"t": "soon"}'), core.beds["b1"].malformed
    ([], 1)
    >>> h = core.health("b1", wall=1700000000.0)
    >>> h["t"], h["received"], h["samples"], h["missing"], h["late_by_channel"]
    (100.25, 4, 1, {}, {})
    >>> {c: round(ms, 1) for c, ms in h["phase_ms"].items()}  # each channel's clock phase
    {'nB': 0.0, 'yB': 11.0}
    >>> core.handle("testbed/*/sensor/nB", b'{"t": 100.3, "v": 1.0}'), dict(core.refused), list(core.beds)
    ([], {'key': 1}, ['b1'])
    """

    def __init__(self, model: Bundle | Model, engines: Mapping[str, EngineState] | None = None,
                 beds: str = "*", max_beds: int = MAX_BEDS, max_channels: int = MAX_CHANNELS,
                 clock: ClockPolicy | None = None, defer_transients: bool = False) -> None:
        """engines: each bed's engine history before (a state file's); others start unknown.
        beds: the pattern of the beds admitted (``sensor_subscription``'s); max_beds: beds tracked
        at once at most; max_channels: channels per bed at most (the model's always admitted);
        clock: every bed's clock guard (``ClockPolicy``; default its defaults); defer_transients:
        a transition's end is not analysed in the outputs but left in ``pending`` (the live node
        analyses it in another process and hands the message back to ``resolved``)."""
        if max_beds < 1 or max_channels < 1:
            raise ValueError(f"max_beds and max_channels must be >= 1, got {max_beds}, {max_channels}")
        self.model = as_model(model)
        unforecast = [b.target for b in self.model.bundles if b.schedule.limits_of(b.target)
                      and (b.forecast is None or len(b.forecast.peak) < MIN_RUNS)]
        if unforecast:  # said once: a bundle trained before the verdict's forecast kept no peaks
            log.warning("the model keeps no training peaks for %s (trained before the forecast, or on "
                        "fewer than %d runs): its verdicts carry no forecast", ", ".join(unforecast),
                        MIN_RUNS)
        self._admits = bed_matcher(beds)  # ValueError for a bad pattern
        self.max_beds = max_beds
        self.max_channels = max_channels
        self.clock = clock or ClockPolicy()
        self._engines = dict(engines or {})
        # the slow temperatures feed the bed's engine history when any target's models use it
        self._slow_temperatures = any(c in HISTORY_CHANNELS for b in self.model.bundles for c in b.inputs)
        self.beds: dict[str, Bed] = {}
        self.refused: Counter[str] = Counter()  # messages refused, per reason (Refused), every bed
        self.published = 0  # outputs returned
        self.defer_transients = defer_transients
        self.pending: list[tuple[str, PendingTransient]] = []  # (key, transition) not yet analysed
        self.alarm_log = EpisodeLog(self.model.config.episode_gap_s)  # alarm episodes, every bed
        self.verdict_log: list[Output] | None = None  # a list: every verdict message kept (replay's report)
        self._routes: dict[str, Route] = {}  # admitted key -> (bed, channel): the tracked beds' only
        # a bed silent this long on the node's clock (receive times) has its waiting slots emitted
        self.idle_ns = round(self.model.config.align_wait_s * 1e9)

    @property
    def foreign(self) -> int:
        """Messages on keys that are no sensor keys by the contract's rule (every bed)."""
        return self.refused[Refused.KEY]

    @property
    def malformed(self) -> int:
        """Malformed payloads, every bed."""
        return sum(b.malformed for b in self.beds.values())

    def handle(self, key: str, payload: bytes) -> list[Output]:
        """One incoming message; returns the outputs it completes (in order)."""
        done = self.handle_batch([key], [payload]).done
        return done[0][1] if done else []

    def handle_batch(self, keys: Sequence[str], payloads: Sequence[bytes],
                     recv: Sequence[int] | np.ndarray | None = None) -> Batch:
        """Messages in the order they arrived, with the very effects of one at a time.

        recv: each message's receive time on the node's clock, ns (the recording's publish time);
        before a bed's message received ``idle_ns`` or more after its previous one, the bed's
        waiting slots are emitted (``flush_idle``'s rule, at the latest moment a replay knows of);
        None: no receive times, the wait is on sensor time only."""
        if len(keys) != len(payloads):
            raise ValueError(f"{len(keys)} keys but {len(payloads)} payloads")
        v: np.ndarray | None = None  # the values as an array: for a bed's SMALL_BATCH messages or more
        if len(payloads) < SMALL_BATCH:  # a live batch: Python lists (one array: Batch.t)
            tl, vl, okl = decode_list(payloads)
            t = np.array(tl, dtype=np.float64)
            received = None if recv is None else (recv.tolist() if isinstance(recv, np.ndarray)
                                                  else list(map(int, recv)))
        else:
            t, v, ok = decode_samples(payloads)
            tl, vl, okl = t.tolist(), v.tolist(), ok.tolist()
            received = None if recv is None else np.asarray(recv, dtype=np.int64).tolist()
        cached, admit = self._routes.get, self.route  # admitted in arrival order
        routes = {key: cached(key) or admit(key) for key in dict.fromkeys(keys)}
        admitted = {key: route for key, route in routes.items() if type(route) is tuple}
        refused = None
        parts: list[tuple[str, Sequence[int]]]
        names = {route[0] for route in admitted.values()}
        if len(names) == 1 and len(admitted) == len(routes):  # the common batch: one bed, sensor keys
            parts = [(names.pop(), range(len(keys)))]
        else:  # each bed's messages, beds in the order of their first message (Python lists: a
            groups: dict[str, list[int]] = {}  # live batch holds a few messages per bed)
            unroutable = []
            for i, key in enumerate(keys):
                route = admitted.get(key)
                if route is None:
                    unroutable.append(i)
                else:
                    group = groups.get(route[0])
                    if group is None:
                        group = groups[route[0]] = []
                    group.append(i)
            if unroutable:
                refused = np.zeros(len(keys), dtype=bool)
                refused[unroutable] = True
                self._count_refused(Counter(keys[i] for i in unroutable), routes)
            parts = list(groups.items())
        done: list[tuple[int, str, list[AlignedSample]]] = []
        receipts: dict[str, int] = {}  # Batch.newest
        for name, idx in parts:
            bed = self.beds[name]
            if received is not None:
                receipts[name] = max(received) if len(idx) == len(keys) else max([received[i] for i in idx])
            good = [i for i in idx if okl[i]]
            bed.received += len(idx)
            bed.malformed += len(idx) - len(good)
            if not good:
                continue
            whole = len(good) == len(keys)
            channels = [admitted[key][1] for key in keys] if whole else [admitted[keys[i]][1] for i in good]
            tg: Sequence[float] | np.ndarray
            vg: Sequence[float] | np.ndarray
            if len(good) >= SMALL_BATCH:  # (then the batch was decoded as arrays)
                assert v is not None
                tg, vg = (t, v) if whole else (t[good], v[good])
            else:
                tg, vg = (tl, vl) if whole else ([tl[i] for i in good], [vl[i] for i in good])
            if bed.aligner.clock is None:  # no confirmed clock yet (node.runtime.clock)
                newest = max(tl[i] for i in good)
                bed.latest_t = newest if bed.latest_t is None else max(bed.latest_t, newest)
            # numpy for a bed's many messages (replay), Python lists for a few (live): the same steps
            push: Callable[..., list[tuple[int, list[AlignedSample]]]] = \
                bed.aligner.push_columns if len(good) >= SMALL_BATCH else bed.aligner.push_list
            rg = None if received is None else (received if whole else [received[i] for i in good])
            cuts = [] if rg is None else self._idle_cuts(bed, rg)
            starts = [0, *cuts] if cuts and cuts[0] else cuts or [0]
            for a, b in zip(starts, [*starts[1:], len(good)], strict=True):
                flushed = bed.aligner.flush() if cuts and a in cuts else []
                if b - a == len(good):
                    part = push(channels, tg, vg, rg)
                else:
                    part = push(channels[a:b], tg[a:b], vg[a:b], None if rg is None else rg[a:b])
                if flushed and part and part[0][0] == 0:  # the message after the silence completed some too
                    flushed += part.pop(0)[1]
                if flushed:
                    done.append((good[a], name, flushed))
                done += [(good[a + j], name, samples) for j, samples in part]
            if bed.aligner.clock is not None:
                bed.latest_t = bed.aligner.clock
        if len(parts) > 1:
            done.sort(key=lambda x: x[0])  # each bed's aligner is independent; outputs in message order
        return Batch(t, [(i, self._run(name, samples)) for i, name, samples in done], refused, receipts)

    def _idle_cuts(self, bed: Bed, recv: list[int]) -> list[int]:
        """Where a bed's messages (receive times recv, ns, in arrival order) come ``idle_ns`` or
        more after the newest receipt before them: each such message index; the bed's newest
        receipt is advanced."""
        prev = bed.last_recv
        newest = recv[0] if prev is None else prev  # the bed's first message: nothing waits before it
        idle = self.idle_ns
        cuts = []
        for j, r in enumerate(recv):
            if r - newest >= idle:
                cuts.append(j)
            if r > newest:
                newest = r
        bed.last_recv = newest
        return cuts

    def flush_idle(self, now: int, margin: int = 0) -> list[Output]:
        """The node's clock is ``now`` (ns): every bed silent ``idle_ns + margin`` or more since its
        newest receipt has its waiting slots emitted; their outputs, bed by bed.

        The live node calls this on a timer so that a bed that falls silent gets its last slots
        out about ``align_wait_s`` after its last message. It changes nothing a replay would not
        do: the bed's next message (received later still) would have flushed them first
        (``handle_batch``), and at the end of a recording ``finish`` does. ``margin`` keeps a
        message received (stamped) before ``now`` but not yet handed over from counting as later."""
        out: list[Output] = []
        for name, bed in self.beds.items():
            if bed.last_recv is not None and now - bed.last_recv >= self.idle_ns + margin:
                samples = bed.aligner.flush()
                if samples:
                    out += self._run(name, samples)
        return out

    def _count_refused(self, counts: Mapping[str, int], routes: Mapping[str, Route | Refused]) -> None:
        """Count refused messages (n per key) per reason, node-wide and on their bed if tracked."""
        for key, n in counts.items():
            reason = routes[key]
            assert isinstance(reason, Refused)
            self.refused[reason.value] += n
            name = bed_of(key) if reason in (Refused.KEY, Refused.CHANNEL_LIMIT) else None
            bed = self.beds.get(name) if name is not None else None
            if bed is not None:
                bed.refused[reason.value] += n

    def handle_aligned(self, bed: str, samples: Sequence[AlignedSample]) -> list[Output]:
        """Samples already on the 40 Hz grid (a planned profile, a synthetic stream): the bed's
        pipelines step on them as on the aligner's samples (the aligner and its counters are
        left out); returns the outputs in order."""
        self._bed(bed)
        return self._run(bed, list(samples))

    def finish(self) -> list[Output]:
        """End of stream: emit every sample still waiting for late channels."""
        out: list[Output] = []
        for name, bed in self.beds.items():
            out += self._run(name, bed.aligner.end())
            ended: list[Output] = []
            for p in bed.pipelines:  # each target's last transition and the verdict of its run
                self._transient(transient_key(name), p.end_transient(), ended)
                verdict = p.end_verdict()
                if verdict is not None:
                    ended.append((verdict_key(name), verdict))
                    self._keep_verdicts(ended[-1:])
            out += ended
            self.published += len(ended)
        return out

    def _keep_verdicts(self, outs: list[Output]) -> None:
        """Verdict messages into ``verdict_log`` when it is kept."""
        if self.verdict_log is not None:
            self.verdict_log += outs

    def _transient(self, key: str, msg: dict | PendingTransient | None, out: list[Output]) -> None:
        """A transition's message into ``out`` (deferred: into ``pending``)."""
        if isinstance(msg, PendingTransient):
            self.pending.append((key, msg))
        elif msg is not None:
            self.alarm_log.add(key, msg)
            out.append((key, msg))

    def resolved(self, key: str, msg: dict) -> Output:
        """A deferred transition's message (``pending``'s, analysed): counted as an output, its
        alarm in the episodes, as if it had gone out at once."""
        self.alarm_log.add(key, msg)
        self.published += 1
        return key, msg

    def flush_bed(self, name: str) -> list[Output]:
        """One bed's samples still waiting for late channels, run now; their outputs in order."""
        return self._run(name, self.beds[name].aligner.flush())

    def forget(self, name: str) -> None:
        """Free a bed's state (its slot among ``max_beds``, its keys in the cache); its engine
        history is kept for its return when known (the engine ran). A new message of the bed
        admits it again, from fresh counters."""
        bed = self.beds.pop(name)
        state = bed.pipeline.history.state
        if state.last_on_t is not None:
            self._engines[name] = state
        else:  # never ran: nothing worth keeping (a flood of names must not grow the state file)
            self._engines.pop(name, None)
        for channel in bed.needed | bed.extra:
            self._routes.pop(sensor_key(name, channel), None)

    def health(self, bed: str, wall: float, dropped: int = 0,
               lag_ms: tuple[float | None, float | None] | None = None) -> HealthMessage:
        """The health message of ``bed``: its latest sensor time and its own counters.

        wall: the node's clock, s; dropped: this bed's messages lost in the node's queue;
        lag_ms: receive-to-publish latency (median, 99th percentile), ms, if measured.
        """
        b = self.beds[bed]
        a = b.aligner.stats
        msg: HealthMessage = {
            "t": b.latest_t if b.latest_t is not None else float("nan"), "wall": wall,
            "received": b.received, "malformed": b.malformed, "dropped": dropped, "samples": a.samples,
            "late": a.late, "duplicates": a.duplicates, "missing": dict(a.missing),
            "alarm_samples": b.alarm_samples, "late_by_channel": dict(a.late_by_channel),
            "phase_ms": b.aligner.phase_ms(), "refused": dict(b.refused)}
        g = b.aligner.guard
        msg["clock_faults"], msg["clock_conflicts"] = g.faults, g.conflicts
        msg["clock_jumps"], msg["clock_held"] = g.jumps, g.held
        msg["transients_dropped"] = sum(p.transients_dropped for p in b.pipelines)
        if lag_ms is not None:
            msg["lag_ms_p50"], msg["lag_ms_p99"] = lag_ms
        return msg

    def engine_states(self) -> dict[str, EngineState]:
        """Each bed's engine history now (beds not seen yet keep the one given), for a state file."""
        out = dict(self._engines)
        out.update({name: b.pipeline.history.state for name, b in self.beds.items()})
        return out

    def route(self, key: str) -> Route | Refused:
        """(bed, channel) of an admitted sensor key, or why the key is refused: each key parsed
        and admitted here (module docstring), the admitted ones cached (the live node asks too).
        Counts nothing; a key's first admission creates its bed, or takes one of its channels.

        >>> from node.contract.schedule import OperatingCondition, Schedule
        >>> core = NodeCore(Bundle("wdmd", "yB", Schedule((OperatingCondition("A", 4000.0),)), []),
        ...                 beds="b$*", max_beds=1, max_channels=3)
        >>> core.route("testbed/b1/sensor/nB"), core.route("other/key"), core.foreign
        (('b1', 'nB'), <Refused.KEY: 'key'>, 0)
        >>> [core.route(f"testbed/{b}/sensor/nB").value for b in ("x1", "b2", "**")]
        ['not_admitted', 'bed_limit', 'key']
        >>> core.route("testbed/b1/sensor/tA"), core.route("testbed/b1/sensor/tB").value
        (('b1', 'tA'), 'channel_limit')
        """
        route = self._routes.get(key)
        if route is not None:
            return route
        parsed = parse_sensor_key(key)
        if parsed is None:
            return Refused.KEY
        name, channel = parsed
        bed = self.beds.get(name)
        if bed is None:
            if not self._admits(name):
                return Refused.NOT_ADMITTED
            if len(self.beds) >= self.max_beds:
                return Refused.BED_LIMIT
            bed = self._bed(name)
        if channel not in bed.needed and channel not in bed.extra:
            if len(bed.needed) + len(bed.extra) >= self.max_channels:
                return Refused.CHANNEL_LIMIT
            bed.extra.add(channel)
        self._routes[key] = parsed
        return parsed

    def known(self, key: str) -> Route | None:
        """(bed, channel) of a key admitted before, None otherwise; admits nothing."""
        return self._routes.get(key)

    def _bed(self, name: str) -> Bed:
        bed = self.beds.get(name)
        if bed is None:
            first = MonitorPipeline(self.model.bundles[0], self._engines.get(name),
                                    slow_temperatures=self._slow_temperatures)
            pipes = [first] + [MonitorPipeline(b, history=first.history,  # one engine, one history,
                                               slow_temperatures=self._slow_temperatures,
                                               detector=first.detector)  # one speed, one OC detector
                               for b in self.model.bundles[1:]]
            if self.defer_transients:
                for p in pipes:
                    p.defer_transients()
            channels = sorted({c for p in pipes for c in p.sensor_channels})
            aligner = Aligner(channels, max_wait=self.model.config.align_wait_s, clock=self.clock)
            keys = [monitor_key(name, p.target) for p in pipes]
            bed = self.beds[name] = Bed(aligner, pipes, keys, frozenset(channels))
        return bed

    def _run(self, name: str, samples: list[AlignedSample]) -> list[Output]:
        bed = self.beds[name]
        out: list[Output] = []
        targets = list(zip(bed.keys, bed.pipelines))
        for s in samples:
            for j, (key, pipe) in enumerate(targets):
                msg, oc_msg = pipe.step(s)
                if oc_msg is not None and not j:
                    out.append((oc_key(name), oc_msg))
                if msg["flag"] == Flag.ALARM:
                    bed.alarm_samples += 1
                    self.alarm_log.add(key, msg)
                out.append((key, msg))
                if pipe.transient is not None:  # the end of a transition: its criticals
                    self._transient(transient_key(name), pipe.transient, out)
                if pipe.verdicts:  # an OC switch or a run's end: the verdict of a limited target
                    key_v = verdict_key(name)
                    out += [(key_v, v) for v in pipe.verdicts]
                    self._keep_verdicts(out[-len(pipe.verdicts):])
        self.published += len(out)
        return out
