"""The live node under faults (issue 12, failures 1, 4, 7, 8): malformed payloads of every kind,
a recording that fails (disk full), a worker thread that dies, health per bed, a short soak."""

from __future__ import annotations

import errno
import io
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import orjson
import pytest
from conftest import small_campaign

from harness.live import wait_for
from node.cli import main
from node.contract import MONITOR_SUBSCRIPTION, health_key, monitor_key, parse_sensor_key, sensor_key
from node.mcap import RecordingWriter, iter_messages

zenoh = pytest.importorskip("zenoh")

ROOT = Path(__file__).resolve().parents[1]

# every kind of payload the contract's rule refuses (node.contract.payload)
MALFORMED = [
    b'{"t": -1.0, "v": 1.0}', b'{"t": -1e308, "v": 1.0}', b'{"t": 1e308, "v": 1.0}',
    b'{"t": 9.3e9, "v": 1.0}',  # beyond what a recording's nanoseconds can hold
    b'{"t": 123456789012345678901234567890123456789, "v": 1}', b'{"t": -12345678901234567890, "v": 1}',
    b'{"t": "NaN", "v": 1}', b'{"t": "Infinity", "v": 1}', b'{"t": NaN, "v": 1}', b'{"t": Infinity, "v": 1}',
    b'{"t": 1.7e9, "v": "NaN"}', b'{"t": 1.7e9, "v": 1e999}', b'\xff\xfe\x00garbage', b'', b'{"t": 1.7e9',
    b'[1.7e9, 1.0]', b'42', b'"text"', b'null', b'{}', b'{"v": 1.0}', b'{"t": 1.7e9}', b'{"t": null, "v": 1}',
    b'{"t": true, "v": 1.0}', b'{"t": 1.7e9, "v": false}', b'{"t": {"x": 1}, "v": 1}', b'{"t": [1], "v": 1}',
]


def free_port() -> int:
    from harness.live import free_port as fp
    return fp()


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    return small_campaign(tmp_path_factory.mktemp("faults"), 5)


class Client:
    """An independent Zenoh session beside the node: publishes, collects the node's outputs."""

    def __init__(self, endpoint: str) -> None:
        from node.edges.zenoh import open_session, zenoh_config
        self.session = open_session(zenoh_config(None, [endpoint]))
        self.out: list[tuple[str, bytes]] = []
        self.sub = self.session.declare_subscriber(
            MONITOR_SUBSCRIPTION, lambda s: self.out.append((str(s.key_expr), s.payload.to_bytes())))
        self.pubs: dict[str, object] = {}

    def put(self, key: str, payload: bytes) -> None:
        pub = self.pubs.get(key)
        if pub is None:
            pub = self.pubs[key] = self.session.declare_publisher(
                key, congestion_control=zenoh.CongestionControl.BLOCK)
            assert wait_for(lambda: pub.matching_status.matching, 20)
        pub.put(payload)

    def health(self, bed: str) -> list[dict]:
        return [orjson.loads(p) for k, p in list(self.out) if k == health_key(bed)]

    def count(self, key: str) -> int:
        return sum(k == key for k, _ in list(self.out))

    def tokens(self) -> list[str]:
        from node.contract import liveliness_key
        return [str(r.ok.key_expr) for r in self.session.liveliness().get(liveliness_key("**"), timeout=2.0)
                if r.ok]

    def close(self) -> None:
        self.session.close()


def monitor(path) -> list[tuple]:
    return [(m.payload["t"], m.payload["predicted"], m.payload["residual"], m.payload["flag"])
            for m in iter_messages(path, decode=True) if m.topic.endswith("/monitor/yB")]


