"""The live node over Zenoh on loopback: identical to offline replay, complete recording, clean stop."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import orjson
import pytest
from conftest import small_campaign

from node.cli import main
from node.mcap import iter_messages

pytest.importorskip("zenoh")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    d = tmp_path_factory.mktemp("live")
    return small_campaign(d, 3)


def start_node(model: Path, rec: Path) -> tuple[subprocess.Popen, int]:
    """``ordervib run`` in a subprocess on a free loopback port, once its recording exists."""
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "node.cli", "run", "--model", str(model),
                             "--record", str(rec), "--listen", f"tcp/127.0.0.1:{port}", "--quiet"],
                            cwd=Path(__file__).resolve().parents[1])
    deadline = time.monotonic() + 30
    while not rec.exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    time.sleep(1.0)  # subscriber declared
    return proc, port


def monitor(path: Path) -> list[tuple]:
    return [(m.payload["t"], m.payload["predicted"], m.payload["residual"], m.payload["flag"])
            for m in iter_messages(path, decode=True) if m.topic.endswith("/monitor/yB")]


def test_live_node_equals_offline_replay_and_records_every_input(setup):
    from node.live.node import LiveNode
    from node.models.bundle import load_bundle
    from replay.publish import publish_recording
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    engine_file = setup / "engine.json"
    node = LiveNode(load_bundle(setup / "m"), str(setup / "node.mcap"), listen=[endpoint],
                    engine_file=str(engine_file))
    node.start()
    try:
        sent = publish_recording(str(setup / "test.mcap"), endpoint, speed=0.0, quiet=True)
        deadline = time.monotonic() + 30
        while node.stats.received < sent and time.monotonic() < deadline:
            time.sleep(0.1)
    finally:
        node.stop()
    assert node.stats.received == sent and node.stats.overflow == 0
    inputs_sent = sorted((m.topic, bytes(m.payload)) for m in iter_messages(setup / "test.mcap"))
    inputs_rec = sorted((m.topic, bytes(m.payload)) for m in iter_messages(setup / "node.mcap")
                        if "/sensor/" in m.topic)
    assert inputs_rec == inputs_sent  # every input message is in the node's recording
    assert main(["replay", str(setup / "test.mcap"), "--model", str(setup / "m"),
                 "--out", str(setup / "offline.mcap"), "--quiet"]) == 0
    live, offline = monitor(setup / "node.mcap"), monitor(setup / "offline.mcap")
    assert len(live) > 1000
    assert live == offline  # predicted values equal to the last bit
    # the engine history it kept is the one the node's logic derives from the same messages
    from node.edges.engine_file import load_engine_states
    from node.runtime.core import NodeCore
    core = NodeCore(load_bundle(setup / "m"))
    for m in iter_messages(setup / "test.mcap"):
        core.handle(m.topic, bytes(m.payload))
    core.finish()
    kept = load_engine_states(engine_file)
    assert kept == core.engine_states() and all(s.last_on_t is not None for s in kept.values())


class _Discard:
    """Stands in for a Zenoh session: its puts go nowhere."""

    def put(self, key: str, data: bytes, **_: object) -> None:
        pass


# keys the node refuses: a wildcard inside a chunk, an over-long chunk, a chunk too many, no sensor key
REFUSED_KEYS = ["testbed/bed1/sensor/bad*key", "testbed/" + "b" * 65 + "/sensor/nB",
                "testbed/bed1/sensor/nB/x", "other/key"]


def test_replay_of_refused_keys_records_what_the_live_node_records(setup, tmp_path):
    """A recording that holds keys the node refuses, among a test bed's messages: offline replay
    records exactly what the live node's worker records from the same messages at the same
    receive times (``LiveNode.handle_batch``, batches of ``BATCH_MAX``): every admitted input with
    its times, each output right after the input that completed it, in the same order, byte for
    byte; the refused keys in neither (replay recorded them before). Aside: the outputs' publish
    times (the live node's clock) and the transitions' messages, which the live node publishes
    once their analysis in its own process is done (compared in the three-targets test)."""
    from node.live.node import BATCH_MAX, LiveNode
    from node.mcap import RecordingWriter
    from node.models.bundle import load_bundle
    from replay.offline import replay
    source = tmp_path / "hostile.mcap"
    rows = []
    for i, m in enumerate(iter_messages(setup / "test.mcap")):
        rows.append((m.topic, m.log_time, m.publish_time, bytes(m.payload)))
        if i % 7 == 3:  # a refused key now and then, inside batches, with a sample's payload
            rows.append((REFUSED_KEYS[i % len(REFUSED_KEYS)], *rows[-1][1:]))
    with RecordingWriter(str(source)) as w:
        w.write_many(rows)
    bundle = load_bundle(setup / "m")
    node = LiveNode(bundle, str(tmp_path / "live.mcap"))
    node.attach(_Discard())
    for start in range(0, len(rows), BATCH_MAX):
        node.handle_batch([(k, data, pub) for k, _, pub, data in rows[start:start + BATCH_MAX]])
    node.publish(node.core.finish())
    node.writer.close()
    replay(str(source), bundle, str(tmp_path / "offline.mcap"))

    def recorded(path: Path) -> list[tuple]:
        return [(m.topic, m.log_time, m.publish_time if "/sensor/" in m.topic else None, bytes(m.payload))
                for m in iter_messages(path) if not m.topic.endswith("/monitor/transient")]
    live, offline = recorded(tmp_path / "live.mcap"), recorded(tmp_path / "offline.mcap")
    refused = sum(k in REFUSED_KEYS for k, *_ in rows)
    assert refused > 4000 and sum(node.core.refused.values()) == refused
    assert offline == live  # to the bit, in the same order
    assert [r for r in live if "/sensor/" in r[0]] == [(k, log, pub, data) for k, log, pub, data in rows
                                                       if k not in REFUSED_KEYS]
    assert sum("/monitor/yB" in r[0] for r in live) > 1000
    transients = [m for m in iter_messages(tmp_path / "offline.mcap")
                  if m.topic.endswith("/monitor/transient")]
    assert len(node.core.pending) == len(transients) > 0  # the live node's, waiting for their analysis


def test_sigterm_finishes_the_recording(setup, tmp_path):
    from mcap.reader import make_reader
    rec = tmp_path / "n.mcap"
    proc, _ = start_node(setup / "m", rec)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=20) == 0
    with open(rec, "rb") as f:
        assert make_reader(f).get_summary() is not None  # finished: summary and footer written


def test_sigkill_then_recover_loses_at_most_the_last_second(setup, tmp_path):
    import orjson

    from node.edges.zenoh import open_session, zenoh_config
    from replay.publish import publish_recording
    rec = tmp_path / "k.mcap"
    proc, port = start_node(setup / "m", rec)
    health: dict = {}
    watcher = open_session(zenoh_config(None, [f"tcp/127.0.0.1:{port}"]))
    watcher.declare_subscriber("testbed/*/monitor/health",
                               lambda s: health.update(orjson.loads(s.payload.to_bytes())))
    try:
        sent = publish_recording(str(setup / "test.mcap"), f"tcp/127.0.0.1:{port}", speed=0.0,
                                 quiet=True)
        deadline = time.monotonic() + 60
        while health.get("received", -1) < sent and time.monotonic() < deadline:
            time.sleep(0.1)  # the node's health message tells how far it got
        time.sleep(2.5)  # two flush periods
    finally:
        proc.kill()
        proc.wait(timeout=20)
        watcher.close()
    fixed = tmp_path / "fixed.mcap"
    assert main(["recover", str(rec), "--out", str(fixed)]) == 0
    inputs = [m for m in iter_messages(fixed) if "/sensor/" in m.topic]
    # everything the node had received (its last health message, sent after the backlog
    # was processed) is in the rescued file
    assert health.get("received", 0) > 0.9 * sent
    assert len(inputs) == health["received"], f"recovered {len(inputs)}; health {health}, sent {sent}"
    assert any("/monitor/yB" in m.topic for m in iter_messages(fixed))


def test_three_beds_at_40_hz_every_sample_gets_its_monitor_message(setup, tmp_path):
    from harness.live import Bench, latencies, load_stream, wait_for
    from node.live.node import LiveNode
    from node.models.bundle import load_bundle
    from node.runtime.pipeline import MonitorPipeline
    bundle = load_bundle(setup / "m")
    stream = load_stream(str(setup / "test.mcap"), 3.0, 0.0, set(MonitorPipeline(bundle).channels))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    node = LiveNode(bundle, str(tmp_path / "n.mcap"), listen=[endpoint])
    node.start()
    beds = ["bedA", "bedB", "bedC"]
    bench = Bench(endpoint, beds, ["nB", "yB", "tF"], "testbed/*/monitor/yB")
    try:
        bench.wait_matched()
        sent = bench.publish(stream)  # 3 beds x 3 channels, 40 Hz in real time
        n = len(stream.slots)
        wait_for(lambda: len(bench.arrivals) >= 3 * n, 20)
        _, seen = latencies(bench, stream, sent["sent"], "/monitor/yB")
    finally:
        bench.close()
        node.stop()
    assert node.stats.received == sent["count"] == 3 * 3 * n and node.stats.overflow == 0
    assert seen == {b: n for b in beds}, f"monitor messages per bed {seen}, {n} samples each"


def test_the_relay_takes_everything_and_answers_each_needed_channel_of_its_beds(setup):
    """The hostile bench's floor (``bench hostile --floor``): a node without its logic takes every
    sensor message and answers, for its own beds only, each message of a needed channel with its
    time and channel, which is what the bench times."""
    from harness.live import Bench, free_port, load_stream, start_relay, stop_peer, wait_for
    stream = load_stream(str(setup / "test.mcap"), 1.0, 0.0, {"nB", "yB"})
    port = free_port()
    relay = start_relay(port, ["bedA"], {"nB", "yB"}, "yB")
    bench = Bench(f"tcp/127.0.0.1:{port}", ["bedA", "bedB"], ["nB", "yB", "tF"], "testbed/*/monitor/**")
    try:
        bench.wait_matched()
        sent = bench.publish(stream)
        expected = sum(c in ("nB", "yB") for slot in stream.slots for c, _ in slot)
        wait_for(lambda: len(bench.arrivals) >= expected, 20)
        time.sleep(0.3)  # nothing more comes
    finally:
        bench.close()
        report = stop_peer(relay)
    assert report == {"received": sent["count"], "published": expected}
    assert {k for k, _, _ in bench.arrivals} == {"testbed/bedA/monitor/yB"}
    answered = [(orjson.loads(p)["t"], orjson.loads(p)["c"]) for _, p, _ in bench.arrivals]
    assert answered == [(orjson.loads(payload)["t"], c) for slot in stream.slots for c, payload in slot
                        if c in ("nB", "yB")]


def test_the_relay_of_no_bed_only_takes_the_intake_floor(setup):
    """``bench live``'s intake floor: the relay given no bed (an empty ``--beds``) takes every
    sensor message and publishes nothing."""
    from harness.live import Bench, free_port, load_stream, start_relay, stop_peer
    stream = load_stream(str(setup / "test.mcap"), 0.5, 0.0, {"nB"})
    port = free_port()
    relay = start_relay(port, [], set(), "yB")
    bench = Bench(f"tcp/127.0.0.1:{port}", ["bedA"], ["nB", "yB", "tF"], "testbed/*/monitor/**")
    try:
        bench.wait_matched()
        sent = bench.publish(stream)
        time.sleep(0.5)  # the relay drains its FIFO
    finally:
        bench.close()
        report = stop_peer(relay)
    assert sent["count"] > 0 and report == {"received": sent["count"], "published": 0}
    assert bench.arrivals == []


def test_three_targets_live_equal_replay_for_each_target(tmp_path, monkeypatch):
    """One model of yA, yB and yC, with their phases: the live node's monitor messages of every
    target equal offline replay's to the last bit, vector fields included, and so do its
    transient messages (each transition's criticals against the fleet's), which the live node
    analyses in a process of its own (never in its own: a ramp's analysis on the worker stalled
    every bed, and on a thread beside it slowed the worker, issue 35)."""
    import threading

    from node.live.node import LiveNode
    from node.models.bundle import load_model
    from node.runtime.transient_watch import TransientWatch
    from replay.publish import publish_recording
    analysed_on: list[str] = []
    message_of = TransientWatch.message_of

    def spy(self, ramp):  # noqa: ANN001, ANN202
        analysed_on.append(threading.current_thread().name)
        return message_of(self, ramp)
    monkeypatch.setattr(TransientWatch, "message_of", spy)
    chans = ["--channels", "nB,yA,yB,yC,tF,yA_ph,yB_ph,yC_ph", "--plateau-scale", "0.05", "--quiet"]
    train, test = str(tmp_path / "train.mcap"), str(tmp_path / "test.mcap")
    assert main(["simulate", "--runs", "3", "--seed", "7", "--out", train, *chans]) == 0  # (3: a forecast)
    assert main(["simulate", "--runs", "4", "--skip", "3", "--seed", "7", "--out", test, *chans]) == 0
    schedule = tmp_path / "train.schedule.toml"  # with acceptance limits: limit, over_limit and verdicts
    schedule.write_text(schedule.read_text() + '[[limit]]\ntarget = "yB"\nmax = 15.0\nfrom_speed = 7000.0\n'
                        '[[limit]]\ntarget = "yA"\nmax = 2.0\noc = "OC7"\n')
    assert main(["train", train, "--schedule", str(schedule),
                 "--out", str(tmp_path / "m"), "--method", "lasso", "--inputs", "nB,tF", "--quiet",
                 "--workers", "1"]) == 0
    model = load_model(tmp_path / "m")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    node = LiveNode(model, str(tmp_path / "node.mcap"), listen=[endpoint])
    analysed_on[:] = []  # (training analysed the fleet's inline)
    node.start()
    try:
        sent = publish_recording(test, endpoint, speed=20.0, quiet=True)  # flat out would test the load
        deadline = time.monotonic() + 30
        while node.stats.received < sent and time.monotonic() < deadline:
            time.sleep(0.1)
    finally:
        node.stop()
    assert node.stats.received == sent
    assert analysed_on == []  # not one analysis in the node's process (they are in the live recording)
    assert main(["replay", test, "--model", str(tmp_path / "m"),
                 "--out", str(tmp_path / "offline.mcap"), "--quiet"]) == 0

    def by_target(path: Path) -> dict[str, list[bytes]]:
        out: dict[str, list[bytes]] = {}
        for m in iter_messages(path):
            if "/monitor/y" in m.topic or m.topic.endswith(("/monitor/transient", "/monitor/verdict")):
                out.setdefault(m.topic, []).append(bytes(m.payload))
        return out
    live, offline = by_target(tmp_path / "node.mcap"), by_target(tmp_path / "offline.mcap")
    transients = "testbed/bed1/monitor/transient"
    verdicts = "testbed/bed1/monitor/verdict"
    assert sorted(live) == [f"testbed/bed1/monitor/{t}" for t in ("transient", "verdict", "yA", "yB", "yC")]
    assert live[transients] == offline[transients]  # byte for byte, in the same order
    assert live[verdicts] == offline[verdicts]
    assert {orjson.loads(m)["target"] for m in live[verdicts]} == {"yA", "yB"}
    assert any(orjson.loads(m)["forecast"] for m in live[verdicts])
    assert {orjson.loads(m)["target"] for m in live[transients]} == {"yA", "yB", "yC"}
    assert sum(len(orjson.loads(m)["criticals"]) for m in live[transients]) >= 3
    for topic in live:
        if topic in (transients, verdicts):
            continue
        assert len(live[topic]) > 500
        assert live[topic] == offline[topic], topic
        assert any(b'"measured_phase":' in m for m in live[topic])  # the phase is used
        assert all((b'"over_limit":' in m) == (not topic.endswith("yC")) for m in live[topic])


def test_two_nodes_with_disjoint_bed_patterns_share_a_fleet(setup, tmp_path):
    """``run --beds``: each bed is served by the one node whose pattern it matches (both nodes
    and the beds on one Zenoh network, peers, no router), and the health says which."""
    from harness.live import Bench, load_stream, wait_for
    from node.live.node import LiveNode
    from node.models.bundle import load_bundle
    from node.runtime.pipeline import MonitorPipeline
    bundle = load_bundle(setup / "m")
    stream = load_stream(str(setup / "test.mcap"), 2.0, 0.0, set(MonitorPipeline(bundle).channels))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    east = LiveNode(bundle, str(tmp_path / "east.mcap"), listen=[endpoint], beds="east$*")
    west = LiveNode(bundle, str(tmp_path / "west.mcap"), connect=[endpoint], beds="west$*")
    east.start()
    west.start()
    beds = ["east1", "east2", "west1"]
    bench = Bench(endpoint, beds, ["nB", "yB", "tF"], "testbed/*/monitor/yB")
    try:
        bench.wait_matched()
        sent = bench.publish(stream)
        n = len(stream.slots)
        wait_for(lambda: len(bench.arrivals) >= 3 * n, 20)
        health = east.health("east1", time.time())
    finally:
        bench.close()
        east.stop()
        west.stop()
    assert set(east.core.beds) == {"east1", "east2"} and set(west.core.beds) == {"west1"}
    assert east.stats.received == 2 * 3 * n and west.stats.received == 3 * n == sent["count"] // 3
    assert health["beds"] == "east$*" and health["node"]
    with pytest.raises(ValueError, match="beds pattern"):
        LiveNode(bundle, str(tmp_path / "x.mcap"), listen=[endpoint], beds="east/*")
    assert not (tmp_path / "x.mcap").exists()
    assert main(["run", "--model", str(setup / "m"), "--record", str(tmp_path / "y.mcap"),
                 "--beds", "a/b"]) == 2
    assert not (tmp_path / "y.mcap").exists()


def test_one_router_two_nodes_forty_hz_beds_each_served_once(setup, tmp_path):
    """docs/deployment.md's fleet: ``ordervib router``, two nodes connected to it with disjoint
    ``--beds``, the beds connected to the router: every sample of every bed gets exactly one
    monitor message, from the node its pattern names."""
    from harness.live import Bench, load_stream, wait_for
    from node.live.node import LiveNode
    from node.models.bundle import load_bundle
    from node.runtime.pipeline import MonitorPipeline
    bundle = load_bundle(setup / "m")
    stream = load_stream(str(setup / "test.mcap"), 2.0, 0.0, set(MonitorPipeline(bundle).channels))
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    router = subprocess.Popen([sys.executable, "-m", "node.cli", "router", "--listen", endpoint,
                               "--duration", "60"], cwd=Path(__file__).resolve().parents[1])
    try:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", port)) == 0:
                    break
            time.sleep(0.1)
        nodes = [LiveNode(bundle, str(tmp_path / f"{b}.mcap"), connect=[endpoint], beds=f"{b}$*")
                 for b in ("east", "west")]
        for node in nodes:
            node.start()
        beds = ["east1", "west1", "west2"]
        bench = Bench(endpoint, beds, ["nB", "yB", "tF"], "testbed/*/monitor/yB")
        try:
            bench.wait_matched()
            bench.publish(stream)
            n = len(stream.slots)
            wait_for(lambda: len(bench.arrivals) >= 3 * n, 20)
            time.sleep(0.5)  # any duplicate would arrive by now
        finally:
            bench.close()
            for node in nodes:
                node.stop()
    finally:
        router.send_signal(signal.SIGTERM)
        router.wait(20)
    per_bed: dict[str, int] = {}
    for key, _, _ in bench.arrivals:
        bed = key.split("/")[1]
        per_bed[bed] = per_bed.get(bed, 0) + 1
    assert per_bed == {b: n for b in beds}, per_bed
    assert set(nodes[0].core.beds) == {"east1"} and set(nodes[1].core.beds) == {"west1", "west2"}
    assert router.returncode == 0


def test_publish_max_gap_shortens_the_standing_between_runs(caplog):
    """The committed four runs span 12,463 s, most of them standing between runs: at 1000 x real
    time their schedule lasts at least 12.5 s; with --max-gap 1 each of the three gaps lasts 1 s
    (1 ms at 1000 x), every message delivered, the shortening logged; progress lines carry the
    rate and the time left. The schedule is read on a virtual pacing clock, not the wall's."""
    import logging

    from node.cli.logs import Progress
    from node.edges.zenoh import open_session, zenoh_config
    from replay.publish import publish_recording

    rec = str(Path(__file__).resolve().parents[1] / "recordings" / "engine1_runs.mcap")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    got = []
    session = open_session(zenoh_config([endpoint], None, None))
    sub = session.declare_subscriber("testbed/**", lambda s: got.append(1))
    log = logging.getLogger("node.cli.test_publish")
    bar = Progress("publish", log, step=50)
    virtual = [0.0]  # the pacing clock, s: advanced by the publisher's sleeps alone

    def sleep(s: float) -> None:
        virtual[0] += s

    try:
        with caplog.at_level(logging.INFO):
            sent = publish_recording(rec, endpoint, speed=1000.0, max_gap_s=1.0,
                                     progress=lambda f, n: bar(f, n, "messages"),
                                     pace=(lambda: virtual[0], sleep))
            deadline = time.monotonic() + 10
            while len(got) < sent and time.monotonic() < deadline:
                time.sleep(0.05)
    finally:
        sub.undeclare()
        session.close()
    assert len(got) == sent > 100_000
    text = caplog.text
    import re
    skipped = re.search(r"shortened 3 gap\(s\) longer than 1 s to it: (\d+) s of standing skipped", text)
    assert skipped and 11_000 < int(skipped.group(1)) < 12_463
    # the schedule at 1000 x: the 12,463 s less the standing skipped (12.5 s unshortened)
    assert abs(virtual[0] - (12_463 - int(skipped.group(1))) / 1000) < 0.002, virtual[0]
    assert "publish: 100% (" in text and "messages/s" in text and "left" in text


def test_a_bad_max_gap_is_one_line(capsys):
    rec = str(Path(__file__).resolve().parents[1] / "recordings" / "engine1_runs.mcap")
    assert main(["replay", rec, "--publish", "--max-gap", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--max-gap" in err[0]
