"""The engine-history inputs (``node.runtime.history``): semantics, node == training, restart."""

from __future__ import annotations

import json
import math

import numpy as np
import orjson
import pytest

from node.contract.schedule import OperatingCondition, Schedule
from node.models.bundle import Bundle
from node.models.config import RuntimeConfig
from node.models.ocmodel import InputScaling, RegressionModel
from node.models.result import Calibration, OCResult
from node.runtime.core import NodeCore
from node.runtime.history import (
    HISTORY_CHANNELS,
    SHUTDOWN_CAP_H,
    EngineState,
    HistoryTracker,
    add_history,
    estimate_cooling,
)
from node.training.dataset import with_history
from node.training.runs import Run

FS = 40.0
SLOW = (100.0, 200.0, 30.0)


def _steps(h: HistoryTracker, t0: float, speeds: np.ndarray, slow=SLOW) -> np.ndarray:
    return np.array([h.step(t0 + k / FS, float(s), slow) for k, s in enumerate(speeds)])


def test_energy_integrates_speed_and_cools_while_standing():
    h = HistoryTracker(on_speed=500.0, cooling=1000.0)
    out = _steps(h, 0.0, np.full(2400, 6000.0))  # one minute at 6000 rpm
    assert out[-1, 0] == pytest.approx(6000.0)  # rpm min
    assert out[-1, 2] == SHUTDOWN_CAP_H and out[-1, 3] == pytest.approx(110.0)  # cold; mean of SLOW
    off = _steps(h, 60.0, np.full(40, 100.0))  # stopped: cools 1000 per hour from the last on sample
    assert off[-1, 2] == pytest.approx((60.0 + 39 / FS - (60.0 - 1 / FS)) / 3600.0)
    assert off[-1, 0] == pytest.approx(6000.0 - 1000.0 * off[-1, 2])
    # two hours later it lights off again: 6000 - 2000 carried, its own shutdown and warmth
    again = _steps(h, 60.0 + 7200.0, np.full(40, 3000.0), slow=(10.0, 20.0, 30.0))
    shut = (60.0 + 7200.0 - (60.0 - 1 / FS)) / 3600.0
    assert again[0, 2] == pytest.approx(shut)
    assert again[0, 0] == pytest.approx(6000.0 - 1000.0 * shut + 3000.0 / (FS * 60.0))
    assert again[-1, 3] == pytest.approx(20.0)
    # a day later nothing is carried (never below zero), and the shutdown is capped
    h2 = HistoryTracker(on_speed=500.0, cooling=1000.0, state=EngineState(0.0, 500.0))
    late = h2.step(3 * 86400.0, 3000.0, SLOW)
    assert late[0] == pytest.approx(3000.0 / (FS * 60.0)) and late[2] == SHUTDOWN_CAP_H


def test_rate_sums_one_second_means_and_a_short_dip_continues_the_run():
    h = HistoryTracker(on_speed=500.0, cooling=0.0)
    ramp = np.concatenate([np.full(400, 4000.0), np.linspace(4000.0, 6000.0, 800), np.full(400, 6000.0)])
    noisy = ramp + np.random.default_rng(0).normal(0.0, 20.0, ramp.size)
    out = _steps(h, 0.0, noisy)
    # noise adds under 5 % (a sum over single samples would add about 36000 rpm here)
    assert 2000.0 * 0.98 < out[-1, 1] < 2000.0 * 1.05
    # below the off level for 10 s, then on again: the same engine run (rate, shutdown kept)
    _steps(h, 40.0, np.full(400, 100.0))
    back = _steps(h, 50.0, np.full(40, 6000.0))
    assert out[-1, 1] <= back[-1, 1] < out[-1, 1] + 10.0  # carries on (one more 1-s step)
    assert back[-1, 2] == SHUTDOWN_CAP_H and h.light_offs == 1
    # a gap in the data while on (the engine stood unseen): a new engine run
    gap = _steps(h, 5000.0, np.full(40, 6000.0))
    assert h.light_offs == 2 and gap[-1, 1] == 0.0
    assert gap[0, 2] == pytest.approx((5000.0 - (50.0 + 39 / FS)) / 3600.0)


def test_unknown_speed_keeps_the_state_and_missing_temperatures_give_nan():
    h = HistoryTracker(on_speed=500.0, cooling=0.0)
    a = h.step(0.0, 6000.0, (math.nan, 1.0, 2.0))
    b = h.step(1 / FS, math.nan, SLOW)
    assert math.isnan(a[3]) and math.isnan(b[3])
    assert b[0] == a[0]  # NaN speed: neither on nor off, nothing added


def test_engine_state_round_trips_and_refuses_malformed():
    st = EngineState(1.5e9, 1234.5, 0.75, 88.0, 2000.0)
    assert EngineState.from_dict(json.loads(json.dumps(st.to_dict()))) == st
    for bad, word in (([], "object"), ({"energy": -1.0}, "energy"), ({"rate": "x"}, "rate"),
                      ({"thermal": math.inf}, "thermal"), ({"extra": 1}, "unknown"),
                      ({"last_on_t": True}, "last_on_t")):
        with pytest.raises(ValueError, match=word):
            EngineState.from_dict(bad)


SCHED = Schedule((OperatingCondition("A", 4000.0), OperatingCondition("B", 6000.0)))


