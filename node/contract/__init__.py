"""The contract with test beds, recordings and outside tools (``docs/contract.md``), in one place.

Imports nothing else from the project. Keys and channels (``keys``), the sensor
payload rule (``payload``), the published messages and their JSON Schemas
(``messages``), the pass-off schedule file (``schedule``) and the one-line error
every command ends with (``errors``). Imported by their module's path: the 1x vector
and phase-lag rule (``vector``), the 40 Hz slot rule (``slotting``) and the project's
own JSON files (``documents``), and the published JSON Schema files (``schemas``).
"""

from node.contract.errors import OrdervibError
from node.contract.keys import (
    CHANNEL_UNITS,
    FS,
    MONITOR_SUBSCRIPTION,
    OFF_FRACTION,
    ORDER_CHANNELS,
    PHASE_CHANNELS,
    RESERVED_NAMES,
    RUN_GAP,
    SENSOR_CHANNELS,
    SENSOR_SUBSCRIPTION,
    SPEED_CHANNELS,
    TopicKind,
    bed_matcher,
    bed_of,
    engine_off,
    health_key,
    is_monitor_key,
    is_name,
    is_output_key,
    is_phase_channel,
    liveliness_key,
    monitor_key,
    monitor_subscription,
    node_health_key,
    oc_key,
    off_speed,
    parse_monitor_key,
    parse_sensor_key,
    phase_channel,
    run_starts,
    sensor_key,
    sensor_subscription,
    topic_kind,
    transient_key,
    verdict_key,
)
from node.contract.messages import (
    Flag,
    HealthMessage,
    MonitorMessage,
    NodeHealthMessage,
    OCMessage,
    Phase,
    Reason,
    Refused,
    SensorSample,
    Status,
    TransientCritical,
    TransientMessage,
    VerdictMessage,
    json_schema,
)
from node.contract.payload import check_sample, decode_sample, decode_samples, log_time_ns, log_times_ns
from node.contract.schedule import RUNDOWN, OperatingCondition, Schedule, load_schedule

__all__ = [
    "CHANNEL_UNITS", "FS", "MONITOR_SUBSCRIPTION", "OFF_FRACTION", "ORDER_CHANNELS", "PHASE_CHANNELS",
    "RESERVED_NAMES", "RUN_GAP",
    "SENSOR_CHANNELS",
    "SENSOR_SUBSCRIPTION", "SPEED_CHANNELS", "TopicKind", "bed_matcher", "bed_of", "engine_off", "health_key",
    "is_monitor_key", "is_name", "is_output_key",
    "is_phase_channel", "liveliness_key", "monitor_key", "monitor_subscription", "node_health_key", "oc_key",
    "off_speed", "parse_monitor_key",
    "parse_sensor_key", "phase_channel", "run_starts", "sensor_key", "sensor_subscription",
    "topic_kind", "transient_key", "verdict_key", "VerdictMessage", "Flag", "HealthMessage",
    "MonitorMessage", "NodeHealthMessage",
    "OCMessage", "Phase", "Reason", "Refused",
    "SensorSample", "Status", "TransientCritical", "TransientMessage", "json_schema", "check_sample",
    "decode_sample",
    "decode_samples", "log_time_ns", "log_times_ns",
    "OrdervibError", "OperatingCondition", "RUNDOWN", "Schedule", "load_schedule",
]
