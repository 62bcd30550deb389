"""Channels that sample on their own clock phase (issue 18), and delivery order (issue 12, item 2).

Every test bed here samples groups of channels at offsets spread over the whole 40 Hz period,
with jitter, and delivers them late and out of order within the aligner's wait.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from node.contract import FS, RUN_GAP, decode_samples, parse_sensor_key, sensor_key
from node.contract.slotting import ChannelPhase
from node.mcap.writer import RecordingWriter
from node.models.config import RuntimeConfig
from node.runtime.align import AlignedSample, Aligner
from node.training.runs import read_runs

pytestmark = pytest.mark.usefixtures("numpy_path_from_16_messages")

JITTER = 1e-3  # s, each group's sampling instant, uniform +-
WAIT = RuntimeConfig.align_wait_s
DELAY = 0.2  # s, the longest delivery delay (uniform), within the wait
# clock phase of each group, periods in [-0.5, 0.5): -0.455 is 13.6 ms after a slot's time
# (just above half a period), 0.455 is 11.4 ms (just below); the others spread between. Within
# the jitter of half a period (11.5 to 13.5 ms) a group may pair with either neighbouring slot
GROUPS = {
    -0.455: ("nA", "nB"), -0.31: ("yA", "yB"), -0.12: ("tA",), 0.0: ("nC", "yC"),
    0.17: ("tB", "tC"), 0.29: ("pA", "pB"), 0.455: ("pC", "pD"),
}
CHANNELS = [c for group in GROUPS.values() for c in group]
Msg = tuple[str, float, float | None]  # (channel, t, value)


def _deliver(slot0: int, n: int, rng: np.random.Generator, first: float | None = None,
             first_jitter: float = 0.0, delay: float = DELAY) -> list[tuple[float, str, float, float]]:
    """(arrival, channel, t, value) of n ticks from slot slot0 on: the sample of tick j is worth
    slot0 + j and belongs to slot slot0 + j; ``first``: the group whose tick-0 message arrives
    first (its jitter ``first_jitter``)."""
    msgs = []
    for j in range(n):
        for phase, group in GROUPS.items():
            t = (slot0 + j + phase) / FS + rng.uniform(-JITTER, JITTER)  # one instant per group
            if j == 0 and phase == first:
                t = (slot0 + phase) / FS + first_jitter
            for c in group:
                lead = j == 0 and phase == first and c == group[0]  # the run's first message
                msgs.append((-math.inf if lead else t + rng.uniform(0, delay), c, t, float(slot0 + j)))
    msgs.sort()
    return msgs


def _align(msgs: list[Msg], batch: int) -> tuple[list[AlignedSample], Aligner]:
    a = Aligner(CHANNELS)
    out: list[AlignedSample] = []
    if batch == 1:
        for c, t, v in msgs:
            out += a.push(c, t, v)
    else:
        for i in range(0, len(msgs), batch):
            cs, ts, vs = zip(*msgs[i:i + batch], strict=True)
            v = np.array([np.nan if x is None else x for x in vs])
            out += [s for _, done in a.push_columns(list(cs), np.array(ts), v) for s in done]
    return out + a.flush(), a


def _check_every_value_in_its_slot(out: list[AlignedSample], a: Aligner, slots: list[int]) -> None:
    assert [s.t for s in out] == [k / FS for k in slots]
    for s, k in zip(out, slots, strict=True):
        assert s.values == dict.fromkeys(CHANNELS, float(k))
    assert a.stats.late == 0 and not a.stats.missing and a.stats.duplicates == 0
    assert a.stats.samples == len(slots)


@pytest.mark.parametrize("batch", [1, 7, 500])
@pytest.mark.parametrize("seed", range(3))
def test_groups_at_phases_over_the_whole_period_arrive_in_any_order(seed: int, batch: int) -> None:
    rng = np.random.default_rng(seed)
    slot0 = 1767600000 * 40 + int(rng.integers(0, 1000))
    msgs = _deliver(slot0, 400, rng)
    out, a = _align([m[1:] for m in msgs], batch)
    _check_every_value_in_its_slot(out, a, list(range(slot0, slot0 + 400)))
    phases = {c: p for p, group in GROUPS.items() for c in group}
    for c, ms in a.phase_ms().items():  # health: each channel's phase, ms
        assert abs(ms - phases[c] * 1000 / FS) < 0.25


@pytest.mark.parametrize("first_jitter", [-JITTER, JITTER])
@pytest.mark.parametrize("first", list(GROUPS))
def test_the_first_message_of_a_run_may_come_from_any_group(first: float, first_jitter: float) -> None:
    """Two runs, each starting with a message of ``first`` (at its extreme jitter)."""
    rng = np.random.default_rng(int(first * 100) + 70)
    slot0 = 1767600000 * 40 + 3
    slot1 = slot0 + 200 + int((RUN_GAP + 5.3) * FS)
    msgs = _deliver(slot0, 200, rng, first, first_jitter) + _deliver(slot1, 200, rng, first, first_jitter)
    for batch in (1, 64):
        out, a = _align([m[1:] for m in msgs], batch)
        _check_every_value_in_its_slot(out, a, [*range(slot0, slot0 + 200), *range(slot1, slot1 + 200)])
        assert [s.new_run for s in out].count(True) == 2 and out[200].new_run


def _record(path: Path, rng: np.random.Generator) -> None:
    """Two runs of 30 s at clock phases over the whole period, with jitter, delivery delays
    (written in arrival order), duplicates, dropouts and a lost message now and then."""
    msgs = []
    for start in (1767600000 * 40 + 11, 1767600000 * 40 + 11 + 1200 + int(200 * FS)):
        for arrival, c, t, _ in _deliver(start, 1200, rng, delay=0.1):
            r = rng.uniform()
            if r < 0.01:
                continue  # lost
            v = None if r > 0.99 else (4000.0 if c in ("nA", "nB", "nC") else 0.0) + rng.normal()
            msgs.append((arrival, c, t, v))
            if r < 0.03:
                msgs.append((arrival + rng.uniform(0, 0.1), c, t, v))  # duplicate
    msgs.sort(key=lambda m: m[0])
    with RecordingWriter(path) as w:
        for arrival, c, t, v in msgs:
            w.write(sensor_key("b1", c), t, {"t": t, "v": v}, int(max(arrival, t) * 1e9))


def test_training_and_the_node_put_every_sample_in_the_same_slot(tmp_path: Path) -> None:
    path = tmp_path / "phases.mcap"
    _record(path, np.random.default_rng(5))
    from node.mcap import iter_messages
    channels, payloads = [], []
    for m in iter_messages(path):  # the node: messages in the order it received them
        channels.append(parse_sensor_key(m.topic)[1])
        payloads.append(m.payload)
    t, v, ok = decode_samples(payloads)
    assert ok.all()
    a = Aligner(CHANNELS)
    node = {s.t: s.values for _, done in a.push_columns(channels, t, v) for s in done}
    node.update({s.t: s.values for s in a.flush()})
    repeats = len(t) - len(set(zip(channels, t.tolist(), strict=True)))
    assert repeats > 0 and a.stats.late + a.stats.duplicates == repeats  # late: only repeats
    assert sum(a.stats.missing.values()) > 0  # the lost ones
    runs = read_runs(path, CHANNELS)
    assert len(runs) == 2 and sum(len(r.t) for r in runs) == 2400
    for r in runs:
        for i, ti in enumerate(r.t.tolist()):
            want = np.array([node[ti][c] for c in CHANNELS])
            np.testing.assert_array_equal(r.data[i], want)
        assert (r.t * FS == np.rint(r.t * FS)).all()  # on the absolute grid


def test_slot_and_slots_agree_and_a_slow_drift_moves_no_sample() -> None:
    """A clock that drifts by 2 ms/s (half a period in 6 s) and jitters 1 ms: every sample in
    its own slot, one after another; ``slots`` in pieces gives exactly ``slot``."""
    rng = np.random.default_rng(3)
    n = 2000
    t = 1767600000.0 + (np.arange(n) + 0.45) / FS + 2e-3 * np.arange(n) / FS + rng.uniform(-JITTER, JITTER, n)
    one, many = ChannelPhase(), ChannelPhase()
    k = [one.slot(x) for x in t.tolist()]
    cuts = np.sort(rng.choice(np.arange(1, n), 60, replace=False))
    k2 = np.concatenate([many.slots(part) for part in np.split(t, cuts)]).tolist()
    assert k == k2 and one.phi == many.phi and one.n == many.n
    assert (np.diff(k) == 1).all()
    assert one.phi is not None and one.phi > 0.5  # followed the drift through half a period


@st.composite
def _deliveries(draw):
    """A clean delivery (time order) and a messy one: every message delayed by up to ``delay``
    (within the wait) and some duplicated (as late), the same dropouts and nulls."""
    n_ch = draw(st.integers(1, 4))
    phases = draw(st.lists(st.floats(-0.45, 0.45), min_size=n_ch, max_size=n_ch))
    n = draw(st.integers(3, 120))
    seed = draw(st.integers(0, 2**32 - 1))
    delay = draw(st.floats(0.0, DELAY))
    p_dup = draw(st.floats(0.0, 1.0))
    p_lost = draw(st.sampled_from([0.0, 0.05, 0.3]))
    gap_at = draw(st.integers(0, n))  # a new run starts at this tick (n: none)
    rng = np.random.default_rng(seed)
    chans = [f"c{i}" for i in range(n_ch)]
    slot0 = 1767600000 * 40 + int(rng.integers(0, 100000))
    clean, messy = [], []
    for j in range(n):
        k = slot0 + j + (int(RUN_GAP * FS) + 37 if j >= gap_at else 0)
        for c, p in zip(chans, phases, strict=True):
            if rng.uniform() < p_lost:
                continue
            t = (k + p) / FS + rng.uniform(-JITTER, JITTER)
            v = None if rng.uniform() < 0.05 else float(rng.normal())
            clean.append((t, c, t, v))
            messy.append((t + rng.uniform(0, delay), c, t, v))
            if rng.uniform() < p_dup:
                messy.append((t + rng.uniform(0, delay), c, t, v))
    clean.sort(key=lambda m: m[0])
    messy.sort(key=lambda m: m[0])
    batch = draw(st.sampled_from([1, 5, 16, 64, 1000]))
    return chans, [m[1:] for m in clean], [m[1:] for m in messy], batch


def _aligned(chans: list[str], msgs: list[Msg], batch: int) -> list[tuple]:
    a = Aligner(chans)
    out: list[AlignedSample] = []
    for i in range(0, len(msgs), batch):
        cs, ts, vs = zip(*msgs[i:i + batch], strict=True)
        v = np.array([np.nan if x is None else x for x in vs])
        out += [s for _, done in a.push_columns(list(cs), np.array(ts), v) for s in done]
    out += a.flush()
    # bit for bit: the time, the run flag and every channel's value (NaN by its bits)
    return [(s.t, s.new_run, sorted((c, np.float64(x).tobytes()) for c, x in s.values.items())) for s in out]


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_deliveries())
def test_duplicates_and_reorderings_within_the_wait_change_nothing(case) -> None:
    chans, clean, messy, batch = case
    assert _aligned(chans, messy, batch) == _aligned(chans, clean, 1)


@pytest.mark.parametrize("seed", range(20))
def test_jitter_up_to_six_ms_keeps_every_sample_in_its_own_slot(seed: int) -> None:
    """docs/clock.md's bound: jitter up to +-6 ms (under a quarter period) at any offset, the
    first sample at its worst: consecutive samples go to consecutive slots."""
    rng = np.random.default_rng(seed)
    n, offset, j = 800, rng.uniform(-0.5, 0.5), 6e-3
    jitter = rng.uniform(-j, j, n)
    jitter[0] = j if seed % 2 else -j
    t = 1767600000.0 + (np.arange(n) + offset) / FS + jitter
    k = ChannelPhase().slots(t)
    assert (np.diff(k) == 1).all()
