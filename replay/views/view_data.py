"""The arrays a view of a recording shows, read from the recording (no Rerun here).

``load_view_data`` reads the recording once (``node.mcap.read_payloads``: a
linear scan that also works on unfinished files) and decodes only the topics the view
needs -- the switch speed, the target's sensor stream, ``monitor/<target>``,
``monitor/oc`` and ``monitor/health`` of one bed -- into time-major arrays, each sorted
by the message time t, and ``vectors_of`` the target's 1x vector (amplitude and order
phase) when the recording has the order's phase. Sensor payloads follow the contract's payload rule
(``node.contract.decode_samples``: malformed ones are left out); monitor messages keep
every object with a numeric t, a missing or null field reading NaN (numbers) or ""
(strings). A sensor-only recording gets its OC switches from a schedule: the node's OC
detector run over the speed.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
import orjson

from node.contract import (
    FS,
    RUN_GAP,
    OrdervibError,
    Phase,
    TopicKind,
    bed_of,
    decode_samples,
    health_key,
    monitor_key,
    oc_key,
    parse_monitor_key,
    phase_channel,
    sensor_key,
    topic_kind,
)
from node.contract.schedule import Schedule
from node.contract.vector import order_vectors, wrap_degrees
from node.mcap import ReadStats, read_payloads
from node.runtime.ocdetect import OCDetector

log = logging.getLogger(__name__)

# ----------------------------------------------------------------------------- data


@dataclass
class Series:
    """One scalar channel. t: (K,) s since the epoch, sorted; v: (K,) NaN for a dropout.

    >>> s = series_of([b'{"t": 2.0, "v": null}', b'{"t": 1.0, "v": 5}', b'{"t": "x", "v": 1}'])
    >>> s.t.tolist(), s.v.tolist()
    ([1.0, 2.0], [5.0, nan])
    """

    t: np.ndarray
    v: np.ndarray


@dataclass
class MonitorColumns:
    """Monitor messages of one target, time-major, shape (K,) each.

    t in s since the epoch; measured, predicted, residual, band in the target's
    unit and score dimensionless, NaN for null; flag, oc, phase (of the OC) as str arrays
    (oc "" for null). The order's phase, where the node publishes it: measured_phase and
    predicted_phase in degrees (lag from the once-per-rev mark), vector_residual (target unit,
    |measured - predicted 1x vector|); NaN where null or absent.
    """

    t: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    residual: np.ndarray
    score: np.ndarray
    band: np.ndarray
    flag: np.ndarray
    oc: np.ndarray
    phase: np.ndarray
    measured_phase: np.ndarray
    predicted_phase: np.ndarray
    vector_residual: np.ndarray
    reason: np.ndarray | None = None  # why a sample is flagged ("residual", "step", ...), "" if not

    def flag_labels(self) -> np.ndarray:
        """Flag with its reason, e.g. "alarm (step)": (K,) str."""
        if self.reason is None:
            return self.flag
        r = self.reason.astype(object)
        return np.where(r != "", self.flag.astype(object) + " (" + r + ")", self.flag.astype(object)
                        ).astype(str)


@dataclass
class OcSwitches:
    """OC switches: t (S,) s since the epoch, oc (S,) str ("" outside any OC), phase (S,) str."""

    t: np.ndarray
    oc: np.ndarray
    phase: np.ndarray


@dataclass
class Health:
    """Health messages: t (H,) s; lag_p50, lag_p99 (H,) ms; late, dropped, malformed, missing (H,) counts."""

    t: np.ndarray
    lag_p50: np.ndarray
    lag_p99: np.ndarray
    late: np.ndarray
    dropped: np.ndarray
    malformed: np.ndarray
    missing: np.ndarray


@dataclass
class ViewData:
    """Everything one view shows, for one test bed and one target channel."""

    bed: str
    switch: str  # speed channel, e.g. "nB"
    target: str  # modelled channel, e.g. "yB"
    speed: Series
    measured: Series | None  # the target's sensor stream, when recorded
    monitor: MonitorColumns | None = None
    switches: OcSwitches | None = None
    health: Health | None = None
    target_unit: str = "mm/s"
    order_phase: Series | None = None  # the target's phase channel (degrees), when recorded


TIME_SERIES = ("speed", "measured", "monitor", "switches", "health", "order_phase")  # ViewData's


def rows_after(data: ViewData, since: dict[str, float]) -> ViewData:
    """``data`` with only the samples and messages later than ``since[part]`` (s since the
    epoch) in each time series part (``speed``, ``measured``, ``monitor``, ``switches``,
    ``health``, ``order_phase``): the stretch a live view has not logged yet."""

    def cut(part: str) -> Any:
        x = getattr(data, part)
        if x is None:
            return None
        keep = x.t > since.get(part, -np.inf)
        return dataclasses.replace(x, **{f.name: getattr(x, f.name)[keep] for f in dataclasses.fields(x)
                                         if isinstance(getattr(x, f.name), np.ndarray)
                                         and getattr(x, f.name).shape[:1] == x.t.shape})

    return dataclasses.replace(data, **{part: cut(part) for part in TIME_SERIES})


@dataclass
class Vectors:
    """The target's 1x vector over the recording, time-major, shape (N,) each, sorted by t.

    t: s since the epoch; speed: the switch speed (rpm) at t; run: run number (0-based, runs
    split by gaps >= RUN_GAP in the speed); amplitude (target unit) and phase (degrees lag from
    the once-per-rev mark, in [-180, 180)) measured, predicted_amplitude and predicted_phase the
    model's; NaN where none. The vector is ``order_vectors(amplitude, phase)``.
    """

    t: np.ndarray
    speed: np.ndarray
    run: np.ndarray
    amplitude: np.ndarray
    phase: np.ndarray
    predicted_amplitude: np.ndarray
    predicted_phase: np.ndarray

    def measured(self) -> np.ndarray:
        """The measured 1x vector, complex (N,), NaN where amplitude or phase is missing."""
        return order_vectors(self.amplitude, self.phase)

    def predicted(self) -> np.ndarray:
        """The predicted 1x vector, complex (N,), NaN where the model gives none."""
        return order_vectors(self.predicted_amplitude, self.predicted_phase)

    def has_predicted(self) -> bool:
        """Whether any predicted vector is there."""
        return bool(np.isfinite(self.predicted()).any())

    def speed_range(self) -> tuple[float, float]:
        """Lowest and highest speed (rpm) of the samples with a vector, measured or predicted."""
        ok = np.isfinite(self.measured()) | np.isfinite(self.predicted())
        return float(np.nanmin(self.speed[ok])), float(np.nanmax(self.speed[ok]))


# ----------------------------------------------------------------------------- decoding


def decode_payloads(payloads: list[bytes]) -> tuple[list[dict[str, Any]], int]:
    """JSON objects of a topic's payloads (one orjson call when all parse); (objects, malformed).

    >>> decode_payloads([b'{"t": 1}', b'[1]', b'{'])
    ([{'t': 1}], 2)
    """
    if not payloads:
        return [], 0
    try:
        objs = orjson.loads(b"[" + b",".join(payloads) + b"]")
        if len(objs) == len(payloads) and all(isinstance(o, dict) for o in objs):
            return objs, 0
    except orjson.JSONDecodeError:
        pass
    out: list[dict[str, Any]] = []
    for p in payloads:
        try:
            o = orjson.loads(p)
        except orjson.JSONDecodeError:
            continue
        if isinstance(o, dict):
            out.append(o)
    return out, len(payloads) - len(out)


def _num(x: Any) -> float:
    """A JSON number as float; NaN for null, bool or anything else."""
    if isinstance(x, (int, float)) and not isinstance(x, bool):
        return float(x)
    return float("nan")


def float_column(objs: list[dict[str, Any]], key: str) -> np.ndarray:
    """Field key of every object as float64 (N,), NaN where null or absent."""
    return np.array([_num(o.get(key)) for o in objs], dtype=float)


def str_column(objs: list[dict[str, Any]], key: str) -> np.ndarray:
    """Field key of every object as a str array (N,), "" where null or absent."""
    return np.array([v if isinstance(v := o.get(key), str) else "" for o in objs], dtype=str)


def _by_time(t: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Indices of the kept entries (mask (N,)), ordered by t (stable)."""
    idx = np.flatnonzero(keep)
    return idx[np.argsort(t[idx], kind="stable")]


