"""The alarm rules (node.runtime.alarms), their calibration (node.training.calibrate), alarm episodes."""

from __future__ import annotations

import math

import numpy as np
import orjson
import pytest
from scipy import stats

from node.runtime.alarms import EpisodeLog, FlatlineCheck
from node.training.calibrate import (
    THRESHOLD_MARGIN,
    flatline_limit,
    gumbel_quantile,
    longest_repeat,
    pooled_thresholds,
)


def test_gumbel_quantile_matches_scipy_for_moment_fit():
    rng = np.random.default_rng(0)
    x = stats.gumbel_r.rvs(loc=2.0, scale=0.5, size=5000, random_state=rng)
    beta = np.std(x) * np.sqrt(6) / np.pi
    mu = np.mean(x) - np.euler_gamma * beta
    for p in (0.1, 0.01, 0.001):
        assert gumbel_quantile(x, p) == pytest.approx(stats.gumbel_r.ppf(1 - p, mu, beta), rel=1e-9)
    # and the fit recovers the law it was drawn from
    assert gumbel_quantile(x, 0.01) == pytest.approx(stats.gumbel_r.ppf(0.99, 2.0, 0.5), rel=0.03)


def test_pooled_thresholds_follow_the_budget_and_the_margin():
    rng = np.random.default_rng(1)
    peaks = {f"OC{i}": list(stats.gumbel_r.rvs(1.5, 0.3, size=8, random_state=rng)) for i in range(12)}
    peaks["OC99"] = [5.0, 1.0, 1.2]  # one OC with a wild CV peak keeps its own margin
    lo = pooled_thresholds(peaks, segments_per_hour=80.0, budget=2.0, undercoverage=1.0)
    hi = pooled_thresholds(peaks, segments_per_hour=80.0, budget=0.2, undercoverage=1.0)
    assert all(hi[k] >= lo[k] for k in peaks)
    assert hi["OC0"] > lo["OC0"]
    assert lo["OC99"] == pytest.approx(THRESHOLD_MARGIN * 5.0)
    for k, v in peaks.items():
        assert hi[k] >= THRESHOLD_MARGIN * max(v) - 1e-12
    # the common level is the pooled Gumbel quantile at p = budget / segments per hour
    every = [v for k, vals in peaks.items() for v in vals]
    expect = max(gumbel_quantile(every, 0.2 / 80.0), THRESHOLD_MARGIN * max(peaks["OC0"]))
    assert hi["OC0"] == pytest.approx(expect)
    # the under-coverage factor divides the chance: 0.8 / 80 / 4 is 0.2 / 80
    assert pooled_thresholds(peaks, 80.0, budget=0.8, undercoverage=4.0) == pytest.approx(hi)
    assert pooled_thresholds({}, 80.0) == {}


def test_longest_repeat_ignores_dropouts_and_restarts_when_off():
    y = np.array([1.0, 1.0, np.nan, 1.0, 2.0, 2.0, 2.0, 2.0, 2.0, 3.0])
    on = np.ones(y.size, dtype=bool)
    assert longest_repeat(y, on) == 4  # 2.0 five times in a row
    on[6] = False  # switching off in the middle breaks the run
    assert longest_repeat(y, on) == 2
    assert longest_repeat(np.array([]), np.array([], dtype=bool)) == 0


def test_flatline_limit_has_a_floor_and_scales_with_training():
    assert flatline_limit(0, 40.0) == 80
    assert flatline_limit(7, 40.0) == 80
    assert flatline_limit(50, 40.0) == 200


def test_flatline_check_flags_a_stuck_value_only_while_running():
    chk = FlatlineCheck(5)
    seq = [0.5, 0.5, 0.5, math.nan, 0.5, 0.5, 0.5, 0.6]
    flags = [chk.step(v, True) for v in seq]
    assert flags == [False, False, False, False, False, False, True, False]  # 6th repeat
    chk.reset()
    assert not any(chk.step(0.0, False) for _ in range(20))  # engine off: zeros are normal


def test_episode_log_merges_close_alarm_samples():
    log = EpisodeLog(gap_s=1.0)
    for t, flag in [(0.0, "ok"), (1.0, "alarm"), (1.5, "alarm"), (2.4, "alarm"), (5.0, "alarm"), (5.1, "ok")]:
        log.add("testbed/b/monitor/yB", {"t": t, "flag": flag, "reason": "residual"})
    log.add("testbed/c/monitor/yB", {"t": 1.2, "flag": "alarm", "reason": "flatline"})
    log.add("testbed/b/monitor/yB", {"t": 5.2, "flag": "alarm", "reason": "flatline"})  # another rule
    assert [(e["key"][8], e["start"], e["end"], e["reason"]) for e in log.episodes] == [
        ("b", 1.0, 2.4, "residual"), ("b", 5.0, 5.0, "residual"), ("c", 1.2, 1.2, "flatline"),
        ("b", 5.2, 5.2, "flatline")]


