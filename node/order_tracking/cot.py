"""Computed order tracking (COT): angular resampling + block DFT at exact order bins.

Pipeline (x: (K,) signal sampled at fs Hz, rpm: (K,) reference shaft speed in rev/min):

1. Shaft angle: rev(t) = integral of rpm/60 dt (trapezoid), rev(0) = 0.
2. Angular resampling, alias-free by construction: x is interpolated (cubic spline in
   time) at equal angle steps of 1/L rev with L = N*M and M = ceil(fs / (N * f_min)),
   f_min = min(rpm)/60 Hz. At L samples/rev even the slowest shaft speed maps the whole
   time-domain band [0, fs/2] below the angular Nyquist L/2 orders, so this step cannot
   alias.
3. Anti-alias low-pass + decimation to N samples/rev: a zero-phase Kaiser FIR
   (80 dB stop band) in the order domain, pass band up to 0.4*N orders, stop band from
   0.6*N orders, followed by keeping every M-th sample (scipy.signal.resample_poly).
   Because the cutoff is fixed in orders, it follows the speed in Hz: this is the
   speed-tracking anti-alias filter that order-domain resampling needs. Content folded
   from [0.5, 0.6]*N lands in [0.4, 0.5]*N, above every allowed order (<= 0.4*N).
4. Block DFT: blocks of B whole revolutions (B*N samples), hop H revolutions. For
   order p the complex amplitude is evaluated exactly at p (no FFT-bin rounding):
       c_p = 2 / sum(w) * sum_j w_j y_j exp(-i 2 pi p rev_j)
   with rev_j the absolute angle, so ``a*cos(2 pi p rev + phi)`` gives c_p = a e^{i phi}.
5. Output time of a block: the time at which the shaft passes the window's centroid
   angle (not the mean of start and end times, which differs during a run-up).

Window choice (``window``):
- "hann" (default, periodic Hann of length B*N): integer orders that differ by >= 2/B
  leak exactly zero into each other; sidelobes decay 18 dB/oct so non-integer orders,
  noise and speed errors leak little; amplitude varying linearly in angle over the
  block is read exactly at the block centre. Costs a 1.5x wider noise bandwidth.
- "rectangular": orders differing by a multiple of 1/B are exactly orthogonal and the
  noise bandwidth is smallest, but any non-integer content leaks strongly (-13 dB).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy.interpolate import CubicSpline
from scipy.signal import firwin, kaiserord, resample_poly

from node.contract.vector import order_lags

from ._checks import check_below_nyquist, check_fs, check_orders, check_rpm, check_signal
from .angle import shaft_revolutions, time_at_revolutions
from .result import OrderTrack

_PASS_FRACTION = 0.4  # highest usable order, as a fraction of samples per revolution
_STOP_FRACTION = 0.6
_STOP_ATTENUATION_DB = 80.0
_MAX_OVERSAMPLED_POINTS = 50_000_000
_WINDOWS = ("hann", "rectangular")


def default_samples_per_rev(max_order: float) -> int:
    """Smallest power of two >= max(32, 4 * max_order)."""
    return int(2 ** math.ceil(math.log2(max(32.0, 4.0 * max_order))))


def angular_resample(x: np.ndarray, fs: float, rpm: np.ndarray,
                     samples_per_rev: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Resample x (K,) to ``samples_per_rev`` samples per revolution, anti-aliased.

    Returns ``(y, rev_grid, rev)``: y (J,) the angle-domain signal at angles
    rev_grid = arange(J) / samples_per_rev (rev), and rev (K,) the shaft angle (rev)
    at the input samples.
    """
    n = int(samples_per_rev)
    rev = shaft_revolutions(rpm, fs)
    f_min = float(rpm.min()) / 60.0
    m = max(1, math.ceil(fs / (n * f_min)))
    l_hi = n * m
    j_hi = int(math.floor(rev[-1] * l_hi)) + 1
    if j_hi > _MAX_OVERSAMPLED_POINTS:
        raise ValueError(
            f"angular oversampling needs {j_hi} points (min speed {60 * f_min:g} rpm is "
            f"too low for fs={fs:g} Hz); raise the minimum speed or lower fs"
        )
    rev_hi = np.arange(j_hi) / l_hi
    t_hi = time_at_revolutions(rev, rpm, fs, rev_hi)
    t = np.arange(x.size) / fs
    y_hi = CubicSpline(t, x)(t_hi)
    if m > 1:
        width = (_STOP_FRACTION - _PASS_FRACTION) * n / (l_hi / 2.0)
        numtaps, beta = kaiserord(_STOP_ATTENUATION_DB, width)
        numtaps |= 1  # odd length: linear phase with an integer delay
        taps = firwin(numtaps, 1.0 / m, window=("kaiser", beta))
        y = resample_poly(y_hi, 1, m, window=taps)
    else:
        y = y_hi
    return y, np.arange(y.size) / n, rev


