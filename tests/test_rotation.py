"""RotatingRecorder: successive complete MCAP files that together hold every message once."""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import orjson
import pytest
from mcap.reader import make_reader

from node.contract import log_time_ns
from node.contract.errors import OrdervibError
from node.mcap import ReadStats, iter_messages
from node.mcap.rotation import RotatingRecorder, rotated_path

T0 = 1767600000.0
KEYS = ["testbed/b/sensor/nB", "testbed/b/sensor/yB", "testbed/b/monitor/yB"]


def _messages(n: int, step_ns: int = 25_000_000) -> list[tuple[str, int, int, bytes]]:
    out = []
    for i in range(n):
        key = KEYS[i % 3]
        t = round(T0 + i / 120, 4)
        body = {"t": t, "v": float(i)} if "/sensor/" in key else {"t": t, "flag": "ok", "i": i}
        out.append((key, log_time_ns(t), log_time_ns(T0) + i * step_ns, orjson.dumps(body)))
    return out


def _file(path: str) -> list[tuple[str, int, int, bytes]]:
    """Messages of one finished file, after checking its summary."""
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        msgs = [(c.topic, m.log_time, m.publish_time, m.data)
                for _, c, m in reader.iter_messages(log_time_order=False)]
        summary = reader.get_summary()
    assert summary is not None and summary.statistics is not None
    assert summary.statistics.message_count == len(msgs) > 0
    topics = {c.topic for c in summary.channels.values()}
    assert topics == {m[0] for m in msgs}  # channels registered again in every file
    assert all(s.encoding == "jsonschema" for s in summary.schemas.values())
    return msgs


def test_names() -> None:
    assert rotated_path("out/node.mcap", 3) == "out/node.0003.mcap"
    assert rotated_path("node", 12) == "node.0012.mcap"
    assert rotated_path("n.mcap", 12345) == "n.12345.mcap"


def test_size_rotation_keeps_every_message_once(tmp_path: Path) -> None:
    msgs = _messages(6000)
    with RotatingRecorder(tmp_path / "node.mcap", max_mb=0.02, chunk_size=8192) as rec:
        for i, (key, log, pub, data) in enumerate(msgs):
            if i % 2:
                rec.write_ns(key, log, data, pub)
            else:
                rec.write(key, log / 1e9, data, pub)
    assert len(rec.paths) >= 4 and rec.count == len(msgs)
    assert sorted(p.name for p in tmp_path.iterdir()) == [Path(p).name for p in rec.paths]
    got = []
    for p in rec.paths:
        part = _file(p)
        got += part
    assert [(k, p, d) for k, _, p, d in got] == [(k, p, d) for k, _, p, d in msgs]
    assert [lt for _, lt, _, _ in got] == [round(log / 1e9 * 1e9) if i % 2 == 0 else log
                                          for i, (_, log, _, _) in enumerate(msgs)]
    for p in rec.paths[:-1]:  # rotated as soon as a file reached the limit, not much later
        assert 20_000 <= Path(p).stat().st_size < 20_000 + 8192 + 4096


def test_time_rotation_by_publish_time(tmp_path: Path) -> None:
    msgs = _messages(1200, step_ns=500_000_000)  # one message every 0.5 s: 10 minutes
    with RotatingRecorder(tmp_path / "t.mcap", max_minutes=2) as rec:
        rec.write_many(msgs)
    assert len(rec.paths) == 5
    got = []
    for p in rec.paths:
        part = _file(p)
        pubs = [m[2] for m in part]
        assert max(pubs) - min(pubs) < 120e9
        assert len(part) == 240
        got += part
    assert got == msgs


def test_a_crash_loses_only_the_open_file_tail(tmp_path: Path) -> None:
    msgs = _messages(3000)
    rec = RotatingRecorder(tmp_path / "c.mcap", max_mb=0.02, chunk_size=8192)
    rec.write_many(msgs[:2000])
    rec.flush()
    crashed = tmp_path / "crashed.mcap"
    shutil.copyfile(rec.current, crashed)  # killed here: the current file is unfinished
    finished = rec.paths[:-1]
    got = [m for p in finished for m in _file(p)]
    stats = ReadStats()
    got += [(m.topic, m.log_time, m.publish_time, m.payload) for m in iter_messages(crashed, stats=stats)]
    assert stats.truncated and got == msgs[:2000]
    rec.write_many(msgs[2000:])
    rec.close()
    assert [m for p in rec.paths for m in _file(p)] == msgs


def test_bad_limits_and_closed_recorder(tmp_path: Path) -> None:
    with pytest.raises(OrdervibError):
        RotatingRecorder(tmp_path / "x.mcap", max_mb=0)
    with pytest.raises(OrdervibError):
        RotatingRecorder(tmp_path / "x.mcap", max_minutes=-1)
    rec = RotatingRecorder(tmp_path / "x.mcap", max_minutes=1)
    rec.close()
    with pytest.raises(OrdervibError):
        rec.write("testbed/b/sensor/nB", T0, {"t": T0, "v": 1.0}, 0)
    with open(rec.paths[0], "rb") as f:  # no message: one empty, valid file
        summary = make_reader(f).get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == 0


def test_live_node_records_into_rotating_files(tmp_path: Path) -> None:
    pytest.importorskip("zenoh")
    import socket

    from node.cli import main
    from node.contract.schedule import OperatingCondition, Schedule
    from node.live.node import LiveNode
    from node.models.bundle import Bundle
    from replay.publish import publish_recording

    sim = tmp_path / "sim.mcap"
    assert main(["simulate", "--runs", "1", "--seed", "3", "--out", str(sim), "--channels", "nB,yB,tF",
                 "--plateau-scale", "0.05", "--quiet"]) == 0
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    bundle = Bundle("wdmd", "yB", Schedule((OperatingCondition("A", 4000.0),)), [])
    rec = RotatingRecorder(tmp_path / "node.mcap", max_mb=0.1, chunk_size=1 << 15)
    node = LiveNode(bundle, rec, listen=[endpoint])
    node.start()
    try:
        sent = publish_recording(str(sim), endpoint, speed=0.0, quiet=True)
        deadline = time.monotonic() + 30
        while node.stats.received < sent and time.monotonic() < deadline:
            time.sleep(0.1)
    finally:
        node.stop()
    assert node.stats.received == sent and len(rec.paths) >= 3
    recorded = []
    for p in rec.paths:
        recorded += [(t, d) for t, _, _, d in _file(p) if "/sensor/" in t]
    assert sorted(recorded) == sorted((m.topic, m.payload) for m in iter_messages(sim))
    assert sum(1 for p in rec.paths for m in _file(p) if m[0].endswith("/monitor/yB")) > 1000
