"""The order tracker's lag estimated from the tracked 1x vector through resonances."""

from __future__ import annotations

import numpy as np
import pytest

from node.runtime.tracker_lag import LagFit, combine, ramp_lags
from node.runtime.transient import lagged


def _ramp(tau: float, rate: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A ramp through a mode at 6000 rpm (zeta 0.04) at ``rate`` rpm/s, its complex 1x vector
    through a first-order tracker lag of ``tau`` s, with 2 % + 0.03 mm/s noise."""
    rng = np.random.default_rng(seed)
    lo, hi = (4000.0, 8000.0) if rate > 0 else (8000.0, 4000.0)
    n = int(abs(hi - lo) / abs(rate) * 40)
    speed = np.concatenate([np.full(200, lo), np.linspace(lo, hi, n), np.full(400, hi)])
    r = speed / 6000.0
    v = speed * r**2 / (1 - r**2 + 0.08j * r) * 1e-3
    y = lagged(v.real, tau) + 1j * lagged(v.imag, tau)
    y = y * (1 + 0.02 * rng.standard_normal(len(y))) + 0.03 * rng.standard_normal(len(y))
    return speed + rng.standard_normal(len(speed)), np.abs(y), -np.degrees(np.angle(y))


@pytest.mark.parametrize(("tau", "rate"), [(0.5, 120.0), (1.0, -100.0), (2.0, 80.0)])
def test_the_lag_of_one_crossing_is_found(tau: float, rate: float) -> None:
    fits = ramp_lags(*_ramp(tau, rate, 1))
    assert len(fits) == 1 and fits[0].identified
    assert fits[0].tau == pytest.approx(tau, rel=0.15)
    est = combine(fits)
    assert est is not None and est.tau == pytest.approx(tau, rel=0.15)


def test_combine_is_robust_to_an_outlier_and_needs_an_identified_fit() -> None:
    fits = [LagFit(t, 0.05, (5000.0,), "up", 400) for t in (0.9, 1.0, 1.1)]
    est = combine([*fits, LagFit(0.3, 1e-4, (5000.0,), "down", 400)])  # over-confident, wrong
    assert est is not None and est.tau == pytest.approx(1.0, abs=0.11)
    assert combine([LagFit(10.0, 5.0, (5000.0,), "up", 400)]) is None
