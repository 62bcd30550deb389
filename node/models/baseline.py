"""The characteristic-curve baseline: mean training amplitude at the same switch speed.

What a vibration engineer compares against first (fixed alarm curves are
built this way). Also usable as a static nonlinear input feature.
"""

from __future__ import annotations

import bisect
import math

import numpy as np


def bin_sums(speed: np.ndarray, y: np.ndarray, bin_width: float
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Speed bins holding data (B,) (bin b spans [b, b + 1) x bin_width), the sum and count of y in each.

    speed, y: (K,) finite.

    >>> bin_sums(np.array([10.0, 20.0, 60.0]), np.array([1.0, 3.0, 5.0]), 25.0)
    (array([0, 2]), array([4., 5.]), array([2, 1]))
    """
    idx = np.floor(np.asarray(speed, float) / bin_width).astype(np.int64)
    uniq, inv = np.unique(idx, return_inverse=True)
    return uniq, np.bincount(inv, weights=np.asarray(y, float)), np.bincount(inv)


class CharacteristicCurve:
    """Mean target per speed bin, linearly interpolated (scikit-learn style).

    Args:
        bin_width: speed bin, in the switch channel's unit (rpm).
    Learned: ``centres_`` (B,), ``means_`` (B,) over bins that hold data.
    """

    def __init__(self, bin_width: float = 25.0) -> None:
        self.bin_width = bin_width

    def fit(self, speed: np.ndarray, y: np.ndarray) -> CharacteristicCurve:
        speed = np.asarray(speed, float).ravel()
        y = np.asarray(y, float).ravel()
        ok = np.isfinite(speed) & np.isfinite(y)
        if not ok.any():
            raise ValueError("no finite (speed, amplitude) pairs to fit a characteristic curve")
        bins, sums, counts = bin_sums(speed[ok], y[ok], self.bin_width)
        self.centres_ = (bins + 0.5) * self.bin_width
        self.means_ = sums / counts
        return self

    def predict(self, speed: np.ndarray) -> np.ndarray:
        """Amplitude at each speed (K,), held constant beyond the trained range."""
        return np.interp(np.asarray(speed, float), self.centres_, self.means_)


class FleetCurve:
    """The characteristic curve (the training runs' mean target per switch speed) at one speed,
    in plain floats: linear between its points, held beyond them (``np.interp``'s rule).

    >>> FleetCurve(np.array([1000.0, 2000.0]), np.array([1.0, 3.0])).at(1500.0)
    2.0
    """

    def __init__(self, speeds: np.ndarray, means: np.ndarray) -> None:
        self._xs = [float(x) for x in np.asarray(speeds, float)]
        self._ys = [float(x) for x in np.asarray(means, float)]
        if not self._xs or len(self._xs) != len(self._ys):
            raise ValueError("a characteristic curve needs as many means as speeds, at least one")

    def at(self, speed: float) -> float:
        """The curve at ``speed`` (NaN for a NaN speed)."""
        if speed != speed:
            return math.nan
        xs, ys = self._xs, self._ys
        i = bisect.bisect_right(xs, speed)
        if i == 0:
            return ys[0]
        if i == len(xs):
            return ys[-1]
        x0, x1 = xs[i - 1], xs[i]
        return ys[i - 1] + (ys[i] - ys[i - 1]) * (speed - x0) / (x1 - x0)