def _run(t0: float, seed: int) -> Run:
    """A short run: off, light-off, 4000 rpm, 6000 rpm, 4000 rpm, off; slow temps; dropouts."""
    t = np.arange(0.0, 90.0, 1 / FS)
    nb = np.interp(t, [0, 5, 8, 25, 35, 55, 65, 82, 86], [100, 100, 4000, 4000, 6000, 6000, 4000, 4000, 100])
    rng = np.random.default_rng(seed)
    nb = nb + rng.normal(0.0, 5.0, t.size)
    yb = 2.0 + nb / 2000.0 + rng.normal(0.0, 0.05, t.size)
    slow = np.column_stack([50.0 + seed + t / 10, 80.0 + t / 20, 20.0 + 0 * t])
    slow = slow + rng.normal(0, 0.3, (t.size, 3))
    nb[[300, 301, 2000]] = np.nan
    slow[[0, 1, 500], 0] = np.nan
    data = np.column_stack([nb, yb, slow])
    return Run(t0 + t, data, ("nB", "yB", "tF", "tI", "tH"), "b", None)


def _bundle(channel: str, cooling: float) -> Bundle:
    # a Lasso model "yB = <channel>": the node's prediction is the derived input itself
    model = RegressionModel({"alpha": 1.0}, InputScaling(np.array([0.0]), np.array([1.0])),
                            coef=np.array([1.0]), intercept=0.0)
    ocs = [OCResult(n, model, [channel], {}, 8, 0.1, 0.1, Calibration(1.0, 1e9)) for n in ("A", "B")]
    return Bundle("lasso", "yB", SCHED, ocs, config=RuntimeConfig(history_cooling=cooling))


def _feed(core: NodeCore, run: Run) -> list[dict]:
    out = []
    for k in range(len(run.t)):
        for j, ch in enumerate(run.channels):
            v = run.data[k, j]
            payload = {"t": float(run.t[k]), "v": None if np.isnan(v) else float(v)}
            out += core.handle(f"testbed/b/sensor/{ch}", orjson.dumps(payload))
    return [m for key, m in out if key.endswith("/yB")]


def _predicted(mon: list[dict]) -> np.ndarray:
    return np.array([np.nan if m["predicted"] is None else m["predicted"] for m in mon])


@pytest.mark.parametrize("channel", HISTORY_CHANNELS)
def test_the_node_computes_the_very_history_training_saw(channel):
    runs = [_run(1.0e6, 1), _run(1.0e6 + 1800.0, 2)]  # 30 min apart: a new run, warm
    cooling = 5.0e4
    core = NodeCore(_bundle(channel, cooling))
    mon = _feed(core, runs[0]) + _feed(core, runs[1])
    for key, m in core.finish():
        if key.endswith("/yB"):
            mon.append(m)
    assert len(mon) == sum(len(r.t) for r in runs)
    derived = with_history(runs, SCHED, RuntimeConfig(history_cooling=cooling))
    offline = np.concatenate([r.column(channel) for r in derived])
    pred = _predicted(mon)
    has = np.isfinite(pred)
    assert has.sum() > 0.5 * pred.size
    np.testing.assert_array_equal(pred[has], offline[has])  # to the last bit
    assert core.beds["b"].aligner.stats.missing.get(channel, 0) == 0  # never awaited


def test_a_node_restarted_between_runs_computes_the_same_history():
    runs = [_run(2.0e6, 3), _run(2.0e6 + 900.0, 4)]
    bundle = _bundle("hist_energy", 1.0e4)
    through = NodeCore(bundle)
    _feed(through, runs[0])
    second_through = _feed(through, runs[1])
    first = NodeCore(bundle)
    _feed(first, runs[0])
    first.finish()
    saved = json.dumps({b: s.to_dict() for b, s in first.engine_states().items()})  # the state file
    restarted = NodeCore(bundle, {b: EngineState.from_dict(d) for b, d in json.loads(saved).items()})
    second_restarted = _feed(restarted, runs[1])
    a, b = _predicted(second_through), _predicted(second_restarted)
    assert np.isfinite(a).sum() > 0.5 * a.size
    np.testing.assert_array_equal(a, b)
    # without the state the second run starts cold: a different history
    cold = _predicted(_feed(NodeCore(bundle), runs[1]))
    assert not np.array_equal(cold[np.isfinite(cold)], a[np.isfinite(a)])


def test_cooling_is_recovered_from_the_warmth_at_light_off():
    """Runs whose warmth at light-off is proportional to the energy carried at a known rate."""
    true_rate = 3.0e3
    rng = np.random.default_rng(5)
    runs, t0, carried = [], 0.0, 0.0
    for i in range(8):
        gap = float(np.exp(rng.uniform(np.log(600.0), np.log(3 * 3600.0))))
        t0 += 100.0 + gap
        shut = gap / 3600.0 if i else SHUTDOWN_CAP_H
        carried = max(0.0, carried - true_rate * shut) if i else 0.0
        warm = 20.0 + carried / 1000.0
        t = np.arange(0.0, 60.0, 1 / FS)
        nb = np.where((t > 2) & (t < 58), 5000.0, 100.0)
        slow = np.full((t.size, 3), warm)
        runs.append(Run(t0 + t, np.column_stack([nb, slow]), ("nB", "tF", "tI", "tH"), "b", None))
        carried += 5000.0 * np.count_nonzero(nb >= 500.0) / (FS * 60.0)
        t0 += 60.0
    rate = estimate_cooling(runs, "nB", 500.0)
    assert rate is not None and true_rate / 1.3 < rate < true_rate * 1.3
    assert estimate_cooling(runs[:3], "nB", 500.0) is None  # 2 light-offs after a known run
    out = add_history(runs, "nB", 500.0, rate)
    assert all(set(HISTORY_CHANNELS) <= set(r.channels) for r in out)
