"""The messages of ``docs/contract.md`` section 2 as typed objects, and their JSON Schemas.

Each message kind is a ``TypedDict`` (a plain dict at run time: no cost on the
per-sample path), annotated with its fields' meanings; ``json_schema`` derives the
JSON Schema that recordings carry for that topic kind, so the schema and the
type cannot drift apart.

>>> Flag.ALARM == "alarm", Phase.STEADY.code
(True, 2)
>>> schema = json_schema(TopicKind.OC)
>>> schema["required"]
['t', 'oc', 'phase', 'previous']
"""

from __future__ import annotations

import types
from enum import StrEnum
from typing import Annotated, Any, NotRequired, TypedDict, Union, get_args, get_origin, get_type_hints

from node.contract.keys import TopicKind


class Flag(StrEnum):
    """A monitor message's ``flag``."""

    OK = "ok"
    ALARM = "alarm"
    NO_MODEL = "no-model"


class Reason(StrEnum):
    """The rule that raised an alarm (a monitor message's ``reason``)."""

    RESIDUAL = "residual"
    STEP = "step"
    FLATLINE = "flatline"
    VECTOR = "vector"
    TRANSIENT = "transient"  # a critical speed shifted beyond the fleet's spread (monitor/transient)


class Phase(StrEnum):
    """Where in an OC the engine is; ``code`` numbers the phases in label arrays."""

    OFF = "off"
    TRANSITION = "transition"
    STEADY = "steady"

    @property
    def code(self) -> int:
        """0 off, 1 transition, 2 steady (phase labels over a whole run, as integers)."""
        return _PHASE_CODES[self]

    @classmethod
    def from_code(cls, code: int) -> Phase:
        return _PHASES[code]


class Status(StrEnum):
    """A verdict's ``status``: the pass-off verdict of a target in a run so far."""

    PASS = "pass"  # the run ended and no sample was over its limit
    FAIL = "fail"  # a sample was over its limit
    PENDING = "pending"  # the run goes on, no sample over its limit so far


class Refused(StrEnum):
    """Why the node refused a message (the keys of a health message's ``refused``): a refused
    message creates no state, no topic and no MCAP channel; it is counted, nothing more."""

    KEY = "key"  # not a sensor key by the contract's name rule (a wildcard, an empty chunk, ...)
    NOT_ADMITTED = "not_admitted"  # a bed outside the node's --beds pattern
    BED_LIMIT = "bed_limit"  # a new bed while the node tracks --max-beds beds
    CHANNEL_LIMIT = "channel_limit"  # a new channel no model needs beyond the bed's --max-channels
    RECORDING = "recording_channels"  # not recorded: the recording's channel table (u16 ids) is full


_PHASES = (Phase.OFF, Phase.TRANSITION, Phase.STEADY)
_PHASE_CODES = {p: i for i, p in enumerate(_PHASES)}


class SensorSample(TypedDict):
    """``testbed/<bed>/sensor/<channel>``: one sample of one channel."""

    t: Annotated[float, "acquisition time, s since the Unix epoch"]
    v: Annotated[float | None, "value; null for a dropout"]


