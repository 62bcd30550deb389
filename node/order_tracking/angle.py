"""Shaft angle from speed, its inverse, and speed from tacho pulses.

Conventions: time t = n / fs in seconds from the first sample; speed in rev/min;
shaft angle in revolutions (rev) unless a name says rad; angle 0 at the first sample.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicHermiteSpline, CubicSpline

from ._checks import check_fs, check_signal


def shaft_revolutions(rpm: np.ndarray, fs: float) -> np.ndarray:
    """Shaft angle in revolutions, (K,) from speed (K,) or (K, m) rev/min.

    Trapezoidal integration of rpm/60 (exact for speed piecewise linear between
    samples); the first sample is at angle 0.
    """
    f_rot = np.asarray(rpm, dtype=float) / 60.0
    inc = 0.5 * (f_rot[1:] + f_rot[:-1]) / fs
    rev = np.zeros_like(f_rot)
    rev[1:] = np.cumsum(inc, axis=0)
    return rev


def time_at_revolutions(rev: np.ndarray, rpm: np.ndarray, fs: float,
                        query: np.ndarray) -> np.ndarray:
    """Invert the (strictly increasing) angle curve: times in s of angles ``query`` (rev).

    Cubic Hermite interpolation of t(rev) with slopes dt/drev = 60/rpm at the samples,
    so the inverse is consistent with the quadratic angle of a linear speed ramp.
    """
    t = np.arange(rev.size) / fs
    inverse = CubicHermiteSpline(rev, t, 60.0 / rpm)
    return inverse(query)


def tacho_pulse_times(tacho: object, fs: float, level: float | None = None) -> np.ndarray:
    """Rising-edge crossing times (s) of a tacho signal (K,), linearly interpolated.

    ``level`` defaults to the mid-range ``(max + min) / 2`` of the signal.
    """
    fs = check_fs(fs)
    sig = check_signal(tacho, name="tacho")
    thr = 0.5 * (sig.max() + sig.min()) if level is None else float(level)
    idx = np.flatnonzero((sig[:-1] < thr) & (sig[1:] >= thr))
    frac = (thr - sig[idx]) / (sig[idx + 1] - sig[idx])
    return (idx + frac) / fs


def rpm_from_tacho(pulse_times: object, fs: float, k: int,
                   pulses_per_rev: int = 1) -> np.ndarray:
    """Speed (K,) in rev/min at the sample times n/fs from tacho pulse times (s).

    Each pulse advances the shaft by 1/pulses_per_rev rev; a cubic spline through
    (pulse time, angle) is differentiated at the sample times. Outside the pulse
    span the speed is held at its end values. Pulse-time jitter is differentiated:
    with a square-wave tacho, quantisation to 1/fs gives speed ripple of about
    f_pulse/fs; the shaft angle (what order tracking integrates) stays exact at the
    pulses. An analog (sine-like) tacho interpolates to far better than 1/fs.
    """
    fs = check_fs(fs)
    times = check_signal(pulse_times, name="pulse_times", min_len=4)
    if np.any(np.diff(times) <= 0.0):
        raise ValueError("pulse_times must be strictly increasing")
    if int(pulses_per_rev) < 1:
        raise ValueError(f"pulses_per_rev must be >= 1, got {pulses_per_rev!r}")
    if int(k) < 2:
        raise ValueError(f"k must be >= 2 samples, got {k!r}")
    angle = np.arange(times.size) / int(pulses_per_rev)
    spline = CubicSpline(times, angle, bc_type="natural")
    t = np.clip(np.arange(int(k)) / fs, times[0], times[-1])
    return 60.0 * spline(t, 1)
