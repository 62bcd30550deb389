"""ordervib recover: an unfinished recording gives back every message flushed before the crash."""

from __future__ import annotations

import shutil
from pathlib import Path

import orjson
import pytest
from mcap.reader import make_reader

from node.cli import main
from node.contract import log_time_ns, sensor_key
from node.mcap import RecordingWriter

T0 = 1767600000.0
N_FLUSHED = 600  # samples per topic written before the last flush


def _sample(i: int) -> list[tuple[str, float, dict, int]]:
    """One 40 Hz step: two sensor messages and one monitor message (key, t, payload, publish ns)."""
    t = round(T0 + i / 40, 4)
    nb = 1000.0 + i
    return [
        (sensor_key("bed1", "nB"), t, {"t": t, "v": nb}, log_time_ns(t) + 2_000_000),
        (sensor_key("bed1", "yB"), t, {"t": t, "v": None if i == 7 else 0.5 + i / 1000}, log_time_ns(t) + 3),
        (
            "testbed/bed1/monitor/yB",
            t,
            {
                "t": t,
                "oc": "OC3",
                "phase": "steady",
                "measured": 0.5,
                "predicted": 0.49,
                "residual": 0.01,
                "flag": "ok",
                "score": 0.2,
                "band": 0.3,
                "model": "m1",
            },
            log_time_ns(t) + 5_000_000,
        ),
    ]


@pytest.fixture
def broken(tmp_path: Path) -> tuple[Path, Path, list[tuple[str, int, int, bytes]]]:
    """(unfinished copy, finished original, the messages written before the last flush)."""
    path = tmp_path / "node.mcap"
    flushed: list[tuple[str, int, int, bytes]] = []
    w = RecordingWriter(path)
    for i in range(N_FLUSHED):
        for key, t, payload, pub in _sample(i):
            w.write(key, t, payload, pub)
            flushed.append((key, log_time_ns(t), pub, orjson.dumps(payload)))
    w.write("testbed/bed1/monitor/oc", T0, {"t": T0, "oc": "OC3", "phase": "steady", "previous": None}, 9)
    flushed.append(("testbed/bed1/monitor/oc", log_time_ns(T0), 9, b""))
    w.flush()
    for i in range(N_FLUSHED, N_FLUSHED + 100):  # still in the open chunk at the "crash"
        for key, t, payload, pub in _sample(i):
            w.write(key, t, payload, pub)
    crashed = tmp_path / "crashed.mcap"
    shutil.copy(path, crashed)  # the bytes on disk of a process killed here
    w.close()
    return crashed, path, flushed


def _read_all(path: Path) -> list[tuple[str, int, int, bytes]]:
    with open(path, "rb") as f:
        reader = make_reader(f)
        out = []
        for schema, channel, msg in reader.iter_messages(log_time_order=False):
            assert schema is not None and schema.encoding == "jsonschema"
            assert orjson.loads(schema.data)["type"] == "object"
            assert channel.message_encoding == "json"
            out.append((channel.topic, msg.log_time, msg.publish_time, msg.data))
        return out


def test_unfinished_file_is_refused_by_the_plain_reader(broken) -> None:
    crashed, _, _ = broken
    with open(crashed, "rb") as f, pytest.raises(Exception):  # noqa: B017
        list(make_reader(f).iter_messages())


def test_recover_keeps_every_flushed_message(broken, tmp_path: Path, capsys) -> None:
    crashed, _, flushed = broken
    out = tmp_path / "fixed.mcap"
    assert main(["recover", str(crashed), "--out", str(out)]) == 0
    got = _read_all(out)
    assert len(got) == len(flushed) == 3 * N_FLUSHED + 1
    for (topic, lt, pt, data), (etopic, elt, ept, edata) in zip(got, flushed):
        assert (topic, lt, pt) == (etopic, elt, ept)
        if edata:
            assert data == edata
    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics.message_count == len(flushed)
    assert {c.topic for c in summary.channels.values()} == {
        "testbed/bed1/sensor/nB",
        "testbed/bed1/sensor/yB",
        "testbed/bed1/monitor/yB",
        "testbed/bed1/monitor/oc",
    }
    first = capsys.readouterr().out.splitlines()[0]
    assert "unfinished input" in first and f"{len(flushed)} messages on 4 topics" in first
    assert f"span {(N_FLUSHED - 1) / 40:.3f} s" in first


def test_recover_of_a_finished_file_copies_everything(broken, tmp_path: Path, capsys) -> None:
    _, finished, _ = broken
    out = tmp_path / "copy.mcap"
    assert main(["recover", str(finished), "--out", str(out)]) == 0
    assert _read_all(out) == _read_all(finished)
    assert "finished input" in capsys.readouterr().out.splitlines()[0]


@pytest.mark.parametrize("content", [b"", b"hello, not an mcap file\n" * 10])
def test_not_mcap_is_one_line_exit_2(tmp_path: Path, capsys, content: bytes) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(content)
    assert main(["recover", str(bad), "--out", str(tmp_path / "o.mcap")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "bad.mcap" in err
    assert not (tmp_path / "o.mcap").exists() and not (tmp_path / "o.mcap.part").exists()


def test_missing_input_and_same_output(tmp_path: Path, capsys, broken) -> None:
    assert main(["recover", str(tmp_path / "nope.mcap"), "--out", str(tmp_path / "o.mcap")]) == 2
    crashed, _, _ = broken
    assert main(["recover", str(crashed), "--out", str(crashed)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "no such recording" in err[0] and "differ" in err[1]


def test_the_span_is_the_beds_data_and_a_node_clock_topic_is_named_apart(tmp_path: Path, capsys) -> None:
    """An older node recorded its own health on its clock, months after the replayed data: the
    span printed is the data's (10 s), the other topic's range named apart. Before: "span
    28265395.956 s" on the demo's recording."""
    src = tmp_path / "old.mcap"
    wall = T0 + 200 * 86400.0  # the node's clock: 200 days later
    with RecordingWriter(str(src)) as w:
        for i in range(401):
            t = T0 + i / 40
            w.write(sensor_key("bed1", "nB"), t, orjson.dumps({"t": t, "v": 1.0}), log_time_ns(t))
        w.write("ordervib/node/n1/health", wall, orjson.dumps({"t": wall, "wall": wall}), log_time_ns(wall))
    assert main(["recover", str(src), "--out", str(tmp_path / "r.mcap")]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert "span 10.000 s from 2026-01-05 08:00:00 UTC (the beds' data; other topics from" in first
    assert "2026-07-24" in first and "outside it" in first
    with RecordingWriter(str(src)) as w:  # the node's health within the data: no word about it
        for i in range(41):
            t = T0 + i / 40
            w.write(sensor_key("bed1", "nB"), t, orjson.dumps({"t": t, "v": 1.0}), log_time_ns(t))
        w.write("ordervib/node/n1/health", T0 + 0.5, orjson.dumps({"t": T0 + 0.5}), log_time_ns(T0 + 0.5))
    assert main(["recover", str(src), "--out", str(tmp_path / "s.mcap")]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert "span 1.000 s from" in first and "outside" not in first