class MonitorMessage(TypedDict):
    """``testbed/<bed>/monitor/<target>``: one aligned sample of the modelled channel."""

    t: Annotated[float, "time of the sample, s (the sensor clock)"]
    oc: Annotated[str | None, "the operating condition in force (\"rundown\" from the last plateau's "
                              "departure to standstill), null only while the engine is off"]
    phase: Annotated[Phase, "where in the OC the engine is"]
    measured: Annotated[float | None, "measured value of the target"]
    predicted: Annotated[float | None, "the model's prediction of the target"]
    residual: Annotated[float | None, "measured - predicted"]
    flag: Annotated[Flag, "ok, alarm, or no-model"]
    score: NotRequired[Annotated[float | None, "smoothed standardized residual, sigma units"]]
    band: NotRequired[Annotated[float | None, "the residual rule's alarm half-width around predicted"]]
    model: NotRequired[Annotated[str | None, "the model in force, method:OC; method:OC@envelope where "
                                             "envelope > 1: its inputs held at the envelope's edge, "
                                             "the band widened"]]
    envelope: NotRequired[Annotated[float | None, "how far the model's inputs and the time since the OC "
                                                  "switch lie from the region its training runs "
                                                  "covered: 1 at its edge, above 1 outside"]]
    reason: NotRequired[Annotated[Reason | None, "the rule that raised the alarm"]]
    run_scale: NotRequired[Annotated[float | None, "how unusual this run has been so far (>= 1)"]]
    measured_phase: NotRequired[Annotated[float | None, "measured phase of the target order, degrees"]]
    predicted_phase: NotRequired[Annotated[float | None, "the model's prediction of that phase, degrees"]]
    vector_residual: NotRequired[Annotated[float | None,
                                           "|measured - predicted 1x vector| (same unit as the target)"]]
    vector_score: NotRequired[Annotated[float | None,
                                        "the vector rule: change of the 1x vector on this plateau over "
                                        "its alarm level (alarm beyond 1)"]]
    limit: NotRequired[Annotated[float | None, "where the schedule holds limits for the target: the "
                                               "acceptance limit in force at this sample's speed or OC "
                                               "(the target's unit); null where none applies"]]
    over_limit: NotRequired[Annotated[bool, "where the schedule holds limits for the target: measured "
                                            "is above limit (independent of flag)"]]


class OCMessage(TypedDict):
    """``testbed/<bed>/monitor/oc``: one message at each OC or phase switch."""

    t: Annotated[float, "time of the switch, s (the sensor clock)"]
    oc: Annotated[str | None, "the OC now in force (\"rundown\" after the last plateau), null while "
                              "the engine is off"]
    phase: Annotated[Phase, "the phase now"]
    previous: Annotated[str | None, "the OC in force before"]


class TransientCritical(TypedDict):
    """One resonance crossed in a transition (an item of a transient message's ``criticals``)."""

    speed: Annotated[float, "critical speed, rpm of the schedule's switch channel"]
    amplitude: Annotated[float, "peak 1x amplitude there (the target's unit)"]
    phase_change: Annotated[float | None, "change of the phase lag across the resonance, degrees; "
                                          "null without phase"]
    af: Annotated[float, "amplification factor, API 684's half-power Nc / (N2 - N1): with phase, "
                         "of the fitted mode's own response (af_method modal fit), else of the "
                         "measured amplitude (half-power)"]
    expected_speed: Annotated[float | None, "the fleet's mean critical of this resonance in this kind "
                                            "of transition (rpm of the switch channel); null: none "
                                            "matches or the model has no fleet transients"]
    shift: Annotated[float | None, "(speed - expected_speed) / expected_speed, %"]
    shift_rpm: NotRequired[Annotated[float | None, "speed - expected_speed, rpm"]]
    limit: NotRequired[Annotated[float | None, "the |shift| beyond which the critical is an alarm, %"]]
    expected_af: NotRequired[Annotated[float | None, "the fleet's mean AF of this resonance"]]
    af_rise: NotRequired[Annotated[float | None, "(af - expected_af) / expected_af, %: a rise is lost "
                                                 "damping"]]
    af_limit: NotRequired[Annotated[float | None, "the af_rise beyond which the critical is an alarm, %"]]
    af_method: NotRequired[Annotated[str, "how af was read: modal fit (with phase) or half-power "
                                          "(amplitude only)"]]
    zeta: NotRequired[Annotated[float, "the damping ratio af implies"]]
    shaft_speed: NotRequired[Annotated[float, "the critical in rpm of the channel analysed (the "
                                              "target's own shaft where the model has it)"]]


