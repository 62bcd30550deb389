"""harness.fault_effect: a fault's effect measured against its fault-free twin run."""

from __future__ import annotations

import numpy as np
import pytest

from harness.fault_effect import SMOOTH_S, fault_effect
from node.contract import FS, SENSOR_CHANNELS
from node.training.runs import Run
from simulator.campaign import DRIFT_RATE, simulate_campaign


def _runs(fault: str | None, size: float = 1.0) -> tuple[Run, dict | None]:
    r = simulate_campaign(3, 1, fault=fault, plateau_scale=0.05, fault_size=size).runs[-1]
    return Run(r.t, r.data, SENSOR_CHANNELS, "bed", None), r.truth.get("fault")


def test_drift_effect_is_its_rate_times_the_window() -> None:
    twin, _ = _runs(None)
    run, fault = _runs("drift", 2.0)
    onset = fault["onset"]
    window = min(60.0, float(run.t[-1] - onset) - 1.0)
    band = np.full(len(run.t), 0.1)
    eff = fault_effect(run, twin, "yB", onset, band, window)
    grown = 2.0 * DRIFT_RATE * window
    assert grown > 0.2
    # values are rounded to 0.01 mm/s; the last samples of the window may be dropouts
    assert eff.peak == pytest.approx(grown, abs=0.02)
    # the largest 2 s mean ends at the window's end: the ramp's mean over its last 2 s
    assert eff.ratio == pytest.approx((grown - DRIFT_RATE * 2.0 * SMOOTH_S / 2) / 0.1, abs=0.25)


def test_band_scales_the_ratio_and_nan_band_is_skipped() -> None:
    twin, _ = _runs(None)
    run, fault = _runs("drift")
    narrow = fault_effect(run, twin, "yB", fault["onset"], np.full(len(run.t), 0.05), 30.0)
    wide = fault_effect(run, twin, "yB", fault["onset"], np.full(len(run.t), 0.5), 30.0)
    assert narrow.peak == wide.peak
    assert narrow.ratio == pytest.approx(10.0 * wide.ratio, rel=1e-9)
    none = fault_effect(run, twin, "yB", fault["onset"], np.full(len(run.t), np.nan), 30.0)
    assert none.peak == narrow.peak and np.isnan(none.ratio)


def test_runs_that_are_not_twins_are_refused() -> None:
    twin, _ = _runs(None)
    run, fault = _runs("drift")
    other = Run(twin.t, twin.data.copy(), twin.channels, "bed", None)
    other.data[0, SENSOR_CHANNELS.index("yB")] += 1.0
    with pytest.raises(ValueError, match="before the onset"):
        fault_effect(run, other, "yB", fault["onset"], np.ones(len(run.t)))
    shifted = Run(twin.t + 0.025, twin.data, twin.channels, "bed", None)
    with pytest.raises(ValueError, match="time stamps"):
        fault_effect(run, shifted, "yB", fault["onset"], np.ones(len(run.t)))


def test_a_sample_stamped_within_one_period_before_the_onset_may_differ() -> None:
    """A channel's clock phase can stamp the first faulted sample just before the onset."""
    twin, _ = _runs(None)
    run, fault = _runs("drift")
    onset, yb = fault["onset"], SENSOR_CHANNELS.index("yB")
    first = int(np.argmax(run.t >= onset))  # the first sample stamped at or after the onset
    assert onset - 1.0 / FS < run.t[first - 1] < onset and run.t[first - 2] < onset - 1.0 / FS
    for k, accepted in ((first - 1, True), (first - 2, False)):
        moved = Run(run.t, run.data.copy(), run.channels, "bed", None)
        moved.data[k, yb] += 1.0
        if accepted:
            assert fault_effect(moved, twin, "yB", onset, np.ones(len(run.t))).peak > 0.0
        else:
            with pytest.raises(ValueError, match="before the onset"):
                fault_effect(moved, twin, "yB", onset, np.ones(len(run.t)))
