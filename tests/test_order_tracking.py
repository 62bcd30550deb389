"""Order tracking (COT, joint VKF and TVDFT) on the dissertation's Fig. 5.1 synthetic signal.

Orders 1, 2, 6 and 10 with amplitudes 1.0, 0.5, 0.3, 0.2, fixed phases and a little
white noise (std 0.01), at constant speed and over a 600 -> 3000 rpm linear run-up
in 10 s, fs = 4096 Hz (order 10 peaks at 500 Hz, a quarter of the Nyquist rate).
The trackers return the contract's phase: the lag from the shaft's angle zero (the first
sample, here the once-per-rev mark), degrees in [-180, 180).
"""

from __future__ import annotations

import numpy as np
import pytest

from node.contract.vector import order_vectors, wrap_degrees
from node.order_tracking import (
    cot_orders,
    rpm_from_tacho,
    tacho_pulse_times,
    tvdft_orders,
    vkf_orders,
    weighting_factor,
)

FS = 4096.0
DURATION = 10.0
ORDERS = np.array([1.0, 2.0, 6.0, 10.0])
AMPS = np.array([1.0, 0.5, 0.3, 0.2])
PHASES = np.array([0.3, -1.1, 2.0, 0.7])  # rad, leads: the signal is a cos(p theta + PHASES)
LAGS = wrap_degrees(-np.degrees(PHASES))  # the same phases as the trackers return them
NOISE = 0.01
EDGE = 1.0  # s ignored at both ends

T = np.arange(int(DURATION * FS)) / FS


def ramp(rpm0: float, rpm1: float) -> tuple[np.ndarray, np.ndarray]:
    """Linear speed (K,) rpm and its exact shaft angle (K,) in revolutions."""
    slope = (rpm1 - rpm0) / DURATION
    return rpm0 + slope * T, (rpm0 * T + 0.5 * slope * T**2) / 60.0


def resonance(rpm: np.ndarray) -> np.ndarray:
    """Order-1 amplitude with an SDOF-like resonance at 1800 rpm (peak 0.8, base 0.5)."""
    w = rpm / 1800.0
    return 0.5 + 0.06 / np.sqrt((1.0 - w**2) ** 2 + (0.2 * w) ** 2)


def fig51_signal(rpm0: float, rpm1: float, order1_amp=None, seed: int = 0):
    """x (K,), rpm (K,), true amplitudes (K, 4)."""
    rpm, rev = ramp(rpm0, rpm1)
    amps = np.tile(AMPS, (T.size, 1))
    if order1_amp is not None:
        amps[:, 0] = order1_amp(rpm)
    x = np.sum(amps * np.cos(2 * np.pi * rev[:, None] * ORDERS + PHASES), axis=1)
    x += NOISE * np.random.default_rng(seed).standard_normal(T.size)
    return x, rpm, amps


TRACKERS = {"cot": cot_orders, "vkf": vkf_orders, "tvdft": tvdft_orders}


def track(method: str, x, rpm, orders=ORDERS, **kw):
    return TRACKERS[method](x, FS, rpm, orders, **kw)


def interior_errors(tr, amps: np.ndarray) -> np.ndarray:
    """Max relative amplitude error (n_orders,) in %, edges excluded."""
    sel = (tr.times > EDGE) & (tr.times < DURATION - EDGE)
    assert sel.sum() > 10
    true = np.column_stack([np.interp(tr.times[sel], T, a) for a in amps.T])
    return 100.0 * np.max(np.abs(tr.amplitudes[sel] - true) / true, axis=0)


@pytest.fixture(scope="module")
def steady():
    return fig51_signal(1800.0, 1800.0)


@pytest.fixture(scope="module")
def runup():
    return fig51_signal(600.0, 3000.0, seed=1)


@pytest.fixture(scope="module")
def runup_resonance():
    return fig51_signal(600.0, 3000.0, order1_amp=resonance, seed=2)


@pytest.mark.parametrize("method", ["cot", "vkf", "tvdft"])
def test_steady_speed_amplitudes_and_phases(method, steady):
    x, rpm, amps = steady
    tr = track(method, x, rpm)
    k_out = tr.times.size
    assert tr.amplitudes.shape == (k_out, 4) and tr.phases.shape == (k_out, 4)
    assert np.all(np.diff(tr.times) > 0)
    assert np.all(interior_errors(tr, amps) < 1.0)
    sel = (tr.times > EDGE) & (tr.times < DURATION - EDGE)
    dphi = np.radians(wrap_degrees(tr.phases[sel] - LAGS))
    assert np.max(np.abs(dphi)) < 0.02  # rad