class TransientMessage(TypedDict):
    """``testbed/<bed>/monitor/transient``: one message per target at the end of each transition the
    node analysed (a run-up, a coast-down, the ramp between two plateaus)."""

    t: Annotated[float, "the transition's end, s (the sensor clock)"]
    target: Annotated[str, "the modelled channel analysed"]
    direction: Annotated[str, "up or down"]
    from_speed: Annotated[float, "speed at its start, rpm of the switch channel"]
    to_speed: Annotated[float, "speed at its end, rpm of the switch channel"]
    criticals: Annotated[list[TransientCritical], "one object per resonance crossed, ascending speed"]
    flag: Annotated[Flag, "ok, alarm (a critical shifted beyond the fleet's spread), or no-model "
                          "(the model has no fleet transients)"]
    reason: Annotated[Reason | None, "the rule that raised the alarm (transient)"]
    kind: NotRequired[Annotated[str, "the kind of transition the fleet is kept per: direction, "
                                     "from and to (an OC or a speed band)"]]
    rate: NotRequired[Annotated[float, "mean speed rate, rpm/s of the switch channel"]]
    speed_channel: NotRequired[Annotated[str, "the speed channel the 1x vector was analysed on"]]


class SegmentForecast(TypedDict):
    """The forecast of one remaining segment of the run (an item of a verdict's ``forecast``)."""

    oc: Annotated[str, "the segment: an OC (its transition and plateau) or rundown"]
    peak: Annotated[float | None, "the predicted peak of the target in it (the target's unit); null: "
                                  "the training runs lack the segment"]
    peak_lo: Annotated[float | None, "the lower end of the predicted peak's 90 % interval"]
    peak_hi: Annotated[float | None, "the upper end of the predicted peak's 90 % interval"]
    p_exceed: Annotated[float | None, "the probability that the target exceeds its limit in the "
                                      "segment; null: no limit applies there"]


class VerdictMessage(TypedDict):
    """``testbed/<bed>/monitor/verdict``: one message per limited target at each OC switch and at
    the end of a run: the pass-off verdict so far and the forecast of the rest of the run."""

    t: Annotated[float, "time of the switch or the run's end, s (the sensor clock)"]
    target: Annotated[str, "the limited target"]
    run: Annotated[float, "the run's start time (light-off), s (the sensor clock)"]
    status: Annotated[Status, "pass (at the end of a run never over its limits), fail (once a sample "
                              "was over its limit) or pending (while the run goes on)"]
    margin: Annotated[float | None, "the smallest limit minus measured value so far (the target's unit); "
                                    "null: no sample had a limit yet"]
    margin_oc: Annotated[str | None, "the segment where the smallest margin fell"]
    margin_speed: Annotated[float | None, "the switch speed where it fell, rpm"]
    p_fail: Annotated[float | None, "the forecast probability that the rest of the run exceeds a limit "
                                    "(0 at its end); null: the model keeps no training peaks"]
    forecast: Annotated[list[SegmentForecast], "one object per remaining segment of the schedule, the "
                                               "segment just entered first; empty at the end of a run"]
    first_exceedance: NotRequired[Annotated[str | None, "the segment where the first exceedance is "
                                                        "expected, when p_fail is at least 0.5"]]


# the fields a bed's health and the node's own share: the serving node and its recording
Wall = Annotated[float, "the node's clock, s since the Unix epoch"]
Recording = Annotated[bool, "the node's recording is being written; false: an alarm"]
Unrecorded = Annotated[int, "messages (every bed) the recording could not keep: it failed, or it "
                            "refused their topic (its channel table full: refused.recording_channels)"]
NodeId = Annotated[str, "the serving node's id (its liveliness token's last chunk)"]
Beds = Annotated[str, "the beds that node serves: a bed name, * or a pattern with $*"]