def _sorted_objects(payloads: list[bytes]) -> tuple[list[dict[str, Any]], np.ndarray]:
    """Decoded payloads with a finite t, sorted by t (stable); and their t (N,)."""
    objs, _ = decode_payloads(payloads)
    t = float_column(objs, "t")
    order = _by_time(t, np.isfinite(t))
    return [objs[i] for i in order], t[order]


# ----------------------------------------------------------------------------- topics to arrays


def series_of(payloads: list[bytes]) -> Series:
    """A sensor topic's well-formed samples as a time-sorted Series."""
    t, v, ok = decode_samples(payloads)
    order = _by_time(t, ok)
    return Series(t=t[order], v=v[order])


def monitor_of(payloads: list[bytes]) -> MonitorColumns:
    """A ``monitor/<target>`` topic as time-sorted columns."""
    objs, t = _sorted_objects(payloads)
    return MonitorColumns(
        t=t,
        measured=float_column(objs, "measured"),
        predicted=float_column(objs, "predicted"),
        residual=float_column(objs, "residual"),
        score=float_column(objs, "score"),
        band=float_column(objs, "band"),
        flag=str_column(objs, "flag"),
        oc=str_column(objs, "oc"),
        phase=str_column(objs, "phase"),
        measured_phase=float_column(objs, "measured_phase"),
        predicted_phase=float_column(objs, "predicted_phase"),
        vector_residual=float_column(objs, "vector_residual"),
        reason=str_column(objs, "reason"),
    )


