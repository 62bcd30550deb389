"""The beds' health stays bounded: at most 100 messages a second whatever the beds, the silent out of
the rotation and counted, a real bed's output beside a flood of bed names equal to its replay."""

from __future__ import annotations

import time
from pathlib import Path

import orjson
import pytest
from conftest import small_campaign
from test_hostile import _bundle, flood_beside_a_real_bed

from harness.live import bed_inputs, free_port, load_stream
from node.cli import main
from node.contract import sensor_key
from node.live.health_rate import HEALTH_MAX_PER_S, most_in_a_second
from node.mcap import iter_messages
from node.models.bundle import load_bundle


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    return small_campaign(tmp_path_factory.mktemp("health_rate"), 3)


class FakeTime:
    """Stands in for the ``time`` module in ``node.live.node``: a clock the test moves."""

    def __init__(self, start: float = 1_800_000_000.0) -> None:
        self.now = start

    def time(self) -> float:
        return self.now

    def time_ns(self) -> int:
        return round(self.now * 1e9)

    def monotonic(self) -> float:
        return self.now

    perf_counter = monotonic

    @staticmethod
    def thread_time() -> float:
        return time.thread_time()


class Puts:
    """Stands in for a Zenoh session: keeps each bed health put with the clock's time."""

    def __init__(self, clock: FakeTime) -> None:
        self.clock, self.health = clock, []

    @staticmethod
    def zid() -> str:
        return "n1"

    def put(self, key: str, data: bytes, **_: object) -> None:
        if key.startswith("testbed/") and key.endswith("/monitor/health"):
            self.health.append((key.split("/")[1], self.clock.time_ns()))


def test_health_rotates_at_most_100_a_second_and_the_silent_leave_it(tmp_path, monkeypatch):
    """300 names, 256 beds tracked: 200 send every second, 56 once. The worker's passes (every 50 ms
    of a fake clock, a tick a second) publish at most 100 health messages within any second; each
    sending bed's health every 2 s once the 56 have left the rotation (silent 4 s) and every 3 s
    before; the node's health counts them silent and says the period. Before: 256 a second."""
    from node.live import node as live
    clock = FakeTime()
    monkeypatch.setattr(live, "time", clock)
    node = live.LiveNode(_bundle(), str(tmp_path / "n.mcap"), health_silence_s=4.0)
    puts = Puts(clock)
    node.attach(puts)
    names = [f"b{i:03d}" for i in range(300)]
    t0 = 1_700_000_000.0
    node_health = []
    for step in range(12 * 20):  # 12 s of passes, 50 ms apart
        clock.now += 0.05
        if step % 20 == 0:  # each second: the 200 first beds send (all 300 at first; 256 taken)
            beds = names if step == 0 else names[:200]
            payload = orjson.dumps({"t": t0 + step / 20, "v": 1.0})
            node.handle_batch([(sensor_key(b, "nB"), payload, clock.time_ns()) for b in beds])
        if node._rotation.due:
            node._publish_health(live.HEALTH_PER_PASS)
        if step % 20 == 19:
            node._tick()
            node_health.append(node.node_health(clock.now))
    node.writer.close()
    assert len(node.core.beds) == 256 and node.core.refused["bed_limit"] == 44
    assert most_in_a_second([ns for _, ns in puts.health]) == HEALTH_MAX_PER_S
    assert node_health[1]["silent"] == 0 and node_health[1]["health_every_s"] == 3
    assert node_health[-1]["silent"] == 56 and node_health[-1]["health_every_s"] == 2
    late = [(b, ns) for b, ns in puts.health if ns > clock.time_ns() - 4e9]  # the last 4 s
    assert {b for b, _ in late} == set(names[:200])  # the silent ones out of the rotation
    for bed in names[:200]:
        times = [ns for b, ns in late if b == bed]
        assert len(times) == 2 and times[1] - times[0] == pytest.approx(2e9, abs=0.2e9)


def test_health_silence_is_an_option_of_run(setup, tmp_path, capsys):
    for value in ("0", "nan", "3601", "-1"):
        rec = tmp_path / "x.mcap"
        args = ["run", "--model", str(setup / "m"), "--record", str(rec), "--health-silence", value]
        assert main(args) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--health-silence" in err[0] and not rec.exists()
    with pytest.raises(ValueError, match="health_silence_s"):
        from node.live.node import LiveNode
        LiveNode(_bundle(), str(tmp_path / "y.mcap"), health_silence_s=0.0)


def _monitor_bytes(path: Path, bed: str) -> dict[str, list[bytes]]:
    """Each of ``bed``'s monitor topics but health: its messages' bytes, in order."""
    out: dict[str, list[bytes]] = {}
    prefix = f"testbed/{bed}/monitor/"
    for m in iter_messages(path):
        if m.topic.startswith(prefix) and not m.topic.endswith("/health"):
            out.setdefault(m.topic, []).append(bytes(m.payload))
    return out


def test_a_flood_of_bed_names_keeps_health_at_100_a_second_and_a_real_bed_equal_to_replay(setup, tmp_path):
    """5,000 bed names x 3 messages beside a real bed at 40 Hz (6 s): 256 beds tracked, their health
    at most 100 messages within any second of the node's recording (publish times) over the run,
    the flood's beds in turn; the real bed's every monitor output, live, equal to the bit to an
    offline replay of its recorded inputs."""
    from node.live.node import LiveNode
    from node.runtime.pipeline import MonitorPipeline
    from replay.offline import replay
    bundle = load_bundle(setup / "m")
    stream = load_stream(str(setup / "test.mcap"), 6.0, 0.0, set(MonitorPipeline(bundle).channels))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    rec = tmp_path / "n.mcap"
    node = LiveNode(bundle, str(rec), listen=[endpoint])
    node.start()
    try:
        sent, seen, _ = flood_beside_a_real_bed(node, endpoint, stream, 5000)
        time.sleep(1.5)  # a last health rotation or two
    finally:
        node.stop()
    assert seen == {"real": len(stream.slots)}
    assert len(node.core.beds) == 256 and node._node_health["health_every_s"] == 3
    health = [(m.topic.split("/")[1], m.publish_time) for m in iter_messages(rec)
              if m.topic.endswith("/monitor/health")]
    span_s = (max(ns for _, ns in health) - min(ns for _, ns in health)) / 1e9
    assert span_s > 5 and len({b for b, _ in health}) == 256  # every tracked bed's turn came
    assert most_in_a_second([ns for _, ns in health]) <= HEALTH_MAX_PER_S
    assert bed_inputs(rec, "real", tmp_path / "real.mcap") == sent["count"]
    replay(str(tmp_path / "real.mcap"), bundle, str(tmp_path / "offline.mcap"), workers=0)
    live, offline = _monitor_bytes(rec, "real"), _monitor_bytes(tmp_path / "offline.mcap", "real")
    assert len(live.get("testbed/real/monitor/yB", [])) == len(stream.slots)
    assert live == offline  # to the bit
