"""The fast file-order message walk yields exactly what the mcap library's reader does."""

from __future__ import annotations

from pathlib import Path

from node.mcap import ReadStats, iter_messages, iter_messages_fast

REC = Path(__file__).resolve().parents[1] / "recordings" / "engine1_fault.mcap"


def as_tuples(it):
    return [(m.topic, m.log_time, m.publish_time, bytes(m.payload)) for m in it]


def test_fast_walk_equals_library_reader():
    assert as_tuples(iter_messages_fast(REC)) == as_tuples(iter_messages(REC))


def test_fast_walk_on_an_unfinished_file(tmp_path):
    data = REC.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    stats = ReadStats()
    fast = as_tuples(iter_messages_fast(cut, stats=stats))
    assert stats.truncated
    assert fast == as_tuples(iter_messages(cut))
    assert 0 < len(fast) < len(as_tuples(iter_messages_fast(REC)))
