"""node.contract: the payload rule (one matrix of cases for the scalar and the batch form, and
arbitrary bytes), the keys, and every recorded message valid under its topic kind's JSON Schema."""

from __future__ import annotations

import json
import math

import jsonschema
import numpy as np
import orjson
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from node.cli import main
from node.contract import (
    FS,
    ORDER_CHANNELS,
    PHASE_CHANNELS,
    SENSOR_CHANNELS,
    Flag,
    Phase,
    Reason,
    TopicKind,
    bed_of,
    decode_sample,
    decode_samples,
    health_key,
    is_monitor_key,
    is_phase_channel,
    json_schema,
    monitor_key,
    oc_key,
    parse_monitor_key,
    parse_sensor_key,
    phase_channel,
    sensor_key,
    topic_kind,
)
from node.contract.payload import T_MAX, decode_list

T = 1_767_600_000.0
# (payload, expected (t, v) or None for malformed)
CASES: list[tuple[bytes, tuple[float, float | None] | None]] = [
    (b'{"t": 1767600000.0, "v": 2.5}', (T, 2.5)),
    (b'{"t": 1767600000.0, "v": null}', (T, None)),
    (b'{"t": 1767600000, "v": 3}', (T, 3.0)),  # integers are numbers
    (b'{"t": 1767600000.0, "v": 2.5, "extra": [1]}', (T, 2.5)),  # further fields ignored
    (b'{"v": 2.5, "t": 1767600000.0}', (T, 2.5)),
    (b'{"t": 0.0, "v": -1e300}', (0.0, -1e300)),
    (b'{"t": -1.0, "v": 2.5}', None),  # before the epoch: cannot be stored as unsigned ns
    (b'{"t": 1e308, "v": 2.5}', None),  # beyond what a nanosecond log_time holds
    (b'{"t": 9.3e9, "v": 2.5}', None),
    (b'{"t": 1e400, "v": 2.5}', None),  # overflows to infinity
    (b'{"t": 1767600000.0, "v": 1e400}', None),
    (b'{"t": 123456789012345678901234567890123456789, "v": 1}', None),
    (b'{"t": true, "v": 2.5}', None),
    (b'{"t": 1767600000.0, "v": false}', None),
    (b'{"t": "1767600000.0", "v": 2.5}', None),
    (b'{"t": 1767600000.0, "v": "2.5"}', None),
    (b'{"t": 1767600000.0, "v": [2.5]}', None),
    (b'{"t": null, "v": 2.5}', None),
    (b'{"t": 1767600000.0}', None),
    (b'{"v": 2.5}', None),
    (b'[1767600000.0, 2.5]', None),
    (b'2.5', None),
    (b'"text"', None),
    (b'null', None),
    (b'', None),
    (b'{"t": 1767600000.0, "v": 2.5', None),
    (b'{"t": NaN, "v": 2.5}', None),
    (b'\xff\xfe\x00', None),
    (b'{"t": 1767600000.0, "v": 2.5}\x00', None),
]


@pytest.mark.parametrize("payload,expected", CASES)
def test_scalar_rule(payload: bytes, expected) -> None:
    assert decode_sample(payload) == expected


def _as_arrays(expected) -> tuple[float, float, bool]:
    if expected is None:
        return math.nan, math.nan, False
    t, v = expected
    return t, math.nan if v is None else v, True


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.array_equal(a, b, equal_nan=True))


def test_batch_rule_equals_the_scalar_rule_on_the_matrix() -> None:
    payloads = [p for p, _ in CASES]
    t, v, ok = decode_samples(payloads)
    _same_as_lists(payloads, t, v, ok)
    want = [_as_arrays(e) for _, e in CASES]
    assert _same(t, np.array([w[0] for w in want]))
    assert _same(v, np.array([w[1] for w in want]))
    assert ok.tolist() == [w[2] for w in want]


def _same_as_lists(payloads: list[bytes], t: np.ndarray, v: np.ndarray, ok: np.ndarray) -> None:
    """decode_list (the live node's few messages) gives decode_samples' very values."""
    tl, vl, okl = decode_list(payloads)
    assert okl == ok.tolist()
    assert np.array(tl, dtype=np.float64).tobytes() == t.tobytes()
    assert np.array(vl, dtype=np.float64).tobytes() == v.tobytes()


def test_batch_fast_path_applies_the_time_range() -> None:
    # all floats: the batch takes its fast path, which must still refuse out-of-range times
    payloads = [b'{"t": 1767600000.0, "v": 1.0}', b'{"t": -2.0, "v": null}', b'{"t": 1e300, "v": 2.0}']
    t, v, ok = decode_samples(payloads)
    _same_as_lists(payloads, t, v, ok)
    assert ok.tolist() == [True, False, False]
    assert _same(t, np.array([T, math.nan, math.nan])) and _same(v, np.array([1.0, math.nan, math.nan]))


def test_empty_batch() -> None:
    t, v, ok = decode_samples([])
    assert t.shape == v.shape == ok.shape == (0,)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False, allow_infinity=False) | st.text(),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=3), inner, max_size=3),
    max_leaves=6)
