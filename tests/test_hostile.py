"""Hostile and broken clients (issue 31, items 1, 2 and 4): bounded, authorized, never blind.

Keys by the contract's name rule, beds by the node's pattern and bounds, the refused counted per
reason in health and never a bed, a topic or an MCAP channel; queue losses counted; the
recording bounded in channels and never failing on them; silent beds freed. The live tests run
the node in this process on a free loopback port and wait on conditions, bounded in time; none
asserts a wall-clock duration.
"""

from __future__ import annotations

import threading
import time

import orjson
import pytest
from conftest import small_campaign

from harness.live import Bench, free_port, latencies, load_stream, wait_for
from node.cli import main
from node.contract import (
    TopicKind,
    bed_matcher,
    is_name,
    node_health_key,
    parse_monitor_key,
    parse_sensor_key,
    sensor_key,
    topic_kind,
)
from node.mcap import RecordingWriter, iter_messages
from node.mcap.rotation import RotatingRecorder
from node.models.bundle import Bundle, load_bundle

GOOD = b'{"t": 1700000000.0, "v": 1.0}'
WILDCARD_KEYS = ["testbed/*/sensor/nB", "testbed/**/sensor/nB", "testbed/b$*/sensor/nB",
                 "testbed/b1/sensor/*", "testbed/b1/sensor/nB/x", "testbed/" + "b" * 65 + "/sensor/nB"]


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    return small_campaign(tmp_path_factory.mktemp("hostile"), 3)


def _bundle() -> Bundle:
    from node.contract.schedule import OperatingCondition, Schedule
    return Bundle("wdmd", "yB", Schedule((OperatingCondition("A", 4000.0),)), [])


# -- the rule, the core's admission (no Zenoh)

def test_names_by_the_contract_rule():
    good = ["b1", "bed-1.a_B", "x" * 64, "0"]
    bad = ["*", "**", "$*", "b$*", "", "x" * 65, "a b", "a/b", "é", "a\n", "@b"]
    assert all(map(is_name, good)) and not any(map(is_name, bad))
    for b in good:
        assert parse_sensor_key(sensor_key(b, "nB")) == (b, "nB")
        assert parse_sensor_key(sensor_key("b1", b)) == ("b1", b)
    for b in bad:
        assert parse_sensor_key(f"testbed/{b}/sensor/nB") is None
        assert parse_sensor_key(f"testbed/b1/sensor/{b}") is None
        assert parse_monitor_key(f"testbed/{b}/monitor/health") is None
    assert parse_sensor_key("testbed/b1/sensor/nB\n") is None
    east = bed_matcher("east$*")
    assert [east(b) for b in ("east", "east1", "weast1", "east.2")] == [True, True, False, True]
    assert bed_matcher("a$*b")("a-x-b") and not bed_matcher("a$*b")("a-x-c")
    assert topic_kind(node_health_key("abc")) is TopicKind.NODE_HEALTH
    assert topic_kind("ordervib/node/*/health") is TopicKind.OTHER


