"""The node's own figures (issue 35, items 2 and 3): no collector stall, and its margin in health.

The node runs in this process on a free loopback port; the tests wait on conditions, bounded in
time, and assert no wall-clock duration.
"""

from __future__ import annotations

import gc
import math

import orjson
from conftest import small_campaign

from harness.live import free_port, wait_for
from node.contract import node_health_key, sensor_key
from node.mcap import iter_messages
from node.models.bundle import load_bundle


def _bundle(tmp_path_factory):
    return load_bundle(small_campaign(tmp_path_factory.mktemp("figures"), 3) / "m")


def test_start_freezes_the_long_lived_and_raises_the_young_threshold(tmp_path, tmp_path_factory):
    from node.live.node import GC_THRESHOLD, LiveNode
    bundle = _bundle(tmp_path_factory)
    before = gc.get_threshold()
    try:
        for i in range(2):  # a second node in the same process: the same settings, no harm
            node = LiveNode(bundle, str(tmp_path / f"n{i}.mcap"), listen=[f"tcp/127.0.0.1:{free_port()}"])
            node.start()
            try:
                assert gc.get_freeze_count() > 0
                assert gc.get_threshold() == GC_THRESHOLD
            finally:
                node.stop()
    finally:
        gc.set_threshold(*before)  # this test's own process, as it found it


def test_node_health_carries_cpu_per_message_and_worker_lag(tmp_path, tmp_path_factory):
    import zenoh

    from node.edges.zenoh import open_session, zenoh_config
    from node.live.node import LiveNode
    bundle = _bundle(tmp_path_factory)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    before = gc.get_threshold()
    node = LiveNode(bundle, str(tmp_path / "n.mcap"), listen=[endpoint])
    node.start()
    client = open_session(zenoh_config(None, [endpoint]))
    try:
        pub = client.declare_publisher(sensor_key("b1", "nB"))
        assert wait_for(lambda: pub.matching_status.matching, 30), "the node never matched"
        pub.undeclare()
        block = zenoh.CongestionControl.BLOCK
        for i in range(200):
            for c in ("nB", "yB", "tF"):
                client.put(sensor_key("b1", c), orjson.dumps({"t": 1.7e9 + i / 40, "v": 1.0}),
                           congestion_control=block)
        assert wait_for(lambda: node.stats.received == 600, 30)
        assert wait_for(lambda: node._node_health.get("cpu_us_per_message") is not None, 30)
    finally:
        client.close()
        node.stop()
        gc.set_threshold(*before)
    health = [orjson.loads(bytes(m.payload)) for m in iter_messages(tmp_path / "n.mcap")
              if m.topic == node_health_key(node.node_id)]
    measured = [h for h in health if h["cpu_us_per_message"] is not None]
    assert measured, health
    for h in measured:
        assert math.isfinite(h["cpu_us_per_message"]) and h["cpu_us_per_message"] > 0
        assert math.isfinite(h["worker_lag_s"]) and h["worker_lag_s"] >= 0