def switches_of(payloads: list[bytes]) -> OcSwitches:
    """``monitor/oc`` messages as time-sorted switches."""
    objs, t = _sorted_objects(payloads)
    return OcSwitches(t=t, oc=str_column(objs, "oc"), phase=str_column(objs, "phase"))


def health_of(payloads: list[bytes]) -> Health:
    """``monitor/health`` messages as time-sorted columns (missing: summed over channels)."""
    objs, t = _sorted_objects(payloads)
    missing = np.array(
        [
            sum(_num(v) for v in m.values()) if isinstance(m := o.get("missing"), dict) else np.nan
            for o in objs
        ],
        dtype=float,
    )
    return Health(
        t=t,
        lag_p50=float_column(objs, "lag_ms_p50"),
        lag_p99=float_column(objs, "lag_ms_p99"),
        late=float_column(objs, "late"),
        dropped=float_column(objs, "dropped"),
        malformed=float_column(objs, "malformed"),
        missing=missing,
    )


def switches_from_schedule(speed: Series, schedule: Schedule) -> OcSwitches:
    """OC switches of a sensor-only recording: the node's OC detector over the speed.

    A fresh detector per run (gaps >= RUN_GAP); one switch per change of (oc, phase).
    """
    names = np.array([""] + list(schedule.segments), dtype=str)
    phases = np.array([Phase.from_code(c).value for c in range(len(Phase))], dtype=str)
    starts = np.concatenate([[0], np.flatnonzero(np.diff(speed.t) >= RUN_GAP) + 1, [len(speed.t)]])
    oc_parts, ph_parts = [], []
    for a, b in zip(starts[:-1], starts[1:]):
        oc, ph = OCDetector(schedule).label(speed.v[a:b])
        oc_parts.append(names[oc + 1])
        ph_parts.append(phases[ph])
    oc = np.concatenate(oc_parts) if oc_parts else np.empty(0, dtype=str)
    ph = np.concatenate(ph_parts) if ph_parts else np.empty(0, dtype=str)
    change = np.ones(len(oc), dtype=bool)
    change[1:] = (oc[1:] != oc[:-1]) | (ph[1:] != ph[:-1])
    return OcSwitches(t=speed.t[change], oc=oc[change], phase=ph[change])


def speed_at(speed: Series, t: np.ndarray) -> np.ndarray:
    """The speed at times t (N,): linear between its valid samples, held over dropouts."""
    ok = np.isfinite(speed.v)
    return np.interp(t, speed.t[ok], speed.v[ok]) if ok.any() else np.full(len(t), np.nan)


def at_times(s: Series, t: np.ndarray, tol: float = 0.5 / FS) -> np.ndarray:
    """s's value at each time t (N,): its nearest sample within tol s, else NaN.

    >>> at_times(Series(np.array([1.0, 2.0]), np.array([5.0, 6.0])), np.array([0.99, 1.5, 2.01])).tolist()
    [5.0, nan, 6.0]
    """
    t = np.asarray(t, dtype=float)
    if not len(s.t):
        return np.full(len(t), np.nan)
    j = np.searchsorted(s.t, t)
    lo, hi = np.clip(j - 1, 0, len(s.t) - 1), np.clip(j, 0, len(s.t) - 1)
    k = np.where(np.abs(s.t[lo] - t) <= np.abs(s.t[hi] - t), lo, hi)
    return np.where(np.abs(s.t[k] - t) <= tol, s.v[k], np.nan)


def vectors_of(data: ViewData) -> Vectors | None:
    """The target's 1x vectors; None when the recording has no phase of it (or no valid speed).

    From the monitor messages when they carry the order's phase (measured_phase or
    predicted_phase), else from the target's sensor stream and its phase channel (the phase
    sample nearest each amplitude sample, within half a sample period; no prediction).
    """
    m = data.monitor
    if m is not None and np.isfinite(np.concatenate([m.measured_phase, m.predicted_phase])).any():
        t, amp, phase, pamp, pphase = m.t, m.measured, m.measured_phase, m.predicted, m.predicted_phase
    elif data.order_phase is not None and data.measured is not None:
        t, amp = data.measured.t, data.measured.v
        phase = at_times(data.order_phase, t)
        pamp = pphase = np.full(len(t), np.nan)
    else:
        return None
    if not np.isfinite(np.concatenate([order_vectors(amp, phase), order_vectors(pamp, pphase)])).any() or \
            not np.isfinite(data.speed.v).any():
        return None
    gap_ends = data.speed.t[np.flatnonzero(np.diff(data.speed.t) >= RUN_GAP) + 1]
    return Vectors(t=t, speed=speed_at(data.speed, t), run=np.searchsorted(gap_ends, t, side="right"),
                   amplitude=amp, phase=wrap_degrees(phase), predicted_amplitude=pamp,
                   predicted_phase=wrap_degrees(pphase))


