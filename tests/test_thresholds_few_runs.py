"""Residual thresholds from few training runs: the predictive level holds its chance where the
plug-in Gumbel fit is optimistic (a known law: runs' largest peaks drawn from a Gumbel)."""

from __future__ import annotations

import numpy as np
import pytest

from node.models.result import Calibration
from node.training.calibrate import (
    gumbel_quantile,
    pooled_thresholds,
    predictive_gumbel_level,
    threshold_levels,
)

MU, BETA, ALPHA = 4.0, 0.8, 0.04


def _exceed(level: float) -> float:
    """The true chance that a run's largest peak (Gumbel MU, BETA) exceeds ``level``."""
    return float(-np.expm1(-np.exp(-(level - MU) / BETA)))


def test_the_predictive_level_holds_its_chance_with_four_runs_where_the_plug_in_does_not():
    rng = np.random.default_rng(3)
    pred, plug = [], []
    for _ in range(80):
        m = rng.gumbel(MU, BETA, 4)
        pred.append(_exceed(predictive_gumbel_level(m, ALPHA)))
        plug.append(_exceed(gumbel_quantile(m, ALPHA)))
    assert 0.6 * ALPHA < np.mean(pred) < 1.5 * ALPHA  # calibrated over data sets of 4 runs
    assert np.mean(plug) > 2.0 * ALPHA  # the plug-in fit: new runs exceed it far more often


def test_more_runs_lower_the_level_toward_the_law_quantile():
    rng = np.random.default_rng(4)
    m = rng.gumbel(MU, BETA, 400)
    true = MU - BETA * np.log(-np.log(1 - ALPHA))
    assert predictive_gumbel_level(m[:4], ALPHA) > predictive_gumbel_level(m, ALPHA)
    assert predictive_gumbel_level(m, ALPHA) == pytest.approx(true, rel=0.08)
    with pytest.raises(ValueError):
        predictive_gumbel_level(m[:1], ALPHA)


def _calibs(n_runs: int, seed: int) -> dict[str, Calibration]:
    rng = np.random.default_rng(seed)
    out = {}
    for j in range(6):
        peaks = rng.gumbel(2.0, 0.5, n_runs)
        out[f"OC{j}"] = Calibration(1.0, float("inf"), peaks=tuple(peaks),
                                    segments=tuple((r, 100 * j, 1.0) for r in range(n_runs)))
    return out


def test_threshold_levels_by_rule():
    calibs = _calibs(6, 5)
    plug = threshold_levels(calibs, hours=1.0, segments=36, budget=0.25, undercoverage=4.0, rule="plug-in")
    # the plug-in rule is the pooled Gumbel fit over the segments, as before
    expect = pooled_thresholds({n: list(c.peaks) for n, c in calibs.items()}, 36.0, 0.25, 4.0)
    assert {n: c.threshold for n, c in plug.items()} == pytest.approx(expect)
    pred = threshold_levels(calibs, hours=1.0, segments=36, budget=0.25, undercoverage=1.0, rule="predictive")
    largest = [max(c.peaks[r] for c in calibs.values()) for r in range(6)]
    common = predictive_gumbel_level(largest, 0.25 * 1.0 / 6)
    assert {n: c.threshold for n, c in pred.items()} == pytest.approx(
        {n: max(common, 1.25 * max(c.peaks)) for n, c in calibs.items()})