@pytest.mark.parametrize("method", ["cot", "vkf", "tvdft"])
def test_phase_is_the_contracts_lag_from_the_once_per_rev_mark(method):
    """A cosine peaking a known angle after the once-per-rev mark (the first sample at the
    mark, a tacho pulse each revolution) gives that angle as the phase: a lag, in degrees,
    wrapped into [-180, 180) (180 comes out as -180); the 1x vector is A exp(-j lag)."""
    rpm, rev = ramp(900.0, 2400.0)
    mark = tacho_pulse_times(np.sin(2 * np.pi * rev), FS)  # once per rev: rising at rev 1, 2, ...
    speed = rpm_from_tacho(np.r_[0.0, mark[mark > 0.01]], FS, T.size)  # the first sample on the mark
    for lag, want in ((30.0, 30.0), (-75.0, -75.0), (150.0, 150.0), (180.0, -180.0), (200.0, -160.0)):
        orders = [1.0, 2.0]
        x = 2.0 * np.cos(2 * np.pi * rev - np.radians(lag)) + 0.5 * np.cos(4 * np.pi * rev - np.radians(lag))
        tr = track(method, x, speed, orders)
        got = tr.phases[(tr.times > EDGE) & (tr.times < DURATION - EDGE)]
        assert np.all((got >= -180.0) & (got < 180.0)), (method, lag)
        err = wrap_degrees(got - want)
        assert np.max(np.abs(err)) < 1.0, (method, lag, np.max(np.abs(err)))  # degrees
        if want == -180.0:  # on the wrap: every value on the -180 side or within a degree of it
            assert np.all((got < -179.0) | (got > 179.0)), (method, lag)
        z = tr.complex_amplitudes[:, 0]
        np.testing.assert_allclose(z, order_vectors(tr.amplitudes[:, 0], tr.phases[:, 0]), equal_nan=True)
        ok = np.isfinite(z)
        assert np.max(np.abs(np.angle(z[ok] * np.exp(1j * np.radians(lag))))) < np.radians(1.0)


@pytest.mark.parametrize("method", ["cot", "vkf", "tvdft"])
def test_runup_constant_amplitudes(method, runup):
    x, rpm, amps = runup
    tr = track(method, x, rpm)
    assert np.all(interior_errors(tr, amps) < 1.0)
    sel = (tr.times > EDGE) & (tr.times < DURATION - EDGE)
    dphi = np.radians(wrap_degrees(tr.phases[sel] - LAGS))
    assert np.max(np.abs(dphi)) < 0.03


@pytest.mark.parametrize("method", ["cot", "vkf", "tvdft"])
def test_runup_follows_resonance(method, runup_resonance):
    x, rpm, amps = runup_resonance
    tr = track(method, x, rpm)
    err = interior_errors(tr, amps)
    assert err[0] < 3.0  # order 1 sweeps through the resonance (0.5 -> 0.8 -> 0.5)
    assert np.all(err[1:] < 1.0)
    peak = tr.rpm[np.nanargmax(tr.amplitudes[:, 0])]
    assert abs(peak - 1800.0) < 60.0


def test_cot_output_times_are_block_centres(runup):
    x, rpm, _ = runup
    tr = cot_orders(x, FS, rpm, ORDERS, block_revs=8, hop_revs=4)
    rev = np.interp(tr.times, T, ramp(600.0, 3000.0)[1])
    np.testing.assert_allclose(rev, 4.0 + 4.0 * np.arange(tr.times.size), atol=1e-6)
    np.testing.assert_allclose(tr.rpm, np.interp(tr.times, T, rpm))


def test_cot_rectangular_window(runup):
    x, rpm, amps = runup
    tr = cot_orders(x, FS, rpm, ORDERS, window="rectangular", block_revs=4)
    assert np.all(interior_errors(tr, amps) < 1.0)


def test_cot_with_tacho_derived_speed(runup):
    x, rpm, amps = runup
    rev = ramp(600.0, 3000.0)[1]
    tacho = np.sin(2 * np.pi * 2.0 * rev)  # analog tacho, 2 pulses per revolution
    pulses = tacho_pulse_times(tacho, FS)
    speed = rpm_from_tacho(pulses, FS, T.size, pulses_per_rev=2)
    inner = (T > 0.5) & (T < DURATION - 0.5)
    assert np.max(np.abs(speed[inner] - rpm[inner])) < 0.5  # rpm
    tr = cot_orders(x, FS, speed, ORDERS)
    assert np.all(interior_errors(tr, amps) < 1.0)


