"""``ordervib view``: a recording in Rerun (viewer, or a saved ``.rrd``).

Reads the recording once (``node.mcap.read_payloads``: a linear scan that
also works on unfinished files), decodes only the topics the view needs (the
switch speed, the target's sensor stream, ``monitor/<target>``, ``monitor/oc``,
``monitor/health`` of one bed) into time-major arrays, and hands them to
``replay.rerun_view``. A sensor-only recording shows its OCs when a schedule is
given (``--schedule``, or ``REC.schedule.toml`` beside it): the node's own OC
detector is run over the speed.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import TYPE_CHECKING, Any

import numpy as np
import orjson

from node.cli.paths import check_output_file
from node.contract import (
    OrdervibError,
    TopicKind,
    bed_of,
    health_key,
    monitor_key,
    oc_key,
    parse_monitor_key,
    sensor_key,
    topic_kind,
)

if TYPE_CHECKING:
    from node.contract.schedule import Schedule
    from node.mcap import ReadStats
    from replay.rerun_view import Health, MonitorColumns, OcSwitches, Series, ViewData

NAME = "view"
HELP = "show a recording in the Rerun viewer, or save the Rerun file (--save OUT.rrd)"



def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="REC.mcap", help="recording (sensor-only or a node's)")
    p.add_argument("--save", metavar="OUT.rrd", default=None, help="write a Rerun file, start no viewer")
    p.add_argument("--bed", metavar="NAME", default=None, help="test bed (default: the only one)")
    p.add_argument(
        "--target",
        metavar="CH",
        default=None,
        help="modelled channel (default: the monitored one, else yB)",
    )
    p.add_argument(
        "--switch", metavar="CH", default=None, help="speed channel (default: schedule's, else nB)"
    )
    p.add_argument(
        "--schedule",
        metavar="S.toml",
        default=None,
        help="derive OCs of a sensor-only recording (default: REC.schedule.toml if present)",
    )
    p.add_argument("--quiet", action="store_true", help="no summary line")


# ----------------------------------------------------------------------------- decoding


def decode_payloads(payloads: list[bytes]) -> tuple[list[dict[str, Any]], int]:
    """JSON objects of a topic's payloads (one orjson call when all parse); (objects, malformed)."""
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


def _sorted_objects(payloads: list[bytes]) -> tuple[list[dict[str, Any]], np.ndarray]:
    """Decoded payloads with a finite t, sorted by t (stable); and their t (N,)."""
    objs, _ = decode_payloads(payloads)
    t = float_column(objs, "t")
    ok = np.flatnonzero(np.isfinite(t))
    order = ok[np.argsort(t[ok], kind="stable")]
    return [objs[i] for i in order], t[order]


# ----------------------------------------------------------------------------- topics to arrays


def series_of(payloads: list[bytes]) -> Series:
    """A sensor topic's samples as a time-sorted Series."""
    from replay.rerun_view import Series

    objs, t = _sorted_objects(payloads)
    return Series(t=t, v=float_column(objs, "v"))


def monitor_of(payloads: list[bytes]) -> MonitorColumns:
    """A ``monitor/<target>`` topic as time-sorted columns."""
    from replay.rerun_view import MonitorColumns

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
        reason=str_column(objs, "reason"),
    )


def switches_of(payloads: list[bytes]) -> OcSwitches:
    """``monitor/oc`` messages as time-sorted switches."""
    from replay.rerun_view import OcSwitches

    objs, t = _sorted_objects(payloads)
    return OcSwitches(t=t, oc=str_column(objs, "oc"), phase=str_column(objs, "phase"))


