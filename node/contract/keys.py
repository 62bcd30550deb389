"""Key expressions, channels and timing of ``docs/contract.md`` sections 1 to 3.

Every key the node reads or writes is built and parsed here, and nowhere else.

>>> sensor_key("bed1", "yB")
'testbed/bed1/sensor/yB'
>>> parse_sensor_key("testbed/bed1/sensor/yB")
('bed1', 'yB')
>>> topic_kind(monitor_key("bed1", "yB")), topic_kind(health_key("bed1"))
(<TopicKind.MONITOR: 'monitor'>, <TopicKind.HEALTH: 'health'>)

A ``<bed>`` or ``<channel>`` is one key chunk of letters, digits, ``_``, ``-`` and ``.``, at
most 64 characters (section 1): a key with a wildcard or an empty chunk is no sensor key.

>>> parse_sensor_key("testbed/*/sensor/nB"), parse_sensor_key("testbed/**/sensor/nB")
(None, None)
>>> parse_sensor_key("testbed/east$*/sensor/nB"), parse_sensor_key("testbed//sensor/nB")
(None, None)
>>> parse_sensor_key("testbed/" + "b" * 65 + "/sensor/nB"), is_name("b" * 64)
(None, True)
"""

from __future__ import annotations

import re
from collections.abc import Callable
from enum import StrEnum

import numpy as np

FS = 40.0  # nominal sample rate per channel, Hz (section 1)
RUN_GAP = 60.0  # s without data separate two runs (section 3)
OFF_FRACTION = 0.05  # the engine is off when every shaft speed is below this fraction of its maximum

# Section 1, in table order.
SPEED_CHANNELS: tuple[str, ...] = ("nA", "nB", "nC")
ORDER_CHANNELS: tuple[str, ...] = ("yA", "yB", "yC")  # tracked order-1 amplitudes, mm/s
PHASE_SUFFIX = "_ph"  # an order's phase channel: the amplitude channel's name + this suffix
PHASE_CHANNELS: tuple[str, ...] = ("yA_ph", "yB_ph", "yC_ph")  # optional order phases, degrees
SENSOR_CHANNELS: tuple[str, ...] = (
    *SPEED_CHANNELS, *ORDER_CHANNELS,
    "tA", "tB", "tC", "tD", "tE", "tF", "tG", "tH", "tI",
    "pA", "pB", "pC", "pD",
    "M1", "M2",
)  # fmt: skip

# The unit of each channel of section 1 ("" for the unitless control signals M1, M2).
CHANNEL_UNITS: dict[str, str] = {
    **dict.fromkeys(SPEED_CHANNELS, "rpm"),
    **dict.fromkeys(ORDER_CHANNELS, "mm/s"),  # peak
    **{f"t{c}": "degC" for c in "ABCDEFGHI"},
    **{f"p{c}": "kPa" for c in "ABCD"},
    "M1": "", "M2": "",
    **dict.fromkeys(PHASE_CHANNELS, "deg"),  # lag from the once-per-rev mark, in [-180, 180)
}


def run_starts(t: np.ndarray) -> np.ndarray:
    """Where a new run starts in sorted times t (K,) s by the gap rule of section 3 (a gap of
    ``RUN_GAP`` s or more): the indices i (int64, ascending, never 0) with t[i] - t[i-1] >= 60 s.
    The other half of the rule (every shaft speed below ``OFF_FRACTION`` of its maximum) needs
    the speeds: ``engine_off``.

    >>> run_starts(np.array([0.0, 0.025, 59.0, 119.0, 119.025])).tolist()
    [3]
    """
    return np.flatnonzero(np.diff(np.asarray(t, dtype=float)) >= RUN_GAP) + 1


def off_speed(top: float, fraction: float = OFF_FRACTION) -> float:
    """The speed (unit of ``top``) below which a shaft counts as off: ``fraction`` of its maximum
    ``top`` (section 3). The one engine-off rule: run splitting (``engine_off``, each shaft's
    maximum over the recording) and the causal OC detector (the switch shaft, its highest
    plateau standing for its maximum) both compare a speed with this level.

    >>> off_speed(9800.0)
    490.0
    """
    return fraction * top


def engine_off(speeds: np.ndarray, tops: np.ndarray, fraction: float = OFF_FRACTION) -> np.ndarray:
    """(K,) bool: the engine is off at each row of ``speeds`` (K, S), every shaft speed below
    ``off_speed`` of its maximum ``tops`` (S,) (section 3). A missing (NaN) speed holds no
    shaft on; a row with no speed at all is not known to be off.

    >>> engine_off(np.array([[10.0, 600.0], [10.0, 20.0], [np.nan, 20.0], [np.nan, np.nan]]),
    ...            np.array([9800.0, 9000.0])).tolist()
    [False, True, True, False]
    """
    levels = np.array([off_speed(float(top), fraction) for top in np.ravel(tops)])
    missing = np.isnan(speeds)
    off: np.ndarray = np.all((speeds < levels) | missing, axis=1)
    return off & ~np.all(missing, axis=1)


