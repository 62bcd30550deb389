"""Messages in, messages out: the node's logic over every test bed, without I/O.

``NodeCore.handle(key, payload)`` takes one sensor message as it arrived (key
expression and raw JSON bytes) and returns the monitor messages it completes.
Bad payloads are counted and skipped; unknown keys and channels are ignored.
The live node and ``ordervib replay`` both drive this class.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from operator import itemgetter

import orjson

from node.contract import Flag, monitor_key, oc_key, parse_sensor_key
from node.models.bundle import Bundle
from node.runtime.alarms import EpisodeLog
from node.runtime.align import Aligner
from node.runtime.pipeline import MonitorPipeline


@dataclass
class BedState:
    aligner: Aligner
    pipeline: MonitorPipeline
    alarms: int = 0


@dataclass
class CoreStats:
    messages: int = 0
    malformed: int = 0
    foreign: int = 0  # keys that are not sensor keys
    published: int = 0
    beds: dict[str, BedState] = field(default_factory=dict)
    alarm_log: EpisodeLog = field(default_factory=EpisodeLog)  # alarm episodes, every bed


Output = tuple[str, dict]  # (key expression, JSON-ready message)


def _check(t: object, v: object) -> tuple[float, float | None] | None:
    """(t, v) as floats when t is a finite number and v a number or null; else None."""
    try:
        ok = isinstance(t, (int, float)) and not isinstance(t, bool) and math.isfinite(t)
        ok = ok and (v is None or (isinstance(v, (int, float)) and not isinstance(v, bool)))
        return (float(t), None if v is None else float(v)) if ok else None
    except OverflowError:  # an integer too large for a float
        return None


_T, _V = itemgetter("t"), itemgetter("v")
_FLOAT_OR_NULL = frozenset((float, type(None)))


def decode_clean(payloads: Sequence[bytes]) -> tuple[list[float], list[float | None]] | None:
    """The t and v columns of a batch of sensor payloads, decoded without a per-message loop,
    when every one holds a finite float t and a float or null v; None when any does not (the
    rule of ``decode_sample`` then decides message by message)."""
    try:
        ds = list(map(orjson.loads, payloads))
        ts, vs = list(map(_T, ds)), list(map(_V, ds))
    except (orjson.JSONDecodeError, TypeError, KeyError):
        return None
    if set(map(type, ts)) == {float} and _FLOAT_OR_NULL.issuperset(map(type, vs)) and math.isfinite(sum(ts)):
        return ts, vs
    return None


def decode_sample(payload: bytes) -> tuple[float, float | None] | None:
    """(t, v) of a sensor payload ``{"t": number, "v": number or null}``; None when malformed."""
    try:
        d = orjson.loads(payload)
        return _check(d["t"], d["v"])
    except (orjson.JSONDecodeError, TypeError, KeyError):
        return None


class NodeCore:
    def __init__(self, bundle: Bundle) -> None:
        self.bundle = bundle
        self.stats = CoreStats()
        self._routes: dict[str, tuple[str, str] | tuple[()]] = {}  # key -> (bed, channel), () if foreign

    def _bed(self, bed: str) -> BedState:
        st = self.stats.beds.get(bed)
        if st is None:
            pipe = MonitorPipeline(self.bundle)
            st = BedState(Aligner(pipe.sensor_channels), pipe)
            self.stats.beds[bed] = st
        return st

    def handle(self, key: str, payload: bytes) -> list[Output]:
        """One incoming message; returns the monitor messages it completes (in order)."""
        self.stats.messages += 1
        parsed = parse_sensor_key(key)
        if parsed is None:
            self.stats.foreign += 1
            return []
        bed, channel = parsed
        sample = decode_sample(payload)
        if sample is None:
            self.stats.malformed += 1
            return []
        st = self._bed(bed)
        return self._run(bed, st, st.aligner.push(channel, sample[0], sample[1]))

    def handle_many(self, keys: Sequence[str], payloads: Sequence[bytes]) -> list[tuple[int, list[Output]]]:
        """``handle`` over a batch of messages, with the very same effects, faster.

        Returns ``(i, outputs)`` for each message i that completed monitor messages.
        """
        beds = self.stats.beds
        clean = self._clean_batch(keys, payloads)
        if clean is not None:
            bed, columns = clean
            done = [(i, bed, samples) for i, samples in beds[bed].aligner.push_columns(*columns)]
        else:
            per_bed = self._sort_batch(keys, payloads)
            # each bed's aligner is independent; the pipelines then run in message order
            done = [(i, bed, samples) for bed, items in per_bed.items()
                    for i, samples in beds[bed].aligner.push_many(items)]
            if len(per_bed) > 1:
                done.sort(key=lambda x: x[0])
        self.stats.messages += len(keys)
        return [(i, self._run(bed, beds[bed], samples)) for i, bed, samples in done]

    def _route(self, key: str) -> tuple[str, str] | tuple[()]:
        """(bed, channel) of a sensor key, () for any other key (cached)."""
        route = self._routes.get(key)
        if route is None:
            route = self._routes[key] = parse_sensor_key(key) or ()
        return route

    def _clean_batch(self, keys: Sequence[str], payloads: Sequence[bytes]
                     ) -> tuple[str, tuple[list[str], list[float], list[float | None]]] | None:
        """The common batch, without a per-message loop: ``(bed, (channels, ts, vs))`` when every
        key is a sensor key of one bed and every payload is well formed; else None."""
        if len(keys) != len(payloads):
            return None
        routes = {key: self._route(key) for key in set(keys)}
        beds = {route[0] if route else None for route in routes.values()}
        if len(beds) != 1 or None in beds:
            return None
        columns = decode_clean(payloads)
        if columns is None:
            return None
        bed = beds.pop()
        if bed not in self.stats.beds:
            self._bed(bed)
        channel_of = {key: route[1] for key, route in routes.items()}
        return bed, (list(map(channel_of.__getitem__, keys)), *columns)

    def _sort_batch(self, keys: Sequence[str], payloads: Sequence[bytes]) -> dict[str, list]:
        """``{bed: [(i, channel, t, v)] of its valid messages}``, one message at a time; counts
        foreign keys and malformed payloads."""
        beds = self.stats.beds
        routes = self._routes
        loads, decode_error = orjson.loads, orjson.JSONDecodeError
        per_bed: dict[str, list] = {}
        foreign = malformed = 0
        for i, (key, payload) in enumerate(zip(keys, payloads, strict=True)):
            route = routes.get(key)
            if route is None:
                route = self._route(key)
            if not route:
                foreign += 1
                continue
            try:
                d = loads(payload)
                t = d["t"]
                v = d["v"]
            except (decode_error, TypeError, KeyError):
                malformed += 1
                continue
            if not (type(t) is float and t - t == 0.0 and (v is None or type(v) is float)):
                sample = _check(t, v)  # the general rule, for ints and anything odd
                if sample is None:
                    malformed += 1
                    continue
                t, v = sample
            items = per_bed.get(route[0])
            if items is None:
                if route[0] not in beds:
                    self._bed(route[0])  # bed states are made in order of first valid message
                items = per_bed[route[0]] = []
            items.append((i, route[1], t, v))
        self.stats.foreign += foreign
        self.stats.malformed += malformed
        return per_bed

    def _run(self, bed: str, st: BedState, samples) -> list[Output]:
        out: list[Output] = []
        target = self.bundle.target
        for s in samples:
            msg, oc_msg = st.pipeline.step(s)
            if oc_msg is not None:
                out.append((oc_key(bed), oc_msg))
            key = monitor_key(bed, target)
            if msg["flag"] == Flag.ALARM:
                st.alarms += 1
                self.stats.alarm_log.add(key, msg)
            out.append((key, msg))
        self.stats.published += len(out)
        return out

    def finish(self) -> list[Output]:
        """End of stream: emit every sample still waiting for late channels."""
        out: list[Output] = []
        for bed, st in self.stats.beds.items():
            out += self._run(bed, st, st.aligner.flush())
        return out

    def health(self, bed: str, t: float, extra: dict | None = None) -> dict:
        st = self.stats.beds[bed]
        a = st.aligner.stats
        return {"t": t, "samples": a.samples, "late": a.late, "duplicates": a.duplicates,
                "missing": dict(a.missing), "malformed": self.stats.malformed,
                "alarm_samples": st.alarms, **(extra or {})}