def test_pipeline_flags_a_stuck_target_without_a_model():
    from node.contract.schedule import OperatingCondition, Schedule
    from node.models.bundle import Bundle
    from node.runtime.core import NodeCore

    sched = Schedule((OperatingCondition("A", 4000.0),))
    core = NodeCore(Bundle("wdmd", "yB", sched, [], checks={"flatline_samples": 80}))
    rng = np.random.default_rng(3)
    out = []
    for k in range(400):
        y = round(2.0 + 0.1 * rng.standard_normal(), 2) if k < 200 else 2.22  # stuck from k = 200
        for ch, v in (("nB", 4000.0), ("yB", y)):
            out += core.handle(f"testbed/b/sensor/{ch}", orjson.dumps({"t": 10.0 + k / 40, "v": v}))
    mon = [m for k, m in out if k.endswith("/yB")]
    flags = [m["flag"] for m in mon]
    first = flags.index("alarm")
    assert 200 + 79 <= first <= 200 + 81  # the limit counts repeats after the first stuck value
    assert all(f == "alarm" for f in flags[first:])
    assert mon[first]["reason"] == "flatline"
    assert all(f == "no-model" for f in flags[:first])


def test_step_check_finds_a_step_in_noise_and_ignores_a_slow_trend():
    from node.runtime.alarms import StepCheck

    rng = np.random.default_rng(5)
    k = np.arange(1200)
    noise = 0.2 * rng.standard_normal(k.size)
    chk = StepCheck(threshold=8.0)
    trend = 5.0 + 0.002 * k + noise  # 0.08 mm/s per second: slow, like a thermal drift
    z_trend = [chk.step(v, True) for v in trend]
    assert max(z_trend) < 4.0 and not chk.flagged
    chk.reset()
    step = 5.0 + noise + 3.0 * (k >= 600)  # 15 noise sd at once
    flags, zs = [], []
    for v in step:
        zs.append(chk.step(v, True))
        flags.append(chk.flagged)
    first = flags.index(True)
    assert 600 <= first <= 600 + 40  # within a second
    assert all(flags[first:])  # held to the end of the plateau
    assert max(zs[:600]) < 4.0
    # outside a plateau nothing is computed, and a new plateau starts afresh
    assert chk.step(100.0, False) == 0.0 and not chk.flagged
    assert chk.step(5.0, True) == 0.0


def test_calibrated_step_threshold_is_above_every_normal_plateau():
    from node.contract.schedule import OperatingCondition, Schedule
    from node.training.calibrate import calibrate_checks

    class R:  # two runs: ramp to a plateau at 4000 rpm, hold, noisy target
        def __init__(self, seed):
            rng = np.random.default_rng(seed)
            speed = np.r_[np.linspace(0, 4000, 400), np.full(4000, 4000.0), np.linspace(4000, 0, 400)]
            y = 2 + 0.001 * speed + 0.1 * rng.standard_normal(speed.size)
            self.cols = {"nB": speed, "yB": np.round(y, 2)}

        def column(self, name):
            return self.cols[name]

    sched = Schedule((OperatingCondition("A", 4000.0),))
    checks = calibrate_checks([R(1), R(2), R(3)], sched, "yB")
    assert checks["step_peaks_in_training"]["n"] == 3
    assert checks["step_threshold"] >= THRESHOLD_MARGIN * checks["step_peaks_in_training"]["max"]
    assert checks["flatline_samples"] == 80


def test_step_check_leaves_the_settling_start_of_a_plateau_out():
    from node.runtime.alarms import StepCheck

    chk = StepCheck(threshold=8.0)
    y = np.r_[np.linspace(0.0, 5.0, chk.n_settle), np.full(400, 5.0)]  # settles, then flat
    y = y + 0.05 * np.random.default_rng(2).standard_normal(y.size)
    z = [chk.step(v, True) for v in y]
    assert max(z) < 4.0 and not chk.flagged
    assert all(v == 0.0 for v in z[: chk.n_settle + chk.n_short + chk.n_long - 1])


def test_run_scale_grows_only_for_an_unusual_run():
    from node.runtime.alarms import RunScale

    typical = RunScale(prior=3.0)
    for m in (1.0, 0.5, 1.2, 0.8):
        typical.add(m)
    assert typical.factor == 1.0  # never below 1: never more sensitive than calibrated
    odd = RunScale(prior=3.0)
    odd.add(9.0)
    assert odd.factor == pytest.approx(math.sqrt((3 + 9) / 4))
    odd.add(9.0)
    assert odd.factor == pytest.approx(math.sqrt((3 + 18) / 5))
    odd.add(float("nan"))  # an OC without residuals changes nothing
    assert odd.count == 2


