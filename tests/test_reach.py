"""A node that reaches no one says so: a warning within seconds while no --connect endpoint
answers, repeated with backoff, and ``connected: false`` in its own health; one line once it
answers. On loopback, a free port nobody listens on."""

from __future__ import annotations

import logging
import time

import orjson
from test_hostile import _bundle

from harness.live import free_port, wait_for
from node.contract import node_health_key
from node.edges.reach import Reach, connect_endpoints
from node.edges.zenoh import open_session, zenoh_config


def test_connect_endpoints_of_a_config():
    assert connect_endpoints(zenoh_config(["tcp/127.0.0.1:1"], ["tcp/127.0.0.1:2", "tcp/127.0.0.1:3"])) == \
        ["tcp/127.0.0.1:2", "tcp/127.0.0.1:3"]
    assert connect_endpoints(zenoh_config(["tcp/127.0.0.1:1"])) == []


def test_an_unreachable_connect_endpoint_is_a_warning_within_5_s_then_answers(tmp_path, caplog):
    from node.live.node import LiveNode
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    node = LiveNode(_bundle(), str(tmp_path / "n.mcap"), connect=[endpoint])
    caplog.set_level(logging.INFO, logger="node.edges.reach")
    seen: list[dict] = []
    start = time.monotonic()
    node.start()
    router = None
    try:
        def warned() -> bool:
            return any(r.levelno == logging.WARNING and endpoint in r.getMessage() for r in caplog.records)
        assert wait_for(warned, 5), caplog.text
        took = time.monotonic() - start
        assert node.node_health(time.time())["connected"] is False
        assert node._node_health["connected"] is False and node._node_health["routers"] == 0
        # someone listens there now: Zenoh's retries reach it, the node says so
        router = open_session(zenoh_config([endpoint]))
        router.declare_subscriber("ordervib/node/*/health",
                                  lambda s: seen.append(orjson.loads(s.payload.to_bytes())))
        assert wait_for(lambda: node._node_health.get("connected") is True, 20), node._node_health
        assert wait_for(lambda: any(h.get("connected") for h in seen), 5)
    finally:
        node.stop()
        if router is not None:
            router.close()
    assert took < 5
    assert node._node_health["peers"] == 1
    assert any(r.levelno == logging.INFO and "answers now" in r.getMessage() for r in caplog.records)
    # before any sensor sample the node's health is published (t null), never recorded
    assert all(h["t"] is None for h in seen)
    from node.mcap import iter_messages
    assert not [m for m in iter_messages(tmp_path / "n.mcap") if m.topic == node_health_key(node.node_id)]


def test_warnings_back_off_while_no_endpoint_answers(caplog):
    """At 2 s, then 4, 8, 16, 32 s later, then every 60 s; none without a connect endpoint."""
    caplog.set_level(logging.WARNING, logger="node.edges.reach")

    class Info:
        @staticmethod
        def links() -> list:
            return []
        routers_zid = peers_zid = links

    r = Reach(["tcp/127.0.0.1:1"], 0.0)
    warned = [t / 2 for t in range(0, 2 * 300) if r.check(Info, t / 2)]
    assert warned == [2.0, 6.0, 14.0, 30.0, 62.0, 122.0, 182.0, 242.0]
    quiet = Reach([], 0.0)
    assert not any(quiet.check(Info, t) for t in range(100)) and quiet.connected is None
