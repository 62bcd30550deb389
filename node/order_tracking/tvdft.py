"""Time-variant discrete Fourier transform (TVDFT) order tracking (dissertation section 3.2.1).

The DFT kernel's frequency follows the order, exp(-i 2 pi p rev(t)) with rev the shaft angle
integrated from the speed, and the sum runs over the raw time samples in a window of
``block_revs`` revolutions centred on each output sample: no resampling, one output per input
sample. Each sample is weighted by the angle it spans (``d rev``), so the sum approximates the
angle-domain integral, and by a Hann window in angle:

    c_p(m) = 2 sum_n w_n x_n exp(-i 2 pi p rev_n) d rev_n / sum_n w_n d rev_n,
    w_n = 0.5 + 0.5 cos(2 pi (rev_n - rev_m) / B),  |rev_n - rev_m| <= B / 2,

so ``a*cos(2 pi p rev + phi)`` gives c_p = a e^{i phi}, returned as the lag -phi in degrees
(``node.contract.vector.order_lags``). The Hann window is three complex
exponentials in angle, so every window sum is a difference of cumulative sums: O(K) per order
whatever B (the reason it is written by hand; scipy has no angle-domain TVDFT). Integer orders
differing by 2 / B or more leak nothing into each other; an amplitude linear in angle is read
exactly at the window's centre. Where the window does not fit in the record (the first and
last B / 2 revolutions) the output is NaN.
"""

from __future__ import annotations

import numpy as np

from node.contract.vector import order_lags

from ._checks import check_below_nyquist, check_fs, check_orders, check_rpm, check_signal
from .angle import shaft_revolutions
from .result import OrderTrack


def _window_sums(values: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """sum(values[lo[m]:hi[m]]) for every m, by a cumulative sum (K,) -> (M,)."""
    c = np.concatenate([np.zeros(1, dtype=values.dtype), np.cumsum(values)])
    return c[hi] - c[lo]


def tvdft_orders(x: object, fs: float, rpm: object, orders: object, *, block_revs: float = 8.0) -> OrderTrack:
    """Order amplitude and phase by the TVDFT (see the module docstring).

    Parameters
    ----------
    x : (K,) vibration signal (any unit; amplitudes come out in the same unit).
    fs : sampling rate of x and rpm, Hz.
    rpm : (K,) shaft speed, rev/min, > 0.
    orders : (n_orders,) orders to track (below the Nyquist frequency at every speed).
    block_revs : B, revolutions per window (order resolution about 2 / B with the Hann window).

    Returns
    -------
    OrderTrack with times (K,) = n / fs s, amplitudes and phases (lags, degrees in [-180, 180))
    (K, n_orders) (NaN where the window does not fit), rpm (K,) as given.

    >>> fs, n = 1000.0, 20000
    >>> rpm = np.linspace(600.0, 1800.0, n)
    >>> rev = shaft_revolutions(rpm, fs)
    >>> tr = tvdft_orders(3.0 * np.cos(2 * np.pi * rev - np.radians(30.0)), fs, rpm, [1.0])
    >>> k = n // 2
    >>> round(float(tr.amplitudes[k, 0]), 4), round(float(tr.phases[k, 0]), 4)
    (3.0, 30.0)
    """
    fs = check_fs(fs)
    sig = check_signal(x)
    ords = check_orders(orders)
    speed = check_rpm(rpm, sig.size)
    check_below_nyquist(ords, speed, fs)
    if not (np.isfinite(block_revs) and block_revs > 0):
        raise ValueError(f"block_revs must be a positive number, got {block_revs!r}")
    rev = shaft_revolutions(speed, fs)
    if rev[-1] - rev[0] < block_revs:
        raise ValueError(f"signal too short: it covers {rev[-1] - rev[0]:.3g} revolutions, one window "
                         f"needs block_revs={block_revs:g}")
    d = np.gradient(rev)  # the angle each sample stands for, rev
    half = 0.5 * block_revs
    lo = np.searchsorted(rev, rev - half, side="left")
    hi = np.searchsorted(rev, rev + half, side="right")
    fits = (rev - half >= rev[0]) & (rev + half <= rev[-1])
    turn = np.exp(2j * np.pi * rev / block_revs)  # the window's exponentials, e^{i 2 pi rev / B}
    den = (0.5 * _window_sums(d, lo, hi)
           + 0.5 * np.real(np.conj(turn) * _window_sums(d * turn, lo, hi)))
    coeff = np.empty((sig.size, ords.size), dtype=complex)
    for j, p in enumerate(ords):
        base = sig * d * np.exp(-2j * np.pi * p * rev)
        num = (0.5 * _window_sums(base, lo, hi)
               + 0.25 * np.conj(turn) * _window_sums(base * turn, lo, hi)
               + 0.25 * turn * _window_sums(base * np.conj(turn), lo, hi))
        coeff[:, j] = 2.0 * num / den
    coeff[~fits] = np.nan
    return OrderTrack(times=np.arange(sig.size) / fs, amplitudes=np.abs(coeff), phases=order_lags(coeff),
                      orders=ords, rpm=speed, method="tvdft")
