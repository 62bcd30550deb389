"""The live worker's fair intake (issue 31): each bed's order kept, nothing lost or doubled, the
beds with the fewest messages waiting taken first, the fullest never starved."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from node.live.intake import FULLEST_SHARE, FairIntake, lane_of


def _bed(m) -> str:
    return m[0].split("/")[1]


beds = st.sampled_from([f"b{i}" for i in range(12)] + ["odd key", "testbed/*"])


@settings(max_examples=200, deadline=None)
@given(st.lists(st.lists(beds, max_size=60), min_size=1, max_size=6), st.integers(1, 40))
def test_every_message_once_each_beds_order_kept(rounds, n):
    """Messages added in rounds between takes: all come out once, each bed's (lane's) in order."""
    fi, seq, out = FairIntake(), 0, []
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
    for lane in {lane_of(m[0]) for m in out}:  # a lane's (so a bed's) messages in order
        stamps = [m[2] for m in out if lane_of(m[0]) == lane]
        assert stamps == sorted(stamps)


def test_a_bed_behind_a_backlog_goes_first_and_the_backlog_is_not_starved():
    fi = FairIntake()
    big = [("testbed/sibling/sensor/nB", b"", i) for i in range(5000)]
    assert lane_of(big[0][0]) != lane_of("testbed/real/sensor/nB")
    fi.extend(big)
    for k in range(10):  # the real bed's 21 channels of a slot each pass, behind the backlog
        fi.extend([("testbed/real/sensor/c%d" % c, b"", 10_000 + 21 * k + c) for c in range(21)])
        batch = fi.take(128)
        real = [m for m in batch if _bed(m) == "real"]
        assert [m[2] for m in real] == list(range(10_000 + 21 * k, 10_000 + 21 * (k + 1)))
        assert batch[:21] == real  # first, whole
        assert sum(_bed(m) == "sibling" for m in batch) == 128 - 21  # the rest from the backlog
    many = FairIntake()  # many small lanes: the fullest still gets its share
    many.extend([(f"testbed/s{i}/sensor/nB", b"", i) for i in range(400)] + big)
    fullest = lane_of(big[0][0])
    assert sum(lane_of(m[0]) == fullest for m in many.take(128)) >= 128 // FULLEST_SHARE
