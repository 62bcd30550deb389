"""Aligning independently published channels into 40 Hz samples."""

from __future__ import annotations

import math

import numpy as np
import orjson
import pytest

from node.runtime.align import Aligner


def feed(aligner: Aligner, msgs):
    out = []
    for ch, t, v in msgs:
        out += aligner.push(ch, t, v)
    return out + aligner.flush()


def grid(n, channels, t0=1000.0, jitter=0.0, seed=0):
    rng = np.random.default_rng(seed)
    msgs = []
    for k in range(n):
        for c in channels:
            msgs.append((c, t0 + k / 40 + jitter * rng.uniform(-1, 1), float(k)))
    return msgs


def test_jitter_and_reordering_within_the_wait_keep_every_value():
    rng = np.random.default_rng(1)
    msgs = grid(200, ["nB", "yB", "tF"], jitter=0.002)
    # shuffle within windows of 6 messages (arrival out of order, 2 samples deep)
    for i in range(0, len(msgs), 6):
        block = msgs[i:i + 6]
        rng.shuffle(block)
        msgs[i:i + 6] = block
    a = Aligner(["nB", "yB", "tF"])
    out = feed(a, msgs)
    assert len(out) == 200
    for k, s in enumerate(out):
        assert s.values == {"nB": k, "yB": k, "tF": k}
        assert math.isclose(s.t, 1000.0 + k / 40, abs_tol=0.003)
    assert a.stats.late == 0 and not a.stats.missing


def test_duplicates_dropouts_missing_and_unknown_channels_are_counted():
    msgs = grid(50, ["nB", "yB"])
    msgs.insert(11, ("nB", 1000.0 + 5 / 40, 99.0))  # duplicate of slot 5 (first one wins)
    msgs = [m for m in msgs if not (m[0] == "yB" and m[2] == 20.0)]  # yB of slot 20 never comes
    msgs[40] = (msgs[40][0], msgs[40][1], None)  # a dropout: null value
    msgs.append(("zz", 1000.5, 1.0))
    a = Aligner(["nB", "yB"])
    out = feed(a, msgs)
    assert len(out) == 50
    assert out[5].values["nB"] == 5.0 and a.stats.duplicates == 1
    assert math.isnan(out[20].values["yB"]) and a.stats.missing["yB"] == 1
    assert sum(math.isnan(v) for s in out for v in s.values.values()) == 2
    assert a.stats.unknown["zz"] == 1


def test_late_message_after_the_wait_is_counted_not_misplaced():
    msgs = grid(40, ["nB", "yB"])
    late = [m for m in msgs if m[0] == "yB" and m[2] == 3.0][0]
    msgs.remove(late)
    msgs.append(late)  # arrives a second late
    a = Aligner(["nB", "yB"], max_wait=0.1)
    out = feed(a, msgs)
    assert len(out) == 40 and math.isnan(out[3].values["yB"]) and a.stats.late == 1


def test_gap_starts_a_new_run_on_a_new_grid():
    msgs = grid(20, ["nB"]) + grid(20, ["nB"], t0=1000.0 + 20 / 40 + 300.013)
    out = feed(Aligner(["nB"]), msgs)
    assert len(out) == 40
    assert out[20].new_run and not out[19].new_run and out[0].new_run
    assert out[20].t == 52021 / 40  # the absolute grid: slot k is k / 40 s; 1300.513 s is 20.52 slots


def test_malformed_payloads_are_counted_and_skipped(tmp_path):
    from node.contract.schedule import OperatingCondition, Schedule
    from node.models.bundle import Bundle
    from node.runtime.core import NodeCore
    sched = Schedule((OperatingCondition("A", 4000.0),))
    core = NodeCore(Bundle("wdmd", "yB", sched, []))
    bad = [b"{", b"[1,2]", b'{"t": "x", "v": 1}', b'{"t": 1.0}', b'{"t": NaN, "v": 1}', b"\xff"]
    for p in bad:
        assert core.handle("testbed/b/sensor/nB", p) == []
    assert core.beds["b"].malformed == core.malformed == len(bad) == core.beds["b"].received
    assert core.handle("some/other/key", b"{}") == [] and core.foreign == 1
    out = []
    for k in range(80):
        for ch in ("nB", "yB"):
            out += core.handle(f"testbed/b/sensor/{ch}", orjson.dumps({"t": 10.0 + k / 40, "v": 1.0}))
    assert len([o for o in out if o[0] == "testbed/b/monitor/yB"]) >= 70
    assert all(o[1]["flag"] == "no-model" for o in out if o[0].endswith("/yB"))


def test_a_sample_is_emitted_by_the_message_that_completes_it():
    # live latency: no waiting for the next sample once every expected channel is in (a run's
    # first slot waits for 0.1 s of data: an earlier message might still come)
    a = Aligner(["nB", "yB", "tF"], max_wait=0.1)
    for k in range(10):
        t = 1000.0 + k / 40
        first = a.push("yB", t + 0.001, 1.0)
        assert [s.t for s in first] == ([(40000 + i) / 40 for i in range(4)] if k == 4 else [])
        assert a.push("zz", t, 1.0) == []  # a channel the model does not need
        assert a.push("tF", t - 0.001, 2.0) == []
        out = a.push("nB", t, 3.0)
        if k < 4:
            assert out == []
            continue
        assert len(out) == 1 and out[0].values == {"nB": 3.0, "yB": 1.0, "tF": 2.0}
        assert out[0].t == (40000 + k) / 40  # the absolute grid, whichever channel came first
    assert a.flush() == []


