"""One timeline per recording: a node's recording of a replayed run spans that run, its own health
logged on the sensor clock (the beds' latest sensor time), the wall clock kept as a field."""

from __future__ import annotations

import time

import orjson
import pytest
from conftest import small_campaign
from mcap.reader import make_reader

from harness.live import free_port, wait_for
from node.cli import main
from node.contract import node_health_key
from node.mcap import iter_messages

pytest.importorskip("zenoh")


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    return small_campaign(tmp_path_factory.mktemp("timeline"), 3)


def _span(path) -> tuple[int, int]:
    """The summary's message start and end times, ns (what an indexed reader shows)."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    return summary.statistics.message_start_time, summary.statistics.message_end_time


def test_a_replayed_run_through_zenoh_spans_its_own_time(setup, tmp_path, capsys):
    """A recording made months ago, published through Zenoh into a live node: the node's
    recording (summary start and end) spans the run, its own health among it, ``wall`` the node's
    clock; ``ordervib recover`` prints that span. Before: 327 days (the node's health on its clock)."""
    from node.live.node import LiveNode
    from node.models.bundle import load_bundle
    from replay.publish import publish_recording
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    rec = tmp_path / "node.mcap"
    node = LiveNode(load_bundle(setup / "m"), str(rec), listen=[endpoint])
    node.start()
    try:
        assert wait_for(lambda: "connected" in node._node_health, 10)  # its first health: no sensor time
        sent = publish_recording(str(setup / "test.mcap"), endpoint, speed=0.0, quiet=True)
        assert wait_for(lambda: node._node_health.get("received") == sent, 30)  # a health after them all
    finally:
        node.stop()
    source, got = _span(setup / "test.mcap"), _span(rec)
    slot = 25_000_000  # a 40 Hz slot, ns: an output is stamped with its slot's time, up to a slot before
    assert source[0] - slot <= got[0] and got[1] <= source[1] + slot  # within the run
    assert (got[1] - got[0]) / 1e9 > 0.99 * (source[1] - source[0]) / 1e9
    health = [(m.log_time, orjson.loads(bytes(m.payload))) for m in iter_messages(rec)
              if m.topic == node_health_key(node.node_id)]
    assert health and all(source[0] <= ns <= source[1] for ns, _ in health)
    assert all(ns == round(h["t"] * 1e9) and abs(h["wall"] - time.time()) < 120 for ns, h in health)
    assert main(["recover", str(rec), "--out", str(tmp_path / "r.mcap")]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert f"span {(got[1] - got[0]) / 1e9:.3f} s" in first and "outside" not in first