payload_objects = st.fixed_dictionaries(
    {}, optional={"t": json_values | st.floats(min_value=-1e10, max_value=2e10), "v": json_values})


@settings(max_examples=400, deadline=None)
@given(st.lists(st.binary(max_size=40) | payload_objects.map(lambda o: json.dumps(o).encode()), max_size=12))
def test_any_bytes_never_raise_and_batch_equals_scalar(payloads: list[bytes]) -> None:
    t, v, ok = decode_samples(payloads)
    _same_as_lists(payloads, t, v, ok)
    for i, p in enumerate(payloads):
        s = decode_sample(p)
        assert ok[i] == (s is not None)
        want = _as_arrays(s)
        assert _same(np.array([t[i], v[i]]), np.array(want[:2]))
        if s is not None:
            assert 0.0 <= s[0] < T_MAX and (s[1] is None or math.isfinite(s[1]))


def test_keys_round_trip_and_kinds() -> None:
    assert parse_sensor_key(sensor_key("bed-1", "yB_ph")) == ("bed-1", "yB_ph")
    assert parse_sensor_key(monitor_key("b", "yB")) is None
    assert parse_sensor_key("testbed/b/sensor/yB/extra") is None
    assert parse_monitor_key(monitor_key("b", "yA")) == ("b", "yA")
    assert topic_kind(sensor_key("b", "nB")) is TopicKind.SENSOR
    assert topic_kind(monitor_key("b", "yC")) is TopicKind.MONITOR
    assert topic_kind(oc_key("b")) is TopicKind.OC and topic_kind(health_key("b")) is TopicKind.HEALTH
    assert topic_kind(monitor_key("b", "transient")) is TopicKind.TRANSIENT
    assert topic_kind("elsewhere/b/sensor/nB") is TopicKind.OTHER
    assert is_monitor_key(health_key("b")) and not is_monitor_key(sensor_key("b", "nB"))
    assert bed_of(oc_key("x7")) == "x7" and bed_of("other") is None
    assert FS == 40.0
    assert set(ORDER_CHANNELS) <= set(SENSOR_CHANNELS) and not set(PHASE_CHANNELS) & set(SENSOR_CHANNELS)
    assert PHASE_CHANNELS == tuple(phase_channel(c) for c in ORDER_CHANNELS)
    assert all(map(is_phase_channel, PHASE_CHANNELS))
    assert not any(map(is_phase_channel, SENSOR_CHANNELS))


def test_enums_hold_the_contract_strings() -> None:
    assert [f.value for f in Flag] == ["ok", "alarm", "no-model"]
    assert {r.value for r in Reason} == {"residual", "step", "flatline", "vector", "transient"}
    assert [Phase.from_code(i) for i in range(3)] == [Phase.OFF, Phase.TRANSITION, Phase.STEADY]
    assert all(Phase.from_code(p.code) is p for p in Phase)


@pytest.mark.parametrize("kind", [TopicKind.SENSOR, TopicKind.MONITOR, TopicKind.OC, TopicKind.HEALTH,
                                  TopicKind.TRANSIENT])
def test_schemas_are_objects_with_properties_and_required(kind: TopicKind) -> None:
    schema = json_schema(kind)
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["type"] == "object" and schema["required"]
    assert set(schema["required"]) <= set(schema["properties"])


def test_schemas_refuse_what_the_contract_refuses() -> None:
    mon = jsonschema.Draft202012Validator(json_schema(TopicKind.MONITOR))
    good = {"t": T, "oc": "OC3", "phase": "steady", "measured": 1.0, "predicted": 0.9, "residual": 0.1,
            "flag": "ok"}
    assert mon.is_valid(good)
    assert not mon.is_valid({**good, "flag": "maybe"})
    assert not mon.is_valid({**good, "phase": "idle"})
    assert not mon.is_valid({k: v for k, v in good.items() if k != "residual"})
    assert mon.is_valid({**good, "reason": None}) and mon.is_valid({**good, "reason": "step"})


def test_every_recorded_message_is_valid_under_its_recorded_schema(tmp_path) -> None:
    from conftest import small_campaign
    from mcap.reader import make_reader

    d = small_campaign(tmp_path, seed=5)
    assert main(["replay", str(d / "test.mcap"), "--model", str(d / "m"), "--out", str(d / "out.mcap"),
                 "--quiet"]) == 0
    kinds: dict[TopicKind, int] = {}
    with open(d / "out.mcap", "rb") as f:
        validators: dict[int, jsonschema.Draft202012Validator] = {}
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
            if schema.id not in validators:
                validators[schema.id] = jsonschema.Draft202012Validator(orjson.loads(schema.data))
                assert orjson.loads(schema.data) == json_schema(topic_kind(channel.topic))
            validators[schema.id].validate(orjson.loads(message.data))
            kinds[topic_kind(channel.topic)] = kinds.get(topic_kind(channel.topic), 0) + 1
    assert kinds[TopicKind.SENSOR] > 0 and kinds[TopicKind.MONITOR] > 0 and kinds[TopicKind.OC] > 0