def test_malformed_payloads_of_every_kind_never_stop_the_node(setup, tmp_path):
    """Failure 1: out-of-range t and every other malformed payload, between good messages."""
    from mcap.reader import make_reader

    from node.live.node import LiveNode
    from node.models.bundle import load_bundle
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    good = [(m.topic, bytes(m.payload)) for m in iter_messages(setup / "test.mcap")
            if parse_sensor_key(m.topic)]
    sent: list[tuple[str, bytes]] = []
    for i, (key, payload) in enumerate(good):
        sent.append((key, payload))
        if i % 50 == 7:  # a malformed payload on a sensor key of the same bed, every 50 messages
            sent.append((key, MALFORMED[(i // 50) % len(MALFORMED)]))
    bad = len(sent) - len(good)
    assert bad > 3 * len(MALFORMED)  # every kind, several times
    node = LiveNode(load_bundle(setup / "m"), str(tmp_path / "node.mcap"), listen=[endpoint])
    node.start()
    client = Client(endpoint)
    try:
        for key, payload in sent:
            client.put(key, payload)
        assert wait_for(lambda: node.stats.received >= len(sent), 60), node.stats
        alive = node.thread.is_alive()
        assert wait_for(lambda: any(h["received"] == len(sent) for h in client.health("bed1")), 5)
    finally:
        node.stop()
        client.close()
    assert alive and node.stats.worker_error is None and node.stats.recording_error is None
    assert node.stats.received == len(sent) and node.core.malformed == bad
    h = client.health("bed1")[-1]
    assert h["malformed"] == bad and h["received"] == len(sent) and h["recording"] is True
    with open(tmp_path / "node.mcap", "rb") as f:
        assert make_reader(f).get_summary() is not None  # finished and readable
    recorded = sorted((m.topic, bytes(m.payload)) for m in iter_messages(tmp_path / "node.mcap")
                      if "/sensor/" in m.topic)
    assert recorded == sorted(sent)  # every input kept, the malformed ones too
    assert main(["replay", str(setup / "test.mcap"), "--model", str(setup / "m"),
                 "--out", str(tmp_path / "offline.mcap"), "--quiet"]) == 0
    live, offline = monitor(tmp_path / "node.mcap"), monitor(tmp_path / "offline.mcap")
    assert len(live) > 1000 and live == offline  # every good sample got its monitor message, same numbers


class FullDisk(io.RawIOBase):
    """A file that takes ``room`` bytes, then fails every write with ENOSPC (nothing written)."""

    def __init__(self, room: int = 0) -> None:
        self.data = bytearray()
        self.room = room

    def writable(self) -> bool:
        return True

    def write(self, b) -> int:
        if len(self.data) + len(b) > self.room:
            raise OSError(errno.ENOSPC, "No space left on device")
        self.data += b
        return len(b)


@pytest.mark.parametrize("room", [0, None])
def test_a_full_disk_raises_the_health_alarm_and_monitoring_goes_on(setup, room):
    """Failure 4: the recorder fails (ENOSPC) at once or after a first flush; the node keeps
    monitoring and publishing, counts every unrecorded message and says so in its health."""
    from node.live.node import LiveNode
    from node.mcap.reader import iter_messages as read
    from node.models.bundle import load_bundle
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    disk = FullDisk(1 << 40 if room is None else room)
    node = LiveNode(load_bundle(setup / "m"), RecordingWriter(disk), listen=[endpoint])
    node.start()
    client = Client(endpoint)
    good = [(m.topic, bytes(m.payload)) for m in iter_messages(setup / "test.mcap")
            if parse_sensor_key(m.topic)]
    half = len(good) // 2
    first = 0 if room == 0 else 500
    try:
        if first:  # some recorded first, then the disk is full
            for key, payload in good[:first]:
                client.put(key, payload)
            assert wait_for(lambda: any(h["received"] == first for h in client.health("bed1")), 20)
            time.sleep(1.2)  # a flush
            disk.room = len(disk.data)
        for key, payload in good[first:half]:
            client.put(key, payload)
        assert wait_for(lambda: any(h["recording"] is False for h in client.health("bed1")), 30)
        for key, payload in good[half:]:
            client.put(key, payload)
        assert wait_for(lambda: node.stats.received >= len(good), 60)
        assert wait_for(lambda: any(h["received"] == len(good) for h in client.health("bed1")), 5)
        assert node.thread.is_alive() and client.tokens()  # alive, and says so honestly
    finally:
        node.stop()
        client.close()
    s = node.stats
    assert s.worker_error is None and "No space left" in (s.recording_error or "")
    h = client.health("bed1")[-1]
    assert h["recording"] is False and h["unrecorded"] > 0
    monitored = client.count(monitor_key("bed1", "yB"))
    assert monitored > 1000
    kept = list(read(io.BytesIO(bytes(disk.data)))) if first else []
    # every message the node received or published is either in the recording or counted
    assert len(kept) + s.unrecorded == s.received + s.published
    if first:
        assert sum("/sensor/" in m.topic for m in kept) == first


def start_run(model: Path, rec: str, port: int, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "node.cli", "run", "--model", str(model), "--record", rec,
                             "--listen", f"tcp/127.0.0.1:{port}", *extra], cwd=ROOT,
                            stderr=subprocess.PIPE, text=True)


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full")
def test_run_record_dev_full_keeps_monitoring_then_exits_non_zero(setup):
    """Failure 4 as found: ``ordervib run --record /dev/full``."""
    port = free_port()
    proc = start_run(setup / "m", "/dev/full", port, "--quiet", "--force")  # /dev/full exists
    client = Client(f"tcp/127.0.0.1:{port}")
    try:
        good = [(m.topic, bytes(m.payload)) for m in iter_messages(setup / "test.mcap")
                if parse_sensor_key(m.topic)][:4000]
        for key, payload in good:
            client.put(key, payload)
        assert wait_for(lambda: any(h["received"] == len(good) and h["recording"] is False
                                    for h in client.health("bed1")), 30), client.health("bed1")[-1:]
        assert client.count(monitor_key("bed1", "yB")) > 100  # monitor messages went out
        assert client.tokens()  # monitoring goes on: still alive
        h = client.health("bed1")[-1]
        assert h["unrecorded"] >= len(good)
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
        client.close()
    assert proc.returncode == 2
    lines = err.strip().splitlines()
    assert len(lines) == 2 and "No space left on device" in lines[0]  # logged at once, then the exit line
    assert lines[-1].startswith("ordervib run: the recording /dev/full failed") and "unrecorded" in lines[-1]


def test_a_dead_worker_withdraws_the_token_and_the_watchdog_exits(setup, tmp_path, monkeypatch, capsys):
    """Failure 4's other half: never a live token over a dead worker thread."""
    from node.live.node import WATCHDOG_S, LiveNode
    from node.models.bundle import load_bundle
    from node.runtime.core import NodeCore
    real = NodeCore.handle_batch

    def handle_batch(self, keys, payloads, recv=None):
        if b"boom" in payloads:
            raise RuntimeError("injected fault")
        return real(self, keys, payloads, recv)

    monkeypatch.setattr(NodeCore, "handle_batch", handle_batch)
    key = sensor_key("bed1", "nB")
    # the node object: the token goes as soon as the worker dies, the session still open
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    node = LiveNode(load_bundle(setup / "m"), str(tmp_path / "a.mcap"), listen=[endpoint])
    node.start()
    client = Client(endpoint)
    try:
        assert len(client.tokens()) == 1
        client.put(key, b"boom")
        assert wait_for(lambda: not node.thread.is_alive(), 10)
        assert client.tokens() == []
        assert "injected fault" in (node.stats.worker_error or "")
    finally:
        node.stop()
        client.close()
    # the command: the watchdog stops it, one line, non-zero exit
    port = free_port()
    done = threading.Event()

    def feed() -> None:
        c = Client(f"tcp/127.0.0.1:{port}")
        try:
            time.sleep(1.0)
            c.put(key, b'{"t": 1700000000.0, "v": 1.0}')
            c.put(key, b"boom")
            done.set()
        finally:
            c.close()

    threading.Thread(target=feed, daemon=True).start()
    start = time.monotonic()
    rc = main(["run", "--model", str(setup / "m"), "--record", str(tmp_path / "b.mcap"),
               "--listen", f"tcp/127.0.0.1:{port}", "--duration", "60", "--quiet"])
    took = time.monotonic() - start
    err = capsys.readouterr().err.strip().splitlines()
    assert done.is_set() and rc == 2 and took < 1.0 + 10 * WATCHDOG_S + 5
    assert len(err) == 1 and "worker thread died" in err[0] and "injected fault" in err[0]


def test_health_is_per_bed_on_the_sensor_clock(setup, tmp_path):
    """Failure 7: each bed's own counters, t on its sensor clock, wall, staleness, dropped, lag."""
    from node.live.node import LiveNode
    from node.models.bundle import load_bundle
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    good = [(m.topic, bytes(m.payload)) for m in iter_messages(setup / "test.mcap")
            if parse_sensor_key(m.topic)][:3000]
    node = LiveNode(load_bundle(setup / "m"), str(tmp_path / "h.mcap"), listen=[endpoint])
    node.start()
    client = Client(endpoint)
    t2 = 1800000000.0
    try:
        for key, payload in good:
            client.put(key, payload)
        for i in range(3):
            client.put(sensor_key("b2", "nB"), orjson.dumps({"t": t2 + i / 40, "v": 1.0}))
        assert wait_for(lambda: client.health("b2") and client.health("bed1")[-1]["received"] == len(good),
                        20)
        time.sleep(2.2)  # staleness grows while b2 is silent
    finally:
        node.stop()
        client.close()
    h1, h2 = client.health("bed1"), client.health("b2")
    last2 = h2[-1]
    assert last2["received"] == 3 and h1[-1]["received"] == len(good)  # each bed its own counters
    assert last2["t"] == t2 + 2 / 40  # the bed's sensor clock
    first_t = orjson.loads(good[0][1])["t"]
    last_t = max(orjson.loads(p)["t"] for _, p in good)
    assert all(first_t <= h["t"] <= last_t for h in h1)
    assert abs(last2["wall"] - time.time()) < 30
    assert h2[-1]["staleness"] > h2[0]["staleness"] >= 0 and h2[-1]["staleness"] > 1.5
    assert last2["dropped"] == 0 and last2["recording"] is True and last2["unrecorded"] == 0
    assert h1[-1]["lag_ms_p99"] is not None and h1[-1]["lag_ms_p50"] <= h1[-1]["lag_ms_p99"]
    assert any(h["lag_ms_max"] is not None for h in h1)
    # the recording stays on the sensor clock: health messages are logged at their sensor time
    times = {m.topic: m.log_time for m in iter_messages(tmp_path / "h.mcap") if m.topic.endswith("/health")}
    assert times[health_key("b2")] == round(last2["t"] * 1e9)
    assert first_t * 1e9 <= times[health_key("bed1")] <= last_t * 1e9 + 1


def test_soak_short(setup, tmp_path):
    """Failure 8's soak, short (``python -m bench soak`` is the long one): the test run pushed
    several times through ``ordervib run`` at 20 x real time; nothing lost, every sample
    monitored, latency bounded."""
    from harness.live import soak
    r = soak(str(setup / "m"), str(setup / "test.mcap"), 0.15, 20.0, tmp_path)
    assert r.exit_code == 0 and r.lost == 0 and r.sent > 3 * 27000
    assert r.recorded_monitor == r.samples and len(r.lat_ms) > 0.9 * r.samples
    assert r.health["received"] == r.sent and r.health["dropped"] == 0 and r.health["recording"] is True
    assert float(r.lat_ms.max()) < 2000.0


def test_a_hung_subscriber_never_stalls_the_node(setup, tmp_path):
    """Failure 8's stall: a subscriber whose callback never returns (small socket buffers fill in
    seconds). Published with BLOCK, the node's worker sat 5 s in ``put`` (Zenoh's wait_before_close)
    and every other subscriber waited too; now the hung one loses messages, nobody else."""
    import json

    from node.edges.zenoh import open_session, zenoh_config
    from node.live.node import LiveNode
    from node.models.bundle import load_bundle
    conf = tmp_path / "small.json5"
    conf.write_text(json.dumps({"transport": {"link": {"tcp": {"so_sndbuf": 4096, "so_rcvbuf": 4096}}}}))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    node = LiveNode(load_bundle(setup / "m"), str(tmp_path / "n.mcap"), listen=[endpoint],
                    config_file=str(conf))
    node.start()
    gate = threading.Event()
    hung = open_session(zenoh_config(None, [endpoint], str(conf)))
    hung.declare_subscriber(MONITOR_SUBSCRIPTION, lambda s: gate.wait(60))
    client = Client(endpoint)
    good = [(m.topic, bytes(m.payload)) for m in iter_messages(setup / "test.mcap")
            if parse_sensor_key(m.topic)][:12000]
    arrivals: list[float] = []
    client.session.declare_subscriber(monitor_key("bed1", "yB"), lambda s: arrivals.append(time.monotonic()))
    try:
        for i, (key, payload) in enumerate(good):  # 1200 messages/s
            client.put(key, payload)
            if i % 30 == 29:
                time.sleep(0.025)
        assert wait_for(lambda: node.stats.received >= len(good), 30)
        time.sleep(1.0)
    finally:
        gate.set()
        node.stop()
        client.close()
        hung.close()
    lag_max = max(max(d) for d in node._lag.values())
    gaps = max(b - a for a, b in zip(arrivals, arrivals[1:], strict=False))
    assert node.stats.received == len(good) and node.stats.overflow == 0
    assert lag_max < 1000.0 and gaps < 1.0, (lag_max, gaps)
    assert len(arrivals) == len(good) // 3  # the healthy subscriber got every monitor message
