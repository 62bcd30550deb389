"""The lean MCAP writer behind RecordingWriter, checked against mcap-python's own readers."""

from __future__ import annotations

import io
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import orjson
import pytest
from mcap.reader import NonSeekingReader, make_reader
from mcap_spec import chunk_records

from node.cli import main
from node.contract import log_time_ns
from node.mcap import ReadStats, RecordingWriter, iter_messages, iter_messages_fast

T0 = 1767600000.0
KEYS = ["testbed/b/sensor/nB", "testbed/b/sensor/yB", "testbed/b/monitor/yB", "testbed/c/sensor/nB"]


def _messages(n: int = 3000) -> list[tuple[str, int, int, bytes]]:
    """(topic, log_time, publish_time, payload) with jittered, partly out-of-order times."""
    out = []
    for i in range(n):
        key = KEYS[(i * 7) % len(KEYS)]
        t = round(T0 + i / 160 + 0.004 * ((i * 5) % 3 - 1), 4)
        v = None if i % 97 == 0 else float(i) / 3
        payload = orjson.dumps({"t": t, "v": v} if "/sensor/" in key else {"t": t, "flag": "ok", "i": i})
        out.append((key, log_time_ns(t), log_time_ns(t) + 1000 + i, payload))
    return out


def _write(path_or_stream, msgs, **kw) -> None:
    """Blocks of 100 messages, written in turn with each of the writer's four methods."""
    with RecordingWriter(path_or_stream, **kw) as w:
        for a in range(0, len(msgs), 100):
            block = msgs[a:a + 100]
            how = (a // 100) % 4
            if how == 0:
                for key, log, pub, data in block:
                    w.write(key, log / 1e9, data, pub)
            elif how == 1:
                for key, log, pub, data in block:
                    w.write_ns(key, log, data, pub)
            elif how == 2:
                w.write_many(block)
            else:
                w.write_columns(*map(list, zip(*block, strict=True)))


def _read(path: Path, **kw) -> list[tuple[str, int, int, bytes]]:
    with open(path, "rb") as f:
        return [(c.topic, m.log_time, m.publish_time, m.data)
                for _, c, m in make_reader(f, validate_crcs=True).iter_messages(**kw)]


def _with_times_from_write(msgs):
    """write() goes through t in seconds: log_time is round(t * 1e9) of log / 1e9."""
    return [(k, round(log / 1e9 * 1e9) if (i // 100) % 4 == 0 else log, pub, d)
            for i, (k, log, pub, d) in enumerate(msgs)]


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
@pytest.mark.parametrize("message_index", [True, False])
def test_round_trip_with_the_mcap_library(tmp_path: Path, compression: str, message_index: bool) -> None:
    msgs = _messages()
    path = tmp_path / "a.mcap"
    _write(path, msgs, chunk_size=8192, compression=compression, message_index=message_index)
    want = _with_times_from_write(msgs)
    assert _read(path, log_time_order=False) == want  # file order, through the chunk indexes
    got = _read(path)  # log-time order
    assert sorted(got, key=lambda m: m[1]) == got and sorted(got) == sorted(want)
    fast = [(m.topic, m.log_time, m.publish_time, m.payload) for m in iter_messages_fast(path)]
    assert fast == want
    with open(path, "rb") as f:
        streamed = [(c.topic, m.log_time, m.publish_time, m.data)
                    for _, c, m in NonSeekingReader(f, validate_crcs=True).iter_messages()]
    assert streamed == want
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        header = reader.get_header()
    assert header.library == "ordervib"
    st = summary.statistics
    assert st.message_count == len(msgs) and st.chunk_count == len(summary.chunk_indexes) > 1
    assert st.message_start_time == min(m[1] for m in want)
    assert st.message_end_time == max(m[1] for m in want)
    topic_of = {c.id: c.topic for c in summary.channels.values()}
    counts = {topic_of[c]: k for c, k in st.channel_message_counts.items()}
    assert counts == {k: sum(1 for m in msgs if m[0] == k) for k in KEYS}
    assert {s.encoding for s in summary.schemas.values()} == {"jsonschema"}
    assert {c.message_encoding for c in summary.channels.values()} == {"json"}
    for ci in summary.chunk_indexes:
        assert ci.compression == {"none": ""}.get(compression, compression)
        assert bool(ci.message_index_offsets) == message_index


def test_time_range_and_topic_queries_use_the_chunk_indexes(tmp_path: Path) -> None:
    msgs = _messages()
    path = tmp_path / "q.mcap"
    _write(path, msgs, chunk_size=4096)
    want = _with_times_from_write(msgs)
    lo, hi = want[1000][1], want[2000][1]
    got = _read(path, starting_at=lo, ending_before=hi, topics=["testbed/b/sensor/yB"])
    assert sorted(got) == sorted(m for m in want if lo <= m[1] < hi and m[0] == "testbed/b/sensor/yB")


def test_message_indexes_point_at_their_messages(tmp_path: Path) -> None:
    msgs = _messages()
    path = tmp_path / "i.mcap"
    _write(path, msgs, chunk_size=4096)
    data = path.read_bytes()
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    seen = 0
    for ci in summary.chunk_indexes:
        records = chunk_records(data, ci.chunk_start_offset)
        assert len(records) == ci.uncompressed_size
        total = 0
        for cid, off in ci.message_index_offsets.items():
            op, _, rcid, rlen = struct.unpack_from("<BQHI", data, off)
            assert op == 0x07 and rcid == cid
            total += 9 + 6 + rlen
            for j in range(rlen // 16):
                log, rec_off = struct.unpack_from("<QQ", data, off + 15 + 16 * j)
                op, _, mcid, _, mlog = struct.unpack_from("<BQHIQ", records, rec_off)
                assert (op, mcid, mlog) == (0x05, cid, log)
                seen += 1
        assert total == ci.message_index_length
    assert seen == len(msgs)


def test_flushed_file_is_recoverable_and_output_is_deterministic(tmp_path: Path) -> None:
    msgs = _messages()
    path, crashed, fixed = tmp_path / "n.mcap", tmp_path / "crashed.mcap", tmp_path / "fixed.mcap"
    w = RecordingWriter(path)
    for key, log, pub, data in msgs[:2000]:
        w.write_ns(key, log, data, pub)
    w.flush()
    for key, log, pub, data in msgs[2000:]:
        w.write_ns(key, log, data, pub)
    shutil.copyfile(path, crashed)  # killed now: the open chunk is lost
    w.close()
    stats = ReadStats()
    got = [(m.topic, m.log_time, m.publish_time, m.payload) for m in iter_messages(crashed, stats=stats)]
    assert got == msgs[:2000] and stats.truncated
    assert main(["recover", str(crashed), "--out", str(fixed), "--quiet"]) == 0
    assert _read(fixed, log_time_order=False) == msgs[:2000]
    again = io.BytesIO()
    w2 = RecordingWriter(again)
    for key, log, pub, data in msgs[:2000]:
        w2.write_ns(key, log, data, pub)
    w2.flush()
    for key, log, pub, data in msgs[2000:]:
        w2.write_ns(key, log, data, pub)
    w2.close()
    assert again.getvalue() == path.read_bytes()  # no clock, no randomness


def test_empty_recording_is_valid(tmp_path: Path) -> None:
    path = tmp_path / "e.mcap"
    with RecordingWriter(path):
        pass
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert list(reader.iter_messages()) == []
        assert reader.get_summary().statistics.message_count == 0


def test_independent_checker_accepts_the_file(tmp_path: Path) -> None:
    rerun = shutil.which("rerun") or str(Path(sys.executable).with_name("rerun"))
    if not Path(rerun).exists():
        pytest.skip("no rerun CLI")
    path = tmp_path / "c.mcap"
    _write(path, _messages(), chunk_size=4096)
    res = subprocess.run([rerun, "mcap", "check", str(path)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stdout + res.stderr


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_chunks_packed_in_a_thread_give_the_same_bytes(tmp_path: Path, compression: str) -> None:
    msgs = _messages(6000)
    msgs += [("testbed/d/sensor/nA", log, pub, data) for _, log, pub, data in msgs[-500:]]  # a late channel
    plain, threaded = io.BytesIO(), io.BytesIO()
    _write(plain, msgs, chunk_size=8192, compression=compression)
    _write(threaded, msgs, chunk_size=8192, compression=compression, background=True)
    assert threaded.getvalue() == plain.getvalue()
    path = tmp_path / "flushed.mcap"
    with RecordingWriter(path, chunk_size=8192, compression=compression, background=True) as w:
        w.write_columns(*map(list, zip(*msgs[:3000], strict=True)))
        w.flush()  # waits for the chunks in the thread
        assert path.stat().st_size == w.bytes_written
        stats = ReadStats()
        got = [tuple(m) for m in iter_messages_fast(path, stats=stats)]
        assert got == msgs[:3000]  # all there (the summary comes at close)