def test_health_is_per_bed_and_pure():
    from node.contract import json_schema
    from node.contract.keys import TopicKind
    from node.contract.schedule import OperatingCondition, Schedule
    from node.models.bundle import Bundle
    from node.runtime.core import NodeCore
    jsonschema = pytest.importorskip("jsonschema")
    core = NodeCore(Bundle("wdmd", "yB", Schedule((OperatingCondition("A", 4000.0),)), []))
    keys, payloads = [], []
    for k in range(40):
        for bed in ("b1", "b2"):
            for ch in ("nB", "yB"):
                if bed == "b2" and ch == "yB" and k % 2:
                    continue  # b2 loses half its yB
                keys.append(f"testbed/{bed}/sensor/{ch}")
                payloads.append(orjson.dumps({"t": 10.0 + k / 40 + (bed == "b2"), "v": 1.0}))
    keys += ["testbed/b1/sensor/nB", "other/key"]
    payloads += [b"{", b"{}"]
    batch = core.handle_batch(keys, payloads)
    assert np.isnan(batch.t[-2]) and batch.t[0] == 10.0 and len(batch.t) == len(keys)
    assert core.foreign == 1 and list(core.beds) == ["b1", "b2"]
    h1, h2 = core.health("b1", 1e9, dropped=3), core.health("b2", 1e9, dropped=3)
    assert (h1["received"], h1["malformed"], h2["received"], h2["malformed"]) == (81, 1, 60, 0)
    assert h1["t"] == 10.0 + 39 / 40 and h2["t"] == 11.0 + 39 / 40 and h1["wall"] == 1e9
    assert h1["dropped"] == h2["dropped"] == 3 and h2["samples"] > h2["missing"].get("yB", 0) > 0
    assert core.health("b1", 1e9, dropped=3) == h1  # no clock, no side effect
    jsonschema.validate(h1, json_schema(TopicKind.HEALTH))


def _hostile_stream(seed: int) -> list[tuple[str, float, float | None]]:
    """Four channels at 40 Hz, jittered and reordered, with duplicates, dropouts, nulls, late
    messages, an unknown channel, a silence that starts a new run and a far-off clock burst."""
    rng = np.random.default_rng(seed)
    chans = ["a", "b", "c", "d"]
    msgs: list[tuple[float, str, float, float | None]] = []  # (arrival, channel, t, v)
    for run, (t0, n) in enumerate(((1000.0, 300), (1200.0, 200))):  # 100 s apart: a new run
        for k in range(n):
            for c in chans:
                if rng.random() < 0.04:
                    continue  # dropout
                t = t0 + k / 40 + rng.uniform(-0.008, 0.008)
                v = None if rng.random() < 0.03 else float(rng.normal())
                arrival = t + (rng.uniform(0.3, 0.6) if rng.random() < 0.02 else rng.uniform(0, 0.01))
                msgs.append((arrival, c, t, v))
                if rng.random() < 0.03:
                    msgs.append((arrival + 0.001, c, t, v))  # duplicate
            if rng.random() < 0.02:
                msgs.append((t0 + k / 40, "zz", t0 + k / 40, 1.0))  # a channel nobody expects
        if run == 0:
            msgs += [(t0 + 5.0 + j * 1e-4, "a", 9e8 + j / 40, 0.0) for j in range(3)]  # a far clock
    msgs.sort(key=lambda m: m[0])
    return [(c, t, v) for _, c, t, v in msgs]


def _state(aligner: Aligner, samples: list) -> tuple:
    s = aligner.stats
    rows = [(x.t, x.new_run, sorted((c, repr(v)) for c, v in x.values.items())) for x in samples]
    return (rows, s.samples, s.late, dict(s.late_by_channel), s.duplicates, dict(s.missing),
            dict(s.unknown), aligner.guard.taken, aligner.guard.faults)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_push_list_has_push_s_very_effects_on_a_hostile_stream(seed):
    msgs = _hostile_stream(seed)
    one = Aligner(["a", "b", "c", "d"], max_wait=0.25)
    by_one = feed(one, msgs)
    rng = np.random.default_rng(seed + 10)
    lists = Aligner(["a", "b", "c", "d"], max_wait=0.25)
    by_list: list = []
    i = 0
    while i < len(msgs):
        j = i + int(rng.integers(1, 40))
        c, t, v = zip(*msgs[i:j], strict=True)
        done = lists.push_list(list(c), list(t), list(v))
        assert [k for k, _ in done] == sorted({k for k, _ in done})  # in message order, once each
        by_list += [x for _, got in done for x in got]
        i = j
    by_list += lists.flush()
    assert by_one and one.stats.late and one.stats.duplicates and one.stats.unknown
    assert _state(lists, by_list) == _state(one, by_one)
