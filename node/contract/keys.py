"""Key expressions, channels and timing of ``INTERFACE.md`` sections 1 to 3.

Every key the node reads or writes is built and parsed here, and nowhere else.

>>> sensor_key("bed1", "yB")
'testbed/bed1/sensor/yB'
>>> parse_sensor_key("testbed/bed1/sensor/yB")
('bed1', 'yB')
>>> topic_kind(monitor_key("bed1", "yB")), topic_kind(health_key("bed1"))
(<TopicKind.MONITOR: 'monitor'>, <TopicKind.HEALTH: 'health'>)
"""

from __future__ import annotations

import re
from enum import StrEnum

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

PREFIX = "testbed"
SENSOR_SUBSCRIPTION = f"{PREFIX}/*/sensor/**"  # every test bed's sensors
MONITOR_SUBSCRIPTION = f"{PREFIX}/*/monitor/**"  # every test bed's node outputs
LIVELINESS_PREFIX = "ordervib/node"
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

OC_TOPIC = "oc"  # monitor/<OC_TOPIC>: OC switches
HEALTH_TOPIC = "health"  # monitor/<HEALTH_TOPIC>: the bed's health

_SENSOR_RE = re.compile(rf"^{PREFIX}/([^/]+)/sensor/([^/]+)$")
_MONITOR_RE = re.compile(rf"^{PREFIX}/([^/]+)/monitor/([^/]+)$")
_BED_RE = re.compile(rf"^{PREFIX}/([^/]+)/")


class TopicKind(StrEnum):
    """What a key expression (and MCAP topic) carries; each kind has its own JSON Schema."""

    SENSOR = "sensor"
    MONITOR = "monitor"  # monitor/<target>
    OC = "oc"
    HEALTH = "health"
    OTHER = "other"


_RESERVED_KINDS = {OC_TOPIC: TopicKind.OC, HEALTH_TOPIC: TopicKind.HEALTH}


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


def parse_sensor_key(key: str) -> tuple[str, str] | None:
    """(bed, channel) of a sensor key expression, or None for any other key."""
    m = _SENSOR_RE.match(key)
    return (m.group(1), m.group(2)) if m else None


def parse_monitor_key(key: str) -> tuple[str, str] | None:
    """(bed, name) of a monitor key (name: a target, ``oc`` or ``health``), or None."""
    m = _MONITOR_RE.match(key)
    return (m.group(1), m.group(2)) if m else None


def bed_of(key: str) -> str | None:
    """The test bed a ``testbed/<bed>/...`` key belongs to, or None."""
    m = _BED_RE.match(key)
    return m.group(1) if m else None


def is_monitor_key(key: str) -> bool:
    """Whether a key is one of the node's outputs (monitor, oc or health)."""
    return _MONITOR_RE.match(key) is not None


def topic_kind(key: str) -> TopicKind:
    """The kind of a key expression."""
    if _SENSOR_RE.match(key):
        return TopicKind.SENSOR
    m = _MONITOR_RE.match(key)
    if m is None:
        return TopicKind.OTHER
    return _RESERVED_KINDS.get(m.group(2), TopicKind.MONITOR)