PREFIX = "testbed"
SENSOR_SUBSCRIPTION = f"{PREFIX}/*/sensor/**"  # every test bed's sensors
MONITOR_SUBSCRIPTION = f"{PREFIX}/*/monitor/**"  # every test bed's node outputs
LIVELINESS_PREFIX = "ordervib/node"
NAME_MAX = 64  # characters of a bed or channel name at most (section 1)
_NAME = rf"[A-Za-z0-9_.\-]{{1,{NAME_MAX}}}"  # a bed or channel name: one key chunk, no wildcard
_NAME_RE = re.compile(_NAME)
_BEDS_CHUNK = re.compile(r"^(\*|(?:[A-Za-z0-9_.\-]|\$\*)+)$")  # a bed name, ``*``, or a name with ``$*``


def sensor_subscription(beds: str = "*") -> str:
    """The sensor key expression of the beds matching ``beds``: one key-expression chunk, a bed's
    name, ``*`` (every bed) or a name with Zenoh's in-chunk wildcard ``$*`` (``east$*``: every
    bed whose name starts with ``east``). ValueError for anything else (a ``/`` would reach
    into other levels).

    >>> sensor_subscription("east$*")
    'testbed/east$*/sensor/**'
    """
    if not _BEDS_CHUNK.match(beds) or "$*$*" in beds:
        raise ValueError(f"beds pattern {beds!r}: give a bed name, * or a name with $* (e.g. east$*)")
    return f"{PREFIX}/{beds}/sensor/**"


def monitor_subscription(beds: str = "*") -> str:
    """The node-output key expression (monitor, oc, health, transient) of the beds matching
    ``beds``, as ``sensor_subscription`` takes it (ValueError for a bad pattern).

    >>> monitor_subscription("b1"), monitor_subscription() == MONITOR_SUBSCRIPTION
    ('testbed/b1/monitor/**', True)
    """
    sensor_subscription(beds)  # ValueError for a bad pattern
    return f"{PREFIX}/{beds}/monitor/**"


def bed_matcher(beds: str = "*") -> Callable[[str], bool]:
    """Whether a bed name matches the pattern ``beds`` (as ``sensor_subscription`` takes it), as
    Zenoh matches the chunk: ``*`` any name, ``$*`` any run of characters (none too).

    >>> east = bed_matcher("east$*")
    >>> east("east1"), east("east"), east("west1"), bed_matcher("*")("x"), bed_matcher("b1")("b10")
    (True, True, False, True, False)
    """
    sensor_subscription(beds)  # ValueError for a bad pattern
    if beds == "*":
        return is_name
    rule = re.compile(".*".join(map(re.escape, beds.split("$*"))), re.DOTALL)
    return lambda name: rule.fullmatch(name) is not None


def is_name(chunk: str) -> bool:
    """Whether ``chunk`` is a valid bed or channel name (section 1: letters, digits, ``_``, ``-``
    and ``.``, 1 to 64 characters; no wildcard).

    >>> is_name("bed-1.a_b"), is_name("*"), is_name("**"), is_name("a$*"), is_name("")
    (True, False, False, False, False)
    """
    return _NAME_RE.fullmatch(chunk) is not None

OC_TOPIC = "oc"  # monitor/<OC_TOPIC>: OC switches
HEALTH_TOPIC = "health"  # monitor/<HEALTH_TOPIC>: the bed's health
TRANSIENT_TOPIC = "transient"  # monitor/<TRANSIENT_TOPIC>: each analysed transition's criticals
VERDICT_TOPIC = "verdict"  # monitor/<VERDICT_TOPIC>: the pass-off verdict per limited target
RESERVED_NAMES = frozenset({OC_TOPIC, HEALTH_TOPIC, TRANSIENT_TOPIC, VERDICT_TOPIC})  # never a target's name

_SENSOR_RE = re.compile(rf"{PREFIX}/({_NAME})/sensor/({_NAME})\Z")
_MONITOR_RE = re.compile(rf"{PREFIX}/({_NAME})/monitor/({_NAME})\Z")
_BED_RE = re.compile(rf"^{PREFIX}/([^/]+)/")
_NODE_HEALTH_RE = re.compile(rf"{LIVELINESS_PREFIX}/[^/*$]+/{HEALTH_TOPIC}\Z")


class TopicKind(StrEnum):
    """What a key expression (and MCAP topic) carries; each kind has its own JSON Schema."""

    SENSOR = "sensor"
    MONITOR = "monitor"  # monitor/<target>
    OC = "oc"
    HEALTH = "health"
    TRANSIENT = "transient"  # monitor/transient: one message per target and transition analysed
    VERDICT = "verdict"  # monitor/verdict: one message per limited target at each OC switch and run end
    NODE_HEALTH = "node-health"  # ordervib/node/<id>/health: a node's own counters
    OTHER = "other"


