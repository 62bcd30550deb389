"""node.mcap: writer layout, streaming reader on unfinished files, read_runs, errors."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import orjson
import pytest
from mcap.reader import make_reader

from node.cli import main
from node.contract import log_time_ns, parse_sensor_key, sensor_key
from node.contract.errors import OrdervibError
from node.mcap import ReadStats, RecordingWriter, iter_messages, read_payloads
from node.training.runs import read_runs

T0 = 1767600000.0


def _write_runs(path: Path, runs: list[tuple[float, int]], channels=("nB", "yB", "tA")) -> None:
    """Runs given as (start time s, samples); nB ramps up and down; yB = 1 + nB / 1000."""
    with RecordingWriter(path) as w:
        for start, k in runs:
            nb = 5000.0 * np.sin(np.pi * np.arange(k) / (k - 1))
            for i in range(k):
                t = round(start + i / 40 + 0.001 * ((i * 7) % 3 - 1), 4)  # +-1 ms jitter
                values = {"nB": nb[i], "yB": 1.0 + nb[i] / 1000, "tA": 15.0 + i}
                for ch in channels:
                    v = None if (ch == "yB" and i == 100) else float(values[ch])
                    w.write(sensor_key("bed1", ch), t, {"t": t, "v": v}, log_time_ns(t) + 10**6)


def test_keys_and_log_time() -> None:
    assert sensor_key("bed7", "yB") == "testbed/bed7/sensor/yB"
    assert parse_sensor_key("testbed/bed7/sensor/yB") == ("bed7", "yB")
    assert parse_sensor_key("testbed/bed7/monitor/yB") is None
    assert log_time_ns(1767600000.0251) == round(1767600000.0251 * 1e9)


def test_writer_layout_readable_by_plain_mcap(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    with RecordingWriter(path) as w:
        w.write("testbed/b/sensor/nB", T0, {"t": T0, "v": 1.0}, 5)
        w.write("testbed/b/sensor/nB", T0 + 0.025, b'{"t":1767600000.025,"v":null}', 6)
        w.write("testbed/b/monitor/yB", T0, {"t": T0, "flag": "ok"}, 7)
    with open(path, "rb") as f:
        msgs = list(make_reader(f).iter_messages(log_time_order=False))
    assert len(msgs) == 3
    topics = [c.topic for _, c, _ in msgs]
    assert topics.count("testbed/b/sensor/nB") == 2
    for schema, channel, msg in msgs:
        assert schema.encoding == "jsonschema"
        assert orjson.loads(schema.data)["type"] == "object"
        assert channel.message_encoding == "json"
        assert msg.log_time == round(orjson.loads(msg.data)["t"] * 1e9)
    # one channel per topic, one schema per kind
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert len(summary.channels) == 2 and len(summary.schemas) == 2


def test_streaming_reader_recovers_unfinished_file(tmp_path: Path) -> None:
    path, crashed = tmp_path / "live.mcap", tmp_path / "crashed.mcap"
    w = RecordingWriter(path, chunk_size=4096)
    for i in range(2000):
        t = T0 + i / 40
        w.write("testbed/b/sensor/nB", t, {"t": t, "v": float(i)}, log_time_ns(t))
    w.flush()
    shutil.copyfile(path, crashed)  # what a crash right after flush() leaves behind
    w.close()
    for name in (crashed,):
        stats = ReadStats()
        got = list(iter_messages(name, decode=True, stats=stats))
        assert len(got) == 2000 and stats.truncated
        assert [m.payload["v"] for m in got] == [float(i) for i in range(2000)]
    # cut mid-way through a chunk too: complete chunks survive
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    stats = ReadStats()
    got = list(iter_messages(cut, stats=stats))
    assert 0 < len(got) < 2000 and stats.truncated
    fast = ReadStats()
    payloads = read_payloads(cut, fast)
    assert len(payloads["testbed/b/sensor/nB"]) == len(got) and fast.truncated


def test_fast_and_streaming_readers_agree(tmp_path: Path) -> None:
    path = tmp_path / "r.mcap"
    _write_runs(path, [(T0, 500)])
    by_topic = read_payloads(path)
    streamed: dict[str, list[bytes]] = {}
    for m in iter_messages(path):
        streamed.setdefault(m.topic, []).append(m.payload)
    assert by_topic == streamed


def test_read_runs_split_shapes_nan_and_shutdown(tmp_path: Path) -> None:
    path = tmp_path / "r.mcap"
    _write_runs(path, [(T0, 800), (T0 + 800 / 40 + 100.0, 600)])
    runs = read_runs(path)
    assert len(runs) == 2
    for run in runs:
        assert run.channels == ("nB", "yB", "tA") and run.bed == "bed1"
        assert run.data.shape == (len(run.t), 3)
        assert np.all(np.abs(np.diff(run.t) - 0.025) < 1e-6)  # float64 at 1.8e9 s
        # the first and last samples have nB = 0 (< 5 % of max): dropped as "off"
        assert np.nanmin(run.column("nB")) >= 0.05 * 5000
    assert runs[0].shutdown_before is None
    # off from the last "on" sample of run 1 to the first "on" sample of run 2
    assert runs[1].shutdown_before == pytest.approx(100.0, abs=3.0)
    # the dropout at sample 100 of run 1 is NaN in yB only
    i = int(round((T0 + 100 / 40 - runs[0].t[0]) * 40))
    assert np.isnan(runs[0].column("yB")[i]) and not np.isnan(runs[0].column("nB")[i])
    sub = read_runs(path, channels=["yB", "nX"])
    assert sub[0].data.shape[1] == 2 and np.all(np.isnan(sub[0].column("nX")))


def test_missing_sample_and_unknown_channel(tmp_path: Path) -> None:
    path = tmp_path / "m.mcap"
    with RecordingWriter(path) as w:
        for i in range(600):
            t = T0 + i / 40
            w.write("testbed/b/sensor/nB", t, {"t": t, "v": 4000.0}, log_time_ns(t))
            if i != 50:  # one sample never arrives
                w.write("testbed/b/sensor/qZ", t, {"t": t, "v": 1.0}, log_time_ns(t))
            w.write("testbed/b/monitor/oc", t, {"t": t, "oc": None}, log_time_ns(t))
    stats = ReadStats()
    (run,) = read_runs(path, stats=stats)
    assert run.channels == ("nB", "qZ")
    assert np.isnan(run.column("qZ")[50]) and np.isnan(run.column("qZ")).sum() == 1
    assert stats.unknown_topics == {"testbed/b/monitor/oc"}


def test_malformed_payloads_are_counted_and_skipped(tmp_path: Path) -> None:
    path = tmp_path / "bad.mcap"
    with RecordingWriter(path) as w:
        for i in range(600):
            t = T0 + i / 40
            payload = {"t": t, "v": 3000.0}
            if i == 10:
                payload = b"not json"
            elif i == 11:
                payload = {"t": "soon", "v": 1.0}
            elif i == 12:
                payload = {"v": 1.0}
            w.write("testbed/b/sensor/nB", t, payload, log_time_ns(t))
    stats = ReadStats()
    (run,) = read_runs(path, stats=stats)
    assert stats.malformed == 3
    assert np.isnan(run.column("nB")[10:13]).all() and run.data.shape == (600, 1)
    stats = ReadStats()
    assert len(list(iter_messages(path, decode=True, stats=stats))) == 599
    assert stats.malformed == 1


@pytest.mark.parametrize("content", [b"", b"hello, not an mcap file at all", None])
def test_bad_files_raise_one_line_errors(tmp_path: Path, content: bytes | None) -> None:
    path = tmp_path / "x.mcap"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(OrdervibError) as err:
        read_runs(path)
    assert "\n" not in str(err.value) and str(path) in str(err.value)
    with pytest.raises(OrdervibError):
        list(iter_messages(path))


def test_cli_bad_option_exits_2_with_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["simulate", "--out", "x.mcap", "--no-such-option"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("ordervib")
