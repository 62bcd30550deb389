"""The live worker's fair intake (issue 31): each bed's order kept, nothing lost or doubled, the
beds with the fewest messages waiting taken first, the fullest never starved."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from node.live.intake import FULLEST_SHARE, LANES_MAX, FairIntake, bed_of


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
    for bed in {bed_of(m[0]) for m in out}:  # each bed's messages in order
        stamps = [m[2] for m in out if bed_of(m[0]) == bed]
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