_RESERVED_KINDS = {OC_TOPIC: TopicKind.OC, HEALTH_TOPIC: TopicKind.HEALTH,
                   TRANSIENT_TOPIC: TopicKind.TRANSIENT, VERDICT_TOPIC: TopicKind.VERDICT}


def sensor_key(bed: str, channel: str) -> str:
    """Key expression (and MCAP topic) of a sensor channel."""
    return f"{PREFIX}/{bed}/sensor/{channel}"


def monitor_key(bed: str, target: str) -> str:
    """Key of the monitor messages of one modelled channel."""
    return f"{PREFIX}/{bed}/monitor/{target}"


def oc_key(bed: str) -> str:
    """Key of a bed's OC switch messages."""
    return monitor_key(bed, OC_TOPIC)


def health_key(bed: str) -> str:
    """Key of a bed's health messages."""
    return monitor_key(bed, HEALTH_TOPIC)


def transient_key(bed: str) -> str:
    """Key of a bed's transient messages (every target's, each names its ``target``).

    >>> transient_key("b1"), topic_kind(transient_key("b1"))
    ('testbed/b1/monitor/transient', <TopicKind.TRANSIENT: 'transient'>)
    """
    return monitor_key(bed, TRANSIENT_TOPIC)


def verdict_key(bed: str) -> str:
    """Key of a bed's verdict messages (every limited target's, each names its ``target``).

    >>> verdict_key("b1"), topic_kind(verdict_key("b1"))
    ('testbed/b1/monitor/verdict', <TopicKind.VERDICT: 'verdict'>)
    """
    return monitor_key(bed, VERDICT_TOPIC)


def phase_channel(order: str) -> str:
    """The phase channel (degrees) of a tracked order's amplitude channel.

    >>> phase_channel("yB")
    'yB_ph'
    """
    return order + PHASE_SUFFIX


def is_phase_channel(channel: str) -> bool:
    """Whether a channel is a tracked order's phase (degrees), not an amplitude or a signal.

    >>> is_phase_channel("yB_ph"), is_phase_channel("yB")
    (True, False)
    """
    return channel.endswith(PHASE_SUFFIX)


def liveliness_key(node_id: str) -> str:
    """The liveliness token a running node holds."""
    return f"{LIVELINESS_PREFIX}/{node_id}"


def node_health_key(node_id: str) -> str:
    """Key of a node's own health messages: its node-wide counters (what it refused, lost in its
    queue, how many beds it tracks), which belong to no bed.

    >>> node_health_key("1f2e"), topic_kind(node_health_key("1f2e"))
    ('ordervib/node/1f2e/health', <TopicKind.NODE_HEALTH: 'node-health'>)
    """
    return f"{LIVELINESS_PREFIX}/{node_id}/{HEALTH_TOPIC}"


def parse_sensor_key(key: str) -> tuple[str, str] | None:
    """(bed, channel) of a sensor key expression, or None for any other key: one whose bed or
    channel breaks the name rule (a wildcard ``*``, ``**``, ``$*``, an empty chunk, more than 64
    characters, another character) is none. The one parse of the node's input keys."""
    m = _SENSOR_RE.match(key)
    return (m.group(1), m.group(2)) if m else None


def parse_monitor_key(key: str) -> tuple[str, str] | None:
    """(bed, name) of a monitor key (name: a target, ``oc``, ``health`` or ``transient``), or None
    (for a bed or name that breaks the name rule too)."""
    m = _MONITOR_RE.match(key)
    return (m.group(1), m.group(2)) if m else None


def bed_of(key: str) -> str | None:
    """The test bed a ``testbed/<bed>/...`` key belongs to, or None."""
    m = _BED_RE.match(key)
    return m.group(1) if m else None


def is_monitor_key(key: str) -> bool:
    """Whether a key is one of the node's outputs of a bed (monitor, oc, health or transient)."""
    return _MONITOR_RE.match(key) is not None


def is_output_key(key: str) -> bool:
    """Whether a key is one of the node's outputs: a bed's (``is_monitor_key``) or its own health.

    >>> is_output_key(health_key("b1")), is_output_key(node_health_key("n1")), is_output_key("x")
    (True, True, False)
    """
    return _MONITOR_RE.match(key) is not None or _NODE_HEALTH_RE.match(key) is not None


def topic_kind(key: str) -> TopicKind:
    """The kind of a key expression."""
    if _SENSOR_RE.match(key):
        return TopicKind.SENSOR
    m = _MONITOR_RE.match(key)
    if m is None:
        return TopicKind.NODE_HEALTH if _NODE_HEALTH_RE.match(key) else TopicKind.OTHER
    return _RESERVED_KINDS.get(m.group(2), TopicKind.MONITOR)