class HealthMessage(TypedDict):
    """``testbed/<bed>/monitor/health``: about once a second, that bed's own counters."""

    t: Annotated[float, "the latest sensor time seen from this bed, s (its confirmed clock)"]
    wall: Wall
    received: Annotated[int, "sensor messages received from this bed"]
    malformed: Annotated[int, "of them, payloads that break the sensor payload rule"]
    dropped: Annotated[int, "this bed's messages lost in the node's queue"]
    samples: Annotated[int, "aligned 40 Hz samples"]
    late: Annotated[int, "messages that arrived after their sample went out"]
    duplicates: Annotated[int, "messages repeating a channel's sample"]
    missing: Annotated[dict[str, int], "samples each expected channel was absent from"]
    alarm_samples: Annotated[int, "monitor samples flagged alarm"]
    late_by_channel: Annotated[dict[str, int], "late messages of each expected channel"]
    phase_ms: Annotated[dict[str, float], "each expected channel's clock phase this run, ms after its slot"]
    clock_faults: NotRequired[Annotated[int, "samples dropped as far from the bed's clock and never "
                                             "confirmed by its other channels (a lone bad time)"]]
    clock_conflicts: NotRequired[Annotated[int, "of them, samples of a key that kept another clock "
                                                "(a second publisher on that key)"]]
    clock_jumps: NotRequired[Annotated[int, "moves of the bed's clock its channels confirmed "
                                            "(a clock set back or forward, a restart)"]]
    clock_held: NotRequired[Annotated[int, "samples held apart now, awaiting confirmation of their clock"]]
    transients_dropped: NotRequired[Annotated[int, "transitions too long to analyse (over 900 s), "
                                                   "dropped unpublished, every target"]]
    lag_ms_p50: NotRequired[Annotated[float | None, "receive to publish, ms, median of the last ones"]]
    lag_ms_p99: NotRequired[Annotated[float | None, "receive to publish, ms, 99th percentile"]]
    staleness: NotRequired[Annotated[float | None, "wall minus the receipt of the bed's last message, s"]]
    lag_ms_max: NotRequired[Annotated[float | None, "receive to publish, ms, largest since the last health"]]
    recording: NotRequired[Recording]
    unrecorded: NotRequired[Unrecorded]
    engine_state: NotRequired[Annotated[bool | None, "the engine-state file holds the node's engine history; "
                                        "false: its last save failed (an alarm), null: no file kept"]]
    node: NotRequired[NodeId]
    beds: NotRequired[Beds]
    refused: NotRequired[Annotated[dict[str, int], "this bed's messages refused, per reason (key: a "
                                                   "channel name breaking the rule, channel_limit: "
                                                   "a channel beyond the bed's bound)"]]
    expired: NotRequired[Annotated[bool, "the bed's last health: silent too long, its state freed"]]


class NodeHealthMessage(TypedDict):
    """``ordervib/node/<id>/health``: a node's own counters, every bed and none (what it refused
    or lost before any bed's state); once a second while they change. Recorded on the sensor
    clock, as a bed's health: ``t`` the beds' latest sensor time, ``wall`` the node's clock."""

    t: Annotated[float | None, "the beds' latest sensor time, s: the largest t of the beds tracked now "
                               "(the last one when none is); null before any sensor time, and then "
                               "published only, not recorded (a recording keeps one timeline)"]
    wall: Wall
    node: NodeId
    beds: Beds
    received: Annotated[int, "messages the node took from its queue, refused ones included"]
    dropped: Annotated[int, "messages lost in the node's queue (it was full), every key"]
    refused: Annotated[dict[str, int], "messages refused, per reason (key, not_admitted, bed_limit, "
                                       "channel_limit, recording_channels)"]
    tracked: Annotated[int, "beds tracked now"]
    max_beds: Annotated[int, "the bound on tracked beds"]
    max_channels: Annotated[int, "the bound on channels per bed"]
    expired: Annotated[int, "beds freed after a silence so far"]
    silent: NotRequired[Annotated[int, "beds tracked but out of the health rotation: silent (receive "
                                       "time) longer than the node's --health-silence"]]
    health_every_s: NotRequired[Annotated[int, "how often each bed in the rotation has its health now, "
                                               "s: ceil(beds / 100), the beds' health being 100 a "
                                               "second at most"]]
    recording: Recording
    unrecorded: Unrecorded
    cpu_us_per_message: Annotated[float | None, "the worker thread's CPU time (time.thread_time) per "
                                                "message taken, us, over the last health interval "
                                                "with messages (handling, publishing, recording, "
                                                "health included); its margin at R messages/s is "
                                                "1e6 / R minus this; null before any"]
    worker_lag_s: Annotated[float, "the age (receive time to now, node's clock) of the oldest "
                                   "message waiting in the node's queue, s; 0 when none waits"]
    clock: Annotated[dict[str, float | None], "the beds' clock guard: max_jump_s (s; null: no guard) "
                                              "and hold_s (s); a replay of the recording guards alike"]
    connected: NotRequired[Annotated[bool | None, "one of the node's connect endpoints answers (a link "
                                                  "to it is up); null: it has none (it only listens)"]]
    routers: NotRequired[Annotated[int, "Zenoh routers the node's session reaches now"]]
    peers: NotRequired[Annotated[int, "Zenoh peers the node's session reaches now"]]


