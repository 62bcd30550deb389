"""The chirp rate, a derived model input (``chirp_rate``, rpm/s); no I/O.

Section 3.3 of the dissertation names the transition rate between OCs, the chirp rate, a
parameter that shapes the vibration: a fast ramp crosses a resonance before its response has
built up (a lower, later peak through the order tracker), a slow one lets it grow. ``ChirpRate``
gives, per sample, the switch speed's change over the last ``window_s`` seconds divided by that
time, causally (the speed ``window_s`` ago is the oldest kept), a dropout holding the last speed;
in a run's first window, over the samples known so far (from the second one), so that the start
from light-off has a rate as soon as the speed has two samples.
The node (``MonitorPipeline``) and training (``add_chirp_rate``) step the very same object, so
their inputs agree to the bit.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque

import numpy as np

from node.contract import FS

CHIRP_RATE = "chirp_rate"  # the derived channel's name (rpm/s of the schedule's switch channel)
WINDOW_S = 1.0  # s over which the speed's change is taken


class ChirpRate:
    """Stateful, bounded memory (``window_s`` x fs speeds).

    >>> c = ChirpRate(window_s=0.1, fs=40.0)  # 4 samples
    >>> [c.step(v) for v in (1000.0, 1010.0, float("nan"), 1030.0, 1040.0, 1050.0)]
    [nan, 400.0, 200.0, 400.0, 400.0, 400.0]
    """

    def __init__(self, window_s: float = WINDOW_S, fs: float = FS) -> None:
        if not (math.isfinite(window_s) and window_s > 0 and math.isfinite(fs) and fs > 0):
            raise ValueError(f"window_s and fs must be positive, got {window_s!r}, {fs!r}")
        self.n = max(1, int(round(window_s * fs)))
        self.fs = fs
        self.per_s = fs / self.n  # 1 / the window's length in s
        self.reset()

    def reset(self) -> None:
        """A new run: no speed known."""
        self._past: deque[float] = deque(maxlen=self.n + 1)
        self._last = math.nan

    def step(self, speed: float) -> float:
        """One sample's switch speed (rpm; NaN: a dropout, the last one held): the rate, rpm/s
        (NaN until two speeds are known; over those known in the run's first window)."""
        if speed == speed:
            self._last = speed
        elif self._last != self._last:
            return math.nan
        past = self._past
        past.append(self._last)
        n = len(past)
        if n <= self.n:
            return (past[-1] - past[0]) * self.fs / (n - 1) if n > 1 else math.nan
        return (past[-1] - past[0]) * self.per_s


def chirp_rate_column(speed: np.ndarray, window_s: float = WINDOW_S, fs: float = FS) -> np.ndarray:
    """``ChirpRate`` stepped over a run's switch speeds (K,): the rates (K,), rpm/s."""
    c = ChirpRate(window_s, fs)
    return np.array([c.step(v) for v in np.asarray(speed, dtype=float).tolist()])


def add_chirp_rate(run, switch: str):
    """``run`` (a ``node.training.runs.Run``) with the ``chirp_rate`` column appended (as it is
    when it has one already or lacks the switch channel)."""
    if CHIRP_RATE in run.channels or switch not in run.channels:
        return run
    col = chirp_rate_column(run.column(switch))
    return dataclasses.replace(run, data=np.column_stack([run.data, col]),
                               channels=(*run.channels, CHIRP_RATE))