def test_the_core_refuses_without_creating_state():
    from node.runtime.core import NodeCore
    core = NodeCore(_bundle(), beds="b$*", max_beds=2, max_channels=4)  # the model needs nB and yB
    keys = ["testbed/b1/sensor/nB", "testbed/*/sensor/nB", "testbed/x/sensor/nB", "testbed/b2/sensor/nB",
            "testbed/b3/sensor/nB", "testbed/b1/sensor/c1", "testbed/b1/sensor/c2", "testbed/b1/sensor/c3",
            "testbed/b1/sensor/**", "other", "testbed/b3/sensor/nB", "testbed/b1/sensor/c1"]
    batch = core.handle_batch(keys, [GOOD] * len(keys))
    assert list(core.beds) == ["b1", "b2"]  # admitted in arrival order
    assert batch.refused is not None
    assert batch.refused.tolist() == [False, True, True, False, True, False, False, True, True, True, True,
                                      False]
    assert dict(core.refused) == {"key": 3, "not_admitted": 1, "bed_limit": 2, "channel_limit": 1}
    assert core.foreign == 3
    assert core.beds["b1"].received == 4 and core.beds["b1"].extra == {"c1", "c2"}
    assert core.health("b1", 0.0)["refused"] == {"key": 1, "channel_limit": 1}
    assert core.health("b2", 0.0)["refused"] == {}
    assert sorted(core._routes) == sorted({k for k, r in zip(keys, batch.refused) if not r})
    # the model's channels are admitted even with the bed's channels at the bound
    assert core.route("testbed/b1/sensor/yB") == ("b1", "yB")
    # a batch of admitted keys only marks nothing (yB: a second channel confirms the bed's clock)
    assert core.handle_batch(["testbed/b1/sensor/nB", "testbed/b1/sensor/yB"], [GOOD] * 2).refused is None
    # a freed bed leaves no key in the cache and its slot to a new bed
    assert [key for key, _ in core.flush_bed("b1")] == ["testbed/b1/monitor/yB"]  # the waiting sample
    core.forget("b1")
    assert list(core.beds) == ["b2"] and not any(k.startswith("testbed/b1/") for k in core._routes)
    assert "b1" not in core.engine_states()  # its engine never ran: nothing kept
    assert core.route("testbed/b3/sensor/nB") == ("b3", "nB") and list(core.beds) == ["b2", "b3"]
    with pytest.raises(ValueError, match="max_beds"):
        NodeCore(_bundle(), max_beds=0)


def test_a_full_intake_holds_the_links_back_and_loses_nothing(setup, tmp_path, monkeypatch):
    """The worker held up while 400 messages arrive at a node whose intake holds 16: none is
    lost (Zenoh holds the publisher back until the worker takes more), the worker's lag shows
    the hold-up, and once going the node takes all 400 (held in Zenoh's and the sockets' buffers
    meanwhile). Before (a callback into a bounded queue): 384 lost, counted as dropped."""
    from node.live.node import LiveNode
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    node = LiveNode(load_bundle(setup / "m"), str(tmp_path / "n.mcap"), listen=[endpoint], queue_size=16)
    held, handle = threading.Event(), node.handle_batch

    def slow(batch):
        held.wait(30)
        handle(batch)

    monkeypatch.setattr(node, "handle_batch", slow)
    node.start()
    client = _client(endpoint)
    keys = [sensor_key("b1", "nB")] * 400
    thread = threading.Thread(target=_put_all, args=(client, keys))
    try:
        _wait_matched(client, keys[0])
        thread.start()
        assert wait_for(lambda: node._worker_lag() > 0.3, 20)  # behind, and saying so
        held.set()
        thread.join(30)
        assert wait_for(lambda: node.stats.received == 400, 30), node.stats.received
    finally:
        held.set()
        client.close()
        node.stop()
    assert node.stats.received == 400 and node.stats.overflow == 0
    assert node.node_health(time.time())["dropped"] == 0 and node._worker_lag() < 0.3
    with pytest.raises(ValueError, match="queue_size"):
        LiveNode(load_bundle(setup / "m"), str(tmp_path / "m.mcap"), queue_size=0)


def test_hundreds_of_beds_health_is_spread_over_the_second(tmp_path):
    """40 beds tracked: a tick publishes at most HEALTH_PER_PASS beds' health, the worker's next
    passes the rest, each bed once a second (the last second's left-overs go out first at the next
    tick); a bed expired before its turn is skipped. Before: all 40 in the tick's one pass."""
    from node.live import node as live
    node = live.LiveNode(_bundle(), str(tmp_path / "n.mcap"))
    sent: list[list[str]] = []  # per call, the health topics' beds

    def send(outs):
        sent.append([k.split("/")[1] for k, _ in outs if k.endswith("/health") and k.startswith("testbed/")])
        return [(k, 0, 0, orjson.dumps(m)) for k, m in outs]
    node._send = send  # no Zenoh session: record what would be published
    beds = [f"h{i:02d}" for i in range(40)]
    node.handle_batch([(f"testbed/{b}/sensor/nB", GOOD, time.time_ns()) for b in beds])
    n = live.HEALTH_PER_PASS
    node._tick()
    assert sum(map(len, sent)) == n  # the tick's own pass: a slice
    node._publish_health(n)
    node.core.forget("h39")  # expires before its turn
    node._tick()  # the rest of the first second first, then the second's first slice
    first = [b for call in sent for b in call]
    assert first[:39] == beds[:39] and first[39:] == beds[:n]
    while node._rotation.due:
        node._publish_health(n)
    second = [b for call in sent for b in call][39:]
    assert second == beds[:39] and max(map(len, sent)) <= 40 - n  # never all at once
    node.writer.close()