MESSAGE_TYPES: dict[TopicKind, type] = {
    TopicKind.SENSOR: SensorSample, TopicKind.MONITOR: MonitorMessage,
    TopicKind.OC: OCMessage, TopicKind.HEALTH: HealthMessage, TopicKind.NODE_HEALTH: NodeHealthMessage,
    TopicKind.TRANSIENT: TransientMessage, TopicKind.VERDICT: VerdictMessage,
}


def _type_schema(tp: Any) -> dict[str, Any]:
    """The JSON Schema of one annotation (float, int, str, None, enums, unions, dict[str, x])."""
    origin = get_origin(tp)
    if origin is Annotated:
        inner, *meta = get_args(tp)
        return {**_type_schema(inner), **({"description": str(meta[0])} if meta else {})}
    if origin in (Union, types.UnionType):
        parts = [_type_schema(a) for a in get_args(tp)]
        out: dict[str, Any] = {"type": [p["type"] for p in parts]}
        enums = [p["enum"] for p in parts if "enum" in p]
        if enums:  # an enumerated string or null: list the values, null among them
            out["enum"] = [v for e in enums for v in e] + ([None] if "null" in out["type"] else [])
        return out
    if origin is dict:
        return {"type": "object", "additionalProperties": _type_schema(get_args(tp)[1])}
    if origin is list:
        return {"type": "array", "items": _type_schema(get_args(tp)[0])}
    if isinstance(tp, type) and issubclass(tp, dict) and hasattr(tp, "__annotations__"):  # a TypedDict
        return _object_schema(tp)
    if isinstance(tp, type) and issubclass(tp, StrEnum):
        return {"type": "string", "enum": [m.value for m in tp]}
    simple = {float: "number", int: "integer", str: "string", bool: "boolean", type(None): "null"}
    if tp in simple:
        return {"type": simple[tp]}
    raise TypeError(f"no JSON Schema for {tp!r}")


def json_schema(kind: TopicKind) -> dict[str, Any]:
    """The JSON Schema of a topic kind's messages (``"type": "object"``, properties, required).

    Enumerated fields list their values; a null where the schema allows one is listed
    as such. ``TopicKind.OTHER`` gets a bare object schema.
    """
    cls = MESSAGE_TYPES.get(kind)
    if cls is None:
        return {"title": "ordervib message", "type": "object"}
    return {"title": f"ordervib {kind.value} message", **_object_schema(cls)}


def _object_schema(cls: type) -> dict[str, Any]:
    """The JSON Schema of a TypedDict: description, ``"type": "object"``, properties, required."""
    hints = get_type_hints(cls, include_extras=True)
    props, required = {}, []
    for name, tp in hints.items():
        if get_origin(tp) is NotRequired:
            tp = get_args(tp)[0]
        else:
            required.append(name)
        props[name] = _type_schema(tp)
    return {"description": (cls.__doc__ or "").strip(), "type": "object", "properties": props,
            "required": required}
