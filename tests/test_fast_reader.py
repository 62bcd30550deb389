"""The file-order record walk yields exactly what the mcap library's reader does, and skips bad chunks."""

from __future__ import annotations

from pathlib import Path

from mcap.reader import NonSeekingReader

from node.cli import main
from node.mcap import ReadStats, iter_messages, iter_messages_fast, read_payloads

REC = Path(__file__).resolve().parents[1] / "recordings" / "engine1_fault.mcap"


def as_tuples(it):
    return [(m.topic, m.log_time, m.publish_time, bytes(m.payload)) for m in it]


def library(path: Path) -> list[tuple[str, int, int, bytes]]:
    """The messages as mcap-python's streaming reader sees them, in file order, up to a cut."""
    out = []
    with open(path, "rb") as f:
        try:
            for _, c, m in NonSeekingReader(f).iter_messages(log_time_order=False):
                out.append((c.topic, m.log_time, m.publish_time, bytes(m.data)))
        except Exception:  # noqa: BLE001 -- the library's own error for a cut file
            pass
    return out


def test_walk_equals_library_reader():
    stats = ReadStats()
    fast = as_tuples(iter_messages_fast(REC, stats=stats))
    assert fast == library(REC) == as_tuples(iter_messages(REC))
    assert stats.messages == len(fast) and not stats.truncated and stats.malformed == 0


def test_walk_on_an_unfinished_file(tmp_path):
    data = REC.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    stats = ReadStats()
    fast = as_tuples(iter_messages_fast(cut, stats=stats))
    assert stats.truncated
    assert fast == library(cut)
    assert 0 < len(fast) < len(as_tuples(iter_messages_fast(REC)))


def test_a_corrupt_chunk_is_skipped_and_counted(tmp_path, capsys):
    data = bytearray(REC.read_bytes())
    data[200_000:200_040] = bytes(40)  # inside the compressed data of one chunk
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    whole = as_tuples(iter_messages(REC))
    stats = ReadStats()
    got = as_tuples(iter_messages(bad, stats=stats))
    assert stats.malformed == 1 and not stats.truncated
    assert 0 < len(whole) - len(got) < len(whole) // 5 and set(got) <= set(whole)
    fast = ReadStats()
    by_topic = read_payloads(bad, fast)
    assert sum(map(len, by_topic.values())) == len(got) and fast.malformed == 1
    assert main(["recover", str(bad), "--out", str(tmp_path / "fixed.mcap")]) == 0
    assert as_tuples(iter_messages(tmp_path / "fixed.mcap")) == got
    first = capsys.readouterr().out.splitlines()[0]
    assert " finished input" in first and "1 unreadable records skipped" in first