def test_the_recording_bounds_its_channels_and_goes_on(tmp_path):
    w = RecordingWriter(str(tmp_path / "r.mcap"), max_channels=3)
    w.write_ns("a/1", 1, b"{}", 1)
    w.write_many([("a/2", 2, 2, b"{}"), ("a/3", 3, 3, b"{}"), ("a/4", 4, 4, b"{}"), ("a/1", 5, 5, b"{}")])
    w.write_columns(["a/5", "a/2", "a/6"], [6, 7, 8], [6, 7, 8], [b"{}", b"{}", b"{}"])
    w.write_ns("a/7", 9, b"{}", 9)
    assert (w.count, w.refused) == (5, 4)
    w.close()
    got = [(m.topic, m.log_time) for m in iter_messages(tmp_path / "r.mcap")]
    assert got == [("a/1", 1), ("a/2", 2), ("a/3", 3), ("a/1", 5), ("a/2", 7)]
    rot = RotatingRecorder(str(tmp_path / "rot.mcap"), max_minutes=1.0, max_channels=1)
    for i in range(3):  # a file a minute, each with its own channel table
        rot.write_ns("a/1", i, b"{}", i * 60_000_000_000)
        rot.write_ns("a/2", i, b"{}", i * 60_000_000_000)
    rot.close()
    assert rot.refused == 3 and len(rot.paths) == 3