# ----------------------------------------------------------------------------- choosing


def pick_bed(topics: list[str], bed: str | None) -> str:
    """The bed asked for, else the recording's only one; OrdervibError otherwise."""
    beds = sorted({b for tp in topics if (b := bed_of(tp))})
    if not beds:
        raise OrdervibError("no testbed/<bed>/... topic in the recording")
    if bed is None:
        if len(beds) > 1:
            raise OrdervibError(f"several test beds ({', '.join(beds)}): choose one with --bed")
        return beds[0]
    if bed not in beds:
        raise OrdervibError(f"no test bed {bed!r} in the recording (found: {', '.join(beds)})")
    return bed


def pick_target(topics: list[str], bed: str, target: str | None) -> str:
    """The target asked for, else yB when monitored or nothing is, else the first monitored channel.

    A node's recording of a model of several targets has a ``monitor/<target>`` each: the view
    shows one of them and says so (``--target`` picks another).
    """
    monitored = sorted(
        name
        for tp in topics
        if topic_kind(tp) is TopicKind.MONITOR and (parsed := parse_monitor_key(tp)) and parsed[0] == bed
        for name in parsed[1:]
    )
    if target is not None:
        return target
    chosen = "yB" if "yB" in monitored or not monitored else monitored[0]
    if len(monitored) > 1:
        log.info("%d targets monitored (%s): showing %s (--target picks another)",
                 len(monitored), ", ".join(monitored), chosen)
    return chosen


def load_view_data(recording: str, bed: str | None = None, target: str | None = None,
                   switch: str | None = None, schedule: Schedule | None = None
                   ) -> tuple[ViewData, str, ReadStats]:
    """Read the recording once and build the arrays of the view; (data, OC source, read stats).

    bed, target: as ``pick_bed`` and ``pick_target``; switch: the speed channel (default the
    schedule's, else nB); schedule: gives the OCs when the recording has no ``monitor/oc``.
    The OC source is "monitor/oc", "schedule (OC detector)" or "none".
    """
    stats = ReadStats()
    by_topic = read_payloads(recording, stats)
    data, source = view_data_of(by_topic, bed, target, switch, schedule)
    return data, source, stats


def view_data_of(by_topic: dict[str, list[bytes]], bed: str | None = None, target: str | None = None,
                 switch: str | None = None, schedule: Schedule | None = None) -> tuple[ViewData, str]:
    """The view's arrays from payloads by topic (a recording's, or those a live view received so
    far); (data, OC source). Arguments as ``load_view_data``'s."""
    topics = sorted(by_topic)
    bed = pick_bed(topics, bed)
    target = pick_target(topics, bed, target)
    switch = switch or (schedule.switch if schedule is not None else "nB")
    key = sensor_key(bed, switch)
    if key not in by_topic:
        raise OrdervibError(f"no {switch} speed in the recording (topic {key})")
    speed = series_of(by_topic[key])
    if not len(speed.t):
        raise OrdervibError(f"no valid {switch} sample in the recording (topic {key})")
    mkey = sensor_key(bed, target)
    measured = series_of(by_topic[mkey]) if mkey in by_topic else None
    data = ViewData(bed=bed, switch=switch, target=target, speed=speed, measured=measured)
    tkey, hkey, okey = monitor_key(bed, target), health_key(bed), oc_key(bed)
    if tkey in by_topic:
        data.monitor = monitor_of(by_topic[tkey])
    if measured is None and data.monitor is None:
        raise OrdervibError(f"no {target} in the recording (neither {mkey} nor {tkey})")
    if (pkey := sensor_key(bed, phase_channel(target))) in by_topic:
        data.order_phase = series_of(by_topic[pkey])
    if hkey in by_topic:
        data.health = health_of(by_topic[hkey])
    source = "none"
    if okey in by_topic:
        data.switches = switches_of(by_topic[okey])
        source = "monitor/oc"
    elif schedule is not None:
        data.switches = switches_from_schedule(speed, schedule)
        source = "schedule (OC detector)"
    return data, source