def test_vkf_crossing_orders_two_shafts():
    """LP spool 600 -> 3000 rpm crosses a constant 1800 rpm HP spool at t = 5 s."""
    fs = 2048.0
    t = np.arange(int(DURATION * fs)) / fs
    n1 = 600.0 + 240.0 * t
    n2 = np.full_like(t, 1800.0)
    rev1 = (600.0 * t + 120.0 * t**2) / 60.0
    a1 = 1.0 + 0.03 * t
    x = a1 * np.cos(2 * np.pi * rev1 + 0.4) + 0.6 * np.cos(2 * np.pi * 30.0 * t - 1.0)
    x += NOISE * np.random.default_rng(3).standard_normal(t.size)
    sel = (t > EDGE) & (t < DURATION - EDGE)

    joint = vkf_orders(x, fs, np.column_stack([n1, n2]), [1.0, 1.0])
    assert np.max(np.abs(joint.amplitudes[sel, 0] - a1[sel]) / a1[sel]) < 0.01
    assert np.max(np.abs(joint.amplitudes[sel, 1] - 0.6) / 0.6) < 0.01
    dphi = np.radians(wrap_degrees(joint.phases[sel] - wrap_degrees(-np.degrees([0.4, -1.0]))))
    assert np.max(np.abs(dphi)) < 0.02

    alone = vkf_orders(x, fs, n2, [1.0])  # one order at a time cannot separate them
    assert np.max(np.abs(alone.amplitudes[sel, 0] - 0.6) / 0.6) > 0.2


def test_vkf_close_orders_joint():
    """Orders 1.0 and 1.05 at 1800 rpm are 1.5 Hz apart, inside one 2 Hz bandwidth."""
    fs = 1024.0
    t = np.arange(int(DURATION * fs)) / fs
    rpm = np.full_like(t, 1800.0)
    rev = 30.0 * t
    x = np.cos(2 * np.pi * rev) + 0.5 * np.cos(2 * np.pi * 1.05 * rev + 1.0)
    x += NOISE * np.random.default_rng(4).standard_normal(t.size)
    sel = (t > EDGE) & (t < DURATION - EDGE)
    joint = vkf_orders(x, fs, rpm, [1.0, 1.05])
    err = np.max(np.abs(joint.amplitudes[sel] - [1.0, 0.5]) / [1.0, 0.5], axis=0)
    assert np.all(err < 0.01)
    alone = vkf_orders(x, fs, rpm, [1.0])
    assert np.max(np.abs(alone.amplitudes[sel, 0] - 1.0)) > 0.05


def test_vkf_bandwidth_is_minus_3db():
    """An envelope modulated at B/2 Hz comes out attenuated by 1/sqrt(2)."""
    fs, bw = 512.0, 2.0
    t = np.arange(int(DURATION * fs)) / fs
    rpm = np.full_like(t, 1200.0)
    envelope = 1.0 + 0.2 * np.cos(2 * np.pi * (bw / 2) * t)
    x = envelope * np.cos(2 * np.pi * 20.0 * t)
    tr = vkf_orders(x, fs, rpm, [1.0], bandwidth_hz=bw)
    sel = (t > 3) & (t < 7)
    ref = np.cos(2 * np.pi * (bw / 2) * t[sel])
    depth = 2 * np.mean((tr.amplitudes[sel, 0] - 1.0) * ref)
    assert depth / 0.2 == pytest.approx(1 / np.sqrt(2), rel=0.02)
    assert weighting_factor(bw, fs) > 0


def test_vkf_solvers_agree(steady):
    x, rpm, _ = steady
    n = 4096
    a = vkf_orders(x[:n], FS, rpm[:n], ORDERS, solver="banded")
    b = vkf_orders(x[:n], FS, rpm[:n], ORDERS, solver="spsolve")
    np.testing.assert_allclose(a.amplitudes, b.amplitudes, atol=1e-9)
    np.testing.assert_allclose(np.radians(wrap_degrees(a.phases - b.phases)), 0.0, atol=1e-9)


# ---------------------------------------------------------------- error paths
GOOD_X = np.cos(2 * np.pi * 30.0 * np.arange(4096) / 1024.0)
GOOD_RPM = np.full(4096, 1800.0)


