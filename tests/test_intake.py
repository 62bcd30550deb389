"""The live worker's fair intake (issue 31): each bed's order kept, nothing lost or doubled, the
beds with the fewest messages waiting taken first, the fullest never starved."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from node.live.intake import FULLEST_SHARE, LANES_MAX, FairIntake, lane_name


def _bed(m) -> str:
    return m[0].split("/")[1]


beds = st.sampled_from([f"b{i}" for i in range(12)] + ["odd key", "*"])


@settings(max_examples=200, deadline=None)
@given(st.lists(st.lists(beds, max_size=60), min_size=1, max_size=6), st.integers(1, 40),
       st.sampled_from([2, 4, LANES_MAX]))
def test_every_message_once_each_beds_order_kept(rounds, n, lanes):
    """Messages added in rounds between takes: all come out once, each bed's in order (with
    few lanes too: the beds beyond them share the overflow lane)."""
    fi, seq, out = FairIntake(lanes), 0, []
    for names in rounds:
        msgs = []
        for b in names:
            msgs.append((f"testbed/{b}/sensor/nB", b"", seq))
            seq += 1
        fi.extend(msgs)
        got = fi.take(n)
        assert len(got) == min(n, len(got) + len(fi)) and len(got) <= n
        out += got
    while fi:
        got = fi.take(n)
        assert got
        out += got
    assert sorted(m[2] for m in out) == list(range(seq))
    for bed in {lane_name(m[0]) for m in out}:  # each bed's messages in order
        stamps = [m[2] for m in out if lane_name(m[0]) == bed]
        assert stamps == sorted(stamps)


def test_a_bed_behind_a_backlog_goes_first_and_the_backlog_is_not_starved():
    fi = FairIntake()
    big = [("testbed/sibling/sensor/nB", b"", i) for i in range(5000)]
    fi.extend(big)
    for k in range(10):  # the real bed's 21 channels of a slot each pass, behind the backlog
        fi.extend([(f"testbed/real/sensor/c{c}", b"", 10_000 + 21 * k + c) for c in range(21)])
        batch = fi.take(128)
        real = [m for m in batch if _bed(m) == "real"]
        assert [m[2] for m in real] == list(range(10_000 + 21 * k, 10_000 + 21 * (k + 1)))
        assert batch[:21] == real  # first, whole
        assert sum(_bed(m) == "sibling" for m in batch) == 128 - 21  # the rest from the backlog
    many = FairIntake()  # many small lanes before it: the backlog still gets its share
    many.extend([(f"testbed/s{i}/sensor/nB", b"", i) for i in range(200)] + big)
    assert sum(_bed(m) == "sibling" for m in many.take(128)) == 128 // FULLEST_SHARE


def test_beds_at_one_rate_all_behind_go_oldest_first():
    """20 beds, 5 slots of 21 channels each waiting, slots sent bed by bed: no lane is big, so
    the beds come in the order their oldest messages arrived, each whole (the last cut)."""
    fi, seq = FairIntake(), 0
    for _ in range(5):
        for b in range(20):
            fi.extend([(f"testbed/b{b:02d}/sensor/c{c}", b"", seq + c) for c in range(21)])
            seq += 21
    got = fi.take(128)
    assert [_bed(m) for m in got] == ["b00"] * 105 + ["b01"] * 23
    assert [m[2] for m in got[:21]] == list(range(21))


class _Fifo:
    """Zenoh's FIFO as the worker sees it: try_recv gives a sample or None."""

    def __init__(self, keys: list[str]) -> None:
        from types import SimpleNamespace as S
        self.samples = [S(key_expr=k, payload=S(to_bytes=lambda i=i: str(i).encode()), timestamp=None)
                        for i, k in enumerate(keys)]
        self.at = 0

    def try_recv(self):
        if self.at == len(self.samples):
            return None
        self.at += 1
        return self.samples[self.at - 1]


@pytest.mark.parametrize("bound", [None, 1500])
def test_the_workers_drain_bounded_fair_and_complete(monkeypatch, bound):
    """LiveNode._drain over a FIFO holding a sibling's 5,000-message backlog, then a real bed's
    slot: the fair intake never holds more than INTAKE_MAX; every message comes out once, each
    bed's in order; the node is behind (its intake not found empty) until the last batch. With
    the default bound the real bed's slot comes out whole once the drain reaches it, after
    5,000 / DRAIN_MAX passes, not after the backlog."""
    import io

    import node.live.node as live
    from node.contract.schedule import OperatingCondition, Schedule
    from node.mcap import RecordingWriter
    from node.models.bundle import Bundle
    if bound is not None:
        monkeypatch.setattr(live, "INTAKE_MAX", bound)
    monkeypatch.setattr(live.time, "sleep", lambda s: None)
    bundle = Bundle("wdmd", "yB", Schedule((OperatingCondition("A", 4000.0),)), [])
    node = live.LiveNode(bundle, RecordingWriter(io.BytesIO()))
    keys = ["testbed/sib/sensor/nB"] * 5000 + [f"testbed/real/sensor/c{c}" for c in range(21)]
    node.sub = _Fifo(keys)
    empty_at = node._last_empty_ns
    out: list = []
    while True:
        batch = node._drain()
        assert len(batch) <= live.BATCH_MAX and len(node._fair) <= live.INTAKE_MAX
        out += batch
        if not node._behind:
            break
        assert node._last_empty_ns == empty_at  # messages wait: the intake was not found empty
    assert node._last_empty_ns > empty_at and not node._fair
    ids = [int(p) for _, p, _ in out]
    assert sorted(ids) == list(range(5021))
    assert [i for i in ids if i < 5000] == list(range(5000))  # the sibling's in order
    real = [i for i, (k, _, _) in enumerate(out) if "/real/" in k]
    assert real == list(range(real[0], real[0] + 21))  # whole, in order
    if bound is None:
        assert real[0] < (5000 // live.DRAIN_MAX + 2) * live.BATCH_MAX