def test_the_bounds_are_options_of_run(setup, tmp_path, capsys):
    for option in (["--max-beds", "0"], ["--max-channels", "-1"], ["--bed-expiry", "0"],
                   ["--bed-expiry", "nan"]):
        rec = tmp_path / "x.mcap"
        assert main(["run", "--model", str(setup / "m"), "--record", str(rec), *option]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and option[0] in err[0] and not rec.exists()


# -- live, over Zenoh on loopback

class Watcher:
    """A Zenoh session that keeps every node output it sees (a bed's monitor keys and node keys),
    wildcard keys included."""

    def __init__(self, endpoint: str) -> None:
        from node.edges.zenoh import open_session, zenoh_config
        self.session = open_session(zenoh_config(None, [endpoint]))
        self.got: list[tuple[str, dict]] = []
        self.subs = [self.session.declare_subscriber(k, self._on) for k in ("testbed/**", "ordervib/**")]

    def _on(self, sample) -> None:
        key = str(sample.key_expr)
        if "/monitor/" in key or key.startswith("ordervib/"):
            self.got.append((key, orjson.loads(sample.payload.to_bytes())))

    def node_health(self) -> dict:
        return next((m for k, m in reversed(self.got) if k.startswith("ordervib/node/")), {})

    def close(self) -> None:
        self.session.close()


def _client(endpoint: str):
    from node.edges.zenoh import open_session, zenoh_config
    return open_session(zenoh_config(None, [endpoint]))


def _put_all(session, keys, payload: bytes = GOOD) -> None:
    import zenoh
    block = zenoh.CongestionControl.BLOCK
    for key in keys:
        session.put(key, payload, congestion_control=block)


def _wait_matched(session, key: str) -> None:
    pub = session.declare_publisher(key)
    assert wait_for(lambda: pub.matching_status.matching, 30), "the node never matched"
    pub.undeclare()


def test_wildcard_keys_are_refused_and_make_no_bed_and_no_topic(setup, tmp_path):
    from node.live.node import LiveNode
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    node = LiveNode(load_bundle(setup / "m"), str(tmp_path / "n.mcap"), listen=[endpoint])
    node.start()
    watcher = Watcher(endpoint)
    client = _client(endpoint)
    try:
        _wait_matched(client, "testbed/b1/sensor/nB")
        _put_all(client, ["testbed/b1/sensor/nB"])
        # the watcher sees the node's outputs once the valid bed's health arrives
        assert wait_for(lambda: any(k == "testbed/b1/monitor/health" for k, _ in watcher.got), 30)
        _put_all(client, WILDCARD_KEYS * 3)
        assert wait_for(lambda: watcher.node_health().get("refused", {}).get("key") == 18, 30), \
            watcher.node_health()
    finally:
        client.close()
        watcher.close()
        node.stop()
    assert list(node.core.beds) == ["b1"] and node.stats.received == 19
    assert node.core.refused["key"] == 18
    assert node.health("b1", time.time())["refused"] == {"key": 6}  # b1/sensor/* and b1/sensor/nB/x
    assert not [k for k, _ in watcher.got if "*" in k or "$" in k or max(map(len, k.split("/"))) > 64]
    health = watcher.node_health()
    assert health["tracked"] == 1 and health["received"] == 19 and health["dropped"] == 0
    topics = {m.topic for m in iter_messages(tmp_path / "n.mcap")}
    assert not [t for t in topics if "*" in t or "$" in t]
    assert {t for t in topics if "/sensor/" in t} == {"testbed/b1/sensor/nB"}
    assert node_health_key(health["node"]) in topics


def flood_beside_a_real_bed(node, endpoint: str, stream, names: int,
                            until=None) -> tuple[dict, dict, list[str]]:
    """``names`` bed names x 3 messages into a started node on ``endpoint``, once a real bed
    ``real`` runs, while that bed publishes ``stream`` at 40 Hz; every message received, the real
    bed's monitor messages seen (and ``until()``, if given). Returns what ``Bench.publish`` sent,
    the monitor messages seen per bed and the flood's keys."""
    bench = Bench(endpoint, ["real"], ["nB", "yB", "tF"], "testbed/*/monitor/yB")
    flood = _client(endpoint)
    hostile = [sensor_key(f"h{i}", c) for i in range(names) for c in ("nB", "yB", "tF")]

    def attack() -> None:
        if wait_for(lambda: "real" in node.core.beds, 30):  # the real bed runs already
            _put_all(flood, hostile)

    thread = threading.Thread(target=attack)
    try:
        bench.wait_matched()
        thread.start()
        sent = bench.publish(stream)
        thread.join(60)
        assert wait_for(lambda: node.stats.received >= sent["count"] + len(hostile), 60)
        wait_for(lambda: len(bench.arrivals) >= len(stream.slots), 20)
        _, seen = latencies(bench, stream, sent["sent"], "/monitor/yB")
        assert until is None or wait_for(until, 10)
    finally:
        flood.close()
        bench.close()
    return sent, seen, hostile


def test_a_flood_of_bed_names_stays_bounded_beside_a_real_bed(setup, tmp_path):
    """5,000 bed names x 3 messages while a real bed runs at 40 Hz: 256 beds tracked (the default
    bound; the real one among them), the rest refused and counted, and every sample of the real
    bed gets its monitor message."""
    from node.live.node import LiveNode
    from node.runtime.core import MAX_BEDS
    from node.runtime.pipeline import MonitorPipeline
    bundle = load_bundle(setup / "m")
    stream = load_stream(str(setup / "test.mcap"), 3.0, 0.0, set(MonitorPipeline(bundle).channels))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    node = LiveNode(bundle, str(tmp_path / "n.mcap"), listen=[endpoint])
    node.start()
    names = 5000
    try:
        sent, seen, hostile = flood_beside_a_real_bed(
            node, endpoint, stream, names,
            until=lambda: node._node_health.get("refused", {}).get("bed_limit", 0) > 0)
        n = len(stream.slots)
    finally:
        node.stop()
    assert seen == {"real": n}, f"monitor messages {seen}, {n} samples"
    assert len(node.core.beds) == MAX_BEDS and "real" in node.core.beds
    assert node.core.refused["bed_limit"] == 3 * (names - (MAX_BEDS - 1))
    assert node.stats.received == sent["count"] + len(hostile) and node.stats.overflow == 0
    assert len(node.core._routes) <= 3 * MAX_BEDS  # the cache of keys: the tracked beds' only
    health = node.node_health(time.time())
    assert health["refused"]["bed_limit"] == node.core.refused["bed_limit"] and health["tracked"] == MAX_BEDS
    topics = {m.topic for m in iter_messages(tmp_path / "n.mcap")}
    beds = {t.split("/")[1] for t in topics if t.startswith("testbed/")}
    assert len(beds) == MAX_BEDS and "real" in beds  # no topic of a refused bed


def test_silent_beds_expire_and_say_so(setup, tmp_path):
    """A bed silent for --bed-expiry is freed: a last health message says expired, then none while
    it stays silent; a new message admits it afresh."""
    from node.live.node import LiveNode
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    node = LiveNode(load_bundle(setup / "m"), str(tmp_path / "n.mcap"), listen=[endpoint], bed_expiry_s=1.5)
    node.start()
    client = _client(endpoint)
    beds = ["s1", "s2", "s3"]
    try:
        _wait_matched(client, "testbed/s1/sensor/nB")
        _put_all(client, [sensor_key(b, c) for b in beds for c in ("nB", "yB", "tF", "extra")])
        assert wait_for(lambda: node.stats.expired == 3, 30)
        assert not node.core.beds and not node.core._routes and not node._last_recv
        assert not node._lag and not node._lag_max  # no per-bed state left (outputs declare none)
        _put_all(client, [sensor_key("s1", "nB")])
        assert wait_for(lambda: "s1" in node.core.beds, 30)
        assert node.core.beds["s1"].received == 1  # fresh counters
    finally:
        client.close()
        node.stop()
    health = [(m.topic.split("/")[1], orjson.loads(bytes(m.payload)))
              for m in iter_messages(tmp_path / "n.mcap") if m.topic.endswith("/monitor/health")]
    for b in ("s2", "s3"):
        mine = [h for bed, h in health if bed == b]
        assert mine and mine[-1].get("expired") is True and not any(h.get("expired") for h in mine[:-1])
    s1 = [h.get("expired", False) for bed, h in health if bed == "s1"]
    assert s1.count(True) == 1  # then its new state's health, if a tick came before the stop
    assert all(h["received"] == 4 for bed, h in health if bed != "s1" or h.get("expired"))


def _flood_one_bed(setup, rec, until=None, first=None, **options):
    """66,000 distinct channel keys on bed ``b`` into a LiveNode (``options``) recording to
    ``rec``, sent once ``first(node)`` holds (if given; the first key is sent before, so that the
    node has a sensor time), every one received (and ``until(node)``, if given) before the node
    stops."""
    from node.live.node import LiveNode
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    node = LiveNode(load_bundle(setup / "m"), str(rec), listen=[endpoint], **options)
    node.start()
    client = _client(endpoint)
    keys = [sensor_key("b", f"c{i}") for i in range(66_000)]
    try:
        _wait_matched(client, "testbed/b/sensor/nB")
        if first is not None:
            _put_all(client, keys[:1])
            assert wait_for(lambda: first(node), 10)
        _put_all(client, keys if first is None else keys[1:])
        assert wait_for(lambda: node.stats.received == len(keys), 60), node.stats
        assert until is None or wait_for(lambda: until(node), 10)
    finally:
        client.close()
        node.stop()
    return node, keys


def test_a_flood_of_channel_keys_on_one_bed_is_refused_and_recorded_bounded(setup, tmp_path):
    """66,000 distinct channel keys on one bed: the default bound (64 channels per bed) refuses
    all but the bed's first 64 channels, counted; the recording goes on and finishes."""
    from node.runtime.core import MAX_CHANNELS
    node, keys = _flood_one_bed(setup, tmp_path / "n.mcap")
    extra = MAX_CHANNELS - len(node.core.beds["b"].needed)
    assert node.core.refused["channel_limit"] == len(keys) - extra
    assert node.health("b", time.time())["refused"] == {"channel_limit": len(keys) - extra}
    assert node.recording and node.stats.unrecorded == 0
    sensors = [m.topic for m in iter_messages(tmp_path / "n.mcap") if "/sensor/" in m.topic]
    assert sorted(sensors) == sorted(keys[:extra])  # the bed's first channels, once each


def test_the_recording_survives_more_keys_than_mcap_channels(setup, tmp_path):
    """With the channel bound per bed lifted, 66,000 keys reach the recorder: it keeps 65,535
    channels (MCAP's u16 ids), refuses the rest, counted in health, and the recording finishes
    (it failed with "ushort format requires 0 <= number <= 65535", exit 2, before).

    The flood starts once the node's first own health message (its first tick after the flood's
    first key, which gives it a sensor time to record it at) is recorded, so an output holds a
    channel before the inputs fill the table: with the flood racing that tick, a machine that took
    the 65,535 first keys within the second recorded inputs only, and the outputs' share of the
    table went untested."""
    from mcap.reader import make_reader

    def counted(node) -> bool:  # the node's own health said so
        return node._node_health.get("refused", {}).get("recording_channels", 0) > 0

    def health_recorded(node) -> bool:  # the node's health of the first key is in the recording
        return node.sensor_t is not None and node._node_health.get("received") == 1

    node, keys = _flood_one_bed(setup, tmp_path / "n.mcap", until=counted, first=health_recorded,
                                max_channels=70_000)
    assert node.recording and node.stats.recording_error is None
    refused = node.writer.refused
    assert refused >= len(keys) - 65_535 and node.unrecorded == refused
    assert node.node_health(time.time())["refused"]["recording_channels"] == refused
    with open(tmp_path / "n.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and len(summary.channels) == 65_535
    recorded = sum(1 for m in iter_messages(tmp_path / "n.mcap") if "/sensor/" in m.topic)
    assert recorded < 65_535 and len(keys) - recorded <= refused  # refused: the inputs beyond, outputs too


def test_a_bed_behind_a_siblings_backlog_is_handled_first(setup, tmp_path, monkeypatch):
    """A sibling bed's 3,000-message backlog arrives while the worker is held, then one slot of a
    real bed: once going, the worker handles the real bed's messages in its first batches, not
    after the backlog (before the fair intake: after all 3,000); every message once, each bed's in
    the order sent."""
    from node.live.node import BATCH_MAX, DRAIN_MAX, LiveNode
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    node = LiveNode(load_bundle(setup / "m"), str(tmp_path / "n.mcap"), listen=[endpoint])
    held, handle, seen = threading.Event(), node.handle_batch, []

    def slow(batch):
        held.wait(30)
        seen.extend((k.split("/")[1], orjson.loads(p)["t"]) for k, p, _ in batch)
        handle(batch)

    monkeypatch.setattr(node, "handle_batch", slow)
    node.start()
    client = _client(endpoint)
    t0 = 1_700_000_000.0
    try:
        _wait_matched(client, sensor_key("sib", "nB"))
        for i in range(3000):
            client.put(sensor_key("sib", "nB"), orjson.dumps({"t": t0 + i / 40, "v": 1.0}))
        assert wait_for(lambda: node._worker_lag() > 0.2, 20)  # the worker held, the backlog waits
        for i in range(3):
            client.put(sensor_key("real", "nB"), orjson.dumps({"t": t0 + i / 40, "v": 2.0}))
        time.sleep(0.3)
        held.set()
        assert wait_for(lambda: node.stats.received == 3003, 30), node.stats.received
    finally:
        held.set()
        client.close()
        node.stop()
    real = [i for i, (bed, _) in enumerate(seen) if bed == "real"]
    # found once the worker has taken the backlog from the FIFO (DRAIN_MAX a pass), then first
    assert len(real) == 3 and real[-1] < (1 + -(-3000 // DRAIN_MAX) + 1) * BATCH_MAX, real
    for bed in ("sib", "real"):
        stamps = [t for b, t in seen if b == bed]
        assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)