def health_of(payloads: list[bytes]) -> Health:
    """``monitor/health`` messages as time-sorted columns (missing: summed over channels)."""
    from replay.rerun_view import Health

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

    A fresh detector per run (gaps >= 60 s); one switch per change of (oc, phase).
    """
    from node.contract import RUN_GAP
    from node.runtime.ocdetect import OCDetector
    from replay.rerun_view import OcSwitches

    names = np.array([""] + list(schedule.names), dtype=str)
    phases = np.array(["off", "transition", "steady"], dtype=str)
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


# ----------------------------------------------------------------------------- choosing


def _pick_bed(topics: list[str], bed: str | None) -> str:
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


def _pick_target(topics: list[str], bed: str, target: str | None) -> str:
    monitored = sorted(
        name
        for tp in topics
        if topic_kind(tp) is TopicKind.MONITOR and (parsed := parse_monitor_key(tp)) and parsed[0] == bed
        for name in parsed[1:]
    )
    if target is not None:
        return target
    if "yB" in monitored or not monitored:
        return "yB"
    return monitored[0]


def _schedule_for(args: argparse.Namespace) -> Schedule | None:
    from node.contract.schedule import load_schedule

    path = args.schedule
    if path is None:
        root, _ = os.path.splitext(args.recording)
        path = root + ".schedule.toml"
        if not os.path.isfile(path):
            return None
    return load_schedule(path)


def load_view_data(args: argparse.Namespace) -> tuple[ViewData, str, ReadStats]:
    """Read the recording once and build the arrays of the view; (data, oc source, stats)."""
    from node.mcap import ReadStats, read_payloads
    from replay.rerun_view import ViewData

    stats = ReadStats()
    by_topic = read_payloads(args.recording, stats)
    topics = sorted(by_topic)
    bed = _pick_bed(topics, args.bed)
    target = _pick_target(topics, bed, args.target)
    schedule = _schedule_for(args)
    switch = args.switch or (schedule.switch if schedule is not None else "nB")
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
    if hkey in by_topic:
        data.health = health_of(by_topic[hkey])
    source = "none"
    if okey in by_topic:
        data.switches = switches_of(by_topic[okey])
        source = "monitor/oc"
    elif schedule is not None:
        data.switches = switches_from_schedule(speed, schedule)
        source = "schedule (OC detector)"
    return data, source, stats


# ----------------------------------------------------------------------------- command


def _check(args: argparse.Namespace) -> None:
    if args.save is None:
        return
    check_output_file(args.save, "--save", ".rrd")


def _has_display() -> bool:
    """Whether a native viewer window could open (always assumed off Linux)."""
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


_NO_VIEWER = "cannot start the Rerun viewer ({why}); use --save OUT.rrd and open it with `rerun OUT.rrd`"


def run(args: argparse.Namespace) -> int:
    _check(args)
    start = time.perf_counter()
    data, source, stats = load_view_data(args)
    if args.save is None and not _has_display():
        raise OrdervibError(_NO_VIEWER.format(why="no display"))

    import rerun as rr

    from replay.rerun_view import blueprint, log_view

    bp = blueprint(data)
    rr.init("ordervib_view", spawn=False)
    if args.save is not None:
        part = args.save + ".part"
        rr.save(part, default_blueprint=bp)
    else:
        try:
            rr.spawn(default_blueprint=bp)
        except Exception as exc:  # viewer binary missing or unable to start
            raise OrdervibError(_NO_VIEWER.format(why=str(exc).splitlines()[0])) from None
    try:
        counts = log_view(data)
    finally:
        rr.disconnect()
    if args.save is not None:
        os.replace(part, args.save)
    if not args.quiet:
        where = f"-> {args.save} ({os.path.getsize(args.save)} bytes)" if args.save else "-> viewer"
        extra = " (unfinished file: read up to its last complete chunk)" if stats.truncated else ""
        print(
            f"view: bed {data.bed}, {data.switch} {counts.get('speed', 0)} samples, "
            f"{data.target} {counts.get('curve', 0)} curve points in {counts.get('runs', 0)} runs, "
            f"monitor {counts.get('monitor', 0)} ({counts.get('alarm', 0)} alarm), "
            f"OCs from {source}{extra} {where} in {time.perf_counter() - start:.2f} s"
        )
    return 0