def test_cv_peaks_are_scaled_by_the_run_so_far_in_time_order():
    from node.models.result import Calibration
    from node.runtime.alarms import RunScale
    from node.training.calibrate import run_scaled_peaks

    a = Calibration(1.0, 0.0, peaks=[2.0, 3.0], segments=[(0, 100, 9.0), (1, 100, 1.0)])
    b = Calibration(1.0, 0.0, peaks=[4.0, 5.0], segments=[(0, 500, 4.0), (1, 500, 1.0)])
    out = run_scaled_peaks({"A": a, "B": b})
    assert out["A"] == [2.0, 3.0]  # first OC of each run: nothing seen yet
    s = RunScale()
    s.add(9.0)
    assert out["B"] == [pytest.approx(4.0 / s.factor), 5.0]  # run 0 strayed in A, run 1 did not
    assert s.factor > 1.0


def test_residual_alarm_needs_persistence_to_rise_and_an_off_delay_to_clear():
    from node.contract.schedule import OperatingCondition, Schedule
    from node.models.bundle import Bundle
    from node.models.config import RuntimeConfig
    from node.models.ocmodel import InputScaling, RegressionModel
    from node.models.result import Calibration, OCResult
    from node.runtime.core import NodeCore

    # an OC whose model predicts yB = 2 whatever nB does (Lasso with a zero weight)
    model = RegressionModel({"alpha": 1.0}, InputScaling(np.array([4000.0]), np.array([1.0])),
                            coef=np.array([0.0]), intercept=2.0)
    calib = Calibration(sigma=0.1, threshold=3.0, ewma_alpha=1.0, persist=40)  # no smoothing: score = z
    sched = Schedule((OperatingCondition("A", 4000.0),))
    res = OCResult("A", model, ["nB"], {}, 8, 0.1, 0.1, calib)
    core = NodeCore(Bundle("lasso", "yB", sched, [res]))
    # 10 s normal, 2 s at +5 sigma, 3 s normal, 1 s at +5 sigma, 10 s normal
    level = [2.0] * 400 + [2.5] * 80 + [2.0] * 120 + [2.5] * 40 + [2.0] * 400
    out = []
    for k, y in enumerate(level):
        for ch, v in (("nB", 4000.0), ("yB", y)):
            out += core.handle(f"testbed/b/sensor/{ch}", orjson.dumps({"t": 10.0 + k / 40, "v": v}))
    mon = [m for key, m in out if key.endswith("/yB")]
    assert len(mon) == len(level) and mon[400]["measured"] == 2.5 and mon[399]["measured"] == 2.0
    assert mon[399]["predicted"] == 2.0  # the model is active well before
    flags = ["alarm" if m["flag"] == "alarm" else "ok" for m in mon]
    off = 400  # the first sample at +5 sigma
    assert "alarm" not in flags[: off + 39]  # persistence: 1 s beyond before it rises
    first = flags.index("alarm")
    assert off + 38 <= first <= off + 40
    assert all(f == "alarm" for f in flags[first: off + 80 + 120 + 40])  # the 3 s dip does not clear it
    clear = off + 240 + int(RuntimeConfig().residual_clear_s * 40)
    assert flags[clear + 2] == "ok" and flags[clear - 2] == "alarm"


def test_calibration_steps_the_residual_rule_of_the_node():
    """Peak scores and alarm masks come from ``ResidualCheck``: the EWMA of z to the last bit,
    the mask a run of ``persist`` samples beyond the threshold (no off-delay per segment)."""
    from scipy.signal import lfilter

    from node.training.calibrate import alarm_mask, peak_score
    from node.training.train import Calibration, OCResult

    rng = np.random.default_rng(3)
    r = rng.standard_normal(2000) * 0.7 + np.r_[np.zeros(1000), np.full(1000, 1.5)]
    sigma, alpha = 0.8, 2.0 / 81.0
    ewma = lfilter([alpha], [1.0, alpha - 1.0], r / sigma)
    assert peak_score(r, sigma, alpha) == float(np.max(np.abs(ewma)))
    res = OCResult("A", None, [], {}, 8, 0.1, 0.1, Calibration(sigma, 1.2, alpha, persist=40))
    beyond = np.abs(ewma) > 1.2
    run = np.zeros(r.size, dtype=int)
    for k in range(r.size):
        run[k] = run[k - 1] + 1 if beyond[k] and k else int(beyond[k])
    mask = alarm_mask(r, res)
    np.testing.assert_array_equal(mask, run >= 40)
    assert 0 < mask.sum() < r.size