def _window(name: str, length: int) -> np.ndarray:
    if name == "hann":
        return 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(length) / length)
    return np.ones(length)


def cot_orders(x: object, fs: float, rpm: object, orders: object, *,
               samples_per_rev: int | None = None, block_revs: int = 8,
               hop_revs: int | None = None, window: str = "hann") -> OrderTrack:
    """Order amplitude and phase by computed order tracking.

    Parameters
    ----------
    x : (K,) vibration signal (any unit; amplitudes come out in the same unit).
    fs : sampling rate of x and rpm, Hz.
    rpm : (K,) shaft speed, rev/min, > 0 (e.g. from :func:`rpm_from_tacho`).
    orders : (n_orders,) orders to track, each <= 0.4 * samples_per_rev.
    samples_per_rev : angular sampling N; default: power of two >= max(32, 4*max order).
    block_revs : B, whole revolutions per DFT block (order resolution 1/B).
    hop_revs : revolutions between block starts; default max(1, B // 2).
    window : "hann" (default) or "rectangular", see the module docstring.

    Returns
    -------
    OrderTrack with times (K_out,) s at block centres, amplitudes and phases (lags, degrees in
    [-180, 180)) (K_out, n_orders), rpm (K_out,) the speed at those times.
    """
    fs = check_fs(fs)
    sig = check_signal(x)
    ords = check_orders(orders)
    speed = check_rpm(rpm, sig.size)
    check_below_nyquist(ords, speed, fs)
    if window not in _WINDOWS:
        raise ValueError(f"window must be one of {_WINDOWS}, got {window!r}")
    n = default_samples_per_rev(ords.max()) if samples_per_rev is None else samples_per_rev
    if int(n) != n or n < 4:
        raise ValueError(f"samples_per_rev must be an integer >= 4, got {samples_per_rev!r}")
    n = int(n)
    if ords.max() > _PASS_FRACTION * n:
        raise ValueError(
            f"order {ords.max():g} exceeds the anti-alias pass band {_PASS_FRACTION * n:g} "
            f"of samples_per_rev={n}; use samples_per_rev >= {ords.max() / _PASS_FRACTION:g}"
        )
    if int(block_revs) != block_revs or block_revs < 1:
        raise ValueError(f"block_revs must be an integer >= 1, got {block_revs!r}")
    block_revs = int(block_revs)
    hop = max(1, block_revs // 2) if hop_revs is None else hop_revs
    if int(hop) != hop or hop < 1:
        raise ValueError(f"hop_revs must be an integer >= 1, got {hop_revs!r}")
    hop = int(hop)
    total_revs = float(np.sum(0.5 * (speed[1:] + speed[:-1]))) / 60.0 / fs
    if total_revs < block_revs:
        raise ValueError(
            f"signal too short: it covers {total_revs:.3g} revolutions, one block needs "
            f"block_revs={block_revs}"
        )

    y, _, rev = angular_resample(sig, fs, speed, n)
    length = block_revs * n
    blocks = sliding_window_view(y, length)[:: hop * n]
    starts = np.arange(blocks.shape[0]) * hop  # block start angle, rev
    w = _window(window, length)
    j = np.arange(length)
    kernel = w[None, :] * np.exp(-2j * np.pi * ords[:, None] * j[None, :] / n)
    coeff = (2.0 / w.sum()) * (blocks @ kernel.T)
    coeff *= np.exp(-2j * np.pi * starts[:, None] * ords[None, :])
    centre_rev = starts + float(np.dot(w, j) / w.sum()) / n
    times = time_at_revolutions(rev, speed, fs, centre_rev)
    rpm_out = np.interp(times, np.arange(sig.size) / fs, speed)
    return OrderTrack(times=times, amplitudes=np.abs(coeff), phases=order_lags(coeff),
                      orders=ords, rpm=rpm_out, method="cot")