@pytest.mark.parametrize("method", ["cot", "vkf", "tvdft"])
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"x": GOOD_X[:, None]}, "x must be 1-D"),
        ({"x": np.where(np.arange(4096) == 7, np.nan, GOOD_X)}, "x contains 1 NaN"),
        ({"fs": 0.0}, "fs must be finite and > 0"),
        ({"fs": -5.0}, "fs must be finite and > 0"),
        ({"fs": float("nan")}, "fs must be finite and > 0"),
        ({"fs": "fast"}, "fs must be a number"),
        ({"rpm": GOOD_RPM[:-1]}, "rpm must have shape"),
        ({"rpm": np.where(np.arange(4096) == 3, np.inf, GOOD_RPM)}, "rpm contains 1 NaN/inf"),
        ({"orders": []}, "orders must be a non-empty"),
        ({"orders": [1.0, -2.0]}, "orders must be finite and > 0"),
        ({"orders": [1.0, 1.0]}, "orders"),
        ({"orders": [40.0]}, "Nyquist"),
        ({"x": GOOD_X[:3], "rpm": GOOD_RPM[:3]}, "too short"),
    ],
)
def test_invalid_input_raises(method, kwargs, match):
    args = {"x": GOOD_X, "fs": 1024.0, "rpm": GOOD_RPM, "orders": [1.0, 2.0]} | kwargs
    with pytest.raises(ValueError, match=match):
        TRACKERS[method](**args)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"rpm": np.zeros(4096)}, "rpm must be > 0"),
        ({"x": GOOD_X[:100], "rpm": GOOD_RPM[:100]}, "too short.*revolutions"),
        ({"window": "kaiser"}, "window must be one of"),
        ({"samples_per_rev": 16, "orders": [7.0]}, "anti-alias pass band"),
        ({"samples_per_rev": 2.5}, "samples_per_rev must be an integer"),
        ({"block_revs": 0}, "block_revs must be an integer >= 1"),
        ({"hop_revs": 0}, "hop_revs must be an integer >= 1"),
    ],
)
def test_cot_invalid_options(kwargs, match):
    args = {"x": GOOD_X, "fs": 1024.0, "rpm": GOOD_RPM, "orders": [1.0, 2.0]} | kwargs
    with pytest.raises(ValueError, match=match):
        cot_orders(**args)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"bandwidth_hz": 0.0}, "bandwidth_hz must lie in"),
        ({"bandwidth_hz": 600.0}, "bandwidth_hz must lie in"),
        ({"bandwidth_hz": [1.0, 2.0, 3.0]}, "bandwidth_hz must be a scalar or have shape"),
        ({"solver": "cg"}, "solver must be one of"),
        ({"bandwidth_hz": 0.01}, "too narrow"),
        ({"rpm": np.column_stack([GOOD_RPM, GOOD_RPM]), "orders": [1.0, 1.0]}, "identical"),
        ({"rpm": np.ones((4096, 3))}, "rpm must have shape"),
    ],
)
def test_vkf_invalid_options(kwargs, match):
    args = {"x": GOOD_X, "fs": 1024.0, "rpm": GOOD_RPM, "orders": [1.0, 2.0]} | kwargs
    with pytest.raises(ValueError, match=match):
        vkf_orders(**args)


def test_tacho_invalid_input():
    with pytest.raises(ValueError, match="strictly increasing"):
        rpm_from_tacho([0.0, 0.1, 0.1, 0.3], 1024.0, 100)
    with pytest.raises(ValueError, match="pulse_times is too short"):
        rpm_from_tacho([0.0, 0.1], 1024.0, 100)
    with pytest.raises(ValueError, match="pulses_per_rev"):
        rpm_from_tacho([0.0, 0.1, 0.2, 0.3], 1024.0, 100, pulses_per_rev=0)


def test_tvdft_one_output_a_sample_nan_only_where_the_window_does_not_fit(runup):
    x, rpm, amps = runup
    tr = tvdft_orders(x, FS, rpm, ORDERS, block_revs=8)
    assert tr.times.shape == (T.size,) and np.allclose(tr.times, T)
    rev = np.cumsum(np.r_[0.0, 0.5 * (rpm[1:] + rpm[:-1]) / 60.0 / FS])
    fits = (rev >= 4.0) & (rev <= rev[-1] - 4.0)  # B / 2 = 4 revolutions from either end
    assert np.isnan(tr.amplitudes[~fits]).all() and np.isfinite(tr.amplitudes[fits]).all()


def test_tvdft_reads_an_amplitude_linear_in_angle_at_the_window_centre():
    rpm, rev = ramp(600.0, 3000.0)
    a = 1.0 + 0.02 * rev  # grows with the angle
    tr = tvdft_orders(a * np.cos(2 * np.pi * rev), FS, rpm, [1.0], block_revs=8)
    ok = np.isfinite(tr.amplitudes[:, 0])
    np.testing.assert_allclose(tr.amplitudes[ok, 0], a[ok], rtol=2e-4)


def test_tvdft_invalid_block():
    with pytest.raises(ValueError, match="block_revs must be a positive number"):
        tvdft_orders(GOOD_X, 1024.0, GOOD_RPM, [1.0], block_revs=0)
    with pytest.raises(ValueError, match="too short.*revolutions"):
        tvdft_orders(GOOD_X[:100], 1024.0, GOOD_RPM[:100], [1.0])
