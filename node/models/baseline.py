"""The characteristic-curve baseline: mean training amplitude at the same switch speed.

What a vibration engineer compares against first (fixed alarm curves are
built this way). Also usable as a static nonlinear input feature.
"""

from __future__ import annotations

import numpy as np


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
        idx = np.floor(speed[ok] / self.bin_width).astype(np.int64)
        uniq, inv = np.unique(idx, return_inverse=True)
        sums = np.bincount(inv, weights=y[ok])
        counts = np.bincount(inv)
        self.centres_ = (uniq + 0.5) * self.bin_width
        self.means_ = sums / counts
        return self

    def predict(self, speed: np.ndarray) -> np.ndarray:
        """Amplitude at each speed (K,), held constant beyond the trained range."""
        return np.interp(np.asarray(speed, float), self.centres_, self.means_)
