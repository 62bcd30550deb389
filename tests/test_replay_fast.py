"""The fast replay path gives exactly what the plain per-message path gives."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import orjson
import pytest

from node.contract import RUN_GAP
from node.contract.schedule import OperatingCondition, Schedule
from node.contract.slotting import ChannelPhase
from node.models.bundle import Bundle
from node.runtime.align import AlignedSample, Aligner
from node.runtime.clock import UNGUARDED
from node.runtime.core import NodeCore

pytestmark = pytest.mark.usefixtures("numpy_path_from_16_messages")

REC = Path(__file__).resolve().parents[1] / "recordings" / "engine1_fault.mcap"


class ReferenceAligner(Aligner):
    """The aligner's push written plainly (no shortcuts), to compare against: each channel's
    phase by ``ChannelPhase.slot``, one message at a time. It has no clock guard: the aligners
    compared with it are ``UNGUARDED`` (the guard's own tests are in test_clock.py)."""

    def push(self, channel, t, v):
        if channel not in self.channels:
            self.stats.unknown[channel] += 1
            return []
        out = []
        if self._last_t is not None and t - self._last_t >= RUN_GAP:
            out += self.flush()
            self._phase = {}
            self._started, self._new_run, self._emitted = False, True, False
        k = self._phase.setdefault(channel, ChannelPhase()).slot(t)
        if not self._started:
            self._started, self._next, self._newest = True, k, k
        self._last_t = t if self._last_t is None else max(self._last_t, t)
        if k < self._next:
            if self._emitted or self._newest - k >= self.wait_slots:
                self.stats.late += 1
                self.stats.late_by_channel[channel] += 1
                return out
            self._next = k
        slot = self._open.setdefault(k, {})
        if channel in slot:
            self.stats.duplicates += 1
            return out
        slot[channel] = float("nan") if v is None else float(v)
        self._newest = max(self._newest, k)
        while True:
            head = self._open.get(self._next)
            complete = self._emitted and head is not None and len(head) == len(self.channels)
            expired = self._newest - self._next >= self.wait_slots
            if not (complete or expired):
                break
            out.append(self._emit(self._next))
        return out


def _stream(seed: int, n: int = 3000) -> list[tuple[str, float, float | None]]:
    """Jitter, reordering, dropouts, duplicates, lost and late messages, unknown channels, gaps."""
    rng = np.random.default_rng(seed)
    chans = ["a", "b", "c", "x"]
    msgs = []
    t0 = 1000.0 - rng.uniform(0, 0.1)
    phases = rng.uniform(-0.45, 0.45, len(chans)).tolist()
    offset = dict(zip(chans, phases, strict=True))  # each channel's clock phase, periods
    for k in range(n):
        if k == n // 2:
            t0 += RUN_GAP + rng.uniform(0, 5)
        for c in chans:
            r = rng.uniform()
            if r < 0.03:
                continue  # lost
            t = t0 + (k + offset[c]) / 40 + rng.normal(0, 0.004)
            v = None if r > 0.98 else float(rng.normal())
            delay = rng.exponential(0.03) if r < 0.9 else rng.uniform(0, 0.6)  # some late
            msgs.append((delay + t, c, t, v))
            if r < 0.05:
                msgs.append((delay + t + 0.01, c, t, v))  # duplicate
    msgs.sort(key=lambda m: m[0])
    return [(c, t, v) for _, c, t, v in msgs]


def _key(s: AlignedSample):
    return (s.t, s.new_run, sorted((c, None if math.isnan(v) else v) for c, v in s.values.items()))


@pytest.mark.parametrize("seed", range(6))
def test_aligner_matches_the_reference(seed: int) -> None:
    fast, ref = Aligner(["a", "b", "c"], clock=UNGUARDED), ReferenceAligner(["a", "b", "c"])
    got, want = [], []
    for i, (c, t, v) in enumerate(_stream(seed)):
        a, b = fast.push(c, t, v), ref.push(c, t, v)
        got += [(i, _key(s)) for s in a]
        want += [(i, _key(s)) for s in b]
    got += [(-1, _key(s)) for s in fast.flush()]
    want += [(-1, _key(s)) for s in ref.flush()]
    assert got == want and len(got) > 1000
    assert fast.stats == ref.stats and fast.stats.late > 0 and fast.stats.duplicates > 0
    assert fast.phase_ms() == ref.phase_ms() and len(fast.phase_ms()) == 3


def _key_in_order(s: AlignedSample):
    return (s.t, s.new_run, [(c, None if math.isnan(v) else v) for c, v in s.values.items()])


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("size", [1, 5, 40, 333, 2000])
def test_aligner_push_columns_matches_the_reference(seed: int, size: int) -> None:
    fast, ref = Aligner(["a", "b", "c"], clock=UNGUARDED), ReferenceAligner(["a", "b", "c"])
    msgs = _stream(seed)
    want = [(i, _key_in_order(s)) for i, (c, t, v) in enumerate(msgs) for s in ref.push(c, t, v)]
    got = []
    for a in range(0, len(msgs), size):
        channels, ts, vs = (list(x) for x in zip(*msgs[a:a + size], strict=True))
        t, v = np.array(ts), np.array([np.nan if x is None else x for x in vs])
        got += [(a + i, _key_in_order(s)) for i, out in fast.push_columns(channels, t, v) for s in out]
    assert got == want and len(got) > 1000
    assert [_key_in_order(s) for s in fast.flush()] == [_key_in_order(s) for s in ref.flush()]
    assert fast.stats == ref.stats and fast.stats.late > 0 and fast.stats.duplicates > 0
    assert fast.phase_ms() == ref.phase_ms() and len(fast.phase_ms()) == 3


def _one_and_many(bundle: Bundle, msgs: list[tuple[str, bytes]], batch: int
                  ) -> tuple[NodeCore, NodeCore, list, list]:
    """Two cores fed the same messages, one by ``handle``, one by ``handle_batch`` in batches;
    with what each returned as ``(message index, outputs)``."""
    one, many = NodeCore(bundle), NodeCore(bundle)
    want = [(i, out) for i, (k, p) in enumerate(msgs) if (out := one.handle(k, p))]
    got = []
    for a in range(0, len(msgs), batch):
        keys, payloads = zip(*msgs[a:a + batch], strict=True)
        got += [(a + i, out) for i, out in many.handle_batch(keys, payloads).done]
    return one, many, want, got


def _same_counts(one: NodeCore, many: NodeCore) -> None:
    assert (many.malformed, many.foreign, many.published) == (one.malformed, one.foreign, one.published)
    assert list(many.beds) == list(one.beds)
    for b in many.beds:
        x, y = many.beds[b], one.beds[b]
        assert (x.received, x.malformed, x.alarm_samples, x.latest_t) == (y.received, y.malformed,
                                                                          y.alarm_samples, y.latest_t)
        assert x.aligner.stats == y.aligner.stats


def test_handle_batch_equals_handle_one_by_one() -> None:
    sched = Schedule((OperatingCondition("A", 4000.0),))
    bundle = Bundle("wdmd", "yB", sched, [])
    msgs: list[tuple[str, bytes]] = []
    for i, (c, t, v) in enumerate(_stream(7, 1500)):
        key = f"testbed/{'b1' if i % 5 else 'b2'}/sensor/{ {'a': 'nB', 'b': 'yB'}.get(c, c)}"
        payload = orjson.dumps({"t": t, "v": v})
        if i % 97 == 0:
            payload = [b"{", b"[1]", b'{"t": "x", "v": 1}', b'{"t": 1.0}', b'{"t": 1e999, "v": 1}',
                       b'{"t": 1000, "v": 2}', b'{"t": 1000.5, "v": true}', b"\xff",
                       b'{"t": 123456789012345678901234567890123456789012345678901234567890'
                       b'1234567890123456789012345678901234567890123456789012345678901234567890'
                       b'1234567890123456789012345678901234567890123456789012345678901234567890'
                       b'1234567890123456789012345678901234567890123456789012345678901234567890'
                       b'12345678901234567890123456789012345678901234567890, "v": 1}'][(i // 97) % 9]
        if i % 211 == 0:
            key = "some/other/key"
        msgs.append((key, payload))
    one, many, want, got = _one_and_many(bundle, msgs, 256)
    assert orjson.dumps(got) == orjson.dumps(want) and len(got) > 100
    _same_counts(one, many)
    assert many.malformed > 5 and many.foreign > 3
    assert set(many.beds) == {"b1", "b2"}
    assert sum(b.received for b in many.beds.values()) + many.foreign == len(msgs)


def test_handle_batch_of_clean_single_bed_batches_equals_handle() -> None:
    """The common batch (one bed, every payload well formed) is aligned at once; a batch with a
    malformed payload or an integer time is decoded message by message, aligned at once still."""
    sched = Schedule((OperatingCondition("A", 4000.0),))
    bundle = Bundle("wdmd", "yB", sched, [])
    names = {"a": "nB", "b": "yB", "c": "tA", "x": "zz"}  # tA and zz: not needed by the model
    msgs = [(f"testbed/b1/sensor/{names[c]}", orjson.dumps({"t": t, "v": v}))
            for c, t, v in _stream(11, 3000)]
    msgs[5000] = (msgs[5000][0], b'{"t": 1000, "v": 1.0}')
    msgs[7000] = (msgs[7000][0], b"{")
    one, many, want, got = _one_and_many(bundle, msgs, 500)
    assert orjson.dumps(got) == orjson.dumps(want) and len(got) > 800  # messages that completed some
    _same_counts(one, many)
    assert many.malformed == 1
    a = many.beds["b1"].aligner.stats
    assert a.late > 0 and a.duplicates > 0 and a.unknown["zz"] > 0


def test_batches_of_any_size_with_receive_times_give_the_same_outputs() -> None:
    """Three beds interleaved, with receive times and silences beyond the alignment wait: batches
    of 1 and 7 messages (each bed's few messages aligned as Python lists, ``Aligner.push_list``)
    and of 1000 (a bed's many at once with numpy) give the same outputs, counts and receipts."""
    sched = Schedule((OperatingCondition("A", 4000.0),))
    bundle = Bundle("wdmd", "yB", sched, [])
    names = {"a": "nB", "b": "yB", "c": "tA", "x": "zz"}
    msgs, recv = [], []
    for j, bed in enumerate(("b1", "b2", "b3")):
        for i, (c, t, v) in enumerate(_stream(20 + j, 1200)):
            msgs.append((i, j, f"testbed/{bed}/sensor/{names[c]}", orjson.dumps({"t": t, "v": v})))
    msgs.sort(key=lambda m: (m[0], m[1]))  # the beds' messages interleaved
    keys, payloads = [m[2] for m in msgs], [m[3] for m in msgs]
    clock = 0
    for i in range(len(msgs)):  # 1 ms apart, with a silence of 1 s every 2000 messages
        clock += 1_000_000 if i % 2000 else 1_000_000_000
        recv.append(clock)
    got = {}
    for size in (1, 7, 1000):
        core = NodeCore(bundle)
        out = [(a + i, o) for a in range(0, len(msgs), size)
               for i, o in core.handle_batch(keys[a:a + size], payloads[a:a + size], recv[a:a + size]).done]
        got[size] = (orjson.dumps(out), orjson.dumps(core.finish()),
                     [(b.received, b.last_recv, b.latest_t, b.aligner.stats) for b in core.beds.values()])
    assert got[1] == got[7] == got[1000]
    assert len(got[1][0]) > 100_000 and got[1][2][0][0] > 3000


@pytest.fixture(scope="module")
def model(tmp_path_factory) -> Path:
    from conftest import small_campaign
    return small_campaign(tmp_path_factory.mktemp("fastreplay"), 5)


def test_worker_process_gives_the_same_bytes(model: Path) -> None:
    from node.cli.replay import replay_offline
    from node.mcap import iter_messages
    a, b = model / "w0.mcap", model / "w1.mcap"
    s0 = replay_offline(str(model / "test.mcap"), str(model / "m"), str(a), quiet=True, workers=0)
    s1 = replay_offline(str(model / "test.mcap"), str(model / "m"), str(b), quiet=True, workers=1)
    assert (s0["workers"], s1["workers"]) == (0, 1)
    assert a.read_bytes() == b.read_bytes()
    for k in ("inputs", "published", "malformed", "beds", "alarm_episodes"):
        assert s0[k] == s1[k], k
    inputs = [(m.topic, m.log_time, m.publish_time, m.payload) for m in iter_messages(model / "test.mcap")]
    out = list(iter_messages(a))
    assert [(m.topic, m.log_time, m.publish_time, m.payload) for m in out if "/sensor/" in m.topic] == inputs
    mon = [m for m in out if m.topic.endswith("/monitor/yB")]
    assert len(mon) > 100 and s0["published"] == sum(1 for m in out if "/monitor/" in m.topic)
    # each monitor message right after the input that completed it, published at its log_time
    # (those flushed at the end of the stream: at their own log_time)
    last_in, after_input = None, 0
    for m in out:
        if "/sensor/" in m.topic:
            last_in = m
        else:
            assert last_in is not None
            assert m.publish_time in (last_in.log_time, m.log_time)
            after_input += m.publish_time == last_in.log_time
    assert after_input > 0.9 * len(mon)
    # replaying the node's own recording recomputes the monitor messages: same file again
    c = model / "again.mcap"
    replay_offline(str(a), str(model / "m"), str(c), quiet=True)
    assert c.read_bytes() == a.read_bytes()


def test_a_failing_worker_ends_the_replay_with_one_line(model: Path, monkeypatch) -> None:
    import replay.offline as off
    from node.contract.errors import OrdervibError
    from node.models.bundle import load_bundle

    def boom(self, *batch):
        raise ValueError("bad model")

    monkeypatch.setattr(off._Logic, "batch", boom)  # inherited by the forked worker
    with pytest.raises(OrdervibError, match="replay worker: ValueError: bad model") as err:
        off.replay(str(model / "test.mcap"), load_bundle(model / "m"), str(model / "x.mcap"), workers=1)
    assert "\n" not in str(err.value)
